//! Lacuna: an embeddable, physically based renderer.
pub mod geometry;
pub mod math;
