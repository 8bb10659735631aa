//! Empty-space analysis (L. Noël, *Discrete shape analysis for global illumination*, PhD
//! thesis 2015, chapters 6 and 10: "000" in `docs/references.md`): voxelize the scene, measure its empty space
//! with distance and opening maps, and cut it into regions joined by portals.
//!
//! [`Analysis::build`] runs the pipeline on a committed scene: voxelize (26-separating) →
//! optional interior fill → 26-distance → 26-opening and forest → opening-forest labels →
//! portals. Each stage is timed; memory is estimated before anything is allocated and refused
//! over the caller's budget.

mod pipeline;
mod report;

pub mod distance;
pub mod grid;
pub mod voxelize;

pub use distance::{distance_map, DistanceMap, Metric, Outside};
pub use grid::{Resolution, VoxelGrid, VoxelSet};
pub use voxelize::{fill_interiors, voxelize};
pub mod opening;
pub mod regions;

pub use crate::timing::StageTime;
pub use opening::{opening_map_26, opening_map_l1, OpeningMap};
pub use pipeline::{Analysis, AnalysisSettings, MemoryUse};
pub use regions::{
    find_portals, label_regions, sample_portal, Labeling, Portal, PortalFace, Region, NO_REGION,
};
pub use report::{summary_json, write_analysis};

// Curvilinear skeleton of the empty space (issue 6).
pub mod complex;
pub mod reach;
pub mod skeleton;
mod skeleton_maps;
mod skeleton_report;
pub mod thinning;
#[cfg(test)]
mod thinning_oracle;

pub use complex::{diagonal_contacts, Betti, Complex};
pub use reach::{may_map_to, may_map_to_where};
pub use skeleton::{
    filter_skeleton, graph_from_complex, map_point, node_map, node_map_seeds, Filtered, Graph,
    NeighbourMasks, Node, Skeleton, SkeletonMaps, SkeletonSettings, EUCLIDEAN_BESIDE_THINNING,
    SKELETON_STAGE, UNDEFINED_NODE,
};
pub use skeleton_report::{
    skeleton_obj, skeleton_ply, window_portal_overlay, write_skeleton, write_skeleton_images,
    write_window_portal_image, PORTAL_OUTLINE,
};
pub use thinning::{Constraint, SubStep, Thinning, ThinningStats};
mod window_portals;
pub use window_portals::{scene_env_portals, window_portals, WindowPortalSettings, WindowPortals};
