//! Correctness of BSDF sampling (see docs/testing.md, "Sampling routines"):
//!
//! - chi-square goodness of fit of sampled directions against the pdf integrated over cells of
//!   the sphere, for Lambert, modified Phong (exponents 1 to 10^4, several diffuse/specular
//!   splits, wo above, grazing and below the surface) and the power-cosine warp;
//! - the pdf integrates to at most 1 (Lambert: exactly 1), and `sample` agrees with `pdf`
//!   and `eval`;
//! - energy conservation: directional albedo <= 1 by quadrature, checked against an
//!   importance-sampled estimate; mirror and dielectric throughputs, Fresnel and Snell;
//! - no NaN or infinity for grazing, in-plane and degenerate arguments.
//!
//! Samples returned as `None` are a "no sample" outcome with probability 1 - (integral of
//! the pdf over the sphere), tested as one more chi-square cell.

mod common;

use common::chi2::{assert_z, chi2_test, significance, Stats};
use common::directions::{to32, to64, SAMPLES};
use common::sphere::SphereGrid;
use glam::DVec3;
use lacuna::math::{warp, Rgb, Rng, Vec2, Vec3};
use lacuna::scene::{fresnel_dielectric, Bsdf, Material, Transport};

/// The f32 vector nearest to unit `v` whose length is 1 to within ~1e-10: each component is
/// nudged by up to 3 ulps. A lobe of exponent n magnifies the length error of wo n times
/// (cos^n of a dot product with |wo| = 1 + e is off by a factor 1 + n e), so the tests use
/// directions as unit as f32 allows and keep their tolerances tight.
fn unit32(v: DVec3) -> Vec3 {
    let v = v.normalize();
    let base = to32(v);
    let nudge = |x: f32, k: i32| {
        let mut y = x;
        for _ in 0..k.abs() {
            y = if k > 0 { next_up(y) } else { next_down(y) };
        }
        y
    };
    let mut best = (f64::INFINITY, base);
    for i in -3..=3 {
        for j in -3..=3 {
            for k in -3..=3 {
                let w = Vec3::new(nudge(base.x, i), nudge(base.y, j), nudge(base.z, k));
                let err = (to64(w).length_squared() - 1.0).abs() + 1e-3 * (to64(w) - v).length();
                if err < best.0 {
                    best = (err, w);
                }
            }
        }
    }
    best.1
}

fn next_up(x: f32) -> f32 {
    if x == 0.0 {
        f32::from_bits(1)
    } else if x > 0.0 {
        f32::from_bits(x.to_bits() + 1)
    } else {
        f32::from_bits(x.to_bits() - 1)
    }
}

fn next_down(x: f32) -> f32 {
    -next_up(-x)
}

/// Unit direction with z = `z` and azimuth `phi` (radians).
fn dir_z(z: f64, phi: f64) -> Vec3 {
    let r = (1.0 - z * z).max(0.0).sqrt();
    unit32(DVec3::new(r * phi.cos(), r * phi.sin(), z))
}

fn lambert(albedo: f32) -> Bsdf {
    Material::diffuse(Rgb::splat(albedo)).bsdf(Rgb::splat(albedo))
}

fn phong(diffuse: f32, specular: f32, exponent: f32) -> Bsdf {
    Material::glossy(Rgb::splat(diffuse), Rgb::splat(specular), exponent).bsdf(Rgb::splat(diffuse))
}

fn rel_close(a: f32, b: f32, tol: f32) -> bool {
    (a - b).abs() <= tol * a.abs().max(b.abs()) + 1e-30
}

/// Outgoing directions used by the chi-square tests: normal, oblique, near-grazing, grazing
/// (wo.z = 1e-3) and below the surface (two-sidedness).
fn test_wos() -> Vec<(&'static str, Vec3)> {
    vec![
        ("normal", Vec3::Z),
        ("45deg", dir_z(45f64.to_radians().cos(), 0.7)),
        ("80deg", dir_z(80f64.to_radians().cos(), 2.1)),
        ("grazing", dir_z(1e-3, 4.0)),
        ("below", dir_z(-0.6, 5.3)),
    ]
}

/// The axis of the Phong lobe for `wo`: its mirror image, on the same side as `wo`.
fn lobe_axis(wo: Vec3) -> DVec3 {
    to64(Vec3::new(-wo.x, -wo.y, wo.z)).normalize()
}

/// A grid resolving a power-cosine lobe of exponent `n` around `axis`.
fn lobe_grid(axis: DVec3, n: f32) -> SphereGrid {
    let mut grid = SphereGrid::uniform(20, 40);
    if n > 0.0 {
        // cos^n(a) ~ exp(-n a^2 / 2): angular standard deviation 1 / sqrt(n).
        grid.refine_lobe(axis, 1.0 / (n as f64).sqrt(), 5.0, 8);
    }
    grid
}

/// Result of one chi-square run.
struct Run {
    /// Integral of the pdf over the sphere (quadrature).
    pdf_integral: f64,
}

/// [`common::directions::chi2_directions`] with the stream of these tests and an f32 pdf.
fn chi2_directions(
    name: &str,
    grid: &SphereGrid,
    seed: u64,
    sample: impl FnMut(&mut Rng) -> Option<Vec3>,
    pdf: impl Fn(Vec3) -> f32,
) -> Run {
    Run {
        pdf_integral: common::directions::chi2_directions(
            name,
            grid,
            Rng::new(seed, 0x5eed),
            sample,
            |w| pdf(w) as f64,
        ),
    }
}

/// Samples `bsdf` at `wo` through `chi2_directions`, checking each sample against `pdf` and
/// `eval`, and returns the run with an importance-sampled estimate of the albedo.
fn chi2_bsdf(name: &str, bsdf: &Bsdf, wo: Vec3, grid: &SphereGrid, seed: u64) -> (Run, Stats) {
    let mut albedo = Stats::default();
    let run = chi2_directions(
        name,
        grid,
        seed,
        |rng| {
            let uc = rng.uniform();
            let u = rng.uniform2();
            let Some(s) = bsdf.sample(wo, uc, u, Transport::Radiance) else {
                albedo.add(0.0);
                return None;
            };
            assert!(!s.delta, "{name}: non-delta BSDF returned a delta sample");
            assert!(
                (s.wi.length() - 1.0).abs() < 1e-4,
                "{name}: wi {} is not unit",
                s.wi
            );
            assert!(
                s.wi.z * wo.z > 0.0,
                "{name}: wi {} is not on the side of wo {wo}",
                s.wi
            );
            let pdf = bsdf.pdf(wo, s.wi);
            assert!(
                s.pdf > 0.0 && s.pdf.is_finite() && rel_close(s.pdf, pdf, 1e-4),
                "{name}: sample pdf {} but pdf() = {pdf} at wi {}",
                s.pdf,
                s.wi
            );
            let f = bsdf.eval(wo, s.wi, Transport::Radiance);
            for c in 0..3 {
                assert!(
                    s.f[c].is_finite() && rel_close(s.f[c], f[c], 1e-4),
                    "{name}: sample f {} but eval() = {f} at wi {}",
                    s.f,
                    s.wi
                );
            }
            albedo.add((s.f.x * s.wi.z.abs() / s.pdf) as f64);
            Some(s.wi)
        },
        |w| bsdf.pdf(wo, w),
    );
    (run, albedo)
}

/// Directional albedo (red channel) of `bsdf` at `wo` by quadrature on `grid`.
fn albedo_quadrature(bsdf: &Bsdf, wo: Vec3, grid: &SphereGrid) -> f64 {
    grid.integrate(|w| {
        let wi = to32(w);
        bsdf.eval(wo, wi, Transport::Radiance).x as f64 * w.z.abs()
    })
    .iter()
    .sum()
}

// ---------------------------------------------------------------------------------------
// The statistics themselves.

#[test]
fn incomplete_gamma_matches_known_values() {
    use common::chi2::{chi2_p_value, gamma_p, gamma_q, ln_gamma, normal_p_value};
    // Gamma(n) = (n - 1)!, Gamma(1/2) = sqrt(pi).
    assert!((ln_gamma(1.0)).abs() < 1e-13);
    assert!((ln_gamma(5.0) - 24f64.ln()).abs() < 1e-13);
    assert!((ln_gamma(0.5) - std::f64::consts::PI.sqrt().ln()).abs() < 1e-13);
    assert!((ln_gamma(171.5) - 709.1431630309282).abs() < 1e-9);
    for x in [0.01, 0.5, 1.0, 2.0, 7.5, 30.0] {
        // Q(1, x) = exp(-x); chi-square with 2 dof: p = exp(-stat / 2).
        assert!((gamma_q(1.0, x) - (-x).exp()).abs() < 1e-14);
        assert!((gamma_p(1.0, x) + gamma_q(1.0, x) - 1.0).abs() < 1e-14);
        assert!((chi2_p_value(2.0 * x, 2) - (-x).exp()).abs() < 1e-14);
        // Q(2, x) = (1 + x) exp(-x).
        assert!((gamma_q(2.0, x) - (1.0 + x) * (-x).exp()).abs() < 1e-13);
    }
    // Tabulated 5 % and 1 % critical values of the chi-square distribution.
    for (stat, dof, p) in [
        (3.841459, 1, 0.05),
        (18.307038, 10, 0.05),
        (124.342113, 100, 0.05),
        (135.806723, 100, 0.01),
        (553.126953, 500, 0.05),
        (6.634897, 1, 0.01),
    ] {
        let got = chi2_p_value(stat, dof);
        assert!(
            (got - p).abs() < 1e-6 * p.max(1.0),
            "chi2 {stat} {dof}: {got}"
        );
    }
    // Two-sided normal tails.
    assert!((normal_p_value(1.959964) - 0.05).abs() < 1e-6);
    assert!((normal_p_value(-3.290527) - 0.001).abs() < 1e-8);
    assert!((normal_p_value(0.0) - 1.0).abs() < 1e-14);
    // The corrected significance is a sensible small number.
    assert!(significance() > 1e-6 && significance() < 1e-3);
}

/// The test can fail: samples of one lobe tested against a slightly different lobe, or
/// against a pdf scaled by 1.1, are rejected.
#[test]
fn chi2_rejects_wrong_pdfs() {
    let grid = lobe_grid(DVec3::Z, 20.0);
    let run = |pdf: &dyn Fn(Vec3) -> f32| {
        let probs = grid.integrate(|w| pdf(to32(w)) as f64);
        let mut observed = vec![0u64; grid.cells() + 1];
        let mut rng = Rng::new(99, 1);
        for _ in 0..SAMPLES {
            observed[grid.cell_of(to64(warp::power_cosine(rng.uniform2(), 20.0)))] += 1;
        }
        let integral: f64 = probs.iter().sum();
        let mut expected: Vec<f64> = probs.iter().map(|p| p * SAMPLES as f64).collect();
        expected.push((1.0 - integral).max(0.0) * SAMPLES as f64);
        (integral, chi2_test(&observed, &expected))
    };
    let (_, right) = run(&|w| warp::power_cosine_pdf(w, 20.0));
    assert!(right.unwrap().p_value >= significance());
    let (_, wrong) = run(&|w| warp::power_cosine_pdf(w, 21.0));
    assert!(wrong.unwrap().p_value < 1e-12);
    let (_, diffuse) = run(&warp::cosine_hemisphere_pdf);
    assert!(diffuse.unwrap().p_value < 1e-12);
    // A pdf scaled by 0.9: the missing tenth is expected as "no sample" and never seen.
    let (_, scaled) = run(&|w| 0.9 * warp::power_cosine_pdf(w, 20.0));
    assert!(scaled.unwrap().p_value < 1e-12);
    // Scaled by 1.1 it integrates to more than 1, which `chi2_directions` rejects first.
    let (integral, _) = run(&|w| 1.1 * warp::power_cosine_pdf(w, 20.0));
    assert!(integral > 1.05);
}

// ---------------------------------------------------------------------------------------
// Chi-square tests of the samplers.

#[test]
fn chi2_power_cosine_warp() {
    for (k, n) in [0.0f32, 1.0, 10.0, 100.0, 1000.0, 10000.0]
        .into_iter()
        .enumerate()
    {
        let grid = lobe_grid(DVec3::Z, n);
        let run = chi2_directions(
            &format!("power_cosine n={n}"),
            &grid,
            1000 + k as u64,
            |rng| Some(warp::power_cosine(rng.uniform2(), n)),
            |w| warp::power_cosine_pdf(w, n),
        );
        assert!(
            (run.pdf_integral - 1.0).abs() < 1e-4,
            "power_cosine n={n}: pdf integrates to {}",
            run.pdf_integral
        );
    }
}

#[test]
fn chi2_lambert() {
    let bsdf = lambert(0.7);
    let wos = [
        ("normal", Vec3::Z),
        ("45deg", dir_z(45f64.to_radians().cos(), 1.0)),
        ("grazing", dir_z(1e-3, 2.5)),
        ("below", dir_z(-0.7, 3.3)),
        ("below grazing", dir_z(-1e-3, 0.2)),
        ("below normal", -Vec3::Z),
    ];
    for (k, (label, wo)) in wos.into_iter().enumerate() {
        let grid = SphereGrid::uniform(20, 40);
        let name = format!("lambert wo {label}");
        let (run, albedo) = chi2_bsdf(&name, &bsdf, wo, &grid, 2000 + k as u64);
        assert!(
            (run.pdf_integral - 1.0).abs() < 1e-5,
            "{name}: pdf integrates to {}",
            run.pdf_integral
        );
        // Cosine sampling is perfect importance sampling: every weight is the albedo.
        assert!(
            (albedo.mean() - 0.7).abs() < 1e-5 && albedo.std_err() < 1e-6,
            "{name}: mean weight {}",
            albedo.mean()
        );
    }
}

/// Chi-square tests of Phong at exponent `n` for four diffuse/specular splits and the five
/// outgoing directions; also the albedo of each by quadrature against the importance-sampled
/// estimate from the same samples.
fn chi2_phong(n: f32, seed: u64) {
    let splits = [(0.0, 1.0), (0.5, 0.5), (0.8, 0.2), (0.2, 0.6)];
    for (si, &(d, s)) in splits.iter().enumerate() {
        let bsdf = phong(d, s, n);
        let p_spec = s / (d + s);
        for (wi, (label, wo)) in test_wos().into_iter().enumerate() {
            let name = format!("phong n={n} kd={d} ks={s} wo {label}");
            let grid = lobe_grid(lobe_axis(wo), n);
            let seed = seed + 10 * si as u64 + wi as u64;
            let (run, albedo_mc) = chi2_bsdf(&name, &bsdf, wo, &grid, seed);
            // Only specular samples below the horizon are lost: the diffuse part is whole.
            // Quadrature of an f32 pdf: cos^n magnifies rounding of the dot product n times.
            let slack = 1e-5 + 1e-8 * n as f64;
            assert!(
                run.pdf_integral <= 1.0 + slack && run.pdf_integral >= 1.0 - p_spec as f64 - 1e-5,
                "{name}: pdf integrates to {}",
                run.pdf_integral
            );
            let albedo = albedo_quadrature(&bsdf, wo, &grid);
            assert!(albedo <= (d + s) as f64 + slack, "{name}: albedo {albedo}");
            // Quadrature and the sampled estimate agree (a tolerance of 2e-5 covers the
            // quadrature error when the estimate has almost no variance).
            let se = (albedo_mc.variance() / SAMPLES as f64 + 4e-10).sqrt();
            assert_z(&format!("{name} albedo"), albedo_mc.mean(), albedo, se);
        }
    }
}

#[test]
fn chi2_phong_exponent_1() {
    chi2_phong(1.0, 3000);
}

#[test]
fn chi2_phong_exponent_10() {
    chi2_phong(10.0, 3100);
}

#[test]
fn chi2_phong_exponent_100() {
    chi2_phong(100.0, 3200);
}

#[test]
fn chi2_phong_exponent_1000() {
    chi2_phong(1000.0, 3300);
}

#[test]
fn chi2_phong_exponent_10000() {
    chi2_phong(10000.0, 3400);
}

// ---------------------------------------------------------------------------------------
// Energy conservation by quadrature.

/// Outgoing directions for the albedo sweeps: theta from 0 to 89.5 degrees, grazing, and
/// below the surface.
fn sweep_wos() -> Vec<Vec3> {
    let mut wos: Vec<Vec3> = [0.0f64, 15.0, 30.0, 45.0, 60.0, 75.0, 85.0, 89.5]
        .iter()
        .enumerate()
        .map(|(k, t)| dir_z(t.to_radians().cos(), 0.4 + k as f64))
        .collect();
    wos.push(dir_z(1e-3, 0.9));
    wos.push(dir_z(-0.3, 2.9));
    wos
}

#[test]
fn lambert_albedo_by_quadrature() {
    for albedo in [0.0f32, 0.3, 1.0] {
        let bsdf = lambert(albedo);
        for wo in sweep_wos() {
            let a = albedo_quadrature(&bsdf, wo, &SphereGrid::uniform(20, 40));
            assert!(
                (a - albedo as f64).abs() < 1e-6,
                "lambert {albedo} wo {wo}: albedo {a}"
            );
        }
    }
}

/// With diffuse + specular = 1 the directional albedo never exceeds 1 and equals 1 at normal
/// incidence (the (n + 2) / (2 pi) normalization), for exponents up to 10^4.
#[test]
fn phong_albedo_at_most_one_by_quadrature() {
    for n in [0.5f32, 1.0, 10.0, 100.0, 1000.0, 10000.0] {
        for (d, s) in [(0.0f32, 1.0f32), (0.4, 0.6)] {
            let bsdf = phong(d, s, n);
            let slack = 1e-5 + 1e-8 * n as f64;
            for (k, wo) in sweep_wos().into_iter().enumerate() {
                let a = albedo_quadrature(&bsdf, wo, &lobe_grid(lobe_axis(wo), n));
                assert!(a <= 1.0 + slack, "phong n={n} kd={d} wo {wo}: albedo {a}");
                if k == 0 {
                    assert!(
                        (a - 1.0).abs() <= slack,
                        "phong n={n} kd={d}: albedo {a} at normal incidence"
                    );
                }
            }
        }
    }
}

#[test]
fn mirror_throughput_is_reflectance() {
    let reflectance = Rgb::new(0.9, 0.5, 0.1);
    let bsdf = Material::mirror(reflectance).bsdf(Rgb::ZERO);
    assert!(bsdf.is_delta());
    let mut rng = Rng::new(7, 7);
    for k in 0..2000 {
        let wo = if k < 4 {
            [Vec3::Z, -Vec3::Z, dir_z(1e-3, 0.3), dir_z(-1e-3, 2.3)][k]
        } else {
            warp::uniform_sphere(rng.uniform2())
        };
        if wo.z == 0.0 {
            continue;
        }
        let s = bsdf
            .sample(wo, rng.uniform(), rng.uniform2(), Transport::Radiance)
            .expect("a mirror always reflects");
        assert!(s.delta);
        assert!((s.wi - Vec3::new(-wo.x, -wo.y, wo.z)).length() < 1e-6);
        let throughput = s.f * s.wi.z.abs() / s.pdf;
        assert!(
            (throughput - reflectance).abs().max_element() < 1e-5,
            "wo {wo}: throughput {throughput}"
        );
        // Delta lobes are invisible to eval and pdf.
        assert_eq!(bsdf.eval(wo, s.wi, Transport::Radiance), Rgb::ZERO);
        assert_eq!(bsdf.pdf(wo, s.wi), 0.0);
    }
}

// ---------------------------------------------------------------------------------------
// Dielectric: Fresnel, Snell, and the split between reflection and refraction.

/// Fresnel reflectance from the angles (Fresnel's sine and tangent laws), independent of the
/// renderer's algebraic form. `cos_i` < 0 arrives from inside (index `eta`).
fn fresnel_reference(cos_i: f64, eta: f64) -> f64 {
    let (c, n1, n2) = if cos_i >= 0.0 {
        (cos_i, 1.0, eta)
    } else {
        (-cos_i, eta, 1.0)
    };
    let ti = c.min(1.0).acos();
    let st = n1 / n2 * ti.sin();
    if st >= 1.0 {
        return 1.0;
    }
    let tt = st.asin();
    if ti < 1e-6 {
        let r = (n1 - n2) / (n1 + n2);
        return r * r;
    }
    let rs = ((ti - tt).sin() / (ti + tt).sin()).powi(2);
    let rp = ((ti - tt).tan() / (ti + tt).tan()).powi(2);
    0.5 * (rs + rp)
}

#[test]
fn fresnel_matches_closed_forms() {
    for eta in [1.33f32, 1.5, 2.4, 0.8] {
        // Normal incidence, from either side.
        let r0 = ((eta - 1.0) / (eta + 1.0)).powi(2);
        assert!((fresnel_dielectric(1.0, eta) - r0).abs() < 1e-6);
        assert!((fresnel_dielectric(-1.0, eta) - r0).abs() < 1e-6);
        for k in 0..=400 {
            let c = -1.0 + 2.0 * k as f32 / 400.0;
            let f = fresnel_dielectric(c, eta);
            let r = fresnel_reference(c as f64, eta as f64);
            assert!((0.0..=1.0).contains(&f), "eta {eta} cos {c}: F = {f}");
            // F has an infinite slope at the critical angle: skip its f32 neighbourhood.
            let rel_eta = if c >= 0.0 { eta } else { 1.0 / eta };
            let sin2_t = (1.0 - c * c) / (rel_eta * rel_eta);
            if (sin2_t - 1.0).abs() < 1e-3 {
                continue;
            }
            assert!(
                (f as f64 - r).abs() < 2e-4,
                "eta {eta} cos {c}: F = {f}, reference {r}"
            );
        }
        // Brewster's angle: the parallel polarisation is not reflected at all.
        let tb = (eta as f64).atan();
        let tt = std::f64::consts::FRAC_PI_2 - tb;
        let rs = ((tb - tt).sin() / (tb + tt).sin()).powi(2);
        let f = fresnel_dielectric(tb.cos() as f32, eta);
        assert!(
            (f as f64 - 0.5 * rs).abs() < 1e-5,
            "Brewster eta {eta}: {f}"
        );
    }
    // Total internal reflection from inside beyond the critical angle, none before it.
    let eta = 1.5f32;
    let critical = (1.0 / eta).asin();
    for k in 1..100 {
        let t = critical + (std::f32::consts::FRAC_PI_2 - critical) * k as f32 / 100.0;
        assert_eq!(fresnel_dielectric(-t.cos(), eta), 1.0, "theta {t}");
        let t = critical * k as f32 / 100.0;
        assert!(fresnel_dielectric(-t.cos(), eta) < 1.0, "theta {t}");
    }
}

/// The two branches of `Bsdf::Dielectric::sample` for `wo`: (reflection, refraction), each
/// `None` when its probability is zero.
fn dielectric_branches(
    bsdf: &Bsdf,
    wo: Vec3,
    mode: Transport,
) -> (
    Option<lacuna::scene::BsdfSample>,
    Option<lacuna::scene::BsdfSample>,
) {
    let (mut refl, mut refr) = (None, None);
    for uc in [0.0, 0.25, 0.5, 0.75, 1.0 - f32::EPSILON / 2.0] {
        if let Some(s) = bsdf.sample(wo, uc, Vec2::new(0.3, 0.6), mode) {
            if s.wi.z * wo.z > 0.0 {
                refl = Some(s);
            } else {
                refr = Some(s);
            }
        }
    }
    (refl, refr)
}

#[test]
fn dielectric_sampling_obeys_fresnel_and_snell() {
    let mut rng = Rng::new(11, 3);
    for eta in [1.5f32, 1.33, 2.4, 1.0 / 1.5] {
        let bsdf = Material::dielectric(eta).bsdf(Rgb::ZERO);
        assert!(bsdf.is_delta());
        for k in 0..500 {
            let mut wo = warp::uniform_sphere(rng.uniform2());
            if k == 0 {
                wo = Vec3::Z;
            } else if k == 1 {
                wo = -Vec3::Z;
            }
            if wo.z.abs() < 1e-3 {
                continue;
            }
            let f = fresnel_dielectric(wo.z, eta);
            // Index on the side of wo and on the far side.
            let (n_o, n_t) = if wo.z > 0.0 { (1.0, eta) } else { (eta, 1.0) };
            let (refl, refr) = dielectric_branches(&bsdf, wo, Transport::Importance);
            let p_refl = refl.map_or(0.0, |s| s.pdf);
            let p_refr = refr.map_or(0.0, |s| s.pdf);
            assert!(
                (p_refl + p_refr - 1.0).abs() < 1e-6,
                "eta {eta} wo {wo}: reflect {p_refl} + refract {p_refr} != 1"
            );
            assert!((p_refl - f).abs() < 1e-6, "eta {eta} wo {wo}");
            if let Some(s) = refl {
                assert!(s.delta && (s.wi - Vec3::new(-wo.x, -wo.y, wo.z)).length() < 1e-6);
                assert!((s.f.x * s.wi.z.abs() / s.pdf - 1.0).abs() < 1e-5);
            }
            let sin_o = (1.0 - wo.z * wo.z).max(0.0).sqrt();
            if let Some(s) = refr {
                assert!(s.delta);
                assert!((s.wi.length() - 1.0).abs() < 1e-5);
                assert!(s.wi.z * wo.z < 0.0, "refraction must cross the surface");
                // Snell: n_o sin_o = n_t sin_t, in the plane of incidence, opposite azimuth.
                let sin_t = (1.0 - s.wi.z * s.wi.z).max(0.0).sqrt();
                assert!(
                    (n_o * sin_o - n_t * sin_t).abs() < 2e-5,
                    "eta {eta} wo {wo} wi {}: Snell {} vs {}",
                    s.wi,
                    n_o * sin_o,
                    n_t * sin_t
                );
                let cross = wo.x * s.wi.y - wo.y * s.wi.x;
                assert!(cross.abs() < 1e-5 && wo.x * s.wi.x + wo.y * s.wi.y <= 1e-6);
                // Importance transport: the throughput of refraction is 1.
                assert!((s.f.x * s.wi.z.abs() / s.pdf - 1.0).abs() < 1e-5);
                // Fresnel is the same seen from both sides (away from grazing wo, where wi is
                // at the critical angle and F is infinitely sensitive to rounding), and
                // refraction is reversible.
                if wo.z.abs() > 0.05 {
                    assert!(
                        (fresnel_dielectric(s.wi.z, eta) - f).abs() < 1e-4,
                        "eta {eta} wo {wo} wi {}: F {f} but {} seen from wi",
                        s.wi,
                        fresnel_dielectric(s.wi.z, eta)
                    );
                }
                let back = bsdf
                    .sample(
                        s.wi,
                        1.0 - f32::EPSILON / 2.0,
                        Vec2::ZERO,
                        Transport::Importance,
                    )
                    .unwrap();
                if back.wi.z * s.wi.z < 0.0 {
                    assert!((back.wi - wo).length() < 1e-4, "wo {wo} back {}", back.wi);
                }
            } else {
                // Only total internal reflection removes the refracted branch.
                assert!(n_o * sin_o >= n_t * (1.0 - 1e-5), "eta {eta} wo {wo}");
            }
            // Radiance transport scales refraction by (n_o / n_t)^2.
            let (_, refr_rad) = dielectric_branches(&bsdf, wo, Transport::Radiance);
            if let Some(s) = refr_rad {
                let t = s.f.x * s.wi.z.abs() / s.pdf;
                let expected = (n_o / n_t) * (n_o / n_t);
                assert!((t - expected).abs() < 1e-4 * expected, "{t} vs {expected}");
            }
        }
    }
}

/// In importance transport the expected throughput of a dielectric sample is exactly 1:
/// every outcome has weight 1 and the branch probabilities sum to 1. The sampled branch
/// frequencies follow Fresnel (uc stratified, so the count is exact to +-1).
#[test]
fn dielectric_importance_transport_conserves_energy() {
    let bsdf = Material::dielectric(1.5).bsdf(Rgb::ZERO);
    let strata = 4096;
    for k in 0..64 {
        let z = -1.0 + 2.0 * (k as f64 + 0.5) / 64.0;
        let wo = dir_z(z, 0.1 * k as f64);
        let f = fresnel_dielectric(wo.z, 1.5);
        let mut sum = 0.0f64;
        let mut reflected = 0;
        for i in 0..strata {
            let uc = (i as f32 + 0.5) / strata as f32;
            let s = bsdf
                .sample(wo, uc, Vec2::new(0.5, 0.5), Transport::Importance)
                .expect("a dielectric always scatters");
            sum += (s.f.x * s.wi.z.abs() / s.pdf) as f64;
            if s.wi.z * wo.z > 0.0 {
                reflected += 1;
            }
        }
        assert!(
            (sum / strata as f64 - 1.0).abs() < 1e-5,
            "wo {wo}: mean throughput {}",
            sum / strata as f64
        );
        assert!(
            (reflected as f32 - f * strata as f32).abs() <= 1.5,
            "wo {wo}: {reflected} reflections of {strata}, Fresnel {f}"
        );
    }
}

// ---------------------------------------------------------------------------------------
// Rough dielectric (GGX microfacet reflection and transmission).

fn rough(eta: f32, alpha: f32) -> Bsdf {
    Material::rough_dielectric(eta, alpha).bsdf(Rgb::ZERO)
}

/// The refracted direction of `wo` through the macro surface, if any (`eta` inside/outside).
fn refracted(wo: Vec3, eta: f32) -> Option<DVec3> {
    let w = to64(wo);
    let etap = if w.z > 0.0 {
        eta as f64
    } else {
        1.0 / eta as f64
    };
    let cos_i = w.z.abs();
    let sin2_t = (1.0 - cos_i * cos_i) / (etap * etap);
    if sin2_t >= 1.0 {
        return None;
    }
    let n = DVec3::new(0.0, 0.0, w.z.signum());
    Some((-w / etap + n * (cos_i / etap - (1.0 - sin2_t).sqrt())).normalize())
}

/// A grid resolving the reflection lobe (around the mirror direction) and the transmission
/// lobe (around the refracted direction) of width about `alpha`.
fn rough_grid(wo: Vec3, eta: f32, alpha: f32) -> SphereGrid {
    let mut grid = SphereGrid::uniform(24, 48);
    // Transmissions end where the half vector wo + etap wi turns horizontal (beyond, only a
    // microfacet facing down would join them), at wi.z = -wo.z / etap, with the density
    // nonzero on one side: a step the quadrature must see as a cell edge.
    let etap = if wo.z > 0.0 {
        eta as f64
    } else {
        1.0 / eta as f64
    };
    let z_step = -(wo.z as f64) / etap;
    if z_step.abs() < 1.0 {
        grid.cos_edges.push(z_step);
    }
    grid.tidy();
    let sigma = 0.5 * alpha as f64;
    grid.refine_lobe(lobe_axis(wo), sigma, 5.0, 8);
    if let Some(t) = refracted(wo, eta) {
        grid.refine_lobe(t, sigma, 5.0, 8);
    }
    grid
}

/// Samples the rough dielectric at `wo` through `chi2_directions` (reflections and
/// transmissions alike), checking each sample against `pdf` and `eval` in `mode`; returns
/// the run and the importance-sampled estimate of the albedo f |cos| / pdf.
fn chi2_rough(
    name: &str,
    bsdf: &Bsdf,
    wo: Vec3,
    grid: &SphereGrid,
    seed: u64,
    mode: Transport,
) -> (Run, Stats) {
    let mut albedo = Stats::default();
    let run = chi2_directions(
        name,
        grid,
        seed,
        |rng| {
            let uc = rng.uniform();
            let u = rng.uniform2();
            let Some(s) = bsdf.sample(wo, uc, u, mode) else {
                albedo.add(0.0);
                return None;
            };
            assert!(
                !s.delta && (s.wi.length() - 1.0).abs() < 1e-4,
                "{name}: {s:?}"
            );
            let pdf = bsdf.pdf(wo, s.wi);
            assert!(
                s.pdf > 0.0 && s.pdf.is_finite() && rel_close(s.pdf, pdf, 1e-4),
                "{name}: sample pdf {} but pdf() = {pdf} at wi {}",
                s.pdf,
                s.wi
            );
            let f = bsdf.eval(wo, s.wi, mode);
            assert!(
                s.f.x.is_finite() && rel_close(s.f.x, f.x, 1e-4),
                "{name}: sample f {} but eval() = {f} at wi {}",
                s.f,
                s.wi
            );
            albedo.add((s.f.x * s.wi.z.abs() / s.pdf) as f64);
            Some(s.wi)
        },
        |w| bsdf.pdf(wo, w),
    );
    (run, albedo)
}

/// Outgoing directions for the rough dielectric: above (outside) and below (inside, where
/// 70 degrees is beyond the critical angle of glass 1.5 and its transmission vanishes).
fn rough_wos() -> Vec<(&'static str, Vec3)> {
    vec![
        ("normal", Vec3::Z),
        ("45deg", dir_z(45f64.to_radians().cos(), 0.7)),
        ("80deg", dir_z(80f64.to_radians().cos(), 2.1)),
        ("below 30deg", dir_z(-(30f64.to_radians().cos()), 5.3)),
        ("below 70deg", dir_z(-(70f64.to_radians().cos()), 1.1)),
    ]
}

/// Chi-square of sampling against the pdf for GGX widths 0.05 to 1, eta 1.5 and 1 / 1.5, wo on
/// both sides; the pdf's integral is the chance of a sample (the rest is the None cell, the
/// microfacet directions that scatter to the wrong side); the albedo in importance transport
/// (reflectance + transmittance, no eta^2) by quadrature is at most 1, agrees with the sampled
/// estimate, and is close to 1 for narrow lobes (single scattering loses only what the
/// masking term hides, Walter et al. 2007 §5.4).
fn chi2_rough_dielectric(alpha: f32, seed: u64) {
    for (ei, eta) in [1.5f32, 1.0 / 1.5].into_iter().enumerate() {
        let bsdf = rough(eta, alpha);
        for (wi, (label, wo)) in rough_wos().into_iter().enumerate() {
            let name = format!("rough dielectric alpha={alpha} eta={eta} wo {label}");
            let grid = rough_grid(wo, eta, alpha);
            let seed = seed + 10 * ei as u64 + wi as u64;
            let (run, albedo_mc) = chi2_rough(&name, &bsdf, wo, &grid, seed, Transport::Importance);
            assert!(
                run.pdf_integral <= 1.0 + 1e-4 && run.pdf_integral > 0.3,
                "{name}: pdf integrates to {}",
                run.pdf_integral
            );
            let albedo: f64 = grid
                .integrate(|w| {
                    let wi = to32(w);
                    bsdf.eval(wo, wi, Transport::Importance).x as f64 * w.z.abs()
                })
                .iter()
                .sum();
            assert!(albedo <= 1.0 + 1e-4, "{name}: albedo {albedo}");
            // Visible-normal sampling loses samples only where the albedo loses energy.
            assert!(albedo <= run.pdf_integral + 1e-3, "{name}: albedo {albedo}");
            if alpha <= 0.05 && wo.z.abs() > 0.3 {
                assert!(albedo > 0.98, "{name}: albedo {albedo}");
            }
            let se = (albedo_mc.variance() / SAMPLES as f64 + 4e-10).sqrt();
            assert_z(&format!("{name} albedo"), albedo_mc.mean(), albedo, se);
        }
    }
}

#[test]
fn chi2_rough_dielectric_alpha_0_05() {
    chi2_rough_dielectric(0.05, 9000);
}

#[test]
fn chi2_rough_dielectric_alpha_0_2() {
    chi2_rough_dielectric(0.2, 9100);
}

#[test]
fn chi2_rough_dielectric_alpha_0_5() {
    chi2_rough_dielectric(0.5, 9200);
}

#[test]
fn chi2_rough_dielectric_alpha_1() {
    chi2_rough_dielectric(1.0, 9300);
}

/// Reciprocity of the physical BTDF, f(wo, wi) / eta_wo^2 = f(wi, wo) / eta_wi^2 (Veach 1997
/// eq. 5.15), and the adjoint (importance) BSDF is the radiance BSDF with its arguments
/// swapped; reflection is symmetric.
#[test]
fn rough_dielectric_is_reciprocal_and_its_adjoint_swaps_arguments() {
    let mut rng = Rng::new(23, 4);
    for alpha in [0.01f32, 0.1, 0.4, 1.0] {
        for eta in [1.5f32, 1.0 / 1.33] {
            let bsdf = rough(eta, alpha);
            let mut checked = 0;
            for _ in 0..20_000 {
                let wo = warp::uniform_sphere(rng.uniform2());
                let wi = warp::uniform_sphere(rng.uniform2());
                let (fr_oi, fr_io) = (
                    bsdf.eval(wo, wi, Transport::Radiance).x,
                    bsdf.eval(wi, wo, Transport::Radiance).x,
                );
                let fi_oi = bsdf.eval(wo, wi, Transport::Importance).x;
                let n = |w: Vec3| if w.z > 0.0 { 1.0 } else { eta };
                let what = format!("alpha {alpha} eta {eta} wo {wo} wi {wi}");
                // Relative to rounding, or absolutely for values where a direction is nearly
                // tangent to the microfacet (a dot product near 0 has few exact digits).
                let close = |a: f32, b: f32| rel_close(a, b, 2e-3) || (a - b).abs() < 1e-6;
                assert!(
                    close(fr_oi / (n(wo) * n(wo)), fr_io / (n(wi) * n(wi))),
                    "{what}: {fr_oi} against {fr_io}"
                );
                assert!(close(fi_oi, fr_io), "{what}: {fi_oi} against {fr_io}");
                if fr_oi > 0.0 && wo.z * wi.z < 0.0 {
                    checked += 1;
                }
            }
            assert!(
                checked > 100,
                "alpha {alpha} eta {eta}: {checked} transmissions"
            );
        }
    }
}

/// As the GGX width shrinks the rough dielectric tends to the smooth one: reflectance and
/// transmittance (importance transport, quadrature around the two lobes) approach Fresnel's
/// split of the smooth interface, and the radiance transmittance carries 1 / etap^2. (Away from
/// the critical angle, where F jumps and any roughness averages it visibly.)
#[test]
fn rough_dielectric_tends_to_the_smooth_one() {
    for eta in [1.5f32, 1.0 / 1.5] {
        for (label, wo) in [
            ("normal", Vec3::Z),
            ("30deg", dir_z(30f64.to_radians().cos(), 0.3)),
            ("below 20deg", dir_z(-(20f64.to_radians().cos()), 2.0)),
        ] {
            let alpha = 0.01;
            let bsdf = rough(eta, alpha);
            let mut grid = SphereGrid::uniform(24, 48);
            grid.refine_lobe(lobe_axis(wo), alpha as f64, 6.0, 12);
            if let Some(t) = refracted(wo, eta) {
                grid.refine_lobe(t, alpha as f64, 6.0, 12);
            }
            let split = |mode: Transport| -> (f64, f64) {
                let cells = grid.integrate(|w| {
                    let wi = to32(w);
                    let v = bsdf.eval(wo, wi, mode).x as f64 * w.z.abs();
                    if (w.z > 0.0) == (wo.z > 0.0) {
                        v
                    } else {
                        -v
                    }
                });
                let r: f64 = cells.iter().filter(|&&c| c > 0.0).sum();
                let t: f64 = -cells.iter().filter(|&&c| c < 0.0).sum::<f64>();
                (r, t)
            };
            let f = fresnel_dielectric(wo.z, eta) as f64;
            let (r, t) = split(Transport::Importance);
            let name = format!("eta {eta} wo {label}");
            assert!((r - f).abs() < 5e-3, "{name}: reflectance {r}, Fresnel {f}");
            assert!(
                (t - (1.0 - f)).abs() < 1e-2,
                "{name}: transmittance {t}, 1 - F {}",
                1.0 - f
            );
            let etap = if wo.z > 0.0 {
                eta as f64
            } else {
                1.0 / eta as f64
            };
            let (_, t_radiance) = split(Transport::Radiance);
            assert!(
                (t_radiance * etap * etap - t).abs() < 1e-4 * t.max(1.0),
                "{name}: radiance transmittance {t_radiance}"
            );
        }
    }
}

// ---------------------------------------------------------------------------------------
// Robustness.

fn all_bsdfs() -> Vec<(String, Bsdf)> {
    let mut v = vec![
        ("lambert 0.8".to_string(), lambert(0.8)),
        ("lambert 0".to_string(), lambert(0.0)),
        (
            "mirror".to_string(),
            Material::mirror(Rgb::splat(0.9)).bsdf(Rgb::ZERO),
        ),
    ];
    for n in [0.0f32, 0.5, 1.0, 10000.0, 1e6] {
        for (d, s) in [(0.0f32, 1.0f32), (0.5, 0.5), (1.0, 0.0), (0.0, 0.0)] {
            v.push((format!("phong n={n} kd={d} ks={s}"), phong(d, s, n)));
        }
    }
    for eta in [1.5f32, 1.0 / 1.5, 1.0, 2.4] {
        v.push((
            format!("dielectric {eta}"),
            Material::dielectric(eta).bsdf(Rgb::ZERO),
        ));
        // Roughness 0 is raised to the smallest width (see `microfacet::MIN_ALPHA`).
        for alpha in [0.0f32, 1e-3, 0.05, 0.5, 1.0] {
            v.push((
                format!("rough dielectric {eta} alpha {alpha}"),
                rough(eta, alpha),
            ));
        }
    }
    v
}

/// Grazing, in-plane, tiny and subnormal z, and the poles.
fn degenerate_wos() -> Vec<Vec3> {
    let mut v = vec![Vec3::Z, -Vec3::Z, Vec3::X, Vec3::Y, -Vec3::X];
    for z in [
        0.5f64, 1e-3, 1e-7, 1e-20, 1e-30, 1e-38, 1e-39, 1e-40, 1e-45, 0.0,
    ] {
        for (sign, phi) in [(1.0, 0.0), (-1.0, 1.3), (1.0, 4.0), (-1.0, 5.9)] {
            let r = (1.0 - z * z).sqrt();
            v.push(Vec3::new(
                (r * f64::cos(phi)) as f32,
                (r * f64::sin(phi)) as f32,
                (sign * z) as f32,
            ));
        }
    }
    v
}

#[test]
fn no_nan_or_inf_for_degenerate_arguments() {
    let mut rng = Rng::new(5, 5);
    let one_minus = 1.0 - f32::EPSILON / 2.0;
    let us: Vec<f32> = vec![0.0, 1e-7, 0.5, one_minus];
    for (name, bsdf) in all_bsdfs() {
        for wo in degenerate_wos() {
            let mut wis = vec![
                wo,
                -wo,
                Vec3::new(-wo.x, -wo.y, wo.z),
                Vec3::new(wo.x, wo.y, -wo.z),
                Vec3::Z,
                -Vec3::Z,
                Vec3::X,
                Vec3::new(-wo.y, wo.x, 0.0),
            ];
            for _ in 0..8 {
                wis.push(warp::uniform_sphere(rng.uniform2()));
            }
            for wi in wis {
                let p = bsdf.pdf(wo, wi);
                for mode in [Transport::Radiance, Transport::Importance] {
                    let f = bsdf.eval(wo, wi, mode);
                    assert!(
                        f.is_finite() && f.min_element() >= 0.0,
                        "{name}: eval({wo}, {wi}, {mode:?}) = {f}"
                    );
                }
                let f = bsdf.eval(wo, wi, Transport::Radiance);
                assert!(
                    f.is_finite() && f.min_element() >= 0.0,
                    "{name}: eval({wo}, {wi}) = {f}"
                );
                assert!(p.is_finite() && p >= 0.0, "{name}: pdf({wo}, {wi}) = {p}");
            }
            let mut us2: Vec<Vec2> = Vec::new();
            for &a in &us {
                for &b in &us {
                    us2.push(Vec2::new(a, b));
                }
            }
            for _ in 0..8 {
                us2.push(rng.uniform2());
            }
            for &uc in &[0.0, 0.3, 0.7, one_minus] {
                for &u in &us2 {
                    for mode in [Transport::Radiance, Transport::Importance] {
                        let Some(s) = bsdf.sample(wo, uc, u, mode) else {
                            continue;
                        };
                        let what = format!("{name}: sample({wo}, {uc}, {u}) = {s:?}");
                        assert!(
                            s.wi.is_finite() && (s.wi.length() - 1.0).abs() < 1e-3,
                            "{what}"
                        );
                        assert!(s.pdf.is_finite() && s.pdf > 0.0, "{what}");
                        assert!(s.f.is_finite() && s.f.min_element() >= 0.0, "{what}");
                        // At most 2.4^2 (radiance leaving glass of index 2.4).
                        let throughput = s.f * s.wi.z.abs() / s.pdf;
                        assert!(
                            throughput.is_finite() && throughput.max_element() <= 6.0,
                            "{what}: throughput {throughput}"
                        );
                    }
                }
            }
        }
    }
}

/// Unbiasedness needs pdf > 0 wherever f > 0 (for the non-delta BSDFs, whose samples are the
/// only way an integrator finds such directions).
#[test]
fn pdf_is_positive_wherever_f_is() {
    let mut rng = Rng::new(17, 2);
    for (name, bsdf) in all_bsdfs() {
        if bsdf.is_delta() {
            continue;
        }
        for _ in 0..20_000 {
            let wo = warp::uniform_sphere(rng.uniform2());
            let wi = warp::uniform_sphere(rng.uniform2());
            let f = bsdf.eval(wo, wi, Transport::Radiance);
            if f.max_element() > 0.0 {
                assert!(
                    bsdf.pdf(wo, wi) > 0.0,
                    "{name}: f({wo}, {wi}) = {f} but the pdf is 0"
                );
            }
        }
    }
}

/// `Bsdf::sample_from` draws only the numbers a BSDF reads and skips the others' requests: its
/// result, and every request after it, must be those of `sample` fed by the sampler's next 1-D
/// and 2-D numbers, for both pixel samplers and both transport modes.
#[test]
fn sample_from_draws_what_sample_would() {
    use lacuna::math::{Sampler, SamplerKind};
    let bsdfs = [
        ("lambert", lambert(0.7)),
        ("phong", phong(0.4, 0.5, 30.0)),
        ("mirror", Material::mirror(Rgb::splat(0.9)).bsdf(Rgb::ZERO)),
        ("dielectric", Material::dielectric(1.5).bsdf(Rgb::ZERO)),
        ("rough dielectric", rough(1.5, 0.3)),
    ];
    let mut rng = Rng::new(11, 3);
    for kind in [SamplerKind::Sobol, SamplerKind::Independent] {
        for (name, bsdf) in &bsdfs {
            for k in 0..500u32 {
                let wo = warp::uniform_sphere(rng.uniform2());
                let mode = if k % 2 == 0 {
                    Transport::Radiance
                } else {
                    Transport::Importance
                };
                let mut skipping = Sampler::new(kind, 5, k as u64, k);
                let mut drawing = Sampler::new(kind, 5, k as u64, k);
                let got = bsdf.sample_from(wo, &mut skipping, mode);
                let uc = drawing.uniform();
                let want = bsdf.sample(wo, uc, drawing.uniform2(), mode);
                match (got, want) {
                    (None, None) => {}
                    (Some(a), Some(b)) => {
                        assert_eq!(
                            (a.wi, a.f, a.pdf, a.delta),
                            (b.wi, b.f, b.pdf, b.delta),
                            "{name} {kind:?} wo {wo}"
                        );
                    }
                    (a, b) => panic!("{name} {kind:?} wo {wo}: {a:?} against {b:?}"),
                }
                assert_eq!(skipping.uniform2(), drawing.uniform2(), "{name} {kind:?}");
                assert_eq!(skipping.uniform(), drawing.uniform(), "{name} {kind:?}");
            }
        }
    }
}
