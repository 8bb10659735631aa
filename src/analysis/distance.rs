//! Exact, linear-time distance maps of a voxel set, by separable passes (one axis after the
//! other, each line independently and in parallel): L1 (6-distance), chessboard (26-distance,
//! Meijster, Roerdink and Hesselink 2000) and squared Euclidean (Felzenszwalb and Huttenlocher
//! 2012). Each can also return, per voxel, the index of a nearest occupied voxel.

use rayon::prelude::*;

use super::grid::VoxelSet;

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

/// One line: input values `g` (BIG = none) and features; writes output values and features.
fn transform_line(metric: Metric, g: &[i64], gf: &[u32], h: &mut [i64], hf: &mut [u32]) {
    let n = g.len();
    match metric {
        Metric::L1 => {
            // min_j |i - j| + g(j): a forward and a backward sweep.
            let (mut best, mut feat) = (BIG, NO_FEATURE);
            for i in 0..n {
                best += 1;
                if g[i] <= best {
                    best = g[i];
                    feat = gf[i];
                }
                h[i] = best.min(BIG);
                hf[i] = feat;
            }
            let (mut best, mut feat) = (BIG, NO_FEATURE);
            for i in (0..n).rev() {
                best += 1;
                if g[i] <= best {
                    best = g[i];
                    feat = gf[i];
                }
                if best < h[i] {
                    h[i] = best;
                    hf[i] = feat;
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
            // Sep(i, u), i < u: the last x at which site i is still at most site u.
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
            let mut s: Vec<usize> = Vec::with_capacity(n);
            let mut t: Vec<i64> = Vec::with_capacity(n);
            for u in 0..n {
                if g[u] >= BIG {
                    continue;
                }
                while let (Some(&sq), Some(&tq)) = (s.last(), t.last()) {
                    if f(tq, sq) > f(tq, u) {
                        s.pop();
                        t.pop();
                    } else {
                        break;
                    }
                }
                match s.last() {
                    None => {
                        s.push(u);
                        t.push(0);
                    }
                    Some(&sq) => {
                        let w = 1 + sep(sq, u);
                        if w < n as i64 {
                            s.push(u);
                            t.push(w.max(0));
                        }
                    }
                }
            }
            if s.is_empty() {
                h.fill(BIG);
                hf.fill(NO_FEATURE);
                return;
            }
            let mut q = s.len() - 1;
            for x in (0..n).rev() {
                h[x] = f(x as i64, s[q]).min(BIG);
                hf[x] = gf[s[q]];
                if q > 0 && x as i64 == t[q] {
                    q -= 1;
                }
            }
        }
    }
}

/// Computes a distance map of `occupied` (distance 0) over a grid of `dims`.
pub fn distance_map(
    dims: [usize; 3],
    occupied: &VoxelSet,
    metric: Metric,
    outside: Outside,
    nearest: bool,
) -> DistanceMap {
    let n = dims[0] * dims[1] * dims[2];
    assert_eq!(occupied.len(), n);
    let mut values: Vec<i64> = (0..n)
        .into_par_iter()
        .map(|i| if occupied.get(i) { 0 } else { BIG })
        .collect();
    let mut feats: Vec<u32> = (0..n)
        .into_par_iter()
        .map(|i| {
            if occupied.get(i) {
                i as u32
            } else {
                NO_FEATURE
            }
        })
        .collect();
    for axis in 0..3 {
        (values, feats) = separable_pass(dims, axis, &values, &feats, metric, outside);
    }
    DistanceMap {
        values: values
            .into_par_iter()
            .map(|v| if v >= BIG { INFINITE } else { v as u32 })
            .collect(),
        nearest: nearest.then_some(feats),
    }
}

/// Runs the 1-D transform on every line along `axis`, in parallel.
fn separable_pass(
    dims: [usize; 3],
    axis: usize,
    values: &[i64],
    feats: &[u32],
    metric: Metric,
    outside: Outside,
) -> (Vec<i64>, Vec<u32>) {
    let stride = [1, dims[0], dims[0] * dims[1]][axis];
    let len = dims[axis];
    let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
    let line_count = dims[a] * dims[b];
    let stride_a = [1, dims[0], dims[0] * dims[1]][a];
    let stride_b = [1, dims[0], dims[0] * dims[1]][b];
    let pad = usize::from(outside == Outside::Solid);
    // Results line by line (line-major), then scattered back.
    let lines: Vec<(Vec<i64>, Vec<u32>)> = (0..line_count)
        .into_par_iter()
        .map_init(
            || {
                (
                    vec![0i64; len + 2],
                    vec![0u32; len + 2],
                    vec![0i64; len + 2],
                    vec![0u32; len + 2],
                )
            },
            |(g, gf, h, hf), line| {
                let start = (line % dims[a]) * stride_a + (line / dims[a]) * stride_b;
                let m = len + 2 * pad;
                if pad == 1 {
                    g[0] = 0;
                    gf[0] = NO_FEATURE;
                    g[m - 1] = 0;
                    gf[m - 1] = NO_FEATURE;
                }
                for i in 0..len {
                    g[i + pad] = values[start + i * stride];
                    gf[i + pad] = feats[start + i * stride];
                }
                transform_line(metric, &g[..m], &gf[..m], &mut h[..m], &mut hf[..m]);
                (h[pad..pad + len].to_vec(), hf[pad..pad + len].to_vec())
            },
        )
        .collect();
    let n = values.len();
    let mut out_v = vec![0i64; n];
    let mut out_f = vec![0u32; n];
    // Scatter: each z-slab (contiguous) in parallel.
    let slab = dims[0] * dims[1];
    out_v
        .par_chunks_mut(slab)
        .zip(out_f.par_chunks_mut(slab))
        .enumerate()
        .for_each(|(z, (sv, sf))| {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let c = [x, y, z];
                    let line = c[a] + dims[a] * c[b];
                    sv[x + dims[0] * y] = lines[line].0[c[axis]];
                    sf[x + dims[0] * y] = lines[line].1[c[axis]];
                }
            }
        });
    (out_v, out_f)
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

    #[test]
    fn distance_maps_equal_brute_force() {
        let mut rng = Rng::new(5, 5);
        for dims in [[1, 1, 1], [7, 1, 1], [5, 6, 7], [9, 4, 11], [16, 16, 3]] {
            let n = dims[0] * dims[1] * dims[2];
            for density in [0.0f32, 0.02, 0.2, 0.7] {
                let mut occ = VoxelSet::new(n);
                for i in 0..n {
                    if rng.uniform() < density {
                        occ.set(i);
                    }
                }
                for metric in [Metric::L1, Metric::Chessboard, Metric::SquaredEuclidean] {
                    for outside in [Outside::Solid, Outside::Empty] {
                        let got = distance_map(dims, &occ, metric, outside, true);
                        let want = brute(dims, &occ, metric, outside);
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
