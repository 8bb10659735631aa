//! Diagnostic images and figures of skeleton guiding at the primary hits of a scene's camera
//! (issue 8): which node each surface point maps to (eq. 151-155), where its lobes point
//! (eq. 162), and how one guided bounce compares with one BSDF-sampled bounce.
//!
//! `cargo run --release --example guide_images -- SCENE OUT_DIR [WIDTH HEIGHT SAMPLES [OPTIONS]]`
//! (SCENE a scene file or `corridor`; defaults 160x80, 16 samples per pixel) with OPTIONS a
//! path_skeleton option list such as `c_skel=0.5:strength=auto`. Writes
//! - `nodes.png`: node of the primary hit, hashed colour (black: unmapped, white: delta BSDF);
//! - `lobes.png`: axis of the most probable active lobe as RGB (black: not guided);
//! - `lit_bsdf.png` / `lit_guide.png`: fraction of BSDF-sampled / guided one-bounce directions
//!   whose next vertex has unoccluded direct light,
//!
//! and prints the importance nodes, the lobes of the nodes covering most pixels, and the
//! one-bounce estimator `f cos / p * L_direct(next vertex)` (max over RGB; one light sample at
//! the next vertex) for BSDF sampling alone and for path_skeleton's one-sample mixture: mean,
//! second moment, fraction lit, the mean per-pixel variance of each, and which nodes the next
//! vertices map to, with their share of the estimate and of its second moment (where the light
//! arrives from, and where the variance comes from). Both estimators have the same mean; their
//! second moments are heavy-tailed on scenes lit through an opening, so use a few hundred
//! samples per pixel at a low resolution (e.g. 32x16, 1024) before reading ratios.
//! Single-threaded and deterministic (fixed seed).

use std::path::Path;

use lacuna::guide::{GuideQuery, SkeletonGuide, SkeletonGuideSettings};
use lacuna::math::{Rgb, Rng, Vec2};
use lacuna::scene::{load_scene_arg, Scene, SurfaceInteraction, Transport};

fn hash_colour(n: u32) -> [u8; 3] {
    let mut h = n.wrapping_mul(0x9e37_79b9) ^ 0x5bd1_e995;
    h ^= h >> 15;
    h = h.wrapping_mul(0x2c1b_3c6d);
    h ^= h >> 12;
    [
        64 + (h & 0xbf) as u8,
        64 + ((h >> 8) & 0xbf) as u8,
        64 + ((h >> 16) & 0xbf) as u8,
    ]
}

/// Direct light at `si` seen from `si.wo` (one light sample, no MIS), and whether it is lit.
fn direct(scene: &Scene, si: &SurfaceInteraction, rng: &mut Rng) -> Rgb {
    let bsdf = scene.bsdf(si);
    if bsdf.is_delta() {
        return Rgb::ZERO;
    }
    let Some(sampler) = scene.light_sampler() else {
        return Rgb::ZERO;
    };
    let (index, pmf) = sampler.sample(rng.uniform());
    let light = &scene.lights()[index];
    let Some(ls) = light.sample(si.p, rng.uniform2()) else {
        return Rgb::ZERO;
    };
    if ls.delta || ls.wi.dot(si.ng) * si.wo.dot(si.ng) <= 0.0 {
        return Rgb::ZERO;
    }
    let frame = si.shading_frame();
    let wo = frame.to_local(si.wo);
    let wi = frame.to_local(ls.wi);
    let f = bsdf.eval(wo, wi, Transport::Radiance) * wi.z.abs();
    if f == Rgb::ZERO || !scene.unoccluded(si, &ls) {
        return Rgb::ZERO;
    }
    f * ls.radiance / (pmf * ls.pdf)
}

#[derive(Default, Clone, Copy)]
struct Moments {
    n: f64,
    sum: f64,
    sum2: f64,
    lit: f64,
}

impl Moments {
    fn add(&mut self, v: f64, lit: bool) {
        self.n += 1.0;
        self.sum += v;
        self.sum2 += v * v;
        self.lit += lit as u8 as f64;
    }
    fn variance(&self) -> f64 {
        let m = self.sum / self.n;
        (self.sum2 / self.n - m * m).max(0.0)
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        eprintln!("usage: guide_images SCENE OUT_DIR [WIDTH HEIGHT SAMPLES [OPTIONS]]");
        std::process::exit(2);
    }
    let out = Path::new(&args[2]);
    std::fs::create_dir_all(out).unwrap();
    let width: u32 = args.get(3).map_or(160, |s| s.parse().unwrap());
    let height: u32 = args.get(4).map_or(80, |s| s.parse().unwrap());
    let samples: u32 = args.get(5).map_or(16, |s| s.parse().unwrap());
    let mut settings = SkeletonGuideSettings::default();
    if let Some(opts) = args.get(6) {
        for kv in opts.split(':').filter(|s| !s.is_empty()) {
            let (k, v) = kv.split_once('=').expect("OPTION=VALUE");
            settings.set(k, v).unwrap();
        }
    }
    let scene = load_scene_arg(Path::new(&args[1]))
        .unwrap()
        .0
        .builder
        .build()
        .unwrap();
    let camera = scene
        .camera()
        .expect("scene camera")
        .frame(width as f32 / height as f32);
    let guide = SkeletonGuide::build(&scene, scene.camera(), &settings, &|_, _| true).unwrap();
    let g = guide.grid();
    println!(
        "grid {:?} voxel {:.4}; {} nodes, {} guided; {} importance nodes kept of {} found; {:.3} s",
        g.dims,
        g.voxel_size,
        guide.node_count(),
        guide.guided_node_count(),
        guide.importance_nodes().len(),
        guide.importance_nodes_found(),
        guide.total_seconds()
    );
    let total_power: f32 = guide.importance_nodes().iter().map(|i| i.power).sum();
    for (i, imp) in guide.importance_nodes().iter().enumerate() {
        let p = guide.node_position(imp.node).unwrap();
        println!(
            "  importance {i:2}: node {:3} at ({:8.2} {:8.2} {:8.2}) radius {:6.2} power {:.4e} ({:.1} %)",
            imp.node,
            p.x,
            p.y,
            p.z,
            guide.node_radius(imp.node).unwrap(),
            imp.power,
            100.0 * imp.power / total_power
        );
    }

    let (w, h) = (width as usize, height as usize);
    let mut nodes = vec![[0u8; 3]; w * h];
    let mut lobes_img = vec![[0u8; 3]; w * h];
    let mut lit_bsdf = vec![0u8; w * h];
    let mut lit_guide = vec![0u8; w * h];
    let mut node_pixels = std::collections::BTreeMap::<u32, u32>::new();
    // Per node of the next vertex (u32::MAX: unmapped): sum and sum of squares of the
    // BSDF-sampled estimator, then of the mixture's guided samples; where the light and the
    // variance come from.
    let mut by_next = std::collections::BTreeMap::<u32, [f64; 4]>::new();
    let (mut bsdf_m, mut guide_m, mut mix_m) =
        (Moments::default(), Moments::default(), Moments::default());
    let (mut var_bsdf, mut var_mix, mut pixels_guided, mut pixels_hit) = (0.0, 0.0, 0u32, 0u32);
    let mut rng = Rng::new(7, 0);
    let mut query = GuideQuery::new();
    let c = settings.c_skel;
    for y in 0..h {
        for x in 0..w {
            let film = Vec2::new((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32);
            let ray = camera.generate_ray(film, Vec2::splat(0.5));
            let Some(si) = scene.intersect(&ray) else {
                continue;
            };
            let bsdf = scene.bsdf(&si);
            if bsdf.is_delta() {
                nodes[y * w + x] = [255, 255, 255];
                continue;
            }
            pixels_hit += 1;
            query.init(&guide, &scene, si.p, si.p_error, si.ng, si.wo);
            if let Some(n) = query.node() {
                nodes[y * w + x] = hash_colour(n);
                *node_pixels.entry(n).or_default() += 1;
            }
            if let Some((axis, _, _)) = query.lobe(0) {
                lobes_img[y * w + x] = [0, 1, 2].map(|a| (127.5 + 127.0 * axis[a]) as u8);
                pixels_guided += 1;
            }
            let frame = si.shading_frame();
            let wo = frame.to_local(si.wo);
            let (mut pb, mut pm) = (Moments::default(), Moments::default());
            let (mut lit_g, mut guided_n) = (0u32, 0u32);
            for _ in 0..samples {
                // BSDF sampling alone.
                if let Some(bs) =
                    bsdf.sample(wo, rng.uniform(), rng.uniform2(), Transport::Radiance)
                {
                    let wi = frame.to_world(bs.wi);
                    let (v, lit) = match scene.intersect(&si.spawn_ray(wi)) {
                        Some(next) => {
                            let l = direct(&scene, &next, &mut rng);
                            let v = (bs.f * (bs.wi.z.abs() / bs.pdf) * l).max_element() as f64;
                            let n = guide
                                .map_point(next.p, next.ng, next.wo)
                                .unwrap_or(u32::MAX);
                            let e = by_next.entry(n).or_default();
                            e[0] += v;
                            e[1] += v * v;
                            (v, l != Rgb::ZERO)
                        }
                        None => (0.0, false),
                    };
                    pb.add(v, lit);
                    bsdf_m.add(v, lit);
                } else {
                    pb.add(0.0, false);
                    bsdf_m.add(0.0, false);
                }
                // The one-sample mixture of path_skeleton and, separately, the lobes alone.
                let guided = query.guiding_probability() > 0.0 && rng.uniform() < c;
                let dir = if guided {
                    query.sample(rng.uniform(), rng.uniform2()).map(|(d, _)| d)
                } else {
                    bsdf.sample(wo, rng.uniform(), rng.uniform2(), Transport::Radiance)
                        .filter(|bs| !bs.delta)
                        .map(|bs| frame.to_world(bs.wi))
                };
                let Some(wi) = dir else {
                    pm.add(0.0, false);
                    mix_m.add(0.0, false);
                    continue;
                };
                let wl = frame.to_local(wi);
                let f = bsdf.eval(wo, wl, Transport::Radiance) * wl.z.abs();
                let pdf = query.mixture_pdf(wi, bsdf.pdf(wo, wl));
                let (v, lit) = match scene.intersect(&si.spawn_ray(wi)) {
                    Some(next) if f != Rgb::ZERO && wi.dot(si.ng) * si.wo.dot(si.ng) > 0.0 => {
                        let l = direct(&scene, &next, &mut rng);
                        let v = (f * l / pdf).max_element() as f64;
                        if guided {
                            let n = guide
                                .map_point(next.p, next.ng, next.wo)
                                .unwrap_or(u32::MAX);
                            let e = by_next.entry(n).or_default();
                            e[2] += v;
                            e[3] += v * v;
                        }
                        (v, l != Rgb::ZERO)
                    }
                    _ => (0.0, false),
                };
                pm.add(v, lit);
                mix_m.add(v, lit);
                if guided {
                    guide_m.add(v, lit);
                    lit_g += lit as u32;
                    guided_n += 1;
                }
            }
            var_bsdf += pb.variance();
            var_mix += pm.variance();
            lit_bsdf[y * w + x] = (255.0 * pb.lit / pb.n) as u8;
            lit_guide[y * w + x] = (255.0 * lit_g as f64 / guided_n.max(1) as f64) as u8;
        }
    }
    let save_rgb = |name: &str, px: &[[u8; 3]]| {
        let buf: Vec<u8> = px.iter().flatten().copied().collect();
        image::save_buffer(out.join(name), &buf, width, height, image::ColorType::Rgb8).unwrap();
    };
    save_rgb("nodes.png", &nodes);
    save_rgb("lobes.png", &lobes_img);
    for (name, px) in [("lit_bsdf.png", &lit_bsdf), ("lit_guide.png", &lit_guide)] {
        image::save_buffer(out.join(name), px, width, height, image::ColorType::L8).unwrap();
    }
    println!(
        "primary hits (non-delta) {pixels_hit}, guided {pixels_guided} ({:.1} %); {} distinct nodes",
        100.0 * pixels_guided as f64 / pixels_hit.max(1) as f64,
        node_pixels.len()
    );
    let mut by_pixels: Vec<_> = node_pixels.into_iter().collect();
    by_pixels.sort_by_key(|b| std::cmp::Reverse(b.1));
    for (n, count) in by_pixels.iter().take(12) {
        let p = guide.node_position(*n).unwrap();
        let lobes: Vec<String> = guide
            .lobes(*n)
            .iter()
            .map(|l| {
                format!(
                    "imp {} p {:.2} d {:.0} -> ({:.0} {:.0} {:.0}) r {:.1}",
                    l.importance,
                    l.probability,
                    l.distance,
                    l.point.x,
                    l.point.y,
                    l.point.z,
                    l.radius
                )
            })
            .collect();
        println!(
            "  node {n:3} ({:6.0} {:6.0} {:6.0}) {count:5} px: {}",
            p.x,
            p.y,
            p.z,
            lobes.join("; ")
        );
    }
    let report = |name: &str, m: &Moments| {
        println!(
            "  {name:22} mean {:.4e}  second moment {:.4e}  lit {:.2} %  (n {})",
            m.sum / m.n,
            m.sum2 / m.n,
            100.0 * m.lit / m.n,
            m.n
        );
    };
    println!("one bounce then direct light, max over RGB, {samples} samples per pixel:");
    report("bsdf", &bsdf_m);
    report("mixture (path_skeleton)", &mix_m);
    report("  of which guided", &guide_m);
    let (bsdf_sum, bsdf_sum2) = (bsdf_m.sum.max(1e-300), bsdf_m.sum2.max(1e-300));
    let (guide_sum, guide_sum2) = (guide_m.sum.max(1e-300), guide_m.sum2.max(1e-300));
    let mut next: Vec<_> = by_next.into_iter().collect();
    next.sort_by(|a, b| b.1[0].total_cmp(&a.1[0]));
    println!("  share of the estimate / of its second moment by node of the next vertex:");
    for (n, e) in next.iter().take(8) {
        let name = if *n == u32::MAX {
            "unmapped".to_string()
        } else {
            format!("node {n:3}")
        };
        let imp = guide.importance_nodes().iter().position(|i| i.node == *n);
        println!(
            "    {name} {:12} bsdf {:5.1} % / {:5.1} %   guided {:5.1} % / {:5.1} %",
            imp.map_or(String::new(), |i| format!("(importance {i})")),
            100.0 * e[0] / bsdf_sum,
            100.0 * e[1] / bsdf_sum2,
            100.0 * e[2] / guide_sum,
            100.0 * e[3] / guide_sum2
        );
    }
    println!(
        "  mean per-pixel variance: bsdf {:.4e}, mixture {:.4e} (ratio {:.3})",
        var_bsdf / pixels_hit as f64,
        var_mix / pixels_hit as f64,
        var_mix / var_bsdf
    );
}
