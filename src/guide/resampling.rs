//! Vertex-connection resampling distributions of SkelBPT (002 §4.2-4.4): per skeleton node and
//! light subpath length, one discrete distribution over the light vertices of a subset of an
//! iteration's light subpaths, from which each camera vertex mapped to the node picks the light
//! vertex it connects to.
//!
//! Three distributions are combined (002 eq. 6-8), for a node at P_n and the light vertices
//! y_i of one length with partial contributions L(y_i):
//! - p_V(i) ∝ V(y_i, P_n) w_n(y_i), w_n(y) = L(y) / |P_n - y|^2 (visible from the node);
//! - p_U(i) ∝ w_n(y_i) (the same without visibility);
//! - p_C(i) = 1 / n (uniform over the subpaths that have a vertex of this length).
//!
//! They are combined with the max heuristic premultiplied into the distributions (002 line
//! 171): each vertex belongs to the distribution that gives it the highest probability, each
//! distribution keeps only its own vertices, renormalized, and a distribution is chosen
//! uniformly among the non-empty ones. 002 chooses among all three with probability 1/3; an
//! empty one (no vertex visible, or none it wins) would then give no sample, so choosing among
//! the non-empty ones is the same estimator with fewer wasted connections. The result is one
//! distribution q over the vertices, stored as a CDF with the winning distribution of each
//! vertex (for the per-distribution images of 002 Figure 10). Every vertex has
//! q(i) >= 1 / (3 n): its winning probability is at least p_C(i) = 1 / n and the
//! renormalization only raises it. So no vertex with a contribution is left out, which makes
//! the estimator unbiased: E[C(y) / (N q(y))] = (1/N) sum_i C(y_i).

use crate::error::{Error, Result};

/// SkelBPT's options (002 §5 defaults).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ResamplingSettings {
    /// Light subpaths resampled from per iteration (N, 002 §5: 1024), the first N of the
    /// iteration's (they are independent, so any N are a random subset).
    pub subset: u32,
    /// Node acceptance alpha_accept (002 §4.4): nodes mapped to no more than alpha_accept times
    /// the mean number of camera vertices per node (over the iterations so far) get no
    /// distribution in an iteration; camera vertices mapped to them resample uniformly.
    pub accept: f32,
    /// Adds the per-distribution contribution images (002 Figure 10).
    pub images: bool,
    /// ICBPT (`bdpt_ic`): importance records come from the eye subpaths of this fraction d of
    /// the pixels per iteration (002 §5: 0.001), at least one subpath.
    pub density: f32,
    /// MIS sample count of the resampled connection strategies (s >= 2, t >= 2).
    pub count: ConnectionCount,
}

/// How many samples the MIS weights credit a resampled connection strategy with, against the
/// strategies that take one (s = 0, next-event estimation s = 1) and light tracing. Any
/// constant keeps the estimate unbiased (the weights still sum to one over the strategies);
/// it only decides which strategy carries a path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConnectionCount {
    /// N, the subset size: the count of the estimator connecting every camera vertex to all N
    /// subpaths (000 eq. 185), which the resampled one only estimates with one connection. It
    /// hands next-event estimation's paths to the resampled s = 2 connections, whose one
    /// pick then carries them at up to 20x `bdpt`'s variance (BENCHMARKS.md, issue 31).
    Subset,
    /// One (the default): a resampled connection samples one path per strategy and camera
    /// vertex (002 line 196 counts the paths each strategy samples), weighted as `bdpt`'s.
    One,
}

impl Default for ResamplingSettings {
    fn default() -> Self {
        ResamplingSettings {
            subset: 1024,
            accept: 1.0,
            images: false,
            density: 0.001,
            count: ConnectionCount::One,
        }
    }
}

/// Option keys of [`ResamplingSettings::set`].
pub const RESAMPLING_KEYS: &[&str] = &["subset", "accept", "images", "density", "count"];

impl ResamplingSettings {
    /// Sets one option from text: `subset=N` (N >= 1), `accept=ALPHA` (ALPHA >= 0, finite),
    /// `images=true|false`, `density=D` (0 < D <= 1), `count=subset|one`.
    pub fn set(&mut self, key: &str, value: &str) -> Result<()> {
        match key {
            "count" => {
                self.count = match value {
                    "subset" => ConnectionCount::Subset,
                    "one" | "1" => ConnectionCount::One,
                    _ => {
                        return Err(Error::invalid(format!(
                            "count={value} must be subset or one"
                        )))
                    }
                };
                Ok(())
            }
            "subset" => self.set_subset(value.parse().map_err(|_| {
                Error::invalid(format!("subset={value} must be a positive integer"))
            })?),
            "accept" => self.set_accept(
                value
                    .parse()
                    .map_err(|_| Error::invalid(format!("accept={value} must be a number")))?,
            ),
            "density" => self.set_density(
                value
                    .parse()
                    .map_err(|_| Error::invalid(format!("density={value} must be a number")))?,
            ),
            "images" => {
                self.images = match value {
                    "true" | "1" | "on" => true,
                    "false" | "0" | "off" => false,
                    _ => {
                        return Err(Error::invalid(format!(
                            "images={value} must be true or false"
                        )))
                    }
                };
                Ok(())
            }
            other => Err(Error::invalid(format!(
                "no resampling option '{other}' (bdpt_skeleton: subset, accept, images, \
                 count, resolution, voxel_budget; bdpt_ic: subset, density, images, count)"
            ))),
        }
    }

    /// MIS sample count of the connection strategies with `light_paths` subpaths traced.
    pub fn connection_count(&self, light_paths: usize) -> f32 {
        match self.count {
            ConnectionCount::Subset => (self.subset as usize).min(light_paths).max(1) as f32,
            ConnectionCount::One => 1.0,
        }
    }

    /// `subset`: light subpaths resampled from, 1..=2^24.
    pub fn set_subset(&mut self, n: u32) -> Result<()> {
        if n == 0 || n > 1 << 24 {
            return Err(Error::invalid(format!(
                "subset={n} must be within 1..=16777216 light subpaths"
            )));
        }
        self.subset = n;
        Ok(())
    }

    /// `accept`: node acceptance alpha_accept, finite and >= 0.
    pub fn set_accept(&mut self, a: f32) -> Result<()> {
        if !(a.is_finite() && a >= 0.0) {
            return Err(Error::invalid(format!(
                "accept={a} must be a finite number >= 0 (002: 0..1, default 1)"
            )));
        }
        self.accept = a;
        Ok(())
    }

    /// `density`: the fraction of pixels placing importance records, in (0, 1].
    pub fn set_density(&mut self, d: f32) -> Result<()> {
        if !(d > 0.0 && d <= 1.0) {
            return Err(Error::invalid(format!(
                "density={d} must be in (0, 1]: the fraction of pixels whose eye \
                 subpaths place importance records (002: 0.001)"
            )));
        }
        self.density = d;
        Ok(())
    }
}

/// Which distribution a vertex's probability came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Origin {
    /// p_V: visible from the node, by weight.
    Visibility = 0,
    /// p_U: by weight.
    Weight = 1,
    /// p_C: uniform.
    Uniform = 2,
    /// The node had no distribution this iteration (or the vertex mapped to no node): uniform.
    Fallback = 3,
}

impl Origin {
    pub const ALL: [Origin; 4] = [
        Origin::Visibility,
        Origin::Weight,
        Origin::Uniform,
        Origin::Fallback,
    ];

    pub fn from_u8(v: u8) -> Origin {
        match v {
            0 => Origin::Visibility,
            1 => Origin::Weight,
            2 => Origin::Uniform,
            _ => Origin::Fallback,
        }
    }

    /// Name of its contribution image.
    pub fn layer_name(self) -> &'static str {
        match self {
            Origin::Visibility => "resampled_visibility",
            Origin::Weight => "resampled_distance",
            Origin::Uniform => "resampled_uniform",
            Origin::Fallback => "resampled_fallback",
        }
    }
}

/// Writes the combined distribution of one node and length (module docs) over vertices with
/// weights `weights` (w_n, finite and >= 0) and visibility `visible`: `cdf` its running sum
/// (ending at 1 up to rounding) and `origins` each vertex's distribution. Empty inputs write
/// nothing.
pub fn combined_distribution(
    weights: &[f32],
    visible: &[bool],
    cdf: &mut [f32],
    origins: &mut [u8],
) {
    let n = weights.len();
    debug_assert!(visible.len() == n && cdf.len() == n && origins.len() == n);
    if n == 0 {
        return;
    }
    let sum_w: f64 = weights.iter().map(|&w| w as f64).sum();
    let sum_vw: f64 = weights
        .iter()
        .zip(visible)
        .filter(|(_, &v)| v)
        .map(|(&w, _)| w as f64)
        .sum();
    let p_c = 1.0 / n as f64;
    let probs = |i: usize| -> [f64; 3] {
        let w = weights[i] as f64;
        let p_v = if visible[i] && sum_vw > 0.0 {
            w / sum_vw
        } else {
            0.0
        };
        let p_u = if sum_w > 0.0 { w / sum_w } else { 0.0 };
        [p_v, p_u, p_c]
    };
    // Max heuristic: the winner of each vertex (ties to the earlier distribution).
    let mut mass = [0.0f64; 3];
    for (i, origin) in origins.iter_mut().enumerate() {
        let p = probs(i);
        let mut best = 0;
        for x in 1..3 {
            if p[x] > p[best] {
                best = x;
            }
        }
        *origin = best as u8;
        mass[best] += p[best];
    }
    let chosen = mass.iter().filter(|&&m| m > 0.0).count() as f64;
    let mut running = 0.0f64;
    for (i, c) in cdf.iter_mut().enumerate() {
        let x = origins[i] as usize;
        running += probs(i)[x] / mass[x] / chosen;
        *c = running as f32;
    }
}

/// Picks a vertex from a CDF written by [`combined_distribution`] (or any non-decreasing CDF
/// whose steps are all positive) with `u` in [0, 1): its index and probability.
#[inline]
pub fn sample_cdf(cdf: &[f32], u: f32) -> (usize, f32) {
    let n = cdf.len();
    debug_assert!(n > 0);
    let total = cdf[n - 1];
    let target = u * total;
    let i = cdf.partition_point(|&c| c <= target).min(n - 1);
    (i, probability(cdf, i))
}

/// Buckets of a guide table ([`cdf_guide`]) for a CDF of `n` entries: a power of two near
/// `n` (so one bucket spans about one entry), at most [`MAX_GUIDE_BUCKETS`].
pub fn guide_buckets(n: usize) -> usize {
    n.next_power_of_two().clamp(1, MAX_GUIDE_BUCKETS)
}

/// Most buckets of a guide table (a power of two: `u * K` and `k / K` must be exact in f32).
pub const MAX_GUIDE_BUCKETS: usize = 1 << 12;

/// Writes the guide table of `cdf` (Chen's cutpoint method): `guide[k]`, k = 0..=K with
/// K = `guide.len() - 1` buckets ([`guide_buckets`]), is the index [`sample_cdf`]'s search
/// returns for the target (k / K) total. [`sample_cdf_guided`] then searches only between two
/// neighbouring entries, a bucket of about one CDF entry, instead of the whole CDF: the
/// binary search's chain of dependent loads was most of SkelBPT's own time per camera vertex
/// (BENCHMARKS.md, issue 31).
pub fn cdf_guide(cdf: &[f32], guide: &mut [u32]) {
    let n = cdf.len();
    let buckets = guide.len() - 1;
    debug_assert!(n > 0 && buckets.is_power_of_two() && buckets <= MAX_GUIDE_BUCKETS);
    let total = cdf[n - 1];
    let mut i = 0;
    for (k, g) in guide.iter_mut().enumerate() {
        let bound = (k as f32 / buckets as f32) * total;
        while i < n && cdf[i] <= bound {
            i += 1;
        }
        *g = i as u32;
    }
}

/// [`sample_cdf`] with the guide table of the same CDF ([`cdf_guide`]): the same index for
/// every `u` in [0, 1), so the same image. With K a power of two, `u K` is exact, so
/// k = floor(u K) has k / K <= u < (k + 1) / K exactly, and rounding the products with the
/// total keeps the order: bound_k <= u total <= bound_(k+1). The whole CDF's search result
/// therefore lies in `guide[k]..=guide[k + 1]`.
#[inline]
pub fn sample_cdf_guided(cdf: &[f32], guide: &[u32], u: f32) -> (usize, f32) {
    let n = cdf.len();
    let buckets = guide.len() - 1;
    debug_assert!(n > 0 && (0.0..1.0).contains(&u));
    let total = cdf[n - 1];
    let target = u * total;
    let k = ((u * buckets as f32) as usize).min(buckets - 1);
    let lo = guide[k] as usize;
    let hi = (guide[k + 1] as usize).min(n);
    let i = (lo + cdf[lo.min(hi)..hi].partition_point(|&c| c <= target)).min(n - 1);
    (i, probability(cdf, i))
}

/// Probability of vertex `i` of a CDF.
#[inline]
pub fn probability(cdf: &[f32], i: usize) -> f32 {
    let below = if i == 0 { 0.0 } else { cdf[i - 1] };
    (cdf[i] - below) / cdf[cdf.len() - 1]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    /// Each vertex's probability of being picked (over a fine grid of u), times the factor
    /// 1 / (N q) it then gets, summed over vertices with any contributions C: the unresampled
    /// estimate (1/N) sum C, up to the grid's resolution. Also checks the probabilities
    /// against an independent evaluation of 002 eq. 6-9 with the max heuristic (three
    /// distributions, one picked among the non-empty ones, weight 1 for the winner only).
    fn check(weights: &[f32], visible: &[bool], contributions: &[f64], label: &str) {
        let n = weights.len();
        let mut cdf = vec![0.0; n];
        let mut origins = vec![0u8; n];
        combined_distribution(weights, visible, &mut cdf, &mut origins);
        // Brute force: picked how often, over a grid of u.
        const GRID: usize = 1 << 20;
        let mut picked = vec![0usize; n];
        for k in 0..GRID {
            let u = (k as f32 + 0.5) / GRID as f32;
            let (i, p) = sample_cdf(&cdf, u);
            assert!(p > 0.0, "{label}: picked vertex {i} with probability 0");
            picked[i] += 1;
        }
        let big_n = 1024.0;
        let mut resampled = 0.0;
        let reference: f64 = contributions.iter().sum::<f64>() / big_n;
        for i in 0..n {
            let chance = picked[i] as f64 / GRID as f64;
            let q = probability(&cdf, i) as f64;
            assert!(
                (chance - q).abs() < 1e-5 + 1e-4 * q,
                "{label}: vertex {i} picked with {chance}, q = {q}"
            );
            assert!(
                q >= 1.0 / (3.0 * n as f64) * (1.0 - 1e-4),
                "{label}: q {q} < 1/3n"
            );
            resampled += chance * contributions[i] / (big_n * q);
        }
        assert!(
            (resampled - reference).abs() <= 1e-4 * reference.abs() + 1e-12,
            "{label}: resampled {resampled}, unresampled {reference}"
        );
        // Independent 002 eq. 6-9: p_V, p_U, p_C; max-heuristic weights; X uniform among the
        // distributions that win any vertex.
        let w: Vec<f64> = weights.iter().map(|&w| w as f64).collect();
        let sum_w: f64 = w.iter().sum();
        let sum_vw: f64 = (0..n).filter(|&i| visible[i]).map(|i| w[i]).sum();
        let dists: Vec<Vec<f64>> = vec![
            (0..n)
                .map(|i| {
                    if visible[i] && sum_vw > 0.0 {
                        w[i] / sum_vw
                    } else {
                        0.0
                    }
                })
                .collect(),
            (0..n)
                .map(|i| if sum_w > 0.0 { w[i] / sum_w } else { 0.0 })
                .collect(),
            vec![1.0 / n as f64; n],
        ];
        let winner =
            |i: usize| (0..3).fold(0, |b, x| if dists[x][i] > dists[b][i] { x } else { b });
        let wins: Vec<bool> = (0..3).map(|x| (0..n).any(|i| winner(i) == x)).collect();
        let k = wins.iter().filter(|&&b| b).count() as f64;
        for i in 0..n {
            let x = winner(i);
            assert_eq!(origins[i] as usize, x, "{label}: origin of {i}");
            let mass: f64 = (0..n)
                .filter(|&j| winner(j) == x)
                .map(|j| dists[x][j])
                .sum();
            let q = dists[x][i] / mass / k;
            let ours = probability(&cdf, i) as f64;
            // The CDF is f32: its steps carry the running sum's rounding (~1e-7 absolute). The
            // factor uses the step itself, which is what the sampler draws with (checked above).
            assert!(
                (q - ours).abs() <= 1e-4 * q,
                "{label}: q({i}) {ours} vs {q}"
            );
        }
    }

    #[test]
    fn resampling_gives_the_unresampled_estimate_exactly() {
        let mut rng = Rng::new(7, 0);
        // Random weights, visibility and contributions, several sizes.
        for n in [1, 2, 3, 7, 40, 300] {
            let weights: Vec<f32> = (0..n)
                .map(|_| {
                    let u = rng.uniform();
                    u * u * u * 50.0
                })
                .collect();
            let visible: Vec<bool> = (0..n).map(|_| rng.uniform() < 0.4).collect();
            let c: Vec<f64> = (0..n).map(|_| rng.uniform() as f64 * 3.0).collect();
            check(&weights, &visible, &c, &format!("random n={n}"));
        }
        // Edge cases: nothing visible; everything visible; all weights zero; ties; one
        // vertex with all the weight.
        let c = vec![1.0, 0.5, 2.0, 0.0, 4.0];
        check(&[1.0, 2.0, 3.0, 4.0, 5.0], &[false; 5], &c, "none visible");
        check(&[1.0, 2.0, 3.0, 4.0, 5.0], &[true; 5], &c, "all visible");
        check(
            &[0.0; 5],
            &[true, false, true, false, true],
            &c,
            "zero weights",
        );
        check(&[1.0; 5], &[true; 5], &c, "ties");
        check(
            &[0.0, 0.0, 9.0, 0.0, 0.0],
            &[false, false, true, false, false],
            &c,
            "one",
        );
    }

    /// The check can fail: a factor that forgets the premultiplied renormalization (uses the
    /// raw winning probability instead of q) moves the estimate.
    #[test]
    fn the_brute_force_check_catches_a_wrong_probability() {
        let weights = [1.0, 2.0, 3.0, 4.0, 50.0];
        let visible = [true, false, true, false, false];
        let mut cdf = [0.0; 5];
        let mut origins = [0u8; 5];
        combined_distribution(&weights, &visible, &mut cdf, &mut origins);
        let c = [1.0, 1.0, 1.0, 1.0, 1.0];
        let sum_w: f32 = weights.iter().sum();
        let wrong: f64 = (0..5)
            .map(|i| {
                let q = probability(&cdf, i) as f64;
                // The p_U probability of the vertex instead of q.
                q * c[i] / (weights[i] / sum_w).max(1e-6) as f64
            })
            .sum();
        let right: f64 = c.iter().sum();
        assert!((wrong - right).abs() > 0.1 * right, "{wrong} vs {right}");
    }

    /// The guided search picks exactly what the whole CDF's search picks, for every u on a
    /// fine grid and at the bucket edges, on CDFs with steep steps, flat runs (zero steps) and
    /// every size from 1 to beyond the bucket cap.
    #[test]
    fn guided_search_picks_what_the_whole_search_picks() {
        let mut rng = Rng::new(11, 0);
        for n in [1, 2, 3, 5, 8, 17, 100, 1000, 5000] {
            for shape in 0..3 {
                let weights: Vec<f32> = (0..n)
                    .map(|i| {
                        let u = rng.uniform();
                        match shape {
                            0 => u,
                            1 => u.powi(8) * 1e4,
                            _ => (i % 7 == 0) as u32 as f32 * u + 1e-7,
                        }
                    })
                    .collect();
                let visible: Vec<bool> = (0..n).map(|_| rng.uniform() < 0.3).collect();
                let mut cdf = vec![0.0; n];
                let mut origins = vec![0u8; n];
                combined_distribution(&weights, &visible, &mut cdf, &mut origins);
                let mut guide = vec![0u32; guide_buckets(n) + 1];
                cdf_guide(&cdf, &mut guide);
                let buckets = (guide.len() - 1) as f32;
                let edges = (0..guide.len() - 1).flat_map(|k| {
                    let e = k as f32 / buckets;
                    [e, f32::from_bits(e.to_bits().saturating_sub(1)).max(0.0)]
                });
                let grid = (0..1 << 16).map(|k| (k as f32 + 0.5) / (1 << 16) as f32);
                let last = [1.0 - f32::EPSILON / 2.0, 0.0];
                for u in grid.chain(edges).chain(last) {
                    assert_eq!(
                        sample_cdf_guided(&cdf, &guide, u),
                        sample_cdf(&cdf, u),
                        "n {n}, shape {shape}, u {u}"
                    );
                }
            }
        }
    }

    #[test]
    fn options_parse_and_reject_bad_values() {
        let mut s = ResamplingSettings::default();
        s.set("subset", "64").unwrap();
        s.set("accept", "0.5").unwrap();
        s.set("images", "true").unwrap();
        s.set("density", "0.01").unwrap();
        s.set("count", "subset").unwrap();
        assert_eq!(
            s,
            ResamplingSettings {
                subset: 64,
                accept: 0.5,
                images: true,
                density: 0.01,
                count: ConnectionCount::Subset,
            }
        );
        for (k, v) in [
            ("subset", "0"),
            ("subset", "-3"),
            ("accept", "-1"),
            ("accept", "nan"),
            ("accept", "inf"),
            ("images", "maybe"),
            ("density", "0"),
            ("density", "1.5"),
            ("density", "nan"),
            ("count", "two"),
            ("radius", "2"),
        ] {
            let err = s.set(k, v).unwrap_err().to_string();
            assert!(err.contains(k), "{k}={v}: {err}");
        }
    }
}
