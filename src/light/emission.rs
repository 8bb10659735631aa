//! Sampling light *leaving* a light (a point and a direction), as light subpaths of
//! bidirectional methods start, with the densities MIS needs (SmallVCM's `Emit` and
//! `Illuminate` quantities, Georgiev 2012 "Implementing vertex connection and merging").

use super::{EnvStrategy, Light};
use crate::math::{warp, Frame, Rgb, Vec2, Vec3, INV_4PI, INV_PI, PI};

/// An emitted ray.
#[derive(Clone, Copy, Debug)]
pub struct EmissionSample {
    pub origin: Vec3,
    /// Bound on the floating-point error of `origin` (zero off surfaces).
    pub origin_error: Vec3,
    pub dir: Vec3,
    /// Normal at the origin (area lights; the direction for others).
    pub normal: Vec3,
    /// Emitted radiance times the cosine at the light (for area lights), intensity (point and
    /// spot) or irradiance (directional): divided by `pdf_emit` it is the initial throughput.
    pub value: Rgb,
    /// Density of choosing this origin and direction (area x solid angle), without the light
    /// selection probability.
    pub pdf_emit: f32,
    /// Area density of choosing this origin by direct light sampling (1 for delta positions).
    pub pdf_direct_area: f32,
    /// Cosine between the normal and the direction (1 for non-area lights).
    pub cos_light: f32,
}

impl Light {
    /// True when light leaves from a finite surface or point (not from infinity).
    pub fn is_finite(&self) -> bool {
        !matches!(self, Light::Directional { .. } | Light::Environment { .. })
    }

    /// Samples an emitted ray with `u_pos` choosing the origin and `u_dir` the direction.
    pub fn sample_emission(&self, u_pos: Vec2, u_dir: Vec2) -> Option<EmissionSample> {
        self.sample_emission_with(EnvStrategy::default(), u_pos, u_dir)
    }

    /// `sample_emission` where environment maps pick directions as `env.for_emission()`
    /// does (there is no receiver normal).
    pub fn sample_emission_with(
        &self,
        env: EnvStrategy,
        u_pos: Vec2,
        u_dir: Vec2,
    ) -> Option<EmissionSample> {
        match *self {
            Light::Area {
                p,
                normal,
                area,
                radiance,
                ..
            } => {
                let (b0, b1) = warp::uniform_triangle(u_pos);
                let b = [b0, b1, 1.0 - b0 - b1];
                let origin = p[0] * b[0] + p[1] * b[1] + p[2] * b[2];
                let local = warp::cosine_hemisphere(u_dir);
                if local.z <= 0.0 {
                    return None;
                }
                let dir = Frame::from_z(normal).to_world(local);
                Some(EmissionSample {
                    origin,
                    origin_error: crate::geometry::barycentric_point_error(p, b),
                    dir,
                    normal,
                    value: radiance * local.z,
                    pdf_emit: local.z * INV_PI / area,
                    pdf_direct_area: 1.0 / area,
                    cos_light: local.z,
                })
            }
            Light::Point {
                position,
                intensity,
            } => {
                let dir = warp::uniform_sphere(u_dir);
                Some(EmissionSample {
                    origin: position,
                    origin_error: Vec3::ZERO,
                    dir,
                    normal: dir,
                    value: intensity,
                    pdf_emit: INV_4PI,
                    pdf_direct_area: 1.0,
                    cos_light: 1.0,
                })
            }
            Light::Spot {
                position,
                direction,
                intensity,
                cos_inner,
                cos_outer,
            } => {
                let local = warp::uniform_cone(u_dir, cos_outer);
                let dir = Frame::from_z(direction).to_world(local);
                let falloff = super::smoothstep(cos_outer, cos_inner, local.z);
                if falloff <= 0.0 {
                    return None;
                }
                Some(EmissionSample {
                    origin: position,
                    origin_error: Vec3::ZERO,
                    dir,
                    normal: dir,
                    value: intensity * falloff,
                    pdf_emit: warp::uniform_cone_pdf(local, cos_outer),
                    pdf_direct_area: 1.0,
                    cos_light: 1.0,
                })
            }
            Light::Photometric {
                position,
                frame,
                intensity,
                ref profile,
            } => {
                let (local, pdf) = profile.sample_direction(u_dir)?;
                let candela = profile.intensity(local);
                if candela <= 0.0 {
                    return None;
                }
                let dir = frame.to_world(local);
                Some(EmissionSample {
                    origin: position,
                    origin_error: Vec3::ZERO,
                    dir,
                    normal: dir,
                    value: intensity * candela,
                    pdf_emit: pdf,
                    pdf_direct_area: 1.0,
                    cos_light: 1.0,
                })
            }
            Light::Directional {
                direction,
                irradiance,
                scene_center,
                scene_radius,
            } => {
                // A point on the disk of the scene's bounding sphere perpendicular to the
                // light, moved back outside the sphere.
                let frame = Frame::from_z(direction);
                let d = warp::concentric_disk(u_pos) * scene_radius;
                let origin =
                    scene_center + frame.s * d.x + frame.t * d.y - direction * scene_radius;
                Some(EmissionSample {
                    origin,
                    origin_error: Vec3::ZERO,
                    dir: direction,
                    normal: direction,
                    value: irradiance,
                    pdf_emit: 1.0 / (PI * scene_radius * scene_radius),
                    pdf_direct_area: 1.0,
                    cos_light: 1.0,
                })
            }
            Light::LightField {
                position,
                frame,
                scale,
                ref field,
            } => {
                let (s, u, pdf_emit) = field.sample_emission(u_pos, u_dir)?;
                let delta = field.layout().plane_distance;
                let local = (Vec3::new(s.x, s.y, delta) - Vec3::new(u.x, u.y, 0.0)).normalize();
                let radiance = field.radiance(u, s) * scale;
                if radiance == Rgb::ZERO {
                    return None;
                }
                Some(EmissionSample {
                    origin: position + frame.to_world(Vec3::new(s.x, s.y, delta)),
                    origin_error: Vec3::ZERO,
                    dir: frame.to_world(local),
                    normal: frame.n,
                    value: radiance * local.z,
                    pdf_emit,
                    // Direct sampling's density depends on the receiver (restricted CDFs):
                    // bidirectional methods put `direct_pdf_area_from` the first vertex in
                    // its place.
                    pdf_direct_area: 1.0,
                    cos_light: local.z,
                })
            }
            Light::Environment {
                ref map,
                scene_center,
                scene_radius,
            } => {
                // A direction towards the map, then a point on the disk of the bounding
                // sphere perpendicular to it, moved out of the sphere on the map's side; the
                // ray travels back into the scene.
                let s = map.sample(env.for_emission(), Vec3::ZERO, u_dir)?;
                let frame = Frame::from_z(s.wi);
                let d = warp::concentric_disk(u_pos) * scene_radius;
                let origin = scene_center + frame.s * d.x + frame.t * d.y + s.wi * scene_radius;
                let dir = -s.wi;
                Some(EmissionSample {
                    origin,
                    origin_error: Vec3::ZERO,
                    dir,
                    normal: dir,
                    value: s.radiance,
                    pdf_emit: s.pdf / (PI * scene_radius * scene_radius),
                    // Direct sampling of this direction depends on the receiver's normal:
                    // this is its density with none; bidirectional methods put the density
                    // at the first vertex in its place.
                    pdf_direct_area: map.pdf(env, Vec3::ZERO, s.wi),
                    cos_light: 1.0,
                })
            }
        }
    }

    /// Density (area x solid angle, without selection probability) of `sample_emission`
    /// producing a ray leaving the light in direction `dir` (for directional lights, the
    /// density of the ray's origin on the disk).
    pub fn emission_pdf(&self, dir: Vec3) -> f32 {
        self.emission_pdf_with(EnvStrategy::default(), dir)
    }

    /// `emission_pdf` for rays of `sample_emission_with(env, ..)`.
    pub fn emission_pdf_with(&self, env: EnvStrategy, dir: Vec3) -> f32 {
        match *self {
            Light::Area { area, normal, .. } => {
                let c = normal.dot(dir);
                if c <= 0.0 {
                    0.0
                } else {
                    c * INV_PI / area
                }
            }
            Light::Point { .. } => INV_4PI,
            Light::Spot {
                direction,
                cos_outer,
                ..
            } => warp::uniform_cone_pdf(Vec3::new(0.0, 0.0, direction.dot(dir)), cos_outer),
            Light::Photometric {
                frame, ref profile, ..
            } => profile.direction_pdf(frame.to_local(dir)),
            Light::Directional { scene_radius, .. } => 1.0 / (PI * scene_radius * scene_radius),
            Light::Environment {
                ref map,
                scene_radius,
                ..
            } => map.pdf(env.for_emission(), Vec3::ZERO, -dir) / (PI * scene_radius * scene_radius),
            // The density depends on where the ray leaves, not only on its direction:
            // `emission_pdf_at` gives it from the ray's origin.
            Light::LightField { .. } => 0.0,
        }
    }

    /// `emission_pdf_with` for the ray leaving point `origin` of the light in unit direction
    /// `dir`: for a light field the density depends on where the ray leaves its image plane
    /// (`LightField::emission_pdf` of the ray's points on both planes); other lights ignore
    /// `origin`.
    pub fn emission_pdf_at(&self, env: EnvStrategy, origin: Vec3, dir: Vec3) -> f32 {
        match *self {
            Light::LightField {
                position,
                frame,
                ref field,
                ..
            } => {
                let s = frame.to_local(origin - position);
                let d = frame.to_local(dir);
                if !(d.z > 0.0) {
                    return 0.0;
                }
                // The filter-plane point (z = 0) the ray came from through s (z = delta).
                let back = field.layout().plane_distance / d.z;
                let u = Vec2::new(s.x - d.x * back, s.y - d.y * back);
                let pdf = field.emission_pdf(Vec2::new(s.x, s.y), u);
                if pdf.is_finite() {
                    pdf
                } else {
                    0.0
                }
            }
            _ => self.emission_pdf_with(env, dir),
        }
    }

    /// Area density with which direct light sampling from `receiver` picks the light point
    /// `point` (by area for emissive triangles, as `bdpt` samples them; 1 for delta
    /// positions), without selection probability. Only a light field's depends on the
    /// receiver: its restricted sampling (`LightField::image_point_pdf`).
    pub fn direct_pdf_area_from(&self, receiver: Vec3, point: Vec3) -> f32 {
        match *self {
            Light::LightField {
                position,
                frame,
                ref field,
                ..
            } => {
                let s = frame.to_local(point - position);
                field.image_point_pdf(
                    frame.to_local(receiver - position),
                    super::LightFieldSampling::Restricted,
                    Vec2::new(s.x, s.y),
                )
            }
            _ => self.direct_pdf_area(),
        }
    }

    /// |cosine| between the light's normal and direction `w` (1 for lights without a surface).
    pub fn cos_at(&self, w: Vec3) -> f32 {
        match *self {
            Light::Area { normal, .. } => normal.dot(w).abs(),
            _ => 1.0,
        }
    }

    /// Area density of direct light sampling choosing a point of this light (1 for delta
    /// positions), without selection probability.
    pub fn direct_pdf_area(&self) -> f32 {
        match *self {
            Light::Area { area, .. } => 1.0 / area,
            _ => 1.0,
        }
    }
}

impl Light {
    /// A density of [`Light::sample_emission_with`] (`pdf_emit`, or [`Light::emission_pdf_with`])
    /// split into the density of the origin (area measure; 1 for the delta positions of point
    /// and spot lights) and of the direction (solid angle; 1 for the delta direction of a
    /// directional light), as light tracers that weight by MIS keep them apart. Their product
    /// is `pdf_emit`. `origin` is where the ray leaves (only a light field's split depends on
    /// it).
    pub fn split_emission_pdf(&self, origin: Vec3, pdf_emit: f32) -> (f32, f32) {
        match *self {
            Light::Area { area, .. } => (1.0 / area, pdf_emit * area),
            Light::Point { .. } | Light::Spot { .. } | Light::Photometric { .. } => (1.0, pdf_emit),
            Light::LightField {
                position,
                frame,
                ref field,
                ..
            } => {
                let local = frame.to_local(origin - position);
                let area = field.emission_origin_pdf(crate::math::Vec2::new(local.x, local.y));
                if area > 0.0 {
                    (area, pdf_emit / area)
                } else {
                    (0.0, 0.0)
                }
            }
            Light::Directional { .. } => (pdf_emit, 1.0),
            Light::Environment { scene_radius, .. } => {
                let disk = PI * scene_radius * scene_radius;
                (1.0 / disk, pdf_emit * disk)
            }
        }
    }
}
