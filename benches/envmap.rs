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
//! `fig36`: the thesis's comparison on its own terms: shading points of a G-buffer (the first
//! hit through each pixel centre, `ENV_BENCH_SIZE`^2 pixels, default 128), the `env_direct`
//! shading estimate with N light samples and no BSDF samples (eq. 3.5, visibility included)
//! for per-normal dynamic balancing, uniform balancing (mu_f = 1/6), power balancing and the
//! lat-long density, `ENV_BENCH_SEEDS` (default 8) independent estimates per point, on the
//! diffuse and the glossy sphere of `scenes/envmaps/` under the sky and the studio maps,
//! resampled to cube maps of 6 x 128 x 128 (the thesis's setting: per-face CDFs over the map's
//! own texels) and as the original 512 x 256 lat-long maps (`ENV_BENCH_LAYOUTS`, default
//! `cube,latlong`). Error: MSE against a per-point reference (mean of
//! `ENV_BENCH_REF_REPEATS` (4) estimates of `ENV_BENCH_REF_SAMPLES` (1024) light + as many
//! BSDF samples), minus the reference's own variance; the thesis reports a mean Lab error
//! instead. Fixed shading points keep pixel-footprint noise (edges, a sharp background) out
//! of the comparison. "valid" is the mean number of light samples per point that carried
//! light (not cancelled by the cosine, the BSDF or a black texel: the thesis's "valid
//! samples"), counted from the shadow rays traced. "N for equal error" interpolates log MSE
//! against log N between the measured N.

use std::path::Path;
use std::sync::Arc;

use lacuna::integrator::{self, EnvDirect, IntegratorSettings, TraceCounters};
use lacuna::light::environment::{describe, EnvImage, Grid};
use lacuna::light::{EnvSettings, EnvStrategy, EnvironmentMap};
use lacuna::math::{Rgb, Rng, Sampler};
use lacuna::scene::{convert_layout, load_scene_file, SurfaceInteraction};
use rayon::prelude::*;

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
    valid: f64,
}

/// One shading point of the G-buffer.
struct Hit {
    si: SurfaceInteraction,
}

fn fig36() {
    let size = env_usize("ENV_BENCH_SIZE", 128) as u32;
    let seeds = env_usize("ENV_BENCH_SEEDS", 8) as u64;
    let ref_samples = env_usize("ENV_BENCH_REF_SAMPLES", 1024) as u32;
    let ref_repeats = env_usize("ENV_BENCH_REF_REPEATS", 4) as u64;
    let counts = [15u32, 30, 60, 120, 180, 240, 480];
    let strategies = [
        EnvStrategy::CubeDynamic,
        EnvStrategy::CubeUniform,
        EnvStrategy::CubePower,
        EnvStrategy::LatLong,
    ];
    println!("## Figure 3.6 of 001: dynamic against uniform face balancing\n");
    println!(
        "Shading points: the first hit through each pixel centre of a {size}x{size} image (a G-buffer, as in the thesis's deferred renderer). At each, the `env_direct` estimate with N light samples and no BSDF samples (eq. 3.5, visibility included), {seeds} independent estimates per point; MSE against a reference per point (mean of {ref_repeats} estimates of {ref_samples} light + {ref_samples} BSDF samples, dynamic balancing), minus the reference's own variance.\n"
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
                let hits: Vec<Hit> =
                    lacuna::integrator::ray_variance::shading_points(&scene, size, size)
                        .into_iter()
                        .map(|si| Hit { si })
                        .collect();
                let estimate = |spec: &str, seed: u64| -> (Vec<Rgb>, u64) {
                    let (_, settings) =
                        integrator::parse_spec(spec, IntegratorSettings::default()).unwrap();
                    let shader = EnvDirect::new(settings).unwrap();
                    let out: Vec<(Rgb, u64)> = hits
                        .par_iter()
                        .enumerate()
                        .map(|(k, h)| {
                            let mut rng = Sampler::independent(Rng::new(seed, k as u64));
                            let mut counters = TraceCounters::default();
                            let v = shader.shade(&scene, &h.si, &mut rng, &mut counters);
                            (v, counters.rays)
                        })
                        .collect();
                    let rays = out.iter().map(|o| o.1).sum();
                    (out.into_iter().map(|o| o.0).collect(), rays)
                };
                eprintln!("{layout} {object} / {map_name}: reference");
                let ref_spec =
                    format!("env_direct:env=cube-dynamic:samples={ref_samples}:bsdf={ref_samples}");
                let repeats: Vec<Vec<Rgb>> = (0..ref_repeats)
                    .map(|r| estimate(&ref_spec, 1_000_000 + r).0)
                    .collect();
                let n_hits = hits.len();
                let mut reference = vec![Rgb::ZERO; n_hits];
                let mut ref_var = 0.0f64;
                for k in 0..n_hits {
                    let mean = repeats.iter().map(|r| r[k]).sum::<Rgb>() / ref_repeats as f32;
                    reference[k] = mean;
                    let var: f64 = repeats
                        .iter()
                        .map(|r| ((r[k] - mean).length_squared() / 3.0) as f64)
                        .sum::<f64>()
                        / (ref_repeats - 1) as f64;
                    ref_var += var / ref_repeats as f64;
                }
                ref_var /= n_hits as f64;
                let mut results: Vec<Vec<Run>> = Vec::new();
                for strategy in strategies {
                    let mut row = Vec::new();
                    for &n in &counts {
                        let spec = format!("env_direct:env={}:samples={n}:bsdf=0", strategy.name());
                        let (mut mse, mut rays) = (0.0f64, 0u64);
                        for seed in 0..seeds {
                            let (est, r) = estimate(&spec, seed * 7919 + 17);
                            mse += est
                                .iter()
                                .zip(&reference)
                                .map(|(e, r)| ((*e - *r).length_squared() / 3.0) as f64)
                                .sum::<f64>()
                                / n_hits as f64;
                            rays += r;
                        }
                        row.push(Run {
                            mse: (mse / seeds as f64 - ref_var).max(0.0),
                            valid: rays as f64 / (seeds as f64 * n_hits as f64),
                        });
                    }
                    eprintln!("{layout} {object} / {map_name}: {} done", strategy.name());
                    results.push(row);
                }
                println!(
                    "### {object} sphere, {map_name} map as {} ({n_hits} shading points)\n",
                    describe(map_grid)
                );
                println!("Reference variance per point: {ref_var:.3e} (subtracted).\n");
                print!("| N |");
                for s in strategies {
                    print!(" {} RMSE | valid |", s.name());
                }
                println!(" MSE uniform / dynamic |");
                print!("|---:|");
                for _ in strategies {
                    print!("---:|---:|");
                }
                println!("---:|");
                for (j, &n) in counts.iter().enumerate() {
                    print!("| {n} |");
                    for row in &results {
                        let r = &row[j];
                        print!(" {:.4e} | {:.1} |", r.mse.sqrt(), r.valid);
                    }
                    println!(
                        " {:.2} |",
                        results[1][j].mse / results[0][j].mse.max(1e-300)
                    );
                }
                let target = results[0][2].mse;
                print!(
                    "\nN for the error of dynamic balancing with N = 60 (RMSE {:.3e}):",
                    target.sqrt()
                );
                for (k, s) in strategies.iter().enumerate() {
                    match samples_for(&counts, &results[k], target) {
                        Some(n) => print!(" {} {:.0} ({:.2}x);", s.name(), n, n / 60.0),
                        None => print!(
                            " {} outside {}..{};",
                            s.name(),
                            counts[0],
                            counts[counts.len() - 1]
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
