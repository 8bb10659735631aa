//! `include/lacuna.h` is generated from `src/capi/` by the pinned cbindgen: this test
//! regenerates it and fails on any difference (run with `LACUNA_BLESS=1` to rewrite it), checks
//! the version macros against Cargo.toml, and compiles the header alone as C99 and C++17 with
//! warnings as errors.

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn version() -> (u32, u32, u32) {
    let p = |s: &str| s.parse::<u32>().unwrap();
    (
        p(env!("CARGO_PKG_VERSION_MAJOR")),
        p(env!("CARGO_PKG_VERSION_MINOR")),
        p(env!("CARGO_PKG_VERSION_PATCH")),
    )
}

/// The version macros, from Cargo.toml (through cargo's environment).
fn version_macros() -> String {
    let (major, minor, patch) = version();
    format!(
        "\n/* Version of the library this header was generated from (Cargo.toml). */\n\
         #define LACUNA_VERSION_MAJOR {major}\n\
         #define LACUNA_VERSION_MINOR {minor}\n\
         #define LACUNA_VERSION_PATCH {patch}\n\
         /* (major << 16) | (minor << 8) | patch, as lacuna_version() returns it. */\n\
         #define LACUNA_VERSION {}\n\
         #define LACUNA_VERSION_STRING \"{}\"\n",
        (major << 16) | (minor << 8) | patch,
        env!("CARGO_PKG_VERSION")
    )
}

fn generate() -> String {
    let mut config = cbindgen::Config::from_file(root().join("cbindgen.toml")).unwrap();
    config.after_includes = Some(version_macros());
    let bindings = cbindgen::Builder::new()
        // Only the C API's module tree: the rest of the crate has public constants that are no
        // part of the C API.
        .with_src(root().join("src/capi/mod.rs"))
        .with_config(config)
        .generate()
        .expect("cbindgen failed");
    let mut out = Vec::new();
    bindings.write(&mut out);
    String::from_utf8(out).unwrap()
}

#[test]
fn header_is_up_to_date() {
    let path = root().join("include/lacuna.h");
    let fresh = generate();
    if std::env::var_os("LACUNA_BLESS").is_some() {
        std::fs::write(&path, &fresh).unwrap();
        return;
    }
    let checked_in = std::fs::read_to_string(&path).unwrap_or_default();
    if checked_in != fresh {
        let first = checked_in
            .lines()
            .zip(fresh.lines())
            .position(|(a, b)| a != b)
            .unwrap_or(checked_in.lines().count().min(fresh.lines().count()));
        panic!(
            "include/lacuna.h is out of date (first difference at line {}): regenerate it with \
             `LACUNA_BLESS=1 cargo test --release --test header` and commit it",
            first + 1
        );
    }
}

#[test]
fn version_macros_match_cargo_toml() {
    let header = std::fs::read_to_string(root().join("include/lacuna.h")).unwrap();
    let (major, minor, patch) = version();
    for (name, value) in [
        ("LACUNA_VERSION_MAJOR", major.to_string()),
        ("LACUNA_VERSION_MINOR", minor.to_string()),
        ("LACUNA_VERSION_PATCH", patch.to_string()),
        (
            "LACUNA_VERSION",
            ((major << 16) | (minor << 8) | patch).to_string(),
        ),
        (
            "LACUNA_VERSION_STRING",
            format!("\"{}\"", env!("CARGO_PKG_VERSION")),
        ),
    ] {
        let line = format!("#define {name} {value}\n");
        assert!(header.contains(&line), "header lacks `{}`", line.trim());
    }
    // Cargo.toml itself, read independently of cargo's environment.
    let toml = std::fs::read_to_string(root().join("Cargo.toml")).unwrap();
    let declared = toml
        .lines()
        .find_map(|l| l.strip_prefix("version = \""))
        .and_then(|l| l.strip_suffix('"'))
        .unwrap();
    assert!(header.contains(&format!("#define LACUNA_VERSION_STRING \"{declared}\"")));
}

fn compile(compiler: &str, args: &[&str], file: &Path) {
    let out = Command::new(compiler)
        .args(args)
        .arg("-I")
        .arg(root().join("include"))
        .arg(file)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {compiler}: {e}"));
    assert!(
        out.status.success(),
        "{compiler} {args:?} {} failed:\n{}",
        file.display(),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn header_compiles_alone_as_c99_and_cpp17() {
    let header = root().join("include/lacuna.h");
    compile(
        "cc",
        &[
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-pedantic",
            "-Werror",
            "-fsyntax-only",
            "-x",
            "c",
        ],
        &header,
    );
    compile(
        "c++",
        &[
            "-std=c++17",
            "-Wall",
            "-Wextra",
            "-pedantic",
            "-Werror",
            "-fsyntax-only",
            "-x",
            "c++",
        ],
        &header,
    );
    // The packed value, checked by the C preprocessor and compiler themselves.
    let dir = std::env::temp_dir().join(format!("lacuna-header-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (major, minor, patch) = version();
    let src = dir.join("version.c");
    std::fs::write(
        &src,
        format!(
            "#include \"lacuna.h\"\n#include \"lacuna.h\"\n\
             #if LACUNA_VERSION != ((LACUNA_VERSION_MAJOR << 16) | (LACUNA_VERSION_MINOR << 8) | LACUNA_VERSION_PATCH)\n\
             #error packed version does not match the parts\n#endif\n\
             #if LACUNA_VERSION_MAJOR != {major} || LACUNA_VERSION_MINOR != {minor} || LACUNA_VERSION_PATCH != {patch}\n\
             #error version parts do not match Cargo.toml\n#endif\n\
             typedef char ray_is_32_bytes[sizeof(lacuna_ray) == 32 ? 1 : -1];\n\
             typedef char hit_is_36_bytes[sizeof(lacuna_hit) == 36 ? 1 : -1];\n\
             typedef char status_is_u32[sizeof(lacuna_status) == 4 ? 1 : -1];\n\
             static const char version_string[] = LACUNA_VERSION_STRING;\n\
             int main(void) {{ return (int)sizeof(version_string) - (int)sizeof(\"{}\"); }}\n",
            env!("CARGO_PKG_VERSION")
        ),
    )
    .unwrap();
    compile(
        "cc",
        &[
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-pedantic",
            "-Werror",
            "-Wno-unused-local-typedefs",
            "-fsyntax-only",
        ],
        &src,
    );
    let _ = std::fs::remove_dir_all(&dir);
}
