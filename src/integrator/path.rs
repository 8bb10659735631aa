//! Unidirectional path tracing (000 §4.1, lines 1214-1304): BSDF sampling plus next-event
//! estimation at every non-delta vertex, combined by MIS (Veach's one-sample-per-strategy
//! estimator), with Russian roulette.

use super::{Integrator, IntegratorSettings, SampleContext, TraceCounters};
use crate::film::PixelSample;
use crate::geometry::Ray;
use crate::math::{Frame, Rgb, Rng, Vec3};
use crate::scene::{Bsdf, Scene, SurfaceInteraction, Transport};

pub struct PathTracer {
    settings: IntegratorSettings,
}

impl PathTracer {
    pub fn new(settings: IntegratorSettings) -> Self {
        PathTracer { settings }
    }

    /// Next-event estimation: radiance from one light sample, MIS-weighted against BSDF
    /// sampling. `wo` is local to the shading frame.
    #[allow(clippy::too_many_arguments)]
    fn sample_light(
        &self,
        scene: &Scene,
        si: &SurfaceInteraction,
        frame: &Frame,
        bsdf: &Bsdf,
        wo_local: Vec3,
        rng: &mut Rng,
        counters: &mut TraceCounters,
    ) -> Rgb {
        let Some(sampler) = scene.light_sampler() else {
            return Rgb::ZERO;
        };
        let (index, pmf) = sampler.sample(rng.uniform());
        let light = &scene.lights()[index];
        let Some(ls) = light.sample_at(si.p, si.facing_normal(), self.settings.env, rng.uniform2())
        else {
            return Rgb::ZERO;
        };
        // Reflection must stay on the side of the geometric surface that wo is on, or
        // shading normals would let light through walls.
        if ls.wi.dot(si.ng) * si.wo.dot(si.ng) <= 0.0 {
            return Rgb::ZERO;
        }
        let wi_local = frame.to_local(ls.wi);
        let f = bsdf.eval(wo_local, wi_local) * wi_local.z.abs();
        if f == Rgb::ZERO {
            return Rgb::ZERO;
        }
        counters.rays += 1;
        if !scene.unoccluded(si, &ls) {
            return Rgb::ZERO;
        }
        let light_pdf = pmf * ls.pdf;
        let weight = if ls.delta {
            1.0
        } else {
            self.settings
                .mis
                .weight(light_pdf, bsdf.pdf(wo_local, wi_local))
        };
        f * ls.radiance * (weight / light_pdf)
    }

    /// Radiance of the environment along a ray that left the scene, MIS-weighted against
    /// the environment's light sampling at the vertex the ray left (normal `prev_normal`);
    /// camera rays see it unless it is hidden.
    fn escaped(
        &self,
        scene: &Scene,
        dir: Vec3,
        depth: u32,
        prev_delta: bool,
        prev_pdf: f32,
        prev_normal: Vec3,
    ) -> Rgb {
        let Some((index, env)) = scene.environment() else {
            return Rgb::ZERO;
        };
        if depth == 0 && !env.visible_to_camera() {
            return Rgb::ZERO;
        }
        let le = env.radiance(dir);
        if prev_delta || le == Rgb::ZERO {
            return le;
        }
        let pmf = scene.light_sampler().map_or(0.0, |s| s.pmf(index));
        let light_pdf = pmf * env.pdf(self.settings.env, prev_normal, dir);
        le * self.settings.mis.weight(prev_pdf, light_pdf)
    }
}

impl Integrator for PathTracer {
    fn name(&self) -> &'static str {
        "path"
    }

    fn sample(
        &self,
        scene: &Scene,
        mut ray: Ray,
        rng: &mut Rng,
        counters: &mut TraceCounters,
        _ctx: &SampleContext,
    ) -> PixelSample {
        let mut out = PixelSample::default();
        let mut radiance = Rgb::ZERO;
        let mut beta = Rgb::ONE;
        // State of the previous vertex, for MIS when a BSDF-sampled ray hits an emitter.
        let mut prev_delta = true;
        let mut prev_pdf = 0.0f32;
        let mut prev_point = ray.origin;
        let mut prev_normal = Vec3::ZERO;
        let mut depth = 0u32;
        loop {
            counters.rays += 1;
            let Some(si) = scene.intersect(&ray) else {
                radiance +=
                    beta * self.escaped(scene, ray.dir, depth, prev_delta, prev_pdf, prev_normal);
                break;
            };
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
                    let light = scene
                        .triangle_light(si.triangle)
                        .expect("emitting triangle is a light");
                    let pmf = scene.light_sampler().map_or(0.0, |s| s.pmf(light));
                    let light_pdf = pmf * scene.lights()[light].pdf(prev_point, si.p);
                    self.settings.mis.weight(prev_pdf, light_pdf)
                };
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
            if !bsdf.is_delta() {
                radiance +=
                    beta * self.sample_light(scene, &si, &frame, &bsdf, wo_local, rng, counters);
            }

            let uc = rng.uniform();
            let Some(bs) = bsdf.sample(wo_local, uc, rng.uniform2(), Transport::Radiance) else {
                break;
            };
            let wi = frame.to_world(bs.wi);
            // Reflections must leave on wo's side of the geometric surface, transmissions on
            // the other side; shading normals can disagree near silhouettes.
            let reflected = bs.wi.z * wo_local.z > 0.0;
            let same_side = wi.dot(si.ng) * si.wo.dot(si.ng) > 0.0;
            if reflected != same_side {
                break;
            }
            beta *= bs.f * (bs.wi.z.abs() / bs.pdf);
            if !crate::math::is_finite3(beta) || beta == Rgb::ZERO {
                break;
            }
            prev_delta = bs.delta;
            prev_pdf = bs.pdf;
            prev_point = si.p;
            prev_normal = si.facing_normal();
            ray = si.spawn_ray(wi);
            depth += 1;

            if depth >= self.settings.rr_start_depth {
                let q = (1.0 - beta.max_element()).max(0.05);
                if rng.uniform() < q {
                    break;
                }
                beta /= 1.0 - q;
            }
        }
        out.radiance = radiance;
        out
    }
}
