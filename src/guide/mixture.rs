//! One-sample MIS of BSDF sampling and a guide (000 eq. 168-170): the strategy is chosen at
//! random with the query's guiding probability `c`, and whichever produced the direction, its
//! density is that of the mixture, `c p_guide + (1 - c) p_bsdf` ([`GuideQuery::mixture_pdf`]),
//! so the estimator `f |cos| / pdf` is the balance-heuristic combination of both.

use super::GuideQuery;
use crate::math::{Frame, Rgb, Sampler, Vec3};
use crate::scene::{Bsdf, BsdfSample, Transport};

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
pub fn sample_bsdf_or_guide(
    bsdf: &Bsdf,
    wo_local: Vec3,
    frame: &Frame,
    query: &GuideQuery,
    rng: &mut Sampler,
) -> Option<MixtureSample> {
    let c = query.guiding_probability();
    if c > 0.0 && rng.uniform() < c {
        let (wi, guide_pdf) = query.sample(rng.uniform(), rng.uniform2())?;
        let wi_local = frame.to_local(wi);
        let f = bsdf.eval(wo_local, wi_local);
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
