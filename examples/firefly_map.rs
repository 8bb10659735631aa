//! Where a render's fireflies come from (feature `diagnostics`): renders SCENE with each spec at
//! WIDTH x HEIGHT, SPP samples per pixel (seed SEED), and prints per spec the RMSE and MAE
//! against REFERENCE, the largest sample luminance and the mean over pixels of each pixel's
//! largest, then re-traces the TOP largest samples with per-vertex records (node, guiding
//! probability, the active lobes' selection probabilities, the BSDF's and the mixture's
//! densities of the direction taken): which vertex made the weight.
//!
//! `cargo run --release --features diagnostics --example firefly_map -- SCENE REFERENCE.exr WIDTH HEIGHT SPP SEED SPECS [TOP]`
//!
//! With `ATTRIB=1` it also records every sample and splits the image's second moment (the sum
//! over samples of the squared luminance, over the sample count: what a guide changes in the
//! MSE, the means being equal) by the sample's largest contribution: its depth and kind (emitter
//! hit, next-event estimation, environment), the product R of bsdf_pdf / pdf over the
//! directions before it (the weight against `path`'s for the same path), the number of guided
//! vertices before it and of those whose direction the BSDF drew, and the node of its largest
//! ratio.

use std::path::Path;

use lacuna::film::{image_errors, read_exr_rgb};
use lacuna::integrator::{
    self, diagnostics, IntegratorSettings, SampleContext, TraceCounters, View,
};
use lacuna::math::{luminance, PixelSampler, Rgb, SamplerKind};
use lacuna::render::prepare;
use lacuna::scene::load_scene_arg;
use rayon::prelude::*;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 8 {
        eprintln!("usage: firefly_map SCENE REFERENCE.exr WIDTH HEIGHT SPP SEED SPECS [TOP]");
        std::process::exit(2);
    }
    let scene = load_scene_arg(Path::new(&args[1]))
        .unwrap()
        .0
        .builder
        .build()
        .unwrap();
    let reference = read_exr_rgb(Path::new(&args[2])).unwrap();
    let width: u32 = args[3].parse().unwrap();
    let height: u32 = args[4].parse().unwrap();
    let spp: u32 = args[5].parse().unwrap();
    // SEED, or cRUN:CONTENDER for the seed `lacuna compare` gives that run (base seed 0).
    let seed: u64 = match args[6].strip_prefix('c') {
        Some(rc) => {
            let (run, contender) = rc.split_once(':').expect("cRUN:CONTENDER");
            lacuna::compare::run_seed(0, run.parse().unwrap(), contender.parse().unwrap())
        }
        None => args[6].parse().unwrap(),
    };
    let top: usize = args.get(8).map_or(3, |s| s.parse().unwrap());
    assert_eq!((reference.width, reference.height), (width, height));
    let camera = *scene.camera().expect("scene camera");
    let view = View {
        frame: camera.frame(width as f32 / height as f32),
        width,
        height,
        sampler: Default::default(),
    };
    for spec in args[7].split(',') {
        let mut integrator = integrator::create(spec, IntegratorSettings::default()).unwrap();
        prepare(integrator.as_mut(), &scene, &camera, None, &|_, _| true).unwrap();
        let integrator = integrator.as_ref();
        // One sample: its radiance, with vertex records when `record`.
        let trace = |pixel: u64, s: u32, record: bool| -> Rgb {
            let (x, y) = ((pixel % width as u64) as u32, (pixel / width as u64) as u32);
            let mut rng = PixelSampler::new(SamplerKind::default(), seed, pixel).sample(s);
            let ray = view.primary_ray(x, y, &mut rng);
            let ctx = SampleContext {
                pixel_index: pixel,
                sample_index: s,
                view: &view,
                iteration: None,
                layers: &[],
            };
            if record {
                diagnostics::start();
            }
            integrator
                .sample(&scene, ray, &mut rng, &mut TraceCounters::default(), &ctx)
                .radiance
        };
        // Per pixel: mean radiance, largest sample luminance and its index.
        let per_pixel: Vec<(Rgb, f32, u32)> = (0..(width * height) as u64)
            .into_par_iter()
            .map(|p| {
                let (mut sum, mut max, mut at) = (Rgb::ZERO, 0.0f32, 0u32);
                for s in 0..spp {
                    let r = trace(p, s, false);
                    let l = if lacuna::math::is_finite3(r) {
                        luminance(r)
                    } else {
                        f32::INFINITY
                    };
                    if l > max {
                        (max, at) = (l, s);
                    }
                    sum += r;
                }
                (sum * (1.0 / spp as f32), max, at)
            })
            .collect();
        let image: Vec<Rgb> = per_pixel.iter().map(|p| p.0).collect();
        let e = image_errors(&image, &reference.pixels).unwrap();
        let mean_max = per_pixel.iter().map(|p| p.1 as f64).sum::<f64>() / per_pixel.len() as f64;
        let mut order: Vec<usize> = (0..per_pixel.len()).collect();
        order.sort_by(|&a, &b| per_pixel[b].1.total_cmp(&per_pixel[a].1));
        println!(
            "{spec}: RMSE {:.4e} MAE {:.4e}; largest sample {:.3e}, mean of per-pixel largest {:.4e}",
            e.rmse, e.mae, per_pixel[order[0]].1, mean_max
        );
        // A pixel's squared error share: how much of the RMSE the worst pixels carry.
        let mut sq: Vec<f64> = image
            .iter()
            .zip(&reference.pixels)
            .map(|(a, b)| {
                let d = *a - *b;
                (d.length_squared() / 3.0) as f64
            })
            .collect();
        let total: f64 = sq.iter().sum();
        sq.sort_by(|a, b| b.total_cmp(a));
        println!(
            "  squared error share of the worst 1 / 5 / 20 pixels: {:.2} / {:.2} / {:.2}",
            sq[0] / total,
            sq[..5].iter().sum::<f64>() / total,
            sq[..20].iter().sum::<f64>() / total
        );
        if std::env::var("ATTRIB").is_ok_and(|v| v == "1") {
            attribute(&trace, width * height, spp);
        }
        for &p in order.iter().take(top) {
            let (mean, max, s) = per_pixel[p];
            let r = trace(p as u64, s, true);
            let vertices = diagnostics::take();
            println!(
                "  pixel ({}, {}) sample {s}: luminance {max:.3e} (pixel mean {:.3e}, reference {:.3e}), radiance {r:?}",
                p as u32 % width,
                p as u32 / width,
                luminance(mean),
                luminance(reference.pixels[p])
            );
            for v in vertices {
                println!(
                    "    depth {} node {:?} c {:.2} {} lobes {:?} bsdf_pdf {:.3e} pdf {:.3e} (ratio {:.2}) radiance before {:.3e}",
                    v.depth,
                    v.node,
                    v.c,
                    if v.from_guide { "guide" } else { "bsdf" },
                    v.lobes
                        .iter()
                        .map(|(w, portal)| format!("{w:.3}{}", if *portal { "p" } else { "" }))
                        .collect::<Vec<_>>(),
                    v.bsdf_pdf,
                    v.pdf,
                    v.bsdf_pdf / v.pdf,
                    v.radiance_before
                );
            }
        }
    }
}

/// One line of `ATTRIB=1`'s split: each bin's share of the second moment per sample.
fn print_shares(label: &str, bins: &[f64], samples: f64) {
    let shares: Vec<String> = bins
        .iter()
        .map(|&v| format!("{:.3e}", v / samples))
        .collect();
    println!("  {label}: {}", shares.join(" "));
}

/// The second-moment split of `ATTRIB=1` (module docs).
fn attribute(trace: &(dyn Fn(u64, u32, bool) -> Rgb + Sync), pixels: u32, spp: u32) {
    use diagnostics::Kind;
    const R_EDGES: [f32; 6] = [0.5, 1.0 - 1e-4, 1.0 + 1e-4, 1.5, 3.0, 10.0];
    #[derive(Default, Clone)]
    struct Acc {
        total: f64,
        by_kind_depth: Vec<f64>, // 3 x 8
        by_r: [f64; 7],
        by_guided: [f64; 4],
        by_bsdf_at_guided: [f64; 4],
        nodes: std::collections::HashMap<u32, f64>,
        squares: Vec<f32>,
    }
    let merge = |mut a: Acc, b: Acc| {
        a.total += b.total;
        for (x, y) in a.by_kind_depth.iter_mut().zip(&b.by_kind_depth) {
            *x += y;
        }
        for (x, y) in a.by_r.iter_mut().zip(&b.by_r) {
            *x += y;
        }
        for (x, y) in a.by_guided.iter_mut().zip(&b.by_guided) {
            *x += y;
        }
        for (x, y) in a.by_bsdf_at_guided.iter_mut().zip(&b.by_bsdf_at_guided) {
            *x += y;
        }
        for (k, v) in b.nodes {
            *a.nodes.entry(k).or_default() += v;
        }
        a.squares.extend(b.squares);
        a
    };
    let empty = || Acc {
        by_kind_depth: vec![0.0; 24],
        ..Acc::default()
    };
    let acc = (0..pixels as u64)
        .into_par_iter()
        .fold(empty, |mut a, p| {
            for s in 0..spp {
                diagnostics::start();
                let r = trace(p, s, true);
                let vertices = diagnostics::take();
                let contributions = diagnostics::take_contributions();
                let x = luminance(r) as f64;
                if !(x.is_finite() && x > 0.0) {
                    continue;
                }
                let x2 = x * x;
                a.total += x2;
                a.squares.push(x2 as f32);
                let Some(top) = contributions
                    .iter()
                    .max_by(|a, b| a.luminance.total_cmp(&b.luminance))
                else {
                    continue;
                };
                let kind = match top.kind {
                    Kind::Hit => 0,
                    Kind::Nee => 1,
                    Kind::Escaped => 2,
                };
                a.by_kind_depth[kind * 8 + (top.depth as usize).min(7)] += x2;
                let before = vertices.iter().filter(|v| v.depth < top.depth);
                let (mut ratio, mut guided, mut bsdf) = (1.0f32, 0usize, 0usize);
                let mut worst: Option<(f32, u32)> = None;
                for v in before {
                    let r = v.bsdf_pdf / v.pdf;
                    ratio *= r;
                    if v.c > 0.0 {
                        guided += 1;
                        bsdf += !v.from_guide as usize;
                        if let Some(n) = v.node {
                            if !worst.is_some_and(|(w, _)| r <= w) {
                                worst = Some((r, n));
                            }
                        }
                    }
                }
                let bin = R_EDGES.iter().filter(|&&e| ratio >= e).count();
                a.by_r[bin] += x2;
                a.by_guided[guided.min(3)] += x2;
                a.by_bsdf_at_guided[bsdf.min(3)] += x2;
                if let Some((r, n)) = worst {
                    if r > 1.0 {
                        *a.nodes.entry(n).or_default() += x2;
                    }
                }
            }
            a
        })
        .reduce(empty, merge);
    let n = pixels as f64 * spp as f64;
    let share = |v: f64| v / acc.total;
    println!(
        "  second moment (sum of squared sample luminance / samples): {:.4e}",
        acc.total / n
    );
    let mut squares = acc.squares.clone();
    squares.sort_by(|a, b| b.total_cmp(a));
    let top = |k: usize| {
        squares[..k.min(squares.len())]
            .iter()
            .map(|&x| x as f64)
            .sum::<f64>()
    };
    println!(
        "  share of the largest 1e-5 / 1e-4 / 1e-3 of the samples: {:.3} / {:.3} / {:.3}",
        share(top((n * 1e-5) as usize)),
        share(top((n * 1e-4) as usize)),
        share(top((n * 1e-3) as usize))
    );
    for (k, name) in ["hit", "nee", "escaped"].iter().enumerate() {
        let row: Vec<String> = acc.by_kind_depth[k * 8..k * 8 + 8]
            .iter()
            .map(|&v| format!("{:.3}", share(v)))
            .collect();
        println!(
            "  by largest contribution, {name} at depth 0..7+: {}",
            row.join(" ")
        );
    }
    print_shares(
        "by R (<0.5, 0.5-1, 1, 1-1.5, 1.5-3, 3-10, >=10)",
        &acc.by_r,
        n,
    );
    print_shares(
        "by guided vertices before it (0, 1, 2, 3+)",
        &acc.by_guided,
        n,
    );
    print_shares(
        "by BSDF-drawn guided vertices before it (0, 1, 2, 3+)",
        &acc.by_bsdf_at_guided,
        n,
    );
    let mut nodes: Vec<(u32, f64)> = acc.nodes.into_iter().collect();
    nodes.sort_by(|a, b| b.1.total_cmp(&a.1));
    println!(
        "  nodes of the largest ratio > 1 (share of the second moment): {}",
        nodes
            .iter()
            .take(10)
            .map(|(k, v)| format!("{k}: {:.3}", share(*v)))
            .collect::<Vec<_>>()
            .join(", ")
    );
}
