//! Directional parallel collapse of a cubical complex (Noël's thesis, "000" in
//! `docs/references.md`, §5.2.4, Algorithm 2, after Chaussard and Couprie 2009), the parameter-free curvilinear constraint of Algorithm 3 (§6.2.3), and the
//! piercing of surface parts (§6.2.4).
//!
//! # Directions
//!
//! A free pair (f, g) has g = f ∩ (f + c e_t) for one axis t and c = ±1 (Dir = t, Orient = 1 if
//! c = +1). We name the directions by the side of f on which the free face lies: "X−" is
//! c = −1 (g is the lower face of f along x, Orient = 0), "X+" is c = +1. Algorithm 2 loops
//! t = 1..n, s = 0..1, d = n..1, so one iteration runs 18 sub-steps in the order X−, X+, Y−,
//! Y+, Z−, Z+, and within each direction the cofaces of dimension 3 (cube, square), then 2
//! (square, edge: both square orientations at once), then 1 (edge, point).
//!
//! # One iteration (Algorithm 2, lines 2-8)
//!
//! L is the closure of Border(X), the set of faces of the free pairs (f, g) of X with g ∉ W at
//! the start of the iteration. A sub-step takes every pair (f, g) that is free *now*, has the
//! sub-step's direction, orientation and dimension, g ∉ W, and f ∈ L (then g ∈ L too, L being
//! closed), and removes them all. Two such pairs have distinct cofaces, so by Corollary 5.13 the
//! removal is a collapse whatever the order. Without the restriction to L a single sub-step
//! would peel a whole row of cubes; with it one iteration removes one layer, so the death date
//! of a cube equals its L1 distance to the complement (tested below): the clock of the collapse
//! is the 6-distance, which is why the constraint uses the L1 maps. `thinning_oracle.rs` is the
//! same algorithm written literally (a full rescan per sub-step); the tests check that this
//! implementation equals it after every sub-step.
//!
//! # Bit-parallel layout
//!
//! The collapse keeps the complex as 8 bit planes (one per cell kind) over *bricks* of 4x4x4
//! lattice vertices, one 64-bit word per brick and plane: bit x + 4y + 16z of a brick is the
//! vertex at offset (x, y, z). A free-pair test is pure bit logic on the cell's cofaces, which
//! sit at the same vertex or one step back along an axis; "one step back" is a shift of the
//! brick word plus the bits coming from the neighbouring brick. So one word operation tests a
//! cell kind at 64 vertices. Cubes (rather than rows) keep the work proportional to the moving
//! border: a layer of the collapse crosses a brick in 4 iterations along any axis, where a
//! 64-vertex row would stay busy for 64 iterations under a front moving along it.
//!
//! PassCost per iteration: only bricks near a change can hold a free face. A cell's freeness depends on
//! its cofaces, so when cells of brick b are removed only the faces of removed cells change, and
//! those lie in b or its +x, +y, +z neighbours (the set A). A face free at the start of an
//! iteration is always removed or loses its coface during it (its coface is in L, so its sub-step
//! takes it unless the coface went first), so no free face lies outside A. Each iteration therefore
//! computes, on A only: births, the free faces, the cofaces of free pairs, their closure L (which
//! reaches the bricks one step forward), and runs the 18 sub-steps on the bricks where L is not
//! empty. Each sub-step first computes the pairs of every brick from the unchanged planes, then
//! removes them; both passes write only the brick they process, so they run in parallel over bricks
//! with results identical to the sequential order (tested): during [`Thinning::run`] on the calling
//! thread and one helper thread, started by the run's first pass worth sharing and kept to the
//! run's end (`PassHelper`: a rayon fork/join per pass cost more than it saved, the sleeping worker's
//! wake-up; a run that resumes a collapse with few changed bricks has no helper), elsewhere over
//! the rayon pool. Scratch planes are atomics with relaxed loads and stores: plain moves on x86-64,
//! and no `unsafe` in the passes (the only `unsafe` is the hand-over of a pass to the helper, see
//! `PassHelper`).
//!
//! # Dates and the constraint (Definitions 6.1-6.3, Algorithm 3)
//!
//! Iterations are numbered from 1. Death(f) = the iteration that removes f. Birth(e) of an edge
//! = the first l such that after l iterations e is a facet (no incident square) or has been
//! removed; it is found at the start of iteration l + 1 among the edges of A (or at the edge's
//! removal). The static W of Algorithm 3 is defined with the lifespans of the unconstrained
//! collapse; like both reference implementations we apply the constraint lazily instead: at
//! the start of iteration l, an edge born and still present is added to W (with its two
//! points, so W stays a complex) when removing it now would give it a lifespan l − Birth(e)
//! greater than
//!
//!   DC1cc(e) + Birth(e) − D1cc(e),
//!
//! which is the printed condition of Algorithm 3, line 1 (Lifespan > DC + Birth − D, where
//! Birth − D estimates the lifespan of the squares around e). The first such l is known at the
//! edge's birth, max(Birth + 1, 2 Birth + DC − D + 1), so each born edge waits in a bucket for
//! that iteration. D1cc and DC1cc of an edge are the maxima of the voxel maps over the (up to
//! four) voxels containing it: the printed definition "max over g ∈ δ* ∩ F_n^n" is garbled; we
//! read δ* as the proper star of f, the n-faces that contain f, which is what "in the same
//! way" for Ω and DC and both reference codes do. W only grows, so a birth date never changes
//! and a constrained edge is never removed.
//!
//! # Piercing (§6.2.4)
//!
//! What the constrained collapse leaves may still hold surfaces; `piercing.rs` removes one
//! square per surface part and the collapse resumes, until only points and edges are left
//! ([`Thinning::curvilinear`]).

mod pass_helper;
mod piercing;

use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

use super::complex::{Complex, SPAN_BIT};
use super::grid::VoxelSet;
use pass_helper::{claim, PassHelper, ShutDownOnDrop};

/// Date of a cell that is never born or never dies.
pub const NEVER: u32 = u32::MAX;

/// The constraint set of the collapse.
#[derive(Clone, Copy, Debug)]
pub enum Constraint<'a> {
    /// W = ∅: the ultimate (minimal) collapse.
    None,
    /// Algorithm 3 with per-voxel L1 distance and L1 decenterness maps (voxel index as in
    /// [`super::VoxelGrid`]). The distance must be measured with the outside of the grid solid,
    /// so that it matches the collapse's clock (grid-boundary faces are free).
    Lifespan {
        distance: &'a [u32],
        decenterness: &'a [u32],
    },
}

/// What one sub-step did (for observers).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SubStep {
    pub iteration: u32,
    pub axis: u8,
    pub positive: bool,
    /// Dimension of the cofaces removed.
    pub dim: u8,
    pub removed_pairs: usize,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct ThinningStats {
    pub iterations: u32,
    pub pairs_removed: u64,
    pub constrained_edges: u64,
    pub pierced: u64,
    pub forced_pierces: u64,
    pub pierce_rounds: u32,
}

/// Observer of the sub-steps (tests): the complex after each one.
pub type Observer<'o, 'f> = Option<&'o mut (dyn FnMut(&Complex, SubStep) + 'f)>;

/// Bits of a brick word with x = 0, x = 3, y = 0, y = 3 (bit = x + 4y + 16z).
const X0: u64 = 0x1111_1111_1111_1111;
const X3: u64 = X0 << 3;
const Y0: u64 = 0x000F_000F_000F_000F;
const Y3: u64 = Y0 << 12;

/// Span of a square from its two axes, and of an edge from its axis.
const EDGE: [usize; 3] = [1, 2, 4];
const CUBE_SPAN: usize = 7;

/// 8 planes per brick (index 8 brick + span), written by at most one task per brick at a time.
struct Planes(Vec<AtomicU64>);

impl Planes {
    fn new(bricks: usize) -> Planes {
        Planes((0..8 * bricks).map(|_| AtomicU64::new(0)).collect())
    }
    #[inline(always)]
    fn get(&self, b: usize, span: usize) -> u64 {
        self.0[8 * b + span].load(Relaxed)
    }
    #[inline(always)]
    fn set(&self, b: usize, span: usize, v: u64) {
        self.0[8 * b + span].store(v, Relaxed)
    }
    #[inline(always)]
    fn or(&self, b: usize, span: usize, v: u64) {
        self.set(b, span, self.get(b, span) | v)
    }
    #[inline(always)]
    fn clear(&self, b: usize, span: usize, v: u64) {
        self.set(b, span, self.get(b, span) & !v)
    }
    fn any(&self, b: usize) -> bool {
        (0..8).any(|s| self.get(b, s) != 0)
    }
}

/// Brick geometry: bricks of 4x4x4 internal vertices (the [`Complex`] layout, coordinates
/// 0..size), with one layer of always-empty bricks around so that neighbour reads need no test.
#[derive(Clone, Copy, Debug)]
struct Layout {
    /// Internal vertices per axis (voxel dims + 2).
    size: [usize; 3],
    /// Bricks per axis, padding included.
    nb: [usize; 3],
    /// Index step of one brick along each axis.
    step: [usize; 3],
}

impl Layout {
    fn new(dims: [usize; 3]) -> Layout {
        let size = dims.map(|d| d + 2);
        let nb = size.map(|s| s.div_ceil(4) + 2);
        Layout {
            size,
            nb,
            step: [1, nb[0], nb[0] * nb[1]],
        }
    }

    fn bricks(&self) -> usize {
        self.nb[0] * self.nb[1] * self.nb[2]
    }

    /// Brick and bit of internal vertex coordinates.
    #[inline]
    fn locate(&self, c: [usize; 3]) -> (usize, u32) {
        let b = (0..3).map(|a| ((c[a] >> 2) + 1) * self.step[a]).sum();
        (b, (c[0] & 3 | (c[1] & 3) << 2 | (c[2] & 3) << 4) as u32)
    }

    /// Internal vertex coordinates of a bit of a brick (possibly past `size`).
    #[inline]
    fn coords(&self, b: usize, bit: u32) -> [usize; 3] {
        let bc = [
            b % self.nb[0],
            (b / self.nb[0]) % self.nb[1],
            b / self.step[2],
        ];
        let off = [bit & 3, (bit >> 2) & 3, bit >> 4].map(|o| o as usize);
        [0, 1, 2].map(|a| (bc[a] - 1) * 4 + off[a])
    }

    /// Whether a brick holds vertices (is not padding).
    #[inline]
    fn real(&self, b: usize) -> bool {
        let bc = [
            b % self.nb[0],
            (b / self.nb[0]) % self.nb[1],
            b / self.step[2],
        ];
        (0..3).all(|a| bc[a] >= 1 && bc[a] + 1 < self.nb[a])
    }
}

/// The word of plane `span` at v − e_axis, for the 64 vertices v of brick b.
#[inline(always)]
fn back(p: &Planes, b: usize, span: usize, axis: usize, step: &[usize; 3]) -> u64 {
    match axis {
        0 => ((p.get(b, span) << 1) & !X0) | ((p.get(b - 1, span) >> 3) & X0),
        1 => ((p.get(b, span) << 4) & !Y0) | ((p.get(b - step[1], span) >> 12) & Y0),
        _ => (p.get(b, span) << 16) | (p.get(b - step[2], span) >> 48),
    }
}

/// The word of plane `span` at v + e_axis, for the 64 vertices v of brick b.
#[inline(always)]
fn fwd(p: &Planes, b: usize, span: usize, axis: usize, step: &[usize; 3]) -> u64 {
    match axis {
        0 => ((p.get(b, span) >> 1) & !X3) | ((p.get(b + 1, span) << 3) & X3),
        1 => ((p.get(b, span) >> 4) & !Y3) | ((p.get(b + step[1], span) << 12) & Y3),
        _ => (p.get(b, span) >> 16) | (p.get(b + step[2], span) << 48),
    }
}

/// Iterates the set bits of a word.
#[inline]
fn bits(mut w: u64) -> impl Iterator<Item = u32> {
    std::iter::from_fn(move || {
        (w != 0).then(|| {
            let b = w.trailing_zeros();
            w &= w - 1;
            b
        })
    })
}

/// A pair kind of one sub-step: free face of span `g`, coface of span `f` at the same vertex
/// (negative orientation) or one step back along the axis (positive), the other cofaces of g.
#[derive(Clone, Copy, Debug)]
struct PairKind {
    g: usize,
    f: usize,
    /// Other cofaces of g: (span, axis of the step back or 3 = same vertex).
    others: [(usize, usize); 5],
    n_others: usize,
}

/// Cofaces of a cell of each span: (span, axis of the step back, or 3 = same vertex), and
/// how many there are.
const COFACES: [([(usize, usize); 6], usize); 8] = {
    let mut table = [([(0, 0); 6], 0); 8];
    let mut span = 0;
    while span < 8 {
        let mut n = 0;
        let mut b = 0;
        while b < 3 {
            if span & (1 << b) == 0 {
                table[span].0[n] = (span | 1 << b, 3);
                table[span].0[n + 1] = (span | 1 << b, b);
                n += 2;
            }
            b += 1;
        }
        table[span].1 = n;
        span += 1;
    }
    table
};

#[inline(always)]
fn cofaces(span: usize) -> &'static [(usize, usize)] {
    &COFACES[span].0[..COFACES[span].1]
}

/// The cells of span `G` of brick b that are free faces: present, not in W, exactly one
/// coface present. Generic over the span so that the coface loop unrolls to straight word
/// logic (this and the two passes below are most of an iteration's work).
#[inline(always)]
fn free_faces<const G: usize>(
    cells: &Planes,
    inhibit: &Planes,
    b: usize,
    step: &[usize; 3],
) -> u64 {
    let present = cells.get(b, G) & !inhibit.get(b, G);
    if present == 0 {
        return 0;
    }
    let (mut one, mut two) = (0u64, 0u64);
    for &(up, at) in cofaces(G) {
        let c = if at == 3 {
            cells.get(b, up)
        } else {
            back(cells, b, up, at, step)
        };
        two |= one & c;
        one |= c;
    }
    present & one & !two
}

/// The present cells of span `F` of brick b that have a free face (the cofaces of free pairs):
/// the face without axis a lies at the same vertex or one step forward along a.
#[inline(always)]
fn cofaces_of_free<const F: usize>(
    cells: &Planes,
    free: &Planes,
    b: usize,
    step: &[usize; 3],
) -> u64 {
    let present = cells.get(b, F);
    if present == 0 {
        return 0;
    }
    let mut has_free_face = 0;
    for a in 0..3 {
        if F & (1 << a) != 0 {
            let g = F & !(1 << a);
            has_free_face |= free.get(b, g) | fwd(free, b, g, a, step);
        }
    }
    present & has_free_face
}

/// Plane `SPAN` of brick b in the closure of the border: its own bits and the faces of the
/// cofaces already in it.
#[inline(always)]
fn closed_up<const SPAN: usize>(border: &Planes, b: usize, step: &[usize; 3]) -> u64 {
    let mut w = border.get(b, SPAN);
    for &(up, at) in cofaces(SPAN) {
        w |= if at == 3 {
            border.get(b, up)
        } else {
            back(border, b, up, at, step)
        };
    }
    w
}

/// The pair kinds of the 18 sub-steps, indexed by 3 * (2 * axis + orientation) + (3 - dim),
/// at most two per sub-step (dim 2: both square orientations containing the axis), and how
/// many each sub-step has. A constant, so that the pair test of each kind compiles to straight
/// word logic ([`Thinning::remove_kind`]).
const PAIR_KINDS: ([[PairKind; 2]; 18], [usize; 18]) = {
    let empty = PairKind {
        g: 0,
        f: 0,
        others: [(0, 0); 5],
        n_others: 0,
    };
    let mut table = [[empty; 2]; 18];
    let mut count = [0usize; 18];
    let mut axis = 0;
    while axis < 3 {
        let mut orient = 0;
        while orient < 2 {
            let mut d = 0;
            while d < 3 {
                let dim = 3 - d as u32;
                let s = 3 * (2 * axis + orient) + d;
                let mut g = 0usize;
                while g < 8 {
                    if g.count_ones() == dim - 1 && g & (1 << axis) == 0 {
                        let f = g | 1 << axis;
                        let f_at = if orient == 1 { axis } else { 3 };
                        let (list, n) = COFACES[g];
                        let mut others = [(0, 0); 5];
                        let mut n_others = 0;
                        let mut i = 0;
                        while i < n {
                            if !(list[i].0 == f && list[i].1 == f_at) {
                                others[n_others] = list[i];
                                n_others += 1;
                            }
                            i += 1;
                        }
                        table[s][count[s]] = PairKind {
                            g,
                            f,
                            others,
                            n_others,
                        };
                        count[s] += 1;
                    }
                    g += 1;
                }
                d += 1;
            }
            orient += 1;
        }
        axis += 1;
    }
    (table, count)
};

/// Rough cost of one brick in a pass, in units of a sub-step's pair test (a few tens of
/// instructions): the free-face, birth, border and closure passes read about four times as
/// many words per brick.
#[derive(Clone, Copy, Debug)]
enum PassCost {
    Light = 1,
    Heavy = 4,
}

/// Brick visits (in [`PassCost`] units) below which a pass is cheaper on the calling thread than
/// split over the pool: a split costs microseconds (waking a sleeping worker more), a light
/// brick visit some 10 ns. The long tail of the collapse (hundreds of iterations of a few
/// hundred bricks after the piercing) then runs without any task overhead, while the first
/// iterations (thousands of bricks per pass) still split. Measured on the door and Sponza.
const MIN_PARALLEL_WORK: usize = 2048;

/// The same threshold for a pass shared with the helper of a run ([`PassHelper`]), which costs
/// some hundreds of nanoseconds (cache lines crossing between the cores) rather than a
/// wake-up. 256, 1024 and 2048 were tried on the door at 234 (on a loaded machine): 1024
/// was as fast as 256 and no slower than 2048.
const MIN_SHARED_WORK: usize = 1024;

/// Changed bricks (the bricks to examine are their dilation) at the start of a [`Thinning::run`]
/// that resumes a collapse below which the run keeps its passes on the calling thread instead of
/// sharing them with a helper ([`PassHelper`]). Measured on the door (BENCHMARKS.md): the
/// re-thinning after a pierce (a run that starts with the one or two bricks of the pierced squares,
/// then some hundred bricks per pass for hundreds of iterations) was 10-20 % faster on 2 threads
/// without the helper at 118 and 234. A first run keeps the helper whatever its size: at 118 (at
/// most 5.8k bricks) the thinning beside the Euclidean distance was slower without it (0.0153
/// against 0.0122 s, medians of five), at 234 (37k bricks) the helper saved some 10 % when it had
/// the second core.
const MIN_HELPER_BRICKS: usize = 16384;

/// How the per-brick passes of a collapse are split over the rayon pool.
#[derive(Clone, Copy, Debug)]
enum Split {
    /// On the calling thread.
    Sequential,
    /// Inside [`Thinning::run`]: passes of at least `min_shared_work` shared with the run's
    /// helper thread ([`PassHelper`]), each thread claiming chunks from one end of the list. Outside
    /// a run (single iterations, the piercing's own passes): one contiguous part of the list
    /// per pool thread, if the pass holds at least `min_parallel_work`. Either way a part of
    /// a brick list sorted by index is a slab of the grid, so each thread mostly reads the
    /// bricks it wrote in the previous pass (its cache) instead of pulling cache lines from
    /// the other core.
    PerThread,
    /// Fixed chunks of this many bricks, however little work the pass holds (tests: splits
    /// every list on small grids).
    Chunks(usize),
}

/// A born edge waiting for the iteration at which the constraint catches it.
#[derive(Clone, Copy, Debug)]
struct Waiting {
    brick: u32,
    bit: u8,
    axis: u8,
}

/// The state of a directional collapse: the complex (as brick planes), W, dates.
pub struct Thinning<'a> {
    dims: [usize; 3],
    layout: Layout,
    constraint: Constraint<'a>,
    cells: Planes,
    /// W: points and edges (planes 0, 1, 2, 4).
    inhibit: Planes,
    /// Born edges (planes 1, 2, 4).
    born: Planes,
    /// Scratch per iteration: free faces, L, pair masks (planes 0 and 1 = the kinds).
    free: Planes,
    border: Planes,
    masks: Planes,
    /// Bricks whose cells changed since the last iteration started.
    changed: Vec<u32>,
    /// Scratch bitset over the bricks for [`Thinning::dilate`] (all zero between calls), and
    /// the bitset of the real (non-padding) bricks.
    listed: Vec<u64>,
    real: Vec<u64>,
    /// Per brick: the `epoch` that last listed it in `changed`.
    changed_in: Vec<u32>,
    /// Number of times `changed` was taken (by an iteration) plus one.
    epoch: u32,
    iteration: u32,
    /// Born edges by the iteration at which they become constrained.
    waiting: Vec<Vec<Waiting>>,
    /// Birth date per edge (3 per internal vertex, by axis) and death date per cell (8 per
    /// vertex, by span), if recorded (complex layout).
    birth: Option<Vec<u32>>,
    death: Option<Vec<u32>>,
    /// How the per-brick passes are split over the pool.
    split: Split,
    /// PassCost (brick visits weighted by [`PassCost`]) below which a pass runs on the calling
    /// thread.
    min_parallel_work: usize,
    /// The helper of [`Thinning::run`] (with [`Split::PerThread`]), whether it is serving
    /// (during a run), and the work below which a pass is not shared with it.
    helper: Arc<PassHelper>,
    serving: bool,
    min_shared_work: usize,
    /// Changed bricks at the start of a resumed run below which the run has no helper
    /// ([`MIN_HELPER_BRICKS`]; the bricks to examine are their dilation).
    min_helper_bricks: usize,
    /// Smallest chunk a thread claims in a shared pass (0: by the pass's [`PassCost`]).
    min_claim: u32,
    /// Chunks the helper ran (tests: the helper did take part).
    helper_chunks: AtomicU64,
    pub stats: ThinningStats,
}

impl<'a> Thinning<'a> {
    /// Prepares the collapse of `complex`. `parallel` runs the per-brick passes on the current
    /// rayon pool (if it has more than one thread); `record_dates` keeps a birth date per edge
    /// and a death date per cell.
    pub fn new(
        complex: Complex,
        constraint: Constraint<'a>,
        parallel: bool,
        record_dates: bool,
    ) -> Thinning<'a> {
        let mut t = Thinning::empty(complex.dims(), constraint, parallel, record_dates);
        let size = t.layout.size;
        for (i, &byte) in complex.bytes().iter().enumerate() {
            if byte == 0 {
                continue;
            }
            let c = [
                i % size[0],
                (i / size[0]) % size[1],
                i / (size[0] * size[1]),
            ];
            let (b, bit) = t.layout.locate(c);
            for span in 0..8 {
                if byte & SPAN_BIT[span] != 0 {
                    t.cells.or(b, span, 1 << bit);
                }
            }
        }
        t.start();
        t
    }

    /// The collapse of the empty-space complex of a voxel grid (the closure of the closed
    /// cubes of the voxels not in `occupied`), built directly in brick planes.
    pub fn from_occupied(
        dims: [usize; 3],
        occupied: &VoxelSet,
        constraint: Constraint<'a>,
        parallel: bool,
        record_dates: bool,
    ) -> Thinning<'a> {
        let t = Thinning::empty(dims, constraint, parallel, record_dates);
        let (layout, step) = (t.layout, t.layout.step);
        let real: Vec<u32> = (0..layout.bricks() as u32)
            .filter(|&b| layout.real(b as usize))
            .collect();
        // Cubes: voxel v is the cube of internal vertex v + 1.
        t.for_each(&real, PassCost::Heavy, |b| {
            let mut word = 0u64;
            let base = layout.coords(b, 0);
            let inside = |a: usize, v: usize| v >= 1 && v <= dims[a];
            // The brick's four vertices along x that hold a voxel (vx - 1), as a bit mask; each
            // row of the brick then takes those voxels' four occupancy bits in one read instead
            // of four lookups.
            let xs = (0..4)
                .filter(|&x| inside(0, base[0] + x))
                .fold(0, |m, x| m | 1 << x);
            if xs == 0 {
                t.cells.set(b, CUBE_SPAN, 0);
                return;
            }
            for z in 0..4 {
                let vz = base[2] + z;
                if !inside(2, vz) {
                    continue;
                }
                for y in 0..4 {
                    let vy = base[1] + y;
                    if !inside(1, vy) {
                        continue;
                    }
                    let row = dims[0] * ((vy - 1) + dims[1] * (vz - 1));
                    // Bit x: voxel row + base[0] + x - 1 (the first brick's x = 0 has none).
                    let occupied_bits = if base[0] == 0 {
                        occupied.bits(row, 3) << 1
                    } else {
                        occupied.bits(row + base[0] - 1, 4)
                    };
                    word |= (!occupied_bits & xs) << (4 * y + 16 * z);
                }
            }
            t.cells.set(b, CUBE_SPAN, word);
        });
        // Closure, one dimension at a time: a cell is present if a coface is.
        for dim in [2u32, 1, 0] {
            t.for_each(&real, PassCost::Heavy, |b| {
                for span in (0..8usize).filter(|s| s.count_ones() == dim) {
                    let mut w = 0;
                    for &(up, at) in cofaces(span) {
                        w |= if at == 3 {
                            t.cells.get(b, up)
                        } else {
                            back(&t.cells, b, up, at, &step)
                        };
                    }
                    t.cells.set(b, span, w);
                }
            });
        }
        let mut t = t;
        t.start();
        t
    }

    fn empty(
        dims: [usize; 3],
        constraint: Constraint<'a>,
        parallel: bool,
        record_dates: bool,
    ) -> Thinning<'a> {
        let layout = Layout::new(dims);
        let n = layout.bricks();
        let vertices = layout.size[0] * layout.size[1] * layout.size[2];
        assert!(n < 1 << 31, "complex too large");
        Thinning {
            dims,
            layout,
            constraint,
            cells: Planes::new(n),
            inhibit: Planes::new(n),
            born: Planes::new(n),
            free: Planes::new(n),
            border: Planes::new(n),
            masks: Planes::new(n),
            changed: Vec::new(),
            listed: vec![0; n.div_ceil(64)],
            real: {
                let mut real = vec![0u64; n.div_ceil(64)];
                for b in (0..n).filter(|&b| layout.real(b)) {
                    real[b >> 6] |= 1 << (b & 63);
                }
                real
            },
            changed_in: vec![0; n],
            epoch: 1,
            iteration: 0,
            waiting: Vec::new(),
            birth: record_dates.then(|| vec![NEVER; 3 * vertices]),
            death: record_dates.then(|| vec![NEVER; 8 * vertices]),
            // One worker: the sequential path (no task overhead).
            split: if parallel && rayon::current_num_threads() > 1 {
                Split::PerThread
            } else {
                Split::Sequential
            },
            min_parallel_work: MIN_PARALLEL_WORK,
            helper: Arc::new(PassHelper::new()),
            serving: false,
            min_shared_work: MIN_SHARED_WORK,
            min_helper_bricks: MIN_HELPER_BRICKS,
            min_claim: 0,
            helper_chunks: AtomicU64::new(0),
            stats: ThinningStats::default(),
        }
    }

    /// After the cells are set: every brick is to be examined, edges without a square are
    /// born at 0.
    fn start(&mut self) {
        let layout = self.layout;
        self.changed = (0..layout.bricks() as u32)
            .filter(|&b| layout.real(b as usize) && self.cells.any(b as usize))
            .collect();
        let all = self.changed.clone();
        self.births(&all, 0, 1);
    }

    /// Sets the number of bricks per parallel task and splits every list longer than that,
    /// however little work it holds (tests use small chunks to exercise the parallel path on
    /// small grids); 0 = sequential.
    pub fn set_chunk_size(&mut self, chunk: usize) {
        self.split = if chunk == 0 {
            Split::Sequential
        } else {
            Split::Chunks(chunk)
        };
        self.min_parallel_work = 0;
    }

    /// Splits every pass of more than one brick into one part per pool thread (tests: the
    /// default split without its work threshold).
    #[cfg(test)]
    fn split_every_pass_per_thread(&mut self) {
        self.split = Split::PerThread;
        self.min_parallel_work = 0;
        self.min_shared_work = 0;
        self.min_helper_bricks = 0;
        self.min_claim = 1;
    }

    /// Whether a pass of `work` over `len` bricks is split into parallel tasks.
    #[inline]
    fn split(&self, len: usize, work: PassCost) -> bool {
        match self.split {
            Split::Sequential => false,
            Split::PerThread => len > 1 && len * work as usize >= self.min_parallel_work,
            Split::Chunks(c) => len > c,
        }
    }

    /// Bricks per task of a split pass over `len` bricks.
    fn chunk_for(&self, len: usize) -> usize {
        match self.split {
            Split::Chunks(c) => c,
            _ => len.div_ceil(rayon::current_num_threads()),
        }
    }

    /// Runs `f` on chunks of the list (each call appends the outputs of its bricks, in list
    /// order) and returns all outputs in list order: shared with the helper during a run (if
    /// worth it), split over the pool outside a run (if enabled and worth it), or on the
    /// calling thread.
    fn chunked<T: Send>(
        &self,
        list: &[u32],
        work: PassCost,
        f: impl Fn(&[u32], &mut Vec<T>) + Sync,
    ) -> Vec<T> {
        if self.serving {
            if list.len() > 1 && list.len() * work as usize >= self.min_shared_work {
                return self.shared_with_helper(list, work, &f);
            }
        } else if self.split(list.len(), work) {
            return list
                .par_chunks(self.chunk_for(list.len()))
                .map(|c| {
                    let mut out = Vec::with_capacity(c.len());
                    f(c, &mut out);
                    out
                })
                .collect::<Vec<Vec<T>>>()
                .into_iter()
                .flatten()
                .collect();
        }
        // One output per brick is what the filters and the span lists write at most (the
        // births up to three, rarely): reserving it saves the doubling reallocations of a
        // growing list, some 10k per collapse at the door's 118 (a few hundred instructions
        // each), most in the re-thinning's short passes.
        let mut out = Vec::with_capacity(list.len());
        f(list, &mut out);
        out
    }

    /// [`Thinning::chunked`] on the calling thread and the helper: the caller claims chunks
    /// from the front of the list, the helper from the back ([`claim`]).
    fn shared_with_helper<T: Send>(
        &self,
        list: &[u32],
        work: PassCost,
        f: &(impl Fn(&[u32], &mut Vec<T>) + Sync),
    ) -> Vec<T> {
        let min = match (self.min_claim, work) {
            (0, PassCost::Light) => 32,
            (0, PassCost::Heavy) => 8,
            (min, _) => min,
        };
        let range = AtomicU64::new((list.len() as u64) << 32);
        // The helper's outputs and where each of its chunks starts in them.
        let theirs: Mutex<(Vec<T>, Vec<usize>)> = Mutex::new((Vec::new(), Vec::new()));
        let helpers_part = || {
            let (mut out, mut starts) = (Vec::new(), Vec::new());
            while let Some((a, b)) = claim(&range, min, false) {
                starts.push(out.len());
                f(&list[a..b], &mut out);
            }
            self.helper_chunks.fetch_add(starts.len() as u64, Relaxed);
            *theirs.lock().unwrap() = (out, starts);
        };
        let mut mine = Vec::new();
        self.helper.start();
        self.helper.run_pair(&helpers_part, || {
            while let Some((a, b)) = claim(&range, min, true) {
                f(&list[a..b], &mut mine);
            }
        });
        // The helper claimed its chunks from the back: append them last claimed first.
        let (mut out, starts) = theirs.into_inner().unwrap();
        mine.reserve(out.len());
        for &start in starts.iter().rev() {
            mine.extend(out.drain(start..));
        }
        mine
    }

    /// Runs `f` on every brick of the list (see [`Thinning::chunked`]).
    fn for_each(&self, list: &[u32], work: PassCost, f: impl Fn(usize) + Sync) {
        self.chunked::<()>(list, work, |c, _| c.iter().for_each(|&b| f(b as usize)));
    }

    /// The bricks of the list for which `keep` holds, in list order.
    fn filter(
        &self,
        list: &[u32],
        work: PassCost,
        keep: impl Fn(usize) -> bool + Sync,
    ) -> Vec<u32> {
        self.chunked(list, work, |c, out| {
            out.extend(c.iter().copied().filter(|&b| keep(b as usize)))
        })
    }

    /// The real bricks of `list` shifted by each of `offsets`, without duplicates, in
    /// increasing order (memory order for the passes, and the slabs of [`Split::PerThread`]).
    /// Long lists go through a bitset over the bricks (a few kB, in cache), read back word by
    /// word, which sorts them for free ([`Thinning::dilate_dense`] when they are dense, else
    /// each shifted brick marked); short ones (the few changed bricks of an iteration late in
    /// the collapse) are sorted directly, so that a few bricks far apart do not cost a scan of
    /// the bitset between them.
    fn dilate(&mut self, list: &[u32], offsets: &[isize]) -> Vec<u32> {
        let is_real = |real: &[u64], c: usize| real[c >> 6] >> (c & 63) & 1 != 0;
        if list.len() * offsets.len() <= 256 {
            let mut out: Vec<u32> = list
                .iter()
                .flat_map(|&b| offsets.iter().map(move |&o| (b as isize + o) as u32))
                .filter(|&c| is_real(&self.real, c as usize))
                .collect();
            out.sort_unstable();
            out.dedup();
            return out;
        }
        if let Some(out) = self.dilate_dense(list, offsets) {
            return out;
        }
        let listed = &mut self.listed;
        let (mut lo, mut hi) = (usize::MAX, 0);
        for &b in list {
            for &o in offsets {
                let c = (b as isize + o) as usize;
                listed[c >> 6] |= 1 << (c & 63);
            }
            lo = lo.min(b as usize);
            hi = hi.max(b as usize);
        }
        let (min_o, max_o) = (offsets.iter().min().unwrap(), offsets.iter().max().unwrap());
        let (lo, hi) = (
            (lo as isize + min_o) as usize,
            (hi as isize + max_o) as usize,
        );
        let mut out = Vec::with_capacity(list.len() * 2);
        for w in lo >> 6..=hi >> 6 {
            let word = listed[w] & self.real[w];
            listed[w] = 0;
            out.extend(bits(word).map(|bit| (64 * w) as u32 + bit));
        }
        out
    }

    /// [`Thinning::dilate`] of a dense list (at least two bricks per bitset word of its range,
    /// as in the first iterations, where A is most of the grid; `None` otherwise): the list's
    /// own bits are marked once, and each output word is the union of the words of that
    /// bitset shifted by the offsets (one shift per word and offset), instead of a
    /// read-modify-write of the bitset per brick and offset, whose chains on one word stall
    /// on store forwarding. The list need not be sorted. At most 8 offsets.
    fn dilate_dense(&mut self, list: &[u32], offsets: &[isize]) -> Option<Vec<u32>> {
        if list.is_empty() {
            return None;
        }
        let (lo, hi) = list
            .iter()
            .fold((u32::MAX, 0), |(lo, hi), &b| (lo.min(b), hi.max(b)));
        let (lo_w, hi_w) = (lo as usize >> 6, hi as usize >> 6);
        if list.len() < 2 * (hi_w - lo_w + 1) {
            return None;
        }
        let listed = &mut self.listed;
        for &b in list {
            listed[b as usize >> 6] |= 1 << (b & 63);
        }
        // Output bit c is list bit c - o: for word w, bits 64 w - o + j (j < 64), i.e. bit
        // r + j of list word w + q with -o = 64 q + r.
        let mut shifts = [(0isize, 0u32); 8];
        for (s, &o) in shifts.iter_mut().zip(offsets) {
            *s = ((-o).div_euclid(64), (-o).rem_euclid(64) as u32);
        }
        let shifts = &shifts[..offsets.len()];
        let listed = &*listed;
        let word = |q: isize| {
            if q >= lo_w as isize && q <= hi_w as isize {
                listed[q as usize]
            } else {
                0
            }
        };
        let (min_o, max_o) = (offsets.iter().min().unwrap(), offsets.iter().max().unwrap());
        let out_lo = (lo as isize + min_o) as usize >> 6;
        let out_hi = (hi as isize + max_o) as usize >> 6;
        let mut out = Vec::with_capacity(list.len() * 2);
        for w in out_lo..=out_hi {
            let mut acc = 0u64;
            for &(q, r) in shifts {
                let q = w as isize + q;
                acc |= if r == 0 {
                    word(q)
                } else {
                    (word(q) >> r) | (word(q + 1) << (64 - r))
                };
            }
            out.extend(bits(acc & self.real[w]).map(|bit| (64 * w) as u32 + bit));
        }
        self.listed[lo_w..=hi_w].fill(0);
        Some(out)
    }

    /// The real bricks of `list` and of `list` shifted by `o`, without duplicates, in
    /// increasing order; `list` must be increasing (all brick lists are: see
    /// [`Thinning::dilate`]). A merge of the two sorted sequences: linear, and no scan of
    /// the brick bitset (the sub-steps' lists are often a few bricks spread over the grid);
    /// a dense list goes through [`Thinning::dilate_dense`].
    fn with_shifted(&mut self, list: &[u32], o: isize) -> Vec<u32> {
        debug_assert!(list.windows(2).all(|w| w[0] < w[1]));
        if let Some(out) = self.dilate_dense(list, &[0, o]) {
            return out;
        }
        let is_real = |c: u32| self.real[c as usize >> 6] >> (c & 63) & 1 != 0;
        let shifted = |i: usize| (list[i] as isize + o) as u32;
        let mut out = Vec::with_capacity(2 * list.len());
        let (mut i, mut j) = (0, 0);
        while i < list.len() || j < list.len() {
            let next = if j == list.len() || (i < list.len() && list[i] < shifted(j)) {
                i += 1;
                list[i - 1]
            } else {
                if i < list.len() && list[i] == shifted(j) {
                    i += 1;
                }
                j += 1;
                shifted(j - 1)
            };
            if is_real(next) {
                out.push(next);
            }
        }
        out
    }

    /// Lists bricks whose cells changed for the next iteration, once each (per `epoch`: the
    /// changes made since the last iteration took the list).
    fn note_changed(&mut self, bricks: &[u32]) {
        let m = self.epoch;
        for &b in bricks {
            if self.changed_in[b as usize] != m {
                self.changed_in[b as usize] = m;
                self.changed.push(b);
            }
        }
    }

    /// The complex (converted from the brick planes).
    pub fn complex(&self) -> Complex {
        let mut c = Complex::empty(self.dims);
        let size = self.layout.size;
        for b in 0..self.layout.bricks() {
            for span in 0..8u8 {
                for bit in bits(self.cells.get(b, span as usize)) {
                    let v = self.layout.coords(b, bit);
                    debug_assert!((0..3).all(|a| v[a] < size[a]));
                    c.add_cell(v[0] + size[0] * (v[1] + size[1] * v[2]), span);
                }
            }
        }
        c
    }

    pub fn into_complex(self) -> Complex {
        self.complex()
    }

    /// Completed iterations.
    pub fn iteration(&self) -> u32 {
        self.iteration
    }

    /// The constraint set W, one byte per vertex like [`Complex::bytes`].
    pub fn inhibited(&self) -> Vec<u8> {
        let size = self.layout.size;
        let mut out = vec![0u8; size[0] * size[1] * size[2]];
        for b in 0..self.layout.bricks() {
            for span in [0usize, 1, 2, 4] {
                for bit in bits(self.inhibit.get(b, span)) {
                    let v = self.layout.coords(b, bit);
                    out[v[0] + size[0] * (v[1] + size[1] * v[2])] |= SPAN_BIT[span];
                }
            }
        }
        out
    }

    /// Birth date of the edge along `axis` owned by internal vertex `i` (complex layout).
    pub fn birth(&self, i: usize, axis: usize) -> Option<u32> {
        self.birth.as_ref().map(|b| b[3 * i + axis])
    }

    /// Death date of a cell, if deaths are recorded.
    pub fn death(&self, i: usize, span: u8) -> Option<u32> {
        self.death.as_ref().map(|d| d[8 * i + span as usize])
    }

    /// Internal vertex index (complex layout) of a brick bit.
    #[inline]
    fn vertex_index(&self, b: usize, bit: u32) -> usize {
        let v = self.layout.coords(b, bit);
        let s = self.layout.size;
        v[0] + s[0] * (v[1] + s[1] * v[2])
    }

    /// First iteration at which a born edge is constrained: l > 2 Birth + DC1cc − D1cc, and
    /// at least the next iteration. `None` without a constraint.
    fn constraint_date(&self, v: [usize; 3], axis: usize, birth: u32) -> Option<u32> {
        let Constraint::Lifespan {
            distance,
            decenterness,
        } = self.constraint
        else {
            return None;
        };
        let dims = self.dims;
        let (mut d, mut dc) = (0i64, 0i64);
        // Voxels containing the edge: lattice vertex (internal − 1) minus a subset of the
        // other axes.
        for s in 0..8usize {
            if s & (1 << axis) != 0 {
                continue;
            }
            let mut k = 0;
            let mut scale = 1;
            let mut inside = true;
            for a in 0..3 {
                let x = v[a] as isize - 1 - ((s >> a) & 1) as isize;
                inside &= x >= 0 && (x as usize) < dims[a];
                k += x.max(0) as usize * scale;
                scale *= dims[a];
            }
            if inside {
                d = d.max(distance[k] as i64);
                dc = dc.max(decenterness[k] as i64);
            }
        }
        let date = (2 * birth as i64 + dc - d + 1).max(birth as i64 + 1);
        Some(date.min(u32::MAX as i64 - 1) as u32)
    }

    /// Adds an edge and its two points to W.
    fn inhibit_edge(&mut self, b: usize, bit: u32, axis: usize) {
        self.inhibit.or(b, EDGE[axis], 1 << bit);
        self.inhibit.or(b, 0, 1 << bit);
        let mut v = self.layout.coords(b, bit);
        v[axis] += 1;
        let (b2, bit2) = self.layout.locate(v);
        self.inhibit.or(b2, 0, 1 << bit2);
        self.stats.constrained_edges += 1;
    }

    /// Edges of the listed bricks that are present, not yet born and without a square are born
    /// at `date`; each waits for (or, if due by iteration `now`, gets) its constraint.
    fn births(&mut self, list: &[u32], date: u32, now: u32) {
        let (cells, born, step) = (&self.cells, &self.born, self.layout.step);
        let found: Vec<(u32, u8, u64)> = {
            let scan = |c: &[u32], out: &mut Vec<(u32, u8, u64)>| {
                for &b in c {
                    let b = b as usize;
                    for axis in 0..3 {
                        let e = cells.get(b, EDGE[axis]) & !born.get(b, EDGE[axis]);
                        if e == 0 {
                            continue;
                        }
                        let mut squares = 0;
                        for other in (0..3).filter(|&o| o != axis) {
                            let sq = EDGE[axis] | EDGE[other];
                            squares |= cells.get(b, sq) | back(cells, b, sq, other, &step);
                        }
                        let new = e & !squares;
                        if new != 0 {
                            out.push((b as u32, axis as u8, new));
                        }
                    }
                }
            };
            self.chunked(list, PassCost::Heavy, scan)
        };
        for (b, axis, new) in found {
            let (b, axis) = (b as usize, axis as usize);
            self.born.or(b, EDGE[axis], new);
            // The brick's coordinates once (three divisions), each bit's by its offset.
            let base = self.layout.coords(b, 0);
            for bit in bits(new) {
                let v = [bit & 3, (bit >> 2) & 3, bit >> 4].map(|o| o as usize);
                let v = [0, 1, 2].map(|a| base[a] + v[a]);
                if let Some(birth) = &mut self.birth {
                    let s = self.layout.size;
                    birth[3 * (v[0] + s[0] * (v[1] + s[1] * v[2])) + axis] = date;
                }
                if let Some(when) = self.constraint_date(v, axis, date) {
                    if when <= now {
                        self.inhibit_edge(b, bit, axis);
                    } else {
                        let when = when as usize;
                        if self.waiting.len() <= when {
                            self.waiting.resize(when + 1, Vec::new());
                        }
                        self.waiting[when].push(Waiting {
                            brick: b as u32,
                            bit: bit as u8,
                            axis: axis as u8,
                        });
                    }
                }
            }
        }
    }

    /// Start of iteration l: the waiting edges due now and still present join W.
    fn apply_constraints(&mut self, l: u32) {
        let Some(due) = self.waiting.get_mut(l as usize).map(std::mem::take) else {
            return;
        };
        for w in due {
            let (b, axis) = (w.brick as usize, w.axis as usize);
            let m = 1u64 << w.bit;
            if self.cells.get(b, EDGE[axis]) & m != 0 && self.inhibit.get(b, EDGE[axis]) & m == 0 {
                self.inhibit_edge(b, w.bit as u32, axis);
            }
        }
    }

    /// One iteration of Algorithm 2. Returns false (and changes nothing but W) if no
    /// unconstrained free pair exists.
    pub fn iterate(&mut self, mut observer: Observer<'_, '_>) -> bool {
        let l = self.iteration + 1;
        let step = self.layout.step;
        let (sx, sy, sz) = (step[0] as isize, step[1] as isize, step[2] as isize);
        // A: the bricks holding faces of cells removed since the last iteration began.
        let changed = std::mem::take(&mut self.changed);
        self.epoch += 1;
        let active = self.dilate(&changed, &[0, sx, sy, sz]);
        // The list's buffer collects this iteration's changes (nothing was noted since the
        // take): reused rather than regrown from empty.
        debug_assert!(self.changed.is_empty());
        let mut changed = changed;
        changed.clear();
        self.changed = changed;
        self.births(&active, l - 1, l);
        self.apply_constraints(l);

        // Free faces (g present, not in W, exactly one coface) on A.
        let (cells, inhibit, free) = (&self.cells, &self.inhibit, &self.free);
        let any_free = self.filter(&active, PassCost::Heavy, |b| {
            let mut any = 0;
            macro_rules! spans {
                ($($g:literal)*) => {$(
                    let f = free_faces::<$g>(cells, inhibit, b, &step);
                    if f != 0 {
                        free.set(b, $g, f);
                        any |= f;
                    }
                )*};
            }
            spans!(0 1 2 3 4 5 6);
            any != 0
        });
        if any_free.is_empty() {
            // No free face was written: nothing to clear.
            return false;
        }
        // Cofaces of free pairs (C = A and one brick back), then their closure L (one brick
        // forward along each axis).
        let with_cofaces = self.dilate(&any_free, &[0, -sx, -sy, -sz]);
        let (cells, free, border) = (&self.cells, &self.free, &self.border);
        self.for_each(&with_cofaces, PassCost::Heavy, |b| {
            macro_rules! spans {
                ($($f:literal)*) => {$(
                    let w = cofaces_of_free::<$f>(cells, free, b, &step);
                    if w != 0 {
                        border.set(b, $f, w);
                    }
                )*};
            }
            spans!(1 2 3 4 5 6 7);
        });
        // The closure only reaches further than C through faces of cubes and squares of C:
        // one brick forward per dimension stepped down.
        let any_in = |spans: &[usize]| {
            with_cofaces
                .iter()
                .any(|&b| spans.iter().any(|&s| border.get(b as usize, s) != 0))
        };
        let top_dim = if any_in(&[CUBE_SPAN]) {
            3
        } else if any_in(&[3, 5, 6]) {
            2
        } else {
            1
        };
        let closure = match top_dim {
            3 => {
                let offsets = [0, sx, sy, sz, sx + sy, sx + sz, sy + sz, sx + sy + sz];
                self.dilate(&with_cofaces, &offsets)
            }
            2 => self.dilate(&with_cofaces, &[0, sx, sy, sz]),
            _ => with_cofaces,
        };
        let border = &self.border;
        for dim in (1..top_dim).rev() {
            self.for_each(&closure, PassCost::Heavy, |b| {
                macro_rules! spans {
                    ($($s:literal)*) => {$(
                        let w = closed_up::<$s>(border, b, &step);
                        if w != 0 {
                            border.set(b, $s, w);
                        }
                    )*};
                }
                if dim == 2 {
                    spans!(3 5 6);
                } else {
                    spans!(1 2 4);
                }
            });
        }
        // Per span (edges to cubes): the bricks holding present cells of that span in L.
        let cells = &self.cells;
        let spans_in_l = self.chunked(&closure, PassCost::Light, |c, out: &mut Vec<(u32, u8)>| {
            for &b in c {
                let mut spans = 0u8;
                for f in 1..8 {
                    if border.get(b as usize, f) & cells.get(b as usize, f) != 0 {
                        spans |= 1 << f;
                    }
                }
                if spans != 0 {
                    out.push((b, spans));
                }
            }
        });
        // Each span's list holds at most every brick of `spans_in_l`: reserved, no regrowth.
        let mut in_l: [Vec<u32>; 8] =
            std::array::from_fn(|f| Vec::with_capacity(if f == 0 { 0 } else { spans_in_l.len() }));
        for &(b, spans) in &spans_in_l {
            for f in bits(spans as u64) {
                in_l[f as usize].push(b);
            }
        }

        for s in 0..PAIR_KINDS.0.len() {
            let removed = self.sub_step(s, l, &in_l);
            if let Some(obs) = observer.as_mut() {
                obs(
                    &self.complex(),
                    SubStep {
                        iteration: l,
                        axis: (s / 6) as u8,
                        positive: (s / 3) % 2 == 1,
                        dim: 3 - (s % 3) as u8,
                        removed_pairs: removed,
                    },
                );
            }
        }
        self.finish_scratch(&any_free, &closure);
        self.iteration = l;
        self.stats.iterations = l;
        true
    }

    /// Clears the scratch planes of an iteration: the free faces of the bricks that have
    /// some (only those are written, a third of A or less), L on the closure's bricks.
    fn finish_scratch(&self, with_free: &[u32], closure: &[u32]) {
        let (free, border) = (&self.free, &self.border);
        self.for_each(with_free, PassCost::Light, |b| {
            (0..7).for_each(|s| free.set(b, s, 0))
        });
        self.for_each(closure, PassCost::Light, |b| {
            (0..8).for_each(|s| border.set(b, s, 0))
        });
    }

    /// Sub-step `s` of iteration l: for each pair kind, finds the pairs from the current planes
    /// on the bricks where L holds cells of the kind's spans (`in_l`, per span, listed at the
    /// start of the iteration), then removes them. The
    /// kinds of one sub-step are independent (a dim-2 sub-step along t removes squares
    /// containing t with one edge, and never touches the cells the other kind's test reads), so
    /// taking them one after the other equals taking them at once. Returns the number of pairs.
    fn sub_step(&mut self, s: usize, l: u32, in_l: &[Vec<u32>; 8]) -> usize {
        macro_rules! dispatch {
            ($($s:literal)*) => {
                match s {
                    $($s => {
                        let first = self.remove_kind::<$s, 0>(l, in_l);
                        first + self.remove_kind::<$s, 1>(l, in_l)
                    })*
                    _ => unreachable!("18 sub-steps"),
                }
            };
        }
        let removed = dispatch!(0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17);
        self.stats.pairs_removed += removed as u64;
        removed
    }

    /// Pair kind `K` of sub-step `S` (see [`Thinning::sub_step`]); 0 if the sub-step has no
    /// such kind. Generic so that the kind's spans and axis are constants.
    fn remove_kind<const S: usize, const K: usize>(
        &mut self,
        l: u32,
        in_l: &[Vec<u32>; 8],
    ) -> usize {
        if K >= PAIR_KINDS.1[S] {
            return 0;
        }
        let (kind, axis, positive) = const { (PAIR_KINDS.0[S][K], S / 6, (S / 3) % 2 == 1) };
        let step = self.layout.step;
        let o = step[axis] as isize;
        let mut removed = 0;
        if in_l[kind.f].is_empty() {
            return 0;
        }
        // The bricks that may hold a pair's g: g ∈ L (a face of f ∈ L), so for squares and
        // edges the bricks where L holds present cells of g's span; L's points are not
        // computed, so for points the bricks of f and, for the positive orientation, one step
        // forward (g lies at f's vertex or one step forward).
        let dilated;
        let candidates: &[u32] = if kind.g != 0 {
            &in_l[kind.g]
        } else if positive {
            dilated = self.with_shifted(&in_l[kind.f], o);
            &dilated
        } else {
            &in_l[kind.f]
        };
        let (cells, inhibit, border, masks) =
            (&self.cells, &self.inhibit, &self.border, &self.masks);
        let with_pairs = self.filter(candidates, PassCost::Light, |b| {
            // Constants here, not captured: the closure body then folds the kind's spans.
            let (kind, axis, positive) = const { (PAIR_KINDS.0[S][K], S / 6, (S / 3) % 2 == 1) };
            let mut m = cells.get(b, kind.g) & !inhibit.get(b, kind.g);
            if m != 0 {
                m &= if positive {
                    back(cells, b, kind.f, axis, &step) & back(border, b, kind.f, axis, &step)
                } else {
                    cells.get(b, kind.f) & border.get(b, kind.f)
                };
            }
            for &(up, at) in &kind.others[..kind.n_others] {
                if m == 0 {
                    break;
                }
                m &= !if at == 3 {
                    cells.get(b, up)
                } else {
                    back(cells, b, up, at, &step)
                };
            }
            // Only bricks with pairs get a mask (and have it cleared below): every other
            // brick's mask stays 0.
            if m != 0 {
                masks.set(b, 0, m);
            }
            m != 0
        });
        // Bricks with an f to clear: f lies at g's vertex or one step back.
        let shifted;
        let touched: &[u32] = if positive {
            shifted = self.with_shifted(&with_pairs, -o);
            &shifted
        } else {
            &with_pairs
        };
        let (cells, masks) = (&self.cells, &self.masks);
        self.for_each(touched, PassCost::Light, |b| {
            let (kind, axis, positive) = const { (PAIR_KINDS.0[S][K], S / 6, (S / 3) % 2 == 1) };
            let m = masks.get(b, 0);
            cells.clear(b, kind.g, m);
            let fm = if positive {
                fwd(masks, b, 0, axis, &step)
            } else {
                m
            };
            cells.clear(b, kind.f, fm);
        });
        for &b in &with_pairs {
            let b = b as usize;
            let m = self.masks.get(b, 0);
            removed += m.count_ones() as usize;
            if self.death.is_some() {
                for bit in bits(m) {
                    self.record_removal(b, bit, &kind, axis, positive, l);
                }
            }
        }
        for &b in &with_pairs {
            self.masks.set(b as usize, 0, 0);
        }
        self.note_changed(touched);
        removed
    }

    /// Dates of a removed pair (g at brick b, bit; f at the same vertex or one step back).
    fn record_removal(
        &mut self,
        b: usize,
        bit: u32,
        kind: &PairKind,
        axis: usize,
        positive: bool,
        l: u32,
    ) {
        let g = self.vertex_index(b, bit);
        let s = self.layout.size;
        let f = if positive {
            g - [1, s[0], s[0] * s[1]][axis]
        } else {
            g
        };
        if let Some(death) = &mut self.death {
            death[8 * g + kind.g] = l;
            death[8 * f + kind.f] = l;
        }
        // An edge removed before it was seen as a facet is born at its death (Def. 6.2).
        if let Some(birth) = &mut self.birth {
            for (cell, span) in [(g, kind.g), (f, kind.f)] {
                let e = 3 * cell + span.trailing_zeros() as usize;
                if span.count_ones() == 1 && birth[e] == NEVER {
                    birth[e] = l;
                }
            }
        }
    }

    /// Runs Algorithm 2 until no unconstrained free pair is left. Returns the iterations run.
    ///
    /// With [`Split::PerThread`] the run keeps one helper thread of the pool ([`PassHelper`]) for
    /// its passes, unless it resumes a collapse (not the first run) with fewer than
    /// [`MIN_HELPER_BRICKS`] changed bricks (then its passes stay on the calling thread). The
    /// helper may start late or never (a busy pool, a pool of one thread) without changing
    /// the result or blocking the run: its task is detached, and the run
    /// waits neither for it to start nor for it to return.
    pub fn run(&mut self, mut observer: Observer<'_, '_>) -> u32 {
        let start = self.iteration;
        if matches!(self.split, Split::PerThread)
            && !self.serving
            && self.iteration > 0
            && self.changed.len() < self.min_helper_bricks
        {
            // A run that resumes a collapse with few bricks to examine (the re-thinning after
            // a pierce): its passes stay on the calling thread ([`MIN_HELPER_BRICKS`]).
            self.split = Split::Sequential;
            while self.iterate(observer.as_deref_mut()) {}
            self.split = Split::PerThread;
        } else if matches!(self.split, Split::PerThread) && !self.serving {
            // A fresh pair per run, its helper a detached task started by the first pass worth
            // sharing ([`PassHelper::start`]): the run never waits for the helper to start (a busy
            // pool, or a caller outside the pool), a helper that starts after the run finds
            // its own pair shut down and returns, and a run without such a pass wakes no
            // worker and keeps no core spinning.
            let helper = Arc::new(PassHelper::new());
            *helper.owner.lock().unwrap_or_else(|e| e.into_inner()) =
                Some(std::thread::current().id());
            self.helper = Arc::clone(&helper);
            let _shut_down = ShutDownOnDrop(&helper);
            self.serving = true;
            while self.iterate(observer.as_deref_mut()) {}
            self.serving = false;
        } else {
            while self.iterate(observer.as_deref_mut()) {}
        }
        self.iteration - start
    }

    /// Runs at most `layers` iterations (Algorithm 2 with ℓ = layers).
    pub fn run_layers(&mut self, layers: u32, mut observer: Observer<'_, '_>) {
        for _ in 0..layers {
            if !self.iterate(observer.as_deref_mut()) {
                break;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::piercing::{surface_parts, ComplementRuns};
    use super::*;
    use crate::analysis::distance::{distance_map, Metric, Outside};
    use crate::analysis::grid::VoxelSet;
    use crate::analysis::opening::opening_map_l1;
    use crate::math::Rng;

    fn random_occupied(dims: [usize; 3], density: f32, rng: &mut Rng) -> VoxelSet {
        VoxelSet::random(dims[0] * dims[1] * dims[2], density, rng)
    }

    fn maps(dims: [usize; 3], occ: &VoxelSet) -> (Vec<u32>, Vec<u32>) {
        let d1 = distance_map(dims, occ, Metric::L1, Outside::Solid, false).values;
        let o1 = opening_map_l1(dims, &d1);
        let dc = o1
            .iter()
            .zip(&d1)
            .map(|(o, d)| o.saturating_sub(*d))
            .collect();
        (d1, dc)
    }

    /// Runs `check(case, dims, thinning)` on 30 random grids (sizes not multiples of the
    /// brick size, three densities) after the constrained collapse: the set-up shared by the
    /// tests of the piercing's pieces. The thinning borrows the maps made here, hence the
    /// closure rather than a returned value.
    fn collapsed_random_complexes(
        mut rng: Rng,
        mut check: impl FnMut(usize, [usize; 3], &mut Thinning<'_>),
    ) {
        for case in 0..30 {
            let dims = [5 + case % 7, 4 + (case * 5) % 6, 4 + (case * 3) % 5];
            let occ = random_occupied(dims, [0.15f32, 0.3, 0.45][case % 3], &mut rng);
            let (d1, dc) = maps(dims, &occ);
            let constraint = Constraint::Lifespan {
                distance: &d1,
                decenterness: &dc,
            };
            let mut t = Thinning::from_occupied(dims, &occ, constraint, false, false);
            t.run(None);
            check(case, dims, &mut t);
        }
    }

    #[test]
    fn cube_death_is_l1_distance() {
        let mut rng = Rng::new(3, 3);
        for dims in [[9usize, 7, 5], [12, 4, 8]] {
            let occ = random_occupied(dims, 0.15, &mut rng);
            let d1 = distance_map(dims, &occ, Metric::L1, Outside::Solid, false).values;
            let cx = Complex::from_occupied(dims, &occ);
            let mut t = Thinning::new(cx, Constraint::None, false, true);
            t.run(None);
            for z in 0..dims[2] {
                for y in 0..dims[1] {
                    for x in 0..dims[0] {
                        let k = x + dims[0] * (y + dims[1] * z);
                        let i = t.complex().vertex(x, y, z);
                        let death = t.death(i, 7).unwrap();
                        if occ.get(k) {
                            assert_eq!(death, NEVER);
                        } else {
                            assert_eq!(death, d1[k], "voxel {x},{y},{z}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn collapse_preserves_topology_and_is_deterministic() {
        let mut rng = Rng::new(5, 9);
        for case in 0..24 {
            let dims = [3 + case % 6, 3 + (case * 5) % 5, 2 + (case * 3) % 4];
            let occ = random_occupied(dims, [0.2f32, 0.35, 0.5][case % 3], &mut rng);
            let cx = Complex::from_occupied(dims, &occ);
            let before = cx.betti();
            let (d1, dc) = maps(dims, &occ);
            let constraint = if case % 2 == 0 {
                Constraint::None
            } else {
                Constraint::Lifespan {
                    distance: &d1,
                    decenterness: &dc,
                }
            };
            let mut seq = Thinning::new(cx.clone(), constraint, false, true);
            let euler = before.euler;
            let mut steps_seq = Vec::new();
            seq.run(Some(&mut |c, _| {
                assert_eq!(c.euler(), euler);
                steps_seq.push(c.bytes().to_vec());
            }));
            assert!(seq.complex().is_closed());
            assert_eq!(seq.complex().betti(), before);
            // A parallel thinning on two threads goes through the sequential one's steps.
            let matches_sequential = |mut t: Thinning| {
                let mut k = 0;
                rayon::ThreadPoolBuilder::new()
                    .num_threads(2)
                    .build()
                    .unwrap()
                    .install(|| {
                        t.run(Some(&mut |c, _| {
                            assert_eq!(c.bytes(), &steps_seq[k][..]);
                            k += 1;
                        }))
                    });
                assert_eq!(k, steps_seq.len());
            };
            let mut par = Thinning::new(cx.clone(), constraint, true, false);
            par.set_chunk_size(7);
            matches_sequential(par);
            // One part per thread, every pass split (the default split, without its
            // work threshold).
            let mut per_thread = Thinning::new(cx.clone(), constraint, true, false);
            per_thread.split_every_pass_per_thread();
            matches_sequential(per_thread);
            // Idempotent: nothing left to collapse with the same W.
            let before_rerun = seq.complex().clone();
            assert_eq!(seq.run(None), 0);
            assert_eq!(seq.complex(), before_rerun);
            let inhibited = seq.inhibited();
            let final_complex = seq.complex();
            // Dates: births never exceed deaths; constrained edges stay.
            for i in 0..cx.len() {
                for a in 0..3 {
                    let (b, d) = (seq.birth(i, a).unwrap(), seq.death(i, 1 << a).unwrap());
                    if d != NEVER {
                        assert!(b <= d, "birth {b} death {d}");
                    }
                    if inhibited[i] & SPAN_BIT[1 << a] != 0 {
                        assert!(final_complex.has(i, 1 << a));
                    }
                }
            }
        }
    }

    /// The runs' helper thread ([`PassHelper`]) with every pass shared and one-brick claims gives the
    /// sequential collapse after every sub-step, through the piercing, with the same dates,
    /// W and statistics, in pools of 1, 2 and 3 threads (with 1, the helper's task only runs
    /// after the run, on the same thread, and returns at once).
    #[test]
    fn shared_passes_equal_sequential() {
        let mut rng = Rng::new(17, 3);
        let (mut helped, mut alone_helped, mut resumed_runs) = (0, 0, 0);
        for case in 0..12 {
            let dims = [10 + case % 7, 9 + (case * 5) % 6, 8 + (case * 3) % 5];
            let occ = random_occupied(dims, [0.2f32, 0.35][case % 2], &mut rng);
            let cx = Complex::from_occupied(dims, &occ);
            let (d1, dc) = maps(dims, &occ);
            let priority: Vec<u32> = (0..d1.len() as u32)
                .map(|i| i.wrapping_mul(2_654_435_761))
                .collect();
            let constraint = Constraint::Lifespan {
                distance: &d1,
                decenterness: &dc,
            };
            let mut seq = Thinning::new(cx.clone(), constraint, false, true);
            let mut steps = Vec::new();
            seq.curvilinear(
                Some(&priority),
                Some(&mut |c, s| steps.push((c.bytes().to_vec(), s))),
            );
            for threads in 1..=3 {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let mut shared = Thinning::new(cx.clone(), constraint, true, true);
                shared.split_every_pass_per_thread();
                let mut k = 0;
                pool.install(|| {
                    shared.curvilinear(
                        Some(&priority),
                        Some(&mut |c, s| {
                            assert_eq!(
                                (c.bytes(), s),
                                (&steps[k].0[..], steps[k].1),
                                "case {case}, {threads} threads, step {k}"
                            );
                            k += 1;
                        }),
                    )
                });
                assert_eq!(k, steps.len());
                assert_eq!(shared.stats, seq.stats);
                assert_eq!(shared.inhibited(), seq.inhibited());
                assert_eq!(shared.birth, seq.birth);
                assert_eq!(shared.death, seq.death);
                if threads > 1 {
                    helped += shared.helper_chunks.load(Relaxed);
                    // The re-thinning runs, which start below `MIN_HELPER_BRICKS` (all of
                    // these), have no helper even when every pass could be shared, with the
                    // same result.
                    let mut alone = Thinning::new(cx.clone(), constraint, true, true);
                    alone.split = Split::PerThread;
                    (alone.min_shared_work, alone.min_claim) = (0, 1);
                    pool.install(|| {
                        // `curvilinear` written out, to count the re-thinning runs.
                        alone.run(None);
                        let first = alone.helper_chunks.load(Relaxed);
                        while alone.pierce(Some(&priority)) > 0 {
                            resumed_runs += 1;
                            alone.run(None);
                        }
                        alone_helped += alone.helper_chunks.load(Relaxed) - first;
                    });
                    assert_eq!(alone.stats, seq.stats);
                    assert_eq!(alone.death, seq.death);
                }
            }
        }
        assert!(helped > 0, "the helper never took part");
        assert!(resumed_runs > 0, "no case was pierced and re-thinned");
        assert_eq!(alone_helped, 0, "a re-thinning run had a helper");
    }

    #[test]
    fn pierce_gives_a_graph_with_the_same_b0_b1() {
        let mut rng = Rng::new(11, 2);
        for case in 0..30 {
            let dims = [4 + case % 5, 4 + (case * 3) % 4, 3 + (case * 7) % 4];
            let occ = random_occupied(dims, [0.1f32, 0.25, 0.4][case % 3], &mut rng);
            let cx = Complex::from_occupied(dims, &occ);
            let before = cx.betti();
            let (d1, dc) = maps(dims, &occ);
            let mut t = Thinning::new(
                cx.clone(),
                Constraint::Lifespan {
                    distance: &d1,
                    decenterness: &dc,
                },
                false,
                false,
            );
            t.curvilinear(Some(&d1), None);
            let after = t.complex().betti();
            assert_eq!(t.stats.forced_pierces, 0);
            assert_eq!(t.complex().counts()[2..], [0, 0]);
            assert_eq!((after.b0, after.b1, after.b2), (before.b0, before.b1, 0));
            assert_eq!(t.stats.pierced as usize, before.b2);
            assert!(t.complex().is_subcomplex_of(&cx));
        }
    }
    /// The fast collapse equals the literal oracle after every sub-step, with the same
    /// constraint set and dates, through piercing and re-thinning.
    #[test]
    fn equals_the_naive_oracle() {
        use crate::analysis::thinning_oracle::Oracle;
        let mut rng = Rng::new(23, 5);
        for case in 0..48 {
            let dims = if case < 40 {
                [3 + case % 6, 3 + (case * 5) % 6, 2 + (case * 3) % 5]
            } else {
                [9 + case % 7, 10 + (case * 5) % 6, 9 + (case * 3) % 5]
            };
            let occ = random_occupied(dims, [0.1f32, 0.2, 0.35, 0.5][case % 4], &mut rng);
            let cx = Complex::from_occupied(dims, &occ);
            let (d1, dc) = maps(dims, &occ);
            let constrained = case % 3 != 0;
            let constraint = if constrained {
                Constraint::Lifespan {
                    distance: &d1,
                    decenterness: &dc,
                }
            } else {
                Constraint::None
            };
            // Built from the voxels directly or from the byte complex: the same planes.
            let mut fast = if case % 3 == 1 {
                Thinning::from_occupied(dims, &occ, constraint, case % 2 == 0, true)
            } else {
                Thinning::new(cx.clone(), constraint, case % 2 == 0, true)
            };
            assert_eq!(fast.complex(), cx);
            fast.set_chunk_size(if case % 2 == 0 { 5 } else { 0 });
            let mut oracle = Oracle::new(cx.clone(), constrained.then_some((&d1[..], &dc[..])));
            for round in 0..10 {
                let mut steps = Vec::new();
                oracle.run(&mut |c| steps.push(c.bytes().to_vec()));
                let mut k = 0;
                fast.run(Some(&mut |c: &Complex, _| {
                    assert_eq!(
                        c.bytes(),
                        &steps[k][..],
                        "case {case} round {round} sub-step {k}"
                    );
                    k += 1;
                }));
                assert_eq!(k, steps.len(), "case {case}: iterations");
                assert_eq!(fast.iteration(), oracle.iteration);
                assert_eq!(fast.inhibited(), oracle.inhibit, "case {case}: W");
                for i in 0..cx.len() {
                    for a in 0..3 {
                        assert_eq!(
                            fast.birth(i, a).unwrap(),
                            oracle.birth[3 * i + a],
                            "case {case} birth"
                        );
                    }
                    for span in 0..8u8 {
                        assert_eq!(
                            fast.death(i, span).unwrap(),
                            oracle.death[8 * i + span as usize]
                        );
                    }
                }
                let before = fast.complex();
                if fast.pierce(Some(&d1)) == 0 {
                    break;
                }
                let after = fast.complex();
                for i in 0..cx.len() {
                    let gone = before.byte(i) & !after.byte(i);
                    for span in [3u8, 5, 6] {
                        if gone & SPAN_BIT[span as usize] != 0 {
                            oracle.remove_square(i, span);
                        }
                    }
                }
                assert_eq!(fast.complex(), oracle.complex);
            }
        }
    }

    /// The run-based components of the complement equal the union-find over every cube
    /// position, on collapsed random complexes (no cubes, surfaces around cavities).
    #[test]
    fn complement_runs_equal_complement_labels() {
        let mut cavities = 0;
        collapsed_random_complexes(Rng::new(31, 7), |case, dims, t| {
            let c = t.complex();
            assert_eq!(c.counts()[3], 0);
            let squares: Vec<(u32, u8)> = (0..c.len())
                .flat_map(|i| [3u8, 5, 6].map(|s| (i as u32, s)))
                .filter(|&(i, s)| c.has(i as usize, s))
                .collect();
            let (labels, count) = c.complement_labels();
            cavities += count - 1;
            let (runs, mut uf) = ComplementRuns::new(dims.map(|d| d + 2), &squares);
            // The same partition: label -> root and root -> label are both functions.
            let mut root_of = vec![usize::MAX; count];
            let mut label_of = std::collections::HashMap::new();
            for i in 0..c.len() {
                let run = runs.run_at(i / (dims[0] + 2), i % (dims[0] + 2));
                let (l, r) = (labels[i] as usize, uf.find(run));
                assert!(root_of[l] == usize::MAX || root_of[l] == r, "case {case}");
                root_of[l] = r;
                assert_eq!(*label_of.entry(r).or_insert(l), l, "case {case}");
            }
        });
        assert!(cavities > 5, "the cases should hold cavities ({cavities})");
    }

    /// The squares gathered from the brick planes in vertex order equal those of the byte
    /// complex, sorted by vertex and then span, sequentially and split over the pool, on
    /// grids whose sizes are not multiples of the brick size.
    #[test]
    fn squares_are_listed_in_vertex_order() {
        let mut rng = Rng::new(53, 5);
        for case in 0..12 {
            let dims = [5 + case % 7, 4 + (case * 5) % 9, 3 + (case * 3) % 6];
            let occ = random_occupied(dims, [0.2f32, 0.35][case % 2], &mut rng);
            let (d1, dc) = maps(dims, &occ);
            let constraint = Constraint::Lifespan {
                distance: &d1,
                decenterness: &dc,
            };
            let mut t = Thinning::from_occupied(dims, &occ, constraint, false, false);
            // Before the collapse (every square of the empty space) and after it.
            for run in [false, true] {
                if run {
                    t.run(None);
                }
                let mut expected = Vec::new();
                for (v, &byte) in t.complex().bytes().iter().enumerate() {
                    for span in [3u8, 5, 6] {
                        if byte & SPAN_BIT[span as usize] != 0 {
                            expected.push((v as u32, span));
                        }
                    }
                }
                assert_eq!(t.squares(), expected, "case {case}");
                t.split_every_pass_per_thread();
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(3)
                    .build()
                    .unwrap();
                assert_eq!(pool.install(|| t.squares()), expected, "case {case}, split");
                t.split = Split::Sequential;
            }
        }
    }

    /// The brick-list dilations (dense shift-or, per-brick marking, sorting, the merge) equal
    /// the set of shifted real bricks, on dense and sparse random lists, unsorted for
    /// `dilate`, with the offsets of the collapse.
    #[test]
    fn brick_dilations_equal_shifted_sets() {
        let mut rng = Rng::new(61, 9);
        let mut t = Thinning::empty([21, 30, 13], Constraint::None, false, false);
        let n = t.layout.bricks();
        let step = t.layout.step.map(|s| s as isize);
        let (sx, sy, sz) = (step[0], step[1], step[2]);
        let offset_sets: [&[isize]; 4] = [
            &[0, sx, sy, sz],
            &[0, -sx, -sy, -sz],
            &[0, sx, sy, sz, sx + sy, sx + sz, sy + sz, sx + sy + sz],
            &[0, -sy],
        ];
        let (mut dense, mut sparse) = (0, 0);
        for case in 0..40 {
            let density = [0.9f32, 0.5, 0.05, 0.005][case % 4];
            let list: Vec<u32> = (0..n as u32)
                .filter(|&b| t.layout.real(b as usize) && rng.uniform() < density)
                .collect();
            let mut shuffled = list.clone();
            shuffled.reverse();
            for offsets in offset_sets {
                let mut expected: Vec<u32> = list
                    .iter()
                    .flat_map(|&b| offsets.iter().map(move |&o| (b as isize + o) as usize))
                    .filter(|&c| t.layout.real(c))
                    .map(|c| c as u32)
                    .collect();
                expected.sort_unstable();
                expected.dedup();
                match t.dilate_dense(&shuffled, offsets) {
                    Some(out) => {
                        dense += 1;
                        assert_eq!(out, expected, "case {case}, dense");
                    }
                    None => sparse += 1,
                }
                assert_eq!(t.dilate(&shuffled, offsets), expected, "case {case}");
                if offsets.len() == 2 {
                    assert_eq!(t.with_shifted(&list, offsets[1]), expected, "case {case}");
                }
                assert!(t.listed.iter().all(|&w| w == 0), "scratch left dirty");
            }
        }
        assert!(dense > 20 && sparse > 20, "{dense} dense, {sparse} sparse");
    }

    /// `surface_parts` equals a direct definition: squares sharing an edge are in one part
    /// (edges listed per square, every pair of squares on an edge joined), parts ordered by
    /// their smallest square, squares in list order within a part.
    #[test]
    fn surface_parts_equal_squares_joined_through_edges() {
        let mut multi_part_cases = 0;
        collapsed_random_complexes(Rng::new(47, 3), |case, dims, t| {
            let squares = t.squares();
            let size = dims.map(|d| d + 2);
            let s = [1, size[0], size[0] * size[1]];
            // Edge (vertex, axis) -> the squares on it.
            let mut on_edge: std::collections::HashMap<(usize, usize), Vec<usize>> =
                Default::default();
            for (k, &(v, span)) in squares.iter().enumerate() {
                let axes: Vec<usize> = (0..3).filter(|a| span & (1 << a) != 0).collect();
                for (a, b) in [(axes[0], axes[1]), (axes[1], axes[0])] {
                    for at in [v as usize, v as usize + s[b]] {
                        on_edge.entry((at, a)).or_default().push(k);
                    }
                }
            }
            let mut uf = super::super::complex::UnionFind::new(squares.len());
            for list in on_edge.values() {
                for &k in &list[1..] {
                    uf.union(list[0], k);
                }
            }
            let mut expected: Vec<(u32, u32)> = (0..squares.len())
                .map(|k| (uf.find(k) as u32, k as u32))
                .collect();
            expected.sort_unstable();
            let got = surface_parts(size, &squares);
            assert_eq!(got, expected, "case {case}");
            if got.chunk_by(|a, b| a.0 == b.0).count() > 1 {
                multi_part_cases += 1;
            }
        });
        assert!(
            multi_part_cases > 2,
            "the cases should hold several parts ({multi_part_cases})"
        );
    }
}
