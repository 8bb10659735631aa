//! SkelBPT (`bdpt_skeleton`, paper 002) must be unbiased: image and region means agree with
//! `bdpt` and `path` within their measured error on the Cornell box, the built-in two rooms
//! and corridor, and the Veach door, and (with ICBPT) under sky light and light fields; no
//! NaN; the same image for any thread count; exactly `bdpt`'s image where it has no skeleton
//! to use. (The resampling distributions against brute
//! force are in `guide::resampling`'s unit tests.)

mod common;

use common::agreement::{
    agree_with_path, agree_with_path_and_bdpt, load_scene, render_image, rough_glass_room,
};
use lacuna::integrator::{self, BdptSkeleton, Integrator, IntegratorSettings};
use lacuna::math::{Rgb, Vec3};
use lacuna::render::RenderSettings;
use lacuna::scene::{Camera, Material, Scene, SceneBuilder};

/// Prepares `spec` (a `bdpt_skeleton` variant) on `scene` and checks whether it resamples
/// (false: the scene is open or unsuited and it falls back to `bdpt`), so that a silent
/// fallback cannot pass for resampling in an agreement test.
fn assert_resamples(label: &str, scene: &Scene, max_depth: u32, spec: &str, resamples: bool) {
    let camera = *scene.camera().unwrap();
    let settings = IntegratorSettings {
        max_depth,
        ..Default::default()
    };
    let (_, settings) = integrator::parse_spec(spec, settings).unwrap();
    let mut skel = BdptSkeleton::new(settings).unwrap();
    lacuna::render::prepare(&mut skel, scene, &camera, None, &|_, _| true).unwrap();
    assert_eq!(skel.resamples(), resamples, "{label}: {spec} resamples");
}

/// Region means of `path`, `bdpt` and each SkelBPT variant; every variant must agree with both
/// and resample or not as `resamples` says ([`assert_resamples`]).
fn agree(
    label: &str,
    scene: &Scene,
    (max_depth, size, spp): (u32, u32, u32),
    resamples: bool,
    variants: &[&str],
) {
    for spec in variants {
        assert_resamples(label, scene, max_depth, spec, resamples);
    }
    agree_with_path_and_bdpt(label, scene, (max_depth, size, spp), variants);
}

/// The paper's defaults (N = 1024, more than the pixels here: all subpaths), a small subset,
/// and every mapped node accepted (alpha = 0), with both MIS counts of the connections.
const VARIANTS: &[&str] = &[
    "bdpt_skeleton",
    "bdpt_skeleton:subset=32:accept=0",
    "bdpt_skeleton:subset=32:accept=0:count=subset",
];

/// The Cornell box is open at the front: its nodes see the outside, so SkelBPT falls back to
/// `bdpt` here (the closed scenes below resample).
#[test]
fn skelbpt_agrees_on_the_cornell_box() {
    let scene = load_scene("scenes/cornell-box/cornell-box.json");
    agree("cornell", &scene, (5, 20, 16), false, VARIANTS);
}

#[test]
fn skelbpt_agrees_on_the_two_rooms() {
    let scene = lacuna::scene::two_rooms_builder().unwrap().build().unwrap();
    agree("two rooms", &scene, (6, 20, 16), true, VARIANTS);
}

#[test]
fn skelbpt_agrees_on_the_corridor() {
    let scene = lacuna::scene::corridor_builder().unwrap().build().unwrap();
    agree("corridor", &scene, (6, 16, 32), true, VARIANTS);
}

/// Under sky light (the built-in interior, lit through its windows) the light subpaths start
/// at infinity and the camera paths that leave the house find the sky: both resampling
/// integrators agree with `path` (their region means were 20-40 % off while the environment's
/// MIS sums left out the N samples of the resampled connections).
#[test]
fn skelbpt_and_icbpt_agree_under_environment_light() {
    let scene = lacuna::scene::interior_builder().unwrap().build().unwrap();
    let camera = *scene.camera().unwrap();
    let spec = "bdpt_skeleton:subset=32:accept=0";
    assert_resamples("interior", &scene, 4, spec, true);
    agree_with_path(
        "interior under the sky",
        &scene,
        &camera,
        4,
        16,
        32,
        &[spec, "bdpt_ic:subset=32:density=0.05"],
    );
}

/// Under light-field luminaires (the baked luminaire room: two fields, no emitting geometry)
/// the light subpaths start on the fields' image planes, whose direct-sampling density depends
/// on the receiver, and no camera path can hit a field: both resampling integrators agree
/// with `bdpt` and `path`.
#[test]
fn skelbpt_and_icbpt_agree_under_light_fields() {
    let scene = load_scene("scenes/luminaire_room_baked.json");
    assert!(scene
        .lights()
        .iter()
        .all(|l| matches!(l, lacuna::light::Light::LightField { .. })));
    let skeleton_specs = ["bdpt_skeleton:subset=32:accept=0", "bdpt_skeleton"];
    for spec in skeleton_specs {
        assert_resamples("luminaire room", &scene, 4, spec, true);
    }
    let mut specs = skeleton_specs.to_vec();
    specs.push("bdpt_ic:subset=32:density=0.05");
    agree_with_path_and_bdpt("luminaire room (light fields)", &scene, (4, 16, 32), &specs);
}

/// Through rough glass ([`rough_glass_room`]): light vertices on the frosted lamp's outside
/// are reached from within, so connections leave them across the surface; ICBPT's
/// distributions count such pairs as connectable (`resampled::may_leave`) and must stay
/// unbiased against `path`.
#[test]
fn icbpt_agrees_with_path_through_rough_glass() {
    let (scene, camera) = rough_glass_room();
    agree_with_path(
        "rough glass",
        &scene,
        &camera,
        6,
        16,
        32,
        &["bdpt_ic:subset=32:density=0.05"],
    );
}

#[test]
fn skelbpt_agrees_on_the_veach_door() {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    agree("veach door", &scene, (6, 16, 16), true, VARIANTS);
}

fn prepared(spec: &str, scene: &Scene, max_depth: u32) -> Box<dyn Integrator> {
    let settings = IntegratorSettings {
        max_depth,
        ..Default::default()
    };
    let mut i = integrator::create(spec, settings).unwrap();
    lacuna::render::prepare(i.as_mut(), scene, scene.camera().unwrap(), None, &|_, _| {
        true
    })
    .unwrap();
    i
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
fn skelbpt_gives_the_same_image_for_any_thread_count() {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    let camera = *scene.camera().unwrap();
    let skel = prepared("bdpt_skeleton:subset=64:images=true", &scene, 6);
    let one = render_image(&scene, &camera, skel.as_ref(), &settings(24, 6, 1));
    let two = render_image(&scene, &camera, skel.as_ref(), &settings(24, 6, 2));
    let three = render_image(&scene, &camera, skel.as_ref(), &settings(24, 6, 3));
    let a = one.radiance();
    assert!(a.iter().all(|p| p.is_finite() && p.min_element() >= 0.0));
    assert!(a.iter().any(|p| p.max_element() > 0.0));
    assert_eq!(a, two.radiance());
    assert_eq!(a, three.radiance());
    // The per-distribution images are there, finite, and the node distributions (not only
    // the uniform fallback) were used.
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
        if name != "resampled_fallback" {
            assert!(
                layer.iter().any(|p| p.max_element() > 0.0),
                "{name} is black"
            );
        }
    }
}

/// A floor and a light above it in the open: the analysis finds no closed empty space worth a
/// skeleton, or no node sees a light vertex; either way SkelBPT renders bdpt's exact image and
/// says why.
#[test]
fn skelbpt_without_a_usable_skeleton_renders_exactly_bdpt() {
    let mut b = SceneBuilder::new();
    let floor = b
        .add_material(Material::diffuse(Rgb::new(0.7, 0.6, 0.5)))
        .unwrap();
    let light = b
        .add_material(Material::emissive(Rgb::splat(10.0)))
        .unwrap();
    let v = Vec3::new;
    for (p, m) in [
        (
            [
                v(-2., 0., -2.),
                v(-2., 0., 2.),
                v(2., 0., 2.),
                v(2., 0., -2.),
            ],
            floor,
        ),
        (
            [
                v(-0.3, 1.5, -0.3),
                v(0.3, 1.5, -0.3),
                v(0.3, 1.5, 0.3),
                v(-0.3, 1.5, 0.3),
            ],
            light,
        ),
    ] {
        common::shapes::quad(&mut b, p, m);
    }
    b.set_camera(Camera::look_at(v(0., 1., 4.), v(0., 0.3, 0.), Vec3::Y, 50.0).unwrap())
        .unwrap();
    let scene = b.build().unwrap();
    let camera = *scene.camera().unwrap();
    let settings_ = IntegratorSettings {
        max_depth: 4,
        ..Default::default()
    };
    let mut skel = BdptSkeleton::new(settings_).unwrap();
    let pre = lacuna::render::prepare(&mut skel, &scene, &camera, None, &|_, _| true).unwrap();
    let bdpt = prepared("bdpt", &scene, 4);
    assert!(!skel.resamples(), "{:?}", pre.notes);
    assert!(
        pre.notes.iter().any(|n| n.contains("renders as bdpt")),
        "{:?}",
        pre.notes
    );
    // Open at every probe point: decided before the scene's analysis, which did not run.
    assert!(
        pre.notes.iter().any(|n| n.contains("an open scene")),
        "{:?}",
        pre.notes
    );
    assert!(
        pre.stages.iter().all(|s| !s.stage.starts_with("analysis")),
        "{:?}",
        pre.stages
    );
    let a = render_image(&scene, &camera, &skel, &settings(16, 4, 2));
    let b = render_image(&scene, &camera, bdpt.as_ref(), &settings(16, 4, 2));
    assert!(a.radiance().iter().any(|p| p.max_element() > 0.0));
    assert_eq!(a.radiance(), b.radiance());
}

#[test]
fn skelbpt_options_are_checked() {
    let s = IntegratorSettings::default();
    assert!(integrator::create("bdpt_skeleton:subset=512:accept=0.5", s).is_ok());
    for bad in [
        "bdpt_skeleton:subset=0",
        "bdpt_skeleton:accept=-1",
        "bdpt_skeleton:images=maybe",
        "bdpt_skeleton:colour=red",
    ] {
        assert!(integrator::create(bad, s).is_err(), "{bad} accepted");
    }
    // Rendering without preparing is refused.
    let scene = lacuna::scene::two_rooms_builder().unwrap().build().unwrap();
    let i = integrator::create("bdpt_skeleton", s).unwrap();
    assert!(i.check_prepared(&scene).is_err());
}
