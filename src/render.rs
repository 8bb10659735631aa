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

/// The size of a time-budgeted render's first pass with sized iterations, before any cost
/// is measured: smaller than the usual, so that it overruns a short budget less.
pub const FIRST_PASS_SIZE: f32 = 0.5;
/// Share of the remaining time the sizes are planned for (a margin for the clock's noise).
const PASS_TIME_SHARE: f64 = 0.95;
/// The share of a pass's cost assumed not to scale with its size (camera rays, next-event
/// estimation; `vpl` at 128x96: about 5 % with exact visibility, more with skeleton
/// visibility's cheap gathers) when a pass is shrunk, so that the last pass does not
/// overrun the budget.
const PASS_FIXED_SHARE: f64 = 0.2;
/// Smallest pass worth running (in units of the usual).
const MIN_PASS_SIZE: f32 = 0.05;

/// The size of the next pass of a time-budgeted render of an integrator with sized
/// iterations ([`Integrator::sized_iterations`]), None to stop. The first pass (no cost
/// measured yet) has [`FIRST_PASS_SIZE`]. Then, from the `last` pass's (size, seconds),
/// with a cost model `a + b size` that puts a share [`PASS_FIXED_SHARE`] of a size-1
/// pass's cost in `a` (and, for passes larger than the measured one, the cost proportional
/// to the size: each model errs low on its own side), the remaining time is planned as the
/// whole number of equal passes nearest to what fits (so sizes stay near the usual while
/// more than one pass fits), and the next is one of them. The render loop weights each
/// pass by its size, so a small last pass adds what it can.
pub fn next_pass_size(remaining: f64, last: Option<(f32, f64)>) -> Option<f32> {
    let Some((measured, seconds)) = last else {
        return Some(FIRST_PASS_SIZE);
    };
    if !(remaining > 0.0 && seconds > 0.0 && measured > 0.0) {
        return None;
    }
    // seconds = a + b measured, a = F (a + b).
    let fixed = PASS_FIXED_SHARE / (1.0 - PASS_FIXED_SHARE);
    let b = seconds / (fixed + f64::from(measured));
    let a = fixed * b;
    let time = PASS_TIME_SHARE * remaining;
    let per_pass = time / (time / (a + b)).round().max(1.0);
    let size = ((per_pass - a) / b).min(per_pass * f64::from(measured) / seconds) as f32;
    (size >= MIN_PASS_SIZE).then_some(size)
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
    // Time-budgeted renders of integrators with sized iterations size their passes to fill
    // the budget ([`next_pass_size`]); `film` is then the size-weighted mean of the passes,
    // `weighted` the sum of their films times their sizes, `size_sum` the sizes' sum.
    let sized = iterative && settings.time_limit.is_some() && integrator.sized_iterations();
    let mut last_pass: Option<(f32, f64)> = None;
    let mut weighted = Film::with_layers(w, h, &layer_names);
    let mut size_sum = 0.0f64;

    while spp_done < settings.spp {
        let elapsed = start.elapsed().saturating_sub(observer_time);
        let size = match settings.time_limit.filter(|_| sized) {
            Some(limit) => {
                let remaining = limit.saturating_sub(elapsed).as_secs_f64();
                match next_pass_size(remaining, last_pass) {
                    Some(size) => size,
                    None => break,
                }
            }
            None => 1.0,
        };
        // Size of this pass: fixed for sample budgets; for time budgets, what fits in the
        // remaining time (at least one sample, at most a quarter of the remaining time per
        // pass so progress stays smooth).
        let pass = match (settings.time_limit, seconds_per_spp) {
            (Some(limit), _) if elapsed >= limit => break,
            _ if sized => 1,
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
                Some(integrator.begin_sized_iteration(scene, &view, settings.seed, first, size)?)
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
        if sized {
            // The sized passes' mean, each weighted by its size (1 spp per pass).
            pass_film.scale_radiance(f64::from(size));
            weighted.merge(&pass_film);
            size_sum += f64::from(size);
            film = weighted.clone();
            film.scale_radiance(f64::from(spp_done + pass) / size_sum);
        } else {
            film.merge(&pass_film);
        }
        let pass_seconds = pass_start.elapsed().as_secs_f64();
        seconds_per_spp = Some(pass_seconds / pass as f64);
        if sized {
            last_pass = Some((size, pass_seconds));
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A time-budgeted render simulated without a clock: passes whose cost is `fixed` plus
    /// `per_size - fixed` times their size (the first also `setup`), sized by
    /// [`next_pass_size`] from the last pass's cost, as the render loop does. Returns the
    /// time used and the sizes.
    fn simulate(budget: f64, setup: f64, fixed: f64, per_size: f64) -> (f64, Vec<f32>) {
        let (mut elapsed, mut sizes, mut last) = (0.0, Vec::new(), None);
        while elapsed < budget {
            let Some(size) = next_pass_size(budget - elapsed, last) else {
                break;
            };
            let first = if sizes.is_empty() { setup } else { 0.0 };
            let cost = first + fixed + (per_size - fixed) * f64::from(size);
            elapsed += cost;
            last = Some((size, cost));
            sizes.push(size);
        }
        (elapsed, sizes)
    }

    /// Where a pass of the usual size costs from a twentieth of the budget to half of it,
    /// with a first pass slowed by a set-up and up to a fifth of each pass's cost not
    /// scaling with its size, the passes fill 90-100 % of the budget (the render loop's
    /// whole passes stop at 55 % when a pass costs half the budget), 80-100 % where a pass
    /// costs up to 0.8 of it (two or three passes: the cost measured on the first, smaller
    /// one extrapolates with a margin); no pass but the last two is far from the usual size.
    #[test]
    fn sized_passes_fill_the_time_budget() {
        for per_size in [0.05, 0.1, 0.2, 0.3, 0.45, 0.5, 0.6, 0.8] {
            let mut fills = Vec::new();
            for (setup, fixed_share) in [(0.0, 0.0), (0.05, 0.1), (0.1, 0.2), (0.0, 0.2)] {
                let fixed = fixed_share * per_size;
                let (used, sizes) = simulate(1.0, setup, fixed, per_size);
                let label = format!(
                    "pass {per_size} s, setup {setup}, fixed {fixed:.3}: {used:.3} s, sizes {sizes:?}"
                );
                fills.push(used);
                let least = if per_size <= 0.5 { 0.9 } else { 0.8 };
                assert!((least..=1.0).contains(&used), "{label}");
                assert_eq!(sizes[0], FIRST_PASS_SIZE, "{label}");
                let middle = sizes.get(1..sizes.len().saturating_sub(2)).unwrap_or(&[]);
                assert!(middle.iter().all(|&s| (0.6..=1.5).contains(&s)), "{label}");
            }
            println!("pass {per_size} s: budget used {fills:.3?}");
        }
    }

    #[test]
    fn next_pass_size_plans_equal_passes() {
        assert_eq!(next_pass_size(1.0, None), Some(FIRST_PASS_SIZE));
        // A pass of size 1 cost 0.5 s: a = 0.1 s, b = 0.4 s per size. 0.45 s left: one
        // pass of (0.95 x 0.45 - 0.1) / 0.4 = 0.81875.
        let s = next_pass_size(0.45, Some((1.0, 0.5))).unwrap();
        assert!((s - 0.81875).abs() < 1e-4, "{s}");
        // The same cost measured on a pass of size 0.5 (0.3 s): the model gives the same,
        // the proportional cost (0.6 s at size 1) less, 0.4275 / 0.6 = 0.7125.
        let t = next_pass_size(0.45, Some((0.5, 0.3))).unwrap();
        assert!((t - 0.7125).abs() < 1e-4, "{t}");
        // 1.3 passes' worth (a = 0.2, b = 0.8): one pass of 1.235 s, the proportional
        // size 1.235 below the model's (1.235 - 0.2) / 0.8.
        let s = next_pass_size(1.3, Some((1.0, 1.0))).unwrap();
        assert!((s - 1.235).abs() < 1e-4, "{s}");
        // 10.3 passes' worth: ten of (0.9785 - 0.2) / 0.8 = 0.9731.
        let s = next_pass_size(10.3, Some((1.0, 1.0))).unwrap();
        assert!((s - 0.973125).abs() < 1e-4, "{s}");
        // Too little time for the fixed part and a useful pass: none.
        assert_eq!(next_pass_size(0.2, Some((1.0, 1.0))), None);
        assert_eq!(next_pass_size(0.0, Some((1.0, 1.0))), None);
    }
}
