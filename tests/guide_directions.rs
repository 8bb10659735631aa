//! `path_skeleton:directions=learned` (issue 8, round 14): a learned directional histogram per
//! skeleton node instead of its lobes (`guide::directional`).
//!
//! - the histogram distribution alone and in one-sample MIS with a BSDF: chi-square of sampled
//!   directions against the pdf, the pdf integrates to 1, `sample`'s pdf is `pdf()`'s, and
//!   f cos / pdf estimates the albedo without bias;
//! - the training is deterministic (any thread count) and a guided query traces no shadow ray
//!   and samples its node's distribution;
//! - unbiasedness: the same region means as `path` within their measured error on the
//!   corridor, the two rooms and the Veach door, with the learned and an aggressive fixed c;
//!   no NaN (`region_means` asserts finite pixels).

mod common;

use common::agreement::{agree_on_corridor, agree_on_two_rooms, agree_on_veach_door, load_scene};
use common::chi2::{assert_z, Stats};
use common::directions::chi2_directions;
use common::sphere::SphereGrid;
use lacuna::guide::directional::{self, BINS};
use lacuna::guide::{sample_bsdf_or_guide, GuideQuery, SkeletonGuide, SkeletonGuideSettings};
use lacuna::math::{warp, Frame, Rgb, Rng, Sampler, Vec3};
use lacuna::scene::{Bsdf, Material, Scene};

/// Bin weights of a peaked, uneven distribution: a histogram of a power-cosine lobe plus a
/// second weaker one, some bins empty before the floor.
fn peaked_bins() -> Vec<f32> {
    peaked_bins_with(directional::FLOOR)
}

/// The same with uniform share `floor` (`histogram_floor`).
fn peaked_bins_with(floor: f32) -> Vec<f32> {
    let mut rng = Sampler::independent(Rng::new(11, 12));
    let a = Vec3::new(0.3, -0.6, 0.5).normalize();
    let b = Vec3::new(-0.8, 0.1, -0.3).normalize();
    let samples: Vec<(Vec3, f64)> = (0..20_000)
        .map(|_| {
            let w = warp::uniform_sphere(rng.uniform2());
            let x = (w.dot(a).max(0.0) as f64).powi(20) + 0.3 * (w.dot(b).max(0.0) as f64).powi(6);
            (w, x)
        })
        .collect();
    directional::bin_probabilities(samples.into_iter(), floor)
}

#[test]
fn chi2_of_the_histogram_distribution() {
    let bins = peaked_bins();
    assert_eq!(bins.len(), BINS);
    assert!(GuideQuery::with_distribution(0.5, &bins[1..]).is_err());
    assert!(GuideQuery::with_distribution(1.0, &bins).is_err());
    assert!(GuideQuery::with_distribution(0.5, &vec![0.0; BINS]).is_err());
    // The default floor (0.05), a larger one (`histogram_floor=0.15`, the default before
    // round 16: the emptiest bins' density three times the default's) and uniform.
    let high = peaked_bins_with(0.15);
    assert!(
        bins.iter().all(|&p| p > 0.0)
            && bins.iter().fold(1.0f32, |m, &p| m.min(p))
                < high.iter().fold(1.0f32, |m, &p| m.min(p))
    );
    for (k, bins) in [bins, high, vec![1.0; BINS]].into_iter().enumerate() {
        let q = GuideQuery::with_distribution(0.5, &bins).unwrap();
        assert_eq!(q.guiding_probability(), 0.5);
        let name = format!("histogram {k}");
        let integral = chi2_directions(
            &name,
            &SphereGrid::uniform(18, 37),
            Sampler::independent(Rng::new(300 + k as u64, 78)),
            |rng| {
                let (w, pdf) = q.sample(rng.uniform(), rng.uniform2())?;
                assert!(
                    (w.length() - 1.0).abs() < 1e-4,
                    "{name}: |w| {}",
                    w.length()
                );
                let p = q.pdf(w);
                assert!(
                    (pdf - p).abs() <= 1e-6 * p,
                    "{name}: sample pdf {pdf} but pdf() {p}"
                );
                Some(w)
            },
            |w| q.pdf(w) as f64,
        );
        assert!(
            (integral - 1.0).abs() < 1e-3,
            "{name}: pdf integrates to {integral}"
        );
    }
}

/// The histogram in one-sample MIS with a Lambertian BSDF, as `path_skeleton` draws it:
/// directions follow `c p_hist + (1 - c) p_bsdf` (guided directions below the surface are "no
/// sample"), each sample carries that density, and f cos / pdf estimates the albedo.
#[test]
fn chi2_and_albedo_of_the_bsdf_and_histogram_mixture() {
    let q = GuideQuery::with_distribution(0.6, &peaked_bins()).unwrap();
    chi2_and_albedo_of_the_mixture("lambert + histogram", &q, 0.6);
}

/// `ratio_max` lowers a query's c at render time (`GuideQuery::cap_guiding_probability`):
/// sampling and every density then use the capped c.
#[test]
fn chi2_and_albedo_of_the_mixture_with_a_capped_c() {
    let mut q = GuideQuery::with_distribution(0.6, &peaked_bins()).unwrap();
    q.cap_guiding_probability(0.25);
    assert_eq!(q.guiding_probability(), 0.25);
    chi2_and_albedo_of_the_mixture("lambert + histogram, c capped at 0.25", &q, 0.25);
    // A cap above c leaves it; a negative one turns guiding off.
    q.cap_guiding_probability(0.9);
    assert_eq!(q.guiding_probability(), 0.25);
    q.cap_guiding_probability(-0.5);
    assert_eq!(q.guiding_probability(), 0.0);
}

/// Chi-square of `sample_bsdf_or_guide` with a Lambertian BSDF and the query `q` (guiding
/// probability `c`) against c p_guide + (1 - c) p_bsdf, and its albedo estimate.
fn chi2_and_albedo_of_the_mixture(label: &str, q: &GuideQuery, c: f32) {
    // The normal along z: the horizon is a boundary of the test's cells (a cell straddling
    // it would hold directions above it that the cell's quadrature may miss).
    let frame = Frame::from_z(Vec3::Z);
    let wo_local = Vec3::new(0.4, -0.2, 0.7).normalize();
    let bsdf: Bsdf = Material::diffuse(Rgb::splat(0.8)).bsdf(Rgb::splat(0.8));
    let mut estimate = Stats::default();
    let integral = chi2_directions(
        label,
        &SphereGrid::uniform(18, 37),
        Sampler::independent(Rng::new(400, 78)),
        |rng| {
            let Some(m) = sample_bsdf_or_guide(&bsdf, wo_local, &frame, q, rng) else {
                estimate.add(0.0);
                return None;
            };
            let s = m.sample;
            let w = frame.to_world(s.wi);
            let expected = q.mixture_pdf(w, bsdf.pdf(wo_local, s.wi));
            assert!(
                (s.pdf - expected).abs() <= 1e-4 * expected,
                "sample pdf {} but mixture pdf {expected}",
                s.pdf
            );
            estimate.add((s.f.x * s.wi.z.abs() / s.pdf) as f64);
            Some(w)
        },
        |w| {
            let wi = frame.to_local(w);
            let guided = if wi.z > 0.0 { q.pdf(w) } else { 0.0 };
            (c * guided + (1.0 - c) * bsdf.pdf(wo_local, wi)) as f64
        },
    );
    assert!(integral < 1.0, "part of the histogram is below the surface");
    assert_z(
        &format!("{label}: albedo"),
        estimate.mean(),
        0.8,
        estimate.std_err(),
    );
}

fn settings(options: &[(&str, &str)]) -> SkeletonGuideSettings {
    let mut s = SkeletonGuideSettings::default();
    for (key, value) in options {
        s.set(key, value).unwrap();
    }
    s
}

fn build(scene: &Scene, settings: &SkeletonGuideSettings, threads: usize) -> SkeletonGuide {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(|| SkeletonGuide::build(scene, scene.camera(), settings, &|_, _| true).unwrap())
}

/// `directions=learned` is the default (round 15); the lobe options `lobe_weights=learned`
/// and `strength=learned` imply `directions=lobes` unless `directions` is named, and named
/// `learned` they are an error, in either order.
#[test]
fn options_parse_and_exclude_the_lobe_options() {
    let default = SkeletonGuideSettings::default();
    assert!(default.learned_directions && default.trains());
    assert!(settings(&[("directions", "learned")]).learned_directions);
    assert!(!settings(&[("directions", "lobes")]).learned_directions);
    let mut s = SkeletonGuideSettings::default();
    assert!(s.set("directions", "histogram").is_err());
    s.set("directions", "learned").unwrap();
    assert!(s.set("lobe_weights", "learned").is_err());
    assert!(s.set("strength", "learned").is_err());
    for (key, value) in [("lobe_weights", "learned"), ("strength", "learned")] {
        let s = settings(&[(key, value)]);
        assert!(!s.learned_directions, "{key}={value} implies the lobes");
        let s = settings(&[(key, value), ("directions", "lobes")]);
        assert!(!s.learned_directions);
        let mut s = settings(&[(key, value)]);
        let err = s.set("directions", "learned").unwrap_err().to_string();
        assert!(err.contains("directions=learned"), "{err}");
    }
    // The implication holds while the lobe option is learned.
    assert!(settings(&[("strength", "learned"), ("strength", "auto")]).learned_directions);
    assert!(
        settings(&[("lobe_weights", "learned"), ("lobe_weights", "distance")]).learned_directions
    );
    // Options that do not weigh lobes keep the default.
    assert!(settings(&[("c_skel", "0.5"), ("lobe_weights", "distance")]).learned_directions);
    for spec in [
        "path_skeleton:directions=learned:lobe_weights=learned",
        "path_skeleton:strength=learned:directions=learned",
    ] {
        assert!(
            lacuna::integrator::create(spec, Default::default()).is_err(),
            "{spec}"
        );
    }
    for spec in [
        "path_skeleton:lobe_weights=learned",
        "path_skeleton:strength=learned",
        "path_skeleton:directions=lobes:lobe_weights=learned",
    ] {
        assert!(
            lacuna::integrator::create(spec, Default::default()).is_ok(),
            "{spec}"
        );
    }
    // Iterative training samples the learned distributions: it needs them.
    s.set("training_passes", "3").unwrap();
    assert_eq!(s.training_passes, 3);
    assert!(s.set("training_passes", "0").is_err());
    assert!(s.set("training_passes", "5").is_err());
    assert!(s.set("directions", "lobes").is_err());
    assert!(settings(&[("directions", "lobes")])
        .set("training_passes", "2")
        .is_err());
    let mut s = settings(&[("directions", "learned")]);
    assert!(!s.training_history && s.histogram_floor == directional::FLOOR);
    s.set("training_history", "all").unwrap();
    s.set("histogram_floor", "0.15").unwrap();
    assert!(s.training_history && s.histogram_floor == 0.15);
    assert!(s.set("training_history", "some").is_err());
    for bad in ["0", "-0.1", "1.5", "nan"] {
        assert!(s.set("histogram_floor", bad).is_err(), "{bad}");
    }
}

#[test]
fn ratio_max_parses_and_validates() {
    let s = SkeletonGuideSettings::default();
    assert_eq!(s.ratio_max, None, "auto by default");
    assert_eq!(settings(&[("ratio_max", "2.5")]).ratio_max, Some(2.5));
    assert_eq!(
        settings(&[("ratio_max", "2"), ("ratio_max", "off")]).ratio_max,
        Some(f32::INFINITY)
    );
    assert_eq!(
        settings(&[("ratio_max", "2"), ("ratio_max", "auto")]).ratio_max,
        None
    );
    let mut s = SkeletonGuideSettings::default();
    for bad in ["1", "0.5", "0", "-3", "nan", "x"] {
        assert!(s.set("ratio_max", bad).is_err(), "{bad}");
    }
}

/// The training (and so the distributions) are the same for any thread count; every guided
/// node has its distribution and a guided query samples it without shadow rays.
#[test]
fn learned_directions_are_deterministic_and_reach_the_queries() {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    check_learned_directions(&scene, &settings(&[("directions", "learned")]));
}

/// The same with two training passes (the second sampling the first's distributions), and
/// the second pass learns something else than the first.
#[test]
fn iterative_training_is_deterministic_and_reaches_the_queries() {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    let one = settings(&[("directions", "learned"), ("training_paths", "32768")]);
    let mut two = one;
    two.set("training_passes", "2").unwrap();
    check_learned_directions(&scene, &two);
    assert_ne!(
        build(&scene, &one, 2).training().unwrap().directions,
        build(&scene, &two, 2).training().unwrap().directions
    );
}

fn check_learned_directions(scene: &Scene, s: &SkeletonGuideSettings) {
    let s = *s;
    let one = build(scene, &s, 1);
    let t = one.training().expect("trained").clone();
    assert_eq!(build(scene, &s, 2).training(), Some(&t));
    assert!(t.guided_nodes() > 0, "no node guided");
    let table = one.directions().expect("a table");
    for (k, &c) in t.probabilities.iter().enumerate() {
        let d = t.directions[k].as_ref();
        if c > 0.0 {
            let d = d.expect("a guided node has a distribution");
            for class in d.chunks_exact(BINS) {
                let sum: f32 = class.iter().sum();
                assert!((sum - 1.0).abs() < 1e-4 && class.iter().all(|&p| p > 0.0));
            }
            assert!(table.slot(k as u32, 0).is_some());
        } else {
            assert!(table.slot(k as u32, 0).is_none());
        }
    }
    let mut rng = Rng::new(5, 5);
    let (mut guided, mut query) = (0, GuideQuery::new());
    let b = scene.bounds();
    for _ in 0..20_000 {
        let u = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform());
        let ray = lacuna::geometry::Ray::new(
            b.min + (b.max - b.min) * u,
            warp::uniform_sphere(rng.uniform2()),
            f32::INFINITY,
        );
        let Some(si) = scene.intersect(&ray) else {
            continue;
        };
        let rays = query.init(&one, scene, si.p, si.p_error, si.ng, si.wo);
        assert_eq!(rays, 0, "a learned distribution traces no shadow ray");
        let Some(node) = query.node() else { continue };
        let c = one.guiding_probability(node);
        assert_eq!(query.guiding_probability(), c);
        assert_eq!(query.lobe_count(), 0);
        if c > 0.0 {
            guided += 1;
            let (w, pdf) = query.sample(rng.uniform(), rng.uniform2()).unwrap();
            assert!(pdf > 0.0 && pdf == query.pdf(w));
        }
    }
    assert!(guided > 100, "{guided} guided points");
}

/// The specs z-tested against `path`: the default (`directions=learned` with the learned c,
/// portal lobes as the training's proposal, voxel visibility) and a fixed high c.
const SPECS: &[&str] = &[
    "path_skeleton",
    // The default's learned choices where its scene-level switch turns them off (two rooms).
    "path_skeleton:cost_model=vertices",
    "path_skeleton:c_skel=0.9:directions=learned",
    // ratio_max binds at c = 0.9 (1 / (1 - 0.9) = 10 > 1.5): c varies with the path's prefix.
    "path_skeleton:c_skel=0.9:directions=learned:ratio_max=1.5",
    "path_skeleton:aim=portal:c_skel=learned:visibility=voxel:directions=learned:histogram_floor=0.05:training_passes=2:training_paths=65536:cost_model=vertices",
    "path_skeleton:c_skel=0.9:directions=learned:training_passes=3:training_paths=16384",
];

#[test]
fn learned_directions_agree_with_path_on_the_corridor() {
    agree_on_corridor(SPECS);
}

#[test]
fn learned_directions_agree_with_path_on_the_two_rooms() {
    agree_on_two_rooms(SPECS);
}

#[test]
fn learned_directions_agree_with_path_on_the_veach_door() {
    agree_on_veach_door(SPECS);
}
