//! The analysis pipeline over a scene, with timings, a memory budget and point queries.

use std::time::Instant;

use super::distance::{distance_map, Metric, Outside};
use super::grid::{Resolution, VoxelGrid, VoxelSet};
use super::opening::{opening_map_26, OpeningMap};
use super::regions::{
    find_portals, label_regions, sample_portal, Labeling, Portal, Region, NO_REGION,
};
use super::skeleton_maps::{SkeletonMaps, EUCLIDEAN_BESIDE_THINNING};
use super::voxelize::{fill_interiors, voxelize};
use crate::error::{Error, Result};
use crate::math::{Vec2, Vec3};
use crate::scene::Scene;
use crate::timing::StageTime;

/// Parameters of an analysis.
#[derive(Clone, Debug, PartialEq)]
pub struct AnalysisSettings {
    pub resolution: Resolution,
    /// Layers of voxels around the scene bounds. Two, because a surface lying exactly on the
    /// bounds also marks the first layer (voxelization is conservative on both sides of a voxel
    /// boundary); the second keeps the outside one connected empty shell.
    pub padding: u32,
    /// Mark the inside of closed objects as occupied.
    pub fill_interiors: bool,
    /// What the distance maps see beyond the grid.
    pub outside: Outside,
    /// Refuse grids whose structures would need more bytes than this.
    pub memory_budget: u64,
    /// Also compute the L1 and squared Euclidean distance maps, the L1 opening and the
    /// decenterness map (the skeleton needs them; the labeling does not).
    pub all_maps: bool,
    /// With `all_maps`, compute the squared Euclidean distance here too. A caller that builds
    /// the skeleton from the analysis turns this off: the skeleton then computes it beside its
    /// thinning (the schedule of [`super::skeleton::Skeleton`]), and the analysis holds only
    /// the L1 maps (unless the schedule computes the distance beside the L1 opening).
    pub euclidean: bool,
    /// Compute the 26-distance, the 26-opening and its forest, the region labels and the
    /// portals. The skeleton uses none of them, so a caller that only wants the skeleton
    /// (the skeleton guide) turns this off and keeps `all_maps`: the analysis then holds the
    /// occupancy and the skeleton's maps, and its region queries answer "none".
    pub regions: bool,
}

impl Default for AnalysisSettings {
    fn default() -> Self {
        AnalysisSettings {
            resolution: Resolution::LongestAxis(128),
            padding: 2,
            fill_interiors: false,
            outside: Outside::Solid,
            memory_budget: 4 << 30,
            all_maps: false,
            euclidean: true,
            regions: true,
        }
    }
}

/// Bytes held by each structure.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MemoryUse {
    pub occupancy: usize,
    pub distance: usize,
    pub opening: usize,
    pub labels: usize,
    pub portals: usize,
    pub extra_maps: usize,
}

impl MemoryUse {
    pub fn total(&self) -> usize {
        self.occupancy + self.distance + self.opening + self.labels + self.portals + self.extra_maps
    }
}

/// The analysed empty space of a scene. Immutable after `build`; queries are thread-safe.
pub struct Analysis {
    pub grid: VoxelGrid,
    pub occupied: VoxelSet,
    /// 26-distance to the occupied voxels (0 on them). This, `opening`, `labels`, `regions`
    /// and `portals` are empty when the settings turned `regions` off (`has_regions`).
    pub distance26: Vec<u32>,
    pub opening: OpeningMap,
    /// Opening-forest label of each voxel (`NO_REGION` on occupied voxels).
    pub labels: Vec<u32>,
    pub regions: Vec<Region>,
    pub portals: Vec<Portal>,
    /// With `all_maps`: L1 distance, squared Euclidean distance (only with `euclidean`), L1
    /// opening, decenterness.
    pub distance_l1: Option<Vec<u32>>,
    pub distance_sq_euclidean: Option<Vec<u32>>,
    pub opening_l1: Option<Vec<u32>>,
    pub decenterness_l1: Option<Vec<u32>>,
    pub timings: Vec<StageTime>,
    pub interior_voxels_filled: usize,
    /// Whether `distance26`, `opening`, `labels`, `regions` and `portals` were computed.
    pub has_regions: bool,
}

/// Peak bytes per voxel of the pipeline (occupancy bits, maps, and the separable passes'
/// line buffers and outputs), used to refuse a resolution before allocating: with the
/// regions, with the regions and the skeleton maps, with the skeleton maps only (four u32
/// maps and the flood's and passes' scratch), and with neither (the occupancy bits).
const BYTES_PER_VOXEL: u64 = 48;
const BYTES_PER_VOXEL_ALL_MAPS: u64 = 64;
const BYTES_PER_VOXEL_SKELETON_MAPS: u64 = 32;
const BYTES_PER_VOXEL_OCCUPANCY: u64 = 1;

impl Analysis {
    /// Predicted peak memory of analysing a grid.
    pub fn estimate_bytes(grid: &VoxelGrid, settings: &AnalysisSettings) -> u64 {
        grid.len() as u64
            * match (settings.regions, settings.all_maps) {
                (true, true) => BYTES_PER_VOXEL_ALL_MAPS,
                (true, false) => BYTES_PER_VOXEL,
                (false, true) => BYTES_PER_VOXEL_SKELETON_MAPS,
                (false, false) => BYTES_PER_VOXEL_OCCUPANCY,
            }
    }

    /// Runs the pipeline. `progress(stage, fraction)` is called between stages and may cancel
    /// by returning false.
    pub fn build(
        scene: &Scene,
        settings: &AnalysisSettings,
        progress: &dyn Fn(&str, f64) -> bool,
    ) -> Result<Analysis> {
        let grid = VoxelGrid::new(scene.bounds(), settings.resolution, settings.padding)?;
        let bytes = Self::estimate_bytes(&grid, settings);
        if bytes > settings.memory_budget {
            return Err(Error::OverBudget {
                what: format!(
                    "analysis grid {}x{}x{}",
                    grid.dims[0], grid.dims[1], grid.dims[2]
                ),
                bytes,
                budget: settings.memory_budget,
            });
        }
        let triangles: Vec<[Vec3; 3]> = (0..scene.triangle_count() as u32)
            .map(|t| scene.triangle_vertices(t))
            .collect();
        Self::build_from_triangles(grid, &triangles, settings, progress)
    }

    /// The pipeline on triangles over a given grid.
    pub fn build_from_triangles(
        grid: VoxelGrid,
        triangles: &[[Vec3; 3]],
        settings: &AnalysisSettings,
        progress: &dyn Fn(&str, f64) -> bool,
    ) -> Result<Analysis> {
        let mut timings = Vec::new();
        // Stages actually run, so that the progress reaches 1.
        let stages = 1.0
            + if settings.fill_interiors { 1.0 } else { 0.0 }
            + if settings.regions { 4.0 } else { 0.0 }
            + if settings.all_maps { 2.0 } else { 0.0 }
            + if settings.all_maps && settings.euclidean && EUCLIDEAN_BESIDE_THINNING {
                1.0
            } else {
                0.0
            };
        let mut done = 0.0;
        let mut stage =
            |name: &'static str, timings: &mut Vec<StageTime>, start: Instant| -> Result<()> {
                timings.push(StageTime {
                    stage: name,
                    seconds: start.elapsed().as_secs_f64(),
                });
                done += 1.0;
                if progress(name, done / stages) {
                    Ok(())
                } else {
                    Err(Error::Cancelled)
                }
            };
        let dims = grid.dims;

        let t = Instant::now();
        let mut occupied = voxelize(&grid, triangles);
        stage("voxelize", &mut timings, t)?;
        let t = Instant::now();
        let interior_voxels_filled = if settings.fill_interiors {
            fill_interiors(&grid, &mut occupied)
        } else {
            0
        };
        if settings.fill_interiors {
            stage("fill interiors", &mut timings, t)?;
        }

        let (mut distance26, mut opening, mut labeling, mut portals) = (
            Vec::new(),
            OpeningMap {
                opening: Vec::new(),
                center: Vec::new(),
            },
            Labeling {
                labels: Vec::new(),
                regions: Vec::new(),
            },
            Vec::new(),
        );
        if settings.regions {
            let t = Instant::now();
            distance26 =
                distance_map(dims, &occupied, Metric::Chessboard, settings.outside, false).values;
            stage("distance 26", &mut timings, t)?;

            let t = Instant::now();
            opening = opening_map_26(dims, &distance26);
            stage("opening 26 + forest", &mut timings, t)?;

            let t = Instant::now();
            labeling = label_regions(&grid, &opening);
            stage("labels", &mut timings, t)?;

            let t = Instant::now();
            portals = find_portals(&grid, &labeling.labels);
            stage("portals", &mut timings, t)?;
        }

        let (mut distance_l1, mut distance_sq_euclidean, mut opening_l1, mut decenterness_l1) =
            (None, None, None, None);
        if settings.all_maps {
            let t = Instant::now();
            let d1 = distance_map(dims, &occupied, Metric::L1, settings.outside, false).values;
            stage("distance L1", &mut timings, t)?;
            let t = Instant::now();
            let maps = SkeletonMaps::from_l1(dims, &occupied, settings.outside, d1);
            if maps.sq_euclidean.is_some() {
                stage(
                    "opening L1 + decenterness || distance Euclidean",
                    &mut timings,
                    t,
                )?;
            } else {
                stage("opening L1 + decenterness", &mut timings, t)?;
            }
            distance_l1 = Some(maps.distance_l1);
            opening_l1 = Some(maps.opening_l1);
            decenterness_l1 = Some(maps.decenterness_l1);
            distance_sq_euclidean = maps.sq_euclidean;
            if settings.euclidean && distance_sq_euclidean.is_none() {
                let t = Instant::now();
                distance_sq_euclidean = Some(
                    distance_map(
                        dims,
                        &occupied,
                        Metric::SquaredEuclidean,
                        settings.outside,
                        false,
                    )
                    .values,
                );
                stage("distance Euclidean", &mut timings, t)?;
            }
        }
        Ok(Analysis {
            grid,
            occupied,
            distance26,
            opening,
            labels: labeling.labels,
            regions: labeling.regions,
            portals,
            distance_l1,
            distance_sq_euclidean,
            opening_l1,
            decenterness_l1,
            timings,
            interior_voxels_filled,
            has_regions: settings.regions,
        })
    }

    pub fn empty_voxels(&self) -> usize {
        self.grid.len() - self.occupied.count()
    }

    pub fn total_seconds(&self) -> f64 {
        self.timings.iter().map(|t| t.seconds).sum()
    }

    pub fn memory(&self) -> MemoryUse {
        let maps = |m: &Option<Vec<u32>>| m.as_ref().map_or(0, |v| v.len() * 4);
        MemoryUse {
            occupancy: self.occupied.memory_bytes(),
            distance: self.distance26.len() * 4,
            opening: self.opening.memory_bytes(),
            labels: self.labels.len() * 4,
            portals: self
                .portals
                .iter()
                .map(|p| p.faces.len() * 8 + std::mem::size_of::<Portal>())
                .sum(),
            extra_maps: maps(&self.distance_l1)
                + maps(&self.distance_sq_euclidean)
                + maps(&self.opening_l1)
                + maps(&self.decenterness_l1),
        }
    }

    /// 26-opening (in voxels) at a world point; `None` outside the grid or without the
    /// regions, 0 in occupied voxels.
    pub fn opening_at(&self, p: Vec3) -> Option<u32> {
        self.grid
            .voxel_at(p)
            .and_then(|i| self.opening.opening.get(i).copied())
    }

    /// Region label at a world point; `None` outside the grid, in occupied voxels or without
    /// the regions.
    pub fn label_at(&self, p: Vec3) -> Option<u32> {
        self.grid
            .voxel_at(p)
            .and_then(|i| self.labels.get(i).copied())
            .filter(|&l| l != NO_REGION)
    }

    /// Samples a point uniformly on portal `index`: (point, normal from its first region to
    /// its second, area density).
    pub fn sample_portal(&self, index: usize, u: f32, v: Vec2) -> Result<(Vec3, Vec3, f32)> {
        let portal = self.portals.get(index).ok_or_else(|| {
            Error::invalid(format!(
                "portal index {index} out of range ({} portals)",
                self.portals.len()
            ))
        })?;
        Ok(sample_portal(&self.grid, &self.labels, portal, u, v))
    }
}
