//! Wall-clock timings of the stages of a computation (the analysis pipeline, a guide's build,
//! an integrator's precomputation), reported to hosts and written into image metadata. Kept
//! at the bottom of the layers so that every stage can record them.

/// Wall-clock time of one stage.
#[derive(Clone, Debug, PartialEq)]
pub struct StageTime {
    pub stage: &'static str,
    pub seconds: f64,
}
