//! Environment-map lights (issue 9). Prints markdown tables on stdout, progress on stderr.
//!
//! ```text
//! cargo bench --bench envmap -- build    # sampling-structure build / rebuild time per map size
//! cargo bench --bench envmap -- sampling # ns per light sample and per pdf, per strategy
//! cargo bench --bench envmap -- fig36    # 001 Figure 3.6: dynamic vs uniform face balancing
//! cargo bench --bench envmap             # both
//! ```
//!
//! `build`: the sky map (512 x 256) resampled to lat-long maps of 128 x 64 ... 2048 x 1024 and to
//! cube maps of faces width / 4; for each, the first build of the lat-long and of the cube-map
//! structures (including, for a density on the other layout, the point -> texel table) and
//! the rebuild from a new image of the same layout (`EnvironmentMap::update`: what a host pays
//! per frame of a dynamic map). Medians of `ENV_BENCH_REPS` (default 7) wall-clock timings.
//!
//! `fig36`: `env_direct` with N light samples and no BSDF samples (the estimator of eq. 3.5,
//! visibility included), per-normal dynamic balancing against uniform balancing (mu_f = 1/6),
//! plus the power balancing and the lat-long density for context, on the diffuse and the
//! glossy sphere of `scenes/envmaps/` under the sky and the studio maps, resampled to cube
//! maps of 6 x 128 x 128 (the thesis's setting: per-face CDFs over the map's own texels) and
//! as the original 512 x 256 lat-long maps (`ENV_BENCH_LAYOUTS`, default `cube,latlong`); 1 sample per pixel
//! with N light samples each, `ENV_BENCH_SEEDS` (default 4) seeds, `ENV_BENCH_SIZE`^2 pixels
//! (default 96). Error: RMSE and relative MSE (the thesis reports a mean Lab error) against a
//! reference of `ENV_BENCH_REF_SPP` (default 32) samples of 128 light + 128 BSDF samples
//! (dynamic balancing), whose own estimated MSE (from two independent halves) is subtracted.
//! "valid" is the mean number of light samples per pixel that carried light (not cancelled by
//! the cosine, the BSDF or a black texel; the thesis's "valid samples"), counted from the
//! shadow rays traced. "N for equal error" interpolates log MSE against log N between the
//! measured N.

use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use lacuna::compare::render_reference;
use lacuna::film::image_errors;
use lacuna::integrator::{self, IntegratorSettings};
use lacuna::light::environment::{describe, EnvImage, Grid};
use lacuna::light::{EnvSettings, EnvStrategy, EnvironmentMap};
use lacuna::render::{render, RenderSettings};
use lacuna::scene::{convert_layout, load_scene_file};

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn load_image(name: &str) -> EnvImage {
    EnvImage::load(&root().join("scenes/envmaps").join(name)).expect("map")
}

fn build_times() {
    let reps = env_usize("ENV_BENCH_REPS", 7);
    let sky = load_image("sky.exr");
    println!("## Environment sampling structures: build and rebuild time\n");
    println!(
        "Sky map resampled; medians of {reps} runs, wall clock, {} rayon threads.\n",
        rayon::current_num_threads()
    );
    println!("| map | texels | structure | first build (ms) | rebuild (ms) | memory (MiB) |");
    println!("|---|---:|---|---:|---:|---:|");
    for width in [128usize, 256, 512, 1024, 2048] {
        let ll = sky
            .convert(Grid::LatLong {
                width,
                height: width / 2,
            })
            .unwrap();
        let cube = ll.convert(Grid::Cube { face: width / 4 }).unwrap();
        for image in [ll, cube] {
            // A second image of the same layout to alternate with.
            let other: Vec<_> = image.texels().iter().map(|c| *c * 1.5).collect();
            for (label, strategy, index) in [
                ("lat-long 2-D CDF", EnvStrategy::LatLong, 0),
                ("cube per-face CDFs", EnvStrategy::CubeDynamic, 1),
            ] {
                let mut first = Vec::new();
                let mut rebuild = Vec::new();
                let mut memory = 0;
                for r in 0..reps {
                    let mut map =
                        EnvironmentMap::new(image.clone(), EnvSettings::default()).unwrap();
                    map.prepare(strategy);
                    first.push(map.build_seconds()[index]);
                    let texels = if r % 2 == 0 {
                        other.clone()
                    } else {
                        image.texels().to_vec()
                    };
                    map.update(&texels).unwrap();
                    rebuild.push(map.build_seconds()[index]);
                    memory = map.memory_bytes();
                }
                println!(
                    "| {} | {} | {label} | {:.2} | {:.2} | {:.1} |",
                    describe(image.grid()),
                    image.grid().texel_count(),
                    median(first) * 1e3,
                    median(rebuild) * 1e3,
                    memory as f64 / (1 << 20) as f64
                );
            }
        }
    }
    println!();
}

struct Run {
    mse: f64,
    rel_mse: f64,
    valid: f64,
}

fn fig36() {
    let size = env_usize("ENV_BENCH_SIZE", 96) as u32;
    let seeds = env_usize("ENV_BENCH_SEEDS", 4) as u64;
    let ref_spp = env_usize("ENV_BENCH_REF_SPP", 32) as u32;
    let counts = [15u32, 30, 60, 120, 180, 240];
    let strategies = [
        EnvStrategy::CubeDynamic,
        EnvStrategy::CubeUniform,
        EnvStrategy::CubePower,
        EnvStrategy::LatLong,
    ];
    println!("## Figure 3.6 of 001: dynamic against uniform face balancing\n");
    println!(
        "`env_direct`, N light samples per pixel (no BSDF samples), {size}x{size} pixels, 1 spp, {seeds} seeds; reference {ref_spp} spp x (128 light + 128 BSDF samples).\n"
    );
    let layouts = std::env::var("ENV_BENCH_LAYOUTS").unwrap_or_else(|_| "cube,latlong".into());
    for layout in layouts.split(',') {
        for object in ["diffuse", "glossy"] {
            for map_name in ["sky", "studio"] {
                let loaded =
                    load_scene_file(&root().join(format!("scenes/envmaps/sphere-{object}.json")))
                        .unwrap();
                let mut builder = loaded.builder;
                let image =
                    convert_layout(&load_image(&format!("{map_name}.exr")), layout).unwrap();
                let mut map = EnvironmentMap::new(image, EnvSettings::default()).unwrap();
                map.prepare(EnvStrategy::CubeDynamic);
                map.prepare(EnvStrategy::LatLong);
                let map_grid = map.image().grid();
                builder.set_environment(Some(Arc::new(map)));
                let scene = builder.build().unwrap();
                let camera = *scene.camera().unwrap();
                let base = IntegratorSettings {
                    max_depth: 1,
                    ..Default::default()
                };
                let rs = RenderSettings {
                    width: size,
                    height: size,
                    spp: ref_spp,
                    seed: 1_000_003,
                    ..Default::default()
                };
                eprintln!("{object} / {map_name}: reference");
                let reference_integrator =
                    integrator::create("env_direct:env=cube-dynamic:samples=128:bsdf=128", base)
                        .unwrap();
                let reference =
                    render_reference(&scene, &camera, reference_integrator.as_ref(), &rs, &|_| {
                        true
                    })
                    .unwrap();
                let ref_px = reference.film.radiance();
                let ref_mse = reference.noise.rmse * reference.noise.rmse;
                let pixels = (size * size) as f64;
                let mut results: Vec<Vec<Run>> = Vec::new();
                for strategy in strategies {
                    let mut row = Vec::new();
                    for &n in &counts {
                        let spec = format!("env_direct:env={}:samples={n}:bsdf=0", strategy.name());
                        let integ = integrator::create(&spec, base).unwrap();
                        let (mut mse, mut rel, mut valid) = (0.0, 0.0, 0.0);
                        for seed in 0..seeds {
                            let rs = RenderSettings {
                                width: size,
                                height: size,
                                spp: 1,
                                seed: seed * 7919 + 17,
                                ..Default::default()
                            };
                            let (film, stats) = render(
                                &scene,
                                &camera,
                                integ.as_ref(),
                                &rs,
                                &|_| true,
                                &AtomicBool::new(false),
                            )
                            .unwrap();
                            let e = image_errors(&film.radiance(), &ref_px).unwrap();
                            mse += e.rmse * e.rmse;
                            rel += e.rel_mse;
                            // Every pixel traces one camera ray; the other rays are shadow rays of
                            // light samples that carried light.
                            valid += (stats.rays as f64 - pixels) / pixels;
                        }
                        let k = seeds as f64;
                        row.push(Run {
                            mse: (mse / k - ref_mse).max(0.0),
                            rel_mse: (rel / k - reference.noise.rel_mse).max(0.0),
                            valid: valid / k,
                        });
                        eprintln!("{object} / {map_name}: {spec} done");
                    }
                    results.push(row);
                }
                println!(
                    "### {object} sphere, {map_name} map as {}\n",
                    describe(map_grid)
                );
                println!(
                    "Reference noise: RMSE {:.3e} (subtracted as MSE).\n",
                    reference.noise.rmse
                );
                print!("| N |");
                for s in strategies {
                    print!(" {} RMSE | relMSE | valid |", s.name());
                }
                println!(" MSE uniform / dynamic |");
                print!("|---:|");
                for _ in strategies {
                    print!("---:|---:|---:|");
                }
                println!("---:|");
                for (j, &n) in counts.iter().enumerate() {
                    print!("| {n} |");
                    for row in &results {
                        let r = &row[j];
                        print!(
                            " {:.4e} | {:.3e} | {:.1} |",
                            r.mse.sqrt(),
                            r.rel_mse,
                            r.valid
                        );
                    }
                    println!(
                        " {:.2} |",
                        results[1][j].mse / results[0][j].mse.max(1e-300)
                    );
                }
                // Samples each strategy needs for the error dynamic balancing reaches with 60.
                let target = results[0][2].mse;
                print!(
                    "\nN for the MSE of dynamic balancing with N = 60 ({:.3e}):",
                    target.sqrt()
                );
                for (k, s) in strategies.iter().enumerate() {
                    match samples_for(&counts, &results[k], target) {
                        Some(n) => print!(" {} {:.0} ({:.2}x);", s.name(), n, n / 60.0),
                        None => print!(
                            " {} > {} or < {};",
                            s.name(),
                            counts[counts.len() - 1],
                            counts[0]
                        ),
                    }
                }
                println!("\n");
            }
        }
    }
}

/// N at which the MSE curve (log-log linear between measured points) reaches `target`.
fn samples_for(counts: &[u32], runs: &[Run], target: f64) -> Option<f64> {
    for j in 0..counts.len() - 1 {
        let (m0, m1) = (runs[j].mse, runs[j + 1].mse);
        if m0 >= target && target >= m1 && m0 > 0.0 && m1 > 0.0 {
            let (l0, l1) = ((counts[j] as f64).ln(), (counts[j + 1] as f64).ln());
            let t = if m0 == m1 {
                0.0
            } else {
                (target.ln() - m0.ln()) / (m1.ln() - m0.ln())
            };
            return Some((l0 + t * (l1 - l0)).exp());
        }
    }
    None
}

/// Cost of one light sample (direction, radiance, pdf) and of one pdf evaluation per strategy,
/// one thread, strategies interleaved in rounds so that load from other processes spreads
/// over all of them; medians over the rounds.
fn sampling_cost() {
    use lacuna::math::{warp, Rng, Vec3};
    let rounds = env_usize("ENV_BENCH_REPS", 7);
    let n = 1 << 20;
    println!("## Cost of environment light samples (one thread)\n");
    println!("Medians of {rounds} rounds of {n} samples and {n} pdf evaluations each; random unit normals.\n");
    println!("| map | strategy | sample (ns) | pdf (ns) |");
    println!("|---|---|---:|---:|");
    for layout in ["latlong", "cube"] {
        let image = convert_layout(&load_image("sky.exr"), layout).unwrap();
        let mut map = EnvironmentMap::new(image, EnvSettings::default()).unwrap();
        map.prepare(EnvStrategy::LatLong);
        map.prepare(EnvStrategy::CubeDynamic);
        let strategies = [
            EnvStrategy::LatLong,
            EnvStrategy::CubeUniform,
            EnvStrategy::CubePower,
            EnvStrategy::CubeDynamic,
        ];
        let mut times = vec![(Vec::new(), Vec::new()); strategies.len()];
        for round in 0..rounds {
            for (k, &s) in strategies.iter().enumerate() {
                let mut rng = Rng::new(round as u64, k as u64);
                let normals: Vec<Vec3> = (0..1024)
                    .map(|_| warp::uniform_sphere(rng.uniform2()))
                    .collect();
                let t = std::time::Instant::now();
                let mut acc = 0.0f32;
                for i in 0..n {
                    if let Some(e) = map.sample(s, normals[i & 1023], rng.uniform2()) {
                        acc += e.pdf + e.radiance.x;
                    }
                }
                times[k].0.push(t.elapsed().as_secs_f64() / n as f64);
                let t = std::time::Instant::now();
                for i in 0..n {
                    let w = normals[(i + 7) & 1023];
                    acc += map.pdf(s, normals[i & 1023], w);
                }
                times[k].1.push(t.elapsed().as_secs_f64() / n as f64);
                std::hint::black_box(acc);
            }
        }
        for (k, s) in strategies.iter().enumerate() {
            println!(
                "| {} | {} | {:.1} | {:.1} |",
                describe(map.image().grid()),
                s.name(),
                median(times[k].0.clone()) * 1e9,
                median(times[k].1.clone()) * 1e9
            );
        }
    }
    println!();
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    let all = args.is_empty();
    if all || args.iter().any(|a| a == "build") {
        build_times();
    }
    if all || args.iter().any(|a| a == "sampling") {
        sampling_cost();
    }
    if all || args.iter().any(|a| a == "fig36") {
        fig36();
    }
}
