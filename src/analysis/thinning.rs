//! Directional parallel collapse of a cubical complex (000 §5.2.4, Algorithm 2, after Chaussard
//! and Couprie 2009), the parameter-free curvilinear constraint of Algorithm 3 (§6.2.3), and the
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
//! removal is a collapse whatever the order: the pairs are gathered read-only (in parallel over
//! chunks of the candidate list, results kept in list order) and then cleared, so the complex
//! after every sub-step is identical bit for bit in parallel and sequential runs (tested). L is
//! marked with atomic ORs in parallel; only the order of internal work lists depends on the
//! schedule, never a result. Without the restriction to L a single
//! sub-step would peel a whole row of cubes; with it one iteration removes one layer, so the
//! death date of a cube equals its L1 distance to the complement (tested below): the clock of
//! the collapse is the 6-distance, which is why the constraint uses the L1 maps.
//!
//! Candidates: a cell's freeness depends only on its cofaces, so after the first full scan the
//! only cells that may have become free are those that lost a coface: when (f, g) is removed,
//! the facets of f other than g and the facets of g (at most 9 cells). A face free at the start
//! of an iteration is always removed or loses its coface during it (f ∈ L, so its sub-step
//! takes it unless f went first), so nothing else needs re-testing: the work per iteration is
//! O(pairs removed + |L|). Within an iteration each sub-step scans the vertices of L (sorted,
//! and bucketed by the spans of their present cells in L, the only candidates for the free
//! face), which is cheaper than tracking the pairs that appear between sub-steps.
//!
//! # Dates and the constraint (Definitions 6.1-6.3, Algorithm 3)
//!
//! Iterations are numbered from 1. Death(f) = the iteration that removes f. Birth(e) of an edge
//! = the first l such that after l iterations e is a facet (no incident square) or has been
//! removed; it is recorded at the start of iteration l + 1, when the edge is re-tested as a face
//! of its last square (or at the edge's removal). The static W of Algorithm 3 is defined with
//! the lifespans of the unconstrained collapse; like both reference implementations we apply
//! the constraint lazily instead: at the start of
//! iteration l, an edge born and still present is added to W (with its two points, so W stays
//! a complex) when removing it now would give it a lifespan l − Birth(e) greater than
//!
//!   DC1cc(e) + Birth(e) − D1cc(e),
//!
//! which is the printed condition of Algorithm 3, line 1 (Lifespan > DC + Birth − D, where
//! Birth − D estimates the lifespan of the squares around e). D1cc and DC1cc of an edge are the
//! maxima of the voxel maps over the (up to four) voxels containing it: the printed definition
//! "max over g ∈ δ* ∩ F_n^n" is garbled; we read δ* as the proper star of f, the n-faces that
//! contain f, which is what "in the same way" for Ω and DC and both reference codes do. W only
//! grows, so a birth date never changes and a constrained edge is never removed.
//!
//! # Piercing (§6.2.4)
//!
//! Without cubes (a complex with a cube always has a free square), what is left of the
//! constrained collapse may still hold squares: every edge of such a square lies on at least two
//! squares (a constrained edge is born, so it has none). Each connected surface part (squares
//! joined through edges) is pierced by removing one square and the collapse is resumed. We pick
//! the square whose two sides lie in different components of the complement (so removing it
//! joins two of them: b2 decreases by one, b0 and b1 are unchanged, by Alexander duality),
//! preferring the one with the largest priority (the Euclidean distance map: the hole is
//! central), and repeat until no square remains. The iteration count goes on through the
//! re-thinning, so the edges of a pierced surface are born late, get large thresholds, and the
//! surface collapses onto the curves attached to it (Figure 36c) instead of growing branches.
//! A part where no square separates two complement
//! components (a contractible 2-complex such as Bing's house) is pierced anyway; that raises b1
//! and is counted in [`ThinningStats::forced_pierces`].

use std::sync::atomic::{AtomicU8, Ordering};

use rayon::prelude::*;

use super::complex::{Complex, CUBE, POINT, SPAN_BIT, SQUARES};

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

/// A pair kind of one sub-step: free face of span `g` at v, coface of span `f` at v − f_off,
/// and the other cofaces of g, which must all be absent.
#[derive(Clone, Copy, Debug)]
struct Kind {
    g_span: u8,
    g_bit: u8,
    f_span: u8,
    f_bit: u8,
    f_off: usize,
    /// Cofaces of g other than f owned by g's own vertex (must be absent), as one mask.
    own_absent: u8,
    /// The other cofaces of g, owned by g − offset.
    absent: [(usize, u8); 5],
    n_absent: usize,
    /// Cells to re-test after removing the pair: bytes at g + offset (offset relative to g,
    /// possibly negative), merged per vertex.
    touched: [(isize, u8); 8],
    n_touched: usize,
}

#[derive(Clone, Copy, Debug)]
struct Living {
    vertex: u32,
    axis: u8,
    birth: u32,
}

/// Gathers `f(items, out)` over the items, in item order; in parallel over chunks of `chunk`
/// items if `chunk` > 0 (0 = sequential). `f` sees a whole chunk so its loop stays tight.
fn gather<T: Send>(chunk: usize, items: &[u32], f: impl Fn(&[u32], &mut Vec<T>) + Sync) -> Vec<T> {
    if chunk > 0 && items.len() > chunk {
        let parts: Vec<Vec<T>> = items
            .par_chunks(chunk)
            .map(|c| {
                let mut out = Vec::new();
                f(c, &mut out);
                out
            })
            .collect();
        let mut all = Vec::with_capacity(parts.iter().map(Vec::len).sum());
        for mut p in parts {
            all.append(&mut p);
        }
        all
    } else {
        let mut out = Vec::new();
        f(items, &mut out);
        out
    }
}

/// Views an exclusively borrowed byte slice as atomics, so that parallel tasks can set and
/// clear bits of shared bytes.
fn atomic_bytes(v: &mut [u8]) -> &[AtomicU8] {
    // SAFETY: AtomicU8 has the size and alignment of u8, and the exclusive borrow guarantees
    // that nothing accesses the bytes non-atomically while the returned slice lives.
    unsafe { &*(v as *mut [u8] as *const [AtomicU8]) }
}

/// The state of a directional collapse: the complex, the constraint set W, dates.
pub struct Thinning<'a> {
    complex: Complex,
    constraint: Constraint<'a>,
    /// W, one byte per vertex like the complex (always closed).
    inhibit: Vec<u8>,
    /// L of the current iteration.
    border: Vec<u8>,
    border_vertices: Vec<u32>,
    /// Cells that may have become free (or, for edges, born) since the last border
    /// computation: one byte of cells per vertex, and the vertices with a nonzero byte.
    dirty: Vec<u8>,
    dirty_vertices: Vec<u32>,
    /// The first border computation scans every cell.
    full_scan: bool,
    iteration: u32,
    /// Born edges: bit `axis` per vertex.
    born: Vec<u8>,
    /// Birth date per edge (3 per vertex, by axis), if dates are recorded.
    birth: Option<Vec<u32>>,
    /// Death date per cell (8 per vertex, by span), if recorded.
    death: Option<Vec<u32>>,
    living: Vec<Living>,
    /// Parallel chunk size (0 = sequential).
    chunk: usize,
    /// Sub-step kinds, indexed by 3 * (2 * axis + orientation) + (3 - dim).
    kinds: Vec<Vec<Kind>>,
    /// The vertices of L holding a present, unconstrained cell of each span in L.
    by_span: [Vec<u32>; 7],
    /// Cofaces of a cell of each span, as (offset to subtract, span).
    cofaces: [Vec<(usize, u8)>; 8],
    /// Closure of a cell of each span, as (offset to add, byte of cells).
    closure: [Vec<(usize, u8)>; 8],
    pub stats: ThinningStats,
}

impl<'a> Thinning<'a> {
    /// Prepares the collapse of `complex`. `parallel` gathers the pairs of each sub-step on the
    /// current rayon pool (if it has more than one thread); `record_dates` keeps a birth date per edge and a death date per cell.
    pub fn new(
        complex: Complex,
        constraint: Constraint<'a>,
        parallel: bool,
        record_dates: bool,
    ) -> Thinning<'a> {
        let n = complex.len();
        let s = complex.stride();
        let mut cofaces: [Vec<(usize, u8)>; 8] = Default::default();
        let mut closure: [Vec<(usize, u8)>; 8] = Default::default();
        for span in 0..8u8 {
            for b in 0..3 {
                if span & (1 << b) == 0 {
                    cofaces[span as usize].push((0, span | 1 << b));
                    cofaces[span as usize].push((s[b], span | 1 << b));
                }
            }
            for shift in 0..8u8 {
                if shift & span != shift {
                    continue;
                }
                let off: usize = (0..3).filter(|a| shift & (1 << a) != 0).map(|a| s[a]).sum();
                let mut byte = 0u8;
                for sub in 0..8u8 {
                    if sub & (span & !shift) == sub {
                        byte |= SPAN_BIT[sub as usize];
                    }
                }
                closure[span as usize].push((off, byte));
            }
        }
        let mut kinds = Vec::with_capacity(18);
        for axis in 0..3usize {
            for positive in [false, true] {
                for dim in [3u32, 2, 1] {
                    let mut list = Vec::new();
                    for g_span in 0..8u8 {
                        if g_span.count_ones() != dim - 1 || g_span & (1 << axis) != 0 {
                            continue;
                        }
                        let f_span = g_span | 1 << axis;
                        // X−: g is the lower face of f, f owned by the same vertex.
                        let f_off = if positive { s[axis] } else { 0 };
                        let mut absent = [(0usize, 0u8); 5];
                        let (mut n_absent, mut own_absent) = (0, 0u8);
                        for &(off, span) in &cofaces[g_span as usize] {
                            if span == f_span && off == f_off {
                                continue;
                            }
                            if off == 0 {
                                own_absent |= SPAN_BIT[span as usize];
                            } else {
                                absent[n_absent] = (off, SPAN_BIT[span as usize]);
                                n_absent += 1;
                            }
                        }
                        // Facets of f (at g − f_off) and of g (at g): their cofaces change.
                        let mut touched = [(0isize, 0u8); 8];
                        let mut n_touched = 0;
                        for (base, span) in [(-(f_off as isize), f_span), (0, g_span)] {
                            for a in 0..3 {
                                if span & (1 << a) == 0 {
                                    continue;
                                }
                                let face = SPAN_BIT[(span & !(1 << a)) as usize];
                                for off in [base, base + s[a] as isize] {
                                    match touched[..n_touched].iter_mut().find(|t| t.0 == off) {
                                        Some(t) => t.1 |= face,
                                        None => {
                                            touched[n_touched] = (off, face);
                                            n_touched += 1;
                                        }
                                    }
                                }
                            }
                        }
                        list.push(Kind {
                            g_span,
                            g_bit: SPAN_BIT[g_span as usize],
                            f_span,
                            f_bit: SPAN_BIT[f_span as usize],
                            f_off,
                            own_absent,
                            absent,
                            n_absent,
                            touched,
                            n_touched,
                        });
                    }
                    kinds.push(list);
                }
            }
        }
        assert!(n < 1 << 29, "complex too large for packed cell indices");
        let mut t = Thinning {
            constraint,
            inhibit: vec![0; n],
            border: vec![0; n],
            border_vertices: Vec::new(),
            dirty: vec![0; n],
            dirty_vertices: Vec::new(),
            full_scan: true,
            iteration: 0,
            born: vec![0; n],
            birth: record_dates.then(|| vec![NEVER; 3 * n]),
            death: record_dates.then(|| vec![NEVER; 8 * n]),
            living: Vec::new(),
            // One worker: the sequential path (no atomics, no task overhead).
            chunk: if parallel && rayon::current_num_threads() > 1 {
                2048
            } else {
                0
            },
            kinds,
            by_span: Default::default(),
            cofaces,
            closure,
            stats: ThinningStats::default(),
            complex,
        };
        // Edges that are facets from the start are born at 0.
        for i in 0..n {
            for axis in 0..3u8 {
                if t.complex.has(i, 1 << axis) {
                    t.check_birth(i, axis, 0);
                }
            }
        }
        t
    }

    /// Sets the number of candidates per parallel task (tests use small chunks to exercise
    /// the parallel path on small grids); 0 = sequential.
    pub fn set_chunk_size(&mut self, chunk: usize) {
        self.chunk = chunk;
    }

    pub fn complex(&self) -> &Complex {
        &self.complex
    }

    pub fn into_complex(self) -> Complex {
        self.complex
    }

    /// Completed iterations.
    pub fn iteration(&self) -> u32 {
        self.iteration
    }

    /// The constraint set W (same layout as the complex bytes).
    pub fn inhibited(&self) -> &[u8] {
        &self.inhibit
    }

    /// Adds a cell and its faces to W.
    pub fn inhibit_closed(&mut self, i: usize, span: u8) {
        for &(off, byte) in &self.closure[span as usize] {
            self.inhibit[i + off] |= byte;
        }
    }

    /// Birth date of the edge along `axis` owned by internal vertex `i`.
    pub fn birth(&self, i: usize, axis: usize) -> Option<u32> {
        self.birth.as_ref().map(|b| b[3 * i + axis])
    }

    /// Death date of a cell, if deaths are recorded.
    pub fn death(&self, i: usize, span: u8) -> Option<u32> {
        self.death.as_ref().map(|d| d[8 * i + span as usize])
    }

    /// Marks an edge born at `l` if it is present, not yet born and has no incident square.
    fn check_birth(&mut self, i: usize, axis: u8, l: u32) {
        let span = 1u8 << axis;
        if self.born[i] & span != 0 || !self.complex.has(i, span) {
            return;
        }
        let has_square = self.cofaces[span as usize]
            .iter()
            .any(|&(off, sq)| self.complex.has(i - off, sq));
        if !has_square {
            self.mark_born(i, axis, l);
        }
    }

    /// Records the birth of a present edge (a facet now) and follows it for the constraint.
    fn mark_born(&mut self, i: usize, axis: u8, l: u32) {
        self.born[i] |= 1 << axis;
        if let Some(b) = &mut self.birth {
            b[3 * i + axis as usize] = l;
        }
        self.living.push(Living {
            vertex: i as u32,
            axis,
            birth: l,
        });
    }

    /// Threshold of Algorithm 3 for a born edge: it is constrained at iteration l when
    /// l − birth > DC1cc + birth − D1cc.
    fn limit(&self, e: &Living) -> Option<i64> {
        let Constraint::Lifespan {
            distance,
            decenterness,
        } = self.constraint
        else {
            return None;
        };
        let dims = self.complex.dims();
        let c = self.complex.coords(e.vertex as usize);
        let (mut d, mut dc) = (0i64, 0i64);
        for s in 0..8usize {
            if s & (1 << e.axis) != 0 {
                continue;
            }
            let mut v = [0usize; 3];
            let mut inside = true;
            for a in 0..3 {
                let x = c[a] - ((s >> a) & 1) as isize;
                inside &= x >= 0 && (x as usize) < dims[a];
                v[a] = x.max(0) as usize;
            }
            if inside {
                let k = v[0] + dims[0] * (v[1] + dims[1] * v[2]);
                d = d.max(distance[k] as i64);
                dc = dc.max(decenterness[k] as i64);
            }
        }
        Some(2 * e.birth as i64 + dc - d)
    }

    /// Start of iteration l: constrain the born edges whose lifespan would exceed their
    /// threshold if they were removed now.
    #[inline(never)]
    fn apply_constraints(&mut self, l: u32) {
        if matches!(self.constraint, Constraint::None) {
            self.living.clear();
            return;
        }
        let living = std::mem::take(&mut self.living);
        let mut keep = Vec::with_capacity(living.len());
        for e in living {
            let (i, span) = (e.vertex as usize, 1u8 << e.axis);
            if !self.complex.has(i, span) || self.inhibit[i] & SPAN_BIT[span as usize] != 0 {
                continue;
            }
            let limit = self.limit(&e).expect("lifespan constraint");
            if l as i64 > limit {
                self.inhibit_closed(i, span);
                self.stats.constrained_edges += 1;
            } else {
                keep.push(e);
            }
        }
        self.living = keep;
    }

    /// Number of present cofaces of a cell (0, 1 or 2 = "two or more") and the last one seen.
    #[inline]
    fn coface_state(bits: &[u8], cofaces: &[(usize, u8)], i: usize) -> (u8, usize, u8) {
        let mut found = (0u8, 0usize, 0u8);
        for &(off, span) in cofaces {
            if bits[i - off] & SPAN_BIT[span as usize] != 0 {
                if found.0 == 1 {
                    return (2, 0, 0);
                }
                found = (1, i - off, span);
            }
        }
        found
    }

    /// Start of iteration l: tests the candidate cells (every cell the first time). Edges left
    /// without a square are born at l − 1 (recorded here rather than at the end of the previous
    /// iteration: an edge only loses its last square when that square is removed, and then it
    /// is a candidate). Then applies the constraint (see `apply_constraints`), builds L = the
    /// closure of the cofaces of the unconstrained free pairs, and the vertices of L sorted
    /// and bucketed by the spans of their present, unconstrained cells in L (the only cells
    /// that can be the free face of a pair removed in this iteration). Returns false if there
    /// is no unconstrained free pair.
    #[inline(never)]
    fn collect_border(&mut self) -> bool {
        let l = self.iteration + 1;
        // (g, g span, f, f span); f span = NO_SPAN marks the birth of edge g.
        const NO_SPAN: u8 = 0xff;
        let found: Vec<(u32, u8, u32, u8)> = {
            let bits = self.complex.bytes();
            let (inhibit, cofaces, born) = (&self.inhibit, &self.cofaces, &self.born);
            let test = |v: usize, cells: u8, out: &mut Vec<(u32, u8, u32, u8)>| {
                let cells = cells & bits[v] & !CUBE & !inhibit[v];
                if cells == 0 {
                    return;
                }
                for span in 0..7u8 {
                    if cells & SPAN_BIT[span as usize] == 0 {
                        continue;
                    }
                    match Self::coface_state(bits, &cofaces[span as usize], v) {
                        (1, f, fs) => out.push((v as u32, span, f as u32, fs)),
                        (0, _, _) if span.count_ones() == 1 && born[v] & span == 0 => {
                            out.push((v as u32, span, 0, NO_SPAN))
                        }
                        _ => {}
                    }
                }
            };
            if self.full_scan {
                let all: Vec<u32> = (0..bits.len() as u32)
                    .filter(|&v| bits[v as usize] != 0)
                    .collect();
                gather(self.chunk, &all, |c, out| {
                    for &v in c {
                        test(v as usize, 0xff, out)
                    }
                })
            } else {
                let dirty = &self.dirty;
                gather(self.chunk, &self.dirty_vertices, |c, out| {
                    for &v in c {
                        test(v as usize, dirty[v as usize], out)
                    }
                })
            }
        };
        self.full_scan = false;
        for &v in &self.dirty_vertices {
            self.dirty[v as usize] = 0;
        }
        self.dirty_vertices.clear();
        for &(g, span, _, fs) in &found {
            if fs == NO_SPAN {
                self.mark_born(g as usize, span.trailing_zeros() as u8, l - 1);
            }
        }
        self.apply_constraints(l);

        // L: the closures of the cofaces, marked in parallel (atomic OR); the vertices whose
        // byte was zero are collected, then sorted.
        let (closure, inhibit, chunk) = (&self.closure, &self.inhibit, self.chunk.max(1));
        let border = atomic_bytes(&mut self.border);
        let mark = |c: &[(u32, u8, u32, u8)], out: &mut Vec<u32>| {
            for &(g, g_span, f, fs) in c {
                if fs == NO_SPAN || inhibit[g as usize] & SPAN_BIT[g_span as usize] != 0 {
                    continue;
                }
                for &(off, byte) in &closure[fs as usize] {
                    let j = f as usize + off;
                    if border[j].fetch_or(byte, Ordering::Relaxed) == 0 {
                        out.push(j as u32);
                    }
                }
            }
        };
        let mut vertices: Vec<u32> = if self.chunk > 0 && found.len() > chunk {
            found
                .par_chunks(chunk)
                .map(|c| {
                    let mut out = Vec::new();
                    mark(c, &mut out);
                    out
                })
                .collect::<Vec<_>>()
                .concat()
        } else {
            let mut out = Vec::new();
            mark(&found, &mut out);
            out
        };
        if vertices.is_empty() {
            return false;
        }
        if self.chunk > 0 {
            vertices.par_sort_unstable();
        } else {
            vertices.sort_unstable();
        }
        self.border_vertices = vertices;
        let (bits, border) = (self.complex.bytes(), &self.border);
        let bucket = |c: &[u32]| {
            let mut lists: [Vec<u32>; 7] = Default::default();
            for &v in c {
                let i = v as usize;
                let cells = border[i] & bits[i] & !inhibit[i] & !CUBE;
                for span in 0..7u8 {
                    if cells & SPAN_BIT[span as usize] != 0 {
                        lists[span as usize].push(v);
                    }
                }
            }
            lists
        };
        let parts: Vec<[Vec<u32>; 7]> = if self.chunk > 0 && self.border_vertices.len() > chunk {
            self.border_vertices.par_chunks(chunk).map(bucket).collect()
        } else {
            vec![bucket(&self.border_vertices)]
        };
        for (span, list) in self.by_span.iter_mut().enumerate() {
            list.clear();
            for p in &parts {
                list.extend_from_slice(&p[span]);
            }
        }
        true
    }

    /// The free pairs of sub-step `step` with their coface in L, in vertex order (read-only).
    #[inline(never)]
    fn substep_pairs(&self, step: usize) -> Vec<(u32, u8)> {
        let (bits, inhibit, border) = (self.complex.bytes(), &self.inhibit, &self.border);
        let mut pairs = Vec::new();
        for (k, kind) in self.kinds[step].iter().enumerate() {
            let kind = *kind;
            let found = gather(self.chunk, &self.by_span[kind.g_span as usize], |c, out| {
                for &v in c {
                    let v = v as usize;
                    let own = bits[v];
                    if own & kind.g_bit == 0
                        || own & kind.own_absent != 0
                        || inhibit[v] & kind.g_bit != 0
                    {
                        continue;
                    }
                    let f = v - kind.f_off;
                    if bits[f] & kind.f_bit == 0 || border[f] & kind.f_bit == 0 {
                        continue;
                    }
                    if kind.absent[..kind.n_absent]
                        .iter()
                        .all(|&(off, bit)| bits[v - off] & bit == 0)
                    {
                        out.push((v as u32, k as u8));
                    }
                }
            });
            pairs.extend(found);
        }
        pairs
    }

    /// Removes the pairs of a sub-step, recording dates and the cells to re-test.
    #[inline(never)]
    fn remove_pairs(&mut self, step: usize, pairs: &[(u32, u8)], l: u32) {
        self.stats.pairs_removed += pairs.len() as u64;
        for &(v, k) in pairs {
            let kind = self.kinds[step][k as usize];
            let (g, f) = (v as usize, v as usize - kind.f_off);
            self.complex.remove(g, kind.g_span);
            self.complex.remove(f, kind.f_span);
            // Cells whose cofaces changed: the facets of f and of g.
            for &(off, faces) in &kind.touched[..kind.n_touched] {
                let w = g.wrapping_add_signed(off);
                let d = &mut self.dirty[w];
                if *d == 0 {
                    self.dirty_vertices.push(w as u32);
                }
                *d |= faces;
            }
            if let Some(death) = &mut self.death {
                death[8 * g + kind.g_span as usize] = l;
                death[8 * f + kind.f_span as usize] = l;
            }
            // An edge removed before it was seen as a facet is born at its death (Def. 6.2).
            for (cell, span) in [(g, kind.g_span), (f, kind.f_span)] {
                if span.count_ones() == 1 && self.born[cell] & span == 0 {
                    self.born[cell] |= span;
                    if let Some(b) = &mut self.birth {
                        b[3 * cell + span.trailing_zeros() as usize] = l;
                    }
                }
            }
        }
    }

    /// One iteration of Algorithm 2. Returns false (and changes nothing) if no unconstrained
    /// free pair exists.
    pub fn iterate(&mut self, observer: &mut dyn FnMut(&Complex, SubStep)) -> bool {
        let l = self.iteration + 1;
        if !self.collect_border() {
            return false;
        }
        for step in 0..self.kinds.len() {
            let pairs = self.substep_pairs(step);
            self.remove_pairs(step, &pairs, l);
            observer(
                &self.complex,
                SubStep {
                    iteration: l,
                    axis: (step / 6) as u8,
                    positive: (step / 3) % 2 == 1,
                    dim: 3 - (step % 3) as u8,
                    removed_pairs: pairs.len(),
                },
            );
        }
        for &v in &self.border_vertices {
            self.border[v as usize] = 0;
        }
        self.iteration = l;
        self.stats.iterations = l;
        true
    }

    /// Adds the faces of a removed cell (a pierced square) to the candidates.
    fn touch_faces(&mut self, i: usize, span: u8) {
        let s = self.complex.stride();
        for a in 0..3 {
            if span & (1 << a) != 0 {
                let face = span & !(1 << a);
                for w in [i, i + s[a]] {
                    if self.dirty[w] == 0 {
                        self.dirty_vertices.push(w as u32);
                    }
                    self.dirty[w] |= SPAN_BIT[face as usize];
                }
            }
        }
    }

    /// Runs Algorithm 2 until no unconstrained free pair is left. Returns the iterations run.
    pub fn run(&mut self, observer: &mut dyn FnMut(&Complex, SubStep)) -> u32 {
        let start = self.iteration;
        while self.iterate(observer) {}
        self.iteration - start
    }

    /// Runs at most `layers` iterations (Algorithm 2 with ℓ = layers).
    pub fn run_layers(&mut self, layers: u32, observer: &mut dyn FnMut(&Complex, SubStep)) {
        for _ in 0..layers {
            if !self.iterate(observer) {
                break;
            }
        }
    }

    /// All squares, as (vertex, span), in index order.
    fn squares(&self) -> Vec<(u32, u8)> {
        const CHUNK: usize = 1 << 16;
        let parts: Vec<Vec<(u32, u8)>> = self
            .complex
            .bytes()
            .par_chunks(CHUNK)
            .enumerate()
            .map(|(c, bytes)| {
                let mut out = Vec::new();
                for (k, &b) in bytes.iter().enumerate() {
                    let b = b & SQUARES;
                    if b == 0 {
                        continue;
                    }
                    for span in [3u8, 5, 6] {
                        if b & SPAN_BIT[span as usize] != 0 {
                            out.push(((c * CHUNK + k) as u32, span));
                        }
                    }
                }
                out
            })
            .collect();
        parts.concat()
    }

    /// Pierces every surface part once (see the module docs). `priority` is a per-voxel map
    /// (larger = pierce there first; e.g. the squared Euclidean distance). Returns the number
    /// of squares removed (0 when no square is left).
    pub fn pierce(&mut self, priority: Option<&[u32]>) -> usize {
        let squares = self.squares();
        if squares.is_empty() {
            return 0;
        }
        self.stats.pierce_rounds += 1;
        // Index of a present square: the first index of its vertex plus its rank there (the
        // list is sorted by vertex, then span 3, 5, 6).
        let mut first = vec![u32::MAX; self.complex.len()];
        for (k, &(v, _)) in squares.iter().enumerate().rev() {
            first[v as usize] = k as u32;
        }
        let bits = self.complex.bytes();
        let index = |v: usize, span: u8| -> usize {
            let below = [3u8, 5, 6]
                .iter()
                .filter(|&&t| t < span && bits[v] & SPAN_BIT[t as usize] != 0)
                .count();
            first[v] as usize + below
        };
        let s = self.complex.stride();
        // Surface parts: squares joined through shared edges.
        let mut parts = super::complex::UnionFind::new(squares.len());
        for (k, &(v, span)) in squares.iter().enumerate() {
            for a in 0..3 {
                if span & (1 << a) == 0 {
                    continue;
                }
                let e = span & !(1 << a);
                for owner in [v as usize, v as usize + s[a]] {
                    for &(off, sq) in &self.cofaces[e as usize] {
                        let w = owner - off;
                        if bits[w] & SPAN_BIT[sq as usize] != 0 {
                            parts.union(k, index(w, sq));
                        }
                    }
                }
            }
        }
        drop(first);
        let (labels, components) = self.complex.complement_labels();
        let mut sides = super::complex::UnionFind::new(components);
        let dims = self.complex.dims();
        let prio = |cube: usize| -> u32 {
            let Some(p) = priority else { return 0 };
            let c = self.complex.coords(cube);
            if (0..3).all(|a| c[a] >= 0 && (c[a] as usize) < dims[a]) {
                p[c[0] as usize + dims[0] * (c[1] as usize + dims[1] * c[2] as usize)]
            } else {
                0
            }
        };
        // Per square: its two cube positions (the square's own vertex and one step back along
        // its normal) and priority.
        let info: Vec<(usize, usize, u32)> = squares
            .iter()
            .map(|&(v, span)| {
                let normal = (0..3).find(|a| span & (1 << a) == 0).unwrap();
                let (c1, c2) = (v as usize, v as usize - s[normal]);
                (c1, c2, prio(c1).max(prio(c2)))
            })
            .collect();
        let mut members: Vec<Vec<usize>> = vec![Vec::new(); squares.len()];
        for k in 0..squares.len() {
            members[parts.find(k)].push(k);
        }
        let mut chosen = Vec::new();
        for part in members.iter().filter(|m| !m.is_empty()) {
            let mut best: Option<usize> = None;
            for &k in part {
                let (c1, c2, p) = info[k];
                let (l1, l2) = (labels[c1] as usize, labels[c2] as usize);
                let better = match best {
                    None => true,
                    Some(b) => p > info[b].2,
                };
                if sides.find(l1) != sides.find(l2) && better {
                    best = Some(k);
                }
            }
            let k = match best {
                Some(k) => {
                    let (c1, c2, _) = info[k];
                    sides.union(labels[c1] as usize, labels[c2] as usize);
                    k
                }
                None => {
                    self.stats.forced_pierces += 1;
                    let mut b = part[0];
                    for &k in part {
                        if info[k].2 > info[b].2 {
                            b = k;
                        }
                    }
                    b
                }
            };
            chosen.push(k);
        }
        chosen.sort_unstable();
        let l = self.iteration;
        for &k in &chosen {
            let (v, span) = squares[k];
            self.complex.remove(v as usize, span);
            if let Some(death) = &mut self.death {
                death[8 * v as usize + span as usize] = l;
            }
        }
        for &k in &chosen {
            let (v, span) = squares[k];
            for a in 0..3 {
                if span & (1 << a) != 0 {
                    let e = span & !(1 << a);
                    let axis = e.trailing_zeros() as u8;
                    self.check_birth(v as usize, axis, l);
                    self.check_birth(v as usize + s[a], axis, l);
                }
            }
        }
        for &k in &chosen {
            let (v, span) = squares[k];
            self.touch_faces(v as usize, span);
        }
        self.stats.pierced += chosen.len() as u64;
        chosen.len()
    }

    /// Algorithm 3 followed by piercing and re-thinning until the complex has no square: the
    /// result is a 1-complex (points and edges). `priority` as in [`Thinning::pierce`].
    pub fn curvilinear(
        &mut self,
        priority: Option<&[u32]>,
        observer: &mut dyn FnMut(&Complex, SubStep),
    ) {
        self.run(observer);
        while self.pierce(priority) > 0 {
            self.run(observer);
        }
        debug_assert!(self.complex.bytes().iter().all(|&b| b & !(POINT | 14) == 0));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::distance::{distance_map, Metric, Outside};
    use crate::analysis::grid::VoxelSet;
    use crate::analysis::opening::opening_map_l1;
    use crate::math::Rng;

    fn random_occupied(dims: [usize; 3], density: f32, rng: &mut Rng) -> VoxelSet {
        let n = dims[0] * dims[1] * dims[2];
        let mut s = VoxelSet::new(n);
        for i in 0..n {
            if rng.uniform() < density {
                s.set(i);
            }
        }
        s
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

    #[test]
    fn cube_death_is_l1_distance() {
        let mut rng = Rng::new(3, 3);
        for dims in [[9usize, 7, 5], [12, 4, 8]] {
            let occ = random_occupied(dims, 0.15, &mut rng);
            let d1 = distance_map(dims, &occ, Metric::L1, Outside::Solid, false).values;
            let cx = Complex::from_occupied(dims, &occ);
            let mut t = Thinning::new(cx, Constraint::None, false, true);
            t.run(&mut |_, _| {});
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
            seq.run(&mut |c, _| {
                assert_eq!(c.euler(), euler);
                steps_seq.push(c.bytes().to_vec());
            });
            assert!(seq.complex().is_closed());
            assert_eq!(seq.complex().betti(), before);
            let mut par = Thinning::new(cx.clone(), constraint, true, false);
            par.set_chunk_size(7);
            let mut k = 0;
            rayon::ThreadPoolBuilder::new()
                .num_threads(2)
                .build()
                .unwrap()
                .install(|| {
                    par.run(&mut |c, _| {
                        assert_eq!(c.bytes(), &steps_seq[k][..]);
                        k += 1;
                    })
                });
            assert_eq!(k, steps_seq.len());
            // Idempotent: nothing left to collapse with the same W.
            let before_rerun = seq.complex().clone();
            assert_eq!(seq.run(&mut |_, _| {}), 0);
            assert_eq!(seq.complex(), &before_rerun);
            // Dates: births never exceed deaths; constrained edges stay.
            for i in 0..cx.len() {
                for a in 0..3 {
                    let (b, d) = (seq.birth(i, a).unwrap(), seq.death(i, 1 << a).unwrap());
                    if d != NEVER {
                        assert!(b <= d, "birth {b} death {d}");
                    }
                    if seq.inhibited()[i] & SPAN_BIT[1 << a] != 0 {
                        assert!(seq.complex().has(i, 1 << a));
                    }
                }
            }
        }
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
            t.curvilinear(Some(&d1), &mut |_, _| {});
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
        for case in 0..40 {
            let dims = [3 + case % 6, 3 + (case * 5) % 6, 2 + (case * 3) % 5];
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
            let mut fast = Thinning::new(cx.clone(), constraint, case % 2 == 0, true);
            fast.set_chunk_size(if case % 2 == 0 { 5 } else { 0 });
            let mut oracle = Oracle::new(cx.clone(), constrained.then_some((&d1[..], &dc[..])));
            for round in 0..10 {
                let mut steps = Vec::new();
                oracle.run(&mut |c| steps.push(c.bytes().to_vec()));
                let mut k = 0;
                fast.run(&mut |c, _| {
                    assert_eq!(
                        c.bytes(),
                        &steps[k][..],
                        "case {case} round {round} sub-step {k}"
                    );
                    k += 1;
                });
                assert_eq!(k, steps.len(), "case {case}: iterations");
                assert_eq!(fast.iteration(), oracle.iteration);
                assert_eq!(fast.inhibited(), &oracle.inhibit[..], "case {case}: W");
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
                let before = fast.complex().clone();
                if fast.pierce(Some(&d1)) == 0 {
                    break;
                }
                for i in 0..cx.len() {
                    let gone = before.byte(i) & !fast.complex().byte(i);
                    for span in [3u8, 5, 6] {
                        if gone & SPAN_BIT[span as usize] != 0 {
                            oracle.remove_square(i, span);
                        }
                    }
                }
                assert_eq!(fast.complex(), &oracle.complex);
            }
        }
    }
}
