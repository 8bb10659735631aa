//! Automatic MIS (issue 33) in the set-up of thesis 001's Table 5.2: the variance of
//! `env_direct`'s direct-lighting estimate at a fixed camera ray per pixel (through the pixel
//! centre), for each MIS weighting, with N samples per light source; efficiency =
//! 1 / (variance x CPU time) relative to the balance heuristic. See
//! `lacuna::integrator::ray_variance` for the estimators and their standard errors.
//! Prints markdown tables on stdout, progress on stderr.
//!
//! ```text
//! cargo bench --bench mis_ray                          # every scene, every weighting
//! MIS_RAY_SCENES=cornell,floor cargo bench --bench mis_ray
//! MIS_RAY_SPECS='balance=mis=balance,auto=mis=auto,auto4=mis=auto:alpha_steps=4' cargo bench --bench mis_ray
//! ```
//!
//! Settings (environment): `MIS_RAY_SIZE` (image width, default 32; the height follows the
//! camera's file aspect: square), `MIS_RAY_GROUPS` (16) groups of `MIS_RAY_K` (2) estimates per
//! point, `MIS_RAY_N` (256) samples per light source, half light and half BSDF for the MIS
//! weightings, `MIS_RAY_SEED` (1). `MIS_RAY_SPECS`: `name=options` pairs separated by commas,
//! each appended to `env_direct:samples=N/2:bsdf=N/2:` (or given whole when it starts with
//! `env_direct`); the first is the baseline. Groups run in turn for every weighting (A B A B),
//! each on all the machine's threads; CPU time is thread CPU time summed over the workers.

use std::path::Path;
use std::sync::Arc;

use lacuna::integrator::ray_variance::{
    compare, measure_group, pooled_squared_means, shading_points, Comparison, GroupStats,
};
use lacuna::integrator::{self, EnvDirect, Integrator, IntegratorSettings};
use lacuna::light::environment::EnvImage;
use lacuna::light::{EnvSettings, EnvStrategy, EnvironmentMap};
use lacuna::scene::{load_scene_file, Scene};

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The issue's scenes: (name, scene file, environment map replacing the file's).
fn scenes() -> Vec<(String, &'static str, Option<&'static str>)> {
    let mut list = vec![
        (
            "cornell".to_string(),
            "scenes/cornell-box/cornell-box.json",
            None,
        ),
        (
            "floor".to_string(),
            "scenes/glossy-floor/glossy-floor.json",
            None,
        ),
    ];
    for map in ["sky", "studio", "venice", "apartment", "sunset"] {
        list.push((
            format!("spheres-{map}"),
            "scenes/envmaps/spheres-exponents.json",
            Some(map),
        ));
    }
    list.extend([
        (
            "door".to_string(),
            "scenes/veach-door-pg2015/veach-door-pg2015.json",
            None,
        ),
        (
            "ajar".to_string(),
            "scenes/veach-ajar-bitterli/veach-ajar-bitterli.json",
            None,
        ),
        ("sibenik".to_string(), "scenes/sibenik/sibenik.json", None),
        (
            "sponza".to_string(),
            "scenes/crytek-sponza/crytek-sponza.json",
            None,
        ),
    ]);
    list
}

fn load(file: &str, map: Option<&str>) -> Scene {
    let loaded = load_scene_file(&root().join(file)).expect("scene");
    let mut builder = loaded.builder;
    if let Some(map) = map {
        let image = EnvImage::load(&root().join(format!("scenes/envmaps/{map}.exr"))).unwrap();
        let mut env = EnvironmentMap::new(image, EnvSettings::default()).unwrap();
        env.prepare(EnvStrategy::CubeDynamic);
        builder.set_environment(Some(Arc::new(env)));
    }
    builder.build().expect("scene builds")
}

fn specs(n: u32) -> Vec<(String, String)> {
    let default = format!(
        "balance=mis=balance,power=mis=power,auto=mis=auto,optimal=mis=optimal,\
         light=env_direct:samples={n}:bsdf=0,bsdf=env_direct:samples=0:bsdf={n}"
    );
    let list = std::env::var("MIS_RAY_SPECS").unwrap_or(default);
    list.split(',')
        .map(|pair| {
            let (name, options) = pair.split_once('=').expect("MIS_RAY_SPECS: name=options");
            let spec = if options.starts_with("env_direct") {
                options.to_string()
            } else {
                format!("env_direct:samples={}:bsdf={}:{options}", n / 2, n - n / 2)
            };
            (name.to_string(), spec)
        })
        .collect()
}

fn shader(spec: &str, scene: &Scene) -> EnvDirect {
    let (name, settings) = integrator::parse_spec(spec, IntegratorSettings::default()).unwrap();
    assert_eq!(name, "env_direct", "{spec}");
    let mut shader = EnvDirect::new(settings).unwrap();
    let camera = *scene.camera().expect("camera");
    shader.prepare(scene, &camera, &|_, _| true).unwrap();
    shader
}

fn main() {
    let size: u32 = env_or("MIS_RAY_SIZE", 32);
    let groups: u32 = env_or("MIS_RAY_GROUPS", 16);
    let k: u32 = env_or("MIS_RAY_K", 2);
    let n: u32 = env_or("MIS_RAY_N", 256);
    let seed: u64 = env_or("MIS_RAY_SEED", 1);
    let filter = std::env::var("MIS_RAY_SCENES").ok();
    let specs = specs(n);
    println!(
        "## Direct lighting per camera ray: {size}x{size} pixel-centre rays, {groups} groups x {k} estimates per point, N = {n} per light source\n"
    );
    for (name, spec) in &specs {
        println!("- `{name}`: `{spec}`");
    }
    println!();
    let mut summary: Vec<(String, Vec<Option<Comparison>>)> = Vec::new();
    for (scene_name, file, map) in scenes() {
        if let Some(f) = &filter {
            if !f.split(',').any(|s| s == scene_name) {
                continue;
            }
        }
        eprintln!("{scene_name}: loading");
        let scene = load(file, map);
        let points = shading_points(&scene, size, size);
        let shaders: Vec<EnvDirect> = specs.iter().map(|(_, s)| shader(s, &scene)).collect();
        let mut stats: Vec<Vec<GroupStats>> = vec![Vec::new(); specs.len()];
        for g in 0..groups {
            for (i, s) in shaders.iter().enumerate() {
                stats[i].push(measure_group(&scene, s, &points, k, seed, g));
            }
            eprintln!("{scene_name}: group {} of {groups}", g + 1);
        }
        let all: Vec<&[GroupStats]> = stats.iter().map(|s| s.as_slice()).collect();
        let denominators = pooled_squared_means(&all);
        let lit = (0..points.len())
            .filter(|&p| stats[0].iter().any(|g| g.mean[p] != 0.0))
            .count();
        let comparisons: Vec<Comparison> = stats
            .iter()
            .map(|s| compare(&stats[0], s, &denominators))
            .collect();
        let base = comparisons[0];
        println!(
            "### {scene_name} ({} shading points of {}, {lit} receiving direct light)\n",
            points.len(),
            size * size
        );
        if !(base.balance_variance > 0.0) {
            println!("No direct-lighting variance at the first hit: every weighting gives the same (deterministic or zero) estimate.\n");
            summary.push((scene_name, vec![None; specs.len()]));
            continue;
        }
        println!(
            "`{}`: mean per-ray variance {:.4e}, {:.1} us CPU per estimate.\n",
            specs[0].0,
            base.balance_variance,
            base.balance_seconds_per_estimate * 1e6
        );
        println!("| weighting | variance | relative variance | CPU time | efficiency |");
        println!("|---|---:|---:|---:|---:|");
        for ((name, _), c) in specs.iter().zip(&comparisons) {
            println!(
                "| {name} | {:.3} ± {:.3} | {:.3} ± {:.3} | {:.3} ± {:.3} | **{:.3}** ± {:.3} |",
                c.variance.value,
                c.variance.std_err,
                c.relative_variance.value,
                c.relative_variance.std_err,
                c.time.value,
                c.time.std_err,
                c.efficiency.value,
                c.efficiency.std_err
            );
        }
        println!();
        summary.push((scene_name, comparisons.into_iter().map(Some).collect()));
    }
    println!(
        "### Efficiency relative to `{}` (± standard error)\n",
        specs[0].0
    );
    print!("| scene |");
    for (name, _) in &specs[1..] {
        print!(" {name} |");
    }
    println!();
    println!("|---|{}", "---:|".repeat(specs.len() - 1));
    for (scene_name, row) in &summary {
        print!("| {scene_name} |");
        for c in &row[1..] {
            match c {
                Some(c) => print!(
                    " {:.2}x ± {:.2} |",
                    c.efficiency.value, c.efficiency.std_err
                ),
                None => print!(" - |"),
            }
        }
        println!();
    }
    print!("| geometric mean |");
    for i in 1..specs.len() {
        let effs: Vec<(f64, f64)> = summary
            .iter()
            .filter_map(|(_, row)| row[i].map(|c| (c.efficiency.value, c.efficiency.std_err)))
            .filter(|(e, _)| *e > 0.0 && e.is_finite())
            .collect();
        let m = effs.len() as f64;
        let gm = (effs.iter().map(|(e, _)| e.ln()).sum::<f64>() / m).exp();
        // The log of each ratio has standard error se / e; their mean's is the root sum / m.
        let se = gm
            * effs
                .iter()
                .map(|(e, s)| (s / e).powi(2))
                .sum::<f64>()
                .sqrt()
            / m;
        print!(" **{gm:.2}x** ± {se:.2} |");
    }
    println!();
}
