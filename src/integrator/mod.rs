//! Integrators: estimators of the radiance arriving along a camera ray. Each lives in its own
//! file behind the small [`Integrator`] trait; [`create`] makes one by name.

mod path;

pub use path::PathTracer;

use crate::error::{Error, Result};
use crate::film::PixelSample;
use crate::geometry::Ray;
use crate::math::Rng;
use crate::scene::Scene;

/// How one-sample MIS weights two strategies.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MisHeuristic {
    Balance,
    /// Power heuristic with exponent 2 (Veach): the usual better choice.
    #[default]
    Power,
}

impl MisHeuristic {
    #[inline]
    pub fn weight(self, pdf_a: f32, pdf_b: f32) -> f32 {
        match self {
            MisHeuristic::Balance => crate::math::balance_heuristic(pdf_a, pdf_b),
            MisHeuristic::Power => crate::math::power_heuristic(pdf_a, pdf_b),
        }
    }

    pub fn parse(name: &str) -> Result<Self> {
        match name {
            "balance" => Ok(MisHeuristic::Balance),
            "power" => Ok(MisHeuristic::Power),
            other => Err(Error::invalid(format!(
                "unknown MIS heuristic '{other}' (expected balance or power)"
            ))),
        }
    }
}

/// Settings shared by the integrators.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IntegratorSettings {
    /// Maximum number of bounces (scattering events) of a path; 0 shows emitters only, 1 is
    /// direct lighting. A path has at most `max_depth + 1` segments.
    pub max_depth: u32,
    pub mis: MisHeuristic,
    /// Bounce after which Russian roulette may end paths.
    pub rr_start_depth: u32,
}

impl Default for IntegratorSettings {
    fn default() -> Self {
        IntegratorSettings {
            max_depth: 8,
            mis: MisHeuristic::Power,
            rr_start_depth: 3,
        }
    }
}

/// Counters an integrator updates while tracing (kept per worker, summed at the end).
#[derive(Clone, Copy, Debug, Default)]
pub struct TraceCounters {
    pub rays: u64,
}

/// An estimator of radiance along camera rays. Implementations are immutable during a render
/// and shared by the worker threads.
pub trait Integrator: Send + Sync {
    fn name(&self) -> &'static str;

    /// One sample of the radiance arriving at the camera along `ray`, with the first-hit AOVs.
    fn sample(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Rng,
        counters: &mut TraceCounters,
    ) -> PixelSample;
}

/// Names of the integrators this build offers.
pub const NAMES: &[&str] = &["path"];

/// Creates an integrator by name.
pub fn create(name: &str, settings: IntegratorSettings) -> Result<Box<dyn Integrator>> {
    match name {
        "path" => Ok(Box::new(PathTracer::new(settings))),
        other => Err(Error::invalid(format!(
            "unknown integrator '{other}' (available: {})",
            NAMES.join(", ")
        ))),
    }
}
