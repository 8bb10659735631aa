//! Top-down surface-area-heuristic (SAH) build of a binary BVH with one triangle per leaf, in
//! obvhs's `Bvh2` layout, for obvhs's BVH2 -> CWBVH conversion (which picks the leaf sizes).
//!
//! Why: obvhs builds with PLOC, which merges clusters that are close in Morton order. In closed
//! rooms (walls, floor, ceiling: the Cornell box, architecture) that merges pieces of different
//! walls into boxes spanning the room, and a ray inside the room enters most of them: 45 nodes
//! per camera ray on a 3,072-triangle room (BENCHMARKS.md). A top-down SAH split separates the
//! walls first. Splits are binned (32 bins per axis) for large nodes and an exact sweep over
//! sorted centroids for small ones; large subtrees are built in parallel.

use glam::Vec3A;
use obvhs::aabb::Aabb;
use obvhs::bvh2::node::Bvh2Node;
use obvhs::bvh2::Bvh2;
use rayon::prelude::*;

/// Bins per axis in binned splits (this builder's and `binned.rs`'s).
pub(super) const BINS: usize = 32;
/// Nodes with at most this many triangles get the exact sweep instead of bins.
const SWEEP_MAX: usize = 32;
/// Subtrees with more triangles than this are built on two rayon tasks.
const PARALLEL_MIN: usize = 4096;
/// Nodes with at least this many triangles bin them on several rayon tasks, in chunks of
/// [`BIN_CHUNK`] (the top levels of the tree, where the subtrees are still too few to keep the
/// threads busy).
const PARALLEL_BIN_MIN: usize = 1 << 15;
pub(super) const BIN_CHUNK: usize = 1 << 13;
/// Beyond this depth, split at the median: keeps the BVH shallow enough for obvhs's 32-entry
/// traversal stack (which silently overwrites its last entry when full) on nearly any input,
/// e.g. SAH peeling one small triangle at a time off a huge one. `Bvh::build_with` checks the
/// final depth and falls back to median splits throughout ([`build_bvh2`] with 0).
const SAH_MAX_DEPTH: u32 = 40;

/// A triangle's bounds and its index in the input.
#[derive(Clone, Copy)]
struct PrimRef {
    aabb: Aabb,
    index: u32,
}

impl PrimRef {
    #[inline]
    fn centroid(&self) -> Vec3A {
        (self.aabb.min + self.aabb.max) * 0.5
    }
}

/// Surface area / 2 of a box, 0 for an empty one.
#[inline]
pub(super) fn half_area(b: &Aabb) -> f32 {
    let d = (b.max - b.min).max(Vec3A::ZERO);
    (d.x + d.y) * d.z + d.x * d.y
}

/// Builds the BVH2 over the given bounds (one per triangle, in input order).
pub fn build_sah_bvh2(aabbs: &[Aabb]) -> Bvh2 {
    build_bvh2(aabbs, SAH_MAX_DEPTH)
}

/// As [`build_sah_bvh2`], with SAH splits down to depth `sah_max_depth` and median splits
/// below (0: median splits throughout, a balanced tree of depth ceil(log2 n)).
pub fn build_bvh2(aabbs: &[Aabb], sah_max_depth: u32) -> Bvh2 {
    let n = aabbs.len();
    let mut bvh = Bvh2::default();
    if n == 0 {
        return bvh;
    }
    let mut prims: Vec<PrimRef> = aabbs
        .iter()
        .enumerate()
        .map(|(i, &aabb)| PrimRef {
            aabb,
            index: i as u32,
        })
        .collect();
    let (bounds, centroids) = prims
        .par_chunks(BIN_CHUNK)
        .map(|c| (union_of(c), centroid_bounds(c)))
        .reduce(
            || (Aabb::empty(), Aabb::empty()),
            |a, b| (a.0.union(&b.0), a.1.union(&b.1)),
        );
    // A subtree over m triangles has exactly 2m - 1 nodes, so every subtree's block of the
    // node array is known before it is built, and subtrees fill disjoint blocks in parallel.
    let mut nodes = vec![Bvh2Node::default(); 2 * n - 1];
    let (root, descendants) = nodes.split_at_mut(1);
    let depth = build_node(
        &mut prims,
        0,
        [bounds, centroids],
        &mut root[0],
        descendants,
        1,
        (0, sah_max_depth),
    );
    bvh.primitive_indices = prims.iter().map(|p| p.index).collect();
    bvh.nodes = nodes;
    bvh.children_are_ordered_after_parents = true;
    bvh.max_depth = bvh.max_depth.max(depth as usize + 1);
    bvh
}

/// Builds the subtree over `prims` (whose first element is leaf slot `prim_offset`) into
/// `node`, its descendants into `desc` (global index `desc_offset` onwards, 2m - 2 nodes).
/// `bounds` are the union of the prims' boxes and the bounds of their centroids.
/// Returns the subtree's depth below `node`.
fn build_node(
    prims: &mut [PrimRef],
    prim_offset: u32,
    [bounds, centroids]: [Aabb; 2],
    node: &mut Bvh2Node,
    desc: &mut [Bvh2Node],
    desc_offset: u32,
    (depth, sah_max_depth): (u32, u32),
) -> u32 {
    let m = prims.len();
    if m == 1 {
        *node = Bvh2Node::new(bounds, 1, prim_offset);
        return 0;
    }
    let binned = if depth < sah_max_depth && m > SWEEP_MAX {
        binned_split(prims, centroids)
    } else {
        None
    };
    let (split, left_bounds, right_bounds) = match binned {
        Some(split) => split,
        None => {
            let split = if depth >= sah_max_depth || m > SWEEP_MAX {
                median_split(prims)
            } else {
                sweep_split(prims)
            };
            let (l, r) = prims.split_at(split);
            (split, bounds_of(l), bounds_of(r))
        }
    };
    debug_assert!(split > 0 && split < m);
    *node = Bvh2Node::new(bounds, 0, desc_offset);
    let (left_prims, right_prims) = prims.split_at_mut(split);
    let (children, rest) = desc.split_at_mut(2);
    let (left_node, right_node) = children.split_at_mut(1);
    let (left_desc, right_desc) = rest.split_at_mut(2 * split - 2);
    let left_desc_offset = desc_offset + 2;
    let right_desc_offset = desc_offset + 2 * split as u32;
    let right_prim_offset = prim_offset + split as u32;
    let mut build_left = || {
        build_node(
            left_prims,
            prim_offset,
            left_bounds,
            &mut left_node[0],
            left_desc,
            left_desc_offset,
            (depth + 1, sah_max_depth),
        )
    };
    let mut build_right = || {
        build_node(
            right_prims,
            right_prim_offset,
            right_bounds,
            &mut right_node[0],
            right_desc,
            right_desc_offset,
            (depth + 1, sah_max_depth),
        )
    };
    let (dl, dr) = if m > PARALLEL_MIN {
        rayon::join(build_left, build_right)
    } else {
        (build_left(), build_right())
    };
    1 + dl.max(dr)
}

/// Box and centroid bounds of `prims` (a child's input to [`build_node`]); the centroid
/// bounds are only computed where a binned split may use them.
fn bounds_of(prims: &[PrimRef]) -> [Aabb; 2] {
    let centroids = if prims.len() > SWEEP_MAX {
        centroid_bounds(prims)
    } else {
        Aabb::empty()
    };
    [union_of(prims), centroids]
}

fn union_of(prims: &[PrimRef]) -> Aabb {
    prims.iter().fold(Aabb::empty(), |b, p| b.union(&p.aabb))
}

fn centroid_bounds(prims: &[PrimRef]) -> Aabb {
    let mut b = Aabb::empty();
    for p in prims {
        b.extend(p.centroid());
    }
    b
}

/// Splits at the median of the centroids' widest axis; returns the size of the left part.
fn median_split(prims: &mut [PrimRef]) -> usize {
    let axis = centroid_bounds(prims).largest_axis();
    let mid = prims.len() / 2;
    prims.select_nth_unstable_by(mid, |a, b| {
        a.centroid()[axis].total_cmp(&b.centroid()[axis])
    });
    mid
}

/// Exact SAH: every split between centroids sorted along each axis (ties in input order).
/// Reorders `prims` so the split is `prims[..k]`, `prims[k..]`, and returns k. At most
/// [`SWEEP_MAX`] prims: the sorts run on small arrays of keys, not on the prims.
fn sweep_split(prims: &mut [PrimRef]) -> usize {
    let m = prims.len();
    debug_assert!(m <= SWEEP_MAX);
    let mut best = (f32::INFINITY, 0usize); // (cost, k)
    let mut best_order = [0u8; SWEEP_MAX];
    let mut right_area = [0.0f32; SWEEP_MAX];
    let mut keys = [(0.0f32, 0u8); SWEEP_MAX];
    for axis in 0..3 {
        for (i, p) in prims.iter().enumerate() {
            keys[i] = (p.centroid()[axis], i as u8);
        }
        let keys = &mut keys[..m];
        keys.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut acc = Aabb::empty();
        for k in (1..m).rev() {
            acc = acc.union(&prims[keys[k].1 as usize].aabb);
            right_area[k] = half_area(&acc);
        }
        let mut acc = Aabb::empty();
        let mut improved = false;
        for k in 1..m {
            acc = acc.union(&prims[keys[k - 1].1 as usize].aabb);
            let cost = half_area(&acc) * k as f32 + right_area[k] * (m - k) as f32;
            if cost < best.0 {
                best = (cost, k);
                improved = true;
            }
        }
        if improved {
            for (o, key) in best_order.iter_mut().zip(keys.iter()) {
                *o = key.1;
            }
        }
    }
    let (_, k) = best;
    if k == 0 {
        // Every cost was NaN (non-finite bounds): any balanced split will do.
        return m / 2;
    }
    let original: [PrimRef; SWEEP_MAX] = std::array::from_fn(|i| prims[i.min(m - 1)]);
    for (p, &o) in prims.iter_mut().zip(best_order.iter()) {
        *p = original[o as usize];
    }
    k
}

/// Per-axis bins of a binned split (this builder's and `binned.rs`'s): the union of the boxes
/// and the number of the prims whose centroid falls in each.
#[derive(Clone, Copy)]
pub(super) struct Bins {
    bounds: [[Aabb; BINS]; 3],
    count: [[u32; BINS]; 3],
}

impl Bins {
    fn empty() -> Bins {
        Bins {
            bounds: [[Aabb::empty(); BINS]; 3],
            count: [[0; BINS]; 3],
        }
    }

    /// Adds a box whose centroid falls in bin `bins[axis]` on each axis.
    #[inline(always)]
    pub(super) fn add_box(&mut self, bins: [usize; 3], lo: Vec3A, hi: Vec3A) {
        for (axis, &b) in bins.iter().enumerate() {
            let bin = &mut self.bounds[axis][b];
            bin.min = bin.min.min(lo);
            bin.max = bin.max.max(hi);
            self.count[axis][b] += 1;
        }
    }

    /// Both sets of bins together (box unions and counts are exact, so the order of merging
    /// does not change the result: the parallel binning gives the serial one's tree).
    fn merge(mut self, other: &Bins) -> Bins {
        for axis in 0..3 {
            for b in 0..BINS {
                self.bounds[axis][b] = self.bounds[axis][b].union(&other.bounds[axis][b]);
                self.count[axis][b] += other.count[axis][b];
            }
        }
        self
    }

    /// The bins of `prims`, `add` binning a chunk of them: all three axes in one pass, on
    /// several rayon tasks for large sets (the top levels of a tree, where the subtrees are
    /// still too few to keep the threads busy).
    pub(super) fn of<P: Sync>(prims: &[P], add: impl Fn(&mut Bins, &[P]) + Sync + Send) -> Bins {
        if prims.len() >= PARALLEL_BIN_MIN {
            prims
                .par_chunks(BIN_CHUNK)
                .fold(Bins::empty, |mut bins, chunk| {
                    add(&mut bins, chunk);
                    bins
                })
                .reduce(Bins::empty, |a, b| a.merge(&b))
        } else {
            let mut bins = Bins::empty();
            add(&mut bins, prims);
            bins
        }
    }

    /// The best of the 3 x (BINS - 1) bin boundaries by SAH (Wald 2007): (axis, boundary), the
    /// left side the bins below `boundary`; None when no boundary separates the centroids (all
    /// coincide, or the bounds are not finite). `extent` is the centroids' extent.
    pub(super) fn best_split(&self, extent: Vec3A) -> Option<(usize, usize)> {
        let mut best = (f32::INFINITY, 0usize, 0usize); // (cost, axis, boundary)
        for axis in 0..3 {
            if !(extent[axis] > 0.0) {
                continue;
            }
            let (bin_bounds, bin_count) = (&self.bounds[axis], &self.count[axis]);
            let mut right_area = [0.0f32; BINS];
            let mut right_count = [0usize; BINS];
            let (mut acc, mut count) = (Aabb::empty(), 0);
            for b in (1..BINS).rev() {
                acc = acc.union(&bin_bounds[b]);
                count += bin_count[b] as usize;
                right_area[b] = half_area(&acc);
                right_count[b] = count;
            }
            let (mut acc, mut count) = (Aabb::empty(), 0);
            for b in 1..BINS {
                acc = acc.union(&bin_bounds[b - 1]);
                count += bin_count[b - 1] as usize;
                if count == 0 || right_count[b] == 0 {
                    continue;
                }
                let cost = half_area(&acc) * count as f32 + right_area[b] * right_count[b] as f32;
                if cost < best.0 {
                    best = (cost, axis, b);
                }
            }
        }
        let (_, axis, boundary) = best;
        (boundary > 0).then_some((axis, boundary))
    }
}

/// Bins per unit of centroid extent on each axis (0 on an axis of zero extent, whose centroids
/// all fall in bin 0).
pub(super) fn bin_scale(extent: Vec3A) -> Vec3A {
    Vec3A::select(
        extent.cmpgt(Vec3A::ZERO),
        Vec3A::splat(BINS as f32) / extent,
        Vec3A::ZERO,
    )
}

/// Binned SAH (Wald 2007): centroids binned along each axis ([`Bins::of`]), the best of the
/// 3 x (BINS - 1) bin boundaries ([`Bins::best_split`]); `prims` is partitioned in place.
/// Returns the left size and the two sides' box and centroid bounds (gathered while
/// partitioning), or None when no boundary separates the centroids.
fn binned_split(prims: &mut [PrimRef], centroids: Aabb) -> Option<(usize, [Aabb; 2], [Aabb; 2])> {
    let m = prims.len();
    let extent = centroids.max - centroids.min;
    let scale = bin_scale(extent);
    let bins = Bins::of(prims, |bins, chunk| {
        for p in chunk {
            let c = p.centroid();
            let b = [0, 1, 2].map(|axis| bin_of(c[axis], centroids.min[axis], scale[axis]));
            bins.add_box(b, p.aabb.min, p.aabb.max);
        }
    });
    let (axis, boundary) = bins.best_split(extent)?;
    let (min, scale) = (centroids.min[axis], scale[axis]);
    let mut left = 0;
    let mut sides = [[Aabb::empty(); 2]; 2]; // [left, right] x [boxes, centroids]
    for i in 0..m {
        let p = prims[i];
        let c = p.centroid();
        let side = (bin_of(c[axis], min, scale) >= boundary) as usize;
        sides[side][0] = sides[side][0].union(&p.aabb);
        sides[side][1].extend(c);
        if side == 0 {
            prims.swap(i, left);
            left += 1;
        }
    }
    Some((left, sides[0], sides[1]))
}

#[inline]
fn bin_of(c: f32, min: f32, scale: f32) -> usize {
    (((c - min) * scale) as usize).min(BINS - 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    fn check_tree(bvh: &Bvh2, n: usize) {
        assert_eq!(bvh.nodes.len(), 2 * n - 1);
        let mut seen = vec![false; n];
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            let node = &bvh.nodes[i];
            if node.is_leaf() {
                assert_eq!(node.prim_count, 1);
                let p = bvh.primitive_indices[node.first_index as usize] as usize;
                assert!(!seen[p], "triangle {p} in two leaves");
                seen[p] = true;
            } else {
                let (l, r) = (node.first_index as usize, node.first_index as usize + 1);
                assert!(l > i, "children after parents");
                for c in [l, r] {
                    let cb = bvh.nodes[c].aabb();
                    assert!(
                        node.aabb().min.cmple(cb.min).all() && cb.max.cmple(node.aabb().max).all()
                    );
                }
                stack.push(l);
                stack.push(r);
            }
        }
        assert!(seen.iter().all(|&s| s), "every triangle in a leaf");
    }

    fn tree_depth(bvh: &Bvh2, i: usize) -> usize {
        let node = &bvh.nodes[i];
        if node.is_leaf() {
            0
        } else {
            let c = node.first_index as usize;
            1 + tree_depth(bvh, c).max(tree_depth(bvh, c + 1))
        }
    }

    #[test]
    fn every_triangle_in_exactly_one_leaf_and_boxes_nest() {
        let mut rng = Rng::new(4, 4);
        for n in [1usize, 2, 3, 31, 32, 33, 100, 5000, 20_000] {
            let aabbs: Vec<Aabb> = (0..n)
                .map(|_| {
                    let c = Vec3A::new(rng.uniform(), rng.uniform(), rng.uniform()) * 10.0;
                    let e = Vec3A::new(rng.uniform(), rng.uniform(), rng.uniform()) * 0.5;
                    Aabb::new(c - e, c + e)
                })
                .collect();
            check_tree(&build_sah_bvh2(&aabbs), n);
        }
    }

    /// Identical boxes (no plane separates their centroids) and a geometric series of sizes
    /// (SAH peels one at a time): still a valid tree, and depth stays bounded.
    #[test]
    fn degenerate_inputs_stay_shallow() {
        let same = vec![Aabb::new(Vec3A::ZERO, Vec3A::ONE); 10_000];
        let bvh = build_sah_bvh2(&same);
        check_tree(&bvh, same.len());
        let nested: Vec<Aabb> = (0..3000)
            .map(|i| {
                let s = 1.0e-3 * 1.01f32.powi(i);
                Aabb::new(Vec3A::splat(-s), Vec3A::splat(s))
            })
            .collect();
        let bvh = build_sah_bvh2(&nested);
        check_tree(&bvh, nested.len());
        let depth = tree_depth(&bvh, 0);
        assert!(depth <= SAH_MAX_DEPTH as usize + 13, "depth {depth}");
        // Median splits throughout (the fallback of `Bvh::build_with` for trees too deep for
        // the traversal stack): balanced, whatever the input.
        for input in [&same, &nested] {
            let bvh = build_bvh2(input, 0);
            check_tree(&bvh, input.len());
            let balanced = (input.len() as f64).log2().ceil() as usize;
            assert_eq!(tree_depth(&bvh, 0), balanced);
        }
    }
}
