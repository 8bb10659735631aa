//! `directions=learned`: a directional distribution per skeleton node, learned from the
//! training pass's samples (issue 8), that replaces the node's lobes.
//!
//! The lobes aim at importance points and openings found by geometry; they cost a mapping, an
//! aim per lobe, spherical rectangles and visibility per guided point (~3 k instructions), and
//! they point where light *may* come from, not where the training saw it come from. Here each
//! trained node gets, per class of point ([`class_of`]: the normal's dominant axis and sign,
//! then the quadrant of the point's offset from the node; a class with few samples takes its
//! parent's distribution), a piecewise-constant density over the sphere in world coordinates:
//! an equal-area histogram of `Z_BINS` x `PHI_BINS` bins, cylindrical in (z = cos theta, phi),
//! so every bin has the same solid angle 4 pi / `BINS`. Bin weights are the node's training
//! estimates of the light its samples carried, sum over the samples in the bin of f_i / q0_i
//! (the contribution proxy with the emission MIS-weighted at the training proposal, over the
//! proposal's density: an unbiased estimate of that bin's integral of f), blurred by a 3 x 3
//! tent (phi wraps around) and mixed with a uniform floor `FLOOR`, so every direction keeps a
//! positive density. Sampling picks a bin from the CDF and a uniform point in (z, phi) within
//! it (uniform in solid angle, the map being equal-area); its density is the bin's. At render
//! time a guided point needs its node only: no aim, no shadow ray. Directions below the surface
//! simply get a zero BSDF (`sample_bsdf_or_guide`). The distribution is a deterministic function
//! of the scene and the training pass, fixed before rendering, so the render stays unbiased.

use crate::math::{Vec2, Vec3};

/// Bins in z = cos theta and in phi.
pub const Z_BINS: usize = 12;
pub const PHI_BINS: usize = 24;
/// Bins of one distribution.
pub const BINS: usize = Z_BINS * PHI_BINS;
/// Share of the density that is uniform over the sphere, by default (`histogram_floor`).
/// 0.05 rather than 0.15: per sample it gains on all five test scenes (BENCHMARKS.md).
pub const FLOOR: f32 = 0.05;
/// Normal classes ([`class_of`]) and, within each, quadrants of the point's position.
pub const NORMALS: usize = 6;
pub const QUADRANTS: usize = 4;
/// Distributions per node: one per (normal class, quadrant) ([`class_of`]).
pub const CLASSES: usize = NORMALS * QUADRANTS;
/// Non-zero samples a class needs for its own histogram (else its parent's is used).
pub const MIN_CLASS_SAMPLES: usize = 16;
/// Share of the parent's distribution (the node's for a normal class, the normal class's for
/// a quadrant) mixed into a class's own.
pub const PARENT_SHARE: f64 = 0.25;

/// The class of a point at `offset` from its node's position whose normal, turned toward the
/// side the path arrives from, is `n`: the normal's dominant axis and sign (a node's region
/// holds floors, walls and ceilings; light arrives at each from its own hemisphere), then the
/// quadrant of the offset along the two other axes (light from an opening arrives from other
/// directions on either side of the node).
#[inline]
pub fn class_of(n: Vec3, offset: Vec3) -> usize {
    let a = n.abs();
    let (normal, u, v) = if a.x >= a.y && a.x >= a.z {
        ((n.x < 0.0) as usize, offset.y, offset.z)
    } else if a.y >= a.z {
        (2 + (n.y < 0.0) as usize, offset.x, offset.z)
    } else {
        (4 + (n.z < 0.0) as usize, offset.x, offset.y)
    };
    normal * QUADRANTS + 2 * (u < 0.0) as usize + (v < 0.0) as usize
}

const INV_4PI: f32 = 1.0 / (4.0 * std::f32::consts::PI);

/// The bin of unit direction `w`.
#[inline]
pub fn bin_of(w: Vec3) -> usize {
    // `as usize` of the row, through i32 (a shorter conversion than to u64 on x86-64): the
    // same row for every float, NaN and negatives 0 either way, anything above the last row
    // clamped to it.
    let z = ((((w.z + 1.0) * 0.5 * Z_BINS as f32) as i32).max(0) as usize).min(Z_BINS - 1);
    let p = phi_bin_fast(w.x, w.y).unwrap_or_else(|| phi_bin(w.x, w.y));
    z * PHI_BINS + p
}

/// The phi column of a direction (x, y, z): `(atan2(y, x) / 2 pi + 0.5) PHI_BINS` rounded
/// down (libm's `atan2f`), at most `PHI_BINS - 1`. This defines the bins.
#[cold]
#[inline(never)]
fn phi_bin(x: f32, y: f32) -> usize {
    let phi = y.atan2(x); // [-pi, pi]
    let p = ((phi * (0.5 / std::f32::consts::PI) + 0.5) * PHI_BINS as f32) as usize;
    p.min(PHI_BINS - 1)
}

/// How far from a column boundary (in columns) [`phi_bin_fast`] must land to answer.
const PHI_MARGIN: f32 = 1e-3;

/// [`phi_bin`] without libm, where that is certain: the column position from a polynomial
/// arctangent (error below 2e-5 radians, 1e-4 columns with the rounding; `atan2f` itself is
/// within a few ulps, below 1e-5 columns), `None` unless it lies more than `PHI_MARGIN` from
/// every column boundary (then both round down to the same column), and for zero, tiny, huge
/// or non-finite (x, y). `atan2f`, which every learned density evaluation called, was 3.7 %
/// of the guided render's time on the ajar; the columns, and so the
/// images, are the same.
#[inline]
fn phi_bin_fast(x: f32, y: f32) -> Option<usize> {
    use std::f32::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let (lo, hi) = if ay > ax { (ax, ay) } else { (ay, ax) };
    if !((1e-20..=1e20).contains(&hi)) {
        return None;
    }
    let r = atan_unit(lo / hi);
    let r = if ay > ax { FRAC_PI_2 - r } else { r };
    let r = if x < 0.0 { PI - r } else { r };
    let r = if y < 0.0 { -r } else { r };
    let s = (r * (0.5 / PI) + 0.5) * PHI_BINS as f32;
    // Within the range (so s > 0 and the truncation is the floor), then away from the
    // boundaries.
    if !(s > PHI_MARGIN && s < PHI_BINS as f32 - PHI_MARGIN) {
        return None;
    }
    // s in (0, PHI_BINS): the truncation through i32 is `as usize`'s, and shorter.
    let column = s as i32;
    let f = s - column as f32;
    (f > PHI_MARGIN && f < 1.0 - PHI_MARGIN).then_some(column as usize)
}

/// arctan(t) for t in [0, 1], within 2e-5 (Abramowitz and Stegun 4.4.49, |error| <= 1e-5).
#[inline(always)]
fn atan_unit(t: f32) -> f32 {
    let t2 = t * t;
    t * (0.999_866 + t2 * (-0.330_299_5 + t2 * (0.180_141 + t2 * (-0.085_133 + t2 * 0.020_835_1))))
}

/// Per node and normal class, a learned distribution; shared by every query.
#[derive(Clone, Debug, PartialEq)]
pub struct DirectionalTable {
    /// Per node: the slot of its first class in `pdf` / `cdf`, or `NONE` (not guided).
    slot: Vec<u32>,
    /// Per slot, `BINS` solid-angle densities.
    pdf: Vec<f32>,
    /// Per slot, `BINS` cumulative bin probabilities (non-decreasing, the last is 1).
    cdf: Vec<f32>,
    /// Per slot, the cumulative probability at the end of each z row of `cdf`, in one cache
    /// line: sampling finds the row here, then the bin in the row's `PHI_BINS` entries (three
    /// lines read instead of the binary search's five or more over the slot's 1,152 bytes).
    row_ends: Vec<RowEnds>,
}

/// [`DirectionalTable::row_ends`] of one slot: `Z_BINS` cumulative probabilities padded with
/// infinity (never <= a sample's `u_select`).
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(64))]
struct RowEnds([f32; ROW_ENDS]);

/// Entries of [`RowEnds`]: `Z_BINS` rounded up to a cache line of f32.
const ROW_ENDS: usize = 16;
const _: () = assert!(Z_BINS <= ROW_ENDS);

const NONE: u32 = u32::MAX;

impl DirectionalTable {
    /// The table of `distributions`: per node, `CLASSES` x `BINS` bin probabilities (each
    /// class's summing to 1: [`fit`]), or None.
    pub fn new(distributions: &[Option<Vec<f32>>]) -> DirectionalTable {
        Self::with_default(distributions, None)
    }

    /// As [`new`](Self::new), but every node without a distribution shares `default`
    /// (`CLASSES` x `BINS` bin probabilities, stored once) instead of being left out: a later
    /// training pass then also samples, and learns, the nodes the previous one never guided.
    pub fn with_default(
        distributions: &[Option<Vec<f32>>],
        default: Option<&[f32]>,
    ) -> DirectionalTable {
        let mut t = DirectionalTable {
            slot: Vec::with_capacity(distributions.len()),
            pdf: Vec::new(),
            cdf: Vec::new(),
            row_ends: Vec::new(),
        };
        let shared = default.map(|p| t.push(p));
        for d in distributions {
            let slot = match d {
                Some(p) => t.push(p),
                None => shared.unwrap_or(NONE),
            };
            t.slot.push(slot);
        }
        t
    }

    /// Appends one node's `CLASSES` distributions; returns the slot of the first.
    fn push(&mut self, p: &[f32]) -> u32 {
        assert_eq!(p.len(), CLASSES * BINS, "a node's distributions");
        let slot = (self.pdf.len() / BINS) as u32;
        for class in p.chunks_exact(BINS) {
            let mut acc = 0.0f64;
            for &x in class {
                self.pdf.push(x * BINS as f32 * INV_4PI);
                acc += x as f64;
                // At most 1 (a sum rounded above 1 before the last bin would break the
                // order the row search relies on; with a positive floor it never is).
                self.cdf.push((acc as f32).min(1.0));
            }
            // Exactly 1 at the end: the sampler's search then always finds a bin.
            *self.cdf.last_mut().expect("BINS > 0") = 1.0;
            let cdf = &self.cdf[self.cdf.len() - BINS..];
            let mut ends = RowEnds([f32::INFINITY; ROW_ENDS]);
            for (iz, end) in ends.0[..Z_BINS].iter_mut().enumerate() {
                *end = cdf[iz * PHI_BINS + PHI_BINS - 1];
            }
            self.row_ends.push(ends);
        }
        slot
    }

    /// The slot of `node`'s distribution for normal class `class`, if it has one.
    #[inline]
    pub fn slot(&self, node: u32, class: usize) -> Option<u32> {
        self.slot
            .get(node as usize)
            .copied()
            .filter(|&s| s != NONE)
            .map(|s| s + class as u32)
    }

    /// Solid-angle density of slot `slot` at unit direction `w`.
    #[inline]
    pub fn pdf(&self, slot: u32, w: Vec3) -> f32 {
        self.pdf[slot as usize * BINS + bin_of(w)]
    }

    /// A direction from slot `slot`: `u_select` picks the bin, `u` the point in it.
    pub fn sample(&self, slot: u32, u_select: f32, u: Vec2) -> Vec3 {
        let (iz, ip) = self.select_bin(slot, u_select);
        let z = (-1.0 + 2.0 * (iz as f32 + u.x) / Z_BINS as f32).clamp(-1.0, 1.0);
        let phi = std::f32::consts::PI * (2.0 * (ip as f32 + u.y) / PHI_BINS as f32 - 1.0);
        let r = (1.0 - z * z).max(0.0).sqrt();
        Vec3::new(r * phi.cos(), r * phi.sin(), z)
    }

    /// The (z row, phi column) of the first bin of slot `slot` whose cumulative probability
    /// exceeds `u_select` (the last bin if none does). The cdf is non-decreasing, so the entries
    /// `<= u_select` are a prefix: its length is the count of row ends `<= u_select` rows of
    /// `PHI_BINS` plus the count within the next row (a count of compares, no search).
    #[inline]
    fn select_bin(&self, slot: u32, u_select: f32) -> (usize, usize) {
        let rows = &self.row_ends[slot as usize].0;
        let iz = rows
            .iter()
            .filter(|&&c| c <= u_select)
            .count()
            .min(Z_BINS - 1);
        let start = slot as usize * BINS + iz * PHI_BINS;
        let row = &self.cdf[start..start + PHI_BINS];
        let ip = row
            .iter()
            .filter(|&&c| c <= u_select)
            .count()
            .min(PHI_BINS - 1);
        (iz, ip)
    }

    /// [`crate::math::prefetch`] of the line [`sample`](Self::sample) of slot `slot` reads
    /// first.
    #[inline]
    pub fn prefetch(&self, slot: u32) {
        if let Some(ends) = self.row_ends.get(slot as usize) {
            crate::math::prefetch(ends);
        }
    }

    /// Distributions stored (`CLASSES` per node).
    pub fn len(&self) -> usize {
        self.pdf.len() / BINS
    }

    pub fn is_empty(&self) -> bool {
        self.pdf.is_empty()
    }

    pub fn memory_bytes(&self) -> usize {
        self.slot.len() * 4
            + self.pdf.len() * 4
            + self.cdf.len() * 4
            + self.row_ends.len() * std::mem::size_of::<RowEnds>()
    }
}

/// A node's `CLASSES` x `BINS` bin probabilities from its samples (class, direction,
/// weight), a hierarchy: the node's [`bin_probabilities`]; per normal class its own mixed with
/// the node's (`PARENT_SHARE`); per quadrant its own mixed with its normal class's. A class
/// with fewer than `MIN_CLASS_SAMPLES` positive weights takes its parent's.
/// `floor` is each histogram's uniform share ([`bin_probabilities`]).
pub fn fit(samples: &[(usize, Vec3, f64)], floor: f32) -> Vec<f32> {
    fit_binned(samples.iter().filter_map(|&s| binned(s)), floor)
}

/// A sample (class, direction, weight) that [`fit`] counts, as (class, bin, weight): None
/// unless its weight is positive and finite.
#[inline]
pub fn binned((class, w, x): (usize, Vec3, f64)) -> Option<(u8, u16, f64)> {
    (x > 0.0 && x.is_finite()).then(|| (class as u8, bin_of(w) as u16, x))
}

/// [`fit`] of samples already [`binned`], in the same order: the same result, bit for bit
/// (a caller fitting several subsets of the same samples bins each sample once).
pub fn fit_binned(samples: impl Iterator<Item = (u8, u16, f64)>, floor: f32) -> Vec<f32> {
    // One pass over the samples fills every histogram of the hierarchy (each bin sums its
    // samples in their order, as one pass per class would: the same result, bit for bit).
    let mut node = vec![0.0f64; BINS];
    let mut by_normal = vec![0.0f64; NORMALS * BINS];
    let mut by_class = vec![0.0f64; CLASSES * BINS];
    let mut positive = [0usize; CLASSES];
    for (class, b, x) in samples {
        let (class, b) = (class as usize, b as usize);
        node[b] += x;
        by_normal[class / QUADRANTS * BINS + b] += x;
        by_class[class * BINS + b] += x;
        positive[class] += 1;
    }
    // The distribution of a histogram holding `own` positive weights mixed with `parent`, or
    // `parent` if `own` is below `MIN_CLASS_SAMPLES`.
    let refine = |parent: &[f32], h: &[f64], own: usize| -> Vec<f32> {
        if own < MIN_CLASS_SAMPLES {
            return parent.to_vec();
        }
        probabilities_of_histogram(h, floor)
            .iter()
            .zip(parent)
            .map(|(&a, &b)| ((1.0 - PARENT_SHARE) * a as f64 + PARENT_SHARE * b as f64) as f32)
            .collect()
    };
    let node = probabilities_of_histogram(&node, floor);
    let mut out = Vec::with_capacity(CLASSES * BINS);
    for normal in 0..NORMALS {
        let classes = normal * QUADRANTS..(normal + 1) * QUADRANTS;
        let own: usize = positive[classes.clone()].iter().sum();
        let parent = refine(&node, &by_normal[normal * BINS..(normal + 1) * BINS], own);
        for class in classes {
            let h = &by_class[class * BINS..(class + 1) * BINS];
            out.extend(refine(&parent, h, positive[class]));
        }
    }
    out
}

/// Bin probabilities (summing to 1) from weighted directions (weights >= 0, non-finite ones
/// ignored): the weights' histogram, blurred by a 3 x 3 tent (phi wraps, z clamps), mixed with
/// the uniform share `floor` (in (0, 1]: module docs). Uniform where no weight is positive.
pub fn bin_probabilities(samples: impl Iterator<Item = (Vec3, f64)>, floor: f32) -> Vec<f32> {
    let mut h = vec![0.0f64; BINS];
    for (w, x) in samples {
        if x > 0.0 && x.is_finite() {
            h[bin_of(w)] += x;
        }
    }
    probabilities_of_histogram(&h, floor)
}

/// [`bin_probabilities`] of the histogram `h` of the positive finite weights.
fn probabilities_of_histogram(h: &[f64], floor: f32) -> Vec<f32> {
    let mut blurred = vec![0.0f64; BINS];
    for iz in 0..Z_BINS {
        for ip in 0..PHI_BINS {
            let mut s = 0.0;
            for dz in -1i32..=1 {
                let z = iz as i32 + dz;
                if !(0..Z_BINS as i32).contains(&z) {
                    continue;
                }
                for dp in -1i32..=1 {
                    let p = (ip as i32 + dp).rem_euclid(PHI_BINS as i32) as usize;
                    let k = (2 - dz.abs()) * (2 - dp.abs());
                    s += k as f64 * h[z as usize * PHI_BINS + p];
                }
            }
            blurred[iz * PHI_BINS + ip] = s;
        }
    }
    let total: f64 = blurred.iter().sum();
    let uniform = 1.0 / BINS as f64;
    if !(total > 0.0 && total.is_finite()) {
        return vec![uniform as f32; BINS];
    }
    let floor = floor as f64;
    blurred
        .iter()
        .map(|&b| ((1.0 - floor) * b / total + floor * uniform) as f32)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{Rng, Sampler};

    fn lobe_table() -> DirectionalTable {
        let mut rng = Sampler::independent(Rng::new(3, 4));
        let axis = Vec3::new(0.3, -0.6, 0.5).normalize();
        let samples: Vec<(Vec3, f64)> = (0..4000)
            .map(|_| {
                let w = crate::math::warp::uniform_sphere(rng.uniform2());
                (w, (w.dot(axis).max(0.0) as f64).powi(8))
            })
            .collect();
        let p = bin_probabilities(samples.into_iter(), FLOOR);
        DirectionalTable::new(&[
            None,
            Some(p.repeat(CLASSES)),
            Some(vec![1.0 / BINS as f32; CLASSES * BINS]),
        ])
    }

    /// Nodes without a distribution share the default's slots (stored once); their own
    /// nodes keep theirs; without a default they have none.
    #[test]
    fn nodes_without_a_distribution_share_the_default() {
        let uniform = vec![1.0 / BINS as f32; CLASSES * BINS];
        let mut peaked = uniform.clone();
        peaked[7] += 1.0;
        let nodes = [None, Some(peaked.clone()), None];
        let t = DirectionalTable::with_default(&nodes, Some(&uniform));
        assert_eq!(t.len(), 2 * CLASSES);
        assert_eq!(t.slot(0, 3), t.slot(2, 3));
        assert_eq!(t.slot(1, 0), Some(CLASSES as u32));
        let own = DirectionalTable::new(&[Some(peaked)]);
        let w = Vec3::new(0.2, -0.5, 0.8).normalize();
        assert_eq!(t.pdf(t.slot(1, 2).unwrap(), w), own.pdf(0, w));
        assert_eq!(t.pdf(t.slot(0, 2).unwrap(), w), INV_4PI);
        assert_eq!(DirectionalTable::new(&nodes).slot(0, 0), None);
    }

    /// The polynomial arctangent stays within its stated error on [0, 1].
    #[test]
    fn atan_unit_is_within_its_bound() {
        let mut worst = 0.0f64;
        for i in 0..=1_000_000 {
            let t = i as f32 / 1_000_000.0;
            worst = worst.max((atan_unit(t) as f64 - (t as f64).atan()).abs());
        }
        assert!(worst < 2e-5, "{worst}");
    }

    /// The fast column is libm's wherever it answers: random directions (and their
    /// neighbours in phi), directions at and next to every column boundary, both signs of
    /// zero, the axes; and it answers for nearly all random directions.
    #[test]
    fn fast_phi_column_is_libms() {
        let mut rng = Sampler::independent(Rng::new(9, 10));
        let mut answered = 0usize;
        let n = 2_000_000;
        for _ in 0..n {
            let w = crate::math::warp::uniform_sphere(rng.uniform2());
            if let Some(p) = phi_bin_fast(w.x, w.y) {
                assert_eq!(p, phi_bin(w.x, w.y), "{w}");
                answered += 1;
            }
        }
        assert!(answered as f64 > 0.99 * n as f64, "{answered}");
        let mut cases: Vec<(f32, f32)> = vec![
            (0.0, 0.0),
            (-0.0, 0.0),
            (0.0, -0.0),
            (-0.0, -0.0),
            (1.0, 0.0),
            (-1.0, 0.0),
            (-1.0, -0.0),
            (0.0, 1.0),
            (0.0, -1.0),
            (f32::NAN, 0.5),
            (f32::INFINITY, 1.0),
            (1e-30, 1e-30),
        ];
        for k in 0..=PHI_BINS {
            let phi =
                -std::f64::consts::PI + 2.0 * std::f64::consts::PI * k as f64 / PHI_BINS as f64;
            for d in -200i32..=200 {
                let a = phi + d as f64 * 1e-7;
                for r in [1.0f64, 0.3, 1e-3] {
                    cases.push(((r * a.cos()) as f32, (r * a.sin()) as f32));
                }
            }
        }
        for (x, y) in cases {
            if let Some(p) = phi_bin_fast(x, y) {
                assert_eq!(p, phi_bin(x, y), "({x}, {y})");
            }
        }
    }

    /// The row search picks the bin of a binary search over the slot's whole cdf, for random
    /// `u_select` and for every cdf entry itself (the boundaries), on peaked and uniform slots.
    #[test]
    fn row_search_selects_the_bin_of_the_binary_search() {
        let t = lobe_table();
        let mut rng = Sampler::independent(Rng::new(7, 8));
        for slot in [0u32, 5, CLASSES as u32, 2 * CLASSES as u32 - 1] {
            let cdf = &t.cdf[slot as usize * BINS..(slot as usize + 1) * BINS];
            assert!(cdf.windows(2).all(|w| w[0] <= w[1]));
            let mut us: Vec<f32> = (0..20_000).map(|_| rng.uniform()).collect();
            // The neighbouring floats of a positive c.
            let down = |c: f32| f32::from_bits(c.to_bits() - 1);
            let up = |c: f32| f32::from_bits(c.to_bits() + 1);
            for &c in cdf {
                us.extend([c, down(c), up(c)]);
            }
            us.extend([0.0, down(1.0), 1.0]);
            for u in us {
                let bin = cdf.partition_point(|&c| c <= u).min(BINS - 1);
                assert_eq!(
                    t.select_bin(slot, u),
                    (bin / PHI_BINS, bin % PHI_BINS),
                    "{u}"
                );
            }
        }
    }

    /// `fit`'s one pass gives, bit for bit, the hierarchy built class by class from
    /// `bin_probabilities` of each class's samples (the definition), on samples with classes
    /// below and above `MIN_CLASS_SAMPLES`, zero and non-finite weights.
    #[test]
    fn fit_in_one_pass_is_the_hierarchy_of_bin_probabilities() {
        let mut rng = Sampler::independent(Rng::new(7, 8));
        let samples: Vec<(usize, Vec3, f64)> = (0..3000)
            .map(|i| {
                // Normal classes 0..3 often (their quadrants skewed), 4 and 5 rarely.
                let class = if i % 50 == 0 {
                    16 + i % 8
                } else {
                    (rng.uniform() * rng.uniform() * 16.0) as usize
                };
                let w = crate::math::warp::uniform_sphere(rng.uniform2());
                let x = match i % 7 {
                    0 => 0.0,
                    1 if i % 3 == 0 => f64::INFINITY,
                    _ => (rng.uniform() as f64).powi(4) * 10.0,
                };
                (class, w, x)
            })
            .collect();
        let floor = 0.05;
        let refine = |parent: &[f32], keep: &dyn Fn(usize) -> bool| -> Vec<f32> {
            let own = samples
                .iter()
                .filter(|s| keep(s.0) && s.2 > 0.0 && s.2.is_finite())
                .count();
            if own < MIN_CLASS_SAMPLES {
                return parent.to_vec();
            }
            let p = bin_probabilities(
                samples
                    .iter()
                    .filter(|s| keep(s.0))
                    .map(|&(_, w, x)| (w, x)),
                floor,
            );
            p.iter()
                .zip(parent)
                .map(|(&a, &b)| ((1.0 - PARENT_SHARE) * a as f64 + PARENT_SHARE * b as f64) as f32)
                .collect()
        };
        let node = bin_probabilities(samples.iter().map(|&(_, w, x)| (w, x)), floor);
        let mut expected = Vec::new();
        let mut own_classes = 0;
        for normal in 0..NORMALS {
            let by_normal = refine(&node, &|c| c / QUADRANTS == normal);
            for class in normal * QUADRANTS..(normal + 1) * QUADRANTS {
                let p = refine(&by_normal, &|c| c == class);
                own_classes += (p != by_normal) as usize;
                expected.extend(p);
            }
        }
        // Some classes have their own histogram, some take their parent's.
        assert!(own_classes > 4 && own_classes < CLASSES, "{own_classes}");
        assert_eq!(fit(&samples, floor), expected);
    }

    #[test]
    fn bins_are_where_sampling_puts_them_and_pdf_integrates_to_one() {
        let t = lobe_table();
        assert_eq!(t.slot(0, 0), None);
        assert_eq!(t.slot(2, 1), Some(CLASSES as u32 + 1));
        assert_eq!(t.len(), 2 * CLASSES);
        // The pdf is constant per bin of equal solid angle: its integral is the mean over bins.
        for slot in 0..2 * CLASSES {
            let base = slot * BINS;
            let integral: f32 =
                t.pdf[base..base + BINS].iter().sum::<f32>() * 4.0 * std::f32::consts::PI
                    / BINS as f32;
            assert!((integral - 1.0).abs() < 1e-4, "{integral}");
            assert!(t.pdf[base..base + BINS].iter().all(|&p| p > 0.0));
        }
        // Sampled directions are unit and land in the bin their u_select picked.
        let mut rng = Sampler::independent(Rng::new(5, 6));
        for _ in 0..10_000 {
            let w = t.sample(0, rng.uniform(), rng.uniform2());
            assert!((w.length() - 1.0).abs() < 1e-4);
            assert!(t.pdf(0, w) > 0.0);
        }
    }
}
