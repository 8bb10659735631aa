//! Builds `examples/embree_crosscheck/crosscheck.c` with the system's `cc` against Embree 3,
//! OpenEXR and the shared library cargo built for this test run (`target/<profile>/`, built
//! here with a nested `cargo build --lib` as `tests/c_api.rs` does), runs it and requires exit
//! status 0: Lacuna's closest-hit and occlusion queries agree with Embree's on millions of rays
//! within the tolerances documented in the program, and so do the depth and AO images; once
//! with Lacuna's Medium BVH and once with its Fast one (another builder).
//!
//! Embree (`libembree-dev`) and OpenEXR (`libopenexr-dev`) are system packages. When their
//! headers are missing the test fails if `CI` is set (`.ci/run` installs them) and otherwise
//! prints a loud notice and passes.

use std::path::PathBuf;
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `target/<profile>/` with the shared library freshly built (this test runs from
/// `target/<profile>/deps/`; `cargo test` builds the library only as an rlib).
fn lib_dir() -> (PathBuf, String) {
    let exe = std::env::current_exe().unwrap();
    let dir = exe.parent().unwrap().parent().unwrap().to_path_buf();
    let target_dir = dir.parent().unwrap();
    let profile = dir.file_name().unwrap().to_str().unwrap().to_string();
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.current_dir(root())
        .args(["build", "--lib", "--quiet", "--target-dir"])
        .arg(target_dir);
    match profile.as_str() {
        "debug" => {}
        "release" => {
            cmd.arg("--release");
        }
        other => {
            cmd.args(["--profile", other]);
        }
    }
    let out = cmd.output().expect("cannot run cargo");
    assert!(
        out.status.success(),
        "cargo build --lib failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(dir.join("liblacuna.so").exists(), "liblacuna.so missing");
    (dir, profile)
}

/// `pkg-config --cflags --libs OpenEXR`, split, or why it is unavailable.
fn openexr_flags() -> Result<(Vec<String>, Vec<String>), String> {
    let flags = |what: &str| -> Result<Vec<String>, String> {
        let out = Command::new("pkg-config")
            .args([what, "OpenEXR"])
            .output()
            .map_err(|e| format!("pkg-config cannot run ({e})"))?;
        if !out.status.success() {
            return Err(format!(
                "pkg-config knows no OpenEXR: {}",
                String::from_utf8_lossy(&out.stderr).trim()
            ));
        }
        Ok(String::from_utf8_lossy(&out.stdout)
            .split_whitespace()
            .map(String::from)
            .collect())
    };
    Ok((flags("--cflags")?, flags("--libs")?))
}

/// Checks that `<embree3/rtcore.h>` and `<ImfCRgbaFile.h>` can be included.
fn dependencies() -> Result<(Vec<String>, Vec<String>), String> {
    let (cflags, libs) = openexr_flags()?;
    let probe = std::env::temp_dir().join(format!("lacuna-embree-probe-{}.c", std::process::id()));
    std::fs::write(
        &probe,
        "#include <embree3/rtcore.h>\n#include <ImfCRgbaFile.h>\nint main(void) { return 0; }\n",
    )
    .unwrap();
    let out = Command::new("cc")
        .arg("-E")
        .args(&cflags)
        .arg(&probe)
        .output()
        .map_err(|e| format!("cc cannot run ({e})"))?;
    let _ = std::fs::remove_file(&probe);
    if !out.status.success() {
        return Err(format!(
            "the Embree 3 or OpenEXR headers are missing:\n{}",
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    Ok((cflags, libs))
}

#[test]
fn lacuna_agrees_with_embree() {
    let (cflags, libs) = match dependencies() {
        Ok(f) => f,
        Err(why) => {
            let msg = format!(
                "Embree cross-check cannot be built: {why}\n\
                 install them with: apt-get install -y libembree-dev libopenexr-dev"
            );
            if std::env::var_os("CI").is_some() {
                panic!("{msg}\n(CI is set: .ci/run installs these packages, so this is a failure)");
            }
            eprintln!("\n{0}\n!!! SKIPPED: {msg}\n{0}\n", "!".repeat(78));
            return;
        }
    };
    let (lib, profile) = lib_dir();
    let out_dir = std::env::temp_dir().join(format!("lacuna-embree-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out_dir);
    std::fs::create_dir_all(&out_dir).unwrap();
    // The shared library laid out as installed: its SONAME is liblacuna.so.X.Y.Z.
    let staged = out_dir.join("lib");
    std::fs::create_dir_all(&staged).unwrap();
    let versioned = format!("liblacuna.so.{}", env!("CARGO_PKG_VERSION"));
    std::fs::copy(lib.join("liblacuna.so"), staged.join(&versioned)).unwrap();
    std::os::unix::fs::symlink(&versioned, staged.join("liblacuna.so")).unwrap();
    let lib = staged;
    let exe = out_dir.join("crosscheck");
    let mut cc = Command::new("cc");
    cc.args([
        "-std=c99",
        "-D_POSIX_C_SOURCE=200809L",
        "-O2",
        "-Wall",
        "-Wextra",
        "-pedantic",
        "-Werror",
    ])
    .arg("-I")
    .arg(root().join("include"))
    .args(&cflags)
    .arg(root().join("examples/embree_crosscheck/crosscheck.c"))
    .arg("-o")
    .arg(&exe)
    .arg(format!("-L{}", lib.display()))
    .arg("-llacuna")
    .arg(format!("-Wl,-rpath,{}", lib.display()))
    .arg("-lembree3")
    .args(&libs)
    .args(["-lpthread", "-lm"]);
    let out = cc.output().expect("cannot run cc");
    assert!(
        out.status.success(),
        "compiling crosscheck.c failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // An unoptimised Lacuna is ~20 times slower: trace a twentieth of the rays there.
    let ray_scale = if profile == "debug" { "0.05" } else { "1" };
    // Medium (the default) and Fast (the binned 8-wide build) are different trees.
    for quality in ["medium", "fast"] {
        let run_dir = out_dir.join(quality);
        std::fs::create_dir_all(&run_dir).unwrap();
        let out = Command::new(&exe)
            .arg(root())
            .arg(&run_dir)
            .arg(ray_scale)
            .arg(quality)
            .output()
            .expect("cannot run crosscheck");
        let stdout = String::from_utf8_lossy(&out.stdout);
        println!("{stdout}");
        eprintln!("{}", String::from_utf8_lossy(&out.stderr));
        assert!(
            out.status.success(),
            "crosscheck exited with {} (disagreements beyond tolerance, see the table above)",
            out.status
        );
        for scene in ["room-1e-4", "room-1", "room-1e4", "cornell-box"] {
            for img in ["depth-embree", "ao-embree", "depth-lacuna", "ao-lacuna"] {
                let p = run_dir.join(format!("{scene}-{img}.exr"));
                assert!(
                    std::fs::metadata(&p).map(|m| m.len() > 0).unwrap_or(false),
                    "{} was not written",
                    p.display()
                );
            }
        }
        assert!(stdout.contains("RESULT: OK"));
    }
    let _ = std::fs::remove_dir_all(&out_dir);
}
