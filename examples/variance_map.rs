//! Where an integrator's error is, without a reference: each spec renders the scene `SEEDS`
//! times at `SPP` samples per pixel (independent seeds), and the per-pixel variance of one
//! sample (the variance of the seeds' pixel means x spp, luminance) is split over image regions:
//! the thirds of the pixels by brightness (of the first spec's mean image), and whether the
//! camera ray's first vertex maps to a node the guide samples (c > 0; the first
//! `path_skeleton` spec's guide). For an unbiased estimator this variance is the error per
//! sample, so the regions say where a guided render gains or loses against `path`. Also
//! writes, per spec, `OUT/NAME-sd.png` (the per-sample standard deviation, on a log scale
//! shared by all specs) and `OUT/NAME-mean.png`.
//!
//! `cargo run --release --example variance_map -- SCENE WIDTH HEIGHT SPP SEEDS SPECS OUT`
//! (SPECS comma-separated; `path:max_depth=2` etc. give the radiance by depth). `SAMPLER=independent`
//! in the environment renders with independent numbers instead of the default Sobol sampler.

use std::path::Path;
use std::sync::atomic::AtomicBool;

use lacuna::integrator::{self, IntegratorSettings, PathTracer};
use lacuna::math::{luminance, Vec2};
use lacuna::render::{prepare, render, RenderSettings};
use lacuna::scene::load_scene_arg;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 8 {
        eprintln!("usage: variance_map SCENE WIDTH HEIGHT SPP SEEDS SPECS OUT");
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
    if seeds < 2 {
        eprintln!("SEEDS must be at least 2: the variance is estimated across seeds");
        std::process::exit(2);
    }
    let out = Path::new(&args[7]);
    std::fs::create_dir_all(out).unwrap();
    let camera = *scene.camera().expect("scene camera");
    let n = (width * height) as usize;
    // Region of each pixel: first-vertex node guided (from the first guided spec) or not.
    let mut guided_first: Option<Vec<bool>> = None;
    let mut bright_rank: Option<Vec<usize>> = None;
    let mut maps: Vec<(String, Vec<f64>, Vec<f64>)> = vec![];
    for spec in args[6].split(',') {
        let settings = IntegratorSettings::default();
        let (name, parsed) = integrator::parse_spec(spec, settings).unwrap();
        let mut integrator = integrator::create(spec, settings).unwrap();
        let first_guided = name == "path_skeleton" && guided_first.is_none();
        if !first_guided {
            prepare(integrator.as_mut(), &scene, &camera, None, &|_, _| true).unwrap();
        } else {
            // The first guided spec renders with the instance whose guide the region map and
            // tables below read (one precomputation, not two).
            let mut pt = PathTracer::skeleton_guided(parsed).unwrap();
            prepare(&mut pt, &scene, &camera, None, &|_, _| true).unwrap();
            let guide = pt.guide().unwrap().clone();
            integrator = Box::new(pt);
            let frame = camera.frame(width as f32 / height as f32);
            let mut g = vec![false; n];
            let mut first_hits = vec![0u32; guide.node_count()];
            for (i, gi) in g.iter_mut().enumerate() {
                let (x, y) = ((i as u32 % width) as f32, (i as u32 / width) as f32);
                let film = Vec2::new((x + 0.5) / width as f32, (y + 0.5) / height as f32);
                let ray = frame.generate_ray(film, Vec2::new(0.5, 0.5));
                if let Some(si) = scene.intersect(&ray) {
                    if let Some(node) = guide.map_point(si.p, si.ng, si.wo) {
                        first_hits[node as usize] += 1;
                        *gi = guide.guiding_probability(node) > 0.0;
                    }
                }
            }
            println!(
                "first vertices in guided nodes: {} of {n} pixels",
                g.iter().filter(|&&b| b).count()
            );
            guided_first = Some(g);
            // PASS_X: of the first vertices where the guide has lobes, the fraction of guided
            // (c = 1) and of cosine-sampled directions whose next hit lies beyond x = PASS_X.
            if let Some(px) = std::env::var("PASS_X")
                .ok()
                .map(|v| v.parse::<f32>().unwrap())
            {
                use lacuna::guide::GuideQuery;
                use lacuna::math::{warp, Frame};
                let mut q = GuideQuery::new();
                let mut rng = lacuna::math::Rng::new(7, 1);
                let (mut with, mut gpass, mut cpass, mut tot) = (0u32, 0u64, 0u64, 0u64);
                // Next-event estimate at the next hit (one light sample, luminance of the
                // radiance it reflects back toward the first vertex), and how often it is lit.
                let (mut glit, mut clit, mut gl, mut cl) = (0u64, 0u64, 0.0f64, 0.0f64);
                let nee =
                    |h: &lacuna::scene::SurfaceInteraction, rng: &mut lacuna::math::Rng| -> f64 {
                        let bsdf = scene.bsdf(h);
                        if bsdf.is_delta() {
                            return 0.0;
                        }
                        let fr = h.shading_frame();
                        let wo = fr.to_local(h.wo);
                        let u = Vec2::new(rng.uniform(), rng.uniform());
                        let Some(ls) = scene.sample_light_toward(
                            h,
                            &fr,
                            &bsdf,
                            wo,
                            Default::default(),
                            Default::default(),
                            u,
                        ) else {
                            return 0.0;
                        };
                        if !scene.unoccluded(h, &ls.sample) {
                            return 0.0;
                        }
                        luminance(ls.sample.radiance * ls.f_cos) as f64
                            / (ls.sample.pdf * ls.pmf) as f64
                    };
                for i in 0..n {
                    let (x, y) = ((i as u32 % width) as f32, (i as u32 / width) as f32);
                    let film = Vec2::new((x + 0.5) / width as f32, (y + 0.5) / height as f32);
                    let ray = frame.generate_ray(film, Vec2::new(0.5, 0.5));
                    let Some(si) = scene.intersect(&ray) else {
                        continue;
                    };
                    if si.p.x < px {
                        continue;
                    }
                    q.clear();
                    q.init(&guide, &scene, si.p, si.p_error, si.ng, si.wo);
                    if q.lobe_count() == 0 {
                        continue;
                    }
                    with += 1;
                    let side = if si.ng.dot(si.wo) > 0.0 {
                        si.ng
                    } else {
                        -si.ng
                    };
                    let f = Frame::from_z(side);
                    for _ in 0..64 {
                        tot += 1;
                        let u = Vec2::new(rng.uniform(), rng.uniform());
                        if let Some((w, _)) = q.sample(rng.uniform(), u) {
                            if let Some(h) = scene.intersect(&si.spawn_ray(w)) {
                                gpass += (h.p.x < px) as u64;
                                let l = nee(&h, &mut rng);
                                glit += (l > 0.0) as u64;
                                gl += l;
                            }
                        }
                        let w = f.to_world(warp::cosine_hemisphere(u));
                        if let Some(h) = scene.intersect(&si.spawn_ray(w)) {
                            cpass += (h.p.x < px) as u64;
                            let l = nee(&h, &mut rng);
                            clit += (l > 0.0) as u64;
                            cl += l;
                        }
                    }
                }
                println!(
                    "PASS_X {px}: {with} first vertices with lobes; beyond: guided {:.4}, \
                     cosine {:.4}; next hit lit: guided {:.4}, cosine {:.4}; mean NEE there: \
                     guided {:.4}, cosine {:.4}",
                    gpass as f64 / tot.max(1) as f64,
                    cpass as f64 / tot.max(1) as f64,
                    glit as f64 / tot.max(1) as f64,
                    clit as f64 / tot.max(1) as f64,
                    gl / tot.max(1) as f64,
                    cl / tot.max(1) as f64
                );
            }
            if std::env::var_os("LOBES").is_some() {
                for (k, imp) in guide.importance_nodes().iter().enumerate() {
                    println!(
                        "importance {k}: node {} at {:?} power {:.3}",
                        imp.node,
                        guide.node_position(imp.node).unwrap(),
                        imp.power
                    );
                }
                let mut order: Vec<usize> = (0..guide.node_count()).collect();
                order.sort_by_key(|&k| std::cmp::Reverse(first_hits[k]));
                for &k in order.iter().take(6) {
                    println!("node {k} ({} first hits):", first_hits[k]);
                    for l in guide.lobes(k as u32) {
                        println!("  {l:?}");
                    }
                }
            }
            if std::env::var_os("NODES").is_some() {
                if let Some(t) = guide.training() {
                    println!(
                        "| node | position | radius | lobes | c | samples | nonzero | ratio | \
                         best ratio | 1st hits | lobe weights |"
                    );
                    for k in 0..guide.node_count() {
                        if t.samples[k] == 0 && first_hits[k] == 0 {
                            continue;
                        }
                        println!(
                            "| {k} | {:?} | {:.3} | {} | {} | {} | {} | {:.3} | {:.3} | {} | {:?} |",
                            guide.node_position(k as u32).unwrap(),
                            guide.node_radius(k as u32).unwrap(),
                            guide.lobes(k as u32).len(),
                            t.probabilities[k],
                            t.samples[k],
                            t.nonzero[k],
                            t.relative_cost[k],
                            t.best_ratio[k],
                            first_hits[k],
                            t.lobe_weights[k]
                        );
                    }
                }
            }
        }
        let sampler_kind = std::env::var("SAMPLER").map_or(Default::default(), |s| {
            lacuna::math::SamplerKind::parse(&s).expect("SAMPLER: sobol or independent")
        });
        let (mut sum, mut sum2) = (vec![0.0f64; n], vec![0.0f64; n]);
        for seed in 0..seeds {
            let rs = RenderSettings {
                width,
                height,
                spp,
                seed: 5000 + seed,
                sampler: sampler_kind,
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
            for (i, p) in film.radiance().iter().enumerate() {
                let l = luminance(*p) as f64;
                sum[i] += l;
                sum2[i] += l * l;
            }
        }
        let s = seeds as f64;
        let mean: Vec<f64> = sum.iter().map(|v| v / s).collect();
        // Unbiased variance of one seed's pixel mean, times spp: the variance of one sample.
        let var: Vec<f64> = (0..n)
            .map(|i| (sum2[i] - sum[i] * sum[i] / s).max(0.0) / (s - 1.0) * spp as f64)
            .collect();
        if bright_rank.is_none() {
            let mut order: Vec<usize> = (0..n).collect();
            order.sort_by(|&a, &b| mean[a].total_cmp(&mean[b]));
            let mut rank = vec![0; n];
            for (r, &i) in order.iter().enumerate() {
                rank[i] = 3 * r / n;
            }
            bright_rank = Some(rank);
        }
        maps.push((spec.to_string(), mean, var));
    }
    let rank = bright_rank.unwrap();
    let guided = guided_first.unwrap_or(vec![false; n]);
    println!(
        "{} {width}x{height}, {spp} spp x {seeds} seeds: mean over pixels of the luminance \
         variance per sample, by region (pixel counts in the header)",
        args[1]
    );
    let regions: Vec<(String, Vec<bool>)> = vec![
        ("all".into(), vec![true; n]),
        ("dark third".into(), rank.iter().map(|&r| r == 0).collect()),
        (
            "middle third".into(),
            rank.iter().map(|&r| r == 1).collect(),
        ),
        (
            "bright third".into(),
            rank.iter().map(|&r| r == 2).collect(),
        ),
        ("1st vertex guided".into(), guided.clone()),
        (
            "1st vertex unguided".into(),
            guided.iter().map(|&g| !g).collect(),
        ),
    ];
    print!("| spec | image mean |");
    for (r, m) in &regions {
        print!(" {r} ({}) |", m.iter().filter(|&&b| b).count());
    }
    println!(" top 1 % pixels' share |");
    for (spec, mean, var) in &maps {
        print!("| {spec} | {:.4} |", mean.iter().sum::<f64>() / n as f64);
        for (_, m) in &regions {
            let (mut t, mut k) = (0.0, 0usize);
            for i in 0..n {
                if m[i] {
                    t += var[i];
                    k += 1;
                }
            }
            // The variance, and (in brackets) the mean standard deviation, which is what
            // the MAE weighs.
            let sd: f64 = (0..n).filter(|&i| m[i]).map(|i| var[i].sqrt()).sum();
            print!(
                " {:.3e} [{:.3e}] |",
                t / k.max(1) as f64,
                sd / k.max(1) as f64
            );
        }
        let mut v = var.clone();
        v.sort_by(|a, b| b.total_cmp(a));
        let top: f64 = v[..n.div_ceil(100)].iter().sum();
        println!(" {:.2} |", top / v.iter().sum::<f64>());
    }
    // Maps on one log scale.
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for (_, _, var) in &maps {
        for &v in var {
            if v > 0.0 {
                lo = lo.min(v.sqrt());
                hi = hi.max(v.sqrt());
            }
        }
    }
    let lo = lo.max(hi * 1e-4);
    for (spec, mean, var) in &maps {
        let file = spec.replace([':', '='], "_");
        let sd = image::GrayImage::from_fn(width, height, |x, y| {
            let v = var[(y * width + x) as usize].sqrt().max(lo);
            image::Luma([(255.0 * (v / lo).ln() / (hi / lo).ln()) as u8])
        });
        sd.save(out.join(format!("{file}-sd.png"))).unwrap();
        let m = image::GrayImage::from_fn(width, height, |x, y| {
            let v = mean[(y * width + x) as usize].max(0.0);
            image::Luma([(255.0 * (v / (1.0 + v)).powf(1.0 / 2.2)) as u8])
        });
        m.save(out.join(format!("{file}-mean.png"))).unwrap();
    }
}
