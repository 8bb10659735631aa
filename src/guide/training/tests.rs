use super::prediction::*;
use super::statistics::*;
use super::*;
use crate::guide::directional::{self, DirectionalTable};
use crate::guide::settings::DEFAULT_TRAINING_MIN_NONZERO as FLOOR;
use crate::guide::TrainingCost;
use crate::math::{warp, Frame, MisHeuristic, Vec3};

/// The reweighted estimate of M(c, s) from samples of the training proposal (c0, s0)
/// agrees with a brute-force estimate from samples of (c, s) itself, on a toy integrand
/// over the sphere: a cosine "BSDF" around z, one power-cosine lobe around a tilted axis,
/// and f peaked off both axes (so neither strategy matches it).
#[test]
fn reweighted_second_moment_matches_brute_force() {
    let axis = Vec3::new(0.5, 0.2, 0.8).normalize();
    let peak = Vec3::new(0.7, -0.1, 0.6).normalize();
    let lobe = Frame::from_z(axis);
    let f = |w: Vec3| -> f32 {
        let cos = w.z.max(0.0);
        cos * (0.2 + 30.0 * w.dot(peak).max(0.0).powi(20))
    };
    let p_bsdf = |w: Vec3| warp::cosine_hemisphere_pdf(w);
    let p_skel = |w: Vec3, s: f32| warp::power_cosine_pdf(lobe.to_local(w), s);
    let draw = |rng: &mut Rng, c: f32, s: f32| -> Vec3 {
        if rng.uniform() < c {
            lobe.to_world(warp::power_cosine(rng.uniform2(), s))
        } else {
            warp::cosine_hemisphere(rng.uniform2())
        }
    };
    let s0 = 4.0;
    let n = 400_000;
    let mut rng = Rng::new(5, 1);
    let proposal: Vec<Vec3> = (0..n).map(|_| draw(&mut rng, TRAINING_C, s0)).collect();
    for &(c, s) in &[
        (0.0, 1.0),
        (0.2, 1.0),
        (0.5, 4.0),
        (0.7, 16.0),
        (0.9, 2.0),
        (0.3, 64.0),
    ] {
        let terms: Vec<f64> = proposal
            .iter()
            .map(|&w| reweighted_second_moment(f(w), p_bsdf(w), p_skel(w, s0), p_skel(w, s), c))
            .collect();
        let brute: Vec<f64> = (0..n)
            .map(|_| {
                let w = draw(&mut rng, c, s);
                let q = c as f64 * p_skel(w, s) as f64 + (1.0 - c as f64) * p_bsdf(w) as f64;
                if f(w) > 0.0 {
                    (f(w) as f64 / q).powi(2)
                } else {
                    0.0
                }
            })
            .collect();
        let stats = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64;
            (m, var / v.len() as f64)
        };
        let ((a, va), (b, vb)) = (stats(&terms), stats(&brute));
        let z = (a - b) / (va + vb).sqrt();
        assert!(a.is_finite() && b > 0.0, "c {c} s {s}: {a} {b}");
        assert!(
            z.abs() < 4.0,
            "c {c} s {s}: reweighted {a}, brute force {b}, z {z}"
        );
    }
}

#[test]
fn second_moment_is_infinite_where_the_candidate_misses() {
    // f > 0 where the BSDF has no density: only c > 0 with lobe density reaches it.
    assert_eq!(
        reweighted_second_moment(1.0, 0.0, 1.0, 0.0, 0.5),
        f64::INFINITY
    );
    assert_eq!(
        reweighted_second_moment(1.0, 0.0, 1.0, 1.0, 0.0),
        f64::INFINITY
    );
    assert!(reweighted_second_moment(1.0, 0.0, 1.0, 2.0, 0.5).is_finite());
    assert_eq!(reweighted_second_moment(0.0, 0.0, 0.0, 0.0, 0.5), 0.0);
}

/// Synthetic training samples at one node: a cosine "BSDF" (albedo 1) around z, one
/// power-cosine lobe (strength 64) aimed at a small cone of directions (cos >= 0.99) from
/// which radiance 10 arrives, drawn from the training proposal q_c0. `light` says whether
/// that radiance is an emitter the render's light sampling draws uniformly in the cone
/// (with one light sample per vertex recorded), or light reflected there (R).
fn cone_node(light: bool, n: usize) -> Vec<Sample> {
    let axis = Vec3::new(0.3, 0.0, 0.95).normalize();
    let lobe = Frame::from_z(axis);
    let (s0, cos_max, radiance) = (64.0, 0.99f32, 10.0f32);
    let p_cone = warp::uniform_cone_pdf(Vec3::new(0.0, 0.0, 1.0), cos_max);
    let p_skel = |w: Vec3| warp::power_cosine_pdf(lobe.to_local(w), s0);
    let in_cone = |w: Vec3| w.dot(axis) >= cos_max;
    let mut rng = Rng::new(11, 3);
    (0..n)
        .map(|_| {
            let w = if rng.uniform() < TRAINING_C {
                lobe.to_world(warp::power_cosine(rng.uniform2(), s0))
            } else {
                warp::cosine_hemisphere(rng.uniform2())
            };
            let f = if in_cone(w) && w.z > 0.0 {
                w.z / std::f32::consts::PI * radiance
            } else {
                0.0
            };
            let nee = if light {
                let wl = lobe.to_world(warp::uniform_cone(rng.uniform2(), cos_max));
                NeeTerms {
                    value: wl.z.max(0.0) / std::f32::consts::PI * radiance / p_cone,
                    p_light: p_cone,
                    wi: wl,
                    p_bsdf: warp::cosine_hemisphere_pdf(wl),
                    p_skel: p_skel(wl),
                    p_strength: [p_skel(wl); MAX_STRENGTHS],
                    p_lobes: [0.0; MAX_LOBES],
                }
            } else {
                NeeTerms::default()
            };
            Sample {
                node: 0,
                wi: w,
                class: 0,
                f_emitted: if light { f } else { 0.0 },
                f_reflected: if light { 0.0 } else { f },
                p_bsdf: warp::cosine_hemisphere_pdf(w),
                p_skel: p_skel(w),
                p_strength: [p_skel(w); MAX_STRENGTHS],
                p_light: if light && f > 0.0 { p_cone } else { 0.0 },
                nee,
                p_lobes: [0.0; MAX_LOBES],
                active: 1,
                rays: 1,
                remaining: 1,
                step: NO_STEP,
            }
        })
        .collect()
}

/// The scene-level prediction weighs each node's variance change by its samples against
/// the whole variance (guided or not), and charges the guided samples' overhead and the
/// mapping of every mapped vertex against all vertices: a node that halves its own
/// variance pays where it carries the image's variance, not where an unguided node carries
/// most of it, nor where the mapping reaches many vertices.
#[test]
fn the_scene_level_switch_weighs_gain_against_all_overhead() {
    let node = |v0: f64, v1: f64, overhead: f64| NodeChoice {
        guided: (overhead > 0.0).then_some((0.5, 0)),
        weights: None,
        relative_cost: 1.0,
        best_ratio: 1.0,
        variance_unguided: v0,
        variance_chosen: v1,
        overhead,
    };
    let scene = |choices: &[NodeChoice], samples: &[u32], mapped: u64| {
        let (variance_ratio, cost_ratio) = scene_prediction(choices, samples, 1000, mapped, 0.1);
        SceneChoice {
            variance_ratio,
            cost_ratio,
            ..SceneChoice::default()
        }
    };
    // Node 0 (guided) halves its variance at 0.5 vertices per sample; node 1 is not
    // guided. 100 samples each, 1000 vertices.
    let guided = node(1.0, 0.5, 0.5);
    let s = scene(&[guided, node(1.0, 1.0, 0.0)], &[100, 100], 200);
    assert!((s.variance_ratio - 150.0 / 200.0).abs() < 1e-12);
    assert!((s.cost_ratio - (1000.0 + 50.0 + 20.0) / 1000.0).abs() < 1e-12);
    assert!(s.pays(), "{}", s.efficiency());
    // Where the unguided node carries 9x the variance, the same node gains 5 %: no.
    let s = scene(&[guided, node(9.0, 9.0, 0.0)], &[100, 100], 200);
    assert!((s.variance_ratio - 9.5 / 10.0).abs() < 1e-12);
    assert!(!s.pays(), "{}", s.efficiency());
    // Mapping 4000 vertex visits (0.1 vertices each: 400 in all) eats the gain.
    let s = scene(&[guided, node(1.0, 1.0, 0.0)], &[100, 100], 4000);
    assert!(!s.pays(), "{}", s.efficiency());
    // Nothing guided: ratios 1, does not pay (nothing to switch off either).
    let s = scene(&[node(1.0, 1.0, 0.0)], &[100], 0);
    assert_eq!((s.variance_ratio, s.cost_ratio), (1.0, 1.0));
    assert!(!s.pays());
    // A contribution only guiding samples (infinite unguided variance) always pays.
    let s = scene(&[node(f64::INFINITY, 1.0, 0.5)], &[100], 5000);
    assert!(s.pays());
}

/// The scene-level prediction charges what the render's directions cost: the learned
/// histograms' query (no set-up, no shadow ray) is cheaper than the lobes'.
/// A camera path of one direction toward two equally probable outcomes under the training
/// proposal: A carries f = 1 (its step's `after` is f / q_0 = 2), B nothing. A policy that
/// draws A with probability a has second moment 1 / a; the path-level prediction is exact
/// on equal numbers of A and B paths, and each policy's weights q_0 / q enter it.
#[test]
fn the_path_level_prediction_is_the_ratio_of_second_moments() {
    let (a_none, a_chosen) = (0.2f64, 0.8f64);
    let mut log = PathLog::default();
    for i in 0..2000u32 {
        let carries = i % 2 == 0;
        let step = if carries {
            Step {
                after: 2.0,
                r_none: 0.5 / a_none,
                r_chosen: 0.5 / a_chosen,
            }
        } else {
            Step {
                after: 0.0,
                r_none: 0.5 / (1.0 - a_none),
                r_chosen: 0.5 / (1.0 - a_chosen),
            }
        };
        log.paths.push(PathRecord {
            first: 0.0,
            start: log.steps.len() as u32,
            len: 1,
        });
        log.steps.push(step);
    }
    let ratio = path_variance_ratio(&log);
    assert!((ratio - a_none / a_chosen).abs() < 1e-9, "{ratio}");
    // Swapping the policies inverts it; equal policies give 1.
    for st in &mut log.steps {
        std::mem::swap(&mut st.r_none, &mut st.r_chosen);
    }
    assert!((path_variance_ratio(&log) - a_chosen / a_none).abs() < 1e-9);
    for st in &mut log.steps {
        st.r_chosen = st.r_none;
    }
    assert_eq!(path_variance_ratio(&log), 1.0);
    // A second vertex's light sample is weighted by the first direction's ratio.
    let mut two = PathLog::default();
    two.paths.push(PathRecord {
        first: 1.0,
        start: 0,
        len: 2,
    });
    two.steps.push(Step {
        after: 0.0,
        r_none: 2.0,
        r_chosen: 1.0,
    });
    two.steps.push(Step {
        after: 1.0,
        r_none: 1.0,
        r_chosen: 1.0,
    });
    // none: e = 1 + 1 x 2 = 3, w = 1 / 2: 4.5; chosen: e = 2, w = 1: 4.
    assert!((path_variance_ratio(&two) - 4.0 / 4.5).abs() < 1e-12);
}

#[test]
fn measured_costs_follow_the_directions() {
    let mut s = crate::guide::SkeletonGuideSettings::default();
    assert!(s.learned_directions);
    assert_eq!(MeasuredCosts::of(&s), LEARNED_COSTS);
    s.set("directions", "lobes").unwrap();
    assert_eq!(MeasuredCosts::of(&s), LOBE_COSTS);
    const { assert!(LEARNED_COSTS.query < LOBE_COSTS.query) };
}

/// Every candidate c > 0 at one fixed strength, with c = 0 allowed to win.
fn one_strength_grid() -> Grid {
    Grid {
        c: CANDIDATES[1..].to_vec(),
        strengths: vec![SkeletonStrength::Fixed(64.0)],
        may_turn_off: true,
        lobe_weights: false,
        guided_cost: crate::guide::settings::DEFAULT_TRAINING_GUIDED_COST as f64,
        measured: LOBE_COSTS,
    }
}

/// The choice judges the render's estimator: guiding toward light that next-event
/// estimation already samples well (MIS-weighted hits, the vertex's own light sample)
/// does not pay and is turned off; the same radiance arriving as reflected light, which
/// only direction sampling finds, is guided. Judged by the unweighted emission alone (no
/// light density, no light sample), the first node would be guided too.
#[test]
fn choice_does_not_guide_toward_light_that_light_sampling_covers() {
    let grid = one_strength_grid();
    let choose = |samples: &[Sample]| {
        choose_node(
            samples,
            mean_shadow_rays(samples),
            &grid,
            TrainingCost::Path,
            1.0,
            FLOOR,
            MisHeuristic::Power,
        )
    };
    let lit = cone_node(true, 20_000);
    let covered = choose(&lit);
    assert_eq!(covered.guided, None, "{covered:?}");
    assert!(covered.best_ratio > 1.0, "{covered:?}");

    let unweighted: Vec<Sample> = lit
        .iter()
        .map(|s| Sample {
            p_light: 0.0,
            nee: NeeTerms::default(),
            ..*s
        })
        .collect();
    let naive = choose(&unweighted);
    assert!(matches!(naive.guided, Some((c, 0)) if c > 0.0), "{naive:?}");

    let reflected = choose(&cone_node(false, 20_000));
    assert!(
        matches!(reflected.guided, Some((c, 0)) if c >= 0.5),
        "{reflected:?}"
    );
    assert!(reflected.relative_cost < 0.2, "{reflected:?}");
}

/// `directions=learned` on the reflected cone: the learned distribution puts its density
/// in the cone (the bin of its axis far above the uniform 1 / 4 pi, a direction away from
/// it at the floor), each sample's candidate density is the other half's, and the choice
/// guides with it (the cone is 0.6 % of the sphere: the histogram's 15-degree bins and its
/// floor lose to the s = 64 lobe aimed at it, but still beat BSDF sampling by far).
#[test]
fn learned_directions_find_the_cone_and_are_chosen() {
    let mut samples = cone_node(false, 20_000);
    let (bins, _) = learn_directions(
        &mut samples,
        MisHeuristic::Power,
        &[],
        directional::FLOOR,
        true,
    );
    let table = DirectionalTable::new(&[Some(bins)]);
    let axis = Vec3::new(0.3, 0.0, 0.95).normalize();
    let uniform = 1.0 / (4.0 * std::f32::consts::PI);
    let slot = table.slot(0, 0).unwrap();
    assert!(
        table.pdf(slot, axis) > 20.0 * uniform,
        "{}",
        table.pdf(slot, axis)
    );
    let away = Vec3::new(-0.9, 0.3, 0.1).normalize();
    let floor = directional::FLOOR * uniform;
    assert!((table.pdf(slot, away) - floor).abs() < 1e-3 * floor);
    // The candidate densities were replaced (the lobe's s = 64 density is far larger in
    // the cone, far smaller away from it).
    assert!(samples
        .iter()
        .all(|s| s.p_strength[0] > 0.0 && s.p_strength[0] < 100.0));
    let choice = choose_node(
        &samples,
        0.0,
        &one_strength_grid(),
        TrainingCost::Path,
        1.0,
        FLOOR,
        MisHeuristic::Power,
    );
    assert!(
        matches!(choice.guided, Some((c, 0)) if c >= 0.3),
        "{choice:?}"
    );
    assert!(choice.relative_cost < 0.5, "{choice:?}");
}

/// Too few samples, or too few that carry anything: not guided, whatever they say.
#[test]
fn nodes_with_few_samples_are_not_guided() {
    let grid = one_strength_grid();
    let few = cone_node(false, MIN_SAMPLES as usize - 1);
    assert_eq!(
        choose_node(
            &few,
            mean_shadow_rays(&few),
            &grid,
            TrainingCost::Path,
            1.0,
            FLOOR,
            MisHeuristic::Power
        )
        .guided,
        None
    );
    let many = cone_node(false, 4 * MIN_SAMPLES as usize);
    assert!(choose_node(
        &many,
        mean_shadow_rays(&many),
        &grid,
        TrainingCost::Path,
        1.0,
        FLOOR,
        MisHeuristic::Power
    )
    .guided
    .is_some());
}

/// `training_min_nonzero` counts the samples that carry anything: a node just below the
/// floor is not guided, the same node at the floor is.
#[test]
fn min_nonzero_floor_counts_carrying_samples() {
    let grid = one_strength_grid();
    let node = cone_node(false, 4 * MIN_SAMPLES as usize);
    let carrying = node.iter().filter(|s| s.carries()).count() as u32;
    assert!(
        carrying > FLOOR && (carrying as usize) < node.len(),
        "{carrying}"
    );
    let choose = |floor: u32| {
        choose_node(
            &node,
            mean_shadow_rays(&node),
            &grid,
            TrainingCost::Path,
            1.0,
            floor,
            MisHeuristic::Power,
        )
        .guided
    };
    assert!(choose(carrying).is_some());
    assert_eq!(choose(carrying + 1), None);
}

/// Synthetic samples at a node with two lobes: lobe 0 (strength 64) aimed at a small cone
/// from which reflected radiance 10 arrives, lobe 1 (strength 8) aimed away from it, with
/// eq. 165-like proposal weights that favour lobe 1 (0.2, 0.8). At every fourth point
/// lobe 0 does not apply (its opening hidden): there the proposal is lobe 1 alone.
fn two_lobe_node(n: usize) -> Vec<Sample> {
    let toward = Vec3::new(0.3, 0.0, 0.95).normalize();
    let away = Vec3::new(-0.6, 0.5, 0.6).normalize();
    let (frames, strengths) = ([Frame::from_z(toward), Frame::from_z(away)], [64.0, 8.0]);
    let proposal = [0.2f32, 0.8];
    let lobe_pdf = |j: usize, w: Vec3| warp::power_cosine_pdf(frames[j].to_local(w), strengths[j]);
    let mut rng = Rng::new(23, 7);
    (0..n)
        .map(|i| {
            let active: u8 = if i % 4 == 3 { 0b10 } else { 0b11 };
            let weights = if active == 0b11 { proposal } else { [0.0, 1.0] };
            let p_skel = |w: Vec3| weights[0] * lobe_pdf(0, w) + weights[1] * lobe_pdf(1, w);
            let w = if rng.uniform() < TRAINING_C {
                let j = if rng.uniform() < weights[0] { 0 } else { 1 };
                frames[j].to_world(warp::power_cosine(rng.uniform2(), strengths[j]))
            } else {
                warp::cosine_hemisphere(rng.uniform2())
            };
            let f = if w.dot(toward) >= 0.99 && w.z > 0.0 {
                w.z / std::f32::consts::PI * 10.0
            } else {
                0.0
            };
            let mut p_lobes = [-1.0; MAX_LOBES];
            for j in 0..2 {
                if active & (1 << j) != 0 {
                    p_lobes[j] = lobe_pdf(j, w);
                }
            }
            Sample {
                node: 0,
                wi: w,
                class: 0,
                f_emitted: 0.0,
                f_reflected: f,
                p_bsdf: warp::cosine_hemisphere_pdf(w),
                p_skel: p_skel(w),
                p_strength: [p_skel(w); MAX_STRENGTHS],
                p_light: 0.0,
                nee: NeeTerms::default(),
                p_lobes,
                active,
                rays: 1,
                remaining: 1,
                step: NO_STEP,
            }
        })
        .collect()
}

/// The lobe mixture under explicit weights is the mixture the samples record when the
/// weights are the proposal's, renormalised over the lobes that apply at each point.
#[test]
fn lobe_weights_reproduce_the_recorded_mixture() {
    let samples = two_lobe_node(4000);
    let proposal = {
        let mut w = [0.0; MAX_LOBES];
        w[..2].copy_from_slice(&[0.2, 0.8]);
        w
    };
    let mut hidden = 0;
    for s in &samples {
        let p = lobe_mixture(&s.p_lobes, s.active, &proposal).unwrap();
        assert!(
            (p - s.p_skel).abs() <= 1e-5 * s.p_skel.max(1.0),
            "{p} {}",
            s.p_skel
        );
        for c in [0.1, 0.5, 0.9] {
            let (a, b) = (
                s.terms(c, 0, Some(&proposal), MisHeuristic::Power),
                s.terms(c, 0, None, MisHeuristic::Power),
            );
            assert!(
                (a.second - b.second).abs() <= 1e-4 * b.second.max(1e-9),
                "{a:?} {b:?}"
            );
        }
        // Lobe 0 alone: the points where it does not apply are not guided.
        let mut only0 = [0.0; MAX_LOBES];
        only0[0] = 1.0;
        if s.active & 1 == 0 {
            hidden += 1;
            assert_eq!(lobe_mixture(&s.p_lobes, s.active, &only0), None);
        }
    }
    assert_eq!(hidden, 1000);
}

/// With `lobe_weights=learned` the choice moves the selection probability onto the lobe
/// the radiance arrives through and guides the node, which with the proposal's (eq.
/// 165's) weights does not pay; the fit alone finds the same lobe.
#[test]
fn learned_lobe_weights_pick_the_lobe_that_carries_the_light() {
    let samples = two_lobe_node(40_000);
    let choose = |lobe_weights: bool| {
        let grid = Grid {
            lobe_weights,
            ..one_strength_grid()
        };
        choose_node(
            &samples,
            mean_shadow_rays(&samples),
            &grid,
            TrainingCost::Path,
            1.0,
            FLOOR,
            MisHeuristic::Power,
        )
    };
    let fixed = choose(false);
    let learned = choose(true);
    assert!(
        fixed.guided.is_none() && fixed.best_ratio > 0.95,
        "{fixed:?}"
    );
    let w = learned.weights.expect("weights learned");
    assert!(learned.guided.is_some(), "{learned:?}");
    assert!(w[0] > 0.9 && w[1] < 0.1, "{learned:?}");
    assert!(
        learned.relative_cost < 0.8 * fixed.best_ratio,
        "{learned:?}"
    );
    let fit = fit_lobe_weights(&samples, 2, MisHeuristic::Power);
    assert!(
        fit[0] > 0.9 && (fit[0] + fit[1] - 1.0).abs() < 1e-6,
        "{fit:?}"
    );
    assert!(fit[2..].iter().all(|&x| x == 0.0), "{fit:?}");
}

/// The candidates' moments summed with the shared work done once per sample
/// (`Sample::add_grid_terms`, which `choose_node` uses) are bit for bit those of
/// `Sample::terms` candidate by candidate, on random samples with zeros, light hits, light
/// samples and several strengths, under both heuristics.
#[test]
fn grid_terms_match_the_terms_one_by_one() {
    let mut rng = Rng::new(21, 7);
    let mut pick = |p_zero: f32| {
        if rng.uniform() < p_zero {
            0.0
        } else {
            rng.uniform() * 4.0
        }
    };
    let mut samples = Vec::new();
    for _ in 0..4000 {
        let mut p_strength = [0.0; MAX_STRENGTHS];
        let mut nee_strength = [0.0; MAX_STRENGTHS];
        for k in 0..MAX_STRENGTHS {
            p_strength[k] = pick(0.2);
            nee_strength[k] = pick(0.2);
        }
        let nee = NeeTerms {
            value: pick(0.5),
            p_light: pick(0.1),
            wi: Vec3::Z,
            p_bsdf: pick(0.2),
            p_skel: pick(0.2),
            p_strength: nee_strength,
            p_lobes: [0.0; MAX_LOBES],
        };
        samples.push(Sample {
            node: 0,
            wi: Vec3::Z,
            class: 0,
            f_emitted: pick(0.6),
            f_reflected: pick(0.5),
            p_bsdf: pick(0.1),
            p_skel: pick(0.2),
            p_strength,
            p_light: pick(0.5),
            nee,
            p_lobes: [0.0; MAX_LOBES],
            active: 1,
            rays: 0,
            remaining: 1,
            step: NO_STEP,
        });
    }
    let grid = Grid {
        strengths: STRENGTH_CANDIDATES.to_vec(),
        ..one_strength_grid()
    };
    for mis in [MisHeuristic::Balance, MisHeuristic::Power] {
        let mut shared = vec![Moments::default(); grid.len() + 1];
        let mut one_by_one = shared.clone();
        for s in &samples {
            s.add_grid_terms(&grid, mis, &mut shared);
            one_by_one[0].add(s.terms(0.0, 0, None, mis));
            for j in 0..grid.len() {
                let (c, k) = grid.at(j);
                one_by_one[j + 1].add(s.terms(c, k, None, mis));
            }
        }
        for (a, b) in shared.iter().zip(&one_by_one) {
            assert_eq!(a.second.to_bits(), b.second.to_bits(), "{mis:?}");
            assert_eq!(a.mean_direction.to_bits(), b.mean_direction.to_bits());
            assert_eq!(a.mean_nee.to_bits(), b.mean_nee.to_bits());
        }
        assert!(one_by_one.iter().all(|m| m.second > 0.0));
    }
}

/// `learn_directions` bins each sample once for its three fits (`directional::fit_binned`):
/// the distribution and the held-out densities are those of `directional::fit` run on each
/// half and on all the weighted samples with the earlier passes', bit for bit, over every
/// class and with zero, negative and non-finite earlier weights.
#[test]
fn learned_directions_are_the_fits_of_the_halves_and_of_all() {
    let mut samples = cone_node(true, 6_000);
    samples.extend(cone_node(false, 3_000));
    for (i, s) in samples.iter_mut().enumerate() {
        s.class = (i * 7 % directional::CLASSES) as u8;
    }
    let mut rng = Rng::new(5, 2);
    let earlier: Vec<Weighted> = (0..2_000)
        .map(|i| {
            let w = warp::uniform_sphere(rng.uniform2());
            let x = match i % 5 {
                0 => 0.0,
                1 => -1.0,
                2 if i % 25 == 2 => f64::NAN,
                _ => rng.uniform() as f64 * 3.0,
            };
            (i % directional::CLASSES, w, x)
        })
        .collect();
    let floor = directional::FLOOR;
    let mut fast = samples.clone();
    let (bins, weighted) = learn_directions(&mut fast, MisHeuristic::Power, &earlier, floor, true);
    let half = |parity: usize| {
        let part: Vec<Weighted> = earlier
            .iter()
            .copied()
            .chain(weighted.iter().copied().skip(parity).step_by(2))
            .collect();
        directional::fit(&part, floor)
    };
    let folds = DirectionalTable::new(&[Some(half(1)), Some(half(0))]);
    for (i, (s, f)) in samples.iter().zip(&fast).enumerate() {
        let slot = folds.slot((i % 2 == 1) as u32, s.class as usize).unwrap();
        assert_eq!(f.p_strength[0].to_bits(), folds.pdf(slot, s.wi).to_bits());
        assert_eq!(
            f.nee.p_strength[0].to_bits(),
            folds.pdf(slot, s.nee.wi).to_bits()
        );
    }
    let all: Vec<Weighted> = earlier.iter().chain(&weighted).copied().collect();
    let expected = directional::fit(&all, floor);
    assert!(bins
        .iter()
        .zip(&expected)
        .all(|(a, b)| a.to_bits() == b.to_bits()));
    assert!(weighted.iter().filter(|w| w.2 > 0.0).count() > 1_000);
}
