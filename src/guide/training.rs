//! `c_skel=learned`: the probability of sampling the skeleton lobes, chosen per node from a
//! training pass (issue 8: "learned per node from accumulated contributions").
//!
//! # Training pass
//!
//! `TRAINING_PATHS` camera paths from the scene's camera (film and lens positions uniform over
//! a 2:1 image),
//! each at most `TRAINING_DEPTH` vertices deep, sample every guided vertex x (a non-delta BSDF
//! whose node has lobes there) from the one-sample mixture at the training probability
//! `c0 = TRAINING_C`, density `q_c0 = c0 p_skel + (1 - c0) p_bsdf`, like `path_skeleton`
//! does. Each such vertex records for its node one sample of the contribution proxy
//!
//!   f = lum( beta (x) f_s(x, wo, wi) |cos| (x) L(wi) ),
//!   L(wi) = L_e(x') + R(x'),  R(x_j) = NEE(x_j) + f_s |cos| / q (x_j) R(x_j+1),
//!
//! with x' the next vertex along wi, R the radiance the rest of the training path reflects
//! toward x estimated by unweighted next-event estimation at each later vertex (the corridor's
//! light arrives after several bounces: a one-bounce proxy sees nothing there), and beta the
//! path throughput up to x (a vertex reached with a large throughput weighs more in the
//! pixel's variance), together with the two
//! densities p_bsdf(wi) and p_skel(wi). The work is cut into fixed chunks with their own
//! random streams and the samples are concatenated in chunk order, so the result is the same
//! for any thread count.
//!
//! # Estimator (derivation)
//!
//! At a node, the one-sample MIS estimator of the integral I = ∫ f dw with guiding
//! probability c is F_c = f(w) / q_c(w), w ~ q_c, q_c = c p_skel + (1 - c) p_bsdf. Its second
//! moment is
//!
//!   M(c) = E_{q_c}[f² / q_c²] = ∫ f² / q_c dw = E_{q_c0}[ f² / (q_c q_c0) ]
//!
//! (importance reweighting: the last expectation is over the training samples, drawn from
//! q_c0), so every candidate c is evaluated from the same samples, unbiasedly, by the mean of
//! f_i² / (q_c(w_i) q_c0(w_i)). The mean I is the same for all c, estimated by the mean of
//! f_i / q_c0(w_i), and the variance is V(c) = M(c) - I². The efficiency to maximise is
//! 1 / (V(c) cost(c)); cost is in units of one unguided path vertex (a continuation ray, a
//! shadow ray, shading): cost(0) = 1 and cost(c > 0) = 1 + `COST_GUIDED` + `COST_SHADOW_RAY`
//! x (the guide's shadow rays per query at this node, counted in training). The constants
//! come from the round-3 profile of the door (callgrind: ~5,500 instructions per `path`
//! vertex, ~1,400 per guide shadow ray, ~600 for the lobe set-up per query plus the lobe
//! densities in the MIS weights); the node mapping is paid at c = 0 too (the node must be
//! known to know its c), so it is not part of the difference. A c with f² / q_c infinite
//! (p_bsdf = 0 where f > 0 makes BSDF sampling alone miss contributions) has M = inf.
//!
//! The node gets c* = argmin over c > 0 of V(c) cost(c) only if guiding is *measurably*
//! better than not guiding: with d_i = f_i² / (q_c0 q_c*) cost(c*) - f_i² / (q_c0 p_bsdf),
//! the efficiency difference is V(c*) cost(c*) - V(0) = mean(d) - I² (cost(c*) - 1), and
//! it must be below zero by two standard errors of mean(d); and the node must have had at
//! least `MIN_SAMPLES` training samples, `MIN_NONZERO` of them non-zero. Otherwise c = 0:
//! the node is not guided at all (no lobes, no shadow rays). The floor is there because M is
//! a mean of squares, dominated by rare large samples: with a few dozen non-zero samples the
//! standard error itself is not to be trusted, and a wrong "guide" costs 1.2-2x per vertex
//! while a wrong "do not guide" only forgoes a gain. Nodes no training path reaches are not
//! guided for the same reason. Whatever the chosen c, the render stays unbiased: c is a
//! deterministic function of the scene, and every density `path_skeleton` uses is the
//! mixture's at that c.
//!
//! Heuristic parts, stated: the proxy stops after `TRAINING_DEPTH` vertices (light arriving
//! after more bounces does not inform the choice), R carries the training path's own noise
//! (it adds to M(c) equally for every c, a common floor, not a bias between candidates), and
//! each vertex is judged as if it were the whole
//! sample (a vertex's guiding overhead is a smaller share of a long path's cost, but so is
//! its variance of the pixel's).

use rayon::prelude::*;

use super::{sample_bsdf_or_guide, GuideQuery, SkeletonGuide};
use crate::light::{EnvStrategy, TriangleSampling};
use crate::math::{luminance, Rgb, Rng, Sampler};
use crate::scene::{Scene, SurfaceInteraction};

/// Guiding probability of the training pass (c0 above): both strategies get half the samples,
/// so the reweighting factor q_c0 / q_c is at most 2 for any c.
pub const TRAINING_C: f32 = 0.5;
/// The candidate probabilities (c = 0 is "not guided").
pub const CANDIDATES: [f32; 11] = [0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9];
/// Camera paths of the training pass (a fixed budget: about 0.1-0.3 s on two cores).
const TRAINING_PATHS: u32 = 1 << 15;
/// Camera paths per chunk (the fixed work partition).
const CHUNK: u32 = 1024;
/// Vertices per training path.
const TRAINING_DEPTH: u32 = 5;
/// Training samples a node needs before it may be guided, and how many must be non-zero.
const MIN_SAMPLES: u32 = 256;
const MIN_NONZERO: u32 = 32;
/// Cost of guiding at a vertex beyond an unguided vertex's (1), without shadow rays, and per
/// guide shadow ray (module docs).
const COST_GUIDED: f64 = 0.15;
const COST_SHADOW_RAY: f64 = 0.25;
/// Standard errors by which guiding must beat not guiding.
const SIGNIFICANCE: f64 = 2.0;
/// Width / height of the training pass's image.
const TRAINING_ASPECT: f32 = 2.0;
const TRAINING_SEED: u64 = 0x7ea1_c5e1;

/// What the training pass found.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainingReport {
    /// The learned guiding probability of each node (one of [`CANDIDATES`]).
    pub probabilities: Vec<f32>,
    /// Training samples recorded per node.
    pub samples: Vec<u32>,
    /// Per node, the estimated variance x cost of the chosen c relative to not guiding
    /// (below 1: guiding is better; 1 for nodes not guided, also where that ratio would
    /// have been below 1 without being significant).
    pub relative_cost: Vec<f32>,
    /// Camera paths traced (0 when the scene has no camera: then no node is guided).
    pub paths: u32,
}

impl TrainingReport {
    /// Nodes with a learned probability above 0.
    pub fn guided_nodes(&self) -> usize {
        self.probabilities.iter().filter(|&&c| c > 0.0).count()
    }
}

/// One training sample at a guided vertex.
#[derive(Clone, Copy, Debug)]
struct Sample {
    node: u32,
    /// The contribution proxy f (module docs); 0 for directions that carry nothing.
    f: f32,
    p_bsdf: f32,
    p_skel: f32,
    /// Shadow rays the guide traced for this vertex's query.
    rays: u32,
}

/// Per-node sums over the training samples.
#[derive(Clone, Copy, Default)]
struct NodeSums {
    n: u32,
    nonzero: u32,
    rays: u64,
    /// Sum of f / q_c0.
    mean: f64,
    /// Per candidate: sum of f² / (q_c q_c0).
    second: [f64; CANDIDATES.len()],
    /// Samples with f > 0 and p_bsdf = 0 (M(0) infinite).
    bsdf_misses: u32,
}

/// Runs the training pass for `guide` (whose node probabilities must all be [`TRAINING_C`])
/// and chooses every node's probability (module docs).
pub(super) fn learn_guiding_probabilities(guide: &SkeletonGuide, scene: &Scene) -> TrainingReport {
    let nodes = guide.node_count();
    let Some(camera) = scene.camera() else {
        return TrainingReport {
            probabilities: vec![0.0; nodes],
            samples: vec![0; nodes],
            relative_cost: vec![1.0; nodes],
            paths: 0,
        };
    };
    // The render's image size is not known here: a 2:1 frame covers the scene files' images
    // (2:1 and 1:1) and more; training nodes outside the view costs samples, not bias.
    let camera = camera.frame(TRAINING_ASPECT);
    let chunks = TRAINING_PATHS.div_ceil(CHUNK);
    let per_chunk: Vec<Vec<Sample>> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let mut rng = Sampler::independent(Rng::new(TRAINING_SEED, c as u64));
            let mut query = GuideQuery::new();
            let mut out = Vec::new();
            for _ in 0..CHUNK.min(TRAINING_PATHS - c * CHUNK) {
                let ray = camera.generate_ray(rng.uniform2(), rng.uniform2());
                if let Some(si) = scene.intersect(&ray) {
                    train_path(guide, scene, si, &mut query, &mut rng, &mut out);
                }
            }
            out
        })
        .collect();

    let c0 = TRAINING_C as f64;
    let mut sums = vec![NodeSums::default(); nodes];
    for s in per_chunk.iter().flatten() {
        let acc = &mut sums[s.node as usize];
        acc.n += 1;
        acc.rays += s.rays as u64;
        if s.f <= 0.0 {
            continue;
        }
        let (f, pb, ps) = (s.f as f64, s.p_bsdf as f64, s.p_skel as f64);
        let q0 = c0 * ps + (1.0 - c0) * pb;
        acc.nonzero += 1;
        acc.mean += f / q0;
        if pb <= 0.0 {
            acc.bsdf_misses += 1;
        }
        for (m, &c) in acc.second.iter_mut().zip(&CANDIDATES) {
            let q = c as f64 * ps + (1.0 - c as f64) * pb;
            *m += if q > 0.0 {
                f * f / (q * q0)
            } else {
                f64::INFINITY
            };
        }
    }

    // The significance test needs the spread of d_i for the chosen c: a second pass over the
    // samples of the nodes that got one (the sums above fix c* first).
    let cost = |acc: &NodeSums, c: f32| -> f64 {
        if c <= 0.0 {
            1.0
        } else {
            let rays = acc.rays as f64 / acc.n.max(1) as f64;
            1.0 + COST_GUIDED + COST_SHADOW_RAY * rays
        }
    };
    let mut chosen = vec![0usize; nodes];
    let mut efficiency = vec![(0.0f64, 0.0f64); nodes];
    for (k, acc) in sums.iter().enumerate() {
        if acc.n < MIN_SAMPLES || acc.nonzero < MIN_NONZERO {
            continue;
        }
        let n = acc.n as f64;
        let mean2 = (acc.mean / n).powi(2);
        let product = |j: usize| (acc.second[j] / n - mean2).max(0.0) * cost(acc, CANDIDATES[j]);
        let best = (1..CANDIDATES.len())
            .min_by(|&a, &b| product(a).total_cmp(&product(b)))
            .expect("candidates beyond 0");
        chosen[k] = best;
        efficiency[k] = (product(best), product(0));
    }
    // d_i = f² / (q_c0 q_c*) cost(c*) - f² / (q_c0 p_bsdf): sum and sum of squares.
    let mut d_sums = vec![(0.0f64, 0.0f64); nodes];
    for s in per_chunk.iter().flatten() {
        let k = s.node as usize;
        let j = chosen[k];
        if j == 0 || s.f <= 0.0 || sums[k].bsdf_misses > 0 {
            continue;
        }
        let (f, pb, ps) = (s.f as f64, s.p_bsdf as f64, s.p_skel as f64);
        let q0 = c0 * ps + (1.0 - c0) * pb;
        let c = CANDIDATES[j] as f64;
        let q = c * ps + (1.0 - c) * pb;
        let d = f * f / q0 * (cost(&sums[k], CANDIDATES[j]) / q - 1.0 / pb);
        d_sums[k].0 += d;
        d_sums[k].1 += d * d;
    }

    let mut probabilities = vec![0.0f32; nodes];
    let mut relative_cost = vec![1.0f32; nodes];
    for k in 0..nodes {
        let j = chosen[k];
        if j == 0 {
            continue;
        }
        let acc = &sums[k];
        let guide_it = if acc.bsdf_misses > 0 {
            true
        } else {
            let n = acc.n as f64;
            let mean_d = d_sums[k].0 / n;
            let var_d = (d_sums[k].1 / n - mean_d * mean_d).max(0.0);
            let mean2 = (acc.mean / n).powi(2);
            let difference = mean_d - mean2 * (cost(acc, CANDIDATES[j]) - 1.0);
            difference + SIGNIFICANCE * (var_d / n).sqrt() < 0.0
        };
        if guide_it {
            probabilities[k] = CANDIDATES[j];
            let (guided, unguided) = efficiency[k];
            relative_cost[k] = if unguided > 0.0 && unguided.is_finite() {
                (guided / unguided) as f32
            } else {
                0.0
            };
        }
    }
    TrainingReport {
        probabilities,
        samples: sums.iter().map(|s| s.n).collect(),
        relative_cost,
        paths: TRAINING_PATHS,
    }
}

/// One vertex of a training path, kept until the radiance arriving there is known.
struct TrainingVertex {
    /// The sample, `f` still to be filled in; None at vertices that are not guided.
    sample: Option<Sample>,
    /// Path throughput up to this vertex, and f_s |cos| / q of its sampled direction.
    beta: Rgb,
    f_cos: Rgb,
    weight: Rgb,
    /// Emitted radiance arriving along the sampled direction (L_e at the next vertex, or the
    /// environment's), and one light sample reflected at the next vertex toward this one.
    emitted: Rgb,
    direct: Rgb,
}

/// One training path from its first hit `si` (module docs), appending the samples of its
/// guided vertices to `out`. The radiance arriving along a vertex's sampled direction is
/// L_e(x') + R(x'), with R the reflected radiance the rest of the path estimates by next-event
/// estimation alone: R(x_i) = NEE(x_i) + f_s |cos| / q (x_i) R(x_i+1) (no emission beyond the
/// first, which NEE accounts for), computed backwards once the path ends.
fn train_path(
    guide: &SkeletonGuide,
    scene: &Scene,
    mut si: SurfaceInteraction,
    query: &mut GuideQuery,
    rng: &mut Sampler,
    out: &mut Vec<Sample>,
) {
    let mut beta = Rgb::ONE;
    let mut path: Vec<TrainingVertex> = Vec::with_capacity(TRAINING_DEPTH as usize);
    for _ in 0..TRAINING_DEPTH {
        let bsdf = scene.bsdf(&si);
        let frame = si.shading_frame();
        let wo_local = frame.to_local(si.wo);
        query.clear();
        let mut rays = 0;
        if !bsdf.is_delta() {
            rays = query.init(guide, scene, si.p, si.p_error, si.ng, si.wo);
        }
        let guided = query.guiding_probability() > 0.0;
        let zero = Sample {
            node: query.node().unwrap_or(0),
            f: 0.0,
            p_bsdf: 0.0,
            p_skel: 0.0,
            rays,
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
        let (emitted, direct) = match &next {
            Some(n) => (scene.emitted(n), direct_light(scene, n, rng)),
            None => (
                scene
                    .environment()
                    .map_or(Rgb::ZERO, |(_, env)| env.radiance(wi)),
                Rgb::ZERO,
            ),
        };
        path.push(TrainingVertex {
            sample: guided.then(|| Sample {
                p_bsdf: bsdf.pdf(wo_local, bs.wi),
                p_skel: query.pdf(wi),
                ..zero
            }),
            beta,
            f_cos,
            weight,
            emitted,
            direct,
        });
        beta *= weight;
        let Some(n) = next else { break };
        if !crate::math::is_finite3(beta) || beta == Rgb::ZERO {
            break;
        }
        si = n;
    }
    // Backwards. At vertex i: R(x_i+1) = NEE(x_i+1) + tail, tail = f_s |cos| / q (x_i+1)
    // R(x_i+2) (zero beyond the last vertex sampled), and L = L_e(x_i+1) + R(x_i+1).
    let mut tail = Rgb::ZERO;
    for v in path.iter().rev() {
        let reflected = v.direct + tail;
        if let Some(mut sample) = v.sample {
            let f = luminance(v.beta * v.f_cos * (v.emitted + reflected));
            sample.f = if f.is_finite() { f.max(0.0) } else { 0.0 };
            out.push(sample);
        }
        tail = v.weight * reflected;
        if !crate::math::is_finite3(tail) {
            tail = Rgb::ZERO;
        }
    }
}

/// One light sample at `si`, reflected toward `si.wo`, without MIS (an unbiased estimate of
/// the direct light there); zero at delta BSDFs.
fn direct_light(scene: &Scene, si: &SurfaceInteraction, rng: &mut Sampler) -> Rgb {
    let bsdf = scene.bsdf(si);
    if bsdf.is_delta() {
        return Rgb::ZERO;
    }
    let frame = si.shading_frame();
    let u = rng.uniform2();
    let wo_local = frame.to_local(si.wo);
    let Some(t) = scene.sample_light_toward(
        si,
        &frame,
        &bsdf,
        wo_local,
        EnvStrategy::default(),
        TriangleSampling::default(),
        u,
    ) else {
        return Rgb::ZERO;
    };
    let (ls, pmf, f) = (t.sample, t.pmf, t.f_cos);
    if !(ls.pdf > 0.0) || !scene.unoccluded(si, &ls) {
        return Rgb::ZERO;
    }
    f * ls.radiance / (pmf * ls.pdf)
}
