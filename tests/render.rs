//! End-to-end tests of the path tracer against closed-form answers, and its robustness on the
//! hard cases of docs/testing.md: scale, grazing light, near-specular lobes, thread count.

use std::sync::atomic::AtomicBool;

use lacuna::film::Film;
use lacuna::integrator::{self, IntegratorSettings, MisHeuristic};
use lacuna::light::LightDesc;
use lacuna::math::{Rgb, Vec3};
use lacuna::render::{render, RenderSettings};
use lacuna::scene::{two_rooms_builder, Camera, Material, MeshDesc, Scene, SceneBuilder};

/// Adds an axis-aligned box of half-size `h` centred at the origin with faces pointing inwards.
fn add_closed_box(b: &mut SceneBuilder, h: f32, material: u32) {
    let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z) * h;
    let quads = [
        [
            c(-1., -1., -1.),
            c(1., -1., -1.),
            c(1., -1., 1.),
            c(-1., -1., 1.),
        ], // floor, up
        [
            c(-1., 1., 1.),
            c(1., 1., 1.),
            c(1., 1., -1.),
            c(-1., 1., -1.),
        ], // ceiling, down
        [
            c(-1., -1., 1.),
            c(1., -1., 1.),
            c(1., 1., 1.),
            c(-1., 1., 1.),
        ]
        .map(|p| p), // z+ wall
        [
            c(1., -1., -1.),
            c(-1., -1., -1.),
            c(-1., 1., -1.),
            c(1., 1., -1.),
        ], // z- wall
        [
            c(-1., -1., -1.),
            c(-1., -1., 1.),
            c(-1., 1., 1.),
            c(-1., 1., -1.),
        ], // x- wall
        [
            c(1., -1., 1.),
            c(1., -1., -1.),
            c(1., 1., -1.),
            c(1., 1., 1.),
        ], // x+ wall
    ];
    let mut positions = Vec::new();
    let mut indices = Vec::new();
    for q in quads {
        let i = positions.len() as u32;
        // Orient each quad towards the centre whatever order it was written in.
        let n = (q[1] - q[0]).cross(q[2] - q[0]);
        let centre = (q[0] + q[2]) * 0.5;
        let inward = n.dot(-centre) > 0.0;
        positions.extend(q);
        if inward {
            indices.extend([[i, i + 1, i + 2], [i, i + 2, i + 3]]);
        } else {
            indices.extend([[i, i + 2, i + 1], [i, i + 3, i + 2]]);
        }
    }
    b.add_mesh(MeshDesc {
        name: "box".into(),
        positions,
        indices,
        materials: vec![material],
        ..Default::default()
    })
    .unwrap();
}

fn run(scene: &Scene, camera: &Camera, settings: IntegratorSettings, rs: &RenderSettings) -> Film {
    let integrator = integrator::create("path", settings).unwrap();
    render(
        scene,
        camera,
        integrator.as_ref(),
        rs,
        &|_| true,
        &AtomicBool::new(false),
    )
    .unwrap()
    .0
}

fn image_mean(film: &Film) -> Rgb {
    let px = film.radiance();
    px.iter().fold(Rgb::ZERO, |a, &p| a + p) / px.len() as f32
}

/// Mean and standard error of the image mean over independent seeds.
fn mean_and_error(seeds: u64, mut f: impl FnMut(u64) -> f64) -> (f64, f64) {
    let xs: Vec<f64> = (0..seeds).map(&mut f).collect();
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

fn assert_film_finite(film: &Film) {
    for p in film.radiance() {
        assert!(p.is_finite() && p.min_element() >= 0.0, "pixel {p}");
    }
}

/// White furnace: inside a closed box whose walls emit Le and reflect diffusely with albedo a,
/// the radiance everywhere is Le (1 + a + ... + a^D) for paths of at most D bounces, and
/// Le / (1 - a) without a limit.
#[test]
fn white_furnace_matches_closed_form() {
    for (albedo, max_depth) in [(0.5f32, 1u32), (0.5, 3), (0.8, 50)] {
        let mut b = SceneBuilder::new();
        let m = b
            .add_material(Material {
                emission: Rgb::ONE,
                ..Material::diffuse(Rgb::splat(albedo))
            })
            .unwrap();
        add_closed_box(&mut b, 1.0, m);
        let scene = b.build().unwrap();
        let camera = Camera::look_at(
            Vec3::new(0.1, 0.2, 0.3),
            Vec3::new(0.5, 0.1, -1.0),
            Vec3::Y,
            60.0,
        )
        .unwrap();
        let expected = (0..=max_depth)
            .map(|k| (albedo as f64).powi(k as i32))
            .sum::<f64>();
        for mis in [MisHeuristic::Power, MisHeuristic::Balance] {
            let settings = IntegratorSettings {
                max_depth,
                mis: Some(mis),
                ..Default::default()
            };
            let (mean, err) = mean_and_error(6, |seed| {
                let rs = RenderSettings {
                    width: 16,
                    height: 16,
                    spp: 16,
                    seed,
                    ..Default::default()
                };
                image_mean(&run(&scene, &camera, settings, &rs)).x as f64
            });
            assert!(
                (mean - expected).abs() < 4.0 * err + 1e-4 * expected,
                "albedo {albedo}, depth {max_depth}, {mis:?}: {mean} +- {err}, expected {expected}"
            );
        }
    }
}

/// A point light of intensity I at height h over a diffuse plane of albedo rho gives radiance
/// rho / pi * I * cos(theta) / d^2 at every point of the plane.
#[test]
fn point_light_over_plane_matches_closed_form() {
    let (intensity, height, rho) = (10.0f32, 2.0f32, 0.6f32);
    let mut b = SceneBuilder::new();
    let m = b.add_material(Material::diffuse(Rgb::splat(rho))).unwrap();
    let s = 50.0;
    b.add_mesh(MeshDesc {
        positions: vec![
            Vec3::new(-s, 0., -s),
            Vec3::new(s, 0., -s),
            Vec3::new(s, 0., s),
            Vec3::new(-s, 0., s),
        ],
        indices: vec![[0, 2, 1], [0, 3, 2]],
        materials: vec![m],
        ..Default::default()
    })
    .unwrap();
    let light_pos = Vec3::new(0.3, height, -0.2);
    b.add_light(LightDesc::Point {
        position: light_pos,
        intensity: Rgb::splat(intensity),
    })
    .unwrap();
    let scene = b.build().unwrap();
    // Look straight down from above the light so each pixel sees a small patch of the plane.
    let camera = Camera::look_at(Vec3::new(0.0, 6.0, 0.0), Vec3::ZERO, Vec3::Z, 50.0).unwrap();
    let rs = RenderSettings {
        width: 32,
        height: 32,
        spp: 1024,
        ..Default::default()
    };
    let film = run(
        &scene,
        &camera,
        IntegratorSettings {
            max_depth: 1,
            ..Default::default()
        },
        &rs,
    );
    let frame = camera.frame(1.0);
    for y in 0..32 {
        for x in 0..32 {
            // Closed form averaged over the pixel footprint by a 4x4 sub-grid.
            let mut expected = 0.0f64;
            for sy in 0..4 {
                for sx in 0..4 {
                    let fp = lacuna::math::Vec2::new(
                        (x as f32 + (sx as f32 + 0.5) / 4.0) / 32.0,
                        (y as f32 + (sy as f32 + 0.5) / 4.0) / 32.0,
                    );
                    let ray = frame.generate_ray(fp, lacuna::math::Vec2::ZERO);
                    let t = -ray.origin.y / ray.dir.y;
                    let p = ray.at(t);
                    let d = light_pos - p;
                    let cos = d.y / d.length();
                    expected += (rho / std::f32::consts::PI * intensity * cos / d.length_squared())
                        as f64
                        / 16.0;
                }
            }
            let got = film.pixel(x, y).x as f64;
            assert!(
                (got - expected).abs() < 0.01 * expected,
                "pixel ({x},{y}): {got} vs {expected}"
            );
        }
    }
}

/// Same seed and sample budget give the same image bit for bit on 1 and 2 threads.
#[test]
fn rendering_is_independent_of_thread_count() {
    let scene = two_rooms_builder().unwrap().build().unwrap();
    let camera = *scene.camera().unwrap();
    let mk = |threads| RenderSettings {
        width: 40,
        height: 24,
        spp: 6,
        seed: 42,
        threads: Some(threads),
        ..Default::default()
    };
    let a = run(&scene, &camera, IntegratorSettings::default(), &mk(1));
    let b = run(&scene, &camera, IntegratorSettings::default(), &mk(2));
    let c = run(&scene, &camera, IntegratorSettings::default(), &mk(3));
    assert_eq!(a.radiance(), b.radiance());
    assert_eq!(a.radiance(), c.radiance());
    assert_film_finite(&a);
    let d = run(
        &scene,
        &camera,
        IntegratorSettings::default(),
        &RenderSettings { seed: 43, ..mk(2) },
    );
    assert_ne!(a.radiance(), d.radiance());
}

/// A closed room with a small ceiling light, a box and a glossy floor, at any scale:
/// radiance is scale invariant, so the image means must agree across 1e-4, 1 and 1e4 — any
/// self-intersection or shadow acne at one scale would darken it.
#[test]
fn scale_invariance_from_1e_minus_4_to_1e4() {
    let build = |scale: f32| {
        let mut b = SceneBuilder::new();
        let wall = b.add_material(Material::diffuse(Rgb::splat(0.6))).unwrap();
        let floor = b
            .add_material(Material::glossy(Rgb::splat(0.3), Rgb::splat(0.5), 1e4))
            .unwrap();
        let light = b
            .add_material(Material::emissive(Rgb::splat(20.0)))
            .unwrap();
        add_closed_box(&mut b, scale, wall);
        let p = |x: f32, y: f32, z: f32| Vec3::new(x, y, z) * scale;
        // Light facing down just below the ceiling; a glossy slab on the floor.
        b.add_mesh(MeshDesc {
            positions: vec![
                p(-0.2, 0.99, -0.2),
                p(0.2, 0.99, -0.2),
                p(0.2, 0.99, 0.2),
                p(-0.2, 0.99, 0.2),
            ],
            indices: vec![[0, 1, 2], [0, 2, 3]],
            materials: vec![light],
            ..Default::default()
        })
        .unwrap();
        b.add_mesh(MeshDesc {
            positions: vec![
                p(-0.6, -0.999, -0.6),
                p(0.6, -0.999, -0.6),
                p(0.6, -0.999, 0.6),
                p(-0.6, -0.999, 0.6),
            ],
            indices: vec![[0, 2, 1], [0, 3, 2]],
            materials: vec![floor],
            ..Default::default()
        })
        .unwrap();
        let scene = b.build().unwrap();
        let camera = Camera::look_at(p(0.0, 0.2, 0.95), p(0.0, -0.5, 0.0), Vec3::Y, 70.0).unwrap();
        (scene, camera)
    };
    let mut means = Vec::new();
    for scale in [1e-4f32, 1.0, 1e4] {
        let (scene, camera) = build(scale);
        let (mean, err) = mean_and_error(6, |seed| {
            let rs = RenderSettings {
                width: 24,
                height: 24,
                spp: 16,
                seed,
                ..Default::default()
            };
            let film = run(&scene, &camera, IntegratorSettings::default(), &rs);
            assert_film_finite(&film);
            image_mean(&film).x as f64
        });
        means.push((scale, mean, err));
    }
    let (_, m1, e1) = means[1];
    for &(scale, m, e) in &means {
        assert!(
            (m - m1).abs() < 4.0 * (e * e + e1 * e1).sqrt(),
            "scale {scale}: mean {m} +- {e} vs {m1} +- {e1}"
        );
    }
}

/// The built-in scene renders without NaN, with light reaching the camera room through the
/// door, on every MIS heuristic and at depths 0, 1 and 8; a directional light at grazing
/// incidence and a spot light also stay finite.
#[test]
fn hard_lighting_cases_stay_finite() {
    let scene = two_rooms_builder().unwrap().build().unwrap();
    let camera = *scene.camera().unwrap();
    for depth in [0, 1, 8] {
        let rs = RenderSettings {
            width: 32,
            height: 32,
            spp: 4,
            ..Default::default()
        };
        let film = run(
            &scene,
            &camera,
            IntegratorSettings {
                max_depth: depth,
                ..Default::default()
            },
            &rs,
        );
        assert_film_finite(&film);
        if depth == 8 {
            assert!(image_mean(&film).x > 0.0);
        }
    }
    let mut b = SceneBuilder::new();
    let m = b
        .add_material(Material::glossy(Rgb::splat(0.2), Rgb::splat(0.8), 1e4))
        .unwrap();
    b.add_mesh(MeshDesc {
        positions: vec![
            Vec3::new(-1., 0., -1.),
            Vec3::new(1., 0., -1.),
            Vec3::new(1., 0., 1.),
            Vec3::new(-1., 0., 1.),
        ],
        indices: vec![[0, 2, 1], [0, 3, 2]],
        materials: vec![m],
        ..Default::default()
    })
    .unwrap();
    b.add_light(LightDesc::Directional {
        direction: Vec3::new(1.0, -1e-4, 0.0),
        irradiance: Rgb::splat(5.0),
    })
    .unwrap();
    b.add_light(LightDesc::Spot {
        position: Vec3::new(0.0, 1e-3, 0.0),
        direction: Vec3::X,
        intensity: Rgb::splat(100.0),
        inner_degrees: 10.0,
        outer_degrees: 89.9,
    })
    .unwrap();
    let scene = b.build().unwrap();
    let camera = Camera::look_at(Vec3::new(0.0, 1e-3, 3.0), Vec3::ZERO, Vec3::Y, 40.0).unwrap();
    let film = run(
        &scene,
        &camera,
        IntegratorSettings::default(),
        &RenderSettings {
            width: 32,
            height: 32,
            spp: 8,
            ..Default::default()
        },
    );
    assert_film_finite(&film);
}

/// A progress callback that returns false stops the render; what completed passes gathered is
/// kept and every pixel has the same count. A time budget stops on time.
#[test]
fn cancellation_and_time_budget() {
    use std::sync::atomic::{AtomicU32, Ordering};
    use std::time::Duration;
    let scene = two_rooms_builder().unwrap().build().unwrap();
    let camera = *scene.camera().unwrap();
    let integrator = integrator::create("path", IntegratorSettings::default()).unwrap();
    let calls = AtomicU32::new(0);
    let rs = RenderSettings {
        width: 64,
        height: 64,
        spp: 1000,
        pass_spp: 1,
        ..Default::default()
    };
    // 16 tiles a pass: cancel during the third pass.
    let (film, stats) = render(
        &scene,
        &camera,
        integrator.as_ref(),
        &rs,
        &|_| calls.fetch_add(1, Ordering::Relaxed) < 40,
        &AtomicBool::new(false),
    )
    .unwrap();
    assert!(stats.cancelled);
    assert_eq!(stats.spp, 2);
    assert_eq!(film.min_samples(), 2);
    assert_eq!(film.total_samples(), 2 * 64 * 64);

    let cancel = AtomicBool::new(true);
    let (film, stats) = render(
        &scene,
        &camera,
        integrator.as_ref(),
        &rs,
        &|_| true,
        &cancel,
    )
    .unwrap();
    assert!(stats.cancelled && film.total_samples() == 0);

    let rs = RenderSettings {
        spp: u32::MAX,
        time_limit: Some(Duration::from_millis(300)),
        ..rs
    };
    let (film, stats) = render(
        &scene,
        &camera,
        integrator.as_ref(),
        &rs,
        &|_| true,
        &AtomicBool::new(false),
    )
    .unwrap();
    // With an unbounded sample budget, only the clock can have stopped it.
    assert!(!stats.cancelled && stats.spp >= 1 && stats.spp < u32::MAX);
    assert_eq!(film.min_samples(), stats.spp);

    let bad = RenderSettings {
        width: 0,
        ..Default::default()
    };
    assert!(render(
        &scene,
        &camera,
        integrator.as_ref(),
        &bad,
        &|_| true,
        &AtomicBool::new(false)
    )
    .is_err());
}
