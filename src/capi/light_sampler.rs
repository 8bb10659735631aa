//! `lacuna_light_sampler`: Lacuna's light sampling at a host's own shading points (next-event
//! estimation with MIS), the density of a direction the host found by its own BSDF sampling,
//! and emission sampling for light tracing; single calls and batches over strided arrays.
//!
//! Every call is a thin layer over [`crate::light`]: the light is picked by power
//! ([`crate::light::LightSampler::sample_reuse`], as `path` picks it) and sampled by
//! [`Light::sample_with`] with the sampler's triangle and environment strategies, so a host
//! gets exactly the samples and densities Lacuna's own `path` integrator uses. Nothing here
//! allocates on success (the environment map's sampling structures are built by
//! `lacuna_light_sampler_new`), so a host may call it per vertex from any number of threads.

use std::sync::Arc;

use super::boundary::{self, lacuna_status, CapiError, CapiResult};
use super::buffer::{arc_clone, arc_into_handle, arc_release, arc_retain, arg, out_ptr, write_out};
use super::scene::lacuna_scene;
use super::types::*;
use crate::light::{EnvStrategy, Light, TriangleSampling};
use crate::math::{Rgb, Vec2, Vec3};
use crate::scene::Scene;

/// Lacuna's light sampling over the lights of a committed scene (emissive triangles, point,
/// spot, directional and photometric lights, the environment map), for a host that shades its
/// own surfaces. Light ids are indices in `[0, light_count)`: one per emissive triangle, one
/// per point, spot, directional or photometric light, and one for the environment map
/// (`lacuna_light_sampler_get_info`, `lacuna_light_sampler_get_light_info`).
///
/// Refcounted (`lacuna_light_sampler_retain`/`lacuna_light_sampler_release`); it keeps its
/// scene alive. Immutable once made, so thread-safe: every function taking a
/// `const lacuna_light_sampler*` may be called from any number of threads at once, and none
/// allocates memory on success.
///
/// ## Combining with the host's BSDF sampling (multiple importance sampling)
/// All densities are per unit **solid angle at the receiver** and **include the probability of
/// having picked the light** (`selection_probability`, by power). At a non-delta vertex a host
/// takes two samples and weights each by the power heuristic
/// `w(a, b) = a^2 / (a^2 + b^2)` (or balance, `a / (a + b)`):
/// - light sample `s` (`lacuna_light_sampler_sample`): unless `s.light` is
///   `LACUNA_INVALID_INDEX` or the shadow ray is blocked, add
///   `f(wo, s.direction) |cos| s.radiance w(s.pdf, p_bsdf(s.direction)) / s.pdf`, where
///   `p_bsdf` is the host BSDF's solid-angle density of that direction; for a
///   `LACUNA_LIGHT_SAMPLE_DELTA` sample (point, spot, directional light) the weight is 1 (no
///   BSDF sample can hit it) and `s.pdf` is just the selection probability.
/// - BSDF sample `wi` with density `p_bsdf`: if the ray hits an emissive triangle (its light
///   from `lacuna_light_sampler_get_triangle_light`) or escapes to the environment
///   (`environment_light`, distance +infinity), `lacuna_light_sampler_eval` gives the emitted
///   radiance `L` and the density `p_light` light sampling has for that direction from the same
///   query; add `f |cos| L w(p_bsdf, p_light) / p_bsdf` (weight 1 after a delta BSDF lobe).
///
/// The query (position, normal, flags) of `eval` must be the one the vertex used to sample, so
/// that both densities describe the same estimator.
pub struct lacuna_light_sampler {
    scene: Arc<lacuna_scene>,
    env: EnvStrategy,
    triangles: TriangleSampling,
}

/// How light sampling picks points of emissive triangles (`lacuna_light_sampler_new`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_triangle_strategy {
    /// Uniformly by area (the default of `lacuna render`).
    Area = 0,
    /// Uniformly in the solid angle the triangle subtends (by area where that construction is
    /// unreliable: tiny or nearly hemispherical solid angles).
    SolidAngle = 1,
}

/// Kinds of lights (`lacuna_light_info.kind`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_light_kind {
    /// One emissive triangle (emitting on its front side).
    Area = 0,
    Point = 1,
    Spot = 2,
    Directional = 3,
    Environment = 4,
    /// A measured luminaire (an IES profile) at a point.
    Photometric = 5,
    /// A light-field luminaire (two planes of images). Rays never hit it: its light samples
    /// carry `LACUNA_LIGHT_SAMPLE_DELTA` (MIS weight 1) with their true solid-angle density.
    LightField = 6,
}

/// `lacuna_light_query.flags`: the host's BSDF transmits (glass, leaves), so light may arrive
/// from both sides: the environment map's per-normal face balancing is then not used (the
/// faces are balanced by power, as for an unknown normal). Light sampling otherwise does not
/// depend on the BSDF.
pub const LACUNA_LIGHT_QUERY_TRANSMISSIVE: u32 = 1;

/// A shading point asking for light. The layout (36 bytes, 4-byte aligned) never changes with
/// build options; fill it with `lacuna_light_query_init` then set the fields.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct lacuna_light_query {
    /// The receiving point (finite).
    pub position: [f32; 3],
    /// `LACUNA_LIGHT_QUERY_*` bits; others must be 0.
    pub flags: u32,
    /// The shading normal on the side of the outgoing direction (finite; need not be unit
    /// length), or zero when unknown. The environment map's per-normal cube-face balancing
    /// uses it; other lights ignore it.
    pub normal: [f32; 3],
    /// Two random numbers in [0, 1) for the sample calls (ignored by `eval`): the first picks
    /// the light and, rescaled within the chosen light's share, the first coordinate of the
    /// point on it, so a stratified pair stays stratified over each light.
    pub u: [f32; 2],
}

/// `lacuna_light_sample.flags`: the light is a delta light (point, spot, directional): no BSDF
/// sample can find it, weight the sample 1 and do not MIS it.
pub const LACUNA_LIGHT_SAMPLE_DELTA: u32 = 1;
/// `lacuna_light_sample.flags`: the light is at infinity (directional, environment):
/// `distance` is +infinity and the shadow ray is unbounded.
pub const LACUNA_LIGHT_SAMPLE_INFINITE: u32 = 2;

/// One light sample seen from a query's position (`lacuna_light_sampler_sample`). The layout
/// (72 bytes, 4-byte aligned) never changes with build options. When no light could be
/// sampled (no lights, the receiver behind the chosen emitter, a zero-probability direction)
/// `light` is `LACUNA_INVALID_INDEX` and `pdf` and `radiance` are 0: the sample contributes
/// nothing (it still counts as a sample).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct lacuna_light_sample {
    /// Unit direction from the receiver towards the light.
    pub direction: [f32; 3],
    /// Distance to the point on the light (+infinity for lights at infinity).
    pub distance: f32,
    /// Incident radiance along `direction` (for delta lights, the value whose ratio to `pdf`
    /// is the contribution: intensity / distance^2 for point, spot and photometric lights,
    /// irradiance for directional ones).
    pub radiance: lacuna_rgb,
    /// Solid-angle density of this direction, selection probability included (for delta
    /// lights, the selection probability alone).
    pub pdf: f32,
    /// The point on the light (the receiver for lights at infinity), for the shadow ray.
    pub point: [f32; 3],
    /// Probability of having picked this light (part of `pdf`).
    pub selection_probability: f32,
    /// The light's normal at `point` (area lights), or the direction light travels.
    pub light_normal: [f32; 3],
    /// The light's id, or `LACUNA_INVALID_INDEX` for no sample.
    pub light: u32,
    /// Bound on the floating-point error of `point` (zero off triangles), for offsetting the
    /// shadow ray's end (`lacuna_surface_spawn_shadow_ray` does it).
    pub point_error: [f32; 3],
    /// `LACUNA_LIGHT_SAMPLE_*` bits.
    pub flags: u32,
}

/// Where a host's own ray met a light (`lacuna_light_sampler_eval`): the light's id, the
/// direction of the ray (finite, non-zero) and the distance along the unit direction to the
/// point on the light (finite and > 0 for emissive triangles; ignored, typically +infinity,
/// for the environment). The point must lie on that light (where the host's ray met it): the
/// solid-angle strategy's density does not depend on the point and is not checked against it.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct lacuna_light_hit {
    pub light: u32,
    pub direction: [f32; 3],
    pub distance: f32,
}

/// The radiance a light sends along a host's ray and the density light sampling gives that
/// direction (`lacuna_light_sampler_eval`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct lacuna_light_eval {
    /// Radiance arriving along the ray from the light (zero from the back of a triangle and
    /// from delta lights).
    pub radiance: lacuna_rgb,
    /// Solid-angle density `lacuna_light_sampler_sample` has of producing this direction at
    /// this light from the same query, selection probability included; 0 for delta lights.
    pub pdf: f32,
    /// Probability of picking this light.
    pub selection_probability: f32,
}

/// `lacuna_emission_sample.flags`: the origin is a single point (point and spot lights):
/// `pdf_position` is 1 and no camera path can hit it.
pub const LACUNA_EMISSION_DELTA_POSITION: u32 = 1;
/// `lacuna_emission_sample.flags`: the direction is fixed (directional lights):
/// `pdf_direction` is 1.
pub const LACUNA_EMISSION_DELTA_DIRECTION: u32 = 2;
/// `lacuna_emission_sample.flags`: light from infinity (directional, environment): the origin
/// is on a disk of the scene's bounding sphere, `pdf_position` per unit area of that disk.
pub const LACUNA_EMISSION_INFINITE: u32 = 4;

/// A ray of light leaving a light, to start a light path (`lacuna_light_sampler_sample_emission`).
/// The layout (64 bytes, 4-byte aligned) never changes with build options. The light path's
/// initial throughput (flux weight) is
/// `power / (selection_probability * pdf_position * pdf_direction)`. With no lights, `light` is
/// `LACUNA_INVALID_INDEX` and the densities and power are 0.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct lacuna_emission_sample {
    pub origin: [f32; 3],
    /// The light's id, or `LACUNA_INVALID_INDEX`.
    pub light: u32,
    /// Unit direction the light travels.
    pub direction: [f32; 3],
    /// `LACUNA_EMISSION_*` bits.
    pub flags: u32,
    /// The light's normal at the origin (area lights), or the direction.
    pub normal: [f32; 3],
    /// Density of the origin per unit area (1 for delta positions).
    pub pdf_position: f32,
    /// Emitted radiance times the cosine at the light (area lights, environment: radiance),
    /// intensity (point, spot) or irradiance (directional).
    pub power: lacuna_rgb,
    /// Density of the direction per unit solid angle (1 for a delta direction).
    pub pdf_direction: f32,
    /// Probability of having picked this light.
    pub selection_probability: f32,
}

/// What a light sampler covers (`lacuna_light_sampler_get_info`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct lacuna_light_sampler_info {
    /// Number of lights (ids are `0..light_count`).
    pub light_count: u32,
    /// Id of the environment map, or `LACUNA_INVALID_INDEX`.
    pub environment_light: u32,
    /// Number of emissive triangles (area lights).
    pub area_light_count: u32,
    /// The `lacuna_triangle_strategy` and `lacuna_environment_strategy` it was made with.
    pub triangle_strategy: u32,
    pub environment_strategy: u32,
    /// Sum of the lights' powers (luminance, W).
    pub total_power: f32,
}

/// One light (`lacuna_light_sampler_get_light_info`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct lacuna_light_info {
    /// A `lacuna_light_kind` value.
    pub kind: u32,
    /// Global triangle index of an area light, else `LACUNA_INVALID_INDEX`.
    pub triangle: u32,
    /// Emitted power (luminance, W), what light selection is proportional to.
    pub power: f32,
    /// Probability that light sampling and emission sampling pick this light.
    pub selection_probability: f32,
}

impl lacuna_triangle_strategy {
    fn from_c(value: u32, name: &str) -> CapiResult<TriangleSampling> {
        match value {
            0 => Ok(TriangleSampling::Area),
            1 => Ok(TriangleSampling::SolidAngle),
            _ => Err(CapiError::invalid(format!(
                "`{name}` = {value} is not a valid lacuna_triangle_strategy (expected 0 or 1)"
            ))),
        }
    }
}

const NO_SAMPLE: lacuna_light_sample = lacuna_light_sample {
    direction: [0.0; 3],
    distance: 0.0,
    radiance: lacuna_rgb {
        r: 0.0,
        g: 0.0,
        b: 0.0,
    },
    pdf: 0.0,
    point: [0.0; 3],
    selection_probability: 0.0,
    light_normal: [0.0; 3],
    light: LACUNA_INVALID_INDEX,
    point_error: [0.0; 3],
    flags: 0,
};

const NO_EMISSION: lacuna_emission_sample = lacuna_emission_sample {
    origin: [0.0; 3],
    light: LACUNA_INVALID_INDEX,
    direction: [0.0; 3],
    flags: 0,
    normal: [0.0; 3],
    pdf_position: 0.0,
    power: lacuna_rgb {
        r: 0.0,
        g: 0.0,
        b: 0.0,
    },
    pdf_direction: 0.0,
    selection_probability: 0.0,
};

fn rgb(c: Rgb) -> lacuna_rgb {
    lacuna_rgb {
        r: c.x,
        g: c.y,
        b: c.z,
    }
}

/// A checked query.
struct Query {
    position: Vec3,
    /// The normal environment maps balance their faces by (zero: unknown or transmissive).
    env_normal: Vec3,
    u: Vec2,
}

/// Names the argument of a single call (`query`) or the element of a batch (`queries[i]`).
fn element(single: &str, plural: &str, index: Option<usize>) -> String {
    index.map_or(single.to_string(), |i| format!("{plural}[{i}]"))
}

/// A random number in [0, 1): non-finite values are invalid, finite ones outside are out of
/// range.
fn unit(v: f32, what: impl Fn() -> String) -> CapiResult<f32> {
    if !v.is_finite() {
        return Err(CapiError::invalid(format!(
            "{} is {v} (must be finite)",
            what()
        )));
    }
    if !(0.0..1.0).contains(&v) {
        return Err(CapiError::range(format!(
            "{} = {v} is outside [0, 1)",
            what()
        )));
    }
    Ok(v)
}

fn query_from_c(q: &lacuna_light_query, index: Option<usize>, with_u: bool) -> CapiResult<Query> {
    let name = || element("query", "queries", index);
    let position = Vec3::from(q.position);
    if !position.is_finite() {
        return Err(CapiError::invalid(format!(
            "{} position {position} must be finite",
            name()
        )));
    }
    let normal = Vec3::from(q.normal);
    if !normal.is_finite() {
        return Err(CapiError::invalid(format!(
            "{} normal {normal} must be finite (zero when unknown)",
            name()
        )));
    }
    if q.flags & !LACUNA_LIGHT_QUERY_TRANSMISSIVE != 0 {
        return Err(CapiError::invalid(format!(
            "{} flags {:#x} has unknown bits (only LACUNA_LIGHT_QUERY_TRANSMISSIVE = 1)",
            name(),
            q.flags
        )));
    }
    let u = if with_u {
        Vec2::new(
            unit(q.u[0], || format!("{} u[0]", name()))?,
            unit(q.u[1], || format!("{} u[1]", name()))?,
        )
    } else {
        Vec2::ZERO
    };
    let env_normal = if q.flags & LACUNA_LIGHT_QUERY_TRANSMISSIVE != 0 {
        Vec3::ZERO
    } else {
        normal.normalize_or_zero()
    };
    Ok(Query {
        position,
        env_normal,
        u,
    })
}

/// A checked emitter hit: light index and unit direction.
fn hit_from_c(
    s: &lacuna_light_sampler,
    h: &lacuna_light_hit,
    index: Option<usize>,
) -> CapiResult<(usize, Vec3, f32)> {
    let name = || element("hit", "hits", index);
    let count = s.scene().lights().len();
    if h.light as usize >= count {
        return Err(CapiError::range(format!(
            "{} light {} is out of range (the scene has {count} lights)",
            name(),
            h.light
        )));
    }
    let d = Vec3::from(h.direction);
    if !d.is_finite() || d == Vec3::ZERO {
        return Err(CapiError::invalid(format!(
            "{} direction {d} must be finite and non-zero",
            name()
        )));
    }
    let light = &s.scene().lights()[h.light as usize];
    if matches!(light, Light::Area { .. }) && !(h.distance > 0.0 && h.distance.is_finite()) {
        return Err(CapiError::invalid(format!(
            "{} distance {} to emissive triangle light {} must be finite and > 0",
            name(),
            h.distance,
            h.light
        )));
    }
    Ok((h.light as usize, d.normalize(), h.distance))
}

impl lacuna_light_sampler {
    fn scene(&self) -> &Scene {
        &self.scene.scene
    }

    fn sample(&self, q: &Query) -> lacuna_light_sample {
        let scene = self.scene();
        let Some(selector) = scene.light_sampler() else {
            return NO_SAMPLE;
        };
        let (index, pmf, u_light) = selector.sample_reuse(q.u.x);
        let Some(s) = scene.sample_light_at(
            index,
            q.position,
            q.env_normal,
            self.env,
            self.triangles,
            Vec2::new(u_light, q.u.y),
        ) else {
            return NO_SAMPLE;
        };
        let pdf = pmf * s.pdf;
        if !(pdf > 0.0 && pdf.is_finite()) {
            return NO_SAMPLE;
        }
        let mut flags = 0;
        if s.delta {
            flags |= LACUNA_LIGHT_SAMPLE_DELTA;
        }
        if s.distance.is_infinite() {
            flags |= LACUNA_LIGHT_SAMPLE_INFINITE;
        }
        lacuna_light_sample {
            direction: s.wi.to_array(),
            distance: s.distance,
            radiance: rgb(s.radiance),
            pdf,
            point: s.point.to_array(),
            selection_probability: pmf,
            light_normal: s.normal.to_array(),
            light: index as u32,
            point_error: s.point_error.to_array(),
            flags,
        }
    }

    fn eval(&self, q: &Query, light: usize, dir: Vec3, distance: f32) -> lacuna_light_eval {
        let scene = self.scene();
        let pmf = scene.light_sampler().map_or(0.0, |s| s.pmf(light));
        let (radiance, pdf) = match &scene.lights()[light] {
            l @ Light::Area { .. } => {
                let point = q.position + dir * distance;
                (
                    l.emitted(-dir),
                    l.pdf_with(q.position, point, self.triangles),
                )
            }
            Light::Environment { map, .. } => (
                map.radiance(dir),
                scene.environment_pdf_at(self.env, q.position, q.env_normal, dir),
            ),
            _ => (Rgb::ZERO, 0.0),
        };
        lacuna_light_eval {
            radiance: rgb(radiance),
            pdf: pmf * pdf,
            selection_probability: pmf,
        }
    }

    fn sample_emission(&self, u: [f32; 4]) -> lacuna_emission_sample {
        let scene = self.scene();
        let Some(selector) = scene.light_sampler() else {
            return NO_EMISSION;
        };
        let (index, pmf, u_light) = selector.sample_reuse(u[0]);
        let light = &scene.lights()[index];
        let Some(s) =
            light.sample_emission_with(self.env, Vec2::new(u_light, u[1]), Vec2::new(u[2], u[3]))
        else {
            return NO_EMISSION;
        };
        let (pdf_position, pdf_direction) = light.split_emission_pdf(s.origin, s.pdf_emit);
        lacuna_emission_sample {
            origin: s.origin.to_array(),
            light: index as u32,
            direction: s.dir.to_array(),
            flags: emission_flags(light),
            normal: s.normal.to_array(),
            pdf_position,
            power: rgb(s.value),
            pdf_direction,
            selection_probability: pmf,
        }
    }
}

fn emission_flags(light: &Light) -> u32 {
    match light {
        Light::Area { .. } => 0,
        Light::Point { .. } | Light::Spot { .. } | Light::Photometric { .. } => {
            LACUNA_EMISSION_DELTA_POSITION
        }
        Light::Directional { .. } => LACUNA_EMISSION_DELTA_DIRECTION | LACUNA_EMISSION_INFINITE,
        Light::Environment { .. } => LACUNA_EMISSION_INFINITE,
        Light::LightField { .. } => 0,
    }
}

/// Reads 4 random numbers in [0, 1) for an emission sample.
///
/// # Safety
/// `u` must be readable for 4 floats.
unsafe fn emission_numbers(u: *const f32, index: Option<usize>) -> CapiResult<[f32; 4]> {
    // SAFETY: readable for 4 floats per the contract (NULL was rejected by the caller).
    let raw: [f32; 4] = unsafe { u.cast::<[f32; 4]>().read_unaligned() };
    for (k, &v) in raw.iter().enumerate() {
        unit(v, || format!("{}[{k}]", element("u", "u", index)))?;
    }
    Ok(raw)
}

/// Checks `count` elements of `size` bytes every `stride` bytes (0 = packed) from `ptr`: non-NULL
/// unless `count` is 0, stride at least one element, span within the address space. Returns the
/// resolved stride.
fn strided(
    ptr: *const u8,
    stride: usize,
    count: usize,
    size: usize,
    name: &str,
) -> CapiResult<usize> {
    let stride = if stride == 0 { size } else { stride };
    if stride < size {
        return Err(CapiError::invalid(format!(
            "`{name}` stride {stride} bytes is smaller than one element ({size} bytes)"
        )));
    }
    if count == 0 {
        return Ok(stride);
    }
    if ptr.is_null() {
        return Err(CapiError::null(name));
    }
    (count - 1)
        .checked_mul(stride)
        .and_then(|s| s.checked_add(size))
        .filter(|&s| s <= isize::MAX as usize)
        .and_then(|s| (ptr as usize).checked_add(s))
        .ok_or_else(|| {
            CapiError::range(format!(
                "`{name}`: {count} elements every {stride} bytes exceed the address space"
            ))
        })?;
    Ok(stride)
}

/// Element `i` of a strided input array checked by [`strided`].
///
/// # Safety
/// `i < count` of a checked array the caller guarantees readable.
unsafe fn read_at<T: Copy>(ptr: *const T, stride: usize, i: usize) -> T {
    // SAFETY: within the checked span; `read_unaligned` needs no alignment.
    unsafe {
        ptr.cast::<u8>()
            .add(i * stride)
            .cast::<T>()
            .read_unaligned()
    }
}

/// Writes element `i` of a strided output array checked by [`strided`].
///
/// # Safety
/// `i < count` of a checked array the caller guarantees writable.
unsafe fn write_at<T>(ptr: *mut T, stride: usize, i: usize, value: T) {
    // SAFETY: within the checked span; `write_out` needs no alignment.
    unsafe { write_out(ptr.cast::<u8>().add(i * stride).cast::<T>(), value) }
}

/// Fills `*query` with defaults: position and normal 0 (normal unknown), flags 0, u = (0, 0).
/// NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_query_init(query: *mut lacuna_light_query) {
    boundary::value("lacuna_light_query_init", (), |_| {
        if !query.is_null() {
            // SAFETY: non-NULL and writable per the contract.
            unsafe {
                write_out(
                    query,
                    lacuna_light_query {
                        position: [0.0; 3],
                        flags: 0,
                        normal: [0.0; 3],
                        u: [0.0; 2],
                    },
                )
            };
        }
        Ok(())
    })
}

/// Makes a light sampler over the lights of `scene` (which it keeps alive), picking points of
/// emissive triangles by `triangle_strategy` (a `lacuna_triangle_strategy` value) and
/// environment directions by `environment_strategy` (a `lacuna_environment_strategy` value;
/// `LACUNA_ENVIRONMENT_STRATEGY_BSDF` never samples the map, which BSDF sampling must then
/// find; `LACUNA_ENVIRONMENT_STRATEGY_PORTALS` samples through the window portals the query's
/// position sees, and weighs hits by the same). Builds the environment map's sampling
/// structures now (for portals, the scene's window portals: an analysis of the scene the
/// first time), so that no later call allocates. Writes the sampler (reference count 1) to `*out_sampler`. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_sampler_new(
    scene: *const lacuna_scene,
    triangle_strategy: u32,
    environment_strategy: u32,
    out_sampler: *mut *mut lacuna_light_sampler,
) -> lacuna_status {
    boundary::status("lacuna_light_sampler_new", |call| {
        // SAFETY: NULL or a live scene.
        let s = unsafe { arg(scene, "scene") }?;
        call.context(&s.ctx);
        let triangles = lacuna_triangle_strategy::from_c(triangle_strategy, "triangle_strategy")?;
        let env = super::environment::strategy_from_c(environment_strategy)?;
        let out = out_ptr(out_sampler, "out_sampler")?;
        if env == EnvStrategy::Portals && s.scene.environment().is_some() {
            crate::analysis::scene_env_portals(&s.scene)?;
        }
        if let Some((_, map)) = s.scene.environment() {
            for strategy in [env, env.for_emission()] {
                match map.resolve(strategy) {
                    EnvStrategy::LatLong => {
                        map.latlong();
                    }
                    EnvStrategy::BsdfOnly => {}
                    _ => {
                        map.cube();
                    }
                }
            }
        }
        // SAFETY: `scene` is a live handle (checked above).
        let scene = unsafe { arc_clone(scene) };
        let sampler = lacuna_light_sampler {
            scene,
            env,
            triangles,
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, arc_into_handle(sampler)) };
        Ok(())
    })
}

/// Adds a reference to `sampler`. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_sampler_retain(sampler: *const lacuna_light_sampler) {
    boundary::value("lacuna_light_sampler_retain", (), |_| {
        // SAFETY: NULL or a live sampler.
        unsafe { arc_retain(sampler) };
        Ok(())
    })
}

/// Drops a reference to `sampler`; the last one destroys it. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_sampler_release(sampler: *const lacuna_light_sampler) {
    boundary::value("lacuna_light_sampler_release", (), |_| {
        // SAFETY: NULL or a live sampler; the caller gives up one reference.
        unsafe { arc_release(sampler) };
        Ok(())
    })
}

/// Writes what the sampler covers (light count, the environment's id, strategies, total power)
/// to `*out_info`. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_sampler_get_info(
    sampler: *const lacuna_light_sampler,
    out_info: *mut lacuna_light_sampler_info,
) -> lacuna_status {
    boundary::status("lacuna_light_sampler_get_info", |call| {
        // SAFETY: NULL or a live sampler.
        let s = unsafe { arg(sampler, "sampler") }?;
        call.context(&s.scene.ctx);
        let out = out_ptr(out_info, "out_info")?;
        let scene = s.scene();
        let lights = scene.lights();
        let info = lacuna_light_sampler_info {
            light_count: lights.len() as u32,
            environment_light: scene
                .environment()
                .map_or(LACUNA_INVALID_INDEX, |(i, _)| i as u32),
            area_light_count: lights
                .iter()
                .filter(|l| matches!(l, Light::Area { .. }))
                .count() as u32,
            triangle_strategy: match s.triangles {
                TriangleSampling::Area => lacuna_triangle_strategy::Area as u32,
                TriangleSampling::SolidAngle => lacuna_triangle_strategy::SolidAngle as u32,
            },
            environment_strategy: super::environment::strategy_to_c(s.env),
            total_power: lights.iter().map(|l| l.power().max(0.0)).sum(),
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, info) };
        Ok(())
    })
}

/// Writes light `light`'s kind, triangle, power and selection probability to `*out_info`.
/// `LACUNA_STATUS_OUT_OF_RANGE` unless `light < light_count`. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_sampler_get_light_info(
    sampler: *const lacuna_light_sampler,
    light: u32,
    out_info: *mut lacuna_light_info,
) -> lacuna_status {
    boundary::status("lacuna_light_sampler_get_light_info", |call| {
        // SAFETY: NULL or a live sampler.
        let s = unsafe { arg(sampler, "sampler") }?;
        call.context(&s.scene.ctx);
        let out = out_ptr(out_info, "out_info")?;
        let scene = s.scene();
        let l = scene.lights().get(light as usize).ok_or_else(|| {
            CapiError::range(format!(
                "light {light} is out of range (the scene has {} lights)",
                scene.lights().len()
            ))
        })?;
        let (kind, triangle) = match l {
            Light::Area { triangle, .. } => (lacuna_light_kind::Area, *triangle),
            Light::Point { .. } => (lacuna_light_kind::Point, LACUNA_INVALID_INDEX),
            Light::Spot { .. } => (lacuna_light_kind::Spot, LACUNA_INVALID_INDEX),
            Light::Directional { .. } => (lacuna_light_kind::Directional, LACUNA_INVALID_INDEX),
            Light::Environment { .. } => (lacuna_light_kind::Environment, LACUNA_INVALID_INDEX),
            Light::Photometric { .. } => (lacuna_light_kind::Photometric, LACUNA_INVALID_INDEX),
            Light::LightField { .. } => (lacuna_light_kind::LightField, LACUNA_INVALID_INDEX),
        };
        let info = lacuna_light_info {
            kind: kind as u32,
            triangle,
            power: l.power().max(0.0),
            selection_probability: scene.light_sampler().map_or(0.0, |t| t.pmf(light as usize)),
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, info) };
        Ok(())
    })
}

/// Writes the id of the light global triangle `triangle` belongs to (`lacuna_hit.triangle`) to
/// `*out_light`, or `LACUNA_INVALID_INDEX` when it does not emit. `LACUNA_STATUS_OUT_OF_RANGE`
/// unless `triangle` is below the scene's triangle count. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_sampler_get_triangle_light(
    sampler: *const lacuna_light_sampler,
    triangle: u32,
    out_light: *mut u32,
) -> lacuna_status {
    boundary::status("lacuna_light_sampler_get_triangle_light", |call| {
        // SAFETY: NULL or a live sampler.
        let s = unsafe { arg(sampler, "sampler") }?;
        call.context(&s.scene.ctx);
        let out = out_ptr(out_light, "out_light")?;
        let scene = s.scene();
        if triangle as usize >= scene.triangle_count() {
            return Err(CapiError::range(format!(
                "triangle {triangle} is out of range (the scene has {} triangles)",
                scene.triangle_count()
            )));
        }
        let light = scene
            .triangle_light(triangle)
            .map_or(LACUNA_INVALID_INDEX, |l| l as u32);
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, light) };
        Ok(())
    })
}

/// Samples one light for the shading point `*query` (position, normal, flags, and its two
/// random numbers `u`) and writes the sample to `*out_sample` (see `lacuna_light_sample` for
/// "no sample"). The shadow ray is the host's (or `lacuna_surface_spawn_shadow_ray`).
/// Errors: NULL pointers, non-finite position or normal (`LACUNA_STATUS_INVALID_ARGUMENT`),
/// unknown flags, `u` outside [0, 1) (`LACUNA_STATUS_OUT_OF_RANGE`). Thread-safe; does not
/// allocate.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_sampler_sample(
    sampler: *const lacuna_light_sampler,
    query: *const lacuna_light_query,
    out_sample: *mut lacuna_light_sample,
) -> lacuna_status {
    boundary::status("lacuna_light_sampler_sample", |call| {
        // SAFETY: NULL or a live sampler.
        let s = unsafe { arg(sampler, "sampler") }?;
        call.context(&s.scene.ctx);
        // SAFETY: NULL or a readable query.
        let q = query_from_c(
            &unsafe { super::buffer::read_arg(query, "query") }?,
            None,
            true,
        )?;
        let out = out_ptr(out_sample, "out_sample")?;
        let sample = s.sample(&q);
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, sample) };
        Ok(())
    })
}

/// The radiance light `hit->light` sends along the host's ray (from the query's position in
/// direction `hit->direction`, meeting the light at `hit->distance`) and the solid-angle
/// density `lacuna_light_sampler_sample` gives that direction from the same query, selection
/// probability included: the light-sampling density for the MIS weight of a BSDF-sampled ray
/// that hit an emitter or escaped to the environment. The query's `u` is ignored. Written to
/// `*out_eval`. Errors: NULL pointers, a light id out of range, non-finite or zero direction,
/// a distance to a triangle that is not finite and positive. Thread-safe; does not allocate.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_sampler_eval(
    sampler: *const lacuna_light_sampler,
    query: *const lacuna_light_query,
    hit: *const lacuna_light_hit,
    out_eval: *mut lacuna_light_eval,
) -> lacuna_status {
    boundary::status("lacuna_light_sampler_eval", |call| {
        // SAFETY: NULL or a live sampler.
        let s = unsafe { arg(sampler, "sampler") }?;
        call.context(&s.scene.ctx);
        // SAFETY: NULL or a readable query.
        let q = query_from_c(
            &unsafe { super::buffer::read_arg(query, "query") }?,
            None,
            false,
        )?;
        // SAFETY: NULL or a readable hit.
        let (light, dir, distance) =
            hit_from_c(s, &unsafe { super::buffer::read_arg(hit, "hit") }?, None)?;
        let out = out_ptr(out_eval, "out_eval")?;
        let e = s.eval(&q, light, dir, distance);
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, e) };
        Ok(())
    })
}

/// Samples a ray of light leaving a light, for light tracing: the light is picked by power
/// with `u[0]` (rescaled, it also picks the origin with `u[1]`), the direction with
/// `u[2], u[3]`. `u` points to 4 floats in [0, 1). Written to `*out_sample`. Thread-safe; does
/// not allocate.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_sampler_sample_emission(
    sampler: *const lacuna_light_sampler,
    u: *const f32,
    out_sample: *mut lacuna_emission_sample,
) -> lacuna_status {
    boundary::status("lacuna_light_sampler_sample_emission", |call| {
        // SAFETY: NULL or a live sampler.
        let s = unsafe { arg(sampler, "sampler") }?;
        call.context(&s.scene.ctx);
        if u.is_null() {
            return Err(CapiError::null("u"));
        }
        // SAFETY: non-NULL and readable for 4 floats per the contract.
        let u = unsafe { emission_numbers(u, None) }?;
        let out = out_ptr(out_sample, "out_sample")?;
        let e = s.sample_emission(u);
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, e) };
        Ok(())
    })
}

/// The densities `lacuna_light_sampler_sample_emission` has of light `light` emitting in unit
/// direction `direction` (finite, non-zero): the origin's per unit area and the direction's per
/// unit solid angle (as in `lacuna_emission_sample`), without the selection probability
/// (`lacuna_light_sampler_get_light_info`). Written to `*out_pdf_position` and
/// `*out_pdf_direction`. A light field's densities depend on where the ray leaves it, not only
/// on its direction: this gives 0 and 0 for one; `lacuna_light_sampler_emission_pdf_at` gives
/// them from the ray's origin. Thread-safe; does not allocate.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_sampler_emission_pdf(
    sampler: *const lacuna_light_sampler,
    light: u32,
    direction: lacuna_vec3,
    out_pdf_position: *mut f32,
    out_pdf_direction: *mut f32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        emission_pdf(
            "lacuna_light_sampler_emission_pdf",
            sampler,
            light,
            None,
            direction,
            out_pdf_position,
            out_pdf_direction,
        )
    }
}

/// `lacuna_light_sampler_emission_pdf` for the ray leaving point `origin` of light `light`
/// (finite; as `lacuna_emission_sample.origin` gives it) in unit direction `direction`
/// (finite, non-zero): a light field's densities depend on the origin (the point of its image
/// plane the ray leaves from); other lights ignore it. Written to `*out_pdf_position` and
/// `*out_pdf_direction`. Thread-safe; does not allocate.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_sampler_emission_pdf_at(
    sampler: *const lacuna_light_sampler,
    light: u32,
    origin: lacuna_vec3,
    direction: lacuna_vec3,
    out_pdf_position: *mut f32,
    out_pdf_direction: *mut f32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        emission_pdf(
            "lacuna_light_sampler_emission_pdf_at",
            sampler,
            light,
            Some(origin),
            direction,
            out_pdf_position,
            out_pdf_direction,
        )
    }
}

/// Both emission-density functions: with an origin, a light field's densities from it;
/// without, a light field gives 0 and 0 (its densities need the origin).
///
/// # Safety
/// As `lacuna_light_sampler_emission_pdf_at`.
#[allow(clippy::too_many_arguments)]
unsafe fn emission_pdf(
    function: &'static str,
    sampler: *const lacuna_light_sampler,
    light: u32,
    origin: Option<lacuna_vec3>,
    direction: lacuna_vec3,
    out_pdf_position: *mut f32,
    out_pdf_direction: *mut f32,
) -> lacuna_status {
    boundary::status(function, |call| {
        // SAFETY: NULL or a live sampler.
        let s = unsafe { arg(sampler, "sampler") }?;
        call.context(&s.scene.ctx);
        let scene = s.scene();
        let l = scene.lights().get(light as usize).ok_or_else(|| {
            CapiError::range(format!(
                "light {light} is out of range (the scene has {} lights)",
                scene.lights().len()
            ))
        })?;
        let o = origin.map(|o| o.finite("origin")).transpose()?;
        let d = direction.finite("direction")?;
        if d == Vec3::ZERO {
            return Err(CapiError::invalid("`direction` must be non-zero"));
        }
        let out_pos = out_ptr(out_pdf_position, "out_pdf_position")?;
        let out_dir = out_ptr(out_pdf_direction, "out_pdf_direction")?;
        let (pos, dir) = match o {
            Some(o) => l.split_emission_pdf(o, l.emission_pdf_at(s.env, o, d.normalize())),
            None => l.split_emission_pdf(Vec3::ZERO, l.emission_pdf_with(s.env, d.normalize())),
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe {
            write_out(out_pos, pos);
            write_out(out_dir, dir);
        }
        Ok(())
    })
}

/// `lacuna_light_sampler_sample` for `count` queries found every `query_stride` bytes from
/// `queries` (0 = packed), samples written every `sample_stride` bytes to `out_samples`
/// (0 = packed). Every query is checked before any sample is written; on failure nothing is
/// written and the message names the first bad element. A count of 0 accepts NULL arrays.
/// Runs on the calling thread (call it from several threads to parallelise); thread-safe;
/// does not allocate.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_sampler_sample_batch(
    sampler: *const lacuna_light_sampler,
    queries: *const lacuna_light_query,
    query_stride: usize,
    count: usize,
    out_samples: *mut lacuna_light_sample,
    sample_stride: usize,
) -> lacuna_status {
    boundary::status("lacuna_light_sampler_sample_batch", |call| {
        // SAFETY: NULL or a live sampler.
        let s = unsafe { arg(sampler, "sampler") }?;
        call.context(&s.scene.ctx);
        let qs = strided(
            queries.cast(),
            query_stride,
            count,
            size_of::<lacuna_light_query>(),
            "queries",
        )?;
        let os = strided(
            out_samples.cast_const().cast(),
            sample_stride,
            count,
            size_of::<lacuna_light_sample>(),
            "out_samples",
        )?;
        for i in 0..count {
            // SAFETY: i < count of the checked array the caller promises readable.
            query_from_c(&unsafe { read_at(queries, qs, i) }, Some(i), true)?;
        }
        for i in 0..count {
            // SAFETY: as above; checked already, so this cannot fail.
            let q = query_from_c(&unsafe { read_at(queries, qs, i) }, Some(i), true)?;
            // SAFETY: i < count of the checked array the caller promises writable.
            unsafe { write_at(out_samples, os, i, s.sample(&q)) };
        }
        Ok(())
    })
}

/// `lacuna_light_sampler_eval` for `count` (query, hit) pairs from strided arrays (0 = packed),
/// results written every `eval_stride` bytes to `out_evals`. Every element is checked before
/// any result is written. Runs on the calling thread; thread-safe; does not allocate.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_sampler_eval_batch(
    sampler: *const lacuna_light_sampler,
    queries: *const lacuna_light_query,
    query_stride: usize,
    hits: *const lacuna_light_hit,
    hit_stride: usize,
    count: usize,
    out_evals: *mut lacuna_light_eval,
    eval_stride: usize,
) -> lacuna_status {
    boundary::status("lacuna_light_sampler_eval_batch", |call| {
        // SAFETY: NULL or a live sampler.
        let s = unsafe { arg(sampler, "sampler") }?;
        call.context(&s.scene.ctx);
        let qs = strided(
            queries.cast(),
            query_stride,
            count,
            size_of::<lacuna_light_query>(),
            "queries",
        )?;
        let hs = strided(
            hits.cast(),
            hit_stride,
            count,
            size_of::<lacuna_light_hit>(),
            "hits",
        )?;
        let es = strided(
            out_evals.cast_const().cast(),
            eval_stride,
            count,
            size_of::<lacuna_light_eval>(),
            "out_evals",
        )?;
        let element = |i: usize| -> CapiResult<(Query, (usize, Vec3, f32))> {
            // SAFETY: i < count of the checked arrays the caller promises readable.
            let q = query_from_c(&unsafe { read_at(queries, qs, i) }, Some(i), false)?;
            // SAFETY: as above.
            let h = hit_from_c(s, &unsafe { read_at(hits, hs, i) }, Some(i))?;
            Ok((q, h))
        };
        for i in 0..count {
            element(i)?;
        }
        for i in 0..count {
            let (q, (light, dir, distance)) = element(i)?;
            // SAFETY: i < count of the checked array the caller promises writable.
            unsafe { write_at(out_evals, es, i, s.eval(&q, light, dir, distance)) };
        }
        Ok(())
    })
}

/// `lacuna_light_sampler_sample_emission` for `count` sets of 4 random numbers found every
/// `u_stride` bytes from `u` (0 = packed, 16 bytes), samples written every `sample_stride`
/// bytes to `out_samples`. Every number is checked before any sample is written. Runs on the
/// calling thread; thread-safe; does not allocate.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_sampler_sample_emission_batch(
    sampler: *const lacuna_light_sampler,
    u: *const f32,
    u_stride: usize,
    count: usize,
    out_samples: *mut lacuna_emission_sample,
    sample_stride: usize,
) -> lacuna_status {
    boundary::status("lacuna_light_sampler_sample_emission_batch", |call| {
        // SAFETY: NULL or a live sampler.
        let s = unsafe { arg(sampler, "sampler") }?;
        call.context(&s.scene.ctx);
        let us = strided(u.cast(), u_stride, count, 16, "u")?;
        let os = strided(
            out_samples.cast_const().cast(),
            sample_stride,
            count,
            size_of::<lacuna_emission_sample>(),
            "out_samples",
        )?;
        // SAFETY (both loops): i < count of the checked array of 16-byte elements the caller
        // promises readable.
        let numbers =
            |i: usize| unsafe { emission_numbers(u.cast::<u8>().add(i * us).cast(), Some(i)) };
        for i in 0..count {
            numbers(i)?;
        }
        for i in 0..count {
            let e = s.sample_emission(numbers(i)?);
            // SAFETY: i < count of the checked array the caller promises writable.
            unsafe { write_at(out_samples, os, i, e) };
        }
        Ok(())
    })
}
