//! Window portals for environment light, found from the regions of the opening forest
//! (000 §10.3, lines 2790-3030): the openings between the interior and the outside, fitted
//! with rectangles, for portal-masked environment sampling (`light::environment::Portal`).
//!
//! - *Outside and interior.* The analysis fills the inside of closed objects. A region is
//!   interior when it does not touch the grid's border and is enclosed: of rays from its
//!   voxel nearest its centroid in [`ENCLOSURE_RAYS`] directions, at least
//!   [`ENCLOSURE`] hit geometry. Every other region is outside. (Touching the border alone is
//!   not enough: in an open scene small pockets, such as the wedge between a sphere and the
//!   ground, are regions that touch no border.)
//! - *Openings.* The voxel faces between an interior and an outside region, split into
//!   clusters of faces whose voxels are 26-neighbours (one room region may see the outside
//!   through several windows; one window may border several room regions).
//! - *Rectangles.* A cluster's outward normal is the axis of the sum of its faces' normals
//!   (from interior to outside); its extent in the other two axes is that of its faces. The
//!   empty voxels of an aperture lie inside it (voxelization is conservative), so each edge
//!   is then moved onto the geometry with a ray cast in the portal's plane from its centre,
//!   when the hit lies within a voxel and a half of the voxel edge. Planes at several offsets
//!   along the normal are tried; the narrowest rectangle bounded so on all four sides (the
//!   aperture, inside the wall) wins. A cluster bounded at no offset is no window (a gap
//!   between a curved object and the ground, say) and is dropped.
//!   A portal a little too large only wastes samples; one too small leaves directions to
//!   BSDF sampling, so the rule errs outward.
//! - *Sky.* A window lets the environment in: of rays from [`SKY_POINTS`]^2 points of the
//!   rectangle in [`SKY_DIRECTIONS`] directions of its outward hemisphere, at least one must
//!   reach infinity. This drops openings into cavities (the inside of a closed object that
//!   the voxels leave open to a pocket of outside space).

use std::time::Instant;

use super::grid::Resolution;
use super::pipeline::{Analysis, AnalysisSettings};
use super::regions::NO_REGION;
use crate::error::{Error, Result};
use crate::geometry::Ray;
use crate::light::environment::{InteriorMask, Portal};
use crate::math::Vec3;
use crate::scene::Scene;

/// Rays per region for the enclosure test (a Fibonacci sphere).
pub const ENCLOSURE_RAYS: usize = 128;
/// Smallest fraction of those rays that must hit geometry for a region to be interior.
pub const ENCLOSURE: f32 = 0.75;

/// Points per side of a rectangle for the sky test.
pub const SKY_POINTS: usize = 3;
/// Directions of the outward hemisphere per point for the sky test.
pub const SKY_DIRECTIONS: usize = 32;

/// How window portals are found.
#[derive(Clone, Debug, PartialEq)]
pub struct WindowPortalSettings {
    /// Voxels along the longest axis of the analysis grid.
    pub resolution: u32,
    /// Clusters of fewer faces are dropped (slits a voxel wide are noise, not windows).
    pub min_faces: usize,
}

impl Default for WindowPortalSettings {
    fn default() -> Self {
        WindowPortalSettings {
            resolution: 192,
            min_faces: 4,
        }
    }
}

/// The portals found, with what they cost.
#[derive(Clone, Debug)]
pub struct WindowPortals {
    pub portals: Vec<Portal>,
    /// The voxels of the interior regions and their 26-neighbours (the surfaces around the
    /// rooms lie in occupied voxels), where the portals apply; None without portals.
    pub interior: Option<InteriorMask>,
    pub voxel_size: f32,
    pub analysis_seconds: f64,
    pub fit_seconds: f64,
}

/// The portal sampler of `env=portals` for `scene`, built on the first call (by a render or
/// a C light sampler, whichever comes first): from the portals the scene lists, or else from
/// those [`window_portals`] finds with its default settings.
pub fn scene_env_portals(scene: &Scene) -> Result<&crate::scene::EnvPortals> {
    scene.env_portals_or_init(|scene| {
        window_portals(scene, &WindowPortalSettings::default())
            .map(|found| (found.portals, found.interior))
    })
}

/// Runs the analysis (regions only) and finds the window portals of `scene`.
pub fn window_portals(scene: &Scene, settings: &WindowPortalSettings) -> Result<WindowPortals> {
    if settings.resolution < 8 {
        return Err(Error::invalid(format!(
            "window portals: resolution {} is too coarse (at least 8)",
            settings.resolution
        )));
    }
    let started = Instant::now();
    let analysis = Analysis::build(
        scene,
        &AnalysisSettings {
            resolution: Resolution::LongestAxis(settings.resolution),
            // The insides of closed objects (thick walls, a sphere) are no rooms.
            fill_interiors: true,
            ..AnalysisSettings::default()
        },
        &|_, _| true,
    )?;
    let analysis_seconds = started.elapsed().as_secs_f64();
    let fitted = Instant::now();
    let portals = window_portals_in(&analysis, scene, settings.min_faces);
    let interior = (!portals.is_empty()).then(|| interior_mask(&analysis, scene));
    Ok(WindowPortals {
        portals,
        interior,
        voxel_size: analysis.grid.voxel_size as f32,
        analysis_seconds,
        fit_seconds: fitted.elapsed().as_secs_f64(),
    })
}

/// The interior regions' voxels, dilated by one voxel (26-neighbours).
fn interior_mask(analysis: &Analysis, scene: &Scene) -> InteriorMask {
    let interior = interior_regions(analysis, scene);
    let grid = &analysis.grid;
    let [nx, ny, nz] = grid.dims;
    let mut inside = vec![false; grid.len()];
    for (i, &label) in analysis.labels.iter().enumerate() {
        if label == NO_REGION || !interior[label as usize] {
            continue;
        }
        let [x, y, z] = grid.coords(i);
        for zz in z.saturating_sub(1)..(z + 2).min(nz) {
            for yy in y.saturating_sub(1)..(y + 2).min(ny) {
                for xx in x.saturating_sub(1)..(x + 2).min(nx) {
                    inside[xx + nx * (yy + ny * zz)] = true;
                }
            }
        }
    }
    InteriorMask {
        origin: Vec3::new(
            grid.origin[0] as f32,
            grid.origin[1] as f32,
            grid.origin[2] as f32,
        ),
        voxel_size: grid.voxel_size as f32,
        dims: grid.dims,
        inside,
    }
}

/// A Fibonacci-sphere direction `i` of `n`.
fn fibonacci_direction(i: usize, n: usize) -> Vec3 {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
    let r = (1.0 - y * y).max(0.0).sqrt();
    let phi = golden * i as f32;
    Vec3::new(r * phi.cos(), y, r * phi.sin())
}

/// Which regions are interior (see the module docs).
fn interior_regions(analysis: &Analysis, scene: &Scene) -> Vec<bool> {
    let grid = &analysis.grid;
    let [nx, ny, nz] = grid.dims;
    let mut touches_border = vec![false; analysis.regions.len()];
    // The region's voxel nearest its centroid: the centroid of a ring-shaped region may lie
    // inside an object.
    let mut nearest = vec![(f32::INFINITY, Vec3::ZERO); analysis.regions.len()];
    for (i, &label) in analysis.labels.iter().enumerate() {
        if label == NO_REGION {
            continue;
        }
        let [x, y, z] = grid.coords(i);
        if x == 0 || y == 0 || z == 0 || x + 1 == nx || y + 1 == ny || z + 1 == nz {
            touches_border[label as usize] = true;
        }
        let c = grid.voxel_center(i);
        let d = c.distance_squared(analysis.regions[label as usize].centroid);
        let best = &mut nearest[label as usize];
        if d < best.0 {
            *best = (d, c);
        }
    }
    nearest
        .iter()
        .zip(&touches_border)
        .map(|(&(_, from), &border)| {
            if border {
                return false;
            }
            let hits = (0..ENCLOSURE_RAYS)
                .filter(|&k| {
                    let ray = Ray::new(from, fibonacci_direction(k, ENCLOSURE_RAYS), f32::INFINITY);
                    scene.intersect_hit(&ray).is_some()
                })
                .count();
            hits as f32 >= ENCLOSURE * ENCLOSURE_RAYS as f32
        })
        .collect()
}

/// One face between an interior voxel and an outside one: its lower voxel's coordinates, its
/// axis, and whether the outside is on the + side.
#[derive(Clone, Copy, Debug)]
struct WindowFace {
    voxel: [usize; 3],
    axis: usize,
    outward_positive: bool,
}

/// The window portals in an analysis with regions (none without).
pub fn window_portals_in(analysis: &Analysis, scene: &Scene, min_faces: usize) -> Vec<Portal> {
    if !analysis.has_regions || analysis.regions.is_empty() {
        return Vec::new();
    }
    let interior = interior_regions(analysis, scene);
    if !interior.iter().any(|&i| i) {
        return Vec::new();
    }
    let grid = &analysis.grid;
    let labels = &analysis.labels;
    let strides = [1, grid.dims[0], grid.dims[0] * grid.dims[1]];
    let mut faces = Vec::new();
    for portal in &analysis.portals {
        let (a, b) = (portal.regions.0 as usize, portal.regions.1 as usize);
        if interior[a] == interior[b] {
            continue;
        }
        for f in &portal.faces {
            let lower = f.voxel as usize;
            let axis = f.axis as usize;
            let upper = lower + strides[axis];
            let lower_inside = interior[labels[lower] as usize];
            debug_assert!(interior[labels[upper] as usize] != lower_inside);
            faces.push(WindowFace {
                voxel: grid.coords(lower),
                axis,
                outward_positive: lower_inside,
            });
        }
    }
    clusters(&faces)
        .into_iter()
        .filter(|c| c.len() >= min_faces)
        .filter_map(|c| fit(analysis, scene, &c))
        .filter(|p| lets_sky_in(scene, p))
        .collect()
}

/// Whether some ray leaving the portal outward reaches infinity (module docs, "Sky").
fn lets_sky_in(scene: &Scene, portal: &Portal) -> bool {
    (0..SKY_POINTS * SKY_POINTS).any(|k| {
        let (s, t) = (
            ((k % SKY_POINTS) as f32 + 0.5) / SKY_POINTS as f32,
            ((k / SKY_POINTS) as f32 + 0.5) / SKY_POINTS as f32,
        );
        let origin = portal.corner + s * portal.edge_u + t * portal.edge_v;
        // Directions of the full sphere, folded onto the outward side.
        (0..SKY_DIRECTIONS).any(|d| {
            let mut dir = fibonacci_direction(d, SKY_DIRECTIONS);
            let cos = dir.dot(portal.outward);
            if cos < 0.0 {
                dir -= 2.0 * cos * portal.outward;
            }
            scene
                .intersect_hit(&Ray::new(origin, dir, f32::INFINITY))
                .is_none()
        })
    })
}

/// Union-find clusters of faces whose lower voxels are 26-neighbours (or the same voxel).
fn clusters(faces: &[WindowFace]) -> Vec<Vec<WindowFace>> {
    use std::collections::HashMap;
    let mut by_voxel: HashMap<[usize; 3], Vec<usize>> = HashMap::new();
    for (k, f) in faces.iter().enumerate() {
        by_voxel.entry(f.voxel).or_default().push(k);
    }
    let mut parent: Vec<usize> = (0..faces.len()).collect();
    fn find(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for (k, f) in faces.iter().enumerate() {
        for dx in -1i64..=1 {
            for dy in -1i64..=1 {
                for dz in -1i64..=1 {
                    let n = [
                        f.voxel[0] as i64 + dx,
                        f.voxel[1] as i64 + dy,
                        f.voxel[2] as i64 + dz,
                    ];
                    if n.iter().any(|&c| c < 0) {
                        continue;
                    }
                    let key = [n[0] as usize, n[1] as usize, n[2] as usize];
                    if let Some(others) = by_voxel.get(&key) {
                        for &o in others {
                            let (ra, rb) = (find(&mut parent, k), find(&mut parent, o));
                            if ra != rb {
                                parent[ra.max(rb)] = ra.min(rb);
                            }
                        }
                    }
                }
            }
        }
    }
    let mut groups: HashMap<usize, Vec<WindowFace>> = HashMap::new();
    for (k, f) in faces.iter().enumerate() {
        let r = find(&mut parent, k);
        groups.entry(r).or_default().push(*f);
    }
    let mut out: Vec<Vec<WindowFace>> = groups.into_values().collect();
    // Deterministic order: by the first face's voxel.
    out.sort_by_key(|c| c.iter().map(|f| f.voxel).min());
    out
}

/// Fits a rectangle to one cluster of window faces (module docs, "Rectangles").
fn fit(analysis: &Analysis, scene: &Scene, cluster: &[WindowFace]) -> Option<Portal> {
    let grid = &analysis.grid;
    let h = grid.voxel_size;
    let mut normal = [0i64; 3];
    for f in cluster {
        normal[f.axis] += if f.outward_positive { 1 } else { -1 };
    }
    let axis = (0..3).max_by_key(|&k| normal[k].abs())?;
    if normal[axis] == 0 {
        return None;
    }
    let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
    // Extents (world) of the faces across the normal axis, and their mean plane.
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    let (mut plane, mut count) = (0f64, 0usize);
    for f in cluster.iter().filter(|f| f.axis == axis) {
        for k in [ua, va] {
            let min = grid.origin[k] + f.voxel[k] as f64 * h;
            lo[k] = lo[k].min(min);
            hi[k] = hi[k].max(min + h);
        }
        plane += grid.origin[axis] + (f.voxel[axis] + 1) as f64 * h;
        count += 1;
    }
    if count == 0 {
        return None;
    }
    plane /= count as f64;
    let unit = |k: usize| {
        let mut v = Vec3::ZERO;
        v[k] = 1.0;
        v
    };
    let center_of = |offset: f64| {
        let mut c = Vec3::ZERO;
        c[axis] = (plane + offset) as f32;
        c[ua] = (0.5 * (lo[ua] + hi[ua])) as f32;
        c[va] = (0.5 * (lo[va] + hi[va])) as f32;
        c
    };
    // For each of the four edges: (axis, sign, distance from the centre to the voxel edge).
    let edges = [
        (ua, 1.0f32, (0.5 * (hi[ua] - lo[ua])) as f32),
        (ua, -1.0, (0.5 * (hi[ua] - lo[ua])) as f32),
        (va, 1.0, (0.5 * (hi[va] - lo[va])) as f32),
        (va, -1.0, (0.5 * (hi[va] - lo[va])) as f32),
    ];
    let hf = h as f32;
    let mut best: Option<(f32, Vec3, [f32; 4])> = None;
    for step in -3i32..=3 {
        let offset = step as f64 * 0.5 * h;
        let c = center_of(offset);
        let mut reach = [0f32; 4];
        let mut bounded = true;
        for (k, &(a, sign, voxel_edge)) in edges.iter().enumerate() {
            let ray = Ray::new(c, unit(a) * sign, voxel_edge + 2.0 * hf);
            match scene.intersect_hit(&ray) {
                Some(hit) if hit.t >= voxel_edge - 0.25 * hf && hit.t <= voxel_edge + 1.5 * hf => {
                    reach[k] = hit.t;
                }
                _ => bounded = false,
            }
        }
        let area = (reach[0] + reach[1]) * (reach[2] + reach[3]);
        if bounded && best.map_or(true, |(a, _, _)| area < a) {
            best = Some((area, c, reach));
        }
    }
    let (_, c, reach) = best?;
    let corner = c - unit(ua) * reach[1] - unit(va) * reach[3];
    let outward = unit(axis) * normal[axis].signum() as f32;
    Portal::new(
        corner,
        unit(ua) * (reach[0] + reach[1]),
        unit(va) * (reach[2] + reach[3]),
        outward,
    )
    .ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{interior_builder, interior_windows};

    #[test]
    fn the_interior_windows_are_found_within_a_voxel() {
        let scene = interior_builder().unwrap().build().unwrap();
        let found = window_portals(&scene, &WindowPortalSettings::default()).unwrap();
        let h = found.voxel_size;
        let windows = interior_windows();
        assert_eq!(
            found.portals.len(),
            windows.len(),
            "found {:?} (voxel {h})",
            found.portals
        );
        for w in &windows {
            let p = found
                .portals
                .iter()
                .find(|p| (p.center() - w.center).length() < 2.0 * h)
                .unwrap_or_else(|| panic!("no portal near window {w:?}: {:?}", found.portals));
            assert_eq!(p.outward, w.outward, "{p:?}");
            // Position within a voxel; size (per axis, the axes ordered as in the window).
            let d = p.center() - w.center;
            assert!(d.abs().max_element() <= h, "{p:?} vs {w:?} (voxel {h})");
            let extents = p.edge_u.abs() + p.edge_v.abs();
            let mut sizes: Vec<f32> = (0..3)
                .filter(|&k| w.outward[k] == 0.0)
                .map(|k| extents[k])
                .collect();
            sizes.truncate(2);
            for (s, half) in sizes.iter().zip(w.half_extents) {
                assert!(
                    (s - 2.0 * half).abs() <= h,
                    "size {s} vs {} (voxel {h}): {p:?}",
                    2.0 * half
                );
            }
        }
    }

    /// `interior:windows=48`: windows of 0.3 m, about three voxels of the detection grid.
    /// Every portal found is a modelled window (centre within a voxel, one portal per window),
    /// and most windows are found (44 of 48 when this was written; the figure is in
    /// BENCHMARKS.md).
    #[test]
    fn many_small_windows_are_found_where_they_are() {
        let n = 48;
        let scene = crate::scene::interior_many_windows_builder(n)
            .unwrap()
            .build()
            .unwrap();
        let found = window_portals(&scene, &WindowPortalSettings::default()).unwrap();
        let h = found.voxel_size;
        let windows = crate::scene::interior_small_windows(n);
        assert_eq!(windows.len(), n);
        let mut matched = vec![false; n];
        for p in &found.portals {
            let k = windows
                .iter()
                .position(|w| (p.center() - w.center).abs().max_element() <= h)
                .unwrap_or_else(|| panic!("portal {p:?} is no window (voxel {h})"));
            assert!(!matched[k], "two portals on window {:?}", windows[k]);
            assert_eq!(p.outward, windows[k].outward, "{p:?}");
            matched[k] = true;
        }
        let count = matched.iter().filter(|&&m| m).count();
        assert!(count * 10 >= n * 8, "{count} of {n} windows found");
        // Counts out of range and names that are no count are refused.
        for bad in [0, crate::scene::MAX_SMALL_WINDOWS + 1] {
            assert!(crate::scene::interior_many_windows_builder(bad).is_err());
        }
        for name in ["interior:windows=x", "interior:windows=0"] {
            let e = crate::scene::load_scene_file(std::path::Path::new(name));
            assert!(e.is_err(), "{name} accepted");
        }
    }

    #[test]
    fn an_open_scene_has_no_window_portals() {
        let scene = crate::scene::load_scene_file(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scenes/envmaps/sphere-diffuse.json"
        )))
        .unwrap()
        .builder
        .build()
        .unwrap();
        let found = window_portals(&scene, &WindowPortalSettings::default()).unwrap();
        assert!(found.portals.is_empty(), "{:?}", found.portals);
    }
}
