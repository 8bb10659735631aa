//! The training's predictions of what guiding gains and costs over a whole image (module docs
//! of `training`, "Measured cost and the scene-level switch" and "The path-level
//! prediction"): the measured costs, the scene-level prediction from the node choices, and
//! the path-level ratio of second moments from the logged training paths.

use super::statistics::NodeChoice;

/// The measured costs (module docs, "Measured cost and the scene-level switch"), in unguided
/// vertices: `query`, a guided query's cost beyond an unguided vertex's whatever its c (with
/// the lobes their set-up, the mixture's sampling and densities and the dearer rays of the
/// paths it sends elsewhere; guide shadow rays aside); `map`, the node mapping, paid by every
/// vertex in a voxel that may map to a guided node, guided or not.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct MeasuredCosts {
    pub(super) query: f64,
    pub(super) map: f64,
}

impl MeasuredCosts {
    /// The costs of the settings' directions: the lobes' or the learned histograms'.
    pub(super) fn of(settings: &crate::guide::SkeletonGuideSettings) -> MeasuredCosts {
        if settings.learned_directions {
            LEARNED_COSTS
        } else {
            LOBE_COSTS
        }
    }
}

/// `directions=lobes`, from callgrind of Sponza (`path_skeleton` minus `path` per camera sample,
/// divided by the guided queries or mapped vertices per sample and by `path`'s instructions per
/// vertex; BENCHMARKS.md).
pub(super) const LOBE_COSTS: MeasuredCosts = MeasuredCosts {
    query: 0.39,
    map: 0.064,
};
/// `directions=learned`, measured as [`LOBE_COSTS`] on the ajar and the door, the mean of the
/// two: no set-up beyond the class lookup, no shadow ray.
pub(super) const LEARNED_COSTS: MeasuredCosts = MeasuredCosts {
    query: 0.19,
    map: 0.12,
};
/// `cost_model=switch|measured`: the whole image's predicted efficiency must gain this much (as a
/// ratio above 1) for anything to be guided.
pub(super) const SCENE_MARGIN: f64 = 0.1;

/// The scene-level prediction (module docs, "Measured cost and the scene-level switch") from
/// the node choices, `samples[k]` training samples at node k: variance sum_k n_k V_k under the
/// choices against guiding nothing, cost `vertices` plus the guided samples' overhead plus
/// `map_cost` at each of `mapped_vertices`. Returns (variance ratio, cost ratio).
pub(super) fn scene_prediction(
    choices: &[NodeChoice],
    samples: &[u32],
    vertices: u64,
    mapped_vertices: u64,
    map_cost: f64,
) -> (f64, f64) {
    let (mut unguided, mut chosen, mut overhead) = (0.0f64, 0.0f64, 0.0f64);
    for (c, &n) in choices.iter().zip(samples) {
        let n = n as f64;
        unguided += n * c.variance_unguided;
        chosen += n * c.variance_chosen;
        overhead += n * c.overhead;
    }
    let variance_ratio = if unguided > 0.0 && unguided.is_finite() {
        chosen / unguided
    } else if unguided.is_infinite() && chosen.is_finite() {
        // Only guiding can sample some contribution: guiding nothing is infinitely worse.
        0.0
    } else {
        1.0
    };
    let base = (vertices as f64).max(1.0);
    let cost_ratio = (base + overhead + map_cost * mapped_vertices as f64) / base;
    (variance_ratio, cost_ratio)
}

/// One sampled direction of a training path, for the path-level prediction (module docs, "The
/// path-level prediction").
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Step {
    /// Luminance of the light sample at the vertex the direction reached, times the path's
    /// throughput there (0 where none).
    pub(super) after: f32,
    /// q_0 / q of the direction under guiding nothing and under the choices (1 where the
    /// training did not guide the vertex: BSDF sampling in both).
    pub(super) r_none: f64,
    pub(super) r_chosen: f64,
}

/// One training path for the path-level prediction: the light sample at its first vertex (as
/// [`Step::after`]) and its [`Step`]s.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct PathRecord {
    pub(super) first: f32,
    pub(super) start: u32,
    pub(super) len: u32,
}
/// The quantile of the paths' second-moment terms at which the path-level prediction caps
/// them (module docs, "The path-level prediction").
pub(super) const PATH_TERM_QUANTILE: f64 = 0.9999;

/// The training paths' [`Step`]s and [`PathRecord`]s (module docs, "The path-level
/// prediction").
#[derive(Clone, Default)]
pub(super) struct PathLog {
    pub(super) steps: Vec<Step>,
    pub(super) paths: Vec<PathRecord>,
}

/// The path-level ratio of the node choices' second moment to guiding nothing's (module docs,
/// "The path-level prediction"); 1 where it cannot be estimated.
pub(super) fn path_variance_ratio(log: &PathLog) -> f64 {
    let n = log.paths.len();
    // Each path's term of the two second moments (0 for a path a policy cannot draw).
    let (mut none, mut chosen) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let term = |e: f64, w: f64| {
        if w > 0.0 && w.is_finite() {
            e * e * w
        } else {
            0.0
        }
    };
    for p in &log.paths {
        let steps = &log.steps[p.start as usize..(p.start + p.len) as usize];
        // Per policy: the estimate, the running product of q_0 / q and the path's density
        // ratio q / q_0 over all its directions.
        let (mut e_none, mut prod_none, mut w_none) = (p.first as f64, 1.0f64, 1.0f64);
        let (mut e_chosen, mut prod_chosen, mut w_chosen) = (p.first as f64, 1.0f64, 1.0f64);
        for st in steps {
            prod_none *= st.r_none;
            w_none /= st.r_none;
            e_none += st.after as f64 * prod_none;
            prod_chosen *= st.r_chosen;
            w_chosen /= st.r_chosen;
            e_chosen += st.after as f64 * prod_chosen;
        }
        none.push(term(e_none, w_none));
        chosen.push(term(e_chosen, w_chosen));
    }
    if n == 0 {
        return 1.0;
    }
    // Both policies' terms capped at the same quantile of all terms (module docs: a few
    // paths in 10^5 would otherwise decide).
    let mut pooled: Vec<f64> = none.iter().chain(&chosen).copied().collect();
    let at = ((pooled.len() as f64 * PATH_TERM_QUANTILE) as usize).min(pooled.len() - 1);
    let cap = *pooled.select_nth_unstable_by(at, |a, b| a.total_cmp(b)).1;
    let moment = |terms: &[f64]| terms.iter().map(|t| t.min(cap)).sum::<f64>();
    let (m_none, m_chosen) = (moment(&none), moment(&chosen));
    if m_none > 0.0 && m_none.is_finite() && m_chosen.is_finite() {
        m_chosen / m_none
    } else {
        1.0
    }
}
