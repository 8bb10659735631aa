//! `vpl` (instant radiosity): unbiased with compensation or without clamping, image and
//! region means agreeing with `path` within their measured error on diffuse scenes (and, with
//! compensation, on a box of glossy, mirror and glass surfaces under delta lights); clamped
//! without compensation, finite and measurably darker; no NaN; the same image for any thread
//! count; its options refused when wrong, and the bias stated.

mod common;

use common::agreement::{
    agree_with_path, assert_agree, box_scene, load_scene, region_means, render_image,
};
use lacuna::integrator::{self, IntegratorSettings};
use lacuna::render::RenderSettings;

/// No clamping (the plain VPL estimator, unbiased where there is no delta surface), a clamp
/// with compensation, and a large clamp with few VPLs, so that the compensation carries most
/// of the indirect light.
const UNBIASED: &[&str] = &[
    "vpl:clamp=0:count=16",
    "vpl:clamp=0.1:compensate=true:count=16",
    "vpl:clamp=0.5:compensate=true:count=4",
];

#[test]
fn vpl_agrees_with_path_on_the_cornell_box() {
    let scene = load_scene("scenes/cornell-box/cornell-box.json");
    let camera = *scene.camera().unwrap();
    agree_with_path("cornell", &scene, &camera, 5, 16, 16, UNBIASED);
}

#[test]
fn vpl_agrees_with_path_on_the_two_rooms() {
    let scene = lacuna::scene::two_rooms_builder().unwrap().build().unwrap();
    let camera = *scene.camera().unwrap();
    agree_with_path("two rooms", &scene, &camera, 6, 16, 16, UNBIASED);
}

#[test]
fn vpl_agrees_with_path_on_the_veach_door() {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    let camera = *scene.camera().unwrap();
    agree_with_path("veach door", &scene, &camera, 6, 16, 16, UNBIASED);
}

/// Delta surfaces (mirror, glass) and delta lights: only the compensated estimator covers the
/// light that reaches a non-delta surface through a delta one.
#[test]
fn compensated_vpl_agrees_with_path_with_delta_surfaces_and_lights() {
    let (scene, camera) = box_scene(true, true, true);
    agree_with_path(
        "box",
        &scene,
        &camera,
        4,
        16,
        16,
        &["vpl:clamp=0.1:compensate=true:count=16"],
    );
}

/// Clamped without compensation: every pixel finite, and the image darker than `path`'s by
/// more than their measured error (the bias is real, and the test could see it vanish).
#[test]
fn clamped_vpl_is_finite_and_darker() {
    let scene = load_scene("scenes/cornell-box/cornell-box.json");
    let camera = *scene.camera().unwrap();
    let settings = IntegratorSettings {
        max_depth: 5,
        ..Default::default()
    };
    // region_means asserts that every pixel is finite and non-negative.
    let path = region_means(&scene, &camera, "path", settings, 16, 64, 8);
    let clamped = region_means(&scene, &camera, "vpl:clamp=1:count=16", settings, 16, 64, 8);
    let ((mp, ep), (mc, ec)) = (path[0], clamped[0]);
    assert!(
        mc < mp - 4.5 * (ep * ep + ec * ec).sqrt(),
        "clamped {mc} +- {ec} against path {mp} +- {ep}"
    );
    // The same estimator compensated is back at path's.
    let compensated = region_means(
        &scene,
        &camera,
        "vpl:clamp=1:count=16:compensate=true",
        settings,
        16,
        64,
        8,
    );
    assert_agree("cornell", ("path", &path), ("compensated", &compensated));
}

#[test]
fn vpl_gives_the_same_image_for_any_thread_count() {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    let camera = *scene.camera().unwrap();
    let s = IntegratorSettings {
        max_depth: 6,
        ..Default::default()
    };
    for spec in ["vpl:count=8", "vpl:count=8:compensate=true"] {
        let vpl = integrator::create(spec, s).unwrap();
        let render = |threads| {
            let rs = RenderSettings {
                width: 20,
                height: 20,
                spp: 3,
                seed: 5,
                threads: Some(threads),
                ..Default::default()
            };
            render_image(&scene, &camera, vpl.as_ref(), &rs)
        };
        let one = render(1);
        let a = one.radiance();
        assert!(a.iter().all(|p| p.is_finite() && p.min_element() >= 0.0));
        assert!(a.iter().any(|p| p.max_element() > 0.0), "{spec}: black");
        assert_eq!(a, render(2).radiance(), "{spec}");
        assert_eq!(a, render(3).radiance(), "{spec}");
    }
}

#[test]
fn vpl_options_are_checked_and_the_bias_stated() {
    let s = IntegratorSettings::default();
    for bad in [
        "vpl:count=0",
        "vpl:count=x",
        "vpl:clamp=-1",
        "vpl:clamp=nan",
        "vpl:compensate=maybe",
        "vpl:visibility=skeleton",
        "vpl:visibility=sometimes",
        "vpl:resolution=4",
    ] {
        let err = integrator::create(bad, s).err().expect(bad).to_string();
        assert!(
            err.contains("vpl") || err.contains("option"),
            "{bad}: {err}"
        );
    }
    let (name, parsed) =
        integrator::parse_spec("vpl:count=128:clamp=0.05:compensate=true", s).unwrap();
    assert_eq!(name, "vpl");
    assert_eq!(
        (parsed.vpl.count, parsed.vpl.clamp, parsed.vpl.compensate),
        (128, 0.05, true)
    );
    let bias = |spec: &str| integrator::create(spec, s).unwrap().bias();
    assert!(bias("vpl").is_some_and(|b| b.contains("clamped")));
    assert!(bias("vpl:clamp=0").is_some_and(|b| b.contains("delta")));
    assert_eq!(bias("vpl:compensate=true"), None);
    assert_eq!(bias("path"), None);
}
