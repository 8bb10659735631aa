//! path_skeleton on the procedural family `rooms:SEED` (scenes no default was tuned on).

mod common;

use lacuna::integrator::{self, IntegratorSettings};
use lacuna::math::{luminance, SamplerKind};
use lacuna::render::{prepare, RenderSettings};
use lacuna::scene::{Camera, FamilyScene, Scene};

/// The largest single-sample luminance of `spec` over `seeds` one-sample renders, the mean,
/// and the render's largest guided path weight against `path`'s.
fn largest_sample(seed: u64, spec: &str, max_depth: u32, seeds: u64) -> (f64, f64, f32) {
    let family = FamilyScene::generate(seed);
    let scene = family.builder().unwrap().build().unwrap();
    let settings = IntegratorSettings {
        max_depth,
        ..Default::default()
    };
    let mut integrator = integrator::create(spec, settings).unwrap();
    prepare(
        integrator.as_mut(),
        &scene,
        &family.camera,
        Some(2),
        &|_, _| true,
    )
    .unwrap();
    let (mut largest, mut sum, mut n, mut ratio) = (0f64, 0f64, 0f64, 0f32);
    for s in 0..seeds {
        let rs = RenderSettings {
            width: 64,
            height: 48,
            spp: 1,
            seed: s * 7919 + 1,
            sampler: lacuna::math::SamplerKind::Independent,
            threads: Some(2),
            ..Default::default()
        };
        let (film, stats) = lacuna::render::render(
            &scene,
            &family.camera,
            integrator.as_ref(),
            &rs,
            &|_| true,
            &std::sync::atomic::AtomicBool::new(false),
        )
        .unwrap();
        ratio = ratio.max(stats.largest_guided_ratio);
        for p in film.radiance() {
            let l = luminance(p) as f64;
            largest = largest.max(l);
            sum += l;
            n += 1.0;
        }
    }
    (largest, sum / n, ratio)
}

/// The fireflies: on a family scene of two rooms and one door (the light in the room
/// the camera looks into), a fixed c = 0.5 with the lobes (what an untrained guide renders)
/// weighed paths up to 2^k times `path`'s, k the directions the BSDF drew where the lobes have
/// no density: single samples at 4x `path`'s largest. With `ratio_max=auto` (2)
/// its largest sample stays within 2x `path`'s; with the bound off they come back (the test
/// can fail).
#[test]
fn a_fixed_c_makes_no_fireflies() {
    let (path, path_mean, no_ratio) = largest_sample(33, "path", 65, 16);
    assert!(no_ratio <= 1.0, "{no_ratio}");
    let (fixed, fixed_mean, ratio) =
        largest_sample(33, "path_skeleton:c_skel=0.5:directions=lobes", 65, 16);
    assert!(ratio > 1.0 && ratio <= 2.0 * (1.0 + 1e-5), "{ratio}");
    let (off, _, off_ratio) = largest_sample(
        33,
        "path_skeleton:c_skel=0.5:directions=lobes:ratio_max=off",
        65,
        16,
    );
    assert!(
        fixed <= 2.0 * path,
        "fixed c: {fixed} against path's {path}"
    );
    assert!(
        off > 2.0 * path,
        "the bound off: {off} against path's {path}"
    );
    assert!(off_ratio > 4.0, "{off_ratio}");
    // Same expectation (a loose check; the z-tests below are the real one).
    assert!(
        (fixed_mean / path_mean - 1.0).abs() < 0.1,
        "{fixed_mean} {path_mean}"
    );
}

/// The cause of the trained guide's heavy tail on deep scenes: at a vertex where the guide's
/// density is small the BSDF's direction weighs up to 1 / (1 - c) of `path`'s, and on paths of
/// dozens of vertices (max depth 65) these factors multiply; most of a closed family scene's
/// second moment is light found after many bounces, which the guide does not aim at. The
/// default bound (`ratio_max=auto`, 2) keeps every guided path within twice `path`'s weight for
/// the same directions, and the per-sample variance at or below `path`'s on rooms:18 (4
/// openings between camera and light), where unbounded it is well above (8.6x here, 1.38x at
/// 64x48: BENCHMARKS.md).
/// Fails with the old default (no bound where the training chose c). The pilot is off so
/// that both render guided samples.
#[test]
fn trained_guides_bound_the_path_weight_product_on_deep_scenes() {
    let (v_path, _, _) = per_sample(18, "path", 16);
    let (v_bounded, _, _) = per_sample(18, "path_skeleton:pilot_paths=0", 16);
    let (v_unbounded, _, _) = per_sample(18, "path_skeleton:pilot_paths=0:ratio_max=off", 16);
    let (_, _, ratio) = largest_sample(18, "path_skeleton:pilot_paths=0", 65, 4);
    let (_, _, ratio_off) = largest_sample(18, "path_skeleton:pilot_paths=0:ratio_max=off", 65, 4);
    println!(
        "rooms:18 per-sample variance: path {v_path:.4e}, bounded {v_bounded:.4e}, unbounded \
         {v_unbounded:.4e}; largest weight ratio {ratio} (unbounded {ratio_off})"
    );
    assert!(ratio > 1.0 && ratio <= 2.0 * (1.0 + 1e-5), "{ratio}");
    assert!(ratio_off > 4.0, "{ratio_off}");
    assert!(v_bounded <= v_path, "{v_bounded} against path's {v_path}");
    assert!(
        v_unbounded > 1.1 * v_path,
        "{v_unbounded} against path's {v_path}"
    );
}

/// The family scenes the tests draw: `n` seeds from 100 on (none chosen by hand; the z-test
/// fails on a black image, so a scene the camera sees no light in would show).
fn drawn_seeds(n: usize) -> Vec<u64> {
    (100..).take(n).collect()
}

/// Unbiasedness: the default `path_skeleton` (smaller training) and a fixed c = 0.5 with the
/// lobes (guiding everywhere) against `path`, region means z-tested over 8 seeds, on a dozen
/// family scenes drawn by seed.
#[test]
fn guided_images_agree_with_path_on_family_scenes() {
    for seed in drawn_seeds(12) {
        let family = FamilyScene::generate(seed);
        let scene = family.builder().unwrap().build().unwrap();
        common::agreement::agree_with_path(
            &family.description(),
            &scene,
            &family.camera,
            12,
            16,
            32,
            &[
                "path_skeleton:training_paths=8192",
                "path_skeleton:c_skel=0.5:directions=lobes",
            ],
        );
    }
}

/// What the scene-level switch decides on family scenes (`cargo test --release --test family
/// -- --ignored --nocapture switch`).
#[test]
#[ignore]
fn probe_switch() {
    for seed in 0..40 {
        let family = FamilyScene::generate(seed);
        let scene = family.builder().unwrap().build().unwrap();
        let (_, settings) =
            integrator::parse_spec("path_skeleton", IntegratorSettings::default()).unwrap();
        let mut pt = lacuna::integrator::PathTracer::skeleton_guided(settings).unwrap();
        prepare(&mut pt, &scene, &family.camera, Some(2), &|_, _| true).unwrap();
        let guide = pt.guide().unwrap();
        let t = guide.training().unwrap();
        println!(
            "{} | guides nothing {} | efficiency {:.3} variance {:.3} cost {:.3}",
            family.description(),
            guide.guides_nothing(),
            t.scene.efficiency(),
            t.scene.predicted_variance(),
            t.scene.cost_ratio
        );
    }
}

/// The scene-level switch on open family scenes (one outer side missing, or no ceiling)
/// whose camera shares its room with a light: guiding cannot pay there (the direct light
/// dominates, much of what the lobes aim at leaves the scene) and the default switches itself
/// off, so `path_skeleton` renders `path`'s samples.
#[test]
fn the_switch_turns_guiding_off_on_open_scenes_lit_in_the_camera_room() {
    for seed in [0, 16, 21] {
        let family = FamilyScene::generate(seed);
        assert_ne!(family.openness, lacuna::scene::Openness::Closed);
        assert_eq!(family.min_openings_to_light(), 0);
        let scene = family.builder().unwrap().build().unwrap();
        let (_, settings) =
            integrator::parse_spec("path_skeleton", IntegratorSettings::default()).unwrap();
        let mut pt = lacuna::integrator::PathTracer::skeleton_guided(settings).unwrap();
        prepare(&mut pt, &scene, &family.camera, Some(2), &|_, _| true).unwrap();
        let guide = pt.guide().unwrap();
        let t = guide.training().unwrap();
        assert!(t.paths > 0);
        assert!(
            guide.guides_nothing(),
            "{}: efficiency {:.3}",
            family.description(),
            t.scene.efficiency()
        );
        // The scout stopped the training (`guide::training`, "The scout"): the switch-off
        // did not pay for the full training.
        assert_eq!(
            t.paths,
            lacuna::guide::DEFAULT_TRAINING_PATHS / 8,
            "{}",
            family.description()
        );
    }
}

/// rooms:SEED, its scene, and `spec` (`path` or `path_skeleton[:options]`) at max depth 65,
/// prepared for the family's camera on 2 threads.
fn prepared(seed: u64, spec: &str) -> (FamilyScene, Scene, lacuna::integrator::PathTracer) {
    let family = FamilyScene::generate(seed);
    let scene = family.builder().unwrap().build().unwrap();
    let pt = prepared_on(&family, &scene, spec);
    (family, scene, pt)
}

/// `spec` (`path` or `path_skeleton[:options]`) at max depth 65, prepared on `scene` for
/// `family`'s camera on 2 threads.
fn prepared_on(family: &FamilyScene, scene: &Scene, spec: &str) -> lacuna::integrator::PathTracer {
    let settings = IntegratorSettings {
        max_depth: 65,
        ..Default::default()
    };
    let (_, settings) = integrator::parse_spec(spec, settings).unwrap();
    let mut pt = if spec.starts_with("path_skeleton") {
        lacuna::integrator::PathTracer::skeleton_guided(settings).unwrap()
    } else {
        lacuna::integrator::PathTracer::new(settings)
    };
    prepare(&mut pt, scene, &family.camera, Some(2), &|_, _| true).unwrap();
    pt
}

/// Per-sample variance (pixel variance over independent renders, averaged over the image) and
/// rays per sample of `spec` on a family scene, and its guide's training report.
fn per_sample(
    seed: u64,
    spec: &str,
    renders: u64,
) -> (f64, f64, Option<lacuna::guide::TrainingReport>) {
    let (family, scene, pt) = prepared(seed, spec);
    let (variance, rays) = pixel_variance(
        &family.camera,
        &scene,
        &pt,
        (32, 16),
        (8, renders),
        (lacuna::math::SamplerKind::Independent, 3),
    );
    let training = pt.guide().and_then(|g| g.training().cloned());
    (variance, rays, training)
}

/// Never a loss, deterministically: the pilot (`integrator::path`, "The pilot") keeps guiding
/// where the render's own per-sample variance and work count say it pays and switches it off
/// where they say it does not, also where the training's prediction said the opposite. The
/// measurement is independent of the pilot: pixel variances over renders under the render's
/// Sobol numbers (other scrambles) at a 2:1 image (the pilot's and the training's aspect), and
/// the renders' ray counts times the training's overhead ratio as the cost (no timing). The
/// test fails if the pilot is ignored (forced choices that the training predicts to pay but
/// do not) or if it switches off a scene that clearly gains (the corridor).
#[test]
fn the_pilot_agrees_with_the_measured_per_sample_efficiency() {
    // The pilot's cost as a work count (`pilot_cost=work`), which this test measures too.
    let forced = "path_skeleton:training_significance=0:training_min_nonzero=1:training_guided_cost=0:pilot_cost=work";
    // Unbounded (`ratio_max=off`) the forced choices lose on rooms:3.
    let forced_unbounded = format!("{forced}:ratio_max=off");
    let piloted = "path_skeleton:pilot_cost=work";
    let corridor = lacuna::scene::corridor_builder().unwrap().build().unwrap();
    let corridor_camera = *corridor.camera().unwrap();
    let family: Vec<(u64, Scene, Camera)> = [30u64, 33, 3]
        .into_iter()
        .map(|seed| {
            let f = FamilyScene::generate(seed);
            (seed, f.builder().unwrap().build().unwrap(), f.camera)
        })
        .collect();
    let cases: Vec<(&str, &Scene, Camera, u32, &str)> = vec![
        ("rooms:30", &family[0].1, family[0].2, 65, piloted),
        ("rooms:33", &family[1].1, family[1].2, 65, piloted),
        ("rooms:3", &family[2].1, family[2].2, 65, forced),
        ("rooms:3", &family[2].1, family[2].2, 65, &forced_unbounded),
        ("corridor", &corridor, corridor_camera, 8, piloted),
    ];
    let (mut on, mut off, mut overruled) = (0, 0, 0);
    for (name, scene, camera, max_depth, spec) in cases {
        let make = |spec: &str| {
            let settings = IntegratorSettings {
                max_depth,
                ..Default::default()
            };
            let (_, settings) = integrator::parse_spec(spec, settings).unwrap();
            let mut pt = if spec.starts_with("path_skeleton") {
                lacuna::integrator::PathTracer::skeleton_guided(settings).unwrap()
            } else {
                lacuna::integrator::PathTracer::new(settings)
            };
            prepare(&mut pt, scene, &camera, Some(2), &|_, _| true).unwrap();
            pt
        };
        let measure = |pt: &lacuna::integrator::PathTracer| {
            pixel_variance(
                &camera,
                scene,
                pt,
                (32, 16),
                (8, 12),
                (SamplerKind::Sobol, 3),
            )
        };
        let (v_path, rays_path) = measure(&make("path"));
        let unpiloted = make(&format!("{spec}:pilot_paths=0"));
        let (v_guided, rays_guided) = measure(&unpiloted);
        let t = unpiloted.guide().unwrap().training().unwrap().clone();
        let measured = v_path / v_guided / (rays_guided / rays_path * t.scene.cost_ratio);
        let pt = make(spec);
        let guide = pt.guide().unwrap();
        let pilot = guide.training().unwrap().scene.pilot;
        let scout = pt.scout_pilot();
        println!(
            "{name} {spec}: training {:.3} (guides {}), scout's pilot {:?}, pilot {:?}, measured {measured:.3}, off {}",
            t.scene.efficiency(),
            !t.scene.switched_off,
            scout.map(|p| p.efficiency()),
            pilot.map(|p| (p.efficiency(), p.efficiency_bound())),
            guide.guides_nothing()
        );
        if t.scene.switched_off {
            continue;
        }
        // The verdict: the pilot's on the trained guide, or where the pilot on the scout's
        // guide read a loss, that one (no full training, nothing guided).
        let pays = match pilot {
            Some(pilot) => pilot.pays(),
            None => {
                let scout = scout.expect("a trained guide that guides runs a pilot");
                assert!(!scout.may_pay_after_training(), "{name} {spec}");
                false
            }
        };
        // The pilot's verdict is conservative (`Pilot::pays`: two standard errors): it must
        // keep clear gains, and may drop marginal ones.
        if measured > 1.6 {
            assert!(
                !guide.guides_nothing(),
                "{name} {spec}: measured {measured}"
            );
            on += 1;
        } else if measured < 0.95 {
            assert!(guide.guides_nothing(), "{name} {spec}: measured {measured}");
            off += 1;
            overruled += usize::from(t.scene.pays());
        }
        assert_eq!(guide.guides_nothing(), !pays);
    }
    assert!(
        on >= 1 && off >= 1 && overruled >= 1,
        "{on} {off} {overruled}"
    );
}

/// Per-sample variance and time of the default `path_skeleton` against `path` on a few family
/// scenes (`-- --ignored --nocapture per_sample`): the training's prediction against what the
/// render does, without precomputation or equal-time noise.
#[test]
#[ignore]
fn probe_per_sample() {
    for seed in [18, 30, 33, 3] {
        let family = FamilyScene::generate(seed);
        let scene = family.builder().unwrap().build().unwrap();
        let mut row = Vec::new();
        for spec in ["path", "path_skeleton"] {
            let settings = IntegratorSettings {
                max_depth: 65,
                ..Default::default()
            };
            let mut integrator = integrator::create(spec, settings).unwrap();
            prepare(
                integrator.as_mut(),
                &scene,
                &family.camera,
                Some(2),
                &|_, _| true,
            )
            .unwrap();
            let (w, h, seeds) = (32u32, 24u32, 24u64);
            let n = (w * h) as usize;
            let (mut sum, mut sum2, mut secs) = (vec![0f64; n], vec![0f64; n], 0f64);
            for s in 0..seeds {
                let rs = RenderSettings {
                    width: w,
                    height: h,
                    spp: 16,
                    seed: s * 7919 + 1,
                    sampler: lacuna::math::SamplerKind::Independent,
                    threads: Some(2),
                    ..Default::default()
                };
                let (film, stats) = lacuna::render::render(
                    &scene,
                    &family.camera,
                    integrator.as_ref(),
                    &rs,
                    &|_| true,
                    &std::sync::atomic::AtomicBool::new(false),
                )
                .unwrap();
                secs += stats.seconds;
                for (k, p) in film.radiance().iter().enumerate() {
                    let l = luminance(*p) as f64;
                    sum[k] += l;
                    sum2[k] += l * l;
                }
            }
            let var: f64 = (0..n)
                .map(|k| {
                    let m = sum[k] / seeds as f64;
                    sum2[k] / seeds as f64 - m * m
                })
                .sum::<f64>()
                / n as f64;
            row.push((var, secs));
        }
        let (vp, tp) = row[0];
        let (vs, ts) = row[1];
        println!(
            "rooms:{seed}: variance path/skel {:.3}x, time skel/path {:.3}x, efficiency {:.3}x",
            vp / vs,
            ts / tp,
            vp / vs / (ts / tp)
        );
    }
}

/// The training's prediction and the pilot's measurement on family scenes (`-- --ignored
/// --nocapture probe_prediction`; SEEDS=3,18 and SPECS="path_skeleton path_skeleton:..." in
/// the environment choose them).
#[test]
#[ignore]
fn probe_prediction() {
    let seeds: Vec<u64> = std::env::var("SEEDS")
        .map(|s| s.split(',').map(|x| x.parse().unwrap()).collect())
        .unwrap_or(vec![18, 30, 33, 3]);
    let specs: Vec<String> = std::env::var("SPECS")
        .map(|s| s.split(' ').map(String::from).collect())
        .unwrap_or(vec!["path_skeleton".into()]);
    for seed in seeds {
        let family = FamilyScene::generate(seed);
        let scene = family.builder().unwrap().build().unwrap();
        for spec in &specs {
            let (_, settings) = integrator::parse_spec(
                spec,
                IntegratorSettings {
                    max_depth: 65,
                    ..Default::default()
                },
            )
            .unwrap();
            let mut pt = lacuna::integrator::PathTracer::skeleton_guided(settings).unwrap();
            let t0 = std::time::Instant::now();
            prepare(&mut pt, &scene, &family.camera, Some(2), &|_, _| true).unwrap();
            let guide = pt.guide().unwrap();
            let t = guide.training().unwrap();
            let p = t.scene.pilot.unwrap_or_default();
            println!(
                "rooms:{seed} {spec} | off {} | pilot var {:.3} cost {:.3} eff {:.3} | eff {:.3} var {:.3} vsum {:.3} cost {:.3} nodes {} | {:.2}s",
                guide.guides_nothing(),
                p.variance_ratio(), p.cost_ratio, p.efficiency(),
                t.scene.efficiency(),
                t.scene.predicted_variance(),
                t.scene.variance_ratio,
                t.scene.cost_ratio,
                t.guided_nodes(),
                t0.elapsed().as_secs_f64()
            );
        }
    }
}

/// FNV-1a of a string: a short, stable fingerprint of exact values.
fn fingerprint(text: &str) -> u64 {
    text.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

/// The bits of a 24x16, 4 spp render of `spec` on rooms:SEED at max depth 65 (2 threads).
fn image_fingerprint(seed: u64, spec: &str) -> (u64, Option<lacuna::guide::TrainingReport>) {
    let (family, scene, pt) = prepared(seed, spec);
    let rs = RenderSettings {
        width: 24,
        height: 16,
        spp: 4,
        threads: Some(2),
        ..Default::default()
    };
    let (film, _) = lacuna::render::render(
        &scene,
        &family.camera,
        &pt,
        &rs,
        &|_| true,
        &std::sync::atomic::AtomicBool::new(false),
    )
    .unwrap();
    let bits: String = film
        .radiance()
        .iter()
        .map(|p| {
            format!(
                "{:08x}{:08x}{:08x}",
                p.x.to_bits(),
                p.y.to_bits(),
                p.z.to_bits()
            )
        })
        .collect();
    let training = pt.guide().and_then(|g| g.training().cloned());
    (fingerprint(&bits), training)
}

/// The path tracer and the training share one estimator (`guide::estimator`): pinned
/// fingerprints of `path`'s and the guided render's pixels and of the training's report (every
/// node's choice and the scene-level prediction, exact values) on a family scene, taken before
/// the two were made to share it. A change to either estimator's arithmetic or random
/// numbers fails here; update the pins only for an intended change of behaviour.
#[test]
fn path_images_and_training_reports_are_pinned() {
    let (path, _) = image_fingerprint(30, "path");
    let (guided, training) = image_fingerprint(30, "path_skeleton:pilot_paths=0");
    let report = fingerprint(&format!("{:?}", training.unwrap()));
    println!("pins: path {path:#018x} guided {guided:#018x} report {report:#018x}");
    assert_eq!(path, 0xea47_0cab_a65d_9f81);
    assert_eq!(guided, 0xda63_c17a_929d_b81d);
    assert_eq!(report, 0x17e5_31c7_e44d_8b7c);
    // A scene the scout lets through learns what it learns without the scout and pilot (the
    // scout's paths are the full training's first; the pilot here, by its point estimate
    // under independent numbers, keeps guiding).
    let (_, piloted) = image_fingerprint(
        30,
        "path_skeleton:pilot_cost=work:pilot_sampler=independent:pilot_sigmas=0",
    );
    let mut piloted = piloted.unwrap();
    // The pilot on the scout's guide ran and let the full training go on, which started from
    // the scout's state exactly (the check's changes undone, its visibility cache included).
    let (_, _, pt) = prepared(
        30,
        "path_skeleton:pilot_cost=work:pilot_sampler=independent:pilot_sigmas=0",
    );
    assert!(pt.scout_pilot().unwrap().may_pay_after_training());
    assert_eq!(piloted.paths, lacuna::guide::DEFAULT_TRAINING_PATHS);
    assert!(piloted.scene.pilot.take().unwrap().pays());
    assert_eq!(fingerprint(&format!("{piloted:?}")), report);
}

/// The pilot's verdict weighs the variance ratio by the measured cost: with the default
/// `pilot_cost=time`, the guided samples' time over the unguided ones' (traced interleaved);
/// with `work`, the ray ratio times the training's overhead ratio. Both pilots see the same
/// training and the same variances (no timing is asserted, only which cost decides).
#[test]
fn the_pilot_decides_with_the_measured_cost() {
    // Without the scout's pilot, which may stop these choices before the full training.
    let forced = "path_skeleton:training_significance=0:training_min_nonzero=1:training_guided_cost=0:scout_pilot=off";
    let pilot_of = |spec: &str| {
        let family = FamilyScene::generate(3);
        let scene = family.builder().unwrap().build().unwrap();
        let settings = IntegratorSettings {
            max_depth: 65,
            ..Default::default()
        };
        let (_, settings) = integrator::parse_spec(spec, settings).unwrap();
        let mut pt = lacuna::integrator::PathTracer::skeleton_guided(settings).unwrap();
        prepare(&mut pt, &scene, &family.camera, Some(2), &|_, _| true).unwrap();
        let guide = pt.guide().unwrap();
        let t = guide.training().unwrap();
        let pilot = t.scene.pilot.expect("the forced choices are piloted");
        assert_eq!(guide.guides_nothing(), !pilot.pays());
        (pilot, t.scene.cost_ratio)
    };
    let (timed, _) = pilot_of(forced);
    let (counted, training_cost) = pilot_of(&format!("{forced}:pilot_cost=work"));
    assert!(timed.seconds_path > 0.0 && timed.seconds_guided > 0.0);
    assert_eq!(timed.cost_ratio, timed.seconds_guided / timed.seconds_path);
    let rays = counted.rays_per_sample_guided / counted.rays_per_sample_path;
    assert_eq!(counted.cost_ratio, rays * training_cost);
    assert_eq!(timed.variance_path, counted.variance_path);
    assert_eq!(timed.variance_guided, counted.variance_guided);
    let bound =
        1.0 / (timed.variance_ratio() * (1.0 + 2.0 * timed.variance_error) * timed.cost_ratio);
    assert_eq!(timed.sigmas, 2.0);
    assert_eq!(timed.pays(), bound > 1.1);
}

/// The per-sample luminance variance of `pt` on a family scene at `w` x `h`, `spp` x `renders`
/// (pixel variance over renders with their own random numbers, seeds `s * 7919 + offset`,
/// averaged over the image) with `sampler`, and the rays traced per sample.
fn pixel_variance(
    camera: &Camera,
    scene: &Scene,
    pt: &lacuna::integrator::PathTracer,
    (w, h): (u32, u32),
    (spp, renders): (u32, u64),
    (sampler, seed_offset): (lacuna::math::SamplerKind, u64),
) -> (f64, f64) {
    let n = (w * h) as usize;
    let (mut sum, mut sum2, mut rays) = (vec![0f64; n], vec![0f64; n], 0u64);
    for s in 0..renders {
        let rs = RenderSettings {
            width: w,
            height: h,
            spp,
            seed: s * 7919 + seed_offset,
            sampler,
            threads: Some(2),
            ..Default::default()
        };
        let (film, stats) = lacuna::render::render(
            scene,
            camera,
            pt,
            &rs,
            &|_| true,
            &std::sync::atomic::AtomicBool::new(false),
        )
        .unwrap();
        rays += stats.rays;
        for (k, p) in film.radiance().iter().enumerate() {
            let l = luminance(*p) as f64;
            sum[k] += l;
            sum2[k] += l * l;
        }
    }
    let r = renders as f64;
    let variance = (0..n)
        .map(|k| sum2[k] / r - (sum[k] / r).powi(2))
        .sum::<f64>()
        / n as f64
        * spp as f64
        * r
        / (r - 1.0);
    (
        variance,
        rays as f64 / (renders * (w * h * spp) as u64) as f64,
    )
}

/// The pilot's variance *ratio* (guided over unguided) against the render's own per-sample
/// ratio, measured independently: pixel variances of renders at the pilot's 2:1 aspect, the
/// same trained choices forced on with `pilot_paths=0`. Both pilots: the default (pairs of
/// independent samples along one ray) against renders with independent numbers, and
/// `pilot_sampler=sobol` (pixels of 16 samples under two scrambles) against renders with the
/// render's default Sobol numbers under other scrambles. On a family scene where guiding
/// gains per sample under independent numbers but less under Sobol (rooms:30, heavy-tailed)
/// and one where it does not pay for its cost (rooms:17), each pilot must agree with its
/// measurement within a multiple of its own stated relative error (`Pilot::variance_error`):
/// 2.5 times and at least 20 % for the default, 2 times and at least 15 % for Sobol; and the
/// default must see the gain on rooms:30. No timing: the verdict's cost
/// is not checked here. Measured 2026-12-07: rooms:30 independent pilot 0.539 (relative error
/// 0.40) against 0.523, Sobol pilot 1.073 (0.32) against 0.753; rooms:17 independent pilot
/// 0.667 (0.12) against 0.802, Sobol pilot 0.989 (0.14) against 0.932. The default pilot
/// against the Sobol measurement would fail on rooms:17 (log off 0.33, 0.24 allowed).
#[test]
fn the_pilot_ratio_agrees_with_the_render_per_sample_ratio() {
    let size = (32u32, 16u32);
    for seed in [30u64, 17] {
        let family = FamilyScene::generate(seed);
        let scene = family.builder().unwrap().build().unwrap();
        let make = |spec: &str| prepared_on(&family, &scene, spec);
        let forced = make("path_skeleton:pilot_cost=work:pilot_paths=0");
        assert!(!forced.guide().unwrap().guides_nothing());
        let unguided = make("path");
        for sampler in [SamplerKind::Independent, SamplerKind::Sobol] {
            // The pilot on the full guide: without the scout's pilot, which may stop first.
            let spec = format!(
                "path_skeleton:pilot_cost=work:scout_pilot=off:pilot_sampler={}",
                sampler.name()
            );
            let piloted = make(&spec);
            let pilot = piloted
                .guide()
                .unwrap()
                .training()
                .unwrap()
                .scene
                .pilot
                .expect("the training guides: the pilot runs");
            let measured = pixel_variance(
                &family.camera,
                &scene,
                &forced,
                size,
                (16, 24),
                (sampler, 11),
            )
            .0 / pixel_variance(
                &family.camera,
                &scene,
                &unguided,
                size,
                (16, 24),
                (sampler, 11),
            )
            .0;
            let off = (pilot.variance_ratio() / measured).ln().abs();
            println!(
                "rooms:{seed} {}: pilot {:.3} ({} units, relative error {:.2}), measured {measured:.3}, log off {off:.3}, efficiency at the pilot's cost: pilot {:.3} measured {:.3}",
                sampler.name(),
                pilot.variance_ratio(),
                pilot.units,
                pilot.variance_error,
                pilot.efficiency(),
                1.0 / (measured * pilot.cost_ratio),
            );
            // The Sobol pilot is held closer (its reading of rooms:17 is tighter).
            let (errors, floor) = match sampler {
                SamplerKind::Independent => (2.5, 0.2),
                SamplerKind::Sobol => (2.0, 0.15),
            };
            assert!(
                off < (errors * pilot.variance_error).max(floor),
                "rooms:{seed} {}: pilot {} against measured {measured}",
                sampler.name(),
                pilot.variance_ratio()
            );
            if seed == 30 && sampler == SamplerKind::Independent {
                assert!(measured < 1.0 && pilot.variance_ratio() < 1.0);
            }
        }
    }
}
