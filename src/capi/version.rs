//! Run-time version queries. The header's `LACUNA_VERSION*` macros carry the version the
//! header was generated from (both come from Cargo.toml).

use std::ffi::c_char;

use super::boundary;

/// Packs a version the way `LACUNA_VERSION` does: `major << 16 | minor << 8 | patch`.
pub(crate) const fn pack(major: u32, minor: u32, patch: u32) -> u32 {
    (major << 16) | (minor << 8) | patch
}

const fn parse(s: &str) -> u32 {
    let b = s.as_bytes();
    let mut i = 0;
    let mut v = 0u32;
    while i < b.len() {
        v = v * 10 + (b[i] - b'0') as u32;
        i += 1;
    }
    v
}

pub(crate) const VERSION: u32 = pack(
    parse(env!("CARGO_PKG_VERSION_MAJOR")),
    parse(env!("CARGO_PKG_VERSION_MINOR")),
    parse(env!("CARGO_PKG_VERSION_PATCH")),
);

/// The library's version packed as `LACUNA_VERSION` is (`major << 16 | minor << 8 | patch`).
/// Compare it with `LACUNA_VERSION` to check that the header matches the library. Thread-safe.
#[no_mangle]
pub extern "C" fn lacuna_version() -> u32 {
    boundary::value("lacuna_version", 0, |_| Ok(VERSION))
}

/// The library's version as a static string, e.g. `"0.1.0"`. Never NULL. Thread-safe.
#[no_mangle]
pub extern "C" fn lacuna_version_string() -> *const c_char {
    boundary::value("lacuna_version_string", c"".as_ptr(), |_| {
        Ok(concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr().cast())
    })
}
