//! `c_skel=learned` and `strength=learned`: the probability c of sampling the skeleton lobes
//! and the lobes' strength s (eq. 163), chosen per node from a training pass before rendering.
//!
//! # Training pass
//!
//! `training_paths` camera paths, each at most `training_depth` vertices deep, sample every
//! guided vertex x from q_0 = c0 p_skel,s0 + (1 - c0) p_bsdf (c0 = [`TRAINING_C`], s0 the
//! settings' strength), as `path_skeleton` does, and record for its node the contribution
//! f = lum(beta f_s |cos| L(wi)), L = L_e(x') + R(x'), R the light the rest of the path reflects
//! toward x by next-event estimation (corridor light arrives after several bounces), with every
//! density a candidate needs and the vertex's own light sample. Fixed chunks with their own
//! random streams make the result independent of the thread count.
//!
//! # Estimator
//!
//! F = f / q_c,s has second moment E_{q_0}[f² / (q_c,s q_0)], so every candidate (c, s) is
//! judged from the same samples by importance reweighting ([`reweighted_second_moment`]),
//! exactly where q_0 > 0 wherever f > 0 (the coverage condition, which the BSDF share of q_0
//! guarantees for every non-delta BSDF).
//!
//! # What is measured
//!
//! The render MIS-weights its direction sample against a light sample, so a candidate is
//! judged by that estimate, w_l n + (w_e e + r) / q_c,s, with the render's heuristic and light
//! sampling (`SkeletonGuideSettings::render_estimator`): f / q alone would credit guiding
//! toward lamps that next-event estimation already finds ([`Sample::terms`]). The light
//! samples and the light densities of emitters hit are the render's own
//! (`guide::estimator`, which `integrator::path` renders with).
//!
//! # Cost
//!
//! Efficiency is 1 / (variance x cost), cost in unguided vertices: guiding adds
//! `training_guided_cost` and `COST_SHADOW_RAY` per guide shadow ray, against the vertices of
//! the estimate from x on (`training_cost=path`) or one vertex (`vertex`).
//!
//! # Choice
//!
//! A node gets the candidate of least variance x cost if it beats c = 0 by
//! `training_significance` standard errors and the node had `MIN_SAMPLES` samples,
//! `training_min_nonzero` of them non-zero; otherwise it is not guided ([`choose_node`]). With
//! a fixed `c_skel` only s is chosen; without a camera nothing is. The choice is a
//! deterministic function of the scene, so the render stays unbiased.
//!
//! # Lobe weights
//!
//! `lobe_weights=learned` adds per-lobe weights to the candidates (eq. 165's, each lobe alone,
//! [`fit_lobe_weights`]), judged by the same reweighting: eq. 165 can favour a lobe whose
//! opening x cannot see.
//!
//! # Learned directions
//!
//! `directions=learned` replaces a node's lobes by equal-area histograms of its sampled
//! directions per class of point (`guide::directional`), each judged on the half of the
//! samples it was not fitted to.
//!
//! # Iterative training
//!
//! With `training_passes=N` each later pass samples from the previous pass's histograms and
//! re-learns from its own samples; the BSDF share keeps the coverage condition.
//!
//! # Measured cost and the scene-level switch
//!
//! `cost_model=measured` adds callgrind-measured per-query and node-mapping costs
//! (`LOBE_COSTS`, `LEARNED_COSTS`). With `switch`, `measured` or `paths` the whole image is then
//! judged ([`SceneChoice`]): below 1 + `SCENE_MARGIN` predicted efficiency nothing is guided
//! ([`SkeletonGuide::guides_nothing`]) and `path_skeleton` renders `path`'s image exactly.
//!
//! # The scout
//!
//! Where the choices face the scene-level switch and the pilot (`c_skel=learned`, a switching
//! cost model, `pilot_paths` > 0, one training pass), the training first traces
//! 1 / [`SCOUT_FRACTION`] of its paths. If the choices from those guide no node (none beats
//! c = 0 by the significance rule on so few samples, or the scene-level switch turns them
//! off), the training stops there and nothing is guided: the full training's cost is paid
//! only where the scout saw something to gain. The scout's paths are the first of the full
//! training's, so a scene that goes on learns exactly what it learned without the scout.
//!
//! Where the scout's choices guide some node, `path_skeleton` (`scout_pilot=on`, the default)
//! runs its pilot (`integrator::path`, "The pilot") on the scout's guide before going on
//! ([`super::SkeletonGuide::build_with_scout_check`]). Unless that guide shows a gain with
//! the variance ratio raised by one standard error ([`Pilot::may_pay_after_training`]), the
//! training stops there and nothing is guided. The final verdict asks more of the full guide:
//! a 10 % gain with the variance ratio raised by two standard errors, an efficiency of about
//! 1.5-2 at the point estimate. Else the full training goes on from the scout's state exactly.
//!
//! # The path-level prediction
//!
//! `cost_model=paths` (the default) takes the variance ratio from whole training paths, as a
//! sum over vertices misses the product of weights along a path: M = E_{q_0}[E² prod_i 1 / r_i],
//! E = a_0 + sum_i a_i prod_{j <= i} r_j, r_i = q_0 / q at each guided vertex, for guiding
//! nothing and for the choices, terms capped at the `PATH_TERM_QUANTILE` quantile.
//!
//! Heuristic parts: the proxy stops after `training_depth` vertices, R carries its own noise,
//! each node is judged with the others guided at c0, and the objective is MSE, not MAE.

use std::sync::atomic::{AtomicU32, Ordering as AtomicOrdering};

use rayon::prelude::*;

use super::{CostModel, GuideQuery, SkeletonGuide, SkeletonStrength};
use super::{MAX_LOBES, STRENGTH_CANDIDATES};
use crate::analysis::{may_map_to, may_map_to_where, VoxelSet};
use crate::math::{Rng, Sampler};
use crate::scene::{Camera, Scene};

use prediction::{
    path_variance_ratio, scene_prediction, MeasuredCosts, PathLog, PathRecord, SCENE_MARGIN,
};
pub(super) use statistics::Weighted;
use statistics::{
    choose_node, learn_directions, mean_shadow_rays, mixture, NodeChoice, Sample, NO_STEP,
};
use tracer::{train_path, Visits};

mod prediction;
mod statistics;
#[cfg(test)]
mod tests;
mod tracer;

/// Guiding probability of the training pass (c0 in the module docs): both strategies get half the samples,
/// so the reweighting factor q_c0 / q_c is at most 2 for any c.
pub const TRAINING_C: f32 = 0.5;
/// The candidate probabilities (c = 0 is "not guided").
pub const CANDIDATES: [f32; 11] = [0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9];
/// Most strengths a training pass compares.
const MAX_STRENGTHS: usize = STRENGTH_CANDIDATES.len();
/// The scout's share of the training paths is 1 / this (module docs, "The scout").
pub(super) const SCOUT_FRACTION: u32 = 8;
/// Camera paths per chunk (the fixed work partition).
const CHUNK: u32 = 1024;
/// Width / height of the training pass's image.
const TRAINING_ASPECT: f32 = 2.0;
const TRAINING_SEED: u64 = 0x7ea1_c5e1;

/// What the training pass found.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainingReport {
    /// The guiding probability of each node: one of [`CANDIDATES`] with `c_skel=learned`,
    /// else the fixed `c_skel`.
    pub probabilities: Vec<f32>,
    /// The strength of each node: one of [`STRENGTH_CANDIDATES`] with `strength=learned`
    /// (the settings' strength at nodes with too few samples), else the settings' strength.
    pub strengths: Vec<SkeletonStrength>,
    /// Training samples recorded per node, and how many of them were non-zero.
    pub samples: Vec<u32>,
    pub nonzero: Vec<u32>,
    /// Per node, the estimated variance x cost of the chosen (c, s) relative to not guiding
    /// (below 1: guiding is better; 1 for nodes not guided, also where that ratio would
    /// have been below 1 without being significant).
    pub relative_cost: Vec<f32>,
    /// The same ratio for the best candidate before the significance rule (1 where the node
    /// had too few samples; with a fixed `c_skel`, the best strength's ratio).
    pub best_ratio: Vec<f32>,
    /// Mean vertices per sample's estimate (the vertex and the rest of its training path).
    pub mean_remaining: Vec<f32>,
    /// With `lobe_weights=learned`: per node, the lobe selection probabilities chosen (in
    /// the order of `SkeletonGuide::lobes`, summing to 1, 0 for a lobe never to be used), or
    /// None where eq. 165's are kept (also at every node not guided).
    pub lobe_weights: Vec<Option<Vec<f32>>>,
    /// With `directions=learned`: per node, the bin probabilities of its learned directional
    /// distribution (`guide::directional`), None where it had no samples (module docs,
    /// "Learned directions").
    pub directions: Vec<Option<Vec<f32>>>,
    /// Camera paths traced (0 when the scene has no camera: then the guide keeps its fixed
    /// `c_skel` and strength).
    pub paths: u32,
    /// The scene-level view of the node choices (module docs, "Measured cost and the
    /// scene-level switch"), predicted with the measured costs whatever the cost model the
    /// nodes were chosen with; with `cost_model=switch|measured` it decides whether anything is
    /// guided.
    pub scene: SceneChoice,
    /// The voxels that may map to a node with a probability above 0 (`analysis::may_map_to`
    /// over the whole grid), where the last pass computed them for its prediction's mapping
    /// cost: the render's mask for the same choices. `SkeletonGuide::build` takes it, so a
    /// guide's stored report always holds None; None also for the scout, switched off or
    /// untrained.
    pub may_guide: Option<VoxelSet>,
}

impl TrainingReport {
    /// Every node set to c = 0, as the scene-level switch does (also the scout's time-budget
    /// stop, `guide::budget`).
    pub(super) fn turn_off(&mut self, settings: &super::SkeletonGuideSettings) {
        self.scene.switched_off = true;
        self.probabilities.fill(0.0);
        self.strengths.fill(settings.strength);
        self.relative_cost.fill(1.0);
        self.lobe_weights.fill(None);
        self.may_guide = None;
    }

    /// Nothing learned: the fixed `c_skel` and strength at every node (no camera, no path).
    fn untrained(settings: &super::SkeletonGuideSettings, nodes: usize) -> TrainingReport {
        TrainingReport {
            probabilities: vec![settings.c_skel; nodes],
            strengths: vec![settings.strength; nodes],
            samples: vec![0; nodes],
            nonzero: vec![0; nodes],
            relative_cost: vec![1.0; nodes],
            best_ratio: vec![1.0; nodes],
            mean_remaining: vec![0.0; nodes],
            lobe_weights: vec![None; nodes],
            directions: vec![None; nodes],
            paths: 0,
            scene: SceneChoice {
                variance_ratio: 1.0,
                cost_ratio: 1.0,
                ..SceneChoice::default()
            },
            may_guide: None,
        }
    }
}

/// What the node choices do to the whole image, predicted from the training paths, before the
/// scene-level switch (module docs, "Measured cost and the scene-level switch").
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SceneChoice {
    /// Vertices of all training paths.
    pub vertices: u64,
    /// Training samples at nodes the choices guide (vertices that set the lobes up).
    pub guided_vertices: u64,
    /// Non-delta training vertices in voxels that may map to a guided node (they pay the
    /// node mapping).
    pub mapped_vertices: u64,
    /// Predicted variance of the choices relative to guiding nothing (sum over the nodes of
    /// samples x variance), and cost (vertices plus the overhead in vertices).
    pub variance_ratio: f64,
    /// With `cost_model=paths`: the predicted variance of the whole camera path's estimate
    /// under the choices relative to guiding nothing (module docs, "The path-level
    /// prediction"), which then replaces `variance_ratio` in [`SceneChoice::efficiency`].
    pub path_variance_ratio: Option<f64>,
    pub cost_ratio: f64,
    /// The pilot's measurement with the render's estimator, where one ran (`pilot_paths`;
    /// `integrator::path`, "The pilot"): it has the last word on the switch.
    pub pilot: Option<Pilot>,
    /// `cost_model=switch|measured` and the predicted efficiency 1 / (variance_ratio cost_ratio)
    /// was not above 1 + `SCENE_MARGIN`: every node was set to c = 0.
    pub switched_off: bool,
}

impl SceneChoice {
    /// Predicted whole-image efficiency of the node choices against guiding nothing (above 1:
    /// the guide pays).
    pub fn efficiency(&self) -> f64 {
        1.0 / (self.predicted_variance() * self.cost_ratio)
    }

    /// The variance ratio the efficiency uses: the path-level one where it was predicted
    /// (`cost_model=paths`), else the sum over the vertices.
    pub fn predicted_variance(&self) -> f64 {
        self.path_variance_ratio.unwrap_or(self.variance_ratio)
    }

    /// Whether the predicted efficiency is clearly above guiding nothing's (by
    /// `SCENE_MARGIN`): `cost_model=switch|measured` guide nothing otherwise.
    pub fn pays(&self) -> bool {
        self.efficiency() > 1.0 + SCENE_MARGIN
    }
}

/// What the pilot measured (`integrator::path`, "The pilot"): the render's own samples, guided
/// against unguided from the same rays or pixels and random numbers.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pilot {
    /// Camera samples per policy and estimate.
    pub rays: u32,
    /// Units (rays or pixels, `pilot_sampler`), each estimated twice per policy.
    pub units: u32,
    /// Mean per-sample variance of a unit's luminance (half the squared difference of its
    /// two independent estimates, times its samples per estimate), unguided and guided.
    pub variance_path: f64,
    pub variance_guided: f64,
    /// The relative standard error of the variance ratio (delta method over the units; a
    /// diagnostic, printed with the verdict).
    pub variance_error: f64,
    /// Rays traced (closest hits and shadow rays) per sample, unguided and guided.
    pub rays_per_sample_path: f64,
    pub rays_per_sample_guided: f64,
    /// Time spent tracing the unguided and the guided samples (interleaved unit by unit, so
    /// that the machine's load weighs on both alike).
    pub seconds_path: f64,
    pub seconds_guided: f64,
    /// Guided cost per sample relative to unguided: with `pilot_cost=time` the ratio of the
    /// measured times, with `work` the ray ratio times the training's overhead ratio (the
    /// guided queries and node mapping per vertex).
    pub cost_ratio: f64,
    /// Standard errors by which the variance ratio is raised for the verdict
    /// (`pilot_sigmas`, default [`PILOT_SIGMAS`]).
    pub sigmas: f64,
}

impl Pilot {
    /// Measured variance ratio, guided over unguided (1 where unguided has none).
    pub fn variance_ratio(&self) -> f64 {
        if self.variance_path > 0.0 {
            self.variance_guided / self.variance_path
        } else {
            1.0
        }
    }

    /// Efficiency of the guided samples against unguided ones at the cost proxy.
    pub fn efficiency(&self) -> f64 {
        1.0 / (self.variance_ratio() * self.cost_ratio)
    }

    /// The efficiency with the measured variance ratio raised by `sigmas` of its relative
    /// standard error: what the pilot can vouch for.
    pub fn efficiency_bound(&self) -> f64 {
        self.efficiency() / (1.0 + self.sigmas * self.variance_error)
    }

    /// Whether guiding pays by the scene-level margin, at the pilot's confidence bound.
    pub fn pays(&self) -> bool {
        self.efficiency_bound() > 1.0 + SCENE_MARGIN
    }

    /// The verdict on a guide trained on the scout's paths alone (`guide::training`, "The
    /// scout"): whether the full training may still make it pay. False unless the scout's
    /// guide shows a gain (efficiency above 1) with the variance ratio raised by half the
    /// final verdict's standard errors (one by default; `pilot_sigmas=0`: the point estimate).
    pub fn may_pay_after_training(&self) -> bool {
        self.scout_efficiency_bound() > 1.0
    }

    /// The efficiency that [`Pilot::may_pay_after_training`] judges: the variance ratio
    /// raised by half of `sigmas` of its relative standard errors.
    pub fn scout_efficiency_bound(&self) -> f64 {
        self.efficiency() / (1.0 + 0.5 * self.sigmas * self.variance_error)
    }
}

/// Default standard errors by which the pilot's variance ratio is raised before its verdict
/// ([`Pilot::pays`], `pilot_sigmas`). The reading is a ratio of heavy-tailed variances with
/// relative errors of 0.1-0.6: at its point estimate the pilot guided the family scenes
/// rooms:29 and rooms:45 (Sobol readings 1.53x and 1.28x, relative errors 0.24-0.25), which
/// then lost 0.81-0.83x at equal time. Two errors (about 97.5 % one-sided) keep the gains the
/// pilot sees clearly: the corridor (5.5x, error 0.44) and the door (1.69x, error 0.23).
pub const PILOT_SIGMAS: f64 = 2.0;

impl TrainingReport {
    /// Nodes with a learned probability above 0.
    pub fn guided_nodes(&self) -> usize {
        self.probabilities.iter().filter(|&&c| c > 0.0).count()
    }
}

/// What a training pass does with the scout's paths ([`learn_guiding_probabilities`]).
pub(super) enum Scout<'a> {
    /// Not the scout, nothing kept.
    None,
    /// This is the scout: keep its paths here.
    Keep(&'a mut ScoutPaths),
    /// The full training after the scout: start from its kept paths (taken).
    Reuse(&'a mut ScoutPaths),
}

/// The candidates of one training pass.
struct Grid {
    /// Guiding probabilities above 0 to choose from (c = 0 is the baseline, not in here).
    c: Vec<f32>,
    strengths: Vec<SkeletonStrength>,
    /// Whether c = 0 competes (`c_skel=learned`); else the fixed c is kept whatever it costs.
    may_turn_off: bool,
    /// `lobe_weights=learned`: the lobes' selection probabilities are chosen too.
    lobe_weights: bool,
    /// Cost of guiding at a vertex beyond an unguided vertex's, shadow rays aside (with
    /// `cost_model=measured` the node mapping included).
    guided_cost: f64,
    /// The measured costs of the settings' directions (the scene-level prediction's).
    measured: MeasuredCosts,
}

impl Grid {
    fn of(guide: &SkeletonGuide) -> Grid {
        let settings = guide.settings();
        let measured = MeasuredCosts::of(settings);
        Grid {
            c: if settings.learned_c_skel {
                // `c_max` >= CANDIDATES[1] (validated): never empty.
                CANDIDATES[1..]
                    .iter()
                    .copied()
                    .filter(|&c| c <= settings.c_max)
                    .collect()
            } else {
                vec![settings.c_skel]
            },
            strengths: if settings.learned_strength {
                STRENGTH_CANDIDATES.to_vec()
            } else {
                vec![settings.strength]
            },
            may_turn_off: settings.learned_c_skel,
            lobe_weights: settings.learned_lobe_weights,
            guided_cost: if settings.cost_model == CostModel::Measured {
                measured.query + measured.map
            } else {
                settings.training_guided_cost as f64
            },
            measured,
        }
    }

    fn len(&self) -> usize {
        self.c.len() * self.strengths.len()
    }

    /// (c, s index) of candidate `j`.
    fn at(&self, j: usize) -> (f32, usize) {
        (self.c[j / self.strengths.len()], j % self.strengths.len())
    }
}

/// One chunk's training paths: its samples, vertices and path records.
type ChunkPaths = (Vec<Sample>, u64, PathLog);

/// The scout's training paths, kept for the full training (module docs, "The scout"): its
/// chunks are the full training's first, traced the same way, so the full training starts
/// from them instead of tracing them again.
#[derive(Default)]
pub(super) struct ScoutPaths {
    /// The first pass's first chunks, in order.
    chunks: Vec<ChunkPaths>,
    /// Their non-delta vertices per voxel.
    per_voxel: Vec<u32>,
}

/// Runs the training pass for `guide` (whose node probabilities must all be [`TRAINING_C`]
/// and whose strength is the settings' everywhere) and chooses every node's probability and
/// strength (module docs).
/// `pass` numbers the passes of iterative training (0 first; module docs, "Iterative
/// training"): each has its own random streams.
/// `scout` (pass 0 only): with `Keep`, this is the scout and its paths are kept there (when
/// they fill whole chunks); with `Reuse`, the kept paths are this pass's first chunks (the
/// guide's state and settings other than `training_paths` must be the scout's).
pub(super) fn learn_guiding_probabilities(
    guide: &SkeletonGuide,
    scene: &Scene,
    camera: Option<&Camera>,
    pass: u32,
    history: &mut [Vec<Weighted>],
    mut scout: Scout<'_>,
) -> TrainingReport {
    let nodes = guide.node_count();
    let settings = guide.settings();
    let grid = Grid::of(guide);
    let Some(camera) = camera else {
        return TrainingReport::untrained(settings, nodes);
    };
    // The render's image size is not known here: a 2:1 frame covers the scene files' images
    // (2:1 and 1:1) and more; training nodes outside the view costs samples, not bias.
    let camera = camera.frame(TRAINING_ASPECT);
    let paths = settings.training_paths;
    let chunks = paths.div_ceil(CHUNK);
    // Non-delta training vertices per voxel (atomic adds: the counts do not depend on the
    // order), for the scene-level prediction's mapping cost.
    let (reused, reused_voxels) = match &mut scout {
        Scout::Reuse(kept) => {
            let kept = std::mem::take(&mut **kept);
            (kept.chunks, kept.per_voxel)
        }
        _ => (Vec::new(), Vec::new()),
    };
    assert!(
        reused.len() as u32 <= chunks && (reused.is_empty() || pass == 0),
        "the scout's paths are the first pass's first chunks"
    );
    let per_voxel: Vec<AtomicU32> = (0..guide.grid().len())
        .map(|k| AtomicU32::new(reused_voxels.get(k).copied().unwrap_or(0)))
        .collect();
    // The path-level prediction's records (module docs, "The path-level prediction").
    let log_paths = settings.cost_model == CostModel::Paths;
    let is_scout = matches!(scout, Scout::Keep(_));
    let first = reused.len() as u32;
    // The full training's chunks hold about as many samples as the scout's: room for the
    // largest of them and a sixteenth more saves growing the vectors by reallocation.
    let capacity = reused
        .iter()
        .map(|(s, _, _)| s.len())
        .max()
        .map_or(0, |n| n + n / 16);
    let traced: Vec<ChunkPaths> = (first..chunks)
        .into_par_iter()
        .map(|c| {
            let seed = TRAINING_SEED.wrapping_add(pass as u64 * 0x9e37_79b9_7f4a_7c15);
            let mut rng = Sampler::independent(Rng::new(seed, c as u64));
            let mut query = GuideQuery::new();
            let mut out = Vec::with_capacity(capacity);
            let mut log = PathLog::default();
            let mut visits = Visits {
                vertices: 0,
                per_voxel: &per_voxel,
            };
            for _ in 0..CHUNK.min(paths - c * CHUNK) {
                let ray = camera.generate_ray(rng.uniform2(), rng.uniform2());
                if let Some(si) = scene.intersect(&ray) {
                    train_path(
                        guide,
                        scene,
                        &grid.strengths,
                        si,
                        &mut query,
                        &mut rng,
                        &mut out,
                        &mut visits,
                        log_paths.then_some(&mut log),
                    );
                }
            }
            (out, visits.vertices, log)
        })
        .collect();
    let mut per_chunk = reused;
    per_chunk.extend(traced);
    // Only whole chunks are the full training's too (a last, partial chunk traces fewer paths).
    if let (Scout::Keep(kept), 0) = (scout, paths % CHUNK) {
        *kept = ScoutPaths {
            chunks: per_chunk.clone(),
            per_voxel: per_voxel
                .iter()
                .map(|n| n.load(AtomicOrdering::Relaxed))
                .collect(),
        };
    }

    // Every node's samples in chunk order (the same order for any thread count): counted,
    // then moved once into per-node vectors of exact size.
    let mut counts = vec![0usize; nodes];
    let mut vertices = 0u64;
    let mut log = PathLog::default();
    for (samples, v, chunk_log) in &mut per_chunk {
        // The chunk's path records appended to the pass's log, its samples' steps moved along.
        let steps = log.steps.len() as u32;
        for s in samples.iter_mut() {
            counts[s.node as usize] += 1;
            if s.step != NO_STEP {
                s.step += steps;
            }
        }
        log.paths
            .extend(chunk_log.paths.drain(..).map(|p| PathRecord {
                start: p.start + steps,
                ..p
            }));
        log.steps.append(&mut chunk_log.steps);
        vertices += *v;
    }
    let mut per_node: Vec<Vec<Sample>> = counts.iter().map(|&n| Vec::with_capacity(n)).collect();
    for (samples, _, _) in per_chunk {
        for s in samples {
            per_node[s.node as usize].push(s);
        }
    }
    // Only the last pass's choices are kept (an earlier pass passes its distributions on):
    // an earlier pass needs neither the choices nor the held-out densities that judge them.
    let last = pass + 1 >= settings.training_passes;
    let mut directions = vec![None; nodes];
    if settings.learned_directions {
        let mis = settings.render_estimator.mis;
        let empty: &[Weighted] = &[];
        let floor = settings.histogram_floor;
        let learned: Vec<(usize, Vec<f32>, Vec<Weighted>)> = per_node
            .par_iter_mut()
            .enumerate()
            .filter(|(_, g)| !g.is_empty())
            .map(|(node, g)| {
                let earlier = history.get(node).map_or(empty, |h| h.as_slice());
                let (d, weighted) = learn_directions(g, mis, earlier, floor, last);
                (node, d, weighted)
            })
            .collect();
        let keep = settings.training_history;
        for (node, d, weighted) in learned {
            directions[node] = Some(d);
            if keep {
                history[node].extend(weighted);
            }
        }
    }
    if !last {
        return TrainingReport {
            directions,
            paths,
            ..TrainingReport::untrained(settings, nodes)
        };
    }
    let by_node: Vec<&[Sample]> = per_node.iter().map(|g| g.as_slice()).collect();
    // Guide shadow rays per node: the cache's fills with `visibility=voxel` (a query that
    // fills an entry may be one whose sample is not recorded, and which query that is depends
    // on thread timing), else each recorded query's own rays.
    let cache_rays = guide.voxel_visibility_rays();
    let choices: Vec<NodeChoice> = by_node
        .par_iter()
        .enumerate()
        .map(|(k, samples)| {
            let rays = match &cache_rays {
                // A learned distribution traces no shadow ray.
                _ if settings.learned_directions => 0.0,
                Some(fills) => fills[k] as f64 / samples.len().max(1) as f64,
                None => mean_shadow_rays(samples),
            };
            choose_node(
                samples,
                rays,
                &grid,
                settings.training_cost,
                settings.training_significance as f64,
                settings.training_min_nonzero,
                settings.render_estimator.mis,
            )
        })
        .collect();

    let mut probabilities = vec![
        if grid.may_turn_off {
            0.0
        } else {
            settings.c_skel
        };
        nodes
    ];
    let mut strengths = vec![settings.strength; nodes];
    for (k, choice) in choices.iter().enumerate() {
        if let Some((c, ks)) = choice.guided {
            probabilities[k] = c;
            strengths[k] = grid.strengths[ks];
        }
    }
    let samples: Vec<u32> = by_node.iter().map(|s| s.len() as u32).collect();
    let mut kept_mask: Option<VoxelSet>;
    let scene_choice = {
        // The vertices that pay the node mapping under these choices: those in voxels that
        // may map to a guided node (the render's `may_guide`). The scout asks only where its
        // vertices fell; the full training finds the render's whole mask, which it keeps.
        let wanted = |n: u32| probabilities[n as usize] > 0.0;
        let may_guide = if is_scout {
            may_map_to_where(guide.grid(), guide.node_map(), wanted, |k| {
                per_voxel[k].load(AtomicOrdering::Relaxed) > 0
            })
        } else {
            may_map_to(guide.grid(), guide.node_map(), wanted)
        };
        let mapped_vertices = per_voxel
            .iter()
            .zip(&may_guide)
            .filter(|(_, &m)| m)
            .map(|(n, _)| n.load(AtomicOrdering::Relaxed) as u64)
            .sum();
        kept_mask = (!is_scout).then(|| VoxelSet::from_flags(&may_guide));
        let (variance_ratio, cost_ratio) = scene_prediction(
            &choices,
            &samples,
            vertices,
            mapped_vertices,
            grid.measured.map,
        );
        let path_variance_ratio = log_paths.then(|| {
            for s in per_node.iter().flatten().filter(|s| s.step != NO_STEP) {
                let q0 = mixture(TRAINING_C, s.p_skel, s.p_bsdf);
                let choice = &choices[s.node as usize];
                let q = match choice.guided {
                    Some((c, k)) => {
                        let (c, p, _) = s.candidate(c, k, choice.weights.as_ref());
                        mixture(c, p, s.p_bsdf)
                    }
                    None => s.p_bsdf as f64,
                };
                let step = &mut log.steps[s.step as usize];
                step.r_none = q0 / s.p_bsdf as f64;
                step.r_chosen = q0 / q;
            }
            path_variance_ratio(&log)
        });
        let mut scene = SceneChoice {
            vertices,
            guided_vertices: choices
                .iter()
                .zip(&samples)
                .filter(|(c, _)| c.guided.is_some())
                .map(|(_, &n)| n as u64)
                .sum(),
            mapped_vertices,
            variance_ratio,
            path_variance_ratio,
            cost_ratio,
            pilot: None,
            switched_off: false,
        };
        if settings.cost_model.switches()
            && grid.may_turn_off
            && probabilities.iter().any(|&c| c > 0.0)
            && !scene.pays()
        {
            scene.switched_off = true;
            probabilities.fill(0.0);
            strengths.fill(settings.strength);
            kept_mask = None;
        }
        scene
    };
    let switched_off = scene_choice.switched_off;
    TrainingReport {
        probabilities,
        strengths,
        samples,
        nonzero: by_node
            .iter()
            .map(|s| s.iter().filter(|s| s.carries()).count() as u32)
            .collect(),
        relative_cost: choices
            .iter()
            .map(|c| if switched_off { 1.0 } else { c.relative_cost })
            .collect(),
        best_ratio: choices.iter().map(|c| c.best_ratio).collect(),
        mean_remaining: by_node
            .iter()
            .map(|s| s.iter().map(|s| s.remaining as f32).sum::<f32>() / s.len().max(1) as f32)
            .collect(),
        lobe_weights: choices
            .iter()
            .enumerate()
            .map(|(k, c)| {
                let lobes = guide.lobes(k as u32).len().min(MAX_LOBES);
                c.weights
                    .filter(|_| !switched_off)
                    .map(|w| w[..lobes].to_vec())
            })
            .collect(),
        directions,
        paths,
        scene: scene_choice,
        may_guide: kept_mask,
    }
}
