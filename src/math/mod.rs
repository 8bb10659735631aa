//! Small numerical building blocks shared by every other module: colours, orthonormal
//! frames, warps from the unit square to directions and shapes (each with its pdf), discrete
//! distributions, the random number generator and the pixel samplers built on it.

mod distribution;
mod frame;
mod rng;
mod sampler;
pub mod warp;

pub use distribution::{AliasTable, Distribution1D, Distribution2D};
pub use frame::Frame;
pub use rng::{mix64, Rng};
pub use sampler::{PixelSampler, Sampler, SamplerKind};

pub use glam::{Vec2, Vec3};

/// Linear RGB radiometric quantity (radiance, power, reflectance). Lacuna renders in linear
/// sRGB primaries; the spectral dimension is three samples, as in both source theses.
pub type Rgb = Vec3;

pub const PI: f32 = std::f32::consts::PI;
pub const INV_PI: f32 = std::f32::consts::FRAC_1_PI;
pub const INV_2PI: f32 = 0.5 * std::f32::consts::FRAC_1_PI;
pub const INV_4PI: f32 = 0.25 * std::f32::consts::FRAC_1_PI;

/// Luminance of a linear sRGB colour (Rec. 709 weights); used for power-proportional choices.
#[inline]
pub fn luminance(c: Rgb) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// True when every component is finite.
#[inline]
pub fn is_finite3(v: Vec3) -> bool {
    v.x.is_finite() && v.y.is_finite() && v.z.is_finite()
}

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

/// Next representable float towards +infinity (pbrt's `NextFloatUp`), used to push spawned
/// ray origins off a surface by exactly the rounding error and no more.
#[inline(always)]
pub fn next_float_up(v: f32) -> f32 {
    if v.is_infinite() && v > 0.0 {
        return v;
    }
    let v = if v == -0.0 { 0.0 } else { v };
    let bits = v.to_bits();
    let bits = if v >= 0.0 { bits + 1 } else { bits - 1 };
    f32::from_bits(bits)
}

/// Next representable float towards -infinity.
#[inline(always)]
pub fn next_float_down(v: f32) -> f32 {
    if v.is_infinite() && v < 0.0 {
        return v;
    }
    let v = if v == 0.0 { -0.0 } else { v };
    let bits = v.to_bits();
    let bits = if v > 0.0 { bits - 1 } else { bits + 1 };
    f32::from_bits(bits)
}

/// Conservative bound on the relative rounding error of `n` chained float operations
/// (Higham's gamma_n, as used by pbrt for intersection error bounds).
#[inline]
pub const fn gamma(n: i32) -> f32 {
    let e = f32::EPSILON * 0.5;
    (n as f32 * e) / (1.0 - n as f32 * e)
}

/// Reflect `wo` about the normal `n` (both pointing away from the surface).
#[inline]
pub fn reflect(wo: Vec3, n: Vec3) -> Vec3 {
    -wo + 2.0 * wo.dot(n) * n
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn next_float_moves_one_ulp() {
        for v in [0.0f32, -0.0, 1.0, -1.0, 1e-30, -1e30, 123.456] {
            assert!(next_float_up(v) > v);
            assert!(next_float_down(v) < v);
            assert_eq!(
                next_float_down(next_float_up(v)),
                if v == -0.0 { 0.0 } else { v }
            );
        }
    }

    #[test]
    fn heuristics_handle_degenerate_pdfs() {
        assert_eq!(power_heuristic(0.0, 0.0), 0.0);
        assert_eq!(power_heuristic(f32::INFINITY, 3.0), 1.0);
        assert_eq!(balance_heuristic(1.0, 1.0), 0.5);
        assert!((power_heuristic(1.0, 2.0) - 0.2).abs() < 1e-6);
        assert_eq!(power_heuristic(1e30, 1.0), 1.0);
    }
}
