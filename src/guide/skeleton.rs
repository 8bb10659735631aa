//! Skeleton-guided ray sampling (000 §9.2-9.5, 004).
//!
//! # Precomputation ([`SkeletonGuide::build`])
//!
//! 1. The empty-space analysis and the filtered skeleton with its node mapping grid
//!    (`analysis::Skeleton`), at `resolution` voxels along the longest axis.
//! 2. **Importance nodes** (eq. 171-176): `light_rays` rays leave the lights (light chosen by
//!    power, then `Light::sample_emission`); the first surface each one hits is mapped to its
//!    node (eq. 151-155) and the node accumulates `L_e / p` of the ray (eq. 176), an unbiased
//!    estimate of the emitted power arriving on the surfaces mapped to it. Nodes with a
//!    non-zero estimate are importance nodes with importance `f` = that power; the
//!    `max_importance_nodes` most powerful are kept (any subset keeps the estimator unbiased:
//!    only the sampling density changes, and it is always evaluated exactly).
//! 3. **Shortest paths**: one Dijkstra per importance node over the filtered graph, edge
//!    length the Euclidean distance between node positions (§9.2.1).
//! 4. Per node `n_k` and importance node `n_i`: the selection weight `c'_i = f_i / d²`
//!    (eq. 164) with `d` the graph distance, floored at the node's maximal-ball radius (the
//!    text divides by zero at the importance node itself; inside its own ball a node is as
//!    close as it gets), the `max_lobes` largest kept and normalised (eq. 165); and the
//!    **skeleton importance point** (eq. 162): the centre of mass of the longest prefix of the
//!    shortest path from `n_k` to `n_i` whose nodes are all visible from `n_k` (one shadow ray
//!    per prefix node), at most `MAX_PREFIX` nodes long (our bound on its cost). The smallest
//!    maximal-ball radius along that prefix is kept for the automatic strength. Lobes of
//!    importance nodes whose paths share the visible prefix (same point and radius) are one
//!    lobe with the sum of their probabilities: the same mixture density, one shadow ray and
//!    one lobe evaluation per vertex instead of several (on the door, every way to the back
//!    room leaves through the gap: 18.6 rays per sample became 10.5).
//!
//! # Aiming through the opening (a variant of eq. 162, `aim=opening`)
//!
//! The thesis motivates eq. 162 as "the point to aim at to get towards the importance node"
//! (000 §9.3, 004). The centre of the prefix visible *from the node* is a good such point in
//! open space, but where the way to the light leaves a room through a narrow opening it lies
//! inside the room: the nodes beyond the opening are hidden from the node's position (the
//! medial axis runs through the room's middle), so the prefix stops short and the lobes of
//! the whole room converge on a point in its middle (the Veach door, BENCHMARKS.md "Why the
//! door gains nothing"). What a surface point x should aim at is the opening itself, and what
//! matters is whether *x* sees it, not whether the node does. So each lobe also keeps the
//! path's **bottleneck**: the first node of smallest maximal-ball radius on the whole
//! shortest path (after the node itself, at most `MAX_BOTTLENECK_SEARCH` nodes: a walk along
//! the Dijkstra tree, no rays), provided the path narrows there (a ball at least
//! `OPENING_NARROWING` times wider comes before it; a corridor has no opening), and the size
//! of the opening there: the radius of the disc of its area across the path, measured with
//! `OPENING_RAYS` rays at precomputation (a maximal ball measures only an opening's
//! narrowest width, and the door's gap is a slit as tall as the door). At a point x with
//! `aim=opening` the lobe aims at the bottleneck when x sees it (one shadow ray with the
//! visibility test) and it is above the surface, with the automatic strength taken from that
//! radius at the bottleneck's distance from x (the lobe as wide as the opening looks from
//! x); otherwise it falls back to the importance point of eq. 162 (a second shadow ray). Which target a lobe takes is
//! decided per point before any sampling, from x alone, so sampling and the pdf see the same
//! mixture and the estimator stays unbiased whatever the aim.
//!
//! # Sampling the opening itself (`aim=portal`)
//!
//! A round lobe fits a slit badly: the Veach door's gap is 15 units wide and as tall as the
//! door (its maximal ball has radius 7.6, the disc of its area 60.7), so a lobe either
//! wastes most samples beside it or misses most of it. With `aim=portal` the precomputation
//! also fits each bottleneck's cross-section as a planar rectangle (`opening_rectangle`):
//! its plane is the one of least cross-section area among normals within 75° of the path's
//! direction (paths often cross a slit obliquely, and a plane normal to the path would cut
//! it lengthwise), its axes the principal axes of the outline in that plane, its extents
//! one ray each way along them. At a point x that sees the bottleneck (the shadow ray of
//! `aim=opening`) the lobe becomes directions uniform in the rectangle's solid angle (the
//! spherical rectangle of Ureña, Fajardo and King 2013, `math::warp::SphericalRectangle`),
//! whose density at any direction is exact (1 / solid angle where the ray from x crosses
//! the rectangle, else 0). Where the rectangle covers wall as well as gap, the estimator
//! stays unbiased: BSDF sampling covers every direction, and the mixture density is exact.
//! Elsewhere (x does not see the bottleneck, lies in the rectangle's plane, or the path has
//! no opening) the lobe is the one of `aim=opening`. The strength does not apply to a
//! rectangle (`c_skel=learned` learns the probability alone).
//!
//! # Query ([`GuideQuery`])
//!
//! At a surface point x with geometric normal n and incident direction wo, x is mapped to its
//! node; each of the node's lobes points from x to its importance point, with pdf
//! `(s + 1) / (2 pi) max(0, cos)^s` (eq. 163). Two cases the thesis leaves to the
//! implementation (004, "Problems") are resolved *per point*, before any sampling, so that
//! sampling and pdf evaluation always see the same mixture and no bias arises:
//! - an importance direction below the surface (on the other side of n from wo) drops its lobe;
//! - with `visibility_test`, an importance point hidden from x (one shadow ray) drops its lobe.
//!
//! The remaining lobes' probabilities are renormalised (eq. 165 over the lobes kept).
//!
//! A point with no lobe left (no path to any importance node, all directions below the surface
//! or hidden, a point outside the grid) is not guided: its guiding probability is 0 and the host
//! samples the BSDF alone. Delta BSDFs are the host's business: it must not guide there (no
//! mixture with a Dirac lobe has a density), which `path_skeleton` does.
//!
//! What a query costs, kept small without changing the mixture: the node mapping visits only
//! the mapped voxels of the neighbourhood (`analysis::NeighbourMasks`, the same node as
//! eq. 151-155), and takes the neighbour that best faces the normal without a search where it is
//! mapped and clearly ahead (`analysis::map_point`); a target shared by several lobes gets one
//! shadow ray; lobes with the same density at x (the same portal rectangle, or the same target
//! and radius) are one active lobe with their summed probability. Which lobes share a target or
//! a portal is found at build (`LobePlan`), not per vertex; lobes keep only their axis; a portal
//! rectangle computes its angles only for a direction that hits it. With `visibility=voxel` the
//! visibility of each target is decided once per mapped voxel, from its centre, and cached: that
//! changes which lobes apply near silhouettes (still a function of the point, so unbiased), not
//! their shapes.
//!
//! # Learned directions, the default (`directions=learned`)
//!
//! Everything above builds the lobes. With a camera the default renders with learned
//! distributions instead: the training pass (`guide::training`) samples the lobes as its
//! proposal and learns per guided node a directional histogram (`guide::directional`) that the
//! render samples, with the learned probability. It needs no aim, rectangle or shadow ray per
//! point and beats the lobes by MSE at equal time on the test scenes (BENCHMARKS.md). Without a
//! camera the lobes are used. `directions=lobes` renders with the lobes; `lobe_weights=learned`
//! and `strength=learned` weigh lobes and imply it unless `directions` is named.

use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::sync::atomic::{AtomicU32, Ordering as AtomicOrdering};
use std::sync::Arc;
use std::time::Instant;

use rayon::prelude::*;

use super::directional::{self, DirectionalTable};
use super::training::{self, TrainingReport};
use crate::analysis::{
    map_point, may_map_to, Analysis, AnalysisSettings, Graph, NeighbourMasks, Resolution, Skeleton,
    SkeletonSettings, StageTime, VoxelGrid, VoxelSet,
};
use crate::error::{Error, Result};
use crate::geometry::{offset_ray_origin, Ray, SHADOW_EPSILON};
use crate::light::{EnvStrategy, TriangleSampling};
use crate::math::{luminance, warp, Frame, MisHeuristic, Rng, Vec2, Vec3};
use crate::scene::{Camera, Scene};

/// Most lobes a query holds (the upper bound of `max_lobes`).
pub const MAX_LOBES: usize = 8;

/// How the skeleton strength `s` of eq. 163 is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SkeletonStrength {
    /// One global exponent, as in the thesis.
    Fixed(f32),
    /// Per point and lobe: the lobe's half-maximum angle is the angle under which the
    /// narrowest free space along the path to the importance point (radius r, the smallest
    /// maximal-ball radius of the visible prefix) is seen from x at the importance point's
    /// distance D: cos^s(a) = 1/2 at tan(a) = r / D, i.e. s = 2 ln 2 / ln(1 + r²/D²), clamped
    /// to [1, max]. Far from the importance point (small r / D) the lobe narrows, near it the
    /// lobe widens: the behaviour the thesis asks for in its conclusion (000 §9.6, "higher far
    /// from importance nodes and lower near them") and the Sponza Dark discussion.
    Auto { max: f32 },
}

impl SkeletonStrength {
    /// "auto", "auto:MAX" or a number >= 0.
    pub fn parse(text: &str) -> Result<Self> {
        let text = text.trim();
        let strength = if text == "auto" {
            SkeletonStrength::Auto {
                max: DEFAULT_AUTO_MAX,
            }
        } else if let Some(max) = text.strip_prefix("auto:") {
            let max = max.trim().parse::<f32>().map_err(|_| {
                Error::invalid(format!(
                    "skeleton strength '{text}': 'auto:MAX' needs a number"
                ))
            })?;
            SkeletonStrength::Auto { max }
        } else {
            let s = text.parse::<f32>().map_err(|_| {
                Error::invalid(format!(
                    "skeleton strength '{text}' must be a number >= 0, 'auto' or 'auto:MAX'"
                ))
            })?;
            SkeletonStrength::Fixed(s)
        };
        strength.validate()?;
        Ok(strength)
    }

    pub fn validate(&self) -> Result<()> {
        match *self {
            SkeletonStrength::Fixed(s) if !(s.is_finite() && (0.0..=MAX_STRENGTH).contains(&s)) => {
                Err(Error::invalid(format!(
                    "skeleton strength {s} must be in [0, {MAX_STRENGTH}]"
                )))
            }
            SkeletonStrength::Auto { max }
                if !(max.is_finite() && (1.0..=MAX_STRENGTH).contains(&max)) =>
            {
                Err(Error::invalid(format!(
                    "automatic skeleton strength bound {max} must be in [1, {MAX_STRENGTH}]"
                )))
            }
            _ => Ok(()),
        }
    }

    /// The exponent for a lobe whose free-space radius is `radius` at distance `distance`.
    #[inline]
    pub fn exponent(&self, radius: f32, distance: f32) -> f32 {
        match *self {
            SkeletonStrength::Fixed(s) => s,
            SkeletonStrength::Auto { max } => {
                let ratio2 = (radius / distance.max(1e-30)).powi(2);
                let s = 2.0 * std::f32::consts::LN_2 / ratio2.ln_1p();
                if s.is_finite() {
                    s.clamp(1.0, max)
                } else {
                    max
                }
            }
        }
    }
}

impl std::fmt::Display for SkeletonStrength {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SkeletonStrength::Fixed(s) => write!(f, "{s}"),
            SkeletonStrength::Auto { max } => write!(f, "auto:{max}"),
        }
    }
}

/// Largest skeleton strength accepted (f32 powers of cosines stay meaningful well beyond).
pub const MAX_STRENGTH: f32 = 1e4;
/// Default voxel budget of the analysis grid.
pub const DEFAULT_VOXEL_BUDGET: u64 = 1 << 20;

/// Default upper bound of the automatic strength.
pub const DEFAULT_AUTO_MAX: f32 = 64.0;

/// Settings of skeleton guiding.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SkeletonGuideSettings {
    /// Probability `c_skel` of sampling the skeleton lobes instead of the BSDF at a guided
    /// point (eq. 168-169), in [0, 1): 1 would leave directions no lobe reaches unsampled.
    /// Used at every guided node unless `learned_c_skel`, and with it where the scene has no
    /// camera to train from (default 0.5, the thesis's).
    pub c_skel: f32,
    /// `c_skel=learned` (the default): a probability per node, learned by a training pass
    /// from the render's camera (`guide::training`); 0 (not guided at all) where guiding is not
    /// measurably better than BSDF sampling. The thesis's one global c = 0.5 guides open
    /// rooms too, where the lobes only add variance and lose to `path` per sample
    /// (BENCHMARKS.md).
    pub learned_c_skel: bool,
    /// `c_max`: with `c_skel=learned`, the largest guiding probability the training may choose
    /// (default [`DEFAULT_C_MAX`]). A BSDF-sampled direction that no lobe covers is weighted
    /// 1 / (1 - c) times what `path` gives it, once per such vertex: a cap bounds that factor
    /// (3.3 at 0.7, 10 at 0.9) where the training's samples missed the rare paths that make
    /// it a firefly (a node learning 0.9 lets a single sample dominate a run's squared error
    /// on Sponza; BENCHMARKS.md).
    pub c_max: f32,
    /// `ratio_max=R`: a bound on how much more than `path` a guided path may weigh. At each
    /// vertex the weight of the direction against BSDF sampling alone is p_bsdf / q <= 1 /
    /// (1 - c), and along a path these factors multiply (the directions the BSDF draws where
    /// the guide's density is small carry up to 1 / (1 - c) of `path`'s weight at each such
    /// vertex). With `ratio_max` the render lowers a vertex's c to 1 - rho / R, rho the
    /// product of p_bsdf / q over the path's earlier directions (0 once rho >= R), so that the
    /// directions' densities never weigh a path more than R times `path`'s for the same
    /// directions (the MIS weights of light samples and emitter hits aside; they stay <= 1).
    /// `None` (`ratio_max=auto`, the default): [`AUTO_RATIO_MAX`], trained or not. Why a
    /// bound at all: at a vertex where the guide's density is small, the BSDF's direction
    /// weighs 1 / (1 - c) of `path`'s, and averaged over BSDF-drawn directions the factor
    /// E_bsdf[p_bsdf / q] is at least 1 (Cauchy-Schwarz) wherever the guide does not aim at
    /// what the path will find. Light that arrives after many bounces (on the closed family
    /// scenes at depth 65 most of the second moment is next-event estimation at depth 7 and
    /// beyond) is such a contribution for every vertex before it, so the path's second moment
    /// grows like a product of these factors. A fixed c guides where the lobes miss the light
    /// as much as where they find it (a family scene of two rooms: single samples at 4x
    /// `path`'s largest); the training's choices do it too, on paths longer than its own:
    /// unbounded, the trained guide's per-sample variance was 1.38x `path`'s on rooms:18,
    /// 0.83x with R = 2 (BENCHMARKS.md, "Procedural family", the product). The directions the
    /// guide draws (rho falls) leave the bound room; chains of them, the corridor's gain,
    /// are not cut. c then depends on the path's prefix only, and the vertex's every density
    /// (its direction's, its light sample's MIS weight, the next emitter hit's) is the
    /// mixture at that c: unbiased.
    pub ratio_max: Option<f32>,
    /// Strength of eq. 163 at every guided node unless `learned_strength`; with it, the
    /// training pass's proposal strength.
    pub strength: SkeletonStrength,
    /// `strength=learned`: a strength per node from [`STRENGTH_CANDIDATES`], chosen by the
    /// training pass together with the probability (`guide::training`). Without a camera the
    /// guide keeps `strength` (and `c_skel`) everywhere.
    pub learned_strength: bool,
    /// `lobe_weights=learned`: each node's lobe selection probabilities chosen by the training
    /// pass (`guide::training`, "Lobe weights") among eq. 165's, each lobe alone and a
    /// variance-minimising fit; lobes given 0 are skipped at render time. `distance` (the
    /// default): eq. 165's inverse-square weights everywhere. Not with `strength=learned`.
    pub learned_lobe_weights: bool,
    /// `directions=learned` (the default): each trained node samples a directional
    /// histogram learned from its training samples instead of its lobes
    /// (`guide::directional`): no aim, no spherical rectangle, no guide shadow ray, and ahead
    /// of the lobes by MSE at equal time on the test scenes (BENCHMARKS.md). `lobes`: the lobes (eq. 163-165). Not with
    /// `strength=learned` or `lobe_weights=learned`, which weigh lobes: naming either without
    /// naming `directions` implies `directions=lobes` ([`set`](Self::set)).
    pub learned_directions: bool,
    /// Whether `directions` was named ([`set`](Self::set)); if not, setting `lobe_weights` or
    /// `strength` makes `learned_directions` false while either is learned and true otherwise.
    /// Not an option key.
    pub directions_named: bool,
    /// The training's cost of guiding at a vertex beyond an unguided vertex's, shadow rays
    /// aside, in unguided vertices (`training_guided_cost`, default
    /// [`DEFAULT_TRAINING_GUIDED_COST`], `guide::training`, "Cost").
    pub training_guided_cost: f32,
    /// What the training charges for guiding (`cost_model`; `guide::training`,
    /// "Measured cost and the scene-level switch"): see [`CostModel`].
    pub cost_model: CostModel,
    /// Vertices per training path (`training_depth`).
    pub training_depth: u32,
    /// `pilot_paths=N` (default [`DEFAULT_PILOT_PATHS`], 0: none): camera rays of the pilot
    /// that checks the scene-level switch's prediction with the render's own estimator
    /// (`integrator::path`, "The pilot"), each traced twice guided and twice unguided.
    pub pilot_paths: u32,
    /// `pilot_cost=time` (the default) or `work`: what the pilot takes as the guided
    /// sample's cost against the unguided one's (`integrator::path`, "The pilot").
    pub pilot_cost: PilotCost,
    /// Camera paths of the training pass (`training_paths`).
    pub training_paths: u32,
    /// `training_passes=N` (with `directions=learned`; default 1): training passes of
    /// `training_paths` paths each; every pass after the first samples from the previous
    /// pass's learned distributions and re-learns them from its own samples
    /// (`guide::training`, "Iterative training").
    pub training_passes: u32,
    /// `training_history=all` (with `training_passes` above 1): each pass's histograms also
    /// count the earlier passes' weighted samples; `last` (the default): its own only.
    pub training_history: bool,
    /// `histogram_floor=F` (with `directions=learned`): the uniform share of every learned
    /// histogram (`guide::directional`), in (0, 1]; default [`directional::FLOOR`].
    pub histogram_floor: f32,
    /// How the training pass weighs the guide's overhead (`training_cost`).
    pub training_cost: TrainingCost,
    /// Standard errors by which guiding must beat not guiding for `c_skel=learned` to guide
    /// a node (`training_significance`).
    pub training_significance: f32,
    /// Non-zero training samples a node needs before `c_skel=learned` may guide it
    /// (`training_min_nonzero`, default [`DEFAULT_TRAINING_MIN_NONZERO`]): the second moment
    /// the choice compares is a mean of squares, and with a few hundred non-zero samples the
    /// best of 70 candidates wins by its winner's margin.
    pub training_min_nonzero: u32,
    /// Resolution of the analysis grid. By default a budget of 2^20 voxels: the thinning's
    /// time grows with the voxel count, so a budget bounds the precomputation whatever the
    /// scene's shape (0.3-0.8 s on two quiet cores for the test scenes, about 1 % of a 60 s
    /// render; the thesis's 234-voxel grids take 1-3.5 s, over the 5 % budget for Sibenik),
    /// and it still resolves the door's gap (the door gets 183 voxels along its longest axis,
    /// more than the thesis's 118; a cube like the Cornell box gets about 100).
    pub resolution: Resolution,
    /// Rays traced from the lights to find the importance nodes (eq. 176).
    pub light_rays: u32,
    /// Importance nodes kept (the most powerful).
    pub max_importance_nodes: u32,
    /// Lobes per node (the largest selection weights), 1..=`MAX_LOBES`.
    pub max_lobes: u32,
    /// Drop a lobe whose importance point is hidden from the shading point (one shadow ray
    /// per lobe per point).
    pub visibility_test: bool,
    /// `visibility=voxel` (the default; `visibility=true` tests per point): with the
    /// visibility test, decide it from the centre of the empty voxel the point maps to
    /// instead of from the point itself, once per voxel and lobe target (`SkeletonGuide`
    /// caches the answers). The lobes at a point stay a function of the point
    /// alone (its mapped voxel, its normal side), so the estimator stays unbiased; what changes
    /// is that points near an occluder's silhouette may get a lobe the point itself does not
    /// see through (those samples are wasted), or lose one it does.
    pub voxel_visibility: bool,
    /// Where each lobe aims (see [`LobeAim`]). By default at the opening's rectangle
    /// (`aim=portal`): aiming through the opening lowers the error per sample against eq.
    /// 162's point where a lobe passes a narrow opening (the Veach door), and
    /// changes nothing where there is none (the corridor); the opening's rectangle fits a slit
    /// better than a round lobe around it (BENCHMARKS.md).
    pub aim: LobeAim,
    /// What a lobe with an opening does where x does not see its bottleneck (see
    /// [`LobeFallback`]); only with `aim=opening` or `aim=portal`.
    pub fallback: LobeFallback,
    /// How the render using this guide samples lights and weighs its MIS pair, so that the
    /// training scores candidates with the render's own weights. `path_skeleton` sets it from
    /// its own settings; a host's guide keeps the defaults (power heuristic, area-sampled
    /// triangles, the default environment strategy). Not an option key.
    pub render_estimator: RenderEstimator,
    /// The wall-clock seconds the whole run (precomputation and render) may take, where the
    /// host gave a budget (`lacuna compare`; `Integrator::set_time_budget`): the scout then
    /// also stops the training where the full training would take more than
    /// [`BUDGET_SHARE`] of it. Not an option key.
    pub time_budget: Option<f64>,
}

/// The largest share of a time budget the training may take after its scout (a guide that
/// gains E per sample then still ends at E (1 - share) of `path`).
pub const BUDGET_SHARE: f64 = 0.2;

/// The render's light sampling and MIS heuristic, as the training must reproduce them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RenderEstimator {
    pub mis: MisHeuristic,
    pub triangles: TriangleSampling,
    pub env: EnvStrategy,
}

/// What the training pass compares the guide's overhead at a vertex with (`guide::training`,
/// "Cost").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrainingCost {
    /// One unguided vertex: each vertex judged as if it were the whole sample.
    Vertex,
    /// The vertices the vertex's estimate is made of: itself and the rest of its path.
    Path,
}

impl TrainingCost {
    pub fn parse(text: &str) -> Result<Self> {
        match text.trim() {
            "vertex" => Ok(TrainingCost::Vertex),
            "path" => Ok(TrainingCost::Path),
            other => Err(Error::invalid(format!(
                "skeleton training_cost '{other}' must be 'vertex' or 'path'"
            ))),
        }
    }
}

/// What the training charges for guiding (`cost_model`; `guide::training`, "Measured cost and
/// the scene-level switch").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CostModel {
    /// `vertices`: a guided vertex costs `training_guided_cost` unguided vertices plus its
    /// shadow rays; no scene-level switch.
    Vertices,
    /// `switch`: the nodes chosen as with `vertices`, then the scene-level switch judges the
    /// whole image with the measured costs and guides nothing unless it gains.
    Switch,
    /// `measured`: the nodes also chosen with the measured costs (a per-query cost and the
    /// node mapping), then the scene-level switch.
    Measured,
    /// `paths` (the default): the nodes chosen as with `vertices`, then the scene-level switch
    /// with the variance of the whole camera path's estimate (`guide::training`, "The path-level
    /// prediction") instead of the sum of the vertices' variances.
    Paths,
}

impl CostModel {
    pub fn parse(text: &str) -> Result<Self> {
        match text.trim() {
            "vertices" => Ok(CostModel::Vertices),
            "switch" => Ok(CostModel::Switch),
            "measured" => Ok(CostModel::Measured),
            "paths" => Ok(CostModel::Paths),
            other => Err(Error::invalid(format!(
                "skeleton cost_model '{other}' must be 'vertices', 'switch', 'measured' or 'paths'"
            ))),
        }
    }

    /// Whether the scene-level switch applies.
    pub fn switches(self) -> bool {
        self != CostModel::Vertices
    }
}

/// The strengths `strength=learned` chooses from (with `auto` the training proposal's
/// default, so the unlearned choice is among them).
pub const STRENGTH_CANDIDATES: [SkeletonStrength; 7] = [
    SkeletonStrength::Fixed(1.0),
    SkeletonStrength::Fixed(2.0),
    SkeletonStrength::Fixed(4.0),
    SkeletonStrength::Fixed(8.0),
    SkeletonStrength::Fixed(16.0),
    SkeletonStrength::Auto { max: 16.0 },
    SkeletonStrength::Auto {
        max: DEFAULT_AUTO_MAX,
    },
];

/// Default of `training_significance`: a stricter test leaves unguided nodes whose training
/// estimates guiding clearly better, because the rare samples that make guiding pay also make
/// its standard error large (`guide::training`, "Choice").
pub const DEFAULT_TRAINING_SIGNIFICANCE: f32 = 1.0;

/// Default of `training_guided_cost`, from a callgrind profile of the door: lobe set-up and
/// densities against a `path` vertex's instructions (`guide::training`, "Cost").
pub const DEFAULT_TRAINING_GUIDED_COST: f32 = 0.15;

/// Default of `training_min_nonzero`: fewer non-zero samples make the standard error itself
/// untrustworthy.
pub const DEFAULT_TRAINING_MIN_NONZERO: u32 = 32;

/// `ratio_max=auto` (module docs of [`SkeletonGuideSettings::ratio_max`]): a path keeps
/// guiding until its directions weigh it twice `path`'s (the first vertex's c at most 0.5).
pub const AUTO_RATIO_MAX: f32 = 2.0;

/// Default camera paths of the training pass: fewer leave the choices unstable on scenes whose
/// gains are in rare samples (the corridor).
pub const DEFAULT_TRAINING_PATHS: u32 = 1 << 17;

/// Default largest learned guiding probability (`c_max`).
pub const DEFAULT_C_MAX: f32 = 0.7;

/// Default vertices per training path: the integrators' default maximum depth.
pub const DEFAULT_TRAINING_DEPTH: u32 = 8;
/// Camera rays of the pilot (`pilot_paths`): 4 x 32768 render samples, a few tenths of a
/// second on the family scenes.
pub const DEFAULT_PILOT_PATHS: u32 = 32768;

/// What the pilot takes as a sample's cost (`pilot_cost`; `integrator::path`, "The pilot").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PilotCost {
    /// `time`: the measured time of the guided samples against the unguided ones, traced
    /// interleaved (what the render pays; the verdict then varies a little between runs).
    Time,
    /// `work`: rays traced per sample times the training's overhead ratio (a deterministic
    /// count, which underestimates the guided queries' cost).
    Work,
}

impl PilotCost {
    pub fn parse(text: &str) -> Result<Self> {
        match text.trim() {
            "time" => Ok(PilotCost::Time),
            "work" => Ok(PilotCost::Work),
            other => Err(Error::invalid(format!(
                "skeleton pilot_cost '{other}' must be 'time' or 'work'"
            ))),
        }
    }
}

/// Where a lobe points from a surface point x.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LobeAim {
    /// The skeleton importance point of eq. 162 (the centre of the path prefix visible from
    /// the node), with the automatic strength from the narrowest ball of that prefix.
    ImportancePoint,
    /// A variant of eq. 162 (module docs, "Aiming through the opening"): the path's
    /// bottleneck, its node of smallest maximal ball, when x sees it (one shadow ray), the
    /// lobe as wide as that ball looks from x; else the importance point as above.
    Opening,
    /// Like `Opening`, but where x sees the bottleneck it samples directions uniformly in
    /// the solid angle of the opening's cross-section fitted as a rectangle (module docs,
    /// "Sampling the opening itself"), not a round lobe around it.
    Portal,
}

impl LobeAim {
    pub fn parse(text: &str) -> Result<Self> {
        match text.trim() {
            "point" | "importance_point" => Ok(LobeAim::ImportancePoint),
            "opening" => Ok(LobeAim::Opening),
            "portal" => Ok(LobeAim::Portal),
            other => Err(Error::invalid(format!(
                "skeleton aim '{other}' must be 'point' (eq. 162), 'opening' or 'portal'"
            ))),
        }
    }
}

/// What a lobe whose path has an opening does at a point x that does not see the opening's
/// bottleneck (or sees it below its surface), with `aim=opening` or `aim=portal`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LobeFallback {
    /// Aim at the importance point of eq. 162 instead (a second shadow ray).
    Point,
    /// Drop the lobe; the lobes kept are renormalised. Aiming at the point instead can send
    /// most of a lobe's probability into empty space with no light (the ajar's near room, at
    /// the back room's point in front of the door).
    Drop,
}

impl LobeFallback {
    pub fn parse(text: &str) -> Result<Self> {
        match text.trim() {
            "point" => Ok(LobeFallback::Point),
            "drop" => Ok(LobeFallback::Drop),
            other => Err(Error::invalid(format!(
                "skeleton fallback '{other}' must be 'point' (eq. 162) or 'drop'"
            ))),
        }
    }
}

impl std::fmt::Display for LobeAim {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            LobeAim::ImportancePoint => "point",
            LobeAim::Opening => "opening",
            LobeAim::Portal => "portal",
        })
    }
}

impl Default for SkeletonGuideSettings {
    fn default() -> Self {
        SkeletonGuideSettings {
            c_skel: 0.5,
            learned_c_skel: true,
            c_max: DEFAULT_C_MAX,
            ratio_max: None,
            strength: SkeletonStrength::Auto {
                max: DEFAULT_AUTO_MAX,
            },
            learned_strength: false,
            learned_lobe_weights: false,
            learned_directions: true,
            directions_named: false,
            training_guided_cost: DEFAULT_TRAINING_GUIDED_COST,
            cost_model: CostModel::Paths,
            training_depth: DEFAULT_TRAINING_DEPTH,
            pilot_paths: DEFAULT_PILOT_PATHS,
            pilot_cost: PilotCost::Time,
            training_paths: DEFAULT_TRAINING_PATHS,
            training_passes: 1,
            training_history: false,
            histogram_floor: directional::FLOOR,
            training_cost: TrainingCost::Path,
            training_significance: DEFAULT_TRAINING_SIGNIFICANCE,
            training_min_nonzero: DEFAULT_TRAINING_MIN_NONZERO,
            resolution: Resolution::VoxelBudget(DEFAULT_VOXEL_BUDGET),
            light_rays: 1 << 14,
            max_importance_nodes: 32,
            max_lobes: 4,
            visibility_test: true,
            voxel_visibility: true,
            aim: LobeAim::Portal,
            fallback: LobeFallback::Point,
            render_estimator: RenderEstimator::default(),
            time_budget: None,
        }
    }
}

/// The option names [`SkeletonGuideSettings::set`] accepts.
pub const OPTION_NAMES: &[&str] = &[
    "c_skel",
    "strength",
    "resolution",
    "voxel_budget",
    "light_rays",
    "importance_nodes",
    "lobes",
    "visibility",
    "aim",
    "fallback",
    "training_depth",
    "training_paths",
    "training_passes",
    "training_history",
    "histogram_floor",
    "training_cost",
    "training_significance",
    "training_min_nonzero",
    "lobe_weights",
    "training_guided_cost",
    "c_max",
    "ratio_max",
    "cost_model",
    "directions",
    "pilot_paths",
    "pilot_cost",
];

impl SkeletonGuideSettings {
    /// Whether the guide runs the training pass (something is learned).
    /// Whether the training starts with a scout (`guide::training`, "The scout"): where the
    /// choices are learned and checked by the scene-level switch and the pilot, in one pass.
    pub fn scouts(&self) -> bool {
        self.learned_c_skel
            && self.cost_model.switches()
            && self.pilot_paths > 0
            && self.training_passes == 1
            && !self.training_history
            && self.training_paths >= training::SCOUT_FRACTION
    }

    pub fn trains(&self) -> bool {
        self.learned_c_skel
            || self.learned_strength
            || self.learned_lobe_weights
            || self.learned_directions
    }

    /// Sets one option by name from text (integrator specs, scene files): `c_skel` (a number
    /// or `learned`),
    /// `strength` (a number, `auto`, `auto:MAX` or `learned`; `learned` keeps the strength set
    /// before as the training proposal), `resolution` (voxels along the longest
    /// axis), `voxel_budget` (most voxels in the grid), `light_rays`,
    /// `importance_nodes`, `lobes`, `visibility` (true, voxel or false), `aim` (`point`, `opening` or `portal`),
    /// `fallback` (`point` or `drop`),
    /// and for the training pass `training_depth` (1..=64), `training_paths`
    /// (1024..=2^24), `training_passes` (1..=4, more than 1 only with `directions=learned`),
    /// `training_history` (`last` or `all`), `histogram_floor` (in (0, 1]),
    /// `training_cost` (`path` or
    /// `vertex`), `training_significance` (>= 0), `training_min_nonzero`,
    /// `training_guided_cost` (>= 0), `cost_model` (`vertices`, `switch`, `measured` or `paths`),
    /// `lobe_weights` (`distance` or `learned`), `c_max` (the largest learned c, in [0.05, 1)),
    /// `ratio_max` (a number > 1, or `off`) and `directions` (`lobes` or `learned`). Validates
    /// the result.
    pub fn set(&mut self, key: &str, value: &str) -> Result<()> {
        fn number<T: std::str::FromStr>(key: &str, value: &str) -> Result<T> {
            value.trim().parse().map_err(|_| {
                Error::invalid(format!(
                    "skeleton option {key}: '{value}' is not a valid number"
                ))
            })
        }
        let mut next = *self;
        match key {
            "c_skel" if value.trim() == "learned" => next.change_c_skel(None),
            "c_skel" => next.change_c_skel(Some(number(key, value)?)),
            "strength" | "s" if value.trim() == "learned" => next.change_strength(None),
            "strength" | "s" => next.change_strength(Some(SkeletonStrength::parse(value)?)),
            "lobe_weights" => {
                next.learned_lobe_weights = match value.trim() {
                    "learned" => true,
                    "distance" => false,
                    other => {
                        return Err(Error::invalid(format!(
                            "skeleton lobe_weights '{other}' must be 'learned' or 'distance'"
                        )))
                    }
                };
                next.imply_directions();
            }
            "directions" => {
                next.directions_named = true;
                next.learned_directions = match value.trim() {
                    "learned" => true,
                    "lobes" => false,
                    other => {
                        return Err(Error::invalid(format!(
                            "skeleton directions '{other}' must be 'learned' or 'lobes'"
                        )))
                    }
                }
            }
            "training_depth" => next.training_depth = number(key, value)?,
            "pilot_paths" => next.pilot_paths = number(key, value)?,
            "pilot_cost" => next.pilot_cost = PilotCost::parse(value)?,
            "training_paths" => next.training_paths = number(key, value)?,
            "training_passes" => next.training_passes = number(key, value)?,
            "histogram_floor" => next.histogram_floor = number(key, value)?,
            "training_history" => {
                next.training_history = match value.trim() {
                    "all" => true,
                    "last" => false,
                    other => {
                        return Err(Error::invalid(format!(
                            "skeleton training_history '{other}' must be 'all' or 'last'"
                        )))
                    }
                }
            }
            "training_cost" => next.training_cost = TrainingCost::parse(value)?,
            "training_significance" => next.training_significance = number(key, value)?,
            "training_min_nonzero" => next.training_min_nonzero = number(key, value)?,
            "training_guided_cost" => next.training_guided_cost = number(key, value)?,
            "c_max" => next.c_max = number(key, value)?,
            "ratio_max" if value.trim() == "off" => next.ratio_max = Some(f32::INFINITY),
            "ratio_max" if value.trim() == "auto" => next.ratio_max = None,
            "ratio_max" => next.ratio_max = Some(number(key, value)?),
            "cost_model" => next.cost_model = CostModel::parse(value)?,
            "resolution" => next.resolution = Resolution::LongestAxis(number(key, value)?),
            "voxel_budget" => next.resolution = Resolution::VoxelBudget(number(key, value)?),
            "light_rays" => next.light_rays = number(key, value)?,
            "importance_nodes" => next.max_importance_nodes = number(key, value)?,
            "lobes" => next.max_lobes = number(key, value)?,
            "aim" => next.aim = LobeAim::parse(value)?,
            "fallback" => next.fallback = LobeFallback::parse(value)?,
            "visibility" => {
                (next.visibility_test, next.voxel_visibility) = match value.trim() {
                    "true" | "1" => (true, false),
                    "voxel" => (true, true),
                    "false" | "0" => (false, false),
                    other => {
                        return Err(Error::invalid(format!(
                            "skeleton option visibility: '{other}' must be true, voxel or false"
                        )))
                    }
                }
            }
            other => {
                return Err(Error::invalid(format!(
                    "unknown skeleton option '{other}' (known: {})",
                    OPTION_NAMES.join(", ")
                )))
            }
        }
        next.validate()?;
        *self = next;
        Ok(())
    }

    /// Applies `change` and validates the result; on an error nothing changes. The typed way
    /// to set options (command line, C API); [`set`](Self::set) parses text into the same
    /// changes.
    pub fn update(&mut self, change: impl FnOnce(&mut Self)) -> Result<()> {
        let mut next = *self;
        change(&mut next);
        next.validate()?;
        *self = next;
        Ok(())
    }

    /// `c_skel`: one fixed probability, or `None` for `learned`.
    pub fn set_c_skel(&mut self, c_skel: Option<f32>) -> Result<()> {
        self.update(|s| s.change_c_skel(c_skel))
    }

    /// `strength`: one rule for every lobe, or `None` for `learned` (the strength set before
    /// stays the training's proposal).
    pub fn set_strength(&mut self, strength: Option<SkeletonStrength>) -> Result<()> {
        self.update(|s| s.change_strength(strength))
    }

    fn change_c_skel(&mut self, c_skel: Option<f32>) {
        match c_skel {
            Some(c) => {
                self.c_skel = c;
                self.learned_c_skel = false;
            }
            None => self.learned_c_skel = true,
        }
    }

    fn change_strength(&mut self, strength: Option<SkeletonStrength>) {
        match strength {
            Some(s) => {
                self.strength = s;
                self.learned_strength = false;
            }
            None => self.learned_strength = true,
        }
        self.imply_directions();
    }

    /// `lobe_weights=learned` and `strength=learned` weigh lobes: unless `directions` was
    /// named (then a contradiction is [`validate`](Self::validate)'s error), the directions
    /// are the lobes while either is set and learned otherwise (the default).
    fn imply_directions(&mut self) {
        if !self.directions_named {
            self.learned_directions = !(self.learned_lobe_weights || self.learned_strength);
        }
    }

    pub fn validate(&self) -> Result<()> {
        if !(self.c_skel.is_finite() && (0.0..1.0).contains(&self.c_skel)) {
            return Err(Error::invalid(format!(
                "c_skel {} must be in [0, 1): BSDF sampling must keep a non-zero probability",
                self.c_skel
            )));
        }
        self.strength.validate()?;
        if self.pilot_paths > 1 << 22 {
            return Err(Error::invalid(format!(
                "skeleton pilot_paths {} must be at most 4194304",
                self.pilot_paths
            )));
        }
        if !(1..=64).contains(&self.training_depth) {
            return Err(Error::invalid(format!(
                "skeleton training_depth {} must be within 1..=64",
                self.training_depth
            )));
        }
        if !(1024..=1 << 24).contains(&self.training_paths) {
            return Err(Error::invalid(format!(
                "skeleton training_paths {} must be within 1024..=2^24",
                self.training_paths
            )));
        }
        if !(self.histogram_floor > 0.0 && self.histogram_floor <= 1.0) {
            return Err(Error::invalid(format!(
                "skeleton histogram_floor {} must be in (0, 1]",
                self.histogram_floor
            )));
        }
        if !(1..=4).contains(&self.training_passes) {
            return Err(Error::invalid(format!(
                "skeleton training_passes {} must be within 1..=4",
                self.training_passes
            )));
        }
        if self.training_passes > 1 && !self.learned_directions {
            // Later passes sample from the learned distributions.
            return Err(Error::invalid(
                "skeleton training_passes above 1 needs directions=learned",
            ));
        }
        if !(self.training_significance.is_finite() && self.training_significance >= 0.0) {
            return Err(Error::invalid(format!(
                "skeleton training_significance {} must be a number >= 0",
                self.training_significance
            )));
        }
        match self.resolution {
            Resolution::LongestAxis(n) if !(4..=4096).contains(&n) => {
                return Err(Error::invalid(format!(
                    "skeleton resolution {n} must be within 4..=4096 voxels along the longest axis"
                )))
            }
            Resolution::VoxelBudget(n) if !(64..=1 << 31).contains(&n) => {
                return Err(Error::invalid(format!(
                    "skeleton voxel budget {n} must be within 64..=2^31"
                )))
            }
            Resolution::VoxelSize(v) if !(v > 0.0 && v.is_finite()) => {
                return Err(Error::invalid(format!(
                    "skeleton voxel size {v} must be positive and finite"
                )))
            }
            _ => {}
        }
        if self.fallback == LobeFallback::Drop && self.aim == LobeAim::ImportancePoint {
            // Without an opening to aim at there is nothing to fall back from: say so rather
            // than accept a setting that does nothing.
            return Err(Error::invalid(
                "skeleton fallback=drop needs aim=opening or aim=portal",
            ));
        }
        if !(self.training_guided_cost.is_finite() && self.training_guided_cost >= 0.0) {
            return Err(Error::invalid(format!(
                "skeleton training_guided_cost {} must be a number >= 0",
                self.training_guided_cost
            )));
        }
        if !(self.c_max >= super::training::CANDIDATES[1] && self.c_max < 1.0) {
            return Err(Error::invalid(format!(
                "skeleton c_max {} must be in [{}, 1)",
                self.c_max,
                super::training::CANDIDATES[1]
            )));
        }
        if let Some(r) = self.ratio_max.filter(|r| !(*r > 1.0)) {
            // At most 1 guides nothing (the cap would be c = 0 at the first vertex); NaN fails.
            return Err(Error::invalid(format!(
                "skeleton ratio_max {r} must be > 1 (or off, or auto)"
            )));
        }
        if self.learned_lobe_weights && self.learned_strength {
            // The training records each lobe's density at the proposal's strength only.
            return Err(Error::invalid(
                "skeleton lobe_weights=learned does not combine with strength=learned",
            ));
        }
        if self.learned_directions && (self.learned_lobe_weights || self.learned_strength) {
            // The learned distribution replaces the lobes: there is nothing to weigh.
            return Err(Error::invalid(
                "skeleton directions=learned does not combine with lobe_weights=learned or strength=learned (they weigh lobes: name directions=lobes, or leave directions out)",
            ));
        }
        if self.light_rays == 0 {
            return Err(Error::invalid("skeleton light rays must be at least 1"));
        }
        if self.max_importance_nodes == 0 {
            return Err(Error::invalid("at least one importance node must be kept"));
        }
        if !(1..=MAX_LOBES as u32).contains(&self.max_lobes) {
            return Err(Error::invalid(format!(
                "max_lobes {} must be within 1..={MAX_LOBES}",
                self.max_lobes
            )));
        }
        Ok(())
    }
}

/// A node whose mapped surfaces receive emitted power.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImportanceNode {
    /// Filtered skeleton node index.
    pub node: u32,
    /// Estimated emitted power arriving on its surfaces (luminance, W), eq. 176.
    pub power: f32,
}

/// A lobe target of one node: toward the importance point of one importance node.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GuideLobe {
    /// Skeleton importance point (eq. 162), world space.
    pub point: Vec3,
    /// Smallest maximal-ball radius along the visible prefix of the path (world units).
    pub radius: f32,
    /// Selection probability among the node's lobes (eq. 165 over the lobes kept, or the
    /// learned one with `lobe_weights=learned`; 0: the lobe is never used).
    pub probability: f32,
    /// Index into [`SkeletonGuide::importance_nodes`]: the most probable of the importance
    /// nodes whose lobes coincide (same point and radius) and were merged into this one.
    pub importance: u32,
    /// Graph distance to that importance node.
    pub distance: f32,
    /// The path's bottleneck (module docs, "Aiming through the opening"): position of the
    /// node of smallest maximal ball on the shortest path to the importance node, the node
    /// itself excluded, and the radius of the disc with the area of the opening there
    /// (measured across the path, at least the ball's). Equal to `point` and `radius` when
    /// the path has no node after this one.
    pub opening: Vec3,
    pub opening_radius: f32,
    /// With `aim=portal`: the opening's cross-section at the bottleneck as a rectangle.
    pub portal: Option<Portal>,
}

impl GuideLobe {
    /// Whether the lobe's path has a bottleneck distinct from its importance point (module
    /// docs, "Aiming through the opening").
    pub fn has_opening(&self) -> bool {
        self.opening != self.point || self.opening_radius != self.radius
    }
}

/// A planar rectangle across a path at its bottleneck: `centre ± half.x u ± half.y v`, with
/// `u`, `v` orthonormal (the principal axes of the opening's outline) and normal `u × v`
/// along the path.
#[derive(Clone, Copy, Debug, PartialEq)]
///
/// The fields are private: `frame` is derived from the others when the portal is made, and a
/// portal changed afterwards would sample with a stale frame.
pub struct Portal {
    centre: Vec3,
    u: Vec3,
    v: Vec3,
    half: Vec2,
    /// The rectangle's corner and frame, set up once for every point that sees it (a function
    /// of the fields above; None for a rectangle without area, which no point sees).
    frame: Option<warp::RectangleFrame>,
}

impl Portal {
    fn new(centre: Vec3, u: Vec3, v: Vec3, half: Vec2) -> Portal {
        let corner = centre - half.x * u - half.y * v;
        let size = 2.0 * half;
        Portal {
            centre,
            u,
            v,
            half,
            frame: warp::RectangleFrame::new(corner, u, v, size.x, size.y),
        }
    }

    /// The rectangle as seen from `p`, for sampling uniformly in solid angle (None where p is
    /// in its plane).
    pub fn seen_from(&self, p: Vec3) -> Option<warp::SphericalRectangle> {
        self.frame.as_ref()?.seen_from(p)
    }

    /// [`Self::seen_from`] written into `rect` (false where it gives None).
    #[inline]
    fn seen_from_into(&self, p: Vec3, rect: &mut warp::SphericalRectangle) -> bool {
        self.frame
            .as_ref()
            .is_some_and(|frame| frame.seen_from_into(p, rect))
    }
}

/// What [`GuideQuery::init`] needs of a node's lobe beyond the lobe itself, found once at build
/// rather than searched per lobe and vertex: which of the node's distinct lobe targets
/// (openings and importance points, equal as `Vec3`s) and distinct portals (equal as
/// `Portal`s) the lobe's are. The answers (the shadow ray, the rectangle) stay per point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct LobePlan {
    /// Whether the lobe aims through its opening ([`GuideLobe::has_opening`] and an aim other
    /// than `point`).
    through_opening: bool,
    /// Slots of the lobe's opening and importance point among the node's distinct targets:
    /// the index of the first target of the node equal to each, in the order opening, point
    /// of lobe 0, then of lobe 1, ...
    opening_slot: u8,
    point_slot: u8,
    /// With a portal: the index of the node's first lobe whose portal equals this one's.
    portal_slot: Option<u8>,
}

/// The plans of one node's lobes ([`LobePlan`]).
fn plan_lobes(lobes: &[GuideLobe], aim: LobeAim) -> Vec<LobePlan> {
    debug_assert!(lobes.len() <= MAX_LOBES);
    let mut targets: Vec<Vec3> = Vec::with_capacity(2 * lobes.len());
    let mut slot_of = |t: Vec3| -> u8 {
        match targets.iter().position(|&seen| seen == t) {
            Some(i) => i as u8,
            None => {
                targets.push(t);
                (targets.len() - 1) as u8
            }
        }
    };
    lobes
        .iter()
        .enumerate()
        .map(|(j, lobe)| LobePlan {
            through_opening: lobe.has_opening() && aim != LobeAim::ImportancePoint,
            opening_slot: slot_of(lobe.opening),
            point_slot: slot_of(lobe.point),
            portal_slot: lobe.portal.as_ref().map(|portal| {
                lobes[..=j]
                    .iter()
                    .position(|l| l.portal.as_ref() == Some(portal))
                    .unwrap_or(j) as u8
            }),
        })
        .collect()
}

/// What a guide was built from, to refuse rendering another scene with it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct SceneFingerprint {
    triangles: usize,
    lights: usize,
    bounds: [u32; 6],
}

impl SceneFingerprint {
    fn of(scene: &Scene) -> Self {
        let b = scene.bounds();
        SceneFingerprint {
            triangles: scene.triangle_count(),
            lights: scene.lights().len(),
            bounds: [
                b.min.x.to_bits(),
                b.min.y.to_bits(),
                b.min.z.to_bits(),
                b.max.x.to_bits(),
                b.max.y.to_bits(),
                b.max.z.to_bits(),
            ],
        }
    }
}

/// Skeleton guiding data of one scene. Immutable after `build`; queries are thread-safe.
pub struct SkeletonGuide {
    settings: SkeletonGuideSettings,
    grid: VoxelGrid,
    node_map: Vec<u32>,
    /// `grid.dims` in f64, for the query's test whether a point lies inside the grid.
    grid_extent: [f64; 3],
    /// Which neighbours of each voxel are mapped, for the query's node mapping.
    neighbours: NeighbourMasks,
    /// With `visibility=voxel`: per voxel, the lobe targets its centre sees
    /// ([`SkeletonGuide::voxel_sees`]); empty otherwise.
    voxel_sees: Vec<AtomicU32>,
    node_positions: Vec<Vec3>,
    node_radii: Vec<f32>,
    /// Lobes of node k: `lobes[lobe_start[k]..lobe_start[k + 1]]`, by decreasing probability.
    lobe_start: Vec<u32>,
    lobes: Vec<GuideLobe>,
    /// `plans[i]`: the query's plan of `lobes[i]` ([`LobePlan`]).
    plans: Vec<LobePlan>,
    /// Probability of sampling the lobes at each node: `c_skel`, or learned per node.
    node_c: Vec<f32>,
    /// Strength at each node with `strength=learned`; empty: `settings.strength` everywhere.
    node_strength: Vec<SkeletonStrength>,
    /// What the training pass of `c_skel=learned` found (None with a fixed `c_skel`).
    training: Option<TrainingReport>,
    /// With `directions=learned`: the nodes' learned distributions (`guide::directional`).
    directions: Option<Arc<DirectionalTable>>,
    /// Per voxel: a point in it may map to a node with a guiding probability above 0 (see
    /// `analysis::may_map_to`); queries elsewhere skip the mapping. Empty: everywhere. One bit
    /// per voxel (a 1 M voxel grid: 128 KB, where one byte per voxel missed the caches at
    /// most vertices).
    may_guide: VoxelSet,
    /// No node has a guiding probability above 0 (every node learned c = 0, or the
    /// scene-level switch of `cost_model=switch|measured`): `path_skeleton` then traces
    /// exactly `path`'s samples.
    guides_nothing: bool,
    importance: Vec<ImportanceNode>,
    /// Nodes with a non-zero power estimate before the `max_importance_nodes` cut.
    importance_found: usize,
    raw_nodes: usize,
    edges: usize,
    timings: Vec<StageTime>,
    fingerprint: SceneFingerprint,
}

/// Longest visible prefix averaged into an importance point. Eq. 162 takes the whole visible
/// prefix; in long open spaces (Sibenik's nave) that means hundreds of shadow rays per node and
/// lobe (3 s of Sibenik's precomputation under load), while the nodes beyond the first few
/// dozen only move the point further along the same line of sight.
const MAX_PREFIX: u32 = 24;

/// Seed of the light-tracing pass (the guide is a deterministic function of the scene).
const LIGHT_TRACING_SEED: u64 = 0x5ce1_e70a;
/// Rays per parallel chunk of the light-tracing pass.
const LIGHT_CHUNK: u32 = 4096;

/// The two bits of lobe target `target` in a voxel's visibility cell
/// ([`SkeletonGuide::voxel_sees`]): (answer known, target seen).
#[inline]
fn voxel_sees_bits(target: u32) -> (u32, u32) {
    (1u32 << (2 * target), 1u32 << (2 * target + 1))
}

impl SkeletonGuide {
    /// Runs the precomputation (module docs) on the current rayon pool. `progress(stage,
    /// fraction)` is called between stages and may cancel by returning false.
    pub fn build(
        scene: &Scene,
        camera: Option<&Camera>,
        settings: &SkeletonGuideSettings,
        progress: &dyn Fn(&str, f64) -> bool,
    ) -> Result<SkeletonGuide> {
        settings.validate()?;
        let started = Instant::now();
        if !progress("start", 0.0) {
            return Err(Error::Cancelled);
        }
        let mut timings = Vec::new();
        let mut stage = |name: &'static str, t: Instant, fraction: f64| -> Result<()> {
            timings.push(StageTime {
                stage: name,
                seconds: t.elapsed().as_secs_f64(),
            });
            if progress(name, fraction) {
                Ok(())
            } else {
                Err(Error::Cancelled)
            }
        };

        let t = Instant::now();
        // Only what the skeleton uses: its maps, not the regions and portals.
        let analysis_settings = AnalysisSettings {
            resolution: settings.resolution,
            all_maps: true,
            // Computed by the skeleton beside its thinning.
            euclidean: false,
            regions: false,
            ..Default::default()
        };
        let analysis = Analysis::build(scene, &analysis_settings, &|_, _| true)?;
        stage("analysis (voxels, maps)", t, 0.3)?;

        let t = Instant::now();
        let skeleton_settings = SkeletonSettings {
            parallel: true,
            topology: false,
        };
        let skeleton = Skeleton::build(&analysis, &skeleton_settings, &|_, _| true)?;
        drop(analysis);
        let Skeleton {
            grid,
            raw,
            filtered,
            node_map,
            ..
        } = skeleton;
        let graph = filtered.graph;
        stage("skeleton (thinning, filter, node map)", t, 0.7)?;

        let t = Instant::now();
        let power = trace_light_power(scene, &grid, &node_map, graph.nodes.len(), settings);
        let mut importance: Vec<ImportanceNode> = power
            .iter()
            .enumerate()
            .filter(|(_, &p)| p > 0.0 && p.is_finite())
            .map(|(node, &p)| ImportanceNode {
                node: node as u32,
                power: p as f32,
            })
            .collect();
        let importance_found = importance.len();
        importance.sort_by(|a, b| b.power.total_cmp(&a.power).then(a.node.cmp(&b.node)));
        importance.truncate(settings.max_importance_nodes as usize);
        stage("importance nodes (light tracing)", t, 0.8)?;

        let t = Instant::now();
        let adjacency = weighted_adjacency(&graph);
        let trees: Vec<ShortestPaths> = importance
            .par_iter()
            .map(|imp| dijkstra(&adjacency, imp.node))
            .collect();
        stage("shortest paths (Dijkstra)", t, 0.85)?;

        let t = Instant::now();
        let openings = OpeningFits::default();
        let per_node: Vec<Vec<GuideLobe>> = (0..graph.nodes.len())
            .into_par_iter()
            .map(|k| node_lobes(scene, &graph, k, &importance, &trees, settings, &openings))
            .collect();
        let mut lobe_start = Vec::with_capacity(per_node.len() + 1);
        let mut lobes = Vec::new();
        let mut plans = Vec::new();
        lobe_start.push(0u32);
        for l in per_node {
            plans.extend(plan_lobes(&l, settings.aim));
            lobes.extend(l);
            lobe_start.push(lobes.len() as u32);
        }
        stage("importance points (eq. 162)", t, 0.9)?;

        let node_count = graph.nodes.len();
        let mut guide = SkeletonGuide {
            settings: *settings,
            neighbours: NeighbourMasks::new(&grid, &node_map),
            grid_extent: grid.dims.map(|n| n as f64),
            voxel_sees: if settings.visibility_test && settings.voxel_visibility {
                (0..grid.len()).map(|_| AtomicU32::new(0)).collect()
            } else {
                Vec::new()
            },
            grid,
            node_map,
            node_positions: graph.nodes.iter().map(|n| n.position).collect(),
            node_radii: graph.nodes.iter().map(|n| n.radius).collect(),
            lobe_start,
            lobes,
            plans,
            node_c: vec![
                if settings.trains() {
                    training::TRAINING_C
                } else {
                    settings.c_skel
                };
                node_count
            ],
            node_strength: Vec::new(),
            training: None,
            directions: None,
            may_guide: VoxelSet::new(0),
            guides_nothing: false,
            importance,
            importance_found,
            raw_nodes: raw.nodes.len(),
            edges: graph.edges.len(),
            timings: Vec::new(),
            fingerprint: SceneFingerprint::of(scene),
        };
        if settings.trains() {
            let t = Instant::now();
            let mut history = vec![
                Vec::new();
                if settings.training_history {
                    node_count
                } else {
                    0
                }
            ];
            // The scout (`guide::training`, "The scout"): a fraction of the training paths
            // first, and the full training only if their choices guide anything.
            let scout = if settings.scouts() && camera.is_some() {
                let full = guide.settings.training_paths;
                guide.settings.training_paths = (full / training::SCOUT_FRACTION).max(1);
                let scout_started = Instant::now();
                let mut report =
                    training::learn_guiding_probabilities(&guide, scene, camera, 0, &mut history);
                guide.settings.training_paths = full;
                // With a time budget: the rest of the training, at the scout's pace, must fit
                // in BUDGET_SHARE of it with what the precomputation has spent already.
                let rest =
                    scout_started.elapsed().as_secs_f64() * (training::SCOUT_FRACTION - 1) as f64;
                let over_budget = settings
                    .time_budget
                    .is_some_and(|b| started.elapsed().as_secs_f64() + rest > BUDGET_SHARE * b);
                if over_budget && report.paths > 0 {
                    report.turn_off(settings);
                }
                Some(report).filter(|r| r.paths > 0 && r.probabilities.iter().all(|&c| c <= 0.0))
            } else {
                None
            };
            let mut report = match scout {
                Some(report) => report,
                None => {
                    training::learn_guiding_probabilities(&guide, scene, camera, 0, &mut history)
                }
            };
            // Iterative training (`training_passes`): each later pass samples every node from
            // the previous pass's distributions (a uniform one where it had none) and learns
            // them again from its own samples; only the last pass's choices are kept.
            for pass in 1..settings.training_passes {
                if report.paths == 0 {
                    break;
                }
                let uniform =
                    vec![1.0 / directional::BINS as f32; directional::CLASSES * directional::BINS];
                guide.directions = Some(Arc::new(DirectionalTable::with_default(
                    &report.directions,
                    Some(&uniform),
                )));
                report = training::learn_guiding_probabilities(
                    &guide,
                    scene,
                    camera,
                    pass,
                    &mut history,
                );
            }
            guide.directions = None;
            if report.paths == 0 {
                // No camera to train from: the documented fixed default.
                guide.node_c = vec![settings.c_skel; node_count];
            } else {
                guide.node_c = report.probabilities.clone();
                if settings.learned_strength {
                    guide.node_strength = report.strengths.clone();
                }
                // Learned selection probabilities replace eq. 165's in place: the lobes keep
                // their indices (the voxel visibility cache the training filled is keyed by
                // them), and a lobe given 0 is skipped by every query.
                for (k, weights) in report.lobe_weights.iter().enumerate() {
                    if let Some(weights) = weights {
                        let start = guide.lobe_start[k] as usize;
                        let end = guide.lobe_start[k + 1] as usize;
                        for (lobe, &w) in guide.lobes[start..end].iter_mut().zip(weights) {
                            lobe.probability = w;
                        }
                    }
                }
            }
            // Without a camera nothing was learned: the lobes at the fixed c, as documented.
            if settings.learned_directions && report.paths > 0 {
                // Only nodes that are guided keep their distribution.
                let kept: Vec<Option<Vec<f32>>> = report
                    .directions
                    .iter()
                    .zip(&guide.node_c)
                    .map(|(d, &c)| d.clone().filter(|_| c > 0.0))
                    .collect();
                guide.directions = Some(Arc::new(DirectionalTable::new(&kept)));
            }
            guide.training = Some(report);
            if settings.learned_c_skel {
                let node_c = &guide.node_c;
                guide.may_guide =
                    VoxelSet::from_flags(&may_map_to(&guide.grid, &guide.node_map, |n| {
                        node_c[n as usize] > 0.0
                    }));
            }
            stage("guiding probabilities (training)", t, 1.0)?;
        }
        guide.guides_nothing = guide.node_c.iter().all(|&c| c <= 0.0);
        guide.timings = timings;
        Ok(guide)
    }

    pub fn settings(&self) -> &SkeletonGuideSettings {
        &self.settings
    }

    /// True when the guide was built for `scene` (same triangles, lights and bounds).
    pub fn built_for(&self, scene: &Scene) -> bool {
        self.fingerprint == SceneFingerprint::of(scene)
    }

    /// With `visibility=voxel`: per node, the (voxel, target) answers the cache holds, i.e.
    /// the shadow rays traced so far to fill it (one per answer, whichever thread stored it).
    /// The set of answers a pass needs does not depend on the order of its queries, so this
    /// count does not either, unlike a per-query count when some queries are not recorded.
    /// None without the cache.
    pub(super) fn voxel_visibility_rays(&self) -> Option<Vec<u32>> {
        if self.voxel_sees.is_empty() {
            return None;
        }
        let all_known = (0..2 * MAX_LOBES as u32).fold(0, |m, t| m | voxel_sees_bits(t).0);
        let mut rays = vec![0u32; self.node_count()];
        for (cell, &node) in self.voxel_sees.iter().zip(&self.node_map) {
            let known = (cell.load(AtomicOrdering::Relaxed) & all_known).count_ones();
            if known > 0 {
                rays[node as usize] += known;
            }
        }
        Some(rays)
    }

    /// Filtered skeleton nodes.
    pub fn node_count(&self) -> usize {
        self.node_positions.len()
    }

    pub fn node_position(&self, node: u32) -> Option<Vec3> {
        self.node_positions.get(node as usize).copied()
    }

    /// Maximal-ball radius of a node (world units).
    pub fn node_radius(&self, node: u32) -> Option<f32> {
        self.node_radii.get(node as usize).copied()
    }

    /// Nodes of the skeleton before filtering.
    pub fn raw_node_count(&self) -> usize {
        self.raw_nodes
    }

    pub fn edge_count(&self) -> usize {
        self.edges
    }

    /// The importance nodes kept, by decreasing power.
    pub fn importance_nodes(&self) -> &[ImportanceNode] {
        &self.importance
    }

    /// Nodes that received power before the `max_importance_nodes` cut.
    pub fn importance_nodes_found(&self) -> usize {
        self.importance_found
    }

    /// The lobes of a node (empty when it has no path to any importance node).
    pub fn lobes(&self, node: u32) -> &[GuideLobe] {
        let k = node as usize;
        if k + 1 >= self.lobe_start.len() {
            return &[];
        }
        &self.lobes[self.lobe_start[k] as usize..self.lobe_start[k + 1] as usize]
    }

    /// The lobes of a node with their plans ([`LobePlan`]).
    fn lobes_and_plans(&self, node: u32) -> (&[GuideLobe], &[LobePlan]) {
        let k = node as usize;
        if k + 1 >= self.lobe_start.len() {
            return (&[], &[]);
        }
        let range = self.lobe_start[k] as usize..self.lobe_start[k + 1] as usize;
        (&self.lobes[range.clone()], &self.plans[range])
    }

    /// Nodes with at least one lobe.
    pub fn guided_node_count(&self) -> usize {
        self.lobe_start.windows(2).filter(|w| w[1] > w[0]).count()
    }

    /// Node of a surface point (eq. 151-155).
    pub fn map_point(&self, p: Vec3, normal: Vec3, incident: Vec3) -> Option<u32> {
        self.neighbours
            .map_point(&self.grid, &self.node_map, p, normal, incident)
    }

    /// Node of a surface point and the mapped voxel it was taken from ([`Self::map_point`]).
    pub fn map_point_voxel(&self, p: Vec3, normal: Vec3, incident: Vec3) -> Option<(u32, usize)> {
        self.neighbours
            .map_point_voxel(&self.grid, &self.node_map, p, normal, incident)
            .map(|k| (self.node_map[k], k))
    }

    /// With `visibility=voxel`: whether the centre of `voxel` (an empty voxel, mapped to node
    /// `node_map[voxel]`) sees lobe target `target` of its node (`2 j` the opening of lobe j,
    /// `2 j + 1` its importance point), and the shadow rays traced to find out (0 when known).
    /// Each answer is traced at the first query that needs it and kept (two bits per target:
    /// known, seen); it is a pure function of the voxel and target, so whichever thread
    /// stores it first, the lobes at a point do not depend on the order of the queries.
    /// The ray is counted only by the query that stores the answer, so the count per node does
    /// not depend on thread timing either (two threads may both trace a cold entry; the
    /// training's cost model must not see that race). False and no ray for a target beyond
    /// the `2 MAX_LOBES` a cell holds.
    pub fn voxel_sees(&self, scene: &Scene, voxel: usize, target: u32) -> (bool, u32) {
        let Some(cell) = self.voxel_sees.get(voxel) else {
            return (false, 0);
        };
        if target as usize >= 2 * MAX_LOBES {
            return (false, 0);
        }
        let (known, seen) = voxel_sees_bits(target);
        let bits = cell.load(AtomicOrdering::Relaxed);
        if bits & known != 0 {
            return (bits & seen != 0, 0);
        }
        self.voxel_sees_traced(scene, voxel, target, cell)
    }

    /// [`Self::voxel_sees`] of a target not known yet in `cell` (out of line: rare once the
    /// cache is warm, and the common case then needs no registers saved).
    #[cold]
    #[inline(never)]
    fn voxel_sees_traced(
        &self,
        scene: &Scene,
        voxel: usize,
        target: u32,
        cell: &AtomicU32,
    ) -> (bool, u32) {
        let (known, seen) = voxel_sees_bits(target);
        let sees = self.voxel_sees_direct(scene, voxel, target);
        let before = cell.fetch_or(known | if sees { seen } else { 0 }, AtomicOrdering::Relaxed);
        (sees, u32::from(before & known == 0))
    }

    /// [`Self::voxel_sees`] without the cache: one shadow ray from the voxel's centre (empty
    /// space) to the target. False for targets the node does not have.
    pub fn voxel_sees_direct(&self, scene: &Scene, voxel: usize, target: u32) -> bool {
        let Some(lobe) = self.lobes(self.node_map[voxel]).get(target as usize / 2) else {
            return false;
        };
        let to = if target % 2 == 0 {
            lobe.opening
        } else {
            lobe.point
        };
        visible(scene, self.grid.voxel_center(voxel), to)
    }

    /// Probability of sampling the lobes at `node` (0 for nodes the guide does not know):
    /// `c_skel`, or with `c_skel=learned` the node's learned probability.
    pub fn guiding_probability(&self, node: u32) -> f32 {
        self.node_c.get(node as usize).copied().unwrap_or(0.0)
    }

    /// Strength of eq. 163 at `node`: the learned one with `strength=learned`, else the
    /// settings'.
    pub fn strength(&self, node: u32) -> SkeletonStrength {
        self.node_strength
            .get(node as usize)
            .copied()
            .unwrap_or(self.settings.strength)
    }

    /// False when a point at `p` cannot map to a node with a guiding probability above 0
    /// (then the query need not map it at all).
    pub fn may_guide_at(&self, p: Vec3) -> bool {
        self.may_guide_in(self.grid.voxel_of(p))
    }

    /// [`Self::may_guide_at`] for a point in voxel `v` (which may lie outside the grid).
    fn may_guide_in(&self, v: [i64; 3]) -> bool {
        if self.may_guide.is_empty() {
            return true;
        }
        if (0..3).any(|a| v[a] < 0 || v[a] >= self.grid.dims[a] as i64) {
            return true;
        }
        self.may_guide
            .get(self.grid.index(v[0] as usize, v[1] as usize, v[2] as usize))
    }

    /// [`Self::map_point_voxel`] where [`Self::may_guide_at`] allows it, else None; the grid
    /// coordinates of `p` computed once for both.
    fn map_guided_point(&self, p: Vec3, normal: Vec3, incident: Vec3) -> Option<(u32, usize)> {
        let g = self.grid.to_grid(p);
        let d = &self.grid_extent;
        let v = if g[0] >= 0.0
            && g[0] < d[0]
            && g[1] >= 0.0
            && g[1] < d[1]
            && g[2] >= 0.0
            && g[2] < d[2]
        {
            // Inside the grid (false for NaN) the floor is the truncation (no saturation, no
            // correction below zero), and the voxel needs no bounds test.
            // (`as i64`: one instruction, where `as usize` tests for values above 2^63.)
            let v = [g[0] as i64, g[1] as i64, g[2] as i64];
            let k = self.grid.index(v[0] as usize, v[1] as usize, v[2] as usize);
            if !self.may_guide.is_empty() && !self.may_guide.get(k) {
                return None;
            }
            v
        } else {
            let v = crate::analysis::grid::floor3_to_i64(g);
            if !self.may_guide_in(v) {
                return None;
            }
            v
        };
        self.neighbours
            .map_grid_point_voxel(&self.grid, &self.node_map, g, v, normal, incident)
            .map(|k| (self.node_map[k], k))
    }

    /// A hint ahead of [`GuideQuery::init`] at point `p` with geometric normal `normal` seen
    /// from `incident`: requests the cache lines the mapping most likely reads (the voxel's
    /// `may_guide` word, and the node map at the neighbour that the normal's dominant axis
    /// faces: the facing shortcut's voxel on walls, floors and ceilings), so that their misses
    /// overlap the work between the ray's hit and the query (the BSDF's texture lookups)
    /// instead of stalling it: they are the guided vertex's largest stalls in a wall-time
    /// profile. No effect on any result.
    #[inline]
    pub fn prefetch(&self, p: Vec3, normal: Vec3, incident: Vec3) {
        let g = self.grid.to_grid(p);
        let d = &self.grid_extent;
        if !(g[0] >= 0.0 && g[0] < d[0] && g[1] >= 0.0 && g[1] < d[1] && g[2] >= 0.0 && g[2] < d[2])
        {
            return;
        }
        let k = self.grid.index(
            g[0] as i64 as usize,
            g[1] as i64 as usize,
            g[2] as i64 as usize,
        );
        self.may_guide.prefetch(k);
        let n = if normal.dot(incident) >= 0.0 {
            normal
        } else {
            -normal
        };
        let a = n.abs();
        let [nx, ny, _] = self.grid.dims;
        let (stride, towards) = if a.x >= a.y && a.x >= a.z {
            (1, n.x)
        } else if a.y >= a.z {
            (nx, n.y)
        } else {
            (nx * ny, n.z)
        };
        let facing = if towards > 0.0 {
            k.wrapping_add(stride)
        } else {
            k.wrapping_sub(stride)
        };
        if let Some(m) = self.node_map.get(facing) {
            crate::math::prefetch(m);
        }
    }

    /// The bound on a guided path's weight against `path`'s the render applies
    /// ([`SkeletonGuideSettings::ratio_max`]; infinite: none).
    pub fn ratio_max(&self) -> f32 {
        self.settings.ratio_max.unwrap_or(AUTO_RATIO_MAX)
    }

    /// The pilot's verdict (`integrator::path`, "The pilot"): recorded in the training report,
    /// and unless `pays`, every node set to c = 0 so that `path_skeleton` traces `path`'s
    /// samples.
    pub fn apply_pilot(&mut self, pilot: super::Pilot) {
        if let Some(t) = self.training.as_mut() {
            t.scene.pilot = Some(pilot);
            if !pilot.pays() {
                t.scene.switched_off = true;
                t.probabilities.fill(0.0);
                t.relative_cost.fill(1.0);
            }
        }
        if !pilot.pays() {
            self.node_c.fill(0.0);
            self.guides_nothing = true;
        }
    }

    /// True when no node is guided (every learned c is 0): no query can guide, and
    /// `path_skeleton` skips the queries altogether (its samples are then `path`'s).
    pub fn guides_nothing(&self) -> bool {
        self.guides_nothing
    }

    /// The node of each voxel (the skeleton's node map), for the training's mapping count.
    pub(super) fn node_map(&self) -> &[u32] {
        &self.node_map
    }

    /// The training pass's findings with `c_skel=learned`.
    pub fn training(&self) -> Option<&TrainingReport> {
        self.training.as_ref()
    }

    pub fn grid(&self) -> &VoxelGrid {
        &self.grid
    }

    /// Wall-clock time of each precomputation stage.
    pub fn timings(&self) -> &[StageTime] {
        &self.timings
    }

    pub fn total_seconds(&self) -> f64 {
        self.timings.iter().map(|t| t.seconds).sum()
    }

    /// Bytes held (node map, nodes, lobes).
    pub fn memory_bytes(&self) -> usize {
        self.node_map.len() * 4
            + self.neighbours.memory_bytes()
            + self.voxel_sees.len() * 4
            + self.may_guide.memory_bytes()
            + self.node_c.len() * 4
            + self.node_positions.len() * 16
            + self.lobe_start.len() * 4
            + self.lobes.len() * std::mem::size_of::<GuideLobe>()
            + self.plans.len() * std::mem::size_of::<LobePlan>()
            + self.importance.len() * std::mem::size_of::<ImportanceNode>()
            + self.directions.as_ref().map_or(0, |d| d.memory_bytes())
    }

    /// With `directions=learned`: the nodes' learned directional distributions.
    pub fn directions(&self) -> Option<&Arc<DirectionalTable>> {
        self.directions.as_ref()
    }
}

/// Eq. 176 for every node at once: the emitted power (luminance) arriving on the surfaces
/// mapped to each node, from `light_rays` rays leaving the lights. Deterministic (fixed seed,
/// per-chunk streams, chunk sums added in chunk order).
fn trace_light_power(
    scene: &Scene,
    grid: &VoxelGrid,
    node_map: &[u32],
    nodes: usize,
    settings: &SkeletonGuideSettings,
) -> Vec<f64> {
    let Some(sampler) = scene.light_sampler() else {
        return vec![0.0; nodes];
    };
    let n = settings.light_rays;
    let chunks = n.div_ceil(LIGHT_CHUNK);
    let partial: Vec<Vec<f64>> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let mut sums = vec![0.0f64; nodes];
            let mut rng = Rng::new(LIGHT_TRACING_SEED, c as u64);
            let count = LIGHT_CHUNK.min(n - c * LIGHT_CHUNK);
            for _ in 0..count {
                let (index, pmf) = sampler.sample(rng.uniform());
                let light = &scene.lights()[index];
                let Some(e) = light.sample_emission(rng.uniform2(), rng.uniform2()) else {
                    continue;
                };
                let weight = luminance(e.value) as f64 / (e.pdf_emit as f64 * pmf as f64);
                if !(weight.is_finite() && weight > 0.0) {
                    continue;
                }
                let origin = offset_ray_origin(e.origin, e.origin_error, e.normal, e.dir);
                let Some(si) = scene.intersect(&Ray::new(origin, e.dir, f32::INFINITY)) else {
                    continue;
                };
                if let Some(node) = map_point(grid, node_map, si.p, si.ng, si.wo) {
                    sums[node as usize] += weight;
                }
            }
            sums
        })
        .collect();
    let mut power = vec![0.0f64; nodes];
    for sums in partial {
        for (p, s) in power.iter_mut().zip(sums) {
            *p += s;
        }
    }
    for p in &mut power {
        *p /= n as f64;
    }
    power
}

/// Neighbours of each node with the Euclidean length of the edge.
fn weighted_adjacency(graph: &Graph) -> Vec<Vec<(u32, f32)>> {
    let mut adj = vec![Vec::new(); graph.nodes.len()];
    for &[a, b] in &graph.edges {
        let d = graph.nodes[a as usize]
            .position
            .distance(graph.nodes[b as usize].position);
        adj[a as usize].push((b, d));
        adj[b as usize].push((a, d));
    }
    adj
}

/// Shortest paths from every node to one source.
struct ShortestPaths {
    /// Graph distance to the source (infinite when unreachable).
    distance: Vec<f32>,
    /// Next node on the way to the source (`u32::MAX` at the source and when unreachable).
    next: Vec<u32>,
}

#[derive(PartialEq)]
struct Queued(f32, u32);

impl Eq for Queued {}

impl Ord for Queued {
    // Reversed: BinaryHeap is a max-heap and Dijkstra pops the nearest node.
    fn cmp(&self, other: &Self) -> Ordering {
        other.0.total_cmp(&self.0).then(other.1.cmp(&self.1))
    }
}

impl PartialOrd for Queued {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

fn dijkstra(adjacency: &[Vec<(u32, f32)>], source: u32) -> ShortestPaths {
    let n = adjacency.len();
    let mut distance = vec![f32::INFINITY; n];
    let mut next = vec![u32::MAX; n];
    let mut heap = BinaryHeap::new();
    distance[source as usize] = 0.0;
    heap.push(Queued(0.0, source));
    while let Some(Queued(d, u)) = heap.pop() {
        if d > distance[u as usize] {
            continue;
        }
        for &(v, w) in &adjacency[u as usize] {
            let nd = d + w;
            if nd < distance[v as usize] {
                distance[v as usize] = nd;
                next[v as usize] = u;
                heap.push(Queued(nd, v));
            }
        }
    }
    ShortestPaths { distance, next }
}

/// True when nothing blocks the straight segment between two points of the empty space.
fn visible(scene: &Scene, a: Vec3, b: Vec3) -> bool {
    let d = b - a;
    let len = d.length();
    if len == 0.0 {
        return true;
    }
    !scene.occluded(&Ray::new(a, d / len, len * (1.0 - SHADOW_EPSILON)))
}

/// Longest stretch of a shortest path searched for its bottleneck (no rays are traced: a
/// walk along the tree).
const MAX_BOTTLENECK_SEARCH: u32 = 256;

/// A path's narrowest ball is an opening when the path has passed a ball at least this many
/// times wider before reaching it (a room narrowing into a door), not a corridor's small
/// variations of width. On the Veach door the gap's ball (7.6) follows the camera room's
/// (60.1): 7.9x; in the two rooms 8x; along the corridor at most 1.3x.
const OPENING_NARROWING: f32 = 2.0;

/// The bottleneck of the shortest path from node `k` in `tree`: position and radius of the
/// first node of smallest maximal ball after `k` (radii are whole voxels, so ties are common:
/// the first is the way into the narrow part), and the path's direction there (from the node
/// before it to the node after it, or to it at the path's end). None when the path has no
/// node after `k` or does not narrow by `OPENING_NARROWING` before its smallest ball.
fn bottleneck(graph: &Graph, tree: &ShortestPaths, k: usize) -> Option<(Vec3, f32, Vec3)> {
    let mut best: Option<(Vec3, f32, Vec3, f32)> = None;
    let mut previous = graph.nodes[k].position;
    let mut widest = graph.nodes[k].radius;
    let mut current = k as u32;
    let mut steps = 0;
    while tree.next[current as usize] != u32::MAX && steps < MAX_BOTTLENECK_SEARCH {
        current = tree.next[current as usize];
        let n = &graph.nodes[current as usize];
        let narrower = match best {
            Some((_, r, _, _)) => n.radius < r,
            None => true,
        };
        if narrower {
            let after = tree.next[current as usize];
            let ahead = if after == u32::MAX {
                n.position
            } else {
                graph.nodes[after as usize].position
            };
            let along = (ahead - previous).normalize_or_zero();
            best = Some((n.position, n.radius, along, widest));
        }
        widest = widest.max(n.radius);
        previous = n.position;
        steps += 1;
    }
    best.filter(|&(_, r, _, wider)| wider >= OPENING_NARROWING * r)
        .map(|(at, r, along, _)| (at, r, along))
}

/// Rays cast across the path at a bottleneck to measure its opening.
const OPENING_RAYS: u32 = 16;

/// The radius of the disc with the area of the opening at `centre` across the path direction
/// `along`: `OPENING_RAYS` rays in the plane normal to `along` (each at most `cap` long) give
/// the opening's outline, a polygon of area `sum d_j d_(j+1) sin(2 pi / N) / 2`. A maximal
/// ball measures an opening's narrowest width; the door's gap is a slit as tall as the door
/// and a few voxels wide, which a lobe as wide as the ball would cover only a sliver of.
/// At least `ball` (the opening is no smaller than its inscribed ball).
fn opening_radius(scene: &Scene, centre: Vec3, along: Vec3, ball: f32, cap: f32) -> f32 {
    if along == Vec3::ZERO {
        return ball;
    }
    let frame = Frame::from_z(along);
    let step = 2.0 * std::f32::consts::PI / OPENING_RAYS as f32;
    let reach: Vec<f32> = (0..OPENING_RAYS)
        .map(|j| {
            let (sin, cos) = (j as f32 * step).sin_cos();
            let dir = frame.to_world(Vec3::new(cos, sin, 0.0));
            scene
                .intersect(&Ray::new(centre, dir, cap))
                .map_or(cap, |hit| hit.t)
        })
        .collect();
    let area: f32 = (0..reach.len())
        .map(|j| reach[j] * reach[(j + 1) % reach.len()])
        .sum::<f32>()
        * 0.5
        * step.sin();
    (area / std::f32::consts::PI).sqrt().max(ball)
}

/// Rays cast across the path at a bottleneck to find the principal axes of its opening.
const PORTAL_RAYS: u32 = 64;
/// Plane normals tried for a portal (module docs: the path's direction at the bottleneck is
/// a poor normal where the path crosses a slit obliquely), with cosines down to
/// `PORTAL_TILT_COS` to the path's direction (75°).
const PORTAL_NORMALS: u32 = 96;
const PORTAL_TILT_COS: f32 = 0.25;
/// Rays per tried normal to measure the cross-section's area.
const PORTAL_AREA_RAYS: u32 = 32;

/// Distance from `centre` along `dir` to the first surface, at most `cap`.
fn reach(scene: &Scene, centre: Vec3, dir: Vec3, cap: f32) -> f32 {
    scene
        .intersect(&Ray::new(centre, dir, cap))
        .map_or(cap, |hit| hit.t)
}

/// Area of the opening's outline in the plane through `centre` normal to `normal`, from
/// `rays` rays (the polygon of `opening_radius`).
fn cross_section_area(scene: &Scene, centre: Vec3, normal: Vec3, rays: u32, cap: f32) -> f32 {
    let frame = Frame::from_z(normal);
    let step = 2.0 * std::f32::consts::PI / rays as f32;
    let d: Vec<f32> = (0..rays)
        .map(|j| {
            let (sin, cos) = (j as f32 * step).sin_cos();
            reach(scene, centre, frame.to_world(Vec3::new(cos, sin, 0.0)), cap)
        })
        .collect();
    (0..d.len())
        .map(|j| d[j] * d[(j + 1) % d.len()])
        .sum::<f32>()
        * 0.5
        * step.sin()
}

/// The opening's cross-section at `centre` fitted as a rectangle. Its plane is the one of
/// least cross-section area among `PORTAL_NORMALS` normals around the path direction `along`
/// (a slit crossed obliquely is cut square, not along its length); in it `PORTAL_RAYS` rays
/// (each at most `cap` long) outline the opening, the outline's second moments about `centre`
/// give its principal axes, and one ray each way along both axes its extents (a slit's length
/// measured along the slit, not by the ray that happens to come closest to its axis). None
/// when `along` is zero.
fn opening_rectangle(scene: &Scene, centre: Vec3, along: Vec3, cap: f32) -> Option<Portal> {
    if along == Vec3::ZERO {
        return None;
    }
    let around = Frame::from_z(along);
    let golden = std::f32::consts::PI * (3.0 - 5.0f32.sqrt());
    let mut normal = along;
    let mut least = cross_section_area(scene, centre, along, PORTAL_AREA_RAYS, cap);
    for i in 0..PORTAL_NORMALS {
        // A Fibonacci spiral over the cap of normals within the tilt bound.
        let cos = 1.0 - (1.0 - PORTAL_TILT_COS) * (i as f32 + 0.5) / PORTAL_NORMALS as f32;
        let sin = (1.0 - cos * cos).max(0.0).sqrt();
        let phi = golden * i as f32;
        let n = around.to_world(Vec3::new(sin * phi.cos(), sin * phi.sin(), cos));
        let area = cross_section_area(scene, centre, n, PORTAL_AREA_RAYS, cap);
        if area < least {
            least = area;
            normal = n;
        }
    }
    let frame = Frame::from_z(normal);
    let step = 2.0 * std::f64::consts::PI / PORTAL_RAYS as f64;
    let (mut sxx, mut sxy, mut syy) = (0.0f64, 0.0f64, 0.0f64);
    for j in 0..PORTAL_RAYS {
        let (sin, cos) = (j as f64 * step).sin_cos();
        let dir = frame.to_world(Vec3::new(cos as f32, sin as f32, 0.0));
        let d = reach(scene, centre, dir, cap) as f64;
        let (qx, qy) = (d * cos, d * sin);
        sxx += qx * qx;
        sxy += qx * qy;
        syy += qy * qy;
    }
    let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let (sin, cos) = (theta.sin() as f32, theta.cos() as f32);
    let u = frame.to_world(Vec3::new(cos, sin, 0.0)).normalize();
    let v = normal.cross(u).normalize();
    let [u_plus, u_minus, v_plus, v_minus] = [u, -u, v, -v].map(|d| reach(scene, centre, d, cap));
    Some(Portal::new(
        centre + 0.5 * (u_plus - u_minus) * u + 0.5 * (v_plus - v_minus) * v,
        u,
        v,
        0.5 * Vec2::new(u_plus + u_minus, v_plus + v_minus),
    ))
}

/// Longest side of a portal, in maximal-ball radii of its bottleneck (an opening into open
/// space has no measurable extent; a larger rectangle only wastes samples on walls).
const PORTAL_CAP: f32 = 64.0;

/// The measured openings of the bottlenecks, shared by the nodes' lobes: every node upstream
/// of a door reaches it along the same path segment, so the door's opening (its radius, and
/// with `aim=portal` its rectangle, about 3,200 rays) would otherwise be measured again for
/// every such node and lobe. The measurements are pure functions of the key (bottleneck
/// position, path direction, ball radius, bit for bit), so which thread fills an entry first
/// changes nothing: the guide stays identical across thread counts.
#[derive(Default)]
struct OpeningFits {
    fits: std::sync::Mutex<std::collections::HashMap<OpeningKey, OpeningFit>>,
}

/// Bits of a bottleneck's position, path direction and ball radius.
type OpeningKey = [u32; 7];
/// The opening's area-equivalent radius and, with `aim=portal`, its rectangle.
type OpeningFit = (f32, Option<Portal>);

impl OpeningFits {
    /// The opening's radius ([`opening_radius`]) and, with `aim=portal`, its rectangle
    /// ([`opening_rectangle`]) at bottleneck `at` crossed along `along`, of maximal ball `ball`.
    fn get(
        &self,
        scene: &Scene,
        settings: &SkeletonGuideSettings,
        at: Vec3,
        along: Vec3,
        ball: f32,
    ) -> OpeningFit {
        let key: OpeningKey = [
            at.x.to_bits(),
            at.y.to_bits(),
            at.z.to_bits(),
            along.x.to_bits(),
            along.y.to_bits(),
            along.z.to_bits(),
            ball.to_bits(),
        ];
        let lock = || {
            self.fits
                .lock()
                .unwrap_or_else(|poisoned| poisoned.into_inner())
        };
        if let Some(&fit) = lock().get(&key) {
            return fit;
        }
        // Measured outside the lock (the other thread may measure the same key meanwhile:
        // same result).
        let fit = (
            opening_radius(scene, at, along, ball, 16.0 * ball),
            (settings.aim == LobeAim::Portal)
                .then(|| opening_rectangle(scene, at, along, PORTAL_CAP * ball))
                .flatten(),
        );
        lock().insert(key, fit);
        fit
    }
}

/// The lobes of node `k`: selection weights (eq. 164-165) and importance points (eq. 162).
fn node_lobes(
    scene: &Scene,
    graph: &Graph,
    k: usize,
    importance: &[ImportanceNode],
    trees: &[ShortestPaths],
    settings: &SkeletonGuideSettings,
    openings: &OpeningFits,
) -> Vec<GuideLobe> {
    let node = &graph.nodes[k];
    let mut candidates: Vec<(f64, usize)> = importance
        .iter()
        .zip(trees)
        .enumerate()
        .filter(|(_, (_, tree))| tree.distance[k].is_finite())
        .map(|(i, (imp, tree))| {
            let d = tree.distance[k].max(node.radius).max(1e-30) as f64;
            (imp.power as f64 / (d * d), i)
        })
        .filter(|(w, _)| *w > 0.0 && w.is_finite())
        .collect();
    candidates.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    candidates.truncate(settings.max_lobes as usize);
    let total: f64 = candidates.iter().map(|c| c.0).sum();
    let mut lobes: Vec<GuideLobe> = Vec::with_capacity(candidates.len());
    for (weight, i) in candidates {
        let tree = &trees[i];
        let from = node.position;
        let mut sum = from;
        let mut count = 1u32;
        let mut radius = node.radius;
        let mut current = k as u32;
        while tree.next[current as usize] != u32::MAX && count < MAX_PREFIX {
            current = tree.next[current as usize];
            let n = &graph.nodes[current as usize];
            if !visible(scene, from, n.position) {
                break;
            }
            sum += n.position;
            count += 1;
            radius = radius.min(n.radius);
        }
        let point = sum / count as f32;
        let (opening, opening_radius, portal) = match bottleneck(graph, tree, k) {
            Some((at, ball, along)) => {
                let (radius, portal) = openings.get(scene, settings, at, along, ball);
                (at, radius, portal)
            }
            None => (point, radius, None),
        };
        let probability = (weight / total) as f32;
        // Shortest paths to several importance nodes often share their visible prefix (every
        // way out of a room goes through its door): their lobes are one lobe, and keeping them
        // apart would cost one shadow ray and one lobe evaluation each per vertex for nothing.
        if let Some(same) = lobes.iter_mut().find(|l| {
            l.point == point
                && l.radius == radius
                && l.opening == opening
                && l.opening_radius == opening_radius
                && l.portal == portal
        }) {
            same.probability += probability;
            continue;
        }
        lobes.push(GuideLobe {
            point,
            radius,
            probability,
            importance: i as u32,
            distance: tree.distance[k],
            opening,
            opening_radius,
            portal,
        });
    }
    lobes.sort_by(|a, b| b.probability.total_cmp(&a.probability));
    lobes
}

/// One lobe of an initialised query.
#[derive(Clone, Debug)]
struct ActiveLobe {
    /// The power-cosine lobe's axis (unit), toward the lobe's target; its frame is set up only
    /// to sample it (the density needs the cosine alone).
    axis: Vec3,
    exponent: f32,
    probability: f32,
    /// Free-space radius and distance the automatic strength was taken from (the lobe's
    /// exponent under any other strength, for the training pass).
    radius: f32,
    distance: f32,
    /// With `aim=portal` where the point sees the bottleneck: directions uniform toward the
    /// opening's rectangle `rect` instead of the power-cosine lobe (`rect` is meaningless
    /// otherwise).
    portal: bool,
    rect: warp::SphericalRectangle,
}

impl ActiveLobe {
    #[inline]
    fn pdf(&self, w: Vec3, exponent: f32) -> f32 {
        if self.portal {
            self.rect.pdf(w)
        } else {
            warp::power_cosine_pdf_cos(w.dot(self.axis), exponent)
        }
    }
}

/// `GuideQuery::lobe_of` of a node lobe that does not apply at the point.
const NOT_ACTIVE: u8 = u8::MAX;

/// An unused lobe slot of a query.
const fn no_lobe() -> ActiveLobe {
    ActiveLobe {
        axis: Vec3::Z,
        exponent: 0.0,
        probability: 0.0,
        radius: 0.0,
        distance: 0.0,
        portal: false,
        rect: warp::SphericalRectangle::empty(),
    }
}

/// The targets a query has aimed at, at one point (see [`GuideQuery::init`]): per slot of the
/// node's distinct targets ([`LobePlan`]), the axis and distance toward it where it applies.
struct Aims<'a> {
    guide: &'a SkeletonGuide,
    scene: &'a Scene,
    p: Vec3,
    p_error: Vec3,
    /// The normal on the incident direction's side.
    side: Vec3,
    voxel: usize,
    /// Shadow rays traced.
    rays: u32,
    /// Bit per slot: aimed at (`known`), and applies (`found`, then `at[slot]` holds it; the
    /// query's storage, left as the last point wrote it elsewhere).
    known: u32,
    found: u32,
    at: &'a mut [(Vec3, f32); 2 * MAX_LOBES],
}

impl Aims<'_> {
    /// Axis and distance toward `target` (slot `slot`) when it is above the surface and, with
    /// the visibility test, seen from p; found once per slot and point. `index` is the
    /// target's number for the voxel's visibility cache (`2 j` the opening of lobe j, `2 j +
    /// 1` its importance point): that of the first lobe that aims at the target at this point.
    #[inline(always)]
    fn aim(&mut self, slot: u8, target: Vec3, index: u32) -> Option<(Vec3, f32)> {
        let bit = 1u32 << slot;
        if self.known & bit != 0 {
            return (self.found & bit != 0).then(|| self.at[slot as usize]);
        }
        self.known |= bit;
        let found = self.aim_at(target, index);
        if let Some(at) = found {
            self.found |= bit;
            self.at[slot as usize] = at;
        }
        found
    }

    /// [`Self::aim`] without the memory (out of line: the memory's test is the common case).
    #[inline(never)]
    fn aim_at(&mut self, target: Vec3, index: u32) -> Option<(Vec3, f32)> {
        let to = target - self.p;
        let distance = to.length();
        let axis = to / distance;
        if !(distance > 0.0 && distance.is_finite()) || axis.dot(self.side) <= 0.0 {
            return None;
        }
        let settings = &self.guide.settings;
        if settings.visibility_test && settings.voxel_visibility {
            // visibility=voxel: what the mapped voxel's centre sees, instead of a ray from p.
            let (sees, traced) = self.guide.voxel_sees(self.scene, self.voxel, index);
            self.rays += traced;
            if !sees {
                return None;
            }
        } else if settings.visibility_test {
            self.rays += 1;
            let origin = offset_ray_origin(self.p, self.p_error, self.side, axis);
            let ray = Ray::new(origin, axis, distance * (1.0 - SHADOW_EPSILON));
            if self.scene.occluded(&ray) {
                return None;
            }
        }
        Some((axis, distance))
    }
}

/// The skeleton sampling distribution at one surface point (eq. 163-167): a mixture of
/// power-cosine lobes. Reusable: one per worker thread, `init` at each point. Holds no
/// reference to the guide, so it can outlive the call that initialised it.
#[derive(Clone, Debug)]
pub struct GuideQuery {
    lobes: [ActiveLobe; MAX_LOBES],
    /// Scratch of `init` ([`Aims`]): kept in the query so that no vertex clears it.
    aimed: [(Vec3, f32); 2 * MAX_LOBES],
    count: usize,
    /// For each of the node's lobes (`SkeletonGuide::lobes`), the active lobe it went into
    /// (merged lobes share one), or `NOT_ACTIVE`: what the training needs to evaluate the
    /// mixture under other selection probabilities.
    lobe_of: [u8; MAX_LOBES],
    c_skel: f32,
    node: Option<u32>,
    /// `directions=learned`: the guide's table and this point's slot in it (`NO_SLOT`: the
    /// lobes, if any, apply). The table is cloned into the query once, not per point.
    directions: Option<Arc<DirectionalTable>>,
    slot: u32,
}

/// [`GuideQuery`]'s slot where no learned distribution applies.
const NO_SLOT: u32 = u32::MAX;

impl Default for GuideQuery {
    fn default() -> Self {
        Self::new()
    }
}

impl GuideQuery {
    /// An unguided query (guiding probability 0) until `init` finds lobes.
    pub const fn new() -> Self {
        GuideQuery {
            lobes: [const { no_lobe() }; MAX_LOBES],
            aimed: [(Vec3::ZERO, 0.0); 2 * MAX_LOBES],
            count: 0,
            lobe_of: [NOT_ACTIVE; MAX_LOBES],
            c_skel: 0.0,
            node: None,
            directions: None,
            slot: NO_SLOT,
        }
    }

    /// A shared unguided query, for integrators without a guide: reading it costs nothing,
    /// while making a query writes its whole lobe array (about 400 bytes, per path).
    pub fn unguided() -> &'static GuideQuery {
        static UNGUIDED: GuideQuery = GuideQuery::new();
        &UNGUIDED
    }

    /// Makes the query unguided (guiding probability 0), as at a point no lobe reaches.
    pub fn clear(&mut self) {
        self.count = 0;
        self.node = None;
        self.slot = NO_SLOT;
    }

    /// A query that samples one learned directional distribution (`guide::directional`) of
    /// bin probabilities `bins` ([`directional::BINS`] of them, >= 0, renormalised), for tests
    /// and hosts. Fails on a wrong count, negative or non-finite entries, no positive entry
    /// or `c_skel` outside [0, 1).
    pub fn with_distribution(c_skel: f32, bins: &[f32]) -> Result<GuideQuery> {
        if !(c_skel.is_finite() && (0.0..1.0).contains(&c_skel)) {
            return Err(Error::invalid(format!("c_skel {c_skel} must be in [0, 1)")));
        }
        let total: f32 = bins.iter().sum();
        if bins.len() != directional::BINS
            || bins.iter().any(|&b| !(b.is_finite() && b >= 0.0))
            || !(total > 0.0 && total.is_finite())
        {
            return Err(Error::invalid(format!(
                "a directional distribution needs {} finite bin weights >= 0, some positive",
                directional::BINS
            )));
        }
        let p: Vec<f32> = bins.iter().map(|b| b / total).collect();
        let p = p.repeat(directional::CLASSES);
        let mut q = GuideQuery::new();
        q.directions = Some(Arc::new(DirectionalTable::new(&[Some(p)])));
        q.slot = 0;
        q.c_skel = c_skel;
        Ok(q)
    }

    /// A query with explicit lobes (axis, exponent, weight), weights renormalised; for hosts
    /// and tests that build their own lobes. Fails on non-finite or zero axes, exponents out
    /// of [0, `MAX_STRENGTH`], negative weights, no positive weight, more than `MAX_LOBES`
    /// lobes or `c_skel` outside [0, 1).
    pub fn with_lobes(c_skel: f32, lobes: &[(Vec3, f32, f32)]) -> Result<GuideQuery> {
        if !(c_skel.is_finite() && (0.0..1.0).contains(&c_skel)) {
            return Err(Error::invalid(format!("c_skel {c_skel} must be in [0, 1)")));
        }
        if lobes.len() > MAX_LOBES {
            return Err(Error::invalid(format!(
                "{} lobes: at most {MAX_LOBES}",
                lobes.len()
            )));
        }
        let total: f32 = lobes.iter().map(|l| l.2).sum();
        let mut q = GuideQuery::new();
        for (i, &(axis, exponent, weight)) in lobes.iter().enumerate() {
            let unit = axis.normalize_or_zero();
            if !crate::math::is_finite3(axis) || unit == Vec3::ZERO {
                return Err(Error::invalid(format!(
                    "lobe {i}: axis {axis} is not a direction"
                )));
            }
            SkeletonStrength::Fixed(exponent).validate()?;
            if !(weight.is_finite() && weight >= 0.0) {
                return Err(Error::invalid(format!(
                    "lobe {i}: weight {weight} must be >= 0"
                )));
            }
            q.lobes[i] = ActiveLobe {
                axis: unit,
                exponent,
                probability: weight / total,
                radius: 0.0,
                distance: 0.0,
                portal: false,
                rect: warp::SphericalRectangle::empty(),
            };
        }
        if !(total > 0.0 && total.is_finite()) {
            return Err(Error::invalid(
                "the lobes need a positive finite total weight",
            ));
        }
        q.count = lobes.len();
        q.c_skel = c_skel;
        Ok(q)
    }

    /// Sets up the distribution at surface point `p` (floating-point error bound `p_error`,
    /// zero if unknown), geometric normal `normal` (either orientation) and incident direction
    /// `wo` (unit, pointing from p back to where the path came from), within `scene` (the
    /// scene the guide was built for; used by the visibility test). Returns the shadow rays
    /// traced. Afterwards [`guiding_probability`](Self::guiding_probability) is the node's
    /// probability (`c_skel`, or the learned one), or 0 when no lobe applies at p (or the
    /// node's probability is 0: then no lobe is set up and no shadow ray traced).
    pub fn init(
        &mut self,
        guide: &SkeletonGuide,
        scene: &Scene,
        p: Vec3,
        p_error: Vec3,
        normal: Vec3,
        wo: Vec3,
    ) -> u32 {
        self.count = 0;
        self.node = None;
        self.slot = NO_SLOT;
        self.lobe_of = [NOT_ACTIVE; MAX_LOBES];
        let Some((node, voxel)) = guide.map_guided_point(p, normal, wo) else {
            return 0;
        };
        self.node = Some(node);
        // A node not worth guiding (learned c = 0) costs no lobe work and no shadow ray.
        self.c_skel = guide.guiding_probability(node);
        if self.c_skel <= 0.0 {
            return 0;
        }
        // directions=learned: the node's distribution, or nothing (no lobes either).
        if let Some(table) = &guide.directions {
            let side = if normal.dot(wo) >= 0.0 {
                normal
            } else {
                -normal
            };
            let offset = p - guide.node_positions[node as usize];
            if let Some(slot) = table.slot(node, directional::class_of(side, offset)) {
                if !self
                    .directions
                    .as_ref()
                    .is_some_and(|t| Arc::ptr_eq(t, table))
                {
                    self.directions = Some(table.clone());
                }
                self.slot = slot;
            }
            return 0;
        }
        let side = if normal.dot(wo) >= 0.0 {
            normal
        } else {
            -normal
        };
        let strength = guide.strength(node);
        let mut total = 0.0f32;
        // A node's lobes often share their bottleneck (every way out of a room leaves through
        // its door) or their importance point, and the answer depends on the target alone (p
        // is fixed; with visibility=voxel the voxel too): one shadow ray per distinct target.
        let mut aims = Aims {
            guide,
            scene,
            p,
            p_error,
            side,
            voxel,
            rays: 0,
            known: 0,
            found: 0,
            at: &mut self.aimed,
        };
        // Per portal slot of the node, the active lobe that samples it (u8::MAX: none yet).
        let mut portal_lobe = [u8::MAX; MAX_LOBES];
        let (lobes, plans) = guide.lobes_and_plans(node);
        for (j, (lobe, plan)) in lobes.iter().zip(plans).enumerate() {
            // lobe_weights=learned: a lobe the training gave 0 is never aimed (no shadow ray).
            if lobe.probability <= 0.0 {
                continue;
            }
            let slot = j;
            let j = j as u32;
            // One shadow ray toward the bottleneck decides whether p aims through it.
            let opening = if plan.through_opening {
                aims.aim(plan.opening_slot, lobe.opening, 2 * j)
            } else {
                None
            };
            // aim=portal: uniform toward the opening's rectangle where p sees the bottleneck
            // (and is not in the rectangle's plane); else the round lobe of aim=opening.
            if let (Some((axis, distance)), Some(portal_slot), Some(portal), LobeAim::Portal) =
                (opening, plan.portal_slot, &lobe.portal, guide.settings.aim)
            {
                // Lobes through the same rectangle are the same density at p (a portal lobe
                // has no strength): one active lobe with their summed probability, one
                // rectangle set-up and one density evaluation per direction instead of several.
                let i = portal_lobe[portal_slot as usize];
                if i != u8::MAX {
                    self.lobes[i as usize].probability += lobe.probability;
                    total += lobe.probability;
                    self.lobe_of[slot] = i;
                    continue;
                }
                let active = &mut self.lobes[self.count];
                if portal.seen_from_into(p, &mut active.rect) {
                    portal_lobe[portal_slot as usize] = self.count as u8;
                    self.lobe_of[slot] = self.count as u8;
                    active.axis = axis;
                    active.exponent = 0.0;
                    active.probability = lobe.probability;
                    active.radius = lobe.opening_radius;
                    active.distance = distance;
                    active.portal = true;
                    total += lobe.probability;
                    self.count += 1;
                    continue;
                }
            }
            // fallback=drop: a lobe whose opening p does not see applies nowhere else at p.
            let fall_back = !plan.through_opening || guide.settings.fallback == LobeFallback::Point;
            let target = match opening {
                Some((axis, distance)) => Some((axis, distance, lobe.opening_radius)),
                None if fall_back => aims
                    .aim(plan.point_slot, lobe.point, 2 * j + 1)
                    .map(|(axis, distance)| (axis, distance, lobe.radius)),
                None => None,
            };
            let Some((axis, distance, radius)) = target else {
                continue;
            };
            // A lobe toward the same target with the same radius is the same density under
            // any strength (the training pass's `pdf_with_strength` too): merged, as above.
            if let Some(i) = self.lobes[..self.count].iter().position(|l| {
                !l.portal && l.axis == axis && l.radius == radius && l.distance == distance
            }) {
                self.lobes[i].probability += lobe.probability;
                total += lobe.probability;
                self.lobe_of[slot] = i as u8;
                continue;
            }
            let active = &mut self.lobes[self.count];
            active.axis = axis;
            active.exponent = strength.exponent(radius, distance);
            active.probability = lobe.probability;
            active.radius = radius;
            active.distance = distance;
            active.portal = false;
            total += lobe.probability;
            self.lobe_of[slot] = self.count as u8;
            self.count += 1;
        }
        let rays = aims.rays;
        if total > 0.0 {
            for l in &mut self.lobes[..self.count] {
                l.probability /= total;
            }
        } else {
            self.count = 0;
        }
        rays
    }

    /// The skeleton node of the last `init` (None outside the grid or in solid voxels, and
    /// where the point cannot map to a node with a guiding probability above 0: there the
    /// mapping is skipped).
    pub fn node(&self) -> Option<u32> {
        self.node
    }

    /// Lobes active at the current point.
    pub fn lobe_count(&self) -> usize {
        self.count
    }

    /// Axis, exponent and probability of active lobe `i`. A portal lobe (`aim=portal`,
    /// [`lobe_is_portal`](Self::lobe_is_portal)) samples a rectangle, not a power-cosine
    /// lobe: its exponent is meaningless (0).
    pub fn lobe(&self, i: usize) -> Option<(Vec3, f32, f32)> {
        (i < self.count).then(|| {
            let l = &self.lobes[i];
            (l.axis, l.exponent, l.probability)
        })
    }

    /// A hint after [`init`](Self::init): requests the cache line that sampling this point's
    /// learned distribution reads first (its row ends), so that the miss overlaps next-event
    /// estimation. No effect on any result.
    #[inline]
    pub fn prefetch_directions(&self) {
        if let Some(table) = self.learned() {
            table.prefetch(self.slot);
        }
    }

    /// The learned distribution that applies at this point (`directions=learned`), if any.
    #[inline]
    fn learned(&self) -> Option<&DirectionalTable> {
        if self.slot == NO_SLOT {
            return None;
        }
        self.directions.as_deref()
    }

    /// Whether active lobe `i` samples the opening's rectangle (`aim=portal`) at this point.
    pub fn lobe_is_portal(&self, i: usize) -> bool {
        i < self.count && self.lobes[i].portal
    }

    /// Lowers the guiding probability here to at most `c` (`ratio_max`): a bound the
    /// integrator derives from the path's prefix, before using any of the query's densities.
    #[inline]
    pub fn cap_guiding_probability(&mut self, c: f32) {
        if self.c_skel > c {
            self.c_skel = c.max(0.0);
        }
    }

    /// Probability of sampling the skeleton rather than the BSDF here: `c_skel` where lobes
    /// apply, else 0.
    pub fn guiding_probability(&self) -> f32 {
        if self.count > 0 || self.slot != NO_SLOT {
            self.c_skel
        } else {
            0.0
        }
    }

    /// Samples the skeleton mixture (eq. 167): `u_select` picks a lobe with its probability,
    /// `u` the direction in it. Returns the unit direction and the mixture's solid-angle pdf
    /// there (all lobes, as [`pdf`](Self::pdf)); `None` when not guided.
    pub fn sample(&self, u_select: f32, u: Vec2) -> Option<(Vec3, f32)> {
        if let Some(table) = self.learned() {
            let w = table.sample(self.slot, u_select, u);
            let pdf = table.pdf(self.slot, w);
            return (pdf > 0.0 && pdf.is_finite()).then_some((w, pdf));
        }
        if self.count == 0 {
            return None;
        }
        let mut acc = 0.0;
        let mut chosen = self.count - 1;
        for (i, l) in self.lobes[..self.count].iter().enumerate() {
            acc += l.probability;
            if u_select < acc {
                chosen = i;
                break;
            }
        }
        let l = &self.lobes[chosen];
        let w = if l.portal {
            l.rect.sample(u)
        } else {
            Frame::from_z(l.axis).to_world(warp::power_cosine(u, l.exponent))
        };
        let pdf = self.pdf(w);
        (pdf > 0.0 && pdf.is_finite()).then_some((w, pdf))
    }

    /// Solid-angle pdf of the skeleton mixture (eq. 167) at unit direction `w`; 0 when not
    /// guided.
    pub fn pdf(&self, w: Vec3) -> f32 {
        if let Some(table) = self.learned() {
            return table.pdf(self.slot, w);
        }
        self.lobes[..self.count]
            .iter()
            .map(|l| l.probability * l.pdf(w, l.exponent))
            .sum()
    }

    /// [`pdf`](Self::pdf) as it would be with every lobe's exponent from `strength` instead
    /// (same lobes, axes and probabilities: which lobes apply at a point does not depend on
    /// the strength). Lobes of [`with_lobes`](Self::with_lobes) have no radius: an automatic
    /// strength gives them its bound. A portal lobe (`aim=portal`) has no strength: its
    /// density is the same under any.
    pub fn pdf_with_strength(&self, w: Vec3, strength: SkeletonStrength) -> f32 {
        self.lobes[..self.count]
            .iter()
            .map(|l| {
                let exponent = strength.exponent(l.radius, l.distance);
                l.probability * l.pdf(w, exponent)
            })
            .sum()
    }

    /// The density at unit direction `w` of each of the node's lobes (`SkeletonGuide::lobes`,
    /// in that order) as it applies at this point, or a negative number for a lobe that does
    /// not apply here; lobes merged into one active lobe get its density. With selection
    /// probabilities `W`, the mixture here is `sum W_j p_j / sum W_j` over the lobes that
    /// apply (the training's candidates, `guide::training`, "Lobe weights").
    pub fn node_lobe_pdfs(&self, w: Vec3) -> [f32; MAX_LOBES] {
        let mut active = [0.0f32; MAX_LOBES];
        for (p, l) in active.iter_mut().zip(&self.lobes[..self.count]) {
            *p = l.pdf(w, l.exponent);
        }
        self.lobe_of.map(|a| {
            if (a as usize) < self.count {
                active[a as usize]
            } else {
                -1.0
            }
        })
    }

    /// Density of the one-sample MIS combination with BSDF sampling (eq. 168-170), the
    /// estimator's denominator: `c p_skel(w) + (1 - c) p_bsdf(w)` with `c` the guiding
    /// probability. The thesis writes the balance-heuristic weights on projected solid angle
    /// (eq. 170 divides both densities by |cos|); the cosine cancels in f cos / (w p), so the
    /// estimator is f cos / this solid-angle mixture density.
    #[inline]
    pub fn mixture_pdf(&self, w: Vec3, bsdf_pdf: f32) -> f32 {
        let c = self.guiding_probability();
        if c > 0.0 {
            mix(c, self.pdf(w), bsdf_pdf)
        } else {
            bsdf_pdf
        }
    }

    /// [`mixture_pdf`](Self::mixture_pdf) at a direction whose skeleton density `guide_pdf`
    /// is known (what [`sample`](Self::sample) returned with it): the same value, without
    /// evaluating the density again.
    #[inline]
    pub fn mixture_pdf_given(&self, guide_pdf: f32, bsdf_pdf: f32) -> f32 {
        let c = self.guiding_probability();
        if c > 0.0 {
            mix(c, guide_pdf, bsdf_pdf)
        } else {
            bsdf_pdf
        }
    }
}

/// The one-sample mixture's density from its parts (eq. 168-170).
#[inline(always)]
fn mix(c: f32, guide_pdf: f32, bsdf_pdf: f32) -> f32 {
    c * guide_pdf + (1.0 - c) * bsdf_pdf
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strength_parses_and_validates() {
        assert_eq!(
            SkeletonStrength::parse("16").unwrap(),
            SkeletonStrength::Fixed(16.0)
        );
        assert_eq!(
            SkeletonStrength::parse("auto").unwrap(),
            SkeletonStrength::Auto {
                max: DEFAULT_AUTO_MAX
            }
        );
        assert_eq!(
            SkeletonStrength::parse("auto:20").unwrap(),
            SkeletonStrength::Auto { max: 20.0 }
        );
        for bad in ["-1", "nan", "inf", "auto:0.5", "auto:x", "x", "1e9"] {
            assert!(SkeletonStrength::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn learned_strength_and_training_options_parse() {
        let mut s = SkeletonGuideSettings::default();
        s.set("strength", "16").unwrap();
        s.set("strength", "learned").unwrap();
        // The strength set before stays the training proposal.
        assert!(s.learned_strength);
        assert_eq!(s.strength, SkeletonStrength::Fixed(16.0));
        s.set("strength", "auto").unwrap();
        assert!(!s.learned_strength);
        s.set("training_depth", "5").unwrap();
        s.set("training_paths", "1024").unwrap();
        assert_eq!(s.training_paths, 1024);
        s.set("training_cost", "vertex").unwrap();
        s.set("training_significance", "0").unwrap();
        s.set("training_min_nonzero", "512").unwrap();
        assert_eq!(
            (
                s.training_depth,
                s.training_cost,
                s.training_significance,
                s.training_min_nonzero
            ),
            (5, TrainingCost::Vertex, 0.0, 512)
        );
        for (key, bad) in [
            ("training_depth", "0"),
            ("training_depth", "65"),
            ("training_paths", "1023"),
            ("training_paths", "16777217"),
            ("training_cost", "pixel"),
            ("training_significance", "-1"),
            ("training_significance", "nan"),
            ("training_min_nonzero", "-1"),
            ("cost_model", "seconds"),
        ] {
            let before = s;
            assert!(s.set(key, bad).is_err(), "{key}={bad}");
            assert_eq!(s, before, "a failed set leaves the settings alone");
        }
        assert!(OPTION_NAMES.contains(&"training_cost"));
        for (text, model) in [
            ("vertices", CostModel::Vertices),
            ("switch", CostModel::Switch),
            ("measured", CostModel::Measured),
            ("paths", CostModel::Paths),
        ] {
            s.set("cost_model", text).unwrap();
            assert_eq!(s.cost_model, model);
        }
        assert_eq!(
            SkeletonGuideSettings::default().cost_model,
            CostModel::Paths
        );
        assert!(OPTION_NAMES.contains(&"cost_model"));
    }

    #[test]
    fn aims_parse_and_print() {
        for aim in [LobeAim::ImportancePoint, LobeAim::Opening, LobeAim::Portal] {
            assert_eq!(LobeAim::parse(&aim.to_string()).unwrap(), aim);
        }
        let mut s = SkeletonGuideSettings::default();
        s.set("aim", "portal").unwrap();
        assert_eq!(s.aim, LobeAim::Portal);
        assert!(s.set("aim", "rectangle").is_err());
        s.set("visibility", "voxel").unwrap();
        assert!(s.visibility_test && s.voxel_visibility);
        s.set("visibility", "false").unwrap();
        assert!(!s.visibility_test && !s.voxel_visibility);
        s.set("visibility", "true").unwrap();
        assert!(s.visibility_test && !s.voxel_visibility);
        assert_eq!(s.fallback, LobeFallback::Point);
        s.set("fallback", "drop").unwrap();
        assert_eq!(s.fallback, LobeFallback::Drop);
        assert!(s.set("fallback", "centre").is_err());
        s.set("fallback", "point").unwrap();
        assert_eq!(s.fallback, LobeFallback::Point);
        // fallback=drop means nothing without an opening to aim at.
        s.set("aim", "point").unwrap();
        assert!(s.set("fallback", "drop").is_err());
        assert_eq!(s.fallback, LobeFallback::Point);
        s.set("aim", "opening").unwrap();
        s.set("fallback", "drop").unwrap();
        assert!(s.set("aim", "point").is_err());
    }

    #[test]
    fn automatic_strength_narrows_with_distance() {
        let auto = SkeletonStrength::Auto { max: 1000.0 };
        // Half maximum at the angle subtended by the radius: cos^s(atan(r / D)) = 1/2.
        for (r, d) in [(1.0f32, 3.0f32), (1.0, 10.0), (2.0, 50.0)] {
            let s = auto.exponent(r, d);
            let cos = d / (d * d + r * r).sqrt();
            assert!((cos.powf(s) - 0.5).abs() < 1e-3, "r {r} d {d}: s {s}");
        }
        assert!(auto.exponent(1.0, 10.0) > auto.exponent(1.0, 3.0));
        // Clamped to [1, max], also at D = 0.
        assert_eq!(auto.exponent(1.0, 0.0), 1.0);
        assert_eq!(auto.exponent(1.0, 1e6), 1000.0);
        assert_eq!(SkeletonStrength::Fixed(7.0).exponent(1.0, 2.0), 7.0);
    }

    #[test]
    fn dijkstra_finds_shortest_paths_and_unreachable_nodes() {
        // 0 - 1 - 2 and 0 - 3 - 2 with the second route shorter; node 4 is isolated.
        let adj = vec![
            vec![(1, 1.0), (3, 0.5)],
            vec![(0, 1.0), (2, 1.0)],
            vec![(1, 1.0), (3, 0.6)],
            vec![(0, 0.5), (2, 0.6)],
            vec![],
        ];
        let sp = dijkstra(&adj, 2);
        assert_eq!(sp.distance[2], 0.0);
        assert!((sp.distance[0] - 1.1).abs() < 1e-6);
        assert_eq!(sp.next[0], 3);
        assert_eq!(sp.next[3], 2);
        assert_eq!(sp.next[2], u32::MAX);
        assert!(sp.distance[4].is_infinite() && sp.next[4] == u32::MAX);
    }

    #[test]
    fn query_with_lobes_validates_and_samples_its_pdf() {
        assert!(GuideQuery::with_lobes(1.0, &[(Vec3::Z, 2.0, 1.0)]).is_err());
        assert!(GuideQuery::with_lobes(0.5, &[(Vec3::ZERO, 2.0, 1.0)]).is_err());
        assert!(GuideQuery::with_lobes(0.5, &[(Vec3::Z, -2.0, 1.0)]).is_err());
        assert!(GuideQuery::with_lobes(0.5, &[(Vec3::Z, 2.0, 0.0)]).is_err());
        assert!(GuideQuery::with_lobes(0.5, &[(Vec3::Z, 2.0, 1.0); 9]).is_err());
        let empty = GuideQuery::new();
        assert_eq!(empty.guiding_probability(), 0.0);
        assert!(empty.sample(0.5, Vec2::splat(0.5)).is_none());
        assert_eq!(empty.mixture_pdf(Vec3::Z, 0.3), 0.3);
        let q = GuideQuery::with_lobes(
            0.25,
            &[(Vec3::Z, 10.0, 3.0), (Vec3::new(1.0, 0.0, 1.0), 1.0, 1.0)],
        )
        .unwrap();
        assert_eq!(q.lobe_count(), 2);
        assert!((q.lobe(0).unwrap().2 - 0.75).abs() < 1e-6);
        let mut rng = Rng::new(1, 2);
        for _ in 0..1000 {
            let (w, pdf) = q.sample(rng.uniform(), rng.uniform2()).unwrap();
            assert!((w.length() - 1.0).abs() < 1e-4);
            assert!((pdf - q.pdf(w)).abs() <= 1e-5 * pdf);
            let m = q.mixture_pdf(w, 0.1);
            assert!((m - (0.25 * pdf + 0.75 * 0.1)).abs() < 1e-5 * m);
        }
    }

    /// A portal's rectangle seen from a point is, bit for bit, the spherical rectangle of the
    /// corner and sides its centre and half sizes give (so `Portal::new` keeps the frame of
    /// its own rectangle), degenerate ones and points in the plane included.
    #[test]
    fn portals_see_points_as_rectangles_set_up_there() {
        let mut rng = Rng::new(11, 4);
        let (mut seen, mut unseen) = (0, 0);
        let mut slot: Option<warp::SphericalRectangle> = None;
        for i in 0..2000 {
            let u = warp::uniform_sphere(rng.uniform2());
            let v = Frame::from_z(u).s;
            let centre = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 8.0 - 4.0;
            let mut half = Vec2::new(rng.uniform(), rng.uniform()) * 2.0;
            if i % 50 == 0 {
                half.x = 0.0;
            }
            let portal = Portal::new(centre, u, v, half);
            for _ in 0..4 {
                let mut p = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 8.0 - 4.0;
                if rng.uniform() < 0.2 {
                    // In the rectangle's plane.
                    p = centre + (rng.uniform() - 0.5) * u + (rng.uniform() - 0.5) * v;
                }
                let corner = centre - half.x * u - half.y * v;
                let size = 2.0 * half;
                let fresh = warp::SphericalRectangle::new(p, corner, u, v, size.x, size.y);
                let kept = portal.seen_from(p);
                assert_eq!(
                    format!("{kept:?}"),
                    format!("{fresh:?}"),
                    "portal {i} from {p}"
                );
                // Set up in place, in a slot that held the last point's rectangle (its angles
                // computed): the same rectangle, nothing of the last one kept.
                if let Some(old) = &slot {
                    old.solid_angle();
                }
                let mut reused = slot.take().unwrap_or_else(warp::SphericalRectangle::empty);
                let set_up = portal.seen_from_into(p, &mut reused);
                assert_eq!(set_up, kept.is_some(), "portal {i} from {p}");
                if set_up {
                    assert_eq!(
                        format!("{:?}", Some(&reused)),
                        format!("{:?}", kept.as_ref())
                    );
                    slot = Some(reused);
                }
                match (kept, fresh) {
                    (Some(a), Some(b)) => {
                        seen += 1;
                        let u = rng.uniform2();
                        let w = a.sample(u);
                        assert_eq!(w.to_array(), b.sample(u).to_array());
                        assert_eq!(a.pdf(w).to_bits(), b.pdf(w).to_bits());
                    }
                    _ => unseen += 1,
                }
            }
        }
        assert!(seen > 5000 && unseen > 400, "{seen} seen, {unseen} not");
    }

    /// The query's mapping (one grid conversion for the `may_guide` test and the node
    /// mapping) finds the voxel and node of `may_guide_at` followed by `map_point_voxel`,
    /// and none where `may_guide_at` rules the point out.
    #[test]
    fn lobe_plans_group_equal_targets_and_portals() {
        // Lobes drawn from small pools, so that targets and portals repeat within a node
        // (openings equal to points of other lobes, signed zeros, NaN: equal as the query's
        // `==` has them, never for NaN).
        let mut rng = Rng::new(12, 2);
        let targets = [
            Vec3::new(1.0, 2.0, 3.0),
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(-0.0, 0.0, 1.0),
            Vec3::new(f32::NAN, 0.0, 0.0),
            Vec3::new(4.0, -1.0, 0.5),
        ];
        let portals = [
            None,
            Some(Portal::new(
                Vec3::ZERO,
                Vec3::X,
                Vec3::Y,
                Vec2::new(1.0, 2.0),
            )),
            Some(Portal::new(
                Vec3::ONE,
                Vec3::Y,
                Vec3::Z,
                Vec2::new(0.5, 0.5),
            )),
            Some(Portal::new(
                Vec3::ONE,
                Vec3::Y,
                Vec3::Z,
                Vec2::new(f32::NAN, 0.5),
            )),
        ];
        let mut shared = [0usize; 2];
        for _ in 0..3000 {
            let n = 1 + (rng.uniform() * MAX_LOBES as f32) as usize;
            let pick = |rng: &mut Rng| targets[(rng.uniform() * 5.0) as usize % 5];
            let lobes: Vec<GuideLobe> = (0..n.min(MAX_LOBES))
                .map(|i| GuideLobe {
                    point: pick(&mut rng),
                    radius: if rng.uniform() < 0.5 { 1.0 } else { 2.0 },
                    probability: 0.1,
                    importance: i as u32,
                    distance: 1.0,
                    opening: pick(&mut rng),
                    opening_radius: 1.0,
                    portal: portals[(rng.uniform() * 4.0) as usize % 4],
                })
                .collect();
            for aim in [LobeAim::ImportancePoint, LobeAim::Opening, LobeAim::Portal] {
                let plans = plan_lobes(&lobes, aim);
                assert_eq!(plans.len(), lobes.len());
                // Every target occurrence with its slot, by brute force over all pairs.
                let occurrences: Vec<(Vec3, u8)> = lobes
                    .iter()
                    .zip(&plans)
                    .flat_map(|(l, p)| [(l.opening, p.opening_slot), (l.point, p.point_slot)])
                    .collect();
                for (a, &(ta, sa)) in occurrences.iter().enumerate() {
                    assert!((sa as usize) < 2 * MAX_LOBES);
                    for &(tb, sb) in &occurrences[a + 1..] {
                        assert_eq!(sa == sb, ta == tb, "{ta} {tb}: slots {sa} {sb}");
                        shared[0] += usize::from(sa == sb);
                    }
                }
                for (j, (l, p)) in lobes.iter().zip(&plans).enumerate() {
                    let wanted_opening = l.has_opening() && aim != LobeAim::ImportancePoint;
                    assert_eq!(p.through_opening, wanted_opening);
                    assert_eq!(p.portal_slot.is_some(), l.portal.is_some());
                    let Some(slot) = p.portal_slot else { continue };
                    // The first lobe with an equal portal (itself when none, or NaN).
                    let first = (0..j)
                        .find(|&k| lobes[k].portal.is_some() && lobes[k].portal == l.portal)
                        .unwrap_or(j);
                    assert_eq!(slot as usize, first, "lobe {j}");
                    shared[1] += usize::from(first < j);
                }
            }
        }
        // Both kinds of sharing happened.
        assert!(shared[0] > 1000 && shared[1] > 1000, "{shared:?}");
    }

    #[test]
    fn guided_points_map_as_may_guide_and_the_node_mapping() {
        let scene = crate::scene::two_rooms_builder().unwrap().build().unwrap();
        let mut settings = SkeletonGuideSettings::default();
        settings.set("c_skel", "learned").unwrap();
        settings.set("training_paths", "8192").unwrap();
        // The mapping of the nodes the training guides, whatever the scene-level switch says.
        settings.set("cost_model", "vertices").unwrap();
        let guide = SkeletonGuide::build(&scene, scene.camera(), &settings, &|_, _| true).unwrap();
        assert!(!guide.may_guide.is_empty());
        let mut rng = Rng::new(5, 1);
        let bounds = scene.bounds();
        let (mut mapped, mut ruled_out) = (0, 0);
        while mapped + ruled_out < 4000 {
            let u = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform());
            let o = bounds.min + (bounds.max - bounds.min) * u;
            let d = warp::uniform_sphere(rng.uniform2());
            let Some(si) = scene.intersect(&Ray::new(o, d, f32::INFINITY)) else {
                continue;
            };
            let got = guide.map_guided_point(si.p, si.ng, si.wo);
            if guide.may_guide_at(si.p) {
                mapped += 1;
                assert_eq!(
                    got,
                    guide.map_point_voxel(si.p, si.ng, si.wo),
                    "at {}",
                    si.p
                );
            } else {
                ruled_out += 1;
                assert_eq!(got, None, "at {}", si.p);
            }
        }
        assert!(
            mapped > 200 && ruled_out > 200,
            "{mapped} mapped, {ruled_out} not"
        );
    }
}
