//! `lacuna_film`: a finished render (radiance and AOVs), readback with strides, EXR/PNG output.

use std::ffi::c_char;
use std::sync::Arc;

use super::boundary::{self, lacuna_status, CapiError, CapiResult};
use super::buffer::{
    arc_clone, arc_into_handle, arc_release, arc_retain, arg, finite, image_layout, out_ptr,
    path_arg, write_out,
};
use super::context::lacuna_context;
use super::types::*;
use crate::film::{read_exr_rgb, ExrMetadata, Film, PixelSample};
use crate::integrator::strategy_layer_name;
use crate::render::RenderStats;

/// The result of a render: per-pixel mean radiance and first-hit AOVs (albedo, normal, depth),
/// with the render's figures and metadata.
///
/// Refcounted (`lacuna_film_retain`/`lacuna_film_release`); immutable. Thread-safe: every
/// function taking a `const lacuna_film*` may be called from any number of threads at once.
pub struct lacuna_film {
    pub(crate) ctx: Arc<lacuna_context>,
    pub(crate) film: Film,
    pub(crate) metadata: ExrMetadata,
    pub(crate) stats: RenderStats,
}

pub(crate) fn stats_to_c(s: &RenderStats) -> lacuna_render_stats {
    lacuna_render_stats {
        seconds: s.seconds,
        spp: s.spp,
        passes: s.passes,
        samples: s.samples,
        rays: s.rays,
        cancelled: s.cancelled,
        precompute_seconds: s.precompute_seconds,
    }
}

/// Adds a reference to `film`. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_film_retain(film: *const lacuna_film) {
    boundary::value("lacuna_film_retain", (), |_| {
        // SAFETY: NULL or a live film.
        unsafe { arc_retain(film) };
        Ok(())
    })
}

/// Drops a reference to `film`; the last one destroys it. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_film_release(film: *const lacuna_film) {
    boundary::value("lacuna_film_release", (), |_| {
        // SAFETY: NULL or a live film; the caller gives up one reference.
        unsafe { arc_release(film) };
        Ok(())
    })
}

/// Loads an EXR image (R, G, B channels) as a film with one sample per pixel and no AOVs;
/// its `lacuna:*` header attributes are kept (a reference made by
/// `lacuna_render_job_run_reference` keeps its error estimate). Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_film_load_exr(
    context: *const lacuna_context,
    path: *const c_char,
    out_film: *mut *mut lacuna_film,
) -> lacuna_status {
    boundary::status("lacuna_film_load_exr", |call| {
        // SAFETY: NULL or a live context.
        let ctx = unsafe { arg(context, "context") }?;
        call.context(ctx);
        // SAFETY: NULL or a NUL-terminated string.
        let path = unsafe { path_arg(path, "path") }?;
        let out = out_ptr(out_film, "out_film")?;
        let img = read_exr_rgb(&path)?;
        let mut film = Film::new(img.width, img.height);
        for (i, p) in img.pixels.iter().enumerate() {
            let (x, y) = (i as u32 % img.width, i as u32 / img.width);
            film.add_sample(
                x,
                y,
                &PixelSample {
                    radiance: *p,
                    ..Default::default()
                },
            );
        }
        let f = lacuna_film {
            // SAFETY: `context` is a live handle (checked above).
            ctx: unsafe { arc_clone(context) },
            film,
            metadata: img.metadata,
            stats: RenderStats {
                spp: 1,
                samples: img.pixels.len() as u64,
                ..Default::default()
            },
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, arc_into_handle(f)) };
        Ok(())
    })
}

/// Writes the film's size in pixels. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_film_get_size(
    film: *const lacuna_film,
    out_width: *mut u32,
    out_height: *mut u32,
) -> lacuna_status {
    boundary::status("lacuna_film_get_size", |call| {
        // SAFETY: NULL or a live film.
        let f = unsafe { arg(film, "film") }?;
        call.context(&f.ctx);
        let ow = out_ptr(out_width, "out_width")?;
        let oh = out_ptr(out_height, "out_height")?;
        // SAFETY: both checked non-NULL, writable per the contract.
        unsafe {
            write_out(ow, f.film.width());
            write_out(oh, f.film.height());
        }
        Ok(())
    })
}

/// Writes the figures of the render that made the film. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_film_get_stats(
    film: *const lacuna_film,
    out_stats: *mut lacuna_render_stats,
) -> lacuna_status {
    boundary::status("lacuna_film_get_stats", |call| {
        // SAFETY: NULL or a live film.
        let f = unsafe { arg(film, "film") }?;
        call.context(&f.ctx);
        let out = out_ptr(out_stats, "out_stats")?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, stats_to_c(&f.stats)) };
        Ok(())
    })
}

/// Writes the bytes the film holds. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_film_get_memory_bytes(
    film: *const lacuna_film,
    out_bytes: *mut usize,
) -> lacuna_status {
    boundary::status("lacuna_film_get_memory_bytes", |call| {
        // SAFETY: NULL or a live film.
        let f = unsafe { arg(film, "film") }?;
        call.context(&f.ctx);
        let out = out_ptr(out_bytes, "out_bytes")?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, f.film.memory_bytes()) };
        Ok(())
    })
}

/// Copies channel `channel` (a `lacuna_film_channel` value: 3 floats per pixel for RADIANCE,
/// ALBEDO and NORMAL, 1 float for DEPTH and SAMPLE_COUNT) into `dst`: pixel (x, y) goes to
/// `(char*)dst + y * row_stride + x * pixel_stride`, rows top to bottom. `width` and `height`
/// must equal the film's; `pixel_stride` 0 means packed, `row_stride` 0 means
/// `width * pixel_stride`. No alignment is required. Nothing is written on failure.
/// Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_film_read(
    film: *const lacuna_film,
    channel: u32,
    dst: *mut f32,
    width: usize,
    height: usize,
    pixel_stride: usize,
    row_stride: usize,
) -> lacuna_status {
    boundary::status("lacuna_film_read", |call| {
        // SAFETY: NULL or a live film.
        let f = unsafe { arg(film, "film") }?;
        call.context(&f.ctx);
        let ch = lacuna_film_channel::from_c(channel, "channel")?;
        let (fw, fh) = (f.film.width() as usize, f.film.height() as usize);
        if (width, height) != (fw, fh) {
            return Err(CapiError::invalid(format!(
                "destination is {width}x{height} but the film is {fw}x{fh}"
            )));
        }
        let components = match ch {
            lacuna_film_channel::Depth | lacuna_film_channel::SampleCount => 1,
            _ => 3,
        };
        let values = move || -> Vec<f32> {
            match ch {
                lacuna_film_channel::Radiance => f
                    .film
                    .radiance()
                    .iter()
                    .flat_map(|p| p.to_array())
                    .collect(),
                lacuna_film_channel::Albedo => {
                    f.film.albedo().iter().flat_map(|p| p.to_array()).collect()
                }
                lacuna_film_channel::Normal => {
                    f.film.normal().iter().flat_map(|p| p.to_array()).collect()
                }
                lacuna_film_channel::Depth => f.film.depth(),
                lacuna_film_channel::SampleCount => (0..fh as u32)
                    .flat_map(|y| (0..fw as u32).map(move |x| (x, y)))
                    .map(|(x, y)| f.film.samples(x, y) as f32)
                    .collect(),
            }
        };
        // SAFETY: the caller promises `dst` spans the described image.
        unsafe {
            write_image(
                dst,
                width,
                height,
                pixel_stride,
                row_stride,
                components,
                values,
            )
        }
    })
}

/// Validates an output image layout of `components` floats per pixel and writes the row-major
/// `values` (made only once the layout is valid) into it.
///
/// # Safety
/// `dst` must be NULL or writable for the described image.
unsafe fn write_image(
    dst: *mut f32,
    width: usize,
    height: usize,
    pixel_stride: usize,
    row_stride: usize,
    components: usize,
    values: impl FnOnce() -> Vec<f32>,
) -> CapiResult<()> {
    let (ps, rs) = image_layout(width, pixel_stride, row_stride, components * 4)?;
    if dst.is_null() {
        return Err(CapiError::null("dst"));
    }
    (height - 1)
        .checked_mul(rs)
        .and_then(|b| b.checked_add((width - 1) * ps + components * 4))
        .and_then(|b| (dst as usize).checked_add(b))
        .ok_or_else(|| {
            CapiError::range(format!(
                "{width}x{height} pixels with row stride {rs} exceed the address space"
            ))
        })?;
    let values = values();
    let base = dst.cast::<u8>();
    for y in 0..height {
        for x in 0..width {
            for c in 0..components {
                let v = values[(y * width + x) * components + c];
                // SAFETY: the offset is within the span checked above, which the caller
                // promises writable; unaligned writes need no alignment.
                unsafe { write_out(base.add(y * rs + x * ps + c * 4).cast::<f32>(), v) };
            }
        }
    }
    Ok(())
}

/// Copies the image of bdpt strategy (`s`, `t`), weighted by its MIS weight or not, into
/// `dst` (3 floats per pixel, layout as in `lacuna_film_read`). The film must come from a job
/// with `lacuna_render_job_set_strategy_images` (else `LACUNA_STATUS_INVALID_OPERATION`), and
/// (s, t) must be one of its strategies: s + t - 1 segments, at most the length set there
/// (else `LACUNA_STATUS_OUT_OF_RANGE`). The weighted images of all strategies sum to the
/// radiance. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_film_read_strategy_image(
    film: *const lacuna_film,
    s: u32,
    t: u32,
    weighted: bool,
    dst: *mut f32,
    width: usize,
    height: usize,
    pixel_stride: usize,
    row_stride: usize,
) -> lacuna_status {
    boundary::status("lacuna_film_read_strategy_image", |call| {
        // SAFETY: NULL or a live film.
        let f = unsafe { arg(film, "film") }?;
        call.context(&f.ctx);
        if f.film.layer_names().is_empty() {
            return Err(CapiError::operation(
                "the film has no strategy images (lacuna_render_job_set_strategy_images)",
            ));
        }
        let name = strategy_layer_name(s, t, weighted);
        let layer = f.film.layer_index(&name).ok_or_else(|| {
            CapiError::range(format!("the film has no image of strategy ({s}, {t})"))
        })?;
        let (fw, fh) = (f.film.width() as usize, f.film.height() as usize);
        if (width, height) != (fw, fh) {
            return Err(CapiError::invalid(format!(
                "destination is {width}x{height} but the film is {fw}x{fh}"
            )));
        }
        let values = || {
            f.film
                .layer(layer)
                .iter()
                .flat_map(|p| p.to_array())
                .collect()
        };
        // SAFETY: the caller promises `dst` spans the described image.
        unsafe { write_image(dst, width, height, pixel_stride, row_stride, 3, values) }
    })
}

/// Writes the film as an OpenEXR file (float32 R, G, B, then albedo.*, normal.* and depth.Z
/// channels, and for strategy images `sS_tT_weighted.R` ... channels, with the render's
/// figures as `lacuna:*` header attributes). Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_film_write_exr(
    film: *const lacuna_film,
    path: *const c_char,
) -> lacuna_status {
    boundary::status("lacuna_film_write_exr", |call| {
        // SAFETY: NULL or a live film.
        let f = unsafe { arg(film, "film") }?;
        call.context(&f.ctx);
        // SAFETY: NULL or a NUL-terminated string.
        let path = unsafe { path_arg(path, "path") }?;
        f.film.write_exr(&path, &f.metadata)?;
        Ok(())
    })
}

/// Writes the film's radiance, scaled by 2^exposure, as an 8-bit sRGB PNG. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_film_write_png(
    film: *const lacuna_film,
    path: *const c_char,
    exposure: f32,
) -> lacuna_status {
    boundary::status("lacuna_film_write_png", |call| {
        // SAFETY: NULL or a live film.
        let f = unsafe { arg(film, "film") }?;
        call.context(&f.ctx);
        // SAFETY: NULL or a NUL-terminated string.
        let path = unsafe { path_arg(path, "path") }?;
        let exposure = finite(exposure, "exposure")?;
        f.film.write_png(&path, exposure)?;
        Ok(())
    })
}
