//! Skeleton build time per stage (issue 6): the stages the skeleton needs, the definition of the
//! BENCHMARKS.md table (voxelize, L1 distance, the L1 opening and decenterness, then the
//! thinning pipeline of `Skeleton::from_maps`, which computes the squared Euclidean distance
//! beside the thinning: the schedule of `Skeleton`'s docs),
//! run in one process so that configurations can be compared side by side. Prints a markdown
//! table on stdout.
//!
//! ```text
//! cargo bench --bench skeleton -- SCENE.obj RESOLUTION [RESOLUTION...]
//! ```
//!
//! Environment: `SKELETON_BENCH_REPS` (repetitions, default 5), `SKELETON_BENCH_THREADS`
//! (comma-separated thread counts, default `1,2`), `SKELETON_BENCH_EUCLIDEAN=opening` (the
//! squared Euclidean distance beside the L1 opening, the alternative schedule, instead of beside the
//! thinning). Each figure is the median over the
//! repetitions, which are interleaved over the thread counts. "cpu" is the on-CPU time of all
//! the process's threads during the stage (from /proc/self/task/*/schedstat), which does not
//! count the time spent waiting for a core on a loaded machine; "busiest thread cpu" the
//! largest on-CPU time of one thread during the stage (the critical path of the schedule on
//! otherwise idle cores, also on a loaded machine); "wall" is elapsed time.

use std::path::Path;
use std::time::Instant;

use lacuna::analysis::{
    distance_map, voxelize, Metric, Outside, Resolution, Skeleton, SkeletonMaps, SkeletonSettings,
    VoxelGrid, EUCLIDEAN_BESIDE_THINNING,
};
use lacuna::math::Vec3;
use lacuna::scene::{load_obj, SceneBuilder};

/// On-CPU nanoseconds of each thread of this process so far, by thread id.
fn cpu_by_thread() -> Vec<(u64, u64)> {
    let Ok(dir) = std::fs::read_dir("/proc/self/task") else {
        return Vec::new();
    };
    let mut v: Vec<(u64, u64)> = dir
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let tid = e.file_name().to_str()?.parse::<u64>().ok()?;
            let s = std::fs::read_to_string(e.path().join("schedstat")).ok()?;
            Some((tid, s.split_whitespace().next()?.parse::<u64>().ok()?))
        })
        .collect();
    v.sort_unstable();
    v
}

/// The largest on-CPU time of one thread between two [`cpu_by_thread`] samples: a lower bound
/// of the stage's wall time with one core per thread, which a loaded machine does not inflate
/// (it counts no time spent waiting for a core), so it shows the critical path of a schedule.
fn busiest(before: &[(u64, u64)], after: &[(u64, u64)]) -> u64 {
    after
        .iter()
        .map(|&(tid, ns)| {
            let start = before
                .binary_search_by_key(&tid, |t| t.0)
                .map_or(0, |k| before[k].1);
            ns - start
        })
        .max()
        .unwrap_or(0)
}

/// Wall, CPU and busiest-thread CPU seconds of `f`.
fn timed<T>(f: impl FnOnce() -> T) -> (T, f64, f64, f64) {
    let (c, t) = (cpu_by_thread(), Instant::now());
    let v = f();
    let wall = t.elapsed().as_secs_f64();
    let after = cpu_by_thread();
    let total = after.iter().map(|t| t.1).sum::<u64>() - c.iter().map(|t| t.1).sum::<u64>();
    (
        v,
        wall,
        total as f64 * 1e-9,
        busiest(&c, &after) as f64 * 1e-9,
    )
}

#[derive(Default, Clone)]
struct Row {
    /// (stage, wall, cpu, busiest thread's cpu) in stage order.
    stages: Vec<(String, f64, f64, f64)>,
    nodes: usize,
    filtered: usize,
    grid: [usize; 3],
}

fn run(triangles: &[[Vec3; 3]], grid: VoxelGrid, euclidean_beside_opening: bool) -> Row {
    let dims = grid.dims;
    let mut row = Row {
        grid: dims,
        ..Default::default()
    };
    let (occ, w, c, b) = timed(|| voxelize(&grid, triangles));
    row.stages.push(("voxelize".into(), w, c, b));
    let (d1, w, c, b) =
        timed(|| distance_map(dims, &occ, Metric::L1, Outside::Solid, false).values);
    row.stages.push(("distance L1".into(), w, c, b));
    // The library's schedule (`Skeleton`'s docs); with `euclidean_beside_opening` the squared
    // Euclidean distance runs beside the L1 opening (the alternative schedule) if the library
    // would compute it beside the thinning.
    let (maps, w, c, b) = timed(|| {
        let maps = || SkeletonMaps::from_l1(dims, &occ, Outside::Solid, d1);
        if euclidean_beside_opening && EUCLIDEAN_BESIDE_THINNING {
            let (mut maps, sq) = rayon::join(maps, || {
                distance_map(dims, &occ, Metric::SquaredEuclidean, Outside::Solid, false).values
            });
            maps.sq_euclidean = Some(sq);
            maps
        } else {
            maps()
        }
    });
    let stage = if maps.sq_euclidean.is_some() {
        "opening L1 + decenterness || distance Euclidean"
    } else {
        "opening L1 + decenterness"
    };
    row.stages.push((stage.into(), w, c, b));
    let sq = maps.sq_euclidean;
    let (d1, dc) = (maps.distance_l1, maps.decenterness_l1);
    let settings = SkeletonSettings {
        parallel: true,
        topology: false,
    };
    // The progress callback runs after each stage: it splits the CPU time by stage.
    let marks = std::sync::Mutex::new(vec![cpu_by_thread()]);
    let progress = |_: &str, _: f64| {
        marks.lock().unwrap().push(cpu_by_thread());
        true
    };
    let (s, w, c, b) = timed(|| {
        Skeleton::from_maps(
            grid,
            &occ,
            &d1,
            &dc,
            sq.as_deref(),
            &settings,
            &progress,
            Vec::new(),
        )
        .expect("skeleton")
    });
    let marks = marks.into_inner().unwrap();
    let sum = |m: &[(u64, u64)]| m.iter().map(|t| t.1).sum::<u64>();
    for (k, t) in s.timings.iter().enumerate() {
        if t.stage != "empty-space topology" {
            let cpu = (sum(&marks[k + 1]) - sum(&marks[k])) as f64 * 1e-9;
            let busy = busiest(&marks[k], &marks[k + 1]) as f64 * 1e-9;
            row.stages.push((t.stage.to_string(), t.seconds, cpu, busy));
        }
    }
    row.stages.push(("skeleton (from maps)".into(), w, c, b));
    row.nodes = s.raw.nodes.len();
    row.filtered = s.filtered.graph.nodes.len();
    row
}

fn median(mut v: Vec<f64>) -> f64 {
    v.retain(|x| !x.is_nan());
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--bench")
        .collect();
    let Some((scene, resolutions)) = args.split_first() else {
        eprintln!("usage: cargo bench --bench skeleton -- SCENE.obj RESOLUTION [RESOLUTION...]");
        std::process::exit(2);
    };
    let reps: usize = std::env::var("SKELETON_BENCH_REPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(5);
    let threads: Vec<usize> = std::env::var("SKELETON_BENCH_THREADS")
        .unwrap_or("1,2".into())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    let beside_opening = std::env::var("SKELETON_BENCH_EUCLIDEAN").as_deref() == Ok("opening");
    let mut builder = SceneBuilder::new();
    load_obj(Path::new(scene), &mut builder, None).expect("scene loads");
    let scene_data = builder.build().expect("scene builds");
    let triangles: Vec<[Vec3; 3]> = (0..scene_data.triangle_count() as u32)
        .map(|t| scene_data.triangle_vertices(t))
        .collect();
    let pools: Vec<rayon::ThreadPool> = threads
        .iter()
        .map(|&n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
        })
        .collect();
    println!(
        "| scene | longest axis | grid | threads | stage | wall (s) | cpu (s) | busiest thread cpu (s) |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for res in resolutions {
        let res: u32 = res.parse().expect("resolution");
        let grid = VoxelGrid::new(scene_data.bounds(), Resolution::LongestAxis(res), 2).unwrap();
        let mut rows: Vec<Vec<Row>> = vec![Vec::new(); threads.len()];
        for _ in 0..reps {
            for (k, pool) in pools.iter().enumerate() {
                rows[k].push(pool.install(|| run(&triangles, grid, beside_opening)));
            }
        }
        for (k, runs) in rows.iter().enumerate() {
            let first = &runs[0];
            let [w, h, d] = first.grid;
            let mut total = (0.0, 0.0, 0.0);
            let name = Path::new(scene).file_stem().unwrap().to_string_lossy();
            for (i, (stage, ..)) in first.stages.iter().enumerate() {
                let wall = median(runs.iter().map(|r| r.stages[i].1).collect());
                let cpu = median(runs.iter().map(|r| r.stages[i].2).collect());
                let busy = median(runs.iter().map(|r| r.stages[i].3).collect());
                if i < 3 || stage.starts_with("skeleton (") {
                    total.0 += wall;
                    total.1 += cpu;
                    total.2 += busy;
                }
                println!(
                    "| {name} | {res} | {w}x{h}x{d} | {} | {stage} | {wall:.4} | {cpu:.4} | {busy:.4} |",
                    threads[k],
                );
            }
            println!(
                "| {name} | {res} | {w}x{h}x{d} | {} | **total** ({} nodes, {} filtered) | **{:.4}** | {:.4} | {:.4} |",
                threads[k],
                first.nodes,
                first.filtered,
                total.0,
                total.1,
                total.2
            );
        }
    }
}
