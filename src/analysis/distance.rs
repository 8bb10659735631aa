//! Exact distance maps of a voxel set, by separable passes (one axis after the other, each
//! line independently and in parallel): L1 (6-distance), chessboard (26-distance, Meijster,
//! Roerdink and Hesselink 2000) and squared Euclidean (Felzenszwalb and Huttenlocher 2012).
//! These passes are linear in the line length, but one: with a solid outside and no nearest
//! voxel, the squared Euclidean passes after x are row windows over contiguous memory
//! instead (`sq_euclidean_yz_solid`): a row's window grows with its largest value, so that
//! pass is not linear, but on scene grids it is faster. Each map can also return, per voxel,
//! the index of a nearest occupied voxel.

use rayon::prelude::*;

use super::grid::{for_each_line, VoxelSet};

/// Distance value of voxels with no occupied voxel at all to measure from.
pub const INFINITE: u32 = u32::MAX;
/// Nearest-feature value meaning "the outside of the grid" or "none".
pub const NO_FEATURE: u32 = u32::MAX;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Metric {
    /// Manhattan distance (6-connected steps).
    L1,
    /// Chebyshev distance (26-connected steps).
    Chessboard,
    /// Squared Euclidean distance between voxel centres.
    SquaredEuclidean,
}

/// What lies beyond the grid's faces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outside {
    /// The grid is surrounded by occupied voxels (distances measure to the boundary too).
    Solid,
    /// Nothing beyond the grid counts.
    Empty,
}

/// A distance map and, optionally, the nearest occupied voxel of each voxel.
#[derive(Clone, Debug)]
pub struct DistanceMap {
    pub values: Vec<u32>,
    pub nearest: Option<Vec<u32>>,
}

impl DistanceMap {
    pub fn memory_bytes(&self) -> usize {
        self.values.len() * 4 + self.nearest.as_ref().map_or(0, |n| n.len() * 4)
    }
}

/// Large value standing for "no site" inside the 1-D transforms (i64 arithmetic never
/// overflows with it).
const BIG: i64 = 1 << 40;

#[inline]
fn widen(v: u32) -> i64 {
    if v == INFINITE {
        BIG
    } else {
        v as i64
    }
}

#[inline]
fn narrow(v: i64) -> u32 {
    if v >= BIG {
        INFINITE
    } else {
        v as u32
    }
}

/// Scratch buffers of one worker: the line with its virtual outside sites, and the envelope.
#[derive(Default)]
struct LineScratch {
    g: Vec<i64>,
    gf: Vec<u32>,
    sites: Vec<usize>,
    starts: Vec<i64>,
}

/// One line of (value, feature) pairs, transformed in place. With `Outside::Solid` a virtual
/// occupied site stands just beyond each end.
fn transform_line(
    metric: Metric,
    outside: Outside,
    scratch: &mut LineScratch,
    line: &mut [(u32, u32)],
) {
    let pad = usize::from(outside == Outside::Solid);
    let n = line.len() + 2 * pad;
    let LineScratch {
        g,
        gf,
        sites,
        starts,
    } = scratch;
    g.clear();
    gf.clear();
    if pad == 1 {
        g.push(0);
        gf.push(NO_FEATURE);
    }
    for &(v, f) in line.iter() {
        g.push(widen(v));
        gf.push(f);
    }
    if pad == 1 {
        g.push(0);
        gf.push(NO_FEATURE);
    }
    let len = line.len();
    let out = move |x: usize| x.checked_sub(pad).filter(|&i| i < len);
    match metric {
        Metric::L1 => {
            // min_j |i - j| + g(j): a forward and a backward sweep.
            let mut fwd = Vec::with_capacity(n);
            let (mut best, mut feat) = (BIG, NO_FEATURE);
            for i in 0..n {
                best += 1;
                if g[i] <= best {
                    best = g[i];
                    feat = gf[i];
                }
                fwd.push((best.min(BIG), feat));
            }
            let (mut best, mut feat) = (BIG, NO_FEATURE);
            for i in (0..n).rev() {
                best += 1;
                if g[i] <= best {
                    best = g[i];
                    feat = gf[i];
                }
                let (v, f) = if best < fwd[i].0 {
                    (best, feat)
                } else {
                    fwd[i]
                };
                if let Some(k) = out(i) {
                    line[k] = (narrow(v), f);
                }
            }
        }
        Metric::Chessboard | Metric::SquaredEuclidean => {
            // Lower envelope of the functions f(x, i) over the sites i with finite g(i).
            let f = |x: i64, i: usize| -> i64 {
                let d = (x - i as i64).abs();
                match metric {
                    Metric::Chessboard => d.max(g[i]),
                    _ => d * d + g[i],
                }
            };
            // Sep(i, u), i < u: the last x at which site i is still no worse than site u
            // (Meijster et al. 2000, Table 1).
            let sep = |i: usize, u: usize| -> i64 {
                let (i_, u_) = (i as i64, u as i64);
                match metric {
                    Metric::Chessboard => {
                        if g[i] <= g[u] {
                            (i_ + g[u]).max((i_ + u_).div_euclid(2))
                        } else {
                            (u_ - g[i]).min((i_ + u_).div_euclid(2))
                        }
                    }
                    _ => (u_ * u_ - i_ * i_ + g[u] - g[i]).div_euclid(2 * (u_ - i_)),
                }
            };
            sites.clear();
            starts.clear();
            for u in 0..n {
                if g[u] >= BIG {
                    continue;
                }
                while let (Some(&sq), Some(&tq)) = (sites.last(), starts.last()) {
                    if f(tq, sq) > f(tq, u) {
                        sites.pop();
                        starts.pop();
                    } else {
                        break;
                    }
                }
                match sites.last() {
                    None => {
                        sites.push(u);
                        starts.push(0);
                    }
                    Some(&sq) => {
                        let w = 1 + sep(sq, u);
                        if w < n as i64 {
                            sites.push(u);
                            starts.push(w.max(0));
                        }
                    }
                }
            }
            if sites.is_empty() {
                line.fill((INFINITE, NO_FEATURE));
                return;
            }
            let mut q = sites.len() - 1;
            for x in (0..n).rev() {
                if let Some(k) = out(x) {
                    line[k] = (narrow(f(x as i64, sites[q])), gf[sites[q]]);
                }
                if q > 0 && x as i64 == starts[q] {
                    q -= 1;
                }
            }
        }
    }
}

/// Computes a distance map of `occupied` (distance 0) over a grid of `dims`: one parallel pass
/// per axis, each line transformed independently.
pub fn distance_map(
    dims: [usize; 3],
    occupied: &VoxelSet,
    metric: Metric,
    outside: Outside,
    nearest: bool,
) -> DistanceMap {
    let n = dims[0] * dims[1] * dims[2];
    assert_eq!(occupied.len(), n);
    if !nearest && metric != Metric::Chessboard {
        return DistanceMap {
            values: distance_values(dims, occupied, metric, outside),
            nearest: None,
        };
    }
    let mut data: Vec<(u32, u32)> = (0..n)
        .into_par_iter()
        .map(|i| {
            if occupied.get(i) {
                (0, i as u32)
            } else {
                (INFINITE, NO_FEATURE)
            }
        })
        .collect();
    for axis in 0..3 {
        for_each_line(dims, axis, &mut data, LineScratch::default, |s, line| {
            transform_line(metric, outside, s, line)
        });
    }
    let values = data.par_iter().map(|p| p.0).collect();
    let nearest = nearest.then(|| data.par_iter().map(|p| p.1).collect());
    DistanceMap { values, nearest }
}

/// Stand-in for "no site" in the value-only passes (u32 sums of it never overflow).
const FAR: u32 = u32::MAX / 4;

/// L1 along one line: the min of the value and one more than the previous value, forward and
/// backward; `edge` is the value of the virtual site beyond both ends (0 for a solid outside).
#[inline]
fn sweep_l1(line: &mut [u32], edge: u32) {
    let mut prev = edge;
    for v in line.iter_mut() {
        prev = (*v).min(prev + 1);
        *v = prev;
    }
    prev = edge;
    for v in line.iter_mut().rev() {
        prev = (*v).min(prev + 1);
        *v = prev;
    }
}

/// Squared Euclidean along one line (Felzenszwalb and Huttenlocher 2012): the lower envelope of
/// the parabolas (x − q)² + f(q) over the sites q with a finite value, plus the virtual sites
/// at −1 and n when the outside is solid. Exact integer arithmetic without division: the
/// parabolas of sites p < q meet at s = (h(q) − h(p)) / (2 (q − p)) with h = f + q² and a
/// positive denominator, and such fractions are compared by cross-multiplication (for lines
/// shorter than 2^16 voxels, numerators stay below 2^34 and denominators below 2^18, so the
/// products fit an i64).
fn envelope_sq(line: &mut [u32], solid: bool, sites: &mut Vec<Parabola>) {
    let n = line.len();
    sites.clear();
    let mut push = |q: i64, f: i64| {
        let h = f + q * q;
        while let Some(last) = sites.last() {
            let (num, den) = (h - last.h, 2 * (q - last.q));
            // The new parabola starts at num / den; the last one is dropped when that is not
            // after its own start (the first parabola starts at −∞ and is never dropped).
            if sites.len() > 1 && num * last.start_den <= last.start_num * den {
                sites.pop();
            } else {
                sites.push(Parabola {
                    q,
                    h,
                    start_num: num,
                    start_den: den,
                });
                return;
            }
        }
        sites.push(Parabola {
            q,
            h,
            start_num: 0,
            start_den: 0,
        });
    };
    if solid {
        push(-1, 0);
    }
    for (q, &v) in line.iter().enumerate() {
        if v < FAR {
            push(q as i64, v as i64);
        }
    }
    if solid {
        push(n as i64, 0);
    }
    if sites.is_empty() {
        line.fill(FAR);
        return;
    }
    let mut k = 0;
    for (x, v) in line.iter_mut().enumerate() {
        let x = x as i64;
        // On to the next parabola while it starts before x (start_num / start_den < x).
        while k + 1 < sites.len() && sites[k + 1].start_num < x * sites[k + 1].start_den {
            k += 1;
        }
        // (x − q)² + f(q) = x² − 2xq + h(q).
        let p = sites[k];
        *v = (x * (x - 2 * p.q) + p.h) as u32;
    }
}

/// One parabola of [`envelope_sq`]'s lower envelope: its site q, h = f(q) + q², and the
/// fraction at which it starts to be the lowest (unused for the first parabola).
#[derive(Clone, Copy)]
struct Parabola {
    q: i64,
    h: i64,
    start_num: i64,
    start_den: i64,
}

/// L1 or squared Euclidean distance values (no nearest feature), on plain u32 lines: the
/// fast path of [`distance_map`] that the skeleton uses.
fn distance_values(
    dims: [usize; 3],
    occupied: &VoxelSet,
    metric: Metric,
    outside: Outside,
) -> Vec<u32> {
    let n = dims[0] * dims[1] * dims[2];
    let solid = outside == Outside::Solid;
    let edge = if solid { 0 } else { FAR };
    let nx = dims[0].max(1);
    // Along x, from the occupancy bits: the 1-D distance to the nearest occupied voxel.
    let mut d = vec![0u32; n];
    d.par_chunks_mut(nx).enumerate().for_each(|(r, row)| {
        let base = r * nx;
        for (x, v) in row.iter_mut().enumerate() {
            *v = if occupied.get(base + x) { 0 } else { FAR };
        }
        sweep_l1(row, edge);
        if metric == Metric::SquaredEuclidean {
            for v in row.iter_mut() {
                *v = if *v >= FAR { FAR } else { *v * *v };
            }
        }
    });
    if metric == Metric::L1 {
        sweep_l1_yz(dims, &mut d, edge);
        return d;
    }
    if solid && dims.iter().all(|&k| k < MAX_WINDOW_DIM) {
        sq_euclidean_yz_solid(dims, &mut d);
        return d;
    }
    for axis in 1..3 {
        for_each_line(dims, axis, &mut d, Vec::new, |sites, line| {
            envelope_sq(line, solid, sites)
        });
    }
    d.par_iter_mut().for_each(|v| {
        if *v >= FAR {
            *v = INFINITE;
        }
    });
    d
}

/// Grid extents below which [`sq_euclidean_yz_solid`] applies: every squared distance is then
/// below 3 · 2^28, and a candidate sum (a value plus a square smaller than another value) below
/// 2^31, so the u32 arithmetic never overflows.
const MAX_WINDOW_DIM: usize = 1 << 15;

/// The squared Euclidean passes along y and z of [`distance_values`] for a solid outside, on
/// the x pass's output: the same values as the lower envelopes of [`envelope_sq`] (both are
/// the exact minimum over the sites of (i − j)² + f(j), and the order of the passes does not
/// change the minimum over the occupied voxels and the outside's faces), but computed on whole
/// rows of x at a time, so the loops run over contiguous memory and vectorize, no line is
/// gathered, and no division-free fraction test runs per site. The window of a row is short:
/// with the outside solid, a voxel at i on an axis of m voxels is within min(i + 1, m − i) of
/// the outside, so only rows closer than that (and than the square root of the row's largest
/// value so far) can lower it. The shorter of y and z goes first: its bound then also caps
/// the values the second pass starts from. Along y the tasks are z-slabs; along z, column
/// blocks of the xy-plane (as in [`sweep_l1_yz`]). With a solid outside no value is `FAR`.
/// Cost: per voxel and pass, twice the window (at most half the axis, in practice the distance
/// to the nearest wall) element operations, vectorized, against the envelopes' few tens of
/// scalar operations per voxel: the door's Euclidean distance went from 81 M to 17 M
/// instructions at 118 and from 559 M to 140 M at 234 (BENCHMARKS.md, skel9).
fn sq_euclidean_yz_solid(dims: [usize; 3], d: &mut [u32]) {
    let [nx, ny, nz] = dims;
    let plane = nx * ny;
    if plane == 0 || nz == 0 {
        return;
    }
    let along_y = |d: &mut [u32]| {
        d.par_chunks_mut(plane)
            .for_each_init(Vec::new, |scratch: &mut Vec<u32>, slab| {
                scratch.clear();
                scratch.extend_from_slice(slab);
                let mut rows: Vec<&mut [u32]> = slab.chunks_mut(nx).collect();
                min_plus_squares(scratch, &mut rows);
            });
    };
    let along_z = |d: &mut [u32]| {
        // Column blocks of at most 512 voxels: the block's nz rows (its scratch copy and the
        // output) stay in the core's cache for the whole window.
        let block = 512.min(plane);
        let blocks = plane.div_ceil(block);
        let mut columns: Vec<Vec<&mut [u32]>> =
            (0..blocks).map(|_| Vec::with_capacity(nz)).collect();
        for layer in d.chunks_mut(plane) {
            for (b, part) in layer.chunks_mut(block).enumerate() {
                columns[b].push(part);
            }
        }
        columns
            .par_iter_mut()
            .for_each_init(Vec::new, |scratch: &mut Vec<u32>, rows| {
                scratch.clear();
                for row in rows.iter() {
                    scratch.extend_from_slice(row);
                }
                min_plus_squares(scratch, rows);
            });
    };
    if nz <= ny {
        along_z(d);
        along_y(d);
    } else {
        along_y(d);
        along_z(d);
    }
}

/// One squared Euclidean pass across a stack of m equally long rows with a solid outside:
/// row i becomes, elementwise, the minimum over j of (i − j)² + src_j, over the rows j of `src`
/// (the stack's input, row after row) and the virtual sites j = −1 and j = m of value 0. Row
/// i starts from its own value and the outside's min(i + 1, m − i)², and takes the rows i ± k
/// for k = 1, 2, ... while k² is below the row's largest value: a farther row adds at least
/// k² and so cannot lower any element. That bound also keeps i ± k inside the stack, since
/// k² < min(i + 1, m − i)². Values below 2^30 (see [`MAX_WINDOW_DIM`]).
fn min_plus_squares(src: &[u32], rows: &mut [&mut [u32]]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked above), the only requirement of a
        // `target_feature` function.
        unsafe { min_plus_squares_avx2(src, rows) };
        return;
    }
    min_plus_squares_body(src, rows);
}

/// [`min_plus_squares_body`] compiled for AVX2 (eight u32 lanes with an unsigned min, which the
/// baseline x86-64 target lacks); the same integer operations, so the same values.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn min_plus_squares_avx2(src: &[u32], rows: &mut [&mut [u32]]) {
    min_plus_squares_body(src, rows);
}

/// See [`min_plus_squares`].
#[inline(always)]
fn min_plus_squares_body(src: &[u32], rows: &mut [&mut [u32]]) {
    let m = rows.len();
    let Some(w) = rows.first().map(|r| r.len()) else {
        return;
    };
    for (i, out) in rows.iter_mut().enumerate() {
        let edge = ((i + 1).min(m - i) as u32).pow(2);
        let mut top = 0;
        for (o, &s) in out.iter_mut().zip(&src[i * w..(i + 1) * w]) {
            let v = s.min(edge);
            *o = v;
            top = top.max(v);
        }
        let mut k = 1;
        while k * k < top as usize {
            let kk = (k * k) as u32;
            let (below, above) = (&src[(i - k) * w..][..w], &src[(i + k) * w..][..w]);
            top = 0;
            for ((o, &a), &b) in out.iter_mut().zip(below).zip(above) {
                let v = (*o).min(a.min(b) + kk);
                *o = v;
                top = top.max(v);
            }
            k += 1;
        }
    }
}

/// The L1 passes along y and z of [`distance_values`], then `FAR` to [`INFINITE`]: the same
/// recurrence as [`sweep_l1`], but applied to whole rows of x at a time (each row against the
/// previous one, elementwise), so the loops run over contiguous memory and vectorize, and no
/// line is gathered. Along y the tasks are z-slabs; along z, column blocks of the xy-plane.
fn sweep_l1_yz(dims: [usize; 3], d: &mut [u32], edge: u32) {
    let [nx, ny, nz] = dims;
    let plane = nx * ny;
    if plane == 0 || nz == 0 {
        return;
    }
    d.par_chunks_mut(plane).for_each(|slab| {
        let mut rows: Vec<&mut [u32]> = slab.chunks_mut(nx).collect();
        sweep_l1_rows(&mut rows, edge);
    });
    // Column blocks of about 2048 voxels: nz rows of one block stay in cache for both sweeps.
    let block = 2048.min(plane);
    let blocks = plane.div_ceil(block);
    let mut columns: Vec<Vec<&mut [u32]>> = (0..blocks).map(|_| Vec::with_capacity(nz)).collect();
    for layer in d.chunks_mut(plane) {
        for (b, part) in layer.chunks_mut(block).enumerate() {
            columns[b].push(part);
        }
    }
    columns.par_iter_mut().for_each(|rows| {
        sweep_l1_rows(rows, edge);
        for row in rows.iter_mut() {
            for v in row.iter_mut() {
                if *v >= FAR {
                    *v = INFINITE;
                }
            }
        }
    });
}

/// [`sweep_l1`] across a stack of equally long rows: forward, each row becomes the min of itself
/// and the previous row plus one (the first row: `edge` plus one), then backward.
fn sweep_l1_rows(rows: &mut [&mut [u32]], edge: u32) {
    let m = rows.len();
    if m == 0 {
        return;
    }
    let step = |cur: &mut [u32], prev: &[u32]| {
        for (c, p) in cur.iter_mut().zip(prev) {
            *c = (*c).min(*p + 1);
        }
    };
    let bound = |row: &mut [u32]| {
        for v in row.iter_mut() {
            *v = (*v).min(edge + 1);
        }
    };
    bound(rows[0]);
    for k in 1..m {
        let (done, rest) = rows.split_at_mut(k);
        step(rest[0], done[k - 1]);
    }
    bound(rows[m - 1]);
    for k in (0..m - 1).rev() {
        let (head, tail) = rows.split_at_mut(k + 1);
        step(head[k], tail[0]);
    }
}

/// Distance between two voxels of a grid under a metric (squared for Euclidean).
pub fn voxel_distance(dims: [usize; 3], i: usize, j: usize, metric: Metric) -> u64 {
    let c = |k: usize| {
        [
            k % dims[0],
            (k / dims[0]) % dims[1],
            k / (dims[0] * dims[1]),
        ]
    };
    let (p, q) = (c(i), c(j));
    let d: Vec<u64> = (0..3)
        .map(|k| (p[k] as i64 - q[k] as i64).unsigned_abs())
        .collect();
    match metric {
        Metric::L1 => d.iter().sum(),
        Metric::Chessboard => *d.iter().max().unwrap(),
        Metric::SquaredEuclidean => d.iter().map(|v| v * v).sum(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    /// Brute force: the minimum over every occupied voxel (and over the outside shell when the
    /// outside is solid).
    fn brute(dims: [usize; 3], occ: &VoxelSet, metric: Metric, outside: Outside) -> Vec<u32> {
        let n = dims[0] * dims[1] * dims[2];
        let sites: Vec<usize> = (0..n).filter(|&i| occ.get(i)).collect();
        (0..n)
            .map(|i| {
                let mut best = sites
                    .iter()
                    .map(|&j| voxel_distance(dims, i, j, metric))
                    .min()
                    .unwrap_or(u64::MAX);
                if outside == Outside::Solid {
                    let c = [
                        i % dims[0],
                        (i / dims[0]) % dims[1],
                        i / (dims[0] * dims[1]),
                    ];
                    for k in 0..3 {
                        let d = (c[k] + 1).min(dims[k] - c[k]) as u64;
                        best = best.min(if metric == Metric::SquaredEuclidean {
                            d * d
                        } else {
                            d
                        });
                    }
                }
                best.min(INFINITE as u64) as u32
            })
            .collect()
    }

    /// The row-window squared Euclidean passes of a solid outside ([`sq_euclidean_yz_solid`])
    /// against the general line transform (the nearest-feature path, an independent lower
    /// envelope), on grids large enough for long windows, with y shorter and longer than z
    /// (both pass orders) and z-column blocks that do not divide the plane.
    #[test]
    fn row_window_euclidean_equals_the_line_envelope() {
        let mut rng = Rng::new(11, 3);
        for dims in [
            [40, 23, 31],
            [33, 41, 17],
            [70, 9, 9],
            [1, 60, 2],
            [29, 1, 35],
        ] {
            let n = dims[0] * dims[1] * dims[2];
            for density in [0.0f32, 0.001, 0.01, 0.1] {
                let occ = VoxelSet::random(n, density, &mut rng);
                let m = Metric::SquaredEuclidean;
                let fast = distance_map(dims, &occ, m, Outside::Solid, false).values;
                let general = distance_map(dims, &occ, m, Outside::Solid, true).values;
                assert_eq!(fast, general, "{dims:?} density {density}");
            }
        }
    }

    /// The line envelope with a solid outside (which the volume passes now reach only for axes
    /// of `MAX_WINDOW_DIM` voxels or more) against its definition: the least (x - q)^2 + f(q)
    /// over the finite sites and the two virtual sites at -1 and n.
    #[test]
    fn solid_line_envelope_equals_the_definition() {
        let mut rng = Rng::new(13, 5);
        let mut sites = Vec::new();
        for n in [1usize, 2, 5, 17, 64, 100] {
            for density in [0.0f32, 0.1, 0.5, 1.0] {
                let line: Vec<u32> = (0..n)
                    .map(|_| {
                        if rng.uniform() < density {
                            (rng.uniform() * 50.0) as u32
                        } else {
                            FAR
                        }
                    })
                    .collect();
                let want: Vec<u32> = (0..n as i64)
                    .map(|x| {
                        let edge = ((x + 1).min(n as i64 - x) as u32).pow(2);
                        line.iter()
                            .enumerate()
                            .filter(|&(_, &v)| v < FAR)
                            .map(|(q, &v)| (x - q as i64).pow(2) as u32 + v)
                            .min()
                            .unwrap_or(FAR)
                            .min(edge)
                    })
                    .collect();
                let mut got = line.clone();
                envelope_sq(&mut got, true, &mut sites);
                assert_eq!(got, want, "n {n} density {density}");
            }
        }
    }

    /// The AVX2 build of the window pass equals the baseline one (the pass picks one by the
    /// CPU, so each machine runs only one of them in the other tests).
    #[test]
    fn window_pass_builds_agree() {
        let mut rng = Rng::new(12, 4);
        for (m, w) in [(1, 1), (2, 3), (7, 17), (30, 64), (61, 5)] {
            // Values as the passes see them: squares of distances within the stack's extent.
            let src: Vec<u32> = (0..m * w)
                .map(|_| {
                    let r = (rng.uniform() * m as f32) as u32;
                    r * r + (rng.uniform() * 3.0) as u32
                })
                .collect();
            let mut a = src.clone();
            let mut rows: Vec<&mut [u32]> = a.chunks_mut(w).collect();
            min_plus_squares_body(&src, &mut rows);
            // The definition, row by row.
            let want: Vec<u32> = (0..m * w)
                .map(|e| {
                    let (i, x) = ((e / w) as i64, e % w);
                    let edge = ((i + 1).min(m as i64 - i) as u32).pow(2);
                    (0..m as i64)
                        .map(|j| ((i - j) * (i - j)) as u32 + src[j as usize * w + x])
                        .min()
                        .unwrap()
                        .min(edge)
                })
                .collect();
            assert_eq!(a, want, "baseline, {m}x{w}");
            let mut b = src.clone();
            let mut rows: Vec<&mut [u32]> = b.chunks_mut(w).collect();
            min_plus_squares(&src, &mut rows);
            assert_eq!(b, want, "dispatched, {m}x{w}");
        }
    }

    #[test]
    fn distance_maps_equal_brute_force() {
        let mut rng = Rng::new(5, 5);
        for dims in [[1, 1, 1], [7, 1, 1], [5, 6, 7], [9, 4, 11], [16, 16, 3]] {
            let n = dims[0] * dims[1] * dims[2];
            for density in [0.0f32, 0.02, 0.2, 0.7] {
                let occ = VoxelSet::random(n, density, &mut rng);
                for metric in [Metric::L1, Metric::Chessboard, Metric::SquaredEuclidean] {
                    for outside in [Outside::Solid, Outside::Empty] {
                        let got = distance_map(dims, &occ, metric, outside, true);
                        let want = brute(dims, &occ, metric, outside);
                        // The value-only fast path agrees too.
                        let values = distance_map(dims, &occ, metric, outside, false).values;
                        assert_eq!(values, want, "values {dims:?} {density} {metric:?}");
                        assert_eq!(
                            got.values, want,
                            "{dims:?} density {density} {metric:?} {outside:?}"
                        );
                        // Every reported nearest voxel is occupied and at the reported distance.
                        for (i, &f) in got.nearest.as_ref().unwrap().iter().enumerate() {
                            if f != NO_FEATURE {
                                assert!(occ.get(f as usize));
                                assert_eq!(
                                    voxel_distance(dims, i, f as usize, metric),
                                    got.values[i] as u64
                                );
                            }
                        }
                    }
                }
            }
        }
    }
}
