//! `lacuna_scene_builder`: materials, meshes, lights, camera and file loading, consumed by
//! `lacuna_scene_builder_build` into a committed `lacuna_scene`.

use std::collections::BTreeSet;
use std::ffi::c_char;
use std::sync::{Arc, Mutex};

use super::boundary::{self, lacuna_status, Call, CapiError, CapiResult};
use super::buffer::{
    arc_clone, arc_into_handle, arg, box_free, finite, out_ptr, path_arg, read_strided, str_arg,
    write_out,
};
use super::context::lacuna_context;
use super::light_field::lacuna_light_field;
use super::mesh::lacuna_mesh;
use super::photometric::lacuna_photometric_profile;
use super::scene::lacuna_scene;
use super::types::*;
use crate::geometry::BvhQuality;
use crate::light::LightDesc;
use crate::math::Rgb;
use crate::scene::{
    load_obj, load_scene_file, Camera, DegeneratePolicy, Material, RenderSettingsFile, SceneBuilder,
};

/// Collects and validates a scene: materials, meshes, lights, camera. Every call checks its
/// input and fails with a message naming the bad value; nothing is kept from a failed call.
///
/// Single owner (`lacuna_scene_builder_new`/`lacuna_scene_builder_free`), consumed by
/// `lacuna_scene_builder_build`. Not thread-safe: one thread at a time may use a builder.
/// It keeps its context alive.
pub struct lacuna_scene_builder {
    pub(crate) ctx: Arc<lacuna_context>,
    pub(crate) builder: SceneBuilder,
    /// The camera set through this API (thin-lens settings apply to it).
    camera: Option<Camera>,
    /// Render settings from a scene file (defaults of render jobs on the built scene).
    pub(crate) settings: RenderSettingsFile,
    pub(crate) label: String,
}

/// Addresses of the live builders. A builder that was built or freed is gone from here, so
/// building it again, using it after the build or freeing it twice is refused
/// (`LACUNA_STATUS_INVALID_OPERATION`) instead of touching freed memory: a cheap check, as
/// builder calls are few. (A new builder may reuse a freed address; then the stale handle
/// names the new builder, which no check can tell.)
static LIVE_BUILDERS: Mutex<BTreeSet<usize>> = Mutex::new(BTreeSet::new());

fn live_builders() -> std::sync::MutexGuard<'static, BTreeSet<usize>> {
    LIVE_BUILDERS.lock().unwrap_or_else(|e| e.into_inner())
}

fn not_live() -> CapiError {
    CapiError::operation(
        "builder is not a live builder: it was already built or freed (a builder is consumed by lacuna_scene_builder_build)",
    )
}

/// Checks that `builder` is live, and with `take` forgets it (it is about to be consumed).
pub(crate) fn check_live(builder: *mut lacuna_scene_builder, take: bool) -> CapiResult<()> {
    let mut live = live_builders();
    let known = if take {
        live.remove(&(builder as usize))
    } else {
        live.contains(&(builder as usize))
    };
    if known {
        Ok(())
    } else {
        Err(not_live())
    }
}

pub(crate) fn new_builder(
    ctx: Arc<lacuna_context>,
    builder: SceneBuilder,
) -> *mut lacuna_scene_builder {
    let handle = Box::into_raw(Box::new(lacuna_scene_builder {
        ctx,
        builder,
        camera: None,
        settings: RenderSettingsFile::default(),
        label: "scene".to_string(),
    }));
    live_builders().insert(handle as usize);
    handle
}

/// Creates an empty scene builder on `context` (which it keeps alive). Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_new(
    context: *const lacuna_context,
    out_builder: *mut *mut lacuna_scene_builder,
) -> lacuna_status {
    boundary::status("lacuna_scene_builder_new", |call| {
        // SAFETY: NULL or a live context.
        let ctx = unsafe { arg(context, "context") }?;
        call.context(ctx);
        let out = out_ptr(out_builder, "out_builder")?;
        // SAFETY: `context` is a live handle (checked above).
        let ctx = unsafe { arc_clone(context) };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, new_builder(ctx, SceneBuilder::new())) };
        Ok(())
    })
}

/// Creates a scene builder filled from a JSON scene file (its OBJ files, shapes, camera, lights
/// and material overrides; see docs/scene-format.md). The file's render settings become the
/// defaults of render jobs on the built scene. Fails with `LACUNA_STATUS_IO` when a file
/// cannot be read and `LACUNA_STATUS_PARSE` (message with file and line or field) when it is
/// malformed. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_new_from_file(
    context: *const lacuna_context,
    path: *const c_char,
    out_builder: *mut *mut lacuna_scene_builder,
) -> lacuna_status {
    boundary::status("lacuna_scene_builder_new_from_file", |call| {
        // SAFETY: NULL or a live context.
        let ctx = unsafe { arg(context, "context") }?;
        call.context(ctx);
        // SAFETY: NULL or a NUL-terminated string.
        let path = unsafe { path_arg(path, "path") }?;
        let out = out_ptr(out_builder, "out_builder")?;
        let loaded = load_scene_file(&path)?;
        // SAFETY: `context` is a live handle (checked above).
        let ctx = unsafe { arc_clone(context) };
        let b = new_builder(ctx, loaded.builder);
        // SAFETY: `b` was just made by `Box::into_raw`.
        unsafe {
            (*b).settings = loaded.settings;
            (*b).label = path
                .file_stem()
                .map_or("scene".into(), |s| s.to_string_lossy().into_owned());
            write_out(out, b);
        }
        Ok(())
    })
}

/// Frees a builder that was not built. NULL is a no-op. A builder that was already built or
/// freed is left alone (the failure is recorded for `lacuna_last_error_message()`).
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_free(builder: *mut lacuna_scene_builder) {
    boundary::value("lacuna_scene_builder_free", (), |_| {
        if builder.is_null() {
            return Ok(());
        }
        check_live(builder, true)?;
        // SAFETY: a live builder from `lacuna_scene_builder_new*` (checked above), not used
        // afterwards.
        unsafe { box_free(builder) };
        Ok(())
    })
}

/// Runs `f` on a builder, with its context's error callback.
///
/// # Safety
/// `builder` must be NULL or a live builder used by this thread only.
unsafe fn with_builder(
    function: &'static str,
    builder: *mut lacuna_scene_builder,
    f: impl FnOnce(&mut lacuna_scene_builder) -> CapiResult<()>,
) -> lacuna_status {
    boundary::status(function, |call: &mut Call<'_>| {
        // SAFETY: NULL or a live builder used by this thread only (caller's contract).
        if builder.is_null() {
            return Err(CapiError::null("builder"));
        }
        check_live(builder, false)?;
        // SAFETY: a live builder (checked above) used by this thread only.
        let b = unsafe { &mut *builder };
        // SAFETY: the context outlives the call: the builder holds a reference to it and
        // `f` cannot drop the builder (it only borrows it).
        call.context(unsafe { &*Arc::as_ptr(&b.ctx) });
        f(b)
    })
}

/// Sets what the builder does with zero-area triangles added afterwards: a
/// `lacuna_degenerate_policy` value (ERROR refuses the mesh, the default; SKIP drops them).
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_set_degenerate_policy(
    builder: *mut lacuna_scene_builder,
    policy: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_set_degenerate_policy", builder, |b| {
            let p = match lacuna_degenerate_policy::from_c(policy, "policy")? {
                lacuna_degenerate_policy::Error => DegeneratePolicy::Error,
                lacuna_degenerate_policy::Skip => DegeneratePolicy::Skip,
            };
            b.builder.set_degenerate_policy(p);
            Ok(())
        })
    }
}

/// Sets the acceleration structure's build quality: a `lacuna_bvh_quality` value.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_set_bvh_quality(
    builder: *mut lacuna_scene_builder,
    quality: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_set_bvh_quality", builder, |b| {
            let q = match lacuna_bvh_quality::from_c(quality, "quality")? {
                lacuna_bvh_quality::Fast => BvhQuality::Fast,
                lacuna_bvh_quality::Medium => BvhQuality::Medium,
                lacuna_bvh_quality::High => BvhQuality::High,
            };
            b.builder.set_bvh_quality(q);
            Ok(())
        })
    }
}

/// Adds a material of kind `kind` (a `lacuna_material_kind` value) with that kind's defaults
/// (diffuse: albedo 0.5; glossy: diffuse 0.4, specular 0.4, exponent 20; mirror: reflectance
/// 1; dielectric: IOR 1.5) and writes its index to `*out_index`. Set its parameters with
/// `lacuna_scene_builder_set_material_*`.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_add_material(
    builder: *mut lacuna_scene_builder,
    kind: u32,
    out_index: *mut u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_add_material", builder, |b| {
            let out = out_ptr(out_index, "out_index")?;
            let m = match lacuna_material_kind::from_c(kind, "kind")? {
                lacuna_material_kind::Diffuse => Material::diffuse(Rgb::splat(0.5)),
                lacuna_material_kind::Glossy => {
                    Material::glossy(Rgb::splat(0.4), Rgb::splat(0.4), 20.0)
                }
                lacuna_material_kind::Mirror => Material::mirror(Rgb::ONE),
                lacuna_material_kind::Dielectric => Material::dielectric(1.5),
                lacuna_material_kind::RoughDielectric => Material::rough_dielectric(1.5, 0.3),
            };
            let index = b.builder.add_material(m)?;
            write_out(out, index);
            Ok(())
        })
    }
}

/// Changes material `index` through `f` and validates the result as a whole.
fn edit_material(
    b: &mut lacuna_scene_builder,
    index: u32,
    f: impl FnOnce(&mut Material),
) -> CapiResult<()> {
    let n = b.builder.material_count();
    let mut m = b
        .builder
        .materials_mut()
        .get(index as usize)
        .cloned()
        .ok_or_else(|| {
            CapiError::range(format!(
                "material index {index} out of range ({n} materials)"
            ))
        })?;
    f(&mut m);
    b.builder.set_material(index, m)?;
    Ok(())
}

/// Sets a colour parameter (a `lacuna_material_rgb` value) of material `index`. The material
/// is validated as a whole: for a glossy material, lower one lobe before raising the other so
/// that diffuse + specular stays <= 1.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_set_material_rgb(
    builder: *mut lacuna_scene_builder,
    index: u32,
    param: u32,
    value: lacuna_rgb,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_set_material_rgb", builder, |b| {
            let p = lacuna_material_rgb::from_c(param, "param")?;
            let v = value.finite("value")?;
            edit_material(b, index, |m| match p {
                lacuna_material_rgb::Diffuse => m.diffuse = v,
                lacuna_material_rgb::Specular => m.specular = v,
                lacuna_material_rgb::Emission => m.emission = v,
            })
        })
    }
}

/// Sets a scalar parameter (a `lacuna_material_float` value) of material `index`.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_set_material_float(
    builder: *mut lacuna_scene_builder,
    index: u32,
    param: u32,
    value: f32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_set_material_float", builder, |b| {
            let p = lacuna_material_float::from_c(param, "param")?;
            let v = finite(value, "value")?;
            edit_material(b, index, |m| match p {
                lacuna_material_float::Exponent => m.exponent = v,
                lacuna_material_float::Ior => m.ior = v,
                lacuna_material_float::Roughness => m.roughness = v,
            })
        })
    }
}

/// Names material `index` (UTF-8; used in messages). Copied.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_set_material_name(
    builder: *mut lacuna_scene_builder,
    index: u32,
    name: *const c_char,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_set_material_name", builder, |b| {
            let name = str_arg(name, "name")?.to_string();
            edit_material(b, index, |m| m.name = name)
        })
    }
}

/// Writes the number of materials (added or loaded) to `*out_count`.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_get_material_count(
    builder: *const lacuna_scene_builder,
    out_count: *mut u32,
) -> lacuna_status {
    boundary::status("lacuna_scene_builder_get_material_count", |call| {
        // SAFETY: NULL or a live builder.
        let b = unsafe { arg(builder, "builder") }?;
        call.context(&b.ctx);
        let out = out_ptr(out_count, "out_count")?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, b.builder.material_count() as u32) };
        Ok(())
    })
}

/// Adds a copy of `mesh` after checking every value (finite positions, normals and uvs,
/// matching counts, vertex and material indices in range, no zero-area triangle unless the
/// degenerate policy is SKIP) and writes its index to `*out_index`. The mesh may be changed,
/// added again or freed afterwards.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_add_mesh(
    builder: *mut lacuna_scene_builder,
    mesh: *const lacuna_mesh,
    out_index: *mut u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_add_mesh", builder, |b| {
            let m = arg(mesh, "mesh")?;
            let out = out_ptr(out_index, "out_index")?;
            if m.desc.indices.len() > u32::MAX as usize - 1 {
                return Err(CapiError::range(format!(
                    "{} triangles exceed the limit of 2^32 - 2",
                    m.desc.indices.len()
                )));
            }
            let index = b.builder.add_mesh(m.desc.clone())?;
            write_out(out, index);
            Ok(())
        })
    }
}

/// Adds an isotropic point light with radiant intensity `intensity` (W/sr, >= 0).
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_add_point_light(
    builder: *mut lacuna_scene_builder,
    position: lacuna_vec3,
    intensity: lacuna_rgb,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_add_point_light", builder, |b| {
            b.builder.add_light(LightDesc::Point {
                position: position.finite("position")?,
                intensity: intensity.finite("intensity")?,
            })?;
            Ok(())
        })
    }
}

/// Adds a spot light at `position` pointing along `direction` (non-zero) with intensity
/// `intensity` inside the half-angle `inner_degrees`, falling smoothly to zero at
/// `outer_degrees` (0 <= inner <= outer <= 180).
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_add_spot_light(
    builder: *mut lacuna_scene_builder,
    position: lacuna_vec3,
    direction: lacuna_vec3,
    intensity: lacuna_rgb,
    inner_degrees: f32,
    outer_degrees: f32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_add_spot_light", builder, |b| {
            b.builder.add_light(LightDesc::Spot {
                position: position.finite("position")?,
                direction: direction.finite("direction")?,
                intensity: intensity.finite("intensity")?,
                inner_degrees: finite(inner_degrees, "inner_degrees")?,
                outer_degrees: finite(outer_degrees, "outer_degrees")?,
            })?;
            Ok(())
        })
    }
}

/// Adds a measured luminaire at `position` with `profile`'s intensity distribution (the
/// builder keeps a reference): radiant intensity `intensity` (>= 0, W/sr per candela) times
/// the profile's candela. The profile's nadir (gamma = 0) points along `direction` (non-zero)
/// and its C0 plane towards `c0` (made perpendicular to `direction`; zero or parallel picks an
/// arbitrary perpendicular); C90 is `direction` x `c0`.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_add_photometric_light(
    builder: *mut lacuna_scene_builder,
    profile: *const lacuna_photometric_profile,
    position: lacuna_vec3,
    direction: lacuna_vec3,
    c0: lacuna_vec3,
    intensity: lacuna_rgb,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_add_photometric_light", builder, |b| {
            let profile = arg(profile, "profile")?.profile.clone();
            b.builder.add_light(LightDesc::Photometric {
                position: position.finite("position")?,
                direction: direction.finite("direction")?,
                c0: c0.finite("c0")?,
                intensity: intensity.finite("intensity")?,
                profile,
            })?;
            Ok(())
        })
    }
}

/// Adds a light-field luminaire with `field`'s light (the builder keeps a reference): its
/// frame's origin at `position`, its +z (where light travels) along `direction` (non-zero),
/// its +x toward `x_axis` (made perpendicular to `direction`; zero or parallel picks an
/// arbitrary perpendicular); radiance times `scale` (>= 0). Rendered by `path` and
/// `path_skeleton`; bidirectional integrators refuse scenes with it when rendering.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_add_light_field_light(
    builder: *mut lacuna_scene_builder,
    field: *const lacuna_light_field,
    position: lacuna_vec3,
    direction: lacuna_vec3,
    x_axis: lacuna_vec3,
    scale: lacuna_rgb,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_add_light_field_light", builder, |b| {
            let field = arg(field, "field")?.field.clone();
            b.builder.add_light(LightDesc::LightField {
                position: position.finite("position")?,
                direction: direction.finite("direction")?,
                x_axis: x_axis.finite("x_axis")?,
                scale: scale.finite("scale")?,
                field,
            })?;
            Ok(())
        })
    }
}

/// Adds a distant light travelling along `direction` (non-zero) that gives irradiance
/// `irradiance` (W/m^2) on a surface facing it.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_add_directional_light(
    builder: *mut lacuna_scene_builder,
    direction: lacuna_vec3,
    irradiance: lacuna_rgb,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_add_directional_light", builder, |b| {
            b.builder.add_light(LightDesc::Directional {
                direction: direction.finite("direction")?,
                irradiance: irradiance.finite("irradiance")?,
            })?;
            Ok(())
        })
    }
}

/// Sets a pinhole camera at `eye` looking at `target`, with `up` (not parallel to the view
/// direction) and a vertical field of view in (0, 180) degrees. Replaces any camera.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_set_camera(
    builder: *mut lacuna_scene_builder,
    eye: lacuna_vec3,
    target: lacuna_vec3,
    up: lacuna_vec3,
    vfov_degrees: f32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_set_camera", builder, |b| {
            let c = Camera::look_at(
                eye.finite("eye")?,
                target.finite("target")?,
                up.finite("up")?,
                vfov_degrees,
            )?;
            b.builder.set_camera(c)?;
            b.camera = Some(c);
            Ok(())
        })
    }
}

/// Makes the camera set with `lacuna_scene_builder_set_camera` a thin lens of radius
/// `lens_radius` (>= 0; 0 is a pinhole) focused at `focus_distance` (> 0).
/// `LACUNA_STATUS_INVALID_OPERATION` when no camera was set through this function.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_set_camera_lens(
    builder: *mut lacuna_scene_builder,
    lens_radius: f32,
    focus_distance: f32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_set_camera_lens", builder, |b| {
            let c = b.camera.ok_or_else(|| {
                CapiError::operation("no camera: call lacuna_scene_builder_set_camera first")
            })?;
            let c = c.with_thin_lens(lens_radius, focus_distance)?;
            b.builder.set_camera(c)?;
            b.camera = Some(c);
            Ok(())
        })
    }
}

/// Loads a Wavefront OBJ file (and its MTL materials and textures) into the builder, with
/// positions transformed by `transform` (16 floats, a column-major 4x4 matrix; NULL for none).
/// Zero-area triangles are skipped. Writes the number of triangles added to
/// `*out_triangle_count` (may be NULL). `LACUNA_STATUS_IO` when the file cannot be read,
/// `LACUNA_STATUS_PARSE` (with file and line) when it is malformed; on failure the builder
/// keeps what it had before only for meshes: materials of a partly read file may remain.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_load_obj(
    builder: *mut lacuna_scene_builder,
    path: *const c_char,
    transform: *const f32,
    out_triangle_count: *mut usize,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_builder("lacuna_scene_builder_load_obj", builder, |b| {
            let path = path_arg(path, "path")?;
            let m = if transform.is_null() {
                None
            } else {
                let t: Vec<f32> = read_strided(transform.cast(), 0, 16, "transform")?;
                if let Some(i) = t.iter().position(|v| !v.is_finite()) {
                    return Err(CapiError::invalid(format!(
                        "transform[{i}] is {} (must be finite)",
                        t[i]
                    )));
                }
                Some(glam::Mat4::from_cols_slice(&t))
            };
            let report = load_obj(&path, &mut b.builder, m)?;
            if let Some(stem) = path.file_stem() {
                b.label = stem.to_string_lossy().into_owned();
            }
            if !out_triangle_count.is_null() {
                write_out(out_triangle_count, report.triangles);
            }
            Ok(())
        })
    }
}

/// Builds the scene: orients normals, builds the acceleration structure and the light
/// sampler, and writes the committed scene (reference count 1) to `*out_scene`.
///
/// Consumes the builder whether or not the build succeeds (unless `builder` is NULL): do not
/// use or free it afterwards. Building (or using, or freeing) a builder that was already built
/// is caught and fails with `LACUNA_STATUS_INVALID_OPERATION`.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_build(
    builder: *mut lacuna_scene_builder,
    out_scene: *mut *mut lacuna_scene,
) -> lacuna_status {
    if builder.is_null() {
        return boundary::status("lacuna_scene_builder_build", |_| {
            Err(CapiError::null("builder"))
        });
    }
    if let Err(e) = check_live(builder, true) {
        return boundary::status("lacuna_scene_builder_build", |_| Err(e));
    }
    // SAFETY: a live builder from `lacuna_scene_builder_new*`; ownership passes to this call.
    let b = unsafe { Box::from_raw(builder) };
    // An owned reference to the context, held until the boundary has reported a failure
    // (the builder, and with it maybe the last reference, is gone by then).
    let ctx = b.ctx.clone();
    let ctx_ptr = Arc::as_ptr(&ctx);
    let result = boundary::status("lacuna_scene_builder_build", move |call| {
        // SAFETY: `ctx` keeps the context alive until after `boundary::status` returns.
        call.context(unsafe { &*ctx_ptr });
        let out = out_ptr(out_scene, "out_scene")?;
        let b = *b;
        let scene = lacuna_scene::new(b.ctx, b.builder.build()?, b.settings, b.label);
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, arc_into_handle(scene)) };
        Ok(())
    });
    drop(ctx);
    result
}
