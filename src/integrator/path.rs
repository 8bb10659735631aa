//! Unidirectional path tracing (000 §4.1, lines 1214-1304): BSDF sampling plus next-event
//! estimation at every non-delta vertex, combined by MIS (Veach's one-sample-per-strategy
//! estimator), with Russian roulette.
//!
//! `path_skeleton` (000 §9.4-9.5) is the same path tracer with a direction guide: at every
//! non-delta vertex the guide ([`crate::guide::GuideQuery`]) proposes skeleton lobes, and the
//! next direction comes from them with probability `c_skel`, from the BSDF otherwise. Every
//! density this file uses for a direction (the throughput's denominator, the MIS weights of
//! next-event estimation and of emitters hit) is then the density of that one-sample mixture,
//! so both integrators estimate the same image. `path_portal` traces with the same loop
//! ([`PathTracer::trace`]), its guide behind the same [`VertexGuide`] trait.
//!
//! # The pilot
//!
//! The training's scene-level prediction (`guide::training`, "The path-level prediction")
//! scores its choices with a proxy: next-event estimation only, paths cut at
//! `training_depth` (8) vertices. On scenes it was not tuned on it promised too much: on
//! the family `rooms:SEED` it predicted variance ratios of 0.41-0.64 where the render's
//! per-sample variance ratio was 0.84-1.06 (BENCHMARKS.md, "Procedural family"), and guided scenes lost
//! to `path`. So before a trained guide is used, `prepare` traces a pilot with this file's own
//! estimator at the render's depth, over an image at the training's 2:1 aspect, both policies
//! with the same random numbers (their difference is less noisy than either), in units of
//! two independent estimates each (`pilot_sampler`):
//! - `sobol` (the default): `pilot_paths / 16` pixels, each estimated from 16 samples (the
//!   render's film, lens and bounce slots) under two independent scrambles of the render's
//!   default Sobol points (`math::pixel_sampler`). Half the squared difference of a pixel's
//!   two estimates, times 16, is an unbiased estimate of the variance per sample that the
//!   render's pixel error has under these numbers, which lower `path`'s variance more than
//!   the guided mixture's (its guide/BSDF choice takes padded slots). On rooms:17 it reads
//!   0.99 where Sobol renders measure 0.93 and independent numbers 0.67.
//! - `independent`: `pilot_paths` camera rays, each traced twice with independent numbers.
//!   Half the squared difference of a ray's two samples is an unbiased estimate of the
//!   variance along that ray (the pixel's variance less the part from where in the pixel the
//!   ray goes, which guiding does not change). It reads the gain guiding has without the
//!   Sobol points, which the render does not have: it guided family scenes that then lost
//!   0.73-0.83x at equal time (BENCHMARKS.md, "Procedural family").
//!
//! The units' means give the measured variance ratio, and the delta method over the units its
//! relative standard error (`Pilot::variance_error`, printed: 0.1-0.2 on family scenes that
//! lose, 0.3-0.6 on heavy-tailed ones, where a few units decide the ratio). The
//! cost ratio is the time of the guided samples over the unguided ones' (`pilot_cost=time`,
//! the default), in this thread's CPU time, timed in batches (16 rays or one pixel), the two policies in turn
//! with the order alternating: time slices given to other processes do not enter it (wall
//! time read 1.2-1.8x on one scene under a changing load), and neither policy is timed on
//! warmer caches. A work count (`pilot_cost=work`: rays traced per sample times the
//! training's overhead ratio for the queries and the node mapping, `guide::training`,
//! "Cost") read 0.90-1.18x on family scenes whose measured cost was 1.12-1.46x. Unless 1 /
//! (variance ratio x cost ratio) exceeds the switch's margin (1.1) with the variance ratio
//! raised by two of its standard errors (`Pilot::pays`, [`crate::guide::PILOT_SIGMAS`]),
//! every node is set to c = 0 and `path_skeleton` traces `path`'s samples. The same pilot
//! runs first on the guide the training's scout learned (`guide::training`, "The scout"):
//! unless that guide shows a gain at one standard error, the full training is skipped. The
//! pilot's random numbers are its own (its own seeds), so the render stays unbiased whatever
//! the verdict; with `pilot_cost=work` the verdict is also a deterministic function of the
//! scene (chunk sums combined in chunk order), with `time` it may differ between runs where
//! the efficiency is near the margin.

use std::cell::RefCell;
use std::sync::Arc;

use rayon::prelude::*;

use super::mis_auto::{MixtureSample, PixelAlphas, VertexAlphas};
use super::{
    Integrator, IntegratorSettings, MisHeuristic, Precomputation, SampleContext, TraceCounters,
    View, ALPHA_LAYER,
};
use crate::error::{Error, Result};
use crate::film::PixelSample;
use crate::geometry::Ray;
use crate::guide::budget;
use crate::guide::{
    estimator, sample_bsdf_or_guide, DirectionGuide, GridPoint, GuideQuery, Pilot, PilotCost,
    RenderEstimator, SkeletonGuide, BUDGET_SHARE,
};
use crate::light::TriangleSampling;
use crate::math::FIRST_INTEGRATOR_DIMENSION;
use crate::math::{luminance, Frame, PixelSampler, Rgb, Rng, Sampler, SamplerKind, Vec3};
use crate::scene::{Bsdf, Camera, Scene, SurfaceInteraction};
use crate::timing::thread_cpu_seconds;

mod roulette;

/// Sampler dimension slots of one bounce, so that each slot means the same thing in every
/// sample of a pixel (and a stratified sampler stratifies that one integral): the light 2-D
/// (whose first coordinate also picks the light, rescaled, so the pair stays a stratified set
/// over each light: [`Scene::sample_light_toward`]), roulette, then three for the direction,
/// consumed in order: the BSDF's component choice and 2-D (unguided), or for `path_skeleton`
/// the guide/BSDF choice followed by the chosen one's 1-D and 2-D (there the slots are padded
/// dimensions whose meaning varies).
const SLOTS_PER_BOUNCE: u32 = 5;
pub(super) const LIGHT_SLOT: u32 = 0;
pub(super) const ROULETTE_SLOT: u32 = 1;
pub(super) const DIRECTION_SLOT: u32 = 2;

pub(super) fn slot(depth: u32, k: u32) -> u32 {
    FIRST_INTEGRATOR_DIMENSION + depth * SLOTS_PER_BOUNCE + k
}

/// The stage name of the time budget's probe (`guide::budget`).
const PROBE_STAGE: &str = "time-budget probe (unguided camera samples)";

pub struct PathTracer {
    settings: IntegratorSettings,
    /// `path_skeleton`: `Some`, holding the guide once `prepare` has built it.
    guiding: Option<Option<Arc<SkeletonGuide>>>,
    /// [`Integrator::set_time_budget`]'s seconds, which the guide's precomputation must fit
    /// a share of (`guide::budget`).
    time_budget: Option<f64>,
    /// The last `prepare` stopped the guide's precomputation to keep within the time budget:
    /// `path`'s samples exactly, no guide.
    over_budget: bool,
    /// `mis=auto`: the per-pixel alpha estimates (see [`super::mis_auto::DEPTH_CLASSES`]).
    alphas: PixelAlphas,
    /// The pilot on the scout's guide, where the last `prepare` ran one (`scout_pilot`).
    scout_pilot: Option<Pilot>,
}

impl PathTracer {
    pub fn new(settings: IntegratorSettings) -> Self {
        PathTracer {
            settings,
            guiding: None,
            time_budget: None,
            over_budget: false,
            alphas: PixelAlphas::default(),
            scout_pilot: None,
        }
    }

    /// `path_skeleton`: path tracing guided by the skeleton of the empty space, with the
    /// guide settings in `settings.skeleton` (validated here; the guide is built by
    /// `prepare`).
    pub fn skeleton_guided(settings: IntegratorSettings) -> Result<Self> {
        settings.skeleton.validate()?;
        Ok(PathTracer {
            settings,
            guiding: Some(None),
            time_budget: None,
            over_budget: false,
            alphas: PixelAlphas::default(),
            scout_pilot: None,
        })
    }

    /// The skeleton guide built by the last `prepare`.
    pub fn guide(&self) -> Option<&Arc<SkeletonGuide>> {
        self.guiding.as_ref().and_then(|g| g.as_ref())
    }

    /// What the pilot on the scout's guide measured in the last `prepare`, where one ran
    /// (module docs, "The pilot"); unless [`Pilot::may_pay_after_training`], that prepare
    /// skipped the full training and guides nothing.
    pub fn scout_pilot(&self) -> Option<Pilot> {
        self.scout_pilot
    }

    /// The render's light sampling and MIS heuristic, as the shared estimator
    /// (`guide::estimator`) and the training take them.
    fn estimator(&self) -> RenderEstimator {
        RenderEstimator {
            mis: self.settings.mis.unwrap_or_default(),
            triangles: self.settings.path.triangles,
            env: self.settings.env,
        }
    }

    /// Next-event estimation ([`estimator::sample_direct_light`]) from the sampler's 2-D `u`:
    /// radiance from one light sample, MIS-weighted against direction sampling (the BSDF,
    /// mixed with the guide's lobes where `query` is guided). `wo` is local to the shading
    /// frame. With `mis=auto` the sample is taken with probability `alphas`' light
    /// probability at `depth` (the first coordinate of `u` decides, then is rescaled) and
    /// recorded during the warm-up, its integrand scaled by `beta`.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn sample_light(
        &self,
        scene: &Scene,
        si: &SurfaceInteraction,
        frame: &Frame,
        bsdf: &Bsdf,
        wo_local: Vec3,
        query: &impl DirectionGuide,
        mut u: crate::math::Vec2,
        (alphas, depth, beta): (&mut VertexAlphas, u32, Rgb),
        counters: &mut TraceCounters,
    ) -> Rgb {
        let pi = alphas.light_probability(depth);
        if pi < 1.0 {
            if u.x >= pi {
                return Rgb::ZERO;
            }
            u.x = (u.x / pi).min(1.0 - f32::EPSILON / 2.0);
        }
        let estimator = self.estimator();
        let Some(light) = estimator::sample_direct_light(
            scene,
            si,
            frame,
            bsdf,
            wo_local,
            &estimator,
            u,
            &mut counters.rays,
        ) else {
            return Rgb::ZERO;
        };
        let direction_pdf = if light.delta {
            0.0
        } else {
            query.mixture_pdf(light.wi, bsdf.pdf(wo_local, light.wi_local))
        };
        if !alphas.is_active() {
            return light.weighted(light.weight(estimator.mis, direction_pdf));
        }
        alphas.record(
            depth,
            beta * light.f_cos * light.radiance,
            direction_pdf,
            light.light_pdf,
        );
        if light.delta {
            light.weighted(1.0 / pi)
        } else {
            light.weighted(VertexAlphas::light_weight(
                pi,
                light.light_pdf,
                direction_pdf,
            ))
        }
    }

    /// The MIS weight of a sampled direction (density `direction_pdf`, from the vertex of
    /// depth `depth`) that found an emitter light sampling draws with density `light_pdf`.
    fn direction_weight(
        &self,
        alphas: &VertexAlphas,
        depth: u32,
        direction_pdf: f32,
        light_pdf: f32,
    ) -> f32 {
        if alphas.is_active() {
            VertexAlphas::direction_weight(
                alphas.light_probability(depth),
                direction_pdf,
                light_pdf,
            )
        } else {
            self.estimator().mis.weight(direction_pdf, light_pdf)
        }
    }

    /// Radiance of the environment along a ray that left the scene, MIS-weighted against
    /// the environment's light sampling at the vertex the ray left (point `prev_point`, normal
    /// `prev_normal`); camera rays see it unless it is hidden. `prev_scale`: the throughput
    /// before the vertex times f |cos| there, the integrand's scale `mis=auto` records.
    #[allow(clippy::too_many_arguments)]
    fn escaped(
        &self,
        scene: &Scene,
        dir: Vec3,
        depth: u32,
        prev_delta: bool,
        prev_pdf: f32,
        prev_point: Vec3,
        prev_normal: Vec3,
        (alphas, prev_scale): (&mut VertexAlphas, Rgb),
    ) -> Rgb {
        let Some((_, env)) = scene.environment() else {
            return Rgb::ZERO;
        };
        if depth == 0 && !env.visible_to_camera() {
            return Rgb::ZERO;
        }
        let estimator = self.estimator();
        let Some((le, light_pdf)) =
            estimator::environment_along(scene, prev_point, prev_normal, dir, &estimator)
        else {
            return Rgb::ZERO;
        };
        if prev_delta || le == Rgb::ZERO {
            return le;
        }
        alphas.record(depth - 1, prev_scale * le, prev_pdf, light_pdf);
        le * self.direction_weight(alphas, depth - 1, prev_pdf, light_pdf)
    }
}

/// Samples per pilot pixel and scramble (`pilot_sampler=sobol`): enough for the Sobol points'
/// stratification to lower `path`'s variance (BENCHMARKS.md, "Procedural family", "A pilot
/// under the render's sampler"; 64 samples over 512 pixels read the door's ratio at 1.35).
const PILOT_SPP: u32 = 16;
const PILOT_SEED: u64 = 0x9170_7a11;
/// Width / height of the pilot's image: the training's (BENCHMARKS.md, "Procedural family",
/// "The pilot against the render": the render's view was tried and not kept).
const PILOT_ASPECT: f32 = 2.0;

/// The pilot's units (module docs, "The pilot"): rays with a pair of independent samples
/// each, or pixels estimated under two scrambles of the Sobol points.
#[derive(Clone, Copy)]
enum PilotUnits {
    Rays(crate::scene::CameraFrame),
    Pixels(View),
}

impl PilotUnits {
    /// `samples` camera samples of the pilot under `sampler`'s numbers.
    fn new(camera: &Camera, sampler: SamplerKind, samples: u32) -> (Self, u32) {
        let frame = camera.frame(PILOT_ASPECT);
        match sampler {
            SamplerKind::Independent => (PilotUnits::Rays(frame), samples),
            SamplerKind::Sobol => {
                let pixels = samples.div_ceil(PILOT_SPP);
                let width = ((pixels as f64 * PILOT_ASPECT as f64).sqrt().ceil() as u32).max(1);
                let view = View {
                    frame,
                    width,
                    height: pixels.div_ceil(width),
                    sampler,
                };
                (PilotUnits::Pixels(view), pixels)
            }
        }
    }

    /// Units per chunk (the fixed work partition) and per timed batch: the thread CPU clock
    /// is a system call, too slow to time a single sample against.
    fn chunk_and_batch(&self) -> (u32, usize) {
        match self {
            PilotUnits::Rays(_) => (256, 16),
            PilotUnits::Pixels(_) => (16, 1),
        }
    }

    /// Samples per unit and estimate.
    fn samples(&self) -> u32 {
        match self {
            PilotUnits::Rays(_) => 1,
            PilotUnits::Pixels(_) => PILOT_SPP,
        }
    }

    /// The unit's two independent estimates (luminance) by `trace`, which maps a camera ray
    /// and its numbers to a sample: for a ray, two samples along it with independent numbers;
    /// for a pixel, its means over [`PILOT_SPP`] samples under two scrambles. The numbers
    /// depend only on the unit, so both policies see the same.
    fn estimates(&self, unit: u32, mut trace: impl FnMut(Ray, &mut Sampler) -> Rgb) -> [f64; 2] {
        let mut out = [0f64; 2];
        match self {
            PilotUnits::Rays(frame) => {
                let mut pick = Rng::new(PILOT_SEED, unit as u64);
                let ray = frame.generate_ray(pick.uniform2(), pick.uniform2());
                for (j, estimate) in out.iter_mut().enumerate() {
                    let mut rng =
                        Sampler::independent(Rng::new(PILOT_SEED + 1 + j as u64, unit as u64));
                    *estimate = luminance(trace(ray, &mut rng)) as f64;
                }
            }
            PilotUnits::Pixels(view) => {
                let (x, y) = (unit % view.width, unit / view.width);
                for (j, estimate) in out.iter_mut().enumerate() {
                    let pixel = PixelSampler::new(view.sampler, PILOT_SEED + j as u64, unit as u64);
                    for s in 0..PILOT_SPP {
                        let mut rng = pixel.sample(s);
                        let ray = view.primary_ray(x, y, &mut rng);
                        *estimate += luminance(trace(ray, &mut rng)) as f64;
                    }
                    *estimate /= PILOT_SPP as f64;
                }
            }
        }
        out
    }
}

/// Half the squared difference of two estimates (an unbiased estimate of either's variance
/// when they are independent and alike); infinite if either is not finite.
fn half_squared_difference([a, b]: [f64; 2]) -> f64 {
    let d = a - b;
    if d.is_finite() {
        0.5 * d * d
    } else {
        f64::INFINITY
    }
}

impl PathTracer {
    /// The pilot's sums over `count` units (module docs, "The pilot"): per policy (unguided,
    /// guided) the summed per-sample variances, rays traced and CPU seconds, then the sums
    /// of the variances' squares and cross product (for the ratio's standard error). Chunk
    /// sums combined in chunk order: the same for any thread count.
    fn pilot_sums(
        &self,
        scene: &Scene,
        units: PilotUnits,
        guide: &SkeletonGuide,
        count: u32,
    ) -> [f64; 9] {
        let (chunk, batch) = units.chunk_and_batch();
        let samples = units.samples() as f64;
        let chunks: Vec<[f64; 9]> = (0..count.div_ceil(chunk))
            .into_par_iter()
            .map(|c| {
                let mut query = GuideQuery::new();
                let mut counters = [TraceCounters::default(), TraceCounters::default()];
                let mut seconds = [0f64; 2];
                let first = c * chunk;
                let chunk_units: Vec<u32> = (first..(first + chunk).min(count)).collect();
                let mut out = [0f64; 9];
                for (b, batch_units) in chunk_units.chunks(batch).enumerate() {
                    let mut d = vec![[0f64; 2]; batch_units.len()];
                    // Unguided and guided in turn, which goes first alternating, so that
                    // neither is timed on warmer caches.
                    for step in 0..2 {
                        let k = (step + b + c as usize) % 2;
                        let started = thread_cpu_seconds();
                        for (&unit, dk) in batch_units.iter().zip(&mut d) {
                            let counters = &mut counters[k];
                            let off = &mut { VertexAlphas::OFF };
                            let estimates = units.estimates(unit, |ray, rng| {
                                let sample = if k == 1 {
                                    let guided = &mut SkeletonVertexGuide::new(guide, &mut query);
                                    self.trace(scene, ray, rng, counters, guided, off)
                                } else {
                                    self.trace(scene, ray, rng, counters, &mut Unguided, off)
                                };
                                sample.radiance
                            });
                            // The variance of the unit's estimate times its samples: the
                            // variance per sample that the render's error has under these
                            // numbers.
                            dk[k] = samples * half_squared_difference(estimates);
                        }
                        seconds[k] += thread_cpu_seconds() - started;
                    }
                    for [a, g] in d {
                        out[0] += a;
                        out[1] += g;
                        out[6] += a * a;
                        out[7] += g * g;
                        out[8] += a * g;
                    }
                }
                out[2] = counters[0].rays as f64;
                out[3] = counters[1].rays as f64;
                out[4] = seconds[0];
                out[5] = seconds[1];
                out
            })
            .collect();
        let mut sum = [0f64; 9];
        for chunk in &chunks {
            for (s, c) in sum.iter_mut().zip(chunk) {
                *s += c;
            }
        }
        sum
    }

    /// Seconds per unguided camera sample of the render's estimator on this thread: the mean
    /// over [`budget::PROBE_SAMPLES`] samples along the pilot's rays (`guide::budget`), in the
    /// thread's CPU time: a probe of a few milliseconds may lose a whole time slice to other
    /// processes on a loaded machine, which the wall clock would read as a slow scene (the
    /// checks after the analysis and the scout read the wall clock, load included). The first
    /// quarter warms the caches, untimed.
    fn probe_sample_seconds(&self, scene: &Scene, camera: &Camera) -> f64 {
        let (units, count) =
            PilotUnits::new(camera, SamplerKind::Independent, budget::PROBE_SAMPLES / 2);
        let mut counters = TraceCounters::default();
        let warm = count / 4;
        let mut trace = |range: std::ops::Range<u32>| {
            for unit in range {
                units.estimates(unit, |ray, rng| {
                    let off = &mut { VertexAlphas::OFF };
                    self.trace(scene, ray, rng, &mut counters, &mut Unguided, off)
                        .radiance
                });
            }
        };
        trace(0..warm);
        let started = thread_cpu_seconds();
        trace(warm..count);
        (thread_cpu_seconds() - started) / (2 * (count - warm).max(1)) as f64
    }

    /// The precomputation of a `prepare` stopped by the time budget (`guide::budget`) before
    /// `stop` = (the next stage, seconds spent, seconds estimated for the rest, the budget):
    /// no guide, `path`'s samples, and a note that says why.
    fn stop_over_budget(
        &mut self,
        portals: Precomputation,
        started: std::time::Instant,
        probe_seconds: f64,
        (next, spent, rest, b): (&str, f64, f64, f64),
    ) -> Precomputation {
        self.guiding = Some(None);
        self.over_budget = true;
        let mut notes = vec![format!(
            "skeleton guide: over the time budget, nothing guided (path's samples): {:.2} s spent and {:.2} s estimated from {next} on, more than {:.0} % of {:.2} s",
            spent,
            rest,
            BUDGET_SHARE * 100.0,
            b
        )];
        notes.extend(portals.notes);
        let mut stages = portals.stages;
        stages.push(crate::analysis::StageTime {
            stage: PROBE_STAGE,
            seconds: probe_seconds,
        });
        stages.push(crate::analysis::StageTime {
            stage: "stages before the time budget's stop",
            seconds: started.elapsed().as_secs_f64() - probe_seconds,
        });
        Precomputation { stages, notes }
    }

    /// The pilot (module docs, "The pilot"): None where it does not apply (no pilot rays, a
    /// guide without a trained scene-level switch, or one that guides nothing already).
    fn pilot(&self, scene: &Scene, camera: &Camera, guide: &SkeletonGuide) -> Option<Pilot> {
        let settings = guide.settings();
        let training = guide.training().filter(|t| t.paths > 0)?;
        if settings.pilot_paths == 0
            || guide.guides_nothing()
            || !settings.learned_c_skel
            || !settings.cost_model.switches()
        {
            return None;
        }
        let (units, count) = PilotUnits::new(camera, settings.pilot_sampler, settings.pilot_paths);
        let sum = self.pilot_sums(scene, units, guide, count);
        let n = count as f64;
        let samples = 2.0 * n * units.samples() as f64;
        let (rays_path, rays_guided) = (sum[2] / samples, sum[3] / samples);
        let ray_ratio = if rays_path > 0.0 {
            rays_guided / rays_path
        } else {
            1.0
        };
        let (seconds_path, seconds_guided) = (sum[4], sum[5]);
        let cost_ratio = match settings.pilot_cost {
            PilotCost::Time if seconds_path > 0.0 => seconds_guided / seconds_path,
            _ => ray_ratio * training.scene.cost_ratio,
        };
        Some(Pilot {
            rays: count * units.samples(),
            units: count,
            variance_path: sum[0] / n,
            variance_guided: sum[1] / n,
            variance_error: ratio_relative_error(&sum, count),
            rays_per_sample_path: rays_path,
            rays_per_sample_guided: rays_guided,
            seconds_path,
            seconds_guided,
            cost_ratio,
            sigmas: settings.pilot_sigmas,
        })
    }
}

/// The relative standard error of the pilot's variance ratio from its sums
/// ([`PathTracer::pilot_sums`]) over `n` units: the delta method for a ratio of two means of
/// paired values (the two policies' variances at one unit are correlated). 0 where either
/// mean is 0 or a sum is not finite.
fn ratio_relative_error(sum: &[f64; 9], n: u32) -> f64 {
    let n = n as f64;
    let (ma, mg) = (sum[0] / n, sum[1] / n);
    if !(ma > 0.0 && mg > 0.0 && sum.iter().all(|s| s.is_finite())) {
        return 0.0;
    }
    let va = sum[6] / n - ma * ma;
    let vg = sum[7] / n - mg * mg;
    let c = sum[8] / n - ma * mg;
    ((vg / (mg * mg) + va / (ma * ma) - 2.0 * c / (ma * mg)) / n)
        .max(0.0)
        .sqrt()
}

impl Integrator for PathTracer {
    fn name(&self) -> &'static str {
        if self.guiding.is_some() {
            "path_skeleton"
        } else {
            "path"
        }
    }

    /// `mis=auto`: the `alpha` layer, R the depth-0 alpha of the pixel's sample (0.5 in the
    /// warm-up; zero where the camera ray hit nothing) and G the fraction of samples that hit
    /// a surface, as `env_direct` writes it.
    fn layers(&self) -> Vec<String> {
        if self.mis() == MisHeuristic::Auto {
            vec![ALPHA_LAYER.to_string()]
        } else {
            Vec::new()
        }
    }

    fn prepare(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        progress: &dyn Fn(&str, f64) -> bool,
    ) -> Result<Precomputation> {
        let mut portals = prepare_env_portals(scene, &self.settings)?;
        self.prepare_roulette(scene, camera, &mut portals);
        if self.guiding.is_none() {
            return Ok(portals);
        }
        let started = std::time::Instant::now();
        self.guiding = Some(None);
        self.scout_pilot = None;
        self.over_budget = false;
        // The training scores its candidates with this render's light sampling and MIS.
        let mut skeleton = self.settings.skeleton;
        skeleton.render_estimator = self.estimator();
        skeleton.time_budget = self.time_budget;
        // With a time budget (`guide::budget`): the probe's pace, and before the analysis,
        // after the skeleton and after the training, the stages done and the rest estimated
        // must fit in the budget's share, or the build stops there (through its progress
        // callback) and nothing is guided.
        let probe_started = std::time::Instant::now();
        let estimate = self.time_budget.map(|_| {
            let sample_seconds = self.probe_sample_seconds(scene, camera);
            budget::PrecomputeEstimate::new(
                scene,
                &skeleton,
                sample_seconds,
                rayon::current_num_threads(),
            )
        });
        let probe_seconds = probe_started.elapsed().as_secs_f64();
        let over = std::cell::Cell::new(None);
        let budgeted_progress = |stage: &str, fraction: f64| -> bool {
            if !progress(stage, fraction) {
                return false;
            }
            let (Some(b), Some(e)) = (self.time_budget, estimate) else {
                return true;
            };
            // The stage just done (`SkeletonGuide::build`'s and `Skeleton::of_scene`'s names).
            let (next, rest) = match stage {
                crate::guide::START_STAGE => ("the analysis", e.whole()),
                crate::analysis::SKELETON_STAGE => ("the light tracing", e.after_analysis()),
                _ => return true,
            };
            let spent = started.elapsed().as_secs_f64();
            if budget::fits(b, spent, rest) {
                true
            } else {
                over.set(Some((next, spent, rest, b)));
                false
            }
        };
        // The pilot on the scout's guide ("The pilot"): unless that guide shows a gain, the
        // full training is skipped.
        let scout_pilot = std::cell::Cell::new(None);
        let scout_check = |scout_guide: &SkeletonGuide| {
            let pilot = self.pilot(scene, camera, scout_guide);
            scout_pilot.set(pilot);
            pilot.map_or(true, |p| p.may_pay_after_training())
        };
        let built = SkeletonGuide::build_with_scout_check(
            scene,
            Some(camera),
            &skeleton,
            &budgeted_progress,
            skeleton.scout_pilot.then_some(&scout_check),
        );
        let mut guide = match (built, over.get()) {
            (Err(Error::Cancelled), Some(stop)) => {
                return Ok(self.stop_over_budget(portals, started, probe_seconds, stop));
            }
            (built, _) => built?,
        };
        // The final pilot, where the guide guides something (`pilot` runs only there).
        if let (Some(b), Some(e)) = (self.time_budget, estimate) {
            let spent = started.elapsed().as_secs_f64();
            let rest = e.after_training();
            if !guide.guides_nothing() && !budget::fits(b, spent, rest) {
                let stop = ("the pilot", spent, rest, b);
                return Ok(self.stop_over_budget(portals, started, probe_seconds, stop));
            }
        }
        let scout_pilot = scout_pilot.get();
        let pilot_started = std::time::Instant::now();
        let pilot = self.pilot(scene, camera, &guide);
        if let Some(p) = pilot {
            guide.apply_pilot(p);
        }
        let pilot_seconds = pilot_started.elapsed().as_secs_f64();
        let mixture_started = std::time::Instant::now();
        let mixture = if self.mis() == MisHeuristic::Auto {
            self.mixture_warmup(scene, camera, &guide)
        } else {
            None
        };
        let mixture_seconds = mixture_started.elapsed().as_secs_f64();
        let mut mixture_note = None;
        if let Some((c, changed, samples)) = &mixture {
            let mean = |c: &mut dyn Iterator<Item = f32>| {
                let (sum, n) = c
                    .filter(|&c| c > 0.0)
                    .fold((0.0, 0), |(s, n), c| (s + c, n + 1));
                sum / n.max(1) as f32
            };
            let before =
                mean(&mut (0..guide.node_count() as u32).map(|n| guide.guiding_probability(n)));
            guide.set_guiding_probabilities(c);
            mixture_note = Some(format!(
                "mis=auto: c re-estimated at {changed} of {} guided nodes from {samples} directions ({:.2} s), mean c {before:.2} -> {:.2}",
                c.iter().filter(|&&c| c > 0.0).count(),
                mixture_seconds,
                mean(&mut c.iter().copied())
            ));
        }
        let notes = vec![format!(
            "skeleton guide: {} nodes ({} raw), {} importance nodes ({} found), {} of {} nodes guided, {:.1} MiB",
            guide.node_count(),
            guide.raw_node_count(),
            guide.importance_nodes().len(),
            guide.importance_nodes_found(),
            guide.guided_node_count(),
            guide.node_count(),
            guide.memory_bytes() as f64 / (1024.0 * 1024.0)
        )];
        let mut notes = notes;
        if let (Some(b), Some(e)) = (self.time_budget, estimate) {
            notes.push(format!(
                "time budget: precomputation estimated at {:.2} s before the analysis, within {:.0} % of {:.2} s",
                e.whole(),
                BUDGET_SHARE * 100.0,
                b
            ));
        }
        notes.extend(portals.notes);
        notes.extend(mixture_note);
        if let Some(p) = scout_pilot {
            notes.push(format!(
                "pilot on the scout's guide: variance {:.3}x (relative error {:.2}), cost {:.3}x, efficiency {:.3}x (bound {:.3}x){}",
                p.variance_ratio(),
                p.variance_error,
                p.cost_ratio,
                p.efficiency(),
                p.scout_efficiency_bound(),
                if p.may_pay_after_training() {
                    ""
                } else {
                    ": no clear gain, no full training, nothing guided"
                }
            ));
        }
        if let Some(p) = pilot {
            notes.push(format!(
                "pilot ({} camera samples in {} units, {:.2} s): variance {:.3}x (relative error {:.2}), cost {:.3}x ({:.2} against {:.2} rays per sample, {:.3} against {:.3} s), efficiency {:.3}x (confidence bound {:.3}x){}",
                p.rays,
                p.units,
                pilot_seconds,
                p.variance_ratio(),
                p.variance_error,
                p.cost_ratio,
                p.rays_per_sample_guided,
                p.rays_per_sample_path,
                p.seconds_guided,
                p.seconds_path,
                p.efficiency(),
                p.efficiency_bound(),
                if p.pays() { "" } else { ": not enough, nothing guided" }
            ));
        }
        if let Some(t) = guide.training() {
            let guided: Vec<f32> = t
                .probabilities
                .iter()
                .copied()
                .filter(|&c| c > 0.0)
                .collect();
            let trained = t.samples.iter().filter(|&&n| n > 0).count();
            // An empty f32 sum is -0.0: say 0 when no node is guided.
            let mean_c = if guided.is_empty() {
                0.0
            } else {
                guided.iter().sum::<f32>() / guided.len() as f32
            };
            notes.push(format!(
                "trained c_skel / strength: {} of {} nodes guided ({} reached by {} training paths), mean c {:.2}",
                guided.len(),
                guide.node_count(),
                trained,
                t.paths,
                mean_c
            ));
            let sc = &t.scene;
            notes.push(format!(
                "scene-level (measured costs): predicted variance {:.3}x, cost {:.3}x ({:.2} guided and {:.2} mapped of {:.2} vertices per training path), efficiency {:.3}x{}",
                sc.predicted_variance(),
                sc.cost_ratio,
                sc.guided_vertices as f64 / t.paths.max(1) as f64,
                sc.mapped_vertices as f64 / t.paths.max(1) as f64,
                sc.vertices as f64 / t.paths.max(1) as f64,
                sc.efficiency(),
                if guide.stopped_over_budget() {
                    ": nothing guided, the rest of the precomputation over the time budget's share"
                } else if sc.switched_off {
                    ": not enough, nothing guided (scene-level switch)"
                } else {
                    ""
                }
            ));
            if guide.settings().learned_strength {
                let mut counts: Vec<(String, usize)> = Vec::new();
                for (s, &c) in t.strengths.iter().zip(&t.probabilities) {
                    if c > 0.0 {
                        let name = s.to_string();
                        match counts.iter_mut().find(|(n, _)| *n == name) {
                            Some(entry) => entry.1 += 1,
                            None => counts.push((name, 1)),
                        }
                    }
                }
                let list: Vec<String> = counts.iter().map(|(n, k)| format!("{n}: {k}")).collect();
                notes.push(format!(
                    "learned strengths of the guided nodes: {}",
                    list.join(", ")
                ));
            }
        }
        let mut stages = portals.stages;
        if estimate.is_some() {
            stages.push(crate::analysis::StageTime {
                stage: PROBE_STAGE,
                seconds: probe_seconds,
            });
        }
        stages.extend_from_slice(guide.timings());
        if pilot.is_some() {
            stages.push(crate::analysis::StageTime {
                stage: "pilot (guided against unguided samples)",
                seconds: pilot_seconds,
            });
        }
        if mixture.is_some() {
            stages.push(crate::analysis::StageTime {
                stage: "mis=auto: the mixture's c per node (warm-up paths)",
                seconds: mixture_seconds,
            });
        }
        self.guiding = Some(Some(Arc::new(guide)));
        self.scout_pilot = scout_pilot;
        Ok(Precomputation { stages, notes })
    }

    fn set_time_budget(&mut self, seconds: Option<f64>) {
        self.time_budget = seconds;
    }

    fn check_prepared(&self, scene: &Scene) -> Result<()> {
        match &self.guiding {
            None => Ok(()),
            Some(Some(guide)) if guide.built_for(scene) => Ok(()),
            Some(Some(_)) => Err(Error::invalid(
                "path_skeleton was prepared for another scene: prepare it for this one",
            )),
            Some(None) if self.over_budget => Ok(()),
            Some(None) => Err(Error::invalid(
                "path_skeleton needs its skeleton guide: prepare the integrator for the scene before rendering",
            )),
        }
    }

    fn sample(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        ctx: &SampleContext,
    ) -> PixelSample {
        // A guide that guides no node (every node learned c = 0, or the scene-level switch of
        // `cost_model=switch|measured`): `path`'s sample exactly, without node mapping or
        // query set-up.
        let Some(guide) = self.guide().filter(|g| !g.guides_nothing()) else {
            return self.sample_with(scene, ray, rng, counters, ctx, &mut Unguided);
        };
        THREAD_QUERY.with(|cell| match cell.try_borrow_mut() {
            Ok(mut query) => {
                let guided = &mut SkeletonVertexGuide::new(guide, &mut query);
                self.sample_with(scene, ray, rng, counters, ctx, guided)
            }
            // Only if a host re-entered the renderer from inside a sample on this thread.
            Err(_) => {
                let mut query = GuideQuery::new();
                let guided = &mut SkeletonVertexGuide::new(guide, &mut query);
                self.sample_with(scene, ray, rng, counters, ctx, guided)
            }
        })
    }
}

impl PathTracer {
    /// `rr_depth=auto`: sets the start of Russian roulette for `scene` and `camera` from the
    /// pilot ([`roulette`]), with its time and note in `pre`; nothing otherwise.
    pub(super) fn prepare_roulette(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        pre: &mut Precomputation,
    ) {
        if !self.settings.path.rr_depth_auto {
            return;
        }
        let started = std::time::Instant::now();
        let choice = roulette::choose_start_depth(scene, camera, &self.settings);
        self.settings.path.rr_start_depth = choice.start_depth;
        let seconds = started.elapsed().as_secs_f64();
        pre.notes.push(choice.note(seconds));
        pre.stages.push(crate::analysis::StageTime {
            stage: "rr_depth=auto (pilot of paths without roulette)",
            seconds,
        });
    }

    /// The start of Russian roulette in use (`rr_depth`, or what `rr_depth=auto` chose).
    pub(super) fn rr_start_depth(&self) -> u32 {
        self.settings.path.rr_start_depth
    }

    pub(super) fn mis(&self) -> MisHeuristic {
        super::mis_in_use(self.name(), &self.settings)
    }

    /// One camera sample guided by `guide` (see [`Integrator::sample`]), with `mis=auto`'s
    /// per-pixel alphas where the render uses them.
    pub(super) fn sample_with<G: VertexGuide>(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        ctx: &SampleContext,
        guide: &mut G,
    ) -> PixelSample {
        if self.mis() == MisHeuristic::Auto {
            return self.sample_auto(scene, ray, rng, counters, ctx, guide);
        }
        self.trace(scene, ray, rng, counters, guide, &mut { VertexAlphas::OFF })
    }

    /// `mis=auto`'s sample (see [`super::mis_auto::DEPTH_CLASSES`]): the pixel's alpha
    /// state, the sample, the warm-up's records back to the pixel, and the depth-0 alpha to
    /// the `alpha` layer (R alpha, G 1) where the camera ray hit a surface.
    fn sample_auto<G: VertexGuide>(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        ctx: &SampleContext,
        guide: &mut G,
    ) -> PixelSample {
        let pixel_count = ctx.view.width as usize * ctx.view.height as usize;
        let pixel = ctx.pixel_index as usize;
        let mut alphas = self.alphas.begin(
            pixel_count,
            pixel,
            ctx.sample_index,
            self.settings.path.mis_warmup,
        );
        let sample = self.trace(scene, ray, rng, counters, guide, &mut alphas);
        self.alphas.finish(pixel, &alphas);
        if let Some(layer) = ctx.layers.first() {
            if sample.hit {
                layer.set(Rgb::new(alphas.alpha(0), 1.0, 0.0));
            }
        }
        sample
    }
}

/// Feature `diagnostics`: per-vertex records of one traced sample (examples/firefly_map.rs),
/// to find which node, lobe weights and densities make a large sample weight.
#[cfg(feature = "diagnostics")]
pub mod diagnostics {
    use std::cell::RefCell;

    use crate::guide::GuideQuery;
    use crate::math::Rgb;

    /// One vertex of a recorded path.
    #[derive(Clone, Debug)]
    pub struct Vertex {
        pub depth: u32,
        pub node: Option<u32>,
        pub c: f32,
        /// The active lobes' (probability, is_portal).
        pub lobes: Vec<(f32, bool)>,
        /// The BSDF's density of the chosen direction and the mixture's.
        pub bsdf_pdf: f32,
        pub pdf: f32,
        /// Radiance accumulated before this vertex's direction (luminance).
        pub radiance_before: f32,
        /// Whether the guide drew the direction (else the BSDF).
        pub from_guide: bool,
    }

    /// What one contribution to the sample's radiance was.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum Kind {
        /// An emitter hit at the vertex of this depth (reached by the previous direction).
        Hit,
        /// Next-event estimation at the vertex of this depth.
        Nee,
        /// The environment, along the ray leaving the vertex of depth - 1.
        Escaped,
    }

    /// One weighted contribution (luminance of beta times the estimate) of a recorded path.
    #[derive(Clone, Copy, Debug)]
    pub struct Contribution {
        pub depth: u32,
        pub kind: Kind,
        pub luminance: f32,
    }

    thread_local! {
        static RECORD: RefCell<Option<Vec<Vertex>>> = const { RefCell::new(None) };
        static CONTRIBUTIONS: RefCell<Vec<Contribution>> = const { RefCell::new(Vec::new()) };
    }

    /// Starts recording on this thread.
    pub fn start() {
        RECORD.with(|r| *r.borrow_mut() = Some(Vec::new()));
        CONTRIBUTIONS.with(|c| c.borrow_mut().clear());
    }

    /// Stops recording and returns the vertices.
    pub fn take() -> Vec<Vertex> {
        RECORD.with(|r| r.borrow_mut().take().unwrap_or_default())
    }

    /// The contributions recorded since [`start`] (call before the next `start`).
    pub fn take_contributions() -> Vec<Contribution> {
        CONTRIBUTIONS.with(|c| std::mem::take(&mut *c.borrow_mut()))
    }

    pub(super) fn contribution(depth: u32, kind: Kind, value: Rgb) {
        let recording = RECORD.with(|r| r.borrow().is_some());
        if recording && value != Rgb::ZERO {
            CONTRIBUTIONS.with(|c| {
                c.borrow_mut().push(Contribution {
                    depth,
                    kind,
                    luminance: crate::math::luminance(value),
                })
            });
        }
    }

    pub(super) fn record(
        query: &GuideQuery,
        depth: u32,
        bsdf_pdf: f32,
        pdf: f32,
        radiance: Rgb,
        from_guide: bool,
    ) {
        RECORD.with(|r| {
            if let Some(v) = r.borrow_mut().as_mut() {
                v.push(Vertex {
                    depth,
                    node: query.node(),
                    c: query.guiding_probability(),
                    lobes: (0..query.lobe_count())
                        .map(|i| (query.lobe(i).unwrap().2, query.lobe_is_portal(i)))
                        .collect(),
                    bsdf_pdf,
                    pdf,
                    radiance_before: crate::math::luminance(radiance),
                    from_guide,
                });
            }
        });
    }
}

thread_local! {
    /// The guided integrator's query, one per thread and reused by every sample the thread
    /// traces: a query is about 1.7 KB (eight lobes with their rectangles), and making and
    /// dropping one per camera sample cost about 860 instructions per sample on the Bitterli
    /// ajar. Each vertex re-initialises it (`GuideQuery::clear`, `GuideQuery::init`), so what
    /// an earlier sample left in it is never read.
    static THREAD_QUERY: RefCell<GuideQuery> = const { RefCell::new(GuideQuery::new()) };
}

/// The direction guide of the shared trace loop ([`PathTracer::trace`]): `path` has none
/// ([`Unguided`]), `path_skeleton` the skeleton's lobes ([`SkeletonVertexGuide`]),
/// `path_portal` the portals (integrator/path_portal.rs). At each non-delta vertex the loop
/// sets the query up and draws the next direction from it or the BSDF by one-sample MIS, and
/// every density of a direction (the throughput's denominator, the MIS weights of next-event
/// estimation and of emitters or the environment found) is that mixture's; so one loop, one
/// estimator, whatever the guide.
pub(super) trait VertexGuide {
    type Query: DirectionGuide;
    /// Whether any vertex may be guided (false: `path`'s own samples, no query work).
    const GUIDED: bool;
    /// The bound on the product of p_bsdf / p along a path (`ratio_max`; infinite: none).
    fn ratio_max(&self) -> f32 {
        f32::INFINITY
    }
    /// What [`prefetch`](Self::prefetch) found of a vertex that [`init`](Self::init) needs
    /// too (found once per vertex).
    type Located: Copy;
    /// Called at every surface hit before its BSDF is built (a guide may start loading what
    /// the vertex will read).
    fn prefetch(&self, si: &SurfaceInteraction) -> Self::Located;
    /// Sets the query up at non-delta vertex `si` (`at` what `prefetch` returned for it), its
    /// guiding probability at most `c_max`; returns the rays it traced.
    fn init(
        &mut self,
        scene: &Scene,
        si: &SurfaceInteraction,
        at: Self::Located,
        c_max: f32,
    ) -> u64;
    /// Makes the query unguided (a delta vertex: no mixture with a Dirac lobe has a density).
    fn clear(&mut self);
    fn query(&self) -> &Self::Query;
    /// Told of each non-delta direction the vertex drew (world `wi`, mixture density `pdf`,
    /// the BSDF's own `pdf_bsdf`), with the sample's radiance before it: the mixture warm-up
    /// of `mis=auto` records them ([`MixtureRecorder`]); the render's guides ignore it.
    #[inline]
    fn drew(&mut self, _radiance: Rgb, _wi: Vec3, _pdf: f32, _pdf_bsdf: f32) {}
    /// Told of each Russian-roulette decision point (before the roulette, whether or not it
    /// applies at this depth): the sample's radiance so far and the throughput the roulette
    /// reads. `rr_depth=auto`'s pilot records them ([`roulette::RouletteRecorder`]).
    #[inline]
    fn roulette_point(&mut self, _radiance: Rgb, _rr_beta: Rgb) {}
    /// Feature `diagnostics`: the skeleton query the vertex records show, if this is one.
    #[cfg(feature = "diagnostics")]
    fn skeleton_query(&self) -> Option<&GuideQuery> {
        None
    }
}

/// `path`: no guide.
pub(super) struct Unguided;

impl VertexGuide for Unguided {
    type Query = GuideQuery;
    type Located = ();
    const GUIDED: bool = false;
    #[inline]
    fn prefetch(&self, _: &SurfaceInteraction) {}
    #[inline]
    fn init(&mut self, _: &Scene, _: &SurfaceInteraction, _: (), _: f32) -> u64 {
        0
    }
    #[inline]
    fn clear(&mut self) {}
    #[inline]
    fn query(&self) -> &GuideQuery {
        GuideQuery::unguided()
    }
    #[cfg(feature = "diagnostics")]
    fn skeleton_query(&self) -> Option<&GuideQuery> {
        Some(GuideQuery::unguided())
    }
}

/// `path_skeleton`: the skeleton guide and the query it initialises at each vertex.
struct SkeletonVertexGuide<'a> {
    guide: &'a SkeletonGuide,
    query: &'a mut GuideQuery,
}

impl<'a> SkeletonVertexGuide<'a> {
    fn new(guide: &'a SkeletonGuide, query: &'a mut GuideQuery) -> Self {
        SkeletonVertexGuide { guide, query }
    }
}

impl VertexGuide for SkeletonVertexGuide<'_> {
    type Query = GuideQuery;
    /// The vertex's place in the guide's grid.
    type Located = GridPoint;
    const GUIDED: bool = true;
    fn ratio_max(&self) -> f32 {
        self.guide.ratio_max()
    }
    #[inline]
    fn prefetch(&self, si: &SurfaceInteraction) -> GridPoint {
        let at = self.guide.locate(si.p);
        self.guide.prefetch_at(&at, si.ng, si.wo);
        at
    }
    fn init(&mut self, scene: &Scene, si: &SurfaceInteraction, at: GridPoint, c_max: f32) -> u64 {
        debug_assert!(at.point() == si.p || si.p.is_nan());
        // `init_at` resets the query itself.
        let rays = self
            .query
            .init_at(self.guide, scene, &at, si.p_error, si.ng, si.wo);
        self.query.cap_guiding_probability(c_max);
        self.query.prefetch_directions();
        rays as u64
    }
    fn clear(&mut self) {
        self.query.clear();
    }
    fn query(&self) -> &GuideQuery {
        self.query
    }
    #[cfg(feature = "diagnostics")]
    fn skeleton_query(&self) -> Option<&GuideQuery> {
        Some(self.query)
    }
}

/// `mis=auto`'s mixture warm-up (see [`super::mis_auto::MixtureSample`]): the skeleton guide,
/// recording each direction drawn at a guided vertex with the sample's radiance before it;
/// [`MixtureRecorder::finish`] turns them into the samples' integrands once the path's
/// radiance is known.
struct MixtureRecorder<'a> {
    guided: SkeletonVertexGuide<'a>,
    /// Per direction of the current path: its node, the radiance before it (luminance), its
    /// guide and BSDF densities and the mixture's.
    pending: Vec<(u32, f32, f32, f32, f32)>,
    samples: Vec<MixtureSample>,
}

impl MixtureRecorder<'_> {
    /// Ends the current path, of radiance `radiance`: each direction's contribution is the
    /// radiance the path gained after it, and its integrand that times the mixture density.
    fn finish(&mut self, radiance: Rgb) {
        let total = luminance(radiance);
        for (node, before, pdf_guide, pdf_bsdf, sampled) in self.pending.drain(..) {
            let h = (total - before).max(0.0) * sampled;
            if h.is_finite() {
                self.samples.push(MixtureSample {
                    node,
                    h,
                    pdf_guide,
                    pdf_bsdf,
                    sampled,
                });
            }
        }
    }
}

impl VertexGuide for MixtureRecorder<'_> {
    type Query = GuideQuery;
    type Located = GridPoint;
    const GUIDED: bool = true;
    fn ratio_max(&self) -> f32 {
        self.guided.ratio_max()
    }
    fn prefetch(&self, si: &SurfaceInteraction) -> GridPoint {
        self.guided.prefetch(si)
    }
    fn init(&mut self, scene: &Scene, si: &SurfaceInteraction, at: GridPoint, c_max: f32) -> u64 {
        self.guided.init(scene, si, at, c_max)
    }
    fn clear(&mut self) {
        self.guided.clear();
    }
    fn query(&self) -> &GuideQuery {
        self.guided.query()
    }
    fn drew(&mut self, radiance: Rgb, wi: Vec3, pdf: f32, pdf_bsdf: f32) {
        let query = self.guided.query();
        let c = query.guiding_probability();
        let Some(node) = query.node().filter(|_| c > 0.0 && c < 1.0) else {
            return;
        };
        let pdf_guide = query.pdf(wi);
        self.pending
            .push((node, luminance(radiance), pdf_guide, pdf_bsdf, pdf));
    }
    #[cfg(feature = "diagnostics")]
    fn skeleton_query(&self) -> Option<&GuideQuery> {
        Some(self.guided.query)
    }
}

/// Camera rays per chunk of the mixture warm-up (the fixed work partition).
const MIXTURE_CHUNK: u32 = 1024;
const MIXTURE_SEED: u64 = 0x313c_a17a;
/// Newton steps of the mixture's c per node, as `env_direct`'s `alpha_steps` default.
const MIXTURE_STEPS: u32 = 2;

impl PathTracer {
    /// `mis=auto`'s mixture warm-up (see [`super::mis_auto::MixtureSample`]): traces
    /// `mix_warmup` camera rays over the pilot's view with the trained guide and its own random
    /// numbers (the render stays unbiased: its c does not depend on its samples), and
    /// re-estimates each guided node's c from the directions drawn there. Chunks are combined
    /// in chunk order and sorted stably by node: the same c for any thread count. Returns the
    /// new probabilities and the samples recorded, or None where nothing is guided.
    fn mixture_warmup(
        &self,
        scene: &Scene,
        camera: &Camera,
        guide: &SkeletonGuide,
    ) -> Option<(Vec<f32>, usize, usize)> {
        let rays = self.settings.path.mix_warmup;
        if rays == 0 || guide.guides_nothing() {
            return None;
        }
        let frame = camera.frame(PILOT_ASPECT);
        let chunk_count = rays.div_ceil(MIXTURE_CHUNK);
        let chunks: Vec<Vec<MixtureSample>> = (0..chunk_count)
            .into_par_iter()
            .map(|c| {
                let mut query = GuideQuery::new();
                let mut recorder = MixtureRecorder {
                    guided: SkeletonVertexGuide::new(guide, &mut query),
                    pending: Vec::new(),
                    samples: Vec::new(),
                };
                let mut counters = TraceCounters::default();
                let first = c * MIXTURE_CHUNK;
                for i in first..(first + MIXTURE_CHUNK).min(rays) {
                    let mut pick = Rng::new(MIXTURE_SEED, i as u64);
                    let ray = frame.generate_ray(pick.uniform2(), pick.uniform2());
                    let mut rng = Sampler::independent(Rng::new(MIXTURE_SEED + 1, i as u64));
                    let sample =
                        self.trace(scene, ray, &mut rng, &mut counters, &mut recorder, &mut {
                            VertexAlphas::OFF
                        });
                    recorder.finish(sample.radiance);
                }
                recorder.samples
            })
            .collect();
        let mut samples: Vec<MixtureSample> = chunks.into_iter().flatten().collect();
        samples.sort_by_key(|s| s.node);
        let mut c: Vec<f32> = (0..guide.node_count() as u32)
            .map(|n| guide.guiding_probability(n))
            .collect();
        let c_max = guide.settings().c_max;
        let changed = super::mis_auto::refine_mixture(&mut c, &samples, MIXTURE_STEPS, c_max);
        Some((c, changed, samples.len()))
    }
}

impl PathTracer {
    /// One camera path (see [`Integrator::sample`]), its directions drawn by one-sample MIS of
    /// the BSDF and `guide` (the BSDF's alone where the guide does not guide).
    #[inline]
    pub(super) fn trace<G: VertexGuide>(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        guide: &mut G,
        alphas: &mut VertexAlphas,
    ) -> PixelSample {
        #[cfg(target_arch = "x86_64")]
        if crate::geometry::has_x86_64_v3() {
            // SAFETY: the CPU runs x86-64-v3 code (checked just above).
            return unsafe { self.trace_v3(scene, ray, rng, counters, guide, alphas) };
        }
        self.trace_baseline(scene, ray, rng, counters, guide, alphas)
    }

    /// [`trace`](Self::trace) for any x86-64 (and other architectures).
    #[inline(never)]
    fn trace_baseline<G: VertexGuide>(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        guide: &mut G,
        alphas: &mut VertexAlphas,
    ) -> PixelSample {
        self.trace_impl(scene, ray, rng, counters, guide, alphas)
    }

    /// [`trace`](Self::trace) compiled for x86-64-v3, as the BVH traversal is: with the
    /// per-vertex work inlined into one loop, three-operand AVX forms spare the register
    /// copies of the shading code (BENCHMARKS.md, issue 30). Results are bit-identical: Rust
    /// never contracts a * b + c into an FMA by itself.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    unsafe fn trace_v3<G: VertexGuide>(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        guide: &mut G,
        alphas: &mut VertexAlphas,
    ) -> PixelSample {
        self.trace_impl(scene, ray, rng, counters, guide, alphas)
    }

    /// The body of [`trace`](Self::trace), inlined into each of its two compilations.
    #[inline(always)]
    fn trace_impl<G: VertexGuide>(
        &self,
        scene: &Scene,
        mut ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        guide: &mut G,
        alphas: &mut VertexAlphas,
    ) -> PixelSample {
        let mut out = PixelSample::default();
        let mut radiance = Rgb::ZERO;
        let mut beta = Rgb::ONE;
        // The throughput BSDF sampling alone would carry, for Russian roulette (see
        // `guide::MixtureSample::bsdf_pdf`); equal to `beta` when nothing is guided.
        let mut rr_beta = Rgb::ONE;
        // The product of p_bsdf / pdf over the directions so far (`ratio_max`).
        let mut ratio = 1.0f32;
        let ratio_max = guide.ratio_max();
        // State of the previous vertex, for MIS when a BSDF-sampled ray hits an emitter.
        let mut prev_delta = true;
        let mut prev_pdf = 0.0f32;
        let mut prev_point = ray.origin;
        let mut prev_normal = Vec3::ZERO;
        // `mis=auto`: the throughput before the previous vertex times f |cos| there.
        let mut prev_scale = Rgb::ZERO;
        let mut depth = 0u32;
        loop {
            counters.rays += 1;
            let Some(si) = scene.intersect(&ray) else {
                let e = beta
                    * self.escaped(
                        scene,
                        ray.dir,
                        depth,
                        prev_delta,
                        prev_pdf,
                        prev_point,
                        prev_normal,
                        (alphas, prev_scale),
                    );
                #[cfg(feature = "diagnostics")]
                diagnostics::contribution(depth, diagnostics::Kind::Escaped, e);
                radiance += e;
                break;
            };
            let located = guide.prefetch(&si);
            if depth == 0 {
                out.hit = true;
                out.depth = si.t;
                out.normal = si.ns;
            }

            let le = scene.emitted(&si);
            if le != Rgb::ZERO {
                let weight = if prev_delta {
                    1.0
                } else {
                    let estimator = self.estimator();
                    let light_pdf =
                        estimator::emitter_light_pdf(scene, prev_point, &si, &estimator);
                    alphas.record(depth - 1, prev_scale * le, prev_pdf, light_pdf);
                    self.direction_weight(alphas, depth - 1, prev_pdf, light_pdf)
                };
                #[cfg(feature = "diagnostics")]
                diagnostics::contribution(depth, diagnostics::Kind::Hit, beta * le * weight);
                radiance += beta * le * weight;
            }
            if depth >= self.settings.max_depth {
                break;
            }

            let bsdf = scene.bsdf(&si);
            if depth == 0 {
                out.albedo = bsdf.albedo_hint();
            }
            let frame = si.shading_frame();
            let wo_local = frame.to_local(si.wo);
            if G::GUIDED {
                // No guiding at delta BSDFs: no mixture with a Dirac lobe has a density.
                if bsdf.is_delta() {
                    guide.clear();
                } else {
                    // Worst case after this vertex: ratio / (1 - c) <= ratio_max.
                    let c_max = if ratio_max.is_finite() {
                        1.0 - ratio / ratio_max
                    } else {
                        f32::INFINITY
                    };
                    counters.rays += guide.init(scene, &si, located, c_max);
                }
            }
            let query = guide.query();
            if !bsdf.is_delta() {
                rng.set_dimension(slot(depth, LIGHT_SLOT));
                let u = rng.uniform2();
                let nee = beta
                    * self.sample_light(
                        scene,
                        &si,
                        &frame,
                        &bsdf,
                        wo_local,
                        query,
                        u,
                        (alphas, depth, beta),
                        counters,
                    );
                #[cfg(feature = "diagnostics")]
                diagnostics::contribution(depth, diagnostics::Kind::Nee, nee);
                radiance += nee;
            }

            rng.set_dimension(slot(depth, DIRECTION_SLOT));
            let Some(ms) = sample_bsdf_or_guide(&bsdf, wo_local, &frame, query, rng) else {
                break;
            };
            let bs = ms.sample;
            let wi = frame.to_world(bs.wi);
            // Reflections must leave on wo's side of the geometric surface, transmissions on
            // the other side; shading normals can disagree near silhouettes.
            let reflected = bs.wi.z * wo_local.z > 0.0;
            let same_side = wi.dot(si.ng) * si.wo.dot(si.ng) > 0.0;
            if reflected != same_side {
                break;
            }
            #[cfg(feature = "diagnostics")]
            if let Some(query) = guide.skeleton_query() {
                diagnostics::record(query, depth, ms.bsdf_pdf, bs.pdf, radiance, ms.from_guide);
            }
            if G::GUIDED && !bs.delta {
                guide.drew(radiance, wi, bs.pdf, ms.bsdf_pdf);
            }
            if alphas.is_active() {
                prev_scale = beta * bs.f * bs.wi.z.abs();
            }
            beta *= bs.f * (bs.wi.z.abs() / bs.pdf);
            rr_beta *= bs.f * (bs.wi.z.abs() / ms.bsdf_pdf);
            ratio *= ms.bsdf_pdf / bs.pdf;
            if G::GUIDED {
                counters.largest_guided_ratio = counters.largest_guided_ratio.max(ratio);
            }
            if !crate::math::is_finite3(beta) || beta == Rgb::ZERO {
                break;
            }
            prev_delta = bs.delta;
            prev_pdf = bs.pdf;
            prev_point = si.p;
            prev_normal = si.facing_normal();
            ray = si.spawn_ray(wi);
            rng.set_dimension(slot(depth, ROULETTE_SLOT));
            depth += 1;

            guide.roulette_point(radiance, rr_beta);
            if depth >= self.settings.path.rr_start_depth {
                let q = (1.0 - rr_beta.max_element()).max(0.05);
                if rng.uniform() < q {
                    break;
                }
                beta /= 1.0 - q;
                rr_beta /= 1.0 - q;
            }
        }
        out.radiance = radiance;
        out
    }
}

/// `env=portals`: the scene's window portals, found by the analysis unless listed by hand
/// (once per scene), with its time and a note saying which they are.
pub(super) fn prepare_env_portals(
    scene: &Scene,
    settings: &IntegratorSettings,
) -> Result<Precomputation> {
    if settings.env != crate::light::EnvStrategy::Portals || scene.environment().is_none() {
        return Ok(Precomputation::default());
    }
    let started = std::time::Instant::now();
    let portals = crate::analysis::scene_env_portals(scene)?;
    let seconds = started.elapsed().as_secs_f64();
    let note = match &portals.sampler {
        Some(s) => format!(
            "env=portals: {} {} portals ({:.3} s, rectified images {:.3} s, {:.1} MiB)",
            s.portals().len(),
            if portals.automatic {
                "window"
            } else {
                "listed"
            },
            seconds,
            s.build_seconds(),
            s.memory_bytes() as f64 / (1024.0 * 1024.0)
        ),
        None => format!(
            "env=portals: no portals ({seconds:.3} s): the environment is sampled by {}",
            crate::light::environment::PORTAL_FALLBACK.name()
        ),
    };
    Ok(Precomputation {
        stages: vec![crate::analysis::StageTime {
            stage: "environment portals (window detection, rectified images)",
            seconds,
        }],
        notes: vec![note],
    })
}

/// `path` in the integrator registry.
pub(super) const PATH: super::Registration = super::Registration {
    name: "path",
    set_option: set_path_option,
    create: |settings| Ok(Box::new(PathTracer::new(settings))),
    adaptive_mis: &[MisHeuristic::Auto],
};

/// `path_skeleton` in the integrator registry: `path`'s options, then the guide's.
pub(super) const PATH_SKELETON: super::Registration = super::Registration {
    name: "path_skeleton",
    set_option: |settings, option| {
        if !set_path_option(settings, option)? {
            settings.skeleton.set(option.key, option.value)?;
        }
        Ok(true)
    },
    create: |settings| Ok(Box::new(PathTracer::skeleton_guided(settings)?)),
    adaptive_mis: &[MisHeuristic::Auto],
};

/// `path`'s and `path_skeleton`'s own options
/// (`path:rr_depth=D|auto:triangles=area|solid_angle:mis_warmup=N`, `path_skeleton:mix_warmup=N`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathOptions {
    /// Russian roulette: a path that has made this many bounces may be ended before the next
    /// one, surviving with probability `min(max(throughput), 0.95)`. Lower starts make samples cheaper and noisier. The default is 5 (as
    /// Mitsuba's): by instructions x MAE^2 per sample, a start at 5 against 3 wins on most test
    /// scenes and loses little on the one where it loses (BENCHMARKS.md).
    pub rr_start_depth: u32,
    /// `rr_depth=auto`: `prepare` sets `rr_start_depth` for the scene and camera from a pilot
    /// ([`roulette`]).
    pub rr_depth_auto: bool,
    /// How next-event estimation samples emissive triangles: by area (default) or by solid
    /// angle (`bdpt` always samples them by area: its MIS weights assume that density).
    pub triangles: TriangleSampling,
    /// `mis=auto`: the samples of each pixel that estimate its alpha (rendered with the
    /// balance heuristic) before the others use it (see [`super::mis_auto::DEPTH_CLASSES`]).
    pub mis_warmup: u32,
    /// `path_skeleton:mis=auto`: camera rays of the warm-up that re-estimates each guided
    /// node's guiding probability c (`integrator::mis_auto::MixtureSample`); 0 keeps the
    /// trained c (then only next-event estimation is balanced automatically).
    pub mix_warmup: u32,
}

impl Default for PathOptions {
    fn default() -> Self {
        PathOptions {
            rr_start_depth: 5,
            rr_depth_auto: false,
            triangles: TriangleSampling::default(),
            mis_warmup: 16,
            mix_warmup: 32768,
        }
    }
}

/// Sets one of [`PathOptions`] from `path:KEY=VALUE`; `Ok(false)` for a key it does not take.
pub(super) fn set_path_option(
    settings: &mut IntegratorSettings,
    option: &super::SpecOption,
) -> Result<bool> {
    let options = &mut settings.path;
    match option.key {
        "rr_depth" if option.value == "auto" => options.rr_depth_auto = true,
        "rr_depth" => {
            options.rr_start_depth = option.value.parse().map_err(|_| {
                Error::invalid(format!(
                    "integrator option rr_depth={} in '{}' must be a non-negative integer or auto",
                    option.value, option.spec
                ))
            })?;
            options.rr_depth_auto = false;
        }
        "triangles" => options.triangles = TriangleSampling::parse(option.value)?,
        "mis_warmup" => options.mis_warmup = option.count()?,
        "mix_warmup" => options.mix_warmup = option.count()?,
        _ => return Ok(false),
    }
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Vec2;

    /// The x86-64-v3 copy of the trace loop gives the baseline copy's samples, bit for bit,
    /// on a scene with diffuse and glossy surfaces.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn v3_trace_matches_the_baseline() {
        if !crate::geometry::has_x86_64_v3() {
            return;
        }
        let scene = crate::scene::two_rooms_builder().unwrap().build().unwrap();
        let frame = scene.camera().unwrap().frame(1.0);
        let tracer = PathTracer::new(IntegratorSettings::default());
        let bits = |s: &PixelSample| {
            [s.radiance, s.albedo, s.normal].map(|c| [c.x.to_bits(), c.y.to_bits(), c.z.to_bits()])
        };
        let mut lit = 0;
        for pixel in 0..1024u64 {
            let film = Vec2::new((pixel % 32) as f32 + 0.5, (pixel / 32) as f32 + 0.5) / 32.0;
            let ray = frame.generate_ray(film, Vec2::splat(0.5));
            let mut samples = [0, 1].map(|_| Sampler::new(SamplerKind::Sobol, 7, pixel, 3));
            let mut counters = [TraceCounters::default(); 2];
            let off = &mut { VertexAlphas::OFF };
            let [a_rng, b_rng] = &mut samples;
            let [a_counters, b_counters] = &mut counters;
            let a = tracer.trace_baseline(&scene, ray, a_rng, a_counters, &mut Unguided, off);
            // SAFETY: the CPU runs x86-64-v3 code (checked above).
            let b = unsafe { tracer.trace_v3(&scene, ray, b_rng, b_counters, &mut Unguided, off) };
            assert_eq!(bits(&a), bits(&b), "pixel {pixel}");
            assert_eq!(a.depth.to_bits(), b.depth.to_bits());
            assert_eq!(a.hit, b.hit);
            assert_eq!(a_counters.rays, b_counters.rays);
            lit += (a.radiance != Rgb::ZERO) as u32;
        }
        assert!(lit > 100, "{lit} lit samples");
    }
}
