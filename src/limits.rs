//! The one table of limits: what the `lacuna` command, the scene file, the loaders and the C
//! API accept. Each limit is here once; the C API's `LACUNA_*` constants are asserted equal to
//! these at compile time, and `docs/limits.md` lists them. Every refusal names the file, the
//! line or field, and the limit it broke.

use std::path::Path;

use crate::error::{Error, Result};

/// Most worker threads a render, an analysis or a C API context accepts (beyond this, starting
/// the threads takes seconds before the system refuses).
pub const MAX_THREADS: u32 = 4096;

/// Largest maximum path depth (bounces); deeper paths carry no measurable energy.
pub const MAX_DEPTH: u32 = 1024;

/// Most light subpaths per iteration of the bidirectional integrator (each costs memory for
/// its vertices).
pub const MAX_LIGHT_PATHS: u32 = 1 << 28;

/// Largest image width or height, in pixels.
pub const MAX_FILM_SIDE: u32 = 1 << 16;

/// Memory budget when none is given (8 GiB), for renders and loaders alike.
pub const DEFAULT_MEMORY_BUDGET: u64 = 8 << 30;

/// Largest environment map, in texels (u32 texel indices, 3 GiB of f32 RGB).
pub const MAX_ENV_TEXELS: usize = 1 << 28;

/// Largest texture image, in pixels.
pub const MAX_TEXTURE_PIXELS: u64 = 1 << 28;

/// Largest JSON scene file, in bytes (scene files describe objects; meshes live in OBJ files).
pub const MAX_SCENE_FILE_BYTES: u64 = 64 << 20;

/// Most triangles the inline shapes of one scene file may make (a 60-byte line asks for a
/// sphere of 4 million triangles; a small file of many would need tens of gigabytes).
pub const MAX_SHAPE_TRIANGLES: u64 = 1 << 24;

/// Largest OBJ or MTL file, in bytes (the text is held in memory while it is parsed).
pub const MAX_OBJ_FILE_BYTES: u64 = 4 << 30;

/// Largest scale factor of an object transform (the length of a column of its linear part):
/// beyond it, positions squared in intersection and sampling code overflow `f32`.
pub const MAX_TRANSFORM_SCALE: f32 = 1e12;

/// Checks the linear part of an object transform: finite, invertible, and no axis scaled by
/// more than [`MAX_TRANSFORM_SCALE`] or by less than its inverse. Returns the message.
pub fn check_transform_scale(linear: glam::Mat3) -> std::result::Result<(), String> {
    for (axis, column) in ["x", "y", "z"].iter().zip(linear.to_cols_array_2d()) {
        let length = glam::DVec3::from(column.map(f64::from)).length() as f32;
        if !(length <= MAX_TRANSFORM_SCALE) {
            return Err(format!(
                "transform scales the {axis} axis by {length:e}, over the limit of {MAX_TRANSFORM_SCALE:e}"
            ));
        }
        if !(length >= 1.0 / MAX_TRANSFORM_SCALE) {
            return Err(format!(
                "transform scales the {axis} axis by {length:e}, under the limit of {:e} (singular: zero scale?)",
                1.0 / MAX_TRANSFORM_SCALE
            ));
        }
    }
    let det = glam::DMat3::from_cols_array(&linear.to_cols_array().map(f64::from)).determinant();
    if det.abs() < (1.0 / MAX_TRANSFORM_SCALE as f64).powi(3) {
        return Err(format!(
            "transform is singular (determinant {det:e}: its axes are parallel or flat)"
        ));
    }
    Ok(())
}

/// Bytes of physical memory of this machine (`None` where it cannot be read).
pub fn physical_memory() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib.saturating_mul(1024))
}

/// The memory budget a caller asked for, checked: zero is refused, and a budget above the
/// machine's physical memory is refused too (allocations that large abort the process instead
/// of failing). `what` names the option or field that gave it.
pub fn check_memory_budget(what: &str, bytes: u64) -> Result<u64> {
    if bytes == 0 {
        return Err(Error::invalid(format!(
            "{what}: a memory budget of 0 bytes"
        )));
    }
    if let Some(physical) = physical_memory() {
        if bytes > physical {
            return Err(Error::invalid(format!(
                "{what}: a memory budget of {} MiB is more than this machine's {} MiB of physical memory",
                bytes >> 20,
                physical >> 20
            )));
        }
    }
    Ok(bytes)
}

/// The budget actually enforced: the requested one, but never more than physical memory.
pub fn effective_memory_budget(bytes: u64) -> u64 {
    physical_memory().map_or(bytes, |p| bytes.min(p))
}

/// Refuses `bytes` of `what` over `budget` ([`Error::OverBudget`] names both).
pub fn check_bytes(what: impl FnOnce() -> String, bytes: u64, budget: u64) -> Result<()> {
    if bytes > budget {
        return Err(Error::OverBudget {
            what: what(),
            bytes,
            budget,
        });
    }
    Ok(())
}

/// Width and height in 1..=[`MAX_FILM_SIDE`].
pub fn check_film_side(width: u32, height: u32) -> Result<()> {
    if width == 0 || height == 0 || width > MAX_FILM_SIDE || height > MAX_FILM_SIDE {
        return Err(Error::invalid(format!(
            "image size {width}x{height} must be within 1..={MAX_FILM_SIDE} on each side"
        )));
    }
    Ok(())
}

pub fn check_threads(what: &str, threads: usize) -> Result<()> {
    if threads > MAX_THREADS as usize {
        return Err(Error::invalid(format!(
            "{what} {threads} exceeds the limit of {MAX_THREADS} threads"
        )));
    }
    Ok(())
}

pub fn check_max_depth(what: &str, depth: u32) -> Result<()> {
    if depth > MAX_DEPTH {
        return Err(Error::invalid(format!(
            "{what} {depth} exceeds the limit of {MAX_DEPTH}"
        )));
    }
    Ok(())
}

pub fn check_light_paths(what: &str, count: u64) -> Result<()> {
    if count == 0 || count > MAX_LIGHT_PATHS as u64 {
        return Err(Error::invalid(format!(
            "{what} {count} must be within 1..={MAX_LIGHT_PATHS}"
        )));
    }
    Ok(())
}

/// Opens an image file for the `image` crate with its size checked first: the header's
/// width x height must be at most `max_pixels`, and `bytes_per_pixel` times that within
/// `budget`, before any pixel is decoded (a 100-byte file can claim gigapixels).
pub fn open_image_checked(
    path: &Path,
    kind: &str,
    max_pixels: u64,
    bytes_per_pixel: u64,
    budget: u64,
) -> Result<image::ImageReader<std::io::BufReader<std::fs::File>>> {
    let open = || -> Result<_> {
        image::ImageReader::open(path)
            .map_err(|e| Error::io(path, e))?
            .with_guessed_format()
            .map_err(|e| Error::io(path, e))
    };
    let (w, h) = open()?
        .into_dimensions()
        .map_err(|e| Error::parse(path, "header", e.to_string()))?;
    let pixels = w as u64 * h as u64;
    if pixels > max_pixels {
        return Err(Error::parse(
            path,
            "header",
            format!("a {w}x{h} {kind} is over the limit of {max_pixels} pixels"),
        ));
    }
    let bytes = pixels.saturating_mul(bytes_per_pixel);
    check_bytes(
        || format!("{}: a {w}x{h} {kind}", path.display()),
        bytes,
        budget,
    )?;
    let mut reader = open()?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(bytes.saturating_add(1 << 20).min(budget));
    reader.limits(limits);
    Ok(reader)
}

/// Reads a whole file that must be a regular file of at most `max_bytes` bytes: a device such
/// as `/dev/zero`, a pipe or a file over the limit is refused before anything is read, and the
/// read itself stops at the limit (the file may grow meanwhile).
pub fn read_file_bounded(path: &Path, kind: &str, max_bytes: u64) -> Result<Vec<u8>> {
    use std::io::Read;
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let meta = file.metadata().map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(Error::parse(
            path,
            "",
            format!("{kind} must be a regular file (not a directory, device or pipe)"),
        ));
    }
    let too_big = || {
        Error::parse(
            path,
            "",
            format!("{kind} is larger than the limit of {max_bytes} bytes"),
        )
    };
    if meta.len() > max_bytes {
        return Err(too_big());
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(max_bytes + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| Error::io(path, e))?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_big());
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_and_oversized_files_are_refused_before_reading() {
        let e = read_file_bounded(Path::new("/dev/zero"), "OBJ file", 1 << 20).unwrap_err();
        assert!(e.to_string().contains("/dev/zero"), "{e}");
        assert!(e.to_string().contains("regular file"), "{e}");
        let dir = std::env::temp_dir().join(format!("lacuna-limits-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("big.txt");
        std::fs::write(&path, vec![b'x'; 100]).unwrap();
        let e = read_file_bounded(&path, "scene file", 99).unwrap_err();
        assert!(e.to_string().contains("limit of 99 bytes"), "{e}");
        assert_eq!(
            read_file_bounded(&path, "scene file", 100).unwrap().len(),
            100
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn budgets_above_physical_memory_are_refused() {
        let Some(physical) = physical_memory() else {
            return;
        };
        assert!(check_memory_budget("--memory-budget-mib", physical + 1).is_err());
        assert!(check_memory_budget("--memory-budget-mib", 0).is_err());
        assert_eq!(check_memory_budget("x", 1 << 20).unwrap(), 1 << 20);
        assert_eq!(effective_memory_budget(u64::MAX), physical);
    }
}
