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
#[inline]
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
#[inline]
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
    power_cosine_pdf_cos(w.z, exponent)
}

/// [`power_cosine_pdf`] of a direction whose cosine with the axis is `cos` (the lobe's density
/// needs no other coordinate: a caller with the axis need not build a frame).
#[inline]
pub fn power_cosine_pdf_cos(cos: f32, exponent: f32) -> f32 {
    if cos <= 0.0 {
        return 0.0;
    }
    (exponent + 1.0) * INV_2PI * cos.powf(exponent)
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

/// Uniform directions toward a planar rectangle, as seen from a point o: the spherical
/// rectangle of Ureña, Fajardo and King (2013), "An area-preserving parametrization for
/// spherical rectangles" (§3-4). Its density is 1 / (solid angle) on the directions from o
/// that hit the rectangle and 0 elsewhere, so it is exact for any direction (a ray-rectangle
/// intersection), and unlike sampling by area it has no t² / |cos| peak at grazing angles.
/// Set up in f64: the solid angle is a sum of four angles minus 2 pi, which cancels in f32
/// for small or distant rectangles. Those four angles (four `acos`, most of the set-up's
/// cost) are computed at the first sample or density evaluation that needs them: a guided
/// vertex sets up its portal's rectangle once and evaluates its density for every direction
/// it weighs, and most of those (the BSDF's samples, the light's) miss it.
#[derive(Clone, Debug)]
pub struct SphericalRectangle {
    /// The rectangle's frame: unit edge directions x, y and z = x × y flipped so that the
    /// rectangle's plane lies at local z = z0 < 0 from the origin.
    x: glam::DVec3,
    y: glam::DVec3,
    z: glam::DVec3,
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
    z0: f64,
    angles: std::sync::OnceLock<RectangleAngles>,
}

/// What sampling a [`SphericalRectangle`] needs beyond its frame (the paper's b0, b1, k and
/// the solid angle).
#[derive(Clone, Copy, Debug)]
struct RectangleAngles {
    b0: f64,
    b1: f64,
    k: f64,
    solid_angle: f64,
}

/// Below this lower bound on its solid angle (sr) a rectangle's angles are computed at once,
/// to refuse it if they do not give a positive finite solid angle; above it they always do
/// (the set-up is accurate to 1e-3 relative at 1e-8 sr, `far` in the tests), so they can wait.
const DEFERRED_SOLID_ANGLE: f64 = 1e-6;

/// What [`SphericalRectangle::new`] computes of a rectangle before it looks at the origin
/// (its corner and its frame in f64), for a rectangle seen from many origins: a guided vertex
/// sets up its portal's rectangle anew at every point.
/// [`seen_from`](Self::seen_from) gives bit for bit what `SphericalRectangle::new` gives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RectangleFrame {
    corner: Vec3,
    x: glam::DVec3,
    y: glam::DVec3,
    z: glam::DVec3,
    ex_len: f64,
    ey_len: f64,
}

impl RectangleFrame {
    /// The rectangle `corner + a ex + b ey` for a in [0, ex_len], b in [0, ey_len] (`ex`, `ey`
    /// orthonormal). None when a side is not a positive finite length (no origin sees it).
    pub fn new(
        corner: Vec3,
        ex: Vec3,
        ey: Vec3,
        ex_len: f32,
        ey_len: f32,
    ) -> Option<RectangleFrame> {
        debug_assert!(
            ex.dot(ey).abs() <= 1e-4 * ex.length() * ey.length(),
            "rectangle edges must be orthogonal"
        );
        let (ex_len, ey_len) = (ex_len as f64, ey_len as f64);
        if !(ex_len > 0.0 && ey_len > 0.0 && ex_len.is_finite() && ey_len.is_finite()) {
            return None;
        }
        let x = ex.as_dvec3().normalize();
        let y = ey.as_dvec3().normalize();
        Some(RectangleFrame {
            corner,
            x,
            y,
            z: x.cross(y),
            ex_len,
            ey_len,
        })
    }

    /// The rectangle seen from `origin` ([`SphericalRectangle::new`]).
    pub fn seen_from(&self, origin: Vec3) -> Option<SphericalRectangle> {
        let mut rect = SphericalRectangle::empty();
        self.seen_from_into(origin, &mut rect).then_some(rect)
    }

    /// [`seen_from`](Self::seen_from) written into `rect` (false where `seen_from` gives None,
    /// and then `rect` holds nothing to sample): a guided vertex sets up a portal's rectangle
    /// in its query's lobe, without moving the 150-byte result there.
    #[inline]
    pub fn seen_from_into(&self, origin: Vec3, rect: &mut SphericalRectangle) -> bool {
        let &RectangleFrame {
            corner,
            x,
            y,
            mut z,
            ex_len,
            ey_len,
        } = self;
        let d = (corner - origin).as_dvec3();
        let (x0, y0) = (d.dot(x), d.dot(y));
        let mut z0 = d.dot(z);
        if z0 > 0.0 {
            z0 = -z0;
            z = -z;
        }
        // In the plane (relative to the rectangle's size): no solid angle to speak of.
        if !(z0 < -1e-6 * ex_len.max(ey_len)) {
            return false;
        }
        let (x1, y1) = (x0 + ex_len, y0 + ey_len);
        *rect = SphericalRectangle {
            x,
            y,
            z,
            x0,
            x1,
            y0,
            y1,
            z0,
            angles: std::sync::OnceLock::new(),
        };
        // Solid angle >= area |z0| / r³ with r the farthest corner's distance (cos / r² over
        // the rectangle, cos = |z0| / r at distance r).
        let far2 = [x0, x1]
            .into_iter()
            .flat_map(|u| [y0, y1].map(|v| u * u + v * v))
            .fold(0.0, f64::max)
            + z0 * z0;
        let lower_bound = ex_len * ey_len * -z0 / (far2 * far2.sqrt());
        if !(lower_bound >= DEFERRED_SOLID_ANGLE) {
            let solid_angle = rect.angles().solid_angle;
            if !(solid_angle > 0.0 && solid_angle.is_finite()) {
                return false;
            }
        }
        true
    }
}

impl SphericalRectangle {
    /// A placeholder that no origin sees (zero extent), for storage a rectangle is later
    /// written into ([`RectangleFrame::seen_from_into`]); not to be sampled.
    pub const fn empty() -> SphericalRectangle {
        SphericalRectangle {
            x: glam::DVec3::X,
            y: glam::DVec3::Y,
            z: glam::DVec3::Z,
            x0: 0.0,
            x1: 0.0,
            y0: 0.0,
            y1: 0.0,
            z0: 0.0,
            angles: std::sync::OnceLock::new(),
        }
    }

    /// The rectangle `corner + a ex + b ey` for a in [0, ex_len], b in [0, ey_len] (`ex`, `ey`
    /// orthonormal), seen from `origin`. None when the origin is (nearly) in the rectangle's
    /// plane or the solid angle is not a positive finite number: the caller must not sample it.
    pub fn new(
        origin: Vec3,
        corner: Vec3,
        ex: Vec3,
        ey: Vec3,
        ex_len: f32,
        ey_len: f32,
    ) -> Option<SphericalRectangle> {
        RectangleFrame::new(corner, ex, ey, ex_len, ey_len)?.seen_from(origin)
    }

    /// The four angles between the great circles of the edges (computed once).
    fn angles(&self) -> &RectangleAngles {
        self.angles.get_or_init(|| {
            let (x0, x1, y0, y1, z0) = (self.x0, self.x1, self.y0, self.y1, self.z0);
            let v00 = glam::DVec3::new(x0, y0, z0);
            let v01 = glam::DVec3::new(x0, y1, z0);
            let v10 = glam::DVec3::new(x1, y0, z0);
            let v11 = glam::DVec3::new(x1, y1, z0);
            let n0 = v00.cross(v10).normalize();
            let n1 = v10.cross(v11).normalize();
            let n2 = v11.cross(v01).normalize();
            let n3 = v01.cross(v00).normalize();
            let angle = |a: glam::DVec3, b: glam::DVec3| (-a.dot(b)).clamp(-1.0, 1.0).acos();
            let (g0, g1, g2, g3) = (angle(n0, n1), angle(n1, n2), angle(n2, n3), angle(n3, n0));
            let k = 2.0 * std::f64::consts::PI - g2 - g3;
            RectangleAngles {
                b0: n0.z,
                b1: n2.z,
                k,
                solid_angle: g0 + g1 - k,
            }
        })
    }

    /// Solid angle of the rectangle seen from the origin (sr).
    pub fn solid_angle(&self) -> f32 {
        self.angles().solid_angle as f32
    }

    /// A unit direction from the origin toward the rectangle, uniform in solid angle (the
    /// paper's algorithm: u picks the x coordinate by the solid angle to its left, v the y
    /// coordinate by the cosine of the elevation within that column).
    pub fn sample(&self, u: Vec2) -> Vec3 {
        let (uu, uv) = (u.x as f64, u.y as f64);
        let &RectangleAngles {
            b0,
            b1,
            k,
            solid_angle,
        } = self.angles();
        let au = uu * solid_angle + k;
        let fu = (au.cos() * b0 - b1) / au.sin();
        let cu = (1.0f64.copysign(fu) / (fu * fu + b0 * b0).sqrt()).clamp(-1.0, 1.0);
        let xu = (-(cu * self.z0) / (1.0 - cu * cu).max(1e-300).sqrt()).clamp(self.x0, self.x1);
        let d = (xu * xu + self.z0 * self.z0).sqrt();
        let h0 = self.y0 / (d * d + self.y0 * self.y0).sqrt();
        let h1 = self.y1 / (d * d + self.y1 * self.y1).sqrt();
        let hv = h0 + uv * (h1 - h0);
        let hv2 = hv * hv;
        let yv = if hv2 < 1.0 - 1e-12 {
            (hv * d / (1.0 - hv2).sqrt()).clamp(self.y0, self.y1)
        } else if hv < 0.0 {
            self.y0
        } else {
            self.y1
        };
        let w = self.x * xu + self.y * yv + self.z * self.z0;
        w.normalize().as_vec3()
    }

    /// Solid-angle density of [`sample`](Self::sample) at unit direction `w`: 1 / solid angle
    /// where the ray from the origin along `w` hits the rectangle, else 0.
    pub fn pdf(&self, w: Vec3) -> f32 {
        let w = w.as_dvec3();
        let wz = w.dot(self.z);
        if wz >= 0.0 {
            return 0.0;
        }
        let t = self.z0 / wz;
        let (hx, hy) = (t * w.dot(self.x), t * w.dot(self.y));
        if (self.x0..=self.x1).contains(&hx) && (self.y0..=self.y1).contains(&hy) {
            (1.0 / self.angles().solid_angle) as f32
        } else {
            0.0
        }
    }
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

    /// Rectangles seen from near, far, oblique and grazing origins, on both sides.
    fn test_rectangles() -> Vec<SphericalRectangle> {
        let corner = Vec3::new(-0.5, -2.0, 1.0);
        let (ex, ey) = (Vec3::X, Vec3::Y);
        let mut rects = Vec::new();
        for origin in [
            Vec3::ZERO,
            Vec3::new(3.0, 1.0, -2.0),
            Vec3::new(0.2, 0.3, 6.0),
            Vec3::new(0.0, 0.0, 0.999),
            Vec3::new(2.0, 0.0, 1.5),
        ] {
            rects.push(SphericalRectangle::new(origin, corner, ex, ey, 1.0, 4.0).unwrap());
        }
        // A slit turned off the axes.
        let (u, v) = (
            Vec3::new(1.0, 1.0, 0.0).normalize(),
            Vec3::new(-1.0, 1.0, 1.0).normalize(),
        );
        let v = (v - u * u.dot(v)).normalize();
        rects.push(
            SphericalRectangle::new(
                Vec3::new(0.1, -0.4, 0.3),
                Vec3::new(1.0, 0.5, 2.0),
                u,
                v,
                0.1,
                3.0,
            )
            .unwrap(),
        );
        rects
    }

    #[test]
    fn spherical_rectangle_samples_hit_it_and_match_their_pdf() {
        let mut rng = Rng::new(3, 0);
        for rect in test_rectangles() {
            for _ in 0..20_000 {
                let w = rect.sample(rng.uniform2());
                assert!(w.is_finite() && (w.length() - 1.0).abs() < 1e-4, "{w}");
                // Samples on the rectangle's outline may miss it by rounding.
                let pdf = rect.pdf(w);
                assert!(pdf == 0.0 || (pdf - 1.0 / rect.solid_angle()).abs() < 1e-6 * pdf);
            }
            let hits = (0..20_000)
                .filter(|_| rect.pdf(rect.sample(rng.uniform2())) > 0.0)
                .count();
            assert!(hits > 19_900, "{hits} of 20000 samples hit the rectangle");
        }
    }

    #[test]
    fn spherical_rectangle_pdf_integrates_to_one_and_solid_angle_is_exact() {
        // The solid angle of a rectangle seen from a point on the normal through its corner:
        // atan(a b / (d sqrt(a² + b² + d²))).
        let (a, b, d) = (1.0f32, 4.0f32, 1.0f32);
        let rect =
            SphericalRectangle::new(Vec3::ZERO, Vec3::new(0.0, 0.0, d), Vec3::X, Vec3::Y, a, b)
                .unwrap();
        let exact = (a * b / (d * (a * a + b * b + d * d).sqrt())).atan();
        assert!(
            (rect.solid_angle() - exact).abs() < 1e-6,
            "{} {exact}",
            rect.solid_angle()
        );
        for rect in test_rectangles() {
            let i = sphere_integral(|w| rect.pdf(w));
            // The midpoint rule resolves the outline only to its cell size.
            assert!((i - 1.0).abs() < 3e-2, "{i} {rect:?}");
        }
        // A far rectangle keeps its tiny solid angle (the f64 setup does not cancel).
        let far = SphericalRectangle::new(
            Vec3::ZERO,
            Vec3::new(0.0, 0.0, 1e4),
            Vec3::X,
            Vec3::Y,
            1.0,
            1.0,
        )
        .unwrap();
        assert!(
            (far.solid_angle() / 1e-8 - 1.0).abs() < 1e-3,
            "{}",
            far.solid_angle()
        );
    }

    /// Rectangles whose angles wait for their first use (a lower bound on the solid angle
    /// above `DEFERRED_SOLID_ANGLE`) and those set up at once, on either side of that bound:
    /// the solid angle is positive, finite and the closed form's whichever way it was made.
    #[test]
    fn spherical_rectangle_solid_angle_is_right_deferred_or_not() {
        let (a, b) = (1.0f32, 4.0f32);
        for d in [1e-3f32, 1.0, 10.0, 100.0, 1e3, 1.9e3, 2.1e3, 1e4] {
            let rect =
                SphericalRectangle::new(Vec3::ZERO, Vec3::new(0.0, 0.0, d), Vec3::X, Vec3::Y, a, b)
                    .unwrap();
            let (a, b, d) = (a as f64, b as f64, d as f64);
            let exact = (a * b / (d * (a * a + b * b + d * d).sqrt())).atan();
            let deferred = rect.angles.get().is_none();
            let got = rect.solid_angle() as f64;
            assert!(
                got > 0.0 && (got / exact - 1.0).abs() < 1e-3,
                "d {d} (deferred {deferred}): {got} against {exact}"
            );
            assert_eq!(deferred, d < 2000.0, "d {d}");
        }
    }

    #[test]
    fn spherical_rectangle_refuses_origins_in_its_plane() {
        let corner = Vec3::new(-0.5, -2.0, 1.0);
        assert!(SphericalRectangle::new(
            Vec3::new(3.0, 0.0, 1.0),
            corner,
            Vec3::X,
            Vec3::Y,
            1.0,
            4.0
        )
        .is_none());
        assert!(SphericalRectangle::new(Vec3::ZERO, corner, Vec3::X, Vec3::Y, 0.0, 4.0).is_none());
        assert!(
            SphericalRectangle::new(Vec3::ZERO, corner, Vec3::X, Vec3::Y, f32::NAN, 4.0).is_none()
        );
        // Nearly in the plane: either refused or finite everywhere.
        if let Some(r) = SphericalRectangle::new(
            Vec3::new(3.0, 0.0, 1.0 + 1e-5),
            corner,
            Vec3::X,
            Vec3::Y,
            1.0,
            4.0,
        ) {
            let mut rng = Rng::new(9, 0);
            for _ in 0..1000 {
                let w = r.sample(rng.uniform2());
                assert!(w.is_finite() && r.pdf(w).is_finite());
            }
        }
    }
}
