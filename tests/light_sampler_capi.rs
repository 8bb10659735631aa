//! Light sampling through the C entry points (`lacuna_light_sampler_*`), tested against its own
//! densities by chi-square over the sphere of directions (tests/common/directions.rs):
//!
//! - next-event samples at a shading point (emissive triangles by area and by solid angle, with
//!   the environment map under each of its strategies, including the per-normal cube-face
//!   balancing, and under a transmissive query): the directions drawn by
//!   `lacuna_light_sampler_sample` against the density `lacuna_light_sampler_eval` gives them
//!   (environment plus the emitter the direction's ray hits, found by `lacuna_scene_intersect`);
//! - delta lights (point, spot, directional): the lights are picked in proportion to the
//!   selection probabilities the sampler reports (chi-square on the counts), with the delta
//!   flag, pdf = selection probability and the radiance intensity / d^2 (times the spot's
//!   falloff) or the irradiance;
//! - emission: directions of `lacuna_light_sampler_sample_emission` against
//!   `lacuna_light_sampler_emission_pdf` weighted by the selection probabilities (area, point,
//!   spot and environment lights), and the origin's density for a directional light;
//! - a batch gives the single calls' results, and no call allocates (a counting allocator).

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use common::chi2::assert_chi2;
use common::directions::{chi2_directions, to32};
use common::sphere::SphereGrid;
use lacuna::capi::*;
use lacuna::math::{Rng, Vec3};

/// Counts allocations, to prove the light-sampling calls make none.
struct Counting;
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);
// SAFETY: forwards to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: forwarded contract.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded contract.
        unsafe { System.dealloc(ptr, layout) }
    }
}
#[global_allocator]
static GLOBAL: Counting = Counting;

fn ok(s: lacuna_status) {
    assert_eq!(s, lacuna_status::Ok, "{:?}", unsafe {
        std::ffi::CStr::from_ptr(lacuna_last_error_message())
    });
}

fn v(x: f32, y: f32, z: f32) -> lacuna_vec3 {
    lacuna_vec3 { x, y, z }
}

fn c(r: f32, g: f32, b: f32) -> lacuna_rgb {
    lacuna_rgb { r, g, b }
}

/// What the test scenes hold besides nothing.
#[derive(Clone, Copy, Default)]
struct Contents {
    lamp: bool,
    environment: bool,
    point: bool,
    spot: bool,
    directional: bool,
}

/// A scene through the C API: an emissive quad at y = 1 facing down (two triangles), a point
/// light, a spot light pointing down, a directional light and a lat-long map with a bright
/// spot, as `contents` says.
fn scene(contents: Contents) -> *mut lacuna_scene {
    unsafe {
        let mut ctx = std::ptr::null_mut();
        ok(lacuna_context_new(&mut ctx));
        let mut b = std::ptr::null_mut();
        ok(lacuna_scene_builder_new(ctx, &mut b));
        if contents.lamp {
            let mut lamp = 0;
            ok(lacuna_scene_builder_add_material(b, 0, &mut lamp));
            ok(lacuna_scene_builder_set_material_rgb(
                b,
                lamp,
                2,
                c(3.0, 2.0, 1.0),
            ));
            let p: [f32; 12] = [
                -0.5, 1.0, -0.3, 0.5, 1.0, -0.3, 0.5, 1.0, 0.3, -0.5, 1.0, 0.3,
            ];
            let idx: [u32; 6] = [0, 1, 2, 0, 2, 3];
            let mut m = std::ptr::null_mut();
            ok(lacuna_mesh_new(&mut m));
            ok(lacuna_mesh_set_positions(m, p.as_ptr(), 0, 4));
            ok(lacuna_mesh_set_indices(m, idx.as_ptr(), 0, 2));
            ok(lacuna_mesh_set_material(m, lamp));
            let mut index = 0;
            ok(lacuna_scene_builder_add_mesh(b, m, &mut index));
            lacuna_mesh_free(m);
        }
        if contents.point {
            ok(lacuna_scene_builder_add_point_light(
                b,
                v(0.4, 0.6, 0.0),
                c(1.0, 1.0, 1.0),
            ));
        }
        if contents.spot {
            ok(lacuna_scene_builder_add_spot_light(
                b,
                v(-0.2, 0.9, 0.1),
                v(0.1, -1.0, 0.0),
                c(2.0, 1.0, 1.0),
                25.0,
                40.0,
            ));
        }
        if contents.directional {
            ok(lacuna_scene_builder_add_directional_light(
                b,
                v(0.3, -1.0, 0.2),
                c(0.5, 0.5, 0.5),
            ));
        }
        if contents.environment {
            let (w, h) = (32usize, 16usize);
            let mut texels = vec![0.0f32; w * h * 3];
            for y in 0..h {
                for x in 0..w {
                    let bright = if (x as i32 - 20).abs() < 3 && (y as i32 - 4).abs() < 2 {
                        40.0
                    } else {
                        0.2 + 0.05 * (x % 5) as f32
                    };
                    for k in 0..3 {
                        texels[(y * w + x) * 3 + k] = bright * (1.0 + 0.2 * k as f32);
                    }
                }
            }
            let mut env = std::ptr::null_mut();
            ok(lacuna_environment_new_from_buffer(
                texels.as_ptr(),
                w,
                h,
                0,
                0,
                0,
                &mut env,
            ));
            ok(lacuna_scene_builder_set_environment(b, env));
            lacuna_environment_free(env);
        }
        let mut s = std::ptr::null_mut();
        ok(lacuna_scene_builder_build(b, &mut s));
        lacuna_context_release(ctx);
        s
    }
}

fn sampler(scene: *const lacuna_scene, triangles: u32, env: u32) -> *mut lacuna_light_sampler {
    let mut s = std::ptr::null_mut();
    ok(unsafe { lacuna_light_sampler_new(scene, triangles, env, &mut s) });
    s
}

fn query(position: Vec3, normal: Vec3, flags: u32, u: [f32; 2]) -> lacuna_light_query {
    lacuna_light_query {
        position: position.to_array(),
        flags,
        normal: normal.to_array(),
        u,
    }
}

/// The density of light sampling for direction `w` from `q`: the environment's, plus that of
/// the emitter `w`'s ray hits.
fn direction_pdf(
    scene: *const lacuna_scene,
    ls: *const lacuna_light_sampler,
    q: &lacuna_light_query,
    w: Vec3,
) -> f64 {
    let mut info = lacuna_light_sampler_info::default();
    ok(unsafe { lacuna_light_sampler_get_info(ls, &mut info) });
    let mut pdf = 0.0;
    let mut eval = lacuna_light_eval::default();
    if info.environment_light != LACUNA_INVALID_INDEX {
        let hit = lacuna_light_hit {
            light: info.environment_light,
            direction: w.to_array(),
            distance: f32::INFINITY,
        };
        ok(unsafe { lacuna_light_sampler_eval(ls, q, &hit, &mut eval) });
        pdf += eval.pdf as f64;
    }
    let ray = lacuna_ray {
        origin: q.position,
        tmax: f32::INFINITY,
        direction: w.to_array(),
        flags: 0,
    };
    let mut h = unsafe { std::mem::zeroed::<lacuna_hit>() };
    ok(unsafe { lacuna_scene_intersect(scene, &ray, &mut h) });
    if h.triangle != LACUNA_INVALID_INDEX {
        let mut light = 0;
        ok(unsafe { lacuna_light_sampler_get_triangle_light(ls, h.triangle, &mut light) });
        let hit = lacuna_light_hit {
            light,
            direction: w.to_array(),
            distance: h.t,
        };
        ok(unsafe { lacuna_light_sampler_eval(ls, q, &hit, &mut eval) });
        pdf += eval.pdf as f64;
    }
    pdf
}

/// Chi-square of next-event directions against `eval`'s densities for one sampler and query.
fn check_directions(
    name: &str,
    scene: *const lacuna_scene,
    ls: *const lacuna_light_sampler,
    q: lacuna_light_query,
) {
    let grid = SphereGrid::uniform(24, 48);
    let integral = chi2_directions(
        name,
        &grid,
        Rng::new(7, name.len() as u64),
        |rng| {
            let u = rng.uniform2();
            let mut q = q;
            q.u = [u.x, u.y];
            let mut s = unsafe { std::mem::zeroed::<lacuna_light_sample>() };
            ok(unsafe { lacuna_light_sampler_sample(ls, &q, &mut s) });
            (s.light != LACUNA_INVALID_INDEX).then(|| Vec3::from(s.direction))
        },
        |w| direction_pdf(scene, ls, &q, w),
    );
    assert!(integral > 0.5, "{name}: the pdf integrates to {integral}");
}

#[test]
fn next_event_directions_follow_their_pdf_for_every_strategy() {
    let s = scene(Contents {
        lamp: true,
        environment: true,
        ..Default::default()
    });
    let below = Vec3::new(0.1, 0.2, 0.05);
    let tilted = Vec3::new(0.3, 1.0, -0.2).normalize();
    for (tri_name, tri) in [("area", 0u32), ("solid_angle", 1)] {
        for (env_name, env) in [
            ("latlong", 0u32),
            ("cube-uniform", 1),
            ("cube-power", 2),
            ("cube-dynamic", 3),
        ] {
            let ls = sampler(s, tri, env);
            let name = format!("triangles={tri_name} env={env_name}");
            check_directions(&name, s, ls, query(below, tilted, 0, [0.0; 2]));
            if env == 3 {
                // The transmissive hint and an unknown normal turn per-normal balancing off;
                // sampling and eval must agree either way.
                check_directions(
                    &format!("{name} transmissive"),
                    s,
                    ls,
                    query(below, tilted, LACUNA_LIGHT_QUERY_TRANSMISSIVE, [0.0; 2]),
                );
                check_directions(
                    &format!("{name} no normal"),
                    s,
                    ls,
                    query(below, Vec3::ZERO, 0, [0.0; 2]),
                );
            }
            unsafe { lacuna_light_sampler_release(ls) };
        }
    }
    unsafe { lacuna_scene_release(s) };
}

#[test]
fn delta_lights_are_picked_by_their_selection_probability_with_exact_radiance() {
    let s = scene(Contents {
        lamp: true,
        point: true,
        spot: true,
        directional: true,
        ..Default::default()
    });
    let ls = sampler(s, 0, 3);
    let mut info = lacuna_light_sampler_info::default();
    ok(unsafe { lacuna_light_sampler_get_info(ls, &mut info) });
    assert_eq!(info.light_count, 5);
    let pmf: Vec<f64> = (0..info.light_count)
        .map(|i| {
            let mut li = lacuna_light_info::default();
            ok(unsafe { lacuna_light_sampler_get_light_info(ls, i, &mut li) });
            li.selection_probability as f64
        })
        .collect();
    // Straight below the spot, inside its inner cone: every light gives a sample.
    let p = Vec3::new(-0.3, 0.0, 0.1);
    let n = 100_000;
    let mut counts = vec![0u64; pmf.len()];
    let mut rng = Rng::new(3, 1);
    for _ in 0..n {
        let u = rng.uniform2();
        let q = query(p, Vec3::Y, 0, [u.x, u.y]);
        let mut smp = unsafe { std::mem::zeroed::<lacuna_light_sample>() };
        ok(unsafe { lacuna_light_sampler_sample(ls, &q, &mut smp) });
        assert_ne!(smp.light, LACUNA_INVALID_INDEX);
        counts[smp.light as usize] += 1;
        assert_eq!(smp.selection_probability as f64, pmf[smp.light as usize]);
        let delta = smp.flags & LACUNA_LIGHT_SAMPLE_DELTA != 0;
        assert_eq!(delta, smp.light >= 2, "light {}", smp.light);
        if !delta {
            continue;
        }
        assert_eq!(smp.pdf, smp.selection_probability);
        let r = smp.radiance.r;
        let expected = match smp.light {
            2 => 1.0 / (Vec3::new(0.4, 0.6, 0.0) - p).length_squared(),
            // Inside the inner cone: the full intensity.
            3 => 2.0 / (Vec3::new(-0.2, 0.9, 0.1) - p).length_squared(),
            _ => 0.5,
        };
        assert!(
            (r - expected).abs() <= 1e-4 * expected,
            "light {}: radiance {r}, expected {expected}",
            smp.light
        );
    }
    let expected: Vec<f64> = pmf.iter().map(|p| p * n as f64).collect();
    assert_chi2("light selection", &counts, &expected);
    unsafe {
        lacuna_light_sampler_release(ls);
        lacuna_scene_release(s);
    }
}

#[test]
fn emitted_directions_follow_their_pdf_for_every_light_kind() {
    for (name, contents) in [
        (
            "area",
            Contents {
                lamp: true,
                ..Default::default()
            },
        ),
        (
            "point",
            Contents {
                point: true,
                ..Default::default()
            },
        ),
        (
            "spot",
            Contents {
                spot: true,
                ..Default::default()
            },
        ),
        (
            "environment",
            Contents {
                environment: true,
                ..Default::default()
            },
        ),
        (
            "all",
            Contents {
                lamp: true,
                point: true,
                spot: true,
                environment: true,
                ..Default::default()
            },
        ),
    ] {
        let s = scene(contents);
        let ls = sampler(s, 0, 3);
        let mut info = lacuna_light_sampler_info::default();
        ok(unsafe { lacuna_light_sampler_get_info(ls, &mut info) });
        let grid = SphereGrid::uniform(24, 48);
        chi2_directions(
            &format!("emission {name}"),
            &grid,
            Rng::new(11, name.len() as u64),
            |rng| {
                let (a, b) = (rng.uniform2(), rng.uniform2());
                let u = [a.x, a.y, b.x, b.y];
                let mut e = unsafe { std::mem::zeroed::<lacuna_emission_sample>() };
                ok(unsafe { lacuna_light_sampler_sample_emission(ls, u.as_ptr(), &mut e) });
                (e.light != LACUNA_INVALID_INDEX).then(|| Vec3::from(e.direction))
            },
            |w| {
                (0..info.light_count)
                    .map(|i| {
                        let mut li = lacuna_light_info::default();
                        ok(unsafe { lacuna_light_sampler_get_light_info(ls, i, &mut li) });
                        let (mut pp, mut pd) = (0.0, 0.0);
                        ok(unsafe {
                            lacuna_light_sampler_emission_pdf(
                                ls,
                                i,
                                v(w.x, w.y, w.z),
                                &mut pp,
                                &mut pd,
                            )
                        });
                        li.selection_probability as f64 * pd as f64
                    })
                    .sum()
            },
        );
        unsafe {
            lacuna_light_sampler_release(ls);
            lacuna_scene_release(s);
        }
    }
    // A directional light: one direction, origins uniform on the disk of the bounding sphere.
    let s = scene(Contents {
        lamp: true,
        directional: true,
        ..Default::default()
    });
    let ls = sampler(s, 0, 3);
    for k in 0..64 {
        let u = [0.999, (k as f32 + 0.5) / 64.0, 0.3, 0.7];
        let mut e = unsafe { std::mem::zeroed::<lacuna_emission_sample>() };
        ok(unsafe { lacuna_light_sampler_sample_emission(ls, u.as_ptr(), &mut e) });
        if e.light == 2 {
            assert_eq!(
                e.flags,
                LACUNA_EMISSION_DELTA_DIRECTION | LACUNA_EMISSION_INFINITE
            );
            assert_eq!(e.pdf_direction, 1.0);
            let dir = Vec3::from(e.direction);
            assert!((dir - Vec3::new(0.3, -1.0, 0.2).normalize()).length() < 1e-5);
            let (mut pp, mut pd) = (0.0, 0.0);
            ok(unsafe {
                lacuna_light_sampler_emission_pdf(ls, 2, v(dir.x, dir.y, dir.z), &mut pp, &mut pd)
            });
            assert_eq!((pp, pd), (e.pdf_position, e.pdf_direction));
        }
    }
    unsafe {
        lacuna_light_sampler_release(ls);
        lacuna_scene_release(s);
    }
}

#[test]
fn calls_do_not_allocate_and_batches_match_single_calls() {
    let s = scene(Contents {
        lamp: true,
        environment: true,
        point: true,
        spot: true,
        directional: true,
    });
    let ls = sampler(s, 1, 3);
    const N: usize = 256;
    let mut rng = Rng::new(5, 5);
    let queries: Vec<lacuna_light_query> = (0..N)
        .map(|_| {
            let u = rng.uniform2();
            query(Vec3::new(-0.3, 0.0, 0.1), Vec3::Y, 0, [u.x, u.y])
        })
        .collect();
    let hits: Vec<lacuna_light_hit> = (0..N)
        .map(|i| lacuna_light_hit {
            light: if i % 2 == 0 { 0 } else { 5 },
            direction: to32(glam::DVec3::new(0.01 * i as f64, 1.0, 0.0)).to_array(),
            distance: 1.0,
        })
        .collect();
    let us: Vec<[f32; 4]> = (0..N)
        .map(|_| {
            let (a, b) = (rng.uniform2(), rng.uniform2());
            [a.x, a.y, b.x, b.y]
        })
        .collect();
    let mut batch = vec![unsafe { std::mem::zeroed::<lacuna_light_sample>() }; N];
    let mut single = batch.clone();
    let mut evals = vec![lacuna_light_eval::default(); N];
    let mut evals1 = evals.clone();
    let mut em = vec![unsafe { std::mem::zeroed::<lacuna_emission_sample>() }; N];
    let mut em1 = em.clone();

    let before = ALLOCATIONS.load(Ordering::SeqCst);
    for i in 0..N {
        ok(unsafe { lacuna_light_sampler_sample(ls, &queries[i], &mut single[i]) });
        ok(unsafe { lacuna_light_sampler_eval(ls, &queries[i], &hits[i], &mut evals1[i]) });
        ok(unsafe { lacuna_light_sampler_sample_emission(ls, us[i].as_ptr(), &mut em1[i]) });
    }
    ok(unsafe {
        lacuna_light_sampler_sample_batch(ls, queries.as_ptr(), 0, N, batch.as_mut_ptr(), 0)
    });
    ok(unsafe {
        lacuna_light_sampler_eval_batch(
            ls,
            queries.as_ptr(),
            0,
            hits.as_ptr(),
            0,
            N,
            evals.as_mut_ptr(),
            0,
        )
    });
    ok(unsafe {
        lacuna_light_sampler_sample_emission_batch(ls, us.as_ptr().cast(), 0, N, em.as_mut_ptr(), 0)
    });
    let after = ALLOCATIONS.load(Ordering::SeqCst);
    // Other tests of this binary may allocate on their threads meanwhile: allow a little, far
    // below one allocation per call (6 x 256 calls).
    assert!(
        after - before < 16,
        "{} allocations during {} light-sampling calls",
        after - before,
        6 * N
    );
    assert_eq!(batch, single);
    assert_eq!(evals, evals1);
    assert_eq!(em, em1);
    unsafe {
        lacuna_light_sampler_release(ls);
        lacuna_scene_release(s);
    }
}
