//! `path_portal`: path tracing guided through the portals of the opening-forest regions
//! (000 §10.4, lines 3033-3090), `strategy=shortest`: at every non-delta vertex the portal
//! guide ([`PortalGuide`], whose module docs give the mixture) proposes the rectangles of the
//! portals leading toward a light, and the next direction comes from them with the query's
//! guiding probability, from the BSDF otherwise. The samples are traced by `path`'s own loop
//! ([`PathTracer::trace`], through [`VertexGuide`]), so every density of a direction (the
//! throughput's denominator, the MIS weights of next-event estimation and of emitters or the
//! environment found) is that one-sample mixture's, and `path`'s options, `mis=auto` included,
//! apply unchanged: the estimator is `path`'s with another direction density.
//!
//! Where the guide guides nothing (no light in an empty region, no portal path: one room, an
//! open scene) every sample is `path`'s own sample, and the render summary says why.
//! `strategy=irradiance` (000 §10.4.2): the same loop with the regions' face distributions
//! ([`crate::guide::FaceIrradiance`], whose module docs give the density) instead of the
//! portals' rectangles.

use std::cell::RefCell;
use std::sync::Arc;

use super::path::{prepare_env_portals, set_path_option, PathTracer, VertexGuide};
use super::{
    Integrator, IntegratorSettings, MisHeuristic, Precomputation, SampleContext, TraceCounters,
};
use crate::error::{Error, Result};
use crate::film::PixelSample;
use crate::geometry::Ray;
use crate::guide::{FaceQuery, PortalGuide, PortalQuery, RenderEstimator};
use crate::math::Sampler;
use crate::scene::{Camera, Scene, SurfaceInteraction};

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
}

/// The portal guide and the query it initialises at each vertex, for `path`'s trace loop.
struct PortalVertexGuide<'a> {
    guide: &'a PortalGuide,
    query: &'a mut PortalQuery,
}

impl VertexGuide for PortalVertexGuide<'_> {
    type Query = PortalQuery;
    type Located = ();
    const GUIDED: bool = true;
    fn ratio_max(&self) -> f32 {
        self.guide.settings().ratio_max
    }
    fn prefetch(&self, _: &SurfaceInteraction) {}
    fn init(&mut self, _: &Scene, si: &SurfaceInteraction, _: (), c_max: f32) -> u64 {
        self.guide.init_query(self.query, si.p, si.facing_normal());
        self.query.cap_guiding_probability(c_max);
        0
    }
    fn clear(&mut self) {
        self.query.clear();
    }
    fn query(&self) -> &PortalQuery {
        self.query
    }
}

/// `strategy=irradiance`: the guide and its face query (a few dozen bytes, on the stack).
struct FaceVertexGuide<'a> {
    guide: &'a PortalGuide,
    query: FaceQuery<'a>,
}

impl<'a> VertexGuide for FaceVertexGuide<'a> {
    type Query = FaceQuery<'a>;
    type Located = ();
    const GUIDED: bool = true;
    fn ratio_max(&self) -> f32 {
        self.guide.settings().ratio_max
    }
    fn prefetch(&self, _: &SurfaceInteraction) {}
    fn init(&mut self, _: &Scene, si: &SurfaceInteraction, _: (), c_max: f32) -> u64 {
        self.guide
            .init_face_query(&mut self.query, si.p, si.facing_normal());
        self.query.cap_guiding_probability(c_max);
        0
    }
    fn clear(&mut self) {
        self.query.clear();
    }
    fn query(&self) -> &FaceQuery<'a> {
        &self.query
    }
}

impl Integrator for PortalPathTracer {
    fn name(&self) -> &'static str {
        "path_portal"
    }

    /// `mis=auto`: `path`'s `alpha` layer.
    fn layers(&self) -> Vec<String> {
        self.path.layers()
    }

    fn prepare(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        progress: &dyn Fn(&str, f64) -> bool,
    ) -> Result<Precomputation> {
        self.guide = None;
        let mut pre = prepare_env_portals(scene, &self.settings)?;
        self.path.prepare_roulette(scene, camera, &mut pre);
        self.settings.path.rr_start_depth = self.path.rr_start_depth();
        let estimator = RenderEstimator {
            mis: self.settings.mis.unwrap_or_default(),
            triangles: self.settings.path.triangles,
            env: self.settings.env,
        };
        let guide = PortalGuide::build(
            scene,
            &self.settings.portal,
            Some((camera, estimator, self.settings.max_depth)),
            progress,
        )?;
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
        if let Some(query) = guide.face_query() {
            let guided = &mut FaceVertexGuide { guide, query };
            return self
                .path
                .sample_with(scene, ray, rng, counters, ctx, guided);
        }
        THREAD_QUERY.with(|cell| match cell.try_borrow_mut() {
            Ok(mut query) => {
                let guided = &mut PortalVertexGuide {
                    guide,
                    query: &mut query,
                };
                self.path
                    .sample_with(scene, ray, rng, counters, ctx, guided)
            }
            // Only if a host re-entered the renderer from inside a sample on this thread.
            Err(_) => {
                let guided = &mut PortalVertexGuide {
                    guide,
                    query: &mut PortalQuery::new(),
                };
                self.path
                    .sample_with(scene, ray, rng, counters, ctx, guided)
            }
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
    adaptive_mis: &[MisHeuristic::Auto],
};
