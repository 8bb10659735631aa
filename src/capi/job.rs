//! `lacuna_render_job`: an integrator with typed settings, run on a scene into a film, with a
//! progress callback and cancellation from any thread.

use std::ffi::{c_char, c_void};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::boundary::{self, lacuna_status, CapiError, CapiResult};
use super::buffer::{arc_clone, arc_into_handle, arg, box_free, out_ptr, str_arg, write_out};
use super::context::{lock, LACUNA_MAX_THREADS};
use super::film::{lacuna_film, stats_to_c};
use super::scene::lacuna_scene;
use super::types::*;
use crate::analysis::Resolution;
use crate::film::{ExrMetadata, Film};
use crate::guide::SkeletonStrength;
use crate::integrator::{self, Bdpt, Integrator, StrategyFilter};
use crate::math::SamplerKind;
use crate::render::settings::{resolve, resolve_camera, ResolvedSettings, SettingsOverrides};
use crate::render::{Progress, RenderSettings, RenderStats};
use crate::scene::Camera;

/// Progress of a render: `user_data` as registered and the fraction done in [0, 1]. Return
/// false to cancel (the run then fails with `LACUNA_STATUS_CANCELLED`). Called on Lacuna's
/// worker threads, one call at a time, with non-decreasing fractions; it must be quick and must
/// not unwind (throw) into Lacuna.
pub type lacuna_progress_callback =
    Option<unsafe extern "C" fn(user_data: *mut c_void, fraction: f64) -> bool>;

/// The host's callback as the `progress(stage, fraction)` closure that staged builds
/// (analysis, skeleton, skeleton guide) take. The mutex makes the closure `Sync` and keeps
/// calls one at a time, as the callback's contract promises; fractions are clamped to [0, 1].
pub(crate) fn stage_progress(
    progress: lacuna_progress_callback,
    user_data: *mut c_void,
) -> impl Fn(&str, f64) -> bool + Sync {
    let user_data = user_data as usize;
    let callback = Mutex::new(progress);
    move |_: &str, fraction: f64| -> bool {
        match *callback.lock().unwrap_or_else(|e| e.into_inner()) {
            // SAFETY: the host registered this callback with this user data.
            Some(f) => unsafe { f(user_data as *mut c_void, fraction.clamp(0.0, 1.0)) },
            None => true,
        }
    }
}

#[derive(Clone, Copy)]
pub(crate) struct ProgressCallback {
    function: unsafe extern "C" fn(*mut c_void, f64) -> bool,
    user_data: usize,
}

/// Settings of a job; copied at the start of each run.
#[derive(Clone)]
pub(crate) struct JobSettings {
    /// Integrator, render and integrator settings (`render::settings::resolve`), changed by
    /// the setters.
    pub resolved: ResolvedSettings,
    pub camera: Option<Camera>,
    /// Thin lens (radius, focus distance) applied to whichever camera the run uses.
    pub lens: Option<(f32, f32)>,
    /// bdpt: one strategy only, and the longest path whose strategies get images.
    pub strategy: Option<StrategyFilter>,
    pub strategy_images: Option<u32>,
    pub progress: Option<ProgressCallback>,
    /// How `lacuna_render_job_compare` runs its contenders.
    pub compare_schedule: crate::compare::Schedule,
}

impl JobSettings {
    /// The integrator these settings describe, told the job's time budget (a precomputation
    /// may stop early rather than spend the render's time).
    pub(crate) fn make_integrator(&self) -> crate::error::Result<Box<dyn Integrator>> {
        let mut integrator = self.make_integrator_unbudgeted()?;
        integrator.set_time_budget(self.resolved.render.time_limit.map(|t| t.as_secs_f64()));
        Ok(integrator)
    }

    fn make_integrator_unbudgeted(&self) -> crate::error::Result<Box<dyn Integrator>> {
        if self.strategy.is_none() && self.strategy_images.is_none() {
            return integrator::create(
                &self.resolved.integrator,
                self.resolved.integrator_settings,
            );
        }
        // Only bdpt jobs can have these (checked by their setters).
        if let Some(mis) = self.resolved.integrator_settings.mis {
            mis.check_supported("bdpt")?;
        }
        let mut bdpt = Bdpt::new(self.resolved.integrator_settings);
        if let Some(f) = self.strategy {
            bdpt = bdpt.with_strategy(f)?;
        }
        if let Some(len) = self.strategy_images {
            bdpt = bdpt.with_strategy_images(len)?;
        }
        Ok(Box::new(bdpt))
    }

    /// The integrator's name without its options.
    pub(crate) fn integrator_name(&self) -> &str {
        self.resolved.integrator_name()
    }

    /// Fails unless the job's integrator traces light subpaths (`bdpt` and the resampling
    /// integrators built on it).
    fn require_light_subpaths(&self, what: &str) -> CapiResult<()> {
        match self.integrator_name() {
            "bdpt" | "bdpt_skeleton" | "bdpt_ic" => Ok(()),
            _ => Err(CapiError::operation(format!(
                "{what} applies to bdpt, bdpt_skeleton and bdpt_ic; this job renders with '{}'",
                self.resolved.integrator
            ))),
        }
    }

    /// Fails unless the job's integrator is plain `bdpt` (its strategy filter and images).
    fn require_bidirectional(&self, what: &str) -> CapiResult<()> {
        if self.resolved.integrator == "bdpt" {
            Ok(())
        } else {
            Err(CapiError::operation(format!(
                "{what} applies to the bdpt integrator; this job renders with '{}'",
                self.resolved.integrator
            )))
        }
    }
}

/// A render of a scene: integrator, settings, progress callback. Runs produce films.
///
/// Single owner (`lacuna_render_job_new`/`lacuna_render_job_free`); keeps its scene alive.
/// Thread safety: `lacuna_render_job_cancel` may be called from any thread at any time, also
/// while the job runs. The other functions must not run concurrently with each other on the
/// same job, except that setters called during a run only affect later runs; starting a second
/// run while one is running fails with `LACUNA_STATUS_INVALID_OPERATION`. Do not free a job
/// while it runs.
pub struct lacuna_render_job {
    pub(crate) scene: Arc<lacuna_scene>,
    settings: Mutex<JobSettings>,
    cancel: AtomicBool,
    running: AtomicBool,
    last_stats: Mutex<Option<RenderStats>>,
    partial: Mutex<Option<Film>>,
}

/// Clears the running flag (and consumes a cancel request) when a run ends, however it ends.
pub(crate) struct RunGuard<'a>(&'a lacuna_render_job);

impl Drop for RunGuard<'_> {
    fn drop(&mut self) {
        self.0.cancel.store(false, Ordering::SeqCst);
        self.0.running.store(false, Ordering::SeqCst);
    }
}

/// What a run needs, resolved from the settings.
pub(crate) struct Prepared {
    pub settings: JobSettings,
    pub camera: Camera,
    pub integrator: Box<dyn Integrator>,
}

impl lacuna_render_job {
    /// Marks the job running (failing if it already is) and resolves its settings.
    pub(crate) fn start(&self) -> CapiResult<(RunGuard<'_>, Prepared)> {
        if self.running.swap(true, Ordering::SeqCst) {
            return Err(CapiError::operation("the job is already running"));
        }
        let guard = RunGuard(self);
        let mut settings = lock(&self.settings).clone();
        if settings.resolved.render.threads.is_none() {
            settings.resolved.render.threads = self.scene.ctx.threads();
        }
        let (w, h) = (
            settings.resolved.render.width,
            settings.resolved.render.height,
        );
        let integrator = settings.make_integrator()?;
        let layers = integrator.layers().len();
        crate::film::Film::check_budget(w, h, layers, self.scene.ctx.memory_budget())?;
        let mut camera = resolve_camera(&self.scene.scene, settings.camera, w, h);
        if let Some((radius, focus)) = settings.lens {
            camera = camera.with_thin_lens(radius, focus)?;
        }
        Ok((
            guard,
            Prepared {
                settings,
                camera,
                integrator,
            },
        ))
    }

    /// The progress closure of a run: honours cancel requests and calls the host's callback
    /// one call at a time with non-decreasing fractions.
    pub(crate) fn progress_fn<'a>(
        &'a self,
        cb: Option<ProgressCallback>,
        last: &'a Mutex<f64>,
    ) -> impl Fn(Progress) -> bool + Sync + 'a {
        move |p: Progress| {
            if self.cancel.load(Ordering::Relaxed) {
                return false;
            }
            let Some(cb) = cb else {
                return true;
            };
            let mut last = lock(last);
            let f = if p.fraction.is_finite() {
                p.fraction.clamp(0.0, 1.0)
            } else {
                0.0
            };
            *last = last.max(f);
            // SAFETY: the host registered this callback with this user data and promised it
            // may run on worker threads; the lock serialises the calls.
            let go_on = unsafe { (cb.function)(cb.user_data as *mut c_void, *last) };
            if !go_on {
                self.cancel.store(true, Ordering::Relaxed);
            }
            go_on
        }
    }

    /// Runs the integrator's per-scene precomputation on the job's threads and returns its
    /// seconds; a cancel request stops it between stages.
    pub(crate) fn prepare(&self, p: &mut Prepared) -> CapiResult<f64> {
        let start = std::time::Instant::now();
        let pre = crate::render::prepare(
            p.integrator.as_mut(),
            &self.scene.scene,
            &p.camera,
            p.settings.resolved.render.threads,
            &|_, _| !self.cancel.load(Ordering::Relaxed),
        )?;
        // Wall-clock time, stage bookkeeping included; none for integrators needing nothing.
        Ok(if pre.stages.is_empty() {
            0.0
        } else {
            start.elapsed().as_secs_f64()
        })
    }

    /// The skeleton guide settings the job's integrator renders with: the setters' (or the
    /// scene file's) values with the integrator name's options (`path_skeleton:directions=lobes`)
    /// applied over them, as `JobSettings::make_integrator` does, so that a guide built for a
    /// host is the one the job would render with.
    pub(crate) fn skeleton_settings(&self) -> CapiResult<crate::guide::SkeletonGuideSettings> {
        let settings = lock(&self.settings);
        let (_, applied) = integrator::parse_spec(
            &settings.resolved.integrator,
            settings.resolved.integrator_settings,
        )?;
        Ok(applied.skeleton)
    }

    /// A copy of the job's settings (for getters).
    pub(crate) fn settings(&self) -> JobSettings {
        lock(&self.settings).clone()
    }

    pub(crate) fn set_last_stats(&self, stats: RenderStats) {
        *lock(&self.last_stats) = Some(stats);
    }

    pub(crate) fn metadata(&self, p: &Prepared, stats: &RenderStats) -> ExrMetadata {
        p.settings
            .resolved
            .metadata(&self.scene.label, stats.spp, stats.seconds)
    }

    pub(crate) fn make_film(
        &self,
        film: Film,
        metadata: ExrMetadata,
        stats: RenderStats,
    ) -> *mut lacuna_film {
        arc_into_handle(lacuna_film {
            ctx: self.scene.ctx.clone(),
            film,
            metadata,
            stats,
        })
    }
}

/// Creates a render job of `scene` (kept alive by the job) with the integrator named
/// `integrator` (`"path"`, `"path_skeleton"`, `"bdpt"`, `"bdpt_skeleton"`, `"bdpt_ic"`,
/// `"path_portal"`, `"env_direct"`, `"vpl"`, optionally with
/// options as `NAME:KEY=VALUE...`; NULL for the scene file's integrator or `"path"`).
/// Integrators with a per-scene precomputation (`path_skeleton`'s skeleton guide) run it at
/// the start of every run, on the job's threads; its time is reported in
/// `lacuna_render_stats::precompute_seconds`. Defaults: the scene file's render settings when
/// the scene came from one, else 512x512, 16 samples per pixel, seed 0, max depth 8, power
/// heuristic, the context's thread count; the scene's camera, or one framing the scene when it
/// has none. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_new(
    scene: *const lacuna_scene,
    integrator: *const c_char,
    out_job: *mut *mut lacuna_render_job,
) -> lacuna_status {
    boundary::status("lacuna_render_job_new", |call| {
        // SAFETY: NULL or a live scene.
        let s = unsafe { arg(scene, "scene") }?;
        call.context(&s.ctx);
        let out = out_ptr(out_job, "out_job")?;
        let overrides = SettingsOverrides {
            integrator: if integrator.is_null() {
                None
            } else {
                // SAFETY: a NUL-terminated string per the contract.
                Some(unsafe { str_arg(integrator, "integrator") }?.to_string())
            },
            ..Default::default()
        };
        let resolved = resolve(&s.settings, &overrides, |_| Ok(()))?;
        integrator::create(&resolved.integrator, resolved.integrator_settings)?;
        let job = Box::new(lacuna_render_job {
            // SAFETY: `scene` is a live handle (checked above).
            scene: unsafe { arc_clone(scene) },
            settings: Mutex::new(JobSettings {
                resolved,
                camera: None,
                lens: None,
                strategy: None,
                strategy_images: None,
                progress: None,
                compare_schedule: Default::default(),
            }),
            cancel: AtomicBool::new(false),
            running: AtomicBool::new(false),
            last_stats: Mutex::new(None),
            partial: Mutex::new(None),
        });
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, Box::into_raw(job)) };
        Ok(())
    })
}

/// Frees a job (not while it runs). NULL is a no-op.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_free(job: *mut lacuna_render_job) {
    boundary::value("lacuna_render_job_free", (), |_| {
        // SAFETY: NULL or a job from `lacuna_render_job_new`, not running, not used afterwards.
        unsafe { box_free(job) };
        Ok(())
    })
}

/// Runs `f` on the settings of a job.
///
/// # Safety
/// `job` must be NULL or a live job.
pub(crate) unsafe fn with_settings(
    function: &'static str,
    job: *mut lacuna_render_job,
    f: impl FnOnce(&mut JobSettings) -> CapiResult<()>,
) -> lacuna_status {
    boundary::status(function, |call| {
        // SAFETY: NULL or a live job; only shared references to it are ever made.
        let j = unsafe { arg(job.cast_const(), "job") }?;
        call.context(&j.scene.ctx);
        let mut s = lock(&j.settings).clone();
        f(&mut s)?;
        *lock(&j.settings) = s;
        Ok(())
    })
}

/// Sets the samples per pixel to reach (>= 1). With a time budget, the render stops at
/// whichever comes first.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_samples_per_pixel(
    job: *mut lacuna_render_job,
    spp: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_samples_per_pixel", job, |s| {
            if spp == 0 {
                return Err(CapiError::invalid("spp 0: at least 1 sample per pixel"));
            }
            s.resolved.render.spp = spp;
            s.resolved.spp_given = true;
            Ok(())
        })
    }
}

/// Sets a wall-clock budget in seconds (> 0 and finite), or removes it with 0. Unless samples
/// per pixel were set explicitly, a budget renders until it runs out.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_time_budget(
    job: *mut lacuna_render_job,
    seconds: f64,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_time_budget", job, |s| {
            if seconds == 0.0 {
                s.resolved.render.time_limit = None;
                if !s.resolved.spp_given {
                    s.resolved.render.spp = RenderSettings::default().spp;
                }
                return Ok(());
            }
            if !(seconds > 0.0 && seconds.is_finite() && seconds < 1e9) {
                return Err(CapiError::invalid(format!(
                    "time budget {seconds} s must be positive and finite (0 removes it)"
                )));
            }
            s.resolved.render.time_limit = Some(Duration::from_secs_f64(seconds));
            if !s.resolved.spp_given {
                s.resolved.render.spp = u32::MAX;
            }
            Ok(())
        })
    }
}

/// Sets the random seed: the same seed, settings and sample budget give the same image
/// whatever the thread count.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_seed(
    job: *mut lacuna_render_job,
    seed: u64,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_seed", job, |s| {
            s.resolved.render.seed = seed;
            Ok(())
        })
    }
}

/// Largest maximum path depth accepted.
pub const LACUNA_MAX_DEPTH_LIMIT: u32 = 1024;
const _: () = assert!(LACUNA_MAX_DEPTH_LIMIT == crate::limits::MAX_DEPTH);

/// Sets the maximum number of bounces (0 shows emitters only, 1 is direct lighting), at most
/// `LACUNA_MAX_DEPTH_LIMIT`.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_max_depth(
    job: *mut lacuna_render_job,
    max_depth: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_max_depth", job, |s| {
            if max_depth > LACUNA_MAX_DEPTH_LIMIT {
                return Err(CapiError::range(format!(
                    "max_depth {max_depth} exceeds {LACUNA_MAX_DEPTH_LIMIT}"
                )));
            }
            s.resolved.integrator_settings.max_depth = max_depth;
            Ok(())
        })
    }
}

/// Sets the image size, each within 1..=65536 (the film must also fit the context's memory
/// budget, checked when the job runs).
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_resolution(
    job: *mut lacuna_render_job,
    width: u32,
    height: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_resolution", job, |s| {
            if !(1..=65536).contains(&width) || !(1..=65536).contains(&height) {
                return Err(CapiError::range(format!(
                    "resolution {width}x{height} must be within 1..=65536 each"
                )));
            }
            s.resolved.render.width = width;
            s.resolved.render.height = height;
            Ok(())
        })
    }
}

/// Sets the worker threads of this job (0 = the context's setting), at most
/// `LACUNA_MAX_THREADS`.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_thread_count(
    job: *mut lacuna_render_job,
    thread_count: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_thread_count", job, |s| {
            if thread_count > LACUNA_MAX_THREADS {
                return Err(CapiError::range(format!(
                    "thread_count {thread_count} exceeds {LACUNA_MAX_THREADS}"
                )));
            }
            s.resolved.render.threads = (thread_count > 0).then_some(thread_count as usize);
            Ok(())
        })
    }
}

/// Sets the MIS heuristic: a `lacuna_mis_heuristic` value. Unset, each integrator uses its
/// own default: `LACUNA_MIS_HEURISTIC_POWER` for `path`, `path_skeleton` and `bdpt`,
/// `LACUNA_MIS_HEURISTIC_BALANCE` for `env_direct`. `AUTO` is taken by `path`,
/// `path_skeleton`, `path_portal` and `env_direct`, `OPTIMAL` by `env_direct`; another
/// integrator refuses them when the job runs.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_mis_heuristic(
    job: *mut lacuna_render_job,
    heuristic: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_mis_heuristic", job, |s| {
            s.resolved.integrator_settings.mis =
                Some(lacuna_mis_heuristic::from_c(heuristic, "heuristic")?.into());
            Ok(())
        })
    }
}

/// Writes the `lacuna_mis_heuristic` the job renders with: the one set (by
/// `lacuna_render_job_set_mis_heuristic` or the integrator specification's `mis=`), else the
/// integrator's own default. `LACUNA_STATUS_INVALID_ARGUMENT` for an invalid specification.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_get_mis_heuristic(
    job: *const lacuna_render_job,
    out_heuristic: *mut u32,
) -> lacuna_status {
    boundary::status("lacuna_render_job_get_mis_heuristic", |call| {
        // SAFETY: NULL or a live job.
        let j = unsafe { arg(job, "job") }?;
        call.context(&j.scene.ctx);
        let out = out_ptr(out_heuristic, "out_heuristic")?;
        let resolved = lock(&j.settings).resolved.clone();
        let (name, settings) =
            integrator::parse_spec(&resolved.integrator, resolved.integrator_settings)?;
        let heuristic = lacuna_mis_heuristic::from(integrator::mis_in_use(name, &settings));
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, heuristic as u32) };
        Ok(())
    })
}

/// Sets the numbers pixel samples draw: a `lacuna_sampler` value (default
/// `LACUNA_SAMPLER_SOBOL`, or the scene file's `render.sampler`).
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_sampler(
    job: *mut lacuna_render_job,
    sampler: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_sampler", job, |s| {
            s.resolved.render.sampler = match lacuna_sampler::from_c(sampler, "sampler")? {
                lacuna_sampler::Sobol => SamplerKind::Sobol,
                lacuna_sampler::Independent => SamplerKind::Independent,
            };
            Ok(())
        })
    }
}

/// `path_skeleton`: one fixed probability `c_skel` of sampling the skeleton lobes instead of
/// the BSDF at every guided point, in [0, 1), as in the thesis. By default the probability is
/// learned per node by a training pass from the camera (0 where guiding does not pay; 0.5
/// where the scene has no camera).
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_skeleton_probability(
    job: *mut lacuna_render_job,
    c_skel: f32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_skeleton_probability", job, |s| {
            s.resolved
                .integrator_settings
                .skeleton
                .set_c_skel(Some(c_skel))?;
            Ok(())
        })
    }
}

/// `path_skeleton`: one fixed skeleton strength (power-cosine exponent) `strength` in
/// [0, `LACUNA_SKELETON_MAX_STRENGTH`] for every lobe, as in the thesis.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_skeleton_strength(
    job: *mut lacuna_render_job,
    strength: f32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_skeleton_strength", job, |s| {
            let fixed = SkeletonStrength::Fixed(strength);
            fixed.validate()?;
            s.resolved.integrator_settings.skeleton.strength = fixed;
            Ok(())
        })
    }
}

/// `path_skeleton`: the automatic skeleton strength (the default, with `max_strength` 64):
/// per point and lobe, the exponent whose half-maximum angle is the angle under which the
/// narrowest free space on the way to the importance point is seen, clamped to
/// [1, `max_strength`]; `max_strength` in [1, `LACUNA_SKELETON_MAX_STRENGTH`].
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_skeleton_strength_auto(
    job: *mut lacuna_render_job,
    max_strength: f32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_skeleton_strength_auto", job, |s| {
            let auto = SkeletonStrength::Auto { max: max_strength };
            auto.validate()?;
            s.resolved.integrator_settings.skeleton.strength = auto;
            Ok(())
        })
    }
}

/// `path_skeleton`: resolution of the skeleton's analysis grid: `longest_axis_voxels`
/// (4..=4096) voxels along the longest side of the scene bounds, or, when that is 0, at most
/// `voxel_budget` voxels (64..=2^31; the default is a budget of 2^20).
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_skeleton_resolution(
    job: *mut lacuna_render_job,
    longest_axis_voxels: u32,
    voxel_budget: u64,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_skeleton_resolution", job, |s| {
            let sk = &mut s.resolved.integrator_settings.skeleton;
            sk.update(|sk| {
                sk.resolution = if longest_axis_voxels > 0 {
                    Resolution::LongestAxis(longest_axis_voxels)
                } else {
                    Resolution::VoxelBudget(voxel_budget)
                }
            })?;
            Ok(())
        })
    }
}

/// `path_skeleton`: rays traced from the lights to find the importance nodes (>= 1, default
/// 16384), the most powerful importance nodes kept (>= 1, default 32), and the lobes per node
/// (1..=`LACUNA_SKELETON_MAX_LOBES`, default 4).
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_skeleton_importance(
    job: *mut lacuna_render_job,
    light_rays: u32,
    importance_nodes: u32,
    lobes_per_node: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_skeleton_importance", job, |s| {
            let sk = &mut s.resolved.integrator_settings.skeleton;
            sk.update(|sk| {
                sk.light_rays = light_rays;
                sk.max_importance_nodes = importance_nodes;
                sk.max_lobes = lobes_per_node;
            })?;
            Ok(())
        })
    }
}

/// `path_skeleton`: whether a lobe whose importance point is hidden from the shading point is
/// dropped there (default true). `true` keeps the mode the integrator spec or the scene file
/// chose: once per empty voxel and lobe target, cached (the default), or one shadow ray per
/// lobe and point with `path_skeleton:visibility=true`; `false` turns the test off in either
/// mode.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_skeleton_visibility_test(
    job: *mut lacuna_render_job,
    enabled: bool,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_skeleton_visibility_test", job, |s| {
            s.resolved.integrator_settings.skeleton.visibility_test = enabled;
            Ok(())
        })
    }
}

/// Largest skeleton strength accepted.
pub const LACUNA_SKELETON_MAX_STRENGTH: f32 = 10000.0;
/// Most lobes per skeleton node.
pub const LACUNA_SKELETON_MAX_LOBES: u32 = 8;

// Literals for cbindgen; they must be the library's values (the strength is checked by
// tests/path_skeleton.rs: float comparisons in constants need Rust 1.83).
const _: () = assert!(LACUNA_SKELETON_MAX_LOBES as usize == crate::guide::MAX_LOBES);

/// Sets the job's camera (overriding the scene's): pinhole at `eye` looking at `target`, with
/// `up` and a vertical field of view in (0, 180) degrees.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_camera(
    job: *mut lacuna_render_job,
    eye: lacuna_vec3,
    target: lacuna_vec3,
    up: lacuna_vec3,
    vfov_degrees: f32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_camera", job, |s| {
            s.camera = Some(Camera::look_at(
                eye.finite("eye")?,
                target.finite("target")?,
                up.finite("up")?,
                vfov_degrees,
            )?);
            Ok(())
        })
    }
}

/// Gives the run's camera (the job's, the scene's or the automatic one) a thin lens of radius
/// `lens_radius` (>= 0, finite; 0 makes it a pinhole again) focused at `focus_distance` (> 0,
/// finite; ignored for a pinhole).
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_thin_lens(
    job: *mut lacuna_render_job,
    lens_radius: f32,
    focus_distance: f32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_thin_lens", job, |s| {
            if !(lens_radius >= 0.0 && lens_radius.is_finite()) {
                return Err(CapiError::invalid(format!(
                    "lens_radius {lens_radius} must be >= 0 and finite"
                )));
            }
            if lens_radius == 0.0 {
                s.lens = None;
                return Ok(());
            }
            if !(focus_distance > 0.0 && focus_distance.is_finite()) {
                return Err(CapiError::invalid(format!(
                    "focus_distance {focus_distance} must be > 0 and finite"
                )));
            }
            s.lens = Some((lens_radius, focus_distance));
            Ok(())
        })
    }
}

/// Largest number of light subpaths per iteration accepted.
pub const LACUNA_MAX_LIGHT_PATHS: u32 = 1 << 28;
const _: () = assert!(LACUNA_MAX_LIGHT_PATHS == crate::limits::MAX_LIGHT_PATHS);

/// bdpt, bdpt_skeleton, bdpt_ic: traces `count` light subpaths per iteration (one iteration
/// per sample per pixel); each camera path connects to one of them (the resampling integrators
/// resample among them), light tracing splats all of them. 0 restores the default, one per
/// pixel. At most `LACUNA_MAX_LIGHT_PATHS`. `LACUNA_STATUS_INVALID_OPERATION` for jobs of
/// other integrators.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_light_paths(
    job: *mut lacuna_render_job,
    count: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_light_paths", job, |s| {
            s.require_light_subpaths("light subpaths per iteration")?;
            if count > LACUNA_MAX_LIGHT_PATHS {
                return Err(CapiError::range(format!(
                    "count {count} exceeds {LACUNA_MAX_LIGHT_PATHS}"
                )));
            }
            s.resolved.integrator_settings.light_paths = (count > 0).then_some(count);
            Ok(())
        })
    }
}

/// bdpt, for debugging: renders only strategy (`s`, `t`) (s light vertices, t camera
/// vertices counting the camera, so paths of s + t - 1 segments), with its MIS weight or,
/// when `unweighted`, without (then the image is that strategy's own unbiased estimate).
/// Needs t >= 1, s + t >= 2 and (s, t) != (1, 1) (`LACUNA_STATUS_INVALID_ARGUMENT`).
/// `LACUNA_STATUS_INVALID_OPERATION` for jobs of other integrators.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_strategy_filter(
    job: *mut lacuna_render_job,
    s: u32,
    t: u32,
    unweighted: bool,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_strategy_filter", job, |settings| {
            settings.require_bidirectional("a strategy filter")?;
            let filter = StrategyFilter { s, t, unweighted };
            filter.validate()?;
            settings.strategy = Some(filter);
            Ok(())
        })
    }
}

/// Removes the strategy filter: every strategy renders again. Never fails on a live job.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_clear_strategy_filter(
    job: *mut lacuna_render_job,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_clear_strategy_filter", job, |s| {
            s.strategy = None;
            Ok(())
        })
    }
}

/// bdpt: also renders, from the same samples, the image of every (s, t) strategy of paths of
/// up to `max_length` segments (clamped to the maximum path length, max depth + 1), weighted
/// by its MIS weight and unweighted (000 Figure 22). Read them with
/// `lacuna_film_read_strategy_image`; `lacuna_film_write_exr` adds them as channels. Each
/// strategy costs 48 bytes per pixel (counted against the memory budget). 0 turns them off.
/// `LACUNA_STATUS_INVALID_OPERATION` for jobs of other integrators.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_strategy_images(
    job: *mut lacuna_render_job,
    max_length: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_strategy_images", job, |s| {
            s.require_bidirectional("strategy images")?;
            s.strategy_images = (max_length > 0).then_some(max_length);
            Ok(())
        })
    }
}

/// Registers (or, with NULL, removes) the progress callback; see `lacuna_progress_callback`.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_progress_callback(
    job: *mut lacuna_render_job,
    callback: lacuna_progress_callback,
    user_data: *mut c_void,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_settings("lacuna_render_job_set_progress_callback", job, |s| {
            s.progress = callback.map(|function| ProgressCallback {
                function,
                user_data: user_data as usize,
            });
            Ok(())
        })
    }
}

/// Asks the job's run to stop as soon as possible; the run then fails with
/// `LACUNA_STATUS_CANCELLED`. A request made while the job is not running cancels its next run.
/// Callable from any thread at any time (also from the progress callback).
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_cancel(job: *const lacuna_render_job) -> lacuna_status {
    boundary::status("lacuna_render_job_cancel", |call| {
        // SAFETY: NULL or a live job; only shared references to it are ever made.
        let j = unsafe { arg(job, "job") }?;
        call.context(&j.scene.ctx);
        j.cancel.store(true, Ordering::SeqCst);
        Ok(())
    })
}

/// Renders, blocking the calling thread while worker threads work, and writes the film
/// (reference count 1) to `*out_film`. Fails with `LACUNA_STATUS_CANCELLED` when cancelled
/// (the passes completed before then are kept: see `lacuna_render_job_take_partial_film`),
/// `LACUNA_STATUS_OVER_BUDGET` when the film exceeds the context's memory budget, and
/// `LACUNA_STATUS_INVALID_OPERATION` when the job is already running.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_run(
    job: *mut lacuna_render_job,
    out_film: *mut *mut lacuna_film,
) -> lacuna_status {
    boundary::status("lacuna_render_job_run", |call| {
        // SAFETY: NULL or a live job; only shared references to it are ever made.
        let j = unsafe { arg(job.cast_const(), "job") }?;
        call.context(&j.scene.ctx);
        let out = out_ptr(out_film, "out_film")?;
        let (_guard, mut p) = j.start()?;
        let precompute_seconds = j.prepare(&mut p)?;
        let last = Mutex::new(0.0);
        let progress = j.progress_fn(p.settings.progress, &last);
        let (film, mut stats) = crate::render::render(
            &j.scene.scene,
            &p.camera,
            p.integrator.as_ref(),
            &p.settings.resolved.render,
            &progress,
            &j.cancel,
        )?;
        stats.precompute_seconds = precompute_seconds;
        j.set_last_stats(stats);
        if stats.cancelled {
            *lock(&j.partial) = Some(film);
            return Err(CapiError::new(
                lacuna_status::Cancelled,
                format!("render cancelled after {} samples per pixel", stats.spp),
            ));
        }
        let meta = j.metadata(&p, &stats);
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, j.make_film(film, meta, stats)) };
        Ok(())
    })
}

/// After a cancelled run: writes the film of the passes completed before the cancellation
/// (possibly with 0 samples per pixel) to `*out_film` and forgets it.
/// `LACUNA_STATUS_INVALID_OPERATION` when there is none.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_take_partial_film(
    job: *mut lacuna_render_job,
    out_film: *mut *mut lacuna_film,
) -> lacuna_status {
    boundary::status("lacuna_render_job_take_partial_film", |call| {
        // SAFETY: NULL or a live job; only shared references to it are ever made.
        let j = unsafe { arg(job.cast_const(), "job") }?;
        call.context(&j.scene.ctx);
        let out = out_ptr(out_film, "out_film")?;
        let film = lock(&j.partial).take().ok_or_else(|| {
            CapiError::operation("no partial film: the last run was not cancelled")
        })?;
        let stats = lock(&j.last_stats).unwrap_or_default();
        let settings = lock(&j.settings).clone();
        let meta = ExrMetadata::default()
            .with("spp", stats.spp)
            .with("integrator", &settings.resolved.integrator)
            .with("cancelled", "true");
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, j.make_film(film, meta, stats)) };
        Ok(())
    })
}

/// Writes the figures of the job's last run (also a cancelled one).
/// `LACUNA_STATUS_INVALID_OPERATION` before the first run.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_get_stats(
    job: *const lacuna_render_job,
    out_stats: *mut lacuna_render_stats,
) -> lacuna_status {
    boundary::status("lacuna_render_job_get_stats", |call| {
        // SAFETY: NULL or a live job.
        let j = unsafe { arg(job, "job") }?;
        call.context(&j.scene.ctx);
        let out = out_ptr(out_stats, "out_stats")?;
        let stats =
            lock(&j.last_stats).ok_or_else(|| CapiError::operation("the job has not run yet"))?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, stats_to_c(&stats)) };
        Ok(())
    })
}
