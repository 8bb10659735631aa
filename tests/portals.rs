//! Portal-masked environment sampling (`path:env=portals`, issue 35): renders agree with
//! `path`'s default environment sampling by z-tests on the image and region means, on the
//! built-in interior with its window portals found automatically, and on the same house with
//! a hand-listed set that misses two windows and covers a third only in part (directions
//! through no portal must stay reachable by BSDF sampling). No pixel is NaN or negative
//! (`region_means` checks every pixel). The sampler's pdf is chi-square tested in
//! `light::environment::portal`, the portal detection in `analysis::window_portals`.

mod common;

use common::agreement::agree_with_path;
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
