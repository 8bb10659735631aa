//! One-sample MIS of BSDF sampling and a guide (000 eq. 168-170): the strategy is chosen at
//! random with the query's guiding probability `c`, and whichever produced the direction, its
//! density is that of the mixture, `c p_guide + (1 - c) p_bsdf` ([`GuideQuery::mixture_pdf`]),
//! so the estimator `f |cos| / pdf` is the balance-heuristic combination of both.

use super::GuideQuery;
use crate::math::{Frame, Rgb, Sampler, Vec2, Vec3};
use crate::scene::{Bsdf, BsdfSample, Transport};

/// A distribution of directions at one point that one-sample MIS mixes with BSDF sampling:
/// the skeleton's [`GuideQuery`] and the portals' `PortalQuery`.
pub trait DirectionGuide {
    /// Probability of sampling the guide rather than the BSDF here (0: not guided).
    fn guiding_probability(&self) -> f32;
    /// A unit world direction from `u_select` (which lobe) and `u`, with the guide's
    /// solid-angle pdf there; None when not guided.
    fn sample(&self, u_select: f32, u: Vec2) -> Option<(Vec3, f32)>;
    /// The guide's solid-angle pdf at unit world direction `w` (0 when not guided).
    fn pdf(&self, w: Vec3) -> f32;

    /// The mixture's density `c p_guide(w) + (1 - c) p_bsdf(w)` (the BSDF's alone where
    /// `c = 0`).
    #[inline]
    fn mixture_pdf(&self, w: Vec3, bsdf_pdf: f32) -> f32 {
        let c = self.guiding_probability();
        if c > 0.0 {
            c * self.pdf(w) + (1.0 - c) * bsdf_pdf
        } else {
            bsdf_pdf
        }
    }

    /// [`mixture_pdf`](Self::mixture_pdf) where the guide's density is known.
    #[inline]
    fn mixture_pdf_given(&self, guide_pdf: f32, bsdf_pdf: f32) -> f32 {
        let c = self.guiding_probability();
        if c > 0.0 {
            c * guide_pdf + (1.0 - c) * bsdf_pdf
        } else {
            bsdf_pdf
        }
    }
}

/// Picks a lobe of a mixture by one uniform number: the first lobe whose cumulative weight
/// exceeds `u_select` (the last one when rounding leaves `u_select` past the total), and
/// `u_select` rescaled to `[0, 1)` inside that lobe's interval, so the same number can choose
/// again inside the lobe. `weights` are the lobes' selection probabilities (summing to about
/// 1); at least one lobe is required.
pub(crate) fn pick_lobe(
    weights: impl ExactSizeIterator<Item = f32>,
    u_select: f32,
) -> (usize, f32) {
    let last = weights.len() - 1;
    let mut acc = 0.0;
    for (j, w) in weights.enumerate() {
        let next = acc + w;
        if u_select < next || j == last {
            let rescaled = if w > 0.0 { (u_select - acc) / w } else { 0.0 };
            return (j, rescaled.clamp(0.0, 1.0 - f32::EPSILON));
        }
        acc = next;
    }
    unreachable!("pick_lobe needs at least one lobe")
}

impl DirectionGuide for GuideQuery {
    #[inline]
    fn guiding_probability(&self) -> f32 {
        GuideQuery::guiding_probability(self)
    }
    #[inline]
    fn sample(&self, u_select: f32, u: Vec2) -> Option<(Vec3, f32)> {
        GuideQuery::sample(self, u_select, u)
    }
    #[inline]
    fn pdf(&self, w: Vec3) -> f32 {
        GuideQuery::pdf(self, w)
    }
    #[inline]
    fn mixture_pdf(&self, w: Vec3, bsdf_pdf: f32) -> f32 {
        GuideQuery::mixture_pdf(self, w, bsdf_pdf)
    }
    #[inline]
    fn mixture_pdf_given(&self, guide_pdf: f32, bsdf_pdf: f32) -> f32 {
        GuideQuery::mixture_pdf_given(self, guide_pdf, bsdf_pdf)
    }
}

/// A direction sampled by [`sample_bsdf_or_guide`].
#[derive(Clone, Copy, Debug)]
pub struct MixtureSample {
    /// Local to the frame; `pdf` is the mixture's density.
    pub sample: BsdfSample,
    /// The BSDF's own density of the direction (BSDF sampling alone would have used it):
    /// `f |cos| / bsdf_pdf` is the throughput BSDF sampling would carry, which is what Russian
    /// roulette should look at. Guided directions have a smaller mixture throughput exactly
    /// where they are more likely to lead to light; a roulette on it would end guided paths
    /// because they were guided.
    pub bsdf_pdf: f32,
    /// Whether the guide (not the BSDF) drew the direction.
    pub from_guide: bool,
}

/// Samples an incident direction at a surface for radiance transport: from `bsdf` (local to
/// `frame`, outgoing direction `wo_local`), or with the query's guiding probability from its
/// lobes. The sample is local to `frame` and its pdf is the mixture's (for a delta BSDF sample,
/// the BSDF's own: no guided point has a delta BSDF, see the module docs of `guide`). With an
/// unguided query this is exactly `bsdf.sample` and draws the same random numbers. `None` when
/// the sample carries nothing (absorbed, or a guided direction the BSDF does not reflect into).
#[inline(always)]
pub fn sample_bsdf_or_guide<G: DirectionGuide + ?Sized>(
    bsdf: &Bsdf,
    wo_local: Vec3,
    frame: &Frame,
    query: &G,
    rng: &mut Sampler,
) -> Option<MixtureSample> {
    let c = query.guiding_probability();
    if c > 0.0 && rng.uniform() < c {
        let (wi, guide_pdf) = query.sample(rng.uniform(), rng.uniform2())?;
        let wi_local = frame.to_local(wi);
        let f = bsdf.eval(wo_local, wi_local, Transport::Radiance);
        if f == Rgb::ZERO {
            return None;
        }
        let bsdf_pdf = bsdf.pdf(wo_local, wi_local);
        let pdf = query.mixture_pdf_given(guide_pdf, bsdf_pdf);
        return Some(MixtureSample {
            sample: BsdfSample {
                wi: wi_local,
                f,
                pdf,
                delta: false,
            },
            bsdf_pdf: if bsdf_pdf > 0.0 { bsdf_pdf } else { pdf },
            from_guide: true,
        });
    }
    let mut bs = bsdf.sample_from(wo_local, rng, Transport::Radiance)?;
    let bsdf_pdf = bs.pdf;
    if c > 0.0 && !bs.delta {
        bs.pdf = query.mixture_pdf(frame.to_world(bs.wi), bs.pdf);
    }
    Some(MixtureSample {
        sample: bs,
        bsdf_pdf,
        from_guide: false,
    })
}

#[cfg(test)]
mod tests {
    use super::pick_lobe;

    #[test]
    fn pick_lobe_follows_the_cumulative_weights_and_rescales_inside_the_lobe() {
        let weights = [0.25f32, 0.0, 0.5, 0.25];
        let pick = |u: f32| pick_lobe(weights.iter().copied(), u);
        assert_eq!(pick(0.0), (0, 0.0));
        assert_eq!(pick(0.125), (0, 0.5));
        // The empty lobe is never chosen: its interval has no width.
        assert_eq!(pick(0.25).0, 2);
        let (lobe, rescaled) = pick(0.5);
        assert_eq!(lobe, 2);
        assert!((rescaled - 0.5).abs() < 1e-6);
        assert_eq!(pick(0.8).0, 3);
        // Rounding that leaves the number past the total falls to the last lobe, inside [0, 1).
        let (lobe, rescaled) = pick_lobe([0.3f32, 0.3].into_iter(), 0.99);
        assert_eq!(lobe, 1);
        assert!((0.0..1.0).contains(&rescaled));
        // Frequencies over a uniform grid of numbers match the weights.
        let n = 10_000;
        let mut counts = [0usize; 4];
        for i in 0..n {
            counts[pick((i as f32 + 0.5) / n as f32).0] += 1;
        }
        for (c, w) in counts.iter().zip(weights) {
            assert!((*c as f32 / n as f32 - w).abs() < 1e-3);
        }
    }
}
