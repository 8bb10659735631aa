//! The speed-against-error tool must be trustworthy: an integrator compared with itself shows
//! no speedup, a biased one is caught by its error plateau (and named when it says it is
//! biased), and the outputs are well formed.

use lacuna::compare::{
    compare, compare_scheduled, render_reference, write_report, Contender, Schedule,
};
use lacuna::integrator::{self, Integrator, IntegratorSettings};
use lacuna::math::{Rgb, Vec3};
use lacuna::render::RenderSettings;
use lacuna::scene::{Camera, Material, MeshDesc, Scene, SceneBuilder};

/// A closed grey room lit by a small ceiling quad: every bounce matters.
fn room() -> (Scene, Camera) {
    let mut b = SceneBuilder::new();
    let wall = b.add_material(Material::diffuse(Rgb::splat(0.7))).unwrap();
    let light = b
        .add_material(Material::emissive(Rgb::splat(10.0)))
        .unwrap();
    let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    let mut positions = Vec::new();
    let mut indices = Vec::new();
    let quads = [
        [
            c(-1., -1., -1.),
            c(-1., -1., 1.),
            c(1., -1., 1.),
            c(1., -1., -1.),
        ],
        [
            c(-1., 1., -1.),
            c(1., 1., -1.),
            c(1., 1., 1.),
            c(-1., 1., 1.),
        ],
        [
            c(-1., -1., -1.),
            c(1., -1., -1.),
            c(1., 1., -1.),
            c(-1., 1., -1.),
        ],
        [
            c(-1., -1., 1.),
            c(-1., 1., 1.),
            c(1., 1., 1.),
            c(1., -1., 1.),
        ],
        [
            c(-1., -1., -1.),
            c(-1., 1., -1.),
            c(-1., 1., 1.),
            c(-1., -1., 1.),
        ],
        [
            c(1., -1., -1.),
            c(1., -1., 1.),
            c(1., 1., 1.),
            c(1., 1., -1.),
        ],
    ];
    for q in quads {
        let i = positions.len() as u32;
        positions.extend(q);
        indices.extend([[i, i + 1, i + 2], [i, i + 2, i + 3]]);
    }
    b.add_mesh(MeshDesc {
        positions,
        indices,
        materials: vec![wall],
        ..Default::default()
    })
    .unwrap();
    b.add_mesh(MeshDesc {
        positions: vec![
            c(-0.2, 0.99, -0.2),
            c(0.2, 0.99, -0.2),
            c(0.2, 0.99, 0.2),
            c(-0.2, 0.99, 0.2),
        ],
        indices: vec![[0, 1, 2], [0, 2, 3]],
        materials: vec![light],
        ..Default::default()
    })
    .unwrap();
    let camera = Camera::look_at(c(0.0, 0.0, 0.9), c(0.0, -0.2, 0.0), Vec3::Y, 70.0).unwrap();
    (b.build().unwrap(), camera)
}

/// `path` at `max_depth`, as a comparison's contender or reference.
fn path_of_depth(max_depth: u32) -> Box<dyn Integrator> {
    integrator::create(
        "path",
        IntegratorSettings {
            max_depth,
            ..Default::default()
        },
    )
    .unwrap()
}

#[test]
fn self_comparison_is_neutral_and_a_dropped_bounce_plateaus() {
    let (scene, camera) = room();
    let depth = 3;
    let settings = RenderSettings {
        width: 16,
        height: 16,
        spp: 8192,
        seed: 99,
        ..Default::default()
    };
    let path = || path_of_depth(depth);
    let reference =
        render_reference(&scene, &camera, path().as_ref(), &settings, &|_| true).unwrap();
    assert!(reference.noise.mae > 0.0);
    let mut contenders = vec![
        Contender {
            label: "path".into(),
            integrator: path(),
            sampler: None,
        },
        Contender {
            label: "path again".into(),
            integrator: path(),
            sampler: None,
        },
        Contender {
            label: "path dropping a bounce".into(),
            integrator: path_of_depth(depth - 1),
            sampler: None,
        },
        // Through the registry, as `lacuna compare --integrators` makes contenders.
        Contender::from_spec(
            "vpl:clamp=0.5:count=8",
            IntegratorSettings {
                max_depth: depth,
                ..Default::default()
            },
        )
        .unwrap(),
    ];
    let ref_pixels = reference.film.radiance();
    let cmp = compare(
        &scene,
        &camera,
        &mut contenders,
        &ref_pixels,
        Some(reference.noise),
        &settings,
        0.3,
        5,
        &|_| true,
    )
    .unwrap();
    let [base, again, biased] = [&cmp.summaries[0], &cmp.summaries[1], &cmp.summaries[2]];
    assert!(
        again.indistinguishable && again.speedup.is_none(),
        "self comparison: {again:?}"
    );
    assert!(
        !biased.indistinguishable && biased.mae.min > base.mae.max,
        "bias not detected: {biased:?}"
    );
    assert!(biased.plateaued(), "biased slope {:?}", biased.slope);
    assert!(!base.plateaued(), "unbiased slope {:?}", base.slope);
    assert!(biased.time_to_baseline_error.is_none());
    // Fireflies show as the brightest pixel against the reference's: near 1 for `path`.
    for s in &cmp.summaries[..2] {
        assert!(
            (0.7..1.5).contains(&s.largest_pixel.median),
            "{}: largest pixel {:?}",
            s.label,
            s.largest_pixel
        );
    }

    let dir = std::env::temp_dir().join(format!("lacuna-compare-{}", std::process::id()));
    write_report(&dir, &cmp, &ref_pixels, 16, 16, "test room").unwrap();
    let svg = std::fs::read_to_string(dir.join("convergence.svg")).unwrap();
    let doc = roxmltree::Document::parse(&svg).expect("convergence.svg is well-formed XML");
    let paths = doc.descendants().filter(|n| n.has_tag_name("path")).count();
    assert_eq!(paths, 4, "one path per integrator");
    let csv = std::fs::read_to_string(dir.join("curves.csv")).unwrap();
    assert!(csv.starts_with("integrator,run,seconds,spp,mae,rmse,rel_mse\n"));
    assert_eq!(csv.lines().count() - 1, cmp.points.len());
    let summary = std::fs::read_to_string(dir.join("summary.md")).unwrap();
    assert!(summary.contains("within run-to-run spread") && summary.contains("plateau"));
    assert!(
        summary.contains("| largest pixel / reference's |"),
        "{summary}"
    );
    // The summary says which contender is biased by construction, and why.
    assert!(
        summary.contains("\nvpl:clamp=0.5:count=8 is biased: VPL geometry term clamped"),
        "{summary}"
    );
    assert!(!summary.contains("\npath is biased"), "{summary}");
    for name in ["path", "path_again", "path_dropping_a_bounce"] {
        for suffix in [".exr", ".png", "_error.png"] {
            assert!(
                dir.join(format!("{name}{suffix}")).exists(),
                "{name}{suffix}"
            );
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// `Schedule::Concurrent` runs the contenders of a run at the same time, each on its own
/// threads: every contender still gets its runs, its film and its summary, an integrator raced
/// against itself stays indistinguishable, a dropped bounce is still caught, and the summary
/// says how the machine was shared.
#[test]
fn concurrent_contenders_share_the_machine_and_keep_their_ratios() {
    let (scene, camera) = room();
    let depth = 3;
    let settings = RenderSettings {
        width: 16,
        height: 16,
        spp: 4096,
        seed: 7,
        threads: Some(1),
        ..Default::default()
    };
    let reference = render_reference(
        &scene,
        &camera,
        path_of_depth(depth).as_ref(),
        &settings,
        &|_| true,
    )
    .unwrap();
    let contender = |label: &str, max_depth| Contender {
        label: label.into(),
        integrator: path_of_depth(max_depth),
        sampler: None,
    };
    let mut contenders = vec![
        contender("path", depth),
        contender("path again", depth),
        contender("path dropping a bounce", depth - 1),
    ];
    let ref_pixels = reference.film.radiance();
    let runs = 4;
    let cmp = compare_scheduled(
        &scene,
        &camera,
        &mut contenders,
        &ref_pixels,
        Some(reference.noise),
        &settings,
        0.3,
        runs,
        Schedule::Concurrent,
        &|_| true,
    )
    .unwrap();
    assert_eq!(cmp.schedule, Schedule::Concurrent);
    assert_eq!(cmp.results.len(), 3 * runs as usize);
    for c in 0..3 {
        let mut seen: Vec<u32> = cmp
            .results
            .iter()
            .filter(|r| r.contender == c)
            .map(|r| r.run)
            .collect();
        seen.sort();
        assert_eq!(seen, (0..runs).collect::<Vec<_>>(), "contender {c}");
        assert!(cmp.points.iter().any(|p| p.contender == c));
    }
    assert_eq!(cmp.films.len(), 3);
    let [base, again, biased] = [&cmp.summaries[0], &cmp.summaries[1], &cmp.summaries[2]];
    assert!(
        again.indistinguishable && again.speedup.is_none(),
        "self comparison: {again:?}"
    );
    assert!(
        !biased.indistinguishable && biased.mae.min > base.mae.max,
        "bias not detected: {biased:?}"
    );
    let dir =
        std::env::temp_dir().join(format!("lacuna-compare-concurrent-{}", std::process::id()));
    write_report(&dir, &cmp, &ref_pixels, 16, 16, "test room").unwrap();
    let summary = std::fs::read_to_string(dir.join("summary.md")).unwrap();
    assert!(summary.contains("at the same time"), "{summary}");
    std::fs::remove_dir_all(&dir).ok();
}
