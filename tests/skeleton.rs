//! The curvilinear skeleton of the empty space (000 §5.2-6.4) against closed-form topology
//! (research/skeleton.md §5.3), a GF(2) homology oracle on random grids, and the built-in
//! scenes.

use std::collections::VecDeque;

use lacuna::analysis::{
    distance_map, node_map_seeds, opening_map_l1, Analysis, AnalysisSettings, Complex, Graph,
    Metric, Outside, Resolution, Skeleton, SkeletonSettings, VoxelGrid, VoxelSet, UNDEFINED_NODE,
};
use lacuna::math::{Rng, Vec3};
use lacuna::scene::{corridor_builder, two_rooms_builder};

fn grid(dims: [usize; 3]) -> VoxelGrid {
    VoxelGrid {
        dims,
        origin: [0.0; 3],
        voxel_size: 0.25,
    }
}

fn solid(dims: [usize; 3], f: impl Fn(usize, usize, usize) -> bool) -> VoxelSet {
    let g = grid(dims);
    let mut s = VoxelSet::new(g.len());
    for i in 0..g.len() {
        let [x, y, z] = g.coords(i);
        if f(x, y, z) {
            s.set(i);
        }
    }
    s
}

fn skeleton_of(dims: [usize; 3], occ: &VoxelSet, parallel: bool) -> Skeleton {
    let d1 = distance_map(dims, occ, Metric::L1, Outside::Solid, false).values;
    let o1 = opening_map_l1(dims, &d1);
    let dc: Vec<u32> = o1
        .iter()
        .zip(&d1)
        .map(|(o, d)| o.saturating_sub(*d))
        .collect();
    // The sequential build is given the Euclidean distance; the parallel one computes it
    // beside the thinning (the default schedule), so comparing them also compares the two.
    let sq = (!parallel)
        .then(|| distance_map(dims, occ, Metric::SquaredEuclidean, Outside::Solid, false).values);
    Skeleton::from_maps(
        grid(dims),
        occ,
        &d1,
        &dc,
        sq.as_deref(),
        &SkeletonSettings {
            parallel,
            topology: true,
        },
        &|_, _| true,
        Vec::new(),
    )
    .unwrap()
}

/// Breadth-first reach through empty voxels from `seeds`, through face neighbours (6) or
/// also edge and corner neighbours (26).
fn reach(g: &VoxelGrid, occ: &VoxelSet, seeds: &[usize], full: bool) -> Vec<bool> {
    let mut seen = vec![false; g.len()];
    let mut queue: VecDeque<usize> = seeds.iter().copied().collect();
    for &q in seeds {
        seen[q] = true;
    }
    while let Some(i) = queue.pop_front() {
        let c = g.coords(i).map(|x| x as i64);
        for dz in -1i64..=1 {
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let order = dx.abs() + dy.abs() + dz.abs();
                    if order == 0 || (!full && order > 1) {
                        continue;
                    }
                    let n = [c[0] + dx, c[1] + dy, c[2] + dz];
                    if (0..3).any(|a| n[a] < 0 || n[a] >= g.dims[a] as i64) {
                        continue;
                    }
                    let j = g.index(n[0] as usize, n[1] as usize, n[2] as usize);
                    if !occ.get(j) && !seen[j] {
                        seen[j] = true;
                        queue.push_back(j);
                    }
                }
            }
        }
    }
    seen
}

/// The node map is total on the components of the empty space (26-connected, the complex's
/// convention) that hold a node's seed voxel, and empty elsewhere; a voxel 6-reachable from
/// the seeds maps to a node whose seed is 6-reachable from it (Algorithm 5).
fn check_node_map(s: &Skeleton, occ: &VoxelSet) {
    let g = &s.grid;
    let nodes = &s.filtered.graph.nodes;
    let seeds = node_map_seeds(g, occ, nodes);
    let mut seed_voxels = Vec::new();
    for (n, seed) in nodes.iter().zip(&seeds) {
        assert!(!occ.get(n.voxel as usize), "node voxel is empty");
        let Some(q) = *seed else { continue };
        let c = g.coords(q as usize);
        assert!((0..3).all(|a| n.lattice[a] as usize == c[a] || n.lattice[a] as usize == c[a] + 1));
        assert!(!occ.get(q as usize) && !seed_voxels.contains(&(q as usize)));
        seed_voxels.push(q as usize);
    }
    let six = reach(g, occ, &seed_voxels, false);
    let all = reach(g, occ, &seed_voxels, true);
    for i in 0..g.len() {
        assert_eq!(all[i], s.node_map[i] != UNDEFINED_NODE, "voxel {i}");
        if all[i] {
            assert!((s.node_map[i] as usize) < nodes.len());
        }
    }
    // Phase 1 stays within 6-components.
    let mut comp = vec![u32::MAX; g.len()];
    let mut count = 0;
    let mut stack = Vec::new();
    for start in 0..g.len() {
        if occ.get(start) || comp[start] != u32::MAX {
            continue;
        }
        comp[start] = count;
        stack.push(start);
        while let Some(i) = stack.pop() {
            let c = g.coords(i);
            for a in 0..3 {
                for up in [false, true] {
                    if (!up && c[a] == 0) || (up && c[a] + 1 == g.dims[a]) {
                        continue;
                    }
                    let mut n = c;
                    n[a] = if up { c[a] + 1 } else { c[a] - 1 };
                    let j = g.index(n[0], n[1], n[2]);
                    if !occ.get(j) && comp[j] == u32::MAX {
                        comp[j] = count;
                        stack.push(j);
                    }
                }
            }
        }
        count += 1;
    }
    for i in 0..g.len() {
        if six[i] {
            let node = s.node_map[i] as usize;
            let seed = seeds[node].expect("a mapped node has a seed") as usize;
            assert_eq!(comp[i], comp[seed], "voxel {i} mapped across a diagonal");
        }
    }
}

/// The checks every skeleton must pass; returns the empty-space (b0, b1, b2).
fn check(dims: [usize; 3], occ: &VoxelSet, expected: Option<(usize, usize, usize)>) -> Skeleton {
    let s = skeleton_of(dims, occ, true);
    let e = s.empty_space.unwrap();
    if let Some(x) = expected {
        assert_eq!((e.b0, e.b1, e.b2), x, "empty-space Betti numbers");
        assert_eq!(e.euler, x.0 as i64 - x.1 as i64 + x.2 as i64);
    }
    assert_eq!(s.thinning.forced_pierces, 0);
    assert_eq!(s.thinning.pierced as usize, e.b2);
    for graph in [&s.raw, &s.filtered.graph] {
        assert_eq!(graph.components(), e.b0);
        assert_eq!(graph.cycle_rank(), e.b1);
    }
    // Every node is a corner of its (empty) voxel, every edge joins lattice neighbours.
    let complex = Complex::from_occupied(dims, occ);
    for n in &s.raw.nodes {
        assert!(!occ.get(n.voxel as usize));
        let c = s.grid.coords(n.voxel as usize);
        assert!((0..3).all(|a| n.lattice[a] as usize == c[a] || n.lattice[a] as usize == c[a] + 1));
        let l = n.lattice.map(|x| x as usize);
        assert!(complex.has(complex.vertex(l[0], l[1], l[2]), 0));
    }
    for &[a, b] in &s.raw.edges {
        let (p, q) = (
            s.raw.nodes[a as usize].lattice,
            s.raw.nodes[b as usize].lattice,
        );
        let d: u32 = (0..3).map(|k| p[k].abs_diff(q[k])).sum();
        assert_eq!(d, 1);
    }
    assert!(s.filtered.graph.nodes.len() <= s.raw.nodes.len());
    check_node_map(&s, occ);
    s
}

const D: [usize; 3] = [24, 18, 20];

#[test]
fn closed_form_shapes() {
    // No solid.
    check(D, &solid(D, |_, _, _| false), Some((1, 0, 0)));
    // Floating cube.
    check(
        D,
        &solid(D, |x, y, z| {
            (8..14).contains(&x) && (6..11).contains(&y) && (7..13).contains(&z)
        }),
        Some((1, 0, 1)),
    );
    // N pillars joining floor and ceiling (the grid boundary).
    for n in 1..=3usize {
        let s = check(
            D,
            &solid(D, |x, _, z| {
                (0..n).any(|k| (3 + 7 * k..6 + 7 * k).contains(&x)) && (8..12).contains(&z)
            }),
            Some((1, n, 0)),
        );
        assert_eq!(s.raw.cycle_rank(), n);
    }
    // Table: a top and k legs on the floor, not touching the ceiling.
    for k in [2usize, 3, 4] {
        let legs = [(3, 3), (17, 3), (3, 14), (17, 14)];
        check(
            D,
            &solid(D, |x, y, z| {
                let top = (3..21).contains(&x) && (8..11).contains(&y) && (3..17).contains(&z);
                let leg = y < 8
                    && legs[..k]
                        .iter()
                        .any(|&(lx, lz)| (lx..lx + 3).contains(&x) && (lz..lz + 3).contains(&z));
                top || leg
            }),
            Some((1, k - 1, 0)),
        );
    }
    // Floating solid torus (square section).
    check(
        D,
        &solid(D, |x, y, z| {
            let ring = (5..19).contains(&x) && (5..15).contains(&z);
            let hole = (9..15).contains(&x) && (9..11).contains(&z);
            ring && !hole && (7..11).contains(&y)
        }),
        Some((1, 1, 1)),
    );
    // Floating thick hollow box, then with 1, 2 and 3 holes.
    for holes in 0..=3usize {
        check(
            D,
            &solid(D, |x, y, z| {
                let outer = (3..21).contains(&x) && (3..15).contains(&y) && (3..17).contains(&z);
                let inner = (6..18).contains(&x) && (6..12).contains(&y) && (6..14).contains(&z);
                // Holes through the -z, +z and +x walls.
                let hole = (holes > 0 && (10..13).contains(&x) && (8..11).contains(&y) && z < 6)
                    || (holes > 1 && (10..13).contains(&x) && (8..11).contains(&y) && z >= 14)
                    || (holes > 2 && (8..11).contains(&y) && (9..12).contains(&z) && x >= 18);
                outer && !inner && !hole
            }),
            Some(if holes == 0 {
                (2, 0, 1)
            } else {
                (1, holes - 1, 1)
            }),
        );
    }
    // Wall splitting the box, with 0..3 doors.
    for doors in 0..=3usize {
        check(
            D,
            &solid(D, |x, y, z| {
                let wall = (10..13).contains(&z);
                let door = (0..doors).any(|k| (2 + 7 * k..5 + 7 * k).contains(&x)) && y < 10;
                wall && !door
            }),
            Some(if doors == 0 {
                (2, 0, 0)
            } else {
                (1, doors - 1, 0)
            }),
        );
    }
}

#[test]
fn random_grids_against_gf2_oracle() {
    let mut rng = Rng::new(17, 4);
    for case in 0..40 {
        let dims = [4 + case % 5, 3 + (case * 3) % 5, 3 + (case * 7) % 4];
        let density = [0.08f32, 0.2, 0.35, 0.5][case % 4];
        let g = grid(dims);
        let mut occ = VoxelSet::new(g.len());
        for i in 0..g.len() {
            if rng.uniform() < density {
                occ.set(i);
            }
        }
        let oracle = Complex::from_occupied(dims, &occ).betti_gf2();
        let s = check(dims, &occ, Some((oracle[0], oracle[1], oracle[2])));
        assert_eq!(oracle[3], 0);
        let seq = skeleton_of(dims, &occ, false);
        assert_eq!(seq.raw, s.raw);
    }
}

#[test]
fn parallel_equals_sequential_and_rerun_is_identical() {
    let mut rng = Rng::new(5, 77);
    let dims = [48, 40, 36];
    let g = grid(dims);
    let mut occ = VoxelSet::new(g.len());
    // Random boxes: pillars, slabs and floating blocks.
    for _ in 0..40 {
        let lo = [0, 1, 2].map(|a| (rng.uniform() * dims[a] as f32) as usize);
        let ext = [0, 1, 2].map(|_| 2 + (rng.uniform() * 8.0) as usize);
        for z in lo[2]..(lo[2] + ext[2]).min(dims[2]) {
            for y in lo[1]..(lo[1] + ext[1]).min(dims[1]) {
                for x in lo[0]..(lo[0] + ext[0]).min(dims[0]) {
                    occ.set(g.index(x, y, z));
                }
            }
        }
    }
    let seq = skeleton_of(dims, &occ, false);
    for threads in [1, 2, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let par = pool.install(|| skeleton_of(dims, &occ, true));
        assert_eq!(par.raw, seq.raw, "{threads} threads");
        assert_eq!(par.filtered.graph, seq.filtered.graph);
        assert_eq!(par.node_map, seq.node_map);
        let again = pool.install(|| skeleton_of(dims, &occ, true));
        assert_eq!(again.raw, par.raw);
    }
    check(dims, &occ, None);
}

/// Breadth-first path between two nodes.
fn path(g: &Graph, from: u32, to: u32) -> Option<Vec<u32>> {
    let adj = g.adjacency();
    let mut prev = vec![u32::MAX; g.nodes.len()];
    prev[from as usize] = from;
    let mut q = VecDeque::from([from]);
    while let Some(u) = q.pop_front() {
        if u == to {
            let mut p = vec![to];
            let mut c = to;
            while c != from {
                c = prev[c as usize];
                p.push(c);
            }
            return Some(p);
        }
        for &v in &adj[u as usize] {
            if prev[v as usize] == u32::MAX {
                prev[v as usize] = u;
                q.push_back(v);
            }
        }
    }
    None
}

fn analyse(builder: lacuna::scene::SceneBuilder, resolution: u32) -> (Analysis, Skeleton) {
    let scene = builder.build().unwrap();
    let settings = AnalysisSettings {
        resolution: Resolution::LongestAxis(resolution),
        all_maps: true,
        ..Default::default()
    };
    let a = Analysis::build(&scene, &settings, &|_, _| true).unwrap();
    let s = Skeleton::build(&a, &SkeletonSettings::default(), &|_, _| true).unwrap();
    (a, s)
}

#[test]
fn two_rooms_path_goes_through_the_door() {
    let (a, s) = analyse(two_rooms_builder().unwrap(), 128);
    let e = s.empty_space.unwrap();
    for graph in [&s.raw, &s.filtered.graph] {
        assert_eq!(graph.components(), e.b0);
        assert_eq!(graph.cycle_rank(), e.b1);
    }
    check_node_map(&s, &a.occupied);
    let g = &s.filtered.graph;
    let inside = |p: Vec3| p.x > 0.2 && p.x < 3.8 && p.y > 0.2 && p.y < 2.3;
    let near = g
        .nodes
        .iter()
        .position(|n| inside(n.position) && n.position.z > 1.0);
    let far = g
        .nodes
        .iter()
        .position(|n| inside(n.position) && n.position.z < -1.0);
    let (near, far) = (
        near.expect("camera-room node") as u32,
        far.expect("far-room node") as u32,
    );
    let p = path(g, near, far).expect("the rooms are joined through the door");
    let through_door = |n: &u32| {
        let q = g.nodes[*n as usize].position;
        (-0.2..=0.1).contains(&q.z) && (1.4..=2.5).contains(&q.x) && q.y < 2.1
    };
    assert!(p.iter().any(through_door), "path misses the doorway");
    // The map sends a point on the camera-room floor, seen from above, to a camera-room node.
    let node = s
        .map_point(
            Vec3::new(3.0, 0.0, 3.0),
            Vec3::Y,
            Vec3::new(0.0, 1.0, 0.2).normalize(),
        )
        .unwrap();
    let q = g.nodes[node as usize].position;
    assert!(q.z > 0.0 && q.y > 0.0, "floor point mapped to {q}");
    // Next to the one-voxel wall at x = 0 the voxels diagonally above the floor on both sides
    // of the wall score the same; the incident direction picks the room, not the outside.
    for x in [0.005f32, 0.02, 0.04] {
        let node = s
            .map_point(
                Vec3::new(x, 0.0, 3.0),
                Vec3::Y,
                Vec3::new(1.0, 1.0, 0.0).normalize(),
            )
            .unwrap();
        let q = g.nodes[node as usize].position;
        assert!(
            inside(q) && q.z > 0.0,
            "floor point at x = {x} mapped to {q}"
        );
    }
}

#[test]
fn corridor_gives_a_corridor_line() {
    let (a, s) = analyse(corridor_builder().unwrap(), 96);
    check_node_map(&s, &a.occupied);
    let e = s.empty_space.unwrap();
    assert_eq!(s.raw.cycle_rank(), e.b1);
    // The component inside the corridor: nodes within the floor plan.
    let g = &s.raw;
    let inside =
        |p: Vec3| p.y > 0.1 && p.y < 7.4 && p.x > -13.1 && p.x < 7.3 && p.z > -6.1 && p.z < 10.6;
    let (labels, _) = g.component_labels();
    let start = g.nodes.iter().position(|n| inside(n.position)).unwrap();
    let comp = labels[start];
    let members: Vec<usize> = (0..g.nodes.len()).filter(|&i| labels[i] == comp).collect();
    assert!(members.iter().all(|&i| inside(g.nodes[i].position)));
    // A tree (the floating lamp makes a cavity, which piercing removes) ...
    let edges = g
        .edges
        .iter()
        .filter(|e| labels[e[0] as usize] == comp)
        .count();
    assert_eq!(edges + 1, members.len(), "corridor skeleton is a tree");
    // ... whose longest path runs from bay A (z < -1.1) through bay B to bay C (z > 4.5).
    let far_end = |from: u32| -> (u32, Vec<u32>) {
        let mut best = (from, vec![from]);
        for &m in &members {
            if let Some(p) = path(g, from, m as u32) {
                if p.len() > best.1.len() {
                    best = (m as u32, p);
                }
            }
        }
        best
    };
    let (a_end, _) = far_end(start as u32);
    let (_, diameter) = far_end(a_end);
    let zs: Vec<f32> = diameter
        .iter()
        .map(|&n| g.nodes[n as usize].position.z)
        .collect();
    let (zmin, zmax) = zs
        .iter()
        .fold((f32::MAX, f32::MIN), |(lo, hi), &z| (lo.min(z), hi.max(z)));
    assert!(zmin < -2.0 && zmax > 6.0, "diameter spans z {zmin}..{zmax}");
    assert!(zs.iter().any(|z| (0.0..3.4).contains(z)), "passes bay B");
    // A line: few branches compared with its length.
    let deg = g.degrees();
    let branch = members.iter().filter(|&&i| deg[i] >= 3).count();
    assert!(
        branch * 4 < diameter.len(),
        "{branch} branch nodes, diameter {}",
        diameter.len()
    );
}

/// `lacuna analyze --skeleton`: the files and the JSON members people read.
#[test]
fn analyze_command_writes_the_skeleton() {
    let dir = std::env::temp_dir().join(format!("lacuna-skeleton-cli-{}", std::process::id()));
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_lacuna"))
        .args([
            "analyze",
            "two-rooms",
            "--skeleton",
            "--resolution",
            "48",
            "--json",
            "-o",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let (k, e) = (&json["skeleton"], &json["empty_space"]);
    for key in [
        "nodes",
        "edges",
        "components",
        "cycle_rank",
        "filtered_nodes",
        "filtered_edges",
    ] {
        assert!(k[key].is_u64(), "skeleton.{key}");
    }
    assert_eq!(k["components"], e["b0"]);
    assert_eq!(k["cycle_rank"], e["b1"]);
    let (b0, b1, b2) = (
        e["b0"].as_i64().unwrap(),
        e["b1"].as_i64().unwrap(),
        e["b2"].as_i64().unwrap(),
    );
    assert_eq!(e["euler"].as_i64().unwrap(), b0 - b1 + b2);
    assert!(json["skeleton_seconds"]["thinning (Alg. 2-3) || distance Euclidean"].is_f64());
    let on_disk: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    assert_eq!(on_disk["skeleton"], json["skeleton"]);
    let obj = std::fs::read_to_string(dir.join("skeleton.obj")).unwrap();
    let nodes = k["nodes"].as_u64().unwrap() as usize;
    assert_eq!(obj.lines().filter(|l| l.starts_with("v ")).count(), nodes);
    assert_eq!(
        obj.lines().filter(|l| l.starts_with("l ")).count(),
        k["edges"].as_u64().unwrap() as usize
    );
    let ply = std::fs::read_to_string(dir.join("skeleton_filtered.ply")).unwrap();
    assert!(ply.contains("property float radius"));
    assert!(ply.contains(&format!("element vertex {}", k["filtered_nodes"])));
    for png in ["skeleton.png", "node_map.png"] {
        assert!(
            std::fs::metadata(dir.join(png)).unwrap().len() > 1000,
            "{png}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Two closed rooms that touch only along one edge: the closed-cube complex joins them (one
/// component, a tree through the shared edge), the contact is reported, and the node map
/// covers both rooms.
#[test]
fn rooms_touching_along_an_edge_are_one_component() {
    let dims = [14, 14, 8];
    let occ = solid(dims, |x, y, z| {
        let a = (1..7).contains(&x) && (1..7).contains(&y);
        let b = (7..13).contains(&x) && (7..13).contains(&y);
        !((a || b) && (1..7).contains(&z))
    });
    let s = check(dims, &occ, Some((1, 0, 0)));
    assert!(s.diagonal_contacts > 0);
    assert_eq!(s.raw.components(), 1);
    // Nodes on both sides of the contact, joined through the shared edge (x = y = 7).
    let side = |n: &lacuna::analysis::Node| (n.lattice[0] + n.lattice[1]).cmp(&14);
    assert!(s.raw.nodes.iter().any(|n| side(n).is_lt()));
    assert!(s.raw.nodes.iter().any(|n| side(n).is_gt()));
    assert!(s
        .raw
        .nodes
        .iter()
        .any(|n| n.lattice[0] == 7 && n.lattice[1] == 7));
    for i in 0..s.grid.len() {
        assert_eq!(occ.get(i), s.node_map[i] == UNDEFINED_NODE);
    }
}
