//! `path_skeleton:c_skel=learned` (issue 8, round 4) and `strength=learned` (round 5):
//!
//! - the training pass is deterministic: the same learned probabilities (and strengths, with
//!   `strength=learned`) for 1, 2 and 3 threads; the learned strength reaches the queries;
//! - a node whose learned probability is 0 sets up no lobe and traces no guide shadow ray;
//! - the learned probabilities guide some nodes of the corridor (where guiding wins) and not all;
//! - unbiasedness with the learned probabilities: the same image and region means as `path`
//!   within their measured error, no NaN.

mod common;

use common::agreement::{
    agree_on_corridor, agree_on_two_rooms, agree_on_veach_door, agree_with_path, box_scene,
    load_scene,
};
use lacuna::guide::{
    GuideQuery, SkeletonGuide, SkeletonGuideSettings, CANDIDATES, STRENGTH_CANDIDATES,
};
use lacuna::math::{warp, Rng, Vec3};
use lacuna::scene::{corridor_builder, Scene};

fn door() -> Scene {
    load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json")
}

fn corridor() -> Scene {
    corridor_builder().unwrap().build().unwrap()
}

/// The learned probability with portal lobes and visibility tested once per voxel (`G`, the
/// defaults of rounds 13-14), named.
fn learned() -> SkeletonGuideSettings {
    let mut s = SkeletonGuideSettings::default();
    for (key, value) in [
        ("directions", "lobes"),
        ("c_skel", "learned"),
        ("aim", "portal"),
        ("visibility", "voxel"),
    ] {
        s.set(key, value).unwrap();
    }
    s
}

/// Probability and strength learned together (round 5).
fn learned_both() -> SkeletonGuideSettings {
    let mut s = learned();
    s.set("strength", "learned").unwrap();
    s
}

fn build(scene: &Scene, settings: &SkeletonGuideSettings, threads: usize) -> SkeletonGuide {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(|| SkeletonGuide::build(scene, scene.camera(), settings, &|_, _| true).unwrap())
}

/// Random surface points (position, error, geometric normal, incident direction).
fn surface_points(scene: &Scene, count: usize, seed: u64) -> Vec<(Vec3, Vec3, Vec3, Vec3)> {
    let mut rng = Rng::new(seed, 3);
    let b = scene.bounds();
    let mut out = Vec::new();
    while out.len() < count {
        let u = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform());
        let o = b.min + (b.max - b.min) * u;
        let d = warp::uniform_sphere(rng.uniform2());
        if let Some(si) = scene.intersect(&lacuna::geometry::Ray::new(o, d, f32::INFINITY)) {
            out.push((si.p, si.p_error, si.ng, si.wo));
        }
    }
    out
}

#[test]
fn training_is_the_same_for_any_thread_count() {
    let scene = door();
    for settings in [learned(), learned_both()] {
        let one = build(&scene, &settings, 1);
        let t1 = one.training().expect("trained").clone();
        for threads in [2, 3] {
            let other = build(&scene, &settings, threads);
            assert_eq!(other.training(), Some(&t1), "{threads} threads");
        }
        assert!(t1.paths > 0);
        assert!(t1.samples.iter().sum::<u32>() > 10_000);
        for (k, &c) in t1.probabilities.iter().enumerate() {
            assert!(CANDIDATES.contains(&c), "node {k}: c {c}");
            assert_eq!(one.guiding_probability(k as u32), c);
            let s = t1.strengths[k];
            if settings.learned_strength {
                assert!(STRENGTH_CANDIDATES.contains(&s), "node {k}: strength {s}");
                assert_eq!(one.strength(k as u32), s);
            } else {
                assert_eq!(one.strength(k as u32), settings.strength);
            }
        }
    }
}

/// With the strength learned, a guided node's lobes carry its learned exponent (a fixed
/// strength gives every lobe that exponent) and the query's pdf is the one
/// `pdf_with_strength` gives for the node's strength.
#[test]
fn learned_strength_reaches_the_queries() {
    let scene = corridor();
    let guide = build(&scene, &learned_both(), 2);
    let t = guide.training().unwrap();
    assert!(t.guided_nodes() > 0);
    let mut rng = Rng::new(4, 4);
    let mut checked = 0;
    let mut query = GuideQuery::new();
    for (p, err, ng, wo) in surface_points(&scene, 20_000, 21) {
        query.init(&guide, &scene, p, err, ng, wo);
        let Some(node) = query.node() else { continue };
        if query.lobe_count() == 0 {
            continue;
        }
        let strength = guide.strength(node);
        assert_eq!(strength, t.strengths[node as usize]);
        if let lacuna::guide::SkeletonStrength::Fixed(s) = strength {
            for i in 0..query.lobe_count() {
                assert_eq!(query.lobe(i).unwrap().1, s, "node {node}");
            }
        }
        let w = warp::uniform_sphere(rng.uniform2());
        let (a, b) = (query.pdf(w), query.pdf_with_strength(w, strength));
        assert!(
            (a - b).abs() <= 1e-5 * a.max(b),
            "node {node}: {a} against {b}"
        );
        checked += 1;
    }
    assert!(checked > 1000, "{checked}");
}

/// Nodes with c = 0 set up no lobe and trace no shadow ray, where the fixed-c guide of the same
/// scene would; the other nodes behave as the fixed guide at their own c. Both test visibility
/// per point, so that each query's rays are its own (a voxel cache's are not).
#[test]
fn unguided_nodes_trace_no_guide_shadow_rays() {
    let scene = door();
    let mut per_point = learned();
    per_point.set("visibility", "true").unwrap();
    let learned = build(&scene, &per_point, 2);
    per_point.set("c_skel", "0.5").unwrap();
    let fixed = build(&scene, &per_point, 2);
    let (mut q_learned, mut q_fixed) = (GuideQuery::new(), GuideQuery::new());
    let (mut skipped_rays, mut guided) = (0u32, 0u32);
    for (p, err, ng, wo) in surface_points(&scene, 20_000, 9) {
        let rays_l = q_learned.init(&learned, &scene, p, err, ng, wo);
        let rays_f = q_fixed.init(&fixed, &scene, p, err, ng, wo);
        // Where the learned guide skipped the mapping, the point's node is not guided.
        let Some(node) = q_learned.node() else {
            if let Some(node) = q_fixed.node() {
                assert_eq!(learned.guiding_probability(node), 0.0, "node {node}");
                assert_eq!(rays_l, 0);
                skipped_rays += rays_f;
            }
            continue;
        };
        assert_eq!(Some(node), q_fixed.node());
        let c = learned.guiding_probability(node);
        if c == 0.0 {
            assert_eq!(rays_l, 0, "node {node}");
            assert_eq!(q_learned.lobe_count(), 0);
            assert_eq!(q_learned.guiding_probability(), 0.0);
            skipped_rays += rays_f;
        } else {
            assert_eq!(rays_l, rays_f);
            assert_eq!(q_learned.lobe_count(), q_fixed.lobe_count());
            let expected = if q_fixed.lobe_count() > 0 { c } else { 0.0 };
            assert_eq!(q_learned.guiding_probability(), expected);
            guided += (q_learned.lobe_count() > 0) as u32;
        }
    }
    // Not vacuous: the fixed guide traced rays at the learned-unguided nodes.
    assert!(skipped_rays > 1000, "{skipped_rays}");
    println!("door: {guided} guided points, {skipped_rays} shadow rays saved");
}

/// In the corridor (the light far from the camera, guiding's best case) training keeps guiding
/// at some nodes; not at every one.
#[test]
fn training_guides_some_corridor_nodes() {
    let scene = corridor();
    let guide = build(&scene, &learned(), 2);
    let t = guide.training().unwrap();
    let guided = t.guided_nodes();
    assert!(guided > 0 && guided < guide.node_count(), "{guided} guided");
    for (k, &c) in t.probabilities.iter().enumerate() {
        if c > 0.0 {
            assert!(t.relative_cost[k] < 1.0, "node {k}: {}", t.relative_cost[k]);
            assert!(!guide.lobes(k as u32).is_empty());
        }
    }
    // Without a camera there is nothing to learn from: the fixed c_skel and strength.
    let (no_camera, _) = box_scene(false, true, false);
    assert!(no_camera.camera().is_none());
    let settings = learned_both();
    let g = build(&no_camera, &settings, 2);
    assert_eq!(g.training().unwrap().paths, 0);
    for k in 0..g.node_count() as u32 {
        assert_eq!(g.guiding_probability(k), settings.c_skel);
        assert_eq!(g.strength(k), settings.strength);
    }
}

/// The specs z-tested against `path`: the learned c with the lobes (the learned directions,
/// the default, in tests/guide_directions.rs).
// `cost_model=vertices`: the learned choices themselves, whether or not the default
// scene-level switch (`cost_model=paths`) would keep them at these scenes.
const SPECS: &[&str] = &[
    "path_skeleton:c_skel=learned:directions=lobes:cost_model=vertices",
    "path_skeleton:c_skel=learned:strength=64:directions=lobes:cost_model=vertices",
    "path_skeleton:c_skel=learned:strength=learned:cost_model=vertices",
];

#[test]
fn learned_agrees_with_path_on_the_corridor() {
    agree_on_corridor(SPECS);
}

#[test]
fn learned_agrees_with_path_on_the_two_rooms() {
    agree_on_two_rooms(SPECS);
}

#[test]
fn learned_agrees_with_path_on_the_veach_door() {
    agree_on_veach_door(SPECS);
}

/// Glossy, mirror and glass surfaces: the training pass walks through delta vertices without
/// recording them; no NaN (checked per pixel by `region_means`).
#[test]
fn learned_agrees_with_path_on_glossy_mirror_and_glass() {
    let (scene, camera) = box_scene(true, true, false);
    agree_with_path("glossy+delta bsdfs", &scene, &camera, 6, 20, 16, SPECS);
}

/// The scout check (`SkeletonGuide::build_with_scout_check`, `path_skeleton`'s pilot on the
/// scout's guide): where it says no, the training ends after the scout and nothing is guided;
/// where it says yes, the full training learns exactly what it learns without the check, even
/// though the check used the guide with the scout's choices (its queries fill the voxel
/// visibility cache, whose fills the training counts as the guide's shadow rays).
#[test]
fn the_scout_check_stops_the_training_or_leaves_it_as_it_was() {
    let scene = corridor();
    let mut settings = learned();
    settings.set("training_paths", "16384").unwrap();
    assert!(settings.scouts());
    let camera = scene.camera();
    let plain = SkeletonGuide::build(&scene, camera, &settings, &|_, _| true).unwrap();
    let full = plain.training().unwrap();
    assert_eq!(full.paths, 16384);
    assert!(!plain.guides_nothing());

    let checks = std::cell::Cell::new(0);
    let look = |scout: &SkeletonGuide| {
        checks.set(checks.get() + 1);
        let t = scout.training().expect("the scout's choices adopted");
        assert_eq!(t.paths, 16384 / 8);
        assert!(!scout.guides_nothing());
        let mut query = GuideQuery::new();
        let rays: u32 = surface_points(&scene, 5_000, 4)
            .into_iter()
            .map(|(p, err, ng, wo)| query.init(scout, &scene, p, err, ng, wo))
            .sum();
        assert!(rays > 0, "the check's queries traced no shadow ray");
        true
    };
    let looked =
        SkeletonGuide::build_with_scout_check(&scene, camera, &settings, &|_, _| true, Some(&look))
            .unwrap();
    assert_eq!(checks.get(), 1);
    assert_eq!(looked.training(), Some(full));
    for node in 0..plain.node_count() as u32 {
        assert_eq!(
            looked.guiding_probability(node),
            plain.guiding_probability(node)
        );
    }

    let stopped = SkeletonGuide::build_with_scout_check(
        &scene,
        camera,
        &settings,
        &|_, _| true,
        Some(&|_: &SkeletonGuide| false),
    )
    .unwrap();
    let t = stopped.training().unwrap();
    assert_eq!(t.paths, 16384 / 8);
    assert!(t.scene.switched_off);
    assert!(stopped.guides_nothing());
}
