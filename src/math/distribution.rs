//! Discrete and piecewise-constant distributions: light selection (alias table), environment
//! maps and textures (1-D and 2-D piecewise-constant).

use glam::Vec2;

/// The largest f32 below 1.
const ONE_MINUS_EPSILON: f32 = 1.0 - f32::EPSILON / 2.0;

/// Walker/Vose alias table: O(1) sampling of a discrete distribution, used for picking a light
/// proportionally to its power.
#[derive(Clone, Debug, Default)]
pub struct AliasTable {
    /// Per bin: probability of keeping the bin, and the alias taken otherwise.
    bins: Vec<(f32, u32)>,
    pmf: Vec<f32>,
}

impl AliasTable {
    /// Builds the table from non-negative weights. Returns `None` when no weight is positive
    /// or a weight is negative or not finite.
    pub fn new(weights: &[f32]) -> Option<Self> {
        if weights.iter().any(|w| !w.is_finite() || *w < 0.0) {
            return None;
        }
        let total: f64 = weights.iter().map(|&w| w as f64).sum();
        if total <= 0.0 {
            return None;
        }
        let n = weights.len();
        let pmf: Vec<f32> = weights.iter().map(|&w| (w as f64 / total) as f32).collect();
        let mut scaled: Vec<f64> = weights
            .iter()
            .map(|&w| w as f64 / total * n as f64)
            .collect();
        let mut bins = vec![(1.0f32, 0u32); n];
        let (mut small, mut large): (Vec<usize>, Vec<usize>) =
            (0..n).partition(|&i| scaled[i] < 1.0);
        while let (Some(s), Some(&l)) = (small.pop(), large.last()) {
            bins[s] = (scaled[s] as f32, l as u32);
            scaled[l] -= 1.0 - scaled[s];
            if scaled[l] < 1.0 {
                large.pop();
                small.push(l);
            }
        }
        for i in large.into_iter().chain(small) {
            bins[i] = (1.0, i as u32);
        }
        Some(AliasTable { bins, pmf })
    }

    pub fn len(&self) -> usize {
        self.pmf.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pmf.is_empty()
    }

    /// Picks an index with one uniform number in [0, 1).
    #[inline]
    pub fn sample(&self, u: f32) -> usize {
        let n = self.bins.len();
        let x = u * n as f32;
        let i = (x as usize).min(n - 1);
        let frac = x - i as f32;
        let (keep, alias) = self.bins[i];
        if frac < keep {
            i
        } else {
            alias as usize
        }
    }

    /// Like [`sample`](Self::sample), and also returns `u` rescaled to a uniform number in
    /// [0, 1) within the part of [0, 1) that chose the index (the bin's kept or aliased
    /// fraction), so one coordinate of a stratified 2-D point can pick the index and then
    /// still serve, stretched, as that coordinate of the chosen item's 2-D sample (Mitsuba's
    /// `sample_reuse`). Same choices and pmf as `sample`; the rescaled number has
    /// log2(len) fewer significant bits than `u`.
    #[inline]
    pub fn sample_reuse(&self, u: f32) -> (usize, f32) {
        let n = self.bins.len();
        let x = u * n as f32;
        let i = (x as usize).min(n - 1);
        let frac = x - i as f32;
        let (keep, alias) = self.bins[i];
        // A bin kept whole (keep 1) is its own alias; testing it here avoids 0 / 0 when
        // rounding gives frac = 1.
        let (index, rescaled) = if frac < keep || keep >= 1.0 {
            (i, frac / keep)
        } else {
            (alias as usize, (frac - keep) / (1.0 - keep))
        };
        // Rounding may land exactly on 1 (or, with u in [1 - 2^-24, 1), just above).
        (index, rescaled.clamp(0.0, ONE_MINUS_EPSILON))
    }

    #[inline]
    pub fn pmf(&self, index: usize) -> f32 {
        self.pmf[index]
    }

    pub fn memory_bytes(&self) -> usize {
        self.bins.len() * std::mem::size_of::<(f32, u32)>() + self.pmf.len() * 4
    }
}

/// Piecewise-constant 1-D distribution on [0, 1) with `n` equal cells.
#[derive(Clone, Debug)]
pub struct Distribution1D {
    func: Vec<f32>,
    cdf: Vec<f32>,
    integral: f32,
}

impl Distribution1D {
    /// Negative or non-finite values are treated as zero; an all-zero function becomes uniform
    /// so that sampling stays defined (its `integral()` is then 0, which callers can test).
    pub fn new(values: &[f32]) -> Self {
        assert!(!values.is_empty());
        let mut d = Distribution1D {
            func: Vec::with_capacity(values.len()),
            cdf: Vec::with_capacity(values.len() + 1),
            integral: 0.0,
        };
        d.rebuild(values);
        d
    }

    /// Rebuilds the distribution from new values in place, reusing its memory when the
    /// length is unchanged (environment maps that change every frame).
    pub fn rebuild(&mut self, values: &[f32]) {
        assert!(!values.is_empty());
        let n = values.len();
        self.func.clear();
        self.func.extend(
            values
                .iter()
                .map(|&v| if v.is_finite() && v > 0.0 { v } else { 0.0 }),
        );
        self.cdf.clear();
        self.cdf.resize(n + 1, 0.0);
        let mut acc = 0.0f64;
        for i in 0..n {
            acc += self.func[i] as f64 / n as f64;
            self.cdf[i + 1] = acc as f32;
        }
        let integral = acc as f32;
        if integral > 0.0 {
            let inv = 1.0 / acc;
            let mut acc = 0.0f64;
            for i in 0..n {
                acc += self.func[i] as f64 / n as f64;
                self.cdf[i + 1] = (acc * inv) as f32;
            }
        } else {
            for (i, c) in self.cdf.iter_mut().enumerate() {
                *c = i as f32 / n as f32;
            }
        }
        self.cdf[n] = 1.0;
        self.integral = integral;
    }

    pub fn len(&self) -> usize {
        self.func.len()
    }

    pub fn is_empty(&self) -> bool {
        self.func.is_empty()
    }

    pub fn integral(&self) -> f32 {
        self.integral
    }

    /// Continuous sample in [0, 1) with its density and the cell index.
    pub fn sample_continuous(&self, u: f32) -> (f32, f32, usize) {
        let n = self.func.len();
        // Largest i with cdf[i] <= u.
        let i = self
            .cdf
            .partition_point(|&c| c <= u)
            .saturating_sub(1)
            .min(n - 1);
        let width = self.cdf[i + 1] - self.cdf[i];
        let du = if width > 0.0 {
            ((u - self.cdf[i]) / width).clamp(0.0, 1.0)
        } else {
            0.5
        };
        let x = ((i as f32 + du) / n as f32).min(1.0 - f32::EPSILON);
        (x, self.pdf_cell(i), i)
    }

    /// Density (with respect to [0, 1)) of cell `i`.
    #[inline]
    pub fn pdf_cell(&self, i: usize) -> f32 {
        if self.integral > 0.0 {
            self.func[i] / self.integral
        } else {
            1.0
        }
    }

    pub fn pdf(&self, x: f32) -> f32 {
        let i = ((x * self.func.len() as f32) as usize).min(self.func.len() - 1);
        self.pdf_cell(i)
    }

    /// Probability of cell `i` when sampling discretely.
    pub fn pmf(&self, i: usize) -> f32 {
        self.cdf[i + 1] - self.cdf[i]
    }
}

/// Piecewise-constant 2-D distribution on [0, 1)^2 (marginal over rows, conditional per row).
#[derive(Clone, Debug)]
pub struct Distribution2D {
    conditional: Vec<Distribution1D>,
    marginal: Distribution1D,
}

impl Distribution2D {
    /// `values` is row-major with `width` columns and `height` rows; v indexes rows.
    pub fn new(values: &[f32], width: usize, height: usize) -> Self {
        assert_eq!(values.len(), width * height);
        let conditional: Vec<Distribution1D> =
            values.chunks(width).map(Distribution1D::new).collect();
        let marginal_values: Vec<f32> = conditional.iter().map(|d| d.integral()).collect();
        Distribution2D {
            marginal: Distribution1D::new(&marginal_values),
            conditional,
        }
    }

    pub fn integral(&self) -> f32 {
        self.marginal.integral()
    }

    /// Rebuilds the distribution in place from values of the same size (no allocation).
    pub fn rebuild(&mut self, values: &[f32]) {
        let (width, height) = (self.conditional[0].len(), self.conditional.len());
        assert_eq!(values.len(), width * height);
        let mut marginal_values = Vec::with_capacity(height);
        for (row, d) in values.chunks(width).zip(self.conditional.iter_mut()) {
            d.rebuild(row);
            marginal_values.push(d.integral());
        }
        self.marginal.rebuild(&marginal_values);
    }

    /// Returns (u, v) in [0, 1)^2 and its density.
    pub fn sample(&self, u: Vec2) -> (Vec2, f32) {
        let (v, pdf_v, row) = self.marginal.sample_continuous(u.y);
        let (x, pdf_u, _) = self.conditional[row].sample_continuous(u.x);
        (Vec2::new(x, v), pdf_v * pdf_u)
    }

    pub fn pdf(&self, p: Vec2) -> f32 {
        let h = self.conditional.len();
        let row = ((p.y * h as f32) as usize).min(h - 1);
        self.marginal.pdf_cell(row) * self.conditional[row].pdf(p.x)
    }

    pub fn memory_bytes(&self) -> usize {
        let one = |d: &Distribution1D| (d.func.len() + d.cdf.len()) * 4;
        self.conditional.iter().map(one).sum::<usize>() + one(&self.marginal)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    #[test]
    fn alias_table_frequencies_match_pmf() {
        let weights = [1.0, 0.0, 3.0, 6.0, 0.5];
        let table = AliasTable::new(&weights).unwrap();
        let mut rng = Rng::new(1, 2);
        let n = 1_000_000;
        let mut counts = [0usize; 5];
        for _ in 0..n {
            counts[table.sample(rng.uniform())] += 1;
        }
        let total: f32 = weights.iter().sum();
        for i in 0..5 {
            let p = weights[i] / total;
            assert!((table.pmf(i) - p).abs() < 1e-6);
            let f = counts[i] as f32 / n as f32;
            let sigma = (p * (1.0 - p) / n as f32).sqrt();
            assert!((f - p).abs() <= 5.0 * sigma + 1e-7, "bin {i}: {f} vs {p}");
        }
        assert_eq!(counts[1], 0);
    }

    #[test]
    fn alias_table_rejects_bad_weights() {
        assert!(AliasTable::new(&[0.0, 0.0]).is_none());
        assert!(AliasTable::new(&[1.0, f32::NAN]).is_none());
        assert!(AliasTable::new(&[1.0, -1.0]).is_none());
        assert!(AliasTable::new(&[]).is_none());
    }

    #[test]
    fn distribution_1d_sample_matches_pdf() {
        let d = Distribution1D::new(&[0.0, 1.0, 4.0, 0.0, 2.0]);
        let mut rng = Rng::new(9, 0);
        let mut hist = [0usize; 5];
        let n = 500_000;
        for _ in 0..n {
            let (x, pdf, i) = d.sample_continuous(rng.uniform());
            assert!((0.0..1.0).contains(&x));
            assert_eq!(pdf, d.pdf(x));
            hist[i] += 1;
        }
        for (i, h) in hist.iter().enumerate() {
            let p = d.pmf(i);
            assert!((*h as f32 / n as f32 - p).abs() < 0.005, "{hist:?}");
        }
        assert_eq!(hist[0] + hist[3], 0);
    }

    #[test]
    fn distribution_2d_pdf_integrates_to_one_and_matches_samples() {
        let (w, h) = (8, 4);
        let values: Vec<f32> = (0..w * h).map(|i| ((i * 7) % 5) as f32).collect();
        let d = Distribution2D::new(&values, w, h);
        let mut integral = 0.0;
        for j in 0..h {
            for i in 0..w {
                integral += d.pdf(Vec2::new(
                    (i as f32 + 0.5) / w as f32,
                    (j as f32 + 0.5) / h as f32,
                )) / (w * h) as f32;
            }
        }
        assert!((integral - 1.0).abs() < 1e-5);
        let mut rng = Rng::new(4, 4);
        for _ in 0..10_000 {
            let (p, pdf) = d.sample(rng.uniform2());
            assert!((pdf - d.pdf(p)).abs() <= 1e-4 * pdf);
            assert!(pdf > 0.0);
        }
    }
}
