//! Top-down binned SAH build of the 8-wide tree itself, in the manner of Embree's
//! `BVHBuilderBinnedSAH` with branching factor 8: no tree-wide binary tree, cost table or
//! conversion pass.
//!
//! Why: building a binary tree (PLOC or `sah.rs`) and then converting it spends most of a
//! build's time walking a 2n-node binary tree (BENCHMARKS.md, "Build time by stage"). Here each
//! large 8-wide node is made by splitting its triangles with binned SAH (centroids in [`BINS`]
//! bins per axis, in-place partition of 32-byte references), always splitting the child with
//! the largest surface area next, until it has 8 children or only sets of at most [`MAX_LEAF`]
//! triangles, which become leaves (small sets take an exact SAH sweep instead of bins).
//! Sets of at most [`COLLAPSE_MAX`] triangles are built as a small binary SAH tree and
//! collapsed by the conversion's cost table ([`collapse`]): a fixed rule for leaves (split
//! every set of more than 3 triangles, never one of 3 or fewer) left nodes of two or three
//! children near the leaves, 1.4-1.8x Medium's node count; the cost table chooses leaf sizes
//! and which subtrees a node takes by the SAH, and the small tree stays in cache. Nodes are
//! written depth first in the order obvhs's conversion writes them (a node's inner children
//! contiguous after the nodes already written, then their subtrees in slot order), children
//! ordered by direction as there. Large subtrees are built on rayon tasks and spliced in that
//! order.

use glam::{Vec3A, Vec4};
use obvhs::aabb::Aabb;
use obvhs::cwbvh::node::CwBvhNode;
use obvhs::cwbvh::CwBvh;
use obvhs::triangle::Triangle;
use rayon::prelude::*;

use super::convert::{cost_row, octant_slots, splice_subtrees, Choice, Kind, MAX_LEAF, PRIM_COST};
use super::sah::{bin_scale, half_area, Bins, BINS, BIN_CHUNK};

/// Sets of at most this many triangles are split by an exact SAH sweep instead of bins (a
/// binning pass costs about as much as its 3 x [`BINS`] bins, whatever the set's size).
const SWEEP_MAX: usize = 16;
/// Nodes with more triangles than this build their inner children's subtrees on rayon tasks.
const PARALLEL_MIN: usize = 1 << 12;
/// From this depth of the 8-wide tree on, nodes split at the median of the largest child
/// instead of by SAH: every level then at least halves the largest set, so any input stays
/// within the traversal stack (`MAX_TRAVERSAL_DEPTH`, which `Bvh::build_with` checks again).
const SAH_MAX_DEPTH: u32 = 16;
/// Sets of at most this many triangles (in nodes that split by SAH) are built as a binary SAH
/// tree and collapsed into 8-wide nodes by the conversion's cost table ([`collapse`]).
const COLLAPSE_MAX: usize = 1024;
/// In a collapsed set, binary nodes from this depth on (the 8-wide depth of the set's node
/// plus the binary depth below it) split at the median: its 8-wide subtree has at most one
/// level per binary level, so the tree stays within this plus log2 [`COLLAPSE_MAX`] levels.
const COLLAPSE_SAH_MAX_DEPTH: u32 = 18;

/// A triangle's box with its index in the input in the `w` lane of `min`: 32 bytes, two SIMD
/// loads.
#[derive(Clone, Copy)]
struct PrimRef {
    min: Vec4,
    max: Vec4,
}

impl PrimRef {
    #[inline(always)]
    fn lo(&self) -> Vec3A {
        Vec3A::from_vec4(self.min)
    }

    #[inline(always)]
    fn hi(&self) -> Vec3A {
        Vec3A::from_vec4(self.max)
    }

    #[inline(always)]
    fn index(&self) -> u32 {
        self.min.w.to_bits()
    }

    /// Twice the box centre (the bins only need the centres' order).
    #[inline(always)]
    fn centroid2(&self) -> Vec3A {
        self.lo() + self.hi()
    }
}

/// A set of triangles: its box and the bounds of its (doubled) centroids.
#[derive(Clone, Copy)]
struct Set {
    start: usize,
    end: usize,
    bounds: Aabb,
    centroids: Aabb,
}

impl Set {
    fn len(&self) -> usize {
        self.end - self.start
    }
}

/// Box and doubled-centroid bounds of `prims`.
fn bounds_of(prims: &[PrimRef]) -> (Aabb, Aabb) {
    let (mut b, mut c) = (Aabb::empty(), Aabb::empty());
    for p in prims {
        b.min = b.min.min(p.lo());
        b.max = b.max.max(p.hi());
        c.extend(p.centroid2());
    }
    (b, c)
}

/// The built tree and its 8-wide SAH cost (the conversion's cost model: each inner node's half
/// area, plus [`PRIM_COST`] times each leaf's half area per triangle).
pub(crate) struct Built {
    pub cwbvh: CwBvh,
    pub cost: f32,
}

/// Builds the 8-wide tree over the triangles (global triangle order).
pub(crate) fn build(tris: &[Triangle]) -> Built {
    build_to_depth(tris, SAH_MAX_DEPTH)
}

/// [`build`] with SAH splits in nodes above depth `sah_max_depth` and median splits below.
fn build_to_depth(tris: &[Triangle], sah_max_depth: u32) -> Built {
    if tris.is_empty() {
        return Built {
            cwbvh: CwBvh::default(),
            cost: 0.0,
        };
    }
    let mut prims: Vec<PrimRef> = tris
        .par_iter()
        .enumerate()
        .map(|(i, t)| {
            let (lo, hi) = (t.v0.min(t.v1).min(t.v2), t.v0.max(t.v1).max(t.v2));
            PrimRef {
                min: lo.extend(f32::from_bits(i as u32)),
                max: hi.extend(0.0),
            }
        })
        .collect();
    let (bounds, centroids) = prims.par_chunks(BIN_CHUNK).map(bounds_of).reduce(
        || (Aabb::empty(), Aabb::empty()),
        |a, b| (a.0.union(&b.0), a.1.union(&b.1)),
    );
    let root = Set {
        start: 0,
        end: prims.len(),
        bounds,
        centroids,
    };
    let (nodes, primitive_indices, cost) = subtree(&mut prims, root, (0, sah_max_depth));
    Built {
        cwbvh: CwBvh {
            nodes,
            primitive_indices,
            total_aabb: bounds,
            exact_node_aabbs: None,
            uses_spatial_splits: false,
        },
        cost,
    }
}

/// The 8-wide subtree over `prims` (the whole of `set`) with its root at index 0 and node and
/// primitive indices relative to the returned arrays, and its cost.
fn subtree(prims: &mut [PrimRef], set: Set, depth: (u32, u32)) -> (Vec<CwBvhNode>, Vec<u32>, f32) {
    let mut nodes = vec![CwBvhNode::default()];
    let mut out = Vec::new();
    let cost = node(prims, set, depth, 0, &mut nodes, &mut out);
    (nodes, out, cost)
}

/// A child of an 8-wide node being laid out: its box, its triangles (`prims[range]`), whether
/// it becomes a leaf, and the caller's index of it.
struct SlotChild {
    bounds: Aabb,
    range: std::ops::Range<usize>,
    leaf: bool,
    id: usize,
}

/// Lays out node `n`'s children (over `node_bounds`) in slot order: a leaf's triangles are
/// appended to `out`, with its meta; an inner child gets its `imask` bit and meta. Returns the
/// node's SAH cost without its inner subtrees, and the ids of its inner children in slot order
/// (the first `count` of the array), whose nodes follow at `child_base_idx`.
fn lay_out(
    n: &mut CwBvhNode,
    node_bounds: &Aabb,
    by_slot: [Option<SlotChild>; 8],
    prims: &[PrimRef],
    out: &mut Vec<u32>,
) -> (f32, [usize; 8], usize) {
    let mut cost = half_area(node_bounds);
    let (mut inner, mut inner_count) = ([0usize; 8], 0);
    let mut leaf_prims = 0u32;
    for (slot, child) in by_slot.into_iter().enumerate() {
        let Some(child) = child else {
            continue;
        };
        if child.leaf {
            let k = child.range.len() as u32;
            out.extend(prims[child.range].iter().map(PrimRef::index));
            n.child_meta[slot] = leaf_prims as u8 | ((1u8 << k) - 1) << 5;
            leaf_prims += k;
            cost += half_area(&child.bounds) * k as f32 * PRIM_COST;
        } else {
            n.imask |= 1 << slot;
            n.child_meta[slot] = (24 + slot as u8) | 0b0010_0000;
            inner[inner_count] = child.id;
            inner_count += 1;
        }
    }
    (cost, inner, inner_count)
}

/// Makes node `wide` (already allocated) over `prims` (the whole of `set`, which need not fit a
/// leaf), then its inner children's subtrees depth first; returns the subtree's cost. `depth`
/// is the node's and the depth from which nodes split at the median.
fn node(
    prims: &mut [PrimRef],
    set: Set,
    (depth, sah_max_depth): (u32, u32),
    wide: usize,
    nodes: &mut Vec<CwBvhNode>,
    out: &mut Vec<u32>,
) -> f32 {
    let median = depth >= sah_max_depth;
    if !median && set.len() <= COLLAPSE_MAX {
        return collapse(prims, set, depth, wide, nodes, out);
    }
    let (children, count) = open(prims, set, median);
    let children = &children[..count];
    let centres: [Vec3A; 8] = std::array::from_fn(|c| {
        children
            .get(c)
            .map_or(Vec3A::ZERO, |s: &Set| s.bounds.center())
    });
    let slots = octant_slots(set.bounds.center(), &centres[..count]);
    let mut by_slot: [Option<SlotChild>; 8] = Default::default();
    for (c, &slot) in slots.iter().enumerate().take(count) {
        let child = &children[c];
        by_slot[slot] = Some(SlotChild {
            bounds: child.bounds,
            range: child.start..child.end,
            leaf: child.len() <= MAX_LEAF as usize,
            id: c,
        });
    }
    let mut n = CwBvhNode {
        primitive_base_idx: out.len() as u32,
        child_base_idx: nodes.len() as u32,
        ..CwBvhNode::default()
    };
    let (mut cost, inner, inner_count) = lay_out(&mut n, &set.bounds, by_slot, prims, out);
    nodes.resize(nodes.len() + inner_count, CwBvhNode::default());
    nodes[wide] = n;
    let inner = &inner[..inner_count];
    let base = n.child_base_idx as usize;
    if set.len() <= PARALLEL_MIN {
        for (rank, &c) in inner.iter().enumerate() {
            let child = rebased(&children[c]);
            let range = children[c].start..children[c].end;
            cost += node(
                &mut prims[range],
                child,
                (depth + 1, sah_max_depth),
                base + rank,
                nodes,
                out,
            );
        }
        return cost;
    }
    // Disjoint slices of the inner children (which lie in `prims` in no particular order),
    // built on separate tasks and spliced in slot order.
    let mut ranked: Vec<(usize, usize)> = inner.iter().enumerate().map(|(r, &c)| (c, r)).collect();
    ranked.sort_unstable_by_key(|&(c, _)| children[c].start);
    let mut parts: Vec<(usize, &mut [PrimRef], Set)> = Vec::with_capacity(inner_count);
    let (mut rest, mut consumed) = (prims, 0usize);
    for &(c, rank) in &ranked {
        let s = &children[c];
        let (_, tail) = rest.split_at_mut(s.start - consumed);
        let (slice, tail) = tail.split_at_mut(s.len());
        parts.push((rank, slice, rebased(s)));
        rest = tail;
        consumed = s.end;
    }
    parts.sort_unstable_by_key(|p| p.0);
    let built: Vec<(Vec<CwBvhNode>, Vec<u32>, f32)> = parts
        .into_par_iter()
        .map(|(_, slice, s)| subtree(slice, s, (depth + 1, sah_max_depth)))
        .collect();
    let mut subtrees = Vec::with_capacity(built.len());
    for (sub_nodes, sub_prims, sub_cost) in built {
        cost += sub_cost;
        subtrees.push((sub_nodes, sub_prims));
    }
    splice_subtrees(nodes, out, base, subtrees);
    cost
}

/// `set` as the whole of its own slice.
fn rebased(set: &Set) -> Set {
    Set {
        start: 0,
        end: set.len(),
        ..*set
    }
}

/// Splits `set` into up to 8 children, Embree's way: the child with the largest surface area
/// among those too large for a leaf is split next (the one with the most triangles when
/// `median`). Leaves are not split further: their triangles are tested together, one SIMD
/// block, and each split costs a binning pass. Returns the children (the first `count`), which
/// partition `prims` into contiguous ranges.
fn open(prims: &mut [PrimRef], set: Set, median: bool) -> ([Set; 8], usize) {
    let mut children = [set; 8];
    let mut count = 1;
    while count < 8 {
        let mut best = (f32::NEG_INFINITY, usize::MAX);
        for (i, c) in children[..count].iter().enumerate() {
            if c.len() <= MAX_LEAF as usize {
                continue;
            }
            let key = if median {
                c.len() as f32
            } else {
                // A NaN area (non-finite input) still gets split, after all others.
                let a = half_area(&c.bounds);
                if a.is_nan() {
                    -1.0
                } else {
                    a
                }
            };
            if key > best.0 {
                best = (key, i);
            }
        }
        let (_, i) = best;
        if i == usize::MAX {
            break;
        }
        let (l, r) = split(prims, children[i], median);
        children[i] = l;
        children[count] = r;
        count += 1;
    }
    (children, count)
}

/// Splits `set` (at least 2 triangles) into two non-empty sets: the SAH split (binned, or the
/// exact sweep for at most [`SWEEP_MAX`] triangles), or at the
/// median of the widest centroid axis when `median` or when no bin boundary separates the
/// centroids (then in the middle of the range if they all coincide).
fn split(prims: &mut [PrimRef], set: Set, median: bool) -> (Set, Set) {
    let slice = &mut prims[set.start..set.end];
    let m = slice.len();
    debug_assert!(m >= 2);
    let binned = if median {
        None
    } else if m <= SWEEP_MAX {
        sweep_split(slice)
    } else {
        binned_split(slice, &set.centroids)
    };
    let (k, [lb, lc], [rb, rc]) = match binned {
        Some(s) => s,
        None => {
            let extent = set.centroids.max - set.centroids.min;
            let mid = m / 2;
            if extent.max_element() > 0.0 {
                let axis = extent.max_position();
                slice.select_nth_unstable_by(mid, |a, b| {
                    a.centroid2()[axis].total_cmp(&b.centroid2()[axis])
                });
            }
            let (l, r) = slice.split_at(mid);
            let ((lb, lc), (rb, rc)) = (bounds_of(l), bounds_of(r));
            (mid, [lb, lc], [rb, rc])
        }
    };
    debug_assert!(k > 0 && k < m);
    let mid = set.start + k;
    (
        Set {
            start: set.start,
            end: mid,
            bounds: lb,
            centroids: lc,
        },
        Set {
            start: mid,
            end: set.end,
            bounds: rb,
            centroids: rc,
        },
    )
}

/// Exact SAH over every split between the centroids sorted along each axis (ties in slice
/// order); reorders `prims` so that the split is `prims[..k]`, `prims[k..]`. Returns k and both
/// sides' box and centroid bounds, or None when every cost is NaN (non-finite input).
#[allow(clippy::type_complexity)]
fn sweep_split(prims: &mut [PrimRef]) -> Option<(usize, [Aabb; 2], [Aabb; 2])> {
    let m = prims.len();
    debug_assert!(m <= SWEEP_MAX);
    let mut best = (f32::INFINITY, 0usize, [0u8; SWEEP_MAX]); // (cost, k, order)
    let mut right_area = [0.0f32; SWEEP_MAX];
    for axis in 0..3 {
        let mut keys = [(0.0f32, 0u8); SWEEP_MAX];
        for (i, p) in prims.iter().enumerate() {
            keys[i] = (p.centroid2()[axis], i as u8);
        }
        let keys = &mut keys[..m];
        keys.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut acc = Aabb::empty();
        for k in (1..m).rev() {
            let p = &prims[keys[k].1 as usize];
            acc = acc.union(&Aabb::new(p.lo(), p.hi()));
            right_area[k] = half_area(&acc);
        }
        let mut acc = Aabb::empty();
        let mut improved = false;
        for k in 1..m {
            let p = &prims[keys[k - 1].1 as usize];
            acc = acc.union(&Aabb::new(p.lo(), p.hi()));
            let cost = half_area(&acc) * k as f32 + right_area[k] * (m - k) as f32;
            if cost < best.0 {
                (best.0, best.1) = (cost, k);
                improved = true;
            }
        }
        if improved {
            for (o, key) in best.2.iter_mut().zip(keys.iter()) {
                *o = key.1;
            }
        }
    }
    let (_, k, order) = best;
    if k == 0 {
        return None;
    }
    let original: [PrimRef; SWEEP_MAX] = std::array::from_fn(|i| prims[i.min(m - 1)]);
    for (p, &o) in prims.iter_mut().zip(order.iter()) {
        *p = original[o as usize];
    }
    let ((lb, lc), (rb, rc)) = (bounds_of(&prims[..k]), bounds_of(&prims[k..]));
    Some((k, [lb, lc], [rb, rc]))
}

/// The bin of a (doubled) centroid on each axis (`scale` 0 on an axis of zero extent).
#[inline(always)]
fn bins_of(c: Vec3A, min: Vec3A, scale: Vec3A) -> [usize; 3] {
    let f = ((c - min) * scale).to_array();
    f.map(|x| (x as usize).min(BINS - 1))
}

/// Binned SAH (Wald 2007) over the three axes; partitions `prims` in place. Returns the left
/// size and both sides' box and centroid bounds (gathered while partitioning), or None when no
/// bin boundary separates the centroids.
#[allow(clippy::type_complexity)]
fn binned_split(prims: &mut [PrimRef], centroids: &Aabb) -> Option<(usize, [Aabb; 2], [Aabb; 2])> {
    let m = prims.len();
    let extent = centroids.max - centroids.min;
    let scale = bin_scale(extent);
    let bins = Bins::of(prims, |bins, chunk| {
        for p in chunk {
            bins.add_box(bins_of(p.centroid2(), centroids.min, scale), p.lo(), p.hi());
        }
    });
    let (axis, boundary) = bins.best_split(extent)?;
    let (min, scale) = (centroids.min[axis], scale[axis]);
    let is_left =
        |p: &PrimRef| ((((p.centroid2()[axis] - min) * scale) as usize).min(BINS - 1)) < boundary;
    // Hoare partition, collecting both sides' bounds on the way.
    let mut sides = [[Aabb::empty(); 2]; 2]; // [left, right] x [boxes, centroids]
    let add = |side: &mut [Aabb; 2], p: &PrimRef| {
        side[0].min = side[0].min.min(p.lo());
        side[0].max = side[0].max.max(p.hi());
        side[1].extend(p.centroid2());
    };
    let (mut i, mut j) = (0usize, m);
    loop {
        while i < j && is_left(&prims[i]) {
            add(&mut sides[0], &prims[i]);
            i += 1;
        }
        while i < j && !is_left(&prims[j - 1]) {
            add(&mut sides[1], &prims[j - 1]);
            j -= 1;
        }
        if i >= j {
            break;
        }
        // prims[i] goes right and prims[j - 1] left.
        prims.swap(i, j - 1);
        add(&mut sides[0], &prims[i]);
        add(&mut sides[1], &prims[j - 1]);
        i += 1;
        j -= 1;
    }
    debug_assert!(i > 0 && i < m);
    Some((i, sides[0], sides[1]))
}

/// A node of the binary tree of a collapsed set ([`collapse`]): its box, its triangles
/// (`prims[start..end]`), its children (`left` and `left + 1`; none for one triangle) and its
/// row of the conversion's cost table.
struct BinaryNode {
    bounds: Aabb,
    start: u32,
    end: u32,
    left: u32,
    cost: [f32; 7],
    choice: [Choice; 7],
}

/// Makes node `wide` over `prims` (the whole of `set`) and its subtree from a binary SAH tree
/// collapsed by the conversion's cost table: each 8-wide node takes the cheapest cover of its
/// binary subtree by up to 8 leaves (1 to [`MAX_LEAF`] triangles) and subtrees, so that leaf
/// sizes and the children's split between leaves and inner nodes follow the SAH rather than
/// the order in which [`open`] splits. Returns the subtree's cost.
fn collapse(
    prims: &mut [PrimRef],
    set: Set,
    depth: u32,
    wide: usize,
    nodes: &mut Vec<CwBvhNode>,
    out: &mut Vec<u32>,
) -> f32 {
    let mut tree = Vec::with_capacity(2 * set.len());
    tree.push(BinaryNode {
        bounds: set.bounds,
        start: 0,
        end: set.len() as u32,
        left: u32::MAX,
        cost: [0.0; 7],
        choice: [Choice::LEAF; 7],
    });
    grow(prims, set, depth, 0, &mut tree);
    emit(prims, &tree, 0, wide, nodes, out)
}

/// Splits binary node `i` (over `set`) down to one triangle per leaf, then fills its row of
/// the cost table ([`cost_row`], as `CostTable::fill` does). Splits are SAH
/// splits down to [`COLLAPSE_SAH_MAX_DEPTH`] (counting the 8-wide depth above), median ones
/// below, so the 8-wide subtree (at most one level per binary level) stays within the
/// traversal stack.
fn grow(prims: &mut [PrimRef], set: Set, depth: u32, i: usize, tree: &mut Vec<BinaryNode>) {
    let ha = half_area(&set.bounds);
    let m = set.len();
    if m == 1 {
        tree[i].cost = [ha * PRIM_COST; 7];
        return;
    }
    let (l, r) = split(prims, set, depth >= COLLAPSE_SAH_MAX_DEPTH);
    let left = tree.len();
    for s in [&l, &r] {
        tree.push(BinaryNode {
            bounds: s.bounds,
            start: s.start as u32,
            end: s.end as u32,
            left: u32::MAX,
            cost: [0.0; 7],
            choice: [Choice::LEAF; 7],
        });
    }
    tree[i].left = left as u32;
    grow(prims, l, depth + 1, left, tree);
    grow(prims, r, depth + 1, left + 1, tree);
    let (cl, cr) = (tree[left].cost, tree[left + 1].cost);
    (tree[i].cost, tree[i].choice) = cost_row(&cl, &cr, ha, m as u32);
}

/// The subtrees that column `column` of binary node `i` distributes to (`CostTable::gather`).
fn gather(
    tree: &[BinaryNode],
    i: usize,
    column: usize,
    children: &mut [u32; 8],
    count: &mut usize,
) {
    let n = &tree[i];
    if n.left == u32::MAX {
        children[*count] = i as u32;
        *count += 1;
        return;
    }
    let choice = n.choice[column];
    for (child, col) in [
        (n.left as usize, choice.left as usize),
        (n.left as usize + 1, choice.right as usize),
    ] {
        if tree[child].choice[col].kind == Kind::Distribute {
            gather(tree, child, col, children, count);
        } else {
            children[*count] = child as u32;
            *count += 1;
        }
    }
}

/// Fills node `wide` (already allocated) for binary node `i` with the up to 8 subtrees of its
/// cheapest cover, ordered by direction, then its inner children's subtrees depth first, in
/// the layout of [`node`]; returns the subtree's cost.
fn emit(
    prims: &[PrimRef],
    tree: &[BinaryNode],
    i: usize,
    wide: usize,
    nodes: &mut Vec<CwBvhNode>,
    out: &mut Vec<u32>,
) -> f32 {
    let (mut children, mut count) = ([u32::MAX; 8], 0);
    gather(tree, i, 0, &mut children, &mut count);
    let centres: [Vec3A; 8] = std::array::from_fn(|c| {
        children[..count]
            .get(c)
            .map_or(Vec3A::ZERO, |&k| tree[k as usize].bounds.center())
    });
    let slots = octant_slots(tree[i].bounds.center(), &centres[..count]);
    let mut by_slot: [Option<SlotChild>; 8] = Default::default();
    for c in 0..count {
        let id = children[c] as usize;
        let child = &tree[id];
        let leaf = child.choice[0].kind == Kind::Leaf;
        debug_assert!(!leaf || (1..=MAX_LEAF).contains(&(child.end - child.start)));
        by_slot[slots[c]] = Some(SlotChild {
            bounds: child.bounds,
            range: child.start as usize..child.end as usize,
            leaf,
            id,
        });
    }
    let mut n = CwBvhNode {
        primitive_base_idx: out.len() as u32,
        child_base_idx: nodes.len() as u32,
        ..CwBvhNode::default()
    };
    let (mut cost, inner, inner_count) = lay_out(&mut n, &tree[i].bounds, by_slot, prims, out);
    nodes.resize(nodes.len() + inner_count, CwBvhNode::default());
    nodes[wide] = n;
    let base = n.child_base_idx as usize;
    for (rank, &c) in inner[..inner_count].iter().enumerate() {
        cost += emit(prims, tree, c, base + rank, nodes, out);
    }
    cost
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    fn random_triangles(n: usize, rng: &mut Rng) -> Vec<Triangle> {
        (0..n)
            .map(|_| {
                let c = Vec3A::new(rng.uniform(), rng.uniform(), rng.uniform()) * 10.0;
                let mut v = || c + (Vec3A::new(rng.uniform(), rng.uniform(), rng.uniform()) - 0.5);
                Triangle {
                    v0: v(),
                    v1: v(),
                    v2: v(),
                }
            })
            .collect()
    }

    fn tri_box(t: &Triangle) -> Aabb {
        Aabb::new(t.v0.min(t.v1).min(t.v2), t.v0.max(t.v1).max(t.v2))
    }

    /// Walks the tree from the root: every node reached exactly once, children after their
    /// parent, leaves of 1 to 3 triangles within the node's 24 triangle bits, every triangle
    /// in exactly one leaf. Returns the exact box of node `i`'s subtree, the subtree's cost in
    /// the conversion's model recomputed from those boxes, and the deepest inner node's depth.
    fn check(
        tris: &[Triangle],
        built: &CwBvh,
        i: usize,
        depth: usize,
        reached: &mut [u32],
        seen: &mut [u32],
    ) -> (Aabb, f64, usize) {
        reached[i] += 1;
        let node = &built.nodes[i];
        let (mut bounds, mut cost, mut deepest) = (Aabb::empty(), 0.0f64, depth);
        let mut rank = 0;
        let mut child_boxes = Vec::new();
        for c in 0..8 {
            let meta = node.child_meta[c];
            if node.imask & (1 << c) != 0 {
                assert_eq!(meta, (24 + c as u8) | 0b0010_0000);
                let child = (node.child_base_idx + rank) as usize;
                rank += 1;
                assert!(child > i, "children after their parent");
                let (b, k, d) = check(tris, built, child, depth + 1, reached, seen);
                child_boxes.push(b);
                cost += k;
                deepest = deepest.max(d);
            } else if meta != 0 {
                let (offset, count) = ((meta & 0x1f) as u32, (meta >> 5).count_ones());
                assert!((1..=3).contains(&count) && meta >> 5 == (1 << count) - 1);
                assert!(offset + count <= 24);
                let mut b = Aabb::empty();
                for k in 0..count {
                    let id =
                        built.primitive_indices[(node.primitive_base_idx + offset + k) as usize];
                    seen[id as usize] += 1;
                    b = b.union(&tri_box(&tris[id as usize]));
                }
                child_boxes.push(b);
                cost += (half_area(&b) * count as f32 * PRIM_COST) as f64;
            }
        }
        assert!(!child_boxes.is_empty(), "node {i} has no children");
        for b in &child_boxes {
            bounds = bounds.union(b);
        }
        // The node's box contains each child's (it is their union; a child is never empty).
        for b in &child_boxes {
            assert!(bounds.min.cmple(b.min).all() && b.max.cmple(bounds.max).all());
            assert!(b.min.cmple(b.max).all());
        }
        (bounds, cost + half_area(&bounds) as f64, deepest)
    }

    /// Checks the tree and returns its depth.
    fn check_tree(tris: &[Triangle], built: &Built) -> usize {
        let n = tris.len();
        let mut reached = vec![0u32; built.cwbvh.nodes.len()];
        let mut seen = vec![0u32; n];
        let (bounds, cost, depth) = check(tris, &built.cwbvh, 0, 0, &mut reached, &mut seen);
        assert!(reached.iter().all(|&r| r == 1), "every node reached once");
        assert!(
            seen.iter().all(|&s| s == 1),
            "every triangle in exactly one leaf"
        );
        assert_eq!(built.cwbvh.primitive_indices.len(), n);
        let total = tris.iter().fold(Aabb::empty(), |b, t| b.union(&tri_box(t)));
        assert_eq!((bounds.min, bounds.max), (total.min, total.max));
        // The cost the builder reports is the tree's (summed in another order).
        let reported = built.cost as f64;
        assert!(
            (reported - cost).abs() <= 1e-4 * cost,
            "cost {reported} vs {cost}, n = {n}"
        );
        depth
    }

    /// Every triangle in exactly one leaf, nested boxes, the reported cost, on random
    /// triangles from one to enough for the parallel binning and subtrees.
    #[test]
    fn every_triangle_in_exactly_one_leaf() {
        let mut rng = Rng::new(30, 7);
        for n in [1usize, 2, 3, 4, 5, 8, 9, 25, 26, 100, 4097, 70_000] {
            let tris = random_triangles(n, &mut rng);
            let built = build(&tris);
            let depth = check_tree(&tris, &built);
            // Near-balanced on uniform input: a few levels more than a full 8-ary tree.
            let full = (n as f64 / 3.0).log(8.0).ceil().max(0.0) as usize;
            assert!(
                depth <= full + 3,
                "n = {n}: depth {depth}, full tree {full}"
            );
        }
    }

    /// The tree does not depend on the number of threads (the bins merge exactly).
    #[test]
    fn same_tree_on_one_and_two_threads() {
        let tris = random_triangles(60_000, &mut Rng::new(30, 8));
        let on = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            pool.install(|| build(&tris))
        };
        let (a, b) = (on(1), on(2));
        assert_eq!(a.cwbvh.primitive_indices, b.cwbvh.primitive_indices);
        assert_eq!(a.cost, b.cost);
        assert_eq!(a.cwbvh.nodes.len(), b.cwbvh.nodes.len());
        for (x, y) in a.cwbvh.nodes.iter().zip(&b.cwbvh.nodes) {
            let key = |n: &CwBvhNode| {
                (
                    n.imask,
                    n.child_base_idx,
                    n.primitive_base_idx,
                    n.child_meta,
                )
            };
            assert_eq!(key(x), key(y));
        }
    }

    /// Depth bounds: median splits (from the root here) give a near-full 8-ary tree, and
    /// degenerate inputs (a geometric chain, on which SAH peels one triangle at a time;
    /// identical and nested triangles) stay within the traversal stack without the
    /// fallback of `Bvh::build_with`.
    #[test]
    fn depth_is_bounded() {
        let mut rng = Rng::new(30, 9);
        for n in [4usize, 100, 5000, 100_000] {
            let tris = random_triangles(n, &mut rng);
            let built = build_to_depth(&tris, 0);
            let depth = check_tree(&tris, &built);
            let bound = ((n as f64).log2() / 3.0).ceil() as usize + 1;
            assert!(depth <= bound, "median, n = {n}: depth {depth} > {bound}");
        }
        let across = |x: f32, s: f32| Triangle {
            v0: Vec3A::new(x, 0.0, 0.0),
            v1: Vec3A::new(x, s, 0.0),
            v2: Vec3A::new(x, 0.0, s),
        };
        let chain: Vec<Triangle> = (0..850).map(|i| across(1.1f32.powi(i), 1e-3)).collect();
        let identical = vec![across(0.0, 1.0); 4000];
        let nested: Vec<Triangle> = (0..3000)
            .map(|i| {
                let s = 1e-3 * 1.01f32.powi(i);
                Triangle {
                    v0: Vec3A::new(-s, -s, 0.0),
                    v1: Vec3A::new(s, -s, 0.0),
                    v2: Vec3A::new(0.0, s, s),
                }
            })
            .collect();
        for (name, tris) in [
            ("chain", chain),
            ("identical", identical),
            ("nested", nested),
        ] {
            let depth = check_tree(&tris, &build(&tris));
            assert!(
                depth <= super::super::bvh::MAX_TRAVERSAL_DEPTH,
                "{name}: depth {depth}"
            );
        }
    }
}
