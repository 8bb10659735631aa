//! [`SkeletonGuide`]: skeleton-guided ray sampling (000 §9.2-9.5, 004), and the build that
//! ties its parts together: its options are in `settings`, the light tracing, shortest paths
//! and openings in `importance`, the lobes in `lobes`, the per-point mixture in `query`.
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
//! 5. With `aim=opening` or `aim=portal`, each path's opening (module `importance`).
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

use std::sync::atomic::{AtomicU32, Ordering as AtomicOrdering};
use std::sync::Arc;
use std::time::Instant;

use rayon::prelude::*;

use super::directional::{self, DirectionalTable};
use super::importance::{
    dijkstra, node_lobes, trace_light_power, visible, weighted_adjacency, OpeningFits,
    ShortestPaths,
};
use super::lobes::{plan_lobes, GuideLobe, ImportanceNode, LobePlan, MAX_LOBES};
use super::settings::{SkeletonGuideSettings, SkeletonStrength, AUTO_RATIO_MAX};
use super::training::{self, TrainingReport};
use crate::analysis::{may_map_to, NeighbourMasks, Skeleton, StageTime, VoxelGrid, VoxelSet};
use crate::error::{Error, Result};
use crate::math::Vec3;
use crate::scene::{Camera, Scene};

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

/// The progress stage [`SkeletonGuide::build`] reports before any work (a host may act on
/// it: `path_skeleton`'s time budget checks the whole precomputation there).
pub const START_STAGE: &str = "start";

/// Skeleton guiding data of one scene. Immutable after `build`; queries are thread-safe.
pub struct SkeletonGuide {
    pub(super) settings: SkeletonGuideSettings,
    grid: VoxelGrid,
    node_map: Vec<u32>,
    /// `grid.dims` in f64, for the query's test whether a point lies inside the grid.
    grid_extent: [f64; 3],
    /// Which neighbours of each voxel are mapped, for the query's node mapping.
    neighbours: NeighbourMasks,
    /// With `visibility=voxel`: per voxel, the lobe targets its centre sees
    /// ([`SkeletonGuide::voxel_sees`]); empty otherwise.
    voxel_sees: Vec<AtomicU32>,
    pub(super) node_positions: Vec<Vec3>,
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
    pub(super) directions: Option<Arc<DirectionalTable>>,
    /// Per voxel: a point in it may map to a node with a guiding probability above 0 (see
    /// `analysis::may_map_to`); queries elsewhere skip the mapping. Empty: everywhere. One bit
    /// per voxel (a 1 M voxel grid: 128 KB, where one byte per voxel missed the caches at
    /// most vertices).
    may_guide: VoxelSet,
    /// No node has a guiding probability above 0 (every node learned c = 0, or the
    /// scene-level switch of `cost_model=switch|measured`): `path_skeleton` then traces
    /// exactly `path`'s samples.
    guides_nothing: bool,
    /// The scout stopped the training because the rest of the precomputation would not fit
    /// in the time budget's share (module `budget`).
    over_budget: bool,
    importance: Vec<ImportanceNode>,
    /// Nodes with a non-zero power estimate before the `max_importance_nodes` cut.
    importance_found: usize,
    raw_nodes: usize,
    edges: usize,
    timings: Vec<StageTime>,
    fingerprint: SceneFingerprint,
}

/// A look at a guide trained on the scout's paths alone
/// ([`SkeletonGuide::build_with_scout_check`]): false stops the training and guides nothing.
pub type ScoutCheck<'a> = &'a dyn Fn(&SkeletonGuide) -> bool;

/// The two bits of lobe target `target` in a voxel's visibility cell
/// ([`SkeletonGuide::voxel_sees`]): (answer known, target seen).
#[inline]
fn voxel_sees_bits(target: u32) -> (u32, u32) {
    (1u32 << (2 * target), 1u32 << (2 * target + 1))
}

/// A surface point's place in the guide's grid ([`SkeletonGuide::locate`]).
#[derive(Clone, Copy, Debug)]
pub struct GridPoint {
    /// The world point located.
    p: Vec3,
    /// Continuous grid coordinates (`VoxelGrid::to_grid`).
    g: [f64; 3],
    /// The voxel, `floor(g)`; may lie outside the grid.
    v: [i64; 3],
    /// The voxel's index where it lies inside the grid, else [`GridPoint::OUTSIDE`].
    k: usize,
}

impl GridPoint {
    const OUTSIDE: usize = usize::MAX;

    /// The world point located.
    #[inline]
    pub fn point(&self) -> Vec3 {
        self.p
    }
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
        Self::build_with_scout_check(scene, camera, settings, progress, None)
    }

    /// [`SkeletonGuide::build`], with a look at the guide trained on the scout's paths alone
    /// where the scout's choices guide some node (`guide::training`, "The scout"): if
    /// `scout_check` returns false, the training stops there and nothing is guided, so a
    /// scene where that guide shows no gain does not pay for the full training.
    /// `path_skeleton` runs its pilot there. The full training goes on from the scout's state
    /// exactly (the check's changes to the guide, its visibility cache included, are undone),
    /// so a scene that goes on learns what it would have learned without the check.
    pub fn build_with_scout_check(
        scene: &Scene,
        camera: Option<&Camera>,
        settings: &SkeletonGuideSettings,
        progress: &dyn Fn(&str, f64) -> bool,
        scout_check: Option<ScoutCheck<'_>>,
    ) -> Result<SkeletonGuide> {
        settings.validate()?;
        let started = Instant::now();
        if !progress(START_STAGE, 0.0) {
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

        let mut fraction = 0.0;
        let skeleton = Skeleton::of_scene(scene, settings.resolution, &mut |name, t| {
            fraction += 0.35;
            stage(name, t, fraction)
        })?;
        let Skeleton {
            grid,
            raw,
            filtered,
            node_map,
            ..
        } = skeleton;
        let graph = filtered.graph;

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
            over_budget: false,
            importance,
            importance_found,
            raw_nodes: raw.nodes.len(),
            edges: graph.edges.len(),
            timings: Vec::new(),
            fingerprint: SceneFingerprint::of(scene),
        };
        let mut scout_check_seconds = None;
        if settings.trains() {
            let mut t = Instant::now();
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
            let mut scout_paths = training::ScoutPaths::default();
            let scout = if settings.scouts() && camera.is_some() {
                let full = guide.settings.training_paths;
                guide.settings.training_paths = (full / training::SCOUT_FRACTION).max(1);
                let scout_started = Instant::now();
                let mut report = training::learn_guiding_probabilities(
                    &guide,
                    scene,
                    camera,
                    0,
                    &mut history,
                    training::Scout::Keep(&mut scout_paths),
                );
                guide.settings.training_paths = full;
                // With a time budget (module `budget`): the rest of the training and the
                // pilots, at the scout's pace (a pilot path costs about a training path), must
                // fit in BUDGET_SHARE of it with what the precomputation has spent already.
                let scout_seconds = scout_started.elapsed().as_secs_f64();
                let pilots = if settings.pilot_paths > 0 && settings.cost_model.switches() {
                    1 + scout_check.is_some() as u32
                } else {
                    0
                };
                let pilot_paths = pilots as f64 * settings.pilot_paths as f64;
                let rest = scout_seconds * (training::SCOUT_FRACTION - 1) as f64
                    + scout_seconds * pilot_paths / guide.settings.training_paths.max(1) as f64
                        * training::SCOUT_FRACTION as f64;
                let over_budget = settings.time_budget.is_some_and(|b| {
                    !super::budget::fits(b, started.elapsed().as_secs_f64(), rest)
                });
                if over_budget && report.paths > 0 {
                    report.turn_off(settings);
                    guide.over_budget = true;
                }
                let guides_some_node = report.probabilities.iter().any(|&c| c > 0.0);
                if let Some(check) = scout_check.filter(|_| report.paths > 0 && guides_some_node) {
                    let check_started = Instant::now();
                    if !guide.scout_verdict(&report, check) {
                        report.turn_off(settings);
                    }
                    let seconds = check_started.elapsed();
                    // The check is its own stage, not the training's.
                    t += seconds;
                    scout_check_seconds = Some(seconds.as_secs_f64());
                }
                Some(report).filter(|r| r.paths > 0 && r.probabilities.iter().all(|&c| c <= 0.0))
            } else {
                None
            };
            let mut report = match scout {
                Some(report) => report,
                None => training::learn_guiding_probabilities(
                    &guide,
                    scene,
                    camera,
                    0,
                    &mut history,
                    training::Scout::Reuse(&mut scout_paths),
                ),
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
                    training::Scout::None,
                );
            }
            guide.adopt_training(report);
            stage("guiding probabilities (training)", t, 1.0)?;
        }
        if let Some(seconds) = scout_check_seconds {
            timings.push(StageTime {
                stage: "pilot on the scout's guide",
                seconds,
            });
        }
        guide.guides_nothing = guide.node_c.iter().all(|&c| c <= 0.0);
        guide.timings = timings;
        Ok(guide)
    }

    /// Whether the scout stopped the training to keep the precomputation within the time
    /// budget's share (`settings.time_budget`, module `budget`): nothing is guided.
    pub fn stopped_over_budget(&self) -> bool {
        self.over_budget
    }

    /// The scout check of [`SkeletonGuide::build_with_scout_check`]: `check` on this guide with
    /// the scout's choices adopted, then the guide put back in the scout's state (its choices,
    /// lobe weights and learned directions, and the visibility cache, whose fills the full
    /// training counts as the guide's shadow rays).
    fn scout_verdict(&mut self, scout: &TrainingReport, check: ScoutCheck<'_>) -> bool {
        let node_c = self.node_c.clone();
        let node_strength = self.node_strength.clone();
        let lobe_probabilities: Vec<f32> = self.lobes.iter().map(|l| l.probability).collect();
        let directions = self.directions.clone();
        let may_guide = std::mem::replace(&mut self.may_guide, VoxelSet::new(0));
        let training = self.training.take();
        let guides_nothing = self.guides_nothing;
        let cache: Vec<u32> = self
            .voxel_sees
            .iter()
            .map(|cell| cell.load(AtomicOrdering::Relaxed))
            .collect();

        self.adopt_training(scout.clone());
        let go_on = check(self);

        self.node_c = node_c;
        self.node_strength = node_strength;
        for (lobe, p) in self.lobes.iter_mut().zip(lobe_probabilities) {
            lobe.probability = p;
        }
        self.directions = directions;
        self.may_guide = may_guide;
        self.training = training;
        self.guides_nothing = guides_nothing;
        for (cell, bits) in self.voxel_sees.iter().zip(cache) {
            cell.store(bits, AtomicOrdering::Relaxed);
        }
        go_on
    }

    /// Puts a training report's choices into the guide (per node c, strengths, lobe weights,
    /// learned directions, the voxels that may guide) and keeps the report. Without paths
    /// (no camera) every node gets the fixed `c_skel`.
    fn adopt_training(&mut self, mut report: TrainingReport) {
        self.directions = None;
        if report.paths == 0 {
            // No camera to train from: the documented fixed default.
            self.node_c = vec![self.settings.c_skel; self.node_count()];
        } else {
            self.node_c = report.probabilities.clone();
            if self.settings.learned_strength {
                self.node_strength = report.strengths.clone();
            }
            // Learned selection probabilities replace eq. 165's in place: the lobes keep
            // their indices (the voxel visibility cache the training filled is keyed by
            // them), and a lobe given 0 is skipped by every query.
            for (k, weights) in report.lobe_weights.iter().enumerate() {
                if let Some(weights) = weights {
                    let start = self.lobe_start[k] as usize;
                    let end = self.lobe_start[k + 1] as usize;
                    for (lobe, &w) in self.lobes[start..end].iter_mut().zip(weights) {
                        lobe.probability = w;
                    }
                }
            }
        }
        // Without a camera nothing was learned: the lobes at the fixed c, as documented.
        if self.settings.learned_directions && report.paths > 0 {
            // Only nodes that are guided keep their distribution.
            let kept: Vec<Option<Vec<f32>>> = report
                .directions
                .iter()
                .zip(&self.node_c)
                .map(|(d, &c)| d.clone().filter(|_| c > 0.0))
                .collect();
            self.directions = Some(Arc::new(DirectionalTable::new(&kept)));
        }
        // The training's mask where it was found for these very probabilities.
        let trained_mask = report
            .may_guide
            .take()
            .filter(|_| report.probabilities == self.node_c);
        self.training = Some(report);
        if self.settings.learned_c_skel {
            let node_c = &self.node_c;
            self.may_guide = trained_mask.unwrap_or_else(|| {
                VoxelSet::from_flags(&may_map_to(&self.grid, &self.node_map, |n| {
                    node_c[n as usize] > 0.0
                }))
            });
        }
        self.guides_nothing = self.node_c.iter().all(|&c| c <= 0.0);
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
    pub(super) fn lobes_and_plans(&self, node: u32) -> (&[GuideLobe], &[LobePlan]) {
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

    /// Where surface point `p` lies in the grid: its grid coordinates and voxel, worked out
    /// once per vertex for both [`Self::prefetch_at`] (ahead of the BSDF) and the query's
    /// mapping ([`GuideQuery::init_at`]).
    #[inline]
    pub fn locate(&self, p: Vec3) -> GridPoint {
        let g = self.grid.to_grid(p);
        let d = &self.grid_extent;
        if g[0] >= 0.0 && g[0] < d[0] && g[1] >= 0.0 && g[1] < d[1] && g[2] >= 0.0 && g[2] < d[2] {
            // Inside the grid (false for NaN) the floor is the truncation (no correction below
            // zero), and the voxel needs no bounds test.
            // SAFETY: each g[a] is finite and in [0, dims[a]) (just tested; the dimensions are
            // far below 2^63), so it truncates to an i64 without saturation: one instruction
            // per axis instead of `as i64`'s saturation and NaN tests.
            let v = unsafe {
                [
                    g[0].to_int_unchecked::<i64>(),
                    g[1].to_int_unchecked::<i64>(),
                    g[2].to_int_unchecked::<i64>(),
                ]
            };
            let k = self.grid.index(v[0] as usize, v[1] as usize, v[2] as usize);
            GridPoint { p, g, v, k }
        } else {
            let v = crate::analysis::grid::floor3_to_i64(g);
            GridPoint {
                p,
                g,
                v,
                k: GridPoint::OUTSIDE,
            }
        }
    }

    /// [`Self::map_point_voxel`] where [`Self::may_guide_at`] allows it, else None: what
    /// [`GuideQuery::init`] maps a point to.
    #[cfg(test)]
    fn map_guided_point(&self, p: Vec3, normal: Vec3, incident: Vec3) -> Option<(u32, usize)> {
        self.map_located(&self.locate(p), normal, incident)
    }

    /// [`Self::map_guided_point`] of a point `at` [`Self::locate`] found.
    #[inline]
    pub(super) fn map_located(
        &self,
        at: &GridPoint,
        normal: Vec3,
        incident: Vec3,
    ) -> Option<(u32, usize)> {
        let k = if at.k != GridPoint::OUTSIDE {
            if !self.may_guide.is_empty() && !self.may_guide.get(at.k) {
                return None;
            }
            self.neighbours.map_inside_grid_point_voxel(
                &self.grid,
                &self.node_map,
                at.g,
                at.v,
                at.k,
                normal,
                incident,
            )
        } else {
            if !self.may_guide_in(at.v) {
                return None;
            }
            self.neighbours.map_grid_point_voxel(
                &self.grid,
                &self.node_map,
                at.g,
                at.v,
                normal,
                incident,
            )
        }?;
        Some((self.node_map[k], k))
    }

    /// A hint ahead of [`GuideQuery::init_at`] at point `at` with geometric normal `normal`
    /// seen from `incident`: requests the cache lines the mapping most likely reads (the
    /// voxel's `may_guide` word, and the node map at the neighbour that the normal's dominant
    /// axis faces: the facing shortcut's voxel on walls, floors and ceilings), so that their
    /// misses overlap the work between the ray's hit and the query (the BSDF's texture
    /// lookups) instead of stalling it: they are the guided vertex's largest stalls in a
    /// wall-time profile. No effect on any result.
    #[inline]
    pub fn prefetch_at(&self, at: &GridPoint, normal: Vec3, incident: Vec3) {
        let k = at.k;
        if k == GridPoint::OUTSIDE {
            return;
        }
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

    /// Replaces the guided nodes' probabilities (`path_skeleton:mis=auto`'s re-estimate,
    /// `integrator::mis_auto::refine_mixture`): a node keeps c = 0 where it had it and stays
    /// guided where it was, so which voxels may guide does not change.
    pub fn set_guiding_probabilities(&mut self, c: &[f32]) {
        for (old, &new) in self.node_c.iter_mut().zip(c) {
            if *old > 0.0 && new > 0.0 {
                *old = new;
            }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Ray;
    use crate::math::{warp, Rng};

    /// The query's mapping (one grid conversion for the `may_guide` test and the node
    /// mapping) finds the voxel and node of `may_guide_at` followed by `map_point_voxel`,
    /// and none where `may_guide_at` rules the point out.
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
