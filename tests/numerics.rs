//! Hard numerical cases (issue 29), each a named test: the scene is either refused with a clear
//! error or renders with every pixel finite (radiance, albedo, normal, depth), with every
//! integrator alike. Images are tiny: these test robustness, not convergence.

mod common;

use std::sync::atomic::AtomicBool;

use common::shapes::quad;
use lacuna::film::Film;
use lacuna::integrator::{self, IntegratorSettings};
use lacuna::light::LightDesc;
use lacuna::math::{Rgb, Vec3};
use lacuna::render::{render, RenderSettings};
use lacuna::scene::{Camera, Material, MeshDesc, Scene, SceneBuilder};

/// A floor quad of half-size `h` at y = 0 facing up, with `material`.
fn floor(b: &mut SceneBuilder, h: f32, material: u32) {
    quad(
        b,
        [
            Vec3::new(-h, 0.0, -h),
            Vec3::new(-h, 0.0, h),
            Vec3::new(h, 0.0, h),
            Vec3::new(h, 0.0, -h),
        ],
        material,
    );
}

/// An emissive quad of half-size `h` at height `y` facing down.
fn ceiling_light(b: &mut SceneBuilder, h: f32, y: f32, radiance: f32) {
    let m = b
        .add_material(Material::emissive(Rgb::splat(radiance)))
        .unwrap();
    quad(
        b,
        [
            Vec3::new(-h, y, -h),
            Vec3::new(h, y, -h),
            Vec3::new(h, y, h),
            Vec3::new(-h, y, h),
        ],
        m,
    );
}

fn grey(b: &mut SceneBuilder) -> u32 {
    b.add_material(Material::diffuse(Rgb::splat(0.5))).unwrap()
}

fn assert_finite_film(film: &Film, what: &str) {
    let rgb = [film.radiance(), film.albedo(), film.normal()];
    for (channel, pixels) in ["radiance", "albedo", "normal"].iter().zip(rgb) {
        if let Some((i, p)) = pixels.iter().enumerate().find(|(_, p)| !p.is_finite()) {
            panic!("{what}: {channel} of pixel {i} is {p:?}");
        }
    }
    if let Some(d) = film
        .depth()
        .iter()
        .find(|d| !(d.is_finite() || **d == f32::INFINITY))
    {
        panic!("{what}: depth {d}");
    }
}

/// Renders with every registered integrator (16x16, 4 spp) and checks every pixel is finite.
/// These scenes are lit by area lights, which every integrator renders: none may refuse them.
fn renders_finite(scene: &Scene, camera: &Camera, what: &str) {
    let settings = RenderSettings {
        width: 16,
        height: 16,
        spp: 4,
        threads: Some(2),
        ..Default::default()
    };
    for name in integrator::names() {
        let mut integrator = integrator::create(name, IntegratorSettings::default()).unwrap();
        lacuna::render::prepare(integrator.as_mut(), scene, camera, Some(2), &|_, _| true)
            .unwrap_or_else(|e| panic!("{what} ({name}): preparation failed: {e}"));
        let (film, _) = render(
            scene,
            camera,
            integrator.as_ref(),
            &settings,
            &|_| true,
            &AtomicBool::new(false),
        )
        .unwrap_or_else(|e| panic!("{what} ({name}): {e}"));
        assert_finite_film(&film, &format!("{what} ({name})"));
    }
}

fn camera(eye: Vec3, target: Vec3) -> Camera {
    Camera::look_at(eye, target, Vec3::Y, 45.0).unwrap()
}

#[test]
fn tiny_and_huge_coordinates_together() {
    let mut b = SceneBuilder::new();
    let m = grey(&mut b);
    // A floor 1e6 across with a 1e-5 triangle at the camera's target.
    floor(&mut b, 1e6, m);
    b.add_mesh(MeshDesc {
        name: "speck".into(),
        positions: vec![
            Vec3::new(0.0, 1e-5, 0.0),
            Vec3::new(1e-5, 1e-5, 0.0),
            Vec3::new(0.0, 2e-5, 0.0),
        ],
        indices: vec![[0, 1, 2]],
        materials: vec![m],
        ..Default::default()
    })
    .unwrap();
    ceiling_light(&mut b, 1e5, 1e6, 1.0);
    let scene = b.build().unwrap();
    renders_finite(
        &scene,
        &camera(Vec3::new(0.0, 3e-5, 5e-5), Vec3::new(0.0, 1e-5, 0.0)),
        "1e-5 next to 1e6",
    );
    renders_finite(
        &scene,
        &camera(Vec3::new(0.0, 5e5, 5e5), Vec3::ZERO),
        "1e6 view of a 1e-5 speck",
    );
}

#[test]
fn camera_inside_a_closed_mesh() {
    let mut b = SceneBuilder::new();
    let m = grey(&mut b);
    // A closed box seen from inside; the light is outside, so only darkness (and no NaN).
    let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    let corners = [
        c(-1., -1., -1.),
        c(1., -1., -1.),
        c(1., 1., -1.),
        c(-1., 1., -1.),
        c(-1., -1., 1.),
        c(1., -1., 1.),
        c(1., 1., 1.),
        c(-1., 1., 1.),
    ];
    let faces: [[u32; 4]; 6] = [
        [0, 1, 2, 3],
        [5, 4, 7, 6],
        [4, 0, 3, 7],
        [1, 5, 6, 2],
        [3, 2, 6, 7],
        [4, 5, 1, 0],
    ];
    b.add_mesh(MeshDesc {
        name: "closed".into(),
        positions: corners.to_vec(),
        indices: faces
            .iter()
            .flat_map(|f| [[f[0], f[1], f[2]], [f[0], f[2], f[3]]])
            .collect(),
        materials: vec![m],
        ..Default::default()
    })
    .unwrap();
    ceiling_light(&mut b, 0.5, 3.0, 10.0);
    b.add_light(LightDesc::Point {
        position: Vec3::new(0.0, 0.5, 0.0),
        intensity: Rgb::splat(1.0),
    })
    .unwrap();
    let scene = b.build().unwrap();
    renders_finite(
        &scene,
        &camera(Vec3::new(0.2, 0.1, 0.3), Vec3::new(0.0, 0.0, -1.0)),
        "camera inside a closed box",
    );
}

#[test]
fn lights_of_1e20() {
    let mut b = SceneBuilder::new();
    let m = grey(&mut b);
    floor(&mut b, 2.0, m);
    ceiling_light(&mut b, 0.3, 2.0, 1e20);
    b.add_light(LightDesc::Point {
        position: Vec3::new(0.5, 1.0, 0.0),
        intensity: Rgb::splat(1e20),
    })
    .unwrap();
    b.add_light(LightDesc::Directional {
        direction: Vec3::new(0.2, -1.0, 0.1),
        irradiance: Rgb::splat(1e20),
    })
    .unwrap();
    let scene = b.build().unwrap();
    renders_finite(
        &scene,
        &camera(Vec3::new(0.0, 1.0, 3.0), Vec3::ZERO),
        "lights of 1e20",
    );
}

/// IORs of 1e-6 and 1e30 are either refused by validation or render finite.
#[test]
fn extreme_indices_of_refraction() {
    for ior in [1e-6f32, 1e30] {
        let mut b = SceneBuilder::new();
        let m = grey(&mut b);
        floor(&mut b, 2.0, m);
        ceiling_light(&mut b, 0.5, 2.0, 10.0);
        let glass = match b.add_material(Material::dielectric(ior)) {
            Ok(g) => g,
            Err(e) => {
                assert!(e.to_string().contains("ior"), "{e}");
                continue;
            }
        };
        quad(
            &mut b,
            [
                Vec3::new(-0.5, 0.5, -0.5),
                Vec3::new(-0.5, 0.5, 0.5),
                Vec3::new(0.5, 0.5, 0.5),
                Vec3::new(0.5, 0.5, -0.5),
            ],
            glass,
        );
        let scene = b.build().unwrap();
        renders_finite(
            &scene,
            &camera(Vec3::new(0.0, 1.5, 1.5), Vec3::ZERO),
            &format!("ior {ior:e}"),
        );
    }
}

#[test]
fn grazing_angles() {
    let mut b = SceneBuilder::new();
    let m = grey(&mut b);
    let glossy = b
        .add_material(Material::glossy(Rgb::splat(0.2), Rgb::splat(0.7), 1e4))
        .unwrap();
    let mirror = b.add_material(Material::mirror(Rgb::splat(0.9))).unwrap();
    floor(&mut b, 10.0, glossy);
    quad(
        &mut b,
        [
            Vec3::new(-10.0, 0.0, -10.0),
            Vec3::new(-10.0, 1.0, -10.0),
            Vec3::new(10.0, 1.0, -10.0),
            Vec3::new(10.0, 0.0, -10.0),
        ],
        mirror,
    );
    // A light in the plane of the floor, and one just above it.
    b.add_light(LightDesc::Point {
        position: Vec3::new(0.0, 0.0, 5.0),
        intensity: Rgb::splat(10.0),
    })
    .unwrap();
    b.add_light(LightDesc::Directional {
        direction: Vec3::new(1.0, -1e-6, 0.0),
        irradiance: Rgb::splat(1.0),
    })
    .unwrap();
    let _ = m;
    let scene = b.build().unwrap();
    // The eye in the floor's plane, and just above it.
    renders_finite(
        &scene,
        &camera(Vec3::new(0.0, 0.0, 9.0), Vec3::new(0.0, 0.0, -10.0)),
        "eye in the plane of the floor",
    );
    renders_finite(
        &scene,
        &camera(Vec3::new(0.0, 1e-6, 9.0), Vec3::new(0.0, 1e-6, -10.0)),
        "eye 1e-6 above the floor",
    );
}

/// Many copies of one triangle (a small count: the builder's cost on large counts is the BVH
/// work of issue 29 #1).
#[test]
fn duplicate_triangles() {
    let mut b = SceneBuilder::new();
    let m = grey(&mut b);
    let light = b.add_material(Material::emissive(Rgb::splat(5.0))).unwrap();
    let tri = [
        Vec3::new(-1.0, 0.0, -1.0),
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::new(1.0, 0.0, -1.0),
    ];
    let copies = 500;
    b.add_mesh(MeshDesc {
        name: "copies".into(),
        positions: (0..copies).flat_map(|_| tri).collect(),
        indices: (0..copies as u32)
            .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect(),
        materials: vec![m],
        ..Default::default()
    })
    .unwrap();
    // Coincident emitters too: every copy of the light is sampled.
    b.add_mesh(MeshDesc {
        name: "light copies".into(),
        positions: (0..50)
            .flat_map(|_| tri.map(|p| p + Vec3::Y * 2.0))
            .collect(),
        indices: (0..50u32).map(|i| [3 * i, 3 * i + 2, 3 * i + 1]).collect(),
        materials: vec![light],
        ..Default::default()
    })
    .unwrap();
    let scene = b.build().unwrap();
    renders_finite(
        &scene,
        &camera(Vec3::new(0.0, 1.0, 3.0), Vec3::ZERO),
        "duplicate triangles",
    );
}

#[test]
fn lens_radius_of_1e6() {
    let mut b = SceneBuilder::new();
    let m = grey(&mut b);
    floor(&mut b, 2.0, m);
    ceiling_light(&mut b, 0.5, 2.0, 10.0);
    let scene = b.build().unwrap();
    let lens = camera(Vec3::new(0.0, 1.0, 3.0), Vec3::ZERO)
        .with_thin_lens(1e6, 3.0)
        .unwrap();
    renders_finite(&scene, &lens, "lens radius 1e6");
}
