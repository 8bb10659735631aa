//! The pixel samplers (`math::Sampler`): Owen-scrambled Sobol values are in [0, 1) and
//! uniform, per dimension slot, over a pixel's samples and over scrambles (pixels); slots are
//! independent of each other; every slot's pairs are (0,m,2)-nets for every aligned block of
//! `2^m` samples; integration is unbiased over scrambles (z-tests whose standard errors come
//! from the spread over independent scrambles) and beats independent numbers; renders do not
//! depend on the thread count or the passes, agree with `independent` renders, and hold no NaN;
//! the setting reaches the command line, the EXR header and `compare`.

mod common;

use common::agreement::{assert_agree, box_scene, region_means_with, render_image};
use common::chi2::{assert_chi2, assert_z, Stats};
use lacuna::compare::Contender;
use lacuna::integrator::{self, IntegratorSettings};
use lacuna::math::{Sampler, SamplerKind, Vec2};
use lacuna::render::RenderSettings;
use lacuna::scene::load_scene_file;

const SOBOL: SamplerKind = SamplerKind::Sobol;

fn cornell() -> (lacuna::scene::Scene, lacuna::scene::Camera) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/cornell-box/cornell-box.json");
    let scene = load_scene_file(&path).unwrap().builder.build().unwrap();
    let camera = *scene.camera().unwrap();
    (scene, camera)
}

fn value(seed: u64, pixel: u64, index: u32, slot: u32) -> f32 {
    let mut s = Sampler::new(SOBOL, seed, pixel, index);
    s.set_dimension(slot);
    s.uniform()
}

fn pair(seed: u64, pixel: u64, index: u32, slot: u32) -> Vec2 {
    let mut s = Sampler::new(SOBOL, seed, pixel, index);
    s.set_dimension(slot);
    s.uniform2()
}

fn bin(u: f32, n: usize) -> usize {
    assert!((0.0..1.0).contains(&u), "value {u} outside [0, 1)");
    ((u * n as f32) as usize).min(n - 1)
}

/// Chi-square of 1-D values against uniform over `n` bins.
fn chi2_1d(name: &str, values: impl Iterator<Item = f32>, n: usize) {
    let mut counts = vec![0u64; n];
    let mut total = 0;
    for u in values {
        counts[bin(u, n)] += 1;
        total += 1;
    }
    assert_chi2(name, &counts, &vec![total as f64 / n as f64; n]);
}

/// Chi-square of 2-D values against uniform over `n x n` cells.
fn chi2_2d(name: &str, values: impl Iterator<Item = Vec2>, n: usize) {
    let mut counts = vec![0u64; n * n];
    let mut total = 0;
    for p in values {
        counts[bin(p.y, n) * n + bin(p.x, n)] += 1;
        total += 1;
    }
    assert_chi2(name, &counts, &vec![total as f64 / (n * n) as f64; n * n]);
}

/// 1-D and 2-D uniformity of every slot over the samples of one pixel (a count that is not a
/// power of two), for two pixels and two seeds: 2 x 2 x 6 x 2 = 48 chi-square tests.
#[test]
fn values_are_uniform_over_a_pixels_samples() {
    for seed in [0, 91] {
        for pixel in [0, 123_457] {
            for slot in 0..6 {
                let name = format!("seed {seed} pixel {pixel} slot {slot}");
                chi2_1d(
                    &format!("{name} 1-D"),
                    (0..3000).map(|i| value(seed, pixel, i, slot)),
                    30,
                );
                chi2_2d(
                    &format!("{name} 2-D"),
                    (0..3000).map(|i| pair(seed, pixel, i, slot)),
                    8,
                );
            }
        }
    }
}

/// Uniformity over scrambles: one sample index across 20000 pixels, which is what makes each
/// sample an unbiased estimate. Sample 0 is the critical one (unscrambled Sobol puts it at the
/// origin). 3 indices x 4 slots x 2 = 24 chi-square tests.
#[test]
fn values_are_uniform_over_scrambles() {
    for index in [0, 7, 1000] {
        for slot in [0, 1, 5, 40] {
            let name = format!("index {index} slot {slot}");
            chi2_1d(
                &format!("{name} 1-D"),
                (0..20_000).map(|p| value(3, p, index, slot)),
                40,
            );
            chi2_2d(
                &format!("{name} 2-D"),
                (0..20_000).map(|p| pair(3, p, index, slot)),
                10,
            );
        }
    }
}

/// Different slots of the same samples are independent: the joint histogram of two slots'
/// values is uniform over a pixel's samples and over pixels. 4 slot pairs x 2 = 8 tests.
#[test]
fn slots_are_independent_of_each_other() {
    for (a, b) in [(0, 1), (2, 3), (0, 7), (4, 30)] {
        chi2_2d(
            &format!("slots {a}, {b} over samples"),
            (0..4096).map(|i| Vec2::new(value(5, 17, i, a), value(5, 17, i, b))),
            8,
        );
        chi2_2d(
            &format!("slots {a}, {b} over pixels"),
            (0..20_000).map(|p| Vec2::new(value(5, p, 3, a), value(5, p, 3, b))),
            8,
        );
    }
}

/// `below` is uniform over samples: 1 chi-square test.
#[test]
fn below_is_uniform() {
    let mut counts = [0u64; 7];
    for i in 0..7000 {
        let mut s = Sampler::new(SOBOL, 2, 9, i);
        counts[s.below(7) as usize] += 1;
    }
    assert_chi2("below(7)", &counts, &[1000.0; 7]);
}

/// The (0,2)-sequence property: for every aligned block of `2^m` samples (the first, as after
/// any number of power-of-two passes, and later ones) and every split `m = a + b`, each of the
/// `2^a x 2^b` elementary intervals of area `2^-m` holds exactly one point; and 1-D requests
/// put one value in each interval of length `2^-m`.
#[test]
fn pairs_are_0_2_nets_at_powers_of_two() {
    for seed in [0, 12] {
        for pixel in [0, 5, 262_143] {
            for slot in 0..10 {
                for m in 0..=12u32 {
                    for block in 0..3u32 {
                        let points: Vec<Vec2> = (block << m..(block + 1) << m)
                            .map(|i| pair(seed, pixel, i, slot))
                            .collect();
                        // 1-D: the slot's scalar values are stratified into 2^m intervals.
                        let mut seen = vec![false; 1 << m];
                        for i in block << m..(block + 1) << m {
                            let cell = bin(value(seed, pixel, i, slot), 1 << m);
                            assert!(!seen[cell], "1-D slot {slot}: block {block} of 2^{m}");
                            seen[cell] = true;
                        }
                        for a in 0..=m {
                            let (nx, ny) = (1usize << a, 1usize << (m - a));
                            let mut seen = vec![false; 1 << m];
                            for p in &points {
                                let cell = bin(p.y, ny) * nx + bin(p.x, nx);
                                assert!(
                                    !seen[cell],
                                    "seed {seed} pixel {pixel} slot {slot}: block {block} of \
                                     2^{m} samples has two points in a {nx}x{ny} interval"
                                );
                                seen[cell] = true;
                            }
                        }
                    }
                }
            }
        }
    }
}

/// Per-pixel estimates of `integral f` with `n` samples of one slot, over `pixels` pixels
/// (independent scrambles and shuffles): the estimates' mean and spread.
fn estimates(kind: SamplerKind, n: u32, pixels: u64, f: impl Fn(&mut Sampler) -> f64) -> Stats {
    let mut stats = Stats::default();
    for p in 0..pixels {
        let mut sum = 0.0;
        for i in 0..n {
            let mut s = Sampler::new(kind, 77, p, i);
            s.set_dimension(3);
            sum += f(&mut s);
        }
        stats.add(sum / n as f64);
    }
    stats
}

/// Test integrands with their exact integrals: a smooth 2-D one, a discontinuous 2-D one (a
/// quarter disk) and a 1-D one.
type Integrand = fn(&mut Sampler) -> f64;

fn integrands() -> Vec<(&'static str, f64, Integrand)> {
    vec![
        ("x e^x y", 0.5, |s| {
            let p = s.uniform2();
            (p.x as f64) * (p.x as f64).exp() * p.y as f64
        }),
        (
            "quarter disk r 0.8",
            std::f64::consts::PI * 0.64 / 4.0,
            |s| {
                let p = s.uniform2();
                f64::from(p.x * p.x + p.y * p.y < 0.64)
            },
        ),
        ("u^3", 0.25, |s| (s.uniform() as f64).powi(3)),
    ]
}

/// Unbiasedness: the mean over 4000 scrambles of n-sample estimates matches the integral, for
/// power-of-two and other n (3 integrands x 4 counts = 12 z-tests). The standard error is the
/// spread of the per-pixel estimates over pixels, whose scrambles are independent.
#[test]
fn integration_is_unbiased_over_scrambles() {
    for (name, exact, f) in integrands() {
        for n in [1, 5, 16, 64] {
            let s = estimates(SOBOL, n, 4000, f);
            assert_z(
                &format!("{name}, {n} samples"),
                s.mean(),
                exact,
                s.std_err(),
            );
        }
    }
}

/// Stratification pays: at 64 samples per pixel the variance of the estimates is well below
/// that of independent numbers (smooth: roughly 1/n^2 against 1/n; the disk's edge: 1/n^1.5).
#[test]
fn sobol_has_lower_variance_than_independent() {
    for (name, _, f) in integrands() {
        let sobol = estimates(SOBOL, 64, 2000, f).variance();
        let independent = estimates(SamplerKind::Independent, 64, 2000, f).variance();
        assert!(
            sobol < 0.3 * independent,
            "{name}: variance {sobol:.3e} (sobol) vs {independent:.3e} (independent)"
        );
    }
}

/// The same image for any thread count and any split into passes (time budgets run passes of
/// varying size), for a power-of-two and another sample count.
#[test]
fn sobol_renders_do_not_depend_on_threads_or_passes() {
    let (scene, camera) = cornell();
    let path = integrator::create("path", IntegratorSettings::default()).unwrap();
    for spp in [8, 7] {
        let rs = |threads, pass_spp| RenderSettings {
            width: 32,
            height: 24,
            spp,
            seed: 9,
            threads: Some(threads),
            pass_spp,
            sampler: SOBOL,
            ..Default::default()
        };
        let a = render_image(&scene, &camera, path.as_ref(), &rs(1, spp));
        let b = render_image(&scene, &camera, path.as_ref(), &rs(2, 3));
        let c = render_image(&scene, &camera, path.as_ref(), &rs(3, 1));
        assert_eq!(a.radiance(), b.radiance(), "{spp} spp");
        assert_eq!(a.radiance(), c.radiance(), "{spp} spp");
        assert!(a.radiance().iter().all(|p| p.is_finite()));
        let other = render_image(
            &scene,
            &camera,
            path.as_ref(),
            &RenderSettings {
                seed: 10,
                ..rs(2, 4)
            },
        );
        assert_ne!(a.radiance(), other.radiance());
    }
}

/// Sobol renders estimate the same image as independent ones: image mean and quadrant means
/// by a z-test with standard errors over 8 seeds (independent scrambles; region_means_with),
/// for the integrators whose samples take fixed slots (path) or padded ones (bdpt's camera
/// subpaths, path_skeleton's guided directions); every pixel finite (checked there too).
#[test]
fn sobol_renders_agree_with_independent() {
    let settings = IntegratorSettings {
        max_depth: 5,
        ..Default::default()
    };
    let (cornell, cornell_camera) = cornell();
    let (boxed, box_camera) = box_scene(true, true, true);
    for (label, scene, camera, name, spp) in [
        ("cornell", &cornell, &cornell_camera, "path", 8),
        ("cornell", &cornell, &cornell_camera, "path", 5),
        ("cornell", &cornell, &cornell_camera, "path_skeleton", 8),
        ("box", &boxed, &box_camera, "path", 8),
        ("box", &boxed, &box_camera, "bdpt", 4),
    ] {
        let means = |kind| region_means_with(scene, camera, name, settings, kind, 24, spp, 8);
        let sobol = means(SOBOL);
        let independent = means(SamplerKind::Independent);
        assert!(sobol[0].0 > 0.0, "{label}: black image");
        assert_agree(
            &format!("{label} {name} {spp} spp"),
            ("sobol", &sobol),
            ("independent", &independent),
        );
    }
}

#[test]
fn contenders_take_a_sampler_option() {
    let s = IntegratorSettings::default();
    let c = Contender::from_spec("path:sampler=independent:max_depth=3", s).unwrap();
    assert_eq!(c.sampler, Some(SamplerKind::Independent));
    assert_eq!(c.label, "path:sampler=independent:max_depth=3");
    assert_eq!(c.integrator.name(), "path");
    assert_eq!(Contender::from_spec("bdpt", s).unwrap().sampler, None);
    let e = Contender::from_spec("path:sampler=halton", s)
        .err()
        .unwrap();
    assert!(e.to_string().contains("halton"), "{e}");
}

#[test]
fn command_line_records_the_sampler() {
    let dir = std::env::temp_dir().join(format!("lacuna-sampler-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let run = |sampler: Option<&str>| {
        let out = dir.join(format!("{}.exr", sampler.unwrap_or("default")));
        let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_lacuna"));
        cmd.args([
            "render", "--width", "8", "--height", "6", "--spp", "2", "--quiet",
        ]);
        if let Some(s) = sampler {
            cmd.args(["--sampler", s]);
        }
        let status = cmd.arg("--out").arg(&out).output().unwrap();
        (status, out)
    };
    for (arg, expected) in [
        (None, "sobol"),
        (Some("independent"), "independent"),
        (Some("sobol"), "sobol"),
    ] {
        let (status, out) = run(arg);
        assert!(
            status.status.success(),
            "{}",
            String::from_utf8_lossy(&status.stderr)
        );
        let img = lacuna::film::read_exr_rgb(&out).unwrap();
        assert_eq!(img.metadata.get("sampler"), Some(expected));
    }
    let (status, _) = run(Some("halton"));
    assert!(!status.status.success());
    assert!(String::from_utf8_lossy(&status.stderr).contains("halton"));
    std::fs::remove_dir_all(&dir).ok();
}

/// The delta-light box of tests/bdpt.rs (point, spot and directional lights beside the area
/// light, no delta surfaces) at its settings, with 16 seeds per sampler.
#[test]
fn sobol_agrees_with_independent_under_delta_lights() {
    let (scene, camera) = box_scene(false, true, true);
    let settings = IntegratorSettings {
        max_depth: 6,
        ..Default::default()
    };
    let means = |kind| region_means_with(&scene, &camera, "path", settings, kind, 20, 16, 16);
    let sobol = means(SOBOL);
    let independent = means(SamplerKind::Independent);
    eprintln!("sobol {sobol:?}\nindependent {independent:?}");
    assert_agree(
        "delta lights path",
        ("sobol", &sobol),
        ("independent", &independent),
    );
}
