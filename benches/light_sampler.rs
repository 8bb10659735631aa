//! Cost of one light sample through the C API (`lacuna_light_sampler_sample`, single calls and
//! `lacuna_light_sampler_sample_batch`) against the same work inside Rust (pick the light by
//! power, `Light::sample_with`), in ns per sample. Prints a markdown table on stdout.
//!
//! ```text
//! cargo bench --bench light_sampler
//! ```
//!
//! Scenes: the Cornell box (two emissive triangles among 36; triangles by area) and the diffuse
//! sphere under the sky map (`scenes/envmaps/sphere-diffuse.json`, cube-dynamic balancing).
//! 4096 shading points (random points in the scene's bounds, random normals, random numbers),
//! each sampled once per pass; `LS_BENCH_REPS` (default 15) passes of each variant alternate
//! A B C A B C so machine load hits all three alike; medians per variant. The C calls are made
//! from Rust through the same `extern "C"` symbols a C host links: the difference is the
//! boundary's cost (argument checks, panic guard, out-parameter copies), not a language's.

use std::hint::black_box;
use std::path::Path;
use std::time::Instant;

use lacuna::capi::*;
use lacuna::light::{EnvStrategy, TriangleSampling};
use lacuna::math::{Rng, Vec2, Vec3};
use lacuna::scene::{load_scene_file, Scene};

const N: usize = 4096;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn queries(scene: &Scene) -> Vec<lacuna_light_query> {
    let b = scene.bounds();
    let mut rng = Rng::new(1, 2);
    (0..N)
        .map(|_| {
            let t = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform());
            let p = b.min + (b.max - b.min) * t;
            let n = Vec3::new(
                rng.uniform() - 0.5,
                rng.uniform() - 0.5,
                rng.uniform() - 0.5,
            )
            .normalize_or_zero();
            lacuna_light_query {
                position: p.to_array(),
                flags: 0,
                normal: n.to_array(),
                u: [rng.uniform(), rng.uniform()],
            }
        })
        .collect()
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let reps: usize = std::env::var("LS_BENCH_REPS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(15);
    println!("| scene | Rust (ns/sample) | C API single (ns/sample) | C API batch (ns/sample) | single / Rust | batch / Rust |");
    println!("|---|---|---|---|---|---|");
    for (label, file, triangles, env, env_c) in [
        (
            "Cornell box",
            "scenes/cornell-box/cornell-box.json",
            TriangleSampling::Area,
            EnvStrategy::CubeDynamic,
            3u32,
        ),
        (
            "sphere under the sky map",
            "scenes/envmaps/sphere-diffuse.json",
            TriangleSampling::Area,
            EnvStrategy::CubeDynamic,
            3u32,
        ),
    ] {
        let path = root.join(file);
        let scene = load_scene_file(&path).unwrap().builder.build().unwrap();
        if let Some((_, map)) = scene.environment() {
            map.cube();
        }
        let qs = queries(&scene);
        // The same scene through the C API.
        let c_path = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
        let (mut ctx, mut b, mut cs, mut ls) = (
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            std::ptr::null_mut(),
        );
        unsafe {
            assert_eq!(lacuna_context_new(&mut ctx), lacuna_status::Ok);
            assert_eq!(
                lacuna_scene_builder_new_from_file(ctx, c_path.as_ptr(), &mut b),
                lacuna_status::Ok
            );
            assert_eq!(lacuna_scene_builder_build(b, &mut cs), lacuna_status::Ok);
            assert_eq!(
                lacuna_light_sampler_new(cs, 0, env_c, &mut ls),
                lacuna_status::Ok
            );
        }
        let mut out = vec![unsafe { std::mem::zeroed::<lacuna_light_sample>() }; N];
        let selector = scene.light_sampler().unwrap();
        let lights = scene.lights();
        let (mut rust, mut single, mut batch) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..reps {
            let t = Instant::now();
            let mut acc = 0.0f32;
            for q in &qs {
                let (i, pmf, ul) = selector.sample_reuse(q.u[0]);
                if let Some(s) = lights[i].sample_with(
                    Vec3::from(q.position),
                    Vec3::from(q.normal),
                    env,
                    triangles,
                    Vec2::new(ul, q.u[1]),
                ) {
                    acc += s.pdf * pmf;
                }
            }
            black_box(acc);
            rust.push(t.elapsed().as_secs_f64() * 1e9 / N as f64);

            let t = Instant::now();
            for (q, o) in qs.iter().zip(out.iter_mut()) {
                unsafe { lacuna_light_sampler_sample(ls, q, o) };
            }
            black_box(&out);
            single.push(t.elapsed().as_secs_f64() * 1e9 / N as f64);

            let t = Instant::now();
            unsafe {
                lacuna_light_sampler_sample_batch(ls, qs.as_ptr(), 0, N, out.as_mut_ptr(), 0)
            };
            black_box(&out);
            batch.push(t.elapsed().as_secs_f64() * 1e9 / N as f64);
        }
        let (r, s, b) = (median(rust), median(single), median(batch));
        println!(
            "| {label} | {r:.1} | {s:.1} | {b:.1} | {:.2}x | {:.2}x |",
            s / r,
            b / r
        );
        unsafe {
            lacuna_light_sampler_release(ls);
            lacuna_scene_release(cs);
            lacuna_context_release(ctx);
        }
    }
}
