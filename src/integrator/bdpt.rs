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
//! vertex pool; each camera vertex then connects to the light subpaths a [`ConnectionPolicy`]
//! picks (by default its camera path's own, one per pixel), with the policy's sample count in
//! the weights: the shape SkelBPT's resampling builds on.
//! Russian roulette uses a per-vertex continuation probability (the BSDF's albedo), folded
//! into both the forward and the reverse pdfs so the weights stay exact. It does not depend on
//! the depth (so `rr_start_depth` is not used here): a vertex's reverse pdf must be known when
//! the vertex is stored, before the depth it would have on the other subpath is.
//!
//! Thin-lens cameras: light tracing (t = 1) samples a point on the lens as camera rays do;
//! the camera ray's direction density at the lens, `d^2 / cos^3` with d the image-plane
//! distance, is the pinhole's, so the weights are the same formulas.
//!
//! Every strategy hands its [`Estimate`] (unweighted value and MIS weight) to one place,
//! [`Bdpt::accept`], which applies the strategy filter and fills the per-strategy images; a
//! [`PathObserver`] sees the vertices and estimates (the weight tests use it).

use std::any::Any;
use std::cell::Cell;

use rayon::prelude::*;

use super::{
    Integrator, IntegratorSettings, Iteration, MisHeuristic, SampleContext, TraceCounters, View,
};
use crate::error::{Error, Result};
use crate::film::PixelSample;
use crate::geometry::{offset_ray_origin, Ray};
use crate::light::{Light, TriangleSampling};
use crate::math::{Rgb, Rng, Sampler, Vec2, Vec3};
use crate::scene::{Bsdf, Scene, SurfaceInteraction, Transport};

/// A camera vertex about to be connected to stored light vertices.
pub struct CameraVertex<'a> {
    pub pixel_index: u64,
    /// Segments from the camera to this vertex.
    pub segments: u32,
    pub si: &'a SurfaceInteraction,
    /// Longest light subpath (segments) a connection from here may use within the maximum
    /// path length.
    pub max_light_segments: u32,
    /// This sample's values of the policy's own layers ([`ConnectionPolicy::layers`]).
    pub layers: &'a [Cell<Rgb>],
}

/// Chooses the stored light subpaths each camera vertex connects to (all the valid vertices of
/// each chosen subpath), the eye pass's pluggable part (000 §11: SkelBPT resamples them).
///
/// The estimate is unbiased when, over the policy's choices, the factors average the N
/// subpaths: E[sum of the factors given to subpath j] = 1 / N for each of the N subpaths
/// (connecting to all of them, [`AllLightPaths`], gives each the factor 1 / N). Separately,
/// `connection_count` is the number of samples the connection strategies get in the MIS
/// weights: any constant keeps the weights summing to one, so it only decides which strategy
/// carries a path (000 eq. 185 credits the all-subpath estimator with N; SkelBPT and ICBPT
/// credit their one pick with one by default, [`crate::guide::ConnectionCount`]). A
/// resampling policy (eq. 186) picks per camera vertex with probability p(j) and gives the
/// factor 1 / (N p(j)). A policy may also pick single vertices of a subpath
/// ([`ConnectionPolicy::connect_vertex`]), as SkelBPT does, one per subpath length.
pub trait ConnectionPolicy: Send + Sync {
    /// MIS sample count of the connection strategies, for `light_paths` subpaths.
    fn connection_count(&self, light_paths: usize) -> f32;

    /// What the policy builds from one iteration's light subpaths (resampling tables), handed
    /// back through [`LightPaths::policy_data`], and the rays it traced for it.
    fn begin_iteration(
        &self,
        _scene: &Scene,
        _paths: &LightPaths,
        _sample_index: u32,
    ) -> Result<(Option<Box<dyn Any + Send + Sync>>, u64)> {
        Ok((None, 0))
    }

    /// Names of the policy's own per-pixel images (after the strategy images).
    fn layers(&self) -> Vec<String> {
        Vec::new()
    }

    /// Calls `connect(subpath, factor)` for each light subpath `vertex` connects to (all its
    /// vertices). The default hands every vertex of those subpaths to `connect_vertex`.
    fn connect(
        &self,
        vertex: &CameraVertex,
        light_paths: usize,
        rng: &mut Sampler,
        connect: &mut dyn FnMut(usize, f32),
    );

    /// Calls `connect(subpath, vertex index in the pool, factor)` for each light vertex
    /// `vertex` connects to; `connect` returns what the connection gave.
    fn connect_vertex(
        &self,
        vertex: &CameraVertex,
        paths: &LightPaths,
        rng: &mut Sampler,
        connect: &mut dyn FnMut(usize, usize, f32) -> Connection,
    ) {
        connect_whole_subpaths(self, vertex, paths, rng, connect);
    }
}

/// [`ConnectionPolicy::connect_vertex`]'s default: every vertex (up to the camera vertex's
/// length limit) of each subpath the policy's `connect` picks.
pub fn connect_whole_subpaths<P: ConnectionPolicy + ?Sized>(
    policy: &P,
    vertex: &CameraVertex,
    paths: &LightPaths,
    rng: &mut Sampler,
    connect: &mut dyn FnMut(usize, usize, f32) -> Connection,
) {
    let mut each = |j: usize, factor: f32| {
        let (a, b) = paths.ranges[j];
        for v in a as usize..b as usize {
            if paths.vertices[v].path_len > vertex.max_light_segments {
                break;
            }
            connect(j, v, factor);
        }
    };
    policy.connect(vertex, paths.ranges.len(), rng, &mut each);
}

/// A policy shared with its integrator (which reads its statistics or hands it per-iteration
/// input) is given to `bdpt` as an `Arc`.
impl<P: ConnectionPolicy + ?Sized> ConnectionPolicy for std::sync::Arc<P> {
    fn connection_count(&self, light_paths: usize) -> f32 {
        (**self).connection_count(light_paths)
    }
    fn begin_iteration(
        &self,
        scene: &Scene,
        paths: &LightPaths,
        sample_index: u32,
    ) -> Result<(Option<Box<dyn Any + Send + Sync>>, u64)> {
        (**self).begin_iteration(scene, paths, sample_index)
    }
    fn layers(&self) -> Vec<String> {
        (**self).layers()
    }
    fn connect(
        &self,
        vertex: &CameraVertex,
        light_paths: usize,
        rng: &mut Sampler,
        connect: &mut dyn FnMut(usize, f32),
    ) {
        (**self).connect(vertex, light_paths, rng, connect)
    }
    fn connect_vertex(
        &self,
        vertex: &CameraVertex,
        paths: &LightPaths,
        rng: &mut Sampler,
        connect: &mut dyn FnMut(usize, usize, f32) -> Connection,
    ) {
        (**self).connect_vertex(vertex, paths, rng, connect)
    }
}

/// What one connection of a camera vertex to a light vertex gave.
#[derive(Clone, Copy, Debug, Default)]
pub struct Connection {
    /// Added to the pixel.
    pub added: Rgb,
    /// The shadow ray between the two vertices was blocked.
    pub occluded: bool,
}

/// The default: every vertex of a camera path connects to the camera path's "own" light
/// subpath (pixel index modulo their number), one connection per strategy.
pub struct UniformPerPixel;

impl ConnectionPolicy for UniformPerPixel {
    fn connection_count(&self, _light_paths: usize) -> f32 {
        1.0
    }

    fn connect(
        &self,
        vertex: &CameraVertex,
        light_paths: usize,
        _rng: &mut Sampler,
        connect: &mut dyn FnMut(usize, f32),
    ) {
        if light_paths > 0 {
            connect((vertex.pixel_index % light_paths as u64) as usize, 1.0);
        }
    }
}

/// Every camera vertex connects to every light subpath, each counting 1/N: the many-path
/// estimator of 000 eq. 185 that SkelBPT's resampling estimates, at N times the connections
/// (a reference for resampling policies; use few light subpaths).
pub struct AllLightPaths;

impl ConnectionPolicy for AllLightPaths {
    fn connection_count(&self, light_paths: usize) -> f32 {
        light_paths.max(1) as f32
    }

    fn connect(
        &self,
        _vertex: &CameraVertex,
        light_paths: usize,
        _rng: &mut Sampler,
        connect: &mut dyn FnMut(usize, f32),
    ) {
        let factor = 1.0 / light_paths.max(1) as f32;
        for j in 0..light_paths {
            connect(j, factor);
        }
    }
}

/// A stored light subpath vertex (never on a delta BSDF).
#[derive(Clone, Copy, Debug)]
pub struct LightVertex {
    pub(crate) si: SurfaceInteraction,
    /// The subpath's contribution so far (emission times scattering and geometry over the
    /// densities), arriving at this vertex.
    pub(crate) throughput: Rgb,
    /// Segments from the light to this vertex.
    pub(crate) path_len: u32,
    d_vcm: f32,
    d_vc: f32,
}

/// The light subpaths of one iteration.
pub struct LightPaths {
    pub(crate) vertices: Vec<LightVertex>,
    /// Range of `vertices` of each light subpath.
    pub(crate) ranges: Vec<(u32, u32)>,
    /// What the connection policy built from them ([`ConnectionPolicy::begin_iteration`]).
    pub(crate) policy_data: Option<Box<dyn Any + Send + Sync>>,
}

/// What light tracing produced besides the vertex pool: splats onto the image and onto the
/// strategy images, and the rays traced.
#[derive(Default)]
pub(crate) struct LightTracingOutput {
    splats: Vec<(u32, Rgb)>,
    layer_splats: Vec<(u32, u32, Rgb)>,
    counters: TraceCounters,
}

impl LightTracingOutput {
    /// Rays traced.
    pub(crate) fn rays(&self) -> u64 {
        self.counters.rays
    }
}

/// What one parallel task of light tracing produced: vertices, per-path ranges (relative to
/// the chunk) and the rest.
type LightPathChunk = (Vec<LightVertex>, Vec<(u32, u32)>, LightTracingOutput);

/// MIS sample counts of the strategies that take more than one sample per camera path:
/// light tracing (one sample per light subpath, over the image) and, per the connection
/// policy, the connections. The others (s = 0, s = 1) take one.
#[derive(Clone, Copy, Debug)]
struct Counts {
    light_paths: f32,
    connections: f32,
}

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

impl StrategyFilter {
    /// Checks that bdpt has this strategy: t >= 1 (no light path hits the camera), s + t >= 2,
    /// and not (1, 1) (an emitter seen directly is s = 0's alone).
    pub fn validate(&self) -> Result<()> {
        let (s, t) = (self.s, self.t);
        if t == 0 || s + t < 2 || (s, t) == (1, 1) || s > 1 << 20 || t > 1 << 20 {
            return Err(Error::invalid(format!(
                "bdpt has no strategy ({s}, {t}): it needs t >= 1 and s + t >= 2, and (1, 1) is \
                 left to s = 0"
            )));
        }
        Ok(())
    }
}

/// What one strategy found for one path: its unweighted contribution (f / p times the
/// subpath throughputs) and its MIS weight.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Estimate {
    pub s: u32,
    pub t: u32,
    pub value: Rgb,
    pub weight: f32,
}

/// The end vertex a strategy sampled that is in neither recorded subpath: the light point of
/// s = 1 (light index and position), the lens point of t = 1; for connections, which light
/// subpath.
#[derive(Clone, Copy, Debug)]
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) enum Endpoint {
    None,
    Light(usize, Vec3),
    Lens(Vec3),
    /// s = 0 or s = 1 on an environment light (its index): the unit direction towards it.
    Sky(usize, Vec3),
    /// s >= 2, t >= 2: the light subpath connected to.
    LightPath(usize),
}

/// Sees the subpaths a render traces and every estimate made from them (for tests; `()` sees
/// nothing and compiles away). Light subpaths: `light_start` with the light, its sampled
/// point and the emitted direction, then `light_vertex` for every surface vertex, delta ones
/// included. Camera paths: `camera_vertex` for the eye (or lens point), then for every surface
/// vertex.
pub(crate) trait PathObserver {
    fn light_start(&mut self, _light: usize, _point: Vec3, _dir: Vec3) {}
    fn light_vertex(&mut self, _si: &SurfaceInteraction) {}
    fn camera_vertex(&mut self, _p: Vec3, _si: Option<&SurfaceInteraction>) {}
    fn estimate(&mut self, _e: &Estimate, _end: Endpoint) {}
}

impl PathObserver for () {}

/// Index of strategy (s, t) among all strategies of paths of 1, 2, ... segments: (0, 2) for
/// one segment, then (0, k + 1), (1, k), ..., (k, 1) for k segments (no (1, 1): a light point
/// is never splatted, emitters seen directly are s = 0's alone).
fn strategy_index(s: u32, t: u32) -> usize {
    let k = (s + t - 1) as usize;
    if k == 1 {
        0
    } else {
        k * (k + 1) / 2 - 2 + s as usize
    }
}

/// Name of the image of strategy (s, t), weighted by its MIS weight or not.
pub fn strategy_layer_name(s: u32, t: u32, weighted: bool) -> String {
    let kind = if weighted { "weighted" } else { "unweighted" };
    format!("s{s}_t{t}_{kind}")
}

/// The strategies of paths of at most `max_len` segments, in layer order.
fn strategies(max_len: u32) -> Vec<(u32, u32)> {
    let mut list = vec![(0, 2)];
    for k in 2..=max_len {
        list.extend((0..=k).map(|s| (s, k + 1 - s)));
    }
    list
}

pub struct Bdpt {
    settings: IntegratorSettings,
    /// The strategy filter, in force when `filtered` (read through [`Bdpt::filter`]). Not an
    /// `Option`, whose `None` leaves the filter's bytes unwritten: the optimizer may compare
    /// `s` and `t` before it looks at the discriminant (harmless, the result is then
    /// discarded), and valgrind reports that branch as a conditional jump on uninitialised
    /// values. It did in `sample` on ab1a4d0 (`keep(0, 2, ..)` became a branch on the
    /// unwritten `s` and `t`), which kept bdpt out of the C tests under valgrind.
    strategy: StrategyFilter,
    filtered: bool,
    /// Longest path (segments) whose strategies get images; `None` = no strategy images.
    strategy_images: Option<u32>,
    /// Light subpaths per iteration; `None` = one per pixel.
    light_paths: Option<usize>,
    /// Light subpaths connect to the camera (t = 1, splatted); `vpl` traces them only for
    /// their vertices and turns this off.
    light_tracing: bool,
    policy: Box<dyn ConnectionPolicy>,
}

/// Stream offset separating light-subpath random numbers from camera-path ones.
const LIGHT_STREAM: u64 = 0x9E6C_63D0_676A_9A99;

impl Bdpt {
    /// A BDPT with `settings` (its `light_paths` included; 0 fails when rendering).
    pub fn new(settings: IntegratorSettings) -> Self {
        Bdpt {
            settings,
            strategy: StrategyFilter {
                s: 0,
                t: 0,
                unweighted: false,
            },
            filtered: false,
            strategy_images: None,
            light_paths: settings.light_paths.map(|n| n as usize),
            light_tracing: true,
            policy: Box::new(UniformPerPixel),
        }
    }

    /// Sets the number of light subpaths traced per iteration (default: one per pixel).
    pub fn with_light_paths(mut self, count: usize) -> Result<Self> {
        crate::limits::check_light_paths("bdpt: light subpaths per iteration", count as u64)?;
        self.light_paths = Some(count);
        Ok(self)
    }

    /// Traces light subpaths for their stored vertices only, without connecting them to the
    /// camera (no splats, no shadow rays to the lens): what instant radiosity (`vpl`) needs.
    pub(crate) fn without_light_tracing(mut self) -> Self {
        self.light_tracing = false;
        self
    }

    /// Keeps only the contributions of one strategy (see [`StrategyFilter::validate`]).
    pub fn with_strategy(mut self, filter: StrategyFilter) -> Result<Self> {
        filter.validate()?;
        self.strategy = filter;
        self.filtered = true;
        Ok(self)
    }

    /// The strategy filter in force, if any.
    #[inline]
    fn filter(&self) -> Option<StrategyFilter> {
        self.filtered.then_some(self.strategy)
    }

    /// Also renders, from the same samples, the image of every strategy of paths up to
    /// `max_length` segments (clamped to the maximum path length), weighted and unweighted,
    /// as the layers named by [`strategy_layer_name`] (000 Figure 22). Each takes 24 bytes
    /// per pixel and layer; the weighted ones sum to the image.
    pub fn with_strategy_images(mut self, max_length: u32) -> Result<Self> {
        if max_length == 0 {
            return Err(Error::invalid(
                "bdpt: strategy images need a path length of at least 1",
            ));
        }
        self.strategy_images = Some(max_length.min(self.max_len()));
        Ok(self)
    }

    /// Factor applied to the unweighted contribution of strategy (s, t) with MIS weight
    /// `weight`.
    #[inline]
    fn keep(&self, s: u32, t: u32, weight: f32) -> f32 {
        match self.filter() {
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

    /// Whether an estimate of strategy (s, t) is used at all (else its shadow ray is skipped).
    #[inline]
    fn wanted(&self, s: u32, t: u32) -> bool {
        self.filter().map_or(true, |f| f.s == s && f.t == t) || self.strategy_layer(s, t).is_some()
    }

    /// Number of strategy images (the policy's layers follow them).
    fn strategy_layer_count(&self) -> usize {
        self.strategy_images
            .map_or(0, |max| 2 * strategies(max).len())
    }

    /// First of the two layers (weighted, unweighted) of strategy (s, t), if it has images.
    #[inline]
    fn strategy_layer(&self, s: u32, t: u32) -> Option<usize> {
        let max = self.strategy_images?;
        (s + t - 1 <= max).then(|| 2 * strategy_index(s, t))
    }

    /// Where every estimate goes: its share of the pixel (strategy filter applied), and its
    /// weighted and unweighted values into the strategy images.
    #[inline]
    fn accept(&self, e: &Estimate, layers: &[Cell<Rgb>]) -> Rgb {
        if let (Some(l), false) = (self.strategy_layer(e.s, e.t), layers.is_empty()) {
            layers[l].set(layers[l].get() + e.value * e.weight);
            layers[l + 1].set(layers[l + 1].get() + e.value);
        }
        e.value * self.keep(e.s, e.t, e.weight)
    }

    /// `accept` for a light-tracing splat.
    fn accept_splat(
        &self,
        e: &Estimate,
        pixel: u32,
        splats: &mut Vec<(u32, Rgb)>,
        layer_splats: &mut Vec<(u32, u32, Rgb)>,
    ) {
        if let Some(l) = self.strategy_layer(e.s, e.t) {
            layer_splats.push((l as u32, pixel, e.value * e.weight));
            layer_splats.push((l as u32 + 1, pixel, e.value));
        }
        let value = e.value * self.keep(e.s, e.t, e.weight);
        if value != Rgb::ZERO {
            splats.push((pixel, value));
        }
    }

    pub fn with_policy(mut self, policy: Box<dyn ConnectionPolicy>) -> Self {
        self.policy = policy;
        self
    }

    /// Replaces the connection policy (an integrator built on bdpt sets its own when prepared).
    pub fn set_policy(&mut self, policy: Box<dyn ConnectionPolicy>) {
        self.policy = policy;
    }

    #[inline]
    fn mis(&self, x: f32) -> f32 {
        match self.settings.mis.unwrap_or_default() {
            // auto and optimal are refused at creation (`MisHeuristic::check_supported`).
            MisHeuristic::Balance | MisHeuristic::Auto | MisHeuristic::Optimal => x,
            MisHeuristic::Power => x * x,
        }
    }

    /// Longest path in segments.
    pub(crate) fn max_len(&self) -> u32 {
        self.settings.max_depth + 1
    }

    fn counts(&self, light_paths: usize) -> Counts {
        Counts {
            light_paths: light_paths.max(1) as f32,
            connections: self.policy.connection_count(light_paths),
        }
    }

    fn light_path_count(&self, view: &View) -> usize {
        self.light_paths
            .unwrap_or(view.width as usize * view.height as usize)
    }

    /// Traces one light subpath, storing its vertices and splatting its light-tracing (t = 1)
    /// contributions.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    fn trace_light_path<O: PathObserver>(
        &self,
        scene: &Scene,
        view: &View,
        counts: Counts,
        rng: &mut Sampler,
        vertices: &mut Vec<LightVertex>,
        out: &mut LightTracingOutput,
        obs: &mut O,
    ) {
        #[cfg(target_arch = "x86_64")]
        if crate::geometry::has_x86_64_v3() {
            // SAFETY: the CPU runs x86-64-v3 code (checked just above).
            return unsafe {
                self.trace_light_path_v3(scene, view, counts, rng, vertices, out, obs)
            };
        }
        self.trace_light_path_baseline(scene, view, counts, rng, vertices, out, obs)
    }

    /// [`trace_light_path`](Self::trace_light_path) for any x86-64 (and other architectures).
    #[inline(never)]
    #[allow(clippy::too_many_arguments)]
    fn trace_light_path_baseline<O: PathObserver>(
        &self,
        scene: &Scene,
        view: &View,
        counts: Counts,
        rng: &mut Sampler,
        vertices: &mut Vec<LightVertex>,
        out: &mut LightTracingOutput,
        obs: &mut O,
    ) {
        self.trace_light_path_impl(scene, view, counts, rng, vertices, out, obs)
    }

    /// [`trace_light_path`](Self::trace_light_path) compiled for x86-64-v3, as
    /// `PathTracer::trace` is (BENCHMARKS.md, issue 30); bit-identical results.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn trace_light_path_v3<O: PathObserver>(
        &self,
        scene: &Scene,
        view: &View,
        counts: Counts,
        rng: &mut Sampler,
        vertices: &mut Vec<LightVertex>,
        out: &mut LightTracingOutput,
        obs: &mut O,
    ) {
        self.trace_light_path_impl(scene, view, counts, rng, vertices, out, obs)
    }

    /// The body of [`trace_light_path`](Self::trace_light_path), inlined into each of its two
    /// compilations.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn trace_light_path_impl<O: PathObserver>(
        &self,
        scene: &Scene,
        view: &View,
        counts: Counts,
        rng: &mut Sampler,
        vertices: &mut Vec<LightVertex>,
        out: &mut LightTracingOutput,
        obs: &mut O,
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
        // The strategies these sums stand for (s = 1 and s = 0) take one sample where the
        // connections take `counts.connections`.
        let mut state = SubpathState {
            throughput: es.value / emission_pdf_w,
            path_len: 1,
            d_vcm: self.mis(direct_pdf_a / emission_pdf_w / counts.connections),
            d_vc: if light.is_delta() {
                0.0
            } else {
                self.mis(used_cos / emission_pdf_w / counts.connections)
            },
            finite_light: light.is_finite(),
        };
        obs.light_start(index, es.origin, es.dir);
        let origin = offset_ray_origin(es.origin, es.origin_error, es.normal, es.dir);
        let mut ray = Ray::new(origin, es.dir, f32::INFINITY);
        loop {
            out.counters.rays += 1;
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
                // Relative to the connections' count, as every light-side sum is.
                let direct_pdf_w =
                    light.direction_pdf(si.facing_normal(), self.settings.env, si.wo);
                state.d_vcm = self.mis(direct_pdf_w * pick / emission_pdf_w / counts.connections);
            }
            if state.path_len == 1 && matches!(light, Light::LightField { .. }) {
                // A light field's restricted sampling depends on the receiver, known only
                // now: the area density of choosing the origin by direct sampling from here.
                let direct_pdf_a = light.direct_pdf_area_from(si.p, es.origin) * pick;
                state.d_vcm = self.mis(direct_pdf_a / emission_pdf_w / counts.connections);
            }
            if state.path_len > 1 || state.finite_light {
                state.d_vcm *= self.mis(si.t * si.t);
            }
            state.d_vcm /= self.mis(cos_in);
            state.d_vc /= self.mis(cos_in);
            obs.light_vertex(&si);
            let bsdf = scene.bsdf(&si);
            if !bsdf.is_delta() {
                let vertex = LightVertex {
                    si,
                    throughput: state.throughput,
                    path_len: state.path_len,
                    d_vcm: state.d_vcm,
                    d_vc: state.d_vc,
                };
                if self.light_tracing && state.path_len < self.max_len() {
                    if let Some((pixel, e, lens)) = self.connect_to_camera(
                        scene,
                        view,
                        counts,
                        &vertex,
                        &bsdf,
                        rng,
                        &mut out.counters,
                    ) {
                        obs.estimate(&e, Endpoint::Lens(lens));
                        self.accept_splat(&e, pixel, &mut out.splats, &mut out.layer_splats);
                    }
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

    /// Light tracing (t = 1): the light vertex seen by the camera through a point of its lens
    /// (the eye for a pinhole). Returns the pixel, the estimate and the lens point.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn connect_to_camera(
        &self,
        scene: &Scene,
        view: &View,
        counts: Counts,
        v: &LightVertex,
        bsdf: &Bsdf,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
    ) -> Option<(u32, Estimate, Vec3)> {
        // Pinholes draw no random number here, so their light subpaths do not depend on it.
        let lens_u = if view.frame.lens_radius > 0.0 {
            rng.uniform2()
        } else {
            Vec2::ZERO
        };
        let lens = view.frame.lens_point(lens_u);
        let (film, cos_at_camera) = view.frame.project_from_lens(lens, v.si.p)?;
        let to_camera = lens - v.si.p;
        let dist2 = to_camera.length_squared();
        let dir = to_camera / dist2.sqrt();
        let frame = v.si.shading_frame();
        let (wo_l, wi_l) = (frame.to_local(v.si.wo), frame.to_local(dir));
        if !v.si.scatters_toward(dir, wo_l, wi_l) {
            return None;
        }
        let f =
            bsdf.eval(wo_l, wi_l, Transport::Importance) * shading_correction(&v.si, v.si.wo, dir);
        let cos_to_camera = wi_l.z.abs();
        if f == Rgb::ZERO || cos_to_camera == 0.0 {
            return None;
        }
        let rev_pdf = bsdf.pdf(wi_l, wo_l) * continuation(bsdf);
        // Area density at the vertex of the camera ray through the lens point: the direction
        // density d^2 / cos^3 (unit pixel area at image-plane distance d) times cos / dist^2.
        let image_dist = view.frame.image_plane_distance(view.height) / cos_at_camera;
        let image_to_surface = image_dist * image_dist / cos_at_camera * cos_to_camera / dist2;
        // Light tracing takes `counts.light_paths` samples, the connections compared with it
        // `counts.connections`.
        let w_light = self.mis(image_to_surface * counts.connections / counts.light_paths)
            * (v.d_vcm + v.d_vc * self.mis(rev_pdf));
        let e = Estimate {
            s: v.path_len + 1,
            t: 1,
            value: v.throughput * f * (image_to_surface / counts.light_paths),
            weight: 1.0 / (1.0 + w_light),
        };
        if !crate::math::is_finite3(e.value) || e.value == Rgb::ZERO || !self.wanted(e.s, e.t) {
            return None;
        }
        counters.rays += 1;
        let shadow = v.si.spawn_ray_to(lens, Vec3::ZERO, -dir);
        if scene.occluded(&shadow) {
            return None;
        }
        let x = ((film.x * view.width as f32) as u32).min(view.width - 1);
        let y = ((film.y * view.height as f32) as u32).min(view.height - 1);
        Some((y * view.width + x, e, lens))
    }

    /// Samples the next direction and updates throughput and MIS sums (SmallVCM's
    /// `SampleScattering`). `None` ends the subpath.
    #[inline(always)]
    fn scatter(
        &self,
        bsdf: &Bsdf,
        si: &SurfaceInteraction,
        state: &mut SubpathState,
        rng: &mut Sampler,
        mode: Transport,
    ) -> Option<Vec3> {
        let frame = si.shading_frame();
        let wo_l = frame.to_local(si.wo);
        let bs = bsdf.sample_from(wo_l, rng, mode)?;
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
            // A Dirac lobe's densities are compared symbolically (Veach 1997 §10.2): in
            // projected solid angle a reflection's delta is the same both ways and a
            // refraction's scales by (eta_in / eta_out)^2 (conservation of etendue), so the
            // reverse-to-forward ratio of solid-angle pdfs is cos_in / cos_out times that.
            // In the general update below this leaves d_vc * mis(cos_in (eta_in/eta_out)^2).
            // (SmallVCM's ratio 1 is the same for mirrors but not for refraction.) No strategy
            // connects at this vertex, hence d_vcm = 0.
            state.d_vcm = 0.0;
            state.d_vc *= self.mis(wo_l.z.abs() * eta_ratio_squared(bsdf, wo_l, bs.wi));
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

    /// s = 1: one light sample at a camera vertex. Returns the estimate (camera throughput
    /// not applied) with the light and the sampled point.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn direct_illumination(
        &self,
        scene: &Scene,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        state: &SubpathState,
        counts: Counts,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
    ) -> Option<(Estimate, Endpoint)> {
        let sampler = scene.light_sampler()?;
        let (index, pick) = sampler.sample(rng.uniform());
        let light = &scene.lights()[index];
        // By area: the weights below take this vertex's density as `direct_pdf_area`.
        let ls = light.sample_with(
            si.p,
            si.facing_normal(),
            self.settings.env,
            TriangleSampling::Area,
            rng.uniform2(),
        )?;
        let frame = si.shading_frame();
        let (wo_l, wi_l) = (frame.to_local(si.wo), frame.to_local(ls.wi));
        if !si.scatters_toward(ls.wi, wo_l, wi_l) {
            return None;
        }
        let f = bsdf.eval(wo_l, wi_l, Transport::Radiance);
        let cos_to_light = wi_l.z.abs();
        if f == Rgb::ZERO || cos_to_light == 0.0 {
            return None;
        }
        let cont = continuation(bsdf);
        let dir_pdf = bsdf.pdf(wo_l, wi_l) * cont;
        let rev_pdf = bsdf.pdf(wi_l, wo_l) * cont;
        // Solid-angle density of choosing this light point by direct sampling: for delta
        // positions, the area density 1 converted at the receiver (distance^2).
        // A light field's point has a true density (its image plane's, by area, converted
        // here with that plane's cosine) though no ray hits it.
        let is_field = matches!(light, Light::LightField { .. });
        let direct_pdf_w = if light.is_delta() && light.is_finite() && !is_field {
            ls.distance * ls.distance
        } else {
            ls.pdf
        };
        let cos_at_light = if light.is_delta() && !is_field {
            1.0
        } else {
            (-ls.wi).dot(ls.normal).abs()
        };
        let emission_pdf_w = light.emission_pdf_at(self.settings.env, ls.point, -ls.wi);
        let w_light = if light.is_delta() {
            0.0
        } else {
            self.mis(dir_pdf / (pick * direct_pdf_w))
        };
        // The strategies with more light vertices are connections (and light tracing, whose
        // count the camera sums carry relative to the connections').
        let w_camera = self.mis(
            emission_pdf_w * cos_to_light * counts.connections / (direct_pdf_w * cos_at_light),
        ) * (state.d_vcm + state.d_vc * self.mis(rev_pdf));
        let e = Estimate {
            s: 1,
            t: state.path_len + 1,
            value: ls.radiance * f * (cos_to_light / (pick * ls.pdf)),
            weight: 1.0 / (w_light + 1.0 + w_camera),
        };
        if !self.wanted(e.s, e.t) {
            return None;
        }
        counters.rays += 1;
        if !scene.unoccluded(si, &ls) {
            return None;
        }
        let end = if matches!(light, Light::Environment { .. }) {
            Endpoint::Sky(index, ls.wi)
        } else {
            Endpoint::Light(index, ls.point)
        };
        Some((e, end))
    }

    /// [`connect_vertices`](Self::connect_vertices), its x86-64-v3 copy if `V3`.
    #[inline(always)]
    fn connect_vertices_in<const V3: bool>(
        &self,
        scene: &Scene,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        state: &SubpathState,
        v: &LightVertex,
        counters: &mut TraceCounters,
    ) -> Option<Estimate> {
        #[cfg(target_arch = "x86_64")]
        if V3 {
            // SAFETY: `V3` is set only by `sample_observed_v3`, which runs on x86-64-v3 CPUs.
            return unsafe { self.connect_vertices_v3(scene, si, bsdf, state, v, counters) };
        }
        self.connect_vertices(scene, si, bsdf, state, v, counters)
    }

    /// [`connect_vertices`](Self::connect_vertices) compiled for x86-64-v3.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    unsafe fn connect_vertices_v3(
        &self,
        scene: &Scene,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        state: &SubpathState,
        v: &LightVertex,
        counters: &mut TraceCounters,
    ) -> Option<Estimate> {
        self.connect_vertices(scene, si, bsdf, state, v, counters)
    }

    /// s >= 2, t >= 2: connects camera vertex `si` to a stored light vertex. Returns the
    /// estimate (camera throughput not applied).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn connect_vertices(
        &self,
        scene: &Scene,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        state: &SubpathState,
        v: &LightVertex,
        counters: &mut TraceCounters,
    ) -> Option<Estimate> {
        let d = v.si.p - si.p;
        let dist2 = d.length_squared();
        if dist2 == 0.0 {
            return None;
        }
        let dir = d / dist2.sqrt();
        let frame_c = si.shading_frame();
        let (wo_c, wi_c) = (frame_c.to_local(si.wo), frame_c.to_local(dir));
        let f_c = bsdf.eval(wo_c, wi_c, Transport::Radiance);
        let cos_c = wi_c.z.abs();
        let light_bsdf = scene.bsdf(&v.si);
        let frame_l = v.si.shading_frame();
        let (wo_l, wi_l) = (frame_l.to_local(v.si.wo), frame_l.to_local(-dir));
        if !si.scatters_toward(dir, wo_c, wi_c) || !v.si.scatters_toward(-dir, wo_l, wi_l) {
            return None;
        }
        let f_l = light_bsdf.eval(wo_l, wi_l, Transport::Importance)
            * shading_correction(&v.si, v.si.wo, -dir);
        let cos_l = wi_l.z.abs();
        if f_c == Rgb::ZERO || f_l == Rgb::ZERO || cos_c == 0.0 || cos_l == 0.0 {
            return None;
        }
        let (cont_c, cont_l) = (continuation(bsdf), continuation(&light_bsdf));
        let camera_dir_pdf_a = bsdf.pdf(wo_c, wi_c) * cont_c * cos_l / dist2;
        let camera_rev_pdf = bsdf.pdf(wi_c, wo_c) * cont_c;
        let light_dir_pdf_a = light_bsdf.pdf(wo_l, wi_l) * cont_l * cos_c / dist2;
        let light_rev_pdf = light_bsdf.pdf(wi_l, wo_l) * cont_l;
        let w_light = self.mis(camera_dir_pdf_a) * (v.d_vcm + v.d_vc * self.mis(light_rev_pdf));
        let w_camera =
            self.mis(light_dir_pdf_a) * (state.d_vcm + state.d_vc * self.mis(camera_rev_pdf));
        let e = Estimate {
            s: v.path_len + 1,
            t: state.path_len + 1,
            value: v.throughput * f_c * f_l * (cos_c * cos_l / dist2),
            weight: 1.0 / (w_light + 1.0 + w_camera),
        };
        if e.value == Rgb::ZERO || !self.wanted(e.s, e.t) {
            return None;
        }
        counters.rays += 1;
        let shadow = si.spawn_ray_to(v.si.p, v.si.p_error, v.si.ng);
        if scene.occluded(&shadow) {
            return None;
        }
        Some(e)
    }
}

impl Bdpt {
    /// s = 0 for a camera path that left the scene in direction `dir`: the environment's
    /// radiance (camera throughput not applied), weighted against direct sampling at the last
    /// vertex (normal `prev_normal`) and light subpaths leaving the environment (SmallVCM's
    /// background light: direction densities take the place of area densities at infinity).
    /// Returns the estimate and the environment's light index.
    #[inline(always)]
    fn escaped(
        &self,
        scene: &Scene,
        dir: Vec3,
        state: &SubpathState,
        prev_normal: Vec3,
        counts: Counts,
    ) -> Option<(Estimate, usize)> {
        let (index, env) = scene.environment()?;
        let le = env.radiance(dir);
        if le == Rgb::ZERO {
            return None;
        }
        let weight = if state.path_len == 1 {
            if !env.visible_to_camera() {
                return None;
            }
            1.0
        } else {
            let sampler = scene.light_sampler()?;
            let light = &scene.lights()[index];
            let pick = sampler.pmf(index);
            let direct_pdf_w = pick * light.direction_pdf(prev_normal, self.settings.env, dir);
            let emission_pdf_w = pick * light.emission_pdf_with(self.settings.env, -dir);
            // d_vcm: s = 1 (one sample, like this); d_vc: the connections and beyond, whose
            // sums are relative to the connections' count (as at an area emitter's hit).
            let w_camera = self.mis(direct_pdf_w) * state.d_vcm
                + self.mis(emission_pdf_w * counts.connections) * state.d_vc;
            1.0 / (1.0 + w_camera)
        };
        let e = Estimate {
            s: 0,
            t: state.path_len + 1,
            value: le,
            weight,
        };
        Some((e, index))
    }
}

/// Probability of continuing a subpath at a vertex: the BSDF's albedo (at most 1). The same
/// value scales forward and reverse pdfs, so MIS weights stay exact.
#[inline(always)]
fn continuation(bsdf: &Bsdf) -> f32 {
    bsdf.albedo_hint().max_element().clamp(0.0, 1.0)
}

/// (eta on `wo`'s side / eta on `wi`'s side)^2 for a specular scattering from `wo` to `wi`
/// (local frame): 1 for reflections.
#[inline(always)]
fn eta_ratio_squared(bsdf: &Bsdf, wo: Vec3, wi: Vec3) -> f32 {
    match *bsdf {
        Bsdf::Dielectric { eta } if wo.z * wi.z < 0.0 => {
            let ratio = if wo.z > 0.0 { 1.0 / eta } else { eta };
            ratio * ratio
        }
        _ => 1.0,
    }
}

/// Adjoint correction for shading normals in importance transport (Veach 1997 §5.3):
/// |wo.ns| |wi.ng| / (|wo.ng| |wi.ns|), with `wo` towards the light side and `wi` onward.
#[inline(always)]
pub(super) fn shading_correction(si: &SurfaceInteraction, wo: Vec3, wi: Vec3) -> f32 {
    let num = wo.dot(si.ns).abs() * wi.dot(si.ng).abs();
    let den = wo.dot(si.ng).abs() * wi.dot(si.ns).abs();
    if den == 0.0 {
        0.0
    } else {
        num / den
    }
}

impl Bdpt {
    /// One camera path and its connections, with `obs` watching.
    #[inline]
    pub(crate) fn sample_observed<O: PathObserver>(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        ctx: &SampleContext,
        obs: &mut O,
    ) -> PixelSample {
        #[cfg(target_arch = "x86_64")]
        if crate::geometry::has_x86_64_v3() {
            // SAFETY: the CPU runs x86-64-v3 code (checked just above).
            return unsafe { self.sample_observed_v3(scene, ray, rng, counters, ctx, obs) };
        }
        self.sample_observed_baseline(scene, ray, rng, counters, ctx, obs)
    }

    /// [`sample_observed`](Self::sample_observed) for any x86-64 (and other architectures).
    #[inline(never)]
    fn sample_observed_baseline<O: PathObserver>(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        ctx: &SampleContext,
        obs: &mut O,
    ) -> PixelSample {
        self.sample_observed_impl::<O, false>(scene, ray, rng, counters, ctx, obs)
    }

    /// [`sample_observed`](Self::sample_observed) compiled for x86-64-v3, as
    /// `PathTracer::trace` is (BENCHMARKS.md, issue 30); bit-identical results.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    unsafe fn sample_observed_v3<O: PathObserver>(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        ctx: &SampleContext,
        obs: &mut O,
    ) -> PixelSample {
        self.sample_observed_impl::<O, true>(scene, ray, rng, counters, ctx, obs)
    }

    /// The body of [`sample_observed`](Self::sample_observed), inlined into each of its two
    /// compilations; `V3` picks the matching copy of the connections, which the policy calls
    /// through a closure compiled apart from this body.
    #[inline(always)]
    fn sample_observed_impl<O: PathObserver, const V3: bool>(
        &self,
        scene: &Scene,
        mut ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        ctx: &SampleContext,
        obs: &mut O,
    ) -> PixelSample {
        let mut out = PixelSample::default();
        let paths = ctx.iteration.and_then(|d| d.downcast_ref::<LightPaths>());
        let counts = self.counts(paths.map_or(1, |p| p.ranges.len()));
        let cos_at_camera = ray.dir.dot(ctx.view.frame.forward);
        if !(cos_at_camera > 0.0) {
            return out;
        }
        // Direction density of the camera ray (unit pixel area at image-plane distance d):
        // d^2 / cos^3, for pinholes and, from the lens point, for thin lenses.
        let image_dist = ctx.view.frame.image_plane_distance(ctx.view.height) / cos_at_camera;
        let camera_pdf_w = image_dist * image_dist / cos_at_camera;
        let mut state = SubpathState {
            throughput: Rgb::ONE,
            path_len: 1,
            // Light tracing's sample count relative to the connections'.
            d_vcm: self.mis(counts.light_paths / (counts.connections * camera_pdf_w)),
            d_vc: 0.0,
            finite_light: true,
        };
        obs.camera_vertex(ray.origin, None);
        let mut radiance = Rgb::ZERO;
        let mut prev_normal = Vec3::ZERO;
        loop {
            counters.rays += 1;
            let Some(si) = scene.intersect(&ray) else {
                if let Some((mut e, light)) =
                    self.escaped(scene, ray.dir, &state, prev_normal, counts)
                {
                    e.value *= state.throughput;
                    obs.estimate(&e, Endpoint::Sky(light, ray.dir));
                    radiance += self.accept(&e, ctx.layers);
                }
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
            obs.camera_vertex(si.p, Some(&si));

            // s = 0: the camera path found an emitter.
            let le = scene.emitted(&si);
            if le != Rgb::ZERO {
                let weight = if state.path_len == 1 {
                    Some(1.0)
                } else if let (Some(l), Some(sampler)) =
                    (scene.triangle_light(si.triangle), scene.light_sampler())
                {
                    let light = &scene.lights()[l];
                    let pick = sampler.pmf(l);
                    let direct_pdf_a = pick * light.direct_pdf_area();
                    let emission_pdf_w = pick * light.emission_pdf(si.wo);
                    // The sums converted the camera's density to area here with the shading
                    // normal; light sampling and emission use the light's own normal, so
                    // convert with that one (they differ on emitters with vertex normals).
                    let to_light_normal = self.mis(cos_in / light.cos_at(si.wo));
                    // d_vcm: s = 1 (one sample, like this); d_vc: connections and beyond.
                    let w_camera = (self.mis(direct_pdf_a) * state.d_vcm
                        + self.mis(emission_pdf_w * counts.connections) * state.d_vc)
                        * to_light_normal;
                    Some(1.0 / (1.0 + w_camera))
                } else {
                    None
                };
                if let Some(weight) = weight {
                    let e = Estimate {
                        s: 0,
                        t: state.path_len + 1,
                        value: state.throughput * le,
                        weight,
                    };
                    obs.estimate(&e, Endpoint::None);
                    radiance += self.accept(&e, ctx.layers);
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
                if let Some((mut e, end)) =
                    self.direct_illumination(scene, &si, &bsdf, &state, counts, rng, counters)
                {
                    e.value *= state.throughput;
                    obs.estimate(&e, end);
                    radiance += self.accept(&e, ctx.layers);
                }
                if let Some(p) = paths {
                    let vertex = CameraVertex {
                        pixel_index: ctx.pixel_index,
                        segments: state.path_len,
                        si: &si,
                        max_light_segments: self.max_len() - 1 - state.path_len,
                        layers: &ctx.layers[self.strategy_layer_count().min(ctx.layers.len())..],
                    };
                    let mut connect = |j: usize, v: usize, factor: f32| {
                        let v = &p.vertices[v];
                        if v.path_len + 1 + state.path_len > self.max_len() {
                            return Connection::default();
                        }
                        let rays_before = counters.rays;
                        let Some(mut e) =
                            self.connect_vertices_in::<V3>(scene, &si, &bsdf, &state, v, counters)
                        else {
                            // A shadow ray was traced only for a connection it then refused.
                            return Connection {
                                added: Rgb::ZERO,
                                occluded: counters.rays > rays_before,
                            };
                        };
                        e.value *= state.throughput * factor;
                        obs.estimate(&e, Endpoint::LightPath(j));
                        let added = self.accept(&e, ctx.layers);
                        radiance += added;
                        Connection {
                            added,
                            occluded: false,
                        }
                    };
                    self.policy.connect_vertex(&vertex, p, rng, &mut connect);
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

    /// The light subpaths of one iteration into the vertex pool, in parallel and
    /// deterministically (fixed chunks merged in order, each path seeded by its index).
    pub(crate) fn trace_light_paths(
        &self,
        scene: &Scene,
        view: &View,
        seed: u64,
        sample_index: u32,
        count: usize,
    ) -> (LightPaths, LightTracingOutput) {
        let counts = self.counts(count);
        const CHUNK: usize = 256;
        let chunks: Vec<LightPathChunk> = (0..count.div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                let mut vertices = Vec::new();
                let mut ranges = Vec::new();
                let mut out = LightTracingOutput::default();
                for k in c * CHUNK..((c + 1) * CHUNK).min(count) {
                    // Light subpaths belong to no pixel: independent numbers.
                    let mut rng = Sampler::independent(Rng::for_sample(
                        seed ^ LIGHT_STREAM,
                        k as u64,
                        sample_index as u64,
                    ));
                    let start = vertices.len() as u32;
                    self.trace_light_path(
                        scene,
                        view,
                        counts,
                        &mut rng,
                        &mut vertices,
                        &mut out,
                        &mut (),
                    );
                    ranges.push((start, vertices.len() as u32));
                }
                (vertices, ranges, out)
            })
            .collect();
        let mut paths = LightPaths {
            vertices: Vec::new(),
            ranges: Vec::with_capacity(count),
            policy_data: None,
        };
        let mut total = LightTracingOutput::default();
        for (v, r, out) in chunks {
            let base = paths.vertices.len() as u32;
            paths
                .ranges
                .extend(r.into_iter().map(|(a, b)| (a + base, b + base)));
            paths.vertices.extend(v);
            total.splats.extend(out.splats);
            total.layer_splats.extend(out.layer_splats);
            total.counters.rays += out.counters.rays;
        }
        (paths, total)
    }
}

impl Integrator for Bdpt {
    fn name(&self) -> &'static str {
        "bdpt"
    }

    fn layers(&self) -> Vec<String> {
        let mut names: Vec<String> = match self.strategy_images {
            Some(max) => strategies(max)
                .into_iter()
                .flat_map(|(s, t)| [true, false].map(|w| strategy_layer_name(s, t, w)))
                .collect(),
            None => Vec::new(),
        };
        names.extend(self.policy.layers());
        names
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
        let count = self.light_path_count(view);
        if count == 0 {
            return Err(Error::invalid(
                "bdpt: light subpaths per iteration must be at least 1",
            ));
        }
        let (mut paths, out) = self.trace_light_paths(scene, view, seed, sample_index, count);
        let (policy_data, policy_rays) =
            self.policy.begin_iteration(scene, &paths, sample_index)?;
        paths.policy_data = policy_data;
        Ok(Iteration {
            data: Some(Box::new(paths)),
            splats: out.splats,
            layer_splats: out.layer_splats,
            rays: out.counters.rays + policy_rays,
        })
    }

    fn sample(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        ctx: &SampleContext,
    ) -> PixelSample {
        self.sample_observed(scene, ray, rng, counters, ctx, &mut ())
    }
}

/// `bdpt` in the integrator registry: no options of its own (`light_paths` is typed only).
pub(super) const REGISTRATION: super::Registration = super::Registration {
    name: "bdpt",
    set_option: |_, _| Ok(false),
    create: |settings| {
        let bdpt = Bdpt::new(settings);
        Ok(Box::new(match settings.light_paths {
            Some(n) => bdpt.with_light_paths(n as usize)?, // validates n >= 1
            None => bdpt,
        }))
    },
    adaptive_mis: &[],
};

#[cfg(test)]
#[path = "bdpt_weights_tests.rs"]
mod weights_tests;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::SamplerKind;

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn v3_subpaths_and_samples_match_the_baseline() {
        if !crate::geometry::has_x86_64_v3() {
            return;
        }
        let scene = crate::scene::two_rooms_builder().unwrap().build().unwrap();
        let view = View {
            frame: scene.camera().unwrap().frame(1.0),
            width: 32,
            height: 32,
            sampler: SamplerKind::Sobol,
        };
        let bdpt = Bdpt::new(IntegratorSettings::default());
        let n = (view.width * view.height) as usize;
        let counts = bdpt.counts(n);
        let rgb = |c: Rgb| [c.x.to_bits(), c.y.to_bits(), c.z.to_bits()];
        // The light subpaths of both copies, from the same numbers.
        let mut pools = [0, 1].map(|_| {
            let paths = LightPaths {
                vertices: Vec::new(),
                ranges: Vec::new(),
                policy_data: None,
            };
            (paths, LightTracingOutput::default())
        });
        for (copy, (paths, out)) in pools.iter_mut().enumerate() {
            for k in 0..n {
                let mut rng = Sampler::independent(Rng::new(5, k as u64));
                let start = paths.vertices.len() as u32;
                let (v, o) = (&mut paths.vertices, &mut *out);
                if copy == 0 {
                    bdpt.trace_light_path_baseline(&scene, &view, counts, &mut rng, v, o, &mut ());
                } else {
                    // SAFETY: the CPU runs x86-64-v3 code (checked above).
                    unsafe {
                        bdpt.trace_light_path_v3(&scene, &view, counts, &mut rng, v, o, &mut ())
                    };
                }
                paths.ranges.push((start, paths.vertices.len() as u32));
            }
        }
        let [(a, a_out), (b, b_out)] = &pools;
        assert_eq!(a.ranges, b.ranges);
        assert!(a.vertices.len() > n, "{} light vertices", a.vertices.len());
        for (u, v) in a.vertices.iter().zip(&b.vertices) {
            assert_eq!(rgb(u.throughput), rgb(v.throughput));
            assert_eq!(rgb(u.si.p), rgb(v.si.p));
            assert_eq!(u.path_len, v.path_len);
            assert_eq!(u.d_vcm.to_bits(), v.d_vcm.to_bits());
            assert_eq!(u.d_vc.to_bits(), v.d_vc.to_bits());
        }
        let splats = |o: &LightTracingOutput| -> Vec<_> {
            o.splats.iter().map(|&(p, c)| (p, rgb(c))).collect()
        };
        assert!(!a_out.splats.is_empty());
        assert_eq!(splats(a_out), splats(b_out));
        assert_eq!(a_out.counters.rays, b_out.counters.rays);

        // Camera paths connecting to them.
        let bits = |s: &PixelSample| [s.radiance, s.albedo, s.normal].map(rgb);
        let mut lit = 0;
        for pixel in 0..n as u64 {
            let ctx = SampleContext {
                pixel_index: pixel,
                sample_index: 0,
                view: &view,
                iteration: Some(a),
                layers: &[],
            };
            let (x, y) = ((pixel % 32) as f32 + 0.5, (pixel / 32) as f32 + 0.5);
            let ray = view
                .frame
                .generate_ray(Vec2::new(x, y) / 32.0, Vec2::splat(0.5));
            let mut samples = [0, 1].map(|_| Sampler::new(SamplerKind::Sobol, 7, pixel, 3));
            let mut counters = [TraceCounters::default(); 2];
            let [a_rng, b_rng] = &mut samples;
            let [a_counters, b_counters] = &mut counters;
            let s = bdpt.sample_observed_baseline(&scene, ray, a_rng, a_counters, &ctx, &mut ());
            // SAFETY: the CPU runs x86-64-v3 code (checked above).
            let t =
                unsafe { bdpt.sample_observed_v3(&scene, ray, b_rng, b_counters, &ctx, &mut ()) };
            assert_eq!(bits(&s), bits(&t), "pixel {pixel}");
            assert_eq!(s.depth.to_bits(), t.depth.to_bits());
            assert_eq!(s.hit, t.hit);
            assert_eq!(a_counters.rays, b_counters.rays);
            lit += (s.radiance != Rgb::ZERO) as u32;
        }
        assert!(lit > 100, "{lit} lit samples");
    }
}
