//! Environment-map lights (issue 9; 001 chapter 3):
//!
//! - every sampling strategy (lat-long 2-D, cube faces with uniform, power and per-normal
//!   dynamic balancing) on several maps, the sun map among them: the pdf integrates to 1
//!   over the sphere (midpoint quadrature, independent of the sampler's tables); samples
//!   carry the pdf `pdf()` gives; sampled directions pass a chi-square test against the
//!   integrated pdf over blocks of texels;
//! - a uniform white environment around a diffuse sphere: radiance albedo x L everywhere on
//!   the sphere (a convex object sees only the sky), with path (each strategy), bdpt and
//!   env_direct;
//! - rendering with each strategy agrees with the others, with BSDF-only sampling, with bdpt
//!   and (direct lighting) with env_direct, by z-tests on the image and region means;
//! - a sun 1e6 brighter than the sky gives no fireflies beyond what MIS allows;
//! - loaders: .exr and .hdr of the same map agree, bad files and bad texels give clear errors,
//!   zero rows and black maps keep the CDFs valid.

mod common;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use common::agreement::render_image;
use common::chi2::{assert_chi2, Stats};
use lacuna::integrator::{self, IntegratorSettings, MisHeuristic};
use lacuna::light::environment::{EnvImage, Grid};
use lacuna::light::{EnvSettings, EnvStrategy, EnvironmentMap};
use lacuna::math::{luminance, warp, Rgb, Rng, SamplerKind, Vec3, PI};
use lacuna::render::RenderSettings;
use lacuna::scene::{Camera, Material, MeshDesc, Scene, SceneBuilder};

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

fn load(name: &str) -> EnvironmentMap {
    EnvironmentMap::load(
        &repo(&format!("scenes/envmaps/{name}")),
        EnvSettings::default(),
    )
    .unwrap()
}

/// A synthetic lat-long map: a smooth sky, a few zero rows below the horizon, and a "sun" of
/// `sun` over a 2 x 2 texel patch.
fn synthetic(width: usize, height: usize, sun: f32) -> EnvironmentMap {
    let grid = Grid::LatLong { width, height };
    let texels = (0..grid.texel_count())
        .map(|i| {
            let (row, col) = (i / width, i % width);
            if row >= height * 5 / 8 && row < height * 3 / 4 {
                return Rgb::ZERO;
            }
            let d = grid.texel_point(i, 0.5, 0.5);
            let mut c = Rgb::new(0.4 + 0.6 * d.y.max(0.0), 0.5 + 0.3 * d.x * d.x, 0.8);
            if (row == height / 5 || row == height / 5 + 1)
                && (col == width / 3 || col == width / 3 + 1)
            {
                c += Rgb::splat(sun);
            }
            c
        })
        .collect();
    EnvironmentMap::new(EnvImage::new(grid, texels).unwrap(), EnvSettings::default()).unwrap()
}

fn constant(value: f32) -> EnvironmentMap {
    let grid = Grid::LatLong {
        width: 16,
        height: 8,
    };
    let texels = vec![Rgb::splat(value); grid.texel_count()];
    EnvironmentMap::new(EnvImage::new(grid, texels).unwrap(), EnvSettings::default()).unwrap()
}

const STRATEGIES: [EnvStrategy; 4] = [
    EnvStrategy::LatLong,
    EnvStrategy::CubeUniform,
    EnvStrategy::CubePower,
    EnvStrategy::CubeDynamic,
];

/// Normals to test the per-normal balancing with (zero = unknown).
fn normals() -> Vec<Vec3> {
    vec![
        Vec3::ZERO,
        Vec3::Y,
        Vec3::new(0.3, -0.8, 0.52).normalize(),
        Vec3::new(-0.9, 0.1, -0.42).normalize(),
    ]
}

fn cases(strategy: EnvStrategy) -> Vec<Vec3> {
    if strategy == EnvStrategy::CubeDynamic {
        normals()
    } else {
        vec![Vec3::ZERO]
    }
}

fn maps() -> Vec<(&'static str, EnvironmentMap)> {
    vec![
        ("synthetic", synthetic(64, 32, 1e5)),
        ("sky", load("sky.exr")),
        ("studio", load("studio.exr")),
    ]
}

/// Solid angle of the sub-cell (a, b) of a k x k split of texel `i` (column a, row b).
fn sub_solid_angle(grid: Grid, i: usize, a: usize, b: usize, k: usize) -> f64 {
    use std::f64::consts::PI as PI64;
    match grid {
        Grid::LatLong { width, height } => {
            let row = (i / width) as f64 + b as f64 / k as f64;
            let (t0, t1) = (
                PI64 * row / height as f64,
                PI64 * (row + 1.0 / k as f64) / height as f64,
            );
            2.0 * PI64 / (width * k) as f64 * (t0.cos() - t1.cos())
        }
        Grid::Cube { face } => {
            let (row, col) = ((i / face) % face, i % face);
            let e = |x: f64| 2.0 * x / face as f64 - 1.0;
            let (s0, s1) = (
                e(col as f64 + a as f64 / k as f64),
                e(col as f64 + (a + 1) as f64 / k as f64),
            );
            let (t0, t1) = (
                e(row as f64 + b as f64 / k as f64),
                e(row as f64 + (b + 1) as f64 / k as f64),
            );
            let area = |s: f64, t: f64| (s * t).atan2((1.0 + s * s + t * t).sqrt());
            area(s1, t1) - area(s0, t1) - area(s1, t0) + area(s0, t0)
        }
    }
}

/// The strategy's density grid.
fn density_grid(map: &EnvironmentMap, strategy: EnvStrategy) -> Grid {
    match strategy {
        EnvStrategy::LatLong => map.latlong().grid(),
        _ => Grid::Cube {
            face: map.cube().face_size(),
        },
    }
}

/// The pdf integrates to 1: midpoint quadrature with 4 x 4 cells per texel of the density's
/// grid, `pdf()` times each cell's exact solid angle. (Cells of a grid over the whole sphere
/// that straddle texel edges would miss a sun holding half the density in four texels by
/// several percent; these cells share the texels' edges, so the quadrature only has to follow
/// the smooth Jacobian inside each texel.) A fine (cos theta, phi) grid checks the same on a
/// map without a sun, independently of the texel layout.
#[test]
fn pdfs_integrate_to_one() {
    const K: usize = 4;
    for (name, map) in maps() {
        for strategy in STRATEGIES {
            let grid = density_grid(&map, strategy);
            for n in cases(strategy) {
                let mut sum = 0.0f64;
                for i in 0..grid.texel_count() {
                    for a in 0..K {
                        for b in 0..K {
                            let d = grid.texel_point(
                                i,
                                (a as f32 + 0.5) / K as f32,
                                (b as f32 + 0.5) / K as f32,
                            );
                            sum +=
                                map.pdf(strategy, n, d) as f64 * sub_solid_angle(grid, i, a, b, K);
                        }
                    }
                }
                // With a dynamic balancing, faces wholly behind the normal get no density,
                // so the integral is 1 all the same.
                assert!(
                    (sum - 1.0).abs() < 2e-3,
                    "{name} {strategy:?} n {n}: pdf integrates to {sum}"
                );
            }
        }
    }
    let map = synthetic(64, 32, 0.0);
    let (nz, nphi) = (1024usize, 2048usize);
    for strategy in STRATEGIES {
        for n in cases(strategy) {
            let mut sum = 0.0f64;
            for i in 0..nz {
                let z = -1.0 + 2.0 * (i as f32 + 0.5) / nz as f32;
                let r = (1.0 - z * z).sqrt();
                for j in 0..nphi {
                    let phi = 2.0 * PI * (j as f32 + 0.5) / nphi as f32;
                    sum += map.pdf(strategy, n, Vec3::new(r * phi.cos(), z, r * phi.sin())) as f64;
                }
            }
            let integral = sum * 4.0 * std::f64::consts::PI / (nz * nphi) as f64;
            assert!(
                (integral - 1.0).abs() < 3e-3,
                "no-sun map {strategy:?} n {n}: pdf integrates to {integral}"
            );
        }
    }
}

#[test]
fn samples_carry_their_pdf_and_radiance() {
    for (name, map) in maps() {
        for strategy in STRATEGIES {
            for n in cases(strategy) {
                let mut rng = Rng::new(17, 3);
                let (mut mismatch, total) = (0usize, 100_000usize);
                for _ in 0..total {
                    let s = map
                        .sample(strategy, n, rng.uniform2())
                        .expect("every strategy samples a lit map");
                    assert!((s.wi.length() - 1.0).abs() < 1e-4);
                    assert!(
                        s.pdf > 0.0 && s.pdf.is_finite(),
                        "{name} {strategy:?}: {}",
                        s.pdf
                    );
                    let p = map.pdf(strategy, n, s.wi);
                    if (p - s.pdf).abs() > 1e-3 * s.pdf || map.radiance(s.wi) != s.radiance {
                        mismatch += 1;
                    }
                }
                // Only samples on a texel edge may round to the neighbouring texel.
                assert!(
                    mismatch * 2000 < total,
                    "{name} {strategy:?} n {n}: {mismatch} of {total} samples disagree with pdf()"
                );
            }
        }
    }
}

/// The grid the strategy's density lives on, and the integral of the pdf over a texel from
/// its value at the centre (exact for these piecewise densities: the lat-long pdf is
/// C / sin(theta), the cube pdf C (1 + s^2 + t^2)^(3/2) within a texel).
fn texel_probability(
    map: &EnvironmentMap,
    strategy: EnvStrategy,
    n: Vec3,
    grid: Grid,
    i: usize,
) -> f64 {
    let c = grid.texel_point(i, 0.5, 0.5);
    let pdf = map.pdf(strategy, n, c) as f64;
    match grid {
        Grid::LatLong { width, height } => {
            let sin = (std::f64::consts::PI * ((i / width) as f64 + 0.5) / height as f64).sin();
            pdf * sin
                * (std::f64::consts::PI / height as f64)
                * (2.0 * std::f64::consts::PI / width as f64)
        }
        Grid::Cube { face } => {
            let (row, col) = ((i / face) % face, i % face);
            let s = 2.0 * (col as f64 + 0.5) / face as f64 - 1.0;
            let t = 2.0 * (row as f64 + 0.5) / face as f64 - 1.0;
            pdf / (1.0 + s * s + t * t).powf(1.5) * 4.0 / (face * face) as f64
        }
    }
}

#[test]
fn sampled_directions_pass_chi_square() {
    for (name, map) in maps() {
        for strategy in STRATEGIES {
            let grid = density_grid(&map, strategy);
            for n in cases(strategy) {
                // Blocks of 4 x 4 texels.
                let block_of = |i: usize| match grid {
                    Grid::LatLong { width, .. } => {
                        ((i / width) / 4) * (width / 4) + (i % width) / 4
                    }
                    Grid::Cube { face } => {
                        let f = i / (face * face);
                        let (row, col) = ((i / face) % face, i % face);
                        (f * face.div_ceil(4) + row / 4) * face.div_ceil(4) + col / 4
                    }
                };
                let blocks = block_of(grid.texel_count() - 1) + 1;
                let samples = 400_000u64;
                let mut expected = vec![0.0f64; blocks];
                for i in 0..grid.texel_count() {
                    expected[block_of(i)] +=
                        samples as f64 * texel_probability(&map, strategy, n, grid, i);
                }
                let total: f64 = expected.iter().sum::<f64>() / samples as f64;
                assert!((total - 1.0).abs() < 1e-3, "{name} {strategy:?}: {total}");
                let mut observed = vec![0u64; blocks];
                let mut rng = Rng::new(29, 5);
                for _ in 0..samples {
                    let s = map.sample(strategy, n, rng.uniform2()).unwrap();
                    observed[block_of(grid.texel_of(map.to_local(s.wi)))] += 1;
                }
                assert_chi2(&format!("{name} {strategy:?} n {n}"), &observed, &expected);
            }
        }
    }
}

#[test]
fn dynamic_balancing_avoids_the_sun_behind_the_surface() {
    // The sun of the synthetic map is high in the sky; a receiver facing down must not spend
    // samples on it, one facing up must.
    let map = synthetic(64, 32, 1e5);
    let sun_dir = Grid::LatLong {
        width: 64,
        height: 32,
    }
    .texel_point(32 / 5 * 64 + 64 / 3, 1.0, 1.0);
    let mut rng = Rng::new(3, 3);
    let near_sun = |n: Vec3, rng: &mut Rng| {
        (0..10_000)
            .filter(|_| {
                map.sample(EnvStrategy::CubeDynamic, n, rng.uniform2())
                    .is_some_and(|s| s.wi.dot(sun_dir) > 0.99)
            })
            .count()
    };
    // Facing down, the +Y face holding the sun is wholly behind: none of its corners is in
    // front (eq. 3.4 is conservative per face: a receiver that sees one corner of the sun's
    // face still samples the sun).
    let down = near_sun(Vec3::NEG_Y, &mut rng);
    let up = near_sun(sun_dir, &mut rng);
    assert_eq!(
        down, 0,
        "samples on the sun for a receiver facing away from it"
    );
    assert!(
        up > 5_000,
        "only {up} of 10000 samples on the sun facing it"
    );
}

// ------------------------------------------------------------------------------------------
// Rendering.

/// A UV sphere of radius `r` at `c` with smooth normals.
fn sphere(b: &mut SceneBuilder, c: Vec3, r: f32, material: u32) {
    let (nu, nv) = (64u32, 32u32);
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    for j in 0..=nv {
        let theta = PI * j as f32 / nv as f32;
        for i in 0..=nu {
            let phi = 2.0 * PI * i as f32 / nu as f32;
            let n = Vec3::new(
                theta.sin() * phi.cos(),
                theta.cos(),
                theta.sin() * phi.sin(),
            );
            positions.push(c + n * r);
            normals.push(n);
        }
    }
    let mut indices = Vec::new();
    for j in 0..nv {
        for i in 0..nu {
            let a = j * (nu + 1) + i;
            let (b0, c0, d0) = (a + 1, a + nu + 1, a + nu + 2);
            if j > 0 {
                indices.push([a, b0, c0]);
            }
            if j + 1 < nv {
                indices.push([b0, d0, c0]);
            }
        }
    }
    b.add_mesh(MeshDesc {
        name: "sphere".into(),
        positions,
        normals,
        indices,
        materials: vec![material],
        ..Default::default()
    })
    .unwrap();
}

fn sphere_scene(map: EnvironmentMap, material: Material, ground: bool) -> (Scene, Camera) {
    let mut b = SceneBuilder::new();
    let m = b.add_material(material).unwrap();
    sphere(&mut b, Vec3::ZERO, 1.0, m);
    if ground {
        let g = b.add_material(Material::diffuse(Rgb::splat(0.4))).unwrap();
        b.add_mesh(MeshDesc {
            name: "ground".into(),
            positions: vec![
                Vec3::new(-3.0, -1.0, -3.0),
                Vec3::new(3.0, -1.0, -3.0),
                Vec3::new(3.0, -1.0, 3.0),
                Vec3::new(-3.0, -1.0, 3.0),
            ],
            indices: vec![[0, 2, 1], [0, 3, 2]],
            materials: vec![g],
            ..Default::default()
        })
        .unwrap();
    }
    b.set_environment(Some(Arc::new(map)));
    let scene = b.build().unwrap();
    let camera = Camera::look_at(
        Vec3::new(0.0, 0.8, 4.0),
        Vec3::new(0.0, -0.2, 0.0),
        Vec3::Y,
        40.0,
    )
    .unwrap();
    (scene, camera)
}

/// Per seed: means of the image, its four quadrants; then mean and standard error over seeds.
fn region_means(
    scene: &Scene,
    camera: &Camera,
    spec: &str,
    settings: IntegratorSettings,
    size: u32,
    spp: u32,
    seeds: u64,
) -> Vec<(f64, f64)> {
    let integrator = integrator::create(spec, settings).unwrap();
    let mut stats = [Stats::default(); 5];
    for seed in 0..seeds {
        let rs = RenderSettings {
            width: size,
            height: size,
            spp,
            seed: seed * 7919 + 11,
            // Independent numbers: an honest seed spread for heavy tails (the sun seen by
            // BSDF sampling), as in tests/common/agreement.rs.
            sampler: SamplerKind::Independent,
            ..Default::default()
        };
        let film = render_image(scene, camera, integrator.as_ref(), &rs);
        let px = film.radiance();
        let mut sums = [0.0f64; 5];
        let h = size / 2;
        for y in 0..size {
            for x in 0..size {
                let p = px[(y * size + x) as usize];
                assert!(p.is_finite() && p.min_element() >= 0.0, "{spec}: pixel {p}");
                let v = luminance(p) as f64;
                sums[0] += v;
                sums[1 + (y / h * 2 + x / h) as usize] += v;
            }
        }
        let n = (size * size) as f64;
        stats[0].add(sums[0] / n);
        for k in 1..5 {
            stats[k].add(sums[k] * 4.0 / n);
        }
    }
    stats.iter().map(|s| (s.mean(), s.std_err())).collect()
}

fn assert_agree(label: &str, a: &[(f64, f64)], b: &[(f64, f64)]) {
    for (k, ((ma, ea), (mb, eb))) in a.iter().zip(b).enumerate() {
        let sigma = (ea * ea + eb * eb).sqrt();
        assert!(
            (ma - mb).abs() <= 4.5 * sigma + 1e-6 * ma.abs().max(mb.abs()),
            "{label} region {k}: {ma} +- {ea} vs {mb} +- {eb}"
        );
    }
}

/// A uniform environment L around a convex diffuse object of albedo a: the object reflects
/// a L towards every direction (it sees only the sky, which fills its whole hemisphere), at
/// every bounce depth >= 1.
#[test]
fn uniform_environment_around_a_diffuse_sphere_matches_the_closed_form() {
    let (albedo, level) = (0.6f32, 2.0f32);
    let (scene, camera) = sphere_scene(
        constant(level),
        Material::diffuse(Rgb::splat(albedo)),
        false,
    );
    let specs = [
        "path:env=latlong",
        "path:env=cube-uniform",
        "path:env=cube-dynamic",
        "path:env=bsdf",
        "bdpt:env=cube-dynamic",
        "bdpt:env=latlong",
        "env_direct:env=cube-dynamic:samples=4:bsdf=4",
        "env_direct:env=cube-uniform:samples=8:bsdf=0",
    ];
    let expected = (albedo * level) as f64;
    for spec in specs {
        let integrator = integrator::create(
            spec,
            IntegratorSettings {
                max_depth: 3,
                ..Default::default()
            },
        )
        .unwrap();
        let mut stats = Stats::default();
        let mut background = Stats::default();
        for seed in 0..4 {
            let rs = RenderSettings {
                width: 24,
                height: 24,
                spp: 16,
                seed: seed + 1,
                ..Default::default()
            };
            let film = render_image(&scene, &camera, integrator.as_ref(), &rs);
            // Pixels wholly on the sphere (away from its silhouette) and wholly on the sky.
            for y in 0..24u32 {
                for x in 0..24u32 {
                    // The sphere's centre is 1.6 pixels above the image centre.
                    let (dx, dy) = (x as f32 - 11.5, y as f32 - 9.9);
                    let r = (dx * dx + dy * dy).sqrt();
                    let v = film.pixel(x, y).x as f64;
                    if r < 6.0 {
                        stats.add(v);
                    } else if r > 12.0 {
                        background.add(v);
                    }
                }
            }
        }
        assert!(stats.n > 100 && background.n > 50);
        common::chi2::assert_z(spec, stats.mean(), expected, stats.std_err().max(1e-7));
        assert!(
            (background.mean() - level as f64).abs() < 1e-5,
            "{spec}: sky {}",
            background.mean()
        );
    }
}

#[test]
fn strategies_agree_with_each_other_bsdf_sampling_and_bdpt() {
    for (name, map) in [("sky", load("sky.exr")), ("studio", load("studio.exr"))] {
        let glossy = Material::glossy(Rgb::splat(0.2), Rgb::splat(0.5), 40.0);
        let (scene, camera) = sphere_scene(map, glossy, true);
        let settings = IntegratorSettings {
            max_depth: 3,
            ..Default::default()
        };
        let reference = region_means(
            &scene,
            &camera,
            "path:env=cube-dynamic",
            settings,
            16,
            64,
            8,
        );
        assert!(reference[0].0 > 0.0);
        for spec in [
            "path:env=latlong",
            "path:env=cube-uniform",
            "path:env=cube-power",
            "path:env=bsdf",
            "bdpt:env=cube-dynamic",
            "bdpt:env=latlong",
        ] {
            let spp = if spec.ends_with("bsdf") { 256 } else { 64 };
            let other = region_means(&scene, &camera, spec, settings, 16, spp, 8);
            assert_agree(
                &format!("{name}: path:env=cube-dynamic vs {spec}"),
                &reference,
                &other,
            );
        }
        // Direct lighting only: env_direct's many-sample estimator against path.
        let direct = IntegratorSettings {
            max_depth: 1,
            ..Default::default()
        };
        let path = region_means(&scene, &camera, "path", direct, 16, 64, 8);
        for spec in [
            "env_direct:env=cube-dynamic:samples=6:bsdf=6",
            "env_direct:env=cube-uniform:samples=12:bsdf=0",
            "env_direct:env=latlong:samples=6:bsdf=2",
        ] {
            let other = region_means(&scene, &camera, spec, direct, 16, 8, 8);
            assert_agree(&format!("{name}: path (depth 1) vs {spec}"), &path, &other);
        }
    }
}

/// env_direct's weightings estimate the same image: `power`, `auto` (the thesis 001 ch. 5
/// sample split with its eq. 5.6 combination) and `optimal` against `balance`, by z-tests on
/// the image and quadrant means, on a glossy sphere (a narrow lobe, where BSDF samples win)
/// over a diffuse floor (where light samples win) under a sky with a sun and a studio map, and
/// a perfect mirror sphere (no MIS at the mirror: the camera path passes it to the floor).
/// `auto` writes its alpha layer, inside the clamp wherever a point was shaded.
#[test]
fn mis_weightings_of_env_direct_agree_with_balance() {
    let glossy = Material::glossy(Rgb::splat(0.2), Rgb::splat(0.5), 200.0);
    let mirror = Material::mirror(Rgb::splat(0.9));
    for (name, map, material) in [
        ("sky", load("sky.exr"), glossy.clone()),
        ("studio", load("studio.exr"), glossy),
        ("sky, mirror sphere", load("sky.exr"), mirror.clone()),
    ] {
        let (scene, camera) = sphere_scene(map, material.clone(), true);
        let with = |mis| IntegratorSettings {
            max_depth: 1,
            mis: Some(mis),
            ..Default::default()
        };
        let spec = "env_direct:env=cube-dynamic:samples=8:bsdf=8";
        let balance = region_means(&scene, &camera, spec, with(MisHeuristic::Balance), 16, 8, 8);
        assert!(balance[0].0 > 0.0);
        // `alpha_steps=1` is the thesis's eq. 5.4 alone; 4 re-expands around each alpha;
        // `warmup=4` spends 4 of the 16 samples on the warm-up instead of 8.
        let single_step = format!("{spec}:alpha_steps=1");
        let newton = format!("{spec}:alpha_steps=4");
        let short_warmup = format!("{spec}:warmup=4");
        for (mis, spec) in [
            (MisHeuristic::Power, spec),
            (MisHeuristic::Auto, spec),
            (MisHeuristic::Auto, single_step.as_str()),
            (MisHeuristic::Auto, newton.as_str()),
            (MisHeuristic::Auto, short_warmup.as_str()),
            (MisHeuristic::Optimal, spec),
        ] {
            let other = region_means(&scene, &camera, spec, with(mis), 16, 8, 8);
            assert_agree(
                &format!("{name}: {spec} balance vs {mis:?}"),
                &balance,
                &other,
            );
        }
        if material == mirror {
            // Through the mirror env_direct shades the floor only: the image test suffices.
            continue;
        }
        let auto = integrator::create(spec, with(MisHeuristic::Auto)).unwrap();
        let rs = RenderSettings {
            width: 16,
            height: 16,
            spp: 4,
            ..Default::default()
        };
        let film = render_image(&scene, &camera, auto.as_ref(), &rs);
        let index = film
            .layer_names()
            .iter()
            .position(|n| n == integrator::ALPHA_LAYER)
            .expect("mis=auto writes the alpha layer");
        let (mut shaded, mut spread) = (0, (1.0f32, 0.0f32));
        for p in film.layer(index) {
            assert!(
                p.is_finite() && (0.0..=1.0).contains(&p.y),
                "{name}: alpha {p}"
            );
            if p.y > 0.99 {
                let alpha = p.x / p.y;
                assert!((0.024..=0.976).contains(&alpha), "{name}: alpha {alpha}");
                spread = (spread.0.min(alpha), spread.1.max(alpha));
                shaded += 1;
            }
        }
        // The sphere and the floor want different splits.
        assert!(
            shaded > 100 && spread.1 - spread.0 > 0.2,
            "{name}: {shaded} {spread:?}"
        );
    }
}

/// `path:mis=auto` (one light and one BSDF sample per vertex, `integrator::mis_auto`) against
/// `mis=balance` at the image and quadrant means, under the sky with a sun and the studio map:
/// a glossy sphere over a diffuse floor, and a perfect mirror sphere (no MIS at the mirror
/// itself). With light sampling off (`env=bsdf`: light samples have density zero) alpha goes
/// to the upper clamp, and the image is `mis=balance`'s bit for bit: the light samples it
/// skips find nothing, and the BSDF directions weigh 1 either way.
#[test]
fn path_auto_agrees_with_balance_under_environment_maps() {
    let glossy = Material::glossy(Rgb::splat(0.2), Rgb::splat(0.5), 200.0);
    let mirror = Material::mirror(Rgb::splat(0.9));
    let with = |mis| IntegratorSettings {
        max_depth: 3,
        mis: Some(mis),
        ..Default::default()
    };
    for (name, map, material) in [
        ("sky", load("sky.exr"), glossy.clone()),
        ("studio", load("studio.exr"), glossy),
        ("sky, mirror sphere", load("sky.exr"), mirror),
    ] {
        let (scene, camera) = sphere_scene(map, material, true);
        let balance = region_means(
            &scene,
            &camera,
            "path",
            with(MisHeuristic::Balance),
            16,
            16,
            8,
        );
        let auto = region_means(
            &scene,
            &camera,
            "path:mis_warmup=2",
            with(MisHeuristic::Auto),
            16,
            16,
            8,
        );
        assert_agree(&format!("{name}: path balance vs auto"), &balance, &auto);
    }
    let (scene, camera) = sphere_scene(load("sky.exr"), Material::diffuse(Rgb::splat(0.5)), true);
    let rs = RenderSettings {
        width: 12,
        height: 12,
        spp: 9,
        seed: 3,
        ..Default::default()
    };
    let film = |spec: &str, mis| {
        let integrator = integrator::create(spec, with(mis)).unwrap();
        render_image(&scene, &camera, integrator.as_ref(), &rs)
    };
    let balance = film("path:env=bsdf", MisHeuristic::Balance);
    let auto = film("path:env=bsdf:mis_warmup=4", MisHeuristic::Auto);
    assert_eq!(balance.radiance(), auto.radiance());
    let index = auto
        .layer_names()
        .iter()
        .position(|n| n == integrator::ALPHA_LAYER)
        .unwrap();
    // Four warm-up samples at 1/2, then five at the clamp (at 1/2 where no warm-up direction
    // of the pixel reached the sky).
    let clamped = (4.0 * 0.5 + 5.0 * integrator::mis_auto::ALPHA_MAX) / 9.0;
    let shaded: Vec<f32> = auto
        .layer(index)
        .iter()
        .filter(|p| p.y > 0.999)
        .map(|p| p.x / p.y)
        .collect();
    let at_clamp = shaded
        .iter()
        .filter(|&&a| (a - clamped).abs() < 1e-4)
        .count();
    assert!(
        shaded
            .iter()
            .all(|&a| (a - clamped).abs() < 1e-4 || a == 0.5),
        "{shaded:?}"
    );
    assert!(
        at_clamp * 4 > shaded.len() * 3,
        "{at_clamp} of {}",
        shaded.len()
    );
}

/// Unset, `mis` is each integrator's own default: env_direct's is the balance heuristic over
/// the counts (bit-identical images), `path`'s the power heuristic.
#[test]
fn unset_mis_is_each_integrators_default() {
    let glossy = Material::glossy(Rgb::splat(0.2), Rgb::splat(0.5), 200.0);
    let (scene, camera) = sphere_scene(load("sky.exr"), glossy, true);
    let rs = RenderSettings {
        width: 16,
        height: 16,
        spp: 2,
        ..Default::default()
    };
    let image = |spec: &str, mis: Option<MisHeuristic>| {
        let settings = IntegratorSettings {
            max_depth: 2,
            mis,
            ..Default::default()
        };
        let integrator = integrator::create(spec, settings).unwrap();
        render_image(&scene, &camera, integrator.as_ref(), &rs).radiance()
    };
    for (spec, default, other) in [
        (
            "env_direct:samples=4:bsdf=4",
            MisHeuristic::Balance,
            MisHeuristic::Power,
        ),
        ("path", MisHeuristic::Power, MisHeuristic::Balance),
    ] {
        let unset = image(spec, None);
        assert_eq!(unset, image(spec, Some(default)), "{spec}: {default:?}");
        assert_ne!(unset, image(spec, Some(other)), "{spec}: {other:?}");
    }
}

/// A sun 1e6 above the sky, a few texels wide, over a diffuse plane: with light sampling and
/// MIS the largest single-sample estimate stays within a small factor of the mean (BSDF
/// sampling alone would hit the sun rarely with enormous values).
#[test]
fn a_bright_sun_gives_no_fireflies_with_mis() {
    let map = synthetic(256, 128, 1e6);
    let (scene, camera) = sphere_scene(map, Material::diffuse(Rgb::splat(0.5)), true);
    for (spec, max_ratio) in [
        ("path:env=cube-dynamic", 30.0),
        ("path:env=latlong", 30.0),
        ("bdpt:env=cube-dynamic", 30.0),
        ("env_direct:samples=4:bsdf=4", 30.0),
    ] {
        let integrator = integrator::create(
            spec,
            IntegratorSettings {
                max_depth: 1,
                ..Default::default()
            },
        )
        .unwrap();
        let rs = RenderSettings {
            width: 16,
            height: 16,
            spp: 64,
            seed: 5,
            ..Default::default()
        };
        let film = render_image(&scene, &camera, integrator.as_ref(), &rs);
        // Pixels on the lit part of the ground (all of them see the sun): per-pixel means
        // over 64 samples stay close to each other.
        let px = film.radiance();
        let ground: Vec<f64> = (12..16)
            .flat_map(|y| (0..16).map(move |x| (x, y)))
            .map(|(x, y)| luminance(px[y * 16 + x]) as f64)
            .collect();
        let mean = ground.iter().sum::<f64>() / ground.len() as f64;
        let max = ground.iter().cloned().fold(0.0, f64::max);
        assert!(mean > 0.0 && max.is_finite());
        assert!(
            max < max_ratio * mean,
            "{spec}: max pixel {max} vs mean {mean}"
        );
    }
}

#[test]
fn hdr_and_exr_of_the_same_map_agree() {
    let exr = load("sky.exr");
    let hdr = load("sky.hdr");
    assert_eq!(exr.image().grid(), hdr.image().grid());
    let (a, b) = (exr.luminance_integral(), hdr.luminance_integral());
    assert!((a - b).abs() < 0.02 * a, "{a} vs {b}");
    let mut rng = Rng::new(1, 1);
    for _ in 0..1000 {
        let w = warp::uniform_sphere(rng.uniform2());
        let (x, y) = (exr.radiance(w), hdr.radiance(w));
        // RGBE keeps 8 bits of mantissa for the largest component.
        assert!(
            (x - y).abs().max_element() <= 0.02 * x.max_element() + 1e-3,
            "{x} vs {y}"
        );
    }
}

#[test]
fn bad_maps_give_clear_errors() {
    let dir = std::env::temp_dir().join(format!("lacuna-env-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let garbage = dir.join("garbage.exr");
    std::fs::write(&garbage, b"not an exr file").unwrap();
    let e = EnvironmentMap::load(&garbage, EnvSettings::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("garbage.exr"), "{e}");
    let hdr = dir.join("garbage.hdr");
    std::fs::write(
        &hdr,
        b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 4\n\x01",
    )
    .unwrap();
    let e = EnvironmentMap::load(&hdr, EnvSettings::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("garbage.hdr"), "{e}");
    let e = EnvironmentMap::load(&dir.join("missing.exr"), EnvSettings::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing.exr"), "{e}");
    let e = EnvironmentMap::load(&dir.join("map.png"), EnvSettings::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains(".exr or .hdr"), "{e}");
    // A 3:1 image is neither layout.
    let e = EnvImage::from_pixels(6, 2, vec![Rgb::ONE; 12])
        .unwrap_err()
        .to_string();
    assert!(e.contains("2:1") && e.contains("4:3"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
    // Bad settings.
    let img = EnvImage::from_pixels(4, 2, vec![Rgb::ONE; 8]).unwrap();
    for s in [
        EnvSettings {
            scale: -1.0,
            ..Default::default()
        },
        EnvSettings {
            scale: f32::NAN,
            ..Default::default()
        },
        EnvSettings {
            rotate_degrees: f32::INFINITY,
            ..Default::default()
        },
    ] {
        assert!(EnvironmentMap::new(img.clone(), s).is_err());
    }
}

#[test]
fn zero_rows_and_black_maps_keep_sampling_valid() {
    // Zero rows: never sampled, pdf zero there, still normalised (checked above for the
    // synthetic map); a black map: no light samples, no power, escapes give black.
    // The lat-long density lives on the map's own texels: never a black one. The cube
    // densities over a lat-long map weight their texels from 3 x 3 points, so a cube texel
    // straddling the edge of the black band may send a sample into it (a few percent of
    // them on this coarse 64 x 32 map, whose cube faces are 16 texels wide).
    let map = synthetic(64, 32, 10.0);
    let mut rng = Rng::new(8, 8);
    for strategy in STRATEGIES {
        let black = (0..20_000)
            .filter(|_| {
                let s = map.sample(strategy, Vec3::ZERO, rng.uniform2()).unwrap();
                map.radiance(s.wi) == Rgb::ZERO
            })
            .count();
        let allowed = if strategy == EnvStrategy::LatLong {
            0
        } else {
            1000
        };
        assert!(
            black <= allowed,
            "{strategy:?}: {black} of 20000 samples on black texels"
        );
    }
    let black = constant(0.0);
    assert_eq!(black.luminance_integral(), 0.0);
    // Uniform balancing still spreads samples over the (black) faces; they carry nothing.
    for strategy in STRATEGIES {
        match black.sample(strategy, Vec3::Y, rng.uniform2()) {
            None => assert_eq!(black.pdf(strategy, Vec3::Y, Vec3::Y), 0.0),
            Some(s) => {
                assert_eq!(strategy, EnvStrategy::CubeUniform);
                assert_eq!(s.radiance, Rgb::ZERO);
            }
        }
    }
    let (scene, camera) = sphere_scene(black, Material::diffuse(Rgb::ONE), false);
    assert!(scene.light_sampler().is_none());
    let integrator = integrator::create("path", IntegratorSettings::default()).unwrap();
    let rs = RenderSettings {
        width: 8,
        height: 8,
        spp: 4,
        ..Default::default()
    };
    let film = render_image(&scene, &camera, integrator.as_ref(), &rs);
    assert!(film.radiance().iter().all(|p| *p == Rgb::ZERO));
}

#[test]
fn hidden_maps_light_the_scene_but_are_not_seen() {
    let mut map = constant(1.0);
    map.set_settings(EnvSettings {
        visible: false,
        ..Default::default()
    })
    .unwrap();
    let (scene, camera) = sphere_scene(map, Material::diffuse(Rgb::splat(0.5)), false);
    for spec in ["path", "bdpt", "env_direct"] {
        let integrator = integrator::create(spec, IntegratorSettings::default()).unwrap();
        let rs = RenderSettings {
            width: 12,
            height: 12,
            spp: 4,
            ..Default::default()
        };
        let film = render_image(&scene, &camera, integrator.as_ref(), &rs);
        assert_eq!(
            film.pixel(0, 0),
            Rgb::ZERO,
            "{spec}: the hidden sky is seen"
        );
        assert!(film.pixel(6, 6).x > 0.3, "{spec}: the sphere is not lit");
    }
}

#[test]
fn rotation_and_up_axis_move_the_map() {
    let grid = Grid::LatLong {
        width: 64,
        height: 32,
    };
    // One bright texel straight ahead (-Z) on the horizon.
    let mut texels = vec![Rgb::ZERO; grid.texel_count()];
    let ahead = grid.texel_of(Vec3::NEG_Z);
    texels[ahead] = Rgb::ONE;
    let img = EnvImage::new(grid, texels).unwrap();
    let with = |rotate: f32, up: &str| {
        EnvironmentMap::new(
            img.clone(),
            EnvSettings {
                rotate_degrees: rotate,
                up: lacuna::light::UpAxis::parse(up).unwrap(),
                ..Default::default()
            },
        )
        .unwrap()
    };
    let probe = |m: &EnvironmentMap, w: Vec3| m.radiance(w.normalize()).x;
    assert_eq!(probe(&with(0.0, "y"), Vec3::NEG_Z), 1.0);
    // Turned 90 degrees counter-clockwise seen from +Y: -Z goes to -X.
    assert_eq!(probe(&with(90.0, "y"), Vec3::NEG_X), 1.0);
    assert_eq!(probe(&with(90.0, "y"), Vec3::NEG_Z), 0.0);
    // Z up: the map's zenith is +Z and straight ahead is +Y.
    assert_eq!(probe(&with(0.0, "z"), Vec3::Y), 1.0);
    let zen = grid.texel_of(Vec3::Y);
    let mut t = vec![Rgb::ZERO; grid.texel_count()];
    t[zen] = Rgb::ONE;
    let m = EnvironmentMap::new(
        EnvImage::new(grid, t).unwrap(),
        EnvSettings {
            up: lacuna::light::UpAxis::Z,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(probe(&m, Vec3::Z), 1.0);
}

#[test]
fn updates_rebuild_in_place_and_match_a_fresh_map() {
    let mut map = load("sky.exr");
    map.prepare(EnvStrategy::CubeDynamic);
    map.prepare(EnvStrategy::LatLong);
    let studio = load("studio.exr");
    let seconds = map.update(studio.image().texels()).unwrap();
    assert!(seconds >= 0.0);
    let mut rng = Rng::new(4, 4);
    for _ in 0..2000 {
        let w = warp::uniform_sphere(rng.uniform2());
        for s in STRATEGIES {
            assert_eq!(map.pdf(s, Vec3::Y, w), studio.pdf(s, Vec3::Y, w));
        }
        assert_eq!(map.radiance(w), studio.radiance(w));
    }
    assert_eq!(map.luminance_integral(), studio.luminance_integral());
    // A different size is refused.
    assert!(map.update(&[Rgb::ONE; 8]).is_err());
}

/// Radiance over density stays bounded everywhere, the sun's edges included: for a density
/// proportional to radiance the ratio luminance / (pdf x integral) is 1; the lat-long density
/// departs from it by its sin(theta) at the texel centre, the cube densities by the solid
/// angle at the texel centre and, over a lat-long map, by the floor of a quarter of the
/// brightest overlapping texel. (A mean of gather points alone let cube texels with a sliver
/// of sun sample it with the sky's density: ratios of 1e4.)
#[test]
fn radiance_over_density_is_bounded_next_to_a_sun() {
    for (name, map) in [
        ("synthetic", synthetic(256, 128, 1e6)),
        ("sky", load("sky.exr")),
    ] {
        let total = map.luminance_integral() as f64;
        for strategy in [EnvStrategy::LatLong, EnvStrategy::CubePower] {
            let mut rng = Rng::new(12, 1);
            let mut worst = 0.0f64;
            for _ in 0..1_000_000 {
                let w = warp::uniform_sphere(rng.uniform2());
                let l = luminance(map.radiance(w)) as f64;
                if l > 0.0 {
                    let p = map.pdf(strategy, Vec3::ZERO, w) as f64;
                    worst = worst.max(l / (p * total));
                }
            }
            assert!(
                worst < 8.0,
                "{name} {strategy:?}: luminance / (pdf x integral) reaches {worst}"
            );
        }
    }
}

#[test]
fn scene_files_and_the_command_line_take_environment_maps() {
    let dir = std::env::temp_dir().join(format!("lacuna-env-scene-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let sky = repo("scenes/envmaps/sky.exr");
    let write = |name: &str, env: &str| {
        let p = dir.join(name);
        std::fs::write(
            &p,
            format!(
                r#"{{ "shapes": [{{ "type": "sphere", "center": [0, 0, 0], "radius": 1 }}],
                     "environment": {env},
                     "camera": {{ "eye": [0, 0, 4], "target": [0, 0, 0], "fov": 40 }} }}"#
            ),
        )
        .unwrap();
        p
    };
    let ok = write(
        "ok.json",
        &format!(
            r#"{{ "file": {:?}, "scale": 2, "rotate": 30, "up": "z", "visible": false, "layout": "cube" }}"#,
            sky.to_str().unwrap()
        ),
    );
    let loaded = lacuna::scene::load_scene_file(&ok).unwrap();
    let env = loaded.builder.environment().expect("environment");
    assert_eq!(env.image().grid(), Grid::Cube { face: 128 });
    let s = env.settings();
    assert!(s.scale == 2.0 && s.rotate_degrees == 30.0 && !s.visible);
    assert_eq!(s.up, lacuna::light::UpAxis::Z);
    for (name, env, needle) in [
        (
            "up.json",
            format!(r#"{{ "file": {:?}, "up": "x" }}"#, sky.to_str().unwrap()),
            "up axis",
        ),
        (
            "scale.json",
            format!(r#"{{ "file": {:?}, "scale": -1 }}"#, sky.to_str().unwrap()),
            "scale",
        ),
        (
            "layout.json",
            format!(
                r#"{{ "file": {:?}, "layout": "octahedral" }}"#,
                sky.to_str().unwrap()
            ),
            "layout",
        ),
        (
            "missing.json",
            r#"{ "file": "nowhere.exr" }"#.to_string(),
            "nowhere.exr",
        ),
        (
            "field.json",
            format!(
                r#"{{ "file": {:?}, "rotation": 3 }}"#,
                sky.to_str().unwrap()
            ),
            "rotation",
        ),
    ] {
        let e = lacuna::scene::load_scene_file(&write(name, &env))
            .err()
            .expect(name)
            .to_string();
        assert!(e.contains(needle), "{name}: {e}");
    }
    // The command line: --env with its options renders; a bad map or option is a clear error.
    let exe = env!("CARGO_BIN_EXE_lacuna");
    let out = dir.join("out.exr");
    let run = |args: &[&str]| {
        std::process::Command::new(exe)
            .args(args)
            .output()
            .expect("lacuna runs")
    };
    let r = run(&[
        "render",
        ok.to_str().unwrap(),
        "--env",
        sky.to_str().unwrap(),
        "--env-scale",
        "0.5",
        "--env-rotate",
        "-45",
        "--env-hidden",
        "--env-strategy",
        "latlong",
        "--integrator",
        "env_direct:samples=4:bsdf=2",
        "--spp",
        "2",
        "--width",
        "16",
        "--height",
        "16",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let film = lacuna::film::read_exr_rgb(&out).unwrap();
    assert_eq!(
        film.pixels[0],
        Rgb::ZERO,
        "--env-hidden: the corner sees the sky"
    );
    assert!(film.pixels[8 * 16 + 8].x > 0.0);
    for (args, needle) in [
        (vec!["--env-strategy", "octahedral"], "octahedral"),
        (vec!["--env", "/nonexistent/map.exr"], "map.exr"),
        (vec!["--integrator", "path:env=nope"], "nope"),
        (
            vec!["--integrator", "env_direct:samples=0:bsdf=0"],
            "at least one",
        ),
        (vec!["--integrator", "path:colour=red"], "colour"),
    ] {
        let mut all = vec![
            "render",
            ok.to_str().unwrap(),
            "--spp",
            "1",
            "--width",
            "8",
            "--height",
            "8",
            "--quiet",
            "--out",
            out.to_str().unwrap(),
        ];
        all.extend(args.iter());
        let r = run(&all);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(
            !r.status.success() && err.contains(needle),
            "{args:?}: {err}"
        );
    }
    let r = run(&[
        "render",
        "two-rooms",
        "--env-scale",
        "2",
        "--spp",
        "1",
        "--width",
        "8",
        "--height",
        "8",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        !r.status.success()
            && String::from_utf8_lossy(&r.stderr).contains("need an environment map")
    );
    let _ = std::fs::remove_dir_all(&dir);
}
