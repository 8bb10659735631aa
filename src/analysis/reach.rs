//! Where a point may map to a node at all ([`may_map_to`]): a per-voxel mask that lets a
//! guide skip [`map_point`](super::map_point) (eq. 151-155) where no node it cares about is within reach.
//!
//! (Round 4 also kept a per-voxel shortcut cache of `map_point` here, `MapPointCache`; it saved
//! 0.2-0.4 % of a guided sample's instructions on the door, because most surface points'
//! neighbourhoods map to several nodes and the full search ran anyway, at 8 bytes per voxel.
//! Removed in round 5; the mask is what pays: no mapping at all where nothing is guided.)

use rayon::prelude::*;

use super::{VoxelGrid, UNDEFINED_NODE};

/// Voxels from which [`map_point`](super::map_point) may return a node for which `wanted` holds: every voxel
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::map_point;
    use crate::math::{Rng, Vec3};

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
