//! `path:rr_depth=auto`: the start of Russian roulette chosen per scene by a pilot
//! (src/integrator/path/roulette.rs). The choice is a deterministic function of the scene and
//! camera, later where light is found only rooms away, the default where it is not (and then
//! the image is `path`'s, bit for bit), and the render stays unbiased whatever it chooses.

mod common;

use common::agreement::{agree_with_path, render_image};
use lacuna::integrator::{self, IntegratorSettings};
use lacuna::render::{prepare, RenderSettings};
use lacuna::scene::{Camera, FamilyScene, Scene};

/// The start `path:rr_depth=auto` chose (from its precomputation note), prepared on `threads`.
fn chosen_start(scene: &Scene, camera: &Camera, max_depth: u32, threads: usize) -> u32 {
    let settings = IntegratorSettings {
        max_depth,
        ..Default::default()
    };
    let mut pt = integrator::create("path:rr_depth=auto", settings).unwrap();
    let pre = prepare(pt.as_mut(), scene, camera, Some(threads), &|_, _| true).unwrap();
    let note = pre
        .notes
        .iter()
        .find_map(|n| n.strip_prefix("rr_depth=auto: roulette from depth "))
        .expect("the pilot's note");
    note.split(' ').next().unwrap().parse().unwrap()
}

/// On a closed family interior whose light is two openings from the camera, paths must walk
/// several rooms to find light: the pilot starts roulette later than the default (5), the same
/// start on one thread and on two.
#[test]
fn auto_starts_later_where_light_is_rooms_away() {
    let family = FamilyScene::generate(3);
    let scene = family.builder().unwrap().build().unwrap();
    let one = chosen_start(&scene, &family.camera, 65, 1);
    let two = chosen_start(&scene, &family.camera, 65, 2);
    assert_eq!(one, two, "the choice depends on the thread count");
    assert!(one > 5, "rooms:3 at depth 65: roulette from {one}");
}

/// Where the light is in view (the Cornell box), the default stays, and the image is `path`'s
/// to the bit.
#[test]
fn auto_keeps_the_default_and_paths_image_where_light_is_near() {
    let scene = common::agreement::load_scene("scenes/cornell-box/cornell-box.json");
    let camera = *scene.camera().unwrap();
    assert_eq!(chosen_start(&scene, &camera, 65, 2), 5);
    let settings = IntegratorSettings {
        max_depth: 65,
        ..Default::default()
    };
    let rs = RenderSettings {
        width: 24,
        height: 24,
        spp: 8,
        ..Default::default()
    };
    let image = |spec: &str| {
        let mut pt = integrator::create(spec, settings).unwrap();
        prepare(pt.as_mut(), &scene, &camera, Some(2), &|_, _| true).unwrap();
        let film = render_image(&scene, &camera, pt.as_ref(), &rs);
        film.radiance()
            .iter()
            .flat_map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
            .collect::<Vec<u32>>()
    };
    assert_eq!(image("path"), image("path:rr_depth=auto"));
}

/// Unbiased whatever the start: `auto` (which starts later here) and a much later fixed start
/// agree with `path` on the family interior.
#[test]
fn later_starts_agree_with_path() {
    let family = FamilyScene::generate(3);
    let scene = family.builder().unwrap().build().unwrap();
    agree_with_path(
        "rooms:3",
        &scene,
        &family.camera,
        65,
        16,
        64,
        &["path:rr_depth=auto", "path:rr_depth=20"],
    );
}

/// `rr_depth=auto` and a fixed `rr_depth` override each other in the order given.
#[test]
fn rr_depth_auto_parses_and_a_later_number_overrides_it() {
    let base = IntegratorSettings::default();
    let (_, s) = integrator::parse_spec("path:rr_depth=auto", base).unwrap();
    assert!(s.path.rr_depth_auto);
    let (_, s) = integrator::parse_spec("path:rr_depth=auto:rr_depth=7", base).unwrap();
    assert!(!s.path.rr_depth_auto);
    assert_eq!(s.path.rr_start_depth, 7);
    let error = integrator::parse_spec("path:rr_depth=sometimes", base).unwrap_err();
    assert!(error.to_string().contains("integer or auto"), "{error}");
}
