//! Photometric (IES) lights end to end: a flat profile renders exactly as a point light, the
//! emitted intensity integrates to the profile's flux, bidirectional light tracing agrees with
//! next-event estimation (tests/bdpt.rs's delta-light scene includes an IES light), and scene
//! files load them with clear errors.

mod common;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use common::agreement::render_image;
use lacuna::integrator::{self, IntegratorSettings};
use lacuna::light::{Light, LightDesc, PhotometricProfile};
use lacuna::math::{Rgb, Rng, Vec2, Vec3};
use lacuna::render::RenderSettings;
use lacuna::scene::{load_scene_file, Camera, Material, MeshDesc, Scene, SceneBuilder};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn ies(name: &str) -> Arc<PhotometricProfile> {
    Arc::new(PhotometricProfile::from_file(&root().join("scenes/ies").join(name)).unwrap())
}

/// An open box (floor and three walls) under `light`, with a camera looking in.
fn room(light: LightDesc) -> (Scene, Camera) {
    let mut b = SceneBuilder::new();
    let m = b.add_material(Material::diffuse(Rgb::splat(0.6))).unwrap();
    let v = Vec3::new;
    let quads = [
        [
            v(-1., 0., -1.),
            v(1., 0., -1.),
            v(1., 0., 1.),
            v(-1., 0., 1.),
        ],
        [
            v(-1., 0., -1.),
            v(-1., 2., -1.),
            v(1., 2., -1.),
            v(1., 0., -1.),
        ],
        [
            v(-1., 0., -1.),
            v(-1., 0., 1.),
            v(-1., 2., 1.),
            v(-1., 2., -1.),
        ],
        [v(1., 0., -1.), v(1., 2., -1.), v(1., 2., 1.), v(1., 0., 1.)],
    ];
    for q in quads {
        b.add_mesh(MeshDesc {
            positions: q.to_vec(),
            indices: vec![[0, 2, 1], [0, 3, 2]],
            materials: vec![m],
            ..Default::default()
        })
        .unwrap();
    }
    b.add_light(light).unwrap();
    let scene = b.build().unwrap();
    let camera = Camera::look_at(v(0.0, 1.2, 3.0), v(0.0, 0.6, 0.0), Vec3::Y, 50.0).unwrap();
    (scene, camera)
}

fn render(scene: &Scene, camera: &Camera, name: &str) -> Vec<Rgb> {
    let settings = IntegratorSettings {
        max_depth: 4,
        ..Default::default()
    };
    let integrator = integrator::create(name, settings).unwrap();
    let rs = RenderSettings {
        width: 24,
        height: 16,
        spp: 8,
        ..Default::default()
    };
    render_image(scene, camera, integrator.as_ref(), &rs)
        .radiance()
        .to_vec()
}

/// A rotationally symmetric profile of 1 cd everywhere gives the radiance of a point light of
/// the same intensity: next-event estimation is identical, and light tracing draws other
/// directions but estimates the same image.
#[test]
fn a_flat_profile_renders_exactly_like_a_point_light() {
    let gamma = vec![0.0, 90.0, 180.0];
    let flat = Arc::new(PhotometricProfile::from_table(gamma, vec![0.0], vec![1.0; 3]).unwrap());
    assert!((flat.flux() / (4.0 * std::f32::consts::PI) - 1.0).abs() < 1e-3);
    let position = Vec3::new(0.2, 1.5, 0.1);
    let intensity = Rgb::new(3.0, 2.0, 1.0);
    let (point, camera) = room(LightDesc::Point {
        position,
        intensity,
    });
    let (photometric, _) = room(LightDesc::Photometric {
        position,
        direction: Vec3::new(0.3, -1.0, 0.2),
        c0: Vec3::X,
        intensity,
        profile: flat,
    });
    assert_eq!(
        render(&point, &camera, "path"),
        render(&photometric, &camera, "path")
    );
}

/// E[value / pdf] of emitted directions is the light's intensity integrated over the sphere:
/// the profile's flux times the colour. Every sample's pdf is what `emission_pdf` gives.
#[test]
fn emitted_intensity_integrates_to_the_flux() {
    for name in ["downlight.ies", "wallwasher.ies"] {
        let profile = ies(name);
        let light = Light::from_desc(
            &LightDesc::Photometric {
                position: Vec3::ZERO,
                direction: Vec3::new(0.2, -1.0, 0.1),
                c0: Vec3::Z,
                intensity: Rgb::new(1.0, 0.5, 0.25),
                profile: profile.clone(),
            },
            &lacuna::geometry::Bounds3::default(),
        );
        let mut rng = Rng::new(7, 0);
        let n = 200_000;
        let (mut sum, mut mismatches) = (0.0f64, 0usize);
        for _ in 0..n {
            let Some(e) = light.sample_emission(Vec2::ZERO, rng.uniform2()) else {
                continue;
            };
            let pdf = light.emission_pdf(e.dir);
            if (pdf - e.pdf_emit).abs() > 1e-3 * pdf {
                mismatches += 1; // a direction rounding into a neighbouring cell
            }
            sum += (e.value.x / e.pdf_emit) as f64 / n as f64;
        }
        assert!(mismatches * 1000 < n, "{name}: {mismatches} pdf mismatches");
        let flux = profile.flux() as f64;
        assert!(
            (sum / flux - 1.0).abs() < 0.01,
            "{name}: {sum} vs flux {flux}"
        );
        assert!(
            (light.power() / profile.flux() - 0.5 * 0.7152 - 0.2126 - 0.0722 * 0.25).abs() < 0.01
        );
    }
}

/// Light sampling reads the profile in the light's frame: the nadir along `direction`, C0
/// towards `c0` (the wall washer throws towards C0).
#[test]
fn the_profile_is_oriented_by_direction_and_c0() {
    let profile = ies("wallwasher.ies");
    let light = Light::from_desc(
        &LightDesc::Photometric {
            position: Vec3::new(0.0, 2.0, 0.0),
            direction: -Vec3::Y,
            c0: Vec3::X,
            intensity: Rgb::ONE,
            profile: profile.clone(),
        },
        &lacuna::geometry::Bounds3::default(),
    );
    let at = |p: Vec3| light.sample(p, Vec2::ZERO).map_or(0.0, |s| s.radiance.x);
    // 35 degrees from the nadir towards +X (C0) against towards -X (C180).
    let d = 2.0 * 35f32.to_radians().tan();
    let (towards_c0, away) = (at(Vec3::new(d, 0.0, 0.0)), at(Vec3::new(-d, 0.0, 0.0)));
    assert!(towards_c0 > 3.0 * away, "{towards_c0} vs {away}");
    let expected = profile.intensity(Vec3::new(
        35f32.to_radians().sin(),
        0.0,
        35f32.to_radians().cos(),
    ));
    let dist2 = 4.0 + d * d;
    assert!((towards_c0 - expected / dist2).abs() < 1e-3 * towards_c0);
    // The wall washer's table reaches the zenith with zero candela: nothing goes up.
    assert_eq!(at(Vec3::new(0.0, 3.0, 0.0)), 0.0);
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn scene_files_load_ies_lights_with_clear_errors() {
    let loaded = load_scene_file(&root().join("scenes/ies_room.json")).unwrap();
    let scene = loaded.builder.build().unwrap();
    assert_eq!(scene.lights().len(), 3);
    assert!(scene
        .lights()
        .iter()
        .all(|l| matches!(l, Light::Photometric { .. })));
    let camera = *scene.camera().unwrap();
    let image = render(&scene, &camera, "path");
    assert!(image.iter().all(|p| p.is_finite()));
    assert!(image.iter().any(|p| p.x > 0.0));

    let dir = std::env::temp_dir().join(format!("lacuna-photometric-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene_with = |light: &str| {
        format!(
            r#"{{ "shapes": [ {{ "type": "quad", "corners": [[-1,0,-1],[1,0,-1],[1,0,1],[-1,0,1]] }} ],
                 "lights": [ {light} ] }}"#
        )
    };
    let missing = write(
        &dir,
        "missing.json",
        &scene_with(
            r#"{ "type": "ies", "file": "nope.ies", "position": [0,1,0], "direction": [0,-1,0] }"#,
        ),
    );
    let e = load_scene_file(&missing).err().unwrap().to_string();
    assert!(e.contains("nope.ies"), "{e}");
    write(
        &dir,
        "bad.ies",
        "IESNA:LM-63-2002\nTILT=NONE\n1 1000 1 2 1 3 2 0 0 0\n1 1 0\n0 90\n0\n1 1\n",
    );
    let bad = write(
        &dir,
        "bad.json",
        &scene_with(
            r#"{ "type": "ies", "file": "bad.ies", "position": [0,1,0], "direction": [0,-1,0] }"#,
        ),
    );
    let e = load_scene_file(&bad).err().unwrap().to_string();
    assert!(e.contains("bad.ies:line 3") && e.contains("type A"), "{e}");
    let zero = write(
        &dir,
        "zero.json",
        &scene_with(
            r#"{ "type": "ies", "file": "bad.ies", "position": [0,1,0], "direction": [0,0,0] }"#,
        ),
    );
    assert!(load_scene_file(&zero).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}
