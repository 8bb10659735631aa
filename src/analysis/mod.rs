//! Empty-space analysis (000 chapters 6 and 10): voxelize the scene, measure its empty space
//! with distance and opening maps, and cut it into regions joined by portals.

pub mod distance;
pub mod grid;
pub mod voxelize;

pub use distance::{distance_map, DistanceMap, Metric, Outside};
pub use grid::{Resolution, VoxelGrid, VoxelSet};
pub use voxelize::{fill_interiors, voxelize};
pub mod opening;
pub mod regions;

pub use opening::{opening_map_26, opening_map_l1, OpeningMap};
pub use regions::{
    find_portals, label_regions, sample_portal, Labeling, Portal, PortalFace, Region, NO_REGION,
};
