//! Correctness of light sampling (see docs/testing.md, "Sampling routines"):
//!
//! - area lights sampled by area: points are uniform on the triangle (chi-square over K^2
//!   congruent sub-triangles); `pdf_with(receiver, point, Area)` equals the sample's pdf and the
//!   closed form d^2 / (cos A);
//! - area lights sampled by solid angle (the default of next-event estimation): points are
//!   uniform in solid angle (chi-square over the same sub-triangles, each expected in proportion
//!   to the solid angle it subtends) for near, oblique, far and grazing receivers; the pdf is
//!   1 / solid angle and equals `pdf()`; no NaN and points on the triangle at scales 1e-4..1e4,
//!   for slivers, tiny and huge triangles;
//! - both strategies: E[1 / pdf] over light samples is the triangle's solid angle (closed
//!   form); the solid-angle pdf integrates to 1 over the sphere of directions (Monte Carlo with
//!   ray casting, uniform over the sphere and over a cone around the triangle); receivers behind
//!   or in the plane of the light get no sample;
//! - point, spot and directional lights: radiance, falloff and power;
//! - the light sampler picks lights in proportion to their power (chi-square on counts), and
//!   `sample_reuse` makes the same choices with the same pmf and a rescaled number uniform on
//!   [0, 1) given the choice (chi-square on the joint counts).

mod common;

use common::chi2::{assert_chi2, assert_z, Stats};
use glam::DVec3;
use lacuna::geometry::{intersect_triangle, Bounds3, RayPrecomp};
use lacuna::light::triangle::{self, spherical_solid_angle};
use lacuna::light::{EnvStrategy, Light, LightDesc, LightSample, LightSampler, TriangleSampling};
use lacuna::math::{luminance, warp, Frame, Rgb, Rng, Vec2, Vec3, PI};

fn to64(v: Vec3) -> DVec3 {
    DVec3::new(v.x as f64, v.y as f64, v.z as f64)
}

fn area_light(p: [Vec3; 3], radiance: Rgb) -> Light {
    let c = (p[1] - p[0]).cross(p[2] - p[0]);
    Light::Area {
        triangle: 0,
        p,
        normal: c.normalize(),
        area: 0.5 * c.length(),
        radiance,
    }
}

fn triangles() -> Vec<(&'static str, [Vec3; 3])> {
    vec![
        (
            "unit",
            [
                Vec3::ZERO,
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
            ],
        ),
        (
            "tilted",
            [
                Vec3::new(1.0, 2.0, 3.0),
                Vec3::new(2.5, 1.7, 3.4),
                Vec3::new(0.8, 3.1, 4.2),
            ],
        ),
        (
            "sliver",
            [
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(10.0, 0.0, 0.0),
                Vec3::new(10.0, 0.05, 0.01),
            ],
        ),
        (
            "far from origin",
            [
                Vec3::new(1000.0, 1000.0, 1000.0),
                Vec3::new(1001.0, 1000.5, 1000.0),
                Vec3::new(1000.2, 1001.0, 1000.3),
            ],
        ),
    ]
}

fn centroid(p: &[Vec3; 3]) -> Vec3 {
    (p[0] + p[1] + p[2]) / 3.0
}

const STRATEGIES: [TriangleSampling; 2] = [TriangleSampling::SolidAngle, TriangleSampling::Area];

fn sample(light: &Light, receiver: Vec3, by: TriangleSampling, u: Vec2) -> Option<LightSample> {
    light.sample_with(receiver, Vec3::ZERO, EnvStrategy::default(), by, u)
}

fn geometry(light: &Light) -> ([Vec3; 3], Vec3, f32) {
    match *light {
        Light::Area {
            p, normal, area, ..
        } => (p, normal, area),
        _ => unreachable!(),
    }
}

/// Receivers in front of triangle `p`: on the normal, oblique, very close and far.
fn receivers(p: &[Vec3; 3], normal: Vec3) -> Vec<(&'static str, Vec3)> {
    let c = centroid(p);
    let scale = (p[1] - p[0]).length().max((p[2] - p[0]).length());
    let side = (p[1] - p[0]).normalize();
    vec![
        ("on the normal", c + normal * scale),
        ("oblique", c + (normal * 0.3 + side * 0.8) * scale),
        ("close", c + normal * (0.02 * scale)),
        ("far", c + (normal * 30.0 - side * 10.0) * scale),
    ]
}

/// Barycentric coordinates (of p1, p2) of `x`, projected onto the triangle's plane.
fn barycentric(p: &[Vec3; 3], x: Vec3) -> (f64, f64) {
    let (p0, e1, e2) = (to64(p[0]), to64(p[1] - p[0]), to64(p[2] - p[0]));
    let d = to64(x) - p0;
    let (a, b, c) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (r1, r2) = (d.dot(e1), d.dot(e2));
    let det = a * c - b * b;
    ((c * r1 - b * r2) / det, (a * r2 - b * r1) / det)
}

/// Solid angle of triangle `p` seen from `o` (Van Oosterom and Strackee 1983).
fn solid_angle(p: &[Vec3; 3], o: Vec3) -> f64 {
    solid_angle64([to64(p[0]), to64(p[1]), to64(p[2])], to64(o))
}

fn solid_angle64(p: [DVec3; 3], o: DVec3) -> f64 {
    let (a, b, c) = (p[0] - o, p[1] - o, p[2] - o);
    let (la, lb, lc) = (a.length(), b.length(), c.length());
    let num = a.dot(b.cross(c)).abs();
    let den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
    2.0 * num.atan2(den)
}

/// Index of the sub-triangle containing barycentrics (b1, b2) when the triangle is cut into
/// k^2 congruent triangles by lines parallel to its edges; `None` outside the triangle.
fn sub_triangle(b1: f64, b2: f64, k: usize) -> Option<usize> {
    // Points far from the origin carry an f32 rounding of ~1e-4 of the triangle's size.
    let eps = 1e-3;
    if b1 < -eps || b2 < -eps || b1 + b2 > 1.0 + eps {
        return None;
    }
    let kf = k as f64;
    let i = ((b1 * kf).floor().max(0.0) as usize).min(k - 1);
    let j = ((b2 * kf).floor().max(0.0) as usize).min(k - 1 - i);
    let (fi, fj) = (b1 * kf - i as f64, b2 * kf - j as f64);
    // Cell (i, j) holds an upward triangle and, when i + j <= k - 2, a downward one.
    let down = fi + fj > 1.0 && i + j + 2 <= k;
    Some(2 * (i * k + j) + down as usize)
}

#[test]
fn area_light_samples_are_uniform_on_the_triangle() {
    let k = 16;
    let n = 200_000;
    for (t, (name, p)) in triangles().into_iter().enumerate() {
        let light = area_light(p, Rgb::new(1.0, 2.0, 3.0));
        let (_, normal, area) = geometry(&light);
        let receiver = centroid(&p) + normal * 2.0;
        let mut counts = vec![0u64; 2 * k * k];
        let mut rng = Rng::new(40 + t as u64, 1);
        for _ in 0..n {
            let s = sample(&light, receiver, TriangleSampling::Area, rng.uniform2())
                .expect("a receiver in front always gets a sample");
            assert!(!s.delta);
            assert_eq!(s.radiance, Rgb::new(1.0, 2.0, 3.0));
            assert!((s.wi.length() - 1.0).abs() < 1e-5);
            let d = to64(s.point) - to64(receiver);
            assert!((d.length() - s.distance as f64).abs() < 1e-5 * d.length());
            assert!((to64(s.wi) - d.normalize()).length() < 1e-5);
            // The pdf agrees with pdf() and with the closed form d^2 / (cos A).
            let closed = d.length_squared() / ((-d.normalize()).dot(to64(normal)) * area as f64);
            let pdf = light.pdf_with(receiver, s.point, TriangleSampling::Area);
            assert!(
                ((s.pdf as f64 - closed) / closed).abs() < 1e-4
                    && ((pdf - s.pdf) / s.pdf).abs() < 1e-5,
                "{name}: sample pdf {} pdf() {pdf} closed form {closed}",
                s.pdf
            );
            // On the triangle's plane, inside it.
            let off_plane = (to64(s.point) - to64(p[0])).dot(to64(normal));
            assert!(off_plane.abs() < 1e-4 * (1.0 + to64(p[0]).length()));
            let (b1, b2) = barycentric(&p, s.point);
            let cell = sub_triangle(b1, b2, k)
                .unwrap_or_else(|| panic!("{name}: point {} outside the triangle", s.point));
            counts[cell] += 1;
        }
        // Only the k^2 existing cells: upward (i + j <= k - 1) and downward (i + j <= k - 2).
        let mut observed = Vec::new();
        for i in 0..k {
            for j in 0..k - i {
                observed.push(counts[2 * (i * k + j)]);
                if i + j + 2 <= k {
                    observed.push(counts[2 * (i * k + j) + 1]);
                }
            }
        }
        assert_eq!(observed.len(), k * k);
        assert_eq!(observed.iter().sum::<u64>(), n);
        let expected = vec![n as f64 / (k * k) as f64; k * k];
        assert_chi2(
            &format!("area light {name}: barycentric cells"),
            &observed,
            &expected,
        );
    }
}

/// E[1 / pdf] under light sampling is the solid angle of the light (closed form): a direct
/// test of the pdf's normalization with little variance.
#[test]
fn area_light_inverse_pdf_mean_is_the_solid_angle() {
    let n = 100_000;
    for (t, (name, p)) in triangles().into_iter().enumerate() {
        let light = area_light(p, Rgb::ONE);
        let (_, normal, _) = geometry(&light);
        for (r, (where_, receiver)) in receivers(&p, normal).into_iter().enumerate() {
            for by in STRATEGIES {
                let mut stats = Stats::default();
                let mut rng = Rng::new(100 + t as u64, r as u64);
                for _ in 0..n {
                    let s = sample(&light, receiver, by, rng.uniform2()).unwrap();
                    stats.add(1.0 / s.pdf as f64);
                }
                let omega = solid_angle(&p, receiver);
                // The f32 pdf has a relative error ~1e-6 that the estimate cannot beat.
                let se = (stats.std_err().powi(2) + (2e-6 * omega).powi(2)).sqrt();
                assert_z(
                    &format!(
                        "area light {name}, receiver {where_}, {by:?}: E[1/pdf] vs solid angle"
                    ),
                    stats.mean(),
                    omega,
                    se,
                );
            }
        }
    }
}

/// pdf(receiver, hit point) integrated over all directions is 1. Directions are drawn
/// uniformly on the sphere (receivers where the light is large) or uniformly in a cone
/// around the triangle, and cast against it.
#[test]
fn area_light_pdf_integrates_to_one_over_directions() {
    let n = 200_000;
    for (t, (name, p)) in triangles().into_iter().enumerate() {
        let light = area_light(p, Rgb::ONE);
        let (_, normal, _) = geometry(&light);
        for (r, (where_, receiver)) in receivers(&p, normal).into_iter().enumerate() {
            let axis = (centroid(&p) - receiver).normalize();
            let frame = Frame::from_z(axis);
            let cos_max = p
                .iter()
                .map(|&v| (v - receiver).normalize().dot(axis))
                .fold(1.0f32, f32::min)
                - 1e-4;
            let omega = solid_angle(&p, receiver);
            // Uniform sphere sampling only where the light covers a useful part of it.
            let use_sphere = omega > 0.3;
            for by in STRATEGIES {
                let mut stats = Stats::default();
                let mut rng = Rng::new(200 + t as u64, r as u64);
                for _ in 0..n {
                    let (dir, pdf_dir) = if use_sphere {
                        (
                            warp::uniform_sphere(rng.uniform2()),
                            warp::uniform_sphere_pdf(),
                        )
                    } else {
                        let local = warp::uniform_cone(rng.uniform2(), cos_max);
                        (
                            frame.to_world(local),
                            warp::uniform_cone_pdf(local, cos_max),
                        )
                    };
                    let ray = RayPrecomp::new(receiver, dir);
                    let value = match intersect_triangle(&ray, p[0], p[1], p[2], f32::INFINITY) {
                        Some(h) => {
                            let point = p[0] * (1.0 - h.b1 - h.b2) + p[1] * h.b1 + p[2] * h.b2;
                            light.pdf_with(receiver, point, by) as f64 / pdf_dir as f64
                        }
                        None => 0.0,
                    };
                    stats.add(value);
                }
                assert_z(
                    &format!(
                        "area light {name}, receiver {where_}, {by:?} ({}): integral of the pdf",
                        if use_sphere { "sphere" } else { "cone" }
                    ),
                    stats.mean(),
                    1.0,
                    stats.std_err(),
                );
            }
        }
    }
}

#[test]
fn area_light_gives_nothing_behind_or_in_its_plane() {
    let mut rng = Rng::new(3, 3);
    for (name, p) in triangles() {
        let light = area_light(p, Rgb::ONE);
        let (_, normal, _) = geometry(&light);
        let c = centroid(&p);
        let side = (p[1] - p[0]).normalize();
        for receiver in [c - normal, c - normal * 1e-3 + side * 5.0] {
            for _ in 0..1000 {
                let u = rng.uniform2();
                let b = warp::uniform_triangle(u);
                let point = p[0] * b.0 + p[1] * b.1 + p[2] * (1.0 - b.0 - b.1);
                for by in STRATEGIES {
                    let s = sample(&light, receiver, by, u);
                    assert!(s.is_none(), "{name}: receiver {receiver} got {s:?}");
                    assert_eq!(light.pdf_with(receiver, point, by), 0.0);
                }
            }
        }
        // Receivers in the light's plane (to rounding): whatever side rounding puts them
        // on, `pdf` agrees with `sample`, and is not huge where `sample` gives nothing.
        for receiver in [c + side * 50.0, p[0] - (p[1] - p[0]), c + side * 1e-3] {
            for _ in 0..1000 {
                let u = rng.uniform2();
                let b = warp::uniform_triangle(u);
                let point = p[0] * b.0 + p[1] * b.1 + p[2] * (1.0 - b.0 - b.1);
                // In the plane the solid angle is ~0, so both strategies sample by area.
                assert_eq!(spherical_solid_angle(&p, normal, receiver), None);
                for by in STRATEGIES {
                    let pdf = light.pdf_with(receiver, point, by);
                    match sample(&light, receiver, by, u) {
                        None => assert_eq!(pdf, 0.0, "{name}: receiver {receiver}"),
                        Some(s) => assert!(
                            s.point == point && s.pdf == pdf,
                            "{name}: receiver {receiver}: sample {s:?}, pdf() {pdf}"
                        ),
                    }
                }
            }
        }
        // Emission only from the front.
        assert_eq!(light.emitted(normal), Rgb::ONE);
        assert_eq!(light.emitted(-normal), Rgb::ZERO);
    }
}

#[test]
fn point_light_radiance_is_intensity_over_distance_squared() {
    let intensity = Rgb::new(2.0, 3.0, 5.0);
    let position = Vec3::new(1.0, -2.0, 0.5);
    let bounds = Bounds3::EMPTY
        .union_point(Vec3::splat(-10.0))
        .union_point(Vec3::splat(10.0));
    let light = Light::from_desc(
        &LightDesc::Point {
            position,
            intensity,
        },
        &bounds,
    );
    assert!(light.is_delta());
    assert!((light.power() - 4.0 * PI * luminance(intensity)).abs() < 1e-4 * light.power());
    let mut rng = Rng::new(8, 8);
    for _ in 0..1000 {
        let dir = warp::uniform_sphere(rng.uniform2());
        let d = 0.01 + 100.0 * rng.uniform();
        let receiver = position + dir * d;
        let s = light.sample(receiver, rng.uniform2()).unwrap();
        assert!(s.delta && s.pdf == 1.0);
        assert!((s.wi + dir).length() < 1e-4, "wi {} vs {}", s.wi, -dir);
        assert!((s.distance - d).abs() < 1e-4 * d);
        assert_eq!(s.point, position);
        let expected = intensity / (d * d);
        assert!(
            ((s.radiance - expected) / expected).abs().max_element() < 1e-4,
            "radiance {} vs {expected}",
            s.radiance
        );
        assert_eq!(light.pdf(receiver, position), 0.0);
    }
    // At the light itself there is nothing to sample.
    assert!(light.sample(position, Vec2::splat(0.5)).is_none());
}

#[test]
fn spot_light_falloff_and_power() {
    let intensity = Rgb::new(4.0, 4.0, 4.0);
    let position = Vec3::new(0.0, 0.0, 3.0);
    let direction = Vec3::new(0.3, -0.2, -1.0);
    let bounds = Bounds3::EMPTY
        .union_point(Vec3::splat(-10.0))
        .union_point(Vec3::splat(10.0));
    for (inner, outer) in [(20.0f32, 35.0f32), (30.0, 30.0), (0.0, 60.0), (80.0, 120.0)] {
        let light = Light::from_desc(
            &LightDesc::Spot {
                position,
                direction,
                intensity,
                inner_degrees: inner,
                outer_degrees: outer,
            },
            &bounds,
        );
        let axis = direction.normalize();
        let frame = Frame::from_z(axis);
        // Falloff at angle t (degrees) from the axis, from radiance * d^2 / I.
        let falloff = |t: f32, phi: f32, d: f32| -> f32 {
            let (st, ct) = t.to_radians().sin_cos();
            let w = frame.to_world(Vec3::new(st * phi.cos(), st * phi.sin(), ct));
            let receiver = position + w * d;
            match light.sample(receiver, Vec2::ZERO) {
                Some(s) => {
                    assert!(s.delta && s.pdf == 1.0);
                    assert!((s.wi + w).length() < 1e-4);
                    s.radiance.x * d * d / intensity.x
                }
                None => 0.0,
            }
        };
        let mut last = 1.0f32;
        for k in 0..=180 {
            let t = k as f32;
            let f = falloff(t, 0.37 * k as f32, 0.5 + 0.1 * k as f32);
            if t < inner - 0.01 {
                assert!(
                    (f - 1.0).abs() < 1e-4,
                    "inner {inner}: falloff {f} at {t} deg"
                );
            }
            if t > outer + 0.01 {
                assert_eq!(f, 0.0, "outer {outer}: falloff {f} at {t} deg");
            }
            assert!((0.0..=1.0 + 1e-4).contains(&f));
            assert!(f <= last + 1e-4, "falloff increases at {t} deg");
            last = f;
        }
        // Power: the integral of intensity * falloff over the sphere (midpoint rule in cos).
        let steps = 20_000;
        let mut integral = 0.0f64;
        for k in 0..steps {
            let c = -1.0 + 2.0 * (k as f64 + 0.5) / steps as f64;
            integral += falloff(c.acos().to_degrees() as f32, 0.0, 1.0) as f64;
        }
        integral *= 2.0 * std::f64::consts::PI * 2.0 / steps as f64;
        let expected = integral * luminance(intensity) as f64;
        assert!(
            (light.power() as f64 - expected).abs() < 2e-3 * expected,
            "spot {inner}/{outer}: power {} vs integral {expected}",
            light.power()
        );
    }
}

#[test]
fn directional_light_sample_and_power() {
    let direction = Vec3::new(1.0, -2.0, -0.5);
    let irradiance = Rgb::new(1.0, 0.5, 0.25);
    let bounds = Bounds3::EMPTY
        .union_point(Vec3::splat(-3.0))
        .union_point(Vec3::splat(1.0));
    let light = Light::from_desc(
        &LightDesc::Directional {
            direction,
            irradiance,
        },
        &bounds,
    );
    let s = light.sample(Vec3::new(0.3, 0.1, -0.2), Vec2::ZERO).unwrap();
    assert!(s.delta && s.pdf == 1.0 && s.distance.is_infinite());
    assert!((s.wi + direction.normalize()).length() < 1e-6);
    assert_eq!(s.radiance, irradiance);
    let radius = bounds.bounding_sphere().1;
    let expected = PI * radius * radius * luminance(irradiance);
    assert!((light.power() - expected).abs() < 1e-5 * expected);
}

/// A mixed set of lights, including one with zero power.
fn mixed_lights() -> Vec<Light> {
    let bounds = Bounds3::EMPTY
        .union_point(Vec3::splat(-2.0))
        .union_point(Vec3::splat(2.0));
    vec![
        area_light([Vec3::ZERO, Vec3::X, Vec3::Y], Rgb::new(10.0, 10.0, 10.0)),
        area_light(
            [Vec3::ZERO, Vec3::X * 3.0, Vec3::Z * 2.0],
            Rgb::new(0.5, 1.0, 0.1),
        ),
        area_light([Vec3::ZERO, Vec3::X, Vec3::Y], Rgb::ZERO),
        Light::from_desc(
            &LightDesc::Point {
                position: Vec3::ONE,
                intensity: Rgb::splat(0.3),
            },
            &bounds,
        ),
        Light::from_desc(
            &LightDesc::Spot {
                position: Vec3::ONE,
                direction: -Vec3::Z,
                intensity: Rgb::splat(5.0),
                inner_degrees: 10.0,
                outer_degrees: 25.0,
            },
            &bounds,
        ),
        Light::from_desc(
            &LightDesc::Directional {
                direction: -Vec3::Y,
                irradiance: Rgb::splat(0.05),
            },
            &bounds,
        ),
    ]
}

fn check_sampler(name: &str, lights: &[Light], seed: u64) {
    let sampler = LightSampler::new(lights).expect("some light has power");
    let powers: Vec<f64> = lights.iter().map(|l| l.power() as f64).collect();
    let total: f64 = powers.iter().sum();
    for (i, &p) in powers.iter().enumerate() {
        let pmf = sampler.pmf(i) as f64;
        assert!(
            (pmf - p / total).abs() <= 1e-5 * (p / total) + 1e-9,
            "{name}: light {i} pmf {pmf} vs power share {}",
            p / total
        );
    }
    let n = 1_000_000u64;
    let mut counts = vec![0u64; lights.len()];
    let mut rng = Rng::new(seed, 9);
    for _ in 0..n {
        let (i, pmf) = sampler.sample(rng.uniform());
        assert_eq!(pmf, sampler.pmf(i));
        assert!(pmf > 0.0, "{name}: light {i} of zero probability chosen");
        counts[i] += 1;
    }
    for (i, &p) in powers.iter().enumerate() {
        if p == 0.0 {
            assert_eq!(counts[i], 0, "{name}: zero-power light {i} chosen");
        }
    }
    let expected: Vec<f64> = powers.iter().map(|p| p / total * n as f64).collect();
    assert_chi2(name, &counts, &expected);
}

#[test]
fn light_sampler_picks_lights_in_proportion_to_power() {
    check_sampler("mixed lights", &mixed_lights(), 1);
    // Many lights with powers spanning six orders of magnitude.
    let mut rng = Rng::new(12, 0);
    let many: Vec<Light> = (0..200)
        .map(|i| {
            let l = 10f32.powf(-3.0 + 6.0 * rng.uniform());
            let p = Vec3::new(i as f32, 0.0, 0.0);
            area_light([p, p + Vec3::X, p + Vec3::Y], Rgb::splat(l))
        })
        .collect();
    check_sampler("200 lights", &many, 2);
}

/// The vertices of sub-triangle `cell` (numbered as `sub_triangle`) of `p`, in f64.
fn cell_vertices(p: &[Vec3; 3], k: usize, cell: usize) -> [DVec3; 3] {
    let (ij, down) = (cell / 2, cell % 2 == 1);
    let (i, j) = ((ij / k) as f64, (ij % k) as f64);
    let kf = k as f64;
    let (p0, e1, e2) = (to64(p[0]), to64(p[1] - p[0]), to64(p[2] - p[0]));
    let at = |b1: f64, b2: f64| p0 + e1 * (b1 / kf) + e2 * (b2 / kf);
    if down {
        [at(i + 1.0, j), at(i, j + 1.0), at(i + 1.0, j + 1.0)]
    } else {
        [at(i, j), at(i + 1.0, j), at(i, j + 1.0)]
    }
}

/// Spherical triangle sampling is uniform in solid angle: the sampled points fall into the
/// k^2 sub-triangles in proportion to the solid angles they subtend (closed form), for near,
/// oblique, far and grazing receivers; the light's sample takes this density (1 / solid
/// angle, equal to `pdf()`) wherever the rule picks solid angle.
#[test]
fn spherical_triangle_samples_are_uniform_in_solid_angle() {
    let k = 8;
    let n = 100_000;
    let mut tests = 0;
    for (t, (name, p)) in triangles().into_iter().enumerate() {
        let light = area_light(p, Rgb::ONE);
        let (_, normal, _) = geometry(&light);
        let scale = (p[1] - p[0]).length().max((p[2] - p[0]).length());
        let side = (p[1] - p[0]).normalize();
        let mut where_ = receivers(&p, normal);
        where_.push((
            "grazing",
            centroid(&p) + (normal * 0.05 + side * 1.5) * scale,
        ));
        for (r, (place, receiver)) in where_.into_iter().enumerate() {
            let omega = triangle::solid_angle(&p, receiver);
            if omega > triangle::MAX_SPHERICAL_SOLID_ANGLE {
                continue; // sampled by area: tested above
            }
            let omega64 = solid_angle(&p, receiver);
            assert!(
                ((omega as f64 - omega64) / omega64).abs() < 1e-5,
                "{name} {place}: solid angle {omega} vs {omega64}"
            );
            let expected: Vec<f64> = (0..2 * k * k)
                .map(|cell| {
                    let (ij, down) = (cell / 2, cell % 2 == 1);
                    let (i, j) = (ij / k, ij % k);
                    let exists = if down { i + j + 2 <= k } else { i + j < k };
                    if exists {
                        n as f64 * solid_angle64(cell_vertices(&p, k, cell), to64(receiver))
                            / omega64
                    } else {
                        0.0
                    }
                })
                .collect();
            let total: f64 = expected.iter().sum();
            assert!((total - n as f64).abs() < 1e-6 * n as f64, "{total}");
            let rule = spherical_solid_angle(&p, normal, receiver);
            let mut counts = vec![0u64; 2 * k * k];
            let mut rng = Rng::new(300 + t as u64, r as u64);
            for _ in 0..n {
                let u = rng.uniform2();
                let b = triangle::sample_spherical_triangle(&p, receiver, omega, u)
                    .expect("a spherical triangle of solid angle > 0 gets a sample");
                let x = p[0] * b[0] + p[1] * b[1] + p[2] * b[2];
                let (b1, b2) = barycentric(&p, x);
                let cell = sub_triangle(b1, b2, k)
                    .unwrap_or_else(|| panic!("{name} {place}: point {x} outside the triangle"));
                counts[cell] += 1;
                if let Some(rule_omega) = rule {
                    // Where the rule picks solid angle, the light samples exactly this way.
                    let s = sample(&light, receiver, TriangleSampling::SolidAngle, u).unwrap();
                    assert_eq!(rule_omega, omega);
                    assert_eq!(s.point, x);
                    assert_eq!(s.pdf, 1.0 / omega);
                    assert_eq!(
                        s.pdf,
                        light.pdf_with(receiver, s.point, TriangleSampling::SolidAngle)
                    );
                }
            }
            // Keep only the k^2 existing cells.
            let (observed, expected): (Vec<u64>, Vec<f64>) = counts
                .iter()
                .zip(&expected)
                .filter(|(_, &e)| e > 0.0)
                .map(|(&o, &e)| (o, e))
                .unzip();
            assert_eq!(observed.len(), k * k);
            assert_chi2(
                &format!("spherical triangle {name}, receiver {place}: solid-angle cells"),
                &observed,
                &expected,
            );
            tests += 1;
        }
    }
    assert!(tests >= 16, "only {tests} receivers sampled by solid angle");
}

/// No NaN, infinite or misplaced samples at scales 1e-4..1e4, for slivers, tiny and huge
/// triangles and receivers from touching to far and grazing; `sample` and `pdf()` agree to
/// the bit.
#[test]
fn triangle_light_samples_are_finite_at_all_scales() {
    let shapes: [(&str, [Vec3; 3]); 4] = [
        ("unit", [Vec3::ZERO, Vec3::X, Vec3::Y]),
        ("sliver", [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1e-4, 0.0)]),
        (
            "needle",
            [
                Vec3::ZERO,
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(0.5, 1e-6, 0.0),
            ],
        ),
        ("tiny", [Vec3::ZERO, Vec3::X * 1e-3, Vec3::Y * 1e-3]),
    ];
    let mut rng = Rng::new(77, 7);
    let corners = [
        Vec2::ZERO,
        Vec2::new(0.99999994, 0.0),
        Vec2::new(0.0, 0.99999994),
        Vec2::splat(0.99999994),
    ];
    let mut sampled = [0usize; 2];
    for scale in [1e-4f32, 1e-2, 1.0, 1e2, 1e4] {
        for (name, shape) in shapes {
            let p = shape.map(|v| v * scale + Vec3::new(0.3, -0.2, 0.1) * scale);
            let c = (p[1] - p[0]).cross(p[2] - p[0]);
            if c.length_squared() == 0.0 {
                continue; // degenerate in f32 at this scale: the scene builder rejects it
            }
            let light = area_light(p, Rgb::ONE);
            let (_, normal, _) = geometry(&light);
            let size = (p[1] - p[0]).length();
            let lo = p[0].min(p[1]).min(p[2]) - Vec3::splat(1e-3 * size);
            let hi = p[0].max(p[1]).max(p[2]) + Vec3::splat(1e-3 * size);
            let cen = centroid(&p);
            for d in [1e-4f32, 1e-2, 1.0, 1e2, 1e4] {
                for dir in [
                    normal,
                    (normal + Vec3::X).normalize(),
                    (normal * 1e-3 + Vec3::X),
                ] {
                    let receiver = cen + dir * (d * size);
                    let spherical = spherical_solid_angle(&p, normal, receiver).is_some();
                    for u in corners.into_iter().chain((0..200).map(|_| rng.uniform2())) {
                        let Some(s) = sample(&light, receiver, TriangleSampling::SolidAngle, u)
                        else {
                            continue;
                        };
                        sampled[spherical as usize] += 1;
                        let ctx = format!("{name} x {scale}, receiver {receiver}: {s:?}");
                        assert!(s.pdf.is_finite() && s.pdf > 0.0, "{ctx}");
                        assert!(s.distance.is_finite() && s.distance > 0.0, "{ctx}");
                        assert!((s.wi.length() - 1.0).abs() < 1e-4, "{ctx}");
                        assert!(s.point.cmpge(lo).all() && s.point.cmple(hi).all(), "{ctx}");
                        assert!(s.point_error.is_finite(), "{ctx}");
                        assert_eq!(
                            s.pdf,
                            light.pdf_with(receiver, s.point, TriangleSampling::SolidAngle),
                            "{ctx}"
                        );
                    }
                    for x in p.iter().copied().chain([cen]) {
                        let pdf = light.pdf_with(receiver, x, TriangleSampling::SolidAngle);
                        assert!(pdf.is_finite() && pdf >= 0.0, "{name}: pdf {pdf}");
                    }
                }
            }
        }
    }
    assert!(sampled[0] > 0 && sampled[1] > 0, "{sampled:?}");
}

/// `sample_reuse` chooses exactly as `sample` with the same pmf, and the rescaled number is
/// uniform on [0, 1) given the choice (chi-square over light x 8 bins of it).
#[test]
fn light_sampler_reuse_keeps_the_pmf_and_rescales_uniformly() {
    let lights = mixed_lights();
    let sampler = LightSampler::new(&lights).unwrap();
    let bins = 8;
    let n = 1_000_000u64;
    let mut counts = vec![0u64; lights.len() * bins];
    let mut rng = Rng::new(21, 4);
    for _ in 0..n {
        let u = rng.uniform();
        let (i, pmf, r) = sampler.sample_reuse(u);
        assert_eq!((i, pmf), sampler.sample(u));
        assert!((0.0..1.0).contains(&r), "rescaled {r}");
        counts[i * bins + ((r * bins as f32) as usize).min(bins - 1)] += 1;
    }
    let powers: Vec<f64> = lights.iter().map(|l| l.power() as f64).collect();
    let total: f64 = powers.iter().sum();
    let (observed, expected): (Vec<u64>, Vec<f64>) = counts
        .iter()
        .enumerate()
        .filter(|(c, _)| powers[c / bins] > 0.0)
        .map(|(c, &o)| (o, powers[c / bins] / total * n as f64 / bins as f64))
        .unzip();
    assert_chi2(
        "light choice reuse: light x rescaled bins",
        &observed,
        &expected,
    );
    // Stratified choice numbers stay stratified over each of two equal lights (the Cornell
    // box's quad): each light's rescaled numbers are a stratified set again.
    let pair = [
        area_light([Vec3::ZERO, Vec3::X, Vec3::Y], Rgb::ONE),
        area_light([Vec3::X, Vec3::ONE, Vec3::Y], Rgb::ONE),
    ];
    let sampler = LightSampler::new(&pair).unwrap();
    let m = 1024;
    let mut per_light = [Vec::new(), Vec::new()];
    for j in 0..m {
        let (i, _, r) = sampler.sample_reuse((j as f32 + 0.5) / m as f32);
        per_light[i].push(r);
    }
    for rescaled in &mut per_light {
        rescaled.sort_by(f32::total_cmp);
        let len = rescaled.len();
        assert!(len > m / 4, "{len}");
        for (j, &r) in rescaled.iter().enumerate() {
            assert!(
                (r - (j as f32 + 0.5) / len as f32).abs() < 1.5 / len as f32,
                "{j}: {r}"
            );
        }
    }
}

/// `path:triangles=solid_angle` (triangles by solid angle where the rule says so) agrees with
/// `path` (by area, the default; both reuse the light choice's coordinate) on the image mean
/// and quadrant means: on the box with glossy, mirror and glass
/// surfaces under an area light, and on the Cornell box (large lamp close to the ceiling).
#[test]
fn path_with_solid_angle_light_samples_agrees_with_area_light_samples() {
    use common::agreement::{assert_agree, box_scene, region_means};
    use lacuna::integrator::IntegratorSettings;
    let cornell = {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("scenes/cornell-box/cornell-box.json");
        let scene = lacuna::scene::load_scene_file(&path)
            .unwrap()
            .builder
            .build()
            .unwrap();
        let camera = *scene.camera().unwrap();
        (scene, camera)
    };
    for (label, (scene, camera)) in [("box", box_scene(true, true, false)), ("cornell", cornell)] {
        let settings = IntegratorSettings {
            max_depth: 5,
            ..Default::default()
        };
        let solid = region_means(
            &scene,
            &camera,
            "path:triangles=solid_angle",
            settings,
            24,
            8,
            8,
        );
        let area = region_means(&scene, &camera, "path", settings, 24, 8, 8);
        assert!(solid[0].0 > 0.0, "{label}: black image");
        assert_agree(label, ("solid angle", &solid), ("area", &area));
    }
}
