//! An exact shortcut for mapping surface points to skeleton nodes.
//!
//! `analysis::map_point` (eq. 151-155) searches the 26-neighbourhood of the voxel v_x holding
//! the point, then up to three voxels further along the normal, then falls back to any mapped
//! neighbour: every voxel it can pick lies within Chebyshev distance 4 of v_x (a step centre is
//! at most 3 voxels from v_x per axis, plus the neighbourhood's 1). So when every mapped voxel
//! within distance 4 of v_x maps to the same node X, and one lies within distance 1 (so the
//! fallback finds one whatever the steps do), the answer is X for every normal and incident
//! direction. Most surface points are of that kind (inside one node's region of the node map);
//! for them a table lookup replaces the search, which measured a third of `path_skeleton`'s
//! instructions per sample on the corridor. Elsewhere the full search runs.

use rayon::prelude::*;

use crate::analysis::{map_point, VoxelGrid, UNDEFINED_NODE};
use crate::math::Vec3;

/// Chebyshev reach of `map_point`'s search around v_x.
const REACH: usize = 4;

/// The node of each voxel when `map_point` cannot answer anything else there, or
/// `UNDEFINED_NODE` where the full search is needed.
pub(crate) struct FastNodeMap {
    pub(super) uniform: Vec<u32>,
}

impl FastNodeMap {
    pub fn new(grid: &VoxelGrid, node_map: &[u32]) -> Self {
        let dims = grid.dims;
        // Smallest and (one plus) largest node over the mapped voxels of each window.
        let lo_in: Vec<u32> = node_map.to_vec();
        let hi_in: Vec<u32> = node_map
            .iter()
            .map(|&n| if n == UNDEFINED_NODE { 0 } else { n + 1 })
            .collect();
        let mut lo = lo_in;
        let mut hi = hi_in;
        for axis in 0..3 {
            lo = window(dims, &lo, axis, REACH, u32::MAX, u32::min);
            hi = window(dims, &hi, axis, REACH, 0, u32::max);
        }
        let (sx, sy) = (dims[0], dims[0] * dims[1]);
        let uniform = (0..node_map.len())
            .into_par_iter()
            .map(|i| {
                if lo[i] == u32::MAX || lo[i].wrapping_add(1) != hi[i] {
                    return UNDEFINED_NODE;
                }
                let (x, y, z) = (i % sx, (i / sx) % dims[1], i / sy);
                let near = |c: usize, n: usize| c.saturating_sub(1)..=(c + 1).min(n - 1);
                for zz in near(z, dims[2]) {
                    for yy in near(y, dims[1]) {
                        for xx in near(x, dims[0]) {
                            if node_map[xx + sx * yy + sy * zz] != UNDEFINED_NODE {
                                return lo[i];
                            }
                        }
                    }
                }
                UNDEFINED_NODE
            })
            .collect();
        FastNodeMap { uniform }
    }

    /// Exactly `map_point(grid, node_map, p, normal, incident)`.
    #[inline]
    pub fn map_point(
        &self,
        grid: &VoxelGrid,
        node_map: &[u32],
        p: Vec3,
        normal: Vec3,
        incident: Vec3,
    ) -> Option<u32> {
        if let Some(v) = grid.voxel_at(p) {
            let node = self.uniform[v];
            if node != UNDEFINED_NODE {
                return Some(node);
            }
        }
        map_point(grid, node_map, p, normal, incident)
    }

    pub fn memory_bytes(&self) -> usize {
        self.uniform.len() * 4
    }
}

/// `out[i] = combine` of `input` over the voxels within `radius` of i along `axis` (clipped to
/// the grid), `identity` for an empty window. Parallel over z slices.
fn window(
    dims: [usize; 3],
    input: &[u32],
    axis: usize,
    radius: usize,
    identity: u32,
    combine: fn(u32, u32) -> u32,
) -> Vec<u32> {
    let (sx, sy) = (dims[0], dims[0] * dims[1]);
    let stride = [1, sx, sy][axis];
    let mut out = vec![identity; input.len()];
    out.par_chunks_mut(sy).enumerate().for_each(|(z, slice)| {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let c = [x, y, z][axis];
                let lo = c.saturating_sub(radius);
                let hi = (c + radius).min(dims[axis] - 1);
                let base = x + sx * y + sy * z - c * stride;
                let mut acc = identity;
                for k in lo..=hi {
                    acc = combine(acc, input[base + k * stride]);
                }
                slice[x + sx * y] = acc;
            }
        }
    });
    out
}
