//! The skeleton guide's options ([`SkeletonGuideSettings`]) and their `key=value` parsing:
//! what the precomputation builds, how the render weighs the guide, what the training tries.
//! One place, so the CLI, the C API and scene files all accept and refuse the same values.

use super::directional;
use super::lobes::MAX_LOBES;
use super::training::{self};
use crate::analysis::Resolution;
use crate::error::{Error, Result};
use crate::light::{EnvStrategy, TriangleSampling};
use crate::math::{MisHeuristic, SamplerKind};

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
    /// `pilot_paths=N` (default [`DEFAULT_PILOT_PATHS`], 0: none): camera samples of the
    /// pilot that checks the scene-level switch's prediction with the render's own estimator
    /// (`integrator::path`, "The pilot"), each traced twice guided and twice unguided.
    pub pilot_paths: u32,
    /// `pilot_cost=time` (the default) or `work`: what the pilot takes as the guided
    /// sample's cost against the unguided one's (`integrator::path`, "The pilot").
    pub pilot_cost: PilotCost,
    /// `pilot_sampler=sobol` (the default) or `independent`: the pilot's numbers
    /// (`integrator::path`, "The pilot"): pixels of 16 samples under two scrambles of the
    /// render's Sobol points, or pairs of independent samples along one ray.
    pub pilot_sampler: SamplerKind,
    /// `pilot_sigmas=X` (default [`crate::guide::PILOT_SIGMAS`], 2): standard errors by which
    /// the pilot's variance ratio is raised before its verdict (0: the point estimate).
    pub pilot_sigmas: f64,
    /// `scout_pilot=on` (the default) or `off`: where the scout's choices guide some node,
    /// `path_skeleton` runs its pilot on the scout's guide too, and skips the full training
    /// unless that guide shows a gain at one standard error (`guide::training`, "The scout").
    pub scout_pilot: bool,
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
    /// host gave a budget (`lacuna compare`; `Integrator::set_time_budget`): the whole
    /// precomputation must then fit in [`BUDGET_SHARE`] of it (module `guide::budget`), or
    /// nothing is guided. Not an option key.
    pub time_budget: Option<f64>,
}

/// The largest share of a time budget the whole precomputation may take, analysis to pilots
/// (module `guide::budget`): a guide that gains E in efficiency then still ends at E (1 -
/// share) of `path`. The door (E about 1.5) needs 5-7 s on one thread of a loaded machine,
/// up to a quarter of 30 s, and must stay guided there (BENCHMARKS.md, issue 27, "The
/// precomputation against a short budget").
pub const BUDGET_SHARE: f64 = 0.3;

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
/// Camera samples of the pilot (`pilot_paths`): 4 x 32768 render samples, a few tenths of a
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
            pilot_sampler: SamplerKind::Sobol,
            pilot_sigmas: super::PILOT_SIGMAS,
            scout_pilot: true,
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
    "pilot_sampler",
    "pilot_sigmas",
    "scout_pilot",
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
            "pilot_sampler" => next.pilot_sampler = SamplerKind::parse(value.trim())?,
            "pilot_sigmas" => next.pilot_sigmas = number(key, value)?,
            "scout_pilot" => {
                next.scout_pilot = match value.trim() {
                    "on" => true,
                    "off" => false,
                    other => {
                        return Err(Error::invalid(format!(
                            "skeleton scout_pilot '{other}' must be 'on' or 'off'"
                        )))
                    }
                }
            }
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
        if !(self.pilot_sigmas.is_finite() && (0.0..=10.0).contains(&self.pilot_sigmas)) {
            return Err(Error::invalid(format!(
                "skeleton pilot_sigmas {} must be a number in [0, 10]",
                self.pilot_sigmas
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
            ("scout_pilot", "yes"),
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
        assert!(SkeletonGuideSettings::default().scout_pilot);
        s.set("scout_pilot", "off").unwrap();
        assert!(!s.scout_pilot);
        s.set("scout_pilot", "on").unwrap();
        assert!(s.scout_pilot);
        assert!(OPTION_NAMES.contains(&"scout_pilot"));
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
}
