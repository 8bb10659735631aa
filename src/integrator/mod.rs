//! Integrators: estimators of the radiance arriving along a camera ray. Each lives in its own
//! file behind the small [`Integrator`] trait; [`create`] makes one by name.

mod bdpt;
mod bdpt_ic;
mod bdpt_skeleton;
mod env_direct;
pub mod mis_auto;
mod node_skeleton;
mod path;
mod path_portal;
pub mod ray_variance;
mod resampled;
mod skeleton_shadow;
mod vpl;

pub use bdpt::{
    strategy_layer_name, AllLightPaths, Bdpt, CameraVertex, Connection, ConnectionPolicy,
    LightPaths, LightVertex, StrategyFilter, UniformPerPixel,
};
pub use bdpt_ic::BdptIc;
pub use bdpt_skeleton::{BdptSkeleton, ResamplingStats};
pub use env_direct::{EnvDirect, EnvDirectOptions, ALPHA_LAYER};
#[cfg(feature = "diagnostics")]
pub use path::diagnostics;
pub use path::PathOptions;
pub use path::PathTracer;
pub use path_portal::PortalPathTracer;
pub use skeleton_shadow::{CubeShadowMap, ShadowMapStats, SkeletonShadowMaps};
pub use vpl::{VisibilityAgreement, VplIntegrator, VplOptions, VplSelect, VplVisibility};

/// Re-exported: the heuristic lives in [`crate::math`], below the guides that weigh with it.
pub use crate::math::MisHeuristic;

use std::any::Any;
use std::cell::Cell;

use crate::error::{Error, Result};
use crate::film::PixelSample;
use crate::geometry::Ray;
use crate::guide::{PortalGuideSettings, ResamplingSettings, SkeletonGuideSettings};
use crate::light::EnvStrategy;
use crate::math::Rgb;
use crate::math::{Sampler, SamplerKind};
use crate::scene::{Camera, CameraFrame, RenderSettingsFile, Scene};
use crate::timing::StageTime;

/// Which integrators may use which heuristic: integrator knowledge, so it lives here rather
/// than beside the heuristic in [`crate::math`].
impl MisHeuristic {
    /// Fails for `auto` and `optimal` in an integrator whose [`Registration::adaptive_mis`]
    /// does not list it (`auto`: `env_direct`, `path`, `path_skeleton` and `path_portal`;
    /// `optimal`: `env_direct`).
    pub fn check_supported(self, integrator: &str) -> Result<()> {
        let adaptive = matches!(self, MisHeuristic::Auto | MisHeuristic::Optimal);
        let supported = find(integrator).is_some_and(|r| r.adaptive_mis.contains(&self));
        if adaptive && !supported {
            let takers: Vec<&str> = REGISTRY
                .iter()
                .filter(|r| r.adaptive_mis.contains(&self))
                .map(|r| r.name)
                .collect();
            return Err(Error::invalid(format!(
                "mis={} is implemented for {} only, not for {integrator} (use balance or power)",
                self.name(),
                takers.join(" and ")
            )));
        }
        Ok(())
    }
}

/// The heuristic integrator `name` weighs with under `settings`: the one set, else its own
/// default (see [`IntegratorSettings::mis`]).
pub fn mis_in_use(name: &str, settings: &IntegratorSettings) -> MisHeuristic {
    settings.mis.unwrap_or(if name == "env_direct" {
        MisHeuristic::Balance
    } else {
        MisHeuristic::Power
    })
}

/// Settings shared by the integrators.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IntegratorSettings {
    /// Maximum number of bounces (scattering events) of a path; 0 shows emitters only, 1 is
    /// direct lighting. A path has at most `max_depth + 1` segments.
    pub max_depth: u32,
    /// How MIS weights light and BSDF sampling. `None` is the integrator's own default:
    /// [`MisHeuristic::Power`] for the one-sample integrators (`path`, `path_skeleton`,
    /// `bdpt`), [`MisHeuristic::Balance`] for `env_direct`, whose many samples per strategy
    /// the balance heuristic over the counts combines as the thesis's estimator does.
    pub mis: Option<MisHeuristic>,
    /// Bidirectional integrators: light subpaths traced per iteration (`None` = one per pixel).
    pub light_paths: Option<u32>,
    /// How light sampling picks environment-map directions.
    pub env: EnvStrategy,
    /// `path` and `path_skeleton`: Russian roulette and how next-event estimation samples
    /// emissive triangles.
    pub path: PathOptions,
    /// `env_direct`'s light and BSDF samples per shading point.
    pub env_direct: EnvDirectOptions,
    /// `path_skeleton`: skeleton guiding (c_skel, strength, analysis resolution ...).
    pub skeleton: SkeletonGuideSettings,
    /// `path_portal`: the portal guide's strategy, c_portal, analysis resolution, smoothing.
    pub portal: PortalGuideSettings,
    /// `bdpt_skeleton` and `bdpt_ic`: the resampling options (N, alpha_accept, record density
    /// d, contribution images).
    pub resampling: ResamplingSettings,
    /// `vpl`: VPL count, clamping, compensation, visibility.
    pub vpl: VplOptions,
}

impl Default for IntegratorSettings {
    fn default() -> Self {
        IntegratorSettings {
            max_depth: 8,
            mis: None,
            light_paths: None,
            env: EnvStrategy::default(),
            path: PathOptions::default(),
            env_direct: EnvDirectOptions::default(),
            skeleton: SkeletonGuideSettings::default(),
            portal: PortalGuideSettings::default(),
            resampling: ResamplingSettings::default(),
            vpl: VplOptions::default(),
        }
    }
}

impl IntegratorSettings {
    /// Applies what a scene file says about integrators: its maximum depth, `path_skeleton`
    /// guide options and the resampling options of `bdpt_skeleton` and `bdpt_ic`.
    /// The file keeps these options raw: they are validated here, and an invalid one is an
    /// [`Error::Parse`] naming the scene file and the option (`render.skeleton.c_skel`).
    pub fn apply_file(&mut self, file: &RenderSettingsFile) -> Result<()> {
        if let Some(d) = file.max_depth {
            crate::limits::check_max_depth("render.max_depth", d)?;
            self.max_depth = d;
        }
        let located = |location: String, e: Error| match (&file.source, e) {
            (Some(path), Error::InvalidArgument(message)) => Error::parse(path, location, message),
            (None, Error::InvalidArgument(message)) => {
                Error::invalid(format!("{location}: {message}"))
            }
            (_, other) => other,
        };
        for (key, value) in file.skeleton_options() {
            self.skeleton
                .set(&key, &value)
                .map_err(|e| located(format!("render.skeleton.{key}"), e))?;
        }
        for (key, value) in file.resampling_options() {
            self.resampling
                .set(&key, &value)
                .map_err(|e| located(format!("render.resampling.{key}"), e))?;
        }
        Ok(())
    }
}

/// What an integrator computed for a scene before rendering it, stage by stage (for the render
/// summary, and counted in equal-time budgets).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Precomputation {
    pub stages: Vec<StageTime>,
    /// Facts worth a line of the summary ("43 filtered nodes, 5 importance nodes").
    pub notes: Vec<String>,
}

impl Precomputation {
    pub fn seconds(&self) -> f64 {
        self.stages.iter().map(|s| s.seconds).sum()
    }
}

/// Counters an integrator updates while tracing (kept per worker, summed at the end).
#[derive(Clone, Copy, Debug, Default)]
pub struct TraceCounters {
    pub rays: u64,
    /// The largest weight of a guided path against plain path tracing's for the same
    /// directions (the product of p_bsdf / p over its directions so far; 1 when no
    /// direction was guided; 0 when the integrator guides nothing): a firefly regression
    /// shows here first.
    pub largest_guided_ratio: f32,
}

/// The camera and image an integrator renders for.
#[derive(Clone, Copy, Debug)]
pub struct View {
    pub frame: CameraFrame,
    pub width: u32,
    pub height: u32,
    /// The render's pixel sampler: an integrator that traces the pixels' samples itself in
    /// `begin_iteration` (`vpl:interleave=N`, which filters them in image space) draws the
    /// numbers the render loop would.
    pub sampler: SamplerKind,
}

impl View {
    /// The camera ray of one pixel sample: the film position jittered over pixel (x, y) and
    /// the lens position from their fixed sampler dimensions, leaving `rng` at the
    /// integrator's first dimension. The one place that maps a pixel sample to its ray, so
    /// that a tool replaying a sample (examples/firefly_map.rs) traces the render's own path.
    #[inline]
    pub fn primary_ray(&self, x: u32, y: u32, rng: &mut Sampler) -> Ray {
        use crate::math::{FILM_DIMENSION, FIRST_INTEGRATOR_DIMENSION, LENS_DIMENSION};
        rng.set_dimension(FILM_DIMENSION);
        let jitter = rng.uniform2();
        let film_pos = crate::math::Vec2::new(
            (x as f32 + jitter.x) / self.width as f32,
            (y as f32 + jitter.y) / self.height as f32,
        );
        rng.set_dimension(LENS_DIMENSION);
        // A pinhole camera ignores the lens position: not computed.
        let lens = if self.frame.has_lens() {
            rng.uniform2()
        } else {
            rng.skip_uniform2();
            crate::math::Vec2::ZERO
        };
        let ray = self.frame.generate_ray(film_pos, lens);
        rng.set_dimension(FIRST_INTEGRATOR_DIMENSION);
        ray
    }
}

/// Work an integrator shares between all pixels of one sample index (e.g. the light subpaths
/// of bidirectional path tracing), and what it adds to the image directly.
#[derive(Default)]
pub struct Iteration {
    /// Handed to every `sample` of this sample index.
    pub data: Option<Box<dyn Any + Send + Sync>>,
    /// Contributions to add to pixels (row-major index), already scaled as one sample's worth
    /// (light tracing splats).
    pub splats: Vec<(u32, Rgb)>,
    /// Splats into the integrator's layers: (layer, pixel, value).
    pub layer_splats: Vec<(u32, u32, Rgb)>,
    pub rays: u64,
}

/// What a pixel sample knows about where it is.
#[derive(Clone, Copy)]
pub struct SampleContext<'a> {
    pub pixel_index: u64,
    /// The index of this sample among the pixel's (a pixel's samples run in this order).
    pub sample_index: u32,
    pub view: &'a View,
    pub iteration: Option<&'a (dyn Any + Send + Sync)>,
    /// This sample's values of the integrator's layers (see [`Integrator::layers`]), zero on
    /// entry; empty when the integrator has none.
    pub layers: &'a [Cell<Rgb>],
}

/// An estimator of radiance along camera rays. Implementations are immutable during a render
/// and shared by the worker threads.
pub trait Integrator: Send + Sync {
    fn name(&self) -> &'static str;

    /// Names of extra per-pixel RGB images the integrator writes through
    /// [`SampleContext::layers`] and [`Iteration::layer_splats`] (debugging images; none by
    /// default).
    fn layers(&self) -> Vec<String> {
        Vec::new()
    }

    /// Builds what this integrator needs of `scene` seen through `camera` (and nothing else:
    /// most need nothing). `camera` is the one the render will use, however it was given
    /// (scene file, command line, C API, automatic framing): a precomputation that learns from
    /// the view (the skeleton guide's training) must see the rendered view.
    /// Must run before rendering `scene` (see [`crate::render::prepare`], which runs it on
    /// the render's worker threads); running it again rebuilds. `progress(stage, fraction)`
    /// may cancel by returning false.
    fn prepare(
        &mut self,
        _scene: &Scene,
        _camera: &Camera,
        _progress: &dyn Fn(&str, f64) -> bool,
    ) -> Result<Precomputation> {
        Ok(Precomputation::default())
    }

    /// The wall-clock seconds the next `prepare` and render may take together, where the host
    /// gave a budget (`lacuna compare`, `lacuna render --time`, a C API job's time budget): a
    /// precomputation may then stop early rather than spend the render's time
    /// (`path_skeleton`'s scout). Most integrators ignore it.
    fn set_time_budget(&mut self, _seconds: Option<f64>) {}

    /// Fails when rendering `scene` needs a `prepare` for it that has not run.
    fn check_prepared(&self, _scene: &Scene) -> Result<()> {
        Ok(())
    }

    /// True when `begin_iteration` must run before the pixels of every sample index.
    fn uses_iterations(&self) -> bool {
        false
    }

    /// Prepares one sample index (parallel inside; deterministic for a given seed).
    fn begin_iteration(
        &self,
        _scene: &Scene,
        _view: &View,
        _seed: u64,
        _sample_index: u32,
    ) -> Result<Iteration> {
        Ok(Iteration::default())
    }

    /// True when [`Self::begin_sized_iteration`] honours its size: a time-budgeted render
    /// then sizes each sample index's work so that its passes fill the budget
    /// ([`crate::render::next_pass_size`]) rather than stopping where the next whole one no
    /// longer fits.
    fn sized_iterations(&self) -> bool {
        false
    }

    /// [`Self::begin_iteration`] with `size` times the usual work (`vpl`: `size` x `count`
    /// light subpaths); each sample index stays one unbiased sample, its variance about
    /// 1 / `size` times the usual. Sample-budget renders always pass 1, so that their images
    /// stay a function of the seed.
    fn begin_sized_iteration(
        &self,
        scene: &Scene,
        view: &View,
        seed: u64,
        sample_index: u32,
        _size: f32,
    ) -> Result<Iteration> {
        self.begin_iteration(scene, view, seed, sample_index)
    }

    /// Why this integrator's images are biased (they converge to something other than the
    /// rendering equation's solution), in a sentence for the render summary and the EXR
    /// metadata; None for a consistent, unbiased estimator.
    fn bias(&self) -> Option<String> {
        None
    }

    /// Lines for the render summary about the last render (statistics the integrator kept).
    fn render_notes(&self) -> Vec<String> {
        Vec::new()
    }

    /// One sample of the radiance arriving at the camera along `ray`, with the first-hit AOVs.
    fn sample(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        ctx: &SampleContext,
    ) -> PixelSample;
}

/// One integrator as [`create`] and [`parse_spec`] know it: registering an integrator is one
/// entry in [`REGISTRY`], defined beside the integrator in its own file.
pub struct Registration {
    pub name: &'static str,
    /// Sets one of the integrator's own `NAME:KEY=VALUE` options (the shared `max_depth`,
    /// `mis` and `env` are set before): `Ok(true)` when it is one, `Ok(false)` when the
    /// integrator has no such option.
    pub set_option: fn(&mut IntegratorSettings, &SpecOption) -> Result<bool>,
    /// Makes the integrator from its settings (validating what is its own).
    pub create: fn(IntegratorSettings) -> Result<Box<dyn Integrator>>,
    /// The heuristics beyond `balance` and `power` it takes (`auto`, `optimal`; see
    /// [`MisHeuristic::check_supported`]).
    pub adaptive_mis: &'static [MisHeuristic],
}

/// The integrators this build offers, in the order help texts list them.
pub const REGISTRY: &[Registration] = &[
    path::PATH,
    path::PATH_SKELETON,
    path_portal::REGISTRATION,
    bdpt::REGISTRATION,
    bdpt_skeleton::REGISTRATION,
    bdpt_ic::REGISTRATION,
    env_direct::REGISTRATION,
    vpl::REGISTRATION,
];

/// The registered integrator called `name`.
pub fn find(name: &str) -> Option<&'static Registration> {
    REGISTRY.iter().find(|r| r.name == name)
}

/// Names of the integrators this build offers.
pub fn names() -> impl Iterator<Item = &'static str> {
    REGISTRY.iter().map(|r| r.name)
}

/// One `KEY=VALUE` option of an integrator specification, as its integrator's
/// [`Registration::set_option`] receives it.
pub struct SpecOption<'a> {
    pub key: &'a str,
    pub value: &'a str,
    /// The whole specification, for error messages.
    pub spec: &'a str,
}

impl SpecOption<'_> {
    /// The value as a non-negative integer.
    pub fn count(&self) -> Result<u32> {
        self.value.parse::<u32>().map_err(|_| {
            Error::invalid(format!(
                "integrator option {}={} in '{}' must be a non-negative integer",
                self.key, self.value, self.spec
            ))
        })
    }
}

/// Splits an integrator specification `NAME[:KEY=VALUE]...` into the name and the settings
/// its options change, so one comparison can race variants of an integrator:
/// - any integrator: `max_depth=D`, `mis=power|balance` (`path` also `auto`, `env_direct` also `auto|optimal`), `env=STRATEGY` (environment
///   sampling: auto, latlong, cube-uniform, cube-power, cube-dynamic, bsdf, portals);
/// - `path` and `path_skeleton`: `rr_depth=D|auto` (bounces before Russian roulette starts;
///   `auto` chooses them per scene with a pilot),
///   `triangles=area|solid_angle` (how next-event estimation samples emissive triangles);
/// - `env_direct`: `samples=N` (light samples per shading point), `bsdf=N` (BSDF samples) and
///   `alpha_steps=K` (`mis=auto`: K quadratic models of the second moment, 1 = eq. 5.4 alone,
///   default 2) and `warmup=M` (`mis=auto|optimal`: warm-up samples, default 32 but at most
///   half the total for `auto`, half for `optimal`);
/// - `path_skeleton`: the guide's options ([`SkeletonGuideSettings::set`]), e.g.
///   `path_skeleton:strength=16:c_skel=0.3` or `strength=auto:64`;
/// - `path_portal`: `path`'s options and the portal guide's ([`PortalGuideSettings::set`]):
///   `strategy=shortest|irradiance`, `c_portal=C` in [0, 1), `resolution=N` (analysis voxels
///   on the longest axis), `smoothing=R` (voxels), with `irradiance` `training_paths=N`,
///   `face_mix=F`, `d_t=D`, `o_t=O`, e.g. `path_portal:c_portal=0.3:resolution=128`;
/// - `bdpt_skeleton`: `subset=N`, `accept=ALPHA`, `images=true`, `count=one|subset` ([`ResamplingSettings::set`])
///   and the skeleton's `resolution=N` / `voxel_budget=N`, e.g. `bdpt_skeleton:subset=1024:accept=1`;
/// - `bdpt_ic`: `subset=N`, `density=D`, `images=true`, `count=one|subset`, e.g. `bdpt_ic:subset=1024:density=0.001`;
/// - `vpl`: `count=N` (light subpaths per pass), `clamp=R` (0 = off), `compensate=true|false`,
///   `visibility=exact|skeleton`, with skeleton visibility `shadow_res=N`,
///   `shadow_budget_mb=M`, `verify=P` and the skeleton's `resolution=N` / `voxel_budget=N`,
///   `select=uniform|importance` with `candidates=K`, `p_min=P`, `probes=N`,
///   `interleave=N` (N x N VPL sets, the indirect light filtered over N x N blocks)
///   ([`VplOptions::set`]), e.g. `vpl:count=128:clamp=0.05:compensate=true` or
///   `vpl:visibility=skeleton:shadow_res=32` or `vpl:select=importance:candidates=8`.
///
/// The shared options are set here, the others by the integrator's
/// [`Registration::set_option`].
pub fn parse_spec(
    spec: &str,
    mut settings: IntegratorSettings,
) -> Result<(&str, IntegratorSettings)> {
    let mut parts = spec.split(':');
    let name = parts.next().unwrap_or_default().trim();
    let registration = find(name);
    let mut options = parts.peekable();
    while let Some(option) = options.next() {
        // "strength=auto:64" arrives split in two: glue a bare number back to `auto`.
        let mut option = option.to_string();
        if option.ends_with("=auto") {
            if let Some(max) = options.peek().filter(|o| !o.contains('=')) {
                option = format!("{option}:{max}");
                options.next();
            }
        }
        let (key, value) = option.split_once('=').ok_or_else(|| {
            Error::invalid(format!(
                "integrator option '{option}' in '{spec}' must be KEY=VALUE"
            ))
        })?;
        let option = SpecOption {
            key: key.trim(),
            value: value.trim(),
            spec,
        };
        let known = match option.key {
            "max_depth" => {
                settings.max_depth = option.count()?;
                crate::limits::check_max_depth(
                    &format!("integrator option max_depth in '{spec}'"),
                    settings.max_depth,
                )?;
                true
            }
            "mis" => {
                settings.mis = Some(MisHeuristic::parse(option.value)?);
                true
            }
            "env" => {
                settings.env = EnvStrategy::parse(option.value)?;
                true
            }
            _ => match registration {
                Some(r) => (r.set_option)(&mut settings, &option)?,
                None => false,
            },
        };
        if !known {
            return Err(Error::invalid(format!(
                "integrator '{name}' has no option '{}' (in '{spec}')",
                option.key
            )));
        }
    }
    Ok((name, settings))
}

/// Creates an integrator from its specification (see [`parse_spec`]).
pub fn create(spec: &str, settings: IntegratorSettings) -> Result<Box<dyn Integrator>> {
    let (name, settings) = parse_spec(spec, settings)?;
    crate::limits::check_max_depth("max_depth", settings.max_depth)?;
    let registration = find(name).ok_or_else(|| {
        Error::invalid(format!(
            "unknown integrator '{name}' (available: {})",
            names().collect::<Vec<_>>().join(", ")
        ))
    })?;
    if let Some(mis) = settings.mis {
        mis.check_supported(name)?;
    }
    // Only the path tracer's estimator knows the shading point where it weighs an escaped ray.
    if settings.env == EnvStrategy::Portals
        && !matches!(name, "path" | "path_skeleton" | "path_portal")
    {
        return Err(Error::invalid(format!(
            "env=portals is implemented for path, path_skeleton and path_portal only, not for {name}"
        )));
    }
    (registration.create)(settings)
}
