//! ICBPT (`bdpt_ic`, paper 002's importance-caching baseline) must be unbiased: image and
//! region means agree with `bdpt` and `path` within their measured error on the Cornell box,
//! the built-in two rooms and corridor, and the Veach door; no NaN; the same image for any
//! thread count; the record distributions (not only the uniform fallback) are used.

mod common;

use common::agreement::{agree_with_path_and_bdpt, load_scene, render_image};
use lacuna::integrator::{self, IntegratorSettings};
use lacuna::render::RenderSettings;
use lacuna::scene::Scene;

/// The paper's defaults (N = 1024, d = 0.001: one record subpath at these sizes) and a small
/// subset with many records.
const VARIANTS: &[&str] = &[
    "bdpt_ic",
    "bdpt_ic:subset=32:density=0.05",
    "bdpt_ic:subset=32:density=0.05:count=subset",
];

fn agree(label: &str, scene: &Scene, size: (u32, u32, u32)) {
    agree_with_path_and_bdpt(label, scene, size, VARIANTS);
}

#[test]
fn icbpt_agrees_on_the_cornell_box() {
    let scene = load_scene("scenes/cornell-box/cornell-box.json");
    agree("cornell", &scene, (5, 20, 16));
}

#[test]
fn icbpt_agrees_on_the_two_rooms() {
    let scene = lacuna::scene::two_rooms_builder().unwrap().build().unwrap();
    agree("two rooms", &scene, (6, 20, 16));
}

#[test]
fn icbpt_agrees_on_the_corridor() {
    let scene = lacuna::scene::corridor_builder().unwrap().build().unwrap();
    agree("corridor", &scene, (6, 16, 32));
}

#[test]
fn icbpt_agrees_on_the_veach_door() {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    agree("veach door", &scene, (6, 16, 16));
}

fn settings(size: u32, spp: u32, threads: usize) -> RenderSettings {
    RenderSettings {
        width: size,
        height: size,
        spp,
        seed: 3,
        threads: Some(threads),
        ..Default::default()
    }
}

#[test]
fn icbpt_gives_the_same_image_for_any_thread_count_and_uses_its_records() {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    let camera = *scene.camera().unwrap();
    let s = IntegratorSettings {
        max_depth: 6,
        ..Default::default()
    };
    let ic = integrator::create("bdpt_ic:subset=64:density=0.02:images=true", s).unwrap();
    let one = render_image(&scene, &camera, ic.as_ref(), &settings(24, 6, 1));
    let two = render_image(&scene, &camera, ic.as_ref(), &settings(24, 6, 2));
    let three = render_image(&scene, &camera, ic.as_ref(), &settings(24, 6, 3));
    let a = one.radiance();
    assert!(a.iter().all(|p| p.is_finite() && p.min_element() >= 0.0));
    assert!(a.iter().any(|p| p.max_element() > 0.0));
    assert_eq!(a, two.radiance());
    assert_eq!(a, three.radiance());
    let notes = ic.render_notes();
    assert!(
        notes.iter().any(|n| n.contains("importance records")),
        "{notes:?}"
    );
    assert!(notes.iter().any(|n| n.contains("occluded")), "{notes:?}");
    for name in [
        "resampled_visibility",
        "resampled_distance",
        "resampled_uniform",
        "resampled_fallback",
    ] {
        let index = one
            .layer_index(name)
            .unwrap_or_else(|| panic!("no layer {name}"));
        let layer = one.layer(index);
        assert!(layer
            .iter()
            .all(|p| p.is_finite() && p.min_element() >= 0.0));
        if name == "resampled_visibility" || name == "resampled_distance" {
            assert!(
                layer.iter().any(|p| p.max_element() > 0.0),
                "{name} is black: the records' distributions were not used"
            );
        }
    }
}

#[test]
fn icbpt_options_are_checked() {
    let s = IntegratorSettings::default();
    let (_, applied) = integrator::parse_spec("bdpt_ic:subset=512:density=0.01", s).unwrap();
    assert_eq!(applied.resampling.subset, 512);
    assert_eq!(applied.resampling.density, 0.01);
    for bad in [
        "bdpt_ic:subset=0",
        "bdpt_ic:density=0",
        "bdpt_ic:density=2",
        "bdpt_ic:accept=1",
        "bdpt_skeleton:density=0.01",
        "bdpt_ic:colour=red",
    ] {
        assert!(integrator::create(bad, s).is_err(), "{bad} accepted");
    }
}
