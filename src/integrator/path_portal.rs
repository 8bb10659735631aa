//! `path_portal`: path tracing guided through the portals of the opening-forest regions
//! (000 §10.4, lines 3033-3090), `strategy=shortest`: at every non-delta vertex the portal
//! guide ([`PortalGuide`], whose module docs give the mixture) proposes the rectangles of the
//! portals leading toward a light, and the next direction comes from them with the query's
//! guiding probability, from the BSDF otherwise. Every density of a direction (the
//! throughput's denominator, the MIS weights of next-event estimation and of emitters or the
//! environment found) is that one-sample mixture's, exactly as in `path_skeleton`
//! (integrator/path.rs), so the estimator is `path`'s with another direction density.
//!
//! Where the guide guides nothing (no light in an empty region, no portal path: one room, an
//! open scene) every sample is `path`'s own sample, and the render summary says why.
//! `strategy=irradiance` (000 §10.4.2) is not implemented and refused.

use std::cell::RefCell;
use std::sync::Arc;

use super::path::{
    prepare_env_portals, set_path_option, slot, PathTracer, DIRECTION_SLOT, LIGHT_SLOT,
    ROULETTE_SLOT,
};
use super::{Integrator, IntegratorSettings, Precomputation, SampleContext, TraceCounters};
use crate::error::{Error, Result};
use crate::film::PixelSample;
use crate::geometry::Ray;
use crate::guide::{
    estimator, sample_bsdf_or_guide, DirectionGuide, PortalGuide, PortalQuery, RenderEstimator,
};
use crate::math::{Rgb, Sampler, Vec3};
use crate::scene::{Camera, Scene};

pub struct PortalPathTracer {
    settings: IntegratorSettings,
    /// `path` itself, for scenes the guide guides nothing in.
    path: PathTracer,
    guide: Option<Arc<PortalGuide>>,
}

thread_local! {
    /// One query per thread, re-initialised at every vertex (about 1.3 KB: not per sample).
    static THREAD_QUERY: RefCell<PortalQuery> = const { RefCell::new(PortalQuery::new()) };
}

impl PortalPathTracer {
    pub fn new(settings: IntegratorSettings) -> Result<Self> {
        settings.portal.validate()?;
        Ok(PortalPathTracer {
            settings,
            path: PathTracer::new(settings),
            guide: None,
        })
    }

    /// The guide the last `prepare` built.
    pub fn guide(&self) -> Option<&Arc<PortalGuide>> {
        self.guide.as_ref()
    }

    fn estimator(&self) -> RenderEstimator {
        RenderEstimator {
            mis: self.settings.mis.unwrap_or_default(),
            triangles: self.settings.path.triangles,
            env: self.settings.env,
        }
    }

    /// One camera path, guided by `guide` through `query`.
    fn trace(
        &self,
        scene: &Scene,
        mut ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        guide: &PortalGuide,
        query: &mut PortalQuery,
    ) -> PixelSample {
        let estimator = self.estimator();
        let mis = estimator.mis;
        let mut out = PixelSample::default();
        let mut radiance = Rgb::ZERO;
        let mut beta = Rgb::ONE;
        // The throughput BSDF sampling alone would carry, for Russian roulette.
        let mut rr_beta = Rgb::ONE;
        // The product of p_bsdf / pdf over the directions so far (`ratio_max`).
        let mut ratio = 1.0f32;
        let ratio_max = guide.settings().ratio_max;
        let mut prev_delta = true;
        let mut prev_pdf = 0.0f32;
        let mut prev_point = ray.origin;
        let mut prev_normal = Vec3::ZERO;
        let mut depth = 0u32;
        loop {
            counters.rays += 1;
            let Some(si) = scene.intersect(&ray) else {
                if let Some((_, env)) = scene.environment() {
                    if depth > 0 || env.visible_to_camera() {
                        if let Some((le, light_pdf)) = estimator::environment_along(
                            scene,
                            prev_point,
                            prev_normal,
                            ray.dir,
                            &estimator,
                        ) {
                            let weight = if prev_delta {
                                1.0
                            } else {
                                mis.weight(prev_pdf, light_pdf)
                            };
                            radiance += beta * le * weight;
                        }
                    }
                }
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
                    let light_pdf =
                        estimator::emitter_light_pdf(scene, prev_point, &si, &estimator);
                    mis.weight(prev_pdf, light_pdf)
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
            // No guiding at delta BSDFs: no mixture with a Dirac lobe has a density.
            if bsdf.is_delta() {
                query.clear();
            } else {
                guide.init_query(query, si.p, si.facing_normal());
                // Worst case after this vertex: ratio / (1 - c) <= ratio_max.
                query.cap_guiding_probability(1.0 - ratio / ratio_max);
                rng.set_dimension(slot(depth, LIGHT_SLOT));
                let u = rng.uniform2();
                if let Some(light) = estimator::sample_direct_light(
                    scene,
                    &si,
                    &frame,
                    &bsdf,
                    wo_local,
                    &estimator,
                    u,
                    &mut counters.rays,
                ) {
                    let direction_pdf = if light.delta {
                        0.0
                    } else {
                        query.mixture_pdf(light.wi, bsdf.pdf(wo_local, light.wi_local))
                    };
                    radiance += beta * light.weighted(light.weight(mis, direction_pdf));
                }
            }
            rng.set_dimension(slot(depth, DIRECTION_SLOT));
            let Some(ms) = sample_bsdf_or_guide(&bsdf, wo_local, &frame, &*query, rng) else {
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
            beta *= bs.f * (bs.wi.z.abs() / bs.pdf);
            rr_beta *= bs.f * (bs.wi.z.abs() / ms.bsdf_pdf);
            ratio *= ms.bsdf_pdf / bs.pdf;
            counters.largest_guided_ratio = counters.largest_guided_ratio.max(ratio);
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

impl Integrator for PortalPathTracer {
    fn name(&self) -> &'static str {
        "path_portal"
    }

    fn prepare(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        progress: &dyn Fn(&str, f64) -> bool,
    ) -> Result<Precomputation> {
        self.guide = None;
        let mut pre = prepare_env_portals(scene, &self.settings)?;
        let _ = camera;
        let guide = PortalGuide::build(scene, &self.settings.portal, progress)?;
        pre.stages.extend_from_slice(guide.timings());
        pre.notes.push(guide.note());
        if let Some(why) = guide.unguided() {
            pre.notes.push(format!(
                "path_portal guides nothing: {why}; rendering path's samples"
            ));
        }
        self.guide = Some(Arc::new(guide));
        Ok(pre)
    }

    fn check_prepared(&self, scene: &Scene) -> Result<()> {
        match &self.guide {
            Some(g) if g.built_for(scene) => Ok(()),
            Some(_) => Err(Error::invalid(
                "path_portal was prepared for another scene: prepare it for this one",
            )),
            None => Err(Error::invalid(
                "path_portal needs its portal guide: prepare the integrator for the scene before rendering",
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
        let Some(guide) = self.guide.as_deref().filter(|g| g.unguided().is_none()) else {
            return self.path.sample(scene, ray, rng, counters, ctx);
        };
        THREAD_QUERY.with(|cell| match cell.try_borrow_mut() {
            Ok(mut query) => self.trace(scene, ray, rng, counters, guide, &mut query),
            // Only if a host re-entered the renderer from inside a sample on this thread.
            Err(_) => self.trace(scene, ray, rng, counters, guide, &mut PortalQuery::new()),
        })
    }
}

/// `path_portal` in the integrator registry: `path`'s options, then the portal guide's.
pub(super) const REGISTRATION: super::Registration = super::Registration {
    name: "path_portal",
    set_option: |settings, option| {
        if set_path_option(settings, option)? {
            return Ok(true);
        }
        settings.portal.set(option.key, option.value)
    },
    create: |settings| Ok(Box::new(PortalPathTracer::new(settings)?)),
    adaptive_mis: &[],
};
