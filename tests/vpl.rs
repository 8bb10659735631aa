//! `vpl` (instant radiosity): unbiased with compensation or without clamping, image and
//! region means agreeing with `path` within their measured error on diffuse scenes (and, with
//! compensation, on a box of glossy, mirror and glass surfaces under delta lights); clamped
//! without compensation, finite and measurably darker; no NaN; the same image for any thread
//! count; its options refused when wrong, and the bias stated. With skeleton visibility (000
//! chapter 8): its agreement with exact shadow rays over VPL / shading point pairs on the door
//! and the two rooms, measured and bounded below; no NaN; the same image for any thread count;
//! the memory budget lowering the maps' resolution. With importance-driven VPL selection (the
//! default): the compensated estimator agreeing with `path` on the Cornell box, the door and
//! the two rooms; the same image for any thread count; its options checked. With interleaved
//! sampling (`interleave=N`): `interleave=1` today's images bit for bit; the region means of
//! `path` kept; the same image for any thread count; the option checked and the bias stated.

mod common;

use common::agreement::{
    agree_with_path, assert_agree, box_scene, load_scene, region_means, render_image,
};
use lacuna::integrator::{self, Integrator, IntegratorSettings, View, VplIntegrator};
use lacuna::render::RenderSettings;
use lacuna::scene::{Camera, Scene};

/// No clamping (the plain VPL estimator, unbiased where there is no delta surface), a clamp
/// with compensation, a large clamp with few VPLs, so that the compensation carries most
/// of the indirect light, and the compensated estimator with importance-driven selection
/// (Russian roulette on the VPLs' light at the camera's probe points, unbiased by its 1 / p
/// weights; a large `p_min` too, where most weights are small, and a small one).
const UNBIASED: &[&str] = &[
    "vpl:clamp=0:count=16:select=uniform",
    "vpl:clamp=0.1:compensate=true:count=16:select=uniform",
    "vpl:clamp=0.5:compensate=true:count=4:select=uniform",
    "vpl:clamp=0.1:compensate=true:count=16:select=importance:candidates=8:p_min=0.02",
    "vpl:clamp=0.1:compensate=true:count=16:select=importance:candidates=2:p_min=0.3",
    "vpl:clamp=0.1:compensate=true:count=16:light_samples=4",
];

#[test]
fn vpl_agrees_with_path_on_the_cornell_box() {
    let scene = load_scene("scenes/cornell-box/cornell-box.json");
    let camera = *scene.camera().unwrap();
    agree_with_path("cornell", &scene, &camera, 5, 16, 16, UNBIASED);
}

#[test]
fn vpl_agrees_with_path_on_the_two_rooms() {
    let scene = lacuna::scene::two_rooms_builder().unwrap().build().unwrap();
    let camera = *scene.camera().unwrap();
    agree_with_path("two rooms", &scene, &camera, 6, 16, 16, UNBIASED);
}

#[test]
fn vpl_agrees_with_path_on_the_veach_door() {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    let camera = *scene.camera().unwrap();
    agree_with_path("veach door", &scene, &camera, 6, 16, 16, UNBIASED);
}

/// Interleaved sampling (N x N VPL sets per pass, the indirect light filtered over N x N
/// blocks of similar pixels): biased by its blur, but on these diffuse scenes, whose walls
/// are flat regions of constant normal and depth, the region means of the compensated
/// estimator stay those of `path` within their measured error (the filter keeps the mean of
/// what it averages), with both selections.
#[test]
fn interleaved_vpl_keeps_the_region_means_of_path() {
    let specs = [
        "vpl:clamp=0.1:compensate=true:count=16:interleave=2",
        "vpl:clamp=0.1:compensate=true:count=16:interleave=4",
        "vpl:clamp=0.1:compensate=true:count=16:interleave=3:select=uniform",
    ];
    let scene = load_scene("scenes/cornell-box/cornell-box.json");
    let camera = *scene.camera().unwrap();
    agree_with_path("cornell", &scene, &camera, 5, 16, 16, &specs);
    let scene = lacuna::scene::two_rooms_builder().unwrap().build().unwrap();
    let camera = *scene.camera().unwrap();
    agree_with_path("two rooms", &scene, &camera, 6, 16, 16, &specs);
}

/// Delta surfaces (mirror, glass) and delta lights: only the compensated estimator covers the
/// light that reaches a non-delta surface through a delta one.
#[test]
fn compensated_vpl_agrees_with_path_with_delta_surfaces_and_lights() {
    let (scene, camera) = box_scene(true, true, true);
    agree_with_path(
        "box",
        &scene,
        &camera,
        4,
        16,
        16,
        &["vpl:clamp=0.1:compensate=true:count=16"],
    );
}

/// Clamped without compensation: every pixel finite, and the image darker than `path`'s by
/// more than their measured error (the bias is real, and the test could see it vanish).
#[test]
fn clamped_vpl_is_finite_and_darker() {
    let scene = load_scene("scenes/cornell-box/cornell-box.json");
    let camera = *scene.camera().unwrap();
    let settings = IntegratorSettings {
        max_depth: 5,
        ..Default::default()
    };
    // region_means asserts that every pixel is finite and non-negative.
    let path = region_means(&scene, &camera, "path", settings, 16, 64, 8);
    let clamped = region_means(&scene, &camera, "vpl:clamp=1:count=16", settings, 16, 64, 8);
    let ((mp, ep), (mc, ec)) = (path[0], clamped[0]);
    assert!(
        mc < mp - 4.5 * (ep * ep + ec * ec).sqrt(),
        "clamped {mc} +- {ec} against path {mp} +- {ep}"
    );
    // The same estimator compensated is back at path's.
    let compensated = region_means(
        &scene,
        &camera,
        "vpl:clamp=1:count=16:compensate=true",
        settings,
        16,
        64,
        8,
    );
    assert_agree("cornell", ("path", &path), ("compensated", &compensated));
}

#[test]
fn vpl_gives_the_same_image_for_any_thread_count() {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    let camera = *scene.camera().unwrap();
    let s = IntegratorSettings {
        max_depth: 6,
        ..Default::default()
    };
    for spec in [
        "vpl:count=8:select=uniform",
        "vpl:count=8:compensate=true",
        "vpl:count=8:visibility=skeleton:shadow_res=16",
        "vpl:count=8:visibility=skeleton:shadow_res=16:verify=0",
        "vpl:count=8:visibility=skeleton:shadow_res=16:verify=0.5:compensate=true",
        "vpl:count=8:select=importance:candidates=4",
        "vpl:count=8:select=importance:candidates=4:visibility=skeleton:shadow_res=16:compensate=true",
        "vpl:count=8:interleave=3",
        "vpl:count=4:interleave=4:select=uniform:compensate=true",
        "vpl:count=4:interleave=2:visibility=skeleton:shadow_res=16:compensate=true",
        "vpl:count=8:visibility=skeleton:shadow_res=16:sites=8",
        "vpl:count=8:visibility=skeleton:shadow_res=16:sites=4:verify=0",
        "vpl:count=8:visibility=skeleton:shadow_res=16:sites=8:probe_maps=true",
        "vpl:count=4:interleave=2:visibility=skeleton:shadow_res=16:probe_maps=true",
    ] {
        // A fresh integrator per render (one integrator rendering again: the next test).
        let render = |threads| {
            let mut vpl = integrator::create(spec, s).unwrap();
            lacuna::render::prepare(vpl.as_mut(), &scene, &camera, Some(2), &|_, _| true)
                .unwrap();
            let rs = RenderSettings {
                width: 20,
                height: 20,
                spp: 3,
                seed: 5,
                threads: Some(threads),
                ..Default::default()
            };
            render_image(&scene, &camera, vpl.as_ref(), &rs)
        };
        let one = render(1);
        let a = one.radiance();
        assert!(a.iter().all(|p| p.is_finite() && p.min_element() >= 0.0));
        assert!(a.iter().any(|p| p.max_element() > 0.0), "{spec}: black");
        assert_eq!(a, render(2).radiance(), "{spec}");
        assert_eq!(a, render(3).radiance(), "{spec}");
    }
}

/// Skeleton visibility keeps the shadow maps of earlier passes and renders; the image must
/// not depend on them: one prepared integrator renders the same image again after a render
/// of another size, seed and sample count (which builds other node and receiver maps).
#[test]
fn skeleton_vpl_renders_the_same_image_again_on_one_integrator() {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    let camera = *scene.camera().unwrap();
    let s = IntegratorSettings {
        max_depth: 6,
        ..Default::default()
    };
    for spec in [
        "vpl:count=8:visibility=skeleton:shadow_res=16",
        "vpl:count=8:visibility=skeleton:shadow_res=16:verify=0.5:compensate=true",
        "vpl:count=4:interleave=2:visibility=skeleton:shadow_res=16",
        "vpl:count=8:visibility=skeleton:shadow_res=16:sites=8",
    ] {
        let mut vpl = integrator::create(spec, s).unwrap();
        lacuna::render::prepare(vpl.as_mut(), &scene, &camera, Some(2), &|_, _| true).unwrap();
        let settings = |width, height, spp, seed| RenderSettings {
            width,
            height,
            spp,
            seed,
            threads: Some(2),
            ..Default::default()
        };
        let first = render_image(&scene, &camera, vpl.as_ref(), &settings(20, 20, 3, 5));
        let a = first.radiance();
        assert!(a.iter().any(|p| p.max_element() > 0.0), "{spec}: black");
        render_image(&scene, &camera, vpl.as_ref(), &settings(48, 36, 6, 9));
        let again = render_image(&scene, &camera, vpl.as_ref(), &settings(20, 20, 3, 5));
        assert_eq!(a, again.radiance(), "{spec}");
    }
}

#[test]
fn vpl_options_are_checked_and_the_bias_stated() {
    let s = IntegratorSettings::default();
    for bad in [
        "vpl:count=0",
        "vpl:count=x",
        "vpl:clamp=-1",
        "vpl:clamp=nan",
        "vpl:compensate=maybe",
        "vpl:visibility=clusters",
        "vpl:visibility=sometimes",
        "vpl:shadow_res=2",
        "vpl:shadow_res=x",
        "vpl:shadow_res=100000",
        "vpl:shadow_budget_mb=0",
        "vpl:shadow_budget_mb=-1",
        "vpl:resolutions=4",
        "vpl:visibility=skeleton:verify=2",
        "vpl:visibility=skeleton:verify=-0.1",
        "vpl:visibility=skeleton:verify=yes",
        "vpl:visibility=skeleton:sites=65",
        "vpl:visibility=skeleton:sites=-1",
        "vpl:select=best",
        "vpl:select=importance:candidates=0",
        "vpl:select=importance:candidates=1000",
        "vpl:select=importance:candidates=x",
        "vpl:select=importance:p_min=0",
        "vpl:select=importance:p_min=1.5",
        "vpl:select=importance:p_min=nan",
        "vpl:select=importance:probes=0",
        "vpl:select=importance:probes=x",
        "vpl:visibility=skeleton:probe_maps=maybe",
        "vpl:interleave=0",
        "vpl:interleave=9",
        "vpl:interleave=x",
        "vpl:light_samples=0",
        "vpl:light_samples=65",
        "vpl:light_samples=x",
    ] {
        let err = integrator::create(bad, s).err().expect(bad).to_string();
        assert!(
            err.contains("vpl") || err.contains("option"),
            "{bad}: {err}"
        );
    }
    let (name, parsed) =
        integrator::parse_spec("vpl:count=128:clamp=0.05:compensate=true", s).unwrap();
    assert_eq!(name, "vpl");
    assert_eq!(
        (parsed.vpl.count, parsed.vpl.clamp, parsed.vpl.compensate),
        (128, 0.05, true)
    );
    let bias = |spec: &str| integrator::create(spec, s).unwrap().bias();
    assert!(bias("vpl").is_some_and(|b| b.contains("clamped")));
    assert!(bias("vpl:clamp=0").is_some_and(|b| b.contains("delta")));
    assert_eq!(bias("vpl:compensate=true"), None);
    assert!(bias("vpl:compensate=true:visibility=skeleton").is_some_and(|b| b.contains("skeleton")));
    // The skeleton guide's own check of the skeleton's resolution.
    assert!(integrator::create("vpl:visibility=skeleton:resolution=2", s).is_err());
    let (_, parsed) = integrator::parse_spec(
        "vpl:visibility=skeleton:shadow_res=32:shadow_budget_mb=8:resolution=48",
        s,
    )
    .unwrap();
    assert_eq!(
        (parsed.vpl.shadow_res, parsed.vpl.shadow_budget_mb),
        (32, 8)
    );
    let (_, parsed) = integrator::parse_spec("vpl:visibility=skeleton:verify=0.5", s).unwrap();
    assert_eq!(parsed.vpl.verify, 0.5);
    let (_, parsed) =
        integrator::parse_spec("vpl:select=importance:candidates=4:p_min=0.1", s).unwrap();
    assert_eq!(
        (parsed.vpl.select, parsed.vpl.candidates, parsed.vpl.p_min),
        (lacuna::integrator::VplSelect::Importance, 4, 0.1)
    );
    // Importance selection is the default and adds no bias of its own.
    assert_eq!(
        integrator::parse_spec("vpl", s).unwrap().1.vpl.select,
        lacuna::integrator::VplSelect::Importance
    );
    assert_eq!(bias("vpl:compensate=true:select=uniform"), None);
    // Interleaved sampling's filter blurs: biased whatever the estimator.
    assert_eq!(
        integrator::parse_spec("vpl:interleave=4", s)
            .unwrap()
            .1
            .vpl
            .interleave,
        4
    );
    assert!(bias("vpl:compensate=true:interleave=2").is_some_and(|b| b.contains("interleave=2")));
    assert!(bias("vpl:interleave=3")
        .is_some_and(|b| b.contains("interleave=3") && b.contains("clamped")));
    assert_eq!(bias("vpl:compensate=true:interleave=1"), None);
    // `lacuna compare` (and the CLI, scene files and the C API, through the same parser).
    let contender = lacuna::compare::Contender::from_spec(
        "vpl:interleave=2:compensate=true:sampler=independent",
        s,
    )
    .unwrap();
    assert!(contender
        .integrator
        .bias()
        .is_some_and(|b| b.contains("interleave=2")));
    assert!(lacuna::compare::Contender::from_spec("vpl:interleave=9", s).is_err());
    // The refusal of clusters points to the measured reason.
    let err = integrator::create("vpl:visibility=clusters", s)
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("docs/vpl-visibility.md"), "{err}");
    assert_eq!(bias("path"), None);
}

/// `vpl:visibility=skeleton` prepared for `scene`, and the precomputation's notes.
fn prepared_skeleton_vpl(scene: &Scene, camera: &Camera, spec: &str) -> (VplIntegrator, String) {
    let (_, settings) = integrator::parse_spec(spec, IntegratorSettings::default()).unwrap();
    let mut vpl = VplIntegrator::new(settings).unwrap();
    let pre = lacuna::render::prepare(&mut vpl, scene, camera, None, &|_, _| true).unwrap();
    (vpl, pre.notes.join("; "))
}

/// Skeleton visibility against exact shadow rays over every pair of a VPL (of two passes of
/// 64 light subpaths) and a pixel's first surface point (48x36 pixels), among the pairs with
/// a non-zero unshadowed term: the rate of agreement (V_f > 1/2 against the ray's verdict),
/// printed, and the balanced rate (the mean of the rates over visible and over occluded
/// pairs), which must stay near what was measured and above 1/2 by a margin: any constant
/// map (all visible, all occluded) scores 1/2 and fails. The causes of the differences and
/// the light's error are printed; the error must stay low, and several times below that of
/// the maps alone (`verify=0`).
#[test]
fn skeleton_visibility_agrees_with_exact_rays_on_the_door_and_two_rooms() {
    let scenes = [
        (
            "veach door",
            load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json"),
            MEASURED_DOOR,
        ),
        (
            "two rooms",
            lacuna::scene::two_rooms_builder().unwrap().build().unwrap(),
            MEASURED_TWO_ROOMS,
        ),
    ];
    for (label, scene, measured) in scenes {
        let camera = *scene.camera().unwrap();
        let (vpl, notes) =
            prepared_skeleton_vpl(&scene, &camera, "vpl:visibility=skeleton:select=uniform");
        assert!(notes.contains("skeleton shadow maps"), "{label}: {notes}");
        let view = View {
            frame: camera.frame(48.0 / 36.0),
            width: 48,
            height: 36,
            sampler: Default::default(),
        };
        for pass in 0..2 {
            let a = vpl.visibility_agreement(&scene, &view, 1, pass).unwrap();
            println!(
                "{label}, pass {pass}: {} of {} pairs agree ({:.4}; a constant map {:.4}); \
                 {} of {} visible pairs; balanced rate {:.4}; mean |V_f - V| {:.4}; \
                 {} of {} VPLs on mapped nodes",
                a.agreeing,
                a.pairs,
                a.rate(),
                a.constant_rate(),
                a.visible_agreeing,
                a.visible,
                a.balanced_rate(),
                a.mean_abs_difference,
                a.mapped_vpls,
                a.vpls
            );
            let share = |b: [f64; 2]| {
                format!(
                    "+{:.3} -{:.3}",
                    b[0] / a.light.max(1e-30),
                    b[1] / a.light.max(1e-30)
                )
            };
            println!(
                "{label}, pass {pass}: disagreements by cause: map {}, unseen node {}, \
                 parallax {} ({} of {} VPLs unseen by their node; {} pairs by exact rays); \
                 light error relative to the exact light: map {}, unseen node {}, parallax {}; \
                 net bias {:+.3}, mean error at most {:.3}",
                a.map_errors,
                a.unseen_errors,
                a.parallax_errors,
                a.unseen_vpls,
                a.mapped_vpls,
                a.exact_rays,
                share(a.map_bias),
                share(a.unseen_bias),
                share(a.parallax_bias),
                a.relative_bias(),
                a.relative_error_bound()
            );
            println!(
                "{label}, pass {pass}: chapter 7 clusters: {} pairs share the VPL's node, {} of \
                 them visible; every pair of a cluster lit adds {:.3} of the exact light at \
                 the occluded ones; {:.3} of the exact light is between different nodes (the \
                 gates' share)",
                a.same_node_pairs,
                a.same_node_visible,
                a.same_node_excess / a.light.max(1e-30),
                a.other_node_light / a.light.max(1e-30)
            );
            assert!(a.pairs > 10_000, "{label}: {a:?}");
            assert!(a.mapped_vpls * 10 > a.vpls * 9, "{label}: {a:?}");
            assert!(a.balanced_rate() >= measured - 0.05, "{label}: {a:?}");
            assert!(a.balanced_rate() >= 0.6, "{label}: {a:?}");
            // The light's error (measured 0.09-0.14 of the exact light) and the rays spent.
            assert!(a.relative_error_bound() < 0.25, "{label}: {a:?}");
            assert!(a.exact_rays * 2 < a.pairs, "{label}: {a:?}");
            // The maps alone (eq. 159 as the thesis has it) err several times as much
            // (measured 0.79-0.88 of the exact light).
            let (maps_alone, _) = prepared_skeleton_vpl(
                &scene,
                &camera,
                "vpl:visibility=skeleton:verify=0:select=uniform",
            );
            let b = maps_alone
                .visibility_agreement(&scene, &view, 1, pass)
                .unwrap();
            println!(
                "{label}, pass {pass}, verify=0: balanced rate {:.4}, light error at most {:.3}, net bias {:+.3}",
                b.balanced_rate(),
                b.relative_error_bound(),
                b.relative_bias()
            );
            assert_eq!(b.exact_rays, 0, "{label}: {b:?}");
            assert!(
                b.relative_error_bound() > 3.0 * a.relative_error_bound(),
                "{label}: {b:?} against {a:?}"
            );
        }
        let notes = vpl.render_notes().join("; ");
        assert!(notes.contains("receiver maps"), "{label}: {notes}");
    }
}

/// Map sites (`sites=K`) against node maps: the same pairs as the test above (door and two
/// rooms, two passes), the maps alone (`verify=0`) and verified (default `verify`), printed
/// with the disagreements split into visible pairs called occluded and occluded pairs
/// called visible, and the light's error by cause. Maps near their VPLs must cut the
/// parallax part of the error (the node's view standing in for the VPL's) of the maps
/// alone.
#[test]
fn map_sites_cut_the_parallax_error_of_node_maps() {
    let scenes = [
        (
            "veach door",
            load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json"),
        ),
        (
            "two rooms",
            lacuna::scene::two_rooms_builder().unwrap().build().unwrap(),
        ),
    ];
    for (label, scene) in scenes {
        let camera = *scene.camera().unwrap();
        let view = View {
            frame: camera.frame(48.0 / 36.0),
            width: 48,
            height: 36,
            sampler: Default::default(),
        };
        for verify in ["0", "0.25"] {
            let mut parallax = Vec::new();
            for sites in [0, 4, 8, 16] {
                let spec =
                    format!("vpl:visibility=skeleton:select=uniform:verify={verify}:sites={sites}");
                let (vpl, _) = prepared_skeleton_vpl(&scene, &camera, &spec);
                let mut error = 0.0;
                for pass in 0..2 {
                    let a = vpl.visibility_agreement(&scene, &view, 1, pass).unwrap();
                    let occluded = a.pairs - a.visible;
                    let called_visible = (a.agreeing - a.visible_agreeing).abs_diff(occluded);
                    let share = |b: [f64; 2]| {
                        format!(
                            "+{:.3} -{:.3}",
                            b[0] / a.light.max(1e-30),
                            b[1] / a.light.max(1e-30)
                        )
                    };
                    println!(
                        "{label}, verify={verify}, sites={sites}, pass {pass}: balanced rate {:.4}; \
                         visible called occluded {} of {} ({:.3}), occluded called visible {} of {} \
                         ({:.4}); {} pairs by rays; {} of {} VPLs unseen by their map; light error: \
                         map {}, unseen {}, parallax {}; net {:+.3}, mean at most {:.3}",
                        a.balanced_rate(),
                        a.visible - a.visible_agreeing,
                        a.visible,
                        (a.visible - a.visible_agreeing) as f64 / a.visible.max(1) as f64,
                        called_visible,
                        occluded,
                        called_visible as f64 / occluded.max(1) as f64,
                        a.exact_rays,
                        a.unseen_vpls,
                        a.mapped_vpls,
                        share(a.map_bias),
                        share(a.unseen_bias),
                        share(a.parallax_bias),
                        a.relative_bias(),
                        a.relative_error_bound()
                    );
                    assert!(a.pairs > 10_000, "{label}: {a:?}");
                    assert!(
                        a.mapped_vpls * 10 > a.vpls * 9,
                        "{label} sites={sites}: {a:?}"
                    );
                    error += (a.parallax_bias[0] + a.parallax_bias[1]) / a.light;
                }
                parallax.push(error / 2.0);
                println!(
                    "{label}, verify={verify}, sites={sites}: notes {}",
                    vpl.render_notes().join("; ")
                );
            }
            println!(
                "{label}, verify={verify}: parallax error for sites 0, 4, 8, 16: {parallax:.3?}"
            );
            // Measured (2026-12-07): door 0.43 -> 0.05, 0.08 (maps alone), 0.09 -> 0.007,
            // 0.011 (verified); two rooms 0.34 -> 0.03, 0.11 and 0.07 -> 0.004, 0.008.
            assert!(parallax[1] < 0.25 * parallax[0], "{label}: {parallax:?}");
            assert!(parallax[2] < 0.5 * parallax[0], "{label}: {parallax:?}");
        }
    }
}

/// A lazy map (texels traced as lookups read them, the map sites') reads as the map built
/// whole: the same PCF visibility at every surface point of a spread of rays through the two
/// rooms, with fewer texels traced than the map holds.
#[test]
fn lazy_shadow_maps_read_as_built_ones() {
    use lacuna::geometry::Ray;
    use lacuna::integrator::CubeShadowMap;
    use lacuna::math::Vec3;
    let scene = lacuna::scene::two_rooms_builder().unwrap().build().unwrap();
    let centre = Vec3::new(2.5, 1.25, 2.0);
    let built = CubeShadowMap::build(&scene, centre, 32);
    let lazy = CubeShadowMap::lazy(centre, 32);
    assert_eq!(lazy.traced_texels(), 0);
    let (mut points, mut lit, mut between) = (0, 0, 0);
    // Rays from two origins along a Fibonacci sphere of directions.
    for origin in [Vec3::new(1.0, 1.0, 1.0), Vec3::new(3.0, 1.5, -2.0)] {
        for k in 0..300 {
            let z = 1.0 - (k as f32 + 0.5) / 150.0;
            let phi = k as f32 * 2.399_963;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let dir = Vec3::new(r * phi.cos(), z, r * phi.sin());
            let Some(si) = scene.intersect(&Ray::new(origin, dir, f32::INFINITY)) else {
                continue;
            };
            let facing = if si.ng.dot(dir) < 0.0 { si.ng } else { -si.ng };
            let v = lazy.visibility(&scene, si.p, facing);
            assert_eq!(v, built.visibility(&scene, si.p, facing), "{:?}", si.p);
            points += 1;
            lit += usize::from(v == 1.0);
            between += usize::from(v > 0.0 && v < 1.0);
        }
    }
    let texels = 6 * 32 * 32;
    println!(
        "{points} points, {lit} lit, {between} on an edge; {} of {texels} texels traced",
        lazy.traced_texels()
    );
    assert!(points > 400 && lit > points / 10 && lit < points * 9 / 10);
    assert!(lazy.traced_texels() > 0 && lazy.traced_texels() < texels);
    assert_eq!(built.traced_texels(), 0);
}

/// The balanced agreement rates the test above measured with the default `verify` (the
/// two-sided test and shadow rays for the pairs the maps are unsure of; 2026-12-06, the
/// lower pass); the maps alone (`verify=0`) measured 0.73 and 0.78.
const MEASURED_DOOR: f64 = 0.86;
const MEASURED_TWO_ROOMS: f64 = 0.92;

/// A budget too small for every node at the asked resolution lowers it (and says so); the
/// image stays finite and lit.
#[test]
fn the_shadow_map_budget_lowers_the_resolution() {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    let camera = *scene.camera().unwrap();
    let (vpl, notes) = prepared_skeleton_vpl(
        &scene,
        &camera,
        "vpl:visibility=skeleton:shadow_res=256:shadow_budget_mb=1:count=8",
    );
    assert!(notes.contains("lowered from 256"), "{notes}");
    let rs = RenderSettings {
        width: 16,
        height: 16,
        spp: 2,
        ..Default::default()
    };
    let image = render_image(&scene, &camera, &vpl, &rs);
    let a = image.radiance();
    assert!(a.iter().all(|p| p.is_finite() && p.min_element() >= 0.0));
    assert!(a.iter().any(|p| p.max_element() > 0.0));
    let stats = vpl.render_notes().join("; ");
    assert!(
        stats.contains("node maps") && stats.contains("traced when first read"),
        "{stats}"
    );
}

/// `interleave=1` (one VPL set per pass, no filter) is today's estimator bit for bit: the
/// images of the door and the two rooms pinned to the bits the estimator gave before
/// interleaved sampling existed (exact and skeleton visibility, importance selection,
/// compensation), and `interleave=1` spelled out gives the same image as the default.
#[test]
fn vpl_interleave_1_is_the_plain_estimator_bit_for_bit() {
    let door = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    let rooms = lacuna::scene::two_rooms_builder().unwrap().build().unwrap();
    let s = IntegratorSettings {
        max_depth: 6,
        ..Default::default()
    };
    let cases: [(&str, &Scene, &str, [u64; 2]); 4] = [
        ("door", &door, "vpl:count=8:select=uniform", PINNED[0]),
        ("door", &door, "vpl:count=8:compensate=true", PINNED[1]),
        (
            "door",
            &door,
            "vpl:count=8:visibility=skeleton:shadow_res=16",
            PINNED[2],
        ),
        ("two rooms", &rooms, "vpl:count=8", PINNED[3]),
    ];
    for (label, scene, spec, pinned) in cases {
        let camera = *scene.camera().unwrap();
        let rs = RenderSettings {
            width: 16,
            height: 12,
            spp: 2,
            seed: 3,
            threads: Some(2),
            ..Default::default()
        };
        let mut images = Vec::new();
        for spec in [spec.to_string(), format!("{spec}:interleave=1")] {
            let mut vpl = integrator::create(&spec, s).unwrap();
            lacuna::render::prepare(vpl.as_mut(), scene, &camera, Some(2), &|_, _| true).unwrap();
            images.push(render_image(scene, &camera, vpl.as_ref(), &rs).radiance());
        }
        assert_eq!(images[0], images[1], "{label} {spec}");
        // The image's sum in a fixed order, and one lit pixel's red channel, as bits.
        let sum: f64 = images[0]
            .iter()
            .map(|p| f64::from(p.x) + f64::from(p.y) + f64::from(p.z))
            .sum();
        let brightest = images[0].iter().map(|p| p.x).fold(0.0f32, f32::max);
        let bits = [sum.to_bits(), u64::from(brightest.to_bits())];
        println!("{label} {spec}: {bits:?}");
        assert_eq!(bits, pinned, "{label} {spec}");
    }
}

/// The bits of the image sum and of the brightest red channel of the cases above, rendered
/// at commit 00310c1 (before `interleave`).
const PINNED: [[u64; 2]; 4] = [
    [4639324784082223104, 1090671824],
    [4644189091871890433, 1091517287],
    [4649966687905973525, 1092805763],
    [4630327761721245696, 1075715876],
];
