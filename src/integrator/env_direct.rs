//! `env_direct`: direct lighting with many light and BSDF samples per shading point, the
//! estimator of 001 chapter 3 (eq. 3.5-3.7, Algorithm 2) for environment maps, and the same
//! many-sample estimator for every other light (the set-up of 001 chapter 5's Table 5.2, where
//! automatic MIS balancing is measured).
//!
//! At the first non-specular surface the camera ray reaches (after mirror and glass
//! bounces, up to `max_depth`), one estimate is made per light source (the environment; each
//! connected emissive surface of one radiance; the point-like lights; the light fields), each with N_L
//! light samples and N_B BSDF directions combined by the balance heuristic over the counts:
//!
//! - **The environment** (001 chapter 3): the N_L light samples are split between the cube
//!   faces by the strategy's face proportions mu_f (M_f = mu_f N_L samples on face f, a
//!   fractional count with the last sample weighted by beta = frac(M_f), eq. 3.5-3.6), and
//!   (eq. 3.7, with the thesis's halves generalised to N_L / N and N_B / N, N = N_L + N_B)
//!   `L ~ 1/N [sum_f sum_i beta_i s(w_i) / q(w_i) + sum_j s(w_j) / q(w_j)]` with
//!   `q(w) = (N_L mu_f(w) pdf_L(w | f(w)) + N_B pdf_B(w)) / N`, where s = f |cos| L V. The
//!   sum of the weights beta over face f's samples is exactly mu_f N_L, so the estimator is unbiased for any mu; mu_f(n) is zero only on faces that lie
//!   wholly behind the surface, where s is zero. With the lat-long strategy all N_L samples
//!   come from the 2-D lat-long density. Unlike the thesis's GPU version, every shading point
//!   draws its own random samples (no sequence shared between pixels, so no spatial bias).
//! - **The emitters** (every other light, per source, [`LightSource`]): the N_L light samples
//!   pick a light of the source by power, then a point on it; the N_B BSDF directions are
//!   traced to the emitter they reach (nothing where it belongs to another source), with q as
//!   above and pdf_L the light's selection probability within the source times its density at
//!   the point (as `path`'s next-event estimation). Delta lights, which BSDF sampling never
//!   finds, are estimated by their light samples alone; the point-like ones (point, spot,
//!   directional, photometric), whose sample at a point is fixed, are each evaluated once
//!   (exact, one shadow ray each) when there are no more of them than N_L.
//!
//! `mis` chooses the weighting of each estimate: `balance` (the above), `power` (exponent 2,
//! over the same counts), `auto` (thesis 001 chapter 5: a warm-up of 16 samples of each
//! technique, at most N/4 (`warmup`; the thesis spends N/4), estimates the fraction alpha of
//! BSDF samples, eq. 5.4-5.5, re-expanded once around that alpha by default (`alpha_steps`,
//! thesis section 5.6), the other samples are
//! split by it, and the two estimates are combined by eq. 5.6; alpha goes to the `alpha`
//! layer) and `optimal` (Kondapaneni et al. 2019, its coefficients from the same warm-up); see
//! [`super::mis_auto`]. Each light source gets its own alpha. With
//! `max_depth` 1 this integrator estimates what `path --max-depth 1` does.

use super::mis_auto::{self, optimal_term, AlphaEstimate, OptimalSystem};
use super::{
    Integrator, IntegratorSettings, MisHeuristic, Precomputation, SampleContext, TraceCounters,
};
use crate::error::{Error, Result};
use crate::film::PixelSample;
use crate::geometry::Ray;
use crate::light::{
    EnvStrategy, EnvironmentMap, Light, LightSample, LightSampler, TriangleSampling,
};
use crate::math::{luminance, Rgb, Sampler, Vec2, Vec3};
use crate::scene::{Bsdf, Camera, Scene, SurfaceInteraction, Transport};

/// `mis=auto`'s default warm-up sample count M (both techniques; at most half the total):
/// enough for a usable alpha, and at N = 256 an eighth of the samples instead of the thesis's
/// half (BENCHMARKS.md, issue 33, per camera ray).
pub const AUTO_WARMUP: u32 = 32;

/// The name of the layer `mis=auto` writes (see [`EnvDirect`]'s `layers`).
pub const ALPHA_LAYER: &str = "alpha";

/// `env_direct`'s own options (`env_direct:samples=N:bsdf=N`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnvDirectOptions {
    /// Environment light samples per shading point (N_L, split between cube faces by the
    /// strategy).
    pub light_samples: u32,
    /// BSDF samples per shading point (N_B).
    pub bsdf_samples: u32,
    /// `mis=auto`: quadratic models of the second moment minimised in turn, the first around
    /// alpha = 1/2 (eq. 5.4), each further one around the previous alpha
    /// ([`mis_auto::refine_alpha`], thesis section 5.6), all from the same warm-up samples.
    /// 2 by default: per camera ray (BENCHMARKS.md, issue 33) the second model gained on
    /// every scene over eq. 5.4 alone, and more gained nothing further.
    pub alpha_steps: u32,
    /// `mis=auto` and `mis=optimal`: the warm-up's sample count M (half from each technique,
    /// at most the total); `None` for [`AUTO_WARMUP`] but at most half the total with `auto`,
    /// and half the total with `optimal`. The thesis's M = N is half the total.
    pub warmup: Option<u32>,
}

impl Default for EnvDirectOptions {
    fn default() -> Self {
        EnvDirectOptions {
            light_samples: 30,
            bsdf_samples: 30,
            alpha_steps: 2,
            warmup: None,
        }
    }
}

pub struct EnvDirect {
    settings: IntegratorSettings,
    /// The emitters' light sources, each estimated on its own (built by `prepare`; empty
    /// before, when the scene's light sampler serves as one source).
    sources: Vec<LightSource>,
}

/// One light source of the emitters' estimate: 001 chapter 5 draws N light and BSDF samples
/// per light source and balances them per source (a small bright lamp and a large dim one want
/// different splits). A source is a connected emissive surface of one radiance (triangles
/// sharing a vertex), the point-like lights together, or the light fields together (BSDF
/// sampling never finds these two).
struct LightSource {
    /// Chooses among the source's lights only, by power.
    sampler: LightSampler,
    /// False for the delta lights: no BSDF samples are drawn for them.
    bsdf_finds_it: bool,
    /// The point-like lights (point, spot, directional, photometric) of the source: each one's
    /// light sample at a point is fixed, so evaluating each once is exact with one shadow ray
    /// per light, where N_L samples chosen by power would cost N_L rays and add the choice's
    /// noise. Used when there are no more of them than N_L; empty for other sources.
    point_like: Vec<usize>,
}

/// Lights whose sample at a receiver does not depend on the random numbers.
fn is_point_like(light: &Light) -> bool {
    matches!(
        light,
        Light::Point { .. }
            | Light::Spot { .. }
            | Light::Directional { .. }
            | Light::Photometric { .. }
    )
}

/// Above this many connected emissive surfaces, every emissive triangle is one source (the
/// cost of a source is its samples at every shading point).
const MAX_LIGHT_SOURCES: usize = 16;

/// The light sources of `scene`'s emitters (see [`LightSource`]); empty without emitters.
fn light_sources(scene: &Scene) -> Vec<LightSource> {
    let lights = scene.lights();
    // Union-find over the area lights: triangles sharing a vertex position with equal radiance.
    let mut parent: Vec<usize> = (0..lights.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let mut first_at = std::collections::HashMap::new();
    for (i, light) in lights.iter().enumerate() {
        if let Light::Area { p, radiance, .. } = light {
            for v in p {
                let key = (
                    v.x.to_bits(),
                    v.y.to_bits(),
                    v.z.to_bits(),
                    radiance.x.to_bits(),
                    radiance.y.to_bits(),
                    radiance.z.to_bits(),
                );
                let other = *first_at.entry(key).or_insert(i);
                let (a, b) = (root(&mut parent, i), root(&mut parent, other));
                parent[a] = b;
            }
        }
    }
    let is_area = |i: usize| matches!(lights[i], Light::Area { .. });
    let mut roots: Vec<usize> = (0..lights.len())
        .filter(|&i| is_area(i) && root(&mut parent, i) == i)
        .collect();
    let mut sources = Vec::new();
    if roots.len() > MAX_LIGHT_SOURCES {
        roots.clear();
        sources.extend(
            LightSampler::of_subset(lights, is_area).map(|sampler| LightSource {
                sampler,
                bsdf_finds_it: true,
                point_like: Vec::new(),
            }),
        );
    }
    for r in roots {
        let members: Vec<bool> = (0..lights.len())
            .map(|i| is_area(i) && root(&mut parent, i) == r)
            .collect();
        sources.extend(
            LightSampler::of_subset(lights, |i| members[i]).map(|sampler| LightSource {
                sampler,
                bsdf_finds_it: true,
                point_like: Vec::new(),
            }),
        );
    }
    // The delta lights: the point-like ones together, and the light fields (whose samples
    // are random) together.
    let point_like: Vec<usize> = (0..lights.len())
        .filter(|&i| is_point_like(&lights[i]))
        .collect();
    sources.extend(
        LightSampler::of_subset(lights, |i| is_point_like(&lights[i])).map(|sampler| LightSource {
            sampler,
            bsdf_finds_it: false,
            point_like,
        }),
    );
    let is_light_field = |i: usize| matches!(lights[i], Light::LightField { .. });
    sources.extend(
        LightSampler::of_subset(lights, is_light_field).map(|sampler| LightSource {
            sampler,
            bsdf_finds_it: false,
            point_like: Vec::new(),
        }),
    );
    sources
}

impl EnvDirect {
    pub fn new(mut settings: IntegratorSettings) -> Result<Self> {
        // `auto` is the thesis's per-face estimator here (001 eq. 3.5-3.6: fractional sample
        // counts per cube face), on either layout.
        if settings.env == EnvStrategy::Auto {
            settings.env = EnvStrategy::CubeDynamic;
        }
        let light = if settings.env == EnvStrategy::BsdfOnly {
            0
        } else {
            settings.env_direct.light_samples
        };
        if light + settings.env_direct.bsdf_samples == 0 {
            return Err(Error::invalid(format!(
                "env_direct needs at least one light or BSDF sample per shading point (samples={}, bsdf={}, env={})",
                settings.env_direct.light_samples,
                settings.env_direct.bsdf_samples,
                settings.env.name()
            )));
        }
        Ok(EnvDirect {
            settings,
            sources: Vec::new(),
        })
    }

    fn light_samples(&self) -> u32 {
        if self.settings.env == EnvStrategy::BsdfOnly {
            0
        } else {
            self.settings.env_direct.light_samples
        }
    }

    /// Direct lighting reflected towards `si.wo` at a non-specular surface point: the
    /// many-sample environment estimate plus one sample of the other lights. The shading
    /// step of the thesis's deferred renderer (Algorithm 2), usable on a G-buffer.
    pub fn shade(
        &self,
        scene: &Scene,
        si: &SurfaceInteraction,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
    ) -> Rgb {
        self.shade_with_alpha(scene, si, rng, counters).0
    }

    /// [`EnvDirect::shade`], and for `mis=auto` the fraction of BSDF samples it chose (the
    /// mean over the light sources that BSDF sampling can find).
    fn shade_with_alpha(
        &self,
        scene: &Scene,
        si: &SurfaceInteraction,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
    ) -> (Rgb, Option<f32>) {
        let bsdf = scene.bsdf(si);
        if bsdf.is_delta() {
            return (Rgb::ZERO, None);
        }
        let mut radiance = Rgb::ZERO;
        let mut alphas = (0.0, 0u32);
        let mut targets: Vec<Target> = Vec::with_capacity(self.sources.len() + 1);
        let prepared = self.sources.first().map(|s| s.sampler.len()) == Some(scene.lights().len());
        if prepared {
            let n_light = self.settings.env_direct.light_samples;
            for source in &self.sources {
                let exact = !source.point_like.is_empty()
                    && n_light > 0
                    && source.point_like.len() <= n_light as usize;
                if exact {
                    radiance += self.point_lights(scene, &source.point_like, si, &bsdf, counters);
                } else {
                    targets.push(Target::Emitters {
                        lights: &source.sampler,
                        bsdf_finds_it: source.bsdf_finds_it,
                    });
                }
            }
        } else if let Some(lights) = scene.light_sampler() {
            // Not prepared for this scene: the scene's light sampler is one source.
            if lights_other_than_environment(scene) {
                targets.push(Target::Emitters {
                    lights,
                    bsdf_finds_it: true,
                });
            }
        }
        if let Some((_, env)) = scene.environment() {
            targets.push(Target::Environment(env));
        }
        for target in targets {
            let (value, alpha) = self.estimate(scene, target, si, &bsdf, rng, counters);
            radiance += value;
            let balanced = !matches!(
                target,
                Target::Emitters {
                    bsdf_finds_it: false,
                    ..
                }
            );
            if let (Some(a), true) = (alpha, balanced) {
                alphas = (alphas.0 + a, alphas.1 + 1);
            }
        }
        let alpha = (alphas.1 > 0).then(|| alphas.0 / alphas.1 as f32);
        (radiance, alpha)
    }

    /// The sample counts (light, BSDF) of one estimate: `env=bsdf` turns off light sampling
    /// of the environment only.
    fn counts(&self, target: Target) -> (u32, u32) {
        let n_bsdf = self.settings.env_direct.bsdf_samples;
        match target {
            Target::Environment(_) => (self.light_samples(), n_bsdf),
            Target::Emitters { bsdf_finds_it, .. } => (
                self.settings.env_direct.light_samples,
                if bsdf_finds_it { n_bsdf } else { 0 },
            ),
        }
    }

    /// Draws the samples of one estimate ([`draw_environment`](Self::draw_environment) or
    /// [`draw_emitters`](Self::draw_emitters)); returns the delta lights' part (see
    /// `draw_emitters`).
    #[allow(clippy::too_many_arguments)]
    fn draw(
        &self,
        scene: &Scene,
        target: Target,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        counts: (u32, u32),
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        out: &mut Vec<Drawn>,
    ) -> Rgb {
        match target {
            Target::Environment(env) => {
                self.draw_environment(scene, env, si, bsdf, counts, rng, counters, out);
                Rgb::ZERO
            }
            Target::Emitters { lights, .. } => {
                self.draw_emitters(scene, lights, si, bsdf, counts, rng, counters, out)
            }
        }
    }

    /// Draws `n_light` samples of the scene's light sampler and `n_bsdf` BSDF directions for
    /// the light of the emitters (every light but the environment, which has its own
    /// estimate), recording each with its value s(w) (zero if occluded, behind the surface or
    /// not reaching an emitter) and both densities: a light sample's is the light's selection
    /// probability times its solid-angle density at the point, as `path`'s next-event
    /// estimation has it. Light samples that pick the environment are dropped (a technique
    /// that sometimes draws nothing stays unbiased over the counts). Delta lights (point, spot,
    /// directional, IES, light fields) cannot be found by BSDF sampling: their samples are not
    /// recorded but summed as s / (pmf pdf), and the return value divided by `n_light` is their
    /// unbiased estimate.
    #[allow(clippy::too_many_arguments)]
    fn draw_emitters(
        &self,
        scene: &Scene,
        lights: &LightSampler,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        (n_light, n_bsdf): (u32, u32),
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        out: &mut Vec<Drawn>,
    ) -> Rgb {
        let frame = si.shading_frame();
        let wo_l = frame.to_local(si.wo);
        let normal = si.facing_normal();
        let triangles = TriangleSampling::default();
        let mut delta = Rgb::ZERO;
        for _ in 0..n_light {
            let (index, pmf) = lights.sample(rng.uniform());
            let u = rng.uniform2();
            let light = &scene.lights()[index];
            if matches!(light, Light::Environment { .. }) {
                continue;
            }
            let Some(ls) = light.sample_with(si.p, normal, self.settings.env, triangles, u) else {
                continue;
            };
            let wi_l = frame.to_local(ls.wi);
            let value = light_sample_value(scene, si, bsdf, wo_l, wi_l, &ls, counters);
            if ls.delta {
                let q = pmf * ls.pdf;
                if value != Rgb::ZERO && q > 0.0 {
                    delta += value / q;
                }
                continue;
            }
            out.push(Drawn {
                weight: 1.0,
                from_bsdf: false,
                value,
                pdf_light: pmf * ls.pdf,
                pdf_bsdf: bsdf.pdf(wo_l, wi_l),
            });
        }
        for _ in 0..n_bsdf {
            let Some(bs) = bsdf.sample_from(wo_l, rng, Transport::Radiance) else {
                continue;
            };
            if bs.delta {
                continue;
            }
            let wi = frame.to_world(bs.wi);
            let mut value = Rgb::ZERO;
            let mut pdf_light = 0.0;
            if si.scatters_toward(wi, wo_l, bs.wi) {
                counters.rays += 1;
                if let Some(hit) = scene.intersect(&si.spawn_ray(wi)) {
                    // Emitters of other sources count as nothing here (pmf 0).
                    if let Some(k) = scene.triangle_light(hit.triangle) {
                        let pmf = lights.pmf(k);
                        if pmf > 0.0 {
                            pdf_light = pmf * scene.lights()[k].pdf_with(si.p, hit.p, triangles);
                            value = bsdf.eval(wo_l, bs.wi, Transport::Radiance)
                                * bs.wi.z.abs()
                                * scene.emitted(&hit);
                        }
                    }
                }
            }
            out.push(Drawn {
                weight: 1.0,
                from_bsdf: true,
                value,
                pdf_light,
                pdf_bsdf: bsdf.pdf(wo_l, bs.wi),
            });
        }
        delta
    }

    /// The exact light of the point-like lights `indices` (see [`LightSource::point_like`]):
    /// one sample and one shadow ray each.
    fn point_lights(
        &self,
        scene: &Scene,
        indices: &[usize],
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        counters: &mut TraceCounters,
    ) -> Rgb {
        let frame = si.shading_frame();
        let wo_l = frame.to_local(si.wo);
        let normal = si.facing_normal();
        let mut sum = Rgb::ZERO;
        for &index in indices {
            let light = &scene.lights()[index];
            // The random numbers are unused by point-like lights.
            let u = Vec2::splat(0.5);
            let triangles = TriangleSampling::default();
            let Some(ls) = light.sample_with(si.p, normal, self.settings.env, triangles, u) else {
                continue;
            };
            let value =
                light_sample_value(scene, si, bsdf, wo_l, frame.to_local(ls.wi), &ls, counters);
            if value != Rgb::ZERO && ls.pdf > 0.0 {
                sum += value / ls.pdf;
            }
        }
        sum
    }

    /// Draws `n_light` environment samples (split between cube faces by the strategy) and
    /// `n_bsdf` BSDF samples at a non-specular surface point, and records each with its value
    /// s(w) (zero behind the surface or occluded) and both densities. Every sample drawn is
    /// recorded, zero ones included: the optimal estimator's control variate needs them.
    #[allow(clippy::too_many_arguments)]
    fn draw_environment(
        &self,
        scene: &Scene,
        env: &EnvironmentMap,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        (n_light, n_bsdf): (u32, u32),
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        out: &mut Vec<Drawn>,
    ) {
        let strategy = self.settings.env;
        let normal = si.facing_normal();
        let frame = si.shading_frame();
        let wo_l = frame.to_local(si.wo);
        let mut record = |weight: f32, from_bsdf: bool, wi: Vec3, pdf_light: f32| {
            let wi_l = frame.to_local(wi);
            let pdf_bsdf = bsdf.pdf(wo_l, wi_l);
            let mut value = Rgb::ZERO;
            if si.scatters_toward(wi, wo_l, wi_l) {
                let v =
                    bsdf.eval(wo_l, wi_l, Transport::Radiance) * wi_l.z.abs() * env.radiance(wi);
                if v != Rgb::ZERO {
                    counters.rays += 1;
                    if !scene.occluded(&si.spawn_ray(wi)) {
                        value = v;
                    }
                }
            }
            out.push(Drawn {
                weight,
                from_bsdf,
                value,
                pdf_light,
                pdf_bsdf,
            });
        };
        match strategy.balancing() {
            Some(balancing) if n_light > 0 => {
                let mu = env.face_balance(balancing, normal);
                let cube = env.cube();
                for (f, &mu_f) in mu.iter().enumerate() {
                    // M_f samples, the last one weighted by the fraction of M_f (eq. 3.6).
                    let m = mu_f * n_light as f32;
                    let count = m.ceil() as u32;
                    for i in 0..count {
                        let beta = (m - i as f32).min(1.0);
                        let Some((local, pdf_f)) = cube.sample_face(f, rng.uniform2()) else {
                            continue;
                        };
                        let wi = env.to_world(local).normalize();
                        record(beta, false, wi, mu_f * pdf_f);
                    }
                }
            }
            _ => {
                for _ in 0..n_light {
                    if let Some(s) = env.sample(strategy, normal, rng.uniform2()) {
                        record(1.0, false, s.wi, s.pdf);
                    }
                }
            }
        }
        for _ in 0..n_bsdf {
            let Some(bs) = bsdf.sample_from(wo_l, rng, Transport::Radiance) else {
                continue;
            };
            if bs.delta {
                continue;
            }
            let wi = frame.to_world(bs.wi);
            record(1.0, true, wi, env.pdf(strategy, normal, wi));
        }
    }

    /// One many-sample estimate (the environment's or the emitters') at a non-specular
    /// surface point, and for `mis=auto` the fraction alpha of BSDF samples it chose.
    fn estimate(
        &self,
        scene: &Scene,
        target: Target,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
    ) -> (Rgb, Option<f32>) {
        let (n_light, n_bsdf) = self.counts(target);
        let total = n_light + n_bsdf;
        // The delta lights' part of a phase that drew `n` light samples.
        let per_light_sample = |delta: Rgb, n: u32| {
            if n > 0 {
                delta / n as f32
            } else {
                Rgb::ZERO
            }
        };
        DRAWN.with(|cell| {
            let mut drawn = cell.take();
            drawn.clear();
            let adaptive = matches!(self.mis(), MisHeuristic::Auto | MisHeuristic::Optimal);
            // The warm-up: `warm` samples of each technique (the half-half mixture of eq. 5.5).
            // By default, for `auto`, AUTO_WARMUP in all but at most half the total (the
            // thesis's half spends half the samples at alpha = 1/2: per camera ray 32 of 256
            // measured better on every scene, an eighth of 64 worse, BENCHMARKS.md), and half
            // for `optimal` (not re-measured).
            let default_warm = if self.mis() == MisHeuristic::Auto {
                (AUTO_WARMUP / 2).min(total / 4)
            } else {
                total / 4
            };
            let warm = self
                .settings
                .env_direct
                .warmup
                .map_or(default_warm, |m| (m / 2).min(total / 2));
            let result = if !adaptive || n_light == 0 || n_bsdf == 0 || warm == 0 {
                let delta = self.draw(
                    scene,
                    target,
                    si,
                    bsdf,
                    (n_light, n_bsdf),
                    rng,
                    counters,
                    &mut drawn,
                );
                let counts = (n_light as f32, n_bsdf as f32);
                let sum = match self.mis() {
                    MisHeuristic::Power => power(&drawn, counts),
                    _ => balance(&drawn, counts),
                };
                let alpha =
                    (self.mis() == MisHeuristic::Auto).then_some(n_bsdf as f32 / total as f32);
                (sum + per_light_sample(delta, n_light), alpha)
            } else {
                let warm_counts = (warm as f32, warm as f32);
                let delta = self.draw(
                    scene,
                    target,
                    si,
                    bsdf,
                    (warm, warm),
                    rng,
                    counters,
                    &mut drawn,
                );
                let first = balance(&drawn, warm_counts) + per_light_sample(delta, warm);
                let (m, n) = (2 * warm, total - 2 * warm);
                let (second, alpha) = if self.mis() == MisHeuristic::Auto {
                    let mut estimate = AlphaEstimate::default();
                    for d in &drawn {
                        estimate.add(d.weight, luminance(d.value), d.pdf_bsdf, d.pdf_light);
                    }
                    let steps = self.settings.env_direct.alpha_steps.saturating_sub(1);
                    let samples = drawn
                        .iter()
                        .map(|d| (d.weight, luminance(d.value), d.pdf_bsdf, d.pdf_light));
                    let alpha = mis_auto::refine_alpha(estimate.alpha(), steps, samples);
                    let counts = mis_auto::split(n, alpha);
                    drawn.clear();
                    let delta =
                        self.draw(scene, target, si, bsdf, counts, rng, counters, &mut drawn);
                    let sum = balance(&drawn, (counts.0 as f32, counts.1 as f32))
                        + per_light_sample(delta, counts.0);
                    (sum, Some(counts.1 as f32 / n as f32))
                } else {
                    let mut system = OptimalSystem::default();
                    for d in &drawn {
                        let mixture = warm as f32 * (d.pdf_light + d.pdf_bsdf);
                        system.add(d.weight, d.value, d.pdf_light, d.pdf_bsdf, mixture);
                    }
                    let a = system.solve();
                    // The rest keeps the requested proportion of light and BSDF samples.
                    let counts = mis_auto::split(n, n_bsdf as f32 / total as f32);
                    drawn.clear();
                    let delta =
                        self.draw(scene, target, si, bsdf, counts, rng, counters, &mut drawn);
                    let (n_l, n_b) = (counts.0 as f32, counts.1 as f32);
                    let sum = drawn.iter().fold(Rgb::ZERO, |acc, d| {
                        acc + d.weight
                            * optimal_term(
                                &a,
                                d.from_bsdf,
                                (n_l, n_b),
                                d.value,
                                d.pdf_light,
                                d.pdf_bsdf,
                            )
                    });
                    (sum + per_light_sample(delta, counts.0), None)
                };
                // Eq. 5.6: the two unbiased estimates weighted by their sample counts.
                let sum = (first * m as f32 + second * n as f32) / (m + n) as f32;
                (sum, alpha)
            };
            cell.set(drawn);
            result
        })
    }
}

/// s(w) of a light sample at `si`: the BSDF times the cosine times the light's radiance, zero
/// behind the surface or occluded (one shadow ray when the rest is non-zero).
fn light_sample_value(
    scene: &Scene,
    si: &SurfaceInteraction,
    bsdf: &Bsdf,
    wo_l: Vec3,
    wi_l: Vec3,
    ls: &LightSample,
    counters: &mut TraceCounters,
) -> Rgb {
    if !si.scatters_toward(ls.wi, wo_l, wi_l) {
        return Rgb::ZERO;
    }
    let v = bsdf.eval(wo_l, wi_l, Transport::Radiance) * wi_l.z.abs() * ls.radiance;
    if v == Rgb::ZERO {
        return v;
    }
    counters.rays += 1;
    if scene.unoccluded(si, ls) {
        v
    } else {
        Rgb::ZERO
    }
}

/// What one many-sample estimate integrates: the environment's light, or the light of the
/// lights `lights` chooses among (a [`LightSource`] of the emitters; `bsdf_finds_it` false for
/// delta lights, which get light samples only).
#[derive(Clone, Copy)]
enum Target<'a> {
    Environment(&'a EnvironmentMap),
    Emitters {
        lights: &'a LightSampler,
        bsdf_finds_it: bool,
    },
}

/// Whether the scene has a light other than its environment map (then the emitters get an
/// estimate of their own).
fn lights_other_than_environment(scene: &Scene) -> bool {
    let env = scene.environment().map(|(index, _)| index);
    scene.lights().len() > usize::from(env.is_some())
}

/// One environment sample of a shading point: its weight (a fractional cube-face sample's
/// share of eq. 3.6, else 1), which technique drew it, s(w), and both densities.
#[derive(Clone, Copy, Debug)]
struct Drawn {
    weight: f32,
    from_bsdf: bool,
    value: Rgb,
    pdf_light: f32,
    pdf_bsdf: f32,
}

thread_local! {
    /// The samples of one shading point, reused by every shading point of the thread.
    static DRAWN: std::cell::Cell<Vec<Drawn>> = const { std::cell::Cell::new(Vec::new()) };
}

/// The balance heuristic over the counts (eq. 3.7): sum of s / (n_L pdf_L + n_B pdf_B),
/// i.e. the mean of s / q over the n_L + n_B samples.
fn balance(drawn: &[Drawn], (n_light, n_bsdf): (f32, f32)) -> Rgb {
    drawn.iter().fold(Rgb::ZERO, |acc, d| {
        let q = n_light * d.pdf_light + n_bsdf * d.pdf_bsdf;
        if d.value == Rgb::ZERO || !(q > 0.0) {
            acc
        } else {
            acc + d.weight * d.value / q
        }
    })
}

/// The power heuristic (exponent 2) over the counts: a sample of technique i weighs
/// (n_i p_i)^2 / sum_k (n_k p_k)^2 and contributes that times s / (n_i p_i).
fn power(drawn: &[Drawn], (n_light, n_bsdf): (f32, f32)) -> Rgb {
    drawn.iter().fold(Rgb::ZERO, |acc, d| {
        let (l, b) = (n_light * d.pdf_light, n_bsdf * d.pdf_bsdf);
        let own = if d.from_bsdf { b } else { l };
        let q2 = l * l + b * b;
        if d.value == Rgb::ZERO || !(q2 > 0.0 && q2.is_finite()) {
            acc
        } else {
            acc + d.weight * d.value * (own / q2)
        }
    })
}

impl EnvDirect {
    /// The weighting in use: balance unless the settings name another (see
    /// [`IntegratorSettings::mis`]).
    fn mis(&self) -> MisHeuristic {
        super::mis_in_use("env_direct", &self.settings)
    }
}

impl Integrator for EnvDirect {
    fn name(&self) -> &'static str {
        "env_direct"
    }

    /// Finds the emitters' light sources (each gets its own estimate and, with `mis=auto`,
    /// its own alpha).
    fn prepare(
        &mut self,
        scene: &Scene,
        _camera: &Camera,
        _progress: &dyn Fn(&str, f64) -> bool,
    ) -> Result<Precomputation> {
        self.sources = light_sources(scene);
        Ok(Precomputation::default())
    }

    /// `mis=auto`: the `alpha` layer, R the fraction of BSDF samples chosen at the shaded
    /// point (zero where the sample shaded nothing) and G the fraction of samples that shaded
    /// a point, so a pixel's alpha is R / G ([`super::mis_auto::alpha_false_colour`] draws it).
    fn layers(&self) -> Vec<String> {
        if self.mis() == MisHeuristic::Auto {
            vec![ALPHA_LAYER.to_string()]
        } else {
            Vec::new()
        }
    }

    fn sample(
        &self,
        scene: &Scene,
        mut ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        ctx: &SampleContext,
    ) -> PixelSample {
        let mut out = PixelSample::default();
        let mut radiance = Rgb::ZERO;
        let mut beta = Rgb::ONE;
        let mut depth = 0u32;
        // Camera rays and mirror/glass bounces until the first non-specular surface.
        loop {
            counters.rays += 1;
            let Some(si) = scene.intersect(&ray) else {
                if let Some((_, env)) = scene.environment() {
                    if depth > 0 || env.visible_to_camera() {
                        radiance += beta * env.radiance(ray.dir);
                    }
                }
                break;
            };
            if depth == 0 {
                out.hit = true;
                out.depth = si.t;
                out.normal = si.ns;
            }
            radiance += beta * scene.emitted(&si);
            if depth >= self.settings.max_depth {
                break;
            }
            let bsdf = scene.bsdf(&si);
            if depth == 0 {
                out.albedo = bsdf.albedo_hint();
            }
            if !bsdf.is_delta() {
                let (shaded, alpha) = self.shade_with_alpha(scene, &si, rng, counters);
                radiance += beta * shaded;
                if let (Some(alpha), Some(layer)) = (alpha, ctx.layers.first()) {
                    layer.set(Rgb::new(alpha, 1.0, 0.0));
                }
                break;
            }
            let frame = si.shading_frame();
            let wo_local = frame.to_local(si.wo);
            let Some(bs) = bsdf.sample_from(wo_local, rng, Transport::Radiance) else {
                break;
            };
            let wi = frame.to_world(bs.wi);
            let reflected = bs.wi.z * wo_local.z > 0.0;
            let same_side = wi.dot(si.ng) * si.wo.dot(si.ng) > 0.0;
            if reflected != same_side {
                break;
            }
            beta *= bs.f * (bs.wi.z.abs() / bs.pdf);
            if !crate::math::is_finite3(beta) || beta == Rgb::ZERO {
                break;
            }
            ray = si.spawn_ray(wi);
            depth += 1;
        }
        out.radiance = radiance;
        out
    }
}

/// `env_direct` in the integrator registry: `samples=N` (light samples per shading point),
/// `bsdf=N` (BSDF samples), `alpha_steps=K` (`mis=auto`'s quadratic models, 1 = eq. 5.4) and
/// `warmup=M` (the warm-up's samples, both techniques);
/// the only integrator taking `mis=auto` and `mis=optimal`.
pub(super) const REGISTRATION: super::Registration = super::Registration {
    name: "env_direct",
    set_option: |settings, option| {
        match option.key {
            "samples" => settings.env_direct.light_samples = option.count()?,
            "bsdf" => settings.env_direct.bsdf_samples = option.count()?,
            "alpha_steps" => settings.env_direct.alpha_steps = option.count()?.max(1),
            "warmup" => settings.env_direct.warmup = Some(option.count()?),
            _ => return Ok(false),
        }
        Ok(true)
    },
    create: |settings| Ok(Box::new(EnvDirect::new(settings)?)),
    adaptive_mis: &[MisHeuristic::Auto, MisHeuristic::Optimal],
};

#[cfg(test)]
mod tests {
    use super::light_sources;
    use crate::light::LightDesc;
    use crate::math::{Rgb, Vec3};
    use crate::scene::{Material, MeshDesc, SceneBuilder};

    /// An emissive quad (two triangles sharing an edge) at height `y`, offset by `x`.
    fn lamp(b: &mut SceneBuilder, x: f32, y: f32, radiance: f32) {
        let m = b
            .add_material(Material::emissive(Rgb::splat(radiance)))
            .unwrap();
        b.add_mesh(MeshDesc {
            name: "lamp".into(),
            positions: vec![
                Vec3::new(x, y, 0.0),
                Vec3::new(x + 1.0, y, 0.0),
                Vec3::new(x + 1.0, y, 1.0),
                Vec3::new(x, y, 1.0),
            ],
            indices: vec![[0, 1, 2], [0, 2, 3]],
            materials: vec![m],
            ..Default::default()
        })
        .unwrap();
    }

    fn sources_of(build: impl Fn(&mut SceneBuilder)) -> Vec<(usize, bool)> {
        let mut b = SceneBuilder::new();
        build(&mut b);
        let scene = b.build().unwrap();
        let n = scene.lights().len();
        light_sources(&scene)
            .iter()
            .map(|s| {
                let members = (0..n).filter(|&i| s.sampler.pmf(i) > 0.0).count();
                (members, s.bsdf_finds_it)
            })
            .collect()
    }

    /// Point lights over a diffuse floor: each is evaluated once, so the estimate at a point
    /// is exact (the same for any random numbers) and equals the closed form
    /// sum_k albedo / pi * I_k cos(theta_k) / d_k^2; with more lights than N_L they are
    /// sampled by power instead, and agree in the mean.
    #[test]
    fn point_lights_are_evaluated_once_each_and_exactly() {
        use super::{EnvDirect, EnvDirectOptions};
        use crate::geometry::Ray;
        use crate::integrator::{IntegratorSettings, TraceCounters};
        use crate::math::{Sampler, SamplerKind};
        let albedo = 0.6;
        let lights = [
            (Vec3::new(0.0, 1.0, 0.0), 2.0),
            (Vec3::new(1.0, 2.0, 0.5), 5.0),
            (Vec3::new(-0.5, 0.5, -1.0), 1.0),
        ];
        let mut b = SceneBuilder::new();
        let m = b
            .add_material(Material::diffuse(Rgb::splat(albedo)))
            .unwrap();
        b.add_mesh(MeshDesc {
            name: "floor".into(),
            positions: vec![
                Vec3::new(-5.0, 0.0, -5.0),
                Vec3::new(5.0, 0.0, -5.0),
                Vec3::new(5.0, 0.0, 5.0),
                Vec3::new(-5.0, 0.0, 5.0),
            ],
            indices: vec![[0, 2, 1], [0, 3, 2]],
            materials: vec![m],
            ..Default::default()
        })
        .unwrap();
        for (position, intensity) in lights {
            b.add_light(LightDesc::Point {
                position,
                intensity: Rgb::splat(intensity),
            })
            .unwrap();
        }
        let scene = b.build().unwrap();
        let si = scene
            .intersect(&Ray::new(
                Vec3::new(0.2, 3.0, 0.1),
                Vec3::new(0.0, -1.0, 0.0),
                f32::INFINITY,
            ))
            .expect("the ray hits the floor");
        let expected: f32 = lights
            .iter()
            .map(|&(position, intensity)| {
                let d = position - si.p;
                albedo / crate::math::PI * intensity * d.normalize().y / d.length_squared()
            })
            .sum();
        let shade = |light_samples: u32, seed: u64| {
            let settings = IntegratorSettings {
                env_direct: EnvDirectOptions {
                    light_samples,
                    bsdf_samples: 4,
                    ..Default::default()
                },
                ..Default::default()
            };
            let mut direct = EnvDirect::new(settings).unwrap();
            direct.sources = light_sources(&scene);
            let mut rng = Sampler::new(SamplerKind::Independent, seed, 0, 0);
            let mut counters = TraceCounters::default();
            let value = direct.shade(&scene, &si, &mut rng, &mut counters);
            (value.x, counters.rays)
        };
        for seed in [1, 2, 3] {
            let (value, rays) = shade(3, seed);
            assert!(
                (value - expected).abs() <= 1e-5 * expected,
                "{value} against {expected}"
            );
            assert_eq!(rays, 3, "one shadow ray per light");
        }
        // Two samples for three lights: chosen by power, unbiased in the mean.
        let n = 20_000;
        let mean = (0..n).map(|seed| shade(2, seed).0 as f64).sum::<f64>() / n as f64;
        assert!(
            (mean - expected as f64).abs() < 0.01 * expected as f64,
            "{mean} against {expected}"
        );
    }

    #[test]
    fn a_source_is_a_connected_surface_of_one_radiance_and_the_delta_lights_are_one_more() {
        // One quad: its two triangles are one source.
        assert_eq!(sources_of(|b| lamp(b, 0.0, 2.0, 5.0)), vec![(2, true)]);
        // Two quads apart, and a point light: three sources.
        let mut two = sources_of(|b| {
            lamp(b, 0.0, 2.0, 50.0);
            lamp(b, 3.0, 2.0, 1.0);
            b.add_light(LightDesc::Point {
                position: Vec3::new(0.0, 1.0, 0.0),
                intensity: Rgb::ONE,
            })
            .unwrap();
        });
        two.sort();
        assert_eq!(two, vec![(1, false), (2, true), (2, true)]);
        // Two quads sharing an edge: one source if they emit alike, two otherwise.
        assert_eq!(
            sources_of(|b| {
                lamp(b, 0.0, 2.0, 5.0);
                lamp(b, 1.0, 2.0, 5.0);
            }),
            vec![(4, true)]
        );
        assert_eq!(
            sources_of(|b| {
                lamp(b, 0.0, 2.0, 5.0);
                lamp(b, 1.0, 2.0, 6.0);
            })
            .len(),
            2
        );
        // More separate lamps than MAX_LIGHT_SOURCES: one source of every emissive triangle.
        let many = sources_of(|b| {
            for i in 0..=super::MAX_LIGHT_SOURCES {
                lamp(b, 2.0 * i as f32, 2.0, 5.0);
            }
        });
        assert_eq!(many, vec![(2 * (super::MAX_LIGHT_SOURCES + 1), true)]);
    }
}
