//! Per-node statistics of the training (module docs of `training`, "Estimator" to "Learned
//! directions"): the samples recorded at guided vertices, the reweighted second moment of
//! every candidate, the choice at each node, the fitted lobe weights and the learned
//! direction histograms.

use super::{Grid, MAX_STRENGTHS, TRAINING_C};
use crate::guide::directional::{self, DirectionalTable};
use crate::guide::TrainingCost;
use crate::guide::MAX_LOBES;
use crate::math::{MisHeuristic, Vec3};

/// Training samples a node needs before it may be guided (how many must be non-zero is the
/// settings' `training_min_nonzero`).
pub(super) const MIN_SAMPLES: u32 = 256;
/// Cost per guide shadow ray in unguided vertices (module docs; the cost of guiding beyond
/// that is the settings' `training_guided_cost`).
pub(super) const COST_SHADOW_RAY: f64 = 0.25;
/// Multiplicative updates of the lobe-weight fit, and the weight below which the fit drops a
/// lobe (module docs, "Lobe weights").
pub(super) const FIT_ITERATIONS: usize = 24;
pub(super) const FIT_FLOOR: f32 = 0.03;

/// One training sample at a guided vertex: the direction it sampled and its own light sample,
/// each with the densities every candidate's MIS weights need (module docs, "What is
/// measured").
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Sample {
    pub(super) node: u32,
    /// The sampled direction (world space), and the point's class (`directional::class_of`).
    pub(super) wi: Vec3,
    pub(super) class: u8,
    /// Luminance of beta f_s |cos| L_e along the sampled direction (the emission found at the
    /// next vertex or the environment's), unweighted; 0 where it found none.
    pub(super) f_emitted: f32,
    /// Luminance of beta f_s |cos| R, the radiance the rest of the path reflects toward x.
    pub(super) f_reflected: f32,
    pub(super) p_bsdf: f32,
    /// The skeleton mixture's density under the training proposal's strength.
    pub(super) p_skel: f32,
    /// The same under each candidate strength (the first `strengths` entries).
    pub(super) p_strength: [f32; MAX_STRENGTHS],
    /// Light sampling's density (pmf x pdf) of the emitter the direction hit; 0 if none.
    pub(super) p_light: f32,
    /// Next-event estimation at this vertex.
    pub(super) nee: NeeTerms,
    /// With `lobe_weights=learned`: each node lobe's density at the direction
    /// (`GuideQuery::node_lobe_pdfs`, negative where the lobe does not apply at x), and which
    /// lobes apply at x (bit j: lobe j).
    pub(super) p_lobes: [f32; MAX_LOBES],
    pub(super) active: u8,
    /// Shadow rays the guide traced for this vertex's query.
    pub(super) rays: u32,
    /// Vertices of the training path from this one to its end (module docs, "Cost").
    pub(super) remaining: u32,
    /// Its sampled direction's entry in the pass's [`Step`]s (`NO_STEP` where it has none or
    /// none are recorded).
    pub(super) step: u32,
}

/// [`Sample::step`] of a sample without a sampled direction's [`Step`].
pub(super) const NO_STEP: u32 = u32::MAX;

/// A vertex's light sample, as the candidates see it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct NeeTerms {
    /// Luminance of beta f_s |cos| L / p_light, unweighted (0 if occluded or no light).
    pub(super) value: f32,
    /// Its light density (infinite for delta lights: MIS weight 1).
    pub(super) p_light: f32,
    /// Its direction (world space).
    pub(super) wi: Vec3,
    /// The direction densities of its direction (BSDF, skeleton at s0, per candidate strength).
    pub(super) p_bsdf: f32,
    pub(super) p_skel: f32,
    pub(super) p_strength: [f32; MAX_STRENGTHS],
    /// Each node lobe's density at its direction (as `Sample::p_lobes`).
    pub(super) p_lobes: [f32; MAX_LOBES],
}

impl Default for NeeTerms {
    fn default() -> Self {
        NeeTerms {
            value: 0.0,
            p_light: 0.0,
            wi: Vec3::ZERO,
            p_bsdf: 0.0,
            p_skel: 0.0,
            p_strength: [0.0; MAX_STRENGTHS],
            p_lobes: [0.0; MAX_LOBES],
        }
    }
}

/// The skeleton mixture at a point where lobes `active` apply, under selection weights
/// `weights` (renormalised over those lobes, as `GuideQuery::init` does), at a direction where
/// the node's lobes have densities `p_lobes`; None where no lobe of positive weight applies
/// (the point is then not guided: BSDF sampling alone).
pub(super) fn lobe_mixture(
    p_lobes: &[f32; MAX_LOBES],
    active: u8,
    weights: &[f32; MAX_LOBES],
) -> Option<f32> {
    let (mut total, mut sum) = (0.0f32, 0.0f32);
    for j in 0..MAX_LOBES {
        if active & (1 << j) != 0 && weights[j] > 0.0 {
            total += weights[j];
            sum += weights[j] * p_lobes[j].max(0.0);
        }
    }
    (total > 0.0).then(|| sum / total)
}

/// One sample's share of the moments of the vertex's estimate under one candidate.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Terms {
    /// (D_c,s)² q_c,s / q_c0 + (N_c,s)²: its terms of the two second moments (module docs).
    pub(super) second: f64,
    /// D_c,s q_c,s / q_c0 and N_c,s: its terms of the two means.
    pub(super) mean_direction: f64,
    pub(super) mean_nee: f64,
}

impl Sample {
    /// Whether the sampled direction carried anything.
    pub(super) fn carries(&self) -> bool {
        self.f_emitted > 0.0 || self.f_reflected > 0.0
    }

    /// This sample's terms under candidate (c, strength index k) (module docs): the direction
    /// part reweighted from the training proposal, with the emission it found MIS-weighted as
    /// the render weighs it, and the light sample with its MIS weight against q_c,s. With
    /// `weights`, the lobes' selection probabilities are those instead of eq. 165's (module
    /// docs, "Lobe weights"; strength index 0).
    pub(super) fn terms(
        &self,
        c: f32,
        k: usize,
        weights: Option<&[f32; MAX_LOBES]>,
        mis: MisHeuristic,
    ) -> Terms {
        let (c, p, p_nee) = self.candidate(c, k, weights);
        self.terms_with(c, p, p_nee, mis)
    }

    /// Candidate (c, strength index k, `weights`)'s probability and skeleton densities at the
    /// sampled direction and at the light sample's: strength k's, or the lobe weights'
    /// mixture; c = 0 where the weights leave the point unguided ([`lobe_mixture`]).
    pub(super) fn candidate(
        &self,
        c: f32,
        k: usize,
        weights: Option<&[f32; MAX_LOBES]>,
    ) -> (f32, f32, f32) {
        let Some(weights) = weights else {
            return (c, self.p_strength[k], self.nee.p_strength[k]);
        };
        match self.densities(weights) {
            Some((p, p_nee)) => (c, p, p_nee),
            None => (0.0, 0.0, 0.0),
        }
    }

    /// The skeleton densities at the sampled direction and at the light sample's under lobe
    /// weights `weights`; None where x is not guided under them ([`lobe_mixture`]).
    fn densities(&self, weights: &[f32; MAX_LOBES]) -> Option<(f32, f32)> {
        let p = lobe_mixture(&self.p_lobes, self.active, weights)?;
        let p_nee = lobe_mixture(&self.nee.p_lobes, self.active, weights).unwrap_or(0.0);
        Some((p, p_nee))
    }

    /// [`Sample::terms`] from [`Sample::densities`].
    fn terms_weighted(&self, c: f32, densities: Option<(f32, f32)>, mis: MisHeuristic) -> Terms {
        match densities {
            Some((p, p_nee)) => self.terms_with(c, p, p_nee, mis),
            None => self.terms_with(0.0, 0.0, 0.0, mis),
        }
    }

    /// [`Sample::terms`] with the candidate's skeleton densities at the sampled direction and
    /// at the light sample's.
    fn terms_with(&self, c: f32, p_direction: f32, p_nee: f32, mis: MisHeuristic) -> Terms {
        self.terms_given(&self.shared(), c, p_direction, p_nee, mis)
    }

    /// What [`Sample::terms_given`] needs of the sample whatever the candidate.
    fn shared(&self) -> Shared {
        let q0 = mixture(TRAINING_C, self.p_skel, self.p_bsdf);
        Shared {
            q0,
            direction: self.carries() && q0 > 0.0,
            nee: self.nee.value > 0.0,
        }
    }

    /// [`Sample::terms_with`] given [`Sample::shared`].
    #[inline]
    fn terms_given(
        &self,
        shared: &Shared,
        c: f32,
        p_direction: f32,
        p_nee: f32,
        mis: MisHeuristic,
    ) -> Terms {
        let mut t = Terms::default();
        if shared.direction {
            let q = mixture(c, p_direction, self.p_bsdf);
            let w = if self.p_light > 0.0 {
                mis.weight(q as f32, self.p_light) as f64
            } else {
                1.0
            };
            let f = w * self.f_emitted as f64 + self.f_reflected as f64;
            if f > 0.0 {
                t.mean_direction = f / shared.q0;
                t.second =
                    reweighted_second_moment(f as f32, self.p_bsdf, self.p_skel, p_direction, c);
            }
        }
        if shared.nee {
            let q = mixture(c, p_nee, self.nee.p_bsdf);
            let w = mis.weight(self.nee.p_light, q as f32) as f64;
            t.mean_nee = self.nee.value as f64 * w;
            t.second += t.mean_nee * t.mean_nee;
        }
        t
    }

    /// Adds this sample's [`Terms`] under c = 0 and under every candidate (c, s) of `grid`
    /// with eq. 165's lobe weights to `moments` (c = 0 first, then `grid`'s order), as
    /// [`Sample::terms`] gives them one by one, with the work shared by the candidates done
    /// once. A sample whose terms are all 0 adds nothing (the sums are >= 0: adding 0 leaves
    /// them as they are).
    pub(super) fn add_grid_terms(&self, grid: &Grid, mis: MisHeuristic, moments: &mut [Moments]) {
        let shared = self.shared();
        if !(shared.direction || shared.nee) {
            return;
        }
        let strengths = grid.strengths.len();
        moments[0].add(self.terms_given(
            &shared,
            0.0,
            self.p_strength[0],
            self.nee.p_strength[0],
            mis,
        ));
        for (&c, m) in grid.c.iter().zip(moments[1..].chunks_exact_mut(strengths)) {
            for (k, m) in m.iter_mut().enumerate() {
                m.add(self.terms_given(
                    &shared,
                    c,
                    self.p_strength[k],
                    self.nee.p_strength[k],
                    mis,
                ));
            }
        }
    }
}

/// The parts of a sample's [`Terms`] that do not depend on the candidate.
struct Shared {
    /// The training proposal's density of the sampled direction.
    q0: f64,
    /// Whether the direction part is counted (it carried something and q0 > 0), and the
    /// light sample (it carried something).
    direction: bool,
    nee: bool,
}

/// c p_skel + (1 - c) p_bsdf (p_bsdf alone at c = 0, whatever p_skel is).
pub(super) fn mixture(c: f32, p_skel: f32, p_bsdf: f32) -> f64 {
    let (c, ps, pb) = (c as f64, p_skel as f64, p_bsdf as f64);
    if c > 0.0 {
        c * ps + (1.0 - c) * pb
    } else {
        pb
    }
}

/// Sums of [`Terms`] over a node's samples.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Moments {
    pub(super) second: f64,
    pub(super) mean_direction: f64,
    pub(super) mean_nee: f64,
}

impl Moments {
    pub(super) fn add(&mut self, t: Terms) {
        self.second += t.second;
        self.mean_direction += t.mean_direction;
        self.mean_nee += t.mean_nee;
    }

    /// Var(N + D) = M_N + M_D - E[N]² - E[D]² (N and D are independent samples), from n
    /// samples.
    fn variance(&self, n: f64) -> f64 {
        let (d, l) = (self.mean_direction / n, self.mean_nee / n);
        (self.second / n - d * d - l * l).max(0.0)
    }
}

/// What the training chose at one node.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct NodeChoice {
    /// (c, strength index) if the node is guided (or the fixed c's best strength).
    pub(super) guided: Option<(f32, usize)>,
    /// The lobes' selection weights chosen, where not eq. 165's.
    pub(super) weights: Option<[f32; MAX_LOBES]>,
    pub(super) relative_cost: f32,
    pub(super) best_ratio: f32,
    /// The estimate's variance per sample unguided and under the choice (the same where the
    /// node is not guided), and the choice's overhead per sample in unguided vertices beyond
    /// an unguided vertex's by the measured costs, the node mapping aside (0 where not
    /// guided).
    pub(super) variance_unguided: f64,
    pub(super) variance_chosen: f64,
    pub(super) overhead: f64,
}

/// A node's learned directional distribution from its samples (module docs, "Learned
/// directions"), returned as bin probabilities; and, for the choice, each sample's candidate
/// skeleton densities (`p_strength[0]`, at the sampled direction and at its light sample's)
/// replaced by those of the distribution learned from the *other* half of the node's samples
/// (even / odd positions), so that a distribution is never judged on the samples it was fitted
/// to.
///
/// `earlier` are weighted samples of earlier passes at the node (`training_history=all`,
/// module docs, "Iterative training"): each is an unbiased estimate of its bin's integral like
/// this pass's, independent of this pass's samples, so they join both halves and the whole.
/// Also returns this pass's weighted samples. Unless `judged` (a pass whose choices are
/// kept), the halves are not fitted and the samples' densities are left alone.
pub(super) fn learn_directions(
    samples: &mut [Sample],
    mis: MisHeuristic,
    earlier: &[Weighted],
    floor: f32,
    judged: bool,
) -> (Vec<f32>, Vec<Weighted>) {
    let weight = |s: &Sample| -> f64 {
        let q0 = mixture(TRAINING_C, s.p_skel, s.p_bsdf);
        if !(s.carries() && q0 > 0.0) {
            return 0.0;
        }
        let w = if s.p_light > 0.0 {
            mis.weight(q0 as f32, s.p_light) as f64
        } else {
            1.0
        };
        (w * s.f_emitted as f64 + s.f_reflected as f64) / q0
    };
    let weighted: Vec<Weighted> = samples
        .iter()
        .map(|s| (s.class as usize, s.wi, weight(s)))
        .collect();
    // Each counted sample binned once for the three fits (`directional::fit_binned`), with
    // the parity of its index among this pass's samples (the earlier passes' are in both).
    let earlier: Vec<(u8, u16, f64)> = earlier
        .iter()
        .filter_map(|&s| directional::binned(s))
        .collect();
    let own: Vec<(usize, (u8, u16, f64))> = weighted
        .iter()
        .enumerate()
        .filter_map(|(i, &s)| directional::binned(s).map(|b| (i % 2, b)))
        .collect();
    let half = |parity: usize| {
        let part = own.iter().filter(|(p, _)| *p == parity).map(|&(_, b)| b);
        directional::fit_binned(earlier.iter().copied().chain(part), floor)
    };
    if judged {
        let folds = DirectionalTable::new(&[Some(half(1)), Some(half(0))]);
        for (i, s) in samples.iter_mut().enumerate() {
            // Sample i is judged by the distribution of the other half: node 0 holds the odd
            // samples', node 1 the even ones'.
            let slot = folds
                .slot((i % 2 == 1) as u32, s.class as usize)
                .expect("both halves have distributions");
            s.p_strength[0] = folds.pdf(slot, s.wi);
            s.nee.p_strength[0] = folds.pdf(slot, s.nee.wi);
        }
    }
    let all = earlier.iter().copied().chain(own.iter().map(|&(_, b)| b));
    (directional::fit_binned(all, floor), weighted)
}

/// A weighted direction sample of a node's histogram: class, direction, weight.
pub(crate) type Weighted = (usize, Vec3, f64);

/// Guide shadow rays per recorded query at a node, counted by the queries themselves.
pub(super) fn mean_shadow_rays(samples: &[Sample]) -> f64 {
    samples.iter().map(|s| s.rays as f64).sum::<f64>() / samples.len().max(1) as f64
}

/// The choice at one node from its training samples (module docs, "Choice"): the candidate of
/// least variance x cost, kept with `c_skel=learned` only if it beats c = 0 by
/// `significance` standard errors and the node had enough samples.
pub(super) fn choose_node(
    samples: &[Sample],
    shadow_rays: f64,
    grid: &Grid,
    training_cost: TrainingCost,
    significance: f64,
    min_nonzero: u32,
    mis: MisHeuristic,
) -> NodeChoice {
    let n = samples.len() as f64;
    let unguided_variance = |samples: &[Sample]| {
        let mut m = Moments::default();
        samples
            .iter()
            .for_each(|s| m.add(s.terms(0.0, 0, None, mis)));
        m.variance(n)
    };
    let not_guided = |variance: f64| NodeChoice {
        guided: None,
        weights: None,
        relative_cost: 1.0,
        best_ratio: 1.0,
        variance_unguided: variance,
        variance_chosen: variance,
        overhead: 0.0,
    };
    let carrying = samples.iter().filter(|s| s.carries()).count() as u32;
    if (samples.len() as u32) < MIN_SAMPLES || carrying < min_nonzero {
        return not_guided(if samples.is_empty() {
            0.0
        } else {
            unguided_variance(samples)
        });
    }
    let base = match training_cost {
        TrainingCost::Vertex => 1.0,
        TrainingCost::Path => {
            (samples.iter().map(|s| s.remaining as f64).sum::<f64>() / n).max(1.0)
        }
    };
    // The selection weights to compare: eq. 165's (None) and, with `lobe_weights=learned`,
    // each lobe alone and the fit (module docs, "Lobe weights"), each with the share of the
    // node's samples at which some lobe of positive weight applies (guided there).
    let mut weights: Vec<(Option<[f32; MAX_LOBES]>, f64)> = vec![(None, 1.0)];
    if grid.lobe_weights {
        let seen = samples.iter().fold(0u8, |m, s| m | s.active);
        let lobes = MAX_LOBES - seen.leading_zeros() as usize;
        if lobes >= 2 {
            for j in 0..lobes {
                let mut w = [0.0; MAX_LOBES];
                w[j] = 1.0;
                weights.push((Some(w), 0.0));
            }
            weights.push((Some(fit_lobe_weights(samples, lobes, mis)), 0.0));
        }
        for (w, share) in weights.iter_mut().skip(1) {
            let w = w.as_ref().expect("explicit weights");
            let guided = samples
                .iter()
                .filter(|s| (0..MAX_LOBES).any(|j| s.active & (1 << j) != 0 && w[j] > 0.0))
                .count();
            *share = guided as f64 / n;
        }
    }
    // Cost of a sample at the node, in unguided vertices, where a share of the samples are
    // guided.
    let cost = |c: f32, share: f64| {
        if c <= 0.0 {
            base
        } else {
            base + share * (grid.guided_cost + COST_SHADOW_RAY * shadow_rays)
        }
    };
    // Candidate 0 is c = 0 (not guided); then each grid entry with each weight vector.
    let count = grid.len() * weights.len();
    let candidate = |j: usize| -> (f32, usize, usize) {
        if j == 0 {
            (0.0, 0, 0)
        } else {
            let (c, k) = grid.at((j - 1) % grid.len());
            (c, k, (j - 1) / grid.len())
        }
    };
    let terms = |s: &Sample, j: usize| {
        let (c, k, w) = candidate(j);
        s.terms(c, k, weights[w].0.as_ref(), mis)
    };
    let cost_of = |j: usize| {
        let (c, _, w) = candidate(j);
        cost(c, weights[w].1)
    };
    let mut moments = vec![Moments::default(); count + 1];
    // Each explicit weight vector's densities once per sample, not once per candidate c.
    let mut densities = vec![None; weights.len()];
    // Candidate 0 and eq. 165's weights' candidates (`candidate`'s first 1 + grid.len()).
    let eq165 = grid.len() + 1;
    for s in samples {
        s.add_grid_terms(grid, mis, &mut moments[..eq165]);
        for (d, (w, _)) in densities.iter_mut().zip(&weights).skip(1) {
            *d = s.densities(w.as_ref().expect("explicit weights"));
        }
        for (j, m) in moments.iter_mut().enumerate().skip(eq165) {
            let (c, _, w) = candidate(j);
            m.add(s.terms_weighted(c, densities[w], mis));
        }
    }
    let product = |j: usize| moments[j].variance(n) * cost_of(j);
    let best = (1..=count)
        .min_by(|&a, &b| product(a).total_cmp(&product(b)))
        .expect("at least one candidate");
    let (guided, unguided) = (product(best), product(0));
    let ratio = if unguided > 0.0 && unguided.is_finite() {
        (guided / unguided) as f32
    } else {
        0.0
    };
    let guide_it = if !grid.may_turn_off || !unguided.is_finite() {
        true
    } else {
        // The spread of d_i = cost(c*) m_i(c*) - cost(0) m_i(0), m_i a sample's
        // second-moment term: the difference's dominant noise (the squared means are
        // estimated far more precisely).
        let (cost_c, cost_0) = (cost_of(best), cost_of(0));
        let (mut sum, mut sum2) = (0.0f64, 0.0f64);
        for s in samples {
            let d = cost_c * terms(s, best).second - cost_0 * terms(s, 0).second;
            sum += d;
            sum2 += d * d;
        }
        let mean = sum / n;
        let spread = ((sum2 / n - mean * mean).max(0.0) / n).sqrt();
        guided - unguided + significance * spread < 0.0
    };
    let variance_unguided = moments[0].variance(n);
    if !guide_it {
        return NodeChoice {
            best_ratio: ratio,
            ..not_guided(variance_unguided)
        };
    }
    let (c, k, w) = candidate(best);
    NodeChoice {
        guided: Some((c, k)),
        weights: weights[w].0,
        relative_cost: ratio,
        best_ratio: ratio,
        variance_unguided,
        variance_chosen: moments[best].variance(n),
        // The measured costs whatever the cost model (the scene-level prediction is of the
        // real cost); the node mapping is counted per mapped vertex there.
        overhead: weights[w].1 * (grid.measured.query + COST_SHADOW_RAY * shadow_rays),
    }
}

/// Lobe selection weights for a node's first `lobes` lobes that lower the reweighted second
/// moment of the direction estimate at the training probability (module docs, "Lobe
/// weights"): from equal weights, multiplicative updates
/// w_j <- w_j mean_i[ f_i² p_j(w_i) / (T_i q_i² q0_i) ], normalised (T_i the weight of the lobes
/// that apply at sample i), whose fixed points are the stationary points of the second moment
/// of the unnormalised mixture; weights below `FIT_FLOOR` are then set to 0 (the lobe is
/// dropped). A candidate like any other: the choice judges it by the exact reweighted moments.
pub(super) fn fit_lobe_weights(
    samples: &[Sample],
    lobes: usize,
    mis: MisHeuristic,
) -> [f32; MAX_LOBES] {
    let mut w = [0.0f32; MAX_LOBES];
    w[..lobes].fill(1.0 / lobes as f32);
    let c = TRAINING_C as f64;
    for _ in 0..FIT_ITERATIONS {
        let mut acc = [0.0f64; MAX_LOBES];
        for s in samples.iter().filter(|s| s.carries()) {
            let total: f32 = (0..lobes)
                .filter(|&j| s.active & (1 << j) != 0)
                .map(|j| w[j])
                .sum();
            let Some(p_skel) = lobe_mixture(&s.p_lobes, s.active, &w) else {
                continue;
            };
            let q0 = mixture(TRAINING_C, s.p_skel, s.p_bsdf);
            let q = c * p_skel as f64 + (1.0 - c) * s.p_bsdf as f64;
            if !(q > 0.0 && q0 > 0.0) {
                continue;
            }
            let weight = if s.p_light > 0.0 {
                mis.weight(q as f32, s.p_light) as f64
            } else {
                1.0
            };
            let f = weight * s.f_emitted as f64 + s.f_reflected as f64;
            let g = f * f / (q * q * q0) / total as f64;
            for j in 0..lobes {
                if s.active & (1 << j) != 0 {
                    acc[j] += w[j] as f64 * s.p_lobes[j].max(0.0) as f64 * g;
                }
            }
        }
        let sum: f64 = acc.iter().sum();
        if !(sum > 0.0 && sum.is_finite()) {
            break;
        }
        for j in 0..lobes {
            w[j] = (acc[j] / sum) as f32;
        }
    }
    for x in w.iter_mut() {
        if *x < FIT_FLOOR {
            *x = 0.0;
        }
    }
    let sum: f32 = w.iter().sum();
    if sum > 0.0 {
        w.iter_mut().for_each(|x| *x /= sum);
    } else {
        w[..lobes].fill(1.0 / lobes as f32);
    }
    w
}

/// One training sample's term of the reweighted second moment M(c, s) (module docs):
/// f² / (q_c,s q_c0), with q_c0 = c0 p_skel,s0 + (1 - c0) p_bsdf the density the sample was
/// drawn from (`p_proposal` = p_skel,s0) and q_c,s = c p_skel,s + (1 - c) p_bsdf the candidate's
/// (`p_candidate` = p_skel,s). Infinite where the candidate cannot sample a direction that
/// carries f > 0.
pub(crate) fn reweighted_second_moment(
    f: f32,
    p_bsdf: f32,
    p_proposal: f32,
    p_candidate: f32,
    c: f32,
) -> f64 {
    let (f, pb, c, c0) = (f as f64, p_bsdf as f64, c as f64, TRAINING_C as f64);
    if f <= 0.0 {
        return 0.0;
    }
    let q0 = c0 * p_proposal as f64 + (1.0 - c0) * pb;
    let q = c * p_candidate as f64 + (1.0 - c) * pb;
    if q > 0.0 {
        f * f / (q * q0)
    } else {
        f64::INFINITY
    }
}
