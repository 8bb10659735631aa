//! Portal-guided path tracing (`path_portal`, 000 §10.4, issue 35), both strategies
//! (`shortest`, the portals' rectangles; `irradiance`, the regions' face distributions):
//!
//! - the face sampler of `strategy=irradiance`: chi-square against its density integrated
//!   over the faces, its pdf on every sample, and the albedo through the one-sample mixture;
//! - the one-sample MIS of BSDF sampling and the portal rectangles as `path_portal` draws it, at
//!   surface points of the Veach door: chi-square of the sampled directions against the
//!   mixture's pdf (directions that miss every portal included: they keep the BSDF's density),
//!   each sample carries that pdf, and f cos / pdf estimates the albedo without bias;
//! - unbiasedness of the integrator: the image and region means agree with `path`'s within
//!   their measured error (z-tests) on the Veach door, the ajar door, the built-in two rooms
//!   and the built-in interior (sky through windows; also with `env=portals`); no pixel is NaN
//!   or negative (`region_means` checks every pixel);
//! - an open scene is not guided: `path_portal` renders `path`'s image bit for bit and says why;
//! - options are validated, and rendering needs the precomputation.

mod common;

use std::sync::atomic::AtomicBool;

use common::agreement::{
    agree_on_two_rooms, agree_on_veach_door, agree_with_path, load_scene, render_image,
};
use common::chi2::{assert_chi2, assert_z, Stats};
use common::directions::{chi2_direction_counts, surface_points, to64, SAMPLES};
use common::sphere::SphereGrid;
use lacuna::guide::{
    sample_bsdf_or_guide, DirectionGuide, PortalGuide, PortalGuideSettings, PortalQuery,
    PortalRectangle, RenderEstimator,
};
use lacuna::integrator::{self, IntegratorSettings};
use lacuna::math::warp::SphericalRectangle;
use lacuna::math::{Frame, Rgb, Rng, Sampler, Vec3};
use lacuna::render::{prepare, render, RenderSettings};
use lacuna::scene::{interior_builder, Material};

/// Where the ray from `origin` along `w` crosses rectangle `rect`: its edge coordinates in
/// [0, 1]^2, or None.
fn hit(rect: &PortalRectangle, origin: Vec3, w: Vec3) -> Option<(f32, f32)> {
    let normal = rect.edge_u.cross(rect.edge_v);
    let t = (rect.corner - origin).dot(normal) / w.dot(normal);
    let q = origin + t * w - rect.corner;
    let (s, r) = (
        q.dot(rect.edge_u) / rect.edge_u.length_squared(),
        q.dot(rect.edge_v) / rect.edge_v.length_squared(),
    );
    (t > 0.0 && (0.0..=1.0).contains(&s) && (0.0..=1.0).contains(&r)).then_some((s, r))
}

/// The portal direction sampler at surface points of the Veach door (one point with several
/// lobes: a window across a region border): chi-square of where its samples cross the
/// rectangles, over cells that are sub-rectangles of each lobe's rectangle, whose expected
/// counts are exact (the lobe's probability times the sub-rectangle's solid angle over the
/// rectangle's; points whose rectangles overlap as seen from them are skipped), and the pdf a
/// sample returns is the mixture's, `sum_j a_j / Omega_j` over the rectangles it crosses.
/// Then the one-sample MIS with a Lambertian BSDF as `path_portal` draws it: each sample
/// carries `c p_portal + (1 - c) p_bsdf`, and f cos / pdf estimates the albedo without bias
/// (directions through no portal come from the BSDF alone and must be weighed right).
#[test]
fn chi2_of_the_portal_sampler_and_albedo_of_the_mixture() {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    let guide =
        PortalGuide::build(&scene, &PortalGuideSettings::default(), None, &|_, _| true).unwrap();
    assert!(guide.unguided().is_none(), "{}", guide.note());
    let bsdf = Material::diffuse(Rgb::splat(0.8)).bsdf(Rgb::splat(0.8));
    let mut query = PortalQuery::new();
    let (mut tested, mut multi) = (0, 0);
    let cells = 6usize;
    for (k, (p, _, ng, wo)) in surface_points(&scene, 3000, 41).into_iter().enumerate() {
        let n = if ng.dot(wo) < 0.0 { -ng } else { ng };
        guide.init_query(&mut query, p, n);
        let c = query.guiding_probability();
        if c == 0.0 {
            continue;
        }
        let lobes: Vec<(u32, f32)> = query.lobes().collect();
        assert!(c > 0.0 && c < 1.0, "c {c}");
        let total: f32 = lobes.iter().map(|l| l.1).sum();
        assert!((total - 1.0).abs() < 1e-5, "lobe weights sum to {total}");
        let wanted = if lobes.len() > 1 {
            multi < 2
        } else {
            tested - multi < 2
        };
        if !wanted {
            continue;
        }
        let rects: Vec<PortalRectangle> = lobes
            .iter()
            .map(|&(portal, _)| *guide.rectangle(portal).unwrap())
            .collect();
        let seen: Vec<SphericalRectangle> = rects
            .iter()
            .map(|r| {
                let (a, b) = (r.edge_u.length(), r.edge_v.length());
                SphericalRectangle::new(p, r.corner, r.edge_u / a, r.edge_v / b, a, b).unwrap()
            })
            .collect();
        let mut rng = Rng::new(900 + k as u64, 5);
        let name = format!("portal sampler at point {k} ({} lobes)", lobes.len());
        let mut observed = vec![0u64; rects.len() * cells * cells];
        let mut overlap = false;
        for _ in 0..SAMPLES {
            let (w, pdf) = query.sample(rng.uniform(), rng.uniform2()).unwrap();
            assert!(
                w.is_finite() && pdf.is_finite() && pdf > 0.0,
                "{name}: {w} {pdf}"
            );
            let crossed: Vec<(usize, (f32, f32))> = rects
                .iter()
                .enumerate()
                .filter_map(|(j, r)| hit(r, p, w).map(|h| (j, h)))
                .collect();
            let expected: f32 = crossed
                .iter()
                .map(|&(j, _)| lobes[j].1 / seen[j].solid_angle())
                .sum();
            assert!(
                crossed.is_empty() || (pdf - expected).abs() <= 1e-3 * expected,
                "{name}: pdf {pdf}, mixture {expected}"
            );
            if crossed.len() > 1 {
                overlap = true;
                break;
            }
            if let Some(&(j, (s, r))) = crossed.first() {
                let i = ((s * cells as f32) as usize).min(cells - 1);
                let l = ((r * cells as f32) as usize).min(cells - 1);
                observed[(j * cells + i) * cells + l] += 1;
            }
        }
        if overlap {
            continue;
        }
        let kept = observed.iter().sum::<u64>() as f64;
        assert!(
            kept > 0.999 * SAMPLES as f64,
            "{name}: {kept} of {SAMPLES} samples off the rectangles"
        );
        let mut expected = Vec::new();
        for (j, r) in rects.iter().enumerate() {
            for i in 0..cells {
                for l in 0..cells {
                    let (du, dv) = (r.edge_u / cells as f32, r.edge_v / cells as f32);
                    let sub = SphericalRectangle::new(
                        p,
                        r.corner + i as f32 * du + l as f32 * dv,
                        du.normalize(),
                        dv.normalize(),
                        du.length(),
                        dv.length(),
                    )
                    .unwrap();
                    let share = (sub.solid_angle() / seen[j].solid_angle()) as f64;
                    expected.push(lobes[j].1 as f64 * share * kept);
                }
            }
        }
        assert_chi2(&name, &observed, &expected);

        // The mixture with the BSDF: its pdf on every sample, and an unbiased albedo.
        let frame = Frame::from_z(n);
        let wo_local = frame.to_local(wo);
        let mut sampler = Sampler::independent(Rng::new(700 + k as u64, 3));
        let mut estimate = Stats::default();
        // A direction a hair from a rectangle's edge may cross it after the round trip through
        // the shading frame: a handful of mismatches is rounding.
        let mut mismatches = 0;
        for _ in 0..SAMPLES {
            let Some(m) = sample_bsdf_or_guide(&bsdf, wo_local, &frame, &query, &mut sampler)
            else {
                estimate.add(0.0);
                continue;
            };
            let s = m.sample;
            let world = frame.to_world(s.wi);
            let expected = c * query.pdf(world) + (1.0 - c) * bsdf.pdf(wo_local, s.wi);
            mismatches += ((s.pdf - expected).abs() > 1e-4 * expected) as u32;
            assert!(s.pdf.is_finite() && s.pdf > 0.0, "{name}: pdf {}", s.pdf);
            estimate.add((s.f.x * s.wi.z.abs() / s.pdf) as f64);
        }
        assert!(
            mismatches < 20,
            "{name}: {mismatches} samples off their mixture pdf"
        );
        assert_z(
            &format!("{name}: albedo"),
            estimate.mean(),
            0.8,
            estimate.std_err(),
        );
        tested += 1;
        multi += (lobes.len() > 1) as usize;
        if tested >= 4 {
            break;
        }
    }
    assert!(multi >= 1, "no point mixes the portals of several regions");
    assert!(tested >= 3, "{tested} points tested");
}

/// `strategy=irradiance`'s face sampler ([`lacuna::guide::FaceIrradiance`]) at surface
/// points of the Veach door: chi-square of its directions over a sphere grid against the
/// probabilities its density implies, integrated over the faces' areas (each face's
/// probability times the share of its area, on a grid of points finer on near faces, whose direction
/// lies in the cell and leaves the lobe's region first through that face; integrating the
/// density over directions instead meets its peaks at faces seen edge-on); rejected draws are
/// their own cell. Every sample's pdf is the pdf's value there, and the one-sample mixture
/// with a Lambertian BSDF (c = 0.9: mostly the faces) estimates the albedo without bias, which
/// holds only if the density is the sampler's.
#[test]
fn chi2_of_the_face_sampler_and_albedo_of_the_mixture() {
    let scene = load_scene("scenes/veach-door-pg2015/veach-door-pg2015.json");
    let camera = *scene.camera().unwrap();
    let mut settings = PortalGuideSettings::default();
    settings.set("strategy", "irradiance").unwrap();
    settings.set("training_paths", "4096").unwrap();
    settings.set("c_portal", "0.9").unwrap();
    let guide = PortalGuide::build(
        &scene,
        &settings,
        Some((&camera, RenderEstimator::default(), 6)),
        &|_, _| true,
    )
    .unwrap();
    assert!(guide.unguided().is_none(), "{}", guide.note());
    let faces = guide.faces().unwrap();
    let bsdf = Material::diffuse(Rgb::splat(0.8)).bsdf(Rgb::splat(0.8));
    let mut query = guide.face_query().unwrap();
    let grid = SphereGrid::uniform(8, 16);
    let (mut tested, mut multi) = (0, 0);
    for (k, (p, _, ng, wo)) in surface_points(&scene, 3000, 43).into_iter().enumerate() {
        let n = if ng.dot(wo) < 0.0 { -ng } else { ng };
        guide.init_face_query(&mut query, p, n);
        let c = query.guiding_probability();
        if c == 0.0 {
            continue;
        }
        let lobes: Vec<(u32, f32)> = query.lobes().collect();
        if (lobes.len() > 1 && multi >= 2) || (lobes.len() == 1 && tested - multi >= 2) {
            continue;
        }
        let name = format!("face sampler at point {k} ({} regions)", lobes.len());
        let mut probs = vec![0f64; grid.cells()];
        for (j, &(region, a)) in lobes.iter().enumerate() {
            for &face in faces.region_faces(region) {
                let (corner, eu, ev) = faces.face_rectangle(guide.analysis(), face);
                // Finer on near faces, which span more directions (and more cell borders).
                let voxels = (corner + 0.5 * (eu + ev) - p).length() / eu.length();
                let points = (96.0 / voxels.max(1.0)).clamp(8.0, 96.0) as usize;
                let share = (a * faces.face_probability(face)) as f64 / (points * points) as f64;
                for s in 0..points {
                    for t in 0..points {
                        let y = corner
                            + eu * ((s as f32 + 0.5) / points as f32)
                            + ev * ((t as f32 + 0.5) / points as f32);
                        let w = (y - p).normalize();
                        if query.exit_faces(w)[j] == face {
                            probs[grid.cell_of(to64(w))] += share;
                        }
                    }
                }
            }
        }
        let mut mismatches = 0;
        let integral =
            chi2_direction_counts(&name, &grid, probs, Rng::new(300 + k as u64, 9), |rng| {
                let (w, pdf) = query.sample(rng.uniform(), rng.uniform2())?;
                let again = query.pdf(w);
                mismatches += ((pdf - again).abs() > 1e-4 * again) as u32;
                Some(w)
            });
        assert!(mismatches == 0, "{name}: {mismatches} samples off the pdf");
        assert!(integral > 0.3, "{name}: only {integral} of the draws kept");

        let frame = Frame::from_z(n);
        let wo_local = frame.to_local(wo);
        let mut sampler = Sampler::independent(Rng::new(800 + k as u64, 3));
        let mut estimate = Stats::default();
        for _ in 0..SAMPLES {
            let Some(m) = sample_bsdf_or_guide(&bsdf, wo_local, &frame, &query, &mut sampler)
            else {
                estimate.add(0.0);
                continue;
            };
            let s = m.sample;
            let expected =
                c * query.pdf(frame.to_world(s.wi)) + (1.0 - c) * bsdf.pdf(wo_local, s.wi);
            assert!(
                (s.pdf - expected).abs() <= 1e-3 * expected,
                "{name}: pdf {} against the mixture's {expected}",
                s.pdf
            );
            estimate.add((s.f.x * s.wi.z.abs() / s.pdf) as f64);
        }
        assert_z(
            &format!("{name}: albedo"),
            estimate.mean(),
            0.8,
            estimate.std_err(),
        );
        tested += 1;
        multi += (lobes.len() > 1) as usize;
        if tested >= 4 {
            break;
        }
    }
    assert!(multi >= 1, "no point mixes the borders of several regions");
    assert!(tested >= 3, "{tested} points tested");
}

#[test]
fn path_portal_agrees_with_path_on_the_veach_door() {
    agree_on_veach_door(&["path_portal", "path_portal:strategy=irradiance"]);
}

#[test]
fn face_irradiance_agrees_with_path_on_the_two_rooms() {
    agree_on_two_rooms(&[
        "path_portal:strategy=irradiance",
        "path_portal:strategy=irradiance:d_t=0.01:o_t=0.5:smoothing=1:c_portal=0.8",
        "path_portal:strategy=irradiance:face_score=radiance:mis=auto",
    ]);
}

#[test]
fn path_portal_agrees_with_path_on_the_two_rooms() {
    agree_on_two_rooms(&["path_portal", "path_portal:c_portal=0.9:smoothing=1"]);
    // Without the bound the same guide is unbiased too, with a heavier tail.
    agree_on_two_rooms(&["path_portal:ratio_max=none", "path_portal:aim=narrowest"]);
    // `path`'s trace loop gives `path_portal` `mis=auto` too.
    agree_on_two_rooms(&["path_portal:mis=auto"]);
}

#[test]
fn path_portal_agrees_with_path_on_the_ajar_door() {
    let scene = load_scene("scenes/veach-ajar-bitterli/veach-ajar-bitterli.json");
    let camera = *scene.camera().unwrap();
    agree_with_path(
        "ajar door",
        &scene,
        &camera,
        6,
        16,
        16,
        &[
            "path_portal",
            "path_portal:aim=last",
            "path_portal:strategy=irradiance",
        ],
    );
}

#[test]
fn path_portal_agrees_with_path_on_the_interior() {
    let scene = interior_builder().unwrap().build().unwrap();
    let camera = *scene.camera().unwrap();
    agree_with_path(
        "interior",
        &scene,
        &camera,
        5,
        16,
        32,
        &["path_portal", "path_portal:env=portals"],
    );
}

/// An open scene (a sphere under the sky): no rooms to guide through, so `path`'s image.
#[test]
fn an_open_scene_renders_paths_image() {
    let scene = load_scene("scenes/envmaps/sphere-diffuse.json");
    let camera = *scene.camera().unwrap();
    let settings = IntegratorSettings::default();
    let rs = RenderSettings {
        width: 24,
        height: 16,
        spp: 4,
        ..Default::default()
    };
    let path = integrator::create("path", settings).unwrap();
    let mut portal = integrator::create("path_portal", settings).unwrap();
    let pre = prepare(portal.as_mut(), &scene, &camera, None, &|_, _| true).unwrap();
    assert!(
        pre.notes.iter().any(|n| n.contains("guides nothing")),
        "{:?}",
        pre.notes
    );
    let a = render_image(&scene, &camera, path.as_ref(), &rs);
    let b = render_image(&scene, &camera, portal.as_ref(), &rs);
    let bits = |f: &lacuna::film::Film| -> Vec<[u32; 3]> {
        f.radiance()
            .iter()
            .map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
            .collect()
    };
    assert_eq!(bits(&a), bits(&b));
}

#[test]
fn options_are_validated_and_rendering_needs_the_precomputation() {
    let settings = IntegratorSettings::default();
    for (spec, needle) in [
        ("path_portal:strategy=irradiance:face_mix=2", "face_mix"),
        ("path_portal:strategy=irradiance:o_t=1", "o_t"),
        (
            "path_portal:strategy=irradiance:face_score=sum",
            "face_score",
        ),
        ("path_portal:strategy=nearest", "unknown portal strategy"),
        ("path_portal:c_portal=1", "c_portal"),
        ("path_portal:smoothing=0", "smoothing"),
        ("path_portal:resolution=2", "resolution"),
        ("path_portal:ratio_max=0.5", "ratio_max"),
        ("path_portal:aim=first", "aim"),
        ("path_portal:strength=2", "no option"),
    ] {
        let e = match integrator::create(spec, settings) {
            Ok(_) => panic!("{spec} accepted"),
            Err(e) => e.to_string(),
        };
        assert!(e.contains(needle), "{spec}: {e}");
    }
    assert!(integrator::create(
        "path_portal:strategy=shortest:c_portal=0.3:rr_depth=3",
        settings
    )
    .is_ok());
    let scene = lacuna::scene::two_rooms_builder().unwrap().build().unwrap();
    let camera = *scene.camera().unwrap();
    let unprepared = integrator::create("path_portal", settings).unwrap();
    let rs = RenderSettings {
        width: 8,
        height: 8,
        spp: 1,
        ..Default::default()
    };
    let e = match render(
        &scene,
        &camera,
        unprepared.as_ref(),
        &rs,
        &|_| true,
        &AtomicBool::new(false),
    ) {
        Ok(_) => panic!("rendering without prepare must fail"),
        Err(e) => e.to_string(),
    };
    assert!(e.contains("prepare"), "{e}");
}
