//! Empty-space analysis against its invariants (000 Definitions 10.7-10.12) on random grids,
//! and on known shapes: rooms joined by a narrow door.

use std::collections::{HashSet, VecDeque};

use lacuna::analysis::{
    distance_map, find_portals, label_regions, opening_map_26, Analysis, AnalysisSettings, Metric,
    Outside, Resolution, VoxelGrid, VoxelSet, NO_REGION,
};
use lacuna::math::{Rng, Vec3};
use lacuna::scene::{load_obj, two_rooms_builder, SceneBuilder};

fn neighbours(grid: &VoxelGrid, i: usize) -> Vec<usize> {
    let c = grid.coords(i);
    let mut out = Vec::new();
    for axis in 0..3 {
        for d in [-1i64, 1] {
            let mut n = [c[0] as i64, c[1] as i64, c[2] as i64];
            n[axis] += d;
            if n[axis] >= 0 && (n[axis] as usize) < grid.dims[axis] {
                out.push(grid.index(n[0] as usize, n[1] as usize, n[2] as usize));
            }
        }
    }
    out
}

/// Every empty voxel is labelled, occupied ones are not; every region is 6-connected; region
/// roots have opening = distance; portals hold exactly the faces between different regions.
#[test]
fn labeling_and_portal_invariants_on_random_grids() {
    let mut rng = Rng::new(31, 0);
    for (dims, density) in [
        ([10, 9, 8], 0.05f32),
        ([16, 12, 10], 0.15),
        ([24, 8, 16], 0.3),
        ([12, 12, 12], 0.0),
    ] {
        let grid = VoxelGrid {
            dims,
            origin: [0.0; 3],
            voxel_size: 0.5,
        };
        let mut occ = VoxelSet::new(grid.len());
        for i in 0..grid.len() {
            if rng.uniform() < density {
                occ.set(i);
            }
        }
        let d = distance_map(dims, &occ, Metric::Chessboard, Outside::Solid, false).values;
        let om = opening_map_26(dims, &d);
        let lab = label_regions(&grid, &om);
        for i in 0..grid.len() {
            assert_eq!(occ.get(i), lab.labels[i] == NO_REGION, "voxel {i}");
            if om.is_root(i) {
                assert_eq!(om.opening[i], d[i]);
                assert_eq!(lab.regions[lab.labels[i] as usize].opening, om.opening[i]);
            }
        }
        // 6-connectivity of every region: a flood fill inside the label reaches all its voxels.
        let mut seen = vec![false; grid.len()];
        let mut components_per_label = vec![0u32; lab.regions.len()];
        for s in 0..grid.len() {
            if seen[s] || lab.labels[s] == NO_REGION {
                continue;
            }
            let l = lab.labels[s];
            components_per_label[l as usize] += 1;
            let mut queue = VecDeque::from([s]);
            seen[s] = true;
            while let Some(i) = queue.pop_front() {
                for j in neighbours(&grid, i) {
                    if !seen[j] && lab.labels[j] == l {
                        seen[j] = true;
                        queue.push_back(j);
                    }
                }
            }
        }
        assert!(
            components_per_label.iter().all(|&c| c == 1),
            "{dims:?}: {components_per_label:?}"
        );
        // Portals: exactly the faces between 6-neighbours of different regions, each once.
        let portals = find_portals(&grid, &lab.labels);
        let mut faces = HashSet::new();
        for p in &portals {
            assert!(p.regions.0 < p.regions.1);
            for f in &p.faces {
                let i = f.voxel as usize;
                let j = i + [1, dims[0], dims[0] * dims[1]][f.axis as usize];
                let pair = (
                    lab.labels[i].min(lab.labels[j]),
                    lab.labels[i].max(lab.labels[j]),
                );
                assert_eq!(pair, p.regions);
                assert!(faces.insert((i, j)));
            }
            assert!((p.area - p.faces.len() as f32 * 0.25).abs() < 1e-4);
        }
        let mut expected = 0;
        for i in 0..grid.len() {
            for j in neighbours(&grid, i) {
                if j > i
                    && lab.labels[i] != NO_REGION
                    && lab.labels[j] != NO_REGION
                    && lab.labels[i] != lab.labels[j]
                {
                    expected += 1;
                }
            }
        }
        assert_eq!(faces.len(), expected);
    }
}

/// Region graph: which regions share a portal.
fn connected(a: &Analysis, from: u32, to: u32) -> bool {
    let mut seen = HashSet::from([from]);
    let mut queue = VecDeque::from([from]);
    while let Some(r) = queue.pop_front() {
        if r == to {
            return true;
        }
        for p in &a.portals {
            let other = if p.regions.0 == r {
                p.regions.1
            } else if p.regions.1 == r {
                p.regions.0
            } else {
                continue;
            };
            if seen.insert(other) {
                queue.push_back(other);
            }
        }
    }
    false
}

/// The built-in scene: the two rooms are two big regions joined by a portal in the doorway.
#[test]
fn two_rooms_are_two_regions_joined_at_the_door() {
    let scene = two_rooms_builder().unwrap().build().unwrap();
    let settings = AnalysisSettings {
        resolution: Resolution::LongestAxis(128),
        ..Default::default()
    };
    let a = Analysis::build(&scene, &settings, &|_, _| true).unwrap();
    let far = a.label_at(Vec3::new(2.0, 1.25, -2.0)).unwrap();
    let near = a.label_at(Vec3::new(2.0, 1.25, 2.0)).unwrap();
    assert_ne!(far, near);
    let room_opening = a.regions[far as usize]
        .opening
        .min(a.regions[near as usize].opening);
    assert!(
        room_opening as f64 * a.grid.voxel_size > 0.8,
        "rooms should be big regions"
    );
    let portal = a
        .portals
        .iter()
        .find(|p| p.regions == (far.min(near), far.max(near)))
        .expect("a portal joins the rooms");
    let c = portal.center;
    assert!(
        (1.4..2.5).contains(&c.x) && (0.0..2.1).contains(&c.y) && (-0.3..0.5).contains(&c.z),
        "portal centre {c}"
    );
    // Sampled portal points lie on its faces, with density 1 / area.
    for k in 0..20 {
        let index = a.portals.iter().position(|p| p == portal).unwrap();
        let (p, n, pdf) = a
            .sample_portal(index, k as f32 / 20.0, lacuna::math::Vec2::new(0.3, 0.7))
            .unwrap();
        assert!((pdf - 1.0 / portal.area).abs() < 1e-6 * pdf && n.length() == 1.0);
        assert!((p - c).length() < 1.5, "{p}");
    }
    assert!(a
        .sample_portal(a.portals.len(), 0.5, lacuna::math::Vec2::ZERO)
        .is_err());
}

/// Veach's door (pg2015 version, Z up): the front and back rooms are distinct regions linked
/// through the portal graph, and the back room's region has a portal in the door's opening.
#[test]
fn veach_door_rooms_are_separated_at_the_door() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/veach-door-pg2015/veach-door.obj");
    let mut b = SceneBuilder::new();
    load_obj(&path, &mut b, None).unwrap();
    let scene = b.build().unwrap();
    let settings = AnalysisSettings {
        resolution: Resolution::LongestAxis(118),
        ..Default::default()
    };
    let a = Analysis::build(&scene, &settings, &|_, _| true).unwrap();
    let front = a.label_at(Vec3::new(-20.0, -100.0, 72.0)).unwrap();
    let back = a.label_at(Vec3::new(0.0, 220.0, 72.0)).unwrap();
    assert_ne!(front, back);
    assert!(
        connected(&a, front, back),
        "light must have a way from the back room to the front room"
    );
    let door_portal = a.portals.iter().any(|p| {
        (p.regions.0 == back || p.regions.1 == back)
            && (50.0..100.0).contains(&p.center.y)
            && (40.0..140.0).contains(&p.center.x)
    });
    assert!(door_portal, "no portal of the back room in the doorway");
}

/// Memory budget: a grid over the budget is refused with a clear error before allocation;
/// cancellation stops the pipeline.
#[test]
fn budget_and_cancellation() {
    let scene = two_rooms_builder().unwrap().build().unwrap();
    let settings = AnalysisSettings {
        resolution: Resolution::LongestAxis(512),
        memory_budget: 1 << 20,
        ..Default::default()
    };
    let err = Analysis::build(&scene, &settings, &|_, _| true)
        .err()
        .unwrap();
    assert!(matches!(err, lacuna::Error::OverBudget { .. }), "{err}");
    let settings = AnalysisSettings {
        resolution: Resolution::LongestAxis(32),
        ..Default::default()
    };
    let err = Analysis::build(&scene, &settings, &|stage, _| stage != "distance 26")
        .err()
        .unwrap();
    assert!(matches!(err, lacuna::Error::Cancelled));
    let settings = AnalysisSettings {
        resolution: Resolution::LongestAxis(32),
        all_maps: true,
        fill_interiors: true,
        ..Default::default()
    };
    let a = Analysis::build(&scene, &settings, &|_, _| true).unwrap();
    assert!(a.decenterness_l1.is_some() && a.memory().total() > 0);
    assert!(a.opening_at(Vec3::splat(1e6)).is_none());
}

/// Without the regions (what the skeleton guide asks for) the analysis holds the same
/// occupancy and skeleton maps, computes no 26-distance, opening, labels or portals, answers
/// region queries with "none", reports every stage it ran and reaches progress 1.
#[test]
fn skeleton_maps_without_regions() {
    let scene = two_rooms_builder().unwrap().build().unwrap();
    let full = AnalysisSettings {
        resolution: Resolution::LongestAxis(40),
        all_maps: true,
        ..Default::default()
    };
    let lean = AnalysisSettings {
        regions: false,
        ..full.clone()
    };
    let a = Analysis::build(&scene, &full, &|_, _| true).unwrap();
    let last = std::sync::Mutex::new(0.0f64);
    let b = Analysis::build(&scene, &lean, &|_, f| {
        *last.lock().unwrap() = f;
        true
    })
    .unwrap();
    assert_eq!(*last.lock().unwrap(), 1.0);
    assert!(a.has_regions && !b.has_regions);
    assert_eq!(a.occupied, b.occupied);
    assert_eq!(a.distance_l1, b.distance_l1);
    assert_eq!(a.distance_sq_euclidean, b.distance_sq_euclidean);
    assert_eq!(a.opening_l1, b.opening_l1);
    assert_eq!(a.decenterness_l1, b.decenterness_l1);
    assert!(b.distance26.is_empty() && b.labels.is_empty() && b.portals.is_empty());
    assert!(b.regions.is_empty() && b.opening.opening.is_empty());
    let stages: Vec<&str> = b.timings.iter().map(|t| t.stage).collect();
    assert!(!stages.contains(&"distance 26") && !stages.contains(&"portals"));
    assert!(stages.contains(&"distance L1"));
    let inside = a
        .grid
        .voxel_center(a.grid.index(a.grid.dims[0] / 2, a.grid.dims[1] / 2, 5));
    assert!(a.opening_at(inside).is_some() && b.opening_at(inside).is_none());
    assert!(b.label_at(inside).is_none());
    assert!(b
        .sample_portal(0, 0.5, lacuna::math::Vec2::new(0.5, 0.5))
        .is_err());
    assert!(Analysis::estimate_bytes(&b.grid, &lean) < Analysis::estimate_bytes(&a.grid, &full));
    assert!(b.memory().total() < a.memory().total());
}
