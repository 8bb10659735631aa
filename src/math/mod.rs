//! Small numerical building blocks shared by every other module: colours, orthonormal
//! frames, warps from the unit square to directions and shapes (each with its pdf), discrete
//! distributions, the random number generator and the pixel samplers built on it.

mod distribution;
mod frame;
mod mis;
mod pixel_sampler;
mod rng;
pub mod warp;

pub use distribution::{AliasTable, Distribution1D, Distribution2D};
pub use frame::Frame;
pub use mis::{balance_heuristic, power_heuristic, MisHeuristic};
pub use pixel_sampler::{
    PixelSampler, Sampler, SamplerKind, FILM_DIMENSION, FIRST_INTEGRATOR_DIMENSION, LENS_DIMENSION,
};
pub use rng::{mix64, Rng};

pub use glam::{Vec2, Vec3};

/// Asks the processor to bring the cache line holding `value` into its caches: a hint with no
/// effect on any result (nothing on other architectures), for data a later step will read.
#[inline(always)]
pub fn prefetch<T>(value: &T) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        // SAFETY: a prefetch has no architectural effect (it cannot fault), and `value` is a
        // live reference; SSE is part of x86-64.
        unsafe { _mm_prefetch::<_MM_HINT_T0>((value as *const T).cast()) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = value;
}

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

/// Next representable float towards +infinity (pbrt's `NextFloatUp`), used to push spawned
/// ray origins off a surface by exactly the rounding error and no more.
#[inline(always)]
pub fn next_float_up(v: f32) -> f32 {
    if v.is_infinite() && v > 0.0 {
        return v;
    }
    let v = if v == -0.0 { 0.0 } else { v };
    let bits = v.to_bits();
    // Wrapping, as the SIMD form: NaN compares false, so NaN bits step too (see below).
    let bits = if v >= 0.0 {
        bits.wrapping_add(1)
    } else {
        bits.wrapping_sub(1)
    };
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
    // Wrapping: a NaN compares false and takes `+ 1`; with every bit set it wraps to +0.0
    // (and 0x7F80_0001 stepped up above becomes +inf). The SIMD form does the same, and
    // no ray origin is NaN, so only the bit-for-bit test meets these.
    let bits = if v > 0.0 {
        bits.wrapping_sub(1)
    } else {
        bits.wrapping_add(1)
    };
    f32::from_bits(bits)
}

/// Per component: `v` moved one ulp towards the sign of `towards` ([`next_float_up`] where it
/// is positive, [`next_float_down`] where negative, unchanged where zero or NaN), bit for bit
/// the same as those scalar functions, NaN payloads included (a test checks every class of
/// input). Ray spawning calls it for every origin, three times per bounce; the signs of the
/// offset are random there, so the per-axis branches of the scalar form mispredicted often
/// and cost about 15 instructions an axis. On x86-64 it is branch-free SSE2 (part of the
/// baseline, so no feature detection) on all three lanes at once.
#[inline(always)]
pub fn next_float_towards(v: Vec3, towards: Vec3) -> Vec3 {
    #[cfg(target_arch = "x86_64")]
    {
        next_float_towards_sse2(v, towards)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        next_float_towards_scalar(v, towards)
    }
}

/// The scalar form of [`next_float_towards`] (other architectures, and its test's reference).
#[inline(always)]
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
fn next_float_towards_scalar(v: Vec3, towards: Vec3) -> Vec3 {
    #[inline(always)]
    fn one(v: f32, towards: f32) -> f32 {
        if towards > 0.0 {
            next_float_up(v)
        } else if towards < 0.0 {
            next_float_down(v)
        } else {
            v
        }
    }
    Vec3::new(
        one(v.x, towards.x),
        one(v.y, towards.y),
        one(v.z, towards.z),
    )
}

#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn next_float_towards_sse2(v: Vec3, towards: Vec3) -> Vec3 {
    use std::arch::x86_64::*;
    // SAFETY: SSE2 is part of the x86-64 baseline; the intrinsics only touch registers and
    // the local array.
    unsafe {
        let x = _mm_setr_ps(v.x, v.y, v.z, 0.0);
        let t = _mm_setr_ps(towards.x, towards.y, towards.z, 0.0);
        let zero = _mm_setzero_ps();
        let bits = _mm_castps_si128(x);
        let up = _mm_castps_si128(_mm_cmpgt_ps(t, zero));
        let down = _mm_castps_si128(_mm_cmplt_ps(t, zero));
        // The scalar rules, with masks for branches. Up: +inf stays; +-0 becomes +0 and then
        // +1 ulp; otherwise +1 in the bits where v >= 0, -1 elsewhere (negative values and
        // NaN). Down: -inf stays; +-0 becomes -0 and then +1 in the bits (away from zero);
        // otherwise -1 where v > 0, +1 elsewhere (negative values and NaN).
        // A step of +1 or -1 is `mask | 1` where the mask is all ones for -1.
        let one = _mm_set1_epi32(1);
        let not_ge = _mm_castps_si128(_mm_cmpnge_ps(x, zero));
        let gt = _mm_castps_si128(_mm_cmpgt_ps(x, zero));
        let step = _mm_or_si128(
            _mm_and_si128(up, _mm_or_si128(not_ge, one)),
            _mm_and_si128(down, _mm_or_si128(gt, one)),
        );
        let stays = _mm_or_si128(
            _mm_and_si128(
                up,
                _mm_castps_si128(_mm_cmpeq_ps(x, _mm_set1_ps(f32::INFINITY))),
            ),
            _mm_and_si128(
                down,
                _mm_castps_si128(_mm_cmpeq_ps(x, _mm_set1_ps(f32::NEG_INFINITY))),
            ),
        );
        let step = _mm_andnot_si128(stays, step);
        // Zeros that move start from the zero of the direction's sign: +0 up, -0 down.
        let moving_zero = _mm_and_si128(
            _mm_castps_si128(_mm_cmpeq_ps(x, zero)),
            _mm_or_si128(up, down),
        );
        let base = _mm_or_si128(
            _mm_andnot_si128(moving_zero, bits),
            _mm_and_si128(_mm_and_si128(moving_zero, down), _mm_set1_epi32(i32::MIN)),
        );
        let r = _mm_castsi128_ps(_mm_add_epi32(base, step));
        let mut out = [0.0f32; 4];
        _mm_storeu_ps(out.as_mut_ptr(), r);
        Vec3::new(out[0], out[1], out[2])
    }
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
    fn next_float_towards_matches_the_scalar_steps_bit_for_bit() {
        // Every class of value (signed zeros, denormals, normals, the largest finite values,
        // infinities, quiet and signalling NaNs with either sign) against every class of
        // direction, in every lane, then random bit patterns.
        let values: Vec<f32> = [
            0x0000_0000u32,
            0x8000_0000,
            0x0000_0001,
            0x8000_0001,
            0x007F_FFFF,
            0x0080_0000,
            0x3F80_0000,
            0xBF80_0000,
            0x7F7F_FFFF,
            0xFF7F_FFFF,
            0x7F80_0000,
            0xFF80_0000,
            0x7FC0_0000,
            0xFFC0_0000,
            0x7F80_0001,
            0xFF80_0001,
            0x7FFF_FFFF,
        ]
        .iter()
        .map(|&b| f32::from_bits(b))
        .chain([1e-30, -1e30, 123.456, -7.5e-3])
        .collect();
        let towards = [
            0.0f32,
            -0.0,
            1e-40,
            -1e-40,
            2.0,
            -2.0,
            f32::INFINITY,
            f32::NAN,
        ];
        let check = |v: Vec3, t: Vec3| {
            let (got, want) = (next_float_towards(v, t), next_float_towards_scalar(v, t));
            for (g, w) in got.to_array().iter().zip(want.to_array()) {
                assert_eq!(g.to_bits(), w.to_bits(), "v {v:?} towards {t:?}");
            }
        };
        for &a in &values {
            for &t in &towards {
                for &b in &[values[2], -t] {
                    check(Vec3::new(a, b, -a), Vec3::new(t, -t, t));
                    check(Vec3::new(b, a, b), Vec3::new(-t, t, 1.0));
                    check(Vec3::new(b, -a, a), Vec3::new(0.0, -t, t));
                }
            }
        }
        let mut rng = Rng::new(11, 4);
        let mut f = || f32::from_bits(rng.next_u32());
        for _ in 0..100_000 {
            check(Vec3::new(f(), f(), f()), Vec3::new(f(), f(), f()));
        }
    }
}
