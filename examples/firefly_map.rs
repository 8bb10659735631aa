//! Where a render's fireflies come from (feature `diagnostics`): renders SCENE with each spec at
//! WIDTH x HEIGHT, SPP samples per pixel (seed SEED), and prints per spec the RMSE and MAE
//! against REFERENCE, the largest sample luminance and the mean over pixels of each pixel's
//! largest, then re-traces the TOP largest samples with per-vertex records (node, guiding
//! probability, the active lobes' selection probabilities, the BSDF's and the mixture's
//! densities of the direction taken): which vertex made the weight.
//!
//! `cargo run --release --features diagnostics --example firefly_map -- SCENE REFERENCE.exr WIDTH HEIGHT SPP SEED SPECS [TOP]`

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
    };
    for spec in args[7].split(',') {
        let mut integrator = integrator::create(spec, IntegratorSettings::default()).unwrap();
        prepare(integrator.as_mut(), &scene, None, &|_, _| true).unwrap();
        let integrator = integrator.as_ref();
        // One sample: its radiance, with vertex records when `record`.
        let trace = |pixel: u64, s: u32, record: bool| -> Rgb {
            let (x, y) = ((pixel % width as u64) as u32, (pixel / width as u64) as u32);
            let mut rng = PixelSampler::new(SamplerKind::default(), seed, pixel).sample(s);
            let ray = view.primary_ray(x, y, &mut rng);
            let ctx = SampleContext {
                pixel_index: pixel,
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
                    "    depth {} node {:?} c {:.2} lobes {:?} bsdf_pdf {:.3e} pdf {:.3e} (ratio {:.2}) radiance before {:.3e}",
                    v.depth,
                    v.node,
                    v.c,
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
