//! Sampling an emissive triangle as seen from a receiving point.
//!
//! With [`TriangleSampling::SolidAngle`](super::TriangleSampling) next-event estimation samples
//! a triangle *uniformly in solid angle* (Arvo 1995, "Stratified sampling of spherical
//! triangles"; the construction pbrt-v4 calls `SampleSphericalTriangle`) wherever the triangle
//! subtends a moderate solid angle: the density is then constant, 1 / Omega, so the light's
//! 1/r^2 and cosine at the light leave no variance. Where the solid angle is tiny (a far or
//! small light: 1/r^2 and the cosine hardly vary over it, and the construction loses
//! precision) or close to a hemisphere (a receiver almost touching the light, where the
//! construction degenerates), the triangle is sampled uniformly by area instead, as pbrt-v4
//! does. [`spherical_solid_angle`] is that rule: a function of the receiver and the triangle
//! only, used by both `Light::sample_with` and `Light::pdf_with`, so the two always agree on
//! which density applies.
//!
//! It is not the default: on the Cornell box and the Veach door it lowers `path`'s error at
//! equal samples by only 1.6 % and 0.3 % while a sample costs 23 % more instructions, so it
//! loses at equal time (BENCHMARKS.md); rules spending it only where the
//! area density varies most across the triangle lost too.

use crate::math::{Vec2, Vec3};
use glam::DVec3;

/// Below this solid angle (sr) triangles are sampled by area (pbrt-v4's
/// `MinSphericalSampleArea`).
pub const MIN_SPHERICAL_SOLID_ANGLE: f32 = 3e-4;
/// Above this solid angle (sr; a hemisphere is 2 pi = 6.283) triangles are sampled by area
/// (pbrt-v4's `MaxSphericalSampleArea`).
pub const MAX_SPHERICAL_SOLID_ANGLE: f32 = 6.22;

/// The sampling rule: `Some(solid angle)` when the triangle `p` (emitting on the side of
/// `normal`) is sampled uniformly in solid angle from `receiver`, `None` when by area (the
/// solid angle outside [`MIN_SPHERICAL_SOLID_ANGLE`, `MAX_SPHERICAL_SOLID_ANGLE`], or the
/// receiver not strictly in front of the emitting side).
///
/// The solid angle comes from Van Oosterom and Strackee's formula in f64 (exact to ~1e-12
/// relative over scales 1e-4..1e4), since it is the sample's whole density: an error in it would
/// be a bias of the same relative size.
#[inline]
pub fn spherical_solid_angle(p: &[Vec3; 3], normal: Vec3, receiver: Vec3) -> Option<f32> {
    let r = receiver.as_dvec3();
    let (a, b, c) = (
        p[0].as_dvec3() - r,
        p[1].as_dvec3() - r,
        p[2].as_dvec3() - r,
    );
    // In front: the receiver on the emitting side of the plane.
    if a.dot(normal.as_dvec3()) >= 0.0 {
        return None;
    }
    let omega = solid_angle_f64(a, b, c) as f32;
    (MIN_SPHERICAL_SOLID_ANGLE..=MAX_SPHERICAL_SOLID_ANGLE)
        .contains(&omega)
        .then_some(omega)
}

/// Solid angle (sr) of triangle `p` seen from `receiver`, computed in f64.
pub fn solid_angle(p: &[Vec3; 3], receiver: Vec3) -> f32 {
    let r = receiver.as_dvec3();
    solid_angle_f64(
        p[0].as_dvec3() - r,
        p[1].as_dvec3() - r,
        p[2].as_dvec3() - r,
    ) as f32
}

/// Solid angle of the triangle with vertices `a`, `b`, `c` relative to the viewpoint (Van
/// Oosterom and Strackee 1983): tan(Omega / 2) = |a . (b x c)| / (|a||b||c| + (a.b)|c| +
/// (a.c)|b| + (b.c)|a|), with atan2 keeping the right branch for Omega > pi.
#[inline]
fn solid_angle_f64(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let (la, lb, lc) = (a.length(), b.length(), c.length());
    let triple = a.dot(b.cross(c)).abs();
    let den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
    2.0 * triple.atan2(den)
}

/// A point of triangle `p` uniform in the solid angle it subtends at `receiver` (`solid_angle`
/// from [`spherical_solid_angle`]), as barycentric weights of `p[0]`, `p[1]`, `p[2]`. `u.x`
/// chooses the area of the sub-triangle cut off by the sample's great circle through vertex
/// `a` (Arvo's A-hat = u.x * Omega), `u.y` the point along that arc, so a stratified `u` gives
/// directions stratified over the spherical triangle. `None` for a degenerate spherical triangle
/// (which the rule's minimum solid angle keeps away).
pub fn sample_spherical_triangle(
    p: &[Vec3; 3],
    receiver: Vec3,
    solid_angle: f32,
    u: Vec2,
) -> Option<[f32; 3]> {
    // In f64: in f32 the construction's cancellations (q and z close to 1 for small spherical
    // triangles) skew the density measurably already at solid angles of ~5e-4 sr.
    let r = receiver.as_dvec3();
    let to = |v: Vec3| (v.as_dvec3() - r).normalize_or_zero();
    let (a, b, c) = (to(p[0]), to(p[1]), to(p[2]));
    // Normals of the great circles through the edges; the angle alpha at vertex a is the one
    // between the planes (a, b) and (a, c). Its sine from the cross product stays accurate for
    // thin triangles, where 1 - cos^2 would not.
    let n_ab = a.cross(b).normalize_or_zero();
    let n_ca = c.cross(a).normalize_or_zero();
    if n_ab == DVec3::ZERO || n_ca == DVec3::ZERO {
        return None;
    }
    let cos_alpha = -n_ab.dot(n_ca);
    let sin_alpha = n_ab.cross(n_ca).length();
    // Arvo, section 3: the sub-triangle (a, b, c') of area A-hat = u.x * Omega, with c' on the
    // arc from a to c; s, t = sin, cos of (A-hat - alpha).
    let (sin_area, cos_area) = (u.x as f64 * solid_angle as f64).sin_cos();
    let s = sin_area * cos_alpha - cos_area * sin_alpha;
    let t = cos_area * cos_alpha + sin_area * sin_alpha;
    let uu = t - cos_alpha;
    let v = s + sin_alpha * a.dot(b);
    let den = (v * s + uu * t) * sin_alpha;
    // q = cos of the arc from a to c'.
    let q = if den != 0.0 {
        (((v * t - uu * s) * cos_alpha - v) / den).clamp(-1.0, 1.0)
    } else {
        1.0
    };
    let c_hat = a * q + orthonormal_part(c, a) * (1.0 - q * q).max(0.0).sqrt();
    // Then a direction on the arc from b to c', uniform in the sub-triangle's area.
    let z = 1.0 - u.y as f64 * (1.0 - c_hat.dot(b));
    let w = b * z + orthonormal_part(c_hat, b) * (1.0 - z * z).max(0.0).sqrt();
    barycentric_along(p, r, w)
}

/// The unit vector along the part of `v` orthogonal to the unit vector `w` (zero if none).
#[inline]
fn orthonormal_part(v: DVec3, w: DVec3) -> DVec3 {
    (v - w * v.dot(w)).normalize_or_zero()
}

/// Barycentric weights of where the ray from `origin` along `dir` meets the plane of `p`
/// (Moller-Trumbore), clamped onto the triangle: directions from the spherical construction
/// lie inside it up to rounding.
#[inline]
fn barycentric_along(p: &[Vec3; 3], origin: DVec3, dir: DVec3) -> Option<[f32; 3]> {
    let p0 = p[0].as_dvec3();
    let (e1, e2) = (p[1].as_dvec3() - p0, p[2].as_dvec3() - p0);
    let s1 = dir.cross(e2);
    let divisor = s1.dot(e1);
    if divisor == 0.0 || !divisor.is_finite() {
        return None;
    }
    let inv = 1.0 / divisor;
    let s = origin - p0;
    let mut b1 = (s.dot(s1) * inv).clamp(0.0, 1.0);
    let mut b2 = (dir.dot(s.cross(e1)) * inv).clamp(0.0, 1.0);
    if !(b1.is_finite() && b2.is_finite()) {
        return None;
    }
    let sum = b1 + b2;
    if sum > 1.0 {
        b1 /= sum;
        b2 /= sum;
    }
    let (b1, b2) = (b1 as f32, b2 as f32);
    Some([(1.0 - b1 - b2).max(0.0), b1, b2])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    #[test]
    fn solid_angle_of_an_octant_is_half_pi() {
        let o = solid_angle_f64(DVec3::X, DVec3::Y, DVec3::Z);
        assert!((o - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }

    /// Samples fall on the triangle and along the sampled direction's ray.
    #[test]
    fn samples_lie_on_the_triangle() {
        let p = [
            Vec3::new(-1.0, 1.0, -1.0),
            Vec3::new(1.0, 1.0, -1.0),
            Vec3::new(0.0, 1.0, 1.0),
        ];
        let receiver = Vec3::new(0.2, -0.5, 0.1);
        let omega = spherical_solid_angle(&p, Vec3::NEG_Y, receiver).unwrap();
        let mut rng = Rng::new(1, 2);
        for _ in 0..10_000 {
            let b = sample_spherical_triangle(&p, receiver, omega, rng.uniform2()).unwrap();
            assert!(b.iter().all(|&x| (0.0..=1.0).contains(&x)));
            assert!((b[0] + b[1] + b[2] - 1.0).abs() < 1e-6);
        }
    }
}
