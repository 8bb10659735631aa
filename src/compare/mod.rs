//! Speed against error: reference renders with an estimate of their own remaining error, and
//! equal-time comparisons of integrators with convergence logs (docs/testing.md, "Measuring speed
//! against error"). The command line (`lacuna reference`, `lacuna compare`) and the C API are
//! thin layers over this module.

mod report;

pub use report::{error_image, write_report};

use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use crate::error::{Error, Result};
use crate::film::{image_errors, largest_pixel_ratio, Film, ImageErrors};
use crate::integrator::{self, Integrator, IntegratorSettings};
use crate::math::{Rgb, SamplerKind};
use crate::render::{prepare, render, render_observed, Progress, RenderSettings, RenderStats};
use crate::scene::{Camera, Scene};

/// A high-sample render and the estimate of its own error.
pub struct Reference {
    pub film: Film,
    pub stats: RenderStats,
    /// Estimated errors of `film` against the converged image: half the distance between two
    /// independent half-sample renders (for independent noise, the difference of two halves
    /// has twice the standard deviation of their average).
    pub noise: ImageErrors,
}

/// Renders a reference as two independent halves (seeds [`reference_half_seeds`]) and
/// averages them.
pub fn render_reference(
    scene: &Scene,
    camera: &Camera,
    integrator: &dyn Integrator,
    settings: &RenderSettings,
    progress: &(dyn Fn(Progress) -> bool + Sync),
) -> Result<Reference> {
    if settings.spp < 2 {
        return Err(Error::invalid(
            "a reference needs at least 2 samples per pixel (two halves)",
        ));
    }
    let cancel = AtomicBool::new(false);
    let [first_seed, second_seed] = reference_half_seeds(settings.seed);
    let half = RenderSettings {
        spp: settings.spp / 2,
        time_limit: None,
        seed: first_seed,
        ..settings.clone()
    };
    let half_progress = |offset: f64| {
        move |p: Progress| {
            progress(Progress {
                fraction: offset + 0.5 * p.fraction,
                ..p
            })
        }
    };
    let (a, stats_a) = render(
        scene,
        camera,
        integrator,
        &half,
        &half_progress(0.0),
        &cancel,
    )?;
    let second = RenderSettings {
        seed: second_seed,
        ..half.clone()
    };
    let (b, stats_b) = render(
        scene,
        camera,
        integrator,
        &second,
        &half_progress(0.5),
        &cancel,
    )?;
    if stats_a.cancelled || stats_b.cancelled {
        return Err(Error::Cancelled);
    }
    let diff = image_errors(&a.radiance(), &b.radiance())?;
    let noise = ImageErrors {
        mae: diff.mae / 2.0,
        rmse: diff.rmse / 2.0,
        rel_mse: diff.rel_mse / 4.0,
    };
    let mut film = a;
    film.merge(&b);
    let stats = RenderStats {
        seconds: stats_a.seconds + stats_b.seconds,
        spp: stats_a.spp + stats_b.spp,
        samples: stats_a.samples + stats_b.samples,
        rays: stats_a.rays + stats_b.rays,
        passes: stats_a.passes + stats_b.passes,
        cancelled: false,
        largest_guided_ratio: stats_a
            .largest_guided_ratio
            .max(stats_b.largest_guided_ratio),
        precompute_seconds: 0.0,
    };
    Ok(Reference { film, stats, noise })
}

/// One integrator taking part in a comparison, under the label shown in reports.
pub struct Contender {
    pub label: String,
    pub integrator: Box<dyn Integrator>,
    /// The pixel sampler of this contender's renders (`None`: the comparison's settings').
    pub sampler: Option<SamplerKind>,
}

impl Contender {
    /// The contender `spec` labels: an integrator specification ([`integrator::parse_spec`])
    /// that may also carry `sampler=sobol|independent` among its options, so that a
    /// comparison can race one integrator on both samplers (`path:sampler=independent,path`).
    pub fn from_spec(spec: &str, settings: IntegratorSettings) -> Result<Self> {
        let mut sampler = None;
        let mut parts = Vec::new();
        for part in spec.split(':') {
            match part.trim().strip_prefix("sampler=") {
                Some(name) => sampler = Some(SamplerKind::parse(name.trim())?),
                None => parts.push(part),
            }
        }
        Ok(Contender {
            label: spec.to_string(),
            integrator: integrator::create(&parts.join(":"), settings)?,
            sampler,
        })
    }
}

/// Errors of one run at one moment.
#[derive(Clone, Copy, Debug)]
pub struct CurvePoint {
    pub contender: usize,
    pub run: u32,
    /// Time since the run started, its precomputation included.
    pub seconds: f64,
    pub spp: u32,
    pub errors: ImageErrors,
}

/// The end of one run.
#[derive(Clone, Copy, Debug)]
pub struct RunResult {
    pub contender: usize,
    pub run: u32,
    /// Time the integrator's per-scene precomputation took in this run (part of its budget).
    pub precompute_seconds: f64,
    pub stats: RenderStats,
    pub errors: ImageErrors,
    /// The run's brightest pixel against the reference's (`film::largest_pixel_ratio`; NaN
    /// where undefined): fireflies.
    pub largest_pixel: f64,
}

/// Median and range of a figure over runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spread {
    pub median: f64,
    pub min: f64,
    pub max: f64,
}

impl Spread {
    pub fn of(values: &[f64]) -> Option<Spread> {
        let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let median = if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        };
        Some(Spread {
            median,
            min: v[0],
            max: v[n - 1],
        })
    }

    /// True when the two ranges do not overlap.
    pub fn separated_from(&self, other: &Spread) -> bool {
        self.max < other.min || other.max < self.min
    }
}

/// What the comparison concludes about one contender.
#[derive(Clone, Debug)]
pub struct Summary {
    pub label: String,
    pub mae: Spread,
    pub rmse: Spread,
    pub rel_mse: Spread,
    pub spp: Spread,
    /// Per-scene precomputation time (included in the budget and in every time below).
    pub precompute_seconds: Spread,
    /// Each run's brightest pixel over the reference's ([`RunResult::largest_pixel`]).
    pub largest_pixel: Spread,
    /// Time at which this contender reached the baseline's final MAE (median over runs);
    /// `None` when no run reached it.
    pub time_to_baseline_error: Option<Spread>,
    /// Speedup over the baseline (baseline time / time to reach its error), reported only when
    /// this contender's final MAE range over runs does not overlap the baseline's.
    pub speedup: Option<Spread>,
    /// Speedup estimated from final errors, (baseline MAE / this MAE)^2 per run: what an
    /// unbiased estimator whose MAE falls as t^-1/2 would need in time. Defined also when the
    /// baseline's error was never reached (a slower contender), where `speedup` is not.
    pub efficiency: Spread,
    /// With the reference's noise known: each run's final MSE minus the reference's own
    /// (RMSE² - noise RMSE²), an unbiased estimate of the MSE against the converged image when
    /// the two are independent. None without the noise estimate.
    pub mse_above_reference: Option<Spread>,
    /// Speedup by that excess MSE: the baseline's median excess over each run's. At equal
    /// time an unbiased estimator's MSE falls as 1/t, so this is the time ratio, free of the
    /// floor a noisy reference puts under MAE and RMSE (which shrinks the MAE speedups toward
    /// 1). None without the noise estimate or where an excess is not above 0 (the error is
    /// within the reference's own).
    pub mse_speedup: Option<Spread>,
    /// True when the final errors are within the run-to-run spread of the baseline's.
    pub indistinguishable: bool,
    /// Slope of log MAE against log time over the second half of the median run: about -0.5
    /// for an unbiased Monte Carlo estimator, near 0 when the error has hit a plateau (bias,
    /// or the reference's own noise).
    pub slope: Option<f64>,
}

/// A slope above this (log MAE per log time) counts as a plateau.
pub const PLATEAU_SLOPE: f64 = -0.15;

impl Summary {
    pub fn plateaued(&self) -> bool {
        self.slope.is_some_and(|s| s > PLATEAU_SLOPE)
    }
}

/// Least-squares slope of log(MAE) against log(time) over the second half (in time) of a curve.
pub fn convergence_slope(curve: &[CurvePoint]) -> Option<f64> {
    let last = curve.last()?.seconds;
    let pts: Vec<(f64, f64)> = curve
        .iter()
        .filter(|p| p.seconds >= 0.5 * last && p.seconds > 0.0 && p.errors.mae > 0.0)
        .map(|p| (p.seconds.ln(), p.errors.mae.ln()))
        .collect();
    if pts.len() < 3 {
        return None;
    }
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

/// Mean and standard error of the mean.
fn mean_and_standard_error(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    if values.len() < 2 {
        return (mean, f64::INFINITY);
    }
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// Everything a comparison measured.
pub struct Comparison {
    pub labels: Vec<String>,
    pub seconds_per_run: f64,
    pub runs: u32,
    pub schedule: Schedule,
    pub points: Vec<CurvePoint>,
    pub results: Vec<RunResult>,
    pub summaries: Vec<Summary>,
    /// The last run's film of each contender.
    pub films: Vec<Film>,
    pub reference_noise: Option<ImageErrors>,
    /// Each contender's [`Integrator::bias`]: why its error has a floor, when it has one.
    pub biases: Vec<Option<String>>,
}

/// How the contenders of one run share the machine.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Schedule {
    /// One after the other, each with the whole machine; the order rotates each run so that
    /// no contender always goes first.
    #[default]
    Sequential,
    /// All at once, each with its own worker threads, for the same wall-clock time: on a
    /// shared machine whose load swings, every contender meets the same load, so their ratios
    /// hold where one-after-the-other runs can be moved by a swing between them. Each gets
    /// about 1 / (contenders) of the machine, so absolute figures drop and ratios stay.
    Concurrent,
}

/// Runs every contender for the same wall-clock time, `runs` times, in one process, one after
/// the other ([`Schedule::Sequential`]); see [`compare_scheduled`].
#[allow(clippy::too_many_arguments)]
pub fn compare(
    scene: &Scene,
    camera: &Camera,
    contenders: &mut [Contender],
    reference: &[Rgb],
    reference_noise: Option<ImageErrors>,
    settings: &RenderSettings,
    seconds_per_run: f64,
    runs: u32,
    progress: &(dyn Fn(Progress) -> bool + Sync),
) -> Result<Comparison> {
    compare_scheduled(
        scene,
        camera,
        contenders,
        reference,
        reference_noise,
        settings,
        seconds_per_run,
        runs,
        Schedule::Sequential,
        progress,
    )
}

/// Runs every contender for the same wall-clock time, `runs` times, in one process, as
/// `schedule` says; logs errors against `reference` after every pass. Each run starts with
/// the contender's per-scene precomputation ([`Integrator::prepare`], built afresh), which is
/// timed and spent from the same budget: the render gets what is left, and curve times count
/// from the start of the precomputation. The first contender is the baseline.
#[allow(clippy::too_many_arguments)]
pub fn compare_scheduled(
    scene: &Scene,
    camera: &Camera,
    contenders: &mut [Contender],
    reference: &[Rgb],
    reference_noise: Option<ImageErrors>,
    settings: &RenderSettings,
    seconds_per_run: f64,
    runs: u32,
    schedule: Schedule,
    progress: &(dyn Fn(Progress) -> bool + Sync),
) -> Result<Comparison> {
    if contenders.is_empty() {
        return Err(Error::invalid("compare needs at least one integrator"));
    }
    if !(seconds_per_run > 0.0 && seconds_per_run.is_finite()) || runs == 0 {
        return Err(Error::invalid(format!(
            "time per run {seconds_per_run} s and runs {runs} must be positive"
        )));
    }
    let pixels = settings.width as usize * settings.height as usize;
    if reference.len() != pixels {
        return Err(Error::invalid(format!(
            "reference has {} pixels but the render has {}x{} = {pixels}",
            reference.len(),
            settings.width,
            settings.height
        )));
    }
    let n = contenders.len();
    let total = (n as u32 * runs) as f64;
    let mut points = Vec::new();
    let mut results = Vec::new();
    let mut films: Vec<Option<Film>> = (0..n).map(|_| None).collect();
    let cancel = AtomicBool::new(false);
    let job = |contender: &mut Contender, c: usize, run: u32, offset: f64, share: f64| {
        run_contender(
            scene,
            camera,
            contender,
            c,
            run,
            reference,
            settings,
            seconds_per_run,
            &cancel,
            &|p: Progress| {
                progress(Progress {
                    fraction: (offset + share * p.fraction) / total,
                    ..p
                })
            },
        )
    };
    for run in 0..runs {
        let done = (run * n as u32) as f64;
        let outcomes: Vec<Result<ContenderRun>> = match schedule {
            Schedule::Sequential => {
                let mut outcomes: Vec<Option<Result<ContenderRun>>> =
                    (0..n).map(|_| None).collect();
                for k in 0..n {
                    let c = (k + run as usize) % n;
                    let outcome = job(&mut contenders[c], c, run, done + k as f64, 1.0);
                    let failed = outcome.is_err();
                    outcomes[c] = Some(outcome);
                    if failed {
                        break;
                    }
                }
                outcomes.into_iter().flatten().collect()
            }
            // Every contender of the run on its own thread (each makes its own worker pool);
            // each one's progress stands for the whole run's.
            Schedule::Concurrent => std::thread::scope(|s| {
                let handles: Vec<_> = contenders
                    .iter_mut()
                    .enumerate()
                    .map(|(c, contender)| {
                        let job = &job;
                        s.spawn(move || job(contender, c, run, done, n as f64))
                    })
                    .collect();
                handles
                    .into_iter()
                    .map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
                    .collect()
            }),
        };
        for outcome in outcomes {
            let outcome = outcome?;
            points.extend(outcome.points);
            films[outcome.result.contender] = Some(outcome.film);
            results.push(outcome.result);
        }
    }
    let labels: Vec<String> = contenders.iter().map(|c| c.label.clone()).collect();
    let summaries = summarize(&labels, &points, &results, seconds_per_run, reference_noise);
    Ok(Comparison {
        labels,
        seconds_per_run,
        runs,
        schedule,
        points,
        results,
        summaries,
        films: films
            .into_iter()
            .map(|f| f.expect("every contender ran"))
            .collect(),
        reference_noise,
        biases: contenders.iter().map(|c| c.integrator.bias()).collect(),
    })
}

/// What one run of one contender measured.
struct ContenderRun {
    result: RunResult,
    points: Vec<CurvePoint>,
    film: Film,
}

/// One run of contender `c`: its precomputation, then its render for what is left of
/// `seconds_per_run`, logging errors against `reference` after every pass.
#[allow(clippy::too_many_arguments)]
fn run_contender(
    scene: &Scene,
    camera: &Camera,
    contender: &mut Contender,
    c: usize,
    run: u32,
    reference: &[Rgb],
    settings: &RenderSettings,
    seconds_per_run: f64,
    cancel: &AtomicBool,
    progress: &(dyn Fn(Progress) -> bool + Sync),
) -> Result<ContenderRun> {
    let start = Instant::now();
    contender.integrator.set_time_budget(Some(seconds_per_run));
    let prepare_progress = |_: &str, _: f64| {
        progress(Progress {
            fraction: 0.0,
            spp_done: 0,
            elapsed: start.elapsed(),
        })
    };
    prepare(
        contender.integrator.as_mut(),
        scene,
        camera,
        settings.threads,
        &prepare_progress,
    )?;
    let precompute_seconds = start.elapsed().as_secs_f64();
    let render_seconds = seconds_per_run - precompute_seconds;
    if render_seconds <= 0.0 {
        return Err(Error::invalid(format!(
            "{}: its precomputation took {precompute_seconds:.3} s, the whole budget of {seconds_per_run} s",
            contender.label
        )));
    }
    let rs = RenderSettings {
        spp: u32::MAX,
        time_limit: Some(Duration::from_secs_f64(render_seconds)),
        seed: run_seed(settings.seed, run, c),
        sampler: contender.sampler.unwrap_or(settings.sampler),
        ..settings.clone()
    };
    let mut points = Vec::new();
    let mut on_pass = |film: &Film, pass: crate::render::PassReport| {
        if let Ok(errors) = image_errors(&film.radiance(), reference) {
            points.push(CurvePoint {
                contender: c,
                run,
                seconds: precompute_seconds + pass.seconds,
                spp: pass.spp,
                errors,
            });
        }
    };
    let (film, stats) = render_observed(
        scene,
        camera,
        contender.integrator.as_ref(),
        &rs,
        progress,
        cancel,
        &mut on_pass,
    )?;
    if stats.cancelled {
        return Err(Error::Cancelled);
    }
    let radiance = film.radiance();
    let errors = image_errors(&radiance, reference)?;
    let largest_pixel = largest_pixel_ratio(&radiance, reference).unwrap_or(f64::NAN);
    Ok(ContenderRun {
        result: RunResult {
            contender: c,
            run,
            precompute_seconds,
            stats,
            errors,
            largest_pixel,
        },
        points,
        film,
    })
}

/// Seeds of a reference's two halves, derived from its `seed` through a hash. A render with
/// the seed of one half and the same integrator replays that half's samples (the same
/// per-pixel, per-sample random numbers), so its error against the reference would be
/// underestimated. Halves at `seed` and `seed + 1` would be replayed by `lacuna render` with
/// seed 0 (the default of both commands) or 1; a hashed seed is one no user picks.
pub fn reference_half_seeds(seed: u64) -> [u64; 2] {
    const REFERENCE_DOMAIN: u64 = 0x2EF0_2E9C_E5EE_D5A1;
    [0u64, 1].map(|half| crate::math::mix64(seed ^ REFERENCE_DOMAIN ^ half))
}

/// Seed of run `run` of contender `contender`, derived through a hash, so that no run replays
/// a reference's half ([`reference_half_seeds`]) or another run.
pub fn run_seed(seed: u64, run: u32, contender: usize) -> u64 {
    const COMPARE_DOMAIN: u64 = 0xC0DE_C0A5_E5EE_D5ED;
    crate::math::mix64(seed ^ COMPARE_DOMAIN)
        .wrapping_add(crate::math::mix64(((run as u64) << 32) | contender as u64))
}

/// Time at which a run's MAE curve first reaches `target`, interpolated in log-log space
/// between the two passes that bracket it.
pub fn time_to_reach(curve: &[CurvePoint], target: f64) -> Option<f64> {
    let mut prev: Option<&CurvePoint> = None;
    for p in curve {
        if p.errors.mae <= target {
            return Some(match prev {
                Some(q)
                    if q.errors.mae > target
                        && q.seconds > 0.0
                        && p.seconds > q.seconds
                        && p.errors.mae > 0.0 =>
                {
                    let (t0, t1) = (q.seconds.ln(), p.seconds.ln());
                    let (e0, e1) = (q.errors.mae.ln(), p.errors.mae.ln());
                    let a = (target.ln() - e0) / (e1 - e0);
                    (t0 + a * (t1 - t0)).exp()
                }
                _ => p.seconds,
            });
        }
        prev = Some(p);
    }
    None
}

fn summarize(
    labels: &[String],
    points: &[CurvePoint],
    results: &[RunResult],
    seconds: f64,
    reference_noise: Option<ImageErrors>,
) -> Vec<Summary> {
    let of = |c: usize, f: &dyn Fn(&RunResult) -> f64| {
        let v: Vec<f64> = results.iter().filter(|r| r.contender == c).map(f).collect();
        Spread::of(&v).unwrap_or(Spread {
            median: f64::NAN,
            min: f64::NAN,
            max: f64::NAN,
        })
    };
    let baseline_mae = of(0, &|r| r.errors.mae);
    let maes = |c: usize| -> Vec<f64> {
        results
            .iter()
            .filter(|r| r.contender == c)
            .map(|r| r.errors.mae)
            .collect()
    };
    let (base_mean, base_se) = mean_and_standard_error(&maes(0));
    let excess_mse = |c: usize| -> Option<Vec<f64>> {
        let noise = reference_noise?;
        Some(
            results
                .iter()
                .filter(|r| r.contender == c)
                .map(|r| r.errors.rmse.powi(2) - noise.rmse.powi(2))
                .collect(),
        )
    };
    let baseline_excess = excess_mse(0).and_then(|v| Spread::of(&v));
    (0..labels.len())
        .map(|c| {
            let mae = of(c, &|r| r.errors.mae);
            let runs: Vec<u32> = results
                .iter()
                .filter(|r| r.contender == c)
                .map(|r| r.run)
                .collect();
            let times: Vec<f64> = runs
                .iter()
                .filter_map(|&run| {
                    let curve: Vec<CurvePoint> = points
                        .iter()
                        .filter(|p| p.contender == c && p.run == run)
                        .copied()
                        .collect();
                    time_to_reach(&curve, baseline_mae.median)
                })
                .collect();
            let time_to_baseline_error = Spread::of(&times);
            // Distinguishable only when the ranges over runs do not overlap and the means
            // differ by more than three combined standard errors.
            let (mean, se) = mean_and_standard_error(&maes(c));
            let indistinguishable = !mae.separated_from(&baseline_mae)
                || (mean - base_mean).abs() <= 3.0 * (se * se + base_se * base_se).sqrt();
            let median_run = {
                let mut rs: Vec<&RunResult> = results.iter().filter(|r| r.contender == c).collect();
                rs.sort_by(|a, b| a.errors.mae.total_cmp(&b.errors.mae));
                rs.get(rs.len() / 2).map_or(0, |r| r.run)
            };
            let curve: Vec<CurvePoint> = points
                .iter()
                .filter(|p| p.contender == c && p.run == median_run)
                .copied()
                .collect();
            let slope = convergence_slope(&curve);
            let speedup = if c == 0 || indistinguishable {
                None
            } else {
                let ratios: Vec<f64> = times.iter().map(|t| seconds / t.max(1e-9)).collect();
                Spread::of(&ratios)
            };
            let efficiency_runs: Vec<f64> = maes(c)
                .iter()
                .map(|m| (baseline_mae.median / m).powi(2))
                .collect();
            let efficiency = Spread::of(&efficiency_runs).unwrap_or(Spread {
                median: f64::NAN,
                min: f64::NAN,
                max: f64::NAN,
            });
            let excess = excess_mse(c);
            let mse_speedup = match (&excess, baseline_excess) {
                (Some(runs), Some(base)) if base.median > 0.0 && runs.iter().all(|&e| e > 0.0) => {
                    let ratios: Vec<f64> = runs.iter().map(|e| base.median / e).collect();
                    Spread::of(&ratios)
                }
                _ => None,
            };
            Summary {
                label: labels[c].clone(),
                mae,
                mse_above_reference: excess.and_then(|v| Spread::of(&v)),
                mse_speedup,
                efficiency,
                rmse: of(c, &|r| r.errors.rmse),
                rel_mse: of(c, &|r| r.errors.rel_mse),
                spp: of(c, &|r| r.stats.spp as f64),
                precompute_seconds: of(c, &|r| r.precompute_seconds),
                largest_pixel: of(c, &|r| r.largest_pixel),
                time_to_baseline_error,
                speedup,
                indistinguishable,
                slope,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(seconds: f64, mae: f64) -> CurvePoint {
        CurvePoint {
            contender: 0,
            run: 0,
            seconds,
            spp: 1,
            errors: ImageErrors {
                mae,
                rmse: mae,
                rel_mse: mae,
            },
        }
    }

    #[test]
    fn reference_halves_are_no_seed_a_user_renders_with() {
        // `lacuna render --seed N` for small N (0 is the default of both commands) must not
        // replay either half of a reference made with any small seed.
        let user_seeds: std::collections::HashSet<u64> = (0..=10_000).collect();
        for s in 0..=1_000u64 {
            let [a, b] = reference_half_seeds(s);
            assert!(a != b, "seed {s}: both halves have one seed");
            assert!(
                !user_seeds.contains(&a) && !user_seeds.contains(&b),
                "seed {s}: a half renders with a small seed"
            );
        }
    }

    #[test]
    fn run_seeds_never_replay_a_reference() {
        // No comparison run may use a reference's half seed, and runs and contenders must not
        // share seeds among themselves.
        for s in [0u64, 1, 2, 41, 999, 1000, u64::MAX] {
            let halves = reference_half_seeds(s);
            let mut seen = std::collections::HashSet::new();
            for run in 0..8 {
                for c in 0..8 {
                    let r = run_seed(s, run, c);
                    assert!(!halves.contains(&r), "seed {s} run {run} c {c}");
                    assert!(
                        seen.insert(r),
                        "seed {s}: run {run} contender {c} repeats a seed"
                    );
                }
            }
        }
    }

    fn result(contender: usize, run: u32, rmse: f64) -> RunResult {
        RunResult {
            contender,
            run,
            precompute_seconds: 0.0,
            stats: RenderStats::default(),
            errors: ImageErrors {
                mae: rmse,
                rmse,
                rel_mse: rmse,
            },
            largest_pixel: 1.0,
        }
    }

    /// Two estimators whose MSE against the converged image is 4e-4 and 1e-4 (a 4x speedup at
    /// equal time), measured against a reference whose own MSE is 9e-4: MSE ratios against
    /// the reference say 1.3x, the excess over the reference's noise says 4x.
    #[test]
    fn mse_speedup_removes_the_reference_noise() {
        let noise = ImageErrors {
            mae: 0.03,
            rmse: 0.03,
            rel_mse: 0.0,
        };
        let (slow, fast) = ((4e-4f64 + 9e-4).sqrt(), (1e-4f64 + 9e-4).sqrt());
        let results = [
            result(0, 0, slow),
            result(1, 0, fast),
            result(0, 1, slow),
            result(1, 1, fast),
        ];
        let labels = ["a".to_string(), "b".to_string()];
        let sm = summarize(&labels, &[], &results, 10.0, Some(noise));
        let sp = sm[1].mse_speedup.unwrap();
        assert!((sp.median - 4.0).abs() < 1e-9, "{sp:?}");
        assert!((sm[0].mse_speedup.unwrap().median - 1.0).abs() < 1e-9);
        assert!((sm[1].mse_above_reference.unwrap().median - 1e-4).abs() < 1e-12);
        assert!((slow / fast).powi(2) < 1.35);
        // Without the noise, or within it, no such speedup.
        assert!(summarize(&labels, &[], &results, 10.0, None)[1]
            .mse_speedup
            .is_none());
        let within = ImageErrors {
            rmse: 0.04,
            ..noise
        };
        assert!(summarize(&labels, &[], &results, 10.0, Some(within))[1]
            .mse_speedup
            .is_none());
    }

    #[test]
    fn time_to_reach_interpolates_in_log_space() {
        let curve = [point(1.0, 1.0), point(4.0, 0.25), point(16.0, 0.0625)];
        assert_eq!(time_to_reach(&curve, 2.0), Some(1.0));
        let t = time_to_reach(&curve, 0.5).unwrap();
        assert!((t - 2.0).abs() < 1e-9, "{t}");
        assert_eq!(time_to_reach(&curve, 0.01), None);
    }

    #[test]
    fn spread_median_and_separation() {
        let s = Spread::of(&[3.0, 1.0, 2.0, f64::NAN]).unwrap();
        assert_eq!((s.median, s.min, s.max), (2.0, 1.0, 3.0));
        assert_eq!(Spread::of(&[1.0, 2.0]).unwrap().median, 1.5);
        assert!(Spread::of(&[]).is_none());
        let t = Spread {
            median: 5.0,
            min: 4.0,
            max: 6.0,
        };
        assert!(
            s.separated_from(&t)
                && !s.separated_from(&Spread {
                    median: 3.0,
                    min: 2.5,
                    max: 4.0
                })
        );
    }
}
