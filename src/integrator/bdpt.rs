//! Bidirectional path tracing (000 §4.1.3 and §4.3; Veach 1997 ch. 10) with every (s, t)
//! strategy: camera paths hitting emitters (s = 0), direct light sampling (s = 1),
//! connections of camera vertices to stored light vertices (s >= 2, t >= 2) and light tracing
//! onto the film (t = 1, splatted).
//!
//! MIS weights are computed in O(1) per connection from two partial sums carried along each
//! subpath (`d_vcm`, `d_vc`), the recursive formulation of Antwerpen (2011) in the notation of
//! Georgiev, "Implementing Vertex Connection and Merging" (2012), without the merging terms.
//! `mis(x)` is x for the balance heuristic and x^2 for the power heuristic.
//!
//! Light subpaths are traced once per sample index ("iteration") for the whole image into a
//! vertex pool; each camera path then connects to the light subpath a [`ConnectionPolicy`]
//! picks (by default its own, one per pixel): the shape SkelBPT's resampling builds on.
//! Russian roulette uses a per-vertex continuation probability (the BSDF's albedo), folded
//! into both the forward and the reverse pdfs so the weights stay exact.

use rayon::prelude::*;

use super::{
    Integrator, IntegratorSettings, Iteration, MisHeuristic, SampleContext, TraceCounters, View,
};
use crate::error::{Error, Result};
use crate::film::PixelSample;
use crate::geometry::{offset_ray_origin, Ray};
use crate::light::Light;
use crate::math::{Rgb, Rng, Vec3};
use crate::scene::{Bsdf, Scene, SurfaceInteraction, Transport};

/// Chooses the light subpath a camera path connects to.
pub trait ConnectionPolicy: Send + Sync {
    fn light_path_for(&self, pixel_index: u64, light_paths: usize) -> usize;
}

/// Each pixel connects to "its" light subpath (index = pixel index modulo their number).
pub struct UniformPerPixel;

impl ConnectionPolicy for UniformPerPixel {
    fn light_path_for(&self, pixel_index: u64, light_paths: usize) -> usize {
        (pixel_index % light_paths.max(1) as u64) as usize
    }
}

/// A stored light subpath vertex (never on a delta BSDF).
#[derive(Clone, Copy, Debug)]
struct LightVertex {
    si: SurfaceInteraction,
    throughput: Rgb,
    /// Segments from the light to this vertex.
    path_len: u32,
    d_vcm: f32,
    d_vc: f32,
}

/// The light subpaths of one iteration.
struct LightPaths {
    vertices: Vec<LightVertex>,
    /// Range of `vertices` of each light subpath.
    ranges: Vec<(u32, u32)>,
}

/// What one parallel task of light tracing produced: vertices, per-path ranges (relative to
/// the chunk), splats and rays traced.
type LightPathChunk = (Vec<LightVertex>, Vec<(u32, u32)>, Vec<(u32, Rgb)>, u64);

/// Throughput and MIS partial sums of a subpath being extended.
#[derive(Clone, Copy, Debug)]
struct SubpathState {
    throughput: Rgb,
    path_len: u32,
    d_vcm: f32,
    d_vc: f32,
    finite_light: bool,
}

/// Restricts a render to one (s, t) strategy, for debugging and for testing each strategy
/// alone (000 Figure 22): s light vertices, t camera vertices (t counts the camera itself).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StrategyFilter {
    pub s: u32,
    pub t: u32,
    /// Without MIS weights: the strategy's own (unbiased, often noisy) estimate of paths of
    /// s + t - 1 segments.
    pub unweighted: bool,
}

pub struct Bdpt {
    settings: IntegratorSettings,
    strategy: Option<StrategyFilter>,
    /// Light subpaths per iteration; `None` = one per pixel.
    light_paths: Option<usize>,
    policy: Box<dyn ConnectionPolicy>,
}

/// Stream offset separating light-subpath random numbers from camera-path ones.
const LIGHT_STREAM: u64 = 0x9E6C_63D0_676A_9A99;

impl Bdpt {
    pub fn new(settings: IntegratorSettings) -> Self {
        Bdpt {
            settings,
            strategy: None,
            light_paths: None,
            policy: Box::new(UniformPerPixel),
        }
    }

    /// Sets the number of light subpaths traced per iteration (default: one per pixel).
    pub fn with_light_paths(mut self, count: usize) -> Result<Self> {
        if count == 0 {
            return Err(Error::invalid(
                "bdpt: light subpaths per iteration must be at least 1",
            ));
        }
        self.light_paths = Some(count);
        Ok(self)
    }

    /// Keeps only the contributions of one strategy.
    pub fn with_strategy(mut self, filter: StrategyFilter) -> Self {
        self.strategy = Some(filter);
        self
    }

    /// Factor applied to the unweighted contribution of strategy (s, t) with MIS weight
    /// `weight`.
    #[inline]
    fn keep(&self, s: u32, t: u32, weight: f32) -> f32 {
        match self.strategy {
            None => weight,
            Some(f) if f.s == s && f.t == t => {
                if f.unweighted {
                    1.0
                } else {
                    weight
                }
            }
            Some(_) => 0.0,
        }
    }

    pub fn with_policy(mut self, policy: Box<dyn ConnectionPolicy>) -> Self {
        self.policy = policy;
        self
    }

    #[inline]
    fn mis(&self, x: f32) -> f32 {
        match self.settings.mis {
            MisHeuristic::Balance => x,
            MisHeuristic::Power => x * x,
        }
    }

    /// Longest path in segments.
    fn max_len(&self) -> u32 {
        self.settings.max_depth + 1
    }

    fn light_path_count(&self, view: &View) -> usize {
        self.light_paths
            .unwrap_or(view.width as usize * view.height as usize)
    }

    /// Traces one light subpath, storing its vertices and splatting its light-tracing (t = 1)
    /// contributions.
    #[allow(clippy::too_many_arguments)]
    fn trace_light_path(
        &self,
        scene: &Scene,
        view: &View,
        n_light: f32,
        rng: &mut Rng,
        vertices: &mut Vec<LightVertex>,
        splats: &mut Vec<(u32, Rgb)>,
        counters: &mut TraceCounters,
    ) {
        let Some(sampler) = scene.light_sampler() else {
            return;
        };
        let (index, pick) = sampler.sample(rng.uniform());
        let light = &scene.lights()[index];
        let Some(es) =
            light.sample_emission_with(self.settings.env, rng.uniform2(), rng.uniform2())
        else {
            return;
        };
        let emission_pdf_w = es.pdf_emit * pick;
        let direct_pdf_a = es.pdf_direct_area * pick;
        if !(emission_pdf_w > 0.0) {
            return;
        }
        let used_cos = if light.is_finite() { es.cos_light } else { 1.0 };
        let mut state = SubpathState {
            throughput: es.value / emission_pdf_w,
            path_len: 1,
            d_vcm: self.mis(direct_pdf_a / emission_pdf_w),
            d_vc: if light.is_delta() {
                0.0
            } else {
                self.mis(used_cos / emission_pdf_w)
            },
            finite_light: light.is_finite(),
        };
        let origin = offset_ray_origin(es.origin, es.origin_error, es.normal, es.dir);
        let mut ray = Ray::new(origin, es.dir, f32::INFINITY);
        loop {
            counters.rays += 1;
            let Some(si) = scene.intersect(&ray) else {
                break;
            };
            let cos_in = si.ns.dot(si.wo).abs();
            if cos_in == 0.0 {
                break;
            }
            if state.path_len == 1 && matches!(light, Light::Environment { .. }) {
                // Direct sampling of an environment direction depends on the receiver's
                // normal, known only now: the density of choosing this direction from here.
                let direct_pdf_w =
                    light.direction_pdf(si.facing_normal(), self.settings.env, si.wo);
                state.d_vcm = self.mis(direct_pdf_w * pick / emission_pdf_w);
            }
            if state.path_len > 1 || state.finite_light {
                state.d_vcm *= self.mis(si.t * si.t);
            }
            state.d_vcm /= self.mis(cos_in);
            state.d_vc /= self.mis(cos_in);
            let bsdf = scene.bsdf(&si);
            if !bsdf.is_delta() {
                let vertex = LightVertex {
                    si,
                    throughput: state.throughput,
                    path_len: state.path_len,
                    d_vcm: state.d_vcm,
                    d_vc: state.d_vc,
                };
                if state.path_len < self.max_len() {
                    self.connect_to_camera(scene, view, n_light, &vertex, &bsdf, splats, counters);
                }
                if state.path_len + 2 <= self.max_len() {
                    vertices.push(vertex);
                }
            }
            if state.path_len + 2 > self.max_len() {
                break;
            }
            let Some(wi) = self.scatter(&bsdf, &si, &mut state, rng, Transport::Importance) else {
                break;
            };
            ray = si.spawn_ray(wi);
            state.path_len += 1;
        }
    }

    /// Light tracing (t = 1): the light vertex seen by the pinhole camera.
    #[allow(clippy::too_many_arguments)]
    fn connect_to_camera(
        &self,
        scene: &Scene,
        view: &View,
        n_light: f32,
        v: &LightVertex,
        bsdf: &Bsdf,
        splats: &mut Vec<(u32, Rgb)>,
        counters: &mut TraceCounters,
    ) {
        let Some((film, cos_at_camera)) = view.frame.project(v.si.p) else {
            return;
        };
        let to_camera = view.frame.eye - v.si.p;
        let dist2 = to_camera.length_squared();
        let dir = to_camera / dist2.sqrt();
        if dir.dot(v.si.ng) * v.si.wo.dot(v.si.ng) <= 0.0 {
            return;
        }
        let frame = v.si.shading_frame();
        let (wo_l, wi_l) = (frame.to_local(v.si.wo), frame.to_local(dir));
        let f = bsdf.eval(wo_l, wi_l) * shading_correction(&v.si, v.si.wo, dir);
        let cos_to_camera = wi_l.z.abs();
        if f == Rgb::ZERO || cos_to_camera == 0.0 {
            return;
        }
        let rev_pdf = bsdf.pdf(wi_l, wo_l) * continuation(bsdf);
        let image_dist = view.frame.image_plane_distance(view.height) / cos_at_camera;
        let image_to_surface = image_dist * image_dist / cos_at_camera * cos_to_camera / dist2;
        let w_light = self.mis(image_to_surface / n_light) * (v.d_vcm + v.d_vc * self.mis(rev_pdf));
        let weight = self.keep(v.path_len + 1, 1, 1.0 / (1.0 + w_light));
        let contribution = v.throughput * f * (weight * image_to_surface / n_light);
        if !crate::math::is_finite3(contribution) || contribution == Rgb::ZERO {
            return;
        }
        counters.rays += 1;
        let shadow = v.si.spawn_ray_to(view.frame.eye, Vec3::ZERO, -dir);
        if scene.occluded(&shadow) {
            return;
        }
        let x = ((film.x * view.width as f32) as u32).min(view.width - 1);
        let y = ((film.y * view.height as f32) as u32).min(view.height - 1);
        splats.push((y * view.width + x, contribution));
    }

    /// Samples the next direction and updates throughput and MIS sums (SmallVCM's
    /// `SampleScattering`). `None` ends the subpath.
    fn scatter(
        &self,
        bsdf: &Bsdf,
        si: &SurfaceInteraction,
        state: &mut SubpathState,
        rng: &mut Rng,
        mode: Transport,
    ) -> Option<Vec3> {
        let frame = si.shading_frame();
        let wo_l = frame.to_local(si.wo);
        let uc = rng.uniform();
        let bs = bsdf.sample(wo_l, uc, rng.uniform2(), mode)?;
        let wi = frame.to_world(bs.wi);
        let reflected = bs.wi.z * wo_l.z > 0.0;
        let same_side = wi.dot(si.ng) * si.wo.dot(si.ng) > 0.0;
        if reflected != same_side {
            return None;
        }
        let cont = continuation(bsdf);
        if rng.uniform() >= cont {
            return None;
        }
        let cos_out = bs.wi.z.abs();
        let dir_pdf = bs.pdf * cont;
        if bs.delta {
            state.d_vcm = 0.0;
            state.d_vc *= self.mis(cos_out);
        } else {
            let rev_pdf = bsdf.pdf(bs.wi, wo_l) * cont;
            state.d_vc =
                self.mis(cos_out / dir_pdf) * (state.d_vc * self.mis(rev_pdf) + state.d_vcm);
            state.d_vcm = self.mis(1.0 / dir_pdf);
        }
        let mut weight = bs.f * (cos_out / dir_pdf);
        if mode == Transport::Importance {
            weight *= shading_correction(si, si.wo, wi);
        }
        state.throughput *= weight;
        (crate::math::is_finite3(state.throughput) && state.throughput != Rgb::ZERO).then_some(wi)
    }

    /// s = 1: one light sample at a camera vertex.
    fn direct_illumination(
        &self,
        scene: &Scene,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        state: &SubpathState,
        rng: &mut Rng,
        counters: &mut TraceCounters,
    ) -> Rgb {
        let Some(sampler) = scene.light_sampler() else {
            return Rgb::ZERO;
        };
        let (index, pick) = sampler.sample(rng.uniform());
        let light = &scene.lights()[index];
        let Some(ls) = light.sample_at(si.p, si.facing_normal(), self.settings.env, rng.uniform2())
        else {
            return Rgb::ZERO;
        };
        if ls.wi.dot(si.ng) * si.wo.dot(si.ng) <= 0.0 {
            return Rgb::ZERO;
        }
        let frame = si.shading_frame();
        let (wo_l, wi_l) = (frame.to_local(si.wo), frame.to_local(ls.wi));
        let f = bsdf.eval(wo_l, wi_l);
        let cos_to_light = wi_l.z.abs();
        if f == Rgb::ZERO || cos_to_light == 0.0 {
            return Rgb::ZERO;
        }
        counters.rays += 1;
        if !scene.unoccluded(si, &ls) {
            return Rgb::ZERO;
        }
        let cont = continuation(bsdf);
        let dir_pdf = bsdf.pdf(wo_l, wi_l) * cont;
        let rev_pdf = bsdf.pdf(wi_l, wo_l) * cont;
        // Solid-angle density of choosing this light point by direct sampling: for delta
        // positions, the area density 1 converted at the receiver (distance^2).
        let direct_pdf_w = if light.is_delta() && light.is_finite() {
            ls.distance * ls.distance
        } else {
            ls.pdf
        };
        let cos_at_light = if light.is_delta() {
            1.0
        } else {
            (-ls.wi).dot(ls.normal).abs()
        };
        let emission_pdf_w = light.emission_pdf_with(self.settings.env, -ls.wi);
        let w_light = if light.is_delta() {
            0.0
        } else {
            self.mis(dir_pdf / (pick * direct_pdf_w))
        };
        let w_camera = self.mis(emission_pdf_w * cos_to_light / (direct_pdf_w * cos_at_light))
            * (state.d_vcm + state.d_vc * self.mis(rev_pdf));
        let weight = self.keep(1, state.path_len + 1, 1.0 / (w_light + 1.0 + w_camera));
        ls.radiance * f * (weight * cos_to_light / (pick * ls.pdf))
    }

    /// s >= 2, t >= 2: connects camera vertex `si` to a stored light vertex.
    #[allow(clippy::too_many_arguments)]
    fn connect_vertices(
        &self,
        scene: &Scene,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        state: &SubpathState,
        v: &LightVertex,
        counters: &mut TraceCounters,
    ) -> Rgb {
        let d = v.si.p - si.p;
        let dist2 = d.length_squared();
        if dist2 == 0.0 {
            return Rgb::ZERO;
        }
        let dir = d / dist2.sqrt();
        if dir.dot(si.ng) * si.wo.dot(si.ng) <= 0.0
            || (-dir).dot(v.si.ng) * v.si.wo.dot(v.si.ng) <= 0.0
        {
            return Rgb::ZERO;
        }
        let frame_c = si.shading_frame();
        let (wo_c, wi_c) = (frame_c.to_local(si.wo), frame_c.to_local(dir));
        let f_c = bsdf.eval(wo_c, wi_c);
        let cos_c = wi_c.z.abs();
        let light_bsdf = scene.bsdf(&v.si);
        let frame_l = v.si.shading_frame();
        let (wo_l, wi_l) = (frame_l.to_local(v.si.wo), frame_l.to_local(-dir));
        let f_l = light_bsdf.eval(wo_l, wi_l) * shading_correction(&v.si, v.si.wo, -dir);
        let cos_l = wi_l.z.abs();
        if f_c == Rgb::ZERO || f_l == Rgb::ZERO || cos_c == 0.0 || cos_l == 0.0 {
            return Rgb::ZERO;
        }
        let (cont_c, cont_l) = (continuation(bsdf), continuation(&light_bsdf));
        let camera_dir_pdf_a = bsdf.pdf(wo_c, wi_c) * cont_c * cos_l / dist2;
        let camera_rev_pdf = bsdf.pdf(wi_c, wo_c) * cont_c;
        let light_dir_pdf_a = light_bsdf.pdf(wo_l, wi_l) * cont_l * cos_c / dist2;
        let light_rev_pdf = light_bsdf.pdf(wi_l, wo_l) * cont_l;
        let w_light = self.mis(camera_dir_pdf_a) * (v.d_vcm + v.d_vc * self.mis(light_rev_pdf));
        let w_camera =
            self.mis(light_dir_pdf_a) * (state.d_vcm + state.d_vc * self.mis(camera_rev_pdf));
        let weight = self.keep(
            v.path_len + 1,
            state.path_len + 1,
            1.0 / (w_light + 1.0 + w_camera),
        );
        let contribution = v.throughput * f_c * f_l * (weight * cos_c * cos_l / dist2);
        if contribution == Rgb::ZERO {
            return Rgb::ZERO;
        }
        counters.rays += 1;
        let shadow = si.spawn_ray_to(v.si.p, v.si.p_error, v.si.ng);
        if scene.occluded(&shadow) {
            return Rgb::ZERO;
        }
        contribution
    }
}

impl Bdpt {
    /// s = 0 for a camera path that left the scene: the environment's radiance, weighted
    /// against direct sampling at the last vertex (normal `prev_normal`) and light subpaths
    /// leaving the environment (SmallVCM's background light: direction densities take the
    /// place of area densities at infinity).
    fn escaped(&self, scene: &Scene, dir: Vec3, state: &SubpathState, prev_normal: Vec3) -> Rgb {
        let Some((index, env)) = scene.environment() else {
            return Rgb::ZERO;
        };
        let le = env.radiance(dir);
        if le == Rgb::ZERO {
            return Rgb::ZERO;
        }
        if state.path_len == 1 {
            return if env.visible_to_camera() {
                le * self.keep(0, 2, 1.0)
            } else {
                Rgb::ZERO
            };
        }
        let Some(sampler) = scene.light_sampler() else {
            return Rgb::ZERO;
        };
        let light = &scene.lights()[index];
        let pick = sampler.pmf(index);
        let direct_pdf_w = pick * light.direction_pdf(prev_normal, self.settings.env, dir);
        let emission_pdf_w = pick * light.emission_pdf_with(self.settings.env, -dir);
        let w_camera = self.mis(direct_pdf_w) * state.d_vcm + self.mis(emission_pdf_w) * state.d_vc;
        le * self.keep(0, state.path_len + 1, 1.0 / (1.0 + w_camera))
    }
}

/// Probability of continuing a subpath at a vertex: the BSDF's albedo (at most 1). The same
/// value scales forward and reverse pdfs, so MIS weights stay exact.
fn continuation(bsdf: &Bsdf) -> f32 {
    bsdf.albedo_hint().max_element().clamp(0.0, 1.0)
}

/// Adjoint correction for shading normals in importance transport (Veach 1997 §5.3):
/// |wo.ns| |wi.ng| / (|wo.ng| |wi.ns|), with `wo` towards the light side and `wi` onward.
fn shading_correction(si: &SurfaceInteraction, wo: Vec3, wi: Vec3) -> f32 {
    let num = wo.dot(si.ns).abs() * wi.dot(si.ng).abs();
    let den = wo.dot(si.ng).abs() * wi.dot(si.ns).abs();
    if den == 0.0 {
        0.0
    } else {
        num / den
    }
}

impl Integrator for Bdpt {
    fn name(&self) -> &'static str {
        "bdpt"
    }

    fn uses_iterations(&self) -> bool {
        true
    }

    fn begin_iteration(
        &self,
        scene: &Scene,
        view: &View,
        seed: u64,
        sample_index: u32,
    ) -> Result<Iteration> {
        if view.frame.lens_radius > 0.0 {
            return Err(Error::invalid("bdpt: light tracing onto a thin-lens camera is not supported; use a pinhole camera"));
        }
        let count = self.light_path_count(view);
        let n_light = count as f32;
        const CHUNK: usize = 256;
        let chunks: Vec<LightPathChunk> = (0..count.div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                let mut vertices = Vec::new();
                let mut ranges = Vec::new();
                let mut splats = Vec::new();
                let mut counters = TraceCounters::default();
                for k in c * CHUNK..((c + 1) * CHUNK).min(count) {
                    let mut rng =
                        Rng::for_sample(seed ^ LIGHT_STREAM, k as u64, sample_index as u64);
                    let start = vertices.len() as u32;
                    self.trace_light_path(
                        scene,
                        view,
                        n_light,
                        &mut rng,
                        &mut vertices,
                        &mut splats,
                        &mut counters,
                    );
                    ranges.push((start, vertices.len() as u32));
                }
                (vertices, ranges, splats, counters.rays)
            })
            .collect();
        let mut paths = LightPaths {
            vertices: Vec::new(),
            ranges: Vec::with_capacity(count),
        };
        let mut splats = Vec::new();
        let mut rays = 0;
        for (v, r, s, n) in chunks {
            let base = paths.vertices.len() as u32;
            paths
                .ranges
                .extend(r.into_iter().map(|(a, b)| (a + base, b + base)));
            paths.vertices.extend(v);
            splats.extend(s);
            rays += n;
        }
        Ok(Iteration {
            data: Some(Box::new(paths)),
            splats,
            rays,
        })
    }

    fn sample(
        &self,
        scene: &Scene,
        mut ray: Ray,
        rng: &mut Rng,
        counters: &mut TraceCounters,
        ctx: &SampleContext,
    ) -> PixelSample {
        let mut out = PixelSample::default();
        let paths = ctx.iteration.and_then(|d| d.downcast_ref::<LightPaths>());
        let n_light = paths.map_or(1, |p| p.ranges.len()).max(1) as f32;
        let light_range = paths.map(|p| {
            let (a, b) = p.ranges[self.policy.light_path_for(ctx.pixel_index, p.ranges.len())];
            &p.vertices[a as usize..b as usize]
        });
        let cos_at_camera = ray.dir.dot(ctx.view.frame.forward);
        if !(cos_at_camera > 0.0) {
            return out;
        }
        let image_dist = ctx.view.frame.image_plane_distance(ctx.view.height) / cos_at_camera;
        let camera_pdf_w = image_dist * image_dist / cos_at_camera;
        let mut state = SubpathState {
            throughput: Rgb::ONE,
            path_len: 1,
            d_vcm: self.mis(n_light / camera_pdf_w),
            d_vc: 0.0,
            finite_light: true,
        };
        let mut radiance = Rgb::ZERO;
        let mut prev_normal = Vec3::ZERO;
        loop {
            counters.rays += 1;
            let Some(si) = scene.intersect(&ray) else {
                radiance += state.throughput * self.escaped(scene, ray.dir, &state, prev_normal);
                break;
            };
            if state.path_len == 1 {
                out.hit = true;
                out.depth = si.t;
                out.normal = si.ns;
            }
            let cos_in = si.ns.dot(si.wo).abs();
            if cos_in == 0.0 {
                break;
            }
            state.d_vcm *= self.mis(si.t * si.t);
            state.d_vcm /= self.mis(cos_in);
            state.d_vc /= self.mis(cos_in);

            // s = 0: the camera path found an emitter.
            let le = scene.emitted(&si);
            if le != Rgb::ZERO {
                if state.path_len == 1 {
                    radiance += state.throughput * le * self.keep(0, 2, 1.0);
                } else if let (Some(l), Some(sampler)) =
                    (scene.triangle_light(si.triangle), scene.light_sampler())
                {
                    let light = &scene.lights()[l];
                    let pick = sampler.pmf(l);
                    let direct_pdf_a = pick * light.direct_pdf_area();
                    let emission_pdf_w = pick * light.emission_pdf(si.wo);
                    let w_camera = self.mis(direct_pdf_a) * state.d_vcm
                        + self.mis(emission_pdf_w) * state.d_vc;
                    radiance += state.throughput
                        * le
                        * self.keep(0, state.path_len + 1, 1.0 / (1.0 + w_camera));
                }
            }
            if state.path_len >= self.max_len() {
                break;
            }
            let bsdf = scene.bsdf(&si);
            if state.path_len == 1 {
                out.albedo = bsdf.albedo_hint();
            }
            if !bsdf.is_delta() {
                radiance += state.throughput
                    * self.direct_illumination(scene, &si, &bsdf, &state, rng, counters);
                if let Some(vertices) = light_range {
                    for v in vertices {
                        if v.path_len + 1 + state.path_len > self.max_len() {
                            break;
                        }
                        radiance += state.throughput
                            * self.connect_vertices(scene, &si, &bsdf, &state, v, counters);
                    }
                }
            }
            let Some(wi) = self.scatter(&bsdf, &si, &mut state, rng, Transport::Radiance) else {
                break;
            };
            prev_normal = si.facing_normal();
            ray = si.spawn_ray(wi);
            state.path_len += 1;
        }
        out.radiance = radiance;
        out
    }
}
