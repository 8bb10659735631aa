//! Piercing of the surface parts left by the constrained collapse (000 §6.2.4).
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
//! A part where no square separates two complement components (a contractible 2-complex such
//! as Bing's house) is pierced anyway; that raises b1 and is counted in
//! [`ThinningStats::forced_pierces`](super::ThinningStats::forced_pierces).

use rayon::prelude::*;

use super::{cofaces, Observer, Split, Thinning};
use crate::analysis::complex::{UnionFind, SPAN_BIT};

impl Thinning<'_> {
    /// The present squares as (internal vertex, span), sorted by vertex and then span (3, 5,
    /// 6): read from the brick planes, so a pierce round costs O(bricks + squares) rather than
    /// a pass over every lattice vertex. The bricks are read in vertex order (per layer of
    /// bricks along z: each vertex row, z then y, across the bricks along x, four bits each),
    /// so the list comes out sorted without a sort; each row of bricks is read once, and its
    /// 16 vertex rows visit only its bricks holding a square.
    pub(super) fn squares(&self) -> Vec<(u32, u8)> {
        const SPANS: [u8; 3] = [3, 5, 6];
        let nb = self.layout.nb;
        let step = self.layout.step;
        let size = self.layout.size;
        let planes = |b: usize| SPANS.map(|span| self.cells.get(b, span as usize));
        // The squares of one layer of bricks (brick z = bz), in vertex order.
        let layer = |bz: usize| {
            let row = |by: usize, bx: usize| by * step[1] + bz * step[2] + bx;
            // Per row of bricks along x: its bricks holding a square (x index and square
            // planes, in x order), read once, and the union of their square bits.
            let mut with_squares: Vec<(usize, [u64; 3])> = Vec::new();
            let mut row_start = vec![0usize; nb[1] + 1];
            let mut row_bits = vec![0u64; nb[1]];
            for by in 0..nb[1] {
                if by > 0 && by + 1 < nb[1] {
                    for bx in 1..nb[0] - 1 {
                        let words = planes(row(by, bx));
                        let union = words.iter().fold(0, |a, &w| a | w);
                        if union != 0 {
                            with_squares.push((bx, words));
                            row_bits[by] |= union;
                        }
                    }
                }
                row_start[by + 1] = with_squares.len();
            }
            let mut out = Vec::new();
            for zo in 0..4 {
                let z = (bz - 1) * 4 + zo;
                for by in 1..nb[1] - 1 {
                    // The 16 bits of vertex layer zo in this row of bricks.
                    let layer_bits = (row_bits[by] >> (16 * zo)) & 0xFFFF;
                    if layer_bits == 0 {
                        continue;
                    }
                    for yo in 0..4 {
                        if (layer_bits >> (4 * yo)) & 0xF == 0 {
                            continue;
                        }
                        let y = (by - 1) * 4 + yo;
                        let shift = 4 * yo + 16 * zo;
                        for &(bx, words) in &with_squares[row_start[by]..row_start[by + 1]] {
                            let words = words.map(|w| (w >> shift) & 0xF);
                            if words.iter().all(|&w| w == 0) {
                                continue;
                            }
                            for xo in 0..4 {
                                for (k, &span) in SPANS.iter().enumerate() {
                                    if (words[k] >> xo) & 1 != 0 {
                                        let x = (bx - 1) * 4 + xo;
                                        let v = x + size[0] * (y + size[1] * z);
                                        out.push((v as u32, span));
                                    }
                                }
                            }
                        }
                    }
                }
            }
            out
        };
        let layers = 1..nb[2] - 1;
        if !matches!(self.split, Split::Sequential) {
            let len = layers.len().div_ceil(rayon::current_num_threads());
            layers
                .into_par_iter()
                .with_min_len(len)
                .flat_map_iter(layer)
                .collect()
        } else {
            layers.flat_map(layer).collect()
        }
    }

    /// Pierces every surface part once (see the module docs). `priority` is a per-voxel map
    /// (larger = pierce there first; e.g. the squared Euclidean distance). Returns the number
    /// of squares removed (0 when no square is left).
    pub fn pierce(&mut self, priority: Option<&[u32]>) -> usize {
        let squares = self.squares();
        let Some((chosen, forced)) = choose_pierced_squares(
            self.dims,
            &squares,
            priority,
            !matches!(self.split, Split::Sequential),
        ) else {
            return 0;
        };
        self.stats.pierce_rounds += 1;
        self.stats.forced_pierces += forced;
        let size = self.layout.size;
        let l = self.iteration;
        for &(v, span) in &chosen {
            let v = v as usize;
            let c = [
                v % size[0],
                (v / size[0]) % size[1],
                v / (size[0] * size[1]),
            ];
            let (b, bit) = self.layout.locate(c);
            self.cells.clear(b, span as usize, 1 << bit);
            self.note_changed(&[b as u32]);
            if let Some(death) = &mut self.death {
                death[8 * v + span as usize] = l;
            }
        }
        self.stats.pierced += chosen.len() as u64;
        chosen.len()
    }

    /// Algorithm 3 followed by piercing and re-thinning until the complex has no square: the
    /// result is a 1-complex (points and edges). `priority` as in [`Thinning::pierce`].
    pub fn curvilinear(&mut self, priority: Option<&[u32]>, mut observer: Observer<'_, '_>) {
        self.run(observer.as_deref_mut());
        while self.pierce(priority) > 0 {
            self.run(observer.as_deref_mut());
        }
    }
}

/// The squares to pierce in a complex without cubes (see the module docs): one per surface
/// part, as (internal vertex, span), and how many of them were forced. `squares` lists every
/// square of the complex (internal vertex index of a complex of voxel dims `dims`, sorted by
/// vertex, then span 3, 5, 6). `None` if there is no square.
fn choose_pierced_squares(
    dims: [usize; 3],
    squares: &[(u32, u8)],
    priority: Option<&[u32]>,
    parallel: bool,
) -> Option<(Vec<(u32, u8)>, u64)> {
    if squares.is_empty() {
        return None;
    }
    let size = dims.map(|d| d + 2);
    // The surface parts and the complement's components are independent: with `parallel`
    // they are computed on two threads (the rest of the choice is a sequential union-find
    // whose outcome depends on the order of the parts).
    let parts = || surface_parts(size, squares);
    let sides = || {
        let (runs, sides) = ComplementRuns::new(size, squares);
        (square_sides(dims, &runs, squares, priority), sides)
    };
    let (by_part, (info, mut sides)) = if parallel {
        rayon::join(parts, sides)
    } else {
        (parts(), sides())
    };
    let mut chosen = Vec::new();
    let mut forced = 0;
    for part in by_part.chunk_by(|a, b| a.0 == b.0) {
        let mut best: Option<usize> = None;
        for &(_, k) in part {
            let (r1, r2, p) = info[k as usize];
            let better = match best {
                None => true,
                Some(b) => p > info[b].2,
            };
            if sides.find(r1 as usize) != sides.find(r2 as usize) && better {
                best = Some(k as usize);
            }
        }
        let k = match best {
            Some(k) => {
                let (r1, r2, _) = info[k];
                sides.union(r1 as usize, r2 as usize);
                k
            }
            None => {
                forced += 1;
                let mut b = part[0].1 as usize;
                for &(_, k) in part {
                    if info[k as usize].2 > info[b].2 {
                        b = k as usize;
                    }
                }
                b
            }
        };
        chosen.push(squares[k]);
    }
    chosen.sort_unstable();
    Some((chosen, forced))
}

/// The surface parts of a complex without cubes (squares joined through shared edges) as
/// (part, square index) sorted by part: parts in order of their smallest square, squares in
/// list order within a part. `squares` as in [`choose_pierced_squares`], `size` the internal
/// vertices per axis.
pub(super) fn surface_parts(size: [usize; 3], squares: &[(u32, u8)]) -> Vec<(u32, u32)> {
    let plane = size[0] * size[1];
    let s = [1, size[0], plane];
    // The squares sharing an edge with a square of span 3, 5 or 6 at vertex v, as (vertex
    // offset, z layers back, span), keeping only those listed before it (at a vertex w < v,
    // or at v with a smaller span): each of the square's four edges (two along each of its
    // axes: at v and one step along the other axis) has four cofaces, at its vertex or one
    // step back. An offset's sign is that of its (z, y, x) steps read lexicographically (the
    // lattice is at least 3 vertices wide), so which neighbours come earlier is the same for
    // every square of a span: a table (6 entries per span) instead of 16 tests per square.
    // Only the earlier squares (which skips a square itself, a coface of its own edges):
    // adjacency is symmetric and a set's root is its smallest square (`UnionFind::union`), so
    // joining each pair once gives the same parts and roots as joining it from both squares.
    let span_slot = |span: u8| usize::from(span != 3) + usize::from(span == 6);
    let mut earlier: [Vec<(isize, usize, u8)>; 3] = Default::default();
    for span in [3u8, 5, 6] {
        for a in (0..3).filter(|&a| span & (1 << a) != 0) {
            let e = (span & !(1 << a)) as usize;
            for own in [[0isize; 3], std::array::from_fn(|i| isize::from(i == a))] {
                for &(sq, at) in cofaces(e) {
                    let d: [isize; 3] = std::array::from_fn(|i| own[i] - isize::from(i == at));
                    let order = [d[2], d[1], d[0]].cmp(&[0, 0, 0]);
                    if order.is_lt() || (order.is_eq() && sq < span as usize) {
                        let delta =
                            d[0] * s[0] as isize + d[1] * s[1] as isize + d[2] * s[2] as isize;
                        earlier[span_slot(span)].push((delta, (-d[2]) as usize, sq as u8));
                    }
                }
            }
        }
    }
    // Each pair of edge-adjacent squares is joined once, from its later square k: the other
    // one, j < k, lies at a vertex w <= v (the list is sorted by vertex), so in k's z layer
    // of vertices or the one before. So the index needs only two layers of vertices (by
    // parity of z; some 100 kB, in cache) instead of the whole lattice: per vertex the
    // square bits, and the first index of its squares plus one (0 = none).
    let mut bits = vec![0u8; 2 * plane];
    let mut first = vec![0u32; 2 * plane];
    // The slot of vertex w in z layer wz: the layers are known from the squares' order and
    // the steps taken, so no division per lookup (a 64-bit division costs some tens of cycles,
    // and there are 6 lookups per square).
    let slot = |w: usize, wz: usize| (wz & 1) * plane + (w - wz * plane);
    // The squares of the layers held: (z, range of square indices), older first.
    let mut held: [Option<(usize, std::ops::Range<usize>)>; 2] = [None, None];
    let mut parts = UnionFind::new(squares.len());
    let mut k = 0;
    while k < squares.len() {
        // The squares of the next layer z: [k, end).
        let z = squares[k].0 as usize / plane;
        let end = k + squares[k..].partition_point(|&(v, _)| v as usize / plane == z);
        // Keep layer z - 1 if held; forget (clear) the others.
        let keep =
            |h: &Option<(usize, std::ops::Range<usize>)>| matches!(h, Some((hz, _)) if hz + 1 == z);
        let mut kept = None;
        for h in held.iter_mut() {
            if keep(h) {
                kept = h.take();
            } else if let Some((hz, range)) = h.take() {
                for &(v, _) in &squares[range] {
                    bits[slot(v as usize, hz)] = 0;
                }
            }
        }
        held = [kept, Some((z, k..end))];
        for (i, &(v, span)) in squares[k..end].iter().enumerate().rev() {
            let at = slot(v as usize, z);
            bits[at] |= SPAN_BIT[span as usize];
            first[at] = (k + i) as u32 + 1;
        }
        // Index of a present square from its vertex's slot: the first index of its vertex
        // plus its rank there (the list is sorted by vertex, then span 3, 5, 6).
        let index = |at: usize, span: u8| -> usize {
            let below = [3u8, 5, 6]
                .iter()
                .filter(|&&t| t < span && bits[at] & SPAN_BIT[t as usize] != 0)
                .count();
            first[at] as usize - 1 + below
        };
        for (k, &(v, span)) in squares.iter().enumerate().take(end).skip(k) {
            for &(delta, back, sq) in &earlier[span_slot(span)] {
                let w = (v as isize + delta) as usize;
                let at = slot(w, z - back);
                if bits[at] & SPAN_BIT[sq as usize] != 0 {
                    parts.union(k, index(at, sq));
                }
            }
        }
        k = end;
    }
    // Sorted by (root, square): a counting sort by root (squares taken in increasing order
    // stay in list order within a part), linear instead of a comparison sort.
    let n = squares.len();
    let roots: Vec<u32> = (0..n).map(|k| parts.find(k) as u32).collect();
    let mut start = vec![0u32; n + 1];
    for &r in &roots {
        start[r as usize + 1] += 1;
    }
    for i in 0..n {
        start[i + 1] += start[i];
    }
    let mut by_part = vec![(0u32, 0u32); n];
    for (k, &r) in roots.iter().enumerate() {
        let at = &mut start[r as usize];
        by_part[*at as usize] = (r, k as u32);
        *at += 1;
    }
    by_part
}

/// Per square: the complement runs on its two sides (the cube positions at the square's own
/// vertex and one step back along its normal) and its priority (the larger of the two cube
/// positions' voxel priorities; 0 outside the grid or without a map).
fn square_sides(
    dims: [usize; 3],
    runs: &ComplementRuns,
    squares: &[(u32, u8)],
    priority: Option<&[u32]>,
) -> Vec<(u32, u32, u32)> {
    let size = dims.map(|d| d + 2);
    // Priority of a cube position given by its internal vertex coordinates (internal vertex v
    // is the cube of voxel v - 1).
    let prio = |c: [usize; 3]| -> u32 {
        let Some(p) = priority else { return 0 };
        if (0..3).all(|a| c[a] >= 1 && c[a] <= dims[a]) {
            p[(c[0] - 1) + dims[0] * ((c[1] - 1) + dims[1] * (c[2] - 1))]
        } else {
            0
        }
    };
    squares
        .iter()
        .map(|&(v, span)| {
            let normal = (0..3).find(|a| span & (1 << a) == 0).unwrap();
            // The coordinates once per square (two divisions), the other cube by a step.
            let (row, x) = (v as usize / size[0], v as usize % size[0]);
            let c1 = [x, row % size[1], row / size[1]];
            let mut c2 = c1;
            c2[normal] -= 1;
            let run = |c: [usize; 3]| runs.run_at(c[1] + size[1] * c[2], c[0]) as u32;
            (run(c1), run(c2), prio(c1).max(prio(c2)))
        })
        .collect()
}

/// The connected components of the complement of a complex that has no cube (what a collapse
/// leaves), for piercing. The complement is the union of the open cells not in the complex;
/// an absent cell's cofaces are absent too, so every component holds open unit cubes, and two
/// cubes that share an absent square are in one component ([`Complex::complement_labels`](crate::analysis::Complex::complement_labels)).
/// Without cubes every cube position of the internal array is open, and only present squares
/// separate neighbours; so the cube positions of one row along x split into runs at the YZ
/// squares, and runs of neighbouring rows join where their overlap has a column without an
/// XZ (rows along y) or XY (rows along z) square. Work: O(rows + squares), against a
/// union-find over every cube position.
pub(super) struct ComplementRuns {
    /// Per row (y + size_y z): the x of its YZ squares (sorted), as CSR offsets into `cuts`.
    cut_start: Vec<u32>,
    cuts: Vec<u32>,
}

impl ComplementRuns {
    /// The runs and their components (a union-find over runs: run r of row w is number
    /// `cut_start[w] + w + r`).
    pub(super) fn new(size: [usize; 3], squares: &[(u32, u8)]) -> (ComplementRuns, UnionFind) {
        let rows = size[1] * size[2];
        // Per span of square (XY = 3, XZ = 5, YZ = 6): CSR lists of x per row; `squares` is
        // sorted by vertex, so by row and then x.
        let csr = |span: u8| {
            let mut start = vec![0u32; rows + 1];
            let mut xs = Vec::new();
            for &(v, sp) in squares {
                if sp == span {
                    start[v as usize / size[0] + 1] += 1;
                    xs.push((v as usize % size[0]) as u32);
                }
            }
            for w in 0..rows {
                start[w + 1] += start[w];
            }
            (start, xs)
        };
        let (cut_start, cuts) = csr(6);
        let runs = cuts.len() + rows;
        let mut components = UnionFind::new(runs);
        // Joins the runs of row a and row b (b one step after a along y or z) wherever their
        // overlap has a column not blocked by a square of `blocks` (listed for row b).
        let join = |uf: &mut UnionFind, a: usize, b: usize, blocks: &(Vec<u32>, Vec<u32>)| {
            let bounds = |w: usize| {
                let c = &cuts[cut_start[w] as usize..cut_start[w + 1] as usize];
                (c, cut_start[w] as usize + w)
            };
            let ((ca, ra), (cb, rb)) = (bounds(a), bounds(b));
            let blocked = &blocks.1[blocks.0[b] as usize..blocks.0[b + 1] as usize];
            let (mut i, mut j, mut k) = (0usize, 0usize, 0usize);
            let mut x = 0u32;
            let end = size[0] as u32;
            while x < end {
                let ea = ca.get(i).copied().unwrap_or(end);
                let eb = cb.get(j).copied().unwrap_or(end);
                let stop = ea.min(eb);
                // Blocked columns in [x, stop).
                while k < blocked.len() && blocked[k] < x {
                    k += 1;
                }
                let mut n = 0;
                while k + n < blocked.len() && blocked[k + n] < stop {
                    n += 1;
                }
                if (n as u32) < stop - x {
                    uf.union(ra + i, rb + j);
                }
                x = stop;
                if ea == stop {
                    i += 1;
                }
                if eb == stop {
                    j += 1;
                }
            }
        };
        let (xz, xy) = (csr(5), csr(3));
        for z in 0..size[2] {
            for y in 0..size[1] {
                let w = y + size[1] * z;
                if y > 0 {
                    join(&mut components, w - 1, w, &xz);
                }
                if z > 0 {
                    join(&mut components, w - size[1], w, &xy);
                }
            }
        }
        (ComplementRuns { cut_start, cuts }, components)
    }

    /// The run holding the cube position at x in row w (y + size_y z).
    pub(super) fn run_at(&self, w: usize, x: usize) -> usize {
        let x = x as u32;
        let c = &self.cuts[self.cut_start[w] as usize..self.cut_start[w + 1] as usize];
        self.cut_start[w] as usize + w + c.partition_point(|&cut| cut <= x)
    }
}
