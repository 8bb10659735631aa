//! The curvilinear skeleton of the empty space as a graph (000 §6.2-6.4): thinning of the
//! empty-space complex (Algorithms 2-3 with piercing, see [`super::thinning`]), graph
//! extraction with maximal-ball radii, the filtered skeleton (Algorithm 4), the node mapping
//! grid (Algorithm 5) and the mapping of a surface point to a node (eq. 151-155).
//!
//! # Nodes and radii
//!
//! A node is a point of the final 1-complex, i.e. a lattice vertex (a voxel corner); its world
//! position is that corner. The thesis treats a node as a voxel (Algorithm 5 seeds the node's
//! grid coordinates, its radius is "the value stored at each node coordinate" of the Euclidean
//! distance map). We extend voxel maps to the vertex as the thesis extends them to faces (max
//! over the voxels containing the face): the node's voxel is the empty voxel around the corner
//! with the largest Euclidean distance (ties: lowest index), and its radius is
//! `voxel_size * sqrt(SEDT(voxel))`, the radius of the largest digital ball centred on that
//! voxel that holds no occupied voxel centre (distances between voxel centres, the outside of
//! the grid counted as solid).
//!
//! # Filtering (Algorithm 4) and the cycle guard
//!
//! Nodes are taken by decreasing radius; a node not yet absorbed becomes a representative and
//! absorbs, by a breadth-first walk along skeleton edges, the unabsorbed nodes within its radius
//! (Euclidean distance between node positions). Representatives are never absorbed (the printed
//! line 7 would also absorb earlier representatives, orphaning their members). Contracting
//! connected clusters keeps b0, but loses cycles inside a cluster and, once parallel edges are
//! merged, cycles through two clusters. Guard (our choice): a node joins a cluster only if it
//! has exactly one edge to the cluster's current members (clusters stay induced trees), does
//! not add a second connection to a cluster already touched, and leaves no unabsorbed
//! neighbour with two edges into the cluster (that neighbour would later be joined to it twice).
//! Then no two clusters share two edges; should it happen anyway, the offending
//! non-singleton cluster is dissolved into single nodes (counted in [`Filtered::repaired`]).
//! The filtered graph has exactly the b0 and b1 of the raw skeleton (tested); a small cycle
//! inside a ball is kept as a ring of a few representatives instead of one node.

use std::borrow::Cow;
use std::collections::{HashMap, VecDeque};

use rayon::prelude::*;
use std::time::Instant;

use super::complex::{diagonal_contacts, Betti, Complex, UnionFind, POINT, SPAN_BIT};
use super::distance::{distance_map, Metric, Outside};
use super::grid::{VoxelGrid, VoxelSet};
use super::pipeline::Analysis;
pub use super::skeleton_maps::{SkeletonMaps, EUCLIDEAN_BESIDE_THINNING};
use super::thinning::{Constraint, Thinning, ThinningStats};
use crate::error::{Error, Result};
use crate::math::Vec3;
use crate::timing::StageTime;

/// Node index of voxels that map to no node (occupied, or unreachable from every node).
pub const UNDEFINED_NODE: u32 = u32::MAX;

/// The progress stage [`Skeleton::of_scene`] reports when the skeleton is done (a host may
/// act on it: `path_skeleton`'s time budget checks the rest there).
pub const SKELETON_STAGE: &str = "skeleton (thinning, filter, node map)";

/// A skeleton node.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Node {
    /// Lattice vertex (voxel corner) coordinates.
    pub lattice: [u32; 3],
    /// World position of the corner.
    pub position: Vec3,
    /// The empty voxel the node stands for (index in the analysis grid).
    pub voxel: u32,
    /// Maximal-ball radius in voxels (sqrt of the squared Euclidean distance of `voxel`).
    pub radius_voxels: f32,
    /// Maximal-ball radius in world units.
    pub radius: f32,
}

/// An undirected simple graph of nodes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Graph {
    pub nodes: Vec<Node>,
    /// Edges as (smaller, larger) node indices, sorted, without duplicates.
    pub edges: Vec<[u32; 2]>,
}

impl Graph {
    pub fn degrees(&self) -> Vec<u32> {
        let mut d = vec![0u32; self.nodes.len()];
        for &[a, b] in &self.edges {
            d[a as usize] += 1;
            d[b as usize] += 1;
        }
        d
    }

    /// Neighbour lists.
    pub fn adjacency(&self) -> Vec<Vec<u32>> {
        let mut adj = vec![Vec::new(); self.nodes.len()];
        for &[a, b] in &self.edges {
            adj[a as usize].push(b);
            adj[b as usize].push(a);
        }
        adj
    }

    /// Component label of each node (labels 0.. in order of first node).
    pub fn component_labels(&self) -> (Vec<u32>, usize) {
        let mut uf = UnionFind::new(self.nodes.len());
        for &[a, b] in &self.edges {
            uf.union(a as usize, b as usize);
        }
        let mut label = vec![u32::MAX; self.nodes.len()];
        let mut count = 0;
        for i in 0..self.nodes.len() {
            let r = uf.find(i);
            if label[r] == u32::MAX {
                label[r] = count;
                count += 1;
            }
            label[i] = label[r];
        }
        (label, count as usize)
    }

    pub fn components(&self) -> usize {
        self.component_labels().1
    }

    /// b1 of the graph: E − V + components.
    pub fn cycle_rank(&self) -> usize {
        self.edges.len() + self.components() - self.nodes.len()
    }
}

/// The graph of a 1-complex: one node per point, one edge per edge cell.
pub fn graph_from_complex(
    complex: &Complex,
    grid: &VoxelGrid,
    occupied: &VoxelSet,
    sq_distance: &[u32],
) -> Graph {
    let dims = grid.dims;
    let points: Vec<usize> = (0..complex.len())
        .filter(|&i| complex.byte(i) & POINT != 0)
        .collect();
    let nodes: Vec<Node> = points
        .iter()
        .map(|&i| {
            let c = complex.coords(i).map(|x| x as usize);
            let mut best: Option<(u32, usize)> = None;
            for s in 0..8usize {
                let mut v = [0usize; 3];
                let mut ok = true;
                for a in 0..3 {
                    let d = (s >> a) & 1;
                    ok &= c[a] >= d && c[a] - d < dims[a];
                    v[a] = c[a].wrapping_sub(d);
                }
                if !ok {
                    continue;
                }
                let k = grid.index(v[0], v[1], v[2]);
                if occupied.get(k) {
                    continue;
                }
                let better = match best {
                    None => true,
                    Some((d, b)) => sq_distance[k] > d || (sq_distance[k] == d && k < b),
                };
                if better {
                    best = Some((sq_distance[k], k));
                }
            }
            let (d2, voxel) = best.expect("a skeleton point is a corner of an empty voxel");
            let r = (d2 as f32).sqrt();
            Node {
                lattice: c.map(|x| x as u32),
                position: grid.to_world(c.map(|x| x as f64)),
                voxel: voxel as u32,
                radius_voxels: r,
                radius: r * grid.voxel_size as f32,
            }
        })
        .collect();
    let s = complex.stride();
    let mut edges = Vec::new();
    for (n, &i) in points.iter().enumerate() {
        for a in 0..3 {
            if complex.byte(i) & SPAN_BIT[1 << a] != 0 {
                let m = points
                    .binary_search(&(i + s[a]))
                    .expect("an edge's end point is present");
                edges.push([n as u32, m as u32]);
            }
        }
    }
    edges.sort_unstable();
    Graph { nodes, edges }
}

/// A filtered skeleton: the graph of representatives and the representative of every raw node.
#[derive(Clone, Debug, Default)]
pub struct Filtered {
    pub graph: Graph,
    /// Filtered node index of each raw node.
    pub cluster_of: Vec<u32>,
    /// Clusters dissolved by the cycle repair.
    pub repaired: usize,
}

/// Algorithm 4 with the cycle guard described in the module docs.
pub fn filter_skeleton(raw: &Graph) -> Filtered {
    const FREE: u32 = u32::MAX;
    let n = raw.nodes.len();
    let adj = raw.adjacency();
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.sort_by(|&a, &b| {
        raw.nodes[b as usize]
            .radius_voxels
            .total_cmp(&raw.nodes[a as usize].radius_voxels)
            .then(a.cmp(&b))
    });
    let lattice = |i: u32| raw.nodes[i as usize].lattice.map(|x| x as f32);
    let mut owner = vec![FREE; n];
    // touched[c] == rep while growing rep's cluster: the cluster touches finished cluster c.
    let mut touched = vec![FREE; n];
    let mut queue = VecDeque::new();
    for &rep in &order {
        if owner[rep as usize] != FREE {
            continue;
        }
        owner[rep as usize] = rep;
        for &m in &adj[rep as usize] {
            let c = owner[m as usize];
            if c != FREE && c != rep {
                touched[c as usize] = rep;
            }
        }
        let (centre, radius) = (lattice(rep), raw.nodes[rep as usize].radius_voxels);
        queue.clear();
        queue.push_back(rep);
        while let Some(u) = queue.pop_front() {
            for &cand in &adj[u as usize] {
                if owner[cand as usize] != FREE {
                    continue;
                }
                let p = lattice(cand);
                let d2 = (0..3).map(|a| (p[a] - centre[a]).powi(2)).sum::<f32>();
                if d2 > radius * radius {
                    continue;
                }
                // Exactly one edge into the cluster, no second connection to a finished one,
                // and no free neighbour left with two edges into the cluster.
                let mut inside = 0;
                let mut ok = true;
                let mut foreign: Vec<u32> = Vec::new();
                for &m in &adj[cand as usize] {
                    let c = owner[m as usize];
                    if c == rep {
                        inside += 1;
                    } else if c != FREE {
                        if touched[c as usize] == rep || foreign.contains(&c) {
                            ok = false;
                        }
                        foreign.push(c);
                    } else if adj[m as usize].iter().any(|&x| owner[x as usize] == rep) {
                        ok = false;
                    }
                }
                if !ok || inside != 1 {
                    continue;
                }
                owner[cand as usize] = rep;
                for c in foreign {
                    touched[c as usize] = rep;
                }
                queue.push_back(cand);
            }
        }
    }
    // Repair: dissolve clusters joined to another by more than one edge.
    let mut repaired = 0;
    loop {
        let mut count: HashMap<(u32, u32), u32> = HashMap::new();
        for &[a, b] in &raw.edges {
            let (ca, cb) = (owner[a as usize], owner[b as usize]);
            if ca != cb {
                *count.entry((ca.min(cb), ca.max(cb))).or_default() += 1;
            }
        }
        let mut bad: Vec<(u32, u32)> = count
            .into_iter()
            .filter(|&(_, m)| m > 1)
            .map(|(k, _)| k)
            .collect();
        if bad.is_empty() {
            break;
        }
        bad.sort_unstable();
        let size = |c: u32, owner: &[u32]| owner.iter().filter(|&&o| o == c).count();
        let mut dissolve = Vec::new();
        for (a, b) in bad {
            let (sa, sb) = (size(a, &owner), size(b, &owner));
            let pick = if sa == 1 {
                b
            } else if sb == 1 {
                a
            } else {
                let (ra, rb) = (
                    raw.nodes[a as usize].radius_voxels,
                    raw.nodes[b as usize].radius_voxels,
                );
                if ra < rb || (ra == rb && a > b) {
                    a
                } else {
                    b
                }
            };
            if !dissolve.contains(&pick) {
                dissolve.push(pick);
            }
        }
        for c in dissolve {
            repaired += 1;
            for (i, o) in owner.iter_mut().enumerate() {
                if *o == c {
                    *o = i as u32;
                }
            }
        }
    }
    // Representatives in index order.
    let mut index = vec![FREE; n];
    let mut nodes = Vec::new();
    for i in 0..n {
        if owner[i] == i as u32 {
            index[i] = nodes.len() as u32;
            nodes.push(raw.nodes[i]);
        }
    }
    let cluster_of: Vec<u32> = owner.iter().map(|&o| index[o as usize]).collect();
    let mut edges: Vec<[u32; 2]> = raw
        .edges
        .iter()
        .filter_map(|&[a, b]| {
            let (ca, cb) = (cluster_of[a as usize], cluster_of[b as usize]);
            (ca != cb).then(|| [ca.min(cb), ca.max(cb)])
        })
        .collect();
    edges.sort_unstable();
    edges.dedup();
    Filtered {
        graph: Graph { nodes, edges },
        cluster_of,
        repaired,
    }
}

/// Seed voxel of each node in the node map: its own voxel, or, when an earlier node (in index
/// order) took it, the first other empty voxel around its corner still free; `None` if all are
/// taken.
pub fn node_map_seeds(grid: &VoxelGrid, occupied: &VoxelSet, nodes: &[Node]) -> Vec<Option<u32>> {
    let dims = grid.dims;
    let mut taken = std::collections::HashSet::new();
    nodes
        .iter()
        .map(|node| {
            let mut seed = Some(node.voxel as usize).filter(|v| !taken.contains(v));
            if seed.is_none() {
                let c = node.lattice.map(|x| x as usize);
                for s in 0..8usize {
                    let mut v = [0usize; 3];
                    let mut ok = true;
                    for a in 0..3 {
                        let d = (s >> a) & 1;
                        ok &= c[a] >= d && c[a] - d < dims[a];
                        v[a] = c[a].wrapping_sub(d);
                    }
                    if ok {
                        let k = grid.index(v[0], v[1], v[2]);
                        if !occupied.get(k) && !taken.contains(&k) {
                            seed = Some(k);
                            break;
                        }
                    }
                }
            }
            if let Some(k) = seed {
                taken.insert(k);
            }
            seed.map(|k| k as u32)
        })
        .collect()
}

/// Algorithm 5: multi-source breadth-first search over 6-connected empty voxels from the
/// nodes' seed voxels ([`node_map_seeds`]), in node index order. Then, because the empty-space
/// complex also joins voxels that touch only along an edge or at a corner (see
/// [`super::complex`]), empty voxels still unmapped take, layer by layer, the node of an
/// already mapped voxel among their 26 neighbours (face neighbours first, then edge, then
/// corner): the map is total on every component of the empty space that holds a node.
/// Occupied voxels and components without a node get [`UNDEFINED_NODE`].
pub fn node_map(grid: &VoxelGrid, occupied: &VoxelSet, nodes: &[Node]) -> Vec<u32> {
    node_map_on(
        NodeMapGrid::new(grid, occupied, true),
        grid,
        occupied,
        nodes,
    )
}

/// Blocked label of the node map's padded grid (occupied voxels and the padding).
const BLOCKED: u32 = UNDEFINED_NODE - 1;

/// What the node map ([`node_map`]) sets up from the occupancy alone, before it knows the
/// nodes: so [`Skeleton::from_maps`] builds it beside the re-thinning, whose thread leaves
/// the second one idle.
struct NodeMapGrid {
    /// The grid's dimensions (the padded layout the search's unchecked steps rely on).
    dims: [usize; 3],
    /// Per voxel of the grid padded by one layer: `BLOCKED` (occupied, padding) or
    /// `UNDEFINED_NODE` (empty), so that search steps need no bounds test.
    map: Vec<u32>,
    /// Empty voxels: when the search labels that many, no voxel is left unmapped.
    empty: usize,
    /// The search's FIFO queue, one entry per voxel.
    queue: Vec<u32>,
}

impl NodeMapGrid {
    /// The set-up of the node map of `grid`; `parallel` splits its pass over the rayon pool.
    fn new(grid: &VoxelGrid, occupied: &VoxelSet, parallel: bool) -> NodeMapGrid {
        let [nx, ny, nz] = grid.dims;
        let (px, py) = (nx + 2, ny + 2);
        let plane = px * py;
        let mut map = vec![BLOCKED; plane * (nz + 2)];
        // One padded z slab: its empty voxels, and how many.
        let slab = |(pz, slab): (usize, &mut [u32])| -> usize {
            if pz == 0 || pz > nz {
                return 0;
            }
            let mut empty = 0;
            for y in 0..ny {
                let row = nx * (y + ny * (pz - 1));
                for x in 0..nx {
                    if !occupied.get(row + x) {
                        slab[(x + 1) + px * (y + 1)] = UNDEFINED_NODE;
                        empty += 1;
                    }
                }
            }
            empty
        };
        let empty = if parallel {
            map.par_chunks_mut(plane).enumerate().map(slab).sum()
        } else {
            map.chunks_mut(plane).enumerate().map(slab).sum()
        };
        NodeMapGrid {
            dims: grid.dims,
            map,
            empty,
            queue: vec![0u32; grid.len()],
        }
    }
}

/// [`node_map`] from its set-up ([`NodeMapGrid::new`] of the same grid and occupancy).
fn node_map_on(
    set_up: NodeMapGrid,
    grid: &VoxelGrid,
    occupied: &VoxelSet,
    nodes: &[Node],
) -> Vec<u32> {
    let [nx, ny, nz] = grid.dims;
    let (px, py) = (nx + 2, ny + 2);
    let plane = px * py;
    assert!(
        set_up.dims == grid.dims && set_up.map.len() == plane * (nz + 2),
        "node map set-up of another grid"
    );
    let padded = |k: usize| (k % nx + 1) + px * ((k / nx) % ny + 1) + plane * (k / (nx * ny) + 1);
    let NodeMapGrid {
        mut map,
        empty,
        mut queue,
        ..
    } = set_up;
    // FIFO queue: a voxel is labelled before it is queued, so it is queued at most once and
    // one entry per voxel holds the whole search.
    let mut tail = 0;
    for (l, seed) in node_map_seeds(grid, occupied, nodes)
        .into_iter()
        .enumerate()
    {
        if let Some(k) = seed {
            // `Node::voxel` is a public field: a seed outside the grid would be queued in the
            // padding and break the unchecked reads below.
            assert!(
                (k as usize) < grid.len(),
                "node seed {k} outside the grid of {} voxels",
                grid.len()
            );
            let p = padded(k as usize);
            map[p] = l as u32;
            queue[tail] = p as u32;
            tail += 1;
        }
    }
    let faces = [
        1isize,
        -1,
        px as isize,
        -(px as isize),
        plane as isize,
        -(plane as isize),
    ];
    let mut head = 0;
    while head < tail {
        let i = queue[head] as usize;
        head += 1;
        let label = map[i];
        for &o in &faces {
            let j = i.wrapping_add_signed(o);
            // SAFETY: `i` was queued, so it is a voxel inside the padding (a seed is, as asserted
            // above; a neighbour is queued only when it holds UNDEFINED_NODE, which no padding
            // voxel, BLOCKED, does) and its face neighbour `j` lies in `map`. Unchecked: one bounds
            // test per neighbour otherwise.
            let m = unsafe { map.get_unchecked_mut(j) };
            if *m == UNDEFINED_NODE {
                *m = label;
                queue[tail] = j as u32;
                tail += 1;
            }
        }
    }
    // Every empty voxel labelled (a seed is an empty voxel, and each voxel is labelled once):
    // nothing is left unmapped, and the scan for the unmapped ones is skipped.
    let mut unmapped: Vec<u32> = if tail == empty {
        Vec::new()
    } else {
        map.par_chunks(plane)
            .enumerate()
            .flat_map_iter(|(pz, slab)| {
                let base = (pz * plane) as u32;
                slab.iter()
                    .enumerate()
                    .filter(|&(_, &m)| m == UNDEFINED_NODE)
                    .map(move |(k, _)| base + k as u32)
            })
            .collect()
    };
    if !unmapped.is_empty() && tail > 0 {
        let mut around: Vec<isize> = Vec::with_capacity(26);
        for order in 1..=3 {
            for dz in -1isize..=1 {
                for dy in -1isize..=1 {
                    for dx in -1isize..=1 {
                        if dx.abs() + dy.abs() + dz.abs() == order {
                            around.push(dx + dy * px as isize + dz * plane as isize);
                        }
                    }
                }
            }
        }
        loop {
            let layer: Vec<(u32, u32)> = unmapped
                .iter()
                .filter_map(|&i| {
                    around.iter().find_map(|&o| {
                        let m = map[(i as usize).wrapping_add_signed(o)];
                        (m < BLOCKED).then_some((i, m))
                    })
                })
                .collect();
            if layer.is_empty() {
                break;
            }
            for &(i, m) in &layer {
                map[i as usize] = m;
            }
            unmapped.retain(|&i| map[i as usize] == UNDEFINED_NODE);
        }
    }
    let mut out = vec![UNDEFINED_NODE; grid.len()];
    out.par_chunks_mut(nx.max(1))
        .enumerate()
        .for_each(|(r, row)| {
            let start = padded(r * nx);
            for (x, v) in row.iter_mut().enumerate() {
                let m = map[start + x];
                *v = if m < BLOCKED { m } else { UNDEFINED_NODE };
            }
        });
    out
}

/// Eq. 151-155: the node of a surface point `p` with normal `normal`, seen from incident
/// direction `incident` (pointing from p towards where the path comes from).
///
/// v_x is the voxel containing p; n⁺ is the normal flipped into the hemisphere of the incident
/// direction; the chosen voxel is the empty (mapped) voxel of the 26-neighbourhood of v_x that
/// best faces n⁺. Eq. 154 prints argmax (v − v_x)·n^G; with unnormalised offsets an axis-aligned
/// normal ties the face neighbour with its four edge and four corner neighbours, so we
/// maximise the cosine (v − v_x)·n^G / |v − v_x| instead, the "similarity between the normal
/// direction and the direction pointing toward the neighbor" the text asks for (v_x itself
/// scores 0), among those on the side n⁺ points to (positive cosine). When that side of the
/// neighbourhood has no mapped voxel (a wall or corner more than one voxel thick), the search
/// moves up to three voxels along n⁺, and only then accepts any mapped neighbour. Ties (an
/// axis-aligned normal next to a one-voxel wall, where the voxels diagonally in front on
/// either side of the wall score the same) go to the voxel more in the incident direction,
/// the side the path comes from. The grid
/// transform is a translation and a uniform scale, so n^G has the direction of n⁺ (eq. 153).
pub fn map_point(
    grid: &VoxelGrid,
    map: &[u32],
    p: Vec3,
    normal: Vec3,
    incident: Vec3,
) -> Option<u32> {
    map_point_with(grid, map, None, p, normal, incident).map(|k| map[k])
}

/// Per voxel of a grid, which voxels of its 3x3x3 neighbourhood (itself included) are inside
/// the grid and mapped to a node: bit `(dz + 1) 9 + (dy + 1) 3 + (dx + 1)`, the order
/// [`map_point`] visits them in. With it, [`NeighbourMasks::map_point`] visits only the
/// mapped neighbours (next to a surface, about half of them are solid) and skips the bounds
/// tests and node-map reads of the rest, with the same result: a guided vertex maps its
/// point once per bounce, about 2,400 instructions without the masks.
#[derive(Clone, Debug, Default)]
pub struct NeighbourMasks {
    masks: Vec<u32>,
}

impl NeighbourMasks {
    /// The masks of every voxel of `grid` for node map `map`: [`neighbour_mask`] of each
    /// voxel, built separably (bit = dx + 3 dy + 9 dz, [`NEIGHBOUR_OFFSETS`]): the 3 bits of
    /// the x-neighbours per voxel, then 9 from three of those along y, then 27 from three of
    /// those along z, so each voxel costs a few operations instead of 27 bounds-checked reads.
    pub fn new(grid: &VoxelGrid, map: &[u32]) -> NeighbourMasks {
        let [nx, ny, _] = grid.dims;
        let slice_len = (nx * ny).max(1);
        // Along x: bit 0 the voxel at x - 1, bit 1 the voxel itself, bit 2 the voxel at x + 1.
        let mut along_x = vec![0u32; grid.len()];
        along_x
            .par_chunks_mut(nx.max(1))
            .zip(map.par_chunks(nx.max(1)))
            .for_each(|(out, row)| {
                for (x, o) in out.iter_mut().enumerate() {
                    let mapped = |i: usize| u32::from(row[i] != UNDEFINED_NODE);
                    *o = mapped(x) << 1;
                    if x > 0 {
                        *o |= mapped(x - 1);
                    }
                    if x + 1 < nx {
                        *o |= mapped(x + 1) << 2;
                    }
                }
            });
        // Along y, within each z-slice: three x-masks at y - 1, y, y + 1.
        let mut along_xy = vec![0u32; grid.len()];
        along_xy
            .par_chunks_mut(slice_len)
            .zip(along_x.par_chunks(slice_len))
            .for_each(|(out, slice)| {
                for y in 0..ny {
                    for x in 0..nx {
                        let at = |y: usize| slice[x + nx * y];
                        let mut m = at(y) << 3;
                        if y > 0 {
                            m |= at(y - 1);
                        }
                        if y + 1 < ny {
                            m |= at(y + 1) << 6;
                        }
                        out[x + nx * y] = m;
                    }
                }
            });
        // Along z: three xy-masks of the slices z - 1, z, z + 1.
        let slices = along_xy.len() / slice_len;
        let mut masks = vec![0u32; grid.len()];
        masks
            .par_chunks_mut(slice_len)
            .enumerate()
            .for_each(|(z, out)| {
                let slice = |z: usize| &along_xy[z * slice_len..(z + 1) * slice_len];
                let mid = slice(z);
                for (k, o) in out.iter_mut().enumerate() {
                    *o = mid[k] << 9;
                }
                if z > 0 {
                    for (o, &m) in out.iter_mut().zip(slice(z - 1)) {
                        *o |= m;
                    }
                }
                if z + 1 < slices {
                    for (o, &m) in out.iter_mut().zip(slice(z + 1)) {
                        *o |= m << 18;
                    }
                }
            });
        NeighbourMasks { masks }
    }

    /// [`map_point`] with the masks (built for this `grid` and `map`): the same node.
    pub fn map_point(
        &self,
        grid: &VoxelGrid,
        map: &[u32],
        p: Vec3,
        normal: Vec3,
        incident: Vec3,
    ) -> Option<u32> {
        self.map_point_voxel(grid, map, p, normal, incident)
            .map(|k| map[k])
    }

    /// The mapped voxel [`map_point`] takes the node of (its index in `grid`).
    pub fn map_point_voxel(
        &self,
        grid: &VoxelGrid,
        map: &[u32],
        p: Vec3,
        normal: Vec3,
        incident: Vec3,
    ) -> Option<usize> {
        debug_assert_eq!(self.masks.len(), grid.len());
        map_point_with(grid, map, Some(&self.masks), p, normal, incident)
    }

    /// [`Self::map_point_voxel`] for a point given by its grid coordinates `g =
    /// grid.to_grid(p)` and voxel `vx = grid.voxel_of(p)`, for a caller that has them already.
    pub fn map_grid_point_voxel(
        &self,
        grid: &VoxelGrid,
        map: &[u32],
        g: [f64; 3],
        vx: [i64; 3],
        normal: Vec3,
        incident: Vec3,
    ) -> Option<usize> {
        debug_assert_eq!(self.masks.len(), grid.len());
        map_grid_point(grid, map, Some(&self.masks), g, vx, normal, incident, true)
    }

    /// [`Self::map_grid_point_voxel`] of a point whose voxel `vx` lies inside the grid, `k`
    /// its index: the same voxel. Inside the grid the axis shortcut's neighbour
    /// ([`axis_shortcut`]) differs from `vx` along one axis only, so it is `k` plus or minus
    /// that axis's stride after one bounds test, instead of three saturating additions, six
    /// bounds tests and a new index.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub fn map_inside_grid_point_voxel(
        &self,
        grid: &VoxelGrid,
        map: &[u32],
        g: [f64; 3],
        vx: [i64; 3],
        k: usize,
        normal: Vec3,
        incident: Vec3,
    ) -> Option<usize> {
        debug_assert_eq!(self.masks.len(), grid.len());
        debug_assert_eq!(
            k,
            grid.index(vx[0] as usize, vx[1] as usize, vx[2] as usize)
        );
        if let Some((axis, positive)) = facing_axis(incident_side(normal, incident)) {
            let [nx, ny, _] = grid.dims;
            let stride = [1, nx, nx * ny][axis];
            let neighbour = if positive {
                (vx[axis] + 1 < grid.dims[axis] as i64).then(|| k + stride)
            } else {
                (vx[axis] > 0).then(|| k - stride)
            };
            if let Some(j) = neighbour.filter(|&j| map[j] != UNDEFINED_NODE) {
                return Some(j);
            }
        }
        map_grid_point_beyond_axes(grid, map, Some(&self.masks), g, vx, normal, incident, true)
    }

    pub fn memory_bytes(&self) -> usize {
        self.masks.len() * 4
    }
}

/// The mapped voxels of the 3x3x3 neighbourhood of `centre` (which may lie outside the
/// grid), one bit per [`NEIGHBOUR_OFFSETS`] entry.
fn neighbour_mask(grid: &VoxelGrid, map: &[u32], centre: [i64; 3]) -> u32 {
    let mut mask = 0u32;
    for (bit, d) in NEIGHBOUR_OFFSETS.iter().enumerate() {
        let v = [centre[0] + d[0], centre[1] + d[1], centre[2] + d[2]];
        let inside = (0..3).all(|a| v[a] >= 0 && v[a] < grid.dims[a] as i64);
        if inside && map[grid.index(v[0] as usize, v[1] as usize, v[2] as usize)] != UNDEFINED_NODE
        {
            mask |= 1 << bit;
        }
    }
    mask
}

/// The offsets of a voxel's 3x3x3 neighbourhood by bit of [`NeighbourMasks`].
const NEIGHBOUR_OFFSETS: [[i64; 3]; 27] = {
    let mut offsets = [[0i64; 3]; 27];
    let mut bit = 0;
    while bit < 27 {
        offsets[bit] = [
            (bit % 3) as i64 - 1,
            ((bit / 3) % 3) as i64 - 1,
            (bit / 9) as i64 - 1,
        ];
        bit += 1;
    }
    offsets
};

/// [`NEIGHBOUR_OFFSETS`] in f32.
const NEIGHBOUR_OFFSETS_F32: [Vec3; 27] = {
    let mut offsets = [Vec3::ZERO; 27];
    let mut bit = 0;
    while bit < 27 {
        let d = NEIGHBOUR_OFFSETS[bit];
        offsets[bit] = Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32);
        bit += 1;
    }
    offsets
};

/// The voxel of [`map_point`], visiting a neighbourhood through its mask where `masks` has
/// one (centre inside the grid), else testing each neighbour.
/// First the shortcut of [`clearly_facing_offset`], then the search.
fn map_point_with(
    grid: &VoxelGrid,
    map: &[u32],
    masks: Option<&[u32]>,
    p: Vec3,
    normal: Vec3,
    incident: Vec3,
) -> Option<usize> {
    map_point_searched(grid, map, masks, p, normal, incident, true)
}

/// The offset of the 26-neighbourhood whose cosine with the unit vector `n` is largest, when
/// every other offset's cosine is more than `FACING_MARGIN` below it. Then the search of
/// [`map_point`] takes that neighbour wherever it is mapped: its score beats every other
/// neighbour's by more than the search's tolerance, so neither the order of the visit nor
/// the tie-break can prefer another. With the axes sorted by |n| (a >= b >= c), the best
/// offset with k non-zero components takes the signs of n on the k largest: cosines a,
/// (a + b) / √2, (a + b + c) / √3; the runner-up among offsets with as many components
/// swaps in the next axis or flips the smallest sign: b, (a + c) / √2, (a + b - c) / √3.
/// A few dozen instructions against a search over every mapped neighbour (about 1,400
/// per guided vertex).
fn clearly_facing_offset(n: Vec3) -> Option<[i64; 3]> {
    /// Far above the search's tolerance (1e-4) and the rounding of either computation.
    const FACING_MARGIN: f32 = 1e-3;
    let m = n.abs().to_array();
    let mut axes = [0usize, 1, 2];
    if m[axes[0]] < m[axes[1]] {
        axes.swap(0, 1);
    }
    if m[axes[1]] < m[axes[2]] {
        axes.swap(1, 2);
    }
    if m[axes[0]] < m[axes[1]] {
        axes.swap(0, 1);
    }
    let [a, b, c] = axes.map(|i| m[i]);
    let third = 1.0 / 3.0f32.sqrt();
    let best = [
        a,
        (a + b) * std::f32::consts::FRAC_1_SQRT_2,
        (a + b + c) * third,
    ];
    let runner_up = [
        b,
        (a + c) * std::f32::consts::FRAC_1_SQRT_2,
        (a + b - c) * third,
    ];
    let k = if best[0] >= best[1] && best[0] >= best[2] {
        0
    } else if best[1] >= best[2] {
        1
    } else {
        2
    };
    let second = (0..3)
        .map(|j| if j == k { runner_up[j] } else { best[j] })
        .fold(f32::NEG_INFINITY, f32::max);
    // Also false for a zero or non-finite n.
    if !(best[k] - second > FACING_MARGIN) {
        return None;
    }
    let mut offset = [0i64; 3];
    for &axis in &axes[..=k] {
        offset[axis] = if n[axis] > 0.0 { 1 } else { -1 };
    }
    Some(offset)
}

/// [`clearly_facing_offset`] of `n.normalize_or_zero()` where `n` lies along an axis (its other
/// two components ±0) with a length in [1e-6, 1e6]: the face neighbour on n's side (its cosine
/// 1 against the runner-up's 1/√2, whatever the rounding of the normalisation), found without
/// normalising n. None elsewhere (then the caller normalises and asks
/// `clearly_facing_offset`). The geometric normals of axis-aligned walls are such vectors;
/// most of the vertices a guided path tracer maps lie on them.
#[inline]
fn axis_facing_offset(n: Vec3) -> Option<[i64; 3]> {
    let (axis, positive) = facing_axis(n)?;
    let mut offset = [0i64; 3];
    offset[axis] = if positive { 1 } else { -1 };
    Some(offset)
}

/// [`axis_facing_offset`] as the axis and whether the offset along it is +1.
#[inline(always)]
fn facing_axis(n: Vec3) -> Option<(usize, bool)> {
    let (axis, value) = if n.y == 0.0 && n.z == 0.0 {
        (0, n.x)
    } else if n.x == 0.0 && n.z == 0.0 {
        (1, n.y)
    } else if n.x == 0.0 && n.y == 0.0 {
        (2, n.z)
    } else {
        return None;
    };
    if !(1e-6..=1e6).contains(&value.abs()) {
        return None;
    }
    Some((axis, value > 0.0))
}

/// The mapping of [`map_point`]; with `shortcut`, a mapped neighbour that clearly faces the
/// normal is taken without the search ([`clearly_facing_offset`]: the same voxel).
fn map_point_searched(
    grid: &VoxelGrid,
    map: &[u32],
    masks: Option<&[u32]>,
    p: Vec3,
    normal: Vec3,
    incident: Vec3,
    shortcut: bool,
) -> Option<usize> {
    let g = grid.to_grid(p);
    let vx = super::grid::floor3_to_i64(g);
    map_grid_point(grid, map, masks, g, vx, normal, incident, shortcut)
}

/// [`map_point_searched`] of the point at grid coordinates `g`, in voxel `vx` (its floor).
/// With `shortcut`, walls, floors and ceilings first ([`axis_shortcut`]; this function is
/// inlined into its callers), then the rest out of line.
#[allow(clippy::too_many_arguments)]
#[inline]
fn map_grid_point(
    grid: &VoxelGrid,
    map: &[u32],
    masks: Option<&[u32]>,
    g: [f64; 3],
    vx: [i64; 3],
    normal: Vec3,
    incident: Vec3,
    shortcut: bool,
) -> Option<usize> {
    if shortcut {
        if let Some(k) = axis_shortcut(grid, map, vx, normal, incident) {
            return Some(k);
        }
    }
    map_grid_point_beyond_axes(grid, map, masks, g, vx, normal, incident, shortcut)
}

/// The mapped neighbour of `vx` that faces n⁺ where n⁺ (the normal on the incident side) lies
/// along an axis ([`axis_facing_offset`]): the voxel the facing shortcut of [`map_point`]
/// takes, found without normalising n. None where n is no such normal or that neighbour is
/// outside the grid or unmapped (then the mapping goes on as if this had not been tried).
#[inline]
fn axis_shortcut(
    grid: &VoxelGrid,
    map: &[u32],
    vx: [i64; 3],
    normal: Vec3,
    incident: Vec3,
) -> Option<usize> {
    mapped_neighbour(
        grid,
        map,
        vx,
        axis_facing_offset(incident_side(normal, incident))?,
    )
}

/// The normal on the incident direction's side (the side the point is seen from).
#[inline(always)]
fn incident_side(normal: Vec3, incident: Vec3) -> Vec3 {
    if normal.dot(incident) >= 0.0 {
        normal
    } else {
        -normal
    }
}

/// Voxel `vx + d` when it is inside the grid and mapped: the facing step of the mapping.
#[inline(always)]
fn mapped_neighbour(grid: &VoxelGrid, map: &[u32], vx: [i64; 3], d: [i64; 3]) -> Option<usize> {
    let v = [
        vx[0].saturating_add(d[0]),
        vx[1].saturating_add(d[1]),
        vx[2].saturating_add(d[2]),
    ];
    let [nx, ny, nz] = grid.dims;
    if !(v[0] >= 0
        && v[0] < nx as i64
        && v[1] >= 0
        && v[1] < ny as i64
        && v[2] >= 0
        && v[2] < nz as i64)
    {
        return None;
    }
    let k = grid.index(v[0] as usize, v[1] as usize, v[2] as usize);
    (map[k] != UNDEFINED_NODE).then_some(k)
}

/// [`map_grid_point`] after [`axis_shortcut`].
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn map_grid_point_beyond_axes(
    grid: &VoxelGrid,
    map: &[u32],
    masks: Option<&[u32]>,
    g: [f64; 3],
    vx: [i64; 3],
    normal: Vec3,
    incident: Vec3,
    shortcut: bool,
) -> Option<usize> {
    let dims = grid.dims;
    let inside = |v: [i64; 3]| (0..3).all(|a| v[a] >= 0 && v[a] < dims[a] as i64);
    let n = incident_side(normal, incident).normalize_or_zero();
    if let Some(d) = clearly_facing_offset(n).filter(|_| shortcut) {
        if let Some(k) = mapped_neighbour(grid, map, vx, d) {
            return Some(k);
        }
    }
    let w = incident.normalize_or_zero();
    // Best mapped voxel of the 26-neighbourhood of `centre`, scored by the cosine from v_x.
    let search = |centre: [i64; 3], facing_only: bool| -> Option<usize> {
        let mut best: Option<(f32, f32, usize)> = None;
        // v − v_x = (centre − v_x) + d: small integers, exact in f32 either way.
        let base = Vec3::new(
            (centre[0] - vx[0]) as f32,
            (centre[1] - vx[1]) as f32,
            (centre[2] - vx[2]) as f32,
        );
        let mut consider = |bit: usize| {
            let off = base + NEIGHBOUR_OFFSETS_F32[bit];
            // The sign of the score without the division (len > 0 where it is not 0).
            if facing_only && off.dot(n) <= 0.0 {
                return;
            }
            let len = off.length();
            let (score, towards) = if len > 0.0 {
                (off.dot(n) / len, off.dot(w) / len)
            } else {
                (0.0, 0.0)
            };
            let better = match best {
                None => true,
                Some((s, t, _)) => score > s + 1e-4 || (score > s - 1e-4 && towards > t + 1e-4),
            };
            if better {
                best = Some((score, towards, bit));
            }
        };
        let mut mask = match masks {
            Some(masks) if inside(centre) => {
                masks[grid.index(centre[0] as usize, centre[1] as usize, centre[2] as usize)]
            }
            _ => neighbour_mask(grid, map, centre),
        };
        while mask != 0 {
            let bit = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            consider(bit);
        }
        best.map(|(_, _, bit)| {
            let d = NEIGHBOUR_OFFSETS[bit];
            let v = [centre[0] + d[0], centre[1] + d[1], centre[2] + d[2]];
            grid.index(v[0] as usize, v[1] as usize, v[2] as usize)
        })
    };
    // Eq. 154 restricted to the side n⁺ faces; a wall thicker than one voxel (corners, the
    // conservative voxelization) may hide that side, so then look further along n⁺, and only
    // as a last resort take any mapped neighbour (which may lie behind the surface).
    for step in 0..=3i64 {
        let centre = [0, 1, 2].map(|a| super::grid::floor_to_i64(g[a] + step as f64 * n[a] as f64));
        if let Some(voxel) = search(if step == 0 { vx } else { centre }, true) {
            return Some(voxel);
        }
    }
    search(vx, false)
}

/// Options of the skeleton pipeline.
#[derive(Clone, Debug, PartialEq)]
pub struct SkeletonSettings {
    /// Gather free pairs on the rayon pool (identical results either way).
    pub parallel: bool,
    /// Also compute the Betti numbers of the empty space (union-find passes over the grid).
    pub topology: bool,
}

impl Default for SkeletonSettings {
    fn default() -> Self {
        SkeletonSettings {
            parallel: true,
            topology: true,
        }
    }
}

/// The skeleton of the empty space of an analysed scene.
///
/// # Schedule
///
/// The order of the stages on the rayon pool, and what runs beside what (the one place to
/// change it is [`EUCLIDEAN_BESIDE_THINNING`]; [`super::pipeline::Analysis`] with `all_maps`
/// runs steps 1-2, and [`Skeleton::build`] goes on from there):
/// 1. voxelize, then the L1 distance (parallel passes);
/// 2. the L1 opening and decenterness ([`SkeletonMaps::from_l1`]: the flood split into slabs,
///    one per thread);
/// 3. the thinning's complex, then the thinning (Algorithms 2-3) **beside the squared
///    Euclidean distance** (`rayon::join`), which only the piercing and the graph read (the
///    thinning's own split passes, with `parallel`, find the other threads busy with the
///    distance until it is done, then share the passes). With
///    [`EUCLIDEAN_BESIDE_THINNING`] off, the distance runs beside step 2 instead;
/// 4. piercing + re-thinning (**beside the node map's set-up**, which needs only the
///    occupancy), graph, filter (Algorithm 4), node map (Algorithm 5).
pub struct Skeleton {
    pub grid: VoxelGrid,
    /// The curvilinear skeleton (one node per point of the thinned complex).
    pub raw: Graph,
    /// The filtered skeleton (Algorithm 4) and the cluster of each raw node.
    pub filtered: Filtered,
    /// Node mapping grid of the filtered skeleton (filtered node index per voxel).
    pub node_map: Vec<u32>,
    /// b0, b1, b2, χ of the empty-space complex, when asked for.
    pub empty_space: Option<Betti>,
    /// Lattice vertices where empty voxels meet only along an edge or at a corner.
    pub diagonal_contacts: usize,
    pub thinning: ThinningStats,
    pub timings: Vec<StageTime>,
}

/// Whether a distance map was computed with the outside of the grid solid: then every empty
/// voxel on the grid boundary is at distance 1 (all metrics used here).
fn measured_with_solid_outside(dims: [usize; 3], map: &[u32]) -> bool {
    let [w, h, d] = dims;
    let ok = |x: usize, y: usize, z: usize| map[x + w * (y + h * z)] <= 1;
    (0..d).all(|z| {
        (0..h).all(|y| {
            if z == 0 || y == 0 || z + 1 == d || y + 1 == h {
                (0..w).all(|x| ok(x, y, z))
            } else {
                ok(0, y, z) && ok(w - 1, y, z)
            }
        })
    })
}

impl Skeleton {
    /// The skeleton of `scene` as the integrators that map points to its nodes build it
    /// (skeleton guiding, SkelBPT, the VPL shadow maps): an analysis of only what the skeleton
    /// uses (its maps, not the regions and portals; the Euclidean map computed beside the
    /// thinning), then the thinning in parallel without the topology checks. `stage(name,
    /// started)` is told of each of the two stages as it ends, and may cancel with an error.
    pub fn of_scene(
        scene: &crate::scene::Scene,
        resolution: super::Resolution,
        stage: &mut dyn FnMut(&'static str, Instant) -> Result<()>,
    ) -> Result<Skeleton> {
        let t = Instant::now();
        let analysis_settings = super::AnalysisSettings {
            resolution,
            all_maps: true,
            euclidean: false,
            regions: false,
            ..Default::default()
        };
        let analysis = Analysis::build(scene, &analysis_settings, &|_, _| true)?;
        stage("analysis (voxels, maps)", t)?;
        let t = Instant::now();
        let skeleton_settings = SkeletonSettings {
            parallel: true,
            topology: false,
        };
        let skeleton = Skeleton::build(&analysis, &skeleton_settings, &|_, _| true)?;
        drop(analysis);
        stage(SKELETON_STAGE, t)?;
        Ok(skeleton)
    }

    /// The skeleton of an analysis. Uses its L1 distance and L1 decenterness maps when present
    /// (`all_maps`) and measured with a solid outside, computes them otherwise; likewise its
    /// squared Euclidean distance, which is otherwise computed beside the thinning.
    pub fn build<'a>(
        analysis: &'a Analysis,
        settings: &SkeletonSettings,
        progress: &dyn Fn(&str, f64) -> bool,
    ) -> Result<Skeleton> {
        let dims = analysis.grid.dims;
        let mut timings = Vec::new();
        let t = Instant::now();
        let occ = &analysis.occupied;
        let solid = |m: &'a Option<Vec<u32>>| -> Option<&'a [u32]> {
            m.as_deref()
                .filter(|m| measured_with_solid_outside(dims, m))
        };
        let computed_sq: Vec<u32>;
        let mut sq: Option<&[u32]> = solid(&analysis.distance_sq_euclidean);
        let (d1, dc): (Cow<'a, [u32]>, Cow<'a, [u32]>) = match (
            solid(&analysis.distance_l1),
            analysis.decenterness_l1.as_deref(),
        ) {
            (Some(d1), Some(dc)) => (d1.into(), dc.into()),
            _ => {
                let maps = SkeletonMaps::new(dims, occ, Outside::Solid);
                timings.push(StageTime {
                    stage: "skeleton maps",
                    seconds: t.elapsed().as_secs_f64(),
                });
                if let (None, Some(m)) = (sq, maps.sq_euclidean) {
                    computed_sq = m;
                    sq = Some(&computed_sq);
                }
                (maps.distance_l1.into(), maps.decenterness_l1.into())
            }
        };
        Self::from_maps(
            analysis.grid,
            occ,
            &d1,
            &dc,
            sq,
            settings,
            progress,
            timings,
        )
    }

    /// The skeleton from the occupied voxels and per-voxel maps measured with a solid outside:
    /// L1 distance, L1 decenterness (Ω1 − D1) and, if given, the squared Euclidean distance
    /// (computed beside the thinning otherwise, see [`Skeleton#schedule`]).
    #[allow(clippy::too_many_arguments)]
    pub fn from_maps(
        grid: VoxelGrid,
        occupied: &VoxelSet,
        distance_l1: &[u32],
        decenterness_l1: &[u32],
        sq_distance: Option<&[u32]>,
        settings: &SkeletonSettings,
        progress: &dyn Fn(&str, f64) -> bool,
        mut timings: Vec<StageTime>,
    ) -> Result<Skeleton> {
        let dims = grid.dims;
        let total = 7.0;
        let mut done = 0.0;
        let mut stage = |name: &'static str, timings: &mut Vec<StageTime>, t: Instant| {
            timings.push(StageTime {
                stage: name,
                seconds: t.elapsed().as_secs_f64(),
            });
            done += 1.0;
            if progress(name, done / total) {
                Ok(())
            } else {
                Err(Error::Cancelled)
            }
        };

        // The thinning builds its own (bit-plane) complex; the byte complex is only needed for
        // the Betti numbers.
        let t = Instant::now();
        let (empty_space, contacts) = if settings.topology {
            let complex = Complex::from_occupied(dims, occupied);
            (Some(complex.betti()), diagonal_contacts(dims, occupied))
        } else {
            (None, 0)
        };
        stage("empty-space topology", &mut timings, t)?;

        let t = Instant::now();
        let mut thinning = Thinning::from_occupied(
            dims,
            occupied,
            Constraint::Lifespan {
                distance: distance_l1,
                decenterness: decenterness_l1,
            },
            settings.parallel,
            false,
        );
        stage("complex", &mut timings, t)?;

        let t = Instant::now();
        let computed: Vec<u32>;
        let sq_distance = match sq_distance {
            Some(sq) => {
                thinning.run(None);
                stage("thinning (Alg. 2-3)", &mut timings, t)?;
                sq
            }
            None => {
                computed = rayon::join(
                    || thinning.run(None),
                    || {
                        distance_map(
                            dims,
                            occupied,
                            Metric::SquaredEuclidean,
                            Outside::Solid,
                            false,
                        )
                        .values
                    },
                )
                .1;
                stage("thinning (Alg. 2-3) || distance Euclidean", &mut timings, t)?;
                &computed
            }
        };

        // The node map's set-up needs only the occupancy: it runs beside the first
        // re-thinning, which keeps its passes on the calling thread (a run that starts from
        // the bricks of the pierced squares), so the second thread takes it; without a pierce
        // it runs with the node map.
        let t = Instant::now();
        let mut node_grid = None;
        while thinning.pierce(Some(sq_distance)) > 0 {
            if node_grid.is_none() {
                node_grid = Some(
                    rayon::join(
                        || thinning.run(None),
                        || NodeMapGrid::new(&grid, occupied, false),
                    )
                    .1,
                );
            } else {
                thinning.run(None);
            }
        }
        stage("piercing + re-thinning || node map set-up", &mut timings, t)?;

        let t = Instant::now();
        let stats = thinning.stats;
        let complex = thinning.into_complex();
        let raw = graph_from_complex(&complex, &grid, occupied, sq_distance);
        drop(complex);
        stage("graph", &mut timings, t)?;

        let t = Instant::now();
        let filtered = filter_skeleton(&raw);
        stage("filter (Alg. 4)", &mut timings, t)?;

        let t = Instant::now();
        let node_grid = node_grid.unwrap_or_else(|| NodeMapGrid::new(&grid, occupied, true));
        let map = node_map_on(node_grid, &grid, occupied, &filtered.graph.nodes);
        stage("node map (Alg. 5)", &mut timings, t)?;

        Ok(Skeleton {
            grid,
            raw,
            filtered,
            node_map: map,
            empty_space,
            diagonal_contacts: contacts,
            thinning: stats,
            timings,
        })
    }

    /// Filtered node of a surface point (eq. 151-155), see [`map_point`].
    pub fn map_point(&self, p: Vec3, normal: Vec3, incident: Vec3) -> Option<u32> {
        map_point(&self.grid, &self.node_map, p, normal, incident)
    }

    pub fn total_seconds(&self) -> f64 {
        self.timings.iter().map(|t| t.seconds).sum()
    }

    /// The `skeleton`, `empty_space` and `skeleton_seconds` members of the JSON summary.
    pub fn summary_json(&self) -> serde_json::Value {
        let stages: serde_json::Map<String, serde_json::Value> = self
            .timings
            .iter()
            .map(|t| (t.stage.to_string(), serde_json::json!(t.seconds)))
            .collect();
        let g = &self.filtered.graph;
        let mut v = serde_json::json!({
            "skeleton": {
                "nodes": self.raw.nodes.len(),
                "edges": self.raw.edges.len(),
                "components": self.raw.components(),
                "cycle_rank": self.raw.cycle_rank(),
                "max_degree": self.raw.degrees().into_iter().max().unwrap_or(0),
                "filtered_nodes": g.nodes.len(),
                "filtered_edges": g.edges.len(),
                "filtered_components": g.components(),
                "filtered_cycle_rank": g.cycle_rank(),
                "filter_repairs": self.filtered.repaired,
                "thinning": self.thinning,
            },
            "skeleton_seconds": stages,
            "skeleton_total_seconds": self.total_seconds(),
        });
        if let Some(b) = self.empty_space {
            v["empty_space"] = serde_json::json!({
                "b0": b.b0, "b1": b.b1, "b2": b.b2, "euler": b.euler,
                "diagonal_contacts": self.diagonal_contacts,
            });
        }
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn graph(points: &[[u32; 3]], radii: &[f32], edges: &[[u32; 2]]) -> Graph {
        let nodes = points
            .iter()
            .zip(radii)
            .map(|(&p, &r)| Node {
                lattice: p,
                position: Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32),
                voxel: 0,
                radius_voxels: r,
                radius: r,
            })
            .collect();
        let mut edges: Vec<[u32; 2]> = edges.iter().map(|&[a, b]| [a.min(b), a.max(b)]).collect();
        edges.sort_unstable();
        Graph { nodes, edges }
    }

    /// Algorithm 5 written literally, on the unpadded grid with bounds tests: a FIFO queue from
    /// the seeds in node order, face neighbours in the order +x, −x, +y, −y, +z, −z, then the
    /// 26-neighbour layers of [`node_map`]'s doc comment.
    fn node_map_reference(grid: &VoxelGrid, occ: &VoxelSet, nodes: &[Node]) -> Vec<u32> {
        let d = grid.dims;
        let mut map = vec![UNDEFINED_NODE; grid.len()];
        let mut queue = std::collections::VecDeque::new();
        for (l, seed) in node_map_seeds(grid, occ, nodes).into_iter().enumerate() {
            if let Some(k) = seed {
                map[k as usize] = l as u32;
                queue.push_back(k as usize);
            }
        }
        let at = |c: [usize; 3], o: [i64; 3]| -> Option<usize> {
            let n: Vec<i64> = (0..3).map(|a| c[a] as i64 + o[a]).collect();
            (0..3)
                .all(|a| n[a] >= 0 && n[a] < d[a] as i64)
                .then(|| grid.index(n[0] as usize, n[1] as usize, n[2] as usize))
        };
        let faces = [
            [1, 0, 0],
            [-1, 0, 0],
            [0, 1, 0],
            [0, -1, 0],
            [0, 0, 1],
            [0, 0, -1],
        ];
        let mut seen_any = !queue.is_empty();
        while let Some(i) = queue.pop_front() {
            for o in faces {
                if let Some(j) = at(grid.coords(i), o) {
                    if !occ.get(j) && map[j] == UNDEFINED_NODE {
                        map[j] = map[i];
                        queue.push_back(j);
                    }
                }
            }
        }
        let mut around = Vec::new();
        for order in 1..=3 {
            for dz in -1i64..=1 {
                for dy in -1i64..=1 {
                    for dx in -1i64..=1 {
                        if dx.abs() + dy.abs() + dz.abs() == order {
                            around.push([dx, dy, dz]);
                        }
                    }
                }
            }
        }
        while seen_any {
            let layer: Vec<(usize, u32)> = (0..grid.len())
                .filter(|&i| !occ.get(i) && map[i] == UNDEFINED_NODE)
                .filter_map(|i| {
                    around.iter().find_map(|&o| {
                        let j = at(grid.coords(i), o)?;
                        (!occ.get(j) && map[j] != UNDEFINED_NODE).then(|| (i, map[j]))
                    })
                })
                .collect();
            seen_any = !layer.is_empty();
            for (i, m) in layer {
                map[i] = m;
            }
        }
        map
    }

    /// A node map of `len` voxels, each solid (unmapped) with probability `solid`, else labelled
    /// with one of `labels` nodes by its index.
    fn random_node_map(
        rng: &mut crate::math::Rng,
        len: usize,
        solid: f32,
        labels: u32,
    ) -> Vec<u32> {
        (0..len as u32)
            .map(|i| {
                if rng.uniform() < solid {
                    UNDEFINED_NODE
                } else {
                    i % labels
                }
            })
            .collect()
    }

    /// The masked mapping finds the node the direct one finds, for points inside, on the
    /// border of and outside random grids (solid fractions from sparse to mostly solid),
    /// axis-aligned and random normals, both sides.
    #[test]
    fn neighbour_masks_map_points_as_the_direct_mapping() {
        let mut rng = crate::math::Rng::new(83, 1);
        let mut compared = [0usize; 3];
        for dims in [[9, 7, 6], [16, 5, 11], [3, 3, 3], [20, 20, 3]] {
            for solid in [0.1f32, 0.5, 0.9] {
                let grid = VoxelGrid {
                    dims,
                    origin: [-1.5, 0.25, 2.0],
                    voxel_size: 0.5,
                };
                let map = random_node_map(&mut rng, grid.len(), solid, 7);
                let masks = NeighbourMasks::new(&grid, &map);
                // The separable build gives every voxel its mask by definition.
                for (k, &mask) in masks.masks.iter().enumerate() {
                    let v = grid.coords(k).map(|c| c as i64);
                    assert_eq!(
                        mask,
                        neighbour_mask(&grid, &map, v),
                        "voxel {v:?} of {dims:?}"
                    );
                }
                for i in 0..4000 {
                    // A little beyond the grid on every side.
                    let g = [0, 1, 2].map(|a| (rng.uniform() as f64 * 1.4 - 0.2) * dims[a] as f64);
                    let p = grid.to_world(g);
                    let axis = |u: f32| {
                        let mut v = [0.0f32; 3];
                        v[(u * 3.0) as usize % 3] = if u < 0.5 { 1.0 } else { -1.0 };
                        Vec3::from_array(v)
                    };
                    let normal = if i % 2 == 0 {
                        axis(rng.uniform())
                    } else {
                        crate::math::warp::uniform_sphere(rng.uniform2())
                    };
                    let incident = crate::math::warp::uniform_sphere(rng.uniform2());
                    let direct = map_point(&grid, &map, p, normal, incident);
                    assert_eq!(
                        masks.map_point(&grid, &map, p, normal, incident),
                        direct,
                        "dims {dims:?}, solid {solid}, p {p}, n {normal}, w {incident}"
                    );
                    compared[direct.is_some() as usize] += 1;
                    // Inside the grid, the mapping from the voxel's index too (the axis
                    // shortcut's single bounds test, voxels on the border included).
                    let g = grid.to_grid(p);
                    let vx = crate::analysis::grid::floor3_to_i64(g);
                    if (0..3).all(|a| vx[a] >= 0 && vx[a] < dims[a] as i64) {
                        let k = grid.index(vx[0] as usize, vx[1] as usize, vx[2] as usize);
                        assert_eq!(
                            masks
                                .map_inside_grid_point_voxel(
                                    &grid, &map, g, vx, k, normal, incident
                                )
                                .map(|k| map[k]),
                            direct,
                            "dims {dims:?}, solid {solid}, p {p}, n {normal}, w {incident}"
                        );
                        compared[2] += 1;
                    }
                }
            }
        }
        assert!(
            compared[0] > 1000 && compared[1] > 10_000 && compared[2] > 10_000,
            "{compared:?}"
        );
    }

    #[test]
    fn the_facing_shortcut_maps_points_as_the_search() {
        let mut rng = crate::math::Rng::new(97, 2);
        // [points compared, shortcuts taken]
        let mut counts = [0usize; 2];
        for dims in [[9, 7, 6], [16, 5, 11], [3, 3, 3]] {
            for solid in [0.1f32, 0.5, 0.9] {
                let grid = VoxelGrid {
                    dims,
                    origin: [0.75, -2.0, 0.5],
                    voxel_size: 0.25,
                };
                let map = random_node_map(&mut rng, grid.len(), solid, 5);
                let masks = NeighbourMasks::new(&grid, &map);
                for i in 0..4000 {
                    let g = [0, 1, 2].map(|a| (rng.uniform() as f64 * 1.4 - 0.2) * dims[a] as f64);
                    let p = grid.to_world(g);
                    // Random normals, and normals near the ties of the 26 offsets (axis, edge
                    // and corner directions with one or two components zeroed or nudged).
                    let mut normal = crate::math::warp::uniform_sphere(rng.uniform2());
                    if i % 2 == 0 {
                        let r = |u: f32| {
                            if u < 0.3 {
                                0.0
                            } else if u < 0.65 {
                                1.0
                            } else {
                                -1.0
                            }
                        };
                        let nudge = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform())
                            * 1e-3
                            * (i % 3) as f32;
                        normal =
                            Vec3::new(r(rng.uniform()), r(rng.uniform()), r(rng.uniform())) + nudge;
                    }
                    let incident = crate::math::warp::uniform_sphere(rng.uniform2());
                    let searched =
                        map_point_searched(&grid, &map, None, p, normal, incident, false);
                    for masks in [None, Some(&masks.masks[..])] {
                        assert_eq!(
                            map_point_searched(&grid, &map, masks, p, normal, incident, true),
                            searched,
                            "dims {dims:?}, solid {solid}, p {p}, n {normal}, w {incident}"
                        );
                    }
                    counts[0] += 1;
                    let n = if normal.dot(incident) >= 0.0 {
                        normal
                    } else {
                        -normal
                    };
                    if let Some(d) = clearly_facing_offset(n.normalize_or_zero()) {
                        let v = [0, 1, 2].map(|a| (g[a].floor() as i64 + d[a]) as usize);
                        if (0..3).all(|a| v[a] < dims[a])
                            && map[grid.index(v[0], v[1], v[2])] != UNDEFINED_NODE
                        {
                            counts[1] += 1;
                        }
                    }
                }
            }
        }
        // The shortcut is taken often, and declined often.
        assert!(
            counts[1] > counts[0] / 10 && counts[1] < counts[0] * 9 / 10,
            "{counts:?}"
        );
    }

    #[test]
    fn axis_facing_offsets_are_the_facing_offsets_of_axis_normals() {
        let mut rng = crate::math::Rng::new(98, 1);
        let mut taken = 0;
        for i in 0..200_000 {
            // Along an axis (signed zeros elsewhere), with lengths across and beyond the
            // accepted range; every fourth one nudged off the axis.
            let axis = i % 3;
            let length = 10f32.powf(rng.uniform() * 16.0 - 8.0);
            let sign = if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
            let mut c = [0.0f32; 3];
            for (a, c) in c.iter_mut().enumerate() {
                *c = if a == axis {
                    sign * length
                } else if rng.uniform() < 0.5 {
                    -0.0
                } else if i % 4 == 0 {
                    (rng.uniform() - 0.5) * 1e-3 * length
                } else {
                    0.0
                };
            }
            let n = Vec3::from_array(c);
            if let Some(d) = axis_facing_offset(n) {
                taken += 1;
                assert_eq!(
                    Some(d),
                    clearly_facing_offset(n.normalize_or_zero()),
                    "{n:?}"
                );
            }
        }
        for n in [
            Vec3::ZERO,
            Vec3::new(f32::NAN, 0.0, 0.0),
            Vec3::new(0.0, f32::INFINITY, 0.0),
        ] {
            assert_eq!(axis_facing_offset(n), None);
        }
        assert!(taken > 80_000 && taken < 150_000, "{taken}");
    }

    #[test]
    fn clearly_facing_offsets_are_the_best_and_ties_are_declined() {
        let all: Vec<[i64; 3]> = NEIGHBOUR_OFFSETS
            .iter()
            .copied()
            .filter(|d| *d != [0, 0, 0])
            .collect();
        let cosine = |d: [i64; 3], n: Vec3| {
            let off = Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32);
            off.dot(n) / off.length()
        };
        let mut rng = crate::math::Rng::new(5, 9);
        let mut taken = 0;
        for _ in 0..20_000 {
            let n = crate::math::warp::uniform_sphere(rng.uniform2());
            let mut scores: Vec<(f32, [i64; 3])> = all.iter().map(|&d| (cosine(d, n), d)).collect();
            scores.sort_by(|x, y| y.0.total_cmp(&x.0));
            match clearly_facing_offset(n) {
                Some(d) => {
                    taken += 1;
                    assert_eq!(d, scores[0].1, "n {n}");
                    assert!(scores[0].0 - scores[1].0 > 9e-4, "n {n}: {scores:?}");
                }
                None => assert!(scores[0].0 - scores[1].0 < 1.1e-3, "n {n}: {scores:?}"),
            }
        }
        assert!(taken > 18_000, "{taken}");
        // (1, 0, 0) and (1, 1, 0) tie at a normal whose y is (√2 - 1) x.
        let tie = Vec3::new(1.0, std::f32::consts::SQRT_2 - 1.0, 0.0).normalize();
        for n in [Vec3::ZERO, tie, Vec3::splat(f32::NAN)] {
            assert_eq!(clearly_facing_offset(n), None, "{n}");
        }
        assert_eq!(clearly_facing_offset(-Vec3::Y), Some([0, -1, 0]));
        assert_eq!(
            clearly_facing_offset(Vec3::new(1.0, -1.0, 0.0).normalize()),
            Some([1, -1, 0])
        );
    }

    #[test]
    fn node_map_equals_the_literal_bfs() {
        let mut rng = crate::math::Rng::new(61, 3);
        for (t, dims) in [[9, 7, 6], [16, 5, 11], [4, 13, 8], [20, 20, 3]]
            .into_iter()
            .enumerate()
        {
            for density in [0.1f32, 0.35, 0.55] {
                let grid = VoxelGrid {
                    dims,
                    origin: [0.0; 3],
                    voxel_size: 1.0,
                };
                let mut occ = VoxelSet::new(grid.len());
                for i in 0..grid.len() {
                    if rng.uniform() < density {
                        occ.set(i);
                    }
                }
                let empty: Vec<usize> = (0..grid.len()).filter(|&i| !occ.get(i)).collect();
                // Some nodes share a voxel, so that seeds also come from the lattice corners.
                let nodes: Vec<Node> = (0..3 + 2 * t)
                    .map(|k| {
                        let v = empty[(rng.uniform() * empty.len() as f32) as usize % empty.len()];
                        let v = if k % 3 == 2 { empty[0] } else { v };
                        let c = grid.coords(v);
                        Node {
                            lattice: c.map(|x| x as u32 + (k % 2) as u32),
                            position: Vec3::new(0.0, 0.0, 0.0),
                            voxel: v as u32,
                            radius_voxels: 1.0,
                            radius: 1.0,
                        }
                    })
                    .collect();
                assert_eq!(
                    node_map(&grid, &occ, &nodes),
                    node_map_reference(&grid, &occ, &nodes),
                    "{dims:?} {density}"
                );
            }
        }
    }

    #[test]
    fn filtering_merges_within_balls_and_keeps_cycles() {
        // A path inside one large ball becomes one node.
        let path = graph(
            &[[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]],
            &[1.0, 5.0, 1.0, 1.0],
            &[[0, 1], [1, 2], [2, 3]],
        );
        let f = filter_skeleton(&path);
        assert_eq!(f.graph.nodes.len(), 1);
        assert_eq!(f.cluster_of, vec![0; 4]);
        // A ring inside one ball: merging it all would lose the cycle.
        let ring_points = [
            [0, 0, 0],
            [1, 0, 0],
            [2, 0, 0],
            [2, 1, 0],
            [2, 2, 0],
            [1, 2, 0],
            [0, 2, 0],
            [0, 1, 0],
        ];
        let ring_edges: Vec<[u32; 2]> = (0..8).map(|i| [i, (i + 1) % 8]).collect();
        let mut radii = [1.0f32; 8];
        radii[0] = 10.0;
        let ring = graph(&ring_points, &radii, &ring_edges);
        let f = filter_skeleton(&ring);
        // The ball takes six nodes; the two far ones stay apart and close the cycle.
        assert_eq!(f.graph.nodes.len(), 3);
        assert_eq!(f.repaired, 0);
        assert_eq!(f.graph.cycle_rank(), 1);
        assert_eq!(f.graph.components(), 1);
        // A triangle: absorbing either neighbour would leave the other with two edges into
        // the cluster, so all three stay.
        let tri = graph(
            &[[0, 0, 0], [1, 0, 0], [0, 1, 0]],
            &[3.0, 1.0, 0.5],
            &[[0, 1], [1, 2], [0, 2]],
        );
        let f = filter_skeleton(&tri);
        assert_eq!(f.graph.cycle_rank(), 1);
        assert_eq!(f.graph.nodes.len(), 3);
        assert_eq!(f.repaired, 0);
    }
}
