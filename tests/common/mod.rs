//! Helpers shared by the sampling tests: chi-square and z-tests with their p-values, and a
//! (cos theta, phi) grid over the sphere with per-cell quadrature.
//!
//! Each test binary uses only part of this module.
#![allow(dead_code)]

pub mod agreement;
pub mod chi2;
pub mod directions;
pub mod sphere;
