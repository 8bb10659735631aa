//! `lacuna_environment`: an environment map a host loads from a file or hands over as floats,
//! updates in place (a new frame of a captured sky), and lights scenes with.

use std::ffi::c_char;
use std::sync::Arc;

use super::boundary::{self, lacuna_status, CapiError, CapiResult};
use super::buffer::{
    arc_into_handle, arg, box_free, finite, image_layout, out_ptr, path_arg, write_out,
};
use super::builder::lacuna_scene_builder;
use super::job::lacuna_render_job;
use super::scene::lacuna_scene;
use super::types::*;
use crate::integrator::EnvDirectOptions;
use crate::light::environment::{EnvImage, Grid};
use crate::light::{EnvSettings, EnvStrategy, EnvironmentMap, UpAxis};
use crate::math::Rgb;

/// An environment map: radiance from infinitely far away, with its placement (scale,
/// rotation, up axis), camera visibility and sampling structures.
///
/// Single owner (`lacuna_environment_new_*`/`lacuna_environment_free`). Scenes made with it
/// (`lacuna_scene_builder_set_environment`, `lacuna_scene_new_with_environment`) keep a
/// snapshot of its state at that moment: later updates change the environment object, not
/// those scenes (copy on write; when no scene shares the map, updates rebuild in place).
/// Not thread-safe: one thread at a time may use an environment object.
pub struct lacuna_environment {
    map: Arc<EnvironmentMap>,
}

/// What an environment map holds (`lacuna_environment_get_info`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct lacuna_environment_info {
    /// Size of the image as handed over: lat-long width x height, or the cross (4F x 3F).
    pub width: u32,
    pub height: u32,
    /// A `lacuna_environment_layout` value.
    pub layout: u32,
    /// Negative texel components clamped to zero in the last image.
    pub clamped_values: u64,
    /// Memory of the texels and of the sampling structures built so far.
    pub memory_bytes: u64,
    /// Seconds of the last build or rebuild of the lat-long and of the cube-map sampling
    /// structures (0 when not built yet).
    pub latlong_build_seconds: f64,
    pub cube_build_seconds: f64,
}

pub(crate) fn strategy_from_c(value: u32) -> CapiResult<EnvStrategy> {
    Ok(
        match lacuna_environment_strategy::from_c(value, "strategy")? {
            lacuna_environment_strategy::LatLong => EnvStrategy::LatLong,
            lacuna_environment_strategy::CubeUniform => EnvStrategy::CubeUniform,
            lacuna_environment_strategy::CubePower => EnvStrategy::CubePower,
            lacuna_environment_strategy::CubeDynamic => EnvStrategy::CubeDynamic,
            lacuna_environment_strategy::Bsdf => EnvStrategy::BsdfOnly,
            lacuna_environment_strategy::Portals => EnvStrategy::Portals,
            lacuna_environment_strategy::Auto => EnvStrategy::Auto,
        },
    )
}

pub(crate) fn strategy_to_c(strategy: EnvStrategy) -> u32 {
    (match strategy {
        EnvStrategy::LatLong => lacuna_environment_strategy::LatLong,
        EnvStrategy::CubeUniform => lacuna_environment_strategy::CubeUniform,
        EnvStrategy::CubePower => lacuna_environment_strategy::CubePower,
        EnvStrategy::CubeDynamic => lacuna_environment_strategy::CubeDynamic,
        EnvStrategy::BsdfOnly => lacuna_environment_strategy::Bsdf,
        EnvStrategy::Portals => lacuna_environment_strategy::Portals,
        EnvStrategy::Auto => lacuna_environment_strategy::Auto,
    }) as u32
}

/// Reads `width` x `height` RGB float pixels (pixel (x, y) at
/// `(const char*)texels + y * row_stride + x * pixel_stride`) and checks they are a map of
/// `layout`.
///
/// # Safety
/// `texels` must be NULL or readable over the span the strides describe.
unsafe fn read_image(
    texels: *const f32,
    width: usize,
    height: usize,
    pixel_stride: usize,
    row_stride: usize,
    layout: u32,
) -> CapiResult<EnvImage> {
    let layout = lacuna_environment_layout::from_c(layout, "layout")?;
    let ok = match layout {
        lacuna_environment_layout::LatLong => width >= 2 && width == 2 * height,
        lacuna_environment_layout::CubeCross => {
            width >= 4 && width % 4 == 0 && 3 * width == 4 * height
        }
    };
    if !ok {
        return Err(CapiError::invalid(format!(
            "a {width}x{height} image is not a {} (width must be {})",
            match layout {
                lacuna_environment_layout::LatLong => "lat-long map",
                lacuna_environment_layout::CubeCross => "horizontal cross of cube faces",
            },
            match layout {
                lacuna_environment_layout::LatLong => "2 x height, at least 2",
                lacuna_environment_layout::CubeCross => "4/3 x height and a multiple of 4",
            }
        )));
    }
    if width.saturating_mul(height) > crate::light::environment::MAX_TEXELS {
        return Err(CapiError::range(format!(
            "a {width}x{height} environment map exceeds 2^28 texels"
        )));
    }
    let (ps, rs) = image_layout(width, pixel_stride, row_stride, 12)?;
    if texels.is_null() {
        return Err(CapiError::null("texels"));
    }
    let span = (height - 1)
        .checked_mul(rs)
        .and_then(|b| b.checked_add((width - 1) * ps + 12))
        .filter(|&s| s <= isize::MAX as usize && (texels as usize).checked_add(s).is_some())
        .ok_or_else(|| {
            CapiError::range(format!(
                "a {width}x{height} image every {ps} bytes, rows every {rs} bytes, exceeds the address space"
            ))
        })?;
    let base = texels.cast::<u8>();
    let mut pixels = Vec::new();
    pixels.try_reserve_exact(width * height).map_err(|_| {
        CapiError::new(
            lacuna_status::OutOfMemory,
            format!("cannot allocate a {width}x{height} environment map"),
        )
    })?;
    for y in 0..height {
        for x in 0..width {
            let offset = y * rs + x * ps;
            debug_assert!(offset + 12 <= span);
            // SAFETY: offset + 12 <= span, which the caller guarantees readable;
            // `read_unaligned` needs no alignment.
            let p = unsafe { base.add(offset).cast::<[f32; 3]>().read_unaligned() };
            pixels.push(Rgb::from(p));
        }
    }
    Ok(EnvImage::from_pixels(width, height, pixels)?)
}

/// Runs `f` on an environment object.
///
/// # Safety
/// `env` must be NULL or a live environment used by this thread only.
unsafe fn with_env(
    function: &'static str,
    env: *mut lacuna_environment,
    f: impl FnOnce(&mut lacuna_environment) -> CapiResult<()>,
) -> lacuna_status {
    boundary::status(function, |_| {
        // SAFETY: NULL or a live environment used by this thread only (caller's contract).
        let e = unsafe { env.as_mut() }.ok_or_else(|| CapiError::null("env"))?;
        f(e)
    })
}

fn new_handle(map: EnvironmentMap) -> *mut lacuna_environment {
    Box::into_raw(Box::new(lacuna_environment { map: Arc::new(map) }))
}

/// Loads an environment map from an OpenEXR (`.exr`) or Radiance (`.hdr`) file: a 2:1
/// lat-long map or a 4:3 horizontal cross. NaN or infinite texels are an error
/// (`LACUNA_STATUS_PARSE`, naming the texel); negative ones are clamped to zero and counted
/// (`lacuna_environment_info.clamped_values`). Scale 1, no rotation, Y up, visible.
/// `LACUNA_STATUS_IO` when the file cannot be read. A file whose header claims more than
/// 2^28 texels is `LACUNA_STATUS_PARSE`, and one needing more than `LACUNA_DEFAULT_MEMORY_BUDGET`
/// (or physical memory) `LACUNA_STATUS_OVER_BUDGET`, both before any pixel is read.
/// Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_environment_new_from_file(
    path: *const c_char,
    out_env: *mut *mut lacuna_environment,
) -> lacuna_status {
    boundary::status("lacuna_environment_new_from_file", |_| {
        // SAFETY: NULL or a NUL-terminated string.
        let path = unsafe { path_arg(path, "path") }?;
        let out = out_ptr(out_env, "out_env")?;
        let map = EnvironmentMap::load(&path, EnvSettings::default())?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, new_handle(map)) };
        Ok(())
    })
}

/// Makes an environment map from `width` x `height` linear RGB float pixels in `layout` (a
/// `lacuna_environment_layout` value); pixel (x, y) is read at
/// `(const char*)texels + y * row_stride + x * pixel_stride` (0 strides mean packed). The
/// pixels are copied. NaN or infinite values are an error naming the texel; negative ones
/// are clamped to zero and counted. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_environment_new_from_buffer(
    texels: *const f32,
    width: usize,
    height: usize,
    pixel_stride: usize,
    row_stride: usize,
    layout: u32,
    out_env: *mut *mut lacuna_environment,
) -> lacuna_status {
    boundary::status("lacuna_environment_new_from_buffer", |_| {
        let out = out_ptr(out_env, "out_env")?;
        // SAFETY: forwarded contract.
        let image = unsafe { read_image(texels, width, height, pixel_stride, row_stride, layout) }?;
        let map = EnvironmentMap::new(image, EnvSettings::default())?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, new_handle(map)) };
        Ok(())
    })
}

/// Frees an environment object (scenes made with it keep their snapshot). NULL is a no-op.
#[no_mangle]
pub unsafe extern "C" fn lacuna_environment_free(env: *mut lacuna_environment) {
    boundary::value("lacuna_environment_free", (), |_| {
        // SAFETY: NULL or an environment from `lacuna_environment_new_*`, not used afterwards.
        unsafe { box_free(env) };
        Ok(())
    })
}

/// Replaces the texels by a new image of the same size and layout (read as in
/// `lacuna_environment_new_from_buffer`) and rebuilds the sampling structures built so far,
/// in place when no scene shares the map. Writes the seconds the rebuild took to
/// `*out_rebuild_seconds` (may be NULL). On failure the map keeps its previous image.
#[no_mangle]
pub unsafe extern "C" fn lacuna_environment_update(
    env: *mut lacuna_environment,
    texels: *const f32,
    width: usize,
    height: usize,
    pixel_stride: usize,
    row_stride: usize,
    layout: u32,
    out_rebuild_seconds: *mut f64,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_env("lacuna_environment_update", env, |e| {
            let image = read_image(texels, width, height, pixel_stride, row_stride, layout)?;
            if image.grid() != e.map.image().grid() {
                return Err(CapiError::invalid(format!(
                    "the new image is a {} but the environment is a {}: make a new environment for another size or layout",
                    crate::light::environment::describe(image.grid()),
                    crate::light::environment::describe(e.map.image().grid())
                )));
            }
            let seconds = Arc::make_mut(&mut e.map).update(image.texels())?;
            if !out_rebuild_seconds.is_null() {
                write_out(out_rebuild_seconds, seconds);
            }
            Ok(())
        })
    }
}

/// Sets the radiance multiplier `scale` (finite, >= 0), the rotation about the up axis in
/// degrees (finite; counter-clockwise seen from above) and the up axis (a `lacuna_up_axis`
/// value).
#[no_mangle]
pub unsafe extern "C" fn lacuna_environment_set_placement(
    env: *mut lacuna_environment,
    scale: f32,
    rotate_degrees: f32,
    up_axis: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_env("lacuna_environment_set_placement", env, |e| {
            let up = match lacuna_up_axis::from_c(up_axis, "up_axis")? {
                lacuna_up_axis::Y => UpAxis::Y,
                lacuna_up_axis::Z => UpAxis::Z,
            };
            let settings = EnvSettings {
                scale: finite(scale, "scale")?,
                rotate_degrees: finite(rotate_degrees, "rotate_degrees")?,
                up,
                ..*e.map.settings()
            };
            settings.validate()?;
            Arc::make_mut(&mut e.map).set_settings(settings)?;
            Ok(())
        })
    }
}

/// Sets whether camera rays that leave the scene see the map (true by default); it lights
/// the scene either way.
#[no_mangle]
pub unsafe extern "C" fn lacuna_environment_set_visible(
    env: *mut lacuna_environment,
    visible: bool,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_env("lacuna_environment_set_visible", env, |e| {
            let settings = EnvSettings {
                visible,
                ..*e.map.settings()
            };
            Arc::make_mut(&mut e.map).set_settings(settings)?;
            Ok(())
        })
    }
}

/// Builds the sampling structures `strategy` (a `lacuna_environment_strategy` value) needs
/// now, rather than during the first render, and times the build
/// (`lacuna_environment_info`). Later updates rebuild them.
#[no_mangle]
pub unsafe extern "C" fn lacuna_environment_prepare(
    env: *mut lacuna_environment,
    strategy: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_env("lacuna_environment_prepare", env, |e| {
            let s = strategy_from_c(strategy)?;
            Arc::make_mut(&mut e.map).prepare(s);
            Ok(())
        })
    }
}

/// Writes what the map holds to `*out_info`.
#[no_mangle]
pub unsafe extern "C" fn lacuna_environment_get_info(
    env: *const lacuna_environment,
    out_info: *mut lacuna_environment_info,
) -> lacuna_status {
    boundary::status("lacuna_environment_get_info", |_| {
        // SAFETY: NULL or a live environment.
        let e = unsafe { arg(env, "env") }?;
        let out = out_ptr(out_info, "out_info")?;
        let image = e.map.image();
        let (width, height, layout) = match image.grid() {
            Grid::LatLong { width, height } => (width, height, lacuna_environment_layout::LatLong),
            Grid::Cube { face } => (4 * face, 3 * face, lacuna_environment_layout::CubeCross),
        };
        let [ll, cube] = e.map.build_seconds();
        let info = lacuna_environment_info {
            width: width as u32,
            height: height as u32,
            layout: layout as u32,
            clamped_values: image.clamped() as u64,
            memory_bytes: e.map.memory_bytes() as u64,
            latlong_build_seconds: ll,
            cube_build_seconds: cube,
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, info) };
        Ok(())
    })
}

/// Lights the scene being built with (a snapshot of) `env`; NULL removes the environment.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_builder_set_environment(
    builder: *mut lacuna_scene_builder,
    env: *const lacuna_environment,
) -> lacuna_status {
    boundary::status("lacuna_scene_builder_set_environment", |call| {
        // SAFETY: NULL or a live builder used by this thread only.
        if builder.is_null() {
            return Err(CapiError::null("builder"));
        }
        super::builder::check_live(builder, false)?;
        // SAFETY: a live builder (checked above) used by this thread only.
        let b = unsafe { &mut *builder };
        // SAFETY: the builder holds its context alive for the call.
        call.context(unsafe { &*Arc::as_ptr(&b.ctx) });
        // SAFETY: NULL or a live environment.
        let map = unsafe { env.as_ref() }.map(|e| e.map.clone());
        b.builder.set_environment(map);
        Ok(())
    })
}

/// Makes a new committed scene (reference count 1) that shares `scene`'s geometry, materials
/// and acceleration structure but is lit by (a snapshot of) `env` instead of its environment
/// map (NULL: none): the cheap way to render a new environment frame. O(lights). Thread-safe
/// for `scene`.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_new_with_environment(
    scene: *const lacuna_scene,
    env: *const lacuna_environment,
    out_scene: *mut *mut lacuna_scene,
) -> lacuna_status {
    boundary::status("lacuna_scene_new_with_environment", |call| {
        // SAFETY: NULL or a live scene.
        let s = unsafe { arg(scene, "scene") }?;
        call.context(&s.ctx);
        let out = out_ptr(out_scene, "out_scene")?;
        // SAFETY: NULL or a live environment.
        let map = unsafe { env.as_ref() }.map(|e| e.map.clone());
        let new = lacuna_scene::new(
            s.ctx.clone(),
            s.scene.with_environment(map),
            s.settings.clone(),
            s.label.clone(),
        );
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, arc_into_handle(new)) };
        Ok(())
    })
}

/// Sets how light sampling picks environment directions: a `lacuna_environment_strategy`
/// value (default `LACUNA_ENVIRONMENT_STRATEGY_AUTO`). An option in the integrator
/// name (`"path:env=latlong"`) takes precedence.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_environment_strategy(
    job: *mut lacuna_render_job,
    strategy: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        super::job::with_settings("lacuna_render_job_set_environment_strategy", job, |s| {
            s.resolved.integrator_settings.env = strategy_from_c(strategy)?;
            Ok(())
        })
    }
}

/// `env_direct` only: environment light samples (`light_samples`, split between the cube
/// faces) and BSDF samples per shading point; their sum must be at least 1.
#[no_mangle]
pub unsafe extern "C" fn lacuna_render_job_set_environment_samples(
    job: *mut lacuna_render_job,
    light_samples: u32,
    bsdf_samples: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        super::job::with_settings("lacuna_render_job_set_environment_samples", job, |s| {
            if light_samples == 0 && bsdf_samples == 0 {
                return Err(CapiError::invalid(
                    "light_samples and bsdf_samples are both 0: at least one sample is needed",
                ));
            }
            s.resolved.integrator_settings.env_direct = EnvDirectOptions {
                light_samples,
                bsdf_samples,
                ..s.resolved.integrator_settings.env_direct
            };
            Ok(())
        })
    }
}
