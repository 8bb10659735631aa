//! Goodness-of-fit statistics for the sampling tests.
//!
//! Every statistical test (chi-square or z-test) across `bsdf_sampling`, `light_sampling` and
//! `path_skeleton`
//! rejects at the Šidák-corrected level `1 - (1 - ALPHA)^(1 / TEST_COUNT)`, so that the whole
//! suite has a false-alarm probability of at most `ALPHA` (the samples are fixed by seeds, so
//! a pass is reproducible).

/// Family-wise significance level over all statistical tests.
pub const ALPHA: f64 = 0.01;

/// Number of statistical tests in the test binaries: bsdf_sampling runs 6 Lambert, 100 Phong,
/// 40 rough dielectric and 6 power-cosine chi-square tests and 140 albedo z-tests (292); light_sampling runs 27
/// chi-square tests and 64 z-tests (91); environment runs 21 chi-square tests and 8 z-tests
/// (29); path_skeleton runs 9 chi-square tests and 4 z-tests (13); sampler runs 81 chi-square
/// tests and 12 z-tests (93). Update it when adding tests (an overestimate only makes the
/// correction conservative).
pub const TEST_COUNT: usize = 518;

/// Cells whose expected count is below this are pooled with their neighbours in order of
/// expected count.
pub const MIN_EXPECTED: f64 = 5.0;

/// The p-value below which one test rejects.
pub fn significance() -> f64 {
    1.0 - (1.0 - ALPHA).powf(1.0 / TEST_COUNT as f64)
}

/// ln Gamma(x) for x > 0: the recurrence Gamma(x + 1) = x Gamma(x) moves x past 15, where
/// Stirling's series with five correction terms is accurate to ~1e-16.
pub fn ln_gamma(x: f64) -> f64 {
    assert!(x > 0.0, "ln_gamma({x})");
    let mut x = x;
    let mut shift = 0.0;
    while x < 15.0 {
        shift += x.ln();
        x += 1.0;
    }
    let inv = 1.0 / x;
    let inv2 = inv * inv;
    // 1/(12x) - 1/(360x^3) + 1/(1260x^5) - 1/(1680x^7) + 1/(1188x^9)
    let series = inv
        * (1.0 / 12.0
            - inv2 * (1.0 / 360.0 - inv2 * (1.0 / 1260.0 - inv2 * (1.0 / 1680.0 - inv2 / 1188.0))));
    (x - 0.5) * x.ln() - x + 0.5 * (2.0 * std::f64::consts::PI).ln() + series - shift
}

/// exp(-x) x^a / Gamma(a), the common factor of both expansions below.
fn gamma_prefactor(a: f64, x: f64) -> f64 {
    (a * x.ln() - x - ln_gamma(a)).exp()
}

/// P(a, x) by its power series sum_k x^k / (a (a + 1) ... (a + k)); converges quickly for
/// x < a + 1.
fn lower_series(a: f64, x: f64) -> f64 {
    let mut term = 1.0 / a;
    let mut sum = term;
    let mut k = 1.0;
    while k < 10_000.0 {
        term *= x / (a + k);
        sum += term;
        if term.abs() < sum.abs() * 1e-16 {
            break;
        }
        k += 1.0;
    }
    sum * gamma_prefactor(a, x)
}

/// Q(a, x) by Legendre's continued fraction
/// 1 / (x + 1 - a - 1 (1 - a) / (x + 3 - a - 2 (2 - a) / (x + 5 - a - ...))),
/// evaluated with the modified Lentz method; converges quickly for x > a + 1.
fn upper_fraction(a: f64, x: f64) -> f64 {
    const TINY: f64 = 1e-300;
    let mut f = x + 1.0 - a;
    if f.abs() < TINY {
        f = TINY;
    }
    let mut c = f;
    let mut d = 0.0;
    for k in 1..10_000 {
        let k = k as f64;
        let an = -k * (k - a);
        let bn = x + 2.0 * k + 1.0 - a;
        d = bn + an * d;
        if d.abs() < TINY {
            d = TINY;
        }
        c = bn + an / c;
        if c.abs() < TINY {
            c = TINY;
        }
        d = 1.0 / d;
        let delta = c * d;
        f *= delta;
        if (delta - 1.0).abs() < 1e-16 {
            break;
        }
    }
    gamma_prefactor(a, x) / f
}

/// Regularized lower incomplete gamma function P(a, x).
pub fn gamma_p(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        0.0
    } else if x < a + 1.0 {
        lower_series(a, x)
    } else {
        1.0 - upper_fraction(a, x)
    }
}

/// Regularized upper incomplete gamma function Q(a, x) = 1 - P(a, x).
pub fn gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        1.0
    } else if x < a + 1.0 {
        1.0 - lower_series(a, x)
    } else {
        upper_fraction(a, x)
    }
}

/// Probability that a chi-square variable with `dof` degrees of freedom exceeds `stat`.
pub fn chi2_p_value(stat: f64, dof: usize) -> f64 {
    gamma_q(0.5 * dof as f64, 0.5 * stat)
}

/// Two-sided p-value of a standard normal deviate: erfc(|z| / sqrt 2) = Q(1/2, z^2 / 2).
pub fn normal_p_value(z: f64) -> f64 {
    gamma_q(0.5, 0.5 * z * z)
}

/// Outcome of a chi-square test after pooling.
#[derive(Clone, Debug)]
pub struct Chi2 {
    pub stat: f64,
    pub dof: usize,
    pub p_value: f64,
    /// Number of cells before and after pooling.
    pub cells: usize,
    pub pooled_cells: usize,
}

/// Pearson's chi-square test of observed counts against expected counts (both over the same
/// cells, which must cover every outcome, including "no sample"). Cells are visited in order
/// of increasing expected count and merged until each merged cell expects at least
/// `MIN_EXPECTED`. An outcome the expectation calls impossible (the pdf is zero over the
/// whole cell) but that was observed is an error by itself.
pub fn chi2_test(observed: &[u64], expected: &[f64]) -> Result<Chi2, String> {
    assert_eq!(observed.len(), expected.len());
    for (i, (&o, &e)) in observed.iter().zip(expected).enumerate() {
        if !(e.is_finite() && e >= 0.0) {
            return Err(format!(
                "cell {i}: expected count {e} is not a finite count"
            ));
        }
        if o > 0 && e <= 0.0 {
            return Err(format!("cell {i}: {o} samples where the pdf is zero"));
        }
    }
    let mut order: Vec<usize> = (0..expected.len()).collect();
    order.sort_by(|&a, &b| expected[a].total_cmp(&expected[b]));
    let mut cells: Vec<(f64, f64)> = Vec::new();
    let (mut po, mut pe) = (0.0f64, 0.0f64);
    for i in order {
        po += observed[i] as f64;
        pe += expected[i];
        if pe >= MIN_EXPECTED {
            cells.push((po, pe));
            po = 0.0;
            pe = 0.0;
        }
    }
    if po > 0.0 || pe > 0.0 {
        match cells.last_mut() {
            Some(last) => {
                last.0 += po;
                last.1 += pe;
            }
            None => return Err("too few samples: every cell expects < 5".into()),
        }
    }
    if cells.len() < 2 {
        return Err(format!(
            "only {} cell(s) after pooling: the test has no power",
            cells.len()
        ));
    }
    let stat: f64 = cells.iter().map(|&(o, e)| (o - e) * (o - e) / e).sum();
    let dof = cells.len() - 1;
    Ok(Chi2 {
        stat,
        dof,
        p_value: chi2_p_value(stat, dof),
        cells: observed.len(),
        pooled_cells: cells.len(),
    })
}

/// Runs `chi2_test` and panics with a readable report when it rejects.
pub fn assert_chi2(name: &str, observed: &[u64], expected: &[f64]) -> Chi2 {
    let result = chi2_test(observed, expected).unwrap_or_else(|e| panic!("{name}: {e}"));
    if result.p_value < significance() {
        // Name the worst cells to make the failure readable.
        let mut worst: Vec<(usize, f64)> = observed
            .iter()
            .zip(expected)
            .enumerate()
            .filter(|(_, (_, &e))| e > 0.0)
            .map(|(i, (&o, &e))| (i, (o as f64 - e) / e.sqrt()))
            .collect();
        worst.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
        let worst: Vec<String> = worst
            .iter()
            .take(6)
            .map(|&(i, z)| {
                format!(
                    "cell {i}: obs {} exp {:.1} (z {z:.1})",
                    observed[i], expected[i]
                )
            })
            .collect();
        panic!(
            "{name}: chi-square rejects: stat {:.1}, dof {}, p = {:.3e} < {:.3e}; worst: {}",
            result.stat,
            result.dof,
            result.p_value,
            significance(),
            worst.join("; ")
        );
    }
    result
}

/// z-test of an estimate against its expected value; `std_err` is the estimate's standard
/// error. Panics when the two-sided p-value is below the corrected significance.
pub fn assert_z(name: &str, estimate: f64, expected: f64, std_err: f64) {
    let z = (estimate - expected) / std_err.max(1e-300);
    let p = normal_p_value(z);
    assert!(
        p >= significance(),
        "{name}: estimate {estimate:.6} vs expected {expected:.6} (std err {std_err:.2e}, \
         z = {z:.2}, p = {p:.2e} < {:.2e})",
        significance()
    );
}

/// Running mean and variance (Welford) for Monte Carlo estimates with a standard error.
#[derive(Clone, Copy, Debug, Default)]
pub struct Stats {
    pub n: u64,
    mean: f64,
    m2: f64,
}

impl Stats {
    pub fn add(&mut self, x: f64) {
        self.n += 1;
        let d = x - self.mean;
        self.mean += d / self.n as f64;
        self.m2 += d * (x - self.mean);
    }

    pub fn mean(&self) -> f64 {
        self.mean
    }

    pub fn variance(&self) -> f64 {
        if self.n < 2 {
            0.0
        } else {
            self.m2 / (self.n - 1) as f64
        }
    }

    pub fn std_err(&self) -> f64 {
        (self.variance() / self.n as f64).sqrt()
    }
}
