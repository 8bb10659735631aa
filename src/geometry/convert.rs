//! The binary BVH -> 8-wide conversion of obvhs (`bvh2_to_cwbvh`, Ylitie et al. 2017: a
//! bottom-up table of the SAH cost of covering each binary subtree with up to 8 subtrees, then
//! a top-down walk that collapses the binary tree along the cheapest choices), with the same
//! decisions, child order, node and primitive layout, but on several threads and in less
//! memory, and without the 8-bit quantised child boxes (Lacuna's [`super::bvh`] stores exact
//! ones).
//!
//! Why: obvhs's conversion runs on one thread over a 84-byte-per-binary-node decision table; on
//! a million triangles it took as long as the PLOC build itself (BENCHMARKS.md, "BVH build by
//! stage"). The table here is 36 bytes per node (costs and packed choices), filled by
//! independent subtrees in parallel; the top-down walk converts the top subtrees in parallel and
//! splices their nodes and primitives in the order obvhs's recursion emits them.

use std::sync::atomic::{AtomicU32, AtomicU8, Ordering::Relaxed};

use glam::Vec3A;
use obvhs::bvh2::Bvh2;
use obvhs::cwbvh::node::CwBvhNode;
use obvhs::cwbvh::CwBvh;
use rayon::prelude::*;

/// Cost of one primitive relative to a node visit (obvhs's `PRIM_COST`).
pub(crate) const PRIM_COST: f32 = 0.3;
/// Most triangles in one leaf of the 8-wide tree (obvhs's `max_prims_per_leaf` as Lacuna calls
/// it; the leaf encoding allows 3).
pub(crate) const MAX_LEAF: u32 = 3;
/// Binary subtrees whose root is above this depth fill their cost tables on separate rayon
/// tasks (2^12 tasks at most; below, one task per subtree).
const PARALLEL_COST_DEPTH: u32 = 12;
/// 8-wide subtrees whose root is above this depth are converted on separate rayon tasks.
const PARALLEL_CONVERT_DEPTH: u32 = 3;

/// What a binary node becomes when it may use `i + 1` subtrees (`i` the table column).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {
    Leaf = 0,
    Internal = 1,
    Distribute = 2,
}

/// The cost table of one binary node: for i in 0..7, the SAH cost of covering the subtree
/// with at most i + 1 subtrees (column 0: one 8-wide node or one leaf), and the choice behind it
/// packed as kind << 6 | left << 3 | right (the columns of the two children it distributes to).
/// Atomics only because tasks on different subtrees fill disjoint entries of one table
/// (relaxed loads and stores are plain moves; `rayon::join` orders children before parents).
#[derive(Default)]
struct NodeCosts {
    cost: [AtomicU32; 7],
    choice: [AtomicU8; 7],
}

/// A table entry's choice: its [`Kind`] and the columns of the two children it distributes
/// to.
#[derive(Clone, Copy)]
pub(super) struct Choice {
    pub kind: Kind,
    pub left: u8,
    pub right: u8,
}

impl Choice {
    pub(super) const LEAF: Choice = Choice {
        kind: Kind::Leaf,
        left: 0,
        right: 0,
    };

    fn pack(self) -> u8 {
        ((self.kind as u8) << 6) | (self.left << 3) | self.right
    }

    fn unpack(v: u8) -> Choice {
        Choice {
            kind: match v >> 6 {
                0 => Kind::Leaf,
                1 => Kind::Internal,
                _ => Kind::Distribute,
            },
            left: (v >> 3) & 7,
            right: v & 7,
        }
    }
}

/// The cost-table row ([`NodeCosts`]) of a binary node with `prims` triangles and half area
/// `half_area`, from its two children's rows `cl` and `cr`. Column 0: a leaf (at most
/// [`MAX_LEAF`] triangles), or an 8-wide node over the best split of 8 subtrees between the
/// children; columns 1..7: distribute i + 1 subtrees between the children, or keep column
/// i - 1. Where no split has a finite cost (non-finite bounds) column 0 names (0, 6), so that
/// every choice names valid columns; obvhs leaves that case undefined.
pub(super) fn cost_row(
    cl: &[f32; 7],
    cr: &[f32; 7],
    half_area: f32,
    prims: u32,
) -> ([f32; 7], [Choice; 7]) {
    let cost_leaf = if prims <= MAX_LEAF {
        (prims as f32) * half_area * PRIM_COST
    } else {
        f32::INFINITY
    };
    let (mut cost_distribute, mut left, mut right) = (f32::INFINITY, 0u8, 6u8);
    for k in 0..7 {
        let c = cl[k] + cr[6 - k];
        if c < cost_distribute {
            (cost_distribute, left, right) = (c, k as u8, 6 - k as u8);
        }
    }
    let cost_internal = cost_distribute + half_area;
    let mut previous = if cost_leaf < cost_internal {
        (cost_leaf, Kind::Leaf)
    } else {
        (cost_internal, Kind::Internal)
    };
    let mut previous_choice = Choice {
        kind: previous.1,
        left,
        right,
    };
    let (mut costs, mut choices) = ([0.0; 7], [Choice::LEAF; 7]);
    (costs[0], choices[0]) = (previous.0, previous_choice);
    for i in 1..7 {
        let mut best = None;
        let mut cost_distribute = previous.0;
        for k in 0..i {
            let c = cl[k] + cr[i - k - 1];
            if c < cost_distribute {
                cost_distribute = c;
                best = Some((k as u8, (i - k - 1) as u8));
            }
        }
        if let Some((left, right)) = best {
            previous_choice = Choice {
                kind: Kind::Distribute,
                left,
                right,
            };
            previous = (cost_distribute, Kind::Distribute);
        }
        (costs[i], choices[i]) = (previous.0, previous_choice);
    }
    (costs, choices)
}

/// The cost table of a binary BVH with one primitive per leaf (as both of Lacuna's builders
/// make), ready to convert.
pub(crate) struct CostTable<'a> {
    bvh2: &'a Bvh2,
    nodes: Vec<NodeCosts>,
}

impl<'a> CostTable<'a> {
    /// Fills the table bottom-up (obvhs's `calculate_cost` with 3 primitives per leaf, the
    /// same arithmetic in the same order, so the same costs and choices).
    pub(crate) fn new(bvh2: &'a Bvh2) -> CostTable<'a> {
        let nodes = (0..bvh2.nodes.len())
            .into_par_iter()
            .map(|_| NodeCosts::default())
            .collect();
        let table = CostTable { bvh2, nodes };
        if !bvh2.nodes.is_empty() {
            table.fill(0, 0);
        }
        table
    }

    /// SAH cost of the 8-wide tree (obvhs's `decisions[0].cost`).
    pub(crate) fn root_cost(&self) -> f32 {
        self.cost(0, 0)
    }

    fn cost(&self, node: usize, i: usize) -> f32 {
        f32::from_bits(self.nodes[node].cost[i].load(Relaxed))
    }

    fn choice(&self, node: usize, i: usize) -> Choice {
        Choice::unpack(self.nodes[node].choice[i].load(Relaxed))
    }

    fn set(&self, node: usize, i: usize, cost: f32, choice: Choice) {
        self.nodes[node].cost[i].store(cost.to_bits(), Relaxed);
        self.nodes[node].choice[i].store(choice.pack(), Relaxed);
    }

    /// Fills the entries of `node`'s subtree; returns its number of primitives.
    fn fill(&self, node: usize, depth: u32) -> u32 {
        let n = &self.bvh2.nodes[node];
        let half_area = n.aabb().half_area();
        if n.is_leaf() {
            let cost = half_area * (n.prim_count as f32) * PRIM_COST;
            for i in 0..7 {
                self.set(node, i, cost, Choice::LEAF);
            }
            return n.prim_count;
        }
        let (l, r) = (n.first_index as usize, n.first_index as usize + 1);
        let (pl, pr) = if depth < PARALLEL_COST_DEPTH {
            rayon::join(|| self.fill(l, depth + 1), || self.fill(r, depth + 1))
        } else {
            (self.fill(l, depth + 1), self.fill(r, depth + 1))
        };
        let prims = pl + pr;
        let (cl, cr): ([f32; 7], [f32; 7]) = (
            std::array::from_fn(|i| self.cost(l, i)),
            std::array::from_fn(|i| self.cost(r, i)),
        );
        let (costs, choices) = cost_row(&cl, &cr, half_area, prims);
        for i in 0..7 {
            self.set(node, i, costs[i], choices[i]);
        }
        prims
    }

    /// The 8-wide tree: obvhs's `convert_to_cwbvh` on these choices, with children ordered by
    /// direction. The nodes' quantised boxes (`p`, `e`, `child_min_*`, `child_max_*`) are left
    /// zero: Lacuna's nodes take exact boxes from the triangles.
    pub(crate) fn convert(&self) -> CwBvh {
        if self.bvh2.nodes.is_empty() {
            return CwBvh::default();
        }
        let (nodes, primitive_indices) = self.subtree(0, 0);
        CwBvh {
            nodes,
            primitive_indices,
            total_aabb: *self.bvh2.nodes[0].aabb(),
            exact_node_aabbs: None,
            uses_spatial_splits: self.bvh2.uses_spatial_splits,
        }
    }

    /// The 8-wide subtree rooted at binary node `root`, as obvhs would emit it into empty
    /// arrays: the root at index 0, node and primitive indices relative to the returned arrays.
    fn subtree(&self, root: usize, depth: u32) -> (Vec<CwBvhNode>, Vec<u32>) {
        let mut nodes = vec![CwBvhNode::default()];
        let mut prims = Vec::new();
        if depth >= PARALLEL_CONVERT_DEPTH {
            self.convert_node(&mut nodes, &mut prims, 0, root);
            return (nodes, prims);
        }
        // The root's own node (children and leaf primitives), then its inner children's
        // subtrees, built in parallel and appended in slot order: obvhs's recursion emits
        // exactly that sequence.
        let (inner, count) = self.emit_node(&mut nodes, &mut prims, 0, root);
        let parts: Vec<(Vec<CwBvhNode>, Vec<u32>)> = inner[..count]
            .par_iter()
            .map(|&child| self.subtree(child as usize, depth + 1))
            .collect();
        let base = nodes[0].child_base_idx as usize;
        splice_subtrees(&mut nodes, &mut prims, base, parts);
        (nodes, prims)
    }

    /// obvhs's `convert_to_cwbvh_impl`: emits node `wide` (already allocated) for binary node
    /// `bvh2_node`, then its inner children's subtrees depth first.
    fn convert_node(
        &self,
        nodes: &mut Vec<CwBvhNode>,
        prims: &mut Vec<u32>,
        wide: usize,
        bvh2_node: usize,
    ) {
        let (inner, count) = self.emit_node(nodes, prims, wide, bvh2_node);
        let base = nodes[wide].child_base_idx as usize;
        for (rank, &child) in inner[..count].iter().enumerate() {
            self.convert_node(nodes, prims, base + rank, child as usize);
        }
    }

    /// Fills node `wide` for binary node `bvh2_node`: gathers its up to 8 children, orders them
    /// by direction, appends its leaves' primitives and allocates its inner children (zeroed,
    /// after the current end). Returns the inner children's binary nodes in slot order (the
    /// first `count` entries).
    fn emit_node(
        &self,
        nodes: &mut Vec<CwBvhNode>,
        prims: &mut Vec<u32>,
        wide: usize,
        bvh2_node: usize,
    ) -> ([u32; 8], usize) {
        let mut children = [u32::MAX; 8];
        let mut count = 0;
        self.gather(bvh2_node, 0, &mut children, &mut count);
        self.order_children(bvh2_node, &mut children, count);
        let mut node = CwBvhNode {
            primitive_base_idx: prims.len() as u32,
            child_base_idx: nodes.len() as u32,
            ..CwBvhNode::default()
        };
        let (mut inner, mut inner_count) = ([u32::MAX; 8], 0);
        let mut leaf_prims = 0u32;
        for (slot, &child) in children.iter().enumerate() {
            if child == u32::MAX {
                continue;
            }
            match self.choice(child as usize, 0).kind {
                Kind::Leaf => {
                    let count = self.push_primitives(child as usize, prims);
                    debug_assert!(count > 0 && count <= MAX_LEAF);
                    node.child_meta[slot] = leaf_prims as u8 | ((1u8 << count) - 1) << 5;
                    leaf_prims += count;
                }
                _ => {
                    node.imask |= 1 << slot;
                    node.child_meta[slot] = (24 + slot as u8) | 0b0010_0000;
                    inner[inner_count] = child;
                    inner_count += 1;
                }
            }
        }
        nodes.resize(nodes.len() + inner_count, CwBvhNode::default());
        nodes[wide] = node;
        (inner, inner_count)
    }

    /// obvhs's `get_children`: the subtrees that column `i` of `node` distributes to.
    fn gather(&self, node: usize, i: usize, children: &mut [u32; 8], count: &mut usize) {
        let n = &self.bvh2.nodes[node];
        if n.is_leaf() {
            children[*count] = node as u32;
            *count += 1;
            return;
        }
        let choice = self.choice(node, i);
        for (child, column) in [
            (n.first_index as usize, choice.left as usize),
            (n.first_index as usize + 1, choice.right as usize),
        ] {
            if self.choice(child, column).kind == Kind::Distribute {
                self.gather(child, column, children, count);
            } else {
                children[*count] = child as u32;
                *count += 1;
            }
        }
    }

    /// obvhs's `order_children` ([`octant_slots`] of the children's box centres).
    fn order_children(&self, node: usize, children: &mut [u32; 8], count: usize) {
        let p = self.bvh2.nodes[node].aabb().center();
        let centres: [Vec3A; 8] = std::array::from_fn(|c| {
            children[..count].get(c).map_or(Vec3A::ZERO, |&i| {
                self.bvh2.nodes[i as usize].aabb().center()
            })
        });
        let slots = octant_slots(p, &centres[..count]);
        let original = std::mem::replace(children, [u32::MAX; 8]);
        for c in 0..count {
            children[slots[c]] = original[c];
        }
    }

    /// obvhs's `count_primitives`: appends the primitives of `node`'s subtree, left first.
    fn push_primitives(&self, node: usize, prims: &mut Vec<u32>) -> u32 {
        let n = &self.bvh2.nodes[node];
        if n.is_leaf() {
            debug_assert_eq!(n.prim_count, 1);
            prims.push(self.bvh2.primitive_indices[n.first_index as usize]);
            return 1;
        }
        self.push_primitives(n.first_index as usize, prims)
            + self.push_primitives(n.first_index as usize + 1, prims)
    }
}

/// obvhs's `order_children`: the slot of each of up to 8 children, assigned greedily by the
/// direction of their box centres from the node's centre `p` (slot bits: negative x, y, z),
/// so that traversal can visit them nearest first by the ray's octant.
pub(crate) fn octant_slots(p: Vec3A, centres: &[Vec3A]) -> [usize; 8] {
    let count = centres.len();
    debug_assert!(count <= 8);
    let mut cost = [[f32::MAX; 8]; 8];
    for s in 0..8 {
        let d = Vec3A::new(
            if s & 0b100 != 0 { -1.0 } else { 1.0 },
            if s & 0b010 != 0 { -1.0 } else { 1.0 },
            if s & 0b001 != 0 { -1.0 } else { 1.0 },
        );
        for c in 0..count {
            cost[c][s] = d.dot(centres[c] - p);
        }
    }
    let mut assignment = [usize::MAX; 8];
    let mut slot_filled = [false; 8];
    loop {
        let (mut min_cost, mut min_slot, mut min_index) = (f32::MAX, usize::MAX, usize::MAX);
        for c in 0..count {
            if assignment[c] == usize::MAX {
                for s in 0..8 {
                    if !slot_filled[s] && cost[c][s] < min_cost {
                        (min_cost, min_slot, min_index) = (cost[c][s], s, c);
                    }
                }
            }
        }
        if min_slot == usize::MAX {
            break;
        }
        slot_filled[min_slot] = true;
        assignment[min_index] = min_slot;
    }
    for a in assignment.iter_mut().take(count) {
        // A child no slot was cheaper than f32::MAX for (NaN centres) takes a free slot.
        if *a == usize::MAX {
            let s = slot_filled.iter().position(|f| !f).expect("a free slot");
            slot_filled[s] = true;
            *a = s;
        }
    }
    assignment
}

/// Appends 8-wide subtrees (each with its root at index 0 and indices relative to its own
/// arrays) to `nodes` and `prims`, as obvhs's depth-first recursion would have written them:
/// subtree `rank`'s root goes to the already allocated `nodes[base + rank]`, its other nodes
/// and its primitives after the current ends.
pub(crate) fn splice_subtrees(
    nodes: &mut Vec<CwBvhNode>,
    prims: &mut Vec<u32>,
    base: usize,
    parts: Vec<(Vec<CwBvhNode>, Vec<u32>)>,
) {
    for (rank, (sub, sub_prims)) in parts.into_iter().enumerate() {
        // Local index j >= 1 of `sub` lands at `node_offset + j - 1`; its root at its slot.
        let node_offset = nodes.len() as u32;
        let prim_offset = prims.len() as u32;
        let shift = |mut n: CwBvhNode| {
            n.child_base_idx = n.child_base_idx + node_offset - 1;
            n.primitive_base_idx += prim_offset;
            n
        };
        let mut sub = sub.into_iter();
        nodes[base + rank] = shift(sub.next().expect("subtree root"));
        nodes.extend(sub.map(shift));
        prims.extend_from_slice(&sub_prims);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;
    use obvhs::aabb::Aabb;
    use obvhs::cwbvh::bvh2_to_cwbvh::{bvh2_to_cwbvh, Bvh2Converter};
    use obvhs::ploc::PlocBuilder;
    use obvhs::BvhBuildParams;

    fn random_boxes(n: usize, rng: &mut Rng) -> Vec<Aabb> {
        (0..n)
            .map(|_| {
                let c = Vec3A::new(rng.uniform(), rng.uniform(), rng.uniform()) * 10.0;
                let e = Vec3A::new(rng.uniform(), rng.uniform(), rng.uniform()) * 0.4;
                Aabb::new(c - e, c + e)
            })
            .collect()
    }

    fn ploc(aabbs: &[Aabb]) -> Bvh2 {
        let p = BvhBuildParams::medium_build();
        let mut bvh2 = PlocBuilder::with_capacity(aabbs.len()).build(
            p.ploc_search_distance,
            aabbs,
            (0..aabbs.len() as u32).collect(),
            p.sort_precision,
            p.search_depth_threshold,
        );
        obvhs::bvh2::reinsertion::ReinsertionOptimizer::default().run(&mut bvh2, 0.05, None);
        bvh2
    }

    /// The same 8-wide tree as obvhs's conversion (topology, leaves, child order, node and
    /// primitive order) and the same cost, on PLOC trees (reinserted, nodes in no particular
    /// order) and SAH trees (depth-first order), small to large enough for the parallel parts,
    /// and on degenerate input (identical boxes; nested ones).
    #[test]
    fn same_tree_as_obvhs() {
        let mut rng = Rng::new(30, 3);
        let same = vec![Aabb::new(Vec3A::ZERO, Vec3A::ONE); 3000];
        let nested: Vec<Aabb> = (0..3000)
            .map(|i| {
                let s = 1.0e-3 * 1.01f32.powi(i);
                Aabb::new(Vec3A::splat(-s), Vec3A::splat(s))
            })
            .collect();
        let mut inputs = vec![same, nested];
        for n in [1usize, 2, 3, 4, 9, 100, 5000, 60_000] {
            inputs.push(random_boxes(n, &mut rng));
        }
        for aabbs in &inputs {
            for bvh2 in [ploc(aabbs), super::super::sah::build_sah_bvh2(aabbs)] {
                let table = CostTable::new(&bvh2);
                let mine = table.convert();
                let theirs = bvh2_to_cwbvh(&bvh2, 3, true, false);
                let mut converter = Bvh2Converter::new(&bvh2, false, false);
                converter.calculate_cost(3);
                assert_eq!(table.root_cost(), converter.decisions[0].cost);
                assert_eq!(mine.primitive_indices, theirs.primitive_indices);
                assert_eq!(mine.nodes.len(), theirs.nodes.len());
                for (a, b) in mine.nodes.iter().zip(&theirs.nodes) {
                    assert_eq!(
                        (
                            a.imask,
                            a.child_base_idx,
                            a.primitive_base_idx,
                            a.child_meta
                        ),
                        (
                            b.imask,
                            b.child_base_idx,
                            b.primitive_base_idx,
                            b.child_meta
                        ),
                        "n = {}",
                        aabbs.len()
                    );
                }
            }
        }
    }
}
