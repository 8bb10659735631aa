//! Helpers shared by the tests: chi-square and z-tests with their p-values, a (cos theta, phi)
//! grid over the sphere with per-cell quadrature, integrator agreement, and small test geometry.
//!
//! Each test binary uses only part of this module.
#![allow(dead_code)]

pub mod agreement;
pub mod chi2;
pub mod directions;
pub mod shapes;
pub mod sphere;
