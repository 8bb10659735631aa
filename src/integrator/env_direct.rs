//! `env_direct`: direct lighting from an environment map with many samples per shading point,
//! the estimator of 001 chapter 3 (eq. 3.5-3.7, Algorithm 2).
//!
//! At the first non-specular surface the camera ray reaches (after mirror and glass
//! bounces, up to `max_depth`), N_L light samples are split between the cube faces by the
//! strategy's face proportions mu_f (M_f = mu_f N_L samples on face f, a fractional count
//! with the last sample weighted by beta = frac(M_f), eq. 3.5-3.6), and N_B directions are
//! drawn from the BSDF. All are combined by the balance heuristic over the counts
//! (eq. 3.7, with the thesis's halves generalised to N_L / N and N_B / N, N = N_L + N_B):
//!
//!   L ~ 1/N [ sum_f sum_i beta_i s(w_i) / q(w_i) + sum_j s(w_j) / q(w_j) ],
//!   q(w) = (N_L mu_f(w) pdf_L(w | f(w)) + N_B pdf_B(w)) / N,
//!
//! where s = f |cos| L V. The sum of the weights beta over face f's samples is exactly
//! mu_f N_L, so the estimator is unbiased for any mu; mu_f(n) is zero only on faces that lie
//! wholly behind the surface, where s is zero. With the lat-long strategy all N_L samples
//! come from the 2-D lat-long density. Unlike the thesis's GPU version, every shading point
//! draws its own random samples (no sequence shared between pixels, so no spatial bias).
//!
//! Other lights contribute one light-sampled estimate per shading point (no MIS: BSDF
//! samples only look for the environment); with `max_depth` 1 this integrator therefore
//! estimates what `path --max-depth 1` does.

use super::{Integrator, IntegratorSettings, SampleContext, TraceCounters};
use crate::error::{Error, Result};
use crate::film::PixelSample;
use crate::geometry::Ray;
use crate::light::{EnvStrategy, EnvironmentMap, Light};
use crate::math::{Rgb, Sampler, Vec3};
use crate::scene::{Bsdf, Scene, SurfaceInteraction, Transport};

pub struct EnvDirect {
    settings: IntegratorSettings,
}

impl EnvDirect {
    pub fn new(settings: IntegratorSettings) -> Result<Self> {
        let light = if settings.env == EnvStrategy::BsdfOnly {
            0
        } else {
            settings.env_samples
        };
        if light + settings.env_bsdf_samples == 0 {
            return Err(Error::invalid(format!(
                "env_direct needs at least one light or BSDF sample per shading point (samples={}, bsdf={}, env={})",
                settings.env_samples,
                settings.env_bsdf_samples,
                settings.env.name()
            )));
        }
        Ok(EnvDirect { settings })
    }

    fn light_samples(&self) -> u32 {
        if self.settings.env == EnvStrategy::BsdfOnly {
            0
        } else {
            self.settings.env_samples
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
        let bsdf = scene.bsdf(si);
        if bsdf.is_delta() {
            return Rgb::ZERO;
        }
        let mut radiance = self.other_lights(scene, si, &bsdf, rng, counters);
        if let Some((_, env)) = scene.environment() {
            radiance += self.environment(scene, env, si, &bsdf, rng, counters);
        }
        radiance
    }

    /// One light-sampled estimate of the lights other than the environment.
    fn other_lights(
        &self,
        scene: &Scene,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
    ) -> Rgb {
        let Some(sampler) = scene.light_sampler() else {
            return Rgb::ZERO;
        };
        let (index, pmf) = sampler.sample(rng.uniform());
        let light = &scene.lights()[index];
        let u = rng.uniform2();
        if matches!(light, Light::Environment { .. }) {
            return Rgb::ZERO;
        }
        let Some(ls) = light.sample(si.p, u) else {
            return Rgb::ZERO;
        };
        if ls.wi.dot(si.ng) * si.wo.dot(si.ng) <= 0.0 {
            return Rgb::ZERO;
        }
        let frame = si.shading_frame();
        let wi_local = frame.to_local(ls.wi);
        let f = bsdf.eval(frame.to_local(si.wo), wi_local) * wi_local.z.abs();
        if f == Rgb::ZERO {
            return Rgb::ZERO;
        }
        counters.rays += 1;
        if !scene.unoccluded(si, &ls) {
            return Rgb::ZERO;
        }
        f * ls.radiance / (pmf * ls.pdf)
    }

    /// s(w) / q(w) for one environment direction, with `pdf_light` the light-sampling
    /// density already multiplied by N_L / N (the BSDF's share is added here).
    #[allow(clippy::too_many_arguments)]
    fn contribution(
        &self,
        scene: &Scene,
        env: &EnvironmentMap,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        wi: Vec3,
        q_light: f32,
        share_bsdf: f32,
        counters: &mut TraceCounters,
    ) -> Rgb {
        if wi.dot(si.ng) * si.wo.dot(si.ng) <= 0.0 {
            return Rgb::ZERO;
        }
        let frame = si.shading_frame();
        let (wo_l, wi_l) = (frame.to_local(si.wo), frame.to_local(wi));
        let f = bsdf.eval(wo_l, wi_l) * wi_l.z.abs();
        let le = env.radiance(wi);
        let value = f * le;
        if value == Rgb::ZERO {
            return Rgb::ZERO;
        }
        let q = q_light + share_bsdf * bsdf.pdf(wo_l, wi_l);
        if !(q > 0.0) {
            return Rgb::ZERO;
        }
        counters.rays += 1;
        if scene.occluded(&si.spawn_ray(wi)) {
            return Rgb::ZERO;
        }
        value / q
    }

    /// The many-sample environment estimate at a non-specular surface point.
    fn environment(
        &self,
        scene: &Scene,
        env: &EnvironmentMap,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
    ) -> Rgb {
        let strategy = self.settings.env;
        let n_light = self.light_samples();
        let n_bsdf = self.settings.env_bsdf_samples;
        let total = (n_light + n_bsdf) as f32;
        let (share_light, share_bsdf) = (n_light as f32 / total, n_bsdf as f32 / total);
        let normal = si.facing_normal();
        let mut sum = Rgb::ZERO;
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
                        let q_light = share_light * mu_f * pdf_f;
                        sum += beta
                            * self.contribution(
                                scene, env, si, bsdf, wi, q_light, share_bsdf, counters,
                            );
                    }
                }
            }
            _ => {
                for _ in 0..n_light {
                    let Some(s) = env.sample(strategy, normal, rng.uniform2()) else {
                        continue;
                    };
                    sum += self.contribution(
                        scene,
                        env,
                        si,
                        bsdf,
                        s.wi,
                        share_light * s.pdf,
                        share_bsdf,
                        counters,
                    );
                }
            }
        }
        let frame = si.shading_frame();
        let wo_l = frame.to_local(si.wo);
        for _ in 0..n_bsdf {
            let Some(bs) = bsdf.sample_from(wo_l, rng, Transport::Radiance) else {
                continue;
            };
            if bs.delta {
                continue;
            }
            let wi = frame.to_world(bs.wi);
            let q_light = share_light * env.pdf(strategy, normal, wi);
            sum += self.contribution(scene, env, si, bsdf, wi, q_light, share_bsdf, counters);
        }
        sum / total
    }
}

impl Integrator for EnvDirect {
    fn name(&self) -> &'static str {
        "env_direct"
    }

    fn sample(
        &self,
        scene: &Scene,
        mut ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        _ctx: &SampleContext,
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
                radiance += beta * self.shade(scene, &si, rng, counters);
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
