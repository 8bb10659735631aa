//! Multiple importance sampling: the two classic weights of one sample per strategy, and
//! [`MisHeuristic`], the user's choice among them (and the many-sample schemes of
//! `env_direct`), shared by the guides and the integrators.

use crate::error::{Error, Result};

/// Power heuristic with beta = 2 (Veach), written so that an infinite pdf (delta strategy)
/// or two zero pdfs never produce NaN.
#[inline]
pub fn power_heuristic(pdf_a: f32, pdf_b: f32) -> f32 {
    if pdf_a.is_infinite() {
        return 1.0;
    }
    let a = pdf_a * pdf_a;
    let b = pdf_b * pdf_b;
    if a + b > 0.0 && (a + b).is_finite() {
        a / (a + b)
    } else if pdf_a > pdf_b {
        1.0
    } else {
        0.0
    }
}

/// Balance heuristic (Veach): the provably good default for one sample per strategy.
#[inline]
pub fn balance_heuristic(pdf_a: f32, pdf_b: f32) -> f32 {
    if pdf_a.is_infinite() {
        return 1.0;
    }
    let s = pdf_a + pdf_b;
    if s > 0.0 && s.is_finite() {
        pdf_a / s
    } else {
        0.0
    }
}

/// How MIS weights two strategies.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MisHeuristic {
    Balance,
    /// Power heuristic with exponent 2 (Veach): the usual better choice.
    #[default]
    Power,
    /// `env_direct` and `path`: the balance heuristic with the split of light and BSDF
    /// samples chosen by the second-order variance approximation of thesis 001 chapter 5
    /// (a warm-up, then the rest split by the estimated alpha, eq. 5.6): per shading point in
    /// `env_direct`, per pixel in `path` (the light sample taken with a probability); see the
    /// integrator's `mis_auto` module.
    Auto,
    /// `env_direct` only: Kondapaneni et al.'s optimal weights, their coefficients estimated
    /// on a warm-up half of the samples; see the integrator's `mis_auto` module.
    Optimal,
}

impl MisHeuristic {
    /// The one-sample weight of strategy a against b. `Auto` and `Optimal` need many samples
    /// of one integral and are refused by the integrators that would call this (the
    /// integrator module's `MisHeuristic::check_supported`); their weight with nothing
    /// estimated yet is the balance heuristic's.
    #[inline]
    pub fn weight(self, pdf_a: f32, pdf_b: f32) -> f32 {
        match self {
            MisHeuristic::Balance | MisHeuristic::Auto | MisHeuristic::Optimal => {
                balance_heuristic(pdf_a, pdf_b)
            }
            MisHeuristic::Power => power_heuristic(pdf_a, pdf_b),
        }
    }

    pub fn parse(name: &str) -> Result<Self> {
        match name {
            "balance" => Ok(MisHeuristic::Balance),
            "power" => Ok(MisHeuristic::Power),
            "auto" => Ok(MisHeuristic::Auto),
            "optimal" => Ok(MisHeuristic::Optimal),
            other => Err(Error::invalid(format!(
                "unknown MIS heuristic '{other}' (expected balance, power, auto or optimal)"
            ))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            MisHeuristic::Balance => "balance",
            MisHeuristic::Power => "power",
            MisHeuristic::Auto => "auto",
            MisHeuristic::Optimal => "optimal",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heuristics_handle_degenerate_pdfs() {
        assert_eq!(power_heuristic(0.0, 0.0), 0.0);
        assert_eq!(power_heuristic(f32::INFINITY, 3.0), 1.0);
        assert_eq!(balance_heuristic(1.0, 1.0), 0.5);
        assert!((power_heuristic(1.0, 2.0) - 0.2).abs() < 1e-6);
        assert_eq!(power_heuristic(1e30, 1.0), 1.0);
    }

    #[test]
    fn names_parse_back() {
        for mis in [
            MisHeuristic::Balance,
            MisHeuristic::Power,
            MisHeuristic::Auto,
            MisHeuristic::Optimal,
        ] {
            assert_eq!(MisHeuristic::parse(mis.name()).unwrap(), mis);
        }
        assert!(MisHeuristic::parse("veach").is_err());
    }
}
