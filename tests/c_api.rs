//! Builds the C and C++ tests of the C API (`tests/c/`) with the system's `cc`/`c++` against
//! the library cargo built for this test run (the cdylib and the staticlib next to this test's
//! executable, under `target/<profile>/`), and runs them: linked shared and static, under
//! AddressSanitizer (checked to be really linked in), and under valgrind when it is installed
//! (`.ci/run` installs it; set `LACUNA_REQUIRE_VALGRIND=1` to make its absence a failure).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

mod common;

/// C test programs besides `test_capi.c`, run the same ways (one program per part of the API).
const MORE_C_TESTS: &[&str] = &[
    "test_environment",
    "test_light_sampler",
    "test_photometric",
    "test_light_field",
];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `target/<profile>/` with the C libraries freshly built: this test runs from
/// `target/<profile>/deps/`, and `cargo test` builds the library only as an rlib, so the
/// cdylib and staticlib are built here (a no-op when they are up to date) with the same cargo,
/// profile and target directory.
fn lib_dir() -> PathBuf {
    static BUILT: OnceLock<PathBuf> = OnceLock::new();
    BUILT
        .get_or_init(|| {
            let exe = std::env::current_exe().unwrap();
            let dir = exe.parent().unwrap().parent().unwrap().to_path_buf();
            let target_dir = dir.parent().unwrap();
            let profile = dir.file_name().unwrap().to_str().unwrap();
            let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
            let mut cmd = Command::new(cargo);
            cmd.current_dir(root())
                .args(["build", "--lib", "--quiet", "--target-dir"])
                .arg(target_dir);
            match profile {
                "debug" => {}
                "release" => {
                    cmd.arg("--release");
                }
                other => {
                    cmd.args(["--profile", other]);
                }
            }
            check(&mut cmd, "building the C libraries (cargo build --lib)");
            for lib in ["liblacuna.so", "liblacuna.a"] {
                assert!(
                    dir.join(lib).exists(),
                    "{} is missing",
                    dir.join(lib).display()
                );
            }
            dir
        })
        .clone()
}

/// The shared library laid out as installed: `liblacuna.so.X.Y.Z` (its SONAME) and a
/// `liblacuna.so` link to it, in `out_dir/lib`.
fn staged_shared_lib(out_dir: &Path) -> PathBuf {
    let dir = out_dir.join("lib");
    std::fs::create_dir_all(&dir).unwrap();
    let versioned = format!("liblacuna.so.{}", env!("CARGO_PKG_VERSION"));
    std::fs::copy(lib_dir().join("liblacuna.so"), dir.join(&versioned)).unwrap();
    let link = dir.join("liblacuna.so");
    let _ = std::fs::remove_file(&link);
    std::os::unix::fs::symlink(&versioned, &link).unwrap();
    dir
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("lacuna-capi-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn run(cmd: &mut Command) -> Output {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e}"));
    out
}

fn check(cmd: &mut Command, what: &str) -> Output {
    let out = run(cmd);
    assert!(
        out.status.success(),
        "{what} failed ({}):\n--- stdout\n{}\n--- stderr\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// Native libraries a Rust staticlib needs on Linux (`--print native-static-libs`).
const STATIC_DEPS: &[&str] = &[
    "-lgcc_s",
    "-lutil",
    "-lrt",
    "-lpthread",
    "-lm",
    "-ldl",
    "-lc",
];

#[derive(Clone, Copy, PartialEq)]
enum Link {
    Shared,
    Static,
}

/// Compiles one test source into `out_dir` and returns the executable.
fn compile(source: &str, link: Link, flags: &[&str], out_dir: &Path, name: &str) -> PathBuf {
    let is_cpp = source.ends_with(".cpp");
    let exe = out_dir.join(name);
    let mut cmd = Command::new(if is_cpp { "c++" } else { "cc" });
    cmd.arg(if is_cpp { "-std=c++17" } else { "-std=c99" })
        .args([
            "-D_POSIX_C_SOURCE=200809L",
            "-Wall",
            "-Wextra",
            "-pedantic",
            "-Werror",
            "-g",
        ])
        .args(flags)
        .arg("-I")
        .arg(root().join("include"))
        .arg("-I")
        .arg(root().join("bindings/cpp"))
        .arg(root().join(source))
        .arg("-o")
        .arg(&exe);
    match link {
        Link::Shared => {
            let lib = staged_shared_lib(out_dir);
            cmd.arg(format!("-L{}", lib.display()))
                .arg("-llacuna")
                .arg(format!("-Wl,-rpath,{}", lib.display()))
                .args(["-lpthread", "-lm"]);
        }
        Link::Static => {
            cmd.arg(lib_dir().join("liblacuna.a")).args(STATIC_DEPS);
        }
    }
    check(&mut cmd, &format!("compiling {source}"));
    exe
}

/// Runs a test executable on a fresh scratch directory and checks its closing line.
fn run_test(prefix: &[&str], exe: &Path, env: &[(&str, &str)], what: &str) -> String {
    let dir = scratch(what);
    let mut cmd = if prefix.is_empty() {
        Command::new(exe)
    } else {
        let mut c = Command::new(prefix[0]);
        c.args(&prefix[1..]).arg(exe);
        c
    };
    cmd.arg(&dir).env("RUST_BACKTRACE", "0");
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = check(&mut cmd, what);
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let last = stdout.lines().last().unwrap_or_default().to_string();
    assert!(
        last.ends_with(" 0 failed") && !last.starts_with("0 passed"),
        "{what}: unexpected closing line {last:?}"
    );
    println!("{what}: {last}");
    let _ = std::fs::remove_dir_all(&dir);
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn shared_library_soname_carries_the_exact_version() {
    let out = check(
        Command::new("readelf")
            .arg("-d")
            .arg(lib_dir().join("liblacuna.so")),
        "readelf",
    );
    let want = format!(
        "Library soname: [liblacuna.so.{}]",
        env!("CARGO_PKG_VERSION")
    );
    assert!(
        String::from_utf8_lossy(&out.stdout).contains(&want),
        "liblacuna.so lacks `{want}`"
    );
}

#[test]
fn c_tests_pass_linked_shared_and_static() {
    let out = scratch("build-plain");
    let shared = compile(
        "tests/c/test_capi.c",
        Link::Shared,
        &[],
        &out,
        "test_capi_shared",
    );
    run_test(&[], &shared, &[], "C tests (shared library)");
    let stat = compile(
        "tests/c/test_capi.c",
        Link::Static,
        &[],
        &out,
        "test_capi_static",
    );
    run_test(&[], &stat, &[], "C tests (static library)");
    for name in MORE_C_TESTS {
        let src = format!("tests/c/{name}.c");
        let exe = compile(&src, Link::Shared, &[], &out, &format!("{name}_shared"));
        run_test(&[], &exe, &[], &format!("{name} (shared library)"));
        let exe = compile(&src, Link::Static, &[], &out, &format!("{name}_static"));
        run_test(&[], &exe, &[], &format!("{name} (static library)"));
    }
    let _ = std::fs::remove_dir_all(&out);
}

fn asan_flags() -> &'static [&'static str] {
    &[
        "-fsanitize=address,undefined",
        "-fno-omit-frame-pointer",
        "-fno-sanitize-recover=all",
    ]
}

/// Proves AddressSanitizer is linked into `exe` and active: the binary references the ASan
/// runtime's `__asan_init`, and ASan reports its own options when asked to.
fn assert_asan_linked(exe: &Path) {
    let nm = check(Command::new("nm").arg(exe), "nm");
    assert!(
        String::from_utf8_lossy(&nm.stdout).contains("__asan_init"),
        "{} does not reference __asan_init: AddressSanitizer is not linked",
        exe.display()
    );
}

#[test]
fn c_tests_pass_under_address_sanitizer() {
    let out = scratch("build-asan");
    // A deliberate heap overflow must be caught: the sanitizer really works here.
    let bad = out.join("overflow.c");
    std::fs::write(
        &bad,
        "#include <stdlib.h>\nint main(void) { volatile char *p = malloc(4); p[4] = 1; free((void *)p); return 0; }\n",
    )
    .unwrap();
    let bad_exe = out.join("overflow");
    check(
        Command::new("cc")
            .args(asan_flags())
            .arg(&bad)
            .arg("-o")
            .arg(&bad_exe),
        "compiling the ASan control",
    );
    assert_asan_linked(&bad_exe);
    let r = run(&mut Command::new(&bad_exe));
    assert!(
        !r.status.success()
            && String::from_utf8_lossy(&r.stderr)
                .contains("AddressSanitizer: heap-buffer-overflow"),
        "ASan did not catch the control overflow"
    );

    let exe = compile(
        "tests/c/test_capi.c",
        Link::Shared,
        asan_flags(),
        &out,
        "test_capi_asan",
    );
    assert_asan_linked(&exe);
    let env = [(
        "ASAN_OPTIONS",
        "detect_leaks=1:abort_on_error=0:verbosity=1",
    )];
    let stderr = run_test(&[], &exe, &env, "C tests (AddressSanitizer)");
    // verbosity=1 makes the ASan runtime announce itself at start-up.
    assert!(
        stderr.contains("AddressSanitizer") || stderr.contains("==ASAN"),
        "the ASan runtime did not announce itself:\n{stderr}"
    );
    for name in MORE_C_TESTS {
        let exe = compile(
            &format!("tests/c/{name}.c"),
            Link::Shared,
            asan_flags(),
            &out,
            &format!("{name}_asan"),
        );
        assert_asan_linked(&exe);
        run_test(&[], &exe, &env, &format!("{name} (AddressSanitizer)"));
    }
    if Path::new(&root().join("tests/c/test_cpp.cpp")).exists() {
        let cpp = compile(
            "tests/c/test_cpp.cpp",
            Link::Shared,
            asan_flags(),
            &out,
            "test_cpp_asan",
        );
        assert_asan_linked(&cpp);
        run_test(&[], &cpp, &env, "C++ wrapper tests (AddressSanitizer)");
    }
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn cpp_wrapper_tests_pass() {
    if !root().join("tests/c/test_cpp.cpp").exists() {
        return;
    }
    let out = scratch("build-cpp");
    let exe = compile("tests/c/test_cpp.cpp", Link::Static, &[], &out, "test_cpp");
    run_test(&[], &exe, &[], "C++ wrapper tests (static library)");
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn c_tests_pass_under_valgrind() {
    let have = Command::new("valgrind").arg("--version").output().is_ok();
    if !have {
        assert!(
            std::env::var_os("LACUNA_REQUIRE_VALGRIND").is_none(),
            "valgrind is required (LACUNA_REQUIRE_VALGRIND) but not installed"
        );
        eprintln!("valgrind is not installed: skipping (.ci/run installs it)");
        return;
    }
    let out = scratch("build-valgrind");
    let supp = format!(
        "--suppressions={}",
        root().join("tests/c/valgrind.supp").display()
    );
    let prefix = [
        "valgrind",
        "--error-exitcode=1",
        "--leak-check=full",
        supp.as_str(),
        "--quiet",
        // Valgrind runs one thread at a time; without fair scheduling, spinning rayon workers
        // can starve the test's cancelling thread for the whole 60 s budget (seen here).
        "--fair-sched=yes",
    ];
    // Control: a host that forgets to release a context must fail under these options.
    let leak = out.join("leak.c");
    std::fs::write(
        &leak,
        "#include \"lacuna.h\"\nint main(int argc, char **argv) { lacuna_context *c = 0; (void)argc; (void)argv;\n\
         return lacuna_context_new(&c) == LACUNA_STATUS_OK ? 0 : 2; }\n",
    )
    .unwrap();
    let leak_exe = out.join("leak");
    let lib = staged_shared_lib(&out);
    check(
        Command::new("cc")
            .arg("-I")
            .arg(root().join("include"))
            .arg(&leak)
            .arg("-o")
            .arg(&leak_exe)
            .arg(format!("-L{}", lib.display()))
            .arg("-llacuna")
            .arg(format!("-Wl,-rpath,{}", lib.display())),
        "compiling the valgrind control",
    );
    let r = run(Command::new(prefix[0]).args(&prefix[1..]).arg(&leak_exe));
    assert!(
        r.status.code() == Some(1)
            && String::from_utf8_lossy(&r.stderr).contains("definitely lost"),
        "valgrind did not report the control leak:\n{}",
        String::from_utf8_lossy(&r.stderr)
    );
    let exe = compile(
        "tests/c/test_capi.c",
        Link::Shared,
        &[],
        &out,
        "test_capi_vg",
    );
    run_test(&prefix, &exe, &[], "C tests (valgrind)");
    for name in MORE_C_TESTS {
        let exe = compile(
            &format!("tests/c/{name}.c"),
            Link::Shared,
            &[],
            &out,
            &format!("{name}_vg"),
        );
        run_test(&prefix, &exe, &[], &format!("{name} (valgrind)"));
    }
    if root().join("tests/c/test_cpp.cpp").exists() {
        let cpp = compile(
            "tests/c/test_cpp.cpp",
            Link::Shared,
            &[],
            &out,
            "test_cpp_vg",
        );
        run_test(&prefix, &cpp, &[], "C++ wrapper tests (valgrind)");
    }
    let _ = std::fs::remove_dir_all(&out);
}

/// Reads a little-endian PFM (as examples/c/host_pathtracer.c writes it) into rows from the top.
fn read_pfm(path: &Path) -> (usize, usize, Vec<[f32; 3]>) {
    let bytes = std::fs::read(path).unwrap();
    let mut fields = Vec::new();
    let mut start = 0;
    let mut pos = 0;
    while fields.len() < 4 {
        if bytes[pos].is_ascii_whitespace() {
            if pos > start {
                fields.push(String::from_utf8_lossy(&bytes[start..pos]).into_owned());
            }
            start = pos + 1;
        }
        pos += 1;
    }
    assert_eq!(fields[0], "PF", "{}: not a colour PFM", path.display());
    let (w, h): (usize, usize) = (fields[1].parse().unwrap(), fields[2].parse().unwrap());
    assert!(fields[3].starts_with('-'), "PFM must be little-endian");
    let data = &bytes[pos..];
    assert_eq!(data.len(), w * h * 12, "{}: wrong size", path.display());
    let mut pixels = vec![[0.0f32; 3]; w * h];
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                let i = ((h - 1 - y) * w + x) * 12 + c * 4;
                pixels[y * w + x][c] = f32::from_le_bytes(data[i..i + 4].try_into().unwrap());
            }
        }
    }
    (w, h, pixels)
}

/// Region means (image and quadrants) with standard errors over `seeds` runs of the host path
/// tracer, as `common::agreement::region_means` computes them for Lacuna's integrators.
fn host_region_means(
    exe: &Path,
    dir: &Path,
    scene: &str,
    size: u32,
    spp: u32,
    max_depth: u32,
    seeds: u64,
) -> Vec<(f64, f64)> {
    let runs: Vec<[f64; 5]> = (0..seeds)
        .map(|seed| {
            let out = dir.join(format!("host-{seed}.pfm"));
            check(
                Command::new(exe)
                    .arg(scene)
                    .arg(&out)
                    .args([size, size, spp].map(|v| v.to_string()))
                    .arg((seed * 7919 + 1).to_string())
                    .arg(max_depth.to_string())
                    .arg("2"),
                "host_pathtracer",
            );
            let (w, h, px) = read_pfm(&out);
            assert_eq!((w, h), (size as usize, size as usize));
            let mut sums = [0.0f64; 5];
            let half = size as usize / 2;
            for y in 0..h {
                for x in 0..w {
                    let p = px[y * w + x];
                    assert!(
                        p.iter().all(|v| v.is_finite() && *v >= 0.0),
                        "host pixel {p:?}"
                    );
                    let v = (p[0] + p[1] + p[2]) as f64 / 3.0;
                    sums[0] += v;
                    sums[1 + y / half * 2 + x / half] += v;
                }
            }
            let n = (w * h) as f64;
            [
                sums[0] / n,
                sums[1] * 4.0 / n,
                sums[2] * 4.0 / n,
                sums[3] * 4.0 / n,
                sums[4] * 4.0 / n,
            ]
        })
        .collect();
    (0..5)
        .map(|k| {
            let n = runs.len() as f64;
            let mean = runs.iter().map(|r| r[k]).sum::<f64>() / n;
            let var = runs.iter().map(|r| (r[k] - mean).powi(2)).sum::<f64>() / (n - 1.0);
            (mean, (var / n).sqrt())
        })
        .collect()
}

/// examples/c/host_pathtracer.c (materials shaded by the host, light sampling and MIS
/// densities from `lacuna_light_sampler`) estimates the same image as Lacuna's `path`
/// integrator (`lacuna render --integrator path`): z-tests of the image and quadrant means over
/// 8 seeds each, on the Cornell box and the built-in two-room scene.
#[test]
fn host_path_tracer_agrees_with_lacuna_render() {
    use lacuna::integrator::IntegratorSettings;
    let out = scratch("host-pathtracer");
    let exe = compile(
        "examples/c/host_pathtracer.c",
        Link::Shared,
        &["-O2"],
        &out,
        "host_pathtracer",
    );
    let cornell = root().join("scenes/cornell-box/cornell-box.json");
    let cases: [(&str, lacuna::scene::Scene, u32, u32, u32); 2] = [
        (
            cornell.to_str().unwrap(),
            common::agreement::load_scene("scenes/cornell-box/cornell-box.json"),
            24,
            16,
            8,
        ),
        (
            "two-rooms",
            lacuna::scene::two_rooms_builder().unwrap().build().unwrap(),
            20,
            16,
            6,
        ),
    ];
    for (name, scene, size, spp, max_depth) in &cases {
        let camera = *scene.camera().unwrap();
        let settings = IntegratorSettings {
            max_depth: *max_depth,
            ..Default::default()
        };
        let lacuna =
            common::agreement::region_means(scene, &camera, "path", settings, *size, *spp, 8);
        let host = host_region_means(&exe, &out, name, *size, *spp, *max_depth, 8);
        println!("{name}: lacuna {lacuna:?}\n  host {host:?}");
        assert!(host[0].0 > 0.0, "{name}: black host image");
        common::agreement::assert_agree(name, ("lacuna path", &lacuna), ("host", &host));
    }
    let _ = std::fs::remove_dir_all(&out);
}
