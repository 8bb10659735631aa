//! `lacuna_photometric_profile`: a measured luminaire's intensity distribution (an IES LM-63
//! or EULUMDAT file), loaded from a file or a host buffer, queried and sampled by hosts, and placed in
//! scenes as lights (`lacuna_scene_builder_add_photometric_light`).

use std::ffi::c_char;
use std::sync::Arc;

use super::boundary::{self, lacuna_status, CapiError};
use super::buffer::{arc_into_handle, arc_release, arc_retain, arg, out_ptr, path_arg, write_out};
use super::types::lacuna_vec3;
use crate::light::photometric::HorizontalSymmetry;
use crate::light::PhotometricProfile;
use crate::math::Vec2;

/// Largest photometric text accepted from a buffer (real files are a few kilobytes to a
/// megabyte).
const MAX_TEXT_BYTES: usize = 64 << 20;

/// An intensity distribution in candela over the type C angles (gamma from the nadir, C about
/// it), read from an IES LM-63 or EULUMDAT file. Immutable and refcounted
/// (`lacuna_photometric_profile_retain`/`_release`); every function is thread-safe. Scenes
/// holding a light made from it keep their own reference.
pub struct lacuna_photometric_profile {
    pub(crate) profile: Arc<PhotometricProfile>,
}

/// `lacuna_photometric_profile_info.symmetry`: how the file's horizontal angles cover C.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_photometric_symmetry {
    /// One horizontal angle: the same in every C plane.
    Rotational = 0,
    /// C 0-90: each quadrant mirrors the first.
    Quadrant = 1,
    /// C 0-180: symmetric about the C0-C180 plane.
    BilateralC0 = 2,
    /// C 90-270: symmetric about the C90-C270 plane.
    BilateralC90 = 3,
    /// C 0-360.
    Full = 4,
}

/// What a profile holds (`lacuna_photometric_profile_get_info`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct lacuna_photometric_profile_info {
    /// Largest tabulated intensity, candela (multipliers applied).
    pub peak_candela: f32,
    /// Intensity integrated over the sphere, lumen (estimated on the sampling grid).
    pub flux_lumen: f32,
    /// A `lacuna_photometric_symmetry` value.
    pub symmetry: u32,
    /// Memory of the table and the sampling structure.
    pub memory_bytes: u64,
}

fn new_handle(profile: PhotometricProfile) -> *mut lacuna_photometric_profile {
    arc_into_handle(lacuna_photometric_profile {
        profile: Arc::new(profile),
    })
}

/// Reads a photometric file: EULUMDAT when its name ends in `.ldt` (any case), IES LM-63
/// otherwise (type C photometry; see docs/scene-format.md for what is read).
/// `LACUNA_STATUS_IO` when it cannot be read, `LACUNA_STATUS_PARSE` (naming the file and the
/// line) when its content is malformed or unsupported. Writes a new profile (one reference) to
/// `*out_profile`. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_photometric_profile_new_from_file(
    path: *const c_char,
    out_profile: *mut *mut lacuna_photometric_profile,
) -> lacuna_status {
    boundary::status("lacuna_photometric_profile_new_from_file", |_| {
        // SAFETY: NULL or a NUL-terminated string.
        let path = unsafe { path_arg(path, "path") }?;
        let out = out_ptr(out_profile, "out_profile")?;
        let profile = PhotometricProfile::from_file(&path)?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, new_handle(profile)) };
        Ok(())
    })
}

/// The `size` bytes at `data` (never NULL: a profile needs text), at most 64 MiB.
///
/// # Safety
/// `data` must be NULL or readable for `size` bytes.
unsafe fn text_arg<'a>(data: *const u8, size: usize) -> Result<&'a [u8], CapiError> {
    if data.is_null() {
        return Err(CapiError::null("data"));
    }
    if size > MAX_TEXT_BYTES {
        return Err(CapiError::range(format!(
            "{size} bytes of photometric text exceed the limit of {MAX_TEXT_BYTES}"
        )));
    }
    // SAFETY: non-NULL and readable for `size` bytes per the contract; size is bounded.
    Ok(unsafe { std::slice::from_raw_parts(data, size) })
}

/// Parses `size` bytes of IES LM-63 text at `data` (copied; no NUL needed; at most 64 MiB).
/// Malformed content is `LACUNA_STATUS_PARSE`, located as `<memory>:line N`. Writes a new
/// profile (one reference) to `*out_profile`. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_photometric_profile_new_from_ies_buffer(
    data: *const u8,
    size: usize,
    out_profile: *mut *mut lacuna_photometric_profile,
) -> lacuna_status {
    boundary::status("lacuna_photometric_profile_new_from_ies_buffer", |_| {
        let out = out_ptr(out_profile, "out_profile")?;
        // SAFETY: forwarded contract.
        let bytes = unsafe { text_arg(data, size) }?;
        let profile = PhotometricProfile::from_ies_bytes(bytes)?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, new_handle(profile)) };
        Ok(())
    })
}

/// Parses `size` bytes of EULUMDAT (`.ldt`) text at `data`, as
/// `lacuna_photometric_profile_new_from_ies_buffer` does IES text. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_photometric_profile_new_from_ldt_buffer(
    data: *const u8,
    size: usize,
    out_profile: *mut *mut lacuna_photometric_profile,
) -> lacuna_status {
    boundary::status("lacuna_photometric_profile_new_from_ldt_buffer", |_| {
        let out = out_ptr(out_profile, "out_profile")?;
        // SAFETY: forwarded contract.
        let bytes = unsafe { text_arg(data, size) }?;
        let profile = PhotometricProfile::from_ldt_bytes(bytes)?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, new_handle(profile)) };
        Ok(())
    })
}

/// Adds a reference to `profile`. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_photometric_profile_retain(
    profile: *const lacuna_photometric_profile,
) {
    boundary::value("lacuna_photometric_profile_retain", (), |_| {
        // SAFETY: NULL or a live profile.
        unsafe { arc_retain(profile) };
        Ok(())
    })
}

/// Drops a reference to `profile`; the last one destroys it (lights made from it keep
/// theirs). NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_photometric_profile_release(
    profile: *const lacuna_photometric_profile,
) {
    boundary::value("lacuna_photometric_profile_release", (), |_| {
        // SAFETY: NULL or a live profile; the caller gives up one reference.
        unsafe { arc_release(profile) };
        Ok(())
    })
}

/// Writes what `profile` holds to `*out_info`. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_photometric_profile_get_info(
    profile: *const lacuna_photometric_profile,
    out_info: *mut lacuna_photometric_profile_info,
) -> lacuna_status {
    boundary::status("lacuna_photometric_profile_get_info", |_| {
        // SAFETY: NULL or a live profile.
        let p = &unsafe { arg(profile, "profile") }?.profile;
        let out = out_ptr(out_info, "out_info")?;
        let symmetry = match p.symmetry() {
            HorizontalSymmetry::Rotational => lacuna_photometric_symmetry::Rotational,
            HorizontalSymmetry::Quadrant => lacuna_photometric_symmetry::Quadrant,
            HorizontalSymmetry::Bilateral0To180 => lacuna_photometric_symmetry::BilateralC0,
            HorizontalSymmetry::Bilateral90To270 => lacuna_photometric_symmetry::BilateralC90,
            HorizontalSymmetry::Full => lacuna_photometric_symmetry::Full,
        };
        let info = lacuna_photometric_profile_info {
            peak_candela: p.peak(),
            flux_lumen: p.flux(),
            symmetry: symmetry as u32,
            memory_bytes: p.memory_bytes() as u64,
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, info) };
        Ok(())
    })
}

/// Checks a direction argument: finite and non-zero; returned normalised.
fn direction(v: lacuna_vec3, name: &str) -> Result<crate::math::Vec3, CapiError> {
    v.finite(name)?.try_normalize().ok_or_else(|| {
        CapiError::invalid(format!(
            "`{name}` ({}, {}, {}) must be non-zero",
            v.x, v.y, v.z
        ))
    })
}

/// Writes the intensity (candela) towards `local_direction` (finite, non-zero; normalised
/// here), given in the profile's frame: +Z the nadir (gamma = 0), +X the C0 axis, +Y the C90
/// axis. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_photometric_profile_intensity(
    profile: *const lacuna_photometric_profile,
    local_direction: lacuna_vec3,
    out_candela: *mut f32,
) -> lacuna_status {
    boundary::status("lacuna_photometric_profile_intensity", |_| {
        // SAFETY: NULL or a live profile.
        let p = &unsafe { arg(profile, "profile") }?.profile;
        let d = direction(local_direction, "local_direction")?;
        let out = out_ptr(out_candela, "out_candela")?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, p.intensity(d)) };
        Ok(())
    })
}

/// Samples a direction in the profile's frame (as in `lacuna_photometric_profile_intensity`)
/// roughly proportional to the intensity, from two numbers in [0, 1); writes it (unit length)
/// and its solid-angle density, which `lacuna_photometric_profile_pdf` reproduces. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_photometric_profile_sample(
    profile: *const lacuna_photometric_profile,
    u0: f32,
    u1: f32,
    out_local_direction: *mut lacuna_vec3,
    out_pdf: *mut f32,
) -> lacuna_status {
    boundary::status("lacuna_photometric_profile_sample", |_| {
        // SAFETY: NULL or a live profile.
        let p = &unsafe { arg(profile, "profile") }?.profile;
        for (u, name) in [(u0, "u0"), (u1, "u1")] {
            if !(0.0..1.0).contains(&u) {
                return Err(CapiError::range(format!("`{name}` {u} must be in [0, 1)")));
            }
        }
        let out_dir = out_ptr(out_local_direction, "out_local_direction")?;
        let out_pdf = out_ptr(out_pdf, "out_pdf")?;
        let (d, pdf) = p
            .sample_direction(Vec2::new(u0, u1))
            .ok_or_else(|| CapiError::invalid("the profile emits no light"))?;
        // SAFETY: both checked non-NULL, writable per the contract.
        unsafe {
            write_out(out_dir, lacuna_vec3::from(d));
            write_out(out_pdf, pdf);
        }
        Ok(())
    })
}

/// Writes the solid-angle density with which `lacuna_photometric_profile_sample` picks
/// `local_direction` (finite, non-zero; normalised here). Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_photometric_profile_pdf(
    profile: *const lacuna_photometric_profile,
    local_direction: lacuna_vec3,
    out_pdf: *mut f32,
) -> lacuna_status {
    boundary::status("lacuna_photometric_profile_pdf", |_| {
        // SAFETY: NULL or a live profile.
        let p = &unsafe { arg(profile, "profile") }?.profile;
        let d = direction(local_direction, "local_direction")?;
        let out = out_ptr(out_pdf, "out_pdf")?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, p.direction_pdf(d)) };
        Ok(())
    })
}
