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

use super::directional::{self, DirectionalTable};
use super::estimator::{self, DirectLight};
use super::{
    sample_bsdf_or_guide, CostModel, GuideQuery, RenderEstimator, SkeletonGuide, SkeletonStrength,
    TrainingCost,
};
use super::{MAX_LOBES, STRENGTH_CANDIDATES};
use crate::math::{luminance, MisHeuristic, Rgb, Rng, Sampler, Vec3};
use crate::scene::{Camera, Scene, SurfaceInteraction};

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
/// Training samples a node needs before it may be guided (how many must be non-zero is the
/// settings' `training_min_nonzero`).
const MIN_SAMPLES: u32 = 256;
/// Cost per guide shadow ray in unguided vertices (module docs; the cost of guiding beyond
/// that is the settings' `training_guided_cost`).
const COST_SHADOW_RAY: f64 = 0.25;
/// Multiplicative updates of the lobe-weight fit, and the weight below which the fit drops a
/// lobe (module docs, "Lobe weights").
const FIT_ITERATIONS: usize = 24;
const FIT_FLOOR: f32 = 0.03;
/// Width / height of the training pass's image.
const TRAINING_ASPECT: f32 = 2.0;
/// The measured costs (module docs, "Measured cost and the scene-level switch"), in unguided
/// vertices: `query`, a guided query's cost beyond an unguided vertex's whatever its c (with
/// the lobes their set-up, the mixture's sampling and densities and the dearer rays of the
/// paths it sends elsewhere; guide shadow rays aside); `map`, the node mapping, paid by every
/// vertex in a voxel that may map to a guided node, guided or not.
#[derive(Clone, Copy, Debug, PartialEq)]
struct MeasuredCosts {
    query: f64,
    map: f64,
}

impl MeasuredCosts {
    /// The costs of the settings' directions: the lobes' or the learned histograms'.
    fn of(settings: &super::SkeletonGuideSettings) -> MeasuredCosts {
        if settings.learned_directions {
            LEARNED_COSTS
        } else {
            LOBE_COSTS
        }
    }
}

/// `directions=lobes`, from callgrind of Sponza (`path_skeleton` minus `path` per camera sample,
/// divided by the guided queries or mapped vertices per sample and by `path`'s instructions per
/// vertex; BENCHMARKS.md).
const LOBE_COSTS: MeasuredCosts = MeasuredCosts {
    query: 0.39,
    map: 0.064,
};
/// `directions=learned`, measured as [`LOBE_COSTS`] on the ajar and the door, the mean of the
/// two: no set-up beyond the class lookup, no shadow ray.
const LEARNED_COSTS: MeasuredCosts = MeasuredCosts {
    query: 0.19,
    map: 0.12,
};
/// `cost_model=switch|measured`: the whole image's predicted efficiency must gain this much (as a
/// ratio above 1) for anything to be guided.
const SCENE_MARGIN: f64 = 0.1;
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
}

impl TrainingReport {
    /// Every node set to c = 0, as the scene-level switch does (the scout's time-budget
    /// stop, `guide::settings`'s `BUDGET_SHARE`).
    pub(super) fn turn_off(&mut self, settings: &super::SkeletonGuideSettings) {
        self.scene.switched_off = true;
        self.probabilities.fill(0.0);
        self.strengths.fill(settings.strength);
        self.relative_cost.fill(1.0);
        self.lobe_weights.fill(None);
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
/// against unguided from the same rays and random numbers.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pilot {
    /// Rays the pilot traced from.
    pub rays: u32,
    /// Mean per-ray variance of the sample's luminance (half the squared difference of two
    /// independent samples along the same ray), unguided and guided.
    pub variance_path: f64,
    pub variance_guided: f64,
    /// Rays traced (closest hits and shadow rays) per sample, unguided and guided.
    pub rays_per_sample_path: f64,
    pub rays_per_sample_guided: f64,
    /// Time spent tracing the unguided and the guided samples (interleaved ray by ray, so
    /// that the machine's load weighs on both alike).
    pub seconds_path: f64,
    pub seconds_guided: f64,
    /// Guided cost per sample relative to unguided: with `pilot_cost=time` the ratio of the
    /// measured times, with `work` the ray ratio times the training's overhead ratio (the
    /// guided queries and node mapping per vertex).
    pub cost_ratio: f64,
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

    /// Whether guiding pays by the scene-level margin.
    pub fn pays(&self) -> bool {
        self.efficiency() > 1.0 + SCENE_MARGIN
    }
}

impl TrainingReport {
    /// Nodes with a learned probability above 0.
    pub fn guided_nodes(&self) -> usize {
        self.probabilities.iter().filter(|&&c| c > 0.0).count()
    }
}

/// One training sample at a guided vertex: the direction it sampled and its own light sample,
/// each with the densities every candidate's MIS weights need (module docs, "What is
/// measured").
#[derive(Clone, Copy, Debug, PartialEq)]
struct Sample {
    node: u32,
    /// The sampled direction (world space), and the point's class (`directional::class_of`).
    wi: Vec3,
    class: u8,
    /// Luminance of beta f_s |cos| L_e along the sampled direction (the emission found at the
    /// next vertex or the environment's), unweighted; 0 where it found none.
    f_emitted: f32,
    /// Luminance of beta f_s |cos| R, the radiance the rest of the path reflects toward x.
    f_reflected: f32,
    p_bsdf: f32,
    /// The skeleton mixture's density under the training proposal's strength.
    p_skel: f32,
    /// The same under each candidate strength (the first `strengths` entries).
    p_strength: [f32; MAX_STRENGTHS],
    /// Light sampling's density (pmf x pdf) of the emitter the direction hit; 0 if none.
    p_light: f32,
    /// Next-event estimation at this vertex.
    nee: NeeTerms,
    /// With `lobe_weights=learned`: each node lobe's density at the direction
    /// (`GuideQuery::node_lobe_pdfs`, negative where the lobe does not apply at x), and which
    /// lobes apply at x (bit j: lobe j).
    p_lobes: [f32; MAX_LOBES],
    active: u8,
    /// Shadow rays the guide traced for this vertex's query.
    rays: u32,
    /// Vertices of the training path from this one to its end (module docs, "Cost").
    remaining: u32,
    /// Its sampled direction's entry in the pass's [`Step`]s (`NO_STEP` where it has none or
    /// none are recorded).
    step: u32,
}

/// [`Sample::step`] of a sample without a sampled direction's [`Step`].
const NO_STEP: u32 = u32::MAX;

/// One sampled direction of a training path, for the path-level prediction (module docs, "The
/// path-level prediction").
#[derive(Clone, Copy, Debug, PartialEq)]
struct Step {
    /// Luminance of the light sample at the vertex the direction reached, times the path's
    /// throughput there (0 where none).
    after: f32,
    /// q_0 / q of the direction under guiding nothing and under the choices (1 where the
    /// training did not guide the vertex: BSDF sampling in both).
    r_none: f64,
    r_chosen: f64,
}

/// One training path for the path-level prediction: the light sample at its first vertex (as
/// [`Step::after`]) and its [`Step`]s.
#[derive(Clone, Copy, Debug, PartialEq)]
struct PathRecord {
    first: f32,
    start: u32,
    len: u32,
}
/// The quantile of the paths' second-moment terms at which the path-level prediction caps
/// them (module docs, "The path-level prediction").
const PATH_TERM_QUANTILE: f64 = 0.9999;

/// A vertex's light sample, as the candidates see it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct NeeTerms {
    /// Luminance of beta f_s |cos| L / p_light, unweighted (0 if occluded or no light).
    value: f32,
    /// Its light density (infinite for delta lights: MIS weight 1).
    p_light: f32,
    /// Its direction (world space).
    wi: Vec3,
    /// The direction densities of its direction (BSDF, skeleton at s0, per candidate strength).
    p_bsdf: f32,
    p_skel: f32,
    p_strength: [f32; MAX_STRENGTHS],
    /// Each node lobe's density at its direction (as `Sample::p_lobes`).
    p_lobes: [f32; MAX_LOBES],
}

impl Default for NeeTerms {
    fn default() -> Self {
        NeeTerms {
            value: 0.0,
            p_light: 0.0,
            wi: Vec3::ZERO,
            p_bsdf: 0.0,
            p_skel: 0.0,
            p_strength: [0.0; MAX_STRENGTHS],
            p_lobes: [0.0; MAX_LOBES],
        }
    }
}

/// The skeleton mixture at a point where lobes `active` apply, under selection weights
/// `weights` (renormalised over those lobes, as `GuideQuery::init` does), at a direction where
/// the node's lobes have densities `p_lobes`; None where no lobe of positive weight applies
/// (the point is then not guided: BSDF sampling alone).
fn lobe_mixture(p_lobes: &[f32; MAX_LOBES], active: u8, weights: &[f32; MAX_LOBES]) -> Option<f32> {
    let (mut total, mut sum) = (0.0f32, 0.0f32);
    for j in 0..MAX_LOBES {
        if active & (1 << j) != 0 && weights[j] > 0.0 {
            total += weights[j];
            sum += weights[j] * p_lobes[j].max(0.0);
        }
    }
    (total > 0.0).then(|| sum / total)
}

/// One sample's share of the moments of the vertex's estimate under one candidate.
#[derive(Clone, Copy, Debug, Default)]
struct Terms {
    /// (D_c,s)² q_c,s / q_c0 + (N_c,s)²: its terms of the two second moments (module docs).
    second: f64,
    /// D_c,s q_c,s / q_c0 and N_c,s: its terms of the two means.
    mean_direction: f64,
    mean_nee: f64,
}

impl Sample {
    /// Whether the sampled direction carried anything.
    fn carries(&self) -> bool {
        self.f_emitted > 0.0 || self.f_reflected > 0.0
    }

    /// This sample's terms under candidate (c, strength index k) (module docs): the direction
    /// part reweighted from the training proposal, with the emission it found MIS-weighted as
    /// the render weighs it, and the light sample with its MIS weight against q_c,s. With
    /// `weights`, the lobes' selection probabilities are those instead of eq. 165's (module
    /// docs, "Lobe weights"; strength index 0).
    fn terms(
        &self,
        c: f32,
        k: usize,
        weights: Option<&[f32; MAX_LOBES]>,
        mis: MisHeuristic,
    ) -> Terms {
        let (c, p, p_nee) = self.candidate(c, k, weights);
        self.terms_with(c, p, p_nee, mis)
    }

    /// Candidate (c, strength index k, `weights`)'s probability and skeleton densities at the
    /// sampled direction and at the light sample's: strength k's, or the lobe weights'
    /// mixture; c = 0 where the weights leave the point unguided ([`lobe_mixture`]).
    fn candidate(&self, c: f32, k: usize, weights: Option<&[f32; MAX_LOBES]>) -> (f32, f32, f32) {
        let Some(weights) = weights else {
            return (c, self.p_strength[k], self.nee.p_strength[k]);
        };
        match self.densities(weights) {
            Some((p, p_nee)) => (c, p, p_nee),
            None => (0.0, 0.0, 0.0),
        }
    }

    /// The skeleton densities at the sampled direction and at the light sample's under lobe
    /// weights `weights`; None where x is not guided under them ([`lobe_mixture`]).
    fn densities(&self, weights: &[f32; MAX_LOBES]) -> Option<(f32, f32)> {
        let p = lobe_mixture(&self.p_lobes, self.active, weights)?;
        let p_nee = lobe_mixture(&self.nee.p_lobes, self.active, weights).unwrap_or(0.0);
        Some((p, p_nee))
    }

    /// [`Sample::terms`] from [`Sample::densities`].
    fn terms_weighted(&self, c: f32, densities: Option<(f32, f32)>, mis: MisHeuristic) -> Terms {
        match densities {
            Some((p, p_nee)) => self.terms_with(c, p, p_nee, mis),
            None => self.terms_with(0.0, 0.0, 0.0, mis),
        }
    }

    /// [`Sample::terms`] with the candidate's skeleton densities at the sampled direction and
    /// at the light sample's.
    fn terms_with(&self, c: f32, p_direction: f32, p_nee: f32, mis: MisHeuristic) -> Terms {
        let mut t = Terms::default();
        let q0 = mixture(TRAINING_C, self.p_skel, self.p_bsdf);
        if self.carries() && q0 > 0.0 {
            let q = mixture(c, p_direction, self.p_bsdf);
            let w = if self.p_light > 0.0 {
                mis.weight(q as f32, self.p_light) as f64
            } else {
                1.0
            };
            let f = w * self.f_emitted as f64 + self.f_reflected as f64;
            if f > 0.0 {
                t.mean_direction = f / q0;
                t.second =
                    reweighted_second_moment(f as f32, self.p_bsdf, self.p_skel, p_direction, c);
            }
        }
        if self.nee.value > 0.0 {
            let q = mixture(c, p_nee, self.nee.p_bsdf);
            let w = mis.weight(self.nee.p_light, q as f32) as f64;
            t.mean_nee = self.nee.value as f64 * w;
            t.second += t.mean_nee * t.mean_nee;
        }
        t
    }
}

/// c p_skel + (1 - c) p_bsdf (p_bsdf alone at c = 0, whatever p_skel is).
fn mixture(c: f32, p_skel: f32, p_bsdf: f32) -> f64 {
    let (c, ps, pb) = (c as f64, p_skel as f64, p_bsdf as f64);
    if c > 0.0 {
        c * ps + (1.0 - c) * pb
    } else {
        pb
    }
}

/// Sums of [`Terms`] over a node's samples.
#[derive(Clone, Copy, Debug, Default)]
struct Moments {
    second: f64,
    mean_direction: f64,
    mean_nee: f64,
}

impl Moments {
    fn add(&mut self, t: Terms) {
        self.second += t.second;
        self.mean_direction += t.mean_direction;
        self.mean_nee += t.mean_nee;
    }

    /// Var(N + D) = M_N + M_D - E[N]² - E[D]² (N and D are independent samples), from n
    /// samples.
    fn variance(&self, n: f64) -> f64 {
        let (d, l) = (self.mean_direction / n, self.mean_nee / n);
        (self.second / n - d * d - l * l).max(0.0)
    }
}

/// What the training chose at one node.
#[derive(Clone, Copy, Debug, PartialEq)]
struct NodeChoice {
    /// (c, strength index) if the node is guided (or the fixed c's best strength).
    guided: Option<(f32, usize)>,
    /// The lobes' selection weights chosen, where not eq. 165's.
    weights: Option<[f32; MAX_LOBES]>,
    relative_cost: f32,
    best_ratio: f32,
    /// The estimate's variance per sample unguided and under the choice (the same where the
    /// node is not guided), and the choice's overhead per sample in unguided vertices beyond
    /// an unguided vertex's by the measured costs, the node mapping aside (0 where not
    /// guided).
    variance_unguided: f64,
    variance_chosen: f64,
    overhead: f64,
}

/// The scene-level prediction (module docs, "Measured cost and the scene-level switch") from
/// the node choices, `samples[k]` training samples at node k: variance sum_k n_k V_k under the
/// choices against guiding nothing, cost `vertices` plus the guided samples' overhead plus
/// `map_cost` at each of `mapped_vertices`. Returns (variance ratio, cost ratio).
fn scene_prediction(
    choices: &[NodeChoice],
    samples: &[u32],
    vertices: u64,
    mapped_vertices: u64,
    map_cost: f64,
) -> (f64, f64) {
    let (mut unguided, mut chosen, mut overhead) = (0.0f64, 0.0f64, 0.0f64);
    for (c, &n) in choices.iter().zip(samples) {
        let n = n as f64;
        unguided += n * c.variance_unguided;
        chosen += n * c.variance_chosen;
        overhead += n * c.overhead;
    }
    let variance_ratio = if unguided > 0.0 && unguided.is_finite() {
        chosen / unguided
    } else if unguided.is_infinite() && chosen.is_finite() {
        // Only guiding can sample some contribution: guiding nothing is infinitely worse.
        0.0
    } else {
        1.0
    };
    let base = (vertices as f64).max(1.0);
    let cost_ratio = (base + overhead + map_cost * mapped_vertices as f64) / base;
    (variance_ratio, cost_ratio)
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

/// Runs the training pass for `guide` (whose node probabilities must all be [`TRAINING_C`]
/// and whose strength is the settings' everywhere) and chooses every node's probability and
/// strength (module docs).
/// `pass` numbers the passes of iterative training (0 first; module docs, "Iterative
/// training"): each has its own random streams.
pub(super) fn learn_guiding_probabilities(
    guide: &SkeletonGuide,
    scene: &Scene,
    camera: Option<&Camera>,
    pass: u32,
    history: &mut [Vec<Weighted>],
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
    let per_voxel: Vec<AtomicU32> = (0..guide.grid().len()).map(|_| AtomicU32::new(0)).collect();
    // The path-level prediction's records (module docs, "The path-level prediction").
    let log_paths = settings.cost_model == CostModel::Paths;
    let mut per_chunk: Vec<(Vec<Sample>, u64, PathLog)> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let seed = TRAINING_SEED.wrapping_add(pass as u64 * 0x9e37_79b9_7f4a_7c15);
            let mut rng = Sampler::independent(Rng::new(seed, c as u64));
            let mut query = GuideQuery::new();
            let mut out = Vec::new();
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
    let scene_choice = {
        // The vertices that pay the node mapping under these choices: those in voxels that
        // may map to a guided node (the render's `may_guide`).
        let may_guide = crate::analysis::may_map_to(guide.grid(), guide.node_map(), |n| {
            probabilities[n as usize] > 0.0
        });
        let mapped_vertices = per_voxel
            .iter()
            .zip(&may_guide)
            .filter(|(_, &m)| m)
            .map(|(n, _)| n.load(AtomicOrdering::Relaxed) as u64)
            .sum();
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
    }
}

/// A node's learned directional distribution from its samples (module docs, "Learned
/// directions"), returned as bin probabilities; and, for the choice, each sample's candidate
/// skeleton densities (`p_strength[0]`, at the sampled direction and at its light sample's)
/// replaced by those of the distribution learned from the *other* half of the node's samples
/// (even / odd positions), so that a distribution is never judged on the samples it was fitted
/// to.
///
/// `earlier` are weighted samples of earlier passes at the node (`training_history=all`,
/// module docs, "Iterative training"): each is an unbiased estimate of its bin's integral like
/// this pass's, independent of this pass's samples, so they join both halves and the whole.
/// Also returns this pass's weighted samples. Unless `judged` (a pass whose choices are
/// kept), the halves are not fitted and the samples' densities are left alone.
fn learn_directions(
    samples: &mut [Sample],
    mis: MisHeuristic,
    earlier: &[Weighted],
    floor: f32,
    judged: bool,
) -> (Vec<f32>, Vec<Weighted>) {
    let weight = |s: &Sample| -> f64 {
        let q0 = mixture(TRAINING_C, s.p_skel, s.p_bsdf);
        if !(s.carries() && q0 > 0.0) {
            return 0.0;
        }
        let w = if s.p_light > 0.0 {
            mis.weight(q0 as f32, s.p_light) as f64
        } else {
            1.0
        };
        (w * s.f_emitted as f64 + s.f_reflected as f64) / q0
    };
    let weighted: Vec<Weighted> = samples
        .iter()
        .map(|s| (s.class as usize, s.wi, weight(s)))
        .collect();
    let half = |parity: usize| {
        let part: Vec<Weighted> = earlier
            .iter()
            .copied()
            .chain(
                weighted
                    .iter()
                    .enumerate()
                    .filter(|(i, _)| i % 2 == parity)
                    .map(|(_, &x)| x),
            )
            .collect();
        directional::fit(&part, floor)
    };
    if judged {
        let folds = DirectionalTable::new(&[Some(half(1)), Some(half(0))]);
        for (i, s) in samples.iter_mut().enumerate() {
            // Sample i is judged by the distribution of the other half: node 0 holds the odd
            // samples', node 1 the even ones'.
            let slot = folds
                .slot((i % 2 == 1) as u32, s.class as usize)
                .expect("both halves have distributions");
            s.p_strength[0] = folds.pdf(slot, s.wi);
            s.nee.p_strength[0] = folds.pdf(slot, s.nee.wi);
        }
    }
    let all: Vec<Weighted> = earlier.iter().chain(&weighted).copied().collect();
    (directional::fit(&all, floor), weighted)
}

/// A weighted direction sample of a node's histogram: class, direction, weight.
pub(super) type Weighted = (usize, Vec3, f64);

/// Guide shadow rays per recorded query at a node, counted by the queries themselves.
fn mean_shadow_rays(samples: &[Sample]) -> f64 {
    samples.iter().map(|s| s.rays as f64).sum::<f64>() / samples.len().max(1) as f64
}

/// The choice at one node from its training samples (module docs, "Choice"): the candidate of
/// least variance x cost, kept with `c_skel=learned` only if it beats c = 0 by
/// `significance` standard errors and the node had enough samples.
fn choose_node(
    samples: &[Sample],
    shadow_rays: f64,
    grid: &Grid,
    training_cost: TrainingCost,
    significance: f64,
    min_nonzero: u32,
    mis: MisHeuristic,
) -> NodeChoice {
    let n = samples.len() as f64;
    let unguided_variance = |samples: &[Sample]| {
        let mut m = Moments::default();
        samples
            .iter()
            .for_each(|s| m.add(s.terms(0.0, 0, None, mis)));
        m.variance(n)
    };
    let not_guided = |variance: f64| NodeChoice {
        guided: None,
        weights: None,
        relative_cost: 1.0,
        best_ratio: 1.0,
        variance_unguided: variance,
        variance_chosen: variance,
        overhead: 0.0,
    };
    let carrying = samples.iter().filter(|s| s.carries()).count() as u32;
    if (samples.len() as u32) < MIN_SAMPLES || carrying < min_nonzero {
        return not_guided(if samples.is_empty() {
            0.0
        } else {
            unguided_variance(samples)
        });
    }
    let base = match training_cost {
        TrainingCost::Vertex => 1.0,
        TrainingCost::Path => {
            (samples.iter().map(|s| s.remaining as f64).sum::<f64>() / n).max(1.0)
        }
    };
    // The selection weights to compare: eq. 165's (None) and, with `lobe_weights=learned`,
    // each lobe alone and the fit (module docs, "Lobe weights"), each with the share of the
    // node's samples at which some lobe of positive weight applies (guided there).
    let mut weights: Vec<(Option<[f32; MAX_LOBES]>, f64)> = vec![(None, 1.0)];
    if grid.lobe_weights {
        let seen = samples.iter().fold(0u8, |m, s| m | s.active);
        let lobes = MAX_LOBES - seen.leading_zeros() as usize;
        if lobes >= 2 {
            for j in 0..lobes {
                let mut w = [0.0; MAX_LOBES];
                w[j] = 1.0;
                weights.push((Some(w), 0.0));
            }
            weights.push((Some(fit_lobe_weights(samples, lobes, mis)), 0.0));
        }
        for (w, share) in weights.iter_mut().skip(1) {
            let w = w.as_ref().expect("explicit weights");
            let guided = samples
                .iter()
                .filter(|s| (0..MAX_LOBES).any(|j| s.active & (1 << j) != 0 && w[j] > 0.0))
                .count();
            *share = guided as f64 / n;
        }
    }
    // Cost of a sample at the node, in unguided vertices, where a share of the samples are
    // guided.
    let cost = |c: f32, share: f64| {
        if c <= 0.0 {
            base
        } else {
            base + share * (grid.guided_cost + COST_SHADOW_RAY * shadow_rays)
        }
    };
    // Candidate 0 is c = 0 (not guided); then each grid entry with each weight vector.
    let count = grid.len() * weights.len();
    let candidate = |j: usize| -> (f32, usize, usize) {
        if j == 0 {
            (0.0, 0, 0)
        } else {
            let (c, k) = grid.at((j - 1) % grid.len());
            (c, k, (j - 1) / grid.len())
        }
    };
    let terms = |s: &Sample, j: usize| {
        let (c, k, w) = candidate(j);
        s.terms(c, k, weights[w].0.as_ref(), mis)
    };
    let cost_of = |j: usize| {
        let (c, _, w) = candidate(j);
        cost(c, weights[w].1)
    };
    let mut moments = vec![Moments::default(); count + 1];
    // Each explicit weight vector's densities once per sample, not once per candidate c.
    let mut densities = vec![None; weights.len()];
    for s in samples {
        for (d, (w, _)) in densities.iter_mut().zip(&weights).skip(1) {
            *d = s.densities(w.as_ref().expect("explicit weights"));
        }
        for (j, m) in moments.iter_mut().enumerate() {
            let (c, k, w) = candidate(j);
            m.add(if w == 0 {
                s.terms(c, k, None, mis)
            } else {
                s.terms_weighted(c, densities[w], mis)
            });
        }
    }
    let product = |j: usize| moments[j].variance(n) * cost_of(j);
    let best = (1..=count)
        .min_by(|&a, &b| product(a).total_cmp(&product(b)))
        .expect("at least one candidate");
    let (guided, unguided) = (product(best), product(0));
    let ratio = if unguided > 0.0 && unguided.is_finite() {
        (guided / unguided) as f32
    } else {
        0.0
    };
    let guide_it = if !grid.may_turn_off || !unguided.is_finite() {
        true
    } else {
        // The spread of d_i = cost(c*) m_i(c*) - cost(0) m_i(0), m_i a sample's
        // second-moment term: the difference's dominant noise (the squared means are
        // estimated far more precisely).
        let (cost_c, cost_0) = (cost_of(best), cost_of(0));
        let (mut sum, mut sum2) = (0.0f64, 0.0f64);
        for s in samples {
            let d = cost_c * terms(s, best).second - cost_0 * terms(s, 0).second;
            sum += d;
            sum2 += d * d;
        }
        let mean = sum / n;
        let spread = ((sum2 / n - mean * mean).max(0.0) / n).sqrt();
        guided - unguided + significance * spread < 0.0
    };
    let variance_unguided = moments[0].variance(n);
    if !guide_it {
        return NodeChoice {
            best_ratio: ratio,
            ..not_guided(variance_unguided)
        };
    }
    let (c, k, w) = candidate(best);
    NodeChoice {
        guided: Some((c, k)),
        weights: weights[w].0,
        relative_cost: ratio,
        best_ratio: ratio,
        variance_unguided,
        variance_chosen: moments[best].variance(n),
        // The measured costs whatever the cost model (the scene-level prediction is of the
        // real cost); the node mapping is counted per mapped vertex there.
        overhead: weights[w].1 * (grid.measured.query + COST_SHADOW_RAY * shadow_rays),
    }
}

/// Lobe selection weights for a node's first `lobes` lobes that lower the reweighted second
/// moment of the direction estimate at the training probability (module docs, "Lobe
/// weights"): from equal weights, multiplicative updates
/// w_j <- w_j mean_i[ f_i² p_j(w_i) / (T_i q_i² q0_i) ], normalised (T_i the weight of the lobes
/// that apply at sample i), whose fixed points are the stationary points of the second moment
/// of the unnormalised mixture; weights below `FIT_FLOOR` are then set to 0 (the lobe is
/// dropped). A candidate like any other: the choice judges it by the exact reweighted moments.
fn fit_lobe_weights(samples: &[Sample], lobes: usize, mis: MisHeuristic) -> [f32; MAX_LOBES] {
    let mut w = [0.0f32; MAX_LOBES];
    w[..lobes].fill(1.0 / lobes as f32);
    let c = TRAINING_C as f64;
    for _ in 0..FIT_ITERATIONS {
        let mut acc = [0.0f64; MAX_LOBES];
        for s in samples.iter().filter(|s| s.carries()) {
            let total: f32 = (0..lobes)
                .filter(|&j| s.active & (1 << j) != 0)
                .map(|j| w[j])
                .sum();
            let Some(p_skel) = lobe_mixture(&s.p_lobes, s.active, &w) else {
                continue;
            };
            let q0 = mixture(TRAINING_C, s.p_skel, s.p_bsdf);
            let q = c * p_skel as f64 + (1.0 - c) * s.p_bsdf as f64;
            if !(q > 0.0 && q0 > 0.0) {
                continue;
            }
            let weight = if s.p_light > 0.0 {
                mis.weight(q as f32, s.p_light) as f64
            } else {
                1.0
            };
            let f = weight * s.f_emitted as f64 + s.f_reflected as f64;
            let g = f * f / (q * q * q0) / total as f64;
            for j in 0..lobes {
                if s.active & (1 << j) != 0 {
                    acc[j] += w[j] as f64 * s.p_lobes[j].max(0.0) as f64 * g;
                }
            }
        }
        let sum: f64 = acc.iter().sum();
        if !(sum > 0.0 && sum.is_finite()) {
            break;
        }
        for j in 0..lobes {
            w[j] = (acc[j] / sum) as f32;
        }
    }
    for x in w.iter_mut() {
        if *x < FIT_FLOOR {
            *x = 0.0;
        }
    }
    let sum: f32 = w.iter().sum();
    if sum > 0.0 {
        w.iter_mut().for_each(|x| *x /= sum);
    } else {
        w[..lobes].fill(1.0 / lobes as f32);
    }
    w
}

/// One training sample's term of the reweighted second moment M(c, s) (module docs):
/// f² / (q_c,s q_c0), with q_c0 = c0 p_skel,s0 + (1 - c0) p_bsdf the density the sample was
/// drawn from (`p_proposal` = p_skel,s0) and q_c,s = c p_skel,s + (1 - c) p_bsdf the candidate's
/// (`p_candidate` = p_skel,s). Infinite where the candidate cannot sample a direction that
/// carries f > 0.
pub(crate) fn reweighted_second_moment(
    f: f32,
    p_bsdf: f32,
    p_proposal: f32,
    p_candidate: f32,
    c: f32,
) -> f64 {
    let (f, pb, c, c0) = (f as f64, p_bsdf as f64, c as f64, TRAINING_C as f64);
    if f <= 0.0 {
        return 0.0;
    }
    let q0 = c0 * p_proposal as f64 + (1.0 - c0) * pb;
    let q = c * p_candidate as f64 + (1.0 - c) * pb;
    if q > 0.0 {
        f * f / (q * q0)
    } else {
        f64::INFINITY
    }
}

/// What the training paths visited, for the scene-level prediction: all their vertices, and
/// per voxel of the grid its non-delta ones (where the render maps points to nodes).
struct Visits<'a> {
    vertices: u64,
    per_voxel: &'a [AtomicU32],
}

impl Visits<'_> {
    fn add(&mut self, guide: &SkeletonGuide, p: Vec3) {
        let grid = guide.grid();
        let v = grid.voxel_of(p);
        if (0..3).all(|a| v[a] >= 0 && v[a] < grid.dims[a] as i64) {
            let k = grid.index(v[0] as usize, v[1] as usize, v[2] as usize);
            self.per_voxel[k].fetch_add(1, AtomicOrdering::Relaxed);
        }
    }
}

/// One vertex of a training path, kept until the radiance arriving there is known.
struct TrainingVertex {
    /// The sample, `f_reflected` still to be filled in; None at vertices that are not guided.
    sample: Option<Sample>,
    /// Path throughput up to this vertex, and f_s |cos| / q of its sampled direction.
    beta: Rgb,
    f_cos: Rgb,
    weight: Rgb,
    /// One light sample reflected at the next vertex toward this one (unweighted).
    direct: Rgb,
}

/// One training path from its first hit `si` (module docs), appending the samples of its
/// guided vertices to `out`. The radiance arriving along a vertex's sampled direction is
/// L_e(x') + R(x'), with R the reflected radiance the rest of the path estimates by next-event
/// estimation alone: R(x_i) = NEE(x_i) + f_s |cos| / q (x_i) R(x_i+1) (no emission beyond the
/// first, which NEE accounts for), computed backwards once the path ends. Each vertex's own
/// light sample is also recorded with its sample (the same draw the previous vertex's R uses).
#[allow(clippy::too_many_arguments)]
fn train_path(
    guide: &SkeletonGuide,
    scene: &Scene,
    strengths: &[SkeletonStrength],
    mut si: SurfaceInteraction,
    query: &mut GuideQuery,
    rng: &mut Sampler,
    out: &mut Vec<Sample>,
    visits: &mut Visits<'_>,
    log: Option<&mut PathLog>,
) {
    let mut beta = Rgb::ONE;
    let depth = guide.settings().training_depth;
    let render = &guide.settings().render_estimator;
    let lobe_weights = guide.settings().learned_lobe_weights;
    let mut path: Vec<TrainingVertex> = Vec::with_capacity(depth as usize);
    let mut own_light = light_sample(scene, &si, rng, render);
    let first = own_light
        .as_ref()
        .map_or(0.0, |l| finite_luminance(l.unweighted()));
    for _ in 0..depth {
        let bsdf = scene.bsdf(&si);
        let frame = si.shading_frame();
        let wo_local = frame.to_local(si.wo);
        query.clear();
        let mut rays = 0;
        visits.vertices += 1;
        if !bsdf.is_delta() {
            rays = query.init(guide, scene, si.p, si.p_error, si.ng, si.wo);
            visits.add(guide, si.p);
        }
        let guided = query.guiding_probability() > 0.0;
        let mut nee = NeeTerms::default();
        if let (true, Some(l)) = (guided, &own_light) {
            let value = luminance(beta * l.unweighted());
            if value.is_finite() && value > 0.0 {
                nee = NeeTerms {
                    value,
                    p_light: l.mis_pdf(),
                    wi: l.wi,
                    p_bsdf: bsdf.pdf(wo_local, l.wi_local),
                    p_skel: query.pdf(l.wi),
                    p_strength: strength_pdfs(query, l.wi, strengths),
                    p_lobes: if lobe_weights {
                        query.node_lobe_pdfs(l.wi)
                    } else {
                        [0.0; MAX_LOBES]
                    },
                };
            }
        }
        // Which of the node's lobes apply here (any direction tells: negative where not).
        let active = if guided && lobe_weights {
            query
                .node_lobe_pdfs(si.wo)
                .iter()
                .enumerate()
                .fold(0u8, |m, (j, &p)| if p >= 0.0 { m | (1 << j) } else { m })
        } else {
            0
        };
        let zero = Sample {
            node: query.node().unwrap_or(0),
            wi: Vec3::Z,
            class: directional::class_of(
                if si.ng.dot(si.wo) >= 0.0 {
                    si.ng
                } else {
                    -si.ng
                },
                si.p - query
                    .node()
                    .and_then(|n| guide.node_position(n))
                    .unwrap_or(si.p),
            ) as u8,
            f_emitted: 0.0,
            f_reflected: 0.0,
            p_bsdf: 0.0,
            p_skel: 0.0,
            p_strength: [0.0; MAX_STRENGTHS],
            p_light: 0.0,
            nee,
            p_lobes: [0.0; MAX_LOBES],
            active,
            rays,
            remaining: 1,
            step: NO_STEP,
        };
        let Some(ms) = sample_bsdf_or_guide(&bsdf, wo_local, &frame, query, rng) else {
            if guided {
                out.push(zero);
            }
            break;
        };
        let bs = ms.sample;
        // A delta direction (never at a guided vertex, see `sample_bsdf_or_guide`) has no
        // density to reweight: the path goes on without a sample.
        let guided = guided && !bs.delta;
        let wi = frame.to_world(bs.wi);
        let reflected = bs.wi.z * wo_local.z > 0.0;
        let same_side = wi.dot(si.ng) * si.wo.dot(si.ng) > 0.0;
        if reflected != same_side {
            if guided {
                out.push(zero);
            }
            break;
        }
        let f_cos = bs.f * bs.wi.z.abs();
        let weight = f_cos / bs.pdf;
        let next = scene.intersect(&si.spawn_ray(wi));
        let (emitted, p_light) = arriving_emission(scene, &si, wi, next.as_ref(), render);
        let next_light = next
            .as_ref()
            .and_then(|n| light_sample(scene, n, rng, render));
        let direct = next_light.as_ref().map_or(Rgb::ZERO, |l| l.unweighted());
        path.push(TrainingVertex {
            sample: guided.then(|| {
                let f_emitted = luminance(beta * f_cos * emitted);
                Sample {
                    wi,
                    f_emitted: if f_emitted.is_finite() {
                        f_emitted.max(0.0)
                    } else {
                        0.0
                    },
                    p_bsdf: bsdf.pdf(wo_local, bs.wi),
                    p_skel: query.pdf(wi),
                    p_strength: strength_pdfs(query, wi, strengths),
                    p_lobes: if lobe_weights {
                        query.node_lobe_pdfs(wi)
                    } else {
                        [0.0; MAX_LOBES]
                    },
                    p_light,
                    ..zero
                }
            }),
            beta,
            f_cos,
            weight,
            direct,
        });
        beta *= weight;
        let Some(n) = next else { break };
        if !crate::math::is_finite3(beta) || beta == Rgb::ZERO {
            break;
        }
        si = n;
        own_light = next_light;
    }
    // Backwards. At vertex i: R(x_i+1) = NEE(x_i+1) + tail, tail = f_s |cos| / q (x_i+1)
    // R(x_i+2) (zero beyond the last vertex sampled).
    let mut tail = Rgb::ZERO;
    let len = path.len() as u32;
    let start = if let Some(log) = log {
        let start = log.steps.len() as u32;
        log.steps.extend(path.iter().map(|v| Step {
            after: finite_luminance(v.beta * v.weight * v.direct),
            r_none: 1.0,
            r_chosen: 1.0,
        }));
        log.paths.push(PathRecord { first, start, len });
        Some(start)
    } else {
        None
    };
    for (i, v) in path.iter().enumerate().rev() {
        let reflected = v.direct + tail;
        if let Some(mut sample) = v.sample {
            let f = luminance(v.beta * v.f_cos * reflected);
            sample.f_reflected = if f.is_finite() { f.max(0.0) } else { 0.0 };
            sample.remaining = len - i as u32;
            sample.step = start.map_or(NO_STEP, |s| s + i as u32);
            out.push(sample);
        }
        tail = v.weight * reflected;
        if !crate::math::is_finite3(tail) {
            tail = Rgb::ZERO;
        }
    }
}

/// Luminance, 0 where it is not finite or negative.
fn finite_luminance(x: Rgb) -> f32 {
    let l = luminance(x);
    if l.is_finite() {
        l.max(0.0)
    } else {
        0.0
    }
}

/// The training paths' [`Step`]s and [`PathRecord`]s (module docs, "The path-level
/// prediction").
#[derive(Default)]
struct PathLog {
    steps: Vec<Step>,
    paths: Vec<PathRecord>,
}

/// The path-level ratio of the node choices' second moment to guiding nothing's (module docs,
/// "The path-level prediction"); 1 where it cannot be estimated.
fn path_variance_ratio(log: &PathLog) -> f64 {
    let n = log.paths.len();
    // Each path's term of the two second moments (0 for a path a policy cannot draw).
    let (mut none, mut chosen) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let term = |e: f64, w: f64| {
        if w > 0.0 && w.is_finite() {
            e * e * w
        } else {
            0.0
        }
    };
    for p in &log.paths {
        let steps = &log.steps[p.start as usize..(p.start + p.len) as usize];
        // Per policy: the estimate, the running product of q_0 / q and the path's density
        // ratio q / q_0 over all its directions.
        let (mut e_none, mut prod_none, mut w_none) = (p.first as f64, 1.0f64, 1.0f64);
        let (mut e_chosen, mut prod_chosen, mut w_chosen) = (p.first as f64, 1.0f64, 1.0f64);
        for st in steps {
            prod_none *= st.r_none;
            w_none /= st.r_none;
            e_none += st.after as f64 * prod_none;
            prod_chosen *= st.r_chosen;
            w_chosen /= st.r_chosen;
            e_chosen += st.after as f64 * prod_chosen;
        }
        none.push(term(e_none, w_none));
        chosen.push(term(e_chosen, w_chosen));
    }
    if n == 0 {
        return 1.0;
    }
    // Both policies' terms capped at the same quantile of all terms (module docs: a few
    // paths in 10^5 would otherwise decide).
    let mut pooled: Vec<f64> = none.iter().chain(&chosen).copied().collect();
    let at = ((pooled.len() as f64 * PATH_TERM_QUANTILE) as usize).min(pooled.len() - 1);
    let cap = *pooled.select_nth_unstable_by(at, |a, b| a.total_cmp(b)).1;
    let moment = |terms: &[f64]| terms.iter().map(|t| t.min(cap)).sum::<f64>();
    let (m_none, m_chosen) = (moment(&none), moment(&chosen));
    if m_none > 0.0 && m_none.is_finite() && m_chosen.is_finite() {
        m_chosen / m_none
    } else {
        1.0
    }
}

/// The guide's density at `wi` under each candidate strength.
fn strength_pdfs(
    query: &GuideQuery,
    wi: Vec3,
    strengths: &[SkeletonStrength],
) -> [f32; MAX_STRENGTHS] {
    let mut p = [0.0; MAX_STRENGTHS];
    for (p, &s) in p.iter_mut().zip(strengths) {
        *p = query.pdf_with_strength(wi, s);
    }
    p
}

/// Emitted radiance arriving at `si` along `wi` (L_e of the next vertex `next`, or the
/// environment's), and the density with which the render's light sampling at `si` draws
/// that direction (pmf x pdf, as `path` weighs a BSDF-sampled hit; 0 if it is no light): the
/// render's own densities ([`estimator::emitter_light_pdf`], [`estimator::environment_along`]).
fn arriving_emission(
    scene: &Scene,
    si: &SurfaceInteraction,
    wi: Vec3,
    next: Option<&SurfaceInteraction>,
    render: &RenderEstimator,
) -> (Rgb, f32) {
    match next {
        Some(n) => {
            let le = scene.emitted(n);
            if le == Rgb::ZERO {
                return (le, 0.0);
            }
            (le, estimator::emitter_light_pdf(scene, si.p, n, render))
        }
        None => estimator::environment_along(scene, si.facing_normal(), wi, render)
            .unwrap_or((Rgb::ZERO, 0.0)),
    }
}

/// The render's light sample at `si` ([`estimator::sample_direct_light`]; None where it
/// carries nothing: a delta BSDF, no light, occluded).
fn light_sample(
    scene: &Scene,
    si: &SurfaceInteraction,
    rng: &mut Sampler,
    render: &RenderEstimator,
) -> Option<DirectLight> {
    let bsdf = scene.bsdf(si);
    if bsdf.is_delta() {
        return None;
    }
    let frame = si.shading_frame();
    let u = rng.uniform2();
    let wo_local = frame.to_local(si.wo);
    let mut shadow_rays = 0;
    estimator::sample_direct_light(
        scene,
        si,
        &frame,
        &bsdf,
        wo_local,
        render,
        u,
        &mut shadow_rays,
    )
}
#[cfg(test)]
mod tests {
    use super::*;
    use crate::guide::settings::DEFAULT_TRAINING_MIN_NONZERO as FLOOR;
    use crate::math::{warp, Frame, Vec3};

    /// The reweighted estimate of M(c, s) from samples of the training proposal (c0, s0)
    /// agrees with a brute-force estimate from samples of (c, s) itself, on a toy integrand
    /// over the sphere: a cosine "BSDF" around z, one power-cosine lobe around a tilted axis,
    /// and f peaked off both axes (so neither strategy matches it).
    #[test]
    fn reweighted_second_moment_matches_brute_force() {
        let axis = Vec3::new(0.5, 0.2, 0.8).normalize();
        let peak = Vec3::new(0.7, -0.1, 0.6).normalize();
        let lobe = Frame::from_z(axis);
        let f = |w: Vec3| -> f32 {
            let cos = w.z.max(0.0);
            cos * (0.2 + 30.0 * w.dot(peak).max(0.0).powi(20))
        };
        let p_bsdf = |w: Vec3| warp::cosine_hemisphere_pdf(w);
        let p_skel = |w: Vec3, s: f32| warp::power_cosine_pdf(lobe.to_local(w), s);
        let draw = |rng: &mut Rng, c: f32, s: f32| -> Vec3 {
            if rng.uniform() < c {
                lobe.to_world(warp::power_cosine(rng.uniform2(), s))
            } else {
                warp::cosine_hemisphere(rng.uniform2())
            }
        };
        let s0 = 4.0;
        let n = 400_000;
        let mut rng = Rng::new(5, 1);
        let proposal: Vec<Vec3> = (0..n).map(|_| draw(&mut rng, TRAINING_C, s0)).collect();
        for &(c, s) in &[
            (0.0, 1.0),
            (0.2, 1.0),
            (0.5, 4.0),
            (0.7, 16.0),
            (0.9, 2.0),
            (0.3, 64.0),
        ] {
            let terms: Vec<f64> = proposal
                .iter()
                .map(|&w| reweighted_second_moment(f(w), p_bsdf(w), p_skel(w, s0), p_skel(w, s), c))
                .collect();
            let brute: Vec<f64> = (0..n)
                .map(|_| {
                    let w = draw(&mut rng, c, s);
                    let q = c as f64 * p_skel(w, s) as f64 + (1.0 - c as f64) * p_bsdf(w) as f64;
                    if f(w) > 0.0 {
                        (f(w) as f64 / q).powi(2)
                    } else {
                        0.0
                    }
                })
                .collect();
            let stats = |v: &[f64]| {
                let m = v.iter().sum::<f64>() / v.len() as f64;
                let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64;
                (m, var / v.len() as f64)
            };
            let ((a, va), (b, vb)) = (stats(&terms), stats(&brute));
            let z = (a - b) / (va + vb).sqrt();
            assert!(a.is_finite() && b > 0.0, "c {c} s {s}: {a} {b}");
            assert!(
                z.abs() < 4.0,
                "c {c} s {s}: reweighted {a}, brute force {b}, z {z}"
            );
        }
    }

    #[test]
    fn second_moment_is_infinite_where_the_candidate_misses() {
        // f > 0 where the BSDF has no density: only c > 0 with lobe density reaches it.
        assert_eq!(
            reweighted_second_moment(1.0, 0.0, 1.0, 0.0, 0.5),
            f64::INFINITY
        );
        assert_eq!(
            reweighted_second_moment(1.0, 0.0, 1.0, 1.0, 0.0),
            f64::INFINITY
        );
        assert!(reweighted_second_moment(1.0, 0.0, 1.0, 2.0, 0.5).is_finite());
        assert_eq!(reweighted_second_moment(0.0, 0.0, 0.0, 0.0, 0.5), 0.0);
    }

    /// Synthetic training samples at one node: a cosine "BSDF" (albedo 1) around z, one
    /// power-cosine lobe (strength 64) aimed at a small cone of directions (cos >= 0.99) from
    /// which radiance 10 arrives, drawn from the training proposal q_c0. `light` says whether
    /// that radiance is an emitter the render's light sampling draws uniformly in the cone
    /// (with one light sample per vertex recorded), or light reflected there (R).
    fn cone_node(light: bool, n: usize) -> Vec<Sample> {
        let axis = Vec3::new(0.3, 0.0, 0.95).normalize();
        let lobe = Frame::from_z(axis);
        let (s0, cos_max, radiance) = (64.0, 0.99f32, 10.0f32);
        let p_cone = warp::uniform_cone_pdf(Vec3::new(0.0, 0.0, 1.0), cos_max);
        let p_skel = |w: Vec3| warp::power_cosine_pdf(lobe.to_local(w), s0);
        let in_cone = |w: Vec3| w.dot(axis) >= cos_max;
        let mut rng = Rng::new(11, 3);
        (0..n)
            .map(|_| {
                let w = if rng.uniform() < TRAINING_C {
                    lobe.to_world(warp::power_cosine(rng.uniform2(), s0))
                } else {
                    warp::cosine_hemisphere(rng.uniform2())
                };
                let f = if in_cone(w) && w.z > 0.0 {
                    w.z / std::f32::consts::PI * radiance
                } else {
                    0.0
                };
                let nee = if light {
                    let wl = lobe.to_world(warp::uniform_cone(rng.uniform2(), cos_max));
                    NeeTerms {
                        value: wl.z.max(0.0) / std::f32::consts::PI * radiance / p_cone,
                        p_light: p_cone,
                        wi: wl,
                        p_bsdf: warp::cosine_hemisphere_pdf(wl),
                        p_skel: p_skel(wl),
                        p_strength: [p_skel(wl); MAX_STRENGTHS],
                        p_lobes: [0.0; MAX_LOBES],
                    }
                } else {
                    NeeTerms::default()
                };
                Sample {
                    node: 0,
                    wi: w,
                    class: 0,
                    f_emitted: if light { f } else { 0.0 },
                    f_reflected: if light { 0.0 } else { f },
                    p_bsdf: warp::cosine_hemisphere_pdf(w),
                    p_skel: p_skel(w),
                    p_strength: [p_skel(w); MAX_STRENGTHS],
                    p_light: if light && f > 0.0 { p_cone } else { 0.0 },
                    nee,
                    p_lobes: [0.0; MAX_LOBES],
                    active: 1,
                    rays: 1,
                    remaining: 1,
                    step: NO_STEP,
                }
            })
            .collect()
    }

    /// The scene-level prediction weighs each node's variance change by its samples against
    /// the whole variance (guided or not), and charges the guided samples' overhead and the
    /// mapping of every mapped vertex against all vertices: a node that halves its own
    /// variance pays where it carries the image's variance, not where an unguided node carries
    /// most of it, nor where the mapping reaches many vertices.
    #[test]
    fn the_scene_level_switch_weighs_gain_against_all_overhead() {
        let node = |v0: f64, v1: f64, overhead: f64| NodeChoice {
            guided: (overhead > 0.0).then_some((0.5, 0)),
            weights: None,
            relative_cost: 1.0,
            best_ratio: 1.0,
            variance_unguided: v0,
            variance_chosen: v1,
            overhead,
        };
        let scene = |choices: &[NodeChoice], samples: &[u32], mapped: u64| {
            let (variance_ratio, cost_ratio) =
                scene_prediction(choices, samples, 1000, mapped, 0.1);
            SceneChoice {
                variance_ratio,
                cost_ratio,
                ..SceneChoice::default()
            }
        };
        // Node 0 (guided) halves its variance at 0.5 vertices per sample; node 1 is not
        // guided. 100 samples each, 1000 vertices.
        let guided = node(1.0, 0.5, 0.5);
        let s = scene(&[guided, node(1.0, 1.0, 0.0)], &[100, 100], 200);
        assert!((s.variance_ratio - 150.0 / 200.0).abs() < 1e-12);
        assert!((s.cost_ratio - (1000.0 + 50.0 + 20.0) / 1000.0).abs() < 1e-12);
        assert!(s.pays(), "{}", s.efficiency());
        // Where the unguided node carries 9x the variance, the same node gains 5 %: no.
        let s = scene(&[guided, node(9.0, 9.0, 0.0)], &[100, 100], 200);
        assert!((s.variance_ratio - 9.5 / 10.0).abs() < 1e-12);
        assert!(!s.pays(), "{}", s.efficiency());
        // Mapping 4000 vertex visits (0.1 vertices each: 400 in all) eats the gain.
        let s = scene(&[guided, node(1.0, 1.0, 0.0)], &[100, 100], 4000);
        assert!(!s.pays(), "{}", s.efficiency());
        // Nothing guided: ratios 1, does not pay (nothing to switch off either).
        let s = scene(&[node(1.0, 1.0, 0.0)], &[100], 0);
        assert_eq!((s.variance_ratio, s.cost_ratio), (1.0, 1.0));
        assert!(!s.pays());
        // A contribution only guiding samples (infinite unguided variance) always pays.
        let s = scene(&[node(f64::INFINITY, 1.0, 0.5)], &[100], 5000);
        assert!(s.pays());
    }

    /// The scene-level prediction charges what the render's directions cost: the learned
    /// histograms' query (no set-up, no shadow ray) is cheaper than the lobes'.
    /// A camera path of one direction toward two equally probable outcomes under the training
    /// proposal: A carries f = 1 (its step's `after` is f / q_0 = 2), B nothing. A policy that
    /// draws A with probability a has second moment 1 / a; the path-level prediction is exact
    /// on equal numbers of A and B paths, and each policy's weights q_0 / q enter it.
    #[test]
    fn the_path_level_prediction_is_the_ratio_of_second_moments() {
        let (a_none, a_chosen) = (0.2f64, 0.8f64);
        let mut log = PathLog::default();
        for i in 0..2000u32 {
            let carries = i % 2 == 0;
            let step = if carries {
                Step {
                    after: 2.0,
                    r_none: 0.5 / a_none,
                    r_chosen: 0.5 / a_chosen,
                }
            } else {
                Step {
                    after: 0.0,
                    r_none: 0.5 / (1.0 - a_none),
                    r_chosen: 0.5 / (1.0 - a_chosen),
                }
            };
            log.paths.push(PathRecord {
                first: 0.0,
                start: log.steps.len() as u32,
                len: 1,
            });
            log.steps.push(step);
        }
        let ratio = path_variance_ratio(&log);
        assert!((ratio - a_none / a_chosen).abs() < 1e-9, "{ratio}");
        // Swapping the policies inverts it; equal policies give 1.
        for st in &mut log.steps {
            std::mem::swap(&mut st.r_none, &mut st.r_chosen);
        }
        assert!((path_variance_ratio(&log) - a_chosen / a_none).abs() < 1e-9);
        for st in &mut log.steps {
            st.r_chosen = st.r_none;
        }
        assert_eq!(path_variance_ratio(&log), 1.0);
        // A second vertex's light sample is weighted by the first direction's ratio.
        let mut two = PathLog::default();
        two.paths.push(PathRecord {
            first: 1.0,
            start: 0,
            len: 2,
        });
        two.steps.push(Step {
            after: 0.0,
            r_none: 2.0,
            r_chosen: 1.0,
        });
        two.steps.push(Step {
            after: 1.0,
            r_none: 1.0,
            r_chosen: 1.0,
        });
        // none: e = 1 + 1 x 2 = 3, w = 1 / 2: 4.5; chosen: e = 2, w = 1: 4.
        assert!((path_variance_ratio(&two) - 4.0 / 4.5).abs() < 1e-12);
    }

    #[test]
    fn measured_costs_follow_the_directions() {
        let mut s = crate::guide::SkeletonGuideSettings::default();
        assert!(s.learned_directions);
        assert_eq!(MeasuredCosts::of(&s), LEARNED_COSTS);
        s.set("directions", "lobes").unwrap();
        assert_eq!(MeasuredCosts::of(&s), LOBE_COSTS);
        const { assert!(LEARNED_COSTS.query < LOBE_COSTS.query) };
    }

    /// Every candidate c > 0 at one fixed strength, with c = 0 allowed to win.
    fn one_strength_grid() -> Grid {
        Grid {
            c: CANDIDATES[1..].to_vec(),
            strengths: vec![SkeletonStrength::Fixed(64.0)],
            may_turn_off: true,
            lobe_weights: false,
            guided_cost: crate::guide::settings::DEFAULT_TRAINING_GUIDED_COST as f64,
            measured: LOBE_COSTS,
        }
    }

    /// The choice judges the render's estimator: guiding toward light that next-event
    /// estimation already samples well (MIS-weighted hits, the vertex's own light sample)
    /// does not pay and is turned off; the same radiance arriving as reflected light, which
    /// only direction sampling finds, is guided. Judged by the unweighted emission alone (no
    /// light density, no light sample), the first node would be guided too.
    #[test]
    fn choice_does_not_guide_toward_light_that_light_sampling_covers() {
        let grid = one_strength_grid();
        let choose = |samples: &[Sample]| {
            choose_node(
                samples,
                mean_shadow_rays(samples),
                &grid,
                TrainingCost::Path,
                1.0,
                FLOOR,
                MisHeuristic::Power,
            )
        };
        let lit = cone_node(true, 20_000);
        let covered = choose(&lit);
        assert_eq!(covered.guided, None, "{covered:?}");
        assert!(covered.best_ratio > 1.0, "{covered:?}");

        let unweighted: Vec<Sample> = lit
            .iter()
            .map(|s| Sample {
                p_light: 0.0,
                nee: NeeTerms::default(),
                ..*s
            })
            .collect();
        let naive = choose(&unweighted);
        assert!(matches!(naive.guided, Some((c, 0)) if c > 0.0), "{naive:?}");

        let reflected = choose(&cone_node(false, 20_000));
        assert!(
            matches!(reflected.guided, Some((c, 0)) if c >= 0.5),
            "{reflected:?}"
        );
        assert!(reflected.relative_cost < 0.2, "{reflected:?}");
    }

    /// `directions=learned` on the reflected cone: the learned distribution puts its density
    /// in the cone (the bin of its axis far above the uniform 1 / 4 pi, a direction away from
    /// it at the floor), each sample's candidate density is the other half's, and the choice
    /// guides with it (the cone is 0.6 % of the sphere: the histogram's 15-degree bins and its
    /// floor lose to the s = 64 lobe aimed at it, but still beat BSDF sampling by far).
    #[test]
    fn learned_directions_find_the_cone_and_are_chosen() {
        let mut samples = cone_node(false, 20_000);
        let (bins, _) = learn_directions(
            &mut samples,
            MisHeuristic::Power,
            &[],
            directional::FLOOR,
            true,
        );
        let table = DirectionalTable::new(&[Some(bins)]);
        let axis = Vec3::new(0.3, 0.0, 0.95).normalize();
        let uniform = 1.0 / (4.0 * std::f32::consts::PI);
        let slot = table.slot(0, 0).unwrap();
        assert!(
            table.pdf(slot, axis) > 20.0 * uniform,
            "{}",
            table.pdf(slot, axis)
        );
        let away = Vec3::new(-0.9, 0.3, 0.1).normalize();
        let floor = directional::FLOOR * uniform;
        assert!((table.pdf(slot, away) - floor).abs() < 1e-3 * floor);
        // The candidate densities were replaced (the lobe's s = 64 density is far larger in
        // the cone, far smaller away from it).
        assert!(samples
            .iter()
            .all(|s| s.p_strength[0] > 0.0 && s.p_strength[0] < 100.0));
        let choice = choose_node(
            &samples,
            0.0,
            &one_strength_grid(),
            TrainingCost::Path,
            1.0,
            FLOOR,
            MisHeuristic::Power,
        );
        assert!(
            matches!(choice.guided, Some((c, 0)) if c >= 0.3),
            "{choice:?}"
        );
        assert!(choice.relative_cost < 0.5, "{choice:?}");
    }

    /// Too few samples, or too few that carry anything: not guided, whatever they say.
    #[test]
    fn nodes_with_few_samples_are_not_guided() {
        let grid = one_strength_grid();
        let few = cone_node(false, MIN_SAMPLES as usize - 1);
        assert_eq!(
            choose_node(
                &few,
                mean_shadow_rays(&few),
                &grid,
                TrainingCost::Path,
                1.0,
                FLOOR,
                MisHeuristic::Power
            )
            .guided,
            None
        );
        let many = cone_node(false, 4 * MIN_SAMPLES as usize);
        assert!(choose_node(
            &many,
            mean_shadow_rays(&many),
            &grid,
            TrainingCost::Path,
            1.0,
            FLOOR,
            MisHeuristic::Power
        )
        .guided
        .is_some());
    }

    /// `training_min_nonzero` counts the samples that carry anything: a node just below the
    /// floor is not guided, the same node at the floor is.
    #[test]
    fn min_nonzero_floor_counts_carrying_samples() {
        let grid = one_strength_grid();
        let node = cone_node(false, 4 * MIN_SAMPLES as usize);
        let carrying = node.iter().filter(|s| s.carries()).count() as u32;
        assert!(
            carrying > FLOOR && (carrying as usize) < node.len(),
            "{carrying}"
        );
        let choose = |floor: u32| {
            choose_node(
                &node,
                mean_shadow_rays(&node),
                &grid,
                TrainingCost::Path,
                1.0,
                floor,
                MisHeuristic::Power,
            )
            .guided
        };
        assert!(choose(carrying).is_some());
        assert_eq!(choose(carrying + 1), None);
    }

    /// Synthetic samples at a node with two lobes: lobe 0 (strength 64) aimed at a small cone
    /// from which reflected radiance 10 arrives, lobe 1 (strength 8) aimed away from it, with
    /// eq. 165-like proposal weights that favour lobe 1 (0.2, 0.8). At every fourth point
    /// lobe 0 does not apply (its opening hidden): there the proposal is lobe 1 alone.
    fn two_lobe_node(n: usize) -> Vec<Sample> {
        let toward = Vec3::new(0.3, 0.0, 0.95).normalize();
        let away = Vec3::new(-0.6, 0.5, 0.6).normalize();
        let (frames, strengths) = ([Frame::from_z(toward), Frame::from_z(away)], [64.0, 8.0]);
        let proposal = [0.2f32, 0.8];
        let lobe_pdf =
            |j: usize, w: Vec3| warp::power_cosine_pdf(frames[j].to_local(w), strengths[j]);
        let mut rng = Rng::new(23, 7);
        (0..n)
            .map(|i| {
                let active: u8 = if i % 4 == 3 { 0b10 } else { 0b11 };
                let weights = if active == 0b11 { proposal } else { [0.0, 1.0] };
                let p_skel = |w: Vec3| weights[0] * lobe_pdf(0, w) + weights[1] * lobe_pdf(1, w);
                let w = if rng.uniform() < TRAINING_C {
                    let j = if rng.uniform() < weights[0] { 0 } else { 1 };
                    frames[j].to_world(warp::power_cosine(rng.uniform2(), strengths[j]))
                } else {
                    warp::cosine_hemisphere(rng.uniform2())
                };
                let f = if w.dot(toward) >= 0.99 && w.z > 0.0 {
                    w.z / std::f32::consts::PI * 10.0
                } else {
                    0.0
                };
                let mut p_lobes = [-1.0; MAX_LOBES];
                for j in 0..2 {
                    if active & (1 << j) != 0 {
                        p_lobes[j] = lobe_pdf(j, w);
                    }
                }
                Sample {
                    node: 0,
                    wi: w,
                    class: 0,
                    f_emitted: 0.0,
                    f_reflected: f,
                    p_bsdf: warp::cosine_hemisphere_pdf(w),
                    p_skel: p_skel(w),
                    p_strength: [p_skel(w); MAX_STRENGTHS],
                    p_light: 0.0,
                    nee: NeeTerms::default(),
                    p_lobes,
                    active,
                    rays: 1,
                    remaining: 1,
                    step: NO_STEP,
                }
            })
            .collect()
    }

    /// The lobe mixture under explicit weights is the mixture the samples record when the
    /// weights are the proposal's, renormalised over the lobes that apply at each point.
    #[test]
    fn lobe_weights_reproduce_the_recorded_mixture() {
        let samples = two_lobe_node(4000);
        let proposal = {
            let mut w = [0.0; MAX_LOBES];
            w[..2].copy_from_slice(&[0.2, 0.8]);
            w
        };
        let mut hidden = 0;
        for s in &samples {
            let p = lobe_mixture(&s.p_lobes, s.active, &proposal).unwrap();
            assert!(
                (p - s.p_skel).abs() <= 1e-5 * s.p_skel.max(1.0),
                "{p} {}",
                s.p_skel
            );
            for c in [0.1, 0.5, 0.9] {
                let (a, b) = (
                    s.terms(c, 0, Some(&proposal), MisHeuristic::Power),
                    s.terms(c, 0, None, MisHeuristic::Power),
                );
                assert!(
                    (a.second - b.second).abs() <= 1e-4 * b.second.max(1e-9),
                    "{a:?} {b:?}"
                );
            }
            // Lobe 0 alone: the points where it does not apply are not guided.
            let mut only0 = [0.0; MAX_LOBES];
            only0[0] = 1.0;
            if s.active & 1 == 0 {
                hidden += 1;
                assert_eq!(lobe_mixture(&s.p_lobes, s.active, &only0), None);
            }
        }
        assert_eq!(hidden, 1000);
    }

    /// With `lobe_weights=learned` the choice moves the selection probability onto the lobe
    /// the radiance arrives through and guides the node, which with the proposal's (eq.
    /// 165's) weights does not pay; the fit alone finds the same lobe.
    #[test]
    fn learned_lobe_weights_pick_the_lobe_that_carries_the_light() {
        let samples = two_lobe_node(40_000);
        let choose = |lobe_weights: bool| {
            let grid = Grid {
                lobe_weights,
                ..one_strength_grid()
            };
            choose_node(
                &samples,
                mean_shadow_rays(&samples),
                &grid,
                TrainingCost::Path,
                1.0,
                FLOOR,
                MisHeuristic::Power,
            )
        };
        let fixed = choose(false);
        let learned = choose(true);
        assert!(
            fixed.guided.is_none() && fixed.best_ratio > 0.95,
            "{fixed:?}"
        );
        let w = learned.weights.expect("weights learned");
        assert!(learned.guided.is_some(), "{learned:?}");
        assert!(w[0] > 0.9 && w[1] < 0.1, "{learned:?}");
        assert!(
            learned.relative_cost < 0.8 * fixed.best_ratio,
            "{learned:?}"
        );
        let fit = fit_lobe_weights(&samples, 2, MisHeuristic::Power);
        assert!(
            fit[0] > 0.9 && (fit[0] + fit[1] - 1.0).abs() < 1e-6,
            "{fit:?}"
        );
        assert!(fit[2..].iter().all(|&x| x == 0.0), "{fit:?}");
    }
}
