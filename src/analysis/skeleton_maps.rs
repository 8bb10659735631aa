//! The voxel maps the curvilinear skeleton is computed from, kept apart from
//! [`skeleton`](super::skeleton) so that the analysis pipeline can compute them without
//! depending on the skeleton (which itself reads a finished [`Analysis`](super::Analysis)).

use super::distance::{distance_map, Metric, Outside};
use super::grid::VoxelSet;
use super::opening::opening_and_decenterness_l1;

/// Where the skeleton's schedule ([`Skeleton#schedule`](super::Skeleton#schedule)) computes the squared Euclidean
/// distance: beside the thinning (true), or beside the L1 opening in [`SkeletonMaps::from_l1`]
/// (false). The one switch of the schedule; the analysis pipeline
/// and [`Skeleton::from_maps`](super::Skeleton::from_maps) follow it.
pub const EUCLIDEAN_BESIDE_THINNING: bool = true;

/// The voxel maps the skeleton needs (000 §6.2.2), all measured with the same `Outside`: the
/// L1 distance D1 and opening Ω1 (the collapse's clock and the constraint of Algorithm 3), the
/// decenterness Ω1 − D1, and the squared Euclidean distance (maximal-ball radii, piercing
/// priority) unless the schedule computes that beside the thinning
/// ([`EUCLIDEAN_BESIDE_THINNING`]): the piercing is the first stage that reads it.
pub struct SkeletonMaps {
    pub distance_l1: Vec<u32>,
    pub opening_l1: Vec<u32>,
    pub decenterness_l1: Vec<u32>,
    /// `None` when [`Skeleton::from_maps`](super::Skeleton::from_maps) computes it beside the thinning.
    pub sq_euclidean: Option<Vec<u32>>,
}

impl SkeletonMaps {
    /// The maps of the empty space of `occupied` (see [`SkeletonMaps::from_l1`]).
    pub fn new(dims: [usize; 3], occupied: &VoxelSet, outside: Outside) -> SkeletonMaps {
        let d1 = distance_map(dims, occupied, Metric::L1, outside, false).values;
        Self::from_l1(dims, occupied, outside, d1)
    }

    /// The maps from an L1 distance map: the L1 opening and decenterness (the flood split over
    /// the rayon pool, see [`super::opening`]), and, unless the schedule computes it beside the
    /// thinning, the squared Euclidean distance alongside them (`rayon::join`).
    pub fn from_l1(
        dims: [usize; 3],
        occupied: &VoxelSet,
        outside: Outside,
        distance_l1: Vec<u32>,
    ) -> SkeletonMaps {
        let opening = || opening_and_decenterness_l1(dims, &distance_l1);
        let ((opening_l1, decenterness_l1), sq_euclidean) = if EUCLIDEAN_BESIDE_THINNING {
            (opening(), None)
        } else {
            let (o, sq) = rayon::join(opening, || {
                distance_map(dims, occupied, Metric::SquaredEuclidean, outside, false).values
            });
            (o, Some(sq))
        };
        SkeletonMaps {
            distance_l1,
            opening_l1,
            decenterness_l1,
            sq_euclidean,
        }
    }
}
