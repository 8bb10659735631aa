//! Error per sample and cost per sample of integrators at a fixed sample count, independent
//! of the machine's load (unlike `lacuna compare`'s equal-time runs): each spec renders the
//! scene `SEEDS` times at `SPP` samples per pixel, and the program prints the median over
//! seeds of MAE² x spp and RMSE² x spp against a reference (lower: a better estimator per
//! sample; both are constant in spp for an unbiased estimator whose error is the reference's
//! error-free variance), and the process's CPU time per sample (utime + stime from
//! /proc/self/stat, all worker threads, precomputation excluded). MAE² x CPU seconds is then
//! the equal-time figure of merit (lower is better) a quiet machine would show. The two error
//! columns give the median and, in parentheses, the range over the seeds.
//!
//! `cargo run --release --example per_sample -- SCENE REFERENCE.exr WIDTH HEIGHT SPP SEEDS SPECS [MAX_DEPTH [SAMPLER]]`
//! with SCENE a scene file or `corridor`, SPECS a comma-separated list of integrator specs
//! (`path,path_skeleton:aim=opening`), MAX_DEPTH 8 by default, SAMPLER `sobol` (default) or
//! `independent`. Linux only (/proc). A reference k times the size in both axes is box-averaged
//! down to WIDTHxHEIGHT. With `PER_SEED=1` each seed's MAE² x spp and RMSE² x spp are printed
//! too (`# seed` lines), and their means: heavy-tailed errors need more than the median.

use std::path::Path;
use std::sync::atomic::AtomicBool;

use lacuna::film::{image_errors, read_exr_rgb, ExrImage};
use lacuna::integrator::{self, IntegratorSettings};
use lacuna::math::Rgb;
use lacuna::math::SamplerKind;
use lacuna::render::{prepare, render, RenderSettings};
use lacuna::scene::load_scene_arg;

/// CPU seconds (user + system) this process has used, all threads.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").expect("/proc/self/stat");
    // Fields after the command name (which is in parentheses and may hold spaces).
    let rest = &stat[stat.rfind(')').expect("stat format") + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of stat(5), 12 and 13 after the name and state.
    let ticks: f64 = fields[11].parse::<f64>().unwrap() + fields[12].parse::<f64>().unwrap();
    // In clock ticks of 1/100 s (_SC_CLK_TCK is 100 on Linux in practice).
    ticks / 100.0
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 8 {
        eprintln!(
            "usage: per_sample SCENE REFERENCE.exr WIDTH HEIGHT SPP SEEDS SPECS [MAX_DEPTH [SAMPLER]]"
        );
        std::process::exit(2);
    }
    let scene = load_scene_arg(Path::new(&args[1]))
        .unwrap()
        .0
        .builder
        .build()
        .unwrap();
    let width: u32 = args[3].parse().unwrap();
    let height: u32 = args[4].parse().unwrap();
    let reference = downsample(read_exr_rgb(Path::new(&args[2])).unwrap(), width, height);
    let spp: u32 = args[5].parse().unwrap();
    let seeds: u64 = args[6].parse().unwrap();
    let max_depth: u32 = args.get(8).map_or(8, |s| s.parse().unwrap());
    let sampler = args
        .get(9)
        .map_or(SamplerKind::default(), |s| SamplerKind::parse(s).unwrap());
    assert_eq!(
        (reference.width, reference.height),
        (width, height),
        "reference size"
    );
    let camera = *scene.camera().expect("scene camera");
    println!(
        "{} at {width}x{height}, {spp} spp x {seeds} seeds, max depth {max_depth}, sampler {}; medians over seeds",
        args[1],
        sampler.name()
    );
    println!("| integrator | MAE | MAE² x spp | RMSE² x spp | CPU µs / sample | MAE² x CPU s |");
    println!("|---|---|---|---|---|---|");
    for spec in args[7].split(',') {
        let settings = IntegratorSettings {
            max_depth,
            ..Default::default()
        };
        let mut integrator = integrator::create(spec, settings).unwrap();
        prepare(integrator.as_mut(), &scene, &camera, None, &|_, _| true).unwrap();
        let (mut mae2, mut rmse2, mut mae, mut cpu) = (vec![], vec![], vec![], vec![]);
        for seed in 0..seeds {
            let rs = RenderSettings {
                width,
                height,
                spp,
                seed: 1000 + seed,
                sampler,
                ..Default::default()
            };
            let t = cpu_seconds();
            let (film, _) = render(
                &scene,
                &camera,
                integrator.as_ref(),
                &rs,
                &|_| true,
                &AtomicBool::new(false),
            )
            .unwrap();
            cpu.push(cpu_seconds() - t);
            let e = image_errors(&film.radiance(), &reference.pixels).unwrap();
            mae.push(e.mae);
            mae2.push(e.mae * e.mae * spp as f64);
            rmse2.push(e.rmse * e.rmse * spp as f64);
            if std::env::var("PER_SEED").is_ok_and(|v| v == "1") {
                println!(
                    "# seed {} {spec} MAE2xspp {:.5e} RMSE2xspp {:.5e}",
                    1000 + seed,
                    mae2[mae2.len() - 1],
                    rmse2[rmse2.len() - 1]
                );
            }
        }
        if std::env::var("PER_SEED").is_ok_and(|v| v == "1") {
            let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
            println!(
                "# mean {spec} MAE2xspp {:.5e} RMSE2xspp {:.5e}",
                mean(&mae2),
                mean(&rmse2)
            );
        }
        let samples = (width * height * spp) as f64;
        let cpu = median(cpu);
        let mae = median(mae);
        println!(
            "| {spec} | {mae:.3e} | {} | {} | {:.2} | {:.3e} |",
            spread(&mae2),
            spread(&rmse2),
            cpu / samples * 1e6,
            mae * mae * cpu
        );
    }
}

/// The reference box-averaged to WIDTHxHEIGHT when it is an integer multiple of it (k x k
/// reference pixels per pixel): exact in expectation, since pixel samples are uniform over the
/// pixel (a box filter), so a 128x64 reference serves 64x32 renders with 4x its samples.
fn downsample(r: ExrImage, width: u32, height: u32) -> ExrImage {
    let k = r.width / width;
    if k <= 1 || r.width != k * width || r.height != k * height {
        return r;
    }
    let mut pixels = vec![Rgb::ZERO; (width * height) as usize];
    for y in 0..r.height {
        for x in 0..r.width {
            let p = &mut pixels[((y / k) * width + x / k) as usize];
            *p += r.pixels[(y * r.width + x) as usize] * (1.0 / (k * k) as f32);
        }
    }
    ExrImage {
        width,
        height,
        pixels,
        metadata: r.metadata,
    }
}

/// Two decimals where that leaves three significant digits, else scientific notation (the
/// errors of dim scenes such as Sponza are far below 1).
fn figure(x: f64) -> String {
    if x.abs() >= 1.0 || x == 0.0 {
        format!("{x:.2}")
    } else {
        format!("{x:.3e}")
    }
}

/// The median and, over several seeds, the range: "median (min-max)".
fn spread(v: &[f64]) -> String {
    let m = figure(median(v.to_vec()));
    if v.len() < 2 {
        return m;
    }
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    format!("{m} ({}-{})", figure(lo), figure(hi))
}
