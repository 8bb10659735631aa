//! What the training pass of `c_skel=learned` / `strength=learned` chose, per node (issue 8,
//! round 5): samples, non-zero samples, mean vertices per estimate, the best candidate's
//! variance x cost relative to not guiding (before the significance rule), the chosen
//! probability and strength.
//!
//! `cargo run --release --example guide_training -- SCENE [OPTION=VALUE ...]` with SCENE a
//! scene file or `corridor`, options as `path_skeleton`'s (`c_skel=learned`
//! `strength=learned` `training_cost=vertex` ...; default `c_skel=learned strength=learned`,
//! which implies `directions=lobes`: add `strength=auto` for `path_skeleton`'s default, the
//! learned directions).

use std::path::Path;

use lacuna::guide::{SkeletonGuide, SkeletonGuideSettings};
use lacuna::scene::load_scene_arg;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 2 {
        eprintln!("usage: guide_training SCENE [OPTION=VALUE ...]");
        std::process::exit(2);
    }
    let scene = load_scene_arg(Path::new(&args[1]))
        .unwrap()
        .0
        .builder
        .build()
        .unwrap();
    let mut settings = SkeletonGuideSettings::default();
    let options: Vec<&String> = args[2..].iter().collect();
    let defaults = ["c_skel=learned".to_string(), "strength=learned".to_string()];
    for option in defaults.iter().chain(options) {
        let (key, value) = option.split_once('=').expect("OPTION=VALUE");
        settings.set(key, value).unwrap();
    }
    let guide = SkeletonGuide::build(&scene, scene.camera(), &settings, &|_, _| true).unwrap();
    let t = guide.training().expect("a training pass");
    println!(
        "# {} nodes, {} training paths, {:.3} s precomputation",
        guide.node_count(),
        t.paths,
        guide.total_seconds()
    );
    println!("node\tposition\tradius\tlobes\tsamples\tnonzero\tremaining\tbest_ratio\tc\tstrength");
    for k in 0..guide.node_count() {
        let node = k as u32;
        println!(
            "{k}\t{}\t{:.3}\t{}\t{}\t{}\t{:.2}\t{:.3}\t{}\t{}",
            guide.node_position(node).unwrap(),
            guide.node_radius(node).unwrap(),
            guide.lobes(node).len(),
            t.samples[k],
            t.nonzero[k],
            t.mean_remaining[k],
            t.best_ratio[k],
            t.probabilities[k],
            t.strengths[k]
        );
    }
    println!("# guided: {} of {}", t.guided_nodes(), guide.node_count());
    let sc = &t.scene;
    let per_path = |x: u64| x as f64 / t.paths.max(1) as f64;
    if let Some(v) = sc.path_variance_ratio {
        println!("# path-level variance {v:.4}x (cost_model=paths)");
    }
    println!(
        "# scene-level: variance {:.4}x, cost {:.4}x, efficiency {:.4}x, switched off: {}; per training path: {:.3} vertices, {:.3} guided, {:.3} mapped",
        sc.variance_ratio,
        sc.cost_ratio,
        sc.efficiency(),
        sc.switched_off,
        per_path(sc.vertices),
        per_path(sc.guided_vertices),
        per_path(sc.mapped_vertices)
    );
}
