//! The filtered skeleton of the empty space with its node map, as the integrators that map
//! surface points to skeleton nodes use it (`bdpt_skeleton`, `vpl:visibility=skeleton`): one
//! build (empty-space analysis, then thinning, filtering and the node map of
//! `analysis::Skeleton`) and one mapping of a surface point to its node (eq. 151-155).

use crate::analysis::{NeighbourMasks, Resolution, Skeleton, StageTime, VoxelGrid};
use crate::error::{Error, Result};
use crate::math::Vec3;
use crate::scene::{Scene, SurfaceInteraction};

/// The filtered skeleton and its node map.
pub(super) struct NodeSkeleton {
    pub grid: VoxelGrid,
    pub node_map: Vec<u32>,
    pub masks: NeighbourMasks,
    /// Position of each filtered node.
    pub positions: Vec<Vec3>,
}

impl NodeSkeleton {
    /// The filtered node of a surface point (eq. 151-155), None where no node maps.
    #[inline]
    pub fn node_of(&self, si: &SurfaceInteraction) -> Option<u32> {
        self.masks
            .map_point(&self.grid, &self.node_map, si.p, si.ng, si.wo)
            .filter(|&n| (n as usize) < self.positions.len())
    }

    /// The empty voxel [`Self::node_of`] takes the node of (its index in `grid`).
    #[inline]
    pub fn voxel_of(&self, si: &SurfaceInteraction) -> Option<usize> {
        self.masks
            .map_point_voxel(&self.grid, &self.node_map, si.p, si.ng, si.wo)
            .filter(|&k| (self.node_map[k] as usize) < self.positions.len())
    }

    /// Builds the analysis and the skeleton of `scene` at `resolution`, pushing their stage
    /// times onto `stages`. `Ok(Err(why))` when there is no skeleton to use (the analysis or
    /// the thinning failed, or it has no node); `Err` only when cancelled.
    pub fn build(
        scene: &Scene,
        resolution: Resolution,
        progress: &dyn Fn(&str, f64) -> bool,
        stages: &mut Vec<StageTime>,
    ) -> Result<std::result::Result<NodeSkeleton, String>> {
        let mut fraction = 0.0;
        let built = Skeleton::of_scene(scene, resolution, &mut |stage, t| {
            stages.push(StageTime {
                stage,
                seconds: t.elapsed().as_secs_f64(),
            });
            fraction += 0.4;
            if progress(stage, fraction) {
                Ok(())
            } else {
                Err(Error::Cancelled)
            }
        });
        let skeleton = match built {
            Ok(s) => s,
            Err(Error::Cancelled) => return Err(Error::Cancelled),
            Err(e) => return Ok(Err(format!("the skeleton could not be built ({e})"))),
        };
        let Skeleton {
            grid,
            filtered,
            node_map,
            ..
        } = skeleton;
        if filtered.graph.nodes.is_empty() {
            return Ok(Err("the skeleton has no node".into()));
        }
        Ok(Ok(NodeSkeleton {
            masks: NeighbourMasks::new(&grid, &node_map),
            grid,
            node_map,
            positions: filtered.graph.nodes.iter().map(|n| n.position).collect(),
        }))
    }
}

/// What a scene was prepared from, to refuse rendering another one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Fingerprint {
    triangles: usize,
    lights: usize,
    bounds: [u32; 6],
}

impl Fingerprint {
    pub fn of(scene: &Scene) -> Self {
        let b = scene.bounds();
        Fingerprint {
            triangles: scene.triangle_count(),
            lights: scene.lights().len(),
            bounds: [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z].map(f32::to_bits),
        }
    }
}
