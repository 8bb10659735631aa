//! Renders with the trees of the two BVH builders, `BvhQuality::Fast` (the binned 8-wide
//! build) and `BvhQuality::Medium` (PLOC, reinsertion and the conversion): different trees
//! over the same triangles must give the same images within noise. Region means of the path
//! tracer over seeds, z-tested as the integrators' agreement tests are (tests/common).

mod common;

use common::agreement::{assert_agree, region_means};
use lacuna::geometry::BvhQuality;
use lacuna::integrator::IntegratorSettings;
use lacuna::scene::Scene;

/// A scene file of the repository, built with the given BVH quality.
fn scene_with(path: &str, quality: BvhQuality) -> Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(path);
    let mut loaded = lacuna::scene::load_scene_file(&path).unwrap();
    loaded.builder.set_bvh_quality(quality);
    loaded.builder.build().unwrap()
}

/// The Cornell box (a few dozen triangles: one collapsed binary tree) and the ajar door (tens
/// of thousands: binned top levels over collapsed subtrees), small images, few samples.
#[test]
fn fast_and_medium_trees_render_alike() {
    for (path, max_depth, size, spp) in [
        ("scenes/cornell-box/cornell-box.json", 8, 16, 16),
        (
            "scenes/veach-ajar-bitterli/veach-ajar-bitterli.json",
            6,
            16,
            16,
        ),
    ] {
        let fast = scene_with(path, BvhQuality::Fast);
        let medium = scene_with(path, BvhQuality::Medium);
        let camera = *fast.camera().unwrap();
        let settings = IntegratorSettings {
            max_depth,
            ..Default::default()
        };
        let a = region_means(&fast, &camera, "path", settings, size, spp, 8);
        let b = region_means(&medium, &camera, "path", settings, size, spp, 8);
        assert!(a[0].0 > 0.0, "{path}: black image");
        assert_agree(path, ("fast", &a), ("medium", &b));
    }
}
