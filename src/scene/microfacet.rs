//! The rough dielectric BSDF: GGX microfacet reflection and transmission after Walter, Marschner,
//! Li and Torrance 2007, "Microfacet models for refraction through rough surfaces" (eq. 20-21,
//! with their separable Smith G, eq. 23), sampled by the distribution of visible normals
//! (Heitz 2018, "Sampling the GGX distribution of visible normals"), then Fresnel choosing
//! reflection or refraction at the sampled microfacet.
//!
//! Local frame, z = the macro normal, both directions pointing away from the surface; `eta` is
//! the index inside (z < 0) over the index outside (z > 0), as for the smooth dielectric.

use crate::math::{Vec2, Vec3, PI};

use super::material::{fresnel_dielectric, BsdfSample, Transport};
use crate::math::Rgb;

/// Smallest GGX width used. D peaks at 1 / (pi alpha^2) and the lobe is about alpha radians
/// wide: at alpha = 1e-3 the peak is 3e5 and the lobe still spans ~8000 f32 ulps of a unit
/// direction, so the half vector, D and the Jacobians stay accurate; much below, the lobe
/// shrinks to a few ulps, rounding decides which directions are in it and pdf and sampling
/// disagree. A smooth interface is `Dielectric`.
pub const MIN_ALPHA: f32 = 1e-3;

/// GGX normal distribution D(m) for a unit `m` with m.z > 0 (Walter et al. eq. 33), written with
/// sin^2 = x^2 + y^2 so that no cancellation occurs near the pole.
fn ggx_d(m: Vec3, alpha: f32) -> f32 {
    let a2 = alpha * alpha;
    let t = m.x * m.x + m.y * m.y + m.z * m.z * a2;
    a2 / (PI * t * t)
}

/// Smith masking G1 of GGX for direction `w` (Walter et al. eq. 34): 2 |z| / (|z| +
/// sqrt(z^2 + alpha^2 (x^2 + y^2))), the same as 2 / (1 + sqrt(1 + alpha^2 tan^2)) without the
/// tangent's overflow at grazing angles.
fn smith_g1(w: Vec3, alpha: f32) -> f32 {
    let z = w.z.abs();
    let r = (w.z * w.z + alpha * alpha * (w.x * w.x + w.y * w.y)).sqrt();
    if z + r == 0.0 {
        0.0
    } else {
        2.0 * z / (z + r)
    }
}

/// Heitz 2018's sampling of a microfacet normal visible from `w` (w.z > 0), density
/// G1(w) max(0, w.m) D(m) / w.z.
fn sample_visible_normal(w: Vec3, alpha: f32, u: Vec2) -> Vec3 {
    // Stretch to the hemisphere configuration (alpha = 1).
    let vh = Vec3::new(alpha * w.x, alpha * w.y, w.z).normalize();
    let len2 = vh.x * vh.x + vh.y * vh.y;
    let t1 = if len2 > 0.0 {
        Vec3::new(-vh.y, vh.x, 0.0) / len2.sqrt()
    } else {
        Vec3::X
    };
    let t2 = vh.cross(t1);
    // A point on the disk, its lower half squeezed into the projected hemisphere's outline.
    let r = u.x.sqrt();
    let phi = 2.0 * PI * u.y;
    let p1 = r * phi.cos();
    let s = 0.5 * (1.0 + vh.z);
    let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * (r * phi.sin());
    let nh = t1 * p1 + t2 * p2 + vh * (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt();
    // Unstretch.
    Vec3::new(alpha * nh.x, alpha * nh.y, nh.z.max(0.0)).normalize()
}

/// A rough dielectric interface at one point.
#[derive(Clone, Copy, Debug)]
pub struct RoughDielectric {
    pub eta: f32,
    pub alpha: f32,
}

/// The microfacet normal that scatters `wo` into `wi` and what the BSDF needs of it.
struct HalfVector {
    /// The generalised half vector (Walter et al. eq. 13 and 16), facing z > 0.
    m: Vec3,
    /// Refraction: eta on wi's side over eta on wo's side. Reflection: 1.
    etap: f32,
    reflect: bool,
}

impl RoughDielectric {
    /// The half vector of (wo, wi), or None when no microfacet seen from both directions
    /// joins them (grazing directions, or a microfacet facing away from one of them).
    fn half_vector(&self, wo: Vec3, wi: Vec3) -> Option<HalfVector> {
        if wo.z == 0.0 || wi.z == 0.0 {
            return None;
        }
        let reflect = wo.z * wi.z > 0.0;
        let etap = match (reflect, wo.z > 0.0) {
            (true, _) => 1.0,
            (false, true) => self.eta,
            (false, false) => 1.0 / self.eta,
        };
        let h = wi * etap + wo;
        let len2 = h.length_squared();
        if !(len2 > 0.0) {
            return None;
        }
        let mut m = h / len2.sqrt();
        if m.z < 0.0 {
            m = -m;
        }
        // Both directions must see the microfacet from their own side of the macro surface
        // (the chi+ factors of Walter et al. eq. 20-21 and of G1).
        if m.z <= 0.0 || m.dot(wo) * wo.z <= 0.0 || m.dot(wi) * wi.z <= 0.0 {
            return None;
        }
        Some(HalfVector { m, etap, reflect })
    }

    /// Fresnel reflectance at microfacet `m` for the pair (wo, wi), taken from the direction
    /// on the side of lower index. Both give the same value in exact arithmetic, but near
    /// total internal reflection the denser side's cosine sits at the critical angle, where
    /// F has an infinite derivative, while the other direction is near grazing, where F is
    /// smooth: this keeps f reciprocal to rounding there.
    fn fresnel(&self, wo: Vec3, wi: Vec3, m: Vec3) -> f32 {
        let outside_is_rarer = self.eta >= 1.0;
        let w = if (wo.z > 0.0) == outside_is_rarer || wo.z * wi.z > 0.0 {
            wo
        } else {
            wi
        };
        fresnel_dielectric(w.dot(m), self.eta)
    }

    /// f(wo, wi) (Walter et al. eq. 20 and 21).
    pub fn eval(&self, wo: Vec3, wi: Vec3, mode: Transport) -> f32 {
        let Some(HalfVector { m, etap, reflect }) = self.half_vector(wo, wi) else {
            return 0.0;
        };
        let (dot_o, dot_i) = (wo.dot(m), wi.dot(m));
        let f = self.fresnel(wo, wi, m);
        let d = ggx_d(m, self.alpha);
        let g = smith_g1(wo, self.alpha) * smith_g1(wi, self.alpha);
        let cos_oi = (wo.z * wi.z).abs();
        let value = if reflect {
            d * g * f / (4.0 * cos_oi)
        } else {
            let denom = dot_i + dot_o / etap;
            let t = d * g * (1.0 - f) * (dot_i * dot_o).abs() / (cos_oi * denom * denom);
            match mode {
                // eta_wo^2 / (eta_i (i.m) + eta_o (o.m))^2 of eq. 21 is this over etap^2.
                Transport::Radiance => t / (etap * etap),
                Transport::Importance => t,
            }
        };
        if value.is_finite() {
            value
        } else {
            0.0
        }
    }

    /// Solid-angle density of `sample` producing `wi`: the visible-normal density of the half
    /// vector, times its Jacobian (Walter et al. eq. 14 for reflection, eq. 17 for refraction),
    /// times Fresnel's choice of the branch.
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        let Some(HalfVector { m, etap, reflect }) = self.half_vector(wo, wi) else {
            return 0.0;
        };
        let (dot_o, dot_i) = (wo.dot(m), wi.dot(m));
        let f = self.fresnel(wo, wi, m);
        let pdf_m = smith_g1(wo, self.alpha) * dot_o.abs() * ggx_d(m, self.alpha) / wo.z.abs();
        let pdf = if reflect {
            // dm/dwi = 1 / (4 |wi.m|), and |wi.m| = |wo.m|.
            pdf_m * f / (4.0 * dot_o.abs())
        } else {
            // dm/dwi = eta_i^2 |i.m| / (eta_i (i.m) + eta_o (o.m))^2, divided through by eta_i^2.
            let denom = dot_i + dot_o / etap;
            pdf_m * (1.0 - f) * dot_i.abs() / (denom * denom)
        };
        if pdf.is_finite() {
            pdf
        } else {
            0.0
        }
    }

    /// Samples a visible microfacet normal with `u`, then reflects (probability F) or refracts
    /// with `uc`. f and pdf are [`eval`](Self::eval) and [`pdf`](Self::pdf) at the result, so
    /// the sample agrees with them to the last bit.
    pub fn sample(&self, wo: Vec3, uc: f32, u: Vec2, mode: Transport) -> Option<BsdfSample> {
        if wo.z == 0.0 {
            return None;
        }
        let side = wo.z.signum();
        let m = sample_visible_normal(wo * side, self.alpha, u);
        let dot_o = wo.dot(m);
        if dot_o * side <= 0.0 {
            return None;
        }
        let f = fresnel_dielectric(dot_o, self.eta);
        let reflect = uc < f;
        let wi = if reflect {
            m * (2.0 * dot_o) - wo
        } else {
            // Refraction through m: etap is eta on the far side over eta on wo's side.
            let etap = if side > 0.0 { self.eta } else { 1.0 / self.eta };
            let n = m * side;
            let cos_i = dot_o.abs();
            let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (etap * etap);
            if sin2_t >= 1.0 {
                return None; // Total internal reflection has f = 1: reached only by rounding.
            }
            let cos_t = (1.0 - sin2_t).sqrt();
            (-wo / etap + n * (cos_i / etap - cos_t)).normalize()
        };
        // A microfacet can send a reflection below the macro surface or a refraction back
        // above it: that light is lost (single scattering), and `pdf` counts such a wi as the
        // other branch's, so it must not be returned.
        if (wi.z * wo.z > 0.0) != reflect {
            return None;
        }
        let pdf = self.pdf(wo, wi);
        let value = self.eval(wo, wi, mode);
        if !(pdf > 0.0 && pdf.is_finite()) || value == 0.0 {
            return None;
        }
        Some(BsdfSample {
            wi,
            f: Rgb::splat(value),
            pdf,
            delta: false,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// D is normalised: the integral of D(m) m.z over the hemisphere is 1 (Walter et al. eq. 4).
    #[test]
    fn ggx_projected_area_is_one() {
        for alpha in [0.05f32, 0.3, 1.0] {
            let n = 4000;
            let mut sum = 0.0f64;
            // Substitution t = tan(theta) spread so that narrow lobes are resolved.
            for i in 0..n {
                let theta = (i as f64 + 0.5) / n as f64 * std::f64::consts::FRAC_PI_2;
                let m = Vec3::new(theta.sin() as f32, 0.0, theta.cos() as f32);
                let d = ggx_d(m, alpha) as f64;
                sum += d
                    * theta.cos()
                    * theta.sin()
                    * 2.0
                    * std::f64::consts::PI
                    * (std::f64::consts::FRAC_PI_2 / n as f64);
            }
            assert!((sum - 1.0).abs() < 2e-3, "alpha {alpha}: {sum}");
        }
    }

    /// The visible normals' density integrates to 1 over the hemisphere of m (Heitz 2014 eq. 2
    /// holds for Smith G1): the sampler's target is a density.
    #[test]
    fn visible_normal_density_is_normalised() {
        for alpha in [0.1f32, 0.5, 1.0] {
            for wz in [0.9f32, 0.4, 0.05] {
                let w = Vec3::new((1.0 - wz * wz).sqrt(), 0.0, wz);
                let (nt, np) = (1500, 200);
                let mut sum = 0.0f64;
                for i in 0..nt {
                    let theta = (i as f64 + 0.5) / nt as f64 * std::f64::consts::FRAC_PI_2;
                    for j in 0..np {
                        let phi = (j as f64 + 0.5) / np as f64 * 2.0 * std::f64::consts::PI;
                        let m = Vec3::new(
                            (theta.sin() * phi.cos()) as f32,
                            (theta.sin() * phi.sin()) as f32,
                            theta.cos() as f32,
                        );
                        let dens = smith_g1(w, alpha) * w.dot(m).max(0.0) * ggx_d(m, alpha) / w.z;
                        sum += dens as f64
                            * theta.sin()
                            * (std::f64::consts::FRAC_PI_2 / nt as f64)
                            * (2.0 * std::f64::consts::PI / np as f64);
                    }
                }
                assert!((sum - 1.0).abs() < 5e-3, "alpha {alpha} wz {wz}: {sum}");
            }
        }
    }
}
