//! The training's path tracer: camera paths that sample guided vertices from the training
//! proposal, as `path_skeleton` does, and record at each one a [`Sample`] with the
//! contribution the rest of the path brings back (module docs of `training`, "Training
//! pass").

use std::sync::atomic::{AtomicU32, Ordering as AtomicOrdering};

use super::prediction::{PathLog, PathRecord, Step};
use super::statistics::{NeeTerms, Sample, NO_STEP};
use super::MAX_STRENGTHS;
use crate::guide::directional::{self};
use crate::guide::estimator::{self, DirectLight};
use crate::guide::MAX_LOBES;
use crate::guide::{
    sample_bsdf_or_guide, GuideQuery, RenderEstimator, SkeletonGuide, SkeletonStrength,
};
use crate::math::{luminance, Rgb, Sampler, Vec3};
use crate::scene::{Scene, SurfaceInteraction};

/// What the training paths visited, for the scene-level prediction: all their vertices, and
/// per voxel of the grid its non-delta ones (where the render maps points to nodes).
pub(super) struct Visits<'a> {
    pub(super) vertices: u64,
    pub(super) per_voxel: &'a [AtomicU32],
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
pub(super) struct TrainingVertex {
    /// The sample, `f_reflected` still to be filled in; None at vertices that are not guided.
    pub(super) sample: Option<Sample>,
    /// Path throughput up to this vertex, and f_s |cos| / q of its sampled direction.
    pub(super) beta: Rgb,
    pub(super) f_cos: Rgb,
    pub(super) weight: Rgb,
    /// One light sample reflected at the next vertex toward this one (unweighted).
    pub(super) direct: Rgb,
}

/// One training path from its first hit `si` (module docs), appending the samples of its
/// guided vertices to `out`. The radiance arriving along a vertex's sampled direction is
/// L_e(x') + R(x'), with R the reflected radiance the rest of the path estimates by next-event
/// estimation alone: R(x_i) = NEE(x_i) + f_s |cos| / q (x_i) R(x_i+1) (no emission beyond the
/// first, which NEE accounts for), computed backwards once the path ends. Each vertex's own
/// light sample is also recorded with its sample (the same draw the previous vertex's R uses).
#[allow(clippy::too_many_arguments)]
pub(super) fn train_path(
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
                let p_skel = query.pdf(l.wi);
                nee = NeeTerms {
                    value,
                    p_light: l.mis_pdf(),
                    wi: l.wi,
                    p_bsdf: bsdf.pdf(wo_local, l.wi_local),
                    p_skel,
                    p_strength: strength_pdfs(query, l.wi, strengths, p_skel),
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
                let p_skel = query.pdf(wi);
                Sample {
                    wi,
                    f_emitted: if f_emitted.is_finite() {
                        f_emitted.max(0.0)
                    } else {
                        0.0
                    },
                    p_bsdf: bsdf.pdf(wo_local, bs.wi),
                    p_skel,
                    p_strength: strength_pdfs(query, wi, strengths, p_skel),
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
pub(super) fn finite_luminance(x: Rgb) -> f32 {
    let l = luminance(x);
    if l.is_finite() {
        l.max(0.0)
    } else {
        0.0
    }
}

/// The guide's density at `wi` under each candidate strength, given its density `pdf` there.
pub(super) fn strength_pdfs(
    query: &GuideQuery,
    wi: Vec3,
    strengths: &[SkeletonStrength],
    pdf: f32,
) -> [f32; MAX_STRENGTHS] {
    let mut p = [0.0; MAX_STRENGTHS];
    for (p, &s) in p.iter_mut().zip(strengths) {
        *p = query.pdf_with_strength_given(wi, s, pdf);
    }
    p
}

/// Emitted radiance arriving at `si` along `wi` (L_e of the next vertex `next`, or the
/// environment's), and the density with which the render's light sampling at `si` draws
/// that direction (pmf x pdf, as `path` weighs a BSDF-sampled hit; 0 if it is no light): the
/// render's own densities ([`estimator::emitter_light_pdf`], [`estimator::environment_along`]).
pub(super) fn arriving_emission(
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
        None => estimator::environment_along(scene, si.p, si.facing_normal(), wi, render)
            .unwrap_or((Rgb::ZERO, 0.0)),
    }
}

/// The render's light sample at `si` ([`estimator::sample_direct_light`]; None where it
/// carries nothing: a delta BSDF, no light, occluded).
pub(super) fn light_sample(
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
