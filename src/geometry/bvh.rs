//! 8-wide BVH over triangles: built with obvhs (PLOC or a top-down SAH build, then obvhs's
//! BVH2 -> CWBVH conversion, which chooses the 8-wide topology, the leaves and the child order;
//! `convert.rs`), or for [`BvhQuality::Fast`] directly by binned SAH (`binned.rs`),
//! but stored and traversed as Lacuna's own uncompressed nodes ([`WideNode`]: the children's
//! exact f32 boxes, one 256-bit load per plane) instead of obvhs's 8-bit quantised ones (why:
//! see [`WideNode`]). The triangles are copied into BVH leaf order (in SIMD blocks of four,
//! [`TriangleBlock`]) so traversal touches memory sequentially, and Lacuna's own watertight
//! triangle test runs four triangles at a time inside the traversal loop.

use std::cell::Cell;

use glam::{UVec2, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::bvh2::reinsertion::ReinsertionOptimizer;
use obvhs::bvh2::Bvh2;
use obvhs::cwbvh::CwBvh;
use obvhs::ploc::PlocBuilder;
use obvhs::splits::split_aabbs_preset;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;
use rayon::prelude::*;

use super::convert::CostTable;
use super::triangle::{
    intersect_triangle_block, intersect_triangle_block_into, BlockHits, RayLanes, TriangleBlock,
};
use super::{Hit, Ray, RayPrecomp};
use crate::math::Vec3;

/// Build quality: a trade between build time and traversal speed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BvhQuality {
    /// Shortest build (interactive edits): the 8-wide tree built directly by binned SAH
    /// ([`BuildMethod::Binned`]).
    Fast,
    /// The default: obvhs's PLOC ("medium" parameters), and up to 2^18 triangles also a
    /// top-down SAH build, keeping the cheaper tree (see [`BvhQuality::method`]).
    #[default]
    Medium,
    /// PLOC with spatial pre-splits and more reinsertion, and the SAH build, keeping the
    /// cheaper tree: best traversal, slowest build.
    High,
}

impl BvhQuality {
    fn ploc_params(self) -> BvhBuildParams {
        match self {
            BvhQuality::Fast => BvhBuildParams::fast_build(),
            BvhQuality::Medium => BvhBuildParams::medium_build(),
            BvhQuality::High => BvhBuildParams::slow_build(),
        }
    }

    /// The builder behind each quality for `n` triangles (measured with `benches/bvh.rs
    /// methods`, BENCHMARKS.md): neither builder wins everywhere. PLOC clusters across the walls
    /// of closed rooms (7x the node visits of a top-down SAH build on a 3,072-triangle room),
    /// while on Sponza PLOC with reinsertion visits 25-35 % fewer nodes than the SAH build.
    /// Medium builds both up to 2^18 triangles (the SAH build then costs at most a few tens of
    /// milliseconds) and High always, keeping the cheaper tree.
    pub fn method(self, n: usize) -> BuildMethod {
        match self {
            BvhQuality::Fast => BuildMethod::Binned,
            BvhQuality::Medium if n <= 1 << 18 => BuildMethod::Cheaper(BvhQuality::Medium, 0.0),
            BvhQuality::Medium => BuildMethod::Ploc(BvhQuality::Medium),
            BvhQuality::High => BuildMethod::Cheaper(BvhQuality::High, 0.05),
        }
    }
}

/// How the binary BVH that obvhs converts to the 8-wide layout is built. Public for
/// `benches/bvh.rs`, which compares them; use [`BvhQuality`] otherwise.
#[doc(hidden)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BuildMethod {
    /// obvhs's PLOC with the parameters of a quality (High adds spatial pre-splits).
    Ploc(BvhQuality),
    /// Top-down SAH (`sah.rs`), then obvhs's reinsertion optimizer over this fraction of the
    /// nodes (0 = none).
    Sah { reinsertion: f32 },
    /// Both of the above; keeps the tree whose 8-wide form has the lower SAH cost (the cost
    /// model of obvhs's BVH2 -> CWBVH conversion, Ylitie et al. 2017).
    Cheaper(BvhQuality, f32),
    /// The 8-wide tree built directly by binned SAH (`binned.rs`): no binary tree.
    Binned,
}

/// obvhs's `build_cwbvh_from_tris` up to the binary BVH: PLOC over the triangles (or over
/// pre-split boxes when the parameters ask for it), then reinsertion.
fn ploc_bvh2(tris: &[Triangle], params: BvhBuildParams, profile: &BuildProfile) -> Bvh2 {
    let mut bvh2 = profile.time("PLOC", || {
        if params.pre_split {
            let mut aabbs: Vec<Aabb> = tris.iter().map(|t| t.aabb()).collect();
            let largest = aabbs.iter().map(Aabb::half_area).fold(0.0f32, f32::max);
            let average = aabbs.iter().map(Aabb::half_area).sum::<f32>() / aabbs.len() as f32;
            let mut indices: Vec<u32> = (0..tris.len() as u32).collect();
            split_aabbs_preset(&mut aabbs, &mut indices, tris, average, largest);
            PlocBuilder::with_capacity(aabbs.len()).build(
                params.ploc_search_distance,
                &aabbs,
                indices,
                params.sort_precision,
                params.search_depth_threshold,
            )
        } else {
            PlocBuilder::with_capacity(tris.len()).build(
                params.ploc_search_distance,
                tris,
                (0..tris.len() as u32).collect(),
                params.sort_precision,
                params.search_depth_threshold,
            )
        }
    });
    bvh2.uses_spatial_splits = params.pre_split;
    profile.time("PLOC reinsertion", || {
        ReinsertionOptimizer::default().run(&mut bvh2, params.reinsertion_batch_ratio, None)
    });
    bvh2
}

fn sah_bvh2(tris: &[Triangle], reinsertion: f32, profile: &BuildProfile) -> Bvh2 {
    let mut bvh2 = profile.time("SAH build", || {
        let aabbs: Vec<Aabb> = tris.par_iter().map(|t| t.aabb()).collect();
        super::sah::build_sah_bvh2(&aabbs)
    });
    if reinsertion > 0.0 {
        profile.time("SAH reinsertion", || {
            ReinsertionOptimizer::default().run(&mut bvh2, reinsertion, None)
        });
    }
    bvh2
}

/// Wall time of each stage of a build and the 8-wide SAH cost of the tree it kept
/// (`benches/bvh.rs stages`). Stages that run at the same time (the two trees of
/// [`BuildMethod::Cheaper`]) overlap.
#[doc(hidden)]
#[derive(Default)]
pub struct BuildProfile {
    enabled: bool,
    stages: std::sync::Mutex<Vec<(&'static str, f64)>>,
    cost: std::sync::Mutex<Option<f32>>,
    both_costs: std::sync::Mutex<Option<(f32, f32)>>,
}

impl BuildProfile {
    /// A profile that records (the default one records nothing and costs nothing).
    pub fn recording() -> BuildProfile {
        BuildProfile {
            enabled: true,
            ..BuildProfile::default()
        }
    }

    fn time<R>(&self, stage: &'static str, f: impl FnOnce() -> R) -> R {
        if !self.enabled {
            return f();
        }
        let start = std::time::Instant::now();
        let r = f();
        let seconds = start.elapsed().as_secs_f64();
        self.stages.lock().expect("profile").push((stage, seconds));
        r
    }

    fn set_cost(&self, cost: f32) {
        *self.cost.lock().expect("profile") = Some(cost);
    }

    fn set_costs(&self, ploc: f32, sah: f32) {
        *self.both_costs.lock().expect("profile") = Some((ploc, sah));
    }

    /// The 8-wide SAH costs of PLOC's and the SAH build's trees, where both were built.
    pub fn both_costs(&self) -> Option<(f32, f32)> {
        *self.both_costs.lock().expect("profile")
    }

    /// (stage, seconds) in the order the stages ended.
    pub fn stages(&self) -> Vec<(&'static str, f64)> {
        self.stages.lock().expect("profile").clone()
    }

    /// SAH cost of the kept binary tree's 8-wide form (the conversion's cost model).
    pub fn cost(&self) -> Option<f32> {
        *self.cost.lock().expect("profile")
    }
}

/// The 8-wide tree, converted as obvhs's own builder does (`convert.rs`): leaves of up to 3
/// triangles chosen by the conversion's SAH cost, children ordered by direction.
fn to_cwbvh(bvh2: &Bvh2) -> CwBvh {
    CostTable::new(bvh2).convert()
}

/// A tree within [`MAX_TRAVERSAL_DEPTH`], for input on which the requested build came out too
/// deep: degenerate input such as a geometric series of positions, where PLOC merges one
/// triangle per step. The depth-bounded SAH build if it is shallow enough, else median splits
/// throughout: that binary tree is balanced, its deepest inner node at depth
/// ceil(log2 n) - 1 <= 31 for any u32 count, and an inner node of the 8-wide tree is an inner
/// node of the binary one strictly below its parent's, so the 8-wide tree is no deeper.
fn shallow_cwbvh(tris: &[Triangle]) -> CwBvh {
    let aabbs: Vec<Aabb> = tris.par_iter().map(|t| t.aabb()).collect();
    let sah = to_cwbvh(&super::sah::build_sah_bvh2(&aabbs));
    if cwbvh_inner_depth(&sah) <= MAX_TRAVERSAL_DEPTH {
        return sah;
    }
    let median = to_cwbvh(&super::sah::build_bvh2(&aabbs, 0));
    debug_assert!(cwbvh_inner_depth(&median) <= MAX_TRAVERSAL_DEPTH);
    median
}

/// Deepest inner node an 8-wide tree may have: obvhs's traversal stack holds 32 node groups
/// and silently overwrites its top entry when full, losing part of the tree. One entry is
/// kept spare, as obvhs's own `CwBvh::validate` asks (depth < 32).
pub(crate) const MAX_TRAVERSAL_DEPTH: usize = 31;

/// Depth of the deepest inner node (root 0). Inner children of a node are stored
/// contiguously from `child_base_idx`, one per bit of `imask`.
fn cwbvh_inner_depth(cwbvh: &CwBvh) -> usize {
    deepest_inner_node(cwbvh.nodes.len(), |i| {
        (cwbvh.nodes[i].child_base_idx, cwbvh.nodes[i].imask)
    })
}

/// Depth of the deepest inner node of an 8-wide tree of `len` nodes whose node `i` has the
/// inner children `base..base + imask.count_ones()`, `(base, imask) = children(i)`: one walk
/// for obvhs's nodes and for [`WideNode`]s, which keep the same two fields.
fn deepest_inner_node(len: usize, children: impl Fn(usize) -> (u32, u8)) -> usize {
    if len == 0 {
        return 0;
    }
    let mut deepest = 0;
    let mut stack = vec![(0usize, 0usize)];
    while let Some((i, depth)) = stack.pop() {
        deepest = deepest.max(depth);
        let (base, imask) = children(i);
        let first = base as usize;
        for c in first..first + imask.count_ones() as usize {
            stack.push((c, depth + 1));
        }
    }
    deepest
}

/// Lays out the leaf triangles of the 8-wide tree in [`TriangleBlock`]s of four, so that
/// traversal tests up to four of a node's triangles with one SIMD test. Every node's
/// triangles start a new block (its `primitive_base_idx` is rewritten to a multiple of 4),
/// and a leaf that would straddle two blocks is moved to the next one when the node's leaves
/// still fit the 24 triangle bits of the traversal mask (its `child_meta` offsets are
/// rewritten), so that a leaf of up to 3 triangles is one test. Slot `s` of the rewritten
/// tree is lane `s % 4` of block `s / 4`; the lanes carry the global triangle ids.
/// Nodes are laid out in parallel: each node's block count first, then every node fills its
/// own run of blocks.
fn triangle_blocks(cwbvh: &mut CwBvh, tris: &[Triangle]) -> Vec<TriangleBlock> {
    let layouts: Vec<LeafLayout> = cwbvh.nodes.par_iter().map(LeafLayout::new).collect();
    let total: usize = layouts.iter().map(|l| l.blocks as usize).sum();
    let mut blocks = vec![TriangleBlock::default(); total];
    // Each node's run of blocks, in node order.
    let mut runs: Vec<(usize, &mut [TriangleBlock])> = Vec::with_capacity(layouts.len());
    let (mut rest, mut first_block) = (&mut blocks[..], 0usize);
    for layout in &layouts {
        let (run, tail) = rest.split_at_mut(layout.blocks as usize);
        runs.push((first_block, run));
        first_block += layout.blocks as usize;
        rest = tail;
    }
    let ids = &cwbvh.primitive_indices;
    cwbvh
        .nodes
        .par_iter_mut()
        .zip(layouts.par_iter())
        .zip(runs.into_par_iter())
        .for_each(|((node, layout), (first_block, run))| {
            let old_base = node.primitive_base_idx;
            for i in 0..layout.count {
                let (child, offset, count) = layout.leaves[i];
                let new_offset = layout.offsets[i];
                for k in 0..count {
                    let slot = (new_offset + k) as usize;
                    let id = ids[(old_base + offset + k) as usize];
                    let t = &tris[id as usize];
                    run[slot / 4].set(slot % 4, [t.v0.into(), t.v1.into(), t.v2.into()], id);
                }
                node.child_meta[child] = (node.child_meta[child] & !0x1f) | new_offset as u8;
            }
            node.primitive_base_idx = (first_block * 4) as u32;
        });
    blocks
}

/// Where a node's leaf triangles go in [`triangle_blocks`]: its leaf children by their offset
/// (child slot, offset, count), each one's new offset, and the blocks they take.
struct LeafLayout {
    leaves: [(usize, u32, u32); 8],
    offsets: [u32; 8],
    count: usize,
    blocks: u32,
}

impl LeafLayout {
    fn new(node: &obvhs::cwbvh::node::CwBvhNode) -> LeafLayout {
        let mut leaves = [(0usize, 0u32, 0u32); 8];
        let mut count = 0;
        for c in 0..8 {
            let meta = node.child_meta[c];
            if node.imask & (1 << c) == 0 && meta != 0 {
                leaves[count] = (c, (meta & 0x1f) as u32, (meta >> 5).count_ones());
                count += 1;
            }
        }
        leaves[..count].sort_unstable_by_key(|&(_, offset, _)| offset);
        let mut aligned = [0u32; 8];
        let mut end = 0u32;
        for (i, &(_, _, n)) in leaves[..count].iter().enumerate() {
            let start = if end % 4 + n > 4 {
                end.next_multiple_of(4)
            } else {
                end
            };
            aligned[i] = start;
            end = start + n;
        }
        // Moving leaves to block starts may not push the node's triangles past the 24 bits of
        // the traversal mask; then they keep obvhs's offsets.
        let offsets = if end <= 24 {
            aligned
        } else {
            std::array::from_fn(|i| leaves[i].1)
        };
        let used = (0..count)
            .map(|i| offsets[i] + leaves[i].2)
            .max()
            .unwrap_or(0);
        LeafLayout {
            leaves,
            offsets,
            count,
            blocks: used.div_ceil(4),
        }
    }
}

/// The 8-wide tree of a method that builds binary trees: the binary tree(s), the 8-wide cost
/// table of each, and the conversion of the cheaper one.
fn via_binary(tris: &[Triangle], method: BuildMethod, profile: &BuildProfile) -> CwBvh {
    // (PLOC's tree, the other) where both are built, else (None, the one).
    let bvh2 = match method {
        BuildMethod::Ploc(quality) => (None, ploc_bvh2(tris, quality.ploc_params(), profile)),
        BuildMethod::Sah { reinsertion } => (None, sah_bvh2(tris, reinsertion, profile)),
        BuildMethod::Cheaper(quality, reinsertion) => {
            let (ploc, sah) = profile.time("both binary trees", || {
                rayon::join(
                    || ploc_bvh2(tris, quality.ploc_params(), profile),
                    || sah_bvh2(tris, reinsertion, profile),
                )
            });
            (Some(ploc), sah)
        }
        BuildMethod::Binned => unreachable!("the binned build makes no binary tree"),
    };
    // The 8-wide costs of both trees (in parallel), then the cheaper one's conversion.
    let (ploc_table, table) = profile.time("8-wide cost", || match &bvh2 {
        (Some(ploc), sah) => {
            let (p, s) = rayon::join(|| CostTable::new(ploc), || CostTable::new(sah));
            profile.set_costs(p.root_cost(), s.root_cost());
            (Some(p), s)
        }
        (None, bvh2) => (None, CostTable::new(bvh2)),
    });
    let table = match ploc_table {
        Some(p) if !(table.root_cost() < p.root_cost()) => p,
        _ => table,
    };
    profile.set_cost(table.root_cost());
    profile.time("cwbvh conversion", || table.convert())
}

/// The acceleration structure of a scene. Immutable and `Sync`: queries may run from any number
/// of threads.
pub struct Bvh {
    /// obvhs's 8-wide tree with its children's exact boxes ([`WideNode`]); the root is
    /// `nodes[0]`.
    nodes: Vec<WideNode>,
    /// Leaf slot `s` (`primitive_base_idx` plus a leaf's offset) is lane `s % 4` of
    /// `blocks[s / 4]` (see [`triangle_blocks`]).
    blocks: Vec<TriangleBlock>,
    /// Whether traversal prefetches the children it will visit: only when nodes and
    /// triangles do not fit in a core's L2 (on small scenes the prefetch loop is pure
    /// overhead, 2 % of a Cornell-box path tracer's instructions).
    prefetch: bool,
}

/// Size above which a BVH is prefetched during traversal (the L2 of this project's machines
/// is 2 MiB per core; half of it is left to the rest of the renderer).
const PREFETCH_MIN_BYTES: usize = 1 << 20;

impl Bvh {
    /// Builds the BVH over triangles given as vertex triples (global triangle order).
    pub fn build(triangles: &[[Vec3; 3]], quality: BvhQuality) -> Bvh {
        Bvh::build_with(triangles, quality.method(triangles.len()))
    }

    /// Builds with an explicit method (benchmarks).
    #[doc(hidden)]
    pub fn build_with(triangles: &[[Vec3; 3]], method: BuildMethod) -> Bvh {
        Bvh::build_profiled(triangles, method, &BuildProfile::default())
    }

    /// [`Bvh::build_with`], recording the wall time of each stage in `profile` (`benches/bvh.rs
    /// stages`).
    #[doc(hidden)]
    pub fn build_profiled(
        triangles: &[[Vec3; 3]],
        method: BuildMethod,
        profile: &BuildProfile,
    ) -> Bvh {
        if triangles.is_empty() {
            return Bvh {
                nodes: Vec::new(),
                blocks: Vec::new(),
                prefetch: false,
            };
        }
        let tris: Vec<Triangle> = profile.time("input", || {
            triangles
                .par_iter()
                .map(|t| Triangle {
                    v0: t[0].into(),
                    v1: t[1].into(),
                    v2: t[2].into(),
                })
                .collect()
        });
        let mut cwbvh = match method {
            BuildMethod::Binned => {
                let built = profile.time("binned 8-wide build", || super::binned::build(&tris));
                profile.set_cost(built.cost);
                built.cwbvh
            }
            _ => via_binary(&tris, method, profile),
        };
        let too_deep = profile.time("depth check", || {
            cwbvh_inner_depth(&cwbvh) > MAX_TRAVERSAL_DEPTH
        });
        if too_deep {
            cwbvh = profile.time("shallow fallback", || shallow_cwbvh(&tris));
        }
        let blocks = profile.time("triangle blocks", || triangle_blocks(&mut cwbvh, &tris));
        let nodes = profile.time("wide nodes", || wide_nodes(&cwbvh, &blocks));
        let mut bvh = Bvh {
            nodes,
            blocks,
            prefetch: false,
        };
        bvh.prefetch = bvh.memory_bytes() > PREFETCH_MIN_BYTES;
        bvh
    }

    pub fn is_empty(&self) -> bool {
        self.blocks.is_empty()
    }

    /// Bytes held by nodes and leaf data.
    pub fn memory_bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<WideNode>()
            + self.blocks.len() * std::mem::size_of::<TriangleBlock>()
    }

    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Closest hit in (0, ray.t_max).
    // Inlined into the caller so that a query is one call (the dispatch wrapper's own frame
    // and the feature check's call were about 30 instructions of a query).
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        #[cfg(target_arch = "x86_64")]
        if has_x86_64_v3() {
            // SAFETY: the CPU has every feature `intersect_v3` is compiled for (checked above).
            return unsafe { self.intersect_v3(ray) };
        }
        self.intersect_impl(ray, Baseline)
    }

    /// True when anything lies on the ray in (0, ray.t_max): stops at the first hit found.
    #[inline]
    pub fn occluded(&self, ray: &Ray) -> bool {
        #[cfg(target_arch = "x86_64")]
        if has_x86_64_v3() {
            // SAFETY: as in `intersect`.
            return unsafe { self.occluded_v3::<false>(ray) };
        }
        self.occluded_impl::<false>(ray, Baseline)
    }

    /// [`Bvh::occluded`] for a succession of related shadow rays, such as a path's
    /// next-event estimation: tests the triangle blocks that stopped this thread's last two
    /// occluded shadow rays first, and traverses only when neither stops this one. The same
    /// answer as [`Bvh::occluded`] (any triangle the ray hits is an answer); fewer
    /// instructions when most shadow rays are blocked by the same few triangles (a light in
    /// another room: 27 % fewer shadow-ray instructions on `rooms:3`, BENCHMARKS.md), a few
    /// more when they are blocked by ever different ones. After an unoccluded ray the next
    /// one traverses directly.
    #[inline(always)]
    pub fn occluded_coherent(&self, ray: &Ray) -> bool {
        #[cfg(target_arch = "x86_64")]
        if has_x86_64_v3() {
            // SAFETY: as in `intersect`.
            return unsafe { self.occluded_v3::<true>(ray) };
        }
        self.occluded_impl::<true>(ray, Baseline)
    }

    /// The same traversal compiled for x86-64-v3 (AVX2, BMI1/2, LZCNT, POPCNT, FMA; most x86
    /// CPUs since 2013-2015), with the AVX2 node test (all eight children at once). Baseline
    /// x86-64 has no `popcnt`, and the traversal counts bits for every node visited; with this
    /// copy the default build ran 1.0-1.27x faster and got within noise of a `-C
    /// target-cpu=native` build (BENCHMARKS.md).
    /// Results are bit-identical: Rust never contracts a * b + c into an FMA by itself.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    unsafe fn intersect_v3(&self, ray: &Ray) -> Option<Hit> {
        // SAFETY: this function's contract is that the CPU has AVX2.
        self.intersect_impl(ray, unsafe { Avx2::new_unchecked() })
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    unsafe fn occluded_v3<const COHERENT: bool>(&self, ray: &Ray) -> bool {
        // SAFETY: as in `intersect_v3`.
        self.occluded_impl::<COHERENT>(ray, unsafe { Avx2::new_unchecked() })
    }

    #[inline(always)]
    fn intersect_impl(&self, ray: &Ray, isa: impl NodeTest) -> Option<Hit> {
        if self.is_empty() || !(ray.t_max > 0.0) {
            return None;
        }
        let q = QueryRay::new(ray);
        let ray_lanes = RayLanes::new(&q.tri);
        let mut best: Option<Hit> = None;
        let mut hits = BlockHits::MISS;
        self.traverse(
            isa,
            &q,
            ray.t_max,
            #[inline(always)]
            || {},
            #[inline(always)]
            |index, lanes, t_max| {
                let block = &self.blocks[index as usize];
                let mut mask = intersect_triangle_block_into(
                    &q.tri, &ray_lanes, block, lanes, *t_max, &mut hits,
                );
                // Highest lane first, keeping a hit only if strictly nearer: the order and
                // rule of testing the triangles one by one.
                while mask != 0 {
                    // `& 3`: the mask has four bits; no bounds checks.
                    let lane = (31 - mask.leading_zeros()) as usize & 3;
                    mask &= !(1 << lane);
                    if hits.t[lane] < *t_max {
                        *t_max = hits.t[lane];
                        best = Some(Hit {
                            t: hits.t[lane],
                            triangle: block.id(lane),
                            b1: hits.b1[lane],
                            b2: hits.b2[lane],
                        });
                    }
                }
                false
            },
        );
        best
    }

    #[inline(always)]
    fn occluded_impl<const COHERENT: bool>(&self, ray: &Ray, isa: impl NodeTest) -> bool {
        if self.is_empty() || !(ray.t_max > 0.0) {
            return false;
        }
        let q = QueryRay::new(ray);
        let ray_lanes = RayLanes::new(&q.tri);
        // Coherent queries test the block of this thread's last occluder first: consecutive
        // shadow rays of a path (and of neighbouring pixels) toward a light behind a wall are
        // mostly stopped by the same few triangles. Any triangle the ray hits is an answer,
        // so this changes no result (only the block's occupied lanes are tested, and an
        // index left by another BVH is only used when in range).
        let [first, second] = if COHERENT {
            LAST_OCCLUDER.with(Cell::get)
        } else {
            [u32::MAX; 2]
        };
        if COHERENT {
            if let Some(block) = self.blocks.get(first as usize) {
                let lanes = block.lanes();
                if intersect_triangle_block(&q.tri, &ray_lanes, block, lanes, ray.t_max).mask != 0 {
                    return true;
                }
                if let Some(block) = self.blocks.get(second as usize) {
                    let lanes = block.lanes();
                    if intersect_triangle_block(&q.tri, &ray_lanes, block, lanes, ray.t_max).mask
                        != 0
                    {
                        LAST_OCCLUDER.with(|c| c.set([second, first]));
                        return true;
                    }
                }
            }
        }
        let mut occluder = u32::MAX;
        self.traverse(
            isa,
            &q,
            ray.t_max,
            #[inline(always)]
            || {},
            #[inline(always)]
            |index, lanes, t_max| {
                let block = &self.blocks[index as usize];
                let hit =
                    intersect_triangle_block(&q.tri, &ray_lanes, block, lanes, *t_max).mask != 0;
                if hit {
                    occluder = index;
                }
                hit
            },
        );
        if COHERENT {
            LAST_OCCLUDER.with(|c| {
                c.set(if occluder == u32::MAX {
                    [u32::MAX; 2]
                } else {
                    [occluder, first]
                })
            });
        }
        occluder != u32::MAX
    }

    /// Depth of the deepest inner node of the 8-wide tree (the root is at depth 0). A ray
    /// descending to a node of depth d holds at most d entries on obvhs's traversal stack (one
    /// node group per level above it), so traversal is exact only while this is at most
    /// [`MAX_TRAVERSAL_DEPTH`].
    #[cfg(test)]
    fn inner_depth(&self) -> usize {
        deepest_inner_node(self.nodes.len(), |i| {
            (self.nodes[i].child_base_idx, self.nodes[i].imask)
        })
    }

    /// Nodes visited and triangles tested by a closest-hit query (BVH quality figures for
    /// `benches/bvh.rs` and tests; the same traversal as [`Bvh::intersect`]).
    #[doc(hidden)]
    pub fn closest_hit_work(&self, ray: &Ray) -> (u32, u32) {
        if self.is_empty() || !(ray.t_max > 0.0) {
            return (0, 0);
        }
        let q = QueryRay::new(ray);
        let ray_lanes = RayLanes::new(&q.tri);
        let (mut nodes, mut tris) = (0u32, 0u32);
        self.traverse(
            Baseline,
            &q,
            ray.t_max,
            #[inline(always)]
            || nodes += 1,
            #[inline(always)]
            |index, lanes, t_max| {
                tris += lanes.count_ones();
                let block = &self.blocks[index as usize];
                let hits = intersect_triangle_block(&q.tri, &ray_lanes, block, lanes, *t_max);
                for lane in 0..4 {
                    if hits.mask & (1 << lane) != 0 && hits.t[lane] < *t_max {
                        *t_max = hits.t[lane];
                    }
                }
                false
            },
        );
        (nodes, tris)
    }

    /// Stack traversal of the 8-wide BVH as for a compressed one (Ylitie et al. 2017), in
    /// obvhs's order (`obvhs::traverse!`: children nearest-first by the ray's octant, a leaf's
    /// triangles from its highest hit bit down), but without its general traversal state: it
    /// starts at the root's node test, keeps its groups in registers and takes the ray's
    /// constants from `q`. Calls `on_node` per node tested and `on_block(block, lanes, &mut
    /// t_max)` per triangle block with triangles to test (bit `lane` of `lanes` set for each),
    /// highest block first; it may lower `t_max` and returns true to end the traversal.
    #[inline(always)]
    fn traverse(
        &self,
        isa: impl NodeTest,
        q: &QueryRay,
        mut t_max: f32,
        mut on_node: impl FnMut(),
        mut on_block: impl FnMut(u32, u32, &mut f32) -> bool,
    ) {
        let nodes = &self.nodes;
        // Node groups still to visit: (first child node, hit bits << 24 | the node's imask).
        // Saturates at the last entry as obvhs's stack does; the builders keep trees
        // shallower than that (`sah.rs`, and PLOC's depth on real scenes).
        // Not zeroed (eight 32-byte stores per query, a tenth of a short query's set-up):
        // entries below `depth` are always written before they are read.
        let mut stack = [std::mem::MaybeUninit::<UVec2>::uninit(); TRAVERSAL_STACK];
        let mut depth = 0usize;
        on_node();
        let (mut group, mut triangles) = self.visit_node(isa, &nodes[0], q, t_max);
        loop {
            // `triangles.x` is a multiple of 4 (`triangle_blocks`): each nibble of the
            // triangle bits is one block.
            while triangles.y != 0 {
                let nibble = (31 - triangles.y.leading_zeros()) / 4;
                let lanes = (triangles.y >> (4 * nibble)) & 0xf;
                triangles.y &= !(0xf << (4 * nibble));
                if on_block(triangles.x / 4 + nibble, lanes, &mut t_max) {
                    return;
                }
            }
            if group.y & 0xff00_0000 != 0 {
                let hit_bits = group.y;
                let bit = 31 - hit_bits.leading_zeros();
                group.y &= !(1 << bit);
                if group.y & 0xff00_0000 != 0 {
                    stack[depth] = std::mem::MaybeUninit::new(group);
                    depth = (depth + 1).min(TRAVERSAL_STACK - 1);
                }
                // Child slot of the hit, and the child's rank among the node's inner children.
                let slot = (bit - 24) ^ (q.oct_inv4 & 0xff);
                let rank = (hit_bits & !(u32::MAX << slot)).count_ones();
                on_node();
                (group, triangles) =
                    self.visit_node(isa, &nodes[(group.x + rank) as usize], q, t_max);
            } else if depth > 0 {
                depth -= 1;
                // SAFETY: entry `depth` (below the old depth) was written when the depth
                // was raised past it, and is written again whenever the stack is full.
                group = unsafe { stack[depth].assume_init() };
            } else {
                return;
            }
        }
    }

    /// A node's test as traversal groups: (first child node, hit bits << 24 | the node's
    /// imask) and (first triangle, one bit per triangle to test).
    #[inline(always)]
    fn visit_node(
        &self,
        isa: impl NodeTest,
        node: &WideNode,
        q: &QueryRay,
        t_max: f32,
    ) -> (UVec2, UVec2) {
        let (boxes, hits) = isa.test(node, q, t_max);
        if self.prefetch {
            self.prefetch_children(node, boxes);
        }
        (
            UVec2::new(
                node.child_base_idx,
                (hits & 0xff00_0000) | node.imask as u32,
            ),
            UVec2::new(node.primitive_base_idx, hits & 0x00ff_ffff),
        )
    }

    /// Starts loading the nodes and leaf triangles of the children a node test hit. Traversal
    /// is bound by memory latency on large scenes (each level waits for the previous one);
    /// with the siblings requested together their misses overlap. Measured in
    /// `benches/bvh.rs` (`kernels`): see BENCHMARKS.md.
    #[inline(always)]
    fn prefetch_children(&self, node: &WideNode, mut hits: u32) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
            while hits != 0 {
                let c = hits.trailing_zeros();
                hits &= hits - 1;
                let meta = node.child_meta[c as usize];
                if meta == 0 {
                    continue; // empty slot
                }
                // A node is four cache lines, a triangle block three (both aligned to 64).
                let (p, lines): (*const i8, usize) = if node.imask & (1 << c) != 0 {
                    let rank = (node.imask as u32 & ((1u32 << c) - 1)).count_ones();
                    let child = &self.nodes[(node.child_base_idx + rank) as usize];
                    ((child as *const WideNode).cast(), 4)
                } else {
                    let first = node.primitive_base_idx + (meta & 0x1f) as u32;
                    (
                        (&self.blocks[first as usize / 4] as *const TriangleBlock).cast(),
                        3,
                    )
                };
                for line in 0..lines {
                    // SAFETY: a prefetch has no architectural effect (it cannot fault), and
                    // `p` points to a live node or block; SSE is part of x86-64.
                    unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(64 * line)) };
                }
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = (node, &mut hits);
    }

    /// Closest hits of many rays, in parallel; `out[i]` answers `rays[i]`.
    pub fn intersect_batch(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
        assert_eq!(rays.len(), out.len());
        rays.par_chunks(256)
            .zip(out.par_chunks_mut(256))
            .for_each(|(r, o)| {
                for (ray, slot) in r.iter().zip(o) {
                    *slot = self.intersect(ray);
                }
            });
    }

    /// Occlusion of many rays, in parallel.
    pub fn occluded_batch(&self, rays: &[Ray], out: &mut [bool]) {
        assert_eq!(rays.len(), out.len());
        rays.par_chunks(256)
            .zip(out.par_chunks_mut(256))
            .for_each(|(r, o)| {
                for (ray, slot) in r.iter().zip(o) {
                    *slot = self.occluded(ray);
                }
            });
    }
}

/// Whether the CPU runs x86-64-v3 code (cached after the first call).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn has_x86_64_v3() -> bool {
    match V3_STATE.load(std::sync::atomic::Ordering::Relaxed) {
        0 => detect_x86_64_v3(),
        v => v == 2,
    }
}

/// 0 unknown, 1 no, 2 yes.
#[cfg(target_arch = "x86_64")]
static V3_STATE: std::sync::atomic::AtomicU8 = std::sync::atomic::AtomicU8::new(0);

/// The first call's detection, out of line so that the check above inlines as a load and a
/// compare.
#[cfg(target_arch = "x86_64")]
#[cold]
#[inline(never)]
fn detect_x86_64_v3() -> bool {
    use std::arch::is_x86_feature_detected as has;
    let yes = has!("avx2")
        && has!("fma")
        && has!("bmi1")
        && has!("bmi2")
        && has!("lzcnt")
        && has!("popcnt");
    V3_STATE.store(
        if yes { 2 } else { 1 },
        std::sync::atomic::Ordering::Relaxed,
    );
    yes
}

thread_local! {
    /// Indices in [`Bvh::blocks`] of the triangle blocks that stopped this thread's last two
    /// occluded [`Bvh::occluded_coherent`] rays, the latest first; `u32::MAX` after an
    /// unoccluded one. Only an index: a
    /// stale value from another BVH is harmless, any block in range is a valid first test.
    static LAST_OCCLUDER: Cell<[u32; 2]> = const { Cell::new([u32::MAX; 2]) };
}

/// Entries of the traversal stack (as obvhs's `traverse!`).
const TRAVERSAL_STACK: usize = 32;

/// Everything a query needs of its ray, computed once: the node test's constants and the
/// triangle test's share one reciprocal of the direction (one vector division per query
/// instead of four scalar ones), and the octant that orders children.
struct QueryRay {
    node: NodeRay,
    tri: RayPrecomp,
    /// obvhs's `ray_get_octant_inv4`: in every byte, bit 2 / 1 / 0 set where the direction's
    /// x / y / z is not negative.
    oct_inv4: u32,
}

impl QueryRay {
    #[inline(always)]
    fn new(ray: &Ray) -> QueryRay {
        let dir = Vec3A::from(ray.dir);
        let recip = dir.recip();
        let negative = dir.cmplt(Vec3A::ZERO).bitmask();
        let positive = |axis: u32| (!negative >> axis) & 1;
        let tri = RayPrecomp::with_reciprocal(ray.origin, ray.dir, recip.into());
        QueryRay {
            node: NodeRay::from_reciprocal(ray.origin, recip),
            tri,
            oct_inv4: (positive(0) * 0x0404_0404)
                | (positive(1) * 0x0202_0202)
                | (positive(2) * 0x0101_0101),
        }
    }
}

/// A node of the 8-wide tree as traversal reads it: the topology, leaves and child order of
/// obvhs's compressed node (`CwBvhNode`: `imask`, `child_meta`, the two base indices, same
/// meaning), but the children's boxes as exact f32 bounds instead of 8-bit planes on a grid
/// relative to the node.
///
/// Why not obvhs's compressed node (issue 2 asks for CWBVH traversal): that node (80 bytes)
/// must be decoded per visit (grid step from the exponents, per-node distances and the rounding
/// slack that keeps the quantised test conservative, byte-to-float conversions), and its boxes
/// are up to one grid step (1/255 of the node) larger on every side, so rays enter children
/// and leaves they miss. This node is 256 bytes (3.2x), one aligned 256-bit load per plane.
/// Measured against the compressed node (BENCHMARKS.md).
///
/// `planes[2 * axis]` holds the eight children's minima on `axis`, `planes[2 * axis + 1]` their
/// maxima: the exact bounds of the triangles below each child (unions of f32 minima and maxima
/// are exact). Empty slots hold the empty box (+inf, -inf); traversal ignores them anyway
/// (`child_meta` 0 gives no traversal bits).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct WideNode {
    planes: [[f32; 8]; 6],
    /// Index of the first inner child in [`Bvh::nodes`]; the inner children follow in slot
    /// order, one per bit of `imask`.
    child_base_idx: u32,
    /// First leaf slot of this node's triangles (a multiple of 4, see [`triangle_blocks`]).
    primitive_base_idx: u32,
    /// As in `CwBvhNode`: 0 empty; a leaf's slot offset (low 5 bits) and its triangles in
    /// unary (high 3); an inner child 0b001 in the high bits and 24 plus its slot in the low 5,
    /// in the order that makes `slot ^ octant` nearest first.
    child_meta: [u8; 8],
    /// Bit c set when child c is an inner node.
    imask: u8,
}

const _: () = assert!(std::mem::size_of::<WideNode>() == 256);

/// The [`WideNode`]s of an 8-wide tree whose leaves `triangle_blocks` has laid out in
/// `blocks`: same topology and indices, children's boxes from the triangles, bottom-up.
fn wide_nodes(cwbvh: &CwBvh, blocks: &[TriangleBlock]) -> Vec<WideNode> {
    let empty = WideNode {
        planes: [
            [f32::INFINITY; 8],
            [f32::NEG_INFINITY; 8],
            [f32::INFINITY; 8],
            [f32::NEG_INFINITY; 8],
            [f32::INFINITY; 8],
            [f32::NEG_INFINITY; 8],
        ],
        child_base_idx: 0,
        primitive_base_idx: 0,
        child_meta: [0; 8],
        imask: 0,
    };
    let mut nodes = vec![empty; cwbvh.nodes.len()];
    if !nodes.is_empty() {
        wide_node(cwbvh, blocks, 0, &mut nodes);
    }
    nodes
}

/// Fills `nodes[i]` and those below it; returns the node's own box (min, max). Recursion
/// depth is the tree's, at most [`MAX_TRAVERSAL_DEPTH`] + 1.
fn wide_node(
    cwbvh: &CwBvh,
    blocks: &[TriangleBlock],
    i: usize,
    nodes: &mut [WideNode],
) -> [Vec3; 2] {
    let src = &cwbvh.nodes[i];
    let mut node = nodes[i];
    node.child_base_idx = src.child_base_idx;
    node.primitive_base_idx = src.primitive_base_idx;
    node.child_meta = src.child_meta;
    node.imask = src.imask;
    let mut total = [Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)];
    let mut rank = 0;
    for c in 0..8 {
        let meta = src.child_meta[c];
        let [lo, hi] = if src.imask & (1 << c) != 0 {
            let child = (src.child_base_idx + rank) as usize;
            rank += 1;
            debug_assert!(child > i);
            wide_node(cwbvh, blocks, child, nodes)
        } else if meta != 0 {
            let first = src.primitive_base_idx + (meta & 0x1f) as u32;
            let mut b = [Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)];
            for slot in first..first + (meta >> 5).count_ones() {
                for p in blocks[slot as usize / 4].triangle(slot as usize % 4) {
                    b = [b[0].min(p), b[1].max(p)];
                }
            }
            b
        } else {
            continue;
        };
        for axis in 0..3 {
            node.planes[2 * axis][c] = lo[axis];
            node.planes[2 * axis + 1][c] = hi[axis];
        }
        total = [total[0].min(lo), total[1].max(hi)];
    }
    nodes[i] = node;
    total
}

/// Per-ray constants of the node test.
///
/// The test computes each plane's distance as `(plane - o) * inv` with `inv = 1 / d` rounded:
/// three roundings of the exact `(plane - o) / d`, so (for normal, non-subnormal results) the
/// computed distance is the exact one times (1 + θ), |θ| <= gamma(3), with the same sign
/// (rounding never changes a sign). If the ray overlaps a box in the exact sense,
/// E = max(0, nears) <= X = min(t_max, fars), every far plane is >= 0 and the computed values
/// are E' <= E (1 + gamma(3)) and X' >= X (1 - gamma(3)) >= 0; then
/// fl(X' * [`EXIT_SCALE`]) >= X (1 - gamma(3)) (1 - eps) (1 + 2 gamma(5)), which is at least
/// E (1 + gamma(3)) >= E' because (1 + gamma(3)) / ((1 - gamma(3)) (1 - eps)) is
/// 1 + 7 eps + O(eps^2) and the rounded factor is 1 + 10 eps. So `E' <= fl(X' * EXIT_SCALE)`
/// never culls a box the ray touches (Ize, "Robust BVH Ray Traversal", JCGT 2013, with the
/// reciprocal's own rounding counted and the scaling's rounding covered), including rays
/// starting inside or on a box.
/// No FMA: `plane * inv - o * inv` would round `o * inv` on its own, an error relative to the
/// origin's distance instead of the plane's.
struct NodeRay {
    origin: Vec3A,
    /// `1 / dir`, clamped to +-2^40 so that no product is NaN (0 * inf) when the ray starts on
    /// a plane and is parallel to it.
    inv_dir: Vec3A,
    /// The origin as far planes see it: `origin`, but -inf * sign(inv_dir) on clamped axes, so
    /// that every far plane of such an axis is at +inf. A clamped reciprocal underestimates
    /// distances, which keeps its near planes conservative but not its far ones; those are
    /// taken as unbounded (finite plane minus an infinite origin, times a finite reciprocal of
    /// the same sign: +inf, never NaN).
    far_origin: Vec3A,
    /// Bit `axis` set when `inv_dir[axis] < 0` (so `dir` negative, also -0.0): swaps near and
    /// far planes.
    negative: u32,
}

const INV_DIR_LIMIT: f32 = (1u64 << 40) as f32;

/// The factor on the exit distance that makes the f32 slab test conservative (see
/// [`NodeRay`]).
const EXIT_SCALE: f32 = 1.0 + 2.0 * crate::math::gamma(5);

impl NodeRay {
    /// From `recip = 1 / dir` (unclamped), on all three axes at once.
    #[inline(always)]
    fn from_reciprocal(origin: Vec3, recip: Vec3A) -> NodeRay {
        let limit = Vec3A::splat(INV_DIR_LIMIT);
        // Written so that NaN takes the clamped branch.
        let in_range = recip.abs().cmple(limit);
        let inv_dir = Vec3A::select(in_range, recip, limit.copysign(recip));
        let origin = Vec3A::from(origin);
        NodeRay {
            origin,
            inv_dir,
            far_origin: Vec3A::select(
                in_range,
                origin,
                Vec3A::splat(f32::INFINITY).copysign(-inv_dir),
            ),
            negative: inv_dir.cmplt(Vec3A::ZERO).bitmask(),
        }
    }

    /// Index in [`WideNode::planes`] of the near planes of `axis` (the far ones are at
    /// `near ^ 1`).
    #[inline(always)]
    fn near_plane(&self, axis: usize) -> usize {
        2 * axis + ((self.negative >> axis) & 1) as usize
    }
}

/// Bit c set when the ray overlaps child box c in [0, t_max] (conservatively, see
/// [`NodeRay`]). The scalar reference: the AVX2 test does the same operations in the same
/// order lane by lane (`a > b ? a : b` and `a < b ? a : b` as `maxps`/`minps` do, so even NaN
/// lanes agree).
#[inline(always)]
fn child_hits(node: &WideNode, r: &NodeRay, t_max: f32) -> u32 {
    let mut hits = 0u32;
    for c in 0..8 {
        let mut enter = 0.0f32;
        let mut exit = t_max;
        for axis in 0..3 {
            let near = r.near_plane(axis);
            let inv = r.inv_dir[axis];
            let tn = (node.planes[near][c] - r.origin[axis]) * inv;
            let tf = (node.planes[near ^ 1][c] - r.far_origin[axis]) * inv;
            enter = if tn > enter { tn } else { enter };
            exit = if tf < exit { tf } else { exit };
        }
        hits |= ((enter <= exit * EXIT_SCALE) as u32) << c;
    }
    hits
}

/// A node test: bit c of the first value set when the ray overlaps child box c in
/// [0, t_max], and the traversal hit mask in obvhs's layout (`CwBvhNode::intersect_ray`):
/// for each child hit, its triangle bits at its leaf offset (bits 0..24) or, for an inner
/// child, one bit at 24 plus its slot in the ray's octant order.
trait NodeTest: Copy {
    fn test(self, node: &WideNode, q: &QueryRay, t_max: f32) -> (u32, u32);
}

/// The node test of baseline x86-64 or of other targets (scalar, [`child_hits`]).
#[derive(Clone, Copy)]
struct Baseline;

impl NodeTest for Baseline {
    #[inline(always)]
    fn test(self, node: &WideNode, q: &QueryRay, t_max: f32) -> (u32, u32) {
        let boxes = child_hits(node, &q.node, t_max);
        let octant = q.oct_inv4 & 7;
        let (mut hits, mut mask) = (boxes, 0u32);
        while hits != 0 {
            let c = hits.trailing_zeros() as usize;
            hits &= hits - 1;
            let meta = node.child_meta[c] as u32;
            // obvhs's `get_child_and_index_bits`, one child.
            let index = if meta & 0x18 == 0x18 {
                (meta ^ octant) & 31
            } else {
                meta & 31
            };
            mask |= (meta >> 5) << index;
        }
        (boxes, mask)
    }
}

/// The node test with all eight children in one 256-bit register. A value of this type is a
/// proof that the CPU has AVX2: it is only made by [`Avx2::new_unchecked`], whose callers
/// (the `_v3` entry points) check that first.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
struct Avx2(());

#[cfg(target_arch = "x86_64")]
impl Avx2 {
    /// # Safety
    /// The CPU must have AVX2.
    #[inline(always)]
    unsafe fn new_unchecked() -> Avx2 {
        Avx2(())
    }
}

#[cfg(target_arch = "x86_64")]
impl NodeTest for Avx2 {
    #[inline(always)]
    fn test(self, node: &WideNode, q: &QueryRay, t_max: f32) -> (u32, u32) {
        // SAFETY: an `Avx2` exists only on a CPU with AVX2 (see the type).
        unsafe { node_test_avx2(node, q, t_max) }
    }
}

/// [`child_hits`] on all eight children at once, with the same roundings in the same order
/// (subtract, multiply; no FMA; min and max with the operand order of the scalar selects), so
/// the same boxes are hit; and the hit mask of [`Baseline`] built in the same register instead
/// of child by child: per child, `(meta >> 5) << index`, where the index is the leaf offset
/// `meta & 31` or, for an inner child (`meta & 0x18 == 0x18`), `(meta ^ octant) & 31`, masked
/// by the box test and OR-ed over the lanes (obvhs's `get_child_and_index_bits`, lane-wise).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn node_test_avx2(node: &WideNode, q: &QueryRay, t_max: f32) -> (u32, u32) {
    use std::arch::x86_64::*;
    let r = &q.node;
    let mut enter = _mm256_setzero_ps();
    let mut exit = _mm256_set1_ps(t_max);
    for axis in 0..3 {
        let near = r.near_plane(axis);
        // SAFETY: `planes` rows are 32 bytes at 32-byte offsets of a 64-aligned node.
        let (pn, pf) = unsafe {
            (
                _mm256_load_ps(node.planes[near].as_ptr()),
                _mm256_load_ps(node.planes[near ^ 1].as_ptr()),
            )
        };
        let inv = _mm256_set1_ps(r.inv_dir[axis]);
        let tn = _mm256_mul_ps(_mm256_sub_ps(pn, _mm256_set1_ps(r.origin[axis])), inv);
        let tf = _mm256_mul_ps(_mm256_sub_ps(pf, _mm256_set1_ps(r.far_origin[axis])), inv);
        enter = _mm256_max_ps(tn, enter);
        exit = _mm256_min_ps(tf, exit);
    }
    let exit = _mm256_mul_ps(exit, _mm256_set1_ps(EXIT_SCALE));
    let hit = _mm256_cmp_ps::<_CMP_LE_OQ>(enter, exit);
    let boxes = _mm256_movemask_ps(hit) as u32;
    // SAFETY: child_meta is 8 bytes of `node`.
    let meta = _mm256_cvtepu8_epi32(unsafe { _mm_loadl_epi64(node.child_meta.as_ptr().cast()) });
    let inner_bits = _mm256_set1_epi32(0x18);
    let inner = _mm256_cmpeq_epi32(_mm256_and_si256(meta, inner_bits), inner_bits);
    let octant = _mm256_set1_epi32((q.oct_inv4 & 7) as i32);
    let index = _mm256_and_si256(
        _mm256_xor_si256(meta, _mm256_and_si256(inner, octant)),
        _mm256_set1_epi32(31),
    );
    let bits = _mm256_sllv_epi32(_mm256_srli_epi32::<5>(meta), index);
    let bits = _mm256_and_si256(bits, _mm256_castps_si256(hit));
    let bits = _mm_or_si128(
        _mm256_castsi256_si128(bits),
        _mm256_extracti128_si256::<1>(bits),
    );
    let bits = _mm_or_si128(bits, _mm_shuffle_epi32::<0b01_00_11_10>(bits));
    let bits = _mm_or_si128(bits, _mm_shuffle_epi32::<0b10_11_00_01>(bits));
    (boxes, _mm_cvtsi128_si32(bits) as u32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::intersect_triangle;
    use crate::math::{warp, Rng};

    /// `triangle_blocks`: every triangle in exactly one lane, with its vertices; node bases
    /// on block boundaries; leaves in one block wherever the node's leaves fit that way;
    /// each block's lane mask marks exactly its triangles.
    #[test]
    fn triangle_blocks_hold_every_triangle_once() {
        let mut rng = Rng::new(5, 1);
        for n in [1usize, 2, 3, 5, 17, 300, 5000] {
            let tris = random_triangles(n, &mut rng);
            for method in [BvhQuality::Medium.method(n), BuildMethod::Binned] {
                let bvh = Bvh::build_with(&tris, method);
                let mut seen = vec![0u32; n];
                for node in &bvh.nodes {
                    assert_eq!(node.primitive_base_idx % 4, 0);
                    let mut leaves: Vec<(u32, u32)> = (0..8)
                        .filter(|&c| node.imask & (1 << c) == 0 && node.child_meta[c] != 0)
                        .map(|c| {
                            let meta = node.child_meta[c];
                            ((meta & 0x1f) as u32, (meta >> 5).count_ones())
                        })
                        .collect();
                    leaves.sort();
                    let packed: u32 = leaves.iter().map(|l| l.1).sum();
                    let straddles = leaves.iter().any(|&(o, c)| o / 4 != (o + c - 1) / 4);
                    // Only a node whose aligned leaves would not fit 24 bits keeps a straddle.
                    assert!(!straddles || packed > 16, "{leaves:?}");
                    for (offset, count) in leaves {
                        for k in 0..count {
                            let slot = (node.primitive_base_idx + offset + k) as usize;
                            let block = &bvh.blocks[slot / 4];
                            assert!(block.lanes() & (1 << (slot % 4)) != 0);
                            let id = block.id(slot % 4) as usize;
                            assert_eq!(block.triangle(slot % 4), tris[id]);
                            seen[id] += 1;
                        }
                    }
                }
                assert!(seen.iter().all(|&s| s == 1), "n = {n}");
                // The occupied-lane masks mark exactly the lanes that hold a triangle.
                let marked: u32 = bvh.blocks.iter().map(|b| b.lanes().count_ones()).sum();
                assert_eq!(marked as usize, n);
            }
        }
    }

    /// Degenerate inputs on which PLOC merges about one triangle per step, and others that
    /// stress the builders (coincident, collinear): every tree fits obvhs's traversal stack
    /// and answers what brute force answers. The geometric chain's raw PLOC tree is deeper
    /// than the stack (checked, else this test would not test the fallback); rays along the
    /// chain hit every node box on their way, the worst case for the stack.
    #[test]
    fn degenerate_inputs_fit_the_traversal_stack() {
        // A triangle in the plane x = c.x, so a ray along x passes through all of them.
        let across = |c: Vec3, s: f32| [c, c + Vec3::new(0.0, s, 0.0), c + Vec3::new(0.0, 0.0, s)];
        let chain: Vec<[Vec3; 3]> = (0..850)
            .map(|i| across(Vec3::new(1.1f32.powi(i), 0.0, 0.0), 1e-3))
            .collect();
        let to_obvhs = |tris: &[[Vec3; 3]]| -> Vec<Triangle> {
            tris.iter()
                .map(|t| Triangle {
                    v0: t[0].into(),
                    v1: t[1].into(),
                    v2: t[2].into(),
                })
                .collect()
        };
        let raw = cwbvh_inner_depth(&to_cwbvh(&ploc_bvh2(
            &to_obvhs(&chain),
            BvhQuality::Fast.ploc_params(),
            &BuildProfile::default(),
        )));
        assert!(raw > MAX_TRAVERSAL_DEPTH, "raw PLOC depth {raw}");
        let nested: Vec<[Vec3; 3]> = (0..3000)
            .map(|i| {
                let s = 1e-3 * 1.01f32.powi(i);
                [
                    Vec3::new(-s, -s, 0.0),
                    Vec3::new(s, -s, 0.0),
                    Vec3::new(0.0, s, s),
                ]
            })
            .collect();
        let identical = vec![across(Vec3::ZERO, 1.0); 4000];
        let collinear: Vec<[Vec3; 3]> = (0..20_000)
            .map(|i| across(Vec3::new(i as f32 * 1e-3, 0.0, 0.0), 0.5))
            .collect();
        let mut rng = Rng::new(5, 9);
        for (name, tris) in [
            ("chain", &chain),
            ("nested", &nested),
            ("identical", &identical),
            ("collinear", &collinear),
        ] {
            let first = tris[0][0];
            let last = tris[tris.len() - 1][0];
            let mut rays: Vec<Ray> = (0..40)
                .flat_map(|_| {
                    // Along the x axis through the triangles, from between two of them.
                    let i = rng.below(tris.len() as u32 - 1) as usize;
                    let x = (tris[i][0].x + tris[i + 1][0].x) * 0.5;
                    let o = Vec3::new(x, 2e-4, 3e-4);
                    [
                        Ray::new(o, Vec3::X, f32::INFINITY),
                        Ray::new(o, -Vec3::X, f32::INFINITY),
                    ]
                })
                .collect();
            for _ in 0..200 {
                let o = first.lerp(last, rng.uniform()) + warp::uniform_sphere(rng.uniform2());
                rays.push(Ray::new(
                    o,
                    warp::uniform_sphere(rng.uniform2()),
                    f32::INFINITY,
                ));
            }
            for method in [
                BuildMethod::Ploc(BvhQuality::Fast),
                BuildMethod::Ploc(BvhQuality::Medium),
                BuildMethod::Ploc(BvhQuality::High),
                BuildMethod::Sah { reinsertion: 0.0 },
                BuildMethod::Binned,
                BvhQuality::Medium.method(tris.len()),
            ] {
                let bvh = Bvh::build_with(tris, method);
                let depth = bvh.inner_depth();
                assert!(
                    depth <= MAX_TRAVERSAL_DEPTH,
                    "{name} {method:?}: depth {depth}"
                );
                for ray in &rays {
                    let brute = brute_force(tris, ray);
                    let got = bvh.intersect(ray);
                    assert_eq!(got.map(|h| h.t), brute.map(|b| b.1), "{name} {method:?}");
                    assert_eq!(bvh.occluded(ray), brute.is_some(), "{name} {method:?}");
                }
            }
        }
    }

    /// Depth of a binary tree (root 0).
    fn bvh2_depth(bvh2: &Bvh2) -> usize {
        let mut deepest = 0;
        let mut stack = vec![(0usize, 0usize)];
        while let Some((i, depth)) = stack.pop() {
            deepest = deepest.max(depth);
            let node = &bvh2.nodes[i];
            if !node.is_leaf() {
                let c = node.first_index as usize;
                stack.push((c, depth + 1));
                stack.push((c + 1, depth + 1));
            }
        }
        deepest
    }

    /// Issue 29: one triangle repeated n times (all neighbour costs tied) and nested, slightly
    /// scaled copies of one triangle (costs monotone along the Morton order) made obvhs's PLOC
    /// merge one pair per iteration: n iterations, O(n^2) time (16,000 copies 5-12 s, 100,000
    /// over two minutes) and a binary tree about n deep. Patched obvhs (vendor/obvhs/PATCHED.md)
    /// pairs Morton neighbours when fewer than 1/32 of at least 1,024 clusters agree, so the
    /// depth stays below 1,024 plus a few per halving; without the patch this test takes
    /// minutes and fails on the depth. Every quality's final tree still answers as brute force.
    #[test]
    fn duplicate_and_nested_triangles_build_in_n_log_n() {
        let n = 30_000;
        let triangle = |s: f32| [Vec3::ZERO, Vec3::new(s, 0.0, 0.0), Vec3::new(0.0, s, 0.2)];
        let identical = vec![triangle(1.0); n];
        let nested: Vec<[Vec3; 3]> = (0..n).map(|i| triangle(1.0 + i as f32 * 1e-5)).collect();
        let bound = 1024 + 128 * (n as f64).log2().ceil() as usize;
        let mut rng = Rng::new(29, 1);
        for (name, tris) in [("identical", &identical), ("nested", &nested)] {
            let obvhs_tris: Vec<Triangle> = tris
                .iter()
                .map(|t| Triangle {
                    v0: t[0].into(),
                    v1: t[1].into(),
                    v2: t[2].into(),
                })
                .collect();
            for quality in [BvhQuality::Fast, BvhQuality::Medium] {
                // PLOC alone: its depth bounds its iterations from below (the reinsertion
                // that follows may deepen a nested chain, as SAH prefers there).
                let params = quality.ploc_params();
                let bvh2 = PlocBuilder::with_capacity(n).build(
                    params.ploc_search_distance,
                    &obvhs_tris,
                    (0..n as u32).collect(),
                    params.sort_precision,
                    params.search_depth_threshold,
                );
                let depth = bvh2_depth(&bvh2);
                assert!(depth <= bound, "{name} {quality:?}: PLOC depth {depth}");
            }
            let rays: Vec<Ray> = (0..100)
                .map(|_| {
                    let o = Vec3::new(0.3, 0.3, -1.0) + warp::uniform_sphere(rng.uniform2()) * 0.3;
                    let target = Vec3::new(rng.uniform(), rng.uniform(), 0.1);
                    Ray::new(o, (target - o).normalize(), f32::INFINITY)
                })
                .collect();
            for quality in [BvhQuality::Fast, BvhQuality::Medium, BvhQuality::High] {
                let bvh = Bvh::build(tris, quality);
                assert!(bvh.inner_depth() <= MAX_TRAVERSAL_DEPTH);
                for ray in &rays {
                    let brute = brute_force(tris, ray);
                    assert_eq!(
                        bvh.intersect(ray).map(|h| h.t),
                        brute.map(|b| b.1),
                        "{name}"
                    );
                    assert_eq!(bvh.occluded(ray), brute.is_some(), "{name}");
                }
            }
        }
    }

    fn random_triangles(n: usize, rng: &mut Rng) -> Vec<[Vec3; 3]> {
        (0..n)
            .map(|_| {
                let c = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 10.0;
                let s = 0.3 + rng.uniform();
                [
                    c,
                    c + warp::uniform_sphere(rng.uniform2()) * s,
                    c + warp::uniform_sphere(rng.uniform2()) * s,
                ]
            })
            .collect()
    }

    /// The BVH answers exactly what testing every triangle answers, at every scene scale and
    /// for rays starting right next to geometry.
    #[test]
    fn bvh_matches_brute_force() {
        let mut rng = Rng::new(17, 1);
        let unit_tris = random_triangles(2000, &mut rng);
        for scale in [1e-4f32, 1.0, 1e4] {
            let tris: Vec<[Vec3; 3]> = unit_tris.iter().map(|t| t.map(|p| p * scale)).collect();
            for quality in [
                BuildMethod::Ploc(BvhQuality::Fast),
                BuildMethod::Ploc(BvhQuality::High),
                BuildMethod::Sah { reinsertion: 0.0 },
                BuildMethod::Sah { reinsertion: 0.05 },
                BuildMethod::Binned,
                BvhQuality::Medium.method(tris.len()),
            ] {
                let bvh = Bvh::build_with(&tris, quality);
                for i in 0..3000 {
                    let o = if i % 2 == 0 {
                        (Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 12.0 - Vec3::ONE)
                            * scale
                    } else {
                        // Just off a random triangle: the nearest geometry is far below 1e-4.
                        let t = tris[rng.below(tris.len() as u32) as usize];
                        let (b0, b1) = warp::uniform_triangle(rng.uniform2());
                        t[0] * b0
                            + t[1] * b1
                            + t[2] * (1.0 - b0 - b1)
                            + warp::uniform_sphere(rng.uniform2()) * (1e-3 * scale)
                    };
                    let d = warp::uniform_sphere(rng.uniform2());
                    let t_max = if rng.uniform() < 0.5 {
                        f32::INFINITY
                    } else {
                        rng.uniform() * 10.0 * scale
                    };
                    let ray = Ray::new(o, d, t_max);
                    let pre = RayPrecomp::new(o, d);
                    let brute = tris
                        .iter()
                        .enumerate()
                        .filter_map(|(i, t)| {
                            intersect_triangle(&pre, t[0], t[1], t[2], t_max).map(|h| (i, h))
                        })
                        .min_by(|a, b| a.1.t.total_cmp(&b.1.t));
                    let got = bvh.intersect(&ray);
                    assert_eq!(
                        got.map(|h| h.t),
                        brute.map(|b| b.1.t),
                        "scale {scale}, {quality:?}"
                    );
                    assert_eq!(got.map(|h| h.triangle as usize), brute.map(|b| b.0));
                    assert_eq!(bvh.occluded(&ray), brute.is_some());
                    // The baseline code path agrees bit for bit with the dispatched one.
                    assert_eq!(bvh.intersect_impl(&ray, Baseline), got);
                    assert_eq!(bvh.occluded_impl::<false>(&ray, Baseline), brute.is_some());
                    // The coherent query, whatever block the previous ray left cached.
                    assert_eq!(bvh.occluded_coherent(&ray), brute.is_some());
                    assert_eq!(bvh.occluded_impl::<true>(&ray, Baseline), brute.is_some());
                }
            }
        }
    }

    /// Both compiled copies of the traversal (baseline and x86-64-v3, the one x86-64 CPUs
    /// with AVX2 run) answer bit for bit alike: closest hits (distance, triangle, barycentrics
    /// as bits), occlusion and coherent occlusion, on random triangles at three scales and
    /// on a closed room of axis-aligned quads (shared edges and vertices, where the zero-edge
    /// rule of the triangle test runs), with rays from inside the room, just off its walls,
    /// axis-aligned ones with signed zeros, and finite and infinite t_max. The dispatched
    /// entry points are one of these copies; `bvh_matches_brute_force` checks them against
    /// brute force. On a CPU without x86-64-v3 only the baseline runs (said on stderr).
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn baseline_and_avx2_copies_agree() {
        use std::arch::is_x86_feature_detected as has;
        let v3 = has!("avx2")
            && has!("fma")
            && has!("bmi1")
            && has!("bmi2")
            && has!("lzcnt")
            && has!("popcnt");
        if !v3 {
            eprintln!("CPU without x86-64-v3: the AVX2 copy is not compared");
        }
        let bits =
            |h: Option<Hit>| h.map(|h| (h.t.to_bits(), h.triangle, h.b1.to_bits(), h.b2.to_bits()));
        let mut rng = Rng::new(41, 3);
        let mut scenes: Vec<(Vec<[Vec3; 3]>, f32)> = [1e-4f32, 1.0, 1e4]
            .iter()
            .map(|&scale| {
                let tris = random_triangles(2000, &mut rng);
                (
                    tris.into_iter().map(|t| t.map(|p| p * scale)).collect(),
                    scale,
                )
            })
            .collect();
        // A closed room: each wall 8 x 8 quads.
        scenes.push((closed_room(8), 1.0));
        let (mut compared, mut hits, mut occluded) = (0usize, 0usize, 0usize);
        for (tris, scale) in &scenes {
            let bvh = Bvh::build(tris, BvhQuality::Medium);
            for i in 0..4000 {
                let o = match i % 3 {
                    0 => {
                        (Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 2.4 - 1.2)
                            * *scale
                    }
                    1 => {
                        // Just off a triangle.
                        let t = tris[rng.below(tris.len() as u32) as usize];
                        let (b0, b1) = warp::uniform_triangle(rng.uniform2());
                        t[0] * b0
                            + t[1] * b1
                            + t[2] * (1.0 - b0 - b1)
                            + warp::uniform_sphere(rng.uniform2()) * (1e-4 * scale)
                    }
                    _ => {
                        (Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 12.0 - Vec3::ONE)
                            * *scale
                    }
                };
                let d = node_test_direction(&mut rng, i % 4);
                let t_max = if i % 2 == 0 {
                    f32::INFINITY
                } else {
                    rng.uniform() * 3.0 * scale
                };
                let ray = Ray::new(o, d, t_max);
                let hit = bits(bvh.intersect_impl(&ray, Baseline));
                let occ = bvh.occluded_impl::<false>(&ray, Baseline);
                let coherent = bvh.occluded_impl::<true>(&ray, Baseline);
                assert_eq!(coherent, occ, "{ray:?}");
                if v3 {
                    // SAFETY: x86-64-v3 detected above.
                    unsafe {
                        assert_eq!(bits(bvh.intersect_v3(&ray)), hit, "{ray:?}");
                        assert_eq!(bvh.occluded_v3::<false>(&ray), occ, "{ray:?}");
                        assert_eq!(bvh.occluded_v3::<true>(&ray), occ, "{ray:?}");
                    }
                }
                compared += 1;
                hits += hit.is_some() as usize;
                occluded += occ as usize;
            }
        }
        // Both answers are common, else the comparison would say little.
        assert!(
            compared == 16_000 && hits > 4000 && occluded > 4000,
            "{hits} {occluded}"
        );
    }

    /// Coherent shadow rays: a wall of 2 x 200 quads with a gap between two sources and their
    /// targets, so that runs of consecutive rays are stopped by one block, then by another,
    /// then pass through the gap; every answer equals brute force and `occluded`, including
    /// right after a query on another BVH left its own block index behind.
    #[test]
    fn coherent_occlusion_matches_brute_force() {
        let mut tris = Vec::new();
        for i in 0..200 {
            if (90..100).contains(&i) {
                continue; // the gap
            }
            let (x0, x1) = (i as f32 * 0.1, (i + 1) as f32 * 0.1);
            for (y0, y1) in [(0.0f32, 1.0f32), (1.0, 2.0)] {
                let p = |x: f32, y: f32| Vec3::new(x, y, 0.0);
                tris.push([p(x0, y0), p(x1, y0), p(x1, y1)]);
                tris.push([p(x0, y0), p(x1, y1), p(x0, y1)]);
            }
        }
        let wall = Bvh::build(&tris, BvhQuality::Medium);
        let other = Bvh::build(
            &random_triangles(3000, &mut Rng::new(5, 9)),
            BvhQuality::Medium,
        );
        let mut rng = Rng::new(23, 2);
        let mut occluded = 0;
        for i in 0..20_000 {
            if i % 97 == 0 {
                // Leaves a block index of another tree in the cache.
                let o = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 10.0;
                other.occluded_coherent(&Ray::new(o, warp::uniform_sphere(rng.uniform2()), 5.0));
            }
            // Sources drift slowly along the wall, as the vertices of neighbouring paths do.
            let x = (i as f32 / 20_000.0) * 20.0 + rng.uniform() * 0.3;
            let from = Vec3::new(x, rng.uniform() * 2.0, -1.0 - rng.uniform());
            let to = Vec3::new(
                x + rng.uniform() - 0.5,
                rng.uniform() * 2.0,
                1.0 + rng.uniform(),
            );
            let d = to - from;
            let ray = Ray::new(from, d.normalize(), d.length());
            let expected = brute_force(&tris, &ray).is_some();
            occluded += expected as usize;
            assert_eq!(wall.occluded_coherent(&ray), expected, "ray {i}");
            assert_eq!(
                wall.occluded_impl::<true>(&ray, Baseline),
                expected,
                "ray {i}"
            );
            assert_eq!(wall.occluded(&ray), expected, "ray {i}");
        }
        // Both answers are well represented.
        assert!(occluded > 10_000 && occluded < 19_900, "{occluded}");
    }

    /// A closed room, the cube [-1, 1]^3, each wall `n` x `n` axis-aligned quads: shared
    /// edges and axis-aligned faces, where watertightness and tree quality are tested.
    fn closed_room(n: usize) -> Vec<[Vec3; 3]> {
        let mut tris = Vec::new();
        for axis in 0..3 {
            for side in [-1.0f32, 1.0] {
                let p = |i: usize, j: usize| {
                    let mut c = Vec3::ZERO;
                    c[axis] = side;
                    c[(axis + 1) % 3] = 2.0 * i as f32 / n as f32 - 1.0;
                    c[(axis + 2) % 3] = 2.0 * j as f32 / n as f32 - 1.0;
                    c
                };
                for i in 0..n {
                    for j in 0..n {
                        tris.push([p(i, j), p(i + 1, j), p(i + 1, j + 1)]);
                        tris.push([p(i, j), p(i + 1, j + 1), p(i, j + 1)]);
                    }
                }
            }
        }
        tris
    }

    fn brute_force(tris: &[[Vec3; 3]], ray: &Ray) -> Option<(usize, f32)> {
        let pre = RayPrecomp::new(ray.origin, ray.dir);
        tris.iter()
            .enumerate()
            .filter_map(|(i, t)| {
                intersect_triangle(&pre, t[0], t[1], t[2], ray.t_max).map(|h| (i, h.t))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// Axis-aligned directions (with +0.0 and -0.0 components) and nearly axis-aligned ones,
    /// aimed exactly at triangle vertices and edge points, which lie on child box faces: the
    /// node test must neither cull those boxes nor lose a hit to a zero direction component.
    #[test]
    fn axis_aligned_rays_at_vertices_and_edges() {
        let mut rng = Rng::new(5, 3);
        let unit_tris = random_triangles(1500, &mut rng);
        for scale in [1e-4f32, 1.0, 1e4] {
            let tris: Vec<[Vec3; 3]> = unit_tris.iter().map(|t| t.map(|p| p * scale)).collect();
            for quality in [
                BuildMethod::Ploc(BvhQuality::Fast),
                BuildMethod::Sah { reinsertion: 0.0 },
                BuildMethod::Binned,
                BvhQuality::High.method(tris.len()),
            ] {
                let bvh = Bvh::build_with(&tris, quality);
                for i in 0..4000 {
                    let axis = rng.below(3) as usize;
                    let mut d = Vec3::ZERO;
                    // Signed zeros on the other axes: -0.0 must behave as +0.0.
                    for k in 0..3 {
                        if rng.uniform() < 0.5 {
                            d[k] = -0.0;
                        }
                    }
                    d[axis] = if rng.uniform() < 0.5 { 1.0 } else { -1.0 };
                    if i % 4 == 1 {
                        // Nearly axis-aligned: components far below the clamp of 1/d.
                        let k = (axis + 1 + rng.below(2) as usize) % 3;
                        d[k] = [1e-30, -1e-20, 1e-13, -3e-9][rng.below(4) as usize];
                    }
                    let t = tris[rng.below(tris.len() as u32) as usize];
                    let target = match rng.below(3) {
                        0 => t[rng.below(3) as usize],
                        1 => t[0] + (t[1] - t[0]) * rng.uniform(),
                        _ => {
                            let (b0, b1) = warp::uniform_triangle(rng.uniform2());
                            t[0] * b0 + t[1] * b1 + t[2] * (1.0 - b0 - b1)
                        }
                    };
                    let dist = (0.01 + rng.uniform() * 5.0) * scale;
                    let origin = target - d * dist;
                    let t_max = if i % 3 == 0 {
                        dist * 1.5
                    } else {
                        f32::INFINITY
                    };
                    let ray = Ray::new(origin, d, t_max);
                    let brute = brute_force(&tris, &ray);
                    let got = bvh.intersect(&ray);
                    assert_eq!(
                        got.map(|h| (h.triangle as usize, h.t)),
                        brute,
                        "scale {scale}, {quality:?}, ray {ray:?}"
                    );
                    assert_eq!(bvh.occluded(&ray), brute.is_some(), "ray {ray:?}");
                }
            }
        }
    }

    /// Directions with negative zero components (common from cross products) still hit.
    #[test]
    fn negative_zero_direction_components_hit() {
        let mut rng = Rng::new(3, 3);
        let tris = random_triangles(500, &mut rng);
        let bvh = Bvh::build(&tris, BvhQuality::Medium);
        for t in &tris {
            let target = (t[0] + t[1] + t[2]) / 3.0;
            for (dir, offset) in [
                (Vec3::new(1.0, -0.0, -0.0), Vec3::new(-20.0, 0.0, 0.0)),
                (Vec3::new(-0.0, -1.0, 0.0), Vec3::new(0.0, 20.0, 0.0)),
                (Vec3::new(-0.0, -0.0, 1.0), Vec3::new(0.0, 0.0, -20.0)),
            ] {
                let ray = Ray::new(target + offset, dir, f32::INFINITY);
                let pre = RayPrecomp::new(ray.origin, ray.dir);
                let brute = tris
                    .iter()
                    .filter_map(|t| intersect_triangle(&pre, t[0], t[1], t[2], f32::INFINITY))
                    .map(|h| h.t)
                    .fold(f32::INFINITY, f32::min);
                assert_eq!(
                    bvh.intersect(&ray).map_or(f32::INFINITY, |h| h.t),
                    brute,
                    "{dir}"
                );
            }
        }
    }

    /// A closed room (each wall 16 x 16 quads, axis-aligned, as the Embree cross-check's):
    /// PLOC merges pieces of different walls; the default build must not (node visits per
    /// camera ray, which do not depend on timing: PLOC Medium needs about 45, SAH about 6).
    #[test]
    fn closed_room_tree_separates_the_walls() {
        let n = 16;
        let tris = closed_room(n);
        let mut rng = Rng::new(2, 2);
        let rays: Vec<Ray> = (0..4000)
            .map(|_| {
                let o = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 1.6 - 0.8;
                Ray::new(o, warp::uniform_sphere(rng.uniform2()), f32::INFINITY)
            })
            .collect();
        let visits = |bvh: &Bvh| {
            rays.iter()
                .map(|r| bvh.closest_hit_work(r).0 as f64)
                .sum::<f64>()
                / rays.len() as f64
        };
        let ploc = visits(&Bvh::build_with(
            &tris,
            BuildMethod::Ploc(BvhQuality::Medium),
        ));
        let bvh = Bvh::build(&tris, BvhQuality::Medium);
        let default = visits(&bvh);
        assert!(
            default < 10.0 && default < 0.5 * ploc,
            "{default} vs PLOC {ploc}"
        );
        // The room is closed: no ray from inside escapes.
        assert!(rays.iter().all(|r| bvh.intersect(r).is_some()));
    }

    /// A direction for the node tests: `kind` 1 axis-aligned with signed zeros on the other
    /// axes (clamped reciprocals, unbounded far planes), 2 nearly parallel to a plane (one
    /// tiny component), else uniform on the sphere.
    fn node_test_direction(rng: &mut Rng, kind: usize) -> Vec3 {
        let mut d = warp::uniform_sphere(rng.uniform2());
        match kind {
            1 => {
                let axis = rng.below(3) as usize;
                let signed_zero = |rng: &mut Rng| if rng.uniform() < 0.5 { 0.0 } else { -0.0 };
                d = Vec3::new(signed_zero(rng), signed_zero(rng), signed_zero(rng));
                d[axis] = if rng.uniform() < 0.5 { 1.0 } else { -1.0 };
            }
            2 => d[rng.below(3) as usize] = [1e-30, -1e-20, 3e-9][rng.below(3) as usize],
            _ => {}
        }
        d
    }

    /// The triangles below child `c` of node `i`.
    fn subtree_triangles(bvh: &Bvh, i: usize, c: usize, out: &mut Vec<[Vec3; 3]>) {
        let node = &bvh.nodes[i];
        let meta = node.child_meta[c];
        if node.imask & (1 << c) != 0 {
            let rank = (node.imask as u32 & ((1u32 << c) - 1)).count_ones();
            let child = (node.child_base_idx + rank) as usize;
            for cc in 0..8 {
                subtree_triangles(bvh, child, cc, out);
            }
        } else if meta != 0 {
            let first = node.primitive_base_idx + (meta & 0x1f) as u32;
            for slot in first..first + (meta >> 5).count_ones() {
                out.push(bvh.blocks[slot as usize / 4].triangle(slot as usize % 4));
            }
        }
    }

    /// Every child box of every node is exactly the bounds of the triangles below it (so
    /// tighter than obvhs's quantised box, and never smaller than the triangles), and empty
    /// slots hold the empty box.
    #[test]
    fn wide_node_boxes_are_exact_bounds() {
        let mut rng = Rng::new(3, 4);
        for n in [1usize, 7, 300, 5000] {
            let tris = random_triangles(n, &mut rng);
            for method in [
                BuildMethod::Ploc(BvhQuality::Medium),
                BuildMethod::Sah { reinsertion: 0.0 },
                BuildMethod::Binned,
            ] {
                let bvh = Bvh::build_with(&tris, method);
                let mut below = Vec::new();
                for i in 0..bvh.nodes.len() {
                    for c in 0..8 {
                        below.clear();
                        subtree_triangles(&bvh, i, c, &mut below);
                        let (mut lo, mut hi) =
                            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
                        for p in below.iter().flatten() {
                            (lo, hi) = (lo.min(*p), hi.max(*p));
                        }
                        assert_eq!(below.is_empty(), bvh.nodes[i].child_meta[c] == 0);
                        for axis in 0..3 {
                            assert_eq!(bvh.nodes[i].planes[2 * axis][c], lo[axis]);
                            assert_eq!(bvh.nodes[i].planes[2 * axis + 1][c], hi[axis]);
                        }
                    }
                }
            }
        }
    }

    /// The f32 node test never culls a box that the ray overlaps in [0, t_max] by an f64 slab
    /// test, on every child of every node of trees at scales 1e-4, 1 and 1e4, with rays aimed
    /// at box corners from a distance (grazing: the f32 origin misses or hits by rounding),
    /// rays starting on corners, axis-aligned and nearly axis-aligned rays (signed zeros,
    /// clamped reciprocals) and random rays; it must see many overlaps shorter than 1e-5 of
    /// their distance (within a few f32 roundings of a miss), else it would not test the bound.
    #[test]
    fn node_test_is_conservative() {
        let mut rng = Rng::new(17, 3);
        let (mut overlaps, mut tangent) = (0usize, 0usize);
        for scale in [1e-4f32, 1.0, 1e4] {
            let tris: Vec<[Vec3; 3]> = random_triangles(2000, &mut rng)
                .into_iter()
                .map(|t| t.map(|p| p * scale))
                .collect();
            let bvh = Bvh::build_with(&tris, BuildMethod::Sah { reinsertion: 0.0 });
            for k in 0..600 {
                // A corner of a random child box.
                let node = &bvh.nodes[rng.below(bvh.nodes.len() as u32) as usize];
                let c = loop {
                    let c = rng.below(8) as usize;
                    if node.child_meta[c] != 0 {
                        break c;
                    }
                };
                let corner = Vec3::new(
                    node.planes[rng.below(2) as usize][c],
                    node.planes[2 + rng.below(2) as usize][c],
                    node.planes[4 + rng.below(2) as usize][c],
                );
                let d = node_test_direction(&mut rng, k % 5);
                let o = match k % 3 {
                    0 => corner - d * ((0.5 + 2.0 * rng.uniform()) * scale),
                    1 => corner,
                    _ => {
                        (Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 12.0 - Vec3::ONE)
                            * scale
                    }
                };
                let t_max = if k % 4 == 0 {
                    rng.uniform() * 3.0 * scale
                } else {
                    f32::INFINITY
                };
                let q = QueryRay::new(&Ray::new(o, d, t_max));
                let (o64, d64) = (o.as_dvec3(), d.as_dvec3());
                for node in &bvh.nodes {
                    let boxes = child_hits(node, &q.node, t_max);
                    for c in (0..8).filter(|&c| node.child_meta[c] != 0) {
                        let (mut enter, mut exit) = (0.0f64, t_max as f64);
                        for axis in 0..3 {
                            let lo = node.planes[2 * axis][c] as f64;
                            let hi = node.planes[2 * axis + 1][c] as f64;
                            if d64[axis] == 0.0 {
                                if o64[axis] < lo || o64[axis] > hi {
                                    exit = f64::NEG_INFINITY;
                                }
                                continue;
                            }
                            let (t0, t1) =
                                ((lo - o64[axis]) / d64[axis], (hi - o64[axis]) / d64[axis]);
                            enter = enter.max(t0.min(t1));
                            exit = exit.min(t0.max(t1));
                        }
                        if enter <= exit {
                            overlaps += 1;
                            tangent += (exit - enter <= 1e-5 * exit.abs()) as usize;
                            assert!(
                                boxes & (1 << c) != 0,
                                "culled: {o:?} {d:?} {t_max} {enter} {exit}"
                            );
                        }
                    }
                }
            }
        }
        assert!(overlaps > 10_000 && tangent > 500, "{overlaps} {tangent}");
    }

    /// The AVX2 node test answers exactly what the baseline one answers (the same boxes and
    /// the same traversal mask) on every node of several trees, for rays in every octant,
    /// axis-aligned ones with signed zeros (clamped reciprocals, unbounded far planes),
    /// ones nearly parallel to a plane (one tiny component), rays starting inside boxes, and
    /// finite and infinite t_max.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_node_test_matches_baseline() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            eprintln!("no AVX2 on this CPU: nothing to compare");
            return;
        }
        // SAFETY: AVX2 detected above.
        let avx2 = unsafe { Avx2::new_unchecked() };
        let mut rng = Rng::new(11, 7);
        let mut compared = 0usize;
        let mut hit_any = 0usize;
        for scale in [1e-4f32, 1.0, 1e4] {
            let tris: Vec<[Vec3; 3]> = random_triangles(3000, &mut rng)
                .into_iter()
                .map(|t| t.map(|p| p * scale))
                .collect();
            for method in [
                BuildMethod::Ploc(BvhQuality::Fast),
                BuildMethod::Sah { reinsertion: 0.0 },
                BuildMethod::Binned,
            ] {
                let bvh = Bvh::build_with(&tris, method);
                for i in 0..400 {
                    let o = (Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 12.0
                        - Vec3::ONE)
                        * scale;
                    let d = node_test_direction(&mut rng, i % 4);
                    let t_max = if i % 3 == 0 {
                        f32::INFINITY
                    } else {
                        rng.uniform() * 8.0 * scale
                    };
                    let q = QueryRay::new(&Ray::new(o, d, t_max));
                    for node in &bvh.nodes {
                        let base = Baseline.test(node, &q, t_max);
                        assert_eq!(avx2.test(node, &q, t_max), base, "ray {o:?} {d:?} {t_max}");
                        compared += 1;
                        hit_any += (base.0 != 0) as usize;
                    }
                }
            }
        }
        assert!(
            compared > 100_000 && hit_any > 10_000,
            "{compared} {hit_any}"
        );
    }

    #[test]
    fn empty_bvh_misses() {
        let bvh = Bvh::build(&[], BvhQuality::Medium);
        let ray = Ray::new(Vec3::ZERO, Vec3::X, f32::INFINITY);
        assert!(bvh.intersect(&ray).is_none());
        assert!(!bvh.occluded(&ray));
    }
}
