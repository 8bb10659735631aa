//! The progressive render loop: passes of N samples per pixel over 16x16 tiles in parallel,
//! a sample or time budget, progress reporting and cancellation.
//!
//! Determinism: every pixel sample draws its numbers from a [`Sampler`](crate::math::Sampler)
//! keyed by (seed, pixel, sample index) only, and each pixel's samples are summed in sample
//! order within a pass, so for a given seed, sampler and sample budget the image does not
//! depend on the thread count.
//! The camera takes dimension slots [`FILM_DIMENSION`] and [`LENS_DIMENSION`]; integrators
//! start at [`FIRST_INTEGRATOR_DIMENSION`].

pub mod capture;
pub mod settings;

use std::cell::Cell;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::film::Film;
use crate::integrator::{Integrator, Precomputation, SampleContext, TraceCounters, View};
use crate::math::{PixelSampler, Rgb, SamplerKind};
use crate::scene::{Camera, Scene};
use crate::workers::WorkerPool;

const TILE: u32 = 16;

/// The camera's dimension slots, defined beside the sampler so that integrators see them
/// without depending on the render loop; re-exported here for the render's users.
pub use crate::math::{FILM_DIMENSION, FIRST_INTEGRATOR_DIMENSION, LENS_DIMENSION};

/// What to render and for how long.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderSettings {
    pub width: u32,
    pub height: u32,
    /// Samples per pixel to reach (the render stops there, or earlier if `time_limit` ends).
    pub spp: u32,
    /// Wall-clock budget; with it, passes continue until the budget (or `spp`) is reached.
    pub time_limit: Option<Duration>,
    pub seed: u64,
    /// Worker threads; `None` uses all cores.
    pub threads: Option<usize>,
    /// Samples per pixel per pass in sample-budget renders (fixed, so results are reproducible).
    pub pass_spp: u32,
    /// Which numbers pixel samples draw (stratified Sobol or independent).
    pub sampler: SamplerKind,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            width: 512,
            height: 512,
            spp: 16,
            time_limit: None,
            seed: 0,
            threads: None,
            pass_spp: 4,
            sampler: SamplerKind::default(),
        }
    }
}

impl RenderSettings {
    pub fn validate(&self) -> Result<()> {
        crate::limits::check_film_side(self.width, self.height)?;
        if self.spp == 0 {
            return Err(Error::invalid("samples per pixel must be at least 1"));
        }
        if self.pass_spp == 0 {
            return Err(Error::invalid("samples per pass must be at least 1"));
        }
        if let Some(t) = self.time_limit {
            if t.is_zero() {
                return Err(Error::invalid("time limit must be positive"));
            }
        }
        if self.threads == Some(0) {
            return Err(Error::invalid("thread count must be at least 1"));
        }
        if let Some(n) = self.threads {
            crate::limits::check_threads("thread count", n)?;
        }
        Ok(())
    }
}

/// Progress seen by a callback: fraction done in [0, 1], passes and samples so far.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    pub fraction: f64,
    pub spp_done: u32,
    pub elapsed: Duration,
}

/// Summary figures of a render.
#[derive(Clone, Copy, Debug, Default)]
pub struct RenderStats {
    pub seconds: f64,
    pub spp: u32,
    pub samples: u64,
    pub rays: u64,
    pub passes: u32,
    pub cancelled: bool,
    /// [`TraceCounters::largest_guided_ratio`] over the render's samples.
    pub largest_guided_ratio: f32,
    /// The integrator's per-scene precomputation before this render ([`prepare`]): not part
    /// of `seconds`; left 0 by `render`, filled in by the caller that ran it.
    pub precompute_seconds: f64,
}

impl RenderStats {
    pub fn samples_per_second(&self) -> f64 {
        self.samples as f64 / self.seconds.max(1e-9)
    }

    pub fn rays_per_second(&self) -> f64 {
        self.rays as f64 / self.seconds.max(1e-9)
    }
}

/// Renders `scene` through `camera` with `integrator`. `progress` is called from worker
/// threads after every tile; returning false cancels, as does setting `cancel`. A cancelled
/// render returns what its completed passes accumulated (`stats.cancelled` is set).
pub fn render(
    scene: &Scene,
    camera: &Camera,
    integrator: &dyn Integrator,
    settings: &RenderSettings,
    progress: &(dyn Fn(Progress) -> bool + Sync),
    cancel: &AtomicBool,
) -> Result<(Film, RenderStats)> {
    settings.validate()?;
    camera.validate()?;
    let pool = WorkerPool::new(settings.threads, None)?;
    pool.install(|| {
        render_in_pool(
            scene,
            camera,
            integrator,
            settings,
            progress,
            cancel,
            &mut |_, _| {},
        )
    })
}

/// Runs the integrator's per-scene precomputation ([`Integrator::prepare`]) for the view of
/// `camera` (the camera the render will use) on `threads` worker threads (`None`: all cores),
/// as the render would use them. Cheap for integrators that need nothing.
pub fn prepare(
    integrator: &mut dyn Integrator,
    scene: &Scene,
    camera: &Camera,
    threads: Option<usize>,
    progress: &(dyn Fn(&str, f64) -> bool + Sync),
) -> Result<Precomputation> {
    if threads == Some(0) {
        return Err(Error::invalid("thread count must be at least 1"));
    }
    camera.validate()?;
    if let Some(n) = threads {
        crate::limits::check_threads("thread count", n)?;
    }
    let pool = WorkerPool::new(threads, None)?;
    pool.install(|| integrator.prepare(scene, camera, progress))
}

/// What an observer learns after each completed pass.
#[derive(Clone, Copy, Debug)]
pub struct PassReport {
    /// Samples per pixel accumulated so far.
    pub spp: u32,
    /// Rendering time so far, excluding the time spent in observers.
    pub seconds: f64,
}

/// [`render`], calling `on_pass` with the accumulated film after every completed pass (for
/// convergence logs). Time spent in `on_pass` counts neither in the budget nor in the stats, so
/// measuring does not handicap the integrator measured.
pub fn render_observed(
    scene: &Scene,
    camera: &Camera,
    integrator: &dyn Integrator,
    settings: &RenderSettings,
    progress: &(dyn Fn(Progress) -> bool + Sync),
    cancel: &AtomicBool,
    on_pass: &mut (dyn FnMut(&Film, PassReport) + Send),
) -> Result<(Film, RenderStats)> {
    settings.validate()?;
    camera.validate()?;
    let pool = WorkerPool::new(settings.threads, None)?;
    pool.install(|| {
        render_in_pool(
            scene, camera, integrator, settings, progress, cancel, on_pass,
        )
    })
}

fn render_in_pool(
    scene: &Scene,
    camera: &Camera,
    integrator: &dyn Integrator,
    settings: &RenderSettings,
    progress: &(dyn Fn(Progress) -> bool + Sync),
    cancel: &AtomicBool,
    on_pass: &mut (dyn FnMut(&Film, PassReport) + Send),
) -> Result<(Film, RenderStats)> {
    integrator.check_prepared(scene)?;
    let (w, h) = (settings.width, settings.height);
    let view = View {
        frame: camera.frame(w as f32 / h as f32),
        width: w,
        height: h,
        sampler: settings.sampler,
    };
    let iterative = integrator.uses_iterations();
    let layer_names = integrator.layers();
    let tiles: Vec<(u32, u32)> = (0..h.div_ceil(TILE))
        .flat_map(|ty| (0..w.div_ceil(TILE)).map(move |tx| (tx * TILE, ty * TILE)))
        .collect();
    let mut film = Film::with_layers(w, h, &layer_names);
    let mut stats = RenderStats::default();
    let start = Instant::now();
    // Time spent in `on_pass`, subtracted from the clock.
    let mut observer_time = Duration::ZERO;
    let rays = AtomicU64::new(0);
    // Bits of a non-negative f32: their order as integers is the floats' order.
    let largest_ratio = AtomicU32::new(0);
    let tiles_done = AtomicU64::new(0);
    let mut spp_done = 0u32;
    let mut seconds_per_spp: Option<f64> = None;

    while spp_done < settings.spp {
        let elapsed = start.elapsed().saturating_sub(observer_time);
        // Size of this pass: fixed for sample budgets; for time budgets, what fits in the
        // remaining time (at least one sample, at most a quarter of the remaining time per
        // pass so progress stays smooth).
        let pass = match (settings.time_limit, seconds_per_spp) {
            (Some(limit), _) if elapsed >= limit => break,
            (Some(limit), Some(sps)) => {
                let remaining = (limit - elapsed).as_secs_f64();
                let fit = (remaining / sps).floor() as u32;
                if fit == 0 {
                    break;
                }
                fit.min(((remaining * 0.25 / sps).ceil() as u32).max(1))
                    .min(64)
            }
            (Some(_), None) => 1,
            (None, _) => settings.pass_spp,
        }
        .min(settings.spp - spp_done);

        let pass_start = Instant::now();
        // Integrators with per-sample-index work (light subpaths) run the pass one sample
        // index at a time; the others run it in one go.
        let sub_passes: Vec<(u32, u32)> = if iterative {
            (spp_done..spp_done + pass).map(|s| (s, 1)).collect()
        } else {
            vec![(spp_done, pass)]
        };
        let work_units = (tiles.len() * sub_passes.len()) as u64;
        let mut pass_film = Film::with_layers(w, h, &layer_names);
        let mut completed = true;
        for &(first, count) in &sub_passes {
            let iteration = if iterative {
                Some(integrator.begin_iteration(scene, &view, settings.seed, first)?)
            } else {
                None
            };
            let data = iteration.as_ref().and_then(|it| it.data.as_deref());
            let results: Vec<Option<Film>> = tiles
                .par_iter()
                .map(|&(x0, y0)| {
                    if cancel.load(Ordering::Relaxed) {
                        return None;
                    }
                    let tw = TILE.min(w - x0);
                    let th = TILE.min(h - y0);
                    let mut tile = Film::with_layers(tw, th, &layer_names);
                    let mut counters = TraceCounters::default();
                    let layers = vec![Cell::new(Rgb::ZERO); layer_names.len()];
                    let mut layer_values = vec![Rgb::ZERO; layer_names.len()];
                    for ty in 0..th {
                        for tx in 0..tw {
                            let (x, y) = (x0 + tx, y0 + ty);
                            let pixel_index = y as u64 * w as u64 + x as u64;
                            let pixel_sampler =
                                PixelSampler::new(settings.sampler, settings.seed, pixel_index);
                            for s in first..first + count {
                                let ctx = SampleContext {
                                    pixel_index,
                                    sample_index: s,
                                    view: &view,
                                    iteration: data,
                                    layers: &layers,
                                };
                                let mut rng = pixel_sampler.sample(s);
                                let ray = view.primary_ray(x, y, &mut rng);
                                let sample =
                                    integrator.sample(scene, ray, &mut rng, &mut counters, &ctx);
                                tile.add_sample(tx, ty, &sample);
                                if !layers.is_empty() {
                                    for (value, cell) in layer_values.iter_mut().zip(&layers) {
                                        *value = cell.replace(Rgb::ZERO);
                                    }
                                    tile.add_layer_values(tx, ty, &layer_values);
                                }
                            }
                        }
                    }
                    rays.fetch_add(counters.rays, Ordering::Relaxed);
                    largest_ratio.fetch_max(
                        counters.largest_guided_ratio.max(0.0).to_bits(),
                        Ordering::Relaxed,
                    );
                    let done = tiles_done.fetch_add(1, Ordering::Relaxed) + 1;
                    let fraction = match settings.time_limit {
                        Some(limit) => {
                            (start.elapsed().saturating_sub(observer_time).as_secs_f64()
                                / limit.as_secs_f64())
                            .min(1.0)
                        }
                        None => {
                            (spp_done as f64 + pass as f64 * done as f64 / work_units.max(1) as f64)
                                / settings.spp as f64
                        }
                    };
                    let p = Progress {
                        fraction,
                        spp_done,
                        elapsed: start.elapsed(),
                    };
                    if !progress(p) {
                        cancel.store(true, Ordering::Relaxed);
                    }
                    Some(tile)
                })
                .collect();
            if cancel.load(Ordering::Relaxed) || results.iter().any(Option::is_none) {
                completed = false;
                break;
            }
            for (&(x0, y0), tile) in tiles.iter().zip(results) {
                pass_film.merge_tile(x0, y0, tile.as_ref().expect("checked above"));
            }
            if let Some(it) = iteration {
                for (pixel, value) in it.splats {
                    pass_film.add_splat(pixel as usize, value);
                }
                for (layer, pixel, value) in it.layer_splats {
                    pass_film.add_layer_splat(layer as usize, pixel as usize, value);
                }
                rays.fetch_add(it.rays, Ordering::Relaxed);
            }
        }
        tiles_done.store(0, Ordering::Relaxed);
        if !completed {
            // A cancelled pass is dropped whole so that every pixel keeps the same count.
            stats.cancelled = true;
            break;
        }
        film.merge(&pass_film);
        let pass_seconds = pass_start.elapsed().as_secs_f64();
        seconds_per_spp = Some(pass_seconds / pass as f64);
        spp_done += pass;
        stats.passes += 1;
        let observer_start = Instant::now();
        on_pass(
            &film,
            PassReport {
                spp: spp_done,
                seconds: start.elapsed().saturating_sub(observer_time).as_secs_f64(),
            },
        );
        observer_time += observer_start.elapsed();
    }
    stats.seconds = start.elapsed().saturating_sub(observer_time).as_secs_f64();
    stats.spp = spp_done;
    stats.samples = film.total_samples();
    stats.rays = rays.load(Ordering::Relaxed);
    stats.largest_guided_ratio = f32::from_bits(largest_ratio.load(Ordering::Relaxed));
    progress(Progress {
        fraction: 1.0,
        spp_done,
        elapsed: start.elapsed(),
    });
    Ok((film, stats))
}
