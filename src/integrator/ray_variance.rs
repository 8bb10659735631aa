//! The variance of `env_direct`'s direct-lighting estimate at fixed camera rays: the set-up of
//! thesis 001's Table 5.2 (variance "per camera ray and per light source"), where the MIS
//! weighting is the only source of noise. A pixel's image variance also holds antialiasing
//! (where in the pixel the camera ray lands, edges, textures), which is the same for every
//! weighting and dilutes their ratio toward 1; a fixed ray per pixel leaves it out.
//!
//! [`shading_points`] casts one ray through each pixel centre and keeps the first hit where
//! `env_direct` shades (a non-delta BSDF). [`measure_group`] evaluates K independent estimates
//! of [`EnvDirect::shade`] (env_direct's own per-source estimator, nothing re-implemented) at
//! every point and keeps per point the mean and the unbiased sample variance of their
//! luminance, with the thread CPU time spent. A measurement is several such groups, run in
//! turn for every weighting (A B A B), so that load changes fall on all alike; [`compare`]
//! forms the ratios against the balance heuristic and their standard errors by the jackknife
//! over the groups (the groups are independent: disjoint random streams).
//!
//! Two variance figures, both relative to balance: the **mean over points of the per-ray
//! variance** (the thesis's "average variance computed over all the pixels", Table 5.1/5.2),
//! which bright points dominate, and the **mean of the relative variance** var / mean^2 per
//! point (each point counts alike, as a relative error would), with the per-point mean pooled
//! over every weighting (all are unbiased) so the same denominators serve all of them, and a
//! floor of (1 % of the image's mean)^2 added to them ([`pooled_squared_means`]).
//! Efficiency is 1 / (variance x CPU time), as the thesis's, from the first figure.

use rayon::prelude::*;

use super::{EnvDirect, TraceCounters};
use crate::math::{luminance, Rng, Sampler, Vec2};
use crate::scene::{Scene, SurfaceInteraction};
use crate::timing::thread_cpu_seconds;

/// The first hit of the ray through each pixel centre of a `width` x `height` image of the
/// scene's camera, where it has a non-delta BSDF (mirror and glass hits, and misses, have no
/// direct-lighting estimate at the first hit and are left out).
pub fn shading_points(scene: &Scene, width: u32, height: u32) -> Vec<SurfaceInteraction> {
    let Some(camera) = scene.camera() else {
        return Vec::new();
    };
    let frame = camera.frame(width as f32 / height as f32);
    (0..width * height)
        .filter_map(|p| {
            let (x, y) = (p % width, p / width);
            let film = Vec2::new(
                (x as f32 + 0.5) / width as f32,
                (y as f32 + 0.5) / height as f32,
            );
            let si = scene.intersect(&frame.generate_ray(film, Vec2::splat(0.5)))?;
            (!scene.bsdf(&si).is_delta()).then_some(si)
        })
        .collect()
}

/// Per-point statistics of one group of estimates.
#[derive(Clone, Debug, Default)]
pub struct GroupStats {
    /// Mean luminance of the group's estimates, per point.
    pub mean: Vec<f64>,
    /// Unbiased sample variance (divisor K - 1) of the estimates' luminance, per point.
    pub variance: Vec<f64>,
    /// Thread CPU time of all the group's estimates (summed over worker threads).
    pub cpu_seconds: f64,
    /// Estimates per point.
    pub estimates: u32,
}

/// Mean and unbiased sample variance of `values` (at least two).
pub fn mean_and_variance(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let ss = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>();
    (mean, ss / (n - 1.0))
}

/// Points per parallel task: enough work per task that reading the thread clock (a system
/// call) twice costs nothing measurable.
const POINTS_PER_TASK: usize = 16;

/// `estimates` (at least 2) independent estimates of `shader` at every point, group `group`:
/// point `p`'s estimate `k` draws from random stream `(group * estimates + k) * points + p` of
/// `seed`: groups never share numbers, weightings measured with the same seed do (common
/// random numbers, so their estimates share some samples, which the jackknife over groups
/// accounts for), and any thread count gives the same figures (the CPU time aside).
pub fn measure_group(
    scene: &Scene,
    shader: &EnvDirect,
    points: &[SurfaceInteraction],
    estimates: u32,
    seed: u64,
    group: u32,
) -> GroupStats {
    assert!(estimates >= 2, "a variance needs two estimates per point");
    let n = points.len() as u64;
    let chunks: Vec<(Vec<(f64, f64)>, f64)> = points
        .par_chunks(POINTS_PER_TASK)
        .enumerate()
        .map(|(c, chunk)| {
            let started = thread_cpu_seconds();
            let mut values = vec![0.0; estimates as usize];
            let stats = chunk
                .iter()
                .enumerate()
                .map(|(i, si)| {
                    let p = (c * POINTS_PER_TASK + i) as u64;
                    for (k, value) in values.iter_mut().enumerate() {
                        let stream = (group as u64 * estimates as u64 + k as u64) * n + p;
                        let mut rng = Sampler::independent(Rng::new(seed, stream));
                        let mut counters = TraceCounters::default();
                        *value = luminance(shader.shade(scene, si, &mut rng, &mut counters)) as f64;
                    }
                    mean_and_variance(&values)
                })
                .collect();
            (stats, thread_cpu_seconds() - started)
        })
        .collect();
    let mut out = GroupStats {
        estimates,
        ..Default::default()
    };
    for (stats, seconds) in chunks {
        out.cpu_seconds += seconds;
        for (m, v) in stats {
            out.mean.push(m);
            out.variance.push(v);
        }
    }
    out
}

/// The per-point denominators of the relative variance: the squared mean over every group of
/// every weighting (all estimate the same value), plus (1 % of the mean over points)^2 so that
/// points in shadow, whose mean is near zero, do not dominate (as relMSE's epsilon).
pub fn pooled_squared_means(all: &[&[GroupStats]]) -> Vec<f64> {
    let points = all
        .iter()
        .flat_map(|g| g.iter())
        .map(|g| g.mean.len())
        .next()
        .unwrap_or(0);
    let mut sum = vec![0.0; points];
    let mut count = 0usize;
    for group in all.iter().flat_map(|g| g.iter()) {
        for (s, m) in sum.iter_mut().zip(&group.mean) {
            *s += m;
        }
        count += 1;
    }
    let means: Vec<f64> = sum.iter().map(|s| s / count.max(1) as f64).collect();
    let floor = (0.01 * means.iter().sum::<f64>() / points.max(1) as f64).powi(2);
    means.iter().map(|m| m * m + floor).collect()
}

/// A ratio and its standard error.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Ratio {
    pub value: f64,
    pub std_err: f64,
}

/// One weighting against the balance heuristic (see the module documentation): variance and
/// relative variance of the weighting over balance's (< 1 = less noise), CPU time per
/// estimate of the weighting over balance's, and efficiency = 1 / (variance x time) of the
/// weighting over balance's (> 1 = better).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Comparison {
    pub variance: Ratio,
    pub relative_variance: Ratio,
    pub time: Ratio,
    pub efficiency: Ratio,
    /// Mean over points of balance's per-ray variance, and its CPU seconds per estimate.
    pub balance_variance: f64,
    pub balance_seconds_per_estimate: f64,
}

/// Sums over the groups `keep` selects: (variance, relative variance, CPU seconds, estimates
/// x points), the variances summed over points.
fn sums(groups: &[GroupStats], denominators: &[f64], keep: impl Fn(usize) -> bool) -> [f64; 4] {
    let mut s = [0.0; 4];
    for (_, group) in groups.iter().enumerate().filter(|(g, _)| keep(*g)) {
        for (v, d) in group.variance.iter().zip(denominators) {
            s[0] += v;
            if *d > 0.0 {
                s[1] += v / d;
            }
        }
        s[2] += group.cpu_seconds;
        s[3] += group.estimates as f64 * group.variance.len() as f64;
    }
    s
}

/// The jackknife estimate of `statistic` (a function of the groups left in) and its standard
/// error over `groups` independent groups: sqrt((G - 1) / G sum (theta_-g - mean)^2).
pub fn jackknife(groups: usize, statistic: impl Fn(Option<usize>) -> f64) -> Ratio {
    let value = statistic(None);
    if groups < 2 {
        return Ratio {
            value,
            std_err: f64::NAN,
        };
    }
    let leave_out: Vec<f64> = (0..groups).map(|g| statistic(Some(g))).collect();
    let mean = leave_out.iter().sum::<f64>() / groups as f64;
    let spread = leave_out.iter().map(|t| (t - mean).powi(2)).sum::<f64>();
    Ratio {
        value,
        std_err: ((groups as f64 - 1.0) / groups as f64 * spread).sqrt(),
    }
}

/// `other` against `balance` (the same number of groups, the same points), with the
/// relative variance's per-point `denominators` ([`pooled_squared_means`]).
pub fn compare(balance: &[GroupStats], other: &[GroupStats], denominators: &[f64]) -> Comparison {
    assert_eq!(balance.len(), other.len(), "the same groups for both");
    let groups = balance.len();
    let ratios = |left_out: Option<usize>| {
        let keep = |g: usize| Some(g) != left_out;
        let b = sums(balance, denominators, keep);
        let o = sums(other, denominators, keep);
        // Per estimate: the variance sums are over the same points and groups.
        let time = (o[2] / o[3]) / (b[2] / b[3]);
        [o[0] / b[0], o[1] / b[1], time, b[0] / o[0] / time]
    };
    let each = |i: usize| jackknife(groups, |left_out| ratios(left_out)[i]);
    let all = sums(balance, denominators, |_| true);
    let points = balance.first().map_or(0, |g| g.variance.len()) as f64;
    Comparison {
        variance: each(0),
        relative_variance: each(1),
        time: each(2),
        efficiency: each(3),
        balance_variance: all[0] / (groups as f64 * points),
        balance_seconds_per_estimate: all[2] / all[3],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn group(rng: &mut Rng, sigma: &[f64], k: u32, seconds: f64) -> GroupStats {
        let mut out = GroupStats {
            estimates: k,
            cpu_seconds: seconds,
            ..Default::default()
        };
        for (p, s) in sigma.iter().enumerate() {
            // Uniform on [mu - s sqrt 3, mu + s sqrt 3]: variance s^2, mean mu = 1 + p.
            let values: Vec<f64> = (0..k)
                .map(|_| 1.0 + p as f64 + s * 3f64.sqrt() * (2.0 * rng.uniform() as f64 - 1.0))
                .collect();
            let (m, v) = mean_and_variance(&values);
            out.mean.push(m);
            out.variance.push(v);
        }
        out
    }

    #[test]
    fn sample_variance_of_a_known_set() {
        let (m, v) = mean_and_variance(&[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(m, 2.5);
        assert!((v - 5.0 / 3.0).abs() < 1e-12);
    }

    /// Per-point estimates with known variances: the ratios converge to the analytic ones
    /// (variance sum ratio, relative-variance ratio with means 1 + p, time ratio, efficiency),
    /// and the jackknife standard error matches the spread of the ratio over repeated trials.
    #[test]
    fn ratios_and_standard_errors_on_an_analytic_case() {
        let sigma_b: Vec<f64> = (0..40).map(|p| 0.2 + 0.01 * p as f64).collect();
        let sigma_o: Vec<f64> = sigma_b
            .iter()
            .enumerate()
            .map(|(p, s)| s * if p % 2 == 0 { 0.5 } else { 1.0 })
            .collect();
        let var = |s: &[f64]| s.iter().map(|s| s * s).sum::<f64>();
        // Means 1 + p, p < 40: the floor is (1 % of 20.5)^2.
        let floor = (0.01f64 * 20.5).powi(2);
        let rel = |s: &[f64]| {
            s.iter()
                .enumerate()
                .map(|(p, s)| s * s / ((1.0 + p as f64).powi(2) + floor))
                .sum::<f64>()
        };
        let exact_var = var(&sigma_o) / var(&sigma_b);
        let exact_rel = rel(&sigma_o) / rel(&sigma_b);
        let mut rng = Rng::new(3, 0);
        let (trials, groups, k) = (200, 16, 4);
        let mut values = Vec::new();
        let mut errors = Vec::new();
        for _ in 0..trials {
            let b: Vec<GroupStats> = (0..groups)
                .map(|_| group(&mut rng, &sigma_b, k, 1.0))
                .collect();
            let o: Vec<GroupStats> = (0..groups)
                .map(|_| group(&mut rng, &sigma_o, k, 2.0))
                .collect();
            let d = pooled_squared_means(&[&b, &o]);
            let c = compare(&b, &o, &d);
            assert!((c.time.value - 2.0).abs() < 1e-12 && c.time.std_err < 1e-12);
            assert!((c.efficiency.value - 1.0 / (2.0 * c.variance.value)).abs() < 1e-9);
            values.push([c.variance.value, c.relative_variance.value]);
            errors.push([c.variance.std_err, c.relative_variance.std_err]);
        }
        for (i, exact) in [exact_var, exact_rel].into_iter().enumerate() {
            let v: Vec<f64> = values.iter().map(|v| v[i]).collect();
            let (mean, spread) = mean_and_variance(&v);
            let mean_se = errors.iter().map(|e| e[i]).sum::<f64>() / trials as f64;
            // The mean over trials is within its own error of the exact ratio (a ratio of
            // sums is biased at order 1/n only, far below this).
            let z = (mean - exact) / (spread / trials as f64).sqrt();
            assert!(z.abs() < 4.0, "figure {i}: {mean} against {exact} (z {z})");
            // The jackknife's standard error agrees with the observed spread.
            let ratio = mean_se / spread.sqrt();
            assert!(
                (0.8..1.25).contains(&ratio),
                "figure {i}: standard error {mean_se} against spread {}",
                spread.sqrt()
            );
        }
    }

    #[test]
    fn jackknife_of_a_mean_is_the_standard_error_of_the_mean() {
        let x = [1.0, 4.0, 2.0, 8.0, 5.0];
        let r = jackknife(x.len(), |out| {
            let kept: Vec<f64> = (0..x.len())
                .filter(|&g| Some(g) != out)
                .map(|g| x[g])
                .collect();
            kept.iter().sum::<f64>() / kept.len() as f64
        });
        let (mean, var) = mean_and_variance(&x);
        assert_eq!(r.value, mean);
        assert!((r.std_err - (var / x.len() as f64).sqrt()).abs() < 1e-12);
    }
}
