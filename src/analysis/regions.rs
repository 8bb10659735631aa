//! Opening-forest labeling and portals (000 §10.3.3-10.3.4): region roots are 6-connected sets
//! of forest roots with equal opening (Definition 10.8); every empty voxel takes the label of
//! the root its forest branch leads to (Definition 10.9); portals are the voxel faces between
//! 6-neighbours of different regions (Definitions 10.11-10.12).

use std::collections::HashMap;

use super::grid::VoxelGrid;
use super::opening::OpeningMap;
use crate::math::Vec3;

/// Label of occupied voxels.
pub const NO_REGION: u32 = u32::MAX;

/// One opening-forest region.
#[derive(Clone, Debug, PartialEq)]
pub struct Region {
    /// Opening of its root voxels.
    pub opening: u32,
    pub root_voxels: u32,
    pub voxels: u64,
    /// Mean position of its voxels (world).
    pub centroid: Vec3,
}

/// One face between two 6-adjacent voxels: the lower voxel's index and the axis of the face
/// normal (the face lies at the lower voxel's +axis side).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PortalFace {
    pub voxel: u32,
    pub axis: u8,
}

/// The faces separating two neighbouring regions `a < b`.
#[derive(Clone, Debug, PartialEq)]
pub struct Portal {
    pub regions: (u32, u32),
    pub faces: Vec<PortalFace>,
    /// World area of all faces.
    pub area: f32,
    /// Area-weighted mean of face centres (world).
    pub center: Vec3,
    /// Area-weighted mean normal pointing from region `a` into region `b`, normalised (zero
    /// when the faces cancel out, e.g. a portal wrapping around an obstacle).
    pub normal: Vec3,
}

/// Labels of every voxel and the regions.
#[derive(Clone, Debug)]
pub struct Labeling {
    pub labels: Vec<u32>,
    pub regions: Vec<Region>,
}

/// Union-find with path halving.
fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        parent[i as usize] = parent[parent[i as usize] as usize];
        i = parent[i as usize];
    }
    i
}

/// Opening-forest labeling of the empty voxels (opening > 0).
pub fn label_regions(grid: &VoxelGrid, om: &OpeningMap) -> Labeling {
    let n = grid.len();
    let [nx, ny, _] = grid.dims;
    let strides = [1, nx, nx * ny];
    // Region roots: union 6-neighbouring forest roots of equal opening.
    let mut parent: Vec<u32> = (0..n as u32).collect();
    for i in 0..n {
        if !om.is_root(i) {
            continue;
        }
        let c = grid.coords(i);
        for axis in 0..3 {
            if c[axis] + 1 < grid.dims[axis] {
                let j = i + strides[axis];
                if om.is_root(j) && om.opening[j] == om.opening[i] {
                    let (ri, rj) = (find(&mut parent, i as u32), find(&mut parent, j as u32));
                    if ri != rj {
                        parent[ri.max(rj) as usize] = ri.min(rj);
                    }
                }
            }
        }
    }
    let mut labels = vec![NO_REGION; n];
    let mut regions: Vec<Region> = Vec::new();
    let mut label_of_set: HashMap<u32, u32> = HashMap::new();
    for i in 0..n {
        if om.is_root(i) {
            let r = find(&mut parent, i as u32);
            let next = regions.len() as u32;
            let l = *label_of_set.entry(r).or_insert_with(|| {
                regions.push(Region {
                    opening: om.opening[i],
                    root_voxels: 0,
                    voxels: 0,
                    centroid: Vec3::ZERO,
                });
                next
            });
            labels[i] = l;
            regions[l as usize].root_voxels += 1;
        }
    }
    // Every other empty voxel follows its forest branch (openings strictly increase along it,
    // so it ends at a root); the path is labelled on the way back.
    let mut path = Vec::new();
    for i in 0..n {
        if om.opening[i] == 0 || labels[i] != NO_REGION {
            continue;
        }
        let mut j = i;
        while labels[j] == NO_REGION {
            path.push(j);
            j = om.center[j] as usize;
        }
        let l = labels[j];
        for &k in &path {
            labels[k] = l;
        }
        path.clear();
    }
    let mut sums = vec![[0.0f64; 3]; regions.len()];
    for (i, &l) in labels.iter().enumerate() {
        if l != NO_REGION {
            let c = grid.coords(i);
            regions[l as usize].voxels += 1;
            for k in 0..3 {
                sums[l as usize][k] += c[k] as f64 + 0.5;
            }
        }
    }
    for (r, s) in regions.iter_mut().zip(sums) {
        let v = r.voxels.max(1) as f64;
        r.centroid = grid.to_world([s[0] / v, s[1] / v, s[2] / v]);
    }
    Labeling { labels, regions }
}

/// Portals between all pairs of neighbouring regions, ordered by (a, b).
pub fn find_portals(grid: &VoxelGrid, labels: &[u32]) -> Vec<Portal> {
    let [nx, ny, _] = grid.dims;
    let strides = [1, nx, nx * ny];
    let mut by_pair: HashMap<(u32, u32), Vec<PortalFace>> = HashMap::new();
    for (i, &li) in labels.iter().enumerate() {
        if li == NO_REGION {
            continue;
        }
        let c = grid.coords(i);
        for axis in 0..3 {
            if c[axis] + 1 < grid.dims[axis] {
                let lj = labels[i + strides[axis]];
                if lj != NO_REGION && lj != li {
                    by_pair
                        .entry((li.min(lj), li.max(lj)))
                        .or_default()
                        .push(PortalFace {
                            voxel: i as u32,
                            axis: axis as u8,
                        });
                }
            }
        }
    }
    let face_area = (grid.voxel_size * grid.voxel_size) as f32;
    let mut portals: Vec<Portal> = by_pair
        .into_iter()
        .map(|((a, b), faces)| {
            let mut centre = Vec3::ZERO;
            let mut normal = Vec3::ZERO;
            for f in &faces {
                centre += face_center(grid, f);
                let mut axis = Vec3::ZERO;
                axis[f.axis as usize] = 1.0;
                // The lower voxel is in region a: the normal from a to b is +axis.
                normal += if labels[f.voxel as usize] == a {
                    axis
                } else {
                    -axis
                };
            }
            let count = faces.len() as f32;
            Portal {
                regions: (a, b),
                area: count * face_area,
                center: centre / count,
                normal: normal.normalize_or_zero(),
                faces,
            }
        })
        .collect();
    portals.sort_by_key(|p| p.regions);
    portals
}

/// World centre of a portal face.
pub fn face_center(grid: &VoxelGrid, f: &PortalFace) -> Vec3 {
    let c = grid.coords(f.voxel as usize);
    let mut g = [c[0] as f64 + 0.5, c[1] as f64 + 0.5, c[2] as f64 + 0.5];
    g[f.axis as usize] += 0.5;
    grid.to_world(g)
}

/// Samples a point uniformly on a portal's faces: returns the point, the face normal (from
/// region a to b) and the area density 1 / area.
pub fn sample_portal(
    grid: &VoxelGrid,
    labels: &[u32],
    portal: &Portal,
    u: f32,
    v: crate::math::Vec2,
) -> (Vec3, Vec3, f32) {
    let k = ((u * portal.faces.len() as f32) as usize).min(portal.faces.len() - 1);
    let f = portal.faces[k];
    let c = grid.coords(f.voxel as usize);
    let axis = f.axis as usize;
    let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
    let mut g = [c[0] as f64, c[1] as f64, c[2] as f64];
    g[axis] += 1.0;
    g[a] += v.x as f64;
    g[b] += v.y as f64;
    let mut n = Vec3::ZERO;
    n[axis] = if labels[f.voxel as usize] == portal.regions.0 {
        1.0
    } else {
        -1.0
    };
    (grid.to_world(g), n, 1.0 / portal.area)
}
