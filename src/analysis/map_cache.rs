//! A per-voxel shortcut for [`map_point`] (eq. 151-155) that gives bit-identical answers.
//!
//! `map_point` first searches the 26-neighbourhood of the point's voxel v_x for the mapped
//! voxel best facing the surface normal n⁺, and only when no mapped neighbour lies on n⁺'s
//! side (`score > 0`) moves on along n⁺. When every mapped voxel of that neighbourhood maps
//! to the same node N, the first search returns N as soon as *any* mapped neighbour passes the
//! facing test, whatever the scores and tie-breaks: the answer is N without reading the grid.
//! [`MapPointCache`] stores, per voxel, that common node (or none when the neighbourhood is
//! mixed or unmapped) and a 26-bit mask of its mapped neighbours, so the shortcut only
//! evaluates the facing test on the mask's offsets, with the very expressions `map_point`
//! uses; everything else falls back to `map_point` itself. On the door this answers most
//! queries (the profile of round 3: ~2,400 instructions per `map_point` call, 25 % of a guided
//! sample).

use rayon::prelude::*;

use super::{map_point, VoxelGrid, UNDEFINED_NODE};
use crate::math::Vec3;

/// The 26 neighbour offsets, in the order of the mask's bits.
const OFFSETS: [[i64; 3]; 26] = {
    let mut out = [[0i64; 3]; 26];
    let mut i = 0;
    let mut dz = -1;
    while dz <= 1 {
        let mut dy = -1;
        while dy <= 1 {
            let mut dx = -1;
            while dx <= 1 {
                if dx != 0 || dy != 0 || dz != 0 {
                    out[i] = [dx, dy, dz];
                    i += 1;
                }
                dx += 1;
            }
            dy += 1;
        }
        dz += 1;
    }
    out
};

/// Per-voxel answers of the first neighbourhood search of [`map_point`] (module docs).
pub struct MapPointCache {
    /// The one node all mapped voxels of the 27-neighbourhood map to, else `UNDEFINED_NODE`.
    node: Vec<u32>,
    /// Bit i: neighbour `OFFSETS[i]` is inside the grid and mapped.
    mapped: Vec<u32>,
}

impl MapPointCache {
    /// Builds the cache of a node map (parallel over z slices; the result does not depend on
    /// the thread count).
    pub fn new(grid: &VoxelGrid, map: &[u32]) -> MapPointCache {
        let [nx, ny, nz] = grid.dims;
        let slice = nx * ny;
        let mut node = vec![UNDEFINED_NODE; map.len()];
        let mut mapped = vec![0u32; map.len()];
        node.par_chunks_mut(slice.max(1))
            .zip(mapped.par_chunks_mut(slice.max(1)))
            .enumerate()
            .for_each(|(z, (node, mapped))| {
                for y in 0..ny {
                    for x in 0..nx {
                        let (common, mask) = neighbourhood(grid, map, [x, y, z]);
                        node[x + nx * y] = common;
                        mapped[x + nx * y] = mask;
                    }
                }
            });
        debug_assert_eq!(nz * slice, map.len());
        MapPointCache { node, mapped }
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> usize {
        (self.node.len() + self.mapped.len()) * 4
    }

    /// Fraction of voxels whose neighbourhood maps to one node (for reports and tests).
    pub fn uniform_fraction(&self) -> f64 {
        let n = self.node.iter().filter(|&&n| n != UNDEFINED_NODE).count();
        n as f64 / self.node.len().max(1) as f64
    }

    /// Exactly `map_point(grid, map, p, normal, incident)` (the grid and map this cache was
    /// built from), answered from the cache where the module docs allow.
    pub fn map_point(
        &self,
        grid: &VoxelGrid,
        map: &[u32],
        p: Vec3,
        normal: Vec3,
        incident: Vec3,
    ) -> Option<u32> {
        if let Some(node) = self.shortcut(grid, p, normal, incident) {
            return Some(node);
        }
        map_point(grid, map, p, normal, incident)
    }

    /// The cached answer, or None when `map_point` must decide. Mirrors `map_point`'s first
    /// steps expression by expression (same n, same voxel, same score), so the facing test
    /// passes here exactly when it passes there.
    #[inline]
    fn shortcut(&self, grid: &VoxelGrid, p: Vec3, normal: Vec3, incident: Vec3) -> Option<u32> {
        let g = grid.to_grid(p);
        let vx = g.map(|x| x.floor() as i64);
        if (0..3).any(|a| vx[a] < 0 || vx[a] >= grid.dims[a] as i64) {
            return None;
        }
        let k = grid.index(vx[0] as usize, vx[1] as usize, vx[2] as usize);
        let common = self.node[k];
        if common == UNDEFINED_NODE {
            return None;
        }
        let n = if normal.dot(incident) >= 0.0 {
            normal
        } else {
            -normal
        };
        let n = n.normalize_or_zero();
        let mut mask = self.mapped[k];
        while mask != 0 {
            let i = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            let [dx, dy, dz] = OFFSETS[i];
            let off = Vec3::new(dx as f32, dy as f32, dz as f32);
            let len = off.length();
            // `map_point` skips a neighbour when `score <= 0.0` (NaN scores pass there too).
            let score = off.dot(n) / len;
            if !(score <= 0.0) {
                return Some(common);
            }
        }
        None
    }
}

/// The common node and the mapped-neighbour mask of voxel `v`.
fn neighbourhood(grid: &VoxelGrid, map: &[u32], v: [usize; 3]) -> (u32, u32) {
    let centre = map[grid.index(v[0], v[1], v[2])];
    let mut common = centre;
    let mut mask = 0u32;
    for (i, o) in OFFSETS.iter().enumerate() {
        let w = [0, 1, 2].map(|a| v[a] as i64 + o[a]);
        if (0..3).any(|a| w[a] < 0 || w[a] >= grid.dims[a] as i64) {
            continue;
        }
        let m = map[grid.index(w[0] as usize, w[1] as usize, w[2] as usize)];
        if m == UNDEFINED_NODE {
            continue;
        }
        mask |= 1 << i;
        if common == UNDEFINED_NODE {
            common = m;
        } else if common != m {
            return (UNDEFINED_NODE, 0);
        }
    }
    if mask == 0 {
        // Only the centre could be mapped, and its score is 0: never a facing hit.
        return (UNDEFINED_NODE, 0);
    }
    (common, mask)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    /// A small grid with nodes in blocks, solid voxels and mixed neighbourhoods; the cache
    /// must answer exactly as `map_point` on random points, normals and incident directions,
    /// including degenerate ones (zero and non-finite normals, points outside the grid).
    #[test]
    fn cache_answers_exactly_as_map_point() {
        let grid = VoxelGrid {
            dims: [9, 7, 6],
            origin: [-1.0, 0.5, 2.0],
            voxel_size: 0.25,
        };
        let mut rng = Rng::new(7, 1);
        let map: Vec<u32> = (0..9 * 7 * 6)
            .map(|k| {
                let [x, y, _] = grid.coords(k);
                let r = rng.uniform();
                if r < 0.3 {
                    UNDEFINED_NODE
                } else if x < 5 && y < 4 {
                    0
                } else {
                    1 + (r < 0.35) as u32
                }
            })
            .collect();
        let cache = MapPointCache::new(&grid, &map);
        assert!(cache.uniform_fraction() > 0.05 && cache.uniform_fraction() < 0.95);
        let lo = Vec3::new(-1.2, 0.3, 1.8);
        let hi = Vec3::new(1.5, 2.5, 3.7);
        let mut shortcuts = 0;
        for i in 0..200_000 {
            let u = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform());
            let p = lo + (hi - lo) * u;
            let mut normal = crate::math::warp::uniform_sphere(rng.uniform2());
            match i % 97 {
                0 => normal = Vec3::ZERO,
                1 => normal = Vec3::new(f32::NAN, 0.0, 1.0),
                2 => normal = Vec3::X,
                3 => normal = -Vec3::Z,
                _ => {}
            }
            let incident = crate::math::warp::uniform_sphere(rng.uniform2());
            let want = map_point(&grid, &map, p, normal, incident);
            let got = cache.map_point(&grid, &map, p, normal, incident);
            assert_eq!(got, want, "p {p} n {normal} w {incident}");
            shortcuts += cache.shortcut(&grid, p, normal, incident).is_some() as u32;
        }
        assert!(shortcuts > 10_000, "the shortcut answered only {shortcuts}");
    }
}
