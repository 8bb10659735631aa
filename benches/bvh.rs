//! BVH build time and ray throughput (issue 2). Prints markdown tables on stdout, progress on
//! stderr.
//!
//! ```text
//! cargo bench --bench bvh                 # build times and rays/s (a few minutes)
//! cargo bench --bench bvh -- kernels      # node-test and triangle-test study (1 thread)
//! cargo bench --bench bvh -- methods      # BVH builders side by side (work per ray, rays/s)
//! cargo bench --bench bvh -- stages       # Medium build's time per stage, 1 and 2 threads
//! RUSTFLAGS="--cfg lacuna_embree" cargo bench --bench bvh   # also Embree 3 on the same rays
//! ```
//!
//! With `--cfg lacuna_embree` the bench links the system's `libembree3` (Debian:
//! `libembree-dev`) and runs Embree on the same triangles and rays: scene build quality medium,
//! `rtcIntersect1` / `rtcOccluded1` from the same rayon threads.
//!
//! Environment: `BVH_BENCH_REPS` (repetitions, default 3), `BVH_BENCH_MESHES` (comma-separated
//! subset of `100k,1m,sponza`, or `room` and `cornell`), `BVH_BENCH_RAYS` (incoherent rays per set, default 2^20),
//! `BVH_BENCH_QUALITIES` (subset of `fast,medium,high`).
//!
//! Meshes:
//! - `sphere-100k`, `sphere-1m`: a displaced "cube sphere" (each face of a cube tessellated into
//!   n x n quads, projected to the unit sphere and displaced radially by a fixed sum of sines),
//!   n = 91 (99,372 triangles) and n = 289 (1,002,252 triangles). No randomness.
//! - `sponza`: Crytek Sponza (262,267 triangles), positions and faces only.
//!
//! Rays:
//! - coherent: a pinhole camera, 1024 x 1024 pixels through pixel centres, in 16 x 16 tiles
//!   (the order the renderer traces them), t_max = infinity.
//! - incoherent: origin on a surface (triangle chosen with probability proportional to area,
//!   point uniform on it, PCG32 seed 7), offset off the surface with `offset_ray_origin` to the
//!   side the direction points to, direction uniform on the sphere, t_max = infinity. These are
//!   diffuse-bounce-like rays, half of them start towards the mesh's inside.
//!   Closest-hit and any-hit queries use the same rays.
//!
//! Each figure is the median over the repetitions; repetitions of all configurations of one
//! mesh are interleaved so that a burst of load from other processes spreads over all of them.
//! "on-CPU" rates divide by the time the (single) worker thread actually ran, which removes
//! the time it waited for a core on a loaded machine (not the cache contention).

#![allow(unexpected_cfgs)]

use std::time::Instant;

use lacuna::geometry::{barycentric_point_error, offset_ray_origin, Bvh, BvhQuality, Hit, Ray};
use lacuna::math::{warp, Rng, Vec3};

const QUALITIES: [BvhQuality; 3] = [BvhQuality::Fast, BvhQuality::Medium, BvhQuality::High];

/// A structure answering ray batches: one of ours, or Embree's.
enum Engine {
    Lacuna(BvhQuality, Bvh),
    #[cfg(lacuna_embree)]
    Embree(embree::Scene),
}

impl Engine {
    fn label(&self) -> String {
        match self {
            Engine::Lacuna(q, _) => format!("{q:?}"),
            #[cfg(lacuna_embree)]
            Engine::Embree(_) => "Embree 3.13 (medium)".into(),
        }
    }

    /// Traces a batch on the current rayon pool; returns the number of rays that hit.
    fn trace(
        &self,
        rays: &[Ray],
        any_hit: bool,
        hits: &mut [Option<Hit>],
        occ: &mut [bool],
    ) -> usize {
        match self {
            Engine::Lacuna(_, bvh) => {
                if any_hit {
                    bvh.occluded_batch(rays, occ);
                    occ.iter().filter(|&&o| o).count()
                } else {
                    bvh.intersect_batch(rays, hits);
                    hits.iter().filter(|h| h.is_some()).count()
                }
            }
            #[cfg(lacuna_embree)]
            Engine::Embree(scene) => {
                if any_hit {
                    scene.occluded_batch(rays, occ);
                    occ.iter().filter(|&&o| o).count()
                } else {
                    scene.intersect_batch(rays, hits);
                    hits.iter().filter(|h| h.is_some()).count()
                }
            }
        }
    }
}

fn qualities() -> Vec<BvhQuality> {
    let wanted = std::env::var("BVH_BENCH_QUALITIES").unwrap_or("fast,medium,high".into());
    QUALITIES
        .iter()
        .copied()
        .filter(|q| {
            wanted
                .to_lowercase()
                .contains(&format!("{q:?}").to_lowercase())
        })
        .collect()
}

/// Builds every engine once per thread count (rayon pool for ours, Embree's own threads),
/// `reps` times, interleaved; returns the engines (built on 2 threads) and the median times.
fn build_engines(
    tris: &[[Vec3; 3]],
    reps: usize,
    pools: &[rayon::ThreadPool],
) -> (Vec<Engine>, Vec<[f64; 2]>) {
    let qs = qualities();
    let n_engines = qs.len() + cfg!(lacuna_embree) as usize;
    let mut times = vec![[Vec::new(), Vec::new()]; n_engines];
    let mut engines: Vec<Option<Engine>> = (0..n_engines).map(|_| None).collect();
    for rep in 0..reps {
        for e in 0..n_engines {
            for (pi, pool) in pools.iter().enumerate() {
                let t = Instant::now();
                let engine = if e < qs.len() {
                    Engine::Lacuna(qs[e], pool.install(|| Bvh::build(tris, qs[e])))
                } else {
                    #[cfg(lacuna_embree)]
                    {
                        Engine::Embree(embree::Scene::build(tris, pi + 1))
                    }
                    #[cfg(not(lacuna_embree))]
                    unreachable!()
                };
                times[e][pi].push(t.elapsed().as_secs_f64());
                if rep == reps - 1 && pi == 1 {
                    engines[e] = Some(engine);
                }
            }
        }
    }
    (
        engines.into_iter().map(|e| e.expect("built")).collect(),
        times
            .iter()
            .map(|t| [median(&t[0]), median(&t[1])])
            .collect(),
    )
}

/// Runs `f` on the pool; returns its result, the wall time and the on-CPU time of the calling
/// worker thread (meaningful for a 1-thread pool).
fn timed_on<R: Send>(pool: &rayon::ThreadPool, f: impl FnOnce() -> R + Send) -> (R, f64, f64) {
    let t = Instant::now();
    let (r, cpu) = pool.install(|| {
        let c0 = thread_cpu_seconds();
        let r = f();
        (r, thread_cpu_seconds() - c0)
    });
    (r, t.elapsed().as_secs_f64(), cpu)
}

/// On-CPU time of the calling thread (Linux scheduler accounting), in seconds; wall-clock
/// time where that is not available.
fn thread_cpu_seconds() -> f64 {
    if let Ok(s) = std::fs::read_to_string("/proc/thread-self/schedstat") {
        if let Some(ns) = s
            .split_whitespace()
            .next()
            .and_then(|v| v.parse::<u64>().ok())
        {
            return ns as f64 * 1e-9;
        }
    }
    use std::sync::OnceLock;
    static START: OnceLock<Instant> = OnceLock::new();
    START.get_or_init(Instant::now).elapsed().as_secs_f64()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let reps: usize = env_or("BVH_BENCH_REPS", 3);
    let n_incoherent: usize = env_or("BVH_BENCH_RAYS", 1 << 20);
    let meshes_wanted = std::env::var("BVH_BENCH_MESHES").unwrap_or("100k,1m,sponza".into());
    let pools: Vec<rayon::ThreadPool> = [1, 2]
        .iter()
        .map(|&n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .expect("thread pool")
        })
        .collect();

    println!("load average at start: {}", load_average());
    if args.iter().any(|a| a == "methods") {
        methods::run(reps, n_incoherent, &pools);
        println!("\nload average at end: {}", load_average());
        return;
    }
    if args.iter().any(|a| a == "stages") {
        stages::run(reps, &pools);
        println!("\nload average at end: {}", load_average());
        return;
    }
    if args.iter().any(|a| a == "kernels") {
        kernels::run(reps, n_incoherent, &pools);
        println!("\nload average at end: {}", load_average());
        return;
    }

    let mut build_rows = Vec::new();
    let mut trace_rows = Vec::new();
    #[allow(unused_mut)] // only filled with --cfg lacuna_embree
    let mut embree_rows: Vec<String> = Vec::new();
    for name in meshes_wanted.split(',') {
        let Some(mesh) = load_mesh(name.trim()) else {
            continue;
        };
        eprintln!("{}: {} triangles", mesh.name, mesh.tris.len());
        let rays = RaySets::new(&mesh, n_incoherent);

        let (engines, build_times) = build_engines(&mesh.tris, reps.min(3), &pools);
        for (e, engine) in engines.iter().enumerate() {
            let (nodes, mib) = match engine {
                Engine::Lacuna(_, bvh) => (
                    bvh.node_count().to_string(),
                    format!("{:.1}", bvh.memory_bytes() as f64 / (1 << 20) as f64),
                ),
                #[cfg(lacuna_embree)]
                Engine::Embree(_) => ("-".into(), "-".into()),
            };
            build_rows.push(format!(
                "| {} | {} | {} | {:.3} | {:.3} | {nodes} | {mib} |",
                mesh.name,
                mesh.tris.len(),
                engine.label(),
                build_times[e][0],
                build_times[e][1],
            ));
        }

        // Throughput: every (engine, ray set, query, threads) once per repetition.
        #[derive(Clone, Copy)]
        struct Config {
            engine: usize,
            coherent: bool,
            any_hit: bool,
            pool: usize,
        }
        let mut configs = Vec::new();
        for engine in 0..engines.len() {
            for coherent in [true, false] {
                for any_hit in [false, true] {
                    for pool in 0..pools.len() {
                        configs.push(Config {
                            engine,
                            coherent,
                            any_hit,
                            pool,
                        });
                    }
                }
            }
        }
        let mut rates = vec![Vec::new(); configs.len()];
        let mut cpu_rates = vec![Vec::new(); configs.len()];
        let mut hit_fraction = vec![0.0; configs.len()];
        let n_max = rays.coherent.len().max(rays.incoherent.len());
        let mut hits: Vec<Option<Hit>> = vec![None; n_max];
        let mut occluded = vec![false; n_max];
        for rep in 0..reps {
            eprintln!("  {}: repetition {}/{}", mesh.name, rep + 1, reps);
            for (ci, c) in configs.iter().enumerate() {
                let rs = if c.coherent {
                    &rays.coherent
                } else {
                    &rays.incoherent
                };
                let engine = &engines[c.engine];
                let (h, o) = (&mut hits[..rs.len()], &mut occluded[..rs.len()]);
                let (n_hit, wall, cpu) =
                    timed_on(&pools[c.pool], || engine.trace(rs, c.any_hit, h, o));
                rates[ci].push(rs.len() as f64 / wall);
                cpu_rates[ci].push(rs.len() as f64 / cpu);
                hit_fraction[ci] = n_hit as f64 / rs.len() as f64;
            }
        }
        let find = |engine: usize, coherent: bool, any_hit: bool, pool: usize| {
            configs
                .iter()
                .position(|d| {
                    d.engine == engine
                        && d.coherent == coherent
                        && d.any_hit == any_hit
                        && d.pool == pool
                })
                .expect("config")
        };
        for (ci, c) in configs.iter().enumerate() {
            if c.pool != 0 {
                continue;
            }
            let two = find(c.engine, c.coherent, c.any_hit, 1);
            let one_rate = median(&rates[ci]);
            let two_rate = median(&rates[two]);
            trace_rows.push(format!(
                "| {} | {} | {} | {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.1} |",
                mesh.name,
                engines[c.engine].label(),
                if c.coherent { "coherent" } else { "incoherent" },
                if c.any_hit { "any hit" } else { "closest" },
                one_rate / 1e6,
                median(&cpu_rates[ci]) / 1e6,
                two_rate / 1e6,
                two_rate / one_rate,
                100.0 * hit_fraction[ci],
            ));
        }
        // Ours (each quality) against Embree, per configuration.
        #[cfg(lacuna_embree)]
        {
            let emb = engines.len() - 1;
            for e in 0..emb {
                for coherent in [true, false] {
                    for any_hit in [false, true] {
                        let r = |pool: usize, cpu: bool| {
                            let v = if cpu { &cpu_rates } else { &rates };
                            median(&v[find(e, coherent, any_hit, pool)])
                                / median(&v[find(emb, coherent, any_hit, pool)])
                        };
                        embree_rows.push(format!(
                            "| {} | {} | {} | {} | {:.2} | {:.2} | {:.2} |",
                            mesh.name,
                            engines[e].label(),
                            if coherent { "coherent" } else { "incoherent" },
                            if any_hit { "any hit" } else { "closest" },
                            r(0, false),
                            r(0, true),
                            r(1, false),
                        ));
                    }
                }
            }
        }
    }

    println!("\n#### BVH build (seconds, median)\n");
    println!("| mesh | triangles | build | 1 thread | 2 threads | nodes | memory (MiB) |");
    println!("|---|---:|---|---:|---:|---:|---:|");
    for r in &build_rows {
        println!("{r}");
    }
    println!("\n#### Ray throughput (M rays/s, median of {reps})\n");
    println!(
        "| mesh | BVH | rays | query | 1 thread | 1 thread on-CPU | 2 threads | 2T/1T | hit % |"
    );
    println!("|---|---|---|---|---:|---:|---:|---:|---:|");
    for r in &trace_rows {
        println!("{r}");
    }
    if !embree_rows.is_empty() {
        println!("\n#### Lacuna / Embree throughput ratio (same rays, same run)\n");
        println!("| mesh | BVH | rays | query | 1 thread | 1 thread on-CPU | 2 threads |");
        println!("|---|---|---|---|---:|---:|---:|");
        for r in &embree_rows {
            println!("{r}");
        }
    }
    println!("\nload average at end: {}", load_average());
}

fn env_or<T: std::str::FromStr>(key: &str, default: T) -> T {
    std::env::var(key)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".into())
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// A triangle soup with a camera that sees it.
struct Mesh {
    name: &'static str,
    tris: Vec<[Vec3; 3]>,
    eye: Vec3,
    target: Vec3,
    vfov_degrees: f32,
}

fn load_mesh(name: &str) -> Option<Mesh> {
    match name {
        "100k" => Some(sphere_mesh("sphere-100k", 91)),
        "1m" => Some(sphere_mesh("sphere-1m", 289)),
        "sponza" => sponza_mesh(),
        "room" => Some(room_mesh()),
        "cornell" => cornell_mesh(),
        other => {
            eprintln!("unknown mesh {other:?} (use 100k, 1m, sponza, room, cornell)");
            None
        }
    }
}

/// Radius of the displaced sphere in direction `d` (unit).
fn displaced_radius(d: Vec3) -> f32 {
    1.0 + 0.06 * (7.0 * d.x + 1.0).sin() * (9.0 * d.y + 2.0).sin() * (8.0 * d.z + 3.0).sin()
        + 0.02 * (31.0 * d.x).sin() * (37.0 * d.y).sin() * (29.0 * d.z).sin()
        + 0.004 * (113.0 * d.x + 0.5).sin() * (127.0 * d.y).sin()
}

/// Cube sphere: 6 faces x n x n quads x 2 triangles, displaced radially.
fn sphere_mesh(name: &'static str, n: usize) -> Mesh {
    let point = |face: usize, i: usize, j: usize| -> Vec3 {
        let u = 2.0 * i as f32 / n as f32 - 1.0;
        let v = 2.0 * j as f32 / n as f32 - 1.0;
        let c = match face {
            0 => Vec3::new(1.0, u, v),
            1 => Vec3::new(-1.0, v, u),
            2 => Vec3::new(v, 1.0, u),
            3 => Vec3::new(u, -1.0, v),
            4 => Vec3::new(u, v, 1.0),
            _ => Vec3::new(v, u, -1.0),
        };
        let d = c.normalize();
        d * displaced_radius(d)
    };
    let mut tris = Vec::with_capacity(12 * n * n);
    for face in 0..6 {
        for i in 0..n {
            for j in 0..n {
                let p00 = point(face, i, j);
                let p10 = point(face, i + 1, j);
                let p01 = point(face, i, j + 1);
                let p11 = point(face, i + 1, j + 1);
                tris.push([p00, p10, p11]);
                tris.push([p00, p11, p01]);
            }
        }
    }
    Mesh {
        name,
        tris,
        eye: Vec3::new(0.9, 0.7, 3.2),
        target: Vec3::ZERO,
        vfov_degrees: 40.0,
    }
}

/// A closed room [-1, 1]^3, each wall 16 x 16 quads (3,072 triangles, axis-aligned): the
/// geometry of the Embree cross-check's room, without its boxes. Not in the default set.
fn room_mesh() -> Mesh {
    let n = 16;
    let mut tris = Vec::new();
    for axis in 0..3 {
        for side in [-1.0f32, 1.0] {
            let p = |i: usize, j: usize| {
                let (u, v) = (
                    2.0 * i as f32 / n as f32 - 1.0,
                    2.0 * j as f32 / n as f32 - 1.0,
                );
                let mut c = [0.0f32; 3];
                c[axis] = side;
                c[(axis + 1) % 3] = u;
                c[(axis + 2) % 3] = v;
                Vec3::from(c)
            };
            for i in 0..n {
                for j in 0..n {
                    tris.push([p(i, j), p(i + 1, j), p(i + 1, j + 1)]);
                    tris.push([p(i, j), p(i + 1, j + 1), p(i, j + 1)]);
                }
            }
        }
    }
    Mesh {
        name: "room",
        tris,
        eye: Vec3::new(0.3, 0.1, 0.9),
        target: Vec3::new(-0.5, -0.2, -1.0),
        vfov_degrees: 60.0,
    }
}

/// The Cornell box of `scenes/cornell-box` (36 triangles), seen by its scene file's camera.
fn cornell_mesh() -> Option<Mesh> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenes/cornell-box/CornellBox-Original.obj"
    );
    Some(Mesh {
        name: "cornell-box",
        tris: obj_triangles(path)?,
        eye: Vec3::new(0.0, 1.0, 3.9),
        target: Vec3::new(0.0, 1.0, 0.0),
        vfov_degrees: 40.0,
    })
}

/// Positions and faces of an OBJ file (triangulated).
fn obj_triangles(path: &str) -> Option<Vec<[Vec3; 3]>> {
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    let (models, _materials) = match tobj::load_obj(path, &options) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("cannot load {path}: {e}");
            return None;
        }
    };
    let mut tris = Vec::new();
    for m in &models {
        let p = &m.mesh.positions;
        let v = |i: u32| {
            Vec3::new(
                p[3 * i as usize],
                p[3 * i as usize + 1],
                p[3 * i as usize + 2],
            )
        };
        for f in m.mesh.indices.chunks_exact(3) {
            tris.push([v(f[0]), v(f[1]), v(f[2])]);
        }
    }
    Some(tris)
}

/// Crytek Sponza positions and faces, from the project's scene copy (skipped when absent).
fn sponza_mesh() -> Option<Mesh> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenes/crytek-sponza/sponza.obj"
    );
    if !std::path::Path::new(path).exists() {
        return None;
    }
    let t = Instant::now();
    let tris = obj_triangles(path)?;
    eprintln!("loaded {path} in {:.2} s", t.elapsed().as_secs_f64());
    let (lo, hi) = bounds(&tris);
    let d = hi - lo;
    // Standing in the atrium near one end, looking down its length.
    Some(Mesh {
        name: "sponza",
        tris,
        eye: Vec3::new(lo.x + 0.12 * d.x, lo.y + 0.2 * d.y, lo.z + 0.5 * d.z),
        target: Vec3::new(hi.x, lo.y + 0.3 * d.y, lo.z + 0.45 * d.z),
        vfov_degrees: 60.0,
    })
}

fn bounds(tris: &[[Vec3; 3]]) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for t in tris {
        for p in t {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    (lo, hi)
}

struct RaySets {
    coherent: Vec<Ray>,
    incoherent: Vec<Ray>,
}

impl RaySets {
    fn new(mesh: &Mesh, n_incoherent: usize) -> RaySets {
        RaySets {
            coherent: camera_rays(mesh, 1024, 1024),
            incoherent: surface_rays(&mesh.tris, n_incoherent, 7),
        }
    }
}

/// Pinhole camera rays through pixel centres, in 16 x 16 tiles.
fn camera_rays(mesh: &Mesh, width: usize, height: usize) -> Vec<Ray> {
    let forward = (mesh.target - mesh.eye).normalize();
    let right = forward.cross(Vec3::Y).normalize();
    let up = right.cross(forward);
    let tan_half = (mesh.vfov_degrees.to_radians() * 0.5).tan();
    let aspect = width as f32 / height as f32;
    let mut rays = Vec::with_capacity(width * height);
    const TILE: usize = 16;
    for ty in (0..height).step_by(TILE) {
        for tx in (0..width).step_by(TILE) {
            for y in ty..(ty + TILE).min(height) {
                for x in tx..(tx + TILE).min(width) {
                    let sx = (2.0 * (x as f32 + 0.5) / width as f32 - 1.0) * tan_half * aspect;
                    let sy = (1.0 - 2.0 * (y as f32 + 0.5) / height as f32) * tan_half;
                    let d = (forward + right * sx + up * sy).normalize();
                    rays.push(Ray::new(mesh.eye, d, f32::INFINITY));
                }
            }
        }
    }
    rays
}

/// Rays leaving random surface points (area-weighted) in uniformly random directions.
fn surface_rays(tris: &[[Vec3; 3]], n: usize, seed: u64) -> Vec<Ray> {
    let mut cdf = Vec::with_capacity(tris.len());
    let mut total = 0.0f64;
    for t in tris {
        total += 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length() as f64;
        cdf.push(total);
    }
    let mut rng = Rng::new(seed, 0);
    let mut rays = Vec::with_capacity(n);
    while rays.len() < n {
        let u = rng.uniform() as f64 * total;
        let i = cdf.partition_point(|&c| c <= u).min(tris.len() - 1);
        let t = tris[i];
        let normal = (t[1] - t[0]).cross(t[2] - t[0]);
        if normal.length_squared() == 0.0 {
            continue;
        }
        let normal = normal.normalize();
        let (b0, b1) = warp::uniform_triangle(rng.uniform2());
        let b = [b0, b1, 1.0 - b0 - b1];
        let p = t[0] * b[0] + t[1] * b[1] + t[2] * b[2];
        let err = barycentric_point_error(t, b);
        let d = warp::uniform_sphere(rng.uniform2());
        let o = offset_ray_origin(p, err, normal, d);
        rays.push(Ray::new(o, d, f32::INFINITY));
    }
    rays
}

/// The node-test and triangle-test study: the same CWBVH traversal with interchangeable
/// kernels, timed side by side on one thread.
mod kernels {

    use glam::{UVec2, Vec3A};
    use lacuna::geometry::{intersect_triangle, Bvh, BvhQuality, Ray, RayPrecomp};
    use lacuna::math::Vec3;
    use obvhs::cwbvh::builder::build_cwbvh_from_tris;
    use obvhs::cwbvh::node::{extract_byte64, CwBvhNode};
    use obvhs::cwbvh::CwBvh;
    use obvhs::ray::Ray as ObvhsRay;
    use obvhs::triangle::Triangle;
    use obvhs::BvhBuildParams;

    use super::{load_mesh, median, thread_cpu_seconds, RaySets};

    // The traversal macro names `UVec2` unqualified.
    #[allow(unused_imports)]
    use UVec2 as _;

    /// A CWBVH with its triangles copied into leaf order, as `Bvh` keeps them.
    pub struct Study {
        cwbvh: CwBvh,
        tris: Vec<[Vec3A; 3]>,
        /// The library's own BVH over the same triangles (built with the same parameters).
        public: Bvh,
    }

    impl Study {
        fn new(tris_in: &[[Vec3; 3]], params: BvhBuildParams) -> Study {
            let t: Vec<Triangle> = tris_in
                .iter()
                .map(|t| Triangle {
                    v0: t[0].into(),
                    v1: t[1].into(),
                    v2: t[2].into(),
                })
                .collect();
            let mut build_time = std::time::Duration::ZERO;
            let cwbvh = build_cwbvh_from_tris(&t, params, &mut build_time);
            let tris = cwbvh
                .primitive_indices
                .iter()
                .map(|&i| {
                    let t = &t[i as usize];
                    [t.v0, t.v1, t.v2]
                })
                .collect();
            let public = Bvh::build(tris_in, BvhQuality::Medium);
            Study {
                cwbvh,
                tris,
                public,
            }
        }
    }

    pub trait NodeKernel {
        type Pre;
        const NAME: &'static str;
        fn pre(ray: &Ray) -> Self::Pre;
        fn test(node: &CwBvhNode, pre: &Self::Pre, t_max: f32, oct_inv4: u32, s: &Study) -> u32;
    }

    pub trait TriKernel {
        type Pre;
        const NAME: &'static str;
        fn pre(ray: &Ray) -> Self::Pre;
        fn test(pre: &Self::Pre, t: &[Vec3A; 3], t_max: f32) -> Option<f32>;
    }

    #[inline(always)]
    fn closest<N: NodeKernel, T: TriKernel>(s: &Study, ray: &Ray) -> Option<(u32, f32)> {
        let np = N::pre(ray);
        let tp = T::pre(ray);
        let mut t_max = ray.t_max;
        let mut best = None;
        let mut state = s.cwbvh.new_traversal(ray.dir.into());
        let mut node;
        obvhs::traverse!(
            s.cwbvh,
            node,
            state,
            N::test(node, &np, t_max, state.oct_inv4, s),
            {
                if let Some(t) = T::test(&tp, &s.tris[state.primitive_id as usize], t_max) {
                    t_max = t;
                    best = Some((state.primitive_id, t));
                }
            }
        );
        best
    }

    #[inline(always)]
    fn any<N: NodeKernel, T: TriKernel>(s: &Study, ray: &Ray) -> bool {
        let np = N::pre(ray);
        let tp = T::pre(ray);
        let mut state = s.cwbvh.new_traversal(ray.dir.into());
        let mut node;
        let mut hit = false;
        'outer: {
            obvhs::traverse!(
                s.cwbvh,
                node,
                state,
                N::test(node, &np, ray.t_max, state.oct_inv4, s),
                {
                    if T::test(&tp, &s.tris[state.primitive_id as usize], ray.t_max).is_some() {
                        hit = true;
                        break 'outer;
                    }
                }
            );
        }
        hit
    }

    /// Nodes visited and triangles tested per ray (closest hit, old node test).
    fn counts(s: &Study, rays: &[Ray]) -> (f64, f64) {
        let (mut nodes, mut tris) = (0u64, 0u64);
        for ray in rays {
            let np = OldNode::pre(ray);
            let tp = Watertight::pre(ray);
            let mut t_max = ray.t_max;
            let mut state = s.cwbvh.new_traversal(ray.dir.into());
            let mut node;
            obvhs::traverse!(
                s.cwbvh,
                node,
                state,
                {
                    nodes += 1;
                    OldNode::test(node, &np, t_max, state.oct_inv4, s)
                },
                {
                    tris += 1;
                    if let Some(t) =
                        Watertight::test(&tp, &s.tris[state.primitive_id as usize], t_max)
                    {
                        t_max = t;
                    }
                }
            );
        }
        (
            nodes as f64 / rays.len() as f64,
            tris as f64 / rays.len() as f64,
        )
    }

    // ---------------------------------------------------------------------------------------
    // Node tests

    /// The node test of `Bvh` before this study (commit 0f87336): obvhs's ray with
    /// `safe_inverse`, scalar loop, exit distance widened by (1 + 2 gamma(3)).
    pub struct OldNode;
    impl NodeKernel for OldNode {
        type Pre = ObvhsRay;
        const NAME: &'static str = "old (0f87336)";
        #[inline(always)]
        fn pre(ray: &Ray) -> ObvhsRay {
            ObvhsRay::new(ray.origin.into(), ray.dir.into(), 0.0, ray.t_max)
        }
        #[inline(always)]
        fn test(node: &CwBvhNode, ray: &ObvhsRay, t_max: f32, oct_inv4: u32, _: &Study) -> u32 {
            let extent = node.compute_extent();
            let dir_inv = extent * ray.inv_direction;
            let origin = (Vec3A::from(node.p) - ray.origin) * ray.inv_direction;
            let (child_bits8, bit_index8) = node.get_child_and_index_bits(oct_inv4);
            fn pick<'a>(
                lo: &'a [u8; 8],
                hi: &'a [u8; 8],
                negative: bool,
            ) -> (&'a [u8; 8], &'a [u8; 8]) {
                if negative {
                    (hi, lo)
                } else {
                    (lo, hi)
                }
            }
            let (x_near, x_far) = pick(
                &node.child_min_x,
                &node.child_max_x,
                ray.inv_direction.x < 0.0,
            );
            let (y_near, y_far) = pick(
                &node.child_min_y,
                &node.child_max_y,
                ray.inv_direction.y < 0.0,
            );
            let (z_near, z_far) = pick(
                &node.child_min_z,
                &node.child_max_z,
                ray.inv_direction.z < 0.0,
            );
            let widen = 1.0 + 2.0 * lacuna::math::gamma(3);
            let mut hit = [false; 8];
            for c in 0..8 {
                let t0x = x_near[c] as f32 * dir_inv.x + origin.x;
                let t1x = x_far[c] as f32 * dir_inv.x + origin.x;
                let t0y = y_near[c] as f32 * dir_inv.y + origin.y;
                let t1y = y_far[c] as f32 * dir_inv.y + origin.y;
                let t0z = z_near[c] as f32 * dir_inv.z + origin.z;
                let t1z = z_far[c] as f32 * dir_inv.z + origin.z;
                let t_enter = t0x.max(t0y).max(t0z).max(0.0);
                let t_exit = (t1x.min(t1y).min(t1z) * widen).min(t_max);
                hit[c] = t_enter <= t_exit;
            }
            let mut mask = 0u32;
            for (c, &h) in hit.iter().enumerate() {
                if h {
                    mask |= extract_byte64(child_bits8, c) << extract_byte64(bit_index8, c);
                }
            }
            mask
        }
    }

    /// obvhs's own SSE test (clamps the entry distance to an absolute 1e-4: not usable as is).
    pub struct ObvhsNode;
    impl NodeKernel for ObvhsNode {
        type Pre = ObvhsRay;
        const NAME: &'static str = "obvhs intersect_ray (SSE, 1e-4)";
        #[inline(always)]
        fn pre(ray: &Ray) -> ObvhsRay {
            OldNode::pre(ray)
        }
        #[inline(always)]
        fn test(node: &CwBvhNode, ray: &ObvhsRay, t_max: f32, oct_inv4: u32, _: &Study) -> u32 {
            let mut r = *ray;
            r.tmax = t_max;
            node.intersect_ray(&r, oct_inv4)
        }
    }

    /// Per-ray constants of the new node tests.
    pub struct NodeRay {
        origin: Vec3A,
        /// 1 / dir, clamped to +-2^40 (keeps every product finite); its sign picks near/far.
        inv: Vec3A,
        /// +inf on clamped axes (the far plane is then unbounded), -inf elsewhere.
        far_floor: Vec3A,
        neg: [bool; 3],
    }

    const INV_LIMIT: f32 = (1u64 << 40) as f32;
    /// Slack per unit of |a| (255 grid steps): a grid step derived with f32 log2 can be a
    /// power of two too small, clamping child boxes up to ~5e-6 of the node short.
    const SLACK_A: f32 = 255.0 / 65536.0;
    /// Slack per unit of |b|: rounding of 1/d, p - o, the products and sums (gamma(5) needed).
    const SLACK_B: f32 = lacuna::math::gamma(7);

    impl NodeRay {
        #[inline(always)]
        fn new(ray: &Ray) -> NodeRay {
            let mut inv = [0.0f32; 3];
            let mut floor = [f32::NEG_INFINITY; 3];
            for i in 0..3 {
                let r = 1.0 / ray.dir[i];
                if r.abs() <= INV_LIMIT {
                    inv[i] = r;
                } else {
                    inv[i] = INV_LIMIT.copysign(r);
                    floor[i] = f32::INFINITY;
                }
            }
            NodeRay {
                origin: ray.origin.into(),
                inv: inv.into(),
                far_floor: floor.into(),
                neg: [inv[0] < 0.0, inv[1] < 0.0, inv[2] < 0.0],
            }
        }

        /// Per node: t = q * a + b for grid coordinate q, and b shifted down (near) and up
        /// (far) by a bound on every rounding error.
        #[inline(always)]
        fn node_constants(&self, node: &CwBvhNode) -> (Vec3A, Vec3A, Vec3A) {
            let a = node.compute_extent() * self.inv;
            let b = (Vec3A::from(node.p) - self.origin) * self.inv;
            let slack = a.abs() * SLACK_A + b.abs() * SLACK_B;
            (a, b - slack, (b + slack).max(self.far_floor))
        }
    }

    #[inline(always)]
    fn fmax(a: f32, b: f32) -> f32 {
        if a > b {
            a
        } else {
            b
        }
    }
    #[inline(always)]
    fn fmin(a: f32, b: f32) -> f32 {
        if a < b {
            a
        } else {
            b
        }
    }

    /// Hit mask over children (bit c = child c) to obvhs's traversal mask.
    #[inline(always)]
    fn traversal_mask_loop(node: &CwBvhNode, oct_inv4: u32, hits: u32) -> u32 {
        let (child_bits8, bit_index8) = node.get_child_and_index_bits(oct_inv4);
        let mut mask = 0u32;
        for c in 0..8 {
            if hits & (1 << c) != 0 {
                mask |= extract_byte64(child_bits8, c) << extract_byte64(bit_index8, c);
            }
        }
        mask
    }

    /// Same, iterating over the set bits only.
    #[inline(always)]
    fn traversal_mask_bits(node: &CwBvhNode, oct_inv4: u32, mut hits: u32) -> u32 {
        let (child_bits8, bit_index8) = node.get_child_and_index_bits(oct_inv4);
        let mut mask = 0u32;
        while hits != 0 {
            let c = hits.trailing_zeros() as usize;
            hits &= hits - 1;
            mask |= extract_byte64(child_bits8, c) << extract_byte64(bit_index8, c);
        }
        mask
    }

    /// New math, scalar loop over the 8 children, plain comparisons for min/max.
    pub struct NewScalar;
    impl NodeKernel for NewScalar {
        type Pre = NodeRay;
        const NAME: &'static str = "new scalar";
        #[inline(always)]
        fn pre(ray: &Ray) -> NodeRay {
            NodeRay::new(ray)
        }
        #[inline(always)]
        fn test(node: &CwBvhNode, r: &NodeRay, t_max: f32, oct_inv4: u32, _: &Study) -> u32 {
            traversal_mask_loop(node, oct_inv4, scalar_hits(node, r, t_max))
        }
    }

    #[inline(always)]
    fn scalar_hits(node: &CwBvhNode, r: &NodeRay, t_max: f32) -> u32 {
        let (a, bn, bf) = r.node_constants(node);
        let pick =
            |lo: &[u8; 8], hi: &[u8; 8], neg: bool| if neg { (*hi, *lo) } else { (*lo, *hi) };
        let (xn, xf) = pick(&node.child_min_x, &node.child_max_x, r.neg[0]);
        let (yn, yf) = pick(&node.child_min_y, &node.child_max_y, r.neg[1]);
        let (zn, zf) = pick(&node.child_min_z, &node.child_max_z, r.neg[2]);
        let mut hits = 0u32;
        for c in 0..8 {
            let enter = fmax(
                fmax(xn[c] as f32 * a.x + bn.x, yn[c] as f32 * a.y + bn.y),
                fmax(zn[c] as f32 * a.z + bn.z, 0.0),
            );
            let exit = fmin(
                fmin(xf[c] as f32 * a.x + bf.x, yf[c] as f32 * a.y + bf.y),
                fmin(zf[c] as f32 * a.z + bf.z, t_max),
            );
            hits |= ((enter <= exit) as u32) << c;
        }
        hits
    }

    /// Explicit SSE2 (x86-64 baseline): both children groups of four at once per axis.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn sse_hits(node: &CwBvhNode, r: &NodeRay, t_max: f32) -> u32 {
        use std::arch::x86_64::*;
        const _: () = assert!(
            std::mem::offset_of!(CwBvhNode, child_max_x)
                == std::mem::offset_of!(CwBvhNode, child_min_x) + 8
                && std::mem::offset_of!(CwBvhNode, child_min_y)
                    == std::mem::offset_of!(CwBvhNode, child_min_x) + 16
                && std::mem::offset_of!(CwBvhNode, child_min_z)
                    == std::mem::offset_of!(CwBvhNode, child_min_x) + 32
                && std::mem::offset_of!(CwBvhNode, child_max_z)
                    == std::mem::offset_of!(CwBvhNode, child_min_x) + 40
        );
        let (a, bn, bf) = r.node_constants(node);
        // SAFETY: SSE2 is part of x86-64. The three 16-byte loads read child_min_x..child_max_z,
        // 48 contiguous bytes inside the node (offsets checked above); loadu needs no alignment.
        unsafe {
            let base = node.child_min_x.as_ptr();
            let zero = _mm_setzero_si128();
            let mut enter_lo = _mm_setzero_ps();
            let mut enter_hi = _mm_setzero_ps();
            let mut exit_lo = _mm_set1_ps(t_max);
            let mut exit_hi = exit_lo;
            for axis in 0..3 {
                let q = _mm_loadu_si128(base.add(16 * axis) as *const __m128i);
                // [min | max] -> [near | far] for this ray direction.
                let q = if r.neg[axis] {
                    _mm_shuffle_epi32::<0x4E>(q)
                } else {
                    q
                };
                let near = _mm_unpacklo_epi8(q, zero);
                let far = _mm_unpackhi_epi8(q, zero);
                let av = _mm_set1_ps(a[axis]);
                let bnv = _mm_set1_ps(bn[axis]);
                let bfv = _mm_set1_ps(bf[axis]);
                let n_lo = _mm_cvtepi32_ps(_mm_unpacklo_epi16(near, zero));
                let n_hi = _mm_cvtepi32_ps(_mm_unpackhi_epi16(near, zero));
                let f_lo = _mm_cvtepi32_ps(_mm_unpacklo_epi16(far, zero));
                let f_hi = _mm_cvtepi32_ps(_mm_unpackhi_epi16(far, zero));
                enter_lo = _mm_max_ps(enter_lo, _mm_add_ps(_mm_mul_ps(n_lo, av), bnv));
                enter_hi = _mm_max_ps(enter_hi, _mm_add_ps(_mm_mul_ps(n_hi, av), bnv));
                exit_lo = _mm_min_ps(exit_lo, _mm_add_ps(_mm_mul_ps(f_lo, av), bfv));
                exit_hi = _mm_min_ps(exit_hi, _mm_add_ps(_mm_mul_ps(f_hi, av), bfv));
            }
            let lo = _mm_movemask_ps(_mm_cmple_ps(enter_lo, exit_lo)) as u32;
            let hi = _mm_movemask_ps(_mm_cmple_ps(enter_hi, exit_hi)) as u32;
            lo | (hi << 4)
        }
    }

    pub struct NewSse;
    impl NodeKernel for NewSse {
        type Pre = NodeRay;
        const NAME: &'static str = "new SSE2, mask loop";
        #[inline(always)]
        fn pre(ray: &Ray) -> NodeRay {
            NodeRay::new(ray)
        }
        #[inline(always)]
        fn test(node: &CwBvhNode, r: &NodeRay, t_max: f32, oct_inv4: u32, _: &Study) -> u32 {
            traversal_mask_loop(node, oct_inv4, sse_hits(node, r, t_max))
        }
    }

    pub struct NewSseBits;
    impl NodeKernel for NewSseBits {
        type Pre = NodeRay;
        const NAME: &'static str = "new SSE2, set-bit loop";
        #[inline(always)]
        fn pre(ray: &Ray) -> NodeRay {
            NodeRay::new(ray)
        }
        #[inline(always)]
        fn test(node: &CwBvhNode, r: &NodeRay, t_max: f32, oct_inv4: u32, _: &Study) -> u32 {
            traversal_mask_bits(node, oct_inv4, sse_hits(node, r, t_max))
        }
    }

    /// Issues prefetches for the children (nodes or leaf triangles) that a node test hit, so
    /// that their cache misses overlap instead of forming one chain per level.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn prefetch_children(node: &CwBvhNode, mut hits: u32, s: &Study) {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        while hits != 0 {
            let c = hits.trailing_zeros();
            hits &= hits - 1;
            let meta = node.child_meta[c as usize];
            if meta == 0 {
                continue;
            }
            let p: *const i8 = if node.imask & (1 << c) != 0 {
                let rank = (node.imask as u32 & ((1u32 << c) - 1)).count_ones();
                s.cwbvh.nodes[(node.child_base_idx + rank) as usize..].as_ptr() as *const i8
            } else {
                let first = node.primitive_base_idx + (meta & 0x1f) as u32;
                s.tris[first as usize..].as_ptr() as *const i8
            };
            // SAFETY: prefetching is a hint without architectural effect; p points into a live
            // slice. SSE is part of x86-64.
            unsafe {
                _mm_prefetch::<_MM_HINT_T0>(p);
                _mm_prefetch::<_MM_HINT_T0>(p.add(64));
            }
        }
    }

    pub struct NewSsePrefetch;
    impl NodeKernel for NewSsePrefetch {
        type Pre = NodeRay;
        const NAME: &'static str = "new SSE2, set-bit loop, prefetch";
        #[inline(always)]
        fn pre(ray: &Ray) -> NodeRay {
            NodeRay::new(ray)
        }
        #[inline(always)]
        fn test(node: &CwBvhNode, r: &NodeRay, t_max: f32, oct_inv4: u32, s: &Study) -> u32 {
            let hits = sse_hits(node, r, t_max);
            prefetch_children(node, hits, s);
            traversal_mask_bits(node, oct_inv4, hits)
        }
    }

    pub struct NewScalarPrefetch;
    impl NodeKernel for NewScalarPrefetch {
        type Pre = NodeRay;
        const NAME: &'static str = "new scalar, prefetch";
        #[inline(always)]
        fn pre(ray: &Ray) -> NodeRay {
            NodeRay::new(ray)
        }
        #[inline(always)]
        fn test(node: &CwBvhNode, r: &NodeRay, t_max: f32, oct_inv4: u32, s: &Study) -> u32 {
            let hits = scalar_hits(node, r, t_max);
            prefetch_children(node, hits, s);
            traversal_mask_bits(node, oct_inv4, hits)
        }
    }

    // ---------------------------------------------------------------------------------------
    // Triangle tests

    /// Lacuna's watertight test (`lacuna::geometry::intersect_triangle`).
    pub struct Watertight;
    impl TriKernel for Watertight {
        type Pre = RayPrecomp;
        const NAME: &'static str = "watertight (lacuna)";
        #[inline(always)]
        fn pre(ray: &Ray) -> RayPrecomp {
            RayPrecomp::new(ray.origin, ray.dir)
        }
        #[inline(always)]
        fn test(pre: &RayPrecomp, t: &[Vec3A; 3], t_max: f32) -> Option<f32> {
            intersect_triangle(pre, t[0].into(), t[1].into(), t[2].into(), t_max).map(|h| h.t)
        }
    }

    /// The watertight test with the permutation and shear folded into three dot products per
    /// vertex (no indexing by kx, ky, kz): the same roundings, so the same results.
    pub struct WatertightDot;
    pub struct DotPre {
        o: Vec3A,
        mx: Vec3A,
        my: Vec3A,
        mz: Vec3A,
    }
    impl TriKernel for WatertightDot {
        type Pre = DotPre;
        const NAME: &'static str = "watertight, dot-product shear";
        #[inline(always)]
        fn pre(ray: &Ray) -> DotPre {
            let d = ray.dir;
            let a = d.abs();
            let kz = if a.x > a.y {
                if a.x > a.z {
                    0
                } else {
                    2
                }
            } else if a.y > a.z {
                1
            } else {
                2
            };
            let mut kx = (kz + 1) % 3;
            let mut ky = (kx + 1) % 3;
            if d[kz] < 0.0 {
                std::mem::swap(&mut kx, &mut ky);
            }
            let sz = 1.0 / d[kz];
            let (sx, sy) = (d[kx] * sz, d[ky] * sz);
            let mut mx = Vec3A::ZERO;
            let mut my = Vec3A::ZERO;
            let mut mz = Vec3A::ZERO;
            mx[kx] = 1.0;
            mx[kz] = -sx;
            my[ky] = 1.0;
            my[kz] = -sy;
            mz[kz] = sz;
            DotPre {
                o: ray.origin.into(),
                mx,
                my,
                mz,
            }
        }
        #[inline(always)]
        fn test(r: &DotPre, t: &[Vec3A; 3], t_max: f32) -> Option<f32> {
            use lacuna::math::gamma;
            let a = t[0] - r.o;
            let b = t[1] - r.o;
            let c = t[2] - r.o;
            let (ax, ay) = (a.dot(r.mx), a.dot(r.my));
            let (bx, by) = (b.dot(r.mx), b.dot(r.my));
            let (cx, cy) = (c.dot(r.mx), c.dot(r.my));
            let mut e0 = bx * cy - by * cx;
            let mut e1 = cx * ay - cy * ax;
            let mut e2 = ax * by - ay * bx;
            if e0 == 0.0 || e1 == 0.0 || e2 == 0.0 {
                e0 = (bx as f64 * cy as f64 - by as f64 * cx as f64) as f32;
                e1 = (cx as f64 * ay as f64 - cy as f64 * ax as f64) as f32;
                e2 = (ax as f64 * by as f64 - ay as f64 * bx as f64) as f32;
            }
            if (e0 < 0.0 || e1 < 0.0 || e2 < 0.0) && (e0 > 0.0 || e1 > 0.0 || e2 > 0.0) {
                return None;
            }
            let det = e0 + e1 + e2;
            if det == 0.0 {
                return None;
            }
            let (az, bz, cz) = (a.dot(r.mz), b.dot(r.mz), c.dot(r.mz));
            let t_scaled = e0 * az + e1 * bz + e2 * cz;
            if det < 0.0 && (t_scaled >= 0.0 || t_scaled < t_max * det) {
                return None;
            }
            if det > 0.0 && (t_scaled <= 0.0 || t_scaled > t_max * det) {
                return None;
            }
            let inv_det = 1.0 / det;
            let t = t_scaled * inv_det;
            if !(t < t_max) {
                return None;
            }
            let max_zt = az.abs().max(bz.abs()).max(cz.abs());
            let delta_z = gamma(3) * max_zt;
            let max_xt = ax.abs().max(bx.abs()).max(cx.abs());
            let max_yt = ay.abs().max(by.abs()).max(cy.abs());
            let delta_x = gamma(5) * (max_xt + max_zt);
            let delta_y = gamma(5) * (max_yt + max_zt);
            let delta_e = 2.0 * (gamma(2) * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt);
            let max_e = e0.abs().max(e1.abs()).max(e2.abs());
            let delta_t = 3.0
                * (gamma(3) * max_e * max_zt + delta_e * max_zt + delta_z * max_e)
                * inv_det.abs();
            if t <= delta_t {
                return None;
            }
            Some(t)
        }
    }

    /// Moller-Trumbore without any error handling: the cost baseline.
    pub struct MollerTrumbore;
    pub struct MtPre {
        o: Vec3A,
        d: Vec3A,
    }
    impl TriKernel for MollerTrumbore {
        type Pre = MtPre;
        const NAME: &'static str = "Moller-Trumbore (not watertight)";
        #[inline(always)]
        fn pre(ray: &Ray) -> MtPre {
            MtPre {
                o: ray.origin.into(),
                d: ray.dir.into(),
            }
        }
        #[inline(always)]
        fn test(r: &MtPre, t: &[Vec3A; 3], t_max: f32) -> Option<f32> {
            let e1 = t[1] - t[0];
            let e2 = t[2] - t[0];
            let p = r.d.cross(e2);
            let det = e1.dot(p);
            if det == 0.0 {
                return None;
            }
            let inv_det = 1.0 / det;
            let s = r.o - t[0];
            let u = s.dot(p) * inv_det;
            if !(0.0..=1.0).contains(&u) {
                return None;
            }
            let q = s.cross(e1);
            let v = r.d.dot(q) * inv_det;
            if v < 0.0 || u + v > 1.0 {
                return None;
            }
            let tt = e2.dot(q) * inv_det;
            (tt > 0.0 && tt < t_max).then_some(tt)
        }
    }

    // ---------------------------------------------------------------------------------------

    /// One timed variant: closest and any-hit functions over a ray slice.
    struct Variant {
        name: String,
        closest: fn(&Study, &[Ray]) -> (usize, f64),
        any: fn(&Study, &[Ray]) -> usize,
    }

    fn run_closest<N: NodeKernel, T: TriKernel>(s: &Study, rays: &[Ray]) -> (usize, f64) {
        let mut n = 0;
        let mut sum = 0.0f64;
        for r in rays {
            if let Some((_, t)) = closest::<N, T>(s, r) {
                n += 1;
                sum += t as f64;
            }
        }
        (n, sum)
    }

    /// As `run_closest`, also reading the hit's global index from a separate array (the
    /// layout `Bvh` had before: `leaf_ids[slot]`).
    fn run_closest_ids<N: NodeKernel, T: TriKernel>(s: &Study, rays: &[Ray]) -> (usize, f64) {
        let mut n = 0;
        let mut sum = 0.0f64;
        for r in rays {
            if let Some((slot, t)) = closest::<N, T>(s, r) {
                n += 1;
                sum += t as f64;
                std::hint::black_box(s.cwbvh.primitive_indices[slot as usize]);
            }
        }
        (n, sum)
    }

    fn run_any<N: NodeKernel, T: TriKernel>(s: &Study, rays: &[Ray]) -> usize {
        rays.iter().filter(|r| any::<N, T>(s, r)).count()
    }

    fn run_public_closest(s: &Study, rays: &[Ray]) -> (usize, f64) {
        let mut n = 0;
        let mut sum = 0.0f64;
        for r in rays {
            if let Some(h) = s.public.intersect(r) {
                n += 1;
                sum += h.t as f64;
            }
        }
        (n, sum)
    }

    fn run_public_any(s: &Study, rays: &[Ray]) -> usize {
        rays.iter().filter(|r| s.public.occluded(r)).count()
    }

    fn variant<N: NodeKernel, T: TriKernel>() -> Variant {
        Variant {
            name: format!("{} + {}", N::NAME, T::NAME),
            closest: run_closest::<N, T>,
            any: run_any::<N, T>,
        }
    }

    pub fn run(reps: usize, n_incoherent: usize, pools: &[rayon::ThreadPool]) {
        let variants = vec![
            variant::<OldNode, Watertight>(),
            variant::<ObvhsNode, Watertight>(),
            variant::<NewScalar, Watertight>(),
            variant::<NewSse, Watertight>(),
            variant::<NewSseBits, Watertight>(),
            variant::<NewScalarPrefetch, Watertight>(),
            variant::<NewSsePrefetch, Watertight>(),
            variant::<OldNode, WatertightDot>(),
            variant::<NewSsePrefetch, WatertightDot>(),
            variant::<OldNode, MollerTrumbore>(),
            variant::<NewSsePrefetch, MollerTrumbore>(),
            Variant {
                name: "new SSE2, set-bit loop, prefetch + watertight, separate id array".into(),
                closest: run_closest_ids::<NewSsePrefetch, Watertight>,
                any: run_any::<NewSsePrefetch, Watertight>,
            },
            Variant {
                name: "public `Bvh::intersect` / `occluded` (this tree)".into(),
                closest: run_public_closest,
                any: run_public_any,
            },
        ];
        let meshes = std::env::var("BVH_BENCH_MESHES").unwrap_or("1m,sponza".into());
        for name in meshes.split(',') {
            let Some(mesh) = load_mesh(name.trim()) else {
                continue;
            };
            let rays = RaySets::new(&mesh, n_incoherent);
            let study = Study::new(&mesh.tris, BvhParams::medium());
            for (label, rs) in [
                ("coherent", &rays.coherent),
                ("incoherent", &rays.incoherent),
            ] {
                let (nodes, tris) = counts(&study, rs);
                println!(
                    "\n#### {} {label}: {:.1} nodes and {:.1} triangles per closest-hit ray (Medium)\n",
                    mesh.name, nodes, tris
                );
                let n_rows = variants.len();
                let mut closest_rates = vec![Vec::new(); n_rows];
                let mut any_rates = vec![Vec::new(); n_rows];
                let mut closest_ratio = vec![Vec::new(); n_rows];
                let mut any_ratio = vec![Vec::new(); n_rows];
                let mut checks = vec![(0usize, 0.0f64, 0usize); n_rows];
                // Fine-grained interleaving: every variant runs on each chunk of rays in turn
                // (order rotated per chunk), timed by the thread's on-CPU time, so load from
                // other processes (descheduling) and its bursts fall on all variants alike.
                pools[0].install(|| {
                    for _ in 0..reps {
                        let mut t_closest = vec![0.0f64; n_rows];
                        let mut t_any = vec![0.0f64; n_rows];
                        let mut rep_checks = vec![(0usize, 0.0f64, 0usize); n_rows];
                        for (ci, chunk) in rs.chunks(CHUNK).enumerate() {
                            for k in 0..n_rows {
                                let vi = (k + ci) % n_rows;
                                let v = &variants[vi];
                                let t0 = thread_cpu_seconds();
                                let (n, sum) = (v.closest)(&study, chunk);
                                let t1 = thread_cpu_seconds();
                                let n_any = (v.any)(&study, chunk);
                                let t2 = thread_cpu_seconds();
                                t_closest[vi] += t1 - t0;
                                t_any[vi] += t2 - t1;
                                let c = &mut rep_checks[vi];
                                c.0 += n;
                                c.1 += sum;
                                c.2 += n_any;
                            }
                        }
                        for vi in 0..n_rows {
                            closest_rates[vi].push(rs.len() as f64 / t_closest[vi]);
                            any_rates[vi].push(rs.len() as f64 / t_any[vi]);
                            closest_ratio[vi].push(t_closest[0] / t_closest[vi]);
                            any_ratio[vi].push(t_any[0] / t_any[vi]);
                        }
                        checks = rep_checks;
                    }
                });
                println!("| node test + triangle test (1 thread, on-CPU time) | closest M/s | vs old | any hit M/s | vs old | hits | sum of t | any hits |");
                println!("|---|---:|---:|---:|---:|---:|---:|---:|");
                for vi in 0..n_rows {
                    let name = &variants[vi].name;
                    let c = median(&closest_rates[vi]);
                    let a = median(&any_rates[vi]);
                    println!(
                        "| {name} | {:.3} | {:.3} | {:.3} | {:.3} | {} | {:.6e} | {} |",
                        c / 1e6,
                        median(&closest_ratio[vi]),
                        a / 1e6,
                        median(&any_ratio[vi]),
                        checks[vi].0,
                        checks[vi].1,
                        checks[vi].2
                    );
                }
            }
        }
    }

    /// Rays per interleaving chunk.
    const CHUNK: usize = 4096;

    struct BvhParams;
    impl BvhParams {
        fn medium() -> BvhBuildParams {
            BvhBuildParams::medium_build()
        }
    }
}

/// The BVH builders side by side: build time, size, work per closest-hit ray and on-CPU
/// rays/s on one thread (every method runs on each chunk of rays in turn, as in `kernels`).
mod methods {
    use lacuna::geometry::{BuildMethod, Bvh, BvhQuality, Ray};

    use super::{load_mesh, median, thread_cpu_seconds, RaySets};

    const CHUNK: usize = 4096;

    pub fn run(reps: usize, n_incoherent: usize, pools: &[rayon::ThreadPool]) {
        let methods = [
            BuildMethod::Ploc(BvhQuality::Fast),
            BuildMethod::Ploc(BvhQuality::Medium),
            BuildMethod::Ploc(BvhQuality::High),
            BuildMethod::Sah { reinsertion: 0.0 },
            BuildMethod::Sah { reinsertion: 0.05 },
            BuildMethod::Sah { reinsertion: 0.2 },
            BuildMethod::Cheaper(BvhQuality::Medium, 0.0),
            BuildMethod::Cheaper(BvhQuality::High, 0.05),
            BuildMethod::Binned,
        ];
        let meshes = std::env::var("BVH_BENCH_MESHES").unwrap_or("room,cornell,100k,sponza".into());
        for name in meshes.split(',') {
            let Some(mesh) = load_mesh(name.trim()) else {
                continue;
            };
            eprintln!("{}: {} triangles", mesh.name, mesh.tris.len());
            let rays = RaySets::new(&mesh, n_incoherent);
            let mut bvhs = Vec::new();
            let mut build_seconds = Vec::new();
            for &m in &methods {
                let mut times = Vec::new();
                let mut built = None;
                for _ in 0..reps.min(3) {
                    let t = std::time::Instant::now();
                    built = Some(pools[1].install(|| Bvh::build_with(&mesh.tris, m)));
                    times.push(t.elapsed().as_secs_f64());
                }
                bvhs.push(built.expect("built"));
                build_seconds.push(median(&times));
            }
            println!(
                "\n#### {} ({} triangles): builders, 1 thread on-CPU\n",
                mesh.name,
                mesh.tris.len()
            );
            println!("| method | build, 2 threads (s) | nodes | coherent: nodes / tris per ray | incoherent: nodes / tris per ray | coherent closest M/s | coherent any M/s | incoherent closest M/s | incoherent any M/s |");
            println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|");
            let mut rates = vec![[Vec::new(), Vec::new(), Vec::new(), Vec::new()]; methods.len()];
            pools[0].install(|| {
                for _ in 0..reps {
                    for (set, rs) in [&rays.coherent, &rays.incoherent].into_iter().enumerate() {
                        let mut t = vec![[0.0f64; 2]; methods.len()];
                        for (ci, chunk) in rs.chunks(CHUNK).enumerate() {
                            for k in 0..methods.len() {
                                let mi = (k + ci) % methods.len();
                                let bvh = &bvhs[mi];
                                let t0 = thread_cpu_seconds();
                                let hits = closest(bvh, chunk);
                                let t1 = thread_cpu_seconds();
                                let occluded = any(bvh, chunk);
                                let t2 = thread_cpu_seconds();
                                std::hint::black_box((hits, occluded));
                                t[mi][0] += t1 - t0;
                                t[mi][1] += t2 - t1;
                            }
                        }
                        for mi in 0..methods.len() {
                            rates[mi][2 * set].push(rs.len() as f64 / t[mi][0]);
                            rates[mi][2 * set + 1].push(rs.len() as f64 / t[mi][1]);
                        }
                    }
                }
            });
            for (mi, m) in methods.iter().enumerate() {
                let work = |rs: &[Ray]| {
                    let (mut n, mut t) = (0u64, 0u64);
                    for r in rs {
                        let (a, b) = bvhs[mi].closest_hit_work(r);
                        n += a as u64;
                        t += b as u64;
                    }
                    (n as f64 / rs.len() as f64, t as f64 / rs.len() as f64)
                };
                let (cn, ct) = work(&rays.coherent);
                let (in_, it) = work(&rays.incoherent);
                println!(
                    "| {m:?} | {:.3} | {} | {cn:.1} / {ct:.1} | {in_:.1} / {it:.1} | {:.2} | {:.2} | {:.2} | {:.2} |",
                    build_seconds[mi],
                    bvhs[mi].node_count(),
                    median(&rates[mi][0]) / 1e6,
                    median(&rates[mi][1]) / 1e6,
                    median(&rates[mi][2]) / 1e6,
                    median(&rates[mi][3]) / 1e6,
                );
            }
        }
    }

    fn closest(bvh: &Bvh, rays: &[Ray]) -> usize {
        rays.iter().filter(|r| bvh.intersect(r).is_some()).count()
    }

    fn any(bvh: &Bvh, rays: &[Ray]) -> usize {
        rays.iter().filter(|r| bvh.occluded(r)).count()
    }
}

/// The Medium build's time per stage (`Bvh::build_profiled`), 1 and 2 threads, with Embree's
/// build in the same run when compiled in.
mod stages {
    use lacuna::geometry::{BuildMethod, BuildProfile, Bvh, BvhQuality};

    use super::{load_mesh, median};

    /// Stages in table order (before the conversion computed its own costs, "8-wide cost" was
    /// the choice between two trees and "cwbvh conversion" included the kept tree's costs) (stages of the two trees of a `Cheaper` build overlap; "both
    /// binary trees" is their wall time together).
    const STAGES: [&str; 12] = [
        "input",
        "binned 8-wide build",
        "PLOC",
        "PLOC reinsertion",
        "SAH build",
        "SAH reinsertion",
        "both binary trees",
        "8-wide cost",
        "cwbvh conversion",
        "depth check",
        "triangle blocks",
        "wide nodes",
    ];

    /// Medium's method, or the one `BVH_BENCH_METHOD` names: `ploc`, `sah` (no reinsertion),
    /// `sah-0.05` (5 % reinsertion), `cheaper` (both, Medium's parameters), `binned` (the
    /// 8-wide binned SAH build).
    fn stages_method(n: usize) -> BuildMethod {
        match std::env::var("BVH_BENCH_METHOD").as_deref() {
            Ok("ploc") => BuildMethod::Ploc(BvhQuality::Medium),
            Ok("sah") => BuildMethod::Sah { reinsertion: 0.0 },
            Ok("sah-0.05") => BuildMethod::Sah { reinsertion: 0.05 },
            Ok("cheaper") => BuildMethod::Cheaper(BvhQuality::Medium, 0.0),
            Ok("binned") => BuildMethod::Binned,
            _ => BvhQuality::Medium.method(n),
        }
    }

    pub fn run(reps: usize, pools: &[rayon::ThreadPool]) {
        let meshes = std::env::var("BVH_BENCH_MESHES").unwrap_or("100k,1m,sponza".into());
        println!("\n#### Medium build by stage (seconds, median of {reps})\n");
        print!("| mesh | threads |");
        for s in STAGES {
            print!(" {s} |");
        }
        println!(" total | Embree | ratio | 8-wide SAH cost (PLOC / SAH build) | nodes |");
        print!("|---|---:|");
        for _ in STAGES {
            print!("---:|");
        }
        println!("---:|---:|---:|---:|---:|");
        for name in meshes.split(',') {
            let Some(mesh) = load_mesh(name.trim()) else {
                continue;
            };
            eprintln!("{}: {} triangles", mesh.name, mesh.tris.len());
            let method = stages_method(mesh.tris.len());
            // [threads][stage] -> seconds per repetition; repetitions interleave the pools.
            let mut times = vec![vec![Vec::new(); STAGES.len() + 2]; pools.len()];
            let (mut cost, mut nodes, mut both) = (0.0f32, 0usize, String::new());
            for _ in 0..reps {
                for (pi, pool) in pools.iter().enumerate() {
                    let profile = BuildProfile::recording();
                    let t = std::time::Instant::now();
                    let bvh = pool.install(|| Bvh::build_profiled(&mesh.tris, method, &profile));
                    times[pi][STAGES.len()].push(t.elapsed().as_secs_f64());
                    nodes = bvh.node_count();
                    drop(bvh);
                    cost = profile.cost().unwrap_or(f32::NAN);
                    if let Some((p, s)) = profile.both_costs() {
                        both = format!(" ({p:.1} / {s:.1})");
                    }
                    for (k, stage) in STAGES.iter().enumerate() {
                        let s: f64 = profile
                            .stages()
                            .iter()
                            .filter(|(n, _)| n == stage)
                            .map(|(_, s)| s)
                            .sum();
                        times[pi][k].push(s);
                    }
                    #[cfg(lacuna_embree)]
                    {
                        let t = std::time::Instant::now();
                        drop(super::embree::Scene::build(&mesh.tris, pi + 1));
                        times[pi][STAGES.len() + 1].push(t.elapsed().as_secs_f64());
                    }
                }
            }
            for (pi, t) in times.iter().enumerate() {
                print!("| {} | {} |", mesh.name, pi + 1);
                for v in &t[..STAGES.len()] {
                    print!(" {:.3} |", median(v));
                }
                let (total, embree) = (median(&t[STAGES.len()]), median(&t[STAGES.len() + 1]));
                println!(
                    " {total:.3} | {embree:.3} | {:.2} | {cost:.1}{both} | {nodes} |",
                    total / embree
                );
            }
        }
    }
}

/// Embree 3 through its C API (`libembree3`), for side-by-side figures.
#[cfg(lacuna_embree)]
mod embree {
    use std::ffi::{c_char, c_void};

    use lacuna::geometry::{Hit, Ray};
    use lacuna::math::Vec3;
    use rayon::prelude::*;

    #[repr(C)]
    struct RtcIntersectContext {
        flags: u32,
        filter: *const c_void,
        inst_id: [u32; 1],
    }

    #[repr(C, align(16))]
    #[derive(Clone, Copy)]
    struct RtcRay {
        org: [f32; 3],
        tnear: f32,
        dir: [f32; 3],
        time: f32,
        tfar: f32,
        mask: u32,
        id: u32,
        flags: u32,
    }

    #[repr(C, align(16))]
    #[derive(Clone, Copy)]
    struct RtcHit {
        ng: [f32; 3],
        u: f32,
        v: f32,
        prim_id: u32,
        geom_id: u32,
        inst_id: [u32; 1],
    }

    #[repr(C, align(16))]
    struct RtcRayHit {
        ray: RtcRay,
        hit: RtcHit,
    }

    const INVALID_ID: u32 = u32::MAX;
    const GEOMETRY_TYPE_TRIANGLE: u32 = 0;
    const BUFFER_TYPE_INDEX: u32 = 0;
    const BUFFER_TYPE_VERTEX: u32 = 1;
    const FORMAT_UINT3: u32 = 0x5003;
    const FORMAT_FLOAT3: u32 = 0x9003;
    const BUILD_QUALITY_MEDIUM: u32 = 1;

    #[link(name = "embree3")]
    extern "C" {
        fn rtcNewDevice(config: *const c_char) -> *mut c_void;
        fn rtcReleaseDevice(device: *mut c_void);
        fn rtcNewScene(device: *mut c_void) -> *mut c_void;
        fn rtcReleaseScene(scene: *mut c_void);
        fn rtcSetSceneBuildQuality(scene: *mut c_void, quality: u32);
        fn rtcNewGeometry(device: *mut c_void, kind: u32) -> *mut c_void;
        fn rtcSetNewGeometryBuffer(
            geometry: *mut c_void,
            kind: u32,
            slot: u32,
            format: u32,
            stride: usize,
            count: usize,
        ) -> *mut c_void;
        fn rtcCommitGeometry(geometry: *mut c_void);
        fn rtcAttachGeometry(scene: *mut c_void, geometry: *mut c_void) -> u32;
        fn rtcReleaseGeometry(geometry: *mut c_void);
        fn rtcCommitScene(scene: *mut c_void);
        fn rtcIntersect1(scene: *mut c_void, ctx: *mut RtcIntersectContext, rayhit: *mut RtcRayHit);
        fn rtcOccluded1(scene: *mut c_void, ctx: *mut RtcIntersectContext, ray: *mut RtcRay);
    }

    /// A committed Embree scene of one triangle mesh.
    pub struct Scene {
        device: *mut c_void,
        scene: *mut c_void,
    }

    // SAFETY: a committed Embree scene may be queried from any number of threads at once
    // (Embree API documentation, rtcIntersect1); it is never modified after `build`.
    unsafe impl Sync for Scene {}
    unsafe impl Send for Scene {}

    impl Scene {
        /// Builds with Embree's own `threads` build threads (its TBB pool, not rayon's).
        pub fn build(tris: &[[Vec3; 3]], threads: usize) -> Scene {
            let config = format!("threads={threads}\0");
            // SAFETY: plain C API calls with valid arguments; the buffers Embree returns have
            // room for `count` items of the requested format (plus padding Embree adds), and
            // we write exactly that many.
            unsafe {
                let device = rtcNewDevice(config.as_ptr() as *const c_char);
                assert!(!device.is_null(), "rtcNewDevice failed");
                let scene = rtcNewScene(device);
                rtcSetSceneBuildQuality(scene, BUILD_QUALITY_MEDIUM);
                let geometry = rtcNewGeometry(device, GEOMETRY_TYPE_TRIANGLE);
                let n = tris.len();
                let v = rtcSetNewGeometryBuffer(
                    geometry,
                    BUFFER_TYPE_VERTEX,
                    0,
                    FORMAT_FLOAT3,
                    12,
                    3 * n,
                ) as *mut f32;
                let idx =
                    rtcSetNewGeometryBuffer(geometry, BUFFER_TYPE_INDEX, 0, FORMAT_UINT3, 12, n)
                        as *mut u32;
                assert!(!v.is_null() && !idx.is_null());
                let v = std::slice::from_raw_parts_mut(v, 9 * n);
                let idx = std::slice::from_raw_parts_mut(idx, 3 * n);
                for (i, t) in tris.iter().enumerate() {
                    for k in 0..3 {
                        v[9 * i + 3 * k..9 * i + 3 * k + 3].copy_from_slice(&t[k].to_array());
                        idx[3 * i + k] = (3 * i + k) as u32;
                    }
                }
                rtcCommitGeometry(geometry);
                rtcAttachGeometry(scene, geometry);
                rtcReleaseGeometry(geometry);
                rtcCommitScene(scene);
                Scene { device, scene }
            }
        }

        fn context() -> RtcIntersectContext {
            RtcIntersectContext {
                flags: 0,
                filter: std::ptr::null(),
                inst_id: [INVALID_ID],
            }
        }

        fn ray(r: &Ray) -> RtcRay {
            RtcRay {
                org: r.origin.to_array(),
                tnear: 0.0,
                dir: r.dir.to_array(),
                time: 0.0,
                tfar: r.t_max,
                mask: u32::MAX,
                id: 0,
                flags: 0,
            }
        }

        pub fn intersect_batch(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
            rays.par_chunks(256)
                .zip(out.par_chunks_mut(256))
                .for_each(|(r, o)| {
                    let mut ctx = Self::context();
                    for (ray, slot) in r.iter().zip(o) {
                        let mut rh = RtcRayHit {
                            ray: Self::ray(ray),
                            hit: RtcHit {
                                ng: [0.0; 3],
                                u: 0.0,
                                v: 0.0,
                                prim_id: INVALID_ID,
                                geom_id: INVALID_ID,
                                inst_id: [INVALID_ID],
                            },
                        };
                        // SAFETY: valid scene, context and ray-hit structure (layouts as in
                        // rtcore_ray.h / rtcore_common.h of Embree 3.13 with one instance level).
                        unsafe { rtcIntersect1(self.scene, &mut ctx, &mut rh) };
                        *slot = (rh.hit.geom_id != INVALID_ID).then_some(Hit {
                            t: rh.ray.tfar,
                            triangle: rh.hit.prim_id,
                            b1: rh.hit.u,
                            b2: rh.hit.v,
                        });
                    }
                });
        }

        pub fn occluded_batch(&self, rays: &[Ray], out: &mut [bool]) {
            rays.par_chunks(256)
                .zip(out.par_chunks_mut(256))
                .for_each(|(r, o)| {
                    let mut ctx = Self::context();
                    for (ray, slot) in r.iter().zip(o) {
                        let mut er = Self::ray(ray);
                        // SAFETY: as above; Embree sets tfar to -inf when occluded.
                        unsafe { rtcOccluded1(self.scene, &mut ctx, &mut er) };
                        *slot = er.tfar == f32::NEG_INFINITY;
                    }
                });
        }
    }

    impl Drop for Scene {
        fn drop(&mut self) {
            // SAFETY: both handles came from rtcNew* and are released once.
            unsafe {
                rtcReleaseScene(self.scene);
                rtcReleaseDevice(self.device);
            }
        }
    }
}
