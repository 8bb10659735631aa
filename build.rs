//! Build script: gives the C library (cdylib) a SONAME carrying the exact version while Lacuna
//! is 0.x (docs/capi-conventions.md, rule 10), so programs linked against one 0.x release never load another.

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    let os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    let version = std::env::var("CARGO_PKG_VERSION").unwrap_or_default();
    if os == "linux" {
        println!("cargo:rustc-cdylib-link-arg=-Wl,-soname,liblacuna.so.{version}");
    }
}
