//! Agreement of integrators: the image mean and region means of a renderer against another's,
//! by a z-test on their measured standard errors over seeds, and the small box scene with
//! every BSDF and light kind (an IES profile among them) that several agreement tests render.

use std::sync::atomic::AtomicBool;

use lacuna::film::Film;
use lacuna::integrator::{self, Integrator, IntegratorSettings};
use lacuna::light::LightDesc;
use lacuna::math::{Rgb, SamplerKind, Vec3};
use lacuna::render::{render, RenderSettings};
use lacuna::scene::{Camera, Material, MeshDesc, Scene, SceneBuilder};

use super::shapes::{open_box, quad, OpenBoxMaterials};

/// Renders to completion, without progress reports or cancellation: what most tests need.
pub fn render_image(
    scene: &Scene,
    camera: &Camera,
    integrator: &dyn Integrator,
    settings: &RenderSettings,
) -> Film {
    let (film, _) = render(
        scene,
        camera,
        integrator,
        settings,
        &|_| true,
        &AtomicBool::new(false),
    )
    .unwrap();
    film
}

/// Means of the whole image and of its four quadrants, with standard errors over seeds, of the
/// integrator `name` (a spec: `name[:key=value]...`), prepared for the scene first; with
/// independent numbers, not the default Sobol sampler: the integrators' agreement tests need
/// a standard error that is honest for heavy-tailed estimators (a rare light path through a
/// sharp lobe or a small opening), and stratified samples shrink the seed spread of the bulk
/// while the tail stays, so at test sample counts their spread understates the error
/// (BENCHMARKS.md, "Quiet machine, round 4"). Sobol's own unbiasedness is tested in
/// tests/sampler.rs.
pub fn region_means(
    scene: &Scene,
    camera: &Camera,
    name: &str,
    settings: IntegratorSettings,
    size: u32,
    spp: u32,
    seeds: u64,
) -> Vec<(f64, f64)> {
    region_means_with(
        scene,
        camera,
        name,
        settings,
        SamplerKind::Independent,
        size,
        spp,
        seeds,
    )
}

/// [`region_means`] with the pixel sampler `sampler`. The standard errors come from the spread
/// of the per-seed means (each seed is an independent render: new random numbers, or new
/// scrambles and shuffles of the Sobol points), never from the spread of samples within a
/// pixel, which stratified samples do not have independently.
#[allow(clippy::too_many_arguments)]
pub fn region_means_with(
    scene: &Scene,
    camera: &Camera,
    name: &str,
    settings: IntegratorSettings,
    sampler: SamplerKind,
    size: u32,
    spp: u32,
    seeds: u64,
) -> Vec<(f64, f64)> {
    let mut integrator = integrator::create(name, settings).unwrap();
    lacuna::render::prepare(integrator.as_mut(), scene, camera, None, &|_, _| true).unwrap();
    let runs: Vec<Vec<f64>> = (0..seeds)
        .map(|seed| {
            let rs = RenderSettings {
                width: size,
                height: size,
                spp,
                seed: seed * 7919 + 1,
                sampler,
                ..Default::default()
            };
            let film = render_image(scene, camera, integrator.as_ref(), &rs);
            let px = film.radiance();
            for p in &px {
                assert!(p.is_finite() && p.min_element() >= 0.0, "{name}: pixel {p}");
            }
            let mut sums = [0.0f64; 5];
            let h = size / 2;
            for y in 0..size {
                for x in 0..size {
                    let v = px[(y * size + x) as usize].element_sum() as f64 / 3.0;
                    sums[0] += v;
                    sums[1 + (y / h * 2 + x / h) as usize] += v;
                }
            }
            let n = (size * size) as f64;
            vec![
                sums[0] / n,
                sums[1] * 4.0 / n,
                sums[2] * 4.0 / n,
                sums[3] * 4.0 / n,
                sums[4] * 4.0 / n,
            ]
        })
        .collect();
    (0..5)
        .map(|k| {
            let xs: Vec<f64> = runs.iter().map(|r| r[k]).collect();
            let n = xs.len() as f64;
            let mean = xs.iter().sum::<f64>() / n;
            let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
            (mean, (var / n).sqrt())
        })
        .collect()
}

/// z-test of every region mean at 4.5 sigma (Bonferroni-safe over the regions and scenes).
pub fn assert_agree(label: &str, a: (&str, &[(f64, f64)]), b: (&str, &[(f64, f64)])) {
    let ((na, a), (nb, b)) = (a, b);
    for (k, ((ma, ea), (mb, eb))) in a.iter().zip(b).enumerate() {
        let sigma = (ea * ea + eb * eb).sqrt();
        assert!(
            (ma - mb).abs() <= 4.5 * sigma + 1e-6 * ma.abs().max(mb.abs()),
            "{label} region {k}: {na} {ma} +- {ea}, {nb} {mb} +- {eb}"
        );
    }
}

/// Renders `path` and each of `specs` over 8 seeds at `size` x `size`, `spp` samples and
/// `max_depth`, and z-tests their region means ([`assert_agree`]).
pub fn agree_with_path(
    label: &str,
    scene: &Scene,
    camera: &Camera,
    max_depth: u32,
    size: u32,
    spp: u32,
    specs: &[&str],
) {
    let settings = IntegratorSettings {
        max_depth,
        ..Default::default()
    };
    let path = region_means(scene, camera, "path", settings, size, spp, 8);
    assert!(path[0].0 > 0.0, "{label}: black image");
    for spec in specs {
        let other = region_means(scene, camera, spec, settings, size, spp, 8);
        assert_agree(label, ("path", &path), (spec, &other));
    }
}

/// Renders `path`, `bdpt` and each of `specs` (bidirectional variants) with the scene's camera
/// over 8 seeds, and z-tests each variant's region means against both.
pub fn agree_with_path_and_bdpt(
    label: &str,
    scene: &Scene,
    (max_depth, size, spp): (u32, u32, u32),
    specs: &[&str],
) {
    let camera = *scene.camera().unwrap();
    let settings = IntegratorSettings {
        max_depth,
        ..Default::default()
    };
    let path = region_means(scene, &camera, "path", settings, size, spp, 8);
    assert!(path[0].0 > 0.0, "{label}: black image");
    let bdpt = region_means(scene, &camera, "bdpt", settings, size, spp, 8);
    for spec in specs {
        let other = region_means(scene, &camera, spec, settings, size, spp, 8);
        assert_agree(label, ("path", &path), (spec, &other));
        assert_agree(label, ("bdpt", &bdpt), (spec, &other));
    }
}

/// A scene file of the repository (`scenes/...`), built.
pub fn load_scene(path: &str) -> Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(path);
    lacuna::scene::load_scene_file(&path)
        .unwrap()
        .builder
        .build()
        .unwrap()
}

/// [`agree_with_path`] on the built-in corridor (the light far from the camera), at the depth,
/// size and samples the guide's test files share: one place, so they test at the same strength.
pub fn agree_on_corridor(specs: &[&str]) {
    let scene = lacuna::scene::corridor_builder().unwrap().build().unwrap();
    let camera = *scene.camera().unwrap();
    agree_with_path("corridor", &scene, &camera, 8, 16, 64, specs);
}

/// [`agree_with_path`] on the built-in two-room scene (light through one opening).
pub fn agree_on_two_rooms(specs: &[&str]) {
    let scene = lacuna::scene::two_rooms_builder().unwrap().build().unwrap();
    let camera = *scene.camera().unwrap();
    agree_with_path("two rooms", &scene, &camera, 6, 20, 16, specs);
}

/// [`agree_with_path`] on the Veach door scene of `scenes/`.
pub fn agree_on_veach_door(specs: &[&str]) {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    let camera = *scene.camera().unwrap();
    agree_with_path("veach door", &scene, &camera, 6, 16, 16, specs);
}

/// A box open at the top with glossy (exponent 50 and 1e4), mirror and glass surfaces, a small
/// area light, and optionally point, spot and directional lights.
pub fn box_scene(delta_bsdfs: bool, area_light: bool, delta_lights: bool) -> (Scene, Camera) {
    let mut b = SceneBuilder::new();
    let wall = b
        .add_material(Material::diffuse(Rgb::new(0.7, 0.6, 0.5)))
        .unwrap();
    let glossy = b
        .add_material(Material::glossy(Rgb::splat(0.3), Rgb::splat(0.5), 50.0))
        .unwrap();
    let sharp = b
        .add_material(Material::glossy(Rgb::splat(0.2), Rgb::splat(0.7), 1e4))
        .unwrap();
    let mirror = b.add_material(Material::mirror(Rgb::splat(0.9))).unwrap();
    let glass = b.add_material(Material::dielectric(1.5)).unwrap();
    let light = b
        .add_material(Material::emissive(Rgb::splat(15.0)))
        .unwrap();
    open_box(
        &mut b,
        OpenBoxMaterials {
            floor: glossy,
            back: wall,
            left: if delta_bsdfs { mirror } else { wall },
            right: sharp,
        },
    );
    let v = Vec3::new;
    if delta_bsdfs {
        quad(
            &mut b,
            [
                v(-0.3, -0.2, -0.3),
                v(0.3, -0.2, -0.3),
                v(0.3, -0.2, 0.3),
                v(-0.3, -0.2, 0.3),
            ],
            glass,
        );
    }
    if area_light {
        quad(
            &mut b,
            [
                v(-0.2, 0.9, -0.5),
                v(0.2, 0.9, -0.5),
                v(0.2, 0.9, -0.1),
                v(-0.2, 0.9, -0.1),
            ],
            light,
        );
    }
    if delta_lights {
        b.add_light(LightDesc::Point {
            position: v(0.5, 0.5, 0.0),
            intensity: Rgb::splat(2.0),
        })
        .unwrap();
        b.add_light(LightDesc::Spot {
            position: v(-0.5, 0.8, 0.5),
            direction: v(0.2, -1.0, -0.3),
            intensity: Rgb::splat(4.0),
            inner_degrees: 15.0,
            outer_degrees: 35.0,
        })
        .unwrap();
        b.add_light(LightDesc::Directional {
            direction: v(0.3, -1.0, -0.2),
            irradiance: Rgb::splat(1.5),
        })
        .unwrap();
        // An asymmetric measured profile, so that light tracing's emission sampling and
        // next-event estimation must agree on its orientation.
        let ies =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/ies/wallwasher.ies");
        b.add_light(LightDesc::Photometric {
            position: v(0.55, 0.85, -0.5),
            direction: v(-0.2, -1.0, 0.1),
            c0: v(-1.0, 0.0, 0.0),
            intensity: Rgb::splat(0.004),
            profile: std::sync::Arc::new(
                lacuna::light::PhotometricProfile::from_file(&ies).unwrap(),
            ),
        })
        .unwrap();
    }
    let scene = b.build().unwrap();
    let camera = Camera::look_at(v(0.0, 0.2, 3.0), v(0.0, -0.2, 0.0), Vec3::Y, 50.0).unwrap();
    (scene, camera)
}

/// Frosted glass (the GGX rough dielectric): a closed rough-glass box with a point light inside
/// (the frosted lamp: light leaves only through rough refraction, entering and leaving), a
/// rough pane under the area light, diffuse walls of an [`open_box`].
pub fn rough_glass_room() -> (Scene, Camera) {
    let mut b = SceneBuilder::new();
    let wall = b
        .add_material(Material::diffuse(Rgb::new(0.7, 0.6, 0.5)))
        .unwrap();
    let frosted = b
        .add_material(Material::rough_dielectric(1.5, 0.3))
        .unwrap();
    let pane = b
        .add_material(Material::rough_dielectric(1.3, 0.1))
        .unwrap();
    let light = b
        .add_material(Material::emissive(Rgb::splat(15.0)))
        .unwrap();
    // Room: floor, back wall, two side walls (open towards the camera and the ceiling).
    open_box(
        &mut b,
        OpenBoxMaterials {
            floor: wall,
            back: wall,
            left: wall,
            right: wall,
        },
    );
    // Area light facing down, the rough pane below it.
    quad(
        &mut b,
        [
            Vec3::new(-0.2, 0.9, -0.5),
            Vec3::new(0.2, 0.9, -0.5),
            Vec3::new(0.2, 0.9, -0.1),
            Vec3::new(-0.2, 0.9, -0.1),
        ],
        light,
    );
    quad(
        &mut b,
        [
            Vec3::new(-0.4, 0.7, -0.7),
            Vec3::new(0.4, 0.7, -0.7),
            Vec3::new(0.4, 0.7, 0.1),
            Vec3::new(-0.4, 0.7, 0.1),
        ],
        pane,
    );
    // A closed frosted box (outward normals) around a point light.
    let (lo, hi) = (Vec3::new(-0.25, -0.6, -0.25), Vec3::new(0.25, -0.1, 0.25));
    let c = |i: usize| {
        Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    };
    b.add_mesh(MeshDesc {
        positions: (0..8).map(c).collect(),
        indices: vec![
            [0, 1, 5],
            [0, 5, 4],
            [2, 6, 7],
            [2, 7, 3], // y faces
            [0, 4, 6],
            [0, 6, 2],
            [1, 3, 7],
            [1, 7, 5], // x faces
            [0, 2, 3],
            [0, 3, 1],
            [4, 5, 7],
            [4, 7, 6], // z faces
        ],
        materials: vec![frosted],
        ..Default::default()
    })
    .unwrap();
    b.add_light(LightDesc::Point {
        position: Vec3::new(0.0, -0.35, 0.0),
        intensity: Rgb::splat(1.5),
    })
    .unwrap();
    let scene = b.build().unwrap();
    let camera = Camera::look_at(
        Vec3::new(0.0, 0.2, 3.2),
        Vec3::new(0.0, -0.2, 0.0),
        Vec3::Y,
        45.0,
    )
    .unwrap();
    (scene, camera)
}
