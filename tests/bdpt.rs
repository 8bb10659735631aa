//! Bidirectional path tracing must agree with the path tracer: same image mean and region
//! means within their measured error, on scenes with area, point, spot and directional lights,
//! glossy, mirror and glass surfaces; and never produce NaN.

mod common;

use std::sync::atomic::AtomicBool;

use common::agreement::{assert_agree, box_scene, region_means};
use lacuna::integrator::{self, IntegratorSettings, MisHeuristic};
use lacuna::math::{Rgb, Vec3};
use lacuna::render::{render, RenderSettings};
use lacuna::scene::{
    load_scene_file, two_rooms_builder, Camera, Material, MeshDesc, Scene, SceneBuilder,
};

fn compare(
    label: &str,
    scene: &Scene,
    camera: &Camera,
    settings: IntegratorSettings,
    size: u32,
    spp: u32,
) {
    let path = region_means(scene, camera, "path", settings, size, spp, 8);
    let bdpt = region_means(scene, camera, "bdpt", settings, size, spp, 8);
    assert!(path[0].0 > 0.0, "{label}: black image");
    assert_agree(label, ("path", &path), ("bdpt", &bdpt));
}

#[test]
fn bdpt_agrees_with_path_on_the_cornell_box() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/cornell-box/cornell-box.json");
    let loaded = load_scene_file(&path).unwrap();
    let scene = loaded.builder.build().unwrap();
    let camera = *scene.camera().unwrap();
    for mis in [MisHeuristic::Power, MisHeuristic::Balance] {
        compare(
            "cornell",
            &scene,
            &camera,
            IntegratorSettings {
                max_depth: 5,
                mis,
                ..Default::default()
            },
            24,
            8,
        );
    }
}

#[test]
fn bdpt_agrees_with_path_on_the_two_rooms() {
    let scene = two_rooms_builder().unwrap().build().unwrap();
    let camera = *scene.camera().unwrap();
    compare(
        "two rooms",
        &scene,
        &camera,
        IntegratorSettings {
            max_depth: 6,
            ..Default::default()
        },
        20,
        16,
    );
}

/// Glossy, mirror and glass surfaces under an area light: the path tracer reaches every path
/// here (caustics by BSDF sampling hitting the light), so the two must agree.
#[test]
fn bdpt_agrees_with_path_on_glossy_mirror_and_glass_under_an_area_light() {
    let (scene, camera) = box_scene(true, true, false);
    compare(
        "glossy+delta bsdfs",
        &scene,
        &camera,
        IntegratorSettings {
            max_depth: 6,
            ..Default::default()
        },
        20,
        16,
    );
}

/// Point, spot and directional lights with diffuse and glossy surfaces.
#[test]
fn bdpt_agrees_with_path_under_delta_lights() {
    let (scene, camera) = box_scene(false, true, true);
    compare(
        "delta lights",
        &scene,
        &camera,
        IntegratorSettings {
            max_depth: 6,
            ..Default::default()
        },
        20,
        16,
    );
}

/// Delta lights seen through delta surfaces (light -> glass/mirror -> diffuse -> camera)
/// are paths the path tracer cannot sample at all (it finds them neither by light sampling
/// through a specular surface nor by hitting a delta light): BDPT finds them by light tracing,
/// so it must be at least as bright, and finite.
#[test]
fn bdpt_handles_delta_lights_through_delta_bsdfs() {
    let (scene, camera) = box_scene(true, true, true);
    let s = IntegratorSettings {
        max_depth: 6,
        ..Default::default()
    };
    let path = region_means(&scene, &camera, "path", s, 20, 16, 6);
    let bdpt = region_means(&scene, &camera, "bdpt", s, 20, 16, 6);
    let sigma = (path[0].1.powi(2) + bdpt[0].1.powi(2)).sqrt();
    assert!(
        bdpt[0].0 > path[0].0 - 4.0 * sigma,
        "path {:?} bdpt {:?}",
        path[0],
        bdpt[0]
    );
}

/// Veach's door (pg2015 version) at low resolution: light reaches the camera room only
/// through the gap of the door.
#[test]
fn bdpt_agrees_with_path_on_the_veach_door() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/veach-door-pg2015/veach-door-pg2015.json");
    let loaded = load_scene_file(&path).unwrap();
    let scene = loaded.builder.build().unwrap();
    let camera = *scene.camera().unwrap();
    compare(
        "veach door",
        &scene,
        &camera,
        IntegratorSettings {
            max_depth: 6,
            ..Default::default()
        },
        16,
        16,
    );
}

#[test]
fn bdpt_refuses_thin_lens_cameras_and_renders_lightless_scenes_black() {
    let scene = two_rooms_builder().unwrap().build().unwrap();
    let camera = scene.camera().unwrap().with_thin_lens(0.05, 3.0).unwrap();
    let integrator = integrator::create("bdpt", IntegratorSettings::default()).unwrap();
    let rs = RenderSettings {
        width: 8,
        height: 8,
        spp: 1,
        ..Default::default()
    };
    assert!(render(
        &scene,
        &camera,
        integrator.as_ref(),
        &rs,
        &|_| true,
        &AtomicBool::new(false)
    )
    .is_err());

    let mut b = SceneBuilder::new();
    let m = b.add_material(Material::diffuse(Rgb::splat(0.5))).unwrap();
    b.add_mesh(MeshDesc {
        positions: vec![v3(-1., 0., -1.), v3(1., 0., -1.), v3(0., 0., 1.)],
        indices: vec![[0, 2, 1]],
        materials: vec![m],
        ..Default::default()
    })
    .unwrap();
    let scene = b.build().unwrap();
    let camera = Camera::look_at(v3(0., 2., 2.), Vec3::ZERO, Vec3::Y, 40.0).unwrap();
    let (film, _) = render(
        &scene,
        &camera,
        integrator.as_ref(),
        &rs,
        &|_| true,
        &AtomicBool::new(false),
    )
    .unwrap();
    assert!(film.radiance().iter().all(|p| *p == Rgb::ZERO));
}

fn v3(x: f32, y: f32, z: f32) -> Vec3 {
    Vec3::new(x, y, z)
}

/// Each (s, t) strategy alone, without MIS weights, is an unbiased estimate of the light
/// carried by paths of s + t - 1 segments: all strategies of one length agree.
#[test]
fn each_strategy_alone_is_unbiased() {
    use lacuna::integrator::{Bdpt, Integrator, StrategyFilter};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/cornell-box/cornell-box.json");
    let scene = load_scene_file(&path).unwrap().builder.build().unwrap();
    let camera = *scene.camera().unwrap();
    let mean_of = |integrator: &dyn Integrator| -> (f64, f64) {
        let xs: Vec<f64> = (0..10u64)
            .map(|seed| {
                let rs = RenderSettings {
                    width: 16,
                    height: 16,
                    spp: 32,
                    seed: seed * 31 + 5,
                    ..Default::default()
                };
                let (film, _) = render(
                    &scene,
                    &camera,
                    integrator,
                    &rs,
                    &|_| true,
                    &AtomicBool::new(false),
                )
                .unwrap();
                let px = film.radiance();
                px.iter().map(|p| p.element_sum() as f64 / 3.0).sum::<f64>() / px.len() as f64
            })
            .collect();
        let n = xs.len() as f64;
        let m = xs.iter().sum::<f64>() / n;
        let var = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
        (m, (var / n).sqrt())
    };
    let settings = IntegratorSettings {
        max_depth: 6,
        ..Default::default()
    };
    for segments in [2u32, 3] {
        let estimates: Vec<((u32, u32), (f64, f64))> = (0..=segments)
            .map(|s| {
                let t = segments + 1 - s;
                let filter = StrategyFilter {
                    s,
                    t,
                    unweighted: true,
                };
                ((s, t), mean_of(&Bdpt::new(settings).with_strategy(filter)))
            })
            .collect();
        // The weighted strategies of this length sum to the same total.
        let weighted: f64 = (0..=segments)
            .map(|s| {
                mean_of(&Bdpt::new(settings).with_strategy(StrategyFilter {
                    s,
                    t: segments + 1 - s,
                    unweighted: false,
                }))
                .0
            })
            .sum();
        let (reference, ref_err) = estimates[1].1; // s = 1: next-event estimation, low variance
        assert!(reference > 0.0);
        for ((s, t), (m, e)) in &estimates {
            let sigma = (e * e + ref_err * ref_err).sqrt();
            assert!(
                (m - reference).abs() <= 4.5 * sigma,
                "({s},{t}) {m} +- {e} vs (1,{}) {reference} +- {ref_err}",
                segments
            );
        }
        assert!(
            (weighted - reference).abs() <= 4.5 * ref_err * 2.0,
            "weighted sum {weighted} vs {reference}"
        );
    }
}
