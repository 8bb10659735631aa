//! The path tracer's estimator at one vertex, written once: next-event estimation (one light
//! sample and its shadow ray) and the light densities that weigh an emitter or the
//! environment found by a sampled direction. `path` and `path_skeleton` (integrator/path.rs)
//! render with it, and the guide's training pass (`guide::training`) scores its candidates
//! with it, so that the training judges exactly the estimate the render makes. The MIS weight
//! itself is the render's heuristic ([`MisHeuristic::weight`]) of these densities against the
//! direction density, which the caller knows (BSDF, or the guided mixture).

use super::RenderEstimator;
use crate::math::{Frame, MisHeuristic, Rgb, Vec2, Vec3};
use crate::scene::{Bsdf, Scene, SurfaceInteraction};

/// One unoccluded light sample at a vertex.
#[derive(Clone, Copy, Debug)]
pub struct DirectLight {
    /// f(wo, wi) |cos(wi)| and the light's radiance toward the vertex (kept apart so that
    /// every caller multiplies them in the same order).
    pub f_cos: Rgb,
    pub radiance: Rgb,
    /// Light sampling's density of the sample: the light's pmf times its pdf.
    pub light_pdf: f32,
    /// A delta light (a point or a direction): MIS weight 1 against any direction density.
    pub delta: bool,
    /// The light direction, in world space and in the shading frame.
    pub wi: Vec3,
    pub wi_local: Vec3,
}

impl DirectLight {
    /// The density the MIS weights compare with a direction density: `light_pdf`, infinite
    /// for a delta light.
    pub fn mis_pdf(&self) -> f32 {
        if self.delta {
            f32::INFINITY
        } else {
            self.light_pdf
        }
    }

    /// The sample's MIS weight against direction sampling of density `direction_pdf` at its
    /// direction (1 for a delta light).
    pub fn weight(&self, mis: MisHeuristic, direction_pdf: f32) -> f32 {
        if self.delta {
            1.0
        } else {
            mis.weight(self.light_pdf, direction_pdf)
        }
    }

    /// The estimate with MIS weight `weight`: f |cos| L w / p_light.
    pub fn weighted(&self, weight: f32) -> Rgb {
        self.f_cos * self.radiance * (weight / self.light_pdf)
    }

    /// The unweighted estimate f |cos| L / p_light.
    pub fn unweighted(&self) -> Rgb {
        self.f_cos * self.radiance / self.light_pdf
    }
}

/// Next-event estimation at `si` (shading `frame`, `bsdf`, `wo_local` = `si.wo` in that frame)
/// from the sampler's 2-D `u`, with the render's light sampling `estimator`: the light sample
/// if it can contribute and nothing blocks it (None otherwise). `shadow_rays` counts the
/// shadow ray when one is traced.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub fn sample_direct_light(
    scene: &Scene,
    si: &SurfaceInteraction,
    frame: &Frame,
    bsdf: &Bsdf,
    wo_local: Vec3,
    estimator: &RenderEstimator,
    u: Vec2,
    shadow_rays: &mut u64,
) -> Option<DirectLight> {
    let toward = scene.sample_light_toward(
        si,
        frame,
        bsdf,
        wo_local,
        estimator.env,
        estimator.triangles,
        u,
    )?;
    let ls = toward.sample;
    // A zero density would make an infinite estimate of something light sampling never draws.
    if !(ls.pdf > 0.0) {
        return None;
    }
    *shadow_rays += 1;
    if !scene.unoccluded(si, &ls) {
        return None;
    }
    Some(DirectLight {
        f_cos: toward.f_cos,
        radiance: ls.radiance,
        light_pdf: toward.pmf * ls.pdf,
        delta: ls.delta,
        wi: ls.wi,
        wi_local: toward.wi_local,
    })
}

/// The density with which light sampling at `from` draws the point of emitter `hit` (the
/// emitting triangle's light's pmf times its pdf, as [`sample_direct_light`] draws it); 0 if
/// the triangle is no light.
pub fn emitter_light_pdf(
    scene: &Scene,
    from: Vec3,
    hit: &SurfaceInteraction,
    estimator: &RenderEstimator,
) -> f32 {
    scene.triangle_light(hit.triangle).map_or(0.0, |light| {
        let pmf = scene.light_sampler().map_or(0.0, |s| s.pmf(light));
        pmf * scene.lights()[light].pdf_with(from, hit.p, estimator.triangles)
    })
}

/// The environment's radiance along `dir`, leaving a vertex at `point` of facing normal
/// `normal`, and the density with which light sampling there draws `dir` (None without an
/// environment). The point matters for `env=portals` (the portals a point sees depend on
/// where it is).
pub fn environment_along(
    scene: &Scene,
    point: Vec3,
    normal: Vec3,
    dir: Vec3,
    estimator: &RenderEstimator,
) -> Option<(Rgb, f32)> {
    let (index, env) = scene.environment()?;
    let pmf = scene.light_sampler().map_or(0.0, |s| s.pmf(index));
    let pdf = scene.environment_pdf_at(estimator.env, point, normal, dir);
    Some((env.radiance(dir), pmf * pdf))
}
