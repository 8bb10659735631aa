//! Checked conversions of C arguments: pointers, strided buffers, strings, handles and
//! out-parameters.

use std::ffi::{c_char, CStr};
use std::path::PathBuf;
use std::sync::Arc;

use super::boundary::{lacuna_status, CapiError, CapiResult};

/// `&T` from a pointer that must not be NULL.
///
/// # Safety
/// A non-NULL `ptr` must point to a live `T` for the returned lifetime.
pub(crate) unsafe fn arg<'a, T>(ptr: *const T, name: &str) -> CapiResult<&'a T> {
    // SAFETY: the caller guarantees a non-NULL pointer is valid; NULL is rejected here.
    unsafe { ptr.as_ref() }.ok_or_else(|| CapiError::null(name))
}

/// Reads a value through a pointer that must not be NULL (no alignment required).
///
/// # Safety
/// A non-NULL `ptr` must be readable for `size_of::<T>()` bytes.
pub(crate) unsafe fn read_arg<T: Copy>(ptr: *const T, name: &str) -> CapiResult<T> {
    if ptr.is_null() {
        return Err(CapiError::null(name));
    }
    // SAFETY: non-NULL and readable per the caller's contract; no alignment needed.
    Ok(unsafe { ptr.read_unaligned() })
}

/// Writes an out-parameter; call only once the function has succeeded.
///
/// # Safety
/// `out` must have been checked with [`out_ptr`] and be valid for a write of `T`.
pub(crate) unsafe fn write_out<T>(out: *mut T, value: T) {
    // SAFETY: per this function's contract, `out` is non-NULL and writable; `write_unaligned`
    // neither reads nor drops the previous (possibly uninitialised) content.
    unsafe { out.write_unaligned(value) }
}

/// Checks that an out-parameter is not NULL (before doing any work).
pub(crate) fn out_ptr<T>(out: *mut T, name: &str) -> CapiResult<*mut T> {
    if out.is_null() {
        Err(CapiError::null(name))
    } else {
        Ok(out)
    }
}

/// A UTF-8 string argument that must not be NULL.
///
/// # Safety
/// A non-NULL `ptr` must point to a NUL-terminated string valid for the returned lifetime.
pub(crate) unsafe fn str_arg<'a>(ptr: *const c_char, name: &str) -> CapiResult<&'a str> {
    if ptr.is_null() {
        return Err(CapiError::null(name));
    }
    // SAFETY: non-NULL and NUL-terminated per the caller's contract.
    let s = unsafe { CStr::from_ptr(ptr) };
    s.to_str().map_err(|e| {
        CapiError::invalid(format!(
            "`{name}` is not valid UTF-8 ({e}): {}",
            s.to_string_lossy()
        ))
    })
}

/// A path argument (bytes as given on Unix, UTF-8 elsewhere) that must not be NULL or empty.
///
/// # Safety
/// A non-NULL `ptr` must point to a NUL-terminated string.
pub(crate) unsafe fn path_arg(ptr: *const c_char, name: &str) -> CapiResult<PathBuf> {
    if ptr.is_null() {
        return Err(CapiError::null(name));
    }
    // SAFETY: non-NULL and NUL-terminated per the caller's contract.
    let s = unsafe { CStr::from_ptr(ptr) };
    if s.is_empty() {
        return Err(CapiError::invalid(format!("`{name}` is an empty path")));
    }
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt;
        Ok(PathBuf::from(std::ffi::OsStr::from_bytes(s.to_bytes())))
    }
    #[cfg(not(unix))]
    {
        // SAFETY: as above.
        Ok(PathBuf::from(unsafe { str_arg(ptr, name) }?))
    }
}

/// Copies `count` elements of `T` found every `byte_stride` bytes from `ptr` (stride 0 means
/// packed). A count of 0 accepts NULL. No alignment is required.
///
/// # Safety
/// For a non-zero count, `ptr` must be readable for `(count - 1) * stride + size_of::<T>()`
/// bytes.
pub(crate) unsafe fn read_strided<T: Copy>(
    ptr: *const u8,
    byte_stride: usize,
    count: usize,
    name: &str,
) -> CapiResult<Vec<T>> {
    let size = std::mem::size_of::<T>();
    let stride = if byte_stride == 0 { size } else { byte_stride };
    if stride < size {
        return Err(CapiError::invalid(format!(
            "`{name}` stride {byte_stride} bytes is smaller than one element ({size} bytes)"
        )));
    }
    if count == 0 {
        return Ok(Vec::new());
    }
    if ptr.is_null() {
        return Err(CapiError::null(name));
    }
    let span = (count - 1)
        .checked_mul(stride)
        .and_then(|s| s.checked_add(size))
        .filter(|&s| s <= isize::MAX as usize)
        .ok_or_else(|| {
            CapiError::range(format!(
                "`{name}`: {count} elements every {stride} bytes exceed the address space"
            ))
        })?;
    if (ptr as usize).checked_add(span).is_none() {
        return Err(CapiError::range(format!(
            "`{name}`: {count} elements every {stride} bytes wrap around the address space"
        )));
    }
    let mut out = Vec::new();
    out.try_reserve_exact(count).map_err(|_| {
        CapiError::new(
            lacuna_status::OutOfMemory,
            format!("`{name}`: cannot allocate {count} elements of {size} bytes"),
        )
    })?;
    for i in 0..count {
        // SAFETY: `i * stride + size <= span`, which the caller guarantees readable;
        // `read_unaligned` needs no alignment.
        out.push(unsafe { ptr.add(i * stride).cast::<T>().read_unaligned() });
    }
    Ok(out)
}

/// Checks an output image layout `(width, pixel_stride, row_stride)` for pixels of
/// `pixel_bytes` bytes and returns the resolved pixel and row strides.
pub(crate) fn image_layout(
    width: usize,
    pixel_stride: usize,
    row_stride: usize,
    pixel_bytes: usize,
) -> CapiResult<(usize, usize)> {
    let ps = if pixel_stride == 0 {
        pixel_bytes
    } else {
        pixel_stride
    };
    if ps < pixel_bytes {
        return Err(CapiError::invalid(format!(
            "pixel_stride {pixel_stride} is smaller than one pixel ({pixel_bytes} bytes)"
        )));
    }
    let row = width.checked_mul(ps).ok_or_else(|| {
        CapiError::range(format!("width {width} times pixel stride {ps} overflows"))
    })?;
    let rs = if row_stride == 0 { row } else { row_stride };
    if rs < row {
        return Err(CapiError::invalid(format!(
            "row_stride {row_stride} is smaller than a row of {width} pixels every {ps} bytes ({row} bytes)"
        )));
    }
    Ok((ps, rs))
}

/// Turns an `Arc` into a handle for C (refcount 1 from the caller's point of view).
pub(crate) fn arc_into_handle<T>(value: T) -> *mut T {
    Arc::into_raw(Arc::new(value)).cast_mut()
}

/// A new `Arc` on a handle: one more reference, owned by the Rust caller.
///
/// # Safety
/// `handle` must be a live handle made by [`arc_into_handle`].
pub(crate) unsafe fn arc_clone<T>(handle: *const T) -> Arc<T> {
    // SAFETY: `handle` came from `Arc::into_raw` and its count is at least 1 (caller's
    // contract), so incrementing then re-owning one count is balanced.
    unsafe {
        Arc::increment_strong_count(handle);
        Arc::from_raw(handle)
    }
}

/// `_retain`: one more reference. NULL is a no-op.
///
/// # Safety
/// A non-NULL `handle` must be a live handle made by [`arc_into_handle`].
pub(crate) unsafe fn arc_retain<T>(handle: *const T) {
    if !handle.is_null() {
        // SAFETY: live handle from `Arc::into_raw` (caller's contract).
        unsafe { Arc::increment_strong_count(handle) }
    }
}

/// `_release`: one reference less; the last one destroys the object. NULL is a no-op.
///
/// # Safety
/// A non-NULL `handle` must be a live handle made by [`arc_into_handle`], and the caller gives
/// up one reference.
pub(crate) unsafe fn arc_release<T>(handle: *const T) {
    if !handle.is_null() {
        // SAFETY: live handle from `Arc::into_raw`; the caller owns the reference dropped here.
        unsafe { Arc::decrement_strong_count(handle) }
    }
}

/// `_free` of a single-owner handle made with `Box::into_raw`. NULL is a no-op.
///
/// # Safety
/// A non-NULL `handle` must come from `Box::into_raw` and not be used afterwards.
pub(crate) unsafe fn box_free<T>(handle: *mut T) {
    if !handle.is_null() {
        // SAFETY: per the contract, the handle is an owned, live Box.
        drop(unsafe { Box::from_raw(handle) })
    }
}

/// Checks a float argument is finite.
pub(crate) fn finite(v: f32, name: &str) -> CapiResult<f32> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(CapiError::invalid(format!(
            "`{name}` is {v} (must be finite)"
        )))
    }
}
