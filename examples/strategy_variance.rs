//! Which bidirectional strategies carry an integrator's error: each spec (`bdpt` or
//! `bdpt_skeleton`, with options) renders the scene `SEEDS` times at `SPP` samples per pixel
//! with every (s, t) strategy's weighted image (and, for `bdpt_skeleton:images=true`, the
//! per-distribution images), and the program prints per layer its image mean and the mean
//! over pixels of the per-sample variance (variance of the seeds' pixel means x spp,
//! luminance): for an unbiased estimator the variance is the error, so the largest rows say
//! where the MSE comes from. The strategies' variances do not add up to the image's exactly
//! (their covariances are left out); the image's own row is `image`.
//!
//! `cargo run --release --example strategy_variance -- SCENE WIDTH HEIGHT SPP SEEDS MAX_DEPTH SPECS`
//! (SPECS comma-separated, e.g. `bdpt,bdpt_skeleton:images=true`).

use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use lacuna::integrator::{self, Bdpt, BdptSkeleton, Integrator, IntegratorSettings};
use lacuna::math::luminance;
use lacuna::render::{prepare, render, RenderSettings};
use lacuna::scene::load_scene_arg;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 8 {
        eprintln!("usage: strategy_variance SCENE WIDTH HEIGHT SPP SEEDS MAX_DEPTH SPECS");
        std::process::exit(2);
    }
    let scene = load_scene_arg(Path::new(&args[1]))
        .unwrap()
        .0
        .builder
        .build()
        .unwrap();
    let width: u32 = args[2].parse().unwrap();
    let height: u32 = args[3].parse().unwrap();
    let spp: u32 = args[4].parse().unwrap();
    let seeds: u64 = args[5].parse().unwrap();
    assert!(seeds >= 2, "SEEDS must be at least 2");
    let max_depth: u32 = args[6].parse().unwrap();
    let camera = *scene.camera().expect("scene camera");
    let n = (width * height) as usize;
    for spec in args[7].split(',') {
        let base = IntegratorSettings {
            max_depth,
            ..Default::default()
        };
        let (name, settings) = integrator::parse_spec(spec, base).unwrap();
        let images = settings.max_depth + 1;
        let mut integrator: Box<dyn Integrator> = match name {
            "bdpt" => Box::new(Bdpt::new(settings).with_strategy_images(images).unwrap()),
            "bdpt_skeleton" => Box::new(
                BdptSkeleton::new(settings)
                    .unwrap()
                    .with_strategy_images(images)
                    .unwrap(),
            ),
            other => panic!("{other}: bdpt or bdpt_skeleton"),
        };
        prepare(integrator.as_mut(), &scene, &camera, None, &|_, _| true).unwrap();
        let mut names: Vec<String> = vec!["image".into()];
        names.extend(integrator.layers());
        let (mut sum, mut sum2) = (vec![0.0f64; names.len() * n], vec![0.0f64; names.len() * n]);
        let start = Instant::now();
        for seed in 0..seeds {
            let rs = RenderSettings {
                width,
                height,
                spp,
                seed: 7000 + seed,
                ..Default::default()
            };
            let (film, _) = render(
                &scene,
                &camera,
                integrator.as_ref(),
                &rs,
                &|_| true,
                &AtomicBool::new(false),
            )
            .unwrap();
            for (k, _) in names.iter().enumerate() {
                let values = if k == 0 {
                    film.radiance()
                } else {
                    film.layer(k - 1)
                };
                for (i, p) in values.iter().enumerate() {
                    let l = luminance(*p) as f64;
                    sum[k * n + i] += l;
                    sum2[k * n + i] += l * l;
                }
            }
        }
        let seconds = start.elapsed().as_secs_f64() / seeds as f64;
        let s = seeds as f64;
        let mut rows: Vec<(String, f64, f64)> = names
            .iter()
            .enumerate()
            .filter(|(_, name)| !name.ends_with("_unweighted"))
            .map(|(k, name)| {
                let (mut mean, mut var) = (0.0, 0.0);
                for i in 0..n {
                    let (a, b) = (sum[k * n + i], sum2[k * n + i]);
                    mean += a / s;
                    var += (b - a * a / s).max(0.0) / (s - 1.0) * spp as f64;
                }
                (name.clone(), mean / n as f64, var / n as f64)
            })
            .collect();
        rows.sort_by(|a, b| b.2.total_cmp(&a.2));
        println!(
            "{spec}: {width}x{height}, {spp} spp x {seeds} seeds, max depth {max_depth}, \
             {seconds:.2} s per render"
        );
        println!("| layer | mean | per-sample variance | share of the image's |");
        let total = rows.iter().find(|r| r.0 == "image").map_or(1.0, |r| r.2);
        for (name, mean, var) in rows.iter().filter(|r| r.2 > 1e-3 * total) {
            println!(
                "| {name} | {mean:.4e} | {var:.4e} | {:.3} |",
                var / total.max(1e-300)
            );
        }
    }
}
