//! What integrators ask of the empty-space analysis (docs/design.md: a module owns its data): a direction and its pdf.
//! Integrators never reach into the voxel grid or the skeleton graph themselves.
//!
//! [`SkeletonGuide`] is skeleton-guided ray sampling (000 chapter 9, lines 2600-2790, and the
//! early write-up 004): importance nodes found by light tracing (eq. 171-176), shortest paths
//! along the filtered skeleton (Dijkstra), skeleton importance points (eq. 162), power-cosine
//! lobes toward them (eq. 163) mixed by one-sample MIS with inverse-square selection
//! probabilities (eq. 164-167). [`GuideQuery`] follows Open PGL's surface sampling
//! distribution: one reusable query per worker thread, initialised at each surface point, that
//! samples a direction from host-supplied random numbers and returns the exact pdf of the whole
//! skeleton mixture, so that a path tracer can combine it with BSDF sampling by MIS
//! (eq. 168-170, [`GuideQuery::mixture_pdf`]).

pub mod budget;
pub mod directional;
pub mod estimator;
mod face_irradiance;
mod importance;
mod lobes;
mod mixture;
mod portal_guide;
mod query;
pub mod resampling;
mod settings;
mod skeleton_guide;
mod training;

pub use directional::DirectionalTable;
pub use face_irradiance::{FaceIrradiance, FaceQuery, FaceScore, MAX_FACE_LOBES};
pub use lobes::{GuideLobe, ImportanceNode, MAX_LOBES};
pub use mixture::{sample_bsdf_or_guide, DirectionGuide, MixtureSample};
pub use portal_guide::{
    FaceSettings, PortalAim, PortalGuide, PortalGuideSettings, PortalQuery, PortalRectangle,
    PortalStrategy, Unguided, MAX_PORTAL_LOBES, OPEN_SCENE_FRACTION, PORTAL_OPTION_NAMES,
};
pub use query::GuideQuery;
pub use resampling::{ConnectionCount, ResamplingSettings};
pub use settings::{
    CostModel, LobeAim, LobeFallback, PilotCost, RenderEstimator, SkeletonGuideSettings,
    SkeletonStrength, TrainingCost, BUDGET_SHARE, DEFAULT_AUTO_MAX, DEFAULT_TRAINING_DEPTH,
    DEFAULT_TRAINING_PATHS, DEFAULT_VOXEL_BUDGET, MAX_STRENGTH, OPTION_NAMES, STRENGTH_CANDIDATES,
};
pub use skeleton_guide::{GridPoint, SkeletonGuide, START_STAGE};
pub use training::{Pilot, SceneChoice, TrainingReport, CANDIDATES, PILOT_SIGMAS, TRAINING_C};
