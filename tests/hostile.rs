//! Hostile input (issue 29): every case of the issue's table and its "also" list, as a named
//! test. Each refusal must be an error (never an abort, a hang or a huge allocation) whose
//! message names the file, the line or field, and the limit.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("lacuna-hostile-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }

    fn write(&self, name: impl AsRef<Path>, content: &[u8]) -> PathBuf {
        let path = self.0.join(name);
        std::fs::write(&path, content).unwrap();
        path
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn lacuna(dir: &TempDir, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lacuna"))
        .current_dir(&dir.0)
        .args(args)
        .output()
        .unwrap()
}

/// Runs the command, expects failure (exit code 1, no signal) and every `needles` in stderr.
fn refused(dir: &TempDir, args: &[&str], needles: &[&str]) {
    let out = lacuna(dir, args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
    for n in needles {
        assert!(stderr.contains(n), "{args:?}: '{n}' missing in: {stderr}");
    }
}

const TRIANGLE: &[u8] = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
const QUICK: &[&str] = &["--quiet", "--spp", "1", "--width", "8", "--height", "8"];

fn with_quick<'a>(args: &[&'a str]) -> Vec<&'a str> {
    let mut v = args.to_vec();
    v.extend_from_slice(QUICK);
    v
}

/// An OpenEXR header (no pixel data) whose data window claims `width` x `height`.
fn exr_header(width: i32, height: i32) -> Vec<u8> {
    fn attr(out: &mut Vec<u8>, name: &str, kind: &str, data: &[u8]) {
        out.extend_from_slice(name.as_bytes());
        out.push(0);
        out.extend_from_slice(kind.as_bytes());
        out.push(0);
        out.extend_from_slice(&(data.len() as i32).to_le_bytes());
        out.extend_from_slice(data);
    }
    let mut channels = Vec::new();
    for c in ["B", "G", "R"] {
        channels.extend_from_slice(c.as_bytes());
        channels.push(0);
        channels.extend_from_slice(&2i32.to_le_bytes()); // FLOAT
        channels.extend_from_slice(&[0; 4]);
        channels.extend_from_slice(&1i32.to_le_bytes());
        channels.extend_from_slice(&1i32.to_le_bytes());
    }
    channels.push(0);
    let window: Vec<u8> = [0, 0, width - 1, height - 1]
        .iter()
        .flat_map(|v: &i32| v.to_le_bytes())
        .collect();
    let mut h = vec![0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0];
    attr(&mut h, "channels", "chlist", &channels);
    attr(&mut h, "compression", "compression", &[0]);
    attr(&mut h, "dataWindow", "box2i", &window);
    attr(&mut h, "displayWindow", "box2i", &window);
    attr(&mut h, "lineOrder", "lineOrder", &[0]);
    attr(&mut h, "pixelAspectRatio", "float", &1f32.to_le_bytes());
    attr(&mut h, "screenWindowCenter", "v2f", &[0; 8]);
    attr(&mut h, "screenWindowWidth", "float", &1f32.to_le_bytes());
    h.push(0);
    h
}

// ---- The issue's table (#1, the BVH build of duplicate triangles, is in geometry/). ----

/// #2: a header claiming 2,000,000 x 1,000,000 aborted on an 8 TB allocation.
#[test]
fn t02_exr_header_claiming_terapixels_is_refused_before_reading() {
    let dir = TempDir::new("exr");
    dir.write("huge.exr", &exr_header(2_000_000, 1_000_000));
    refused(
        &dir,
        &with_quick(&["render", "--env", "huge.exr", "-o", "x.png"]),
        &["huge.exr", "2000000x1000000", "268435456"],
    );
    // Under the texel limit but over a small budget: refused by the budget, from the header.
    dir.write("big.exr", &exr_header(16384, 8192));
    let e = lacuna::light::environment::EnvImage::load_within(&dir.0.join("big.exr"), 1 << 30)
        .unwrap_err();
    assert!(
        matches!(e, lacuna::Error::OverBudget { .. }) && e.to_string().contains("big.exr"),
        "{e}"
    );
    // The same file through the C API: an error status, not an abort.
    let path = std::ffi::CString::new(dir.0.join("huge.exr").to_str().unwrap()).unwrap();
    let mut env = std::ptr::null_mut();
    let status = unsafe { lacuna::capi::lacuna_environment_new_from_file(path.as_ptr(), &mut env) };
    assert_eq!(status, lacuna::capi::lacuna_status::Parse);
    assert!(env.is_null());
}

/// A small tiled EXR whose tile description claims tiles of gigabytes (found by the fuzzer,
/// `fuzz/known/environment-huge-tile-1`, after its first byte that picks `.exr`): the reader
/// sizes each block by the tile, so the tile counts against the budget, from the header.
#[test]
fn exr_header_claiming_huge_tiles_is_refused_before_reading() {
    let dir = TempDir::new("exr-tile");
    let input = include_bytes!("../fuzz/known/environment-huge-tile-1");
    dir.write("tile.exr", &input[1..]);
    let e = lacuna::light::environment::EnvImage::load_within(&dir.0.join("tile.exr"), 256 << 20)
        .unwrap_err();
    assert!(
        matches!(e, lacuna::Error::OverBudget { .. }) && e.to_string().contains("tile.exr"),
        "{e}"
    );
}

/// A Radiance header claiming gigapixels is refused the same way.
#[test]
fn t02_hdr_header_claiming_gigapixels_is_refused_before_reading() {
    let dir = TempDir::new("hdr");
    dir.write(
        "huge.hdr",
        b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1000000 +X 2000000\n",
    );
    refused(
        &dir,
        &with_quick(&["render", "--env", "huge.hdr", "-o", "x.png"]),
        &["huge.hdr", "2000000x1000000", "268435456"],
    );
}

/// #3: a 65536 x 65536 film (inside the size range) aborted on 103 GB in the CLI.
#[test]
fn t03_film_over_the_memory_budget_is_refused_by_the_cli_as_by_the_c_api() {
    let dir = TempDir::new("film");
    dir.write("t.obj", TRIANGLE);
    dir.write(
        "big.json",
        br#"{"objects": [{"obj": "t.obj"}], "render": {"width": 65536, "height": 65536}}"#,
    );
    refused(
        &dir,
        &["render", "big.json", "--quiet", "-o", "x.png"],
        &["65536x65536 film", "memory budget of 8589934592 bytes"],
    );
    refused(
        &dir,
        &with_quick(&["render", "t.obj", "--memory-budget-mib", "0", "-o", "x.png"]),
        &["--memory-budget-mib", "0 bytes"],
    );
}

/// #4: `--light-paths 4000000000` was accepted (the C API caps at 2^28).
#[test]
fn t04_light_paths_over_the_limit_are_refused() {
    let dir = TempDir::new("lp");
    refused(
        &dir,
        &with_quick(&[
            "render",
            "--integrator",
            "bdpt",
            "--light-paths",
            "4000000000",
            "-o",
            "x.png",
        ]),
        &["--light-paths 4000000000", "268435456"],
    );
}

/// #5: a memory budget above physical memory aborted instead of failing.
#[test]
fn t05_memory_budget_above_physical_memory_is_refused() {
    let dir = TempDir::new("budget");
    refused(
        &dir,
        &["analyze", "--memory-budget-mib", "1000000000", "-o", "out"],
        &["--memory-budget-mib", "physical memory"],
    );
    refused(
        &dir,
        &with_quick(&["render", "--memory-budget-mib", "1000000000", "-o", "x.png"]),
        &["--memory-budget-mib", "physical memory"],
    );
}

/// #6: an OBJ whose name is not UTF-8 rendered, then failed writing its name into the EXR.
#[cfg(unix)]
#[test]
fn t06_non_utf8_obj_name_renders_to_exr() {
    use std::os::unix::ffi::OsStrExt;
    let dir = TempDir::new("name");
    let name = std::ffi::OsStr::from_bytes(b"tri\xff\xfe.obj");
    dir.write(name, TRIANGLE);
    let out = Command::new(env!("CARGO_BIN_EXE_lacuna"))
        .current_dir(&dir.0)
        .arg("render")
        .arg(name)
        .args(with_quick(&["-o", "x.exr"]))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(dir.0.join("x.exr").is_file());
}

/// #7: `--exposure nan` gave exit 0 and a black PNG.
#[test]
fn t07_nan_exposure_is_refused() {
    let dir = TempDir::new("exposure");
    refused(
        &dir,
        &with_quick(&["render", "--exposure", "nan", "-o", "x.png"]),
        &["--exposure NaN", "finite"],
    );
}

/// #8: `mtllib` naming an existing MTL file whose name is not UTF-8: "No such file".
#[cfg(unix)]
#[test]
fn t08_non_utf8_mtllib_name_is_found() {
    use std::os::unix::ffi::OsStrExt;
    let dir = TempDir::new("mtl");
    dir.write(
        std::ffi::OsStr::from_bytes(b"m\xe9.mtl"),
        b"newmtl red\nKd 0.8 0.1 0.1\n",
    );
    let mut obj = b"mtllib m\xe9.mtl\nusemtl red\n".to_vec();
    obj.extend_from_slice(TRIANGLE);
    let path = dir.write("t.obj", &obj);
    let mut builder = lacuna::scene::SceneBuilder::new();
    let report = lacuna::scene::load_obj(&path, &mut builder, None).unwrap();
    assert!(
        report.warnings.iter().all(|w| !w.contains("not read")),
        "{:?}",
        report.warnings
    );
    assert_eq!(report.materials.len(), 1, "{:?}", report.warnings);
}

/// #9: a transform of scale 1e30 was called "singular".
#[test]
fn t09_huge_scale_is_called_too_large() {
    let dir = TempDir::new("scale");
    dir.write("t.obj", TRIANGLE);
    dir.write(
        "s.json",
        br#"{"objects": [{"obj": "t.obj", "transform": {"scale": 1e30}}]}"#,
    );
    refused(
        &dir,
        &with_quick(&["render", "s.json", "-o", "x.png"]),
        &[
            "s.json",
            "objects[0].transform",
            "1e30",
            "over the limit of 1e12",
        ],
    );
    dir.write(
        "z.json",
        br#"{"objects": [{"obj": "t.obj", "transform": {"scale": [1, 0, 1]}}]}"#,
    );
    refused(
        &dir,
        &with_quick(&["render", "z.json", "-o", "x.png"]),
        &["objects[0].transform", "singular"],
    );
}

/// #10: `compare --out` naming an existing file failed only after the whole budget.
#[test]
fn t10_compare_out_naming_a_file_is_refused_up_front() {
    let dir = TempDir::new("compare");
    dir.write("taken", b"");
    let start = std::time::Instant::now();
    refused(
        &dir,
        &[
            "compare",
            "--time",
            "600",
            "--reference",
            "missing.exr",
            "-o",
            "taken",
        ],
        &["--out taken", "not a directory"],
    );
    assert!(start.elapsed().as_secs() < 60);
}

/// #11: `"obj": "/dev/zero"` read until memory ran out.
#[cfg(unix)]
#[test]
fn t11_device_as_obj_is_refused_without_reading() {
    let dir = TempDir::new("zero");
    dir.write("z.json", br#"{"objects": [{"obj": "/dev/zero"}]}"#);
    refused(
        &dir,
        &with_quick(&["render", "z.json", "-o", "x.png"]),
        &["/dev/zero", "regular file"],
    );
    refused(
        &dir,
        &with_quick(&["render", "/dev/zero", "-o", "x.png"]),
        &["/dev/zero"],
    );
}

// ---- Garbage accepted. ----

#[test]
fn random_bytes_as_obj_are_refused() {
    let dir = TempDir::new("random");
    let mut rng = 0x2545_f491_4f6c_dd1du64;
    let bytes: Vec<u8> = (0..4096)
        .map(|_| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng as u8
        })
        .collect();
    dir.write("r.obj", &bytes);
    refused(
        &dir,
        &with_quick(&["render", "r.obj", "-o", "x.png"]),
        &["r.obj:line", "binary data", "not an OBJ file"],
    );
}

#[test]
fn png_renamed_obj_is_refused() {
    let dir = TempDir::new("png");
    let png = dir.0.join("p.png");
    image::RgbImage::from_pixel(4, 4, image::Rgb([200, 10, 10]))
        .save(&png)
        .unwrap();
    std::fs::rename(&png, dir.0.join("p.obj")).unwrap();
    refused(
        &dir,
        &with_quick(&["render", "p.obj", "-o", "x.png"]),
        &["p.obj:line 3", "not an OBJ file"],
    );
}

#[test]
fn text_without_geometry_is_refused_unless_asked_for() {
    let dir = TempDir::new("empty");
    dir.write("e.json", b"{}");
    dir.write("words.obj", b"hello world\nthis is not a mesh\n");
    refused(
        &dir,
        &with_quick(&["render", "e.json", "-o", "x.png"]),
        &["e.json is empty", "--allow-empty"],
    );
    refused(
        &dir,
        &with_quick(&["render", "words.obj", "-o", "x.png"]),
        &["words.obj is empty"],
    );
    let out = lacuna(
        &dir,
        &with_quick(&["render", "e.json", "--allow-empty", "-o", "x.png"]),
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

// ---- Limits shared with the C API. ----

#[test]
fn cli_limits_are_the_c_api_limits() {
    use lacuna::limits;
    assert_eq!(limits::MAX_THREADS, lacuna::capi::LACUNA_MAX_THREADS);
    assert_eq!(limits::MAX_DEPTH, lacuna::capi::LACUNA_MAX_DEPTH_LIMIT);
    assert_eq!(
        limits::MAX_LIGHT_PATHS,
        lacuna::capi::LACUNA_MAX_LIGHT_PATHS
    );
    assert_eq!(
        limits::DEFAULT_MEMORY_BUDGET,
        lacuna::capi::LACUNA_DEFAULT_MEMORY_BUDGET
    );
    let dir = TempDir::new("limits");
    let start = std::time::Instant::now();
    refused(
        &dir,
        &with_quick(&["render", "--threads", "100000", "-o", "x.png"]),
        &["--threads 100000", "4096"],
    );
    assert!(
        start.elapsed().as_secs() < 10,
        "refused only after starting threads"
    );
    refused(
        &dir,
        &with_quick(&["render", "--max-depth", "4294967295", "-o", "x.png"]),
        &["--max-depth 4294967295", "1024"],
    );
    refused(
        &dir,
        &with_quick(&[
            "render",
            "--integrator",
            "path:max_depth=5000",
            "-o",
            "x.png",
        ]),
        &["max_depth", "5000", "1024"],
    );
    dir.write("t.obj", TRIANGLE);
    dir.write(
        "d.json",
        br#"{"objects": [{"obj": "t.obj"}], "render": {"max_depth": 100000}}"#,
    );
    refused(
        &dir,
        &with_quick(&["render", "d.json", "-o", "x.png"]),
        &["render.max_depth 100000", "1024"],
    );
}

// ---- Messages. ----

#[test]
fn byte_order_mark_is_accepted() {
    let dir = TempDir::new("bom");
    dir.write("t.obj", b"\xef\xbb\xbfv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    dir.write(
        "s.json",
        b"\xef\xbb\xbf{\"objects\": [{\"obj\": \"t.obj\"}]}",
    );
    let out = lacuna(&dir, &with_quick(&["render", "s.json", "-o", "x.png"]));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    dir.write("bad.json", b"{\"objects\": [\xff]}");
    refused(
        &dir,
        &with_quick(&["render", "bad.json", "-o", "x.png"]),
        &["bad.json:line 1", "not UTF-8"],
    );
}

#[test]
fn zero_up_vector_is_called_zero() {
    let dir = TempDir::new("up");
    refused(
        &dir,
        &with_quick(&["render", "--up", "0,0,0", "-o", "x.png"]),
        &["camera up [0, 0, 0] is the zero vector"],
    );
}

#[test]
fn counts_are_plural_in_english() {
    let dir = TempDir::new("plural");
    dir.write("f.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n");
    refused(
        &dir,
        &with_quick(&["render", "f.obj", "-o", "x.png"]),
        &["f.obj:line 4", "the file has 3 vertices"],
    );
}

#[test]
fn oversized_scene_file_is_refused_by_size() {
    let dir = TempDir::new("bigscene");
    let path = dir.0.join("big.json");
    let file = std::fs::File::create(&path).unwrap();
    file.set_len(lacuna::limits::MAX_SCENE_FILE_BYTES + 1)
        .unwrap();
    refused(
        &dir,
        &with_quick(&["render", "big.json", "-o", "x.png"]),
        &["big.json", "limit of 67108864 bytes"],
    );
}

// ---- C API misuse. ----

#[test]
fn building_a_builder_twice_is_an_error() {
    use lacuna::capi::*;
    unsafe {
        let mut ctx = std::ptr::null_mut();
        assert_eq!(lacuna_context_new(&mut ctx), lacuna_status::Ok);
        let mut builder = std::ptr::null_mut();
        assert_eq!(
            lacuna_scene_builder_new(ctx, &mut builder),
            lacuna_status::Ok
        );
        let mut scene = std::ptr::null_mut();
        assert_eq!(
            lacuna_scene_builder_build(builder, &mut scene),
            lacuna_status::Ok
        );
        let mut again = std::ptr::null_mut();
        assert_eq!(
            lacuna_scene_builder_build(builder, &mut again),
            lacuna_status::InvalidOperation
        );
        assert!(again.is_null());
        let message = std::ffi::CStr::from_ptr(lacuna_last_error_message()).to_string_lossy();
        assert!(message.contains("already built or freed"), "{message}");
        assert_eq!(
            lacuna_scene_builder_set_degenerate_policy(builder, 0),
            lacuna_status::InvalidOperation
        );
        lacuna_scene_builder_free(builder); // already consumed: refused, not freed twice
        lacuna_scene_release(scene);
        lacuna_context_release(ctx);
    }
}

/// A few short lines asking for spheres of millions of triangles each: refused by count
/// before any is built.
#[test]
fn shapes_making_too_many_triangles_are_refused() {
    let dir = TempDir::new("shapes");
    let sphere = r#"{"type": "sphere", "center": [0, 0, 0], "radius": 1, "segments": 2048}"#;
    let file = format!(r#"{{"shapes": [{}]}}"#, [sphere; 5].join(", "));
    dir.write("s.json", file.as_bytes());
    refused(
        &dir,
        &with_quick(&["render", "s.json", "-o", "x.png"]),
        &["s.json:shapes[4]", "over the limit of 16777216"],
    );
}
