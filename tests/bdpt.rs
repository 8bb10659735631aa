//! Bidirectional path tracing must agree with the path tracer: same image mean and region
//! means within their measured error, on scenes with area, point, spot and directional lights,
//! glossy, mirror and glass surfaces; and never produce NaN.

mod common;

use std::sync::atomic::AtomicBool;

use common::agreement::{assert_agree, box_scene, region_means, render_image, rough_glass_room};
use lacuna::integrator::{
    self, strategy_layer_name, Bdpt, Integrator, IntegratorSettings, MisHeuristic, StrategyFilter,
};
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
                mis: Some(mis),
                ..Default::default()
            },
            24,
            8,
        );
    }
}

/// Fewer and more light subpaths per iteration than pixels (24 x 24 = 576): camera paths share
/// light subpaths, or some light subpaths only splat; the light-tracing weights use the count.
#[test]
fn bdpt_agrees_with_path_for_any_number_of_light_subpaths() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/cornell-box/cornell-box.json");
    let scene = load_scene_file(&path).unwrap().builder.build().unwrap();
    let camera = *scene.camera().unwrap();
    let settings = IntegratorSettings {
        max_depth: 4,
        ..Default::default()
    };
    let reference = region_means(&scene, &camera, "path", settings, 24, 8, 8);
    for n in [37, 2000] {
        let bdpt = region_means(
            &scene,
            &camera,
            "bdpt",
            IntegratorSettings {
                light_paths: Some(n),
                ..settings
            },
            24,
            8,
            8,
        );
        assert_agree(
            &format!("cornell, {n} light subpaths"),
            ("path", &reference),
            ("bdpt", &bdpt),
        );
    }
}

/// The many-path estimator (000 eq. 185): every camera vertex connected to all 24 light
/// subpaths of the iteration, each counting 1/24, with 24 connection samples in the weights.
#[test]
fn bdpt_connecting_to_every_light_subpath_agrees_with_path() {
    use lacuna::integrator::AllLightPaths;
    let (scene, camera) = box_scene(true, true, false);
    let settings = IntegratorSettings {
        max_depth: 4,
        ..Default::default()
    };
    let path = region_means(&scene, &camera, "path", settings, 16, 8, 8);
    let all = Bdpt::new(settings)
        .with_light_paths(24)
        .unwrap()
        .with_policy(Box::new(AllLightPaths));
    // Image mean and quadrant means (in region_means' order) over 8 seeds.
    let runs: Vec<Vec<f64>> = (0..8u64)
        .map(|seed| {
            let px = render_once(&scene, &camera, &all, 16, 8, seed * 7919 + 1, None).radiance();
            assert!(px.iter().all(|p| p.is_finite() && p.min_element() >= 0.0));
            let mut q = vec![mean(&px)];
            q.extend(block_means(&px, 16, 8));
            q
        })
        .collect();
    let bdpt: Vec<(f64, f64)> = (0..5)
        .map(|k| {
            let xs: Vec<f64> = runs.iter().map(|r| r[k]).collect();
            let n = xs.len() as f64;
            let m = xs.iter().sum::<f64>() / n;
            let var = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
            (m, (var / n).sqrt())
        })
        .collect();
    assert_agree("all light subpaths", ("path", &path), ("bdpt", &bdpt));
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

/// Frosted glass ([`rough_glass_room`]): paths through rough glass are found by every
/// strategy: next-event estimation and connections through the glass, light tracing out of it
/// (importance transport, no eta^2), so the two integrators must agree.
#[test]
fn bdpt_agrees_with_path_through_rough_glass() {
    let (scene, camera) = rough_glass_room();
    compare(
        "rough glass",
        &scene,
        &camera,
        IntegratorSettings {
            max_depth: 8,
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
    let settings = IntegratorSettings {
        max_depth: 6,
        ..Default::default()
    };
    // The point light seen by way of the exponent-1e4 wall (diffuse -> sharp glossy -> point
    // light, found only when a BSDF direction happens to hit the highlight's spot) makes path's
    // estimate heavy-tailed: at 16 spp most seeds miss the tail, their means sit low and their
    // spread understates the error (with stratified samples even more: the bulk varies less
    // while the tail stays), so path gets enough samples here to sample the tail; bdpt finds
    // those paths by light tracing. At 256 spp x 32 seeds path agreed with bdpt on every
    // region with either sampler (BENCHMARKS.md, issue 2, round 4).
    let path = region_means(&scene, &camera, "path", settings, 20, 256, 16);
    let bdpt = region_means(&scene, &camera, "bdpt", settings, 20, 16, 8);
    assert!(path[0].0 > 0.0, "delta lights: black image");
    assert_agree("delta lights", ("path", &path), ("bdpt", &bdpt));
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
/// Bitterli's "Veach, Ajar" at low resolution: the second door scene.
#[test]
fn bdpt_agrees_with_path_on_bitterlis_ajar_door() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/veach-ajar-bitterli/veach-ajar-bitterli.json");
    let scene = load_scene_file(&path).unwrap().builder.build().unwrap();
    let camera = *scene.camera().unwrap();
    compare(
        "ajar door",
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

/// A thin-lens camera: light tracing (t = 1) connects to sampled lens points. Glossy, mirror
/// and glass surfaces under an area light, so the path tracer reaches every path too.
#[test]
fn bdpt_agrees_with_path_through_a_thin_lens() {
    let (scene, camera) = box_scene(true, true, false);
    let camera = camera.with_thin_lens(0.2, 2.2).unwrap();
    compare(
        "thin lens",
        &scene,
        &camera,
        IntegratorSettings {
            max_depth: 5,
            ..Default::default()
        },
        20,
        16,
    );
}

#[test]
fn bdpt_renders_lightless_scenes_black() {
    let integrator = integrator::create("bdpt", IntegratorSettings::default()).unwrap();
    let rs = RenderSettings {
        width: 8,
        height: 8,
        spp: 1,
        ..Default::default()
    };
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
    let film = render_image(&scene, &camera, integrator.as_ref(), &rs);
    assert!(film.radiance().iter().all(|p| *p == Rgb::ZERO));
}

fn v3(x: f32, y: f32, z: f32) -> Vec3 {
    Vec3::new(x, y, z)
}

fn render_once(
    scene: &Scene,
    camera: &Camera,
    integrator: &dyn Integrator,
    size: u32,
    spp: u32,
    seed: u64,
    threads: Option<usize>,
) -> lacuna::film::Film {
    let rs = RenderSettings {
        width: size,
        height: size,
        spp,
        seed,
        threads,
        ..Default::default()
    };
    render(
        scene,
        camera,
        integrator,
        &rs,
        &|_| true,
        &AtomicBool::new(false),
    )
    .unwrap()
    .0
}

/// Means of `block` x `block` pixel blocks of a `size` x `size` image.
fn block_means(px: &[Rgb], size: u32, block: u32) -> Vec<f64> {
    let n = size / block;
    let mut sums = vec![0.0f64; (n * n) as usize];
    for y in 0..size {
        for x in 0..size {
            sums[(y / block * n + x / block) as usize] +=
                px[(y * size + x) as usize].element_sum() as f64 / 3.0;
        }
    }
    sums.iter().map(|s| s / (block * block) as f64).collect()
}

fn mean(px: &[Rgb]) -> f64 {
    px.iter().map(|p| p.element_sum() as f64 / 3.0).sum::<f64>() / px.len() as f64
}

fn layer(film: &lacuna::film::Film, s: u32, t: u32, weighted: bool) -> Vec<Rgb> {
    let name = strategy_layer_name(s, t, weighted);
    film.layer(
        film.layer_index(&name)
            .unwrap_or_else(|| panic!("no layer {name}")),
    )
}

/// Each (s, t) strategy alone, without MIS weights, is an unbiased estimate of the light
/// carried by paths of s + t - 1 segments: all strategies of one length agree, for a pinhole
/// and for a thin lens (where t = 1 connects to sampled lens points). All strategies come
/// from one render per seed, as strategy images.
#[test]
fn each_strategy_alone_is_unbiased() {
    let cornell = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/cornell-box/cornell-box.json");
    let scene = load_scene_file(&cornell).unwrap().builder.build().unwrap();
    let pinhole = *scene.camera().unwrap();
    // A wide lens focused well in front of the box: the walls' edges blur over a few pixels.
    let lens = pinhole.with_thin_lens(1.0, 1.5).unwrap();
    let settings = IntegratorSettings {
        max_depth: 6,
        ..Default::default()
    };
    let bdpt = Bdpt::new(settings).with_strategy_images(4).unwrap();
    for (label, camera) in [("pinhole", pinhole), ("thin lens", lens)] {
        let films: Vec<_> = (0..16u64)
            .map(|seed| render_once(&scene, &camera, &bdpt, 16, 32, seed * 31 + 5, None))
            .collect();
        // Mean and standard error over the seeds of one layer's image mean.
        let stat = |s: u32, t: u32, weighted: bool| -> (f64, f64) {
            let xs: Vec<f64> = films
                .iter()
                .map(|f| mean(&layer(f, s, t, weighted)))
                .collect();
            let n = xs.len() as f64;
            let m = xs.iter().sum::<f64>() / n;
            let var = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
            (m, (var / n).sqrt())
        };
        for segments in [2u32, 3, 4] {
            let (reference, ref_err) = stat(1, segments, false); // next-event estimation
            assert!(reference > 0.0);
            for s in 0..=segments {
                let t = segments + 1 - s;
                let (m, e) = stat(s, t, false);
                let sigma = (e * e + ref_err * ref_err).sqrt();
                assert!(
                    (m - reference).abs() <= 4.5 * sigma,
                    "{label}: ({s},{t}) {m} +- {e} vs (1,{segments}) {reference} +- {ref_err}"
                );
            }
            // Light tracing through the lens blurs like the camera rays: the same means on
            // 4x4-pixel blocks as next-event estimation.
            let blocks = |s: u32, t: u32| -> Vec<(f64, f64)> {
                let per_seed: Vec<Vec<f64>> = films
                    .iter()
                    .map(|f| block_means(&layer(f, s, t, false), 16, 4))
                    .collect();
                (0..per_seed[0].len())
                    .map(|b| {
                        let xs: Vec<f64> = per_seed.iter().map(|v| v[b]).collect();
                        let n = xs.len() as f64;
                        let m = xs.iter().sum::<f64>() / n;
                        let var = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
                        (m, (var / n).sqrt())
                    })
                    .collect()
            };
            if segments <= 3 {
                assert_agree(
                    &format!("{label}: ({segments},1) vs (1,{segments}) on blocks"),
                    ("(1,t)", &blocks(1, segments)),
                    ("(s,1)", &blocks(segments, 1)),
                );
            }
            // The weighted strategies of this length sum to the same total.
            let weighted: f64 = (0..=segments)
                .map(|s| stat(s, segments + 1 - s, true).0)
                .sum();
            assert!(
                (weighted - reference).abs() <= 4.5 * ref_err * 2.0,
                "{label}: weighted sum {weighted} vs {reference}"
            );
        }
    }
}

/// The strategy images of one render: their weighted layers sum to the image, a render
/// restricted to one strategy (`StrategyFilter`) equals that strategy's layer bit for bit, and
/// the images do not depend on the thread count.
#[test]
fn strategy_images_sum_to_the_image_and_match_single_strategy_renders() {
    let (scene, camera) = box_scene(true, true, true);
    let settings = IntegratorSettings {
        max_depth: 4,
        light_paths: Some(150),
        ..Default::default()
    };
    let bdpt = Bdpt::new(settings)
        .with_light_paths(150)
        .unwrap()
        .with_strategy_images(99)
        .unwrap();
    // Every strategy of paths up to 5 segments (clamped to the maximum), weighted and not.
    assert_eq!(bdpt.layers().len(), 2 * (1 + 3 + 4 + 5 + 6));
    let film = render_once(&scene, &camera, &bdpt, 20, 6, 3, Some(2));
    let image = film.radiance();
    let mut sum = vec![Rgb::ZERO; image.len()];
    for name in film
        .layer_names()
        .iter()
        .filter(|n| n.ends_with("_weighted"))
    {
        for (acc, p) in sum
            .iter_mut()
            .zip(film.layer(film.layer_index(name).unwrap()))
        {
            *acc += p;
        }
    }
    for (i, (a, b)) in image.iter().zip(&sum).enumerate() {
        assert!(
            (*a - *b).abs().max_element() <= 1e-4 * a.max_element().max(1e-3),
            "pixel {i}: image {a} vs sum of weighted strategies {b}"
        );
    }
    assert!(mean(&image) > 0.0);

    for (s, t, unweighted) in [
        (0, 3, true),
        (1, 3, false),
        (2, 2, true),
        (3, 1, true),
        (4, 1, false),
    ] {
        let single = Bdpt::new(settings)
            .with_light_paths(150)
            .unwrap()
            .with_strategy(StrategyFilter { s, t, unweighted })
            .unwrap();
        let alone = render_once(&scene, &camera, &single, 20, 6, 3, Some(1)).radiance();
        assert_eq!(alone, layer(&film, s, t, !unweighted), "({s},{t})");
        assert!(mean(&alone) > 0.0, "({s},{t}) is black");
    }

    let again = render_once(&scene, &camera, &bdpt, 20, 6, 3, Some(1));
    assert_eq!(again.radiance(), image);
    for (i, _) in film.layer_names().iter().enumerate() {
        assert_eq!(again.layer(i), film.layer(i));
    }
}

#[test]
fn strategy_options_are_validated() {
    for (s, t) in [(0, 0), (1, 0), (3, 0), (0, 1), (1, 1)] {
        let f = StrategyFilter {
            s,
            t,
            unweighted: false,
        };
        assert!(Bdpt::new(IntegratorSettings::default())
            .with_strategy(f)
            .is_err());
    }
    assert!(Bdpt::new(IntegratorSettings::default())
        .with_strategy_images(0)
        .is_err());
    assert!(Bdpt::new(IntegratorSettings::default())
        .with_light_paths(0)
        .is_err());
    let zero = IntegratorSettings {
        light_paths: Some(0),
        ..Default::default()
    };
    assert!(integrator::create("bdpt", zero).is_err());
    let (scene, camera) = box_scene(false, true, false);
    let rs = RenderSettings {
        width: 4,
        height: 4,
        spp: 1,
        ..Default::default()
    };
    let err = render(
        &scene,
        &camera,
        &Bdpt::new(zero),
        &rs,
        &|_| true,
        &AtomicBool::new(false),
    )
    .unwrap_err();
    assert!(err.to_string().contains("at least 1"), "{err}");
}

/// `lacuna render --strategy-images DIR` writes every strategy's images (by default of all
/// path lengths, here up to 3 segments) and the two sheets; the weighted EXRs sum to the
/// rendered EXR.
#[test]
fn command_line_writes_strategy_images() {
    let dir = std::env::temp_dir().join(format!("lacuna-strategies-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let scene = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/cornell-box/cornell-box.json");
    let main = dir.join("main.exr");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_lacuna"))
        .arg("render")
        .arg(&scene)
        .args(["--integrator", "bdpt", "--max-depth", "2", "--width", "12"])
        .args(["--height", "10", "--spp", "2", "--quiet"])
        .arg("--strategy-images")
        .arg(&dir)
        .arg("--out")
        .arg(&main)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let image = lacuna::film::read_exr_rgb(&main).unwrap();
    let mut sum = vec![Rgb::ZERO; image.pixels.len()];
    let mut count = 0;
    for k in 1..=3u32 {
        for s in 0..=k {
            let t = k + 1 - s;
            if k == 1 && s == 1 {
                continue;
            }
            for weighted in [true, false] {
                let name = strategy_layer_name(s, t, weighted);
                assert!(dir.join(format!("{name}.png")).exists(), "{name}.png");
                let layer = lacuna::film::read_exr_rgb(&dir.join(format!("{name}.exr"))).unwrap();
                if weighted {
                    for (acc, p) in sum.iter_mut().zip(&layer.pixels) {
                        *acc += *p;
                    }
                }
                count += 1;
            }
        }
    }
    assert_eq!(count, 2 * (1 + 3 + 4));
    assert!(!dir.join("s0_t5_weighted.exr").exists()); // longer than the longest path
    for (a, b) in image.pixels.iter().zip(&sum) {
        assert!((*a - *b).abs().max_element() <= 1e-4 * a.max_element().max(1e-3));
    }
    assert!(dir.join("weighted.png").exists() && dir.join("unweighted.png").exists());
    let _ = std::fs::remove_dir_all(&dir);
}
