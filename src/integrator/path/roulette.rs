//! `rr_depth=auto`: where Russian roulette starts, chosen per scene and camera by a pilot.
//!
//! Roulette from depth d ends a path at each later decision with probability
//! 1 - min(max(throughput), 0.95), the throughput carrying earlier survivals' 1 / s. A fixed d
//! suits some scenes and not others: on a closed interior whose light is two rooms from the
//! camera, d = 12 reaches equal error 1.3x sooner than d = 5, because light is found only by
//! paths that have walked there; on the Cornell box d = 12 is 0.66x (BENCHMARKS.md, "Where
//! Russian roulette starts").
//!
//! # The prediction
//!
//! The pilot traces camera paths with no roulette and records, at each decision point k (the
//! start of bounce k), the radiance found so far R_k and the throughput b_k the roulette
//! would read. For a start d the survival at decision k >= d is s_k = min(0.95, b_k / S_{k-1}),
//! S_k = s_1 ... s_k (s_k = 1 below d), so the same path under roulette is the estimator
//! F = sum_k D_k I_k / S_k, with D_0 = R_1, D_k = R_{k+1} - R_k (R_{K+1} the path's
//! radiance), I_k the indicator of surviving decisions 1..k, E[I_a I_b] = S_max(a,b). Given
//! the path, exactly:
//! - E[F^2] = sum_a sum_b D_a D_b / S_min(a,b) = sum_a (D_a / S_a) (D_a + 2 sum_{b>a} D_b);
//! - the rays traced, 1 + sum_k S_k.
//!
//! Roulette's coins are independent of the path's numbers, so it adds E[F^2] - R^2 to the
//! variance per sample the render has without it. That one the pilot measures as
//! `path_skeleton`'s pilot does ([`PilotUnits`], "The pilot" in the parent module), under the
//! render's default numbers: with Sobol points, pixels estimated under two scrambles, which is
//! what makes roulette's share of the noise larger than independent numbers suggest. Averaged
//! over the pilot's paths, every candidate's added variance and cost come from the same paths
//! (their differences are far less noisy than either). The start of least variance x (rays +
//! [`SAMPLE_OVERHEAD`]) wins if it beats the default by [`MARGIN`] with its variance raised by
//! [`SIGMAS`] standard errors (the delta method over the pilot's units, as `path_skeleton`'s
//! pilot); else the default stays.
//!
//! The pilot's numbers are its own, so the render stays unbiased whatever it picks (any
//! survival probability in (0, 1] that depends on the path so far is unbiased), and chunk sums
//! combined in chunk order make the choice independent of the thread count.

use rayon::prelude::*;

use super::{half_squared_difference, PathTracer, PilotUnits, VertexGuide};
use crate::geometry::Ray;
use crate::guide::GuideQuery;
use crate::integrator::mis_auto::VertexAlphas;
use crate::integrator::{IntegratorSettings, TraceCounters};
use crate::math::{luminance, Rgb, SamplerKind};
use crate::scene::{Camera, Scene, SurfaceInteraction};

/// The starts the pilot compares (those at or beyond the render's max depth are skipped).
/// None is earlier than the default: an earlier start trades the error of dark pixels for
/// that of bright ones, which lowers the MSE the pilot predicts but not the MAE (the Cornell
/// box from depth 2: 1.09x by MSE, a 12 % higher MAE, BENCHMARKS.md).
pub(super) const CANDIDATES: [u32; 9] = [5, 6, 8, 10, 12, 16, 20, 24, 32];
/// Camera samples of the pilot (each unit of them traced twice, `PilotUnits`).
const PILOT_SAMPLES: u32 = 8192;
/// The cost of a sample outside its path's rays (camera ray set-up, film), in rays.
const SAMPLE_OVERHEAD: f64 = 0.3;
/// A start other than the default must predict this much more efficiency with its variance
/// raised by `SIGMAS` standard errors (a few bright paths decide the pilot's variance on the
/// scenes where a later start pays: a pilot of 2048 samples without the bound chose 16 on
/// rooms:45, which lost 0.79-0.91x).
const MARGIN: f64 = 1.05;
const SIGMAS: f64 = 2.0;
/// The pilot's paths are cut here (their contributions beyond are negligible for the choice).
const PILOT_MAX_DEPTH: u32 = 48;

/// What the pilot found.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct RouletteChoice {
    pub start_depth: u32,
    /// Predicted efficiency (1 / (variance x cost)) of each candidate over the default's, and
    /// its bound (the variance raised by [`SIGMAS`] standard errors).
    pub efficiencies: Vec<(u32, f64, f64)>,
    pub paths: u32,
}

impl RouletteChoice {
    pub fn note(&self, seconds: f64) -> String {
        let list: Vec<String> = self
            .efficiencies
            .iter()
            .map(|(d, e, b)| format!("{d}: {e:.2} ({b:.2})"))
            .collect();
        format!(
            "rr_depth=auto: roulette from depth {} ({} pilot paths, {seconds:.2} s; predicted efficiency against depth {} (bound): {})",
            self.start_depth,
            self.paths,
            super::PathOptions::default().rr_start_depth,
            list.join(", ")
        )
    }
}

/// A path's second moment under roulette from `start` and the rays it would trace, from its
/// decision points (radiance so far, throughput) and its final radiance (module docs).
pub(super) fn path_moments(points: &[(f64, f64)], radiance: f64, start: u32) -> (f64, f64) {
    // One pass over D_0 .. D_K: D_a = R_{a+1} - R_a carries S_a, and sum_{b>a} D_b is the
    // radiance still to come after it, radiance - R_{a+1}.
    let mut second = 0.0;
    let mut rays = 1.0;
    let mut survival = 1.0f64;
    let mut before = 0.0;
    for k in 0..=points.len() {
        let next = points.get(k).map_or(radiance, |&(r, _)| r);
        let d = next - before;
        if survival > 0.0 {
            second += d / survival * (d + 2.0 * (radiance - next));
        }
        before = next;
        if let Some(&(_, throughput)) = points.get(k) {
            if k as u32 + 1 >= start {
                survival *= if survival > 0.0 {
                    (throughput / survival).min(0.95)
                } else {
                    0.0
                };
            }
            rays += survival;
        }
    }
    (second, rays)
}

/// Records a path's decision points for the pilot; otherwise `path`'s own samples (as
/// [`super::Unguided`]).
struct RouletteRecorder<'a> {
    points: &'a mut Vec<(f64, f64)>,
}

impl VertexGuide for RouletteRecorder<'_> {
    type Query = GuideQuery;
    type Located = ();
    const GUIDED: bool = false;
    #[inline]
    fn prefetch(&self, _: &SurfaceInteraction) {}
    #[inline]
    fn init(&mut self, _: &Scene, _: &SurfaceInteraction, _: (), _: f32) -> u64 {
        0
    }
    #[inline]
    fn clear(&mut self) {}
    #[inline]
    fn query(&self) -> &GuideQuery {
        GuideQuery::unguided()
    }
    #[inline]
    fn roulette_point(&mut self, radiance: Rgb, rr_beta: Rgb) {
        self.points
            .push((luminance(radiance) as f64, rr_beta.max_element() as f64));
    }
}

/// The start of roulette for `scene` seen by `camera` under `settings` (module docs).
pub(super) fn choose_start_depth(
    scene: &Scene,
    camera: &Camera,
    settings: &IntegratorSettings,
) -> RouletteChoice {
    let default = super::PathOptions::default().rr_start_depth;
    let candidates: Vec<u32> = CANDIDATES
        .iter()
        .copied()
        .filter(|&d| d < settings.max_depth || d == default)
        .collect();
    let mut unrouletted = *settings;
    unrouletted.path.rr_start_depth = u32::MAX;
    unrouletted.path.rr_depth_auto = false;
    unrouletted.max_depth = settings.max_depth.min(PILOT_MAX_DEPTH);
    let tracer = PathTracer::new(unrouletted);
    // The render's default numbers (`prepare` is not told the render's sampler).
    let (units, count) = PilotUnits::new(camera, SamplerKind::default(), PILOT_SAMPLES);
    let chunk = match units {
        PilotUnits::Rays(_) => 64,
        PilotUnits::Pixels(_) => 4,
    };
    let n = candidates.len();
    let base = candidates.iter().position(|&d| d == default).unwrap();
    let per_unit = units.samples() as f64;
    // Per chunk, for each candidate i: the sums over units of v_i (the unit's variance per
    // sample under roulette from candidate i), v_i^2, v_i v_base and the rays traced.
    let chunks: Vec<Vec<f64>> = (0..count.div_ceil(chunk))
        .into_par_iter()
        .map(|c| {
            let mut sums = vec![0f64; 4 * n];
            let mut added = vec![0f64; n];
            let mut points = Vec::new();
            let mut counters = TraceCounters::default();
            for unit in c * chunk..((c + 1) * chunk).min(count) {
                added.fill(0.0);
                let estimates = units.estimates(unit, |ray: Ray, rng| {
                    points.clear();
                    let off = &mut { VertexAlphas::OFF };
                    let recorder = &mut RouletteRecorder {
                        points: &mut points,
                    };
                    let sample = tracer.trace(scene, ray, rng, &mut counters, recorder, off);
                    let radiance = luminance(sample.radiance) as f64;
                    for (i, &d) in candidates.iter().enumerate() {
                        let (second, rays) = path_moments(&points, radiance, d);
                        added[i] += second - radiance * radiance;
                        sums[3 * n + i] += rays;
                    }
                    sample.radiance
                });
                let unrouletted = per_unit * half_squared_difference(estimates);
                // The unit traced 2 x per_unit paths.
                let v: Vec<f64> = added
                    .iter()
                    .map(|a| unrouletted + a / (2.0 * per_unit))
                    .collect();
                for i in 0..n {
                    sums[i] += v[i];
                    sums[n + i] += v[i] * v[i];
                    sums[2 * n + i] += v[i] * v[base];
                }
            }
            sums
        })
        .collect();
    let mut sums = vec![0f64; 4 * n];
    for chunk in &chunks {
        for (s, c) in sums.iter_mut().zip(chunk) {
            *s += c;
        }
    }
    let units_n = count as f64;
    let paths = 2.0 * units_n * per_unit;
    let variance = |i: usize| sums[i] / units_n;
    let cost = |i: usize| sums[3 * n + i] / paths + SAMPLE_OVERHEAD;
    // The relative standard error of variance(i) / variance(base), by the delta method over
    // the units (paired: both from the same paths).
    let ratio_error = |i: usize| {
        let (mi, mb) = (variance(i), variance(base));
        let vi = sums[n + i] / units_n - mi * mi;
        let vb = sums[n + base] / units_n - mb * mb;
        let cov = sums[2 * n + i] / units_n - mi * mb;
        ((vi / (mi * mi) + vb / (mb * mb) - 2.0 * cov / (mi * mb)) / units_n)
            .max(0.0)
            .sqrt()
    };
    let mut choice = RouletteChoice {
        start_depth: default,
        efficiencies: Vec::with_capacity(n),
        paths: 2 * count * units.samples(),
    };
    let base_cost = variance(base) * cost(base);
    if !(base_cost.is_finite() && base_cost > 0.0) {
        return choice;
    }
    let mut best = (default, 1.0);
    for (i, &d) in candidates.iter().enumerate() {
        let relative = base_cost / (variance(i) * cost(i));
        // The efficiency with this candidate's variance raised by `SIGMAS` standard errors.
        let bound = relative / (1.0 + SIGMAS * ratio_error(i));
        if !(relative.is_finite() && bound.is_finite() && relative > 0.0) {
            continue;
        }
        choice.efficiencies.push((d, relative, bound));
        if bound > best.1 {
            best = (d, bound);
        }
    }
    if best.1 >= MARGIN {
        choice.start_depth = best.0;
    }
    choice
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    /// Roulette simulated on a recorded path, as `PathTracer::trace` plays it.
    fn simulate(points: &[(f64, f64)], radiance: f64, start: u32, rng: &mut Rng) -> (f64, f64) {
        let mut estimate = 0.0;
        let mut before = 0.0;
        let mut s = 1.0f64;
        let mut rays = 1.0;
        for (i, &(r, b)) in points.iter().enumerate() {
            estimate += (r - before) / s;
            before = r;
            if i as u32 + 1 >= start {
                let survive = (b / s).min(0.95);
                if (rng.uniform() as f64) >= survive {
                    return (estimate, rays);
                }
                s *= survive;
            }
            rays += 1.0;
        }
        estimate += (radiance - before) / s;
        (estimate, rays)
    }

    /// The exact second moment and rays of [`path_moments`] against roulette played out a
    /// million times on paths of growing and shrinking throughput, for every start.
    #[test]
    fn moments_match_roulette_played_out() {
        let paths: [(&[(f64, f64)], f64); 3] = [
            (
                &[
                    (0.0, 0.7),
                    (0.0, 0.49),
                    (0.2, 0.34),
                    (0.2, 0.24),
                    (0.5, 0.17),
                ],
                0.9,
            ),
            (&[(0.1, 1.2), (0.1, 0.9), (0.4, 0.3), (0.4, 0.05)], 0.41),
            (&[], 0.3),
        ];
        let mut rng = Rng::new(7, 0);
        for (points, radiance) in paths {
            for start in 1..=6 {
                let (second, rays) = path_moments(points, radiance, start);
                let n = 1_000_000;
                let (mut m1, mut m2, mut r) = (0.0, 0.0, 0.0);
                for _ in 0..n {
                    let (f, k) = simulate(points, radiance, start, &mut rng);
                    m1 += f;
                    m2 += f * f;
                    r += k;
                }
                let (m1, m2, r) = (m1 / n as f64, m2 / n as f64, r / n as f64);
                // Unbiased: the mean is the path's radiance.
                assert!(
                    (m1 - radiance).abs() < 0.01 * radiance.max(0.1),
                    "{m1} {radiance}"
                );
                assert!(
                    (m2 - second).abs() < 0.01 * second,
                    "start {start}: {m2} {second}"
                );
                assert!((r - rays).abs() < 0.002 * rays, "start {start}: {r} {rays}");
            }
        }
    }

    /// Without roulette (a start beyond the path) the second moment is the radiance squared
    /// and every ray is traced.
    #[test]
    fn no_roulette_is_the_path_itself() {
        let points = [(0.0, 0.7), (0.3, 0.5), (0.3, 0.2)];
        let (second, rays) = path_moments(&points, 0.5, 10);
        assert!((second - 0.25).abs() < 1e-12);
        assert_eq!(rays, 4.0);
    }
}
