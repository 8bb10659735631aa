//! Light sources and their sampling. Every `sample` returns the solid-angle pdf at the
//! receiving point, and `pdf` returns the same value for a direction found by other means
//! (BSDF sampling hitting an emitter), so the two strategies can be combined by MIS.

mod emission;
pub mod environment;
pub mod light_field;
pub mod photometric;
mod selection;
pub mod triangle;

pub use emission::EmissionSample;
pub use environment::{EnvSettings, EnvStrategy, EnvironmentMap, UpAxis};
pub use light_field::{FilterBasis, LightField, LightFieldLayout, LightFieldSampling};
pub use photometric::PhotometricProfile;
pub use selection::LightSampler;

use std::sync::Arc;

use crate::error::{Error, Result};
use crate::geometry::{barycentric_point_error, Bounds3};
use crate::math::{is_finite3, luminance, warp, Frame, Rgb, Vec2, Vec3, PI};

/// A light as a host describes it. Area lights are not described here: they come from
/// triangles whose material emits.
#[derive(Clone, Debug)]
pub enum LightDesc {
    /// Isotropic point light with radiant intensity `intensity` (W/sr).
    Point { position: Vec3, intensity: Rgb },
    /// Spot light: intensity `intensity` inside `inner_degrees` of `direction`, smoothly
    /// falling to zero at `outer_degrees` (half-angles).
    Spot {
        position: Vec3,
        direction: Vec3,
        intensity: Rgb,
        inner_degrees: f32,
        outer_degrees: f32,
    },
    /// Distant light travelling along `direction`, giving irradiance `irradiance` (W/m^2) on a
    /// surface facing it.
    Directional { direction: Vec3, irradiance: Rgb },
    /// A measured luminaire (an IES profile) at a point: radiant intensity `intensity` times
    /// the profile's candela towards each direction. The profile's nadir (gamma = 0) points
    /// along `direction` and its C0 plane towards `c0` (projected perpendicular to
    /// `direction`; zero or parallel picks an arbitrary perpendicular axis).
    Photometric {
        position: Vec3,
        direction: Vec3,
        c0: Vec3,
        intensity: Rgb,
        profile: Arc<PhotometricProfile>,
    },
    /// A light-field luminaire (docs/light-field.md), its local origin (on the filter plane)
    /// at `position`, light travelling along `direction` (its +z), its local
    /// +x toward `x_axis` (projected perpendicular to `direction`; zero or parallel picks an
    /// arbitrary perpendicular axis); the field's radiance times `scale`.
    LightField {
        position: Vec3,
        direction: Vec3,
        x_axis: Vec3,
        scale: Rgb,
        field: Arc<LightField>,
    },
}

impl LightDesc {
    pub fn validate(&self) -> Result<()> {
        let colour = |name: &str, c: Rgb| {
            if !is_finite3(c) || c.min_element() < 0.0 {
                Err(Error::invalid(format!(
                    "light {name} {c} must be finite and >= 0"
                )))
            } else {
                Ok(())
            }
        };
        let point = |p: Vec3| {
            if is_finite3(p) {
                Ok(())
            } else {
                Err(Error::invalid(format!("light position {p} must be finite")))
            }
        };
        let dir = |d: Vec3| {
            if is_finite3(d) && d.length_squared() > 0.0 {
                Ok(())
            } else {
                Err(Error::invalid(format!(
                    "light direction {d} must be finite and non-zero"
                )))
            }
        };
        match *self {
            LightDesc::Point {
                position,
                intensity,
            } => {
                point(position)?;
                colour("intensity", intensity)
            }
            LightDesc::Spot {
                position,
                direction,
                intensity,
                inner_degrees,
                outer_degrees,
            } => {
                point(position)?;
                dir(direction)?;
                colour("intensity", intensity)?;
                if !(0.0..=180.0).contains(&outer_degrees)
                    || !(0.0..=outer_degrees).contains(&inner_degrees)
                {
                    return Err(Error::invalid(format!(
                        "spot angles inner {inner_degrees} and outer {outer_degrees} must satisfy 0 <= inner <= outer <= 180"
                    )));
                }
                Ok(())
            }
            LightDesc::Directional {
                direction,
                irradiance,
            } => {
                dir(direction)?;
                colour("irradiance", irradiance)
            }
            LightDesc::Photometric {
                position,
                direction,
                c0,
                intensity,
                ..
            } => {
                point(position)?;
                dir(direction)?;
                if !is_finite3(c0) {
                    return Err(Error::invalid(format!("light c0 axis {c0} must be finite")));
                }
                colour("intensity", intensity)
            }
            LightDesc::LightField {
                position,
                direction,
                x_axis,
                scale,
                ..
            } => {
                point(position)?;
                dir(direction)?;
                if !is_finite3(x_axis) {
                    return Err(Error::invalid(format!(
                        "light x axis {x_axis} must be finite"
                    )));
                }
                colour("scale", scale)
            }
        }
    }
}

/// The frame of a light-field luminaire from its `direction` and `x_axis` (as the light and
/// the luminaire capture place it): the photometric light's frame.
pub fn light_field_frame(direction: Vec3, x_axis: Vec3) -> Frame {
    photometric_frame(direction, x_axis)
}

/// The frame of a photometric light: z its nadir `direction`, x the C0 axis (`c0` made
/// perpendicular), y = z x x the C90 axis.
fn photometric_frame(direction: Vec3, c0: Vec3) -> Frame {
    let n = direction.normalize();
    let s = (c0 - n * c0.dot(n)).try_normalize();
    match s {
        Some(s) => Frame {
            s,
            t: n.cross(s),
            n,
        },
        None => Frame::from_z(n),
    }
}

/// A light ready for sampling.
#[derive(Clone, Debug)]
pub enum Light {
    /// One emissive triangle, emitting `radiance` on the side of `normal`.
    Area {
        triangle: u32,
        p: [Vec3; 3],
        normal: Vec3,
        area: f32,
        radiance: Rgb,
    },
    Point {
        position: Vec3,
        intensity: Rgb,
    },
    Spot {
        position: Vec3,
        direction: Vec3,
        intensity: Rgb,
        cos_inner: f32,
        cos_outer: f32,
    },
    /// `direction` is where the light travels; the scene's bounding sphere (`scene_center`,
    /// `scene_radius`) gives its power and where emitted rays start.
    Directional {
        direction: Vec3,
        irradiance: Rgb,
        scene_center: Vec3,
        scene_radius: f32,
    },
    /// An environment map at infinity. Like a directional light, the scene's bounding sphere
    /// gives its power and the disk where emitted rays start.
    Environment {
        map: Arc<EnvironmentMap>,
        scene_center: Vec3,
        scene_radius: f32,
    },
    /// A measured luminaire; `frame` maps the profile's (C0, C90, nadir) axes to the world.
    Photometric {
        position: Vec3,
        frame: Frame,
        intensity: Rgb,
        profile: Arc<PhotometricProfile>,
    },
    /// A light-field luminaire; `frame` maps its local axes (z: where light travels) to the
    /// world, `position` is its local origin (on the filter plane).
    LightField {
        position: Vec3,
        frame: Frame,
        scale: Rgb,
        field: Arc<LightField>,
    },
}

/// Radiance arriving at a point from a sampled point of a light.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    /// Unit direction from the receiver towards the light.
    pub wi: Vec3,
    /// Incident radiance (or, for delta lights, the value whose ratio to `pdf` is the
    /// contribution).
    pub radiance: Rgb,
    /// Solid-angle density (not including the light selection probability); 1 for delta lights
    /// (a light-field luminaire has its true density, though its samples are `delta`).
    pub pdf: f32,
    /// The point on the light (for the shadow ray) with its error bound and normal.
    /// `distance` is infinite for directional lights.
    pub point: Vec3,
    pub point_error: Vec3,
    pub normal: Vec3,
    pub distance: f32,
    /// No other strategy finds this point (a delta light, or a light-field luminaire, which
    /// rays never hit): its MIS weight is 1.
    pub delta: bool,
}

impl LightSample {
    /// An environment direction sampled for `receiver` (infinitely far, no delta).
    pub fn from_environment(s: environment::EnvSample, receiver: Vec3) -> Self {
        LightSample {
            wi: s.wi,
            radiance: s.radiance,
            pdf: s.pdf,
            point: receiver,
            point_error: Vec3::ZERO,
            normal: -s.wi,
            distance: f32::INFINITY,
            delta: false,
        }
    }
}

impl Light {
    pub fn from_desc(desc: &LightDesc, bounds: &Bounds3) -> Light {
        match *desc {
            LightDesc::Photometric {
                position,
                direction,
                c0,
                intensity,
                ref profile,
            } => Light::Photometric {
                position,
                frame: photometric_frame(direction, c0),
                intensity,
                profile: profile.clone(),
            },
            LightDesc::LightField {
                position,
                direction,
                x_axis,
                scale,
                ref field,
            } => Light::LightField {
                position,
                frame: light_field_frame(direction, x_axis),
                scale,
                field: field.clone(),
            },
            LightDesc::Point {
                position,
                intensity,
            } => Light::Point {
                position,
                intensity,
            },
            LightDesc::Spot {
                position,
                direction,
                intensity,
                inner_degrees,
                outer_degrees,
            } => Light::Spot {
                position,
                direction: direction.normalize(),
                intensity,
                cos_inner: inner_degrees.to_radians().cos(),
                cos_outer: outer_degrees.to_radians().cos(),
            },
            LightDesc::Directional {
                direction,
                irradiance,
            } => {
                let (scene_center, radius) = bounds.bounding_sphere();
                Light::Directional {
                    direction: direction.normalize(),
                    irradiance,
                    scene_center,
                    scene_radius: radius.max(1e-6),
                }
            }
        }
    }

    /// Total emitted power (luminance-weighted), for power-proportional selection.
    pub fn power(&self) -> f32 {
        match *self {
            Light::Area { area, radiance, .. } => PI * area * luminance(radiance),
            Light::Point { intensity, .. } => 4.0 * PI * luminance(intensity),
            Light::Spot {
                intensity,
                cos_inner,
                cos_outer,
                ..
            } => 2.0 * PI * luminance(intensity) * (1.0 - 0.5 * (cos_inner + cos_outer)),
            Light::Directional {
                irradiance,
                scene_radius,
                ..
            } => PI * scene_radius * scene_radius * luminance(irradiance),
            // The flux through the disk of the bounding sphere: pi r^2 times the integral
            // of radiance over all directions.
            Light::Environment {
                ref map,
                scene_radius,
                ..
            } => PI * scene_radius * scene_radius * map.luminance_integral(),
            Light::Photometric {
                intensity,
                ref profile,
                ..
            } => luminance(intensity) * profile.flux(),
            Light::LightField {
                scale, ref field, ..
            } => luminance(scale) * field.power(),
        }
    }

    pub fn is_delta(&self) -> bool {
        !matches!(self, Light::Area { .. } | Light::Environment { .. })
    }

    /// Samples a point of the light as seen from `receiver`, without knowing its normal
    /// (environment maps then use the default strategy, `auto`, with no normal: the
    /// lat-long density, or the cube faces balanced by power).
    pub fn sample(&self, receiver: Vec3, u: Vec2) -> Option<LightSample> {
        self.sample_at(receiver, Vec3::ZERO, EnvStrategy::default(), u)
    }

    /// Samples a point of the light as seen from `receiver` whose shading normal facing the
    /// outgoing direction is `normal` (zero if unknown); `env` is how environment maps pick
    /// directions (other lights ignore both). [`Light::direction_pdf`] gives the matching
    /// density of environment directions.
    ///
    /// Area lights are sampled as [`TriangleSampling::default`] says; [`Light::pdf`] is the
    /// matching density.
    pub fn sample_at(
        &self,
        receiver: Vec3,
        normal: Vec3,
        env: EnvStrategy,
        u: Vec2,
    ) -> Option<LightSample> {
        self.sample_with(receiver, normal, env, TriangleSampling::default(), u)
    }

    /// As [`sample_at`](Self::sample_at) with area lights sampled as `triangles` says;
    /// [`Light::pdf_with`] with the same `triangles` is its density.
    #[inline(always)]
    pub fn sample_with(
        &self,
        receiver: Vec3,
        normal: Vec3,
        env: EnvStrategy,
        triangles: TriangleSampling,
        u: Vec2,
    ) -> Option<LightSample> {
        match *self {
            Light::Area {
                ref p,
                normal,
                area,
                radiance,
                ..
            } => match triangles.solid_angle(p, normal, receiver) {
                Some(solid_angle) => {
                    let b = triangle::sample_spherical_triangle(p, receiver, solid_angle, u)?;
                    area_light_sample(p, normal, radiance, receiver, b, |_| 1.0 / solid_angle)
                }
                _ => {
                    let (b0, b1) = warp::uniform_triangle(u);
                    let b = [b0, b1, 1.0 - b0 - b1];
                    area_light_sample(p, normal, radiance, receiver, b, |d2_over_cos| {
                        d2_over_cos / area
                    })
                }
            },
            Light::Point {
                position,
                intensity,
            } => delta_point_sample(receiver, position, intensity),
            Light::Spot {
                position,
                direction,
                intensity,
                cos_inner,
                cos_outer,
            } => {
                let s = delta_point_sample(receiver, position, intensity)?;
                let falloff = smoothstep(cos_outer, cos_inner, (-s.wi).dot(direction));
                if falloff <= 0.0 {
                    return None;
                }
                Some(LightSample {
                    radiance: s.radiance * falloff,
                    ..s
                })
            }
            Light::Directional {
                direction,
                irradiance,
                ..
            } => Some(LightSample {
                wi: -direction,
                radiance: irradiance,
                pdf: 1.0,
                point: receiver,
                point_error: Vec3::ZERO,
                normal: direction,
                distance: f32::INFINITY,
                delta: true,
            }),
            Light::Photometric {
                position,
                frame,
                intensity,
                ref profile,
            } => {
                let s = delta_point_sample(receiver, position, intensity)?;
                let candela = profile.intensity(frame.to_local(-s.wi));
                if candela <= 0.0 {
                    return None;
                }
                Some(LightSample {
                    radiance: s.radiance * candela,
                    ..s
                })
            }
            Light::Environment { ref map, .. } => Some(LightSample::from_environment(
                map.sample(env, normal, u)?,
                receiver,
            )),
            Light::LightField {
                position,
                frame,
                scale,
                ref field,
            } => light_field_sample(position, frame, scale, field, receiver, u),
        }
    }

    /// Solid-angle density of `sample_at(.., normal, env, ..)` choosing direction `wi` of an
    /// environment map; zero for other lights (their densities come from `pdf`).
    pub fn direction_pdf(&self, normal: Vec3, env: EnvStrategy, wi: Vec3) -> f32 {
        match self {
            Light::Environment { map, .. } => map.pdf(env, normal, wi),
            _ => 0.0,
        }
    }

    /// Solid-angle pdf of `sample` choosing the light point `point` seen from `receiver`; zero
    /// for delta lights.
    pub fn pdf(&self, receiver: Vec3, point: Vec3) -> f32 {
        self.pdf_with(receiver, point, TriangleSampling::default())
    }

    /// Solid-angle pdf of [`sample_with`](Self::sample_with) (same `triangles`) choosing the
    /// light point `point` seen from `receiver`.
    pub fn pdf_with(&self, receiver: Vec3, point: Vec3, triangles: TriangleSampling) -> f32 {
        match *self {
            Light::Area {
                ref p,
                normal,
                area,
                ..
            } => {
                // The same operations as `sample`, so that both agree to the bit (a receiver
                // in the light's plane must not get a huge pdf where `sample` gives none).
                let Some(d2_over_cos) = area_light_geometry(normal, receiver, point).map(|g| g.3)
                else {
                    return 0.0;
                };
                let pdf = match triangles.solid_angle(p, normal, receiver) {
                    Some(solid_angle) => 1.0 / solid_angle,
                    None => d2_over_cos / area,
                };
                if pdf.is_finite() {
                    pdf
                } else {
                    0.0
                }
            }
            _ => 0.0,
        }
    }

    /// Radiance leaving an area light towards direction `w` (pointing away from it).
    #[inline]
    pub fn emitted(&self, w: Vec3) -> Rgb {
        match *self {
            Light::Area {
                normal, radiance, ..
            } if w.dot(normal) > 0.0 => radiance,
            _ => Rgb::ZERO,
        }
    }
}

/// How light sampling picks points of area lights (emissive triangles) seen from a receiver.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TriangleSampling {
    /// Uniformly in solid angle where the triangle subtends a moderate solid angle, uniformly
    /// by area where [`triangle::spherical_solid_angle`] says the construction is unreliable
    /// (tiny or nearly hemispherical solid angles). Less error per sample near large, close
    /// lamps, but dearer: not the default (see [`triangle`]).
    SolidAngle,
    /// Uniformly by area: density 1 / area in area measure (also what `bdpt`'s MIS weights
    /// assume of its light vertices). The default: the best at equal time on the Cornell box
    /// and the Veach door.
    #[default]
    Area,
}

impl TriangleSampling {
    pub const NAMES: &'static [&'static str] = &["solid_angle", "area"];

    pub fn parse(name: &str) -> Result<Self> {
        match name {
            "solid_angle" => Ok(TriangleSampling::SolidAngle),
            "area" => Ok(TriangleSampling::Area),
            other => Err(Error::invalid(format!(
                "unknown triangle-light sampling '{other}' (expected solid_angle or area)"
            ))),
        }
    }

    /// The solid angle of triangle `p` seen from `receiver` when it is sampled by solid angle,
    /// `None` when by area: the one choice rule of `Light::sample_with` and `Light::pdf_with`
    /// (the solid angle is only computed when this strategy may use it).
    #[inline]
    fn solid_angle(self, p: &[Vec3; 3], normal: Vec3, receiver: Vec3) -> Option<f32> {
        match self {
            TriangleSampling::SolidAngle => triangle::spherical_solid_angle(p, normal, receiver),
            TriangleSampling::Area => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            TriangleSampling::SolidAngle => "solid_angle",
            TriangleSampling::Area => "area",
        }
    }
}

/// Direction, distance and d^2 / cos(light) from `receiver` to `point` of an area light
/// facing `normal`; `None` when the point coincides with the receiver or the receiver is not in
/// front of it. Shared by sampling and `pdf` so that both agree to the bit.
#[inline]
fn area_light_geometry(normal: Vec3, receiver: Vec3, point: Vec3) -> Option<(Vec3, f32, f32, f32)> {
    let to_light = point - receiver;
    let dist2 = to_light.length_squared();
    if dist2 == 0.0 {
        return None;
    }
    let distance = dist2.sqrt();
    let wi = to_light / distance;
    let cos_light = -wi.dot(normal);
    if cos_light <= 0.0 {
        return None;
    }
    Some((wi, distance, cos_light, dist2 / cos_light))
}

/// The sample of area light `p` at barycentrics `b` seen from `receiver`, with the solid-angle
/// pdf `pdf(d^2 / cos(light))`.
#[inline]
fn area_light_sample(
    p: &[Vec3; 3],
    normal: Vec3,
    radiance: Rgb,
    receiver: Vec3,
    b: [f32; 3],
    pdf: impl Fn(f32) -> f32,
) -> Option<LightSample> {
    let point = p[0] * b[0] + p[1] * b[1] + p[2] * b[2];
    let (wi, distance, _, d2_over_cos) = area_light_geometry(normal, receiver, point)?;
    let pdf = pdf(d2_over_cos);
    if !pdf.is_finite() {
        return None;
    }
    Some(LightSample {
        wi,
        radiance,
        pdf,
        point,
        point_error: barycentric_point_error(*p, b),
        normal,
        distance,
        delta: false,
    })
}

/// A light-field luminaire's sample seen from `receiver`: a point of its image plane by
/// restricted sampling, the radiance along the ray from the filter plane through it, and the
/// solid-angle density (area density times d^2 / cos at the image plane).
fn light_field_sample(
    position: Vec3,
    frame: Frame,
    scale: Rgb,
    field: &LightField,
    receiver: Vec3,
    u: Vec2,
) -> Option<LightSample> {
    let p = frame.to_local(receiver - position);
    let (s, pdf_area) = field.sample_image_point(p, LightFieldSampling::Restricted, u)?;
    let delta = field.layout().plane_distance;
    let point_local = Vec3::new(s.x, s.y, delta);
    let to_light = point_local - p;
    let dist2 = to_light.length_squared();
    let distance = dist2.sqrt();
    let cos = -to_light.z / distance;
    if !(cos > 0.0) {
        return None;
    }
    let radiance = field.radiance(field.filter_point(p, s), s) * scale;
    let pdf = pdf_area * dist2 / cos;
    if !(pdf.is_finite() && pdf > 0.0) || radiance == Rgb::ZERO || !is_finite3(radiance) {
        return None;
    }
    Some(LightSample {
        wi: frame.to_world(to_light / distance),
        radiance,
        pdf,
        point: position + frame.to_world(point_local),
        point_error: Vec3::ZERO,
        normal: frame.n,
        distance,
        delta: true,
    })
}

fn delta_point_sample(receiver: Vec3, position: Vec3, intensity: Rgb) -> Option<LightSample> {
    let to_light = position - receiver;
    let dist2 = to_light.length_squared();
    if dist2 == 0.0 {
        return None;
    }
    let distance = dist2.sqrt();
    let wi = to_light / distance;
    Some(LightSample {
        wi,
        radiance: intensity / dist2,
        pdf: 1.0,
        point: position,
        point_error: Vec3::ZERO,
        normal: -wi,
        distance,
        delta: true,
    })
}

pub(crate) fn smoothstep(a: f32, b: f32, x: f32) -> f32 {
    if a == b {
        return if x >= a { 1.0 } else { 0.0 };
    }
    let t = ((x - a) / (b - a)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}
