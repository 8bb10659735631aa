//! The skeleton guide's training sees the camera the render uses, however it was given: the
//! scene file's, one given apart from the scene (command-line flags, a C API job's camera,
//! `render::prepare`'s argument), or the automatic framing. A training silently skipped (the
//! guide falling back to its fixed c everywhere) fails these tests.

use std::path::{Path, PathBuf};

use lacuna::integrator::{self, IntegratorSettings, PathTracer};
use lacuna::render::prepare;
use lacuna::scene::{auto_camera, load_scene_arg, Camera, FamilyScene, Scene};

/// A small training so each route costs well under a second.
const SPEC: &str = "path_skeleton:training_paths=4096";

fn family_files(seed: u64, test: &str) -> (FamilyScene, PathBuf) {
    let family = FamilyScene::generate(seed);
    let dir =
        std::env::temp_dir().join(format!("lacuna-guide-camera-{test}-{}", std::process::id()));
    let json = family.write_files(&dir).unwrap();
    (family, json)
}

/// The training ran: all of `SPEC`'s 4096 paths, or the scout's eighth of them where the
/// scout found nothing to guide (`guide::training`, "The scout").
fn reached_training(paths: u32) -> bool {
    paths == 4096 || paths == 4096 / 8
}

/// Prepares `path_skeleton` for `camera` and returns (training paths, nodes the training
/// reached).
fn trained(scene: &Scene, camera: &Camera) -> (u32, Vec<u32>) {
    let (_, settings) = integrator::parse_spec(SPEC, IntegratorSettings::default()).unwrap();
    let mut pt = PathTracer::skeleton_guided(settings).unwrap();
    prepare(&mut pt, scene, camera, Some(2), &|_, _| true).unwrap();
    let t = pt
        .guide()
        .unwrap()
        .training()
        .expect("a guide with learned c has a training report");
    (t.paths, t.samples.clone())
}

#[test]
fn a_camera_given_apart_from_the_scene_reaches_the_training() {
    // rooms:33: two rooms, one door, the light in the room the camera does not see into.
    let (family, json) = family_files(33, "apart");
    let obj = json.with_extension("obj");
    let (loaded, _) = load_scene_arg(&obj).unwrap();
    let scene = loaded.builder.build().unwrap();
    assert!(scene.camera().is_none(), "an OBJ has no camera");
    let (paths, samples) = trained(&scene, &family.camera);
    assert!(reached_training(paths), "{paths} training paths");
    assert!(samples.iter().any(|&n| n > 0), "no node reached");

    // The view trained from is the one given, not some other: a camera in the other room
    // reaches other nodes.
    let (x0, x1, z0, z1) = family.room_extent(1 - family.camera_room);
    let centre = lacuna::math::Vec3::new((x0 + x1) / 2.0, 1.5, (z0 + z1) / 2.0);
    let other = Camera::look_at(
        centre,
        centre + lacuna::math::Vec3::X,
        lacuna::math::Vec3::Y,
        60.0,
    )
    .unwrap();
    let (_, elsewhere) = trained(&scene, &other);
    assert_ne!(samples, elsewhere);
}

#[test]
fn the_scene_files_camera_and_the_automatic_framing_reach_the_training() {
    let (family, json) = family_files(33, "file");
    let (loaded, _) = load_scene_arg(&json).unwrap();
    let scene = loaded.builder.build().unwrap();
    let camera = *scene.camera().expect("the scene file's camera");
    assert_eq!(camera.eye, family.camera.eye);
    let (paths, samples) = trained(&scene, &camera);
    assert!(reached_training(paths), "{paths} training paths");
    assert!(samples.iter().any(|&n| n > 0));

    // Automatic framing, on a roofless scene so the view from outside sees in.
    let seed = (0..64)
        .find(|&s| FamilyScene::generate(s).openness == lacuna::scene::Openness::Roofless)
        .unwrap();
    let (_, json) = family_files(seed, "auto");
    let (loaded, _) = load_scene_arg(&json.with_extension("obj")).unwrap();
    let scene = loaded.builder.build().unwrap();
    let camera = auto_camera(scene.bounds(), 4.0 / 3.0);
    let (paths, samples) = trained(&scene, &camera);
    assert!(reached_training(paths), "{paths} training paths");
    assert!(samples.iter().any(|&n| n > 0));
}

/// The command line: an OBJ (no camera of its own) with `--eye --target --up --fov`, as the
/// issue's user ran it; the precomputation's note says how many nodes the training reached.
#[test]
fn command_line_camera_flags_reach_the_training() {
    let (family, json) = family_files(33, "cli");
    let obj = json.with_extension("obj");
    let c = family.camera;
    let v = |p: lacuna::math::Vec3| format!("{},{},{}", p.x, p.y, p.z);
    let out_file = obj.with_file_name("cli.exr");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_lacuna"))
        .arg("render")
        .arg(&obj)
        .args([
            "--eye",
            &v(c.eye),
            "--target",
            &v(c.target),
            "--up",
            "0,1,0",
        ])
        .args(["--fov", &c.vfov_degrees.to_string()])
        .args([
            "--width",
            "16",
            "--height",
            "12",
            "--spp",
            "1",
            "--threads",
            "2",
        ])
        .args(["--integrator", SPEC, "--quiet", "--out"])
        .arg(&out_file)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let note = stdout
        .lines()
        .find(|l| l.contains("training paths"))
        .unwrap_or_else(|| panic!("no training note in {stdout}"));
    assert!(
        note.contains("reached by 4096 training paths")
            || note.contains("reached by 512 training paths"),
        "{note}"
    );
    assert!(!note.contains("(0 reached"), "{note}");
    assert!(Path::new(&out_file).exists());
}

/// `lacuna render --time` hands its budget to the integrator as `lacuna compare` does: on the
/// corridor, where the full training runs without a budget, a 0.2 s budget stops
/// `path_skeleton` before the analysis (`guide::budget`: the whole precomputation, about a
/// second here, cannot fit in its share), and the summary says so.
#[test]
fn a_time_budget_on_the_command_line_reaches_the_guide() {
    // Without the pilot on the scout's guide, which may stop the training first.
    let spec = "path_skeleton:training_paths=65536:scout_pilot=off";
    let dir = std::env::temp_dir().join(format!("lacuna-guide-budget-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let summary = |budget: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_lacuna"))
            .args(["render", "corridor", "--integrator", spec, "--quiet"])
            .args(["--width", "16", "--height", "12", "--threads", "2"])
            .args(budget)
            .arg("--out")
            .arg(dir.join("budget.exr"))
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let unbudgeted = summary(&["--spp", "1"]);
    assert!(
        unbudgeted.contains("by 65536 training paths"),
        "{unbudgeted}"
    );
    let budgeted = summary(&["--time", "0.2"]);
    assert!(
        budgeted.contains("over the time budget")
            && budgeted.contains("from the analysis on")
            && !budgeted.contains("analysis (voxels, maps)")
            && !budgeted.contains("training paths"),
        "{budgeted}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
