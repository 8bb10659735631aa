//! Portal-masked environment sampling (`path:env=portals`, issue 35): renders agree with
//! `path`'s default environment sampling by z-tests on the image and region means, on the
//! built-in interior with its window portals found automatically, and on the same house with
//! a hand-listed set that misses two windows and covers a third only in part (directions
//! through no portal must stay reachable by BSDF sampling). No pixel is NaN or negative
//! (`region_means` checks every pixel). The door, the ajar door and the built-in two rooms have
//! no environment light (emitters only): there `env=portals` must change nothing, which is
//! tested bit for bit. The sampler's pdf is chi-square tested in
//! `light::environment::portal`, the portal detection in `analysis::window_portals`.

mod common;

use common::agreement::{agree_with_path, load_scene, render_image};
use lacuna::integrator::{self, IntegratorSettings};
use lacuna::light::environment::Portal;
use lacuna::math::Vec3;
use lacuna::scene::{interior_builder, PortalSettings};

#[test]
fn portals_agree_with_path_on_the_interior() {
    let scene = interior_builder().unwrap().build().unwrap();
    let camera = *scene.camera().unwrap();
    agree_with_path(
        "interior",
        &scene,
        &camera,
        5,
        16,
        32,
        &["path:env=portals"],
    );
    // The portals were found (not the fallback everywhere).
    let found = scene.env_portals().expect("window portals");
    assert_eq!(found.portals().len(), 4);
}

#[test]
fn portals_that_miss_windows_stay_unbiased() {
    let mut builder = interior_builder().unwrap();
    // Half of the large south window (x in [1.2, 3.6], y in [0.8, 2.2] at z = 0.1) and the
    // west window shifted by 0.3 m; the two north windows are not listed.
    builder.set_portals(PortalSettings {
        listed: vec![
            Portal::new(
                Vec3::new(1.2, 0.8, 0.1),
                Vec3::new(1.2, 0.0, 0.0),
                Vec3::new(0.0, 1.4, 0.0),
                Vec3::NEG_Z,
            )
            .unwrap(),
            Portal::new(
                Vec3::new(0.1, 1.3, 2.5),
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(0.0, 0.0, 1.0),
                Vec3::NEG_X,
            )
            .unwrap(),
        ],
        automatic: false,
    });
    let scene = builder.build().unwrap();
    let camera = *scene.camera().unwrap();
    agree_with_path(
        "interior, partial portals",
        &scene,
        &camera,
        5,
        16,
        32,
        &["path:env=portals"],
    );
    assert_eq!(
        scene.env_portals().expect("listed portals").portals().len(),
        2
    );
}

#[test]
fn env_portals_is_refused_by_other_integrators() {
    for name in ["bdpt", "env_direct"] {
        let err = integrator::create(
            &format!("{name}:env=portals"),
            IntegratorSettings::default(),
        )
        .err()
        .unwrap_or_else(|| panic!("{name} took env=portals"));
        assert!(err.to_string().contains("env=portals"), "{err}");
    }
}

/// scenes/interior/ is what `write_interior_files` writes (`LACUNA_BLESS=1` rewrites it), and
/// the scene file finds the same window portals as the built-in.
#[test]
fn the_interior_scene_file_is_the_built_in() {
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/interior");
    if std::env::var_os("LACUNA_BLESS").is_some() {
        lacuna::scene::write_interior_files(&repo).unwrap();
    }
    let dir = std::env::temp_dir().join(format!("lacuna-interior-{}", std::process::id()));
    lacuna::scene::write_interior_files(&dir).unwrap();
    for name in ["interior.obj", "interior.mtl", "interior.json"] {
        let written = std::fs::read_to_string(dir.join(name)).unwrap();
        let stored = std::fs::read_to_string(repo.join(name)).unwrap();
        assert!(
            written == stored,
            "scenes/interior/{name} differs from the built-in (LACUNA_BLESS=1)"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
    let scene = common::agreement::load_scene("scenes/interior/interior.json");
    let found = lacuna::analysis::window_portals(&scene, &Default::default()).unwrap();
    assert_eq!(found.portals.len(), 4);
}

/// Portals listed in a scene file replace the automatic ones; bad ones are refused.
#[test]
fn scene_files_list_portals_or_turn_them_off() {
    let dir = std::env::temp_dir().join(format!("lacuna-portals-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let shapes = r#""shapes": [{ "type": "quad", "corners": [[0,0,0],[1,0,0],[1,0,1],[0,0,1]] }]"#;
    let write = |name: &str, extra: &str| {
        let path = dir.join(name);
        std::fs::write(&path, format!("{{ {shapes}, {extra} }}")).unwrap();
        path
    };
    let listed = write(
        "listed.json",
        r#""portals": [{ "corner": [0,1,0], "edge_u": [1,0,0], "edge_v": [0,0,1], "outward": [0,1,0] }], "auto_portals": false"#,
    );
    let loaded = lacuna::scene::load_scene_file(&listed)
        .unwrap()
        .builder
        .build()
        .unwrap();
    assert_eq!(loaded.portal_settings().listed.len(), 1);
    assert!(!loaded.portal_settings().automatic);
    let bad = write(
        "bad.json",
        r#""portals": [{ "corner": [0,1,0], "edge_u": [1,0,0], "edge_v": [1,0,1], "outward": [0,1,0] }]"#,
    );
    let err = lacuna::scene::load_scene_file(&bad)
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("portals[0]") && err.contains("orthogonal"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// Without an environment light `env=portals` is a no-op: the same image, bit for bit, and no
/// portal sampler (no analysis run) on the door, the ajar door and the built-in two rooms.
#[test]
fn env_portals_changes_nothing_without_an_environment() {
    let scenes = [
        (
            "veach door",
            load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json"),
        ),
        (
            "veach ajar",
            load_scene("scenes/veach-ajar-bitterli/veach-ajar-bitterli.json"),
        ),
        (
            "two rooms",
            lacuna::scene::two_rooms_builder().unwrap().build().unwrap(),
        ),
    ];
    for (label, scene) in &scenes {
        assert!(scene.environment().is_none(), "{label} has an environment");
        let camera = *scene.camera().unwrap();
        let settings = lacuna::render::RenderSettings {
            width: 24,
            height: 16,
            spp: 4,
            seed: 5,
            ..Default::default()
        };
        let image = |spec: &str| {
            let mut integrator = integrator::create(
                spec,
                IntegratorSettings {
                    max_depth: 6,
                    ..Default::default()
                },
            )
            .unwrap();
            lacuna::render::prepare(integrator.as_mut(), scene, &camera, None, &|_, _| true)
                .unwrap();
            render_image(scene, &camera, integrator.as_ref(), &settings).radiance()
        };
        let (path, portals) = (image("path"), image("path:env=portals"));
        assert!(path.iter().any(|p| p.max_element() > 0.0), "{label}: black");
        assert!(path == portals, "{label}: env=portals changed the image");
        assert!(scene.env_portals().is_none(), "{label}: portals built");
    }
}
