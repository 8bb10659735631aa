//! `lacuna capture-luminaire`: a captured emissive quad is the light field `LightField::bake`
//! projects from its radiance; the shipped mirror downlight rendered as its captured light
//! field matches the render of its geometry under `path`, in the far field and in the near
//! field (the differences printed); bad luminaire files get clear errors; the command writes
//! a field the light reads and prints its time and memory.

mod common;

use std::path::{Path, PathBuf};

use common::agreement::region_means;
use lacuna::integrator::IntegratorSettings;
use lacuna::light::{FilterBasis, LightFieldLayout};
use lacuna::math::{Vec2, Vec3};
use lacuna::render::capture::{capture, load_luminaire, CaptureSettings};
use lacuna::scene::{Camera, Scene};

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lacuna-capture-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn scenes() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/luminaires")
}

/// A luminaire file: `shapes` (JSON) and a capture block with `capture` (JSON fields).
fn luminaire_text(shapes: &str, capture: &str) -> String {
    format!(r#"{{ "shapes": [ {shapes} ], "capture": {{ {capture} }} }}"#)
}

const QUAD: &str = r#"{ "type": "quad", "corners": [[-0.2, 0, -0.2], [0.2, 0, -0.2], [0.2, 0, 0.2], [-0.2, 0, 0.2]],
    "normal": [0, -1, 0], "material": { "diffuse": 0, "emission": 4 } }"#;

const QUAD_CAPTURE: &str = r#""position": [0, 0, 0], "direction": [0, -1, 0], "x_axis": [1, 0, 0],
    "plane_distance": 0.5, "nodes": [9, 9], "node_min": [-0.3, -0.3], "node_spacing": [0.075, 0.075],
    "image_min": [-0.9, -0.9], "image_max": [0.9, 0.9], "resolution": [16, 16], "samples": 64"#;

#[test]
fn a_captured_emissive_quad_is_the_projection_of_its_radiance() {
    let dir = temp_dir("quad");
    let path = dir.join("quad.json");
    std::fs::write(&path, luminaire_text(QUAD, QUAD_CAPTURE)).unwrap();
    let luminaire = load_luminaire(&path).unwrap();
    let (captured, stats) = capture(&luminaire.scene, &luminaire.settings).unwrap();
    assert_eq!(stats.paths, 81 * 256 * 64);
    // The field's integrals by quadrature over both planes: G(u), the power leaving quad
    // point u through the image rectangle, on a grid of u; the power is the integral of G, and
    // image m's integral over the image plane is that of G Phi_m / (h_x h_y).
    let layout = luminaire.settings.layout.clone();
    let n = 48usize;
    let (du, ds) = (
        Vec2::splat(0.4 / n as f32),
        (layout.image_max - layout.image_min) / n as f32,
    );
    let delta = layout.plane_distance;
    let cell = |k: usize, corner: Vec2, size: Vec2| {
        corner + size * Vec2::new((k % n) as f32 + 0.5, (k / n) as f32 + 0.5)
    };
    let g: Vec<(Vec2, f64)> = (0..n * n)
        .map(|a| {
            let u = cell(a, Vec2::splat(-0.2), du);
            let mut e = 0f64;
            for b in 0..n * n {
                let s = cell(b, layout.image_min, ds);
                let d2 = (s - u).length_squared() + delta * delta;
                e += (4.0 * delta * delta / (d2 * d2)) as f64;
            }
            (u, e * (du.x * du.y * ds.x * ds.y) as f64)
        })
        .collect();
    let power: f64 = g.iter().map(|(_, e)| e).sum();
    let relative = captured.power() as f64 / power - 1.0;
    println!(
        "captured quad: power {:+.3} % against quadrature",
        relative * 100.0
    );
    assert!(relative.abs() < 0.01, "{} vs {power}", captured.power());
    // Per image (luminance = the value of a grey field), against the quadrature's.
    let h = layout.node_spacing;
    let pixel = (layout.image_max - layout.image_min)
        / Vec2::new(layout.resolution[0] as f32, layout.resolution[1] as f32);
    let per_image = layout.pixels_per_image();
    let integrals: Vec<(f64, f64)> = (0..layout.image_count() as u32)
        .map(|m| {
            let node = layout.node_point(m % layout.nodes[0], m / layout.nodes[0]);
            let expected: f64 = g
                .iter()
                .map(|&(u, e)| {
                    let t = (u - node) / h;
                    e * (layout.basis.eval(t.x) * layout.basis.eval(t.y)) as f64
                })
                .sum::<f64>()
                / (h.x * h.y) as f64;
            let got: f64 = captured.pixels()[m as usize * per_image..(m as usize + 1) * per_image]
                .iter()
                .map(|c| c.y as f64)
                .sum::<f64>()
                * (pixel.x * pixel.y) as f64;
            (got, expected)
        })
        .collect();
    // Images of basis functions that barely overlap the quad get few of their paths on it:
    // only those with a tenth of the largest integral are compared.
    let largest = integrals.iter().map(|&(_, e)| e).fold(0.0, f64::max);
    let mut worst = 0f64;
    for (m, &(got, expected)) in integrals.iter().enumerate() {
        if expected >= 0.1 * largest {
            worst = worst.max((got / expected - 1.0).abs());
            assert!(
                (got - expected).abs() <= 0.02 * expected,
                "image {m}: captured {got}, quadrature {expected}"
            );
        }
    }
    println!(
        "captured quad: worst image {:.2} % from quadrature",
        worst * 100.0
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// A luminaire of scenes/luminaires (`file`) over a grey floor `drop` metres below its
/// filter plane (all shipped luminaires light along -y from the origin): as its geometry (the
/// file's objects and shapes), or as the light field `field` at the same place. The camera
/// looks at the floor under the lamp from the side, the lamp out of view.
fn luminaire_over_floor(
    file: &str,
    field: Option<&Path>,
    drop: f32,
    eye: Vec3,
    fov: f32,
) -> (Scene, Camera) {
    use serde_json::{json, Value};
    let dir = temp_dir(&format!("{file}-{drop}-{}", field.is_some()));
    let floor = json!({ "type": "quad",
        "corners": [[-4, -drop, -4], [4, -drop, -4], [4, -drop, 4], [-4, -drop, 4]],
        "normal": [0, 1, 0], "material": { "diffuse": 0.3 } });
    let text = match field {
        None => {
            let text = std::fs::read_to_string(scenes().join(file)).unwrap();
            let mut lamp: Value = serde_json::from_str(&text).unwrap();
            let mut objects = lamp["objects"].as_array().cloned().unwrap_or_default();
            for o in &mut objects {
                let obj = scenes().join(o["obj"].as_str().unwrap());
                o["obj"] = json!(obj.to_str().unwrap());
            }
            let mut shapes = lamp["shapes"].as_array().cloned().unwrap_or_default();
            shapes.push(floor);
            let materials = lamp["materials"].take();
            let mut scene = json!({ "objects": objects, "shapes": shapes });
            if !materials.is_null() {
                scene["materials"] = materials;
            }
            scene
        }
        Some(f) => json!({ "shapes": [floor], "lights": [{ "type": "light_field",
            "file": f.to_str().unwrap(), "position": [0, 0, 0], "direction": [0, -1, 0],
            "x_axis": [1, 0, 0] }] }),
    }
    .to_string();
    let path = dir.join("scene.json");
    std::fs::write(&path, text).unwrap();
    let scene = lacuna::scene::load_scene_file(&path)
        .unwrap()
        .builder
        .build()
        .unwrap();
    std::fs::remove_dir_all(&dir).ok();
    let camera = Camera::look_at(eye, Vec3::new(0.0, -drop, 0.0), Vec3::Y, fov).unwrap();
    (scene, camera)
}

#[test]
fn the_captured_downlight_renders_as_its_geometry_far_and_near() {
    let luminaire = load_luminaire(&scenes().join("reflector_lamp.json")).unwrap();
    // Finer basis functions than the shipped file's 11 x 11 (their blur costs the far field
    // 2.5 to 5 % there), and fewer paths per texel, to stay fast.
    let settings = CaptureSettings {
        samples: 8,
        ..luminaire.settings.clone()
    }
    .with_nodes([16, 16]);
    let (field, _) = capture(&luminaire.scene, &settings).unwrap();
    let dir = temp_dir("downlight-field");
    let field_path = dir.join("downlight.exr");
    field.write(&field_path).unwrap();
    let integrator = IntegratorSettings {
        max_depth: 6,
        ..Default::default()
    };
    for (name, drop, eye, fov) in [
        ("far field", 2.0, Vec3::new(1.2, -0.6, 1.2), 40.0),
        ("near field", 0.35, Vec3::new(0.45, -0.22, 0.45), 50.0),
    ] {
        let lamp = "reflector_lamp.json";
        let (geometry, camera) = luminaire_over_floor(lamp, None, drop, eye, fov);
        let (baked, _) = luminaire_over_floor(lamp, Some(&field_path), drop, eye, fov);
        // bdpt's light tracing finds the mirror's beam, which path tracing from the floor
        // finds only by chance (tests/agreement*.rs check bdpt against path).
        let a = region_means(&geometry, &camera, "bdpt", integrator, 16, 64, 8);
        let b = region_means(&baked, &camera, "path", integrator, 16, 64, 8);
        assert!(a[0].0 > 0.0, "{name}: the floor is lit");
        for (k, ((ma, ea), (mb, eb))) in a.iter().zip(&b).enumerate() {
            let sigma = (ea * ea + eb * eb).sqrt();
            println!(
                "{name} region {k}: geometry {ma:.4} +- {ea:.4}, light field {mb:.4} +- {eb:.4}: {:+.1} % ({:.1} sigma)",
                (mb / ma - 1.0) * 100.0,
                (mb - ma).abs() / sigma
            );
            // The field's own error (its basis blurs the beam by the node and pixel sizes;
            // light the floor sends back onto the reflector's outside is missing) is given
            // BIAS of the geometry's value on top of the renders' measured noise.
            assert!(
                (ma - mb).abs() <= 4.5 * sigma + BIAS * ma,
                "{name} region {k}: geometry {ma} +- {ea}, light field {mb} +- {eb}"
            );
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// The frosted glass globe's shipped field (scenes/luminaires/glass_globe.exr: 13 x 13 basis
/// functions, 32 x 32 pixels, 64 paths) against its geometry under `bdpt`, far (2 m) and near
/// (0.4 m below its equator); the differences are printed for docs/light-field.md with
/// `cargo test --release --test luminaire_capture -- --nocapture glass_globe`. A stale field
/// (the luminaire file changed without a re-bake) fails here. In the far field every region
/// agrees within the noise and BIAS; in the near field the two lower regions (the floor
/// under the lamp) do, while the upper two see the floor at more than about 60 degrees from
/// the axis, through lines the field does not record (docs/light-field.md): there the field
/// may only be darker.
#[test]
fn the_glass_globes_field_against_its_geometry() {
    let field_path = scenes().join("glass_globe.exr");
    let integrator = IntegratorSettings {
        max_depth: 12,
        ..Default::default()
    };
    for (name, drop, eye, fov) in [
        ("far field", 2.0, Vec3::new(1.2, -0.6, 1.2), 40.0),
        ("near field", 0.4, Vec3::new(0.5, -0.25, 0.5), 50.0),
    ] {
        let lamp = "glass_globe.json";
        let (geometry, camera) = luminaire_over_floor(lamp, None, drop, eye, fov);
        let (baked, _) = luminaire_over_floor(lamp, Some(&field_path), drop, eye, fov);
        let a = region_means(&geometry, &camera, "bdpt", integrator, 16, 256, 8);
        let b = region_means(&baked, &camera, "path", integrator, 16, 64, 8);
        assert!(a[0].0 > 0.0, "{name}: the floor is lit");
        for (k, ((ma, ea), (mb, eb))) in a.iter().zip(&b).enumerate() {
            let sigma = (ea * ea + eb * eb).sqrt();
            println!(
                "globe {name} region {k}: geometry {ma:.4} +- {ea:.4}, light field {mb:.4} +- {eb:.4}: {:+.1} % ({:.1} sigma)",
                (mb / ma - 1.0) * 100.0,
                (mb - ma).abs() / sigma
            );
            let recorded = name == "far field" || k >= 3;
            let what =
                format!("globe {name} region {k}: geometry {ma} +- {ea}, light field {mb} +- {eb}");
            if recorded {
                assert!((ma - mb).abs() <= 4.5 * sigma + BIAS * ma, "{what}");
            } else {
                assert!(*mb <= ma + 4.5 * sigma, "{what}");
            }
        }
    }
}

/// The relative difference the light field may have from the geometry it was captured from,
/// beyond noise: the basis and pixels blur the beam (measured -1 to -2.5 % per region with 16
/// x 16 basis functions, -0.3 to -1.6 % with 21 x 21 and 48 x 48 pixels), and the light the
/// floor sends back into the reflector is missing.
const BIAS: f64 = 0.04;

/// The error of loading the luminaire file `text`, or of capturing it; true when loading
/// failed (its errors name the file).
fn capture_error(name: &str, text: &str) -> (String, bool) {
    let dir = temp_dir(name);
    let path = dir.join("luminaire.json");
    std::fs::write(&path, text).unwrap();
    let e = match load_luminaire(&path) {
        Ok(l) => (
            capture(&l.scene, &l.settings)
                .err()
                .unwrap_or_else(|| panic!("{name}: accepted"))
                .to_string(),
            false,
        ),
        Err(e) => (e.to_string(), true),
    };
    std::fs::remove_dir_all(&dir).ok();
    e
}

#[test]
fn bad_luminaire_files_get_clear_errors() {
    let cases: Vec<(&str, String, &[&str])> = vec![
        (
            "no capture block",
            r#"{ "shapes": [ QUAD ] }"#.replace("QUAD", QUAD),
            &["capture", "missing"],
        ),
        (
            "misspelt capture field",
            luminaire_text(QUAD, &QUAD_CAPTURE.replace("\"samples\"", "\"sample\"")),
            &["capture", "sample"],
        ),
        (
            "no emitter",
            luminaire_text(&QUAD.replace("\"emission\": 4", "\"emission\": 0"), QUAD_CAPTURE),
            &["no emitter"],
        ),
        (
            "point light",
            luminaire_text(QUAD, QUAD_CAPTURE).replace(
                "\"capture\"",
                r#""lights": [ { "type": "point", "position": [0, 0.1, 0], "intensity": 1 } ], "capture""#,
            ),
            &["emissive shapes"],
        ),
        (
            "geometry past the image plane",
            luminaire_text(QUAD, &QUAD_CAPTURE.replace("\"position\": [0, 0, 0]", "\"position\": [0, 0.6, 0]")),
            &["past the image plane"],
        ),
        (
            "zero nodes",
            luminaire_text(QUAD, &QUAD_CAPTURE.replace("\"nodes\": [9, 9]", "\"nodes\": [0, 9]")),
            &["capture", "nodes"],
        ),
        (
            "unknown basis",
            luminaire_text(QUAD, &format!("{QUAD_CAPTURE}, \"basis\": \"cubic\"")),
            &["capture", "cubic"],
        ),
        (
            "zero samples",
            luminaire_text(QUAD, &QUAD_CAPTURE.replace("\"samples\": 64", "\"samples\": 0")),
            &["capture", "samples"],
        ),
        (
            "zero direction",
            luminaire_text(QUAD, &QUAD_CAPTURE.replace("\"direction\": [0, -1, 0]", "\"direction\": [0, 0, 0]")),
            &["capture", "direction"],
        ),
        (
            "planes facing away",
            luminaire_text(QUAD, &QUAD_CAPTURE.replace("\"direction\": [0, -1, 0]", "\"direction\": [0, 1, 0]").replace("\"position\": [0, 0, 0]", "\"position\": [0, 0.01, 0]")),
            &["no light"],
        ),
        ("not JSON", "{ \"shapes\": [ ".to_string(), &["line"]),
    ];
    for (name, text, needles) in cases {
        let (e, loading) = capture_error(&name.replace(' ', "-"), &text);
        println!("{name}: {e}");
        for needle in needles {
            assert!(e.contains(needle), "{name}: '{e}' lacks '{needle}'");
        }
        assert!(
            !loading || e.contains("luminaire.json"),
            "{name}: '{e}' does not name the file"
        );
    }
}

#[test]
fn fewer_nodes_keep_the_span_of_the_grid() {
    let layout = LightFieldLayout {
        nodes: [9, 5],
        node_min: Vec2::new(-0.3, -0.2),
        node_spacing: Vec2::new(0.075, 0.1),
        basis: FilterBasis::Quadratic,
        plane_distance: 0.5,
        image_min: Vec2::splat(-1.0),
        image_max: Vec2::splat(1.0),
        resolution: [8, 8],
    };
    let settings = CaptureSettings {
        position: Vec3::ZERO,
        direction: -Vec3::Y,
        x_axis: Vec3::X,
        layout,
        samples: 4,
        max_depth: 4,
        seed: 0,
        threads: None,
    }
    .with_nodes([5, 3]);
    let l = &settings.layout;
    assert_eq!(l.nodes, [5, 3]);
    let last = l.node_point(4, 2);
    assert!((last - Vec2::new(0.3, 0.2)).length() < 1e-6, "{last}");
}

#[test]
fn the_command_writes_a_field_and_reports_time_and_memory() {
    let dir = temp_dir("command");
    let luminaire = dir.join("quad.json");
    std::fs::write(&luminaire, luminaire_text(QUAD, QUAD_CAPTURE)).unwrap();
    let out = dir.join("quad.exr");
    let run = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_lacuna"))
            .arg("capture-luminaire")
            .arg(&luminaire)
            .args(args)
            .output()
            .unwrap()
    };
    let ok = run(&[
        "--out",
        out.to_str().unwrap(),
        "--nodes",
        "5",
        "--resolution",
        "6x4",
        "--samples",
        "2",
        "--threads",
        "1",
    ]);
    let stdout = String::from_utf8_lossy(&ok.stdout);
    assert!(
        ok.status.success(),
        "{stdout} {}",
        String::from_utf8_lossy(&ok.stderr)
    );
    assert!(
        stdout.contains("captured in") && stdout.contains("peak resident"),
        "{stdout}"
    );
    let field = lacuna::light::LightField::from_file(&out).unwrap();
    assert_eq!(field.layout().nodes, [5, 5]);
    assert_eq!(field.layout().resolution, [6, 4]);
    assert!(field.power() > 0.0);
    for bad in [
        vec!["--out", "field.png"],
        vec!["--out", out.to_str().unwrap(), "--samples", "0"],
        vec!["--out", out.to_str().unwrap(), "--nodes", "5y5"],
    ] {
        let e = run(&bad);
        let stderr = String::from_utf8_lossy(&e.stderr);
        assert!(
            !e.status.success() && !stderr.is_empty(),
            "{bad:?} accepted"
        );
        assert!(!stderr.contains("panicked"), "{bad:?}: {stderr}");
    }
    std::fs::remove_dir_all(&dir).ok();
}
