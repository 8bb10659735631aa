//! Warps from the unit square to directions and shapes. Each `sample_*` has a matching `*_pdf`
//! (with respect to solid angle for directions, area for shapes); the tests check they agree.

use super::{Vec2, Vec3, INV_2PI, INV_4PI, INV_PI, PI};

/// Uniform direction on the unit sphere.
pub fn uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

pub fn uniform_sphere_pdf() -> f32 {
    INV_4PI
}

/// Uniform direction on the hemisphere z >= 0.
pub fn uniform_hemisphere(u: Vec2) -> Vec3 {
    let z = u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

pub fn uniform_hemisphere_pdf(w: Vec3) -> f32 {
    if w.z >= 0.0 {
        INV_2PI
    } else {
        0.0
    }
}

/// Concentric map of the square to the unit disk (Shirley-Chiu): low distortion, so
/// stratification survives.
pub fn concentric_disk(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, theta) = if o.x.abs() > o.y.abs() {
        (o.x, PI / 4.0 * (o.y / o.x))
    } else {
        (o.y, PI / 2.0 - PI / 4.0 * (o.x / o.y))
    };
    r * Vec2::new(theta.cos(), theta.sin())
}

/// Cosine-weighted direction on the hemisphere z >= 0 (Malley's method).
pub fn cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = concentric_disk(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3::new(d.x, d.y, z)
}

pub fn cosine_hemisphere_pdf(w: Vec3) -> f32 {
    w.z.max(0.0) * INV_PI
}

/// Power-cosine lobe around +z: pdf (n + 1) / (2 pi) cos^n(theta) on the hemisphere around the
/// axis. This is the lobe of the modified Phong BRDF (001 §2, Lafortune & Willems) and of the
/// skeleton importance lobe (000 eq. 163).
pub fn power_cosine(u: Vec2, exponent: f32) -> Vec3 {
    // Inverse cdf of cos(theta): F(cos) = 1 - cos^(n+1)  =>  cos = (1 - u)^(1/(n+1)), which
    // is never 0 for u in [0, 1) (cos = 0 has zero density).
    let cos_theta = (1.0 - u.x).powf(1.0 / (exponent + 1.0));
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(sin_theta * phi.cos(), sin_theta * phi.sin(), cos_theta)
}

pub fn power_cosine_pdf(w: Vec3, exponent: f32) -> f32 {
    if w.z <= 0.0 {
        return 0.0;
    }
    (exponent + 1.0) * INV_2PI * w.z.powf(exponent)
}

/// Uniform direction inside the cone of half-angle acos(cos_max) around +z.
pub fn uniform_cone(u: Vec2, cos_max: f32) -> Vec3 {
    let cos_theta = (1.0 - u.x) + u.x * cos_max;
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(sin_theta * phi.cos(), sin_theta * phi.sin(), cos_theta)
}

pub fn uniform_cone_pdf(w: Vec3, cos_max: f32) -> f32 {
    if w.z >= cos_max && cos_max < 1.0 {
        1.0 / (2.0 * PI * (1.0 - cos_max))
    } else {
        0.0
    }
}

/// Uniform barycentric coordinates (b0, b1) on a triangle; b2 = 1 - b0 - b1.
/// Uses the low-distortion square-to-triangle map of Heitz (2019).
pub fn uniform_triangle(u: Vec2) -> (f32, f32) {
    let (b0, b1);
    if u.x < u.y {
        b0 = u.x / 2.0;
        b1 = u.y - b0;
    } else {
        b1 = u.y / 2.0;
        b0 = u.x - b1;
    }
    (b0, b1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    /// Integrates `pdf` over the sphere with a fine midpoint rule in (cos theta, phi).
    fn sphere_integral(pdf: impl Fn(Vec3) -> f32) -> f64 {
        let (nt, np) = (800, 400);
        let mut sum = 0.0f64;
        for i in 0..nt {
            let z = -1.0 + 2.0 * (i as f32 + 0.5) / nt as f32;
            let r = (1.0 - z * z).sqrt();
            for j in 0..np {
                let phi = 2.0 * PI * (j as f32 + 0.5) / np as f32;
                sum += pdf(Vec3::new(r * phi.cos(), r * phi.sin(), z)) as f64;
            }
        }
        sum * 4.0 * std::f64::consts::PI / (nt * np) as f64
    }

    #[test]
    fn direction_pdfs_integrate_to_one() {
        assert!((sphere_integral(|_| uniform_sphere_pdf()) - 1.0).abs() < 1e-3);
        assert!((sphere_integral(uniform_hemisphere_pdf) - 1.0).abs() < 1e-3);
        assert!((sphere_integral(cosine_hemisphere_pdf) - 1.0).abs() < 1e-3);
        for n in [0.0, 1.0, 10.0, 100.0] {
            let i = sphere_integral(|w| power_cosine_pdf(w, n));
            assert!((i - 1.0).abs() < 2e-2, "exponent {n}: {i}");
        }
        let i = sphere_integral(|w| uniform_cone_pdf(w, 0.5));
        assert!((i - 1.0).abs() < 1e-2, "{i}");
    }

    #[test]
    fn samples_are_in_their_domain_and_unit_length() {
        let mut rng = Rng::new(11, 0);
        for _ in 0..10_000 {
            let u = rng.uniform2();
            for w in [
                uniform_sphere(u),
                uniform_hemisphere(u),
                cosine_hemisphere(u),
                power_cosine(u, 50.0),
                uniform_cone(u, 0.9),
            ] {
                assert!((w.length() - 1.0).abs() < 1e-4);
            }
            assert!(cosine_hemisphere(u).z >= 0.0);
            assert!(uniform_cone(u, 0.9).z >= 0.9 - 1e-6);
            let (b0, b1) = uniform_triangle(u);
            assert!(b0 >= 0.0 && b1 >= 0.0 && b0 + b1 <= 1.0 + 1e-6);
        }
    }

    /// Mean of cos(theta) under each warp equals its closed form, which checks the sampled
    /// distribution against the pdf (the chi-square tests of the BSDFs check the shape finely).
    #[test]
    fn warp_moments_match_pdfs() {
        let mut rng = Rng::new(5, 0);
        let n = 400_000;
        let mut m_cos = 0.0f64;
        let mut m_pow = 0.0f64;
        let e = 20.0f32;
        for _ in 0..n {
            m_cos += cosine_hemisphere(rng.uniform2()).z as f64;
            m_pow += power_cosine(rng.uniform2(), e).z as f64;
        }
        // E[cos] under cos/pi = 2/3; under (n+1)/(2pi) cos^n = (n+1)/(n+2).
        assert!((m_cos / n as f64 - 2.0 / 3.0).abs() < 2e-3);
        assert!((m_pow / n as f64 - (e as f64 + 1.0) / (e as f64 + 2.0)).abs() < 2e-3);
    }
}
