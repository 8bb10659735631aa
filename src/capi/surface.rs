//! What a host that shades its own surfaces reads from a committed scene: the surface and
//! material at a hit, the scene's camera, and rays leaving a surface robustly (offset by the
//! hit point's floating-point error bound, as Lacuna's own integrators spawn them).

use std::ffi::c_char;

use super::boundary::{self, lacuna_status, CapiError, CapiResult};
use super::buffer::{arg, out_ptr, read_arg, str_arg, write_out};
use super::light_sampler::{lacuna_light_sample, LACUNA_LIGHT_SAMPLE_INFINITE};
use super::scene::lacuna_scene;
use super::types::*;
use crate::geometry::{offset_ray_origin, Hit, Ray, SHADOW_EPSILON};
use crate::math::Vec3;
use crate::scene::MaterialKind;

/// A surface point and its material, resolved at a hit (`lacuna_scene_get_surface`). The
/// layout (120 bytes, 4-byte aligned) never changes with build options.
///
/// Materials follow Lacuna's conventions (docs/scene-format.md): BSDFs are two-sided (they
/// reflect on the side of the outgoing direction); DIFFUSE is Lambertian `diffuse / pi`;
/// GLOSSY is the modified Phong `diffuse / pi + specular (exponent + 2) / (2 pi)
/// cos^exponent(alpha)` with alpha the angle between the incident direction and the mirror
/// direction of the outgoing one (zero beyond 90 degrees); MIRROR reflects `specular`;
/// DIELECTRIC is smooth glass of index `ior`; ROUGH_DIELECTRIC is frosted glass of index `ior`,
/// GGX microfacet reflection and transmission (Walter et al. 2007, separable Smith G) of width
/// alpha = `roughness`. `emission` is emitted on the geometric normal's
/// side only.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct lacuna_surface {
    pub position: [f32; 3],
    /// Global triangle index.
    pub triangle: u32,
    /// Bound on the floating-point error of `position`, per axis.
    pub position_error: [f32; 3],
    /// Material index.
    pub material: u32,
    /// Unit geometric normal on the triangle's front side.
    pub geometric_normal: [f32; 3],
    /// A `lacuna_material_kind` value.
    pub kind: u32,
    /// Unit shading normal (interpolated vertex normals, else the geometric normal), on the
    /// same side as the geometric normal.
    pub shading_normal: [f32; 3],
    /// Phong exponent (GLOSSY).
    pub exponent: f32,
    /// Texture coordinates (the barycentrics u, v without texture coordinates).
    pub uv: [f32; 2],
    /// Index of refraction (DIELECTRIC, ROUGH_DIELECTRIC).
    pub ior: f32,
    /// Diffuse albedo with the texture applied.
    pub diffuse: lacuna_rgb,
    /// Specular reflectance (GLOSSY, MIRROR).
    pub specular: lacuna_rgb,
    /// Emitted radiance on the front side.
    pub emission: lacuna_rgb,
    /// GGX width alpha (ROUGH_DIELECTRIC; at least 1e-3 where it is rendered).
    pub roughness: f32,
}

/// The scene's camera (`lacuna_scene_get_camera`): a look-at placement with a vertical field
/// of view, and a thin lens when `lens_radius > 0`. Camera rays through film position
/// (fx, fy) in [0, 1)^2 (x right, y down) of a W x H image: `forward = normalize(target - eye)`,
/// `right = normalize(cross(forward, up))`, `up' = cross(right, forward)`,
/// `t = tan(vfov / 2)`, direction
/// `normalize(forward + right t (W / H) (2 fx - 1) + up' t (1 - 2 fy))` from `eye`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct lacuna_camera {
    pub eye: [f32; 3],
    /// Vertical field of view, degrees.
    pub vfov_degrees: f32,
    pub target: [f32; 3],
    pub lens_radius: f32,
    pub up: [f32; 3],
    pub focus_distance: f32,
}

/// Checks a hit from C against the scene and turns it into Lacuna's.
fn hit_from_c(s: &lacuna_scene, h: &lacuna_hit) -> CapiResult<Hit> {
    let count = s.scene.triangle_count();
    if h.triangle as usize >= count {
        return Err(CapiError::range(format!(
            "hit triangle {} is out of range (the scene has {count} triangles; a miss has no surface)",
            h.triangle
        )));
    }
    let ok = |x: f32| x.is_finite() && (-1e-3..=1.0 + 1e-3).contains(&x);
    if !ok(h.u) || !ok(h.v) || !ok(h.u + h.v) {
        return Err(CapiError::invalid(format!(
            "hit barycentrics u = {}, v = {} must be finite with u, v, u + v in [0, 1]",
            h.u, h.v
        )));
    }
    Ok(Hit {
        t: h.t,
        triangle: h.triangle,
        b1: h.u,
        b2: h.v,
    })
}

fn rgb(c: crate::math::Rgb) -> lacuna_rgb {
    lacuna_rgb {
        r: c.x,
        g: c.y,
        b: c.z,
    }
}

/// Writes the surface point and the material at `*hit` (from `lacuna_scene_intersect` on this
/// scene) to `*out_surface`: position with its error bound, normals, uv, and the material's
/// parameters with textures applied. `LACUNA_STATUS_OUT_OF_RANGE` for a miss or a triangle
/// index out of range, `LACUNA_STATUS_INVALID_ARGUMENT` for barycentrics outside the
/// triangle. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_get_surface(
    scene: *const lacuna_scene,
    hit: *const lacuna_hit,
    out_surface: *mut lacuna_surface,
) -> lacuna_status {
    boundary::status("lacuna_scene_get_surface", |call| {
        // SAFETY: NULL or a live scene.
        let s = unsafe { arg(scene, "scene") }?;
        call.context(&s.ctx);
        // SAFETY: NULL or a readable hit.
        let h = hit_from_c(s, &unsafe { read_arg(hit, "hit") }?)?;
        let out = out_ptr(out_surface, "out_surface")?;
        // The interaction does not depend on the ray's origin; its direction only sets `wo`,
        // which is not part of the surface.
        let si = s
            .scene
            .interaction(&Ray::new(Vec3::ZERO, Vec3::Z, f32::INFINITY), &h);
        let ns = if si.ns.dot(si.ng) < 0.0 {
            -si.ns
        } else {
            si.ns
        };
        let material = &s.scene.materials()[si.material as usize];
        let diffuse = match material.diffuse_texture {
            Some(t) => s.scene.textures()[t as usize].lookup(si.uv) * material.diffuse,
            None => material.diffuse,
        };
        let kind = match material.kind {
            MaterialKind::Diffuse => lacuna_material_kind::Diffuse,
            MaterialKind::Glossy => lacuna_material_kind::Glossy,
            MaterialKind::Mirror => lacuna_material_kind::Mirror,
            MaterialKind::Dielectric => lacuna_material_kind::Dielectric,
            MaterialKind::RoughDielectric => lacuna_material_kind::RoughDielectric,
        };
        let surface = lacuna_surface {
            position: si.p.to_array(),
            triangle: si.triangle,
            position_error: si.p_error.to_array(),
            material: si.material,
            geometric_normal: si.ng.to_array(),
            kind: kind as u32,
            shading_normal: ns.to_array(),
            exponent: material.exponent,
            uv: si.uv.to_array(),
            ior: material.ior,
            diffuse: rgb(diffuse),
            specular: rgb(material.specular),
            emission: rgb(material.emission),
            roughness: material.roughness,
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, surface) };
        Ok(())
    })
}

/// Writes the scene's camera (from its scene file, the built-in scene, or
/// `lacuna_scene_builder_set_camera`) to `*out_camera`. `LACUNA_STATUS_INVALID_OPERATION` when
/// the scene has none. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_get_camera(
    scene: *const lacuna_scene,
    out_camera: *mut lacuna_camera,
) -> lacuna_status {
    boundary::status("lacuna_scene_get_camera", |call| {
        // SAFETY: NULL or a live scene.
        let s = unsafe { arg(scene, "scene") }?;
        call.context(&s.ctx);
        let out = out_ptr(out_camera, "out_camera")?;
        let c = s
            .scene
            .camera()
            .ok_or_else(|| CapiError::operation("the scene has no camera"))?;
        let camera = lacuna_camera {
            eye: c.eye.to_array(),
            vfov_degrees: c.vfov_degrees,
            target: c.target.to_array(),
            lens_radius: c.lens_radius,
            up: c.up.to_array(),
            focus_distance: c.focus_distance,
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, camera) };
        Ok(())
    })
}

/// Checks a surface from C.
fn surface_from_c(s: &lacuna_surface) -> CapiResult<(Vec3, Vec3, Vec3)> {
    let p = Vec3::from(s.position);
    let e = Vec3::from(s.position_error);
    let n = Vec3::from(s.geometric_normal);
    if !p.is_finite() || !e.is_finite() || !n.is_finite() || n == Vec3::ZERO {
        return Err(CapiError::invalid(format!(
            "surface position {p}, position_error {e} and geometric_normal {n} must be finite (the normal non-zero)"
        )));
    }
    Ok((p, e, n))
}

/// Writes the ray leaving `*surface` in `direction` (finite, non-zero), its origin moved off
/// the surface by the position's error bound on the side `direction` goes to, tmax = +infinity,
/// to `*out_ray`. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_surface_spawn_ray(
    surface: *const lacuna_surface,
    direction: lacuna_vec3,
    out_ray: *mut lacuna_ray,
) -> lacuna_status {
    boundary::status("lacuna_surface_spawn_ray", |_| {
        // SAFETY: NULL or a readable surface.
        let (p, e, n) = surface_from_c(&unsafe { read_arg(surface, "surface") }?)?;
        let d = direction.finite("direction")?;
        if d == Vec3::ZERO {
            return Err(CapiError::invalid("`direction` must be non-zero"));
        }
        let out = out_ptr(out_ray, "out_ray")?;
        let ray = lacuna_ray {
            origin: offset_ray_origin(p, e, n, d).to_array(),
            tmax: f32::INFINITY,
            direction: d.to_array(),
            flags: 0,
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, ray) };
        Ok(())
    })
}

/// Writes the shadow ray from `*surface` to the light point of `*sample` (a sample with a
/// light, from a query at this surface) to `*out_ray`: both ends moved off their surfaces by
/// their error bounds and the far end short by a relative 1e-4, or an unbounded ray for lights
/// at infinity. `lacuna_scene_occluded` on it tells whether the light is visible.
/// `LACUNA_STATUS_INVALID_ARGUMENT` for a sample without a light. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_surface_spawn_shadow_ray(
    surface: *const lacuna_surface,
    sample: *const lacuna_light_sample,
    out_ray: *mut lacuna_ray,
) -> lacuna_status {
    boundary::status("lacuna_surface_spawn_shadow_ray", |_| {
        // SAFETY: NULL or a readable surface.
        let (p, e, n) = surface_from_c(&unsafe { read_arg(surface, "surface") }?)?;
        // SAFETY: NULL or a readable sample.
        let ls = unsafe { read_arg(sample, "sample") }?;
        let out = out_ptr(out_ray, "out_ray")?;
        let wi = Vec3::from(ls.direction);
        if ls.light == LACUNA_INVALID_INDEX || !wi.is_finite() || wi == Vec3::ZERO {
            return Err(CapiError::invalid(
                "`sample` has no light (light = LACUNA_INVALID_INDEX) or no direction",
            ));
        }
        let ray = if ls.flags & LACUNA_LIGHT_SAMPLE_INFINITE != 0 {
            Ray::new(offset_ray_origin(p, e, n, wi), wi, f32::INFINITY)
        } else {
            let to = Vec3::from(ls.point);
            let to_error = Vec3::from(ls.point_error);
            let to_normal = Vec3::from(ls.light_normal);
            if !to.is_finite() || !to_error.is_finite() || !to_normal.is_finite() {
                return Err(CapiError::invalid(format!(
                    "`sample` point {to}, point_error {to_error} and light_normal {to_normal} must be finite"
                )));
            }
            let from = offset_ray_origin(p, e, n, to - p);
            let to = offset_ray_origin(to, to_error, to_normal, from - to);
            let d = to - from;
            let len = d.length();
            if len == 0.0 {
                Ray::new(from, n, 0.0)
            } else {
                Ray::new(from, d / len, len * (1.0 - SHADOW_EPSILON))
            }
        };
        let r = lacuna_ray {
            origin: ray.origin.to_array(),
            tmax: ray.t_max,
            direction: ray.dir.to_array(),
            flags: 0,
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, r) };
        Ok(())
    })
}

/// Creates a scene builder filled with one of Lacuna's built-in scenes (camera included), as
/// `lacuna render` names them: `"two-rooms"` (two rooms joined by a doorway, lit from the far
/// one), `"corridor"` or `"interior"` (a house lit by a sky map through windows). `LACUNA_STATUS_INVALID_ARGUMENT` for another name. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_new_builtin(
    context: *const super::context::lacuna_context,
    name: *const c_char,
    out_builder: *mut *mut super::builder::lacuna_scene_builder,
) -> lacuna_status {
    boundary::status("lacuna_scene_builder_new_builtin", |call| {
        // SAFETY: NULL or a live context.
        let ctx = unsafe { arg(context, "context") }?;
        call.context(ctx);
        // SAFETY: NULL or a NUL-terminated string.
        let name = unsafe { str_arg(name, "name") }?;
        let out = out_ptr(out_builder, "out_builder")?;
        let (builder, settings) = match name {
            "two-rooms" => (
                crate::scene::two_rooms_builder()?,
                crate::scene::RenderSettingsFile::default(),
            ),
            "corridor" => (
                crate::scene::corridor_builder()?,
                crate::scene::corridor_render_settings(),
            ),
            "interior" => (
                crate::scene::interior_builder()?,
                crate::scene::RenderSettingsFile::default(),
            ),
            other => {
                return Err(CapiError::invalid(format!(
                    "unknown built-in scene '{other}' (expected two-rooms, corridor or interior)"
                )))
            }
        };
        // SAFETY: `context` is a live handle (checked above).
        let ctx = unsafe { super::buffer::arc_clone(context) };
        let b = super::builder::new_builder(ctx, builder);
        // SAFETY: `b` was just made by `Box::into_raw`.
        unsafe {
            (*b).settings = settings;
            (*b).label = name.to_string();
            write_out(out, b);
        }
        Ok(())
    })
}
