//! `lacuna_light_field`: a light-field luminaire (docs/light-field.md), loaded from an EXR
//! mosaic or built from a host buffer of images, queried and sampled by hosts, and placed in
//! scenes as lights (`lacuna_scene_builder_add_light_field_light`).

use std::ffi::c_char;
use std::sync::Arc;

use super::boundary::{self, lacuna_status, CapiError};
use super::buffer::{arc_into_handle, arc_release, arc_retain, arg, out_ptr, path_arg, write_out};
use super::types::{lacuna_rgb, lacuna_vec3};
use crate::light::{FilterBasis, LightField, LightFieldLayout, LightFieldSampling};
use crate::math::{Rgb, Vec2, Vec3};

/// Two planes of images emitting light toward +z of its own frame (docs/light-field.md).
/// Immutable and refcounted (`lacuna_light_field_retain`/`_release`); every function is
/// thread-safe. Scenes holding a light made from it keep their own reference.
pub struct lacuna_light_field {
    pub(crate) field: Arc<LightField>,
}

/// `lacuna_light_field_layout.basis`: the reconstruction basis on the filter plane.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_light_field_basis {
    /// Tensor tent functions (bilinear), half-width one node spacing.
    Linear = 0,
    /// Tensor quadratic B-splines, half-width 1.5 node spacings.
    Quadratic = 1,
}

/// Where the planes and images of a light field are, in its frame (metres): the filter plane
/// z = 0 with `nodes_x` x `nodes_y` basis functions, the first at `node_min`, spaced by
/// `node_spacing`; the image plane z = `plane_distance` with one image per basis function,
/// `resolution_x` x `resolution_y` pixels covering [`image_min`, `image_max`].
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct lacuna_light_field_layout {
    pub nodes_x: u32,
    pub nodes_y: u32,
    pub node_min: [f32; 2],
    pub node_spacing: [f32; 2],
    /// A `lacuna_light_field_basis` value.
    pub basis: u32,
    pub plane_distance: f32,
    pub image_min: [f32; 2],
    pub image_max: [f32; 2],
    pub resolution_x: u32,
    pub resolution_y: u32,
}

/// What a light field holds (`lacuna_light_field_get_info`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct lacuna_light_field_info {
    pub layout: lacuna_light_field_layout,
    /// Emitted power (luminance, W) through the image rectangle.
    pub power: f32,
    /// Memory of the images and their summed-area tables.
    pub memory_bytes: u64,
}

fn new_handle(field: LightField) -> *mut lacuna_light_field {
    arc_into_handle(lacuna_light_field {
        field: Arc::new(field),
    })
}

fn layout_from_c(l: &lacuna_light_field_layout) -> Result<LightFieldLayout, CapiError> {
    let basis = match l.basis {
        0 => FilterBasis::Linear,
        1 => FilterBasis::Quadratic,
        other => {
            return Err(CapiError::invalid(format!(
                "`layout.basis` {other} is not a lacuna_light_field_basis"
            )))
        }
    };
    let v = |a: [f32; 2]| Vec2::new(a[0], a[1]);
    Ok(LightFieldLayout {
        nodes: [l.nodes_x, l.nodes_y],
        node_min: v(l.node_min),
        node_spacing: v(l.node_spacing),
        basis,
        plane_distance: l.plane_distance,
        image_min: v(l.image_min),
        image_max: v(l.image_max),
        resolution: [l.resolution_x, l.resolution_y],
    })
}

fn layout_to_c(l: &LightFieldLayout) -> lacuna_light_field_layout {
    lacuna_light_field_layout {
        nodes_x: l.nodes[0],
        nodes_y: l.nodes[1],
        node_min: l.node_min.to_array(),
        node_spacing: l.node_spacing.to_array(),
        basis: match l.basis {
            FilterBasis::Linear => lacuna_light_field_basis::Linear as u32,
            FilterBasis::Quadratic => lacuna_light_field_basis::Quadratic as u32,
        },
        plane_distance: l.plane_distance,
        image_min: l.image_min.to_array(),
        image_max: l.image_max.to_array(),
        resolution_x: l.resolution[0],
        resolution_y: l.resolution[1],
    }
}

/// Reads a light field stored as an EXR mosaic (docs/light-field.md). `LACUNA_STATUS_IO` when
/// it cannot be read; `LACUNA_STATUS_PARSE` (naming the file and the attribute) when it is
/// truncated, corrupt, not a light field or inconsistent; `LACUNA_STATUS_OVER_BUDGET` when its
/// header claims more memory than the budget. Writes a new light field (one reference) to
/// `*out_field`. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_field_new_from_file(
    path: *const c_char,
    out_field: *mut *mut lacuna_light_field,
) -> lacuna_status {
    boundary::status("lacuna_light_field_new_from_file", |_| {
        // SAFETY: NULL or a NUL-terminated string.
        let path = unsafe { path_arg(path, "path") }?;
        let out = out_ptr(out_field, "out_field")?;
        let field = LightField::from_file(&path)?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, new_handle(field)) };
        Ok(())
    })
}

/// Builds a light field from `*layout` and `float_count` floats at `rgb` (copied): R, G, B
/// per pixel, image after image (image m = j * nodes_x + i for basis function (i, j)), each
/// row-major from the image rectangle's smallest y; `float_count` must be
/// 3 * nodes_x * nodes_y * resolution_x * resolution_y. Values must be finite and >= 0, one
/// positive; an invalid layout or value is `LACUNA_STATUS_INVALID_ARGUMENT` naming it. Writes a
/// new light field (one reference) to `*out_field`. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_field_new_from_buffer(
    layout: *const lacuna_light_field_layout,
    rgb: *const f32,
    float_count: usize,
    out_field: *mut *mut lacuna_light_field,
) -> lacuna_status {
    boundary::status("lacuna_light_field_new_from_buffer", |_| {
        // SAFETY: NULL or readable per the contract.
        let layout = layout_from_c(unsafe { arg(layout, "layout") }?)?;
        let out = out_ptr(out_field, "out_field")?;
        if rgb.is_null() {
            return Err(CapiError::null("rgb"));
        }
        layout.validate()?;
        let expected = 3 * layout.image_count() * layout.pixels_per_image();
        if float_count != expected {
            return Err(CapiError::invalid(format!(
                "`float_count` {float_count} must be {expected} (3 per pixel of every image)"
            )));
        }
        // SAFETY: non-NULL and readable for `float_count` floats per the contract; the count
        // is bounded by the layout's validated pixel limit.
        let floats = unsafe { std::slice::from_raw_parts(rgb, float_count) };
        let pixels = floats
            .chunks_exact(3)
            .map(|c| Rgb::new(c[0], c[1], c[2]))
            .collect();
        let field = LightField::new(layout, pixels)?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, new_handle(field)) };
        Ok(())
    })
}

/// Adds a reference to `field`. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_field_retain(field: *const lacuna_light_field) {
    boundary::value("lacuna_light_field_retain", (), |_| {
        // SAFETY: NULL or a live light field.
        unsafe { arc_retain(field) };
        Ok(())
    })
}

/// Drops a reference to `field`; the last one destroys it (lights made from it keep theirs).
/// NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_field_release(field: *const lacuna_light_field) {
    boundary::value("lacuna_light_field_release", (), |_| {
        // SAFETY: NULL or a live light field; the caller gives up one reference.
        unsafe { arc_release(field) };
        Ok(())
    })
}

/// Writes what `field` holds to `*out_info`. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_field_get_info(
    field: *const lacuna_light_field,
    out_info: *mut lacuna_light_field_info,
) -> lacuna_status {
    boundary::status("lacuna_light_field_get_info", |_| {
        // SAFETY: NULL or a live light field.
        let f = &unsafe { arg(field, "field") }?.field;
        let out = out_ptr(out_info, "out_info")?;
        let info = lacuna_light_field_info {
            layout: layout_to_c(f.layout()),
            power: f.power(),
            memory_bytes: f.memory_bytes() as u64,
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, info) };
        Ok(())
    })
}

/// Samples a point of the image plane as seen from `receiver` (in the field's frame) by
/// restricted sampling with per-image balancing (docs/light-field.md), from two numbers in
/// [0, 1). Writes the point (z = plane distance), the radiance arriving at `receiver` from it,
/// and the solid-angle density at `receiver` (`lacuna_light_field_pdf` reproduces it). A
/// receiver that the field does not light (not beyond the image plane, or outside every
/// projected support) gets density 0 and radiance 0: that is not an error. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_field_sample(
    field: *const lacuna_light_field,
    receiver: lacuna_vec3,
    u0: f32,
    u1: f32,
    out_point: *mut lacuna_vec3,
    out_radiance: *mut lacuna_rgb,
    out_pdf: *mut f32,
) -> lacuna_status {
    boundary::status("lacuna_light_field_sample", |_| {
        // SAFETY: NULL or a live light field.
        let f = &unsafe { arg(field, "field") }?.field;
        let p = receiver.finite("receiver")?;
        for (u, name) in [(u0, "u0"), (u1, "u1")] {
            if !(0.0..1.0).contains(&u) {
                return Err(CapiError::range(format!("`{name}` {u} must be in [0, 1)")));
            }
        }
        let out_point = out_ptr(out_point, "out_point")?;
        let out_radiance = out_ptr(out_radiance, "out_radiance")?;
        let out_pdf = out_ptr(out_pdf, "out_pdf")?;
        let delta = f.layout().plane_distance;
        let (point, radiance, pdf) =
            match f.sample_image_point(p, LightFieldSampling::Restricted, Vec2::new(u0, u1)) {
                Some((s, pdf_area)) => {
                    let point = Vec3::new(s.x, s.y, delta);
                    let to = point - p;
                    let d2 = to.length_squared();
                    let cos = -to.z / d2.sqrt();
                    let radiance = f.radiance(f.filter_point(p, s), s);
                    (point, radiance, pdf_area * d2 / cos)
                }
                None => (Vec3::ZERO, Rgb::ZERO, 0.0),
            };
        // SAFETY: all checked non-NULL, writable per the contract.
        unsafe {
            write_out(out_point, lacuna_vec3::from(point));
            write_out(
                out_radiance,
                lacuna_rgb {
                    r: radiance.x,
                    g: radiance.y,
                    b: radiance.z,
                },
            );
            write_out(out_pdf, pdf);
        }
        Ok(())
    })
}

/// Writes the solid-angle density at `receiver` with which `lacuna_light_field_sample` picks
/// `point` (both in the field's frame; `point` is projected on the image plane along its x and
/// y). Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_light_field_pdf(
    field: *const lacuna_light_field,
    receiver: lacuna_vec3,
    point: lacuna_vec3,
    out_pdf: *mut f32,
) -> lacuna_status {
    boundary::status("lacuna_light_field_pdf", |_| {
        // SAFETY: NULL or a live light field.
        let f = &unsafe { arg(field, "field") }?.field;
        let p = receiver.finite("receiver")?;
        let q = point.finite("point")?;
        let out = out_ptr(out_pdf, "out_pdf")?;
        let delta = f.layout().plane_distance;
        let s = Vec2::new(q.x, q.y);
        let to = Vec3::new(q.x, q.y, delta) - p;
        let d2 = to.length_squared();
        let cos = -to.z / d2.sqrt();
        let area = f.image_point_pdf(p, LightFieldSampling::Restricted, s);
        let pdf = if area > 0.0 && cos > 0.0 {
            area * d2 / cos
        } else {
            0.0
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, pdf) };
        Ok(())
    })
}
