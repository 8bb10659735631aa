//! A per-voxel shortcut for [`map_point`] (eq. 151-155) that gives bit-identical answers.
//!
//! `map_point` searches the 27-neighbourhood of the point's voxel v_x for the mapped voxel
//! best facing the surface normal n⁺; when no mapped voxel there lies on n⁺'s side
//! (`score > 0`) it searches the neighbourhoods of voxels up to three steps along n⁺, and at
//! last takes any mapped neighbour of v_x. When every mapped voxel of a searched neighbourhood
//! maps to the same node N, its search returns N as soon as *any* of them passes the facing
//! test, whatever the scores and tie-breaks. [`MapPointCache`] stores per voxel that common
//! node (or none when the neighbourhood maps to several) and a 26-bit mask of its mapped
//! neighbours, so the shortcut evaluates only the facing tests, with the very expressions
//! `map_point` uses, and reads no grid values beyond the centre voxel's; a search that would
//! return from a neighbourhood with several nodes, or a centre outside the grid, falls back to
//! `map_point` itself. Round 3's profile of the door: ~2,400 instructions per `map_point` call,
//! 1.57 neighbourhood searches per call, 25 % of a guided sample.

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
        match self.shortcut(grid, map, p, normal, incident) {
            Some(answer) => answer,
            None => map_point(grid, map, p, normal, incident),
        }
    }

    /// The cached answer (`Some(node or None)`), or None when `map_point` must decide. Follows `map_point`'s steps
    /// expression by expression (same n, same voxels, same scores), so each facing test passes
    /// here exactly when it passes there: a search that finds no facing mapped voxel fails
    /// there too and the next step is taken; one that finds some returns its neighbourhood's
    /// common node, when it has one.
    #[inline]
    fn shortcut(
        &self,
        grid: &VoxelGrid,
        map: &[u32],
        p: Vec3,
        normal: Vec3,
        incident: Vec3,
    ) -> Option<Option<u32>> {
        let n = if normal.dot(incident) >= 0.0 {
            normal
        } else {
            -normal
        };
        let n = n.normalize_or_zero();
        let g = grid.to_grid(p);
        let vx = g.map(|x| x.floor() as i64);
        let inside = |v: [i64; 3]| (0..3).all(|a| v[a] >= 0 && v[a] < grid.dims[a] as i64);
        if !inside(vx) {
            return None;
        }
        let index = |v: [i64; 3]| grid.index(v[0] as usize, v[1] as usize, v[2] as usize);
        // `map_point`'s facing test of voxel v: it skips v when `score <= 0.0` (so NaN scores
        // pass), with score 0 for v = v_x.
        let facing = |v: [i64; 3]| {
            let off = Vec3::new(
                (v[0] - vx[0]) as f32,
                (v[1] - vx[1]) as f32,
                (v[2] - vx[2]) as f32,
            );
            let len = off.length();
            let score = if len > 0.0 { off.dot(n) / len } else { 0.0 };
            !(score <= 0.0)
        };
        for step in 0..=3i64 {
            let centre = if step == 0 {
                vx
            } else {
                [0, 1, 2].map(|a| (g[a] + step as f64 * n[a] as f64).floor() as i64)
            };
            if !inside(centre) {
                return None;
            }
            let k = index(centre);
            let common = self.node[k];
            if common == UNDEFINED_NODE && (self.mapped[k] != 0 || map[k] != UNDEFINED_NODE) {
                // Several nodes here: this search may decide between them.
                return None;
            }
            let mut found = map[k] != UNDEFINED_NODE && facing(centre);
            let mut mask = self.mapped[k];
            while !found && mask != 0 {
                let i = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                let o = OFFSETS[i];
                found = facing([centre[0] + o[0], centre[1] + o[1], centre[2] + o[2]]);
            }
            if found {
                return Some(Some(common));
            }
        }
        // The last resort: any mapped voxel of v_x's neighbourhood (none: no node).
        let k = index(vx);
        match self.node[k] {
            UNDEFINED_NODE if self.mapped[k] == 0 && map[k] == UNDEFINED_NODE => Some(None),
            UNDEFINED_NODE => None,
            common => Some(Some(common)),
        }
    }
}

/// Voxels from which [`map_point`] may return a node for which `wanted` holds: every voxel
/// within 4 voxels (per axis) of a mapped voxel whose node is wanted. `map_point` from a point
/// in voxel v_x only reads the neighbourhoods of v_x and of floor(g + s n⁺) for s <= 3, and
/// floor(x + d) - floor(x) lies in [-3, 3] for |d| <= 3: all within 3 + 1 voxels of v_x. So
/// where this is false, the point maps to no wanted node (or to none), without searching.
/// (A box dilation, separable, one pass per axis.)
pub fn may_map_to(grid: &VoxelGrid, map: &[u32], wanted: impl Fn(u32) -> bool + Sync) -> Vec<bool> {
    const REACH: usize = 4;
    let dims = grid.dims;
    let mut flags: Vec<bool> = map
        .par_iter()
        .map(|&m| m != UNDEFINED_NODE && wanted(m))
        .collect();
    for axis in 0..3 {
        let stride = [1, dims[0], dims[0] * dims[1]][axis];
        let len = dims[axis];
        let input = flags.clone();
        flags.par_iter_mut().enumerate().for_each(|(k, out)| {
            if *out {
                return;
            }
            let c = grid.coords(k)[axis];
            let lo = c.saturating_sub(REACH);
            let hi = (c + REACH).min(len - 1);
            let base = k - c * stride;
            *out = (lo..=hi).any(|i| input[base + i * stride]);
        });
    }
    flags
}

/// The common node of voxel `v`'s 27-neighbourhood (`UNDEFINED_NODE` when none of it is
/// mapped or it maps to several nodes) and the mask of its mapped neighbours (always).
fn neighbourhood(grid: &VoxelGrid, map: &[u32], v: [usize; 3]) -> (u32, u32) {
    let mut common = map[grid.index(v[0], v[1], v[2])];
    let mut mixed = false;
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
            mixed = true;
        }
    }
    (if mixed { UNDEFINED_NODE } else { common }, mask)
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
            shortcuts += cache.shortcut(&grid, &map, p, normal, incident).is_some() as u32;
        }
        assert!(shortcuts > 10_000, "the shortcut answered only {shortcuts}");
    }

    /// Wherever `map_point` reaches node 2, `may_map_to` says it may; far from it, it may not.
    #[test]
    fn may_map_to_covers_every_point_that_reaches_a_node() {
        let grid = VoxelGrid {
            dims: [30, 20, 12],
            origin: [0.0, 0.0, 0.0],
            voxel_size: 0.5,
        };
        let mut rng = Rng::new(3, 9);
        let map: Vec<u32> = (0..30 * 20 * 12)
            .map(|k| {
                let [x, y, z] = grid.coords(k);
                if rng.uniform() < 0.3 {
                    UNDEFINED_NODE
                } else if (4..8).contains(&x) && (5..9).contains(&y) && z < 6 {
                    2
                } else {
                    (x / 10) as u32 * 3 + 1
                }
            })
            .collect();
        let reach = may_map_to(&grid, &map, |n| n == 2);
        assert!(reach.iter().any(|&r| !r) && reach.iter().any(|&r| r));
        let lo = Vec3::splat(-0.5);
        let hi = Vec3::new(15.5, 10.5, 6.5);
        let mut hits = 0;
        for _ in 0..200_000 {
            let u = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform());
            let p = lo + (hi - lo) * u;
            let normal = crate::math::warp::uniform_sphere(rng.uniform2());
            let incident = crate::math::warp::uniform_sphere(rng.uniform2());
            if map_point(&grid, &map, p, normal, incident) == Some(2) {
                let v = grid.to_grid(p).map(|x| x.floor() as i64);
                if (0..3).all(|a| v[a] >= 0 && v[a] < grid.dims[a] as i64) {
                    assert!(reach[grid.index(v[0] as usize, v[1] as usize, v[2] as usize)]);
                    hits += 1;
                }
            }
        }
        assert!(hits > 100, "{hits}");
    }
}
