//! `vpl`: instant radiosity (Keller 1997; 000 §4.1.4, lines 1356-1436), a fast preview.
//!
//! Each sample index ("pass") traces `count` light subpaths with `bdpt`'s light tracing
//! ([`Bdpt::trace_light_paths`], without its splats onto the camera); every stored vertex is a
//! virtual point light (VPL). A camera path follows delta surfaces to its first non-delta
//! vertex x, which gets
//! - direct light by next-event estimation ([`estimator::sample_direct_light`]), and
//! - indirect light from every VPL y of the pass with an exact shadow ray:
//!   `T_y f_y(y -> x) f_x(x -> y) G(x, y) / 1`, T_y the VPL's light-subpath throughput (the
//!   pass's subpaths are one sample each of the light transport, so their VPLs together are
//!   one unbiased estimate of the indirect light at every point).
//!
//! # Clamping and its compensation
//!
//! `G = |cos_x| |cos_y| / d^2` (shading cosines) is unbounded where x and y are close: the
//! estimate's variance is infinite and the image shows bright blotches. With `clamp = r > 0`,
//! the VPL term uses `min(G, b)` with `b = 1 / (r D)^2`, D the diagonal of the scene's bounds
//! (a term clamped at distance r D). When G exceeds b the clamped term is computed as
//! `T f_y f_x b`, so no tiny distance divides anything. Clamping removes energy (the image is
//! darker near corners): biased.
//!
//! `compensate=true` adds back what was clamped (Kollig & Keller 2004, "Illumination in the
//! presence of weak singularities"). Write c(x, y) = min(1, b / G(x, y)); the VPLs estimate
//! the integral of the indirect integrand times c, and one BSDF-sampled direction from x
//! estimates the integral times (1 - c): it finds the surface point y along that direction and
//! continues there with weight (1 - c(x, y)) f_x |cos_x| / p, estimating the light leaving y
//! towards x by this same estimator (next-event estimation, VPLs, compensation), without y's
//! emission, which next-event estimation at x counted. A delta surface hit this way has no
//! VPL (c = 0): the continuation goes through it with weight 1, and there the emitters found
//! behind it count (no light sample reaches through a delta surface). The sum is unbiased
//! whatever b; far from corners 1 - c = 0 and the continuation ends at once.
//!
//! Without compensation the paths VPLs cannot represent are missing too: light reaching a
//! non-delta vertex by way of a delta surface (caustics seen on a diffuse wall). The image is
//! unbiased only with compensation (or with `clamp=0` on scenes without delta surfaces);
//! [`VplOptions::bias`] says which.
//!
//! Every pass draws new VPLs from the seed and the sample index, so the image converges as
//! passes accumulate, and the light subpaths are traced in fixed chunks: the same image for
//! any thread count.

use super::bdpt::{shading_correction, Bdpt};
use super::{Integrator, IntegratorSettings, Iteration, SampleContext, SpecOption, TraceCounters};
use super::{Registration, View};
use crate::error::{Error, Result};
use crate::film::PixelSample;
use crate::geometry::Ray;
use crate::guide::{estimator, RenderEstimator};
use crate::math::{Frame, Rgb, Sampler, Vec3, FIRST_INTEGRATOR_DIMENSION};
use crate::scene::{Bsdf, Scene, SurfaceInteraction, Transport};

/// Which shadow test the VPL term uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VplVisibility {
    /// A shadow ray per VPL and shading point: the reference.
    Exact,
}

impl VplVisibility {
    pub fn parse(value: &str) -> Result<Self> {
        match value {
            "exact" => Ok(VplVisibility::Exact),
            "skeleton" | "clusters" => Err(Error::invalid(format!(
                "vpl: visibility={value} is not implemented (only visibility=exact)"
            ))),
            _ => Err(Error::invalid(format!(
                "vpl: visibility={value} is not one of: exact"
            ))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            VplVisibility::Exact => "exact",
        }
    }
}

/// `vpl`'s own options (`vpl:count=N:clamp=R:compensate=true|false:visibility=exact`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VplOptions {
    /// Light subpaths per pass; each leaves a VPL at every non-delta surface it reaches.
    pub count: u32,
    /// Clamping distance as a fraction of the scene's bounding diagonal: the geometry term is
    /// capped at `1 / (clamp D)^2`. 0 turns clamping off.
    pub clamp: f32,
    /// Adds back what clamping removed with a path-traced continuation (module docs): unbiased.
    pub compensate: bool,
    pub visibility: VplVisibility,
}

impl Default for VplOptions {
    fn default() -> Self {
        VplOptions {
            count: 64,
            clamp: 0.1,
            compensate: false,
            visibility: VplVisibility::Exact,
        }
    }
}

impl VplOptions {
    /// Sets the option `key` from `value`: `Ok(false)` when `vpl` has no such option.
    pub fn set(&mut self, key: &str, value: &str) -> Result<bool> {
        match key {
            "count" => {
                let n = value.parse::<u32>().map_err(|_| {
                    Error::invalid(format!(
                        "vpl: count={value} must be a positive integer (light subpaths per pass)"
                    ))
                })?;
                self.count = n;
            }
            "clamp" => {
                let r = value.parse::<f32>().map_err(|_| {
                    Error::invalid(format!(
                        "vpl: clamp={value} must be a number (a fraction of the scene's diagonal, 0 = off)"
                    ))
                })?;
                self.clamp = r;
            }
            "compensate" => {
                self.compensate = match value {
                    "true" | "1" | "on" => true,
                    "false" | "0" | "off" => false,
                    _ => {
                        return Err(Error::invalid(format!(
                            "vpl: compensate={value} must be true or false"
                        )))
                    }
                }
            }
            "visibility" => self.visibility = VplVisibility::parse(value)?,
            _ => return Ok(false),
        }
        self.validate()?;
        Ok(true)
    }

    pub fn validate(&self) -> Result<()> {
        if self.count == 0 {
            return Err(Error::invalid(
                "vpl: count must be at least 1 light subpath per pass",
            ));
        }
        crate::limits::check_light_paths(
            "vpl: count (light subpaths per pass)",
            self.count as u64,
        )?;
        if !(self.clamp >= 0.0 && self.clamp.is_finite()) {
            return Err(Error::invalid(format!(
                "vpl: clamp={} must be a finite number >= 0 (0 = off)",
                self.clamp
            )));
        }
        Ok(())
    }

    /// Why an image rendered with these options is biased, or None when it is not (for the
    /// render summary and the EXR metadata).
    pub fn bias(&self) -> Option<String> {
        if self.compensate {
            return None;
        }
        Some(if self.clamp > 0.0 {
            format!(
                "biased: VPL geometry term clamped at distance {} of the scene diagonal without compensation (darker near corners; light through delta surfaces onto non-delta ones missing); compensate=true makes it unbiased",
                self.clamp
            )
        } else {
            "biased on scenes with delta surfaces: light through them onto non-delta surfaces is missing without compensation (compensate=true makes it unbiased)".to_string()
        })
    }
}

/// Sampler slots of one vertex: the light sample's 2-D, then three for the BSDF direction
/// (component choice, 2-D).
const SLOTS_PER_VERTEX: u32 = 4;
const LIGHT_SLOT: u32 = 0;
const DIRECTION_SLOT: u32 = 1;

fn slot(depth: u32, k: u32) -> u32 {
    FIRST_INTEGRATOR_DIMENSION + depth * SLOTS_PER_VERTEX + k
}

/// One virtual point light: a stored light-subpath vertex with its BSDF resolved.
struct Vpl {
    si: SurfaceInteraction,
    bsdf: Bsdf,
    frame: Frame,
    /// `si.wo` (towards the light subpath's previous vertex) in `frame`.
    wo_local: Vec3,
    throughput: Rgb,
    /// Segments from the light to this vertex.
    path_len: u32,
}

/// The VPLs of one pass, sorted by subpath length so that a vertex that may use only the
/// shorter ones stops early.
struct VplSet {
    vpls: Vec<Vpl>,
    /// The cap on the geometry term (infinite without clamping).
    bound: f32,
}

pub struct VplIntegrator {
    settings: IntegratorSettings,
    options: VplOptions,
    light: Bdpt,
}

impl VplIntegrator {
    pub fn new(settings: IntegratorSettings) -> Result<Self> {
        settings.vpl.validate()?;
        let light = Bdpt::new(settings)
            .with_light_paths(settings.vpl.count as usize)?
            .without_light_tracing();
        Ok(VplIntegrator {
            settings,
            options: settings.vpl,
            light,
        })
    }

    fn estimator(&self) -> RenderEstimator {
        RenderEstimator {
            mis: self.settings.mis.unwrap_or_default(),
            // `triangles=` is `path`'s option; `vpl` samples emissive triangles by area.
            triangles: crate::light::TriangleSampling::default(),
            env: self.settings.env,
        }
    }

    /// The cap on the geometry term for `scene` (module docs).
    fn bound(&self, scene: &Scene) -> f32 {
        let diagonal = scene.bounds().diagonal().length();
        let r = self.options.clamp * diagonal;
        if r > 0.0 {
            1.0 / (r * r)
        } else {
            f32::INFINITY
        }
    }

    /// Light from every VPL of at most `max_len` segments at x (shading `frame`, `wo_local`).
    #[allow(clippy::too_many_arguments)]
    fn gather(
        &self,
        scene: &Scene,
        set: &VplSet,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        frame: &Frame,
        wo_local: Vec3,
        max_len: u32,
        counters: &mut TraceCounters,
    ) -> Rgb {
        let mut sum = Rgb::ZERO;
        for v in set.vpls.iter().take_while(|v| v.path_len <= max_len) {
            let d = v.si.p - si.p;
            let dist2 = d.length_squared();
            if !(dist2 > 0.0) {
                continue;
            }
            let dir = d / dist2.sqrt();
            // Both ends must scatter on the side the connection leaves from.
            if dir.dot(si.ng) * si.wo.dot(si.ng) <= 0.0
                || (-dir).dot(v.si.ng) * v.si.wo.dot(v.si.ng) <= 0.0
            {
                continue;
            }
            let wi_x = frame.to_local(dir);
            let f_x = bsdf.eval(wo_local, wi_x);
            let wi_y = v.frame.to_local(-dir);
            let f_y = v.bsdf.eval(v.wo_local, wi_y) * shading_correction(&v.si, v.si.wo, -dir);
            let cosines = wi_x.z.abs() * wi_y.z.abs();
            if f_x == Rgb::ZERO || f_y == Rgb::ZERO || cosines == 0.0 {
                continue;
            }
            // min(G, b) without dividing by a tiny distance when the cap applies.
            let g = if cosines >= set.bound * dist2 {
                set.bound
            } else {
                cosines / dist2
            };
            let value = v.throughput * f_x * f_y * g;
            if !crate::math::is_finite3(value) || value == Rgb::ZERO {
                continue;
            }
            counters.rays += 1;
            let shadow = si.spawn_ray_to(v.si.p, v.si.p_error, v.si.ng);
            if !scene.occluded(&shadow) {
                sum += value;
            }
        }
        sum
    }

    /// One camera path (module docs).
    fn trace(
        &self,
        scene: &Scene,
        set: &VplSet,
        mut ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
    ) -> PixelSample {
        let mut out = PixelSample::default();
        let mut radiance = Rgb::ZERO;
        let mut beta = Rgb::ONE;
        // Emitters and the environment found along the path count only where no light sample
        // could have found them: from the camera and behind delta surfaces.
        let mut count_emission = true;
        let mut depth = 0u32;
        let max_depth = self.settings.max_depth;
        let estimator = self.estimator();
        let mut hit = {
            counters.rays += 1;
            scene.intersect(&ray)
        };
        loop {
            let Some(si) = hit else {
                if count_emission {
                    if let Some((_, env)) = scene.environment() {
                        if depth > 0 || env.visible_to_camera() {
                            radiance += beta * env.radiance(ray.dir);
                        }
                    }
                }
                break;
            };
            let bsdf = scene.bsdf(&si);
            if depth == 0 {
                out.hit = true;
                out.depth = si.t;
                out.normal = si.ns;
                out.albedo = bsdf.albedo_hint();
            }
            if count_emission {
                radiance += beta * scene.emitted(&si);
            }
            if depth >= max_depth {
                break;
            }
            let frame = si.shading_frame();
            let wo_local = frame.to_local(si.wo);
            if !bsdf.is_delta() {
                rng.set_dimension(slot(depth, LIGHT_SLOT));
                if let Some(light) = estimator::sample_direct_light(
                    scene,
                    &si,
                    &frame,
                    &bsdf,
                    wo_local,
                    &estimator,
                    rng.uniform2(),
                    &mut counters.rays,
                ) {
                    radiance += beta * light.unweighted();
                }
                // A VPL of j segments makes a path of (depth + 1) + 1 + j segments.
                let max_len = max_depth - depth;
                if max_len >= 2 {
                    let gathered = self.gather(
                        scene,
                        set,
                        &si,
                        &bsdf,
                        &frame,
                        wo_local,
                        max_len - 1,
                        counters,
                    );
                    radiance += beta * gathered;
                }
                if !self.options.compensate {
                    break;
                }
            }
            // A delta surface, or the compensation's continuation.
            rng.set_dimension(slot(depth, DIRECTION_SLOT));
            let Some(bs) = bsdf.sample_from(wo_local, rng, Transport::Radiance) else {
                break;
            };
            let wi = frame.to_world(bs.wi);
            let reflected = bs.wi.z * wo_local.z > 0.0;
            let same_side = wi.dot(si.ng) * si.wo.dot(si.ng) > 0.0;
            if reflected != same_side || !(bs.pdf > 0.0) {
                break;
            }
            ray = si.spawn_ray(wi);
            counters.rays += 1;
            hit = scene.intersect(&ray);
            let mut weight = bs.f * (bs.wi.z.abs() / bs.pdf);
            if bsdf.is_delta() {
                count_emission = true;
            } else {
                count_emission = false;
                // The share the VPLs left out: 1 - min(1, b / G) at the point found (0 past
                // the scene: an escaped direction is next-event estimation's).
                let Some(y) = &hit else {
                    break;
                };
                if !scene.bsdf(y).is_delta() {
                    // G as `gather` computes it for a VPL at y: the same split of the
                    // integrand, so the two parts sum to it exactly.
                    let d = y.p - si.p;
                    let dist2 = d.length_squared();
                    let dir = d / dist2.sqrt();
                    let cosines = si.ns.dot(dir).abs() * y.ns.dot(dir).abs();
                    let scaled_bound = set.bound * dist2;
                    if !(cosines > scaled_bound) {
                        break;
                    }
                    weight *= 1.0 - scaled_bound / cosines;
                }
            }
            beta *= weight;
            if !crate::math::is_finite3(beta) || beta == Rgb::ZERO {
                break;
            }
            depth += 1;
        }
        out.radiance = radiance;
        out
    }
}

impl Integrator for VplIntegrator {
    fn name(&self) -> &'static str {
        "vpl"
    }

    fn bias(&self) -> Option<String> {
        self.options.bias()
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
        let count = self.options.count as usize;
        let (paths, out) = self
            .light
            .trace_light_paths(scene, view, seed, sample_index, count);
        let mut vpls: Vec<Vpl> = paths
            .vertices
            .iter()
            .map(|v| {
                let frame = v.si.shading_frame();
                Vpl {
                    si: v.si,
                    bsdf: scene.bsdf(&v.si),
                    frame,
                    wo_local: frame.to_local(v.si.wo),
                    throughput: v.throughput / count as f32,
                    path_len: v.path_len,
                }
            })
            .collect();
        // Stable: the order stays a function of the seed alone.
        vpls.sort_by_key(|v| v.path_len);
        Ok(Iteration {
            data: Some(Box::new(VplSet {
                vpls,
                bound: self.bound(scene),
            })),
            rays: out.rays(),
            ..Default::default()
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
        let empty = VplSet {
            vpls: Vec::new(),
            bound: f32::INFINITY,
        };
        let set = ctx
            .iteration
            .and_then(|d| d.downcast_ref::<VplSet>())
            .unwrap_or(&empty);
        self.trace(scene, set, ray, rng, counters)
    }
}

/// `vpl` in the integrator registry.
pub(super) const REGISTRATION: Registration = Registration {
    name: "vpl",
    set_option: |settings, option: &SpecOption| settings.vpl.set(option.key, option.value),
    create: |settings| Ok(Box::new(VplIntegrator::new(settings)?)),
    adaptive_mis: &[],
};
