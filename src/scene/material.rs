//! Materials (what the scene stores) and BSDFs (a material resolved at one surface point).
//!
//! BSDFs work in the local shading frame, z = shading normal; `wo` and `wi` point away from
//! the surface. `eval` returns f (no cosine); `sample` returns f, the sampled direction and its
//! solid-angle pdf. Opaque BSDFs are two-sided: they reflect on whichever side `wo` is.

use super::microfacet;
use crate::error::{Error, Result};
use crate::math::{luminance, warp, Rgb, Sampler, Vec2, Vec3, INV_2PI, INV_PI};

/// Index of a texture in the scene.
pub type TextureId = u32;

/// The reflection models Lacuna supports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MaterialKind {
    /// Lambertian reflection, albedo `diffuse`.
    Diffuse,
    /// Modified Phong (Lafortune and Willems 1994), the glossy model of both source theses:
    /// `diffuse / pi + specular (n + 2) / (2 pi) cos^n(alpha)`, alpha the angle to the mirror
    /// direction. Energy conserving when `diffuse + specular <= 1` per channel.
    Glossy,
    /// Perfect mirror with reflectance `specular`.
    Mirror,
    /// Smooth dielectric interface (glass) with index of refraction `ior`.
    Dielectric,
    /// Rough dielectric interface (frosted glass): GGX microfacet reflection and transmission
    /// (Walter et al. 2007) with index of refraction `ior` and GGX width `roughness`.
    RoughDielectric,
}

/// A surface material. Emission makes every triangle using it an area light.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub name: String,
    pub kind: MaterialKind,
    pub diffuse: Rgb,
    pub diffuse_texture: Option<TextureId>,
    pub specular: Rgb,
    /// Phong exponent n (0..=1e6).
    pub exponent: f32,
    pub ior: f32,
    /// GGX width alpha of a rough dielectric's microfacet normals (0..=1; alpha = tan of the
    /// normals' spread, not squared). Below [`microfacet::MIN_ALPHA`] it is raised to it.
    pub roughness: f32,
    /// Emitted radiance (W sr^-1 m^-2) on the front side.
    pub emission: Rgb,
}

impl Default for Material {
    fn default() -> Self {
        Material {
            name: String::new(),
            kind: MaterialKind::Diffuse,
            diffuse: Rgb::splat(0.5),
            diffuse_texture: None,
            specular: Rgb::ZERO,
            exponent: 1.0,
            ior: 1.5,
            roughness: 0.3,
            emission: Rgb::ZERO,
        }
    }
}

impl Material {
    pub fn diffuse(albedo: Rgb) -> Self {
        Material {
            diffuse: albedo,
            ..Default::default()
        }
    }

    pub fn glossy(diffuse: Rgb, specular: Rgb, exponent: f32) -> Self {
        Material {
            kind: MaterialKind::Glossy,
            diffuse,
            specular,
            exponent,
            ..Default::default()
        }
    }

    pub fn mirror(reflectance: Rgb) -> Self {
        Material {
            kind: MaterialKind::Mirror,
            diffuse: Rgb::ZERO,
            specular: reflectance,
            ..Default::default()
        }
    }

    pub fn dielectric(ior: f32) -> Self {
        Material {
            kind: MaterialKind::Dielectric,
            diffuse: Rgb::ZERO,
            ior,
            ..Default::default()
        }
    }

    pub fn rough_dielectric(ior: f32, roughness: f32) -> Self {
        Material {
            kind: MaterialKind::RoughDielectric,
            diffuse: Rgb::ZERO,
            ior,
            roughness,
            ..Default::default()
        }
    }

    pub fn emissive(radiance: Rgb) -> Self {
        Material {
            diffuse: Rgb::ZERO,
            emission: radiance,
            ..Default::default()
        }
    }

    pub fn is_emissive(&self) -> bool {
        self.emission.max_element() > 0.0
    }

    /// Checks physical plausibility; the message names the material and the field.
    pub fn validate(&self, texture_count: usize) -> Result<()> {
        let name = &self.name;
        let unit = |what: &str, c: Rgb| -> Result<()> {
            if !crate::math::is_finite3(c) || c.min_element() < 0.0 || c.max_element() > 1.0 {
                return Err(Error::invalid(format!(
                    "material '{name}': {what} {c} must be in [0, 1]"
                )));
            }
            Ok(())
        };
        unit("diffuse", self.diffuse)?;
        unit("specular", self.specular)?;
        if self.kind == MaterialKind::Glossy {
            let sum = self.diffuse + self.specular;
            if sum.max_element() > 1.0 + 1e-6 {
                return Err(Error::invalid(format!(
                    "material '{name}': diffuse + specular = {sum} exceeds 1 and would create energy"
                )));
            }
        }
        if !(self.exponent.is_finite() && (0.0..=1e6).contains(&self.exponent)) {
            return Err(Error::invalid(format!(
                "material '{name}': exponent {} must be in [0, 1e6]",
                self.exponent
            )));
        }
        if !(self.ior.is_finite() && self.ior > 0.0) {
            return Err(Error::invalid(format!(
                "material '{name}': ior {} must be positive",
                self.ior
            )));
        }
        if !(self.roughness.is_finite() && (0.0..=1.0).contains(&self.roughness)) {
            return Err(Error::invalid(format!(
                "material '{name}': roughness {} must be in [0, 1]",
                self.roughness
            )));
        }
        if !crate::math::is_finite3(self.emission) || self.emission.min_element() < 0.0 {
            return Err(Error::invalid(format!(
                "material '{name}': emission {} must be finite and >= 0",
                self.emission
            )));
        }
        if let Some(t) = self.diffuse_texture {
            if t as usize >= texture_count {
                return Err(Error::invalid(format!(
                    "material '{name}': texture index {t} out of range ({texture_count} textures)"
                )));
            }
        }
        Ok(())
    }

    /// The BSDF at a point whose (texture-resolved) diffuse colour is `diffuse`.
    pub fn bsdf(&self, diffuse: Rgb) -> Bsdf {
        match self.kind {
            MaterialKind::Diffuse => Bsdf::Lambert { albedo: diffuse },
            MaterialKind::Glossy => {
                let (ld, ls) = (luminance(diffuse), luminance(self.specular));
                let p_specular = if ld + ls > 0.0 { ls / (ld + ls) } else { 0.0 };
                Bsdf::Phong {
                    diffuse,
                    specular: self.specular,
                    exponent: self.exponent,
                    p_specular,
                }
            }
            MaterialKind::Mirror => Bsdf::Mirror {
                reflectance: self.specular,
            },
            MaterialKind::Dielectric => Bsdf::Dielectric { eta: self.ior },
            MaterialKind::RoughDielectric => Bsdf::RoughDielectric {
                eta: self.ior,
                alpha: self.roughness.max(microfacet::MIN_ALPHA),
            },
        }
    }
}

/// Whether radiance (camera paths) or importance (light paths) is transported: refraction
/// scales them differently (Veach 1997 §5.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Transport {
    Radiance,
    Importance,
}

/// A sampled direction.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    pub wi: Vec3,
    /// BSDF value f (for delta lobes, the weight such that f |cos| / pdf is the throughput).
    pub f: Rgb,
    pub pdf: f32,
    /// Sampled from a Dirac lobe: no other strategy can produce this direction.
    pub delta: bool,
}

/// A material resolved at one point.
#[derive(Clone, Copy, Debug)]
pub enum Bsdf {
    Lambert {
        albedo: Rgb,
    },
    Phong {
        diffuse: Rgb,
        specular: Rgb,
        exponent: f32,
        p_specular: f32,
    },
    Mirror {
        reflectance: Rgb,
    },
    Dielectric {
        eta: f32,
    },
    /// `eta` as for `Dielectric`; `alpha` the GGX width, at least [`microfacet::MIN_ALPHA`].
    RoughDielectric {
        eta: f32,
        alpha: f32,
    },
}

/// The Lambertian [`Bsdf::eval`].
#[inline(always)]
fn eval_lambert(albedo: Rgb, wo: Vec3, wi: Vec3) -> Rgb {
    let (wo, wi) = to_upper(wo, wi);
    if wo.z > 0.0 && wi.z > 0.0 {
        albedo * INV_PI
    } else {
        Rgb::ZERO
    }
}

/// The Lambertian [`Bsdf::sample`]: a cosine-weighted direction on `wo`'s side.
#[inline(always)]
fn sample_lambert(albedo: Rgb, wo: Vec3, u: Vec2) -> Option<BsdfSample> {
    if wo.z == 0.0 {
        return None;
    }
    let mut wi = warp::cosine_hemisphere(u);
    if wo.z < 0.0 {
        wi.z = -wi.z;
    }
    let pdf = warp::cosine_hemisphere_pdf(Vec3::new(wi.x, wi.y, wi.z.abs()));
    if pdf <= 0.0 {
        return None;
    }
    Some(BsdfSample {
        wi,
        f: albedo * INV_PI,
        pdf,
        delta: false,
    })
}

/// Flips both directions to the upper hemisphere when `wo` is below: opaque BSDFs are two-sided.
#[inline]
fn to_upper(wo: Vec3, wi: Vec3) -> (Vec3, Vec3) {
    if wo.z < 0.0 {
        (Vec3::new(wo.x, wo.y, -wo.z), Vec3::new(wi.x, wi.y, -wi.z))
    } else {
        (wo, wi)
    }
}

#[inline]
fn mirror_local(w: Vec3) -> Vec3 {
    Vec3::new(-w.x, -w.y, w.z)
}

/// Unpolarised Fresnel reflectance of a dielectric interface. `cos_i` is signed (negative when
/// arriving from inside) and `eta` is the inside/outside index ratio.
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let (cos_i, eta) = if cos_i < 0.0 {
        (-cos_i, 1.0 / eta)
    } else {
        (cos_i, eta)
    };
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let r_par = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (r_par * r_par + r_perp * r_perp)
}

impl Bsdf {
    /// True when all the BSDF's lobes are Dirac deltas (NEE is then useless).
    pub fn is_delta(&self) -> bool {
        matches!(self, Bsdf::Mirror { .. } | Bsdf::Dielectric { .. })
    }

    /// Whether light can leave across the surface (refraction): for those BSDFs a connection
    /// may leave on either side of it, for the others only on the side light arrived from.
    pub fn transmits(&self) -> bool {
        matches!(self, Bsdf::Dielectric { .. } | Bsdf::RoughDielectric { .. })
    }

    /// Albedo used for the albedo AOV.
    pub fn albedo_hint(&self) -> Rgb {
        match *self {
            Bsdf::Lambert { albedo } => albedo,
            Bsdf::Phong {
                diffuse, specular, ..
            } => diffuse + specular,
            Bsdf::Mirror { reflectance } => reflectance,
            Bsdf::Dielectric { .. } | Bsdf::RoughDielectric { .. } => Rgb::ONE,
        }
    }

    /// f(wo, wi); zero for delta lobes. `mode` matters only for transmission: the BSDF of a
    /// light path's vertex (`Importance`, `wo` towards the light) is the adjoint, which lacks
    /// the radiance's (eta_wo / eta_wi)^2 (Veach 1997 §5.2).
    #[inline(always)]
    pub fn eval(&self, wo: Vec3, wi: Vec3, mode: Transport) -> Rgb {
        // The diffuse case inlines into the callers; the others stay one call.
        match *self {
            Bsdf::Lambert { albedo } => eval_lambert(albedo, wo, wi),
            _ => self.eval_other(wo, wi, mode),
        }
    }

    /// [`eval`](Self::eval) of the BSDFs other than Lambert's.
    #[inline(never)]
    fn eval_other(&self, wo: Vec3, wi: Vec3, mode: Transport) -> Rgb {
        match *self {
            Bsdf::Lambert { albedo } => eval_lambert(albedo, wo, wi),
            Bsdf::Phong {
                diffuse,
                specular,
                exponent,
                ..
            } => {
                let (wo, wi) = to_upper(wo, wi);
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    return Rgb::ZERO;
                }
                // Zero behind the lobe, as in `pdf` (0^0 = 1 would make exponent 0 reflect
                // where the lobe is never sampled).
                let cos_alpha = mirror_local(wo).dot(wi);
                let lobe = if cos_alpha > 0.0 {
                    cos_alpha.powf(exponent)
                } else {
                    0.0
                };
                diffuse * INV_PI + specular * ((exponent + 2.0) * INV_2PI * lobe)
            }
            Bsdf::Mirror { .. } | Bsdf::Dielectric { .. } => Rgb::ZERO,
            Bsdf::RoughDielectric { eta, alpha } => {
                Rgb::splat(microfacet::RoughDielectric { eta, alpha }.eval(wo, wi, mode))
            }
        }
    }

    /// Solid-angle pdf of `sample` producing `wi`; zero for delta lobes.
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        match *self {
            Bsdf::Lambert { .. } => {
                let (wo, wi) = to_upper(wo, wi);
                if wo.z > 0.0 {
                    warp::cosine_hemisphere_pdf(wi)
                } else {
                    0.0
                }
            }
            Bsdf::Phong {
                exponent,
                p_specular,
                ..
            } => {
                let (wo, wi) = to_upper(wo, wi);
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    return 0.0;
                }
                let r = mirror_local(wo);
                let cos_alpha = r.dot(wi);
                let spec = if cos_alpha > 0.0 {
                    (exponent + 1.0) * INV_2PI * cos_alpha.powf(exponent)
                } else {
                    0.0
                };
                (1.0 - p_specular) * warp::cosine_hemisphere_pdf(wi) + p_specular * spec
            }
            Bsdf::Mirror { .. } | Bsdf::Dielectric { .. } => 0.0,
            Bsdf::RoughDielectric { eta, alpha } => {
                microfacet::RoughDielectric { eta, alpha }.pdf(wo, wi)
            }
        }
    }

    /// Samples an incident direction with `uc` choosing the lobe and `u` the direction.
    /// Returns `None` when the sample carries no energy (below the surface, total absorption).
    /// [`Bsdf::sample`] with its numbers from `rng`: the component choice (one 1-D request),
    /// then the direction (one 2-D request), as `sample(wo, rng.uniform(), rng.uniform2(),
    /// mode)` would draw them, but computing only the ones this BSDF reads (a Lambertian reads
    /// no component choice, a mirror neither number, a dielectric no direction) and skipping
    /// the others' requests, so every request keeps its meaning and the result is the same.
    #[inline(always)]
    pub fn sample_from(&self, wo: Vec3, rng: &mut Sampler, mode: Transport) -> Option<BsdfSample> {
        let (reads_choice, reads_direction) = match self {
            Bsdf::Lambert { .. } => (false, true),
            Bsdf::Phong { .. } => (true, true),
            Bsdf::Mirror { .. } => (false, false),
            Bsdf::Dielectric { .. } => (true, false),
            Bsdf::RoughDielectric { .. } => (true, true),
        };
        let uc = if reads_choice {
            rng.uniform()
        } else {
            rng.skip_uniform();
            0.0
        };
        let u = if reads_direction {
            rng.uniform2()
        } else {
            rng.skip_uniform2();
            Vec2::ZERO
        };
        // The diffuse walls of an interior are most vertices: their sample inlines here.
        if let Bsdf::Lambert { albedo } = *self {
            return sample_lambert(albedo, wo, u);
        }
        self.sample(wo, uc, u, mode)
    }

    pub fn sample(&self, wo: Vec3, uc: f32, u: Vec2, mode: Transport) -> Option<BsdfSample> {
        match *self {
            Bsdf::Lambert { albedo } => sample_lambert(albedo, wo, u),
            Bsdf::Phong {
                exponent,
                p_specular,
                ..
            } => {
                if wo.z == 0.0 {
                    return None;
                }
                let flip = wo.z < 0.0;
                let wo_up = if flip {
                    Vec3::new(wo.x, wo.y, -wo.z)
                } else {
                    wo
                };
                let wi_up = if uc < p_specular {
                    let lobe = warp::power_cosine(u, exponent);
                    crate::math::Frame::from_z(mirror_local(wo_up)).to_world(lobe)
                } else {
                    warp::cosine_hemisphere(u)
                };
                if wi_up.z <= 0.0 {
                    return None;
                }
                let wi = if flip {
                    Vec3::new(wi_up.x, wi_up.y, -wi_up.z)
                } else {
                    wi_up
                };
                let pdf = self.pdf(wo, wi);
                if pdf <= 0.0 || !pdf.is_finite() {
                    return None;
                }
                Some(BsdfSample {
                    wi,
                    f: self.eval(wo, wi, mode),
                    pdf,
                    delta: false,
                })
            }
            Bsdf::Mirror { reflectance } => {
                if wo.z == 0.0 {
                    return None;
                }
                let wi = mirror_local(wo);
                let f = reflectance / wi.z.abs();
                // |wo.z| below ~3e-39 overflows f to infinity.
                if !crate::math::is_finite3(f) {
                    return None;
                }
                Some(BsdfSample {
                    wi,
                    f,
                    pdf: 1.0,
                    delta: true,
                })
            }
            Bsdf::Dielectric { eta } => {
                if wo.z == 0.0 {
                    return None;
                }
                let f = fresnel_dielectric(wo.z, eta);
                if uc < f {
                    let wi = mirror_local(wo);
                    let fr = f / wi.z.abs();
                    // |wo.z| below ~3e-39 overflows the weight to infinity.
                    if !fr.is_finite() {
                        return None;
                    }
                    return Some(BsdfSample {
                        wi,
                        f: Rgb::splat(fr),
                        pdf: f,
                        delta: true,
                    });
                }
                // Refraction: eta_rel is the ratio of the index on the far side to the near side.
                let eta_rel = if wo.z > 0.0 { eta } else { 1.0 / eta };
                let n = Vec3::new(0.0, 0.0, wo.z.signum());
                let cos_i = wo.z.abs();
                let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta_rel * eta_rel);
                if sin2_t >= 1.0 {
                    return None; // Unreachable: total internal reflection has f = 1.
                }
                let cos_t = (1.0 - sin2_t).sqrt();
                let wi = (-wo / eta_rel + n * (cos_i / eta_rel - cos_t)).normalize();
                let mut ft = (1.0 - f) / wi.z.abs();
                if mode == Transport::Radiance {
                    // Radiance is compressed entering a denser medium (Veach 1997 §5.2).
                    ft /= eta_rel * eta_rel;
                }
                if !ft.is_finite() {
                    return None;
                }
                Some(BsdfSample {
                    wi,
                    f: Rgb::splat(ft),
                    pdf: 1.0 - f,
                    delta: true,
                })
            }
            Bsdf::RoughDielectric { eta, alpha } => {
                microfacet::RoughDielectric { eta, alpha }.sample(wo, uc, u, mode)
            }
        }
    }
}
