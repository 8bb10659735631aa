//! Automatic balancing of light and BSDF samples (`mis=auto`, thesis 001 chapter 5, Lu et al.
//! 2013) and optimal MIS weights (`mis=optimal`, Kondapaneni et al. 2019), for estimators that
//! draw many light and BSDF samples of one integral (`env_direct`), and the per-pixel alpha of
//! `path`'s one light and one BSDF sample per vertex ([`PixelAlphas`], [`VertexAlphas`]).
//!
//! **Second-order balancing.** With a fraction alpha of N samples drawn from pdf_B and the rest
//! from pdf_L, the balance heuristic over the counts is the one-mixture estimator (eq. 5.3)
//! `1/N sum f / q_alpha`, `q_alpha = alpha pdf_B + (1 - alpha) pdf_L`. Writing
//! `q_alpha = pbar + t dpdf` with `pbar = (pdf_B + pdf_L) / 2`, `dpdf = (pdf_B - pdf_L) / 2`,
//! `t = 2 alpha - 1`, its second moment expands around t = 0 as
//! `E[L^2] = sum_n (-t)^n I_n`, `I_n = int f^2 dpdf^n / pbar^(n+1)`; the second-order
//! truncation is minimal at `t = I_1 / (2 I_2)`, i.e. (eq. 5.4)
//!
//!   alpha = 1/2 + I_1 / (4 I_2).
//!
//! (Re-derived here: the extracted text of eq. 5.4 writes `pbar` garbled as `\bar{p}df`; the
//! derivation above reproduces it.) Both integrals are estimated from samples of the half-half
//! mixture `pbar` (eq. 5.5): `I_1 ~ mean (f / pbar)^2 dpdf / pbar`,
//! `I_2 ~ mean (f / pbar)^2 (dpdf / pbar)^2`; the common 1/M cancels in the ratio.
//!
//! The estimate is clamped to [`ALPHA_MIN`, `ALPHA_MAX`] = [0.025, 0.975], the interval the
//! thesis settles on (section 5.4.3). The thesis shows (section 5.3.4) that where one technique
//! is useless (a perfect mirror against a light, a Dirac light against a BSDF) the formula gives
//! 3/4 or 1/4, not 1 or 0; this module detects that case exactly (every sample with f != 0 had
//! the other technique's density zero) and puts alpha at the clamp.
//!
//! **Optimal weights.** Kondapaneni et al. show the variance-optimal weights make the
//! multi-sample estimator `F = sum_i a_i c_i + sum_samples (f - sum_k a_k p_k) / sum_k n_k p_k`
//! (a control variate on the balance heuristic), with `a` solving `A a = b`,
//! `A_ik = int p_i p_k / sum_j n_j p_j`, `b_i = int f p_i / sum_j n_j p_j`, and
//! `c_i = int p_i`. F is unbiased for any fixed `a`, so `a` estimated from independent
//! samples (the warm-up) keeps it unbiased. A sampler that sometimes fails (a Phong lobe below
//! the horizon) has `c_i < 1`; counting `a_i / n_i` for each sample it did return estimates
//! `a_i c_i` without knowing `c_i`.

use std::sync::{Mutex, RwLock};

use crate::math::{balance_heuristic, Rgb};

/// The clamp of alpha (thesis 001 section 5.4.3).
pub const ALPHA_MIN: f32 = 0.025;
pub const ALPHA_MAX: f32 = 0.975;

/// Running sums of eq. 5.5 over samples of the half-half mixture.
#[derive(Clone, Copy, Debug, Default)]
pub struct AlphaEstimate {
    /// Sum of (f / pbar)^2 dpdf / pbar (eq. 5.5, first line, times M).
    first: f64,
    /// Sum of (f / pbar)^2 (dpdf / pbar)^2 (eq. 5.5, second line, times M).
    second: f64,
    /// Samples with f != 0, and how many of them had the light's (BSDF's) density zero.
    nonzero: u32,
    light_zero: u32,
    bsdf_zero: u32,
}

impl AlphaEstimate {
    /// Adds one sample of the half-half mixture with weight `w` (1, or a fractional cube-face
    /// sample's share): `f` the (scalar) integrand there, and the two techniques' densities.
    /// Samples with f = 0 add nothing to either integral.
    #[inline]
    pub fn add(&mut self, w: f32, f: f32, pdf_bsdf: f32, pdf_light: f32) {
        let pbar = 0.5 * (pdf_bsdf as f64 + pdf_light as f64);
        if !(f != 0.0 && f.is_finite() && pbar > 0.0 && pbar.is_finite()) {
            return;
        }
        let r = 0.5 * (pdf_bsdf as f64 - pdf_light as f64) / pbar; // in [-1, 1]
        let g = w as f64 * (f as f64 / pbar).powi(2);
        if !g.is_finite() {
            return;
        }
        self.first += g * r;
        self.second += g * r * r;
        self.nonzero += 1;
        self.light_zero += (pdf_light == 0.0) as u32;
        self.bsdf_zero += (pdf_bsdf == 0.0) as u32;
    }

    /// Adds the sums of `other` (the same integrals from other samples).
    pub fn merge(&mut self, other: &AlphaEstimate) {
        self.first += other.first;
        self.second += other.second;
        self.nonzero += other.nonzero;
        self.light_zero += other.light_zero;
        self.bsdf_zero += other.bsdf_zero;
    }

    /// The fraction of BSDF samples, eq. 5.4 clamped; 1/2 (the balance heuristic's even split)
    /// when no sample saw the integrand or both techniques had the same density everywhere.
    pub fn alpha(&self) -> f32 {
        if self.nonzero == 0 {
            return 0.5;
        }
        if self.light_zero == self.nonzero {
            return ALPHA_MAX;
        }
        if self.bsdf_zero == self.nonzero {
            return ALPHA_MIN;
        }
        if !(self.second > 0.0) {
            return 0.5;
        }
        let alpha = 0.5 + self.first / (4.0 * self.second);
        (alpha as f32).clamp(ALPHA_MIN, ALPHA_MAX)
    }
}

/// Re-expands the second moment around the current alpha `steps` times (thesis 001 section
/// 5.6: "a second-order Taylor expansion around the previously estimated value alpha_i ... used
/// to estimate the next alpha_i+1"), starting from `alpha` (eq. 5.4's). With
/// `q0 = alpha0 pdf_B + (1 - alpha0) pdf_L` and `D = pdf_B - pdf_L`, the moment
/// `M(alpha) = int f^2 / q_alpha` has `M' = -int f^2 D / q0^2` and `M'' = 2 int f^2 D^2 / q0^3`
/// at alpha0, so its quadratic model is minimal at
/// `alpha0 + int f^2 D / q0^2 / (2 int f^2 D^2 / q0^3)` (a Newton step; from alpha0 = 1/2 it
/// is eq. 5.4 exactly). M is convex in alpha (f^2 / q is convex in q, q linear in alpha), so
/// the steps move toward the minimiser of the estimated exact moment rather than that of its
/// expansion around 1/2, which the thesis finds poor far from 1/2. Each step is clamped to
/// [`ALPHA_MIN`, `ALPHA_MAX`]; the steps stop early once alpha stops moving (at the clamp).
/// The integrals are estimated from the warm-up's samples of the half-half mixture `pbar`,
/// each divided by `pbar`: `samples` yields (weight, f, pdf_B, pdf_L) as [`AlphaEstimate::add`].
pub fn refine_alpha(
    alpha: f32,
    steps: u32,
    samples: impl Iterator<Item = (f32, f32, f32, f32)> + Clone,
) -> f32 {
    let mut alpha = alpha;
    for _ in 0..steps {
        match newton_step(alpha, samples.clone()) {
            Some(next) if next != alpha => alpha = next,
            _ => break,
        }
    }
    alpha
}

/// One step of [`refine_alpha`] from `alpha0`; `None` when no sample carries information
/// (then alpha stays).
fn newton_step(alpha0: f32, samples: impl Iterator<Item = (f32, f32, f32, f32)>) -> Option<f32> {
    newton_step_sampled(
        alpha0,
        samples.map(|(w, f, pb, pl)| (w, f, pb, pl, 0.5 * (pb as f64 + pl as f64))),
    )
}

/// [`newton_step`] from samples drawn with density `sampled` (the fifth item), each yielding
/// (weight, f, pdf_B, pdf_L, sampled).
fn newton_step_sampled(
    alpha0: f32,
    samples: impl Iterator<Item = (f32, f32, f32, f32, f64)>,
) -> Option<f32> {
    let a = alpha0 as f64;
    let (mut first, mut second) = (0.0f64, 0.0f64);
    for (w, f, pdf_bsdf, pdf_light, sampled) in samples {
        // Samples with f = 0 add nothing (most of them where a light is small or occluded).
        if f == 0.0 {
            continue;
        }
        let (pb, pl) = (pdf_bsdf as f64, pdf_light as f64);
        let q0 = a * pb + (1.0 - a) * pl;
        // f^2 D / q0^2 / sampled and f^2 D^2 / q0^3 / sampled with one division.
        let inv = 1.0 / (sampled * q0 * q0 * q0);
        let d = pb - pl;
        let h = w as f64 * (f as f64) * (f as f64) * d * inv;
        if !(h.is_finite() && q0 > 0.0) {
            continue;
        }
        first += h * q0;
        second += h * d;
    }
    if !(second > 0.0 && second.is_finite() && first.is_finite()) {
        return None;
    }
    let alpha = a + first / (2.0 * second);
    alpha
        .is_finite()
        .then(|| (alpha as f32).clamp(ALPHA_MIN, ALPHA_MAX))
}

/// **`path_skeleton`'s mixture.** At a guided node `path_skeleton` draws its direction from
/// the skeleton's lobes with probability c and from the BSDF otherwise, with the mixture's
/// density `q_c = c p_G + (1 - c) p_B` (one-sample MIS, `guide::mixture`): eq. 5.3 with the
/// guide in the BSDF's place and the BSDF in the light's, alpha = c. The sample's estimate is
/// `h / q_c`, `h` the integrand (f |cos| times the radiance the rest of the path brings, times
/// the throughput before the vertex: the sample's share of the pixel), so the second moment is
/// `int h^2 / q_c`, convex in c, and [`refine_alpha`]'s Newton steps apply, from samples drawn
/// with the density the render used there (`sampled`, the mixture at the node's trained c or
/// lower where `ratio_max` capped it). A [`MixtureSample`] is one such direction; the steps
/// start at the node's trained c and are clamped to [`ALPHA_MIN`, `c_max`] (the guide's own
/// bound on c, below [`ALPHA_MAX`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MixtureSample {
    /// The node the vertex mapped to.
    pub node: u32,
    /// The integrand h (luminance) of the direction: the sample's contribution times `sampled`.
    pub h: f32,
    /// The guide's and the BSDF's densities of the direction.
    pub pdf_guide: f32,
    pub pdf_bsdf: f32,
    /// The mixture density it was drawn with.
    pub sampled: f32,
}

/// Nodes need at least this many samples with h != 0 for their c to be re-estimated; fewer
/// keep the trained c (the estimate from a handful of samples is mostly noise).
pub const MIXTURE_MIN_SAMPLES: usize = 16;

/// The Newton steps of the mixture's c per node (see [`MixtureSample`]): `samples` sorted by
/// node, `c` the trained probabilities (only nodes with c > 0 change), `c_max` the largest c
/// allowed. Returns how many nodes changed. Deterministic: each node's sums run over its
/// samples in the given order.
pub fn refine_mixture(c: &mut [f32], samples: &[MixtureSample], steps: u32, c_max: f32) -> usize {
    let c_max = c_max.clamp(ALPHA_MIN, ALPHA_MAX);
    let mut changed = 0;
    for group in samples.chunk_by(|a, b| a.node == b.node) {
        let Some(c0) = c.get_mut(group[0].node as usize) else {
            continue;
        };
        if *c0 <= 0.0 || group.iter().filter(|s| s.h != 0.0).count() < MIXTURE_MIN_SAMPLES {
            continue;
        }
        let mut alpha = c0.clamp(ALPHA_MIN, c_max);
        for _ in 0..steps {
            let step = newton_step_sampled(
                alpha,
                group
                    .iter()
                    .map(|s| (1.0, s.h, s.pdf_guide, s.pdf_bsdf, s.sampled as f64)),
            )
            .map(|a| a.min(c_max));
            match step {
                Some(next) if next != alpha => alpha = next,
                _ => break,
            }
        }
        if alpha != *c0 {
            *c0 = alpha;
            changed += 1;
        }
    }
    changed
}

/// Splits `total` samples into (light, BSDF) counts with a fraction `alpha` (rounded) from the
/// BSDF, keeping at least one of each when `total >= 2` so both densities stay in the weights.
pub fn split(total: u32, alpha: f32) -> (u32, u32) {
    if total < 2 {
        return (total, 0);
    }
    let bsdf = ((alpha * total as f32).round() as u32).clamp(1, total - 1);
    (total - bsdf, bsdf)
}

/// **`path`'s adaptation.** `path` draws at every non-delta vertex one BSDF direction (which it
/// needs anyway to continue the path: a free sample) and one light sample (which costs a
/// shadow ray). Its balance heuristic is the estimator of eq. 5.3 with counts (n_L, n_B) =
/// (1, 1), alpha = 1/2. With `mis=auto` the light sample is taken with probability
/// `pi` = min(1, (1 - alpha) / alpha) (expected counts (pi, 1)) and both samples are weighed
/// by the balance heuristic over the expected counts, q = pi pdf_L + pdf_B: the light sample,
/// when taken, contributes f / q, the BSDF direction f / q where it finds an emitter. The
/// expectation is pi int f pdf_L / q + int f pdf_B / q = int f for any pi in (0, 1], so the
/// estimator is unbiased, and at pi = 1 it is `mis=balance` exactly. For alpha >= 1/2 this is
/// the thesis's split, alpha = n_B / (n_L + n_B) = 1 / (1 + pi), with shadow rays saved where
/// BSDF sampling does better. For alpha < 1/2 the split would need more than one light
/// sample per vertex; `path` keeps one (pi = 1, the even split): more shadow rays per vertex
/// are a different cost than the thesis's fixed sample budget.
///
/// alpha is estimated per pixel (eq. 5.5) from the first `warmup` samples of the pixel, which
/// are `mis=balance` samples: each vertex's light sample and BSDF direction are one sample of
/// each technique, the half-half mixture eq. 5.5 needs. The integrand of a vertex is scaled by
/// the path throughput before it (its share of the pixel's variance). Vertices at depth 0 and
/// deeper ones keep separate estimates. The later samples use the frozen alpha: each sample is
/// unbiased given the earlier ones, so the pixel's mean (the count-weighted combination of
/// eq. 5.6) is unbiased. A light sample from a delta light counts as a sample the BSDF cannot
/// draw (pdf_B = 0), so a scene lit by point lights only keeps alpha at the lower clamp and
/// renders exactly as `mis=balance`.
pub const DEPTH_CLASSES: usize = 2;

/// The probability of taking the light sample at a vertex for the thesis's `alpha`
/// (see [`DEPTH_CLASSES`]): (1 - alpha) / alpha light samples per BSDF sample, at most one.
pub fn light_sample_probability(alpha: f32) -> f32 {
    if alpha > 0.5 {
        ((1.0 - alpha) / alpha).min(1.0)
    } else {
        1.0
    }
}

/// One pixel sample's `mis=auto` state in `path` (see [`DEPTH_CLASSES`]).
#[derive(Clone, Copy, Debug)]
pub struct VertexAlphas {
    /// alpha per depth class (0.5 during the warm-up).
    alpha: [f32; DEPTH_CLASSES],
    /// The light-sample probability per depth class.
    light_probability: [f32; DEPTH_CLASSES],
    /// During the warm-up: this sample's contribution to the pixel's estimates.
    warmup: Option<[AlphaEstimate; DEPTH_CLASSES]>,
    /// False for the other heuristics: the caller's own weights, no light sample skipped.
    active: bool,
}

impl VertexAlphas {
    /// Not `mis=auto`: every light sample taken, nothing recorded.
    pub const OFF: VertexAlphas = VertexAlphas {
        alpha: [0.5; DEPTH_CLASSES],
        light_probability: [1.0; DEPTH_CLASSES],
        warmup: None,
        active: false,
    };

    pub fn is_active(&self) -> bool {
        self.active
    }

    fn class(depth: u32) -> usize {
        (depth as usize).min(DEPTH_CLASSES - 1)
    }

    /// The alpha used at vertices of depth `depth`.
    pub fn alpha(&self, depth: u32) -> f32 {
        self.alpha[Self::class(depth)]
    }

    /// The probability of taking the light sample at a vertex of depth `depth`.
    pub fn light_probability(&self, depth: u32) -> f32 {
        self.light_probability[Self::class(depth)]
    }

    /// Records, during the warm-up, one sample of the vertex at depth `depth`: `f` the
    /// integrand (scaled by the throughput), and both densities.
    #[inline]
    pub fn record(&mut self, depth: u32, f: Rgb, pdf_bsdf: f32, pdf_light: f32) {
        if let Some(estimates) = &mut self.warmup {
            estimates[Self::class(depth)].add(1.0, crate::math::luminance(f), pdf_bsdf, pdf_light);
        }
    }

    /// The MIS weight of a light sample of density `pdf_light`, taken with probability `pi`,
    /// against direction density `pdf_direction`, including the 1 / pi of having taken it:
    /// pdf_L / (pi pdf_L + pdf_B).
    #[inline]
    pub fn light_weight(pi: f32, pdf_light: f32, pdf_direction: f32) -> f32 {
        balance_heuristic(pi * pdf_light, pdf_direction) / pi
    }

    /// The MIS weight of a sampled direction of density `pdf_direction` that found an emitter
    /// light sampling draws with density `pdf_light` with probability `pi`.
    #[inline]
    pub fn direction_weight(pi: f32, pdf_direction: f32, pdf_light: f32) -> f32 {
        balance_heuristic(pdf_direction, pi * pdf_light)
    }
}

/// `path`'s per-pixel alpha estimates (see [`DEPTH_CLASSES`]), shared by the render's threads:
/// a pixel's samples run in order on one thread at a time, so its state depends only on the
/// pixel's earlier samples, whatever the thread count or the split into passes. Sample 0 of a
/// pixel resets it, so every render starts afresh.
#[derive(Debug, Default)]
pub struct PixelAlphas {
    pixels: RwLock<Vec<Mutex<[AlphaEstimate; DEPTH_CLASSES]>>>,
}

impl PixelAlphas {
    /// Bytes per pixel of the state.
    pub const BYTES_PER_PIXEL: usize = std::mem::size_of::<Mutex<[AlphaEstimate; DEPTH_CLASSES]>>();

    /// The state for sample `sample_index` of pixel `pixel` of an image of `pixel_count`
    /// pixels: a warm-up sample (balance, recording) for the first `warmup` samples, then the
    /// estimated alphas.
    pub fn begin(
        &self,
        pixel_count: usize,
        pixel: usize,
        sample_index: u32,
        warmup: u32,
    ) -> VertexAlphas {
        if self.pixels.read().map_or(true, |p| p.len() != pixel_count) {
            let mut pixels = self.pixels.write().unwrap_or_else(|e| e.into_inner());
            if pixels.len() != pixel_count {
                pixels.clear();
                pixels.resize_with(pixel_count, Default::default);
            }
        }
        let pixels = self.pixels.read().unwrap_or_else(|e| e.into_inner());
        let Some(cell) = pixels.get(pixel) else {
            return VertexAlphas::OFF;
        };
        let mut state = cell.lock().unwrap_or_else(|e| e.into_inner());
        if sample_index == 0 {
            *state = Default::default();
        }
        if sample_index < warmup {
            return VertexAlphas {
                warmup: Some(Default::default()),
                active: true,
                ..VertexAlphas::OFF
            };
        }
        let alpha = state.map(|e| e.alpha());
        VertexAlphas {
            alpha,
            light_probability: alpha.map(light_sample_probability),
            warmup: None,
            active: true,
        }
    }

    /// Adds a warm-up sample's records to its pixel's estimates.
    pub fn finish(&self, pixel: usize, sample: &VertexAlphas) {
        let Some(recorded) = &sample.warmup else {
            return;
        };
        let pixels = self.pixels.read().unwrap_or_else(|e| e.into_inner());
        if let Some(cell) = pixels.get(pixel) {
            let mut state = cell.lock().unwrap_or_else(|e| e.into_inner());
            for (s, r) in state.iter_mut().zip(recorded) {
                s.merge(r);
            }
        }
    }
}

/// Kondapaneni et al.'s linear system for two techniques (light, BSDF), estimated from
/// weighted samples of the balance heuristic with counts (n_light, n_bsdf).
#[derive(Clone, Copy, Debug, Default)]
pub struct OptimalSystem {
    /// A_LL, A_LB, A_BB.
    a: [f64; 3],
    /// b_L, b_B per colour channel.
    b: [[f64; 3]; 2],
}

/// The control-variate coefficients `a` of the optimal estimator, per colour channel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OptimalCoefficients {
    pub light: Rgb,
    pub bsdf: Rgb,
}

impl OptimalSystem {
    /// Adds a sample with weight `w` (a fractional cube-face sample's share) and value `f`;
    /// `mixture = n_light pdf_light + n_bsdf pdf_bsdf` of the warm-up's counts. Every sample
    /// drawn counts, f = 0 included: A integrates densities, not the integrand.
    #[inline]
    pub fn add(&mut self, w: f32, f: Rgb, pdf_light: f32, pdf_bsdf: f32, mixture: f32) {
        if !(mixture > 0.0 && mixture.is_finite()) {
            return;
        }
        let s = w as f64 / (mixture as f64 * mixture as f64);
        let (pl, pb) = (pdf_light as f64, pdf_bsdf as f64);
        if !(s * pl * pl).is_finite() || !(s * pb * pb).is_finite() {
            return;
        }
        self.a[0] += s * pl * pl;
        self.a[1] += s * pl * pb;
        self.a[2] += s * pb * pb;
        for (c, v) in [f.x, f.y, f.z].into_iter().enumerate() {
            self.b[0][c] += s * v as f64 * pl;
            self.b[1][c] += s * v as f64 * pb;
        }
    }

    /// Solves A a = b; zero coefficients (the balance heuristic) when A is near singular (one
    /// technique never sampled anything the other could, or both densities are equal).
    pub fn solve(&self) -> OptimalCoefficients {
        let [all, alb, abb] = self.a;
        let det = all * abb - alb * alb;
        let scale = (all + abb).powi(2);
        if !(det > 1e-6 * scale) || !det.is_finite() {
            return OptimalCoefficients::default();
        }
        let mut light = [0.0f32; 3];
        let mut bsdf = [0.0f32; 3];
        for c in 0..3 {
            let (bl, bb) = (self.b[0][c], self.b[1][c]);
            let l = (abb * bl - alb * bb) / det;
            let b = (all * bb - alb * bl) / det;
            if l.is_finite() && b.is_finite() {
                light[c] = l as f32;
                bsdf[c] = b as f32;
            }
        }
        OptimalCoefficients {
            light: Rgb::new(light[0], light[1], light[2]),
            bsdf: Rgb::new(bsdf[0], bsdf[1], bsdf[2]),
        }
    }
}

/// One sample's term of the optimal estimator with counts (n_light, n_bsdf): its share of
/// `a_i c_i` plus its control-variate-corrected balance term.
#[inline]
pub fn optimal_term(
    a: &OptimalCoefficients,
    from_bsdf: bool,
    counts: (f32, f32),
    f: Rgb,
    pdf_light: f32,
    pdf_bsdf: f32,
) -> Rgb {
    let (n_light, n_bsdf) = counts;
    let own = if from_bsdf {
        a.bsdf / n_bsdf
    } else {
        a.light / n_light
    };
    let mixture = n_light * pdf_light + n_bsdf * pdf_bsdf;
    if !(mixture > 0.0 && mixture.is_finite()) {
        return own;
    }
    own + (f - a.light * pdf_light - a.bsdf * pdf_bsdf) / mixture
}

/// The thesis's colour for a pixel's alpha (Figure 5.7): red where light samples dominate,
/// green where BSDF samples do, yellow for the even split; black where `coverage` (the
/// fraction of samples that shaded a point) is zero. `sum` is the alpha layer's R (alpha
/// times coverage).
pub fn alpha_false_colour(sum: f32, coverage: f32) -> Rgb {
    if !(coverage > 0.0) {
        return Rgb::ZERO;
    }
    let alpha = (sum / coverage).clamp(0.0, 1.0);
    let light = 1.0 - alpha;
    let m = light.max(alpha);
    Rgb::new(light / m, alpha / m, 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    /// The second moment (up to a constant) of estimating int_0^1 x^k with the densities
    /// 2x and 2(1 - x) mixed at `alpha`: int x^2k / (alpha 2x + (1 - alpha) 2(1 - x)),
    /// by the midpoint rule.
    fn ramp_moment(k: i32, alpha: f64) -> f64 {
        let n = 20000;
        (0..n)
            .map(|i| {
                let x = (i as f64 + 0.5) / n as f64;
                x.powi(2 * k) / (alpha * 2.0 * x + (1.0 - alpha) * 2.0 * (1.0 - x))
            })
            .sum::<f64>()
    }

    /// The minimiser of [`ramp_moment`] over alpha in [0.025, 0.975], by a fine search.
    fn ramp_minimiser(k: i32) -> f64 {
        (25..=975)
            .map(|i| i as f64 / 1000.0)
            .min_by(|a, b| ramp_moment(k, *a).total_cmp(&ramp_moment(k, *b)))
            .unwrap()
    }

    /// pdf_B(x) = 2x, pdf_L(x) = 2(1 - x) on [0, 1], f(x) = x^k: pbar = 1, dpdf = 2x - 1, so
    /// I_1 = int x^2k (2x - 1) and I_2 = int x^2k (2x - 1)^2 in closed form.
    fn closed_form_alpha(k: i32) -> f64 {
        let m = (2 * k) as f64;
        let i1 = 2.0 / (m + 2.0) - 1.0 / (m + 1.0);
        let i2 = 4.0 / (m + 3.0) - 4.0 / (m + 2.0) + 1.0 / (m + 1.0);
        (0.5 + i1 / (4.0 * i2)).clamp(ALPHA_MIN as f64, ALPHA_MAX as f64)
    }

    fn estimate(k: i32, m: u32, seed: u64) -> f32 {
        let mut rng = Rng::new(seed, 0);
        let mut est = AlphaEstimate::default();
        for i in 0..m {
            let u = rng.uniform().sqrt();
            // Half the samples from pdf_B (x = sqrt(u)), half from pdf_L (x = 1 - sqrt(u)).
            let x = if i % 2 == 0 { u } else { 1.0 - u };
            est.add(1.0, x.powi(k), 2.0 * x, 2.0 * (1.0 - x));
        }
        est.alpha()
    }

    #[test]
    fn alpha_estimate_converges_to_closed_form() {
        for k in [0, 1, 2] {
            let exact = closed_form_alpha(k);
            let mut previous_error = f64::INFINITY;
            for m in [256u32, 4096, 65536] {
                // The mean absolute error over a few seeds shrinks with M.
                let error: f64 = (0..8)
                    .map(|s| (estimate(k, m, 100 + s) as f64 - exact).abs())
                    .sum::<f64>()
                    / 8.0;
                assert!(
                    error < previous_error.max(1e-3),
                    "k={k} M={m}: error {error} after {previous_error}"
                );
                previous_error = error;
            }
            assert!(
                previous_error < 0.01,
                "k={k}: {previous_error} from {exact}"
            );
        }
        // f = 1: by symmetry the even split; f = x: 13/16 (I_1 = 1/6, I_2 = 2/15).
        assert!((closed_form_alpha(0) - 0.5).abs() < 1e-12);
        assert!((closed_form_alpha(1) - 0.8125).abs() < 1e-12);
    }

    /// The second-order alpha points the same way as the exact minimiser of the second
    /// moment int f^2 / q_alpha (found by a fine search), and lowers the moment below the even
    /// split's.
    #[test]
    fn second_order_alpha_reduces_the_exact_second_moment() {
        for k in [1, 2, 3] {
            let moment = |alpha: f64| {
                let n = 20000;
                (0..n)
                    .map(|i| {
                        let x = (i as f64 + 0.5) / n as f64;
                        let q = alpha * 2.0 * x + (1.0 - alpha) * 2.0 * (1.0 - x);
                        x.powi(2 * k) / q / n as f64
                    })
                    .sum::<f64>()
            };
            let alpha = closed_form_alpha(k);
            let best = (1..1000)
                .map(|i| i as f64 / 1000.0)
                .min_by(|a, b| moment(*a).total_cmp(&moment(*b)))
                .unwrap();
            assert!(best > 0.5 && alpha > 0.5, "k={k}: {alpha} vs {best}");
            assert!(moment(alpha) < moment(0.5), "k={k}");
        }
    }

    /// The first Newton step from 1/2 is eq. 5.4 on the same samples; repeated steps reach
    /// the exact minimiser of the second moment (fine search) on pdf_B = 2x, pdf_L = 2(1 - x),
    /// f = x^k, where eq. 5.4 alone stops short of it.
    #[test]
    fn newton_steps_start_at_eq_5_4_and_reach_the_exact_minimiser() {
        for k in [1, 2, 3] {
            let mut rng = Rng::new(11 + k as u64, 0);
            let samples: Vec<(f32, f32, f32, f32)> = (0..200_000)
                .map(|i| {
                    let u = rng.uniform().sqrt();
                    let x = if i % 2 == 0 { u } else { 1.0 - u };
                    (1.0, x.powi(k), 2.0 * x, 2.0 * (1.0 - x))
                })
                .collect();
            let mut est = AlphaEstimate::default();
            for &(w, f, pb, pl) in &samples {
                est.add(w, f, pb, pl);
            }
            let first = refine_alpha(0.5, 1, samples.iter().copied());
            assert!(
                (first - est.alpha()).abs() < 1e-5,
                "k={k}: {first} vs {}",
                est.alpha()
            );
            assert_eq!(refine_alpha(first, 0, samples.iter().copied()), first);
            let alpha = refine_alpha(first, 8, samples.iter().copied());
            let moment = |alpha: f64| ramp_moment(k, alpha);
            let best = ramp_minimiser(k);
            assert!(
                (alpha as f64 - best).abs() < 0.01,
                "k={k}: {alpha} vs {best}"
            );
            assert!(
                moment(alpha as f64) <= moment(first as f64) * (1.0 + 1e-9),
                "k={k}"
            );
        }
        assert_eq!(refine_alpha(0.3, 4, std::iter::empty()), 0.3);
        assert_eq!(
            refine_alpha(0.3, 4, [(1.0, 0.0, 1.0, 2.0)].into_iter()),
            0.3
        );
    }

    /// `path_skeleton`'s mixture: samples drawn from the mixture at c = 0.3 (not the even
    /// split) of pdf_G = 2x and pdf_B = 2(1 - x), integrand h = x^k: the steps reach the exact
    /// minimiser of int h^2 / q_c (fine search) from the trained c, per node; a node with c = 0,
    /// one with too few samples, and samples with zero or infinite densities change nothing
    /// and give no NaN.
    #[test]
    fn mixture_steps_reach_the_exact_minimiser_from_the_sampled_c() {
        let c_s = 0.3f32;
        let mut rng = Rng::new(5, 0);
        let mut samples = Vec::new();
        for (node, k) in [(0u32, 1), (2, 3)] {
            for _ in 0..100_000 {
                let u = rng.uniform().sqrt();
                let x = if rng.uniform() < c_s { u } else { 1.0 - u };
                let (pg, pb) = (2.0 * x, 2.0 * (1.0 - x));
                samples.push(MixtureSample {
                    node,
                    h: x.powi(k),
                    pdf_guide: pg,
                    pdf_bsdf: pb,
                    sampled: c_s * pg + (1.0 - c_s) * pb,
                });
            }
        }
        // Node 3: c = 0 (not guided); node 4: too few samples; node 5: degenerate densities.
        for i in 0..MIXTURE_MIN_SAMPLES + 4 {
            let node = if i < 4 { 4 } else { 3 };
            samples.push(MixtureSample {
                node,
                h: 1.0,
                pdf_guide: 1.0,
                pdf_bsdf: 3.0,
                sampled: 2.0,
            });
        }
        for (pg, pb, q) in [(0.0, 0.0, 0.0), (f32::INFINITY, 1.0, 1.0), (1.0, 1.0, 1.0)] {
            for _ in 0..MIXTURE_MIN_SAMPLES {
                samples.push(MixtureSample {
                    node: 5,
                    h: 1.0,
                    pdf_guide: pg,
                    pdf_bsdf: pb,
                    sampled: q,
                });
            }
        }
        samples.sort_by_key(|s| s.node);
        let mut c = vec![c_s, 0.5, c_s, 0.0, 0.4, 0.6];
        let changed = refine_mixture(&mut c, &samples, 8, ALPHA_MAX);
        assert_eq!(changed, 2, "{c:?}");
        assert_eq!([c[1], c[3], c[4], c[5]], [0.5, 0.0, 0.4, 0.6]);
        let mut c2 = vec![c_s, 0.5, c_s, 0.0, 0.4, 0.6];
        refine_mixture(&mut c2, &samples, 8, ALPHA_MAX);
        assert_eq!(c, c2, "deterministic");
        for (node, k) in [(0usize, 1), (2, 3)] {
            let moment = |c: f64| ramp_moment(k, c);
            let best = ramp_minimiser(k);
            let got = c[node];
            assert!((got as f64 - best).abs() < 0.02, "k={k}: {got} vs {best}");
            assert!(moment(got as f64) < moment(c_s as f64), "k={k}");
        }
    }

    #[test]
    fn useless_technique_puts_alpha_at_the_clamp() {
        let mut mirror = AlphaEstimate::default();
        mirror.add(1.0, 3.0, 50.0, 0.0);
        mirror.add(1.0, 0.0, 1.0, 2.0); // f = 0: ignored
        mirror.add(1.0, 1.0, 20.0, 0.0);
        assert_eq!(mirror.alpha(), ALPHA_MAX);
        let mut delta = AlphaEstimate::default();
        delta.add(1.0, 3.0, 0.0, 5.0);
        assert_eq!(delta.alpha(), ALPHA_MIN);
        assert_eq!(AlphaEstimate::default().alpha(), 0.5);
    }

    #[test]
    fn zero_and_non_finite_densities_give_no_nan() {
        let mut est = AlphaEstimate::default();
        est.add(1.0, 1.0, 0.0, 0.0);
        est.add(1.0, f32::NAN, 1.0, 1.0);
        est.add(1.0, 1.0, f32::INFINITY, 1.0);
        est.add(1.0, 1.0, 1.0, 1.0); // equal densities: dpdf = 0, I_2 = 0
        assert_eq!(est.alpha(), 0.5);
        let mut sys = OptimalSystem::default();
        sys.add(1.0, Rgb::ONE, 0.0, 0.0, 0.0);
        sys.add(1.0, Rgb::ONE, 1.0, 0.0, 1.0);
        let a = sys.solve(); // singular: one technique only
        assert_eq!(a, OptimalCoefficients::default());
        let t = optimal_term(&a, true, (1.0, 1.0), Rgb::ONE, 0.0, 0.0);
        assert!(crate::math::is_finite3(t));
    }

    /// `path`'s weights with the light sample taken with probability pi: pi w_L + w_B = 1
    /// wherever both techniques can draw the point (so the estimate is unbiased), each
    /// weight alone is right where the other density is zero, and no weight is NaN for zero
    /// or infinite densities.
    #[test]
    fn one_sample_weights_sum_to_one_and_stay_finite() {
        for alpha in [0.3f32, 0.5, 0.6, 0.9, ALPHA_MAX] {
            let pi = light_sample_probability(alpha);
            assert!(pi > 0.0 && pi <= 1.0);
            if alpha > 0.5 {
                assert!((1.0 / (1.0 + pi) - alpha).abs() < 1e-6, "alpha {alpha}");
            }
            for (pl, pb) in [(1.0f32, 1.0f32), (0.01, 40.0), (300.0, 0.2), (1e-30, 1e30)] {
                let sum = pi * VertexAlphas::light_weight(pi, pl, pb)
                    + VertexAlphas::direction_weight(pi, pb, pl);
                assert!((sum - 1.0).abs() < 1e-5, "alpha {alpha}: {pl} {pb}: {sum}");
            }
            assert!((pi * VertexAlphas::light_weight(pi, 2.0, 0.0) - 1.0).abs() < 1e-6);
            assert_eq!(VertexAlphas::direction_weight(pi, 2.0, 0.0), 1.0);
            for (a, b) in [(0.0, 0.0), (f32::INFINITY, 1.0), (1.0, f32::INFINITY)] {
                assert!(VertexAlphas::light_weight(pi, a, b).is_finite());
                assert!(VertexAlphas::direction_weight(pi, a, b).is_finite());
            }
        }
        assert_eq!(light_sample_probability(ALPHA_MIN), 1.0);
    }

    #[test]
    fn split_keeps_both_techniques() {
        assert_eq!(split(30, 0.5), (15, 15));
        assert_eq!(split(30, 0.975), (1, 29));
        assert_eq!(split(30, 0.025), (29, 1));
        assert_eq!(split(1, 0.9), (1, 0));
    }

    /// The optimal estimator on pdf_B = 2x, pdf_L = 2(1 - x), f = x^2 (integral 1/3): unbiased
    /// with the coefficients from an independent warm-up, and of lower variance than the
    /// balance heuristic.
    #[test]
    fn optimal_estimator_is_unbiased_and_beats_balance() {
        let mut rng = Rng::new(7, 0);
        let mut draw = |from_bsdf: bool| {
            let u = rng.uniform().sqrt();
            if from_bsdf {
                u
            } else {
                1.0 - u
            }
        };
        let (trials, n) = (4000, 4);
        let (mut opt, mut bal) = (Vec::new(), Vec::new());
        for _ in 0..trials {
            let mut sys = OptimalSystem::default();
            for i in 0..2 * n {
                let x = draw(i % 2 == 0);
                let (pb, pl) = (2.0 * x, 2.0 * (1.0 - x));
                sys.add(1.0, Rgb::splat(x * x), pl, pb, n as f32 * (pl + pb));
            }
            let a = sys.solve();
            let (mut o, mut b) = (0.0, 0.0);
            for i in 0..2 * n {
                let from_bsdf = i % 2 == 0;
                let x = draw(from_bsdf);
                let (pb, pl) = (2.0 * x, 2.0 * (1.0 - x));
                let f = Rgb::splat(x * x);
                o += optimal_term(&a, from_bsdf, (n as f32, n as f32), f, pl, pb).x as f64;
                b += (x * x / (n as f32 * (pl + pb))) as f64;
            }
            opt.push(o);
            bal.push(b);
        }
        let stats = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64;
            (m, var)
        };
        let ((mo, vo), (mb, vb)) = (stats(&opt), stats(&bal));
        let z = |m: f64, v: f64| (m - 1.0 / 3.0) / (v / trials as f64).sqrt();
        assert!(z(mo, vo).abs() < 4.0, "optimal mean {mo}, z {}", z(mo, vo));
        assert!(z(mb, vb).abs() < 4.0, "balance mean {mb}");
        assert!(vo < vb, "optimal variance {vo} vs balance {vb}");
    }
}
