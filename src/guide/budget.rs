//! The skeleton guide's precomputation against a time budget (issue 27).
//!
//! A guide pays for itself only with the time left after its precomputation: one that gains a
//! factor G in efficiency and spends a share s of the budget ends at G (1 - s) of `path`,
//! and a scene that is switched off after the precomputation loses s outright. So where the
//! host gives a budget (`Integrator::set_time_budget`), the whole precomputation must fit in
//! [`BUDGET_SHARE`] of it. Before each stage the rest is estimated ([`PrecomputeEstimate`]):
//! the analysis and skeleton from the voxel count, every stage that traces paths (light
//! tracing, training, pilots) from the measured time of one unguided camera sample of the
//! render's own estimator (a probe of [`PROBE_SAMPLES`] samples, a few milliseconds of thread
//! CPU time), and,
//! once the scout has run, the training's own pace. Where the stages done and the estimate
//! of the rest exceed the share, `path_skeleton` stops and renders `path`'s samples exactly.

use super::settings::{SkeletonGuideSettings, BUDGET_SHARE};
use crate::analysis::{Resolution, VoxelGrid};
use crate::scene::Scene;

/// Camera samples the probe traces to time one sample of the render's estimator: enough to
/// average over pixels (a few ms on the test scenes), few enough to cost nothing against a
/// budget of a second.
pub const PROBE_SAMPLES: u32 = 1024;

/// Seconds per voxel of the analysis and the skeleton together on one thread of the
/// development machine (2 vCPU AMD EPYC KVM, shared): 0.16-0.36 s for the default 1 M voxels
/// on the rooms family, the door and the corridor at load 3 (BENCHMARKS.md, issue 27, "The
/// precomputation against a short budget"). Machine-bound, unlike the stages below, but
/// measured again once done: the next check reads the real elapsed time.
pub const ANALYSIS_SECONDS_PER_VOXEL: f64 = 3.5e-7;

/// One training path's cost in unguided camera samples of the render's estimator: 8-13 on
/// the door, the corridor and rooms:3 (the training traces the lobes as its proposal, with
/// shadow rays and candidate scores at every vertex).
pub const TRAINING_PATH_SAMPLES: f64 = 10.0;

/// One pilot path's cost (both policies, two estimates each, timed per batch) in unguided
/// camera samples: 6-14 on the same scenes.
pub const PILOT_PATH_SAMPLES: f64 = 10.0;

/// The precomputation's estimated seconds, stage group by stage group, from the scene, the
/// settings and the probe's seconds per camera sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrecomputeEstimate {
    /// Voxel analysis and skeleton.
    pub analysis: f64,
    /// Light tracing for the importance nodes.
    pub light_tracing: f64,
    /// The training pass (scout included).
    pub training: f64,
    /// One pilot (guided against unguided samples).
    pub pilot: f64,
    /// Pilots a guided scene runs: the scout's and the final one.
    pub pilots: u32,
}

impl PrecomputeEstimate {
    /// The estimate for `scene` under `settings`, with `sample_seconds` the probe's measured
    /// seconds per camera sample on one thread and `threads` the pool that runs the stages.
    pub fn new(
        scene: &Scene,
        settings: &SkeletonGuideSettings,
        sample_seconds: f64,
        threads: usize,
    ) -> PrecomputeEstimate {
        let voxels = voxel_count(scene, settings.resolution);
        let per_thread = sample_seconds / threads.max(1) as f64;
        let training = if settings.trains() {
            settings.training_paths as f64
                * settings.training_passes.max(1) as f64
                * TRAINING_PATH_SAMPLES
                * per_thread
        } else {
            0.0
        };
        let pilots = if settings.pilot_paths > 0
            && settings.learned_c_skel
            && settings.cost_model.switches()
        {
            1 + settings.scout_pilot as u32
        } else {
            0
        };
        PrecomputeEstimate {
            analysis: voxels as f64 * ANALYSIS_SECONDS_PER_VOXEL,
            light_tracing: settings.light_rays as f64 * per_thread,
            training,
            pilot: settings.pilot_paths as f64 * PILOT_PATH_SAMPLES * per_thread,
            pilots,
        }
    }

    /// Everything, from the start.
    pub fn whole(&self) -> f64 {
        self.analysis + self.after_analysis()
    }

    /// What follows the analysis and skeleton.
    pub fn after_analysis(&self) -> f64 {
        self.light_tracing + self.training + self.pilots as f64 * self.pilot
    }

    /// What follows the training of a guide that guides something: the final pilot.
    pub fn after_training(&self) -> f64 {
        if self.pilots > 0 {
            self.pilot
        } else {
            0.0
        }
    }
}

/// Whether `spent` seconds and an estimated `rest` fit in [`BUDGET_SHARE`] of `budget`.
pub fn fits(budget: f64, spent: f64, rest: f64) -> bool {
    spent + rest <= BUDGET_SHARE * budget
}

/// The voxels the analysis will have at `resolution` (the grid without its padding, which
/// changes the count by a few per cent); 0 where the scene has no bounds.
pub fn voxel_count(scene: &Scene, resolution: Resolution) -> usize {
    VoxelGrid::new(scene.bounds(), resolution, 0).map_or(0, |g| g.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_whole_estimate_is_the_sum_of_its_stages_and_fits_compares_with_the_share() {
        let e = PrecomputeEstimate {
            analysis: 0.3,
            light_tracing: 0.01,
            training: 2.0,
            pilot: 0.5,
            pilots: 2,
        };
        assert!((e.whole() - 3.31).abs() < 1e-12);
        assert!((e.after_analysis() - 3.01).abs() < 1e-12);
        assert_eq!(e.after_training(), 0.5);
        assert!(fits(100.0, 0.0, e.whole()));
        assert!(!fits(3.0, 0.0, e.whole()));
        assert!(fits(4.0 / BUDGET_SHARE, 0.5, 3.5));
        assert!(!fits(4.0 / BUDGET_SHARE, 0.6, 3.5));
    }
}
