//! SkelBPT (002, whole paper; 000 chapter 11): bidirectional path tracing whose camera
//! vertices resample the light vertex they connect to, one per light subpath length, from
//! distributions cached at the nodes of the filtered skeleton of the empty space.
//!
//! Each iteration (002 §4.1): `bdpt` traces the light subpaths (one per pixel by default) and
//! splats light tracing (t = 1, not resampled); [`SkeletonResampler`] then builds, for every
//! node in use, one distribution per light subpath length over the vertices of the first N
//! subpaths (`guide::resampling`: p_V from shadow rays between the node and each vertex, p_U,
//! p_C, max heuristic premultiplied). Each camera vertex z_{t-1}, t >= 2, maps to its node
//! through the node map and, for each light subpath length, picks one light vertex of that
//! length (connected with probability n / N, n of the N subpaths having one, and the factor
//! 1 / (n q): `resampled::Tables::resample`). In the MIS weights a resampled connection
//! strategy counts one sample by default, the paths it samples (002 line 196), as `bdpt`'s;
//! `count=subset` credits it with N, the estimator connecting every camera vertex to all N
//! subpaths (002 eq. 3), which weights next-event estimation's paths over to single
//! resampled connections (much noisier: BENCHMARKS.md, issue 31). Light tracing counts one
//! sample per light subpath.
//!
//! Node acceptance (002 §4.4): camera vertices are counted per node over the iterations of a
//! render; an iteration builds distributions only at nodes mapped to more than alpha_accept
//! times the mean, and vertices mapped elsewhere resample uniformly (the first iteration has
//! no counts yet, so it resamples uniformly everywhere). Everything a distribution depends on
//! is fixed before the iteration's camera paths, so the estimate stays unbiased.
//!
//! Graceful degradation: without a usable skeleton (the analysis fails, finds no node, or the
//! scene is open: every node sees the outside in a quarter of its directions or more), or
//! when no node sees any vertex of a pilot set of light subpaths, the integrator renders
//! exactly `bdpt`'s image (same samples, same numbers) and its precomputation notes say why.
//! What can be decided without the skeleton is decided before its analysis: a pilot that
//! reaches no surface, or a scene open at every probe point along the camera's rays and the
//! pilot's subpaths.

use std::any::Any;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use rayon::prelude::*;

use super::bdpt::{
    connect_whole_subpaths, CameraVertex, Connection, ConnectionPolicy, LightPaths, UniformPerPixel,
};
use super::node_skeleton::{Fingerprint, NodeSkeleton};
use super::resampled::{
    build_tables, distribution_layers, Anchor, OcclusionTally, Tables, NO_TABLE,
};
use super::{
    Bdpt, Integrator, IntegratorSettings, Iteration, Precomputation, SampleContext, TraceCounters,
    View,
};
use crate::analysis::StageTime;
use crate::error::{Error, Result};
use crate::film::PixelSample;
use crate::geometry::Ray;
use crate::guide::ResamplingSettings;
use crate::math::{Sampler, Vec2, Vec3};
use crate::scene::{Camera, Scene};

/// Light subpaths of the pilot that decides whether any node sees light vertices.
const PILOT_LIGHT_PATHS: usize = 256;
/// Seed of the pilot's light subpaths (the decision is a deterministic function of the scene).
const PILOT_SEED: u64 = 0x5ce1_b9d7;
/// Directions each node casts to tell an enclosed node from an open one.
const OPENNESS_RAYS: usize = 64;
/// A node is enclosed when fewer than this fraction of its rays leave the scene.
const ENCLOSED_ESCAPE_FRACTION: f32 = 0.25;
/// Camera rays per axis, and pilot light-subpath segments at most, whose midpoints probe the
/// scene's openness before the analysis.
const PROBE_CAMERA_RAYS_PER_AXIS: u32 = 8;
const PROBE_SEGMENTS: usize = 192;

/// Accumulated over a render, for the render notes (002 Table 4 and the resampling cost).
#[derive(Clone, Copy, Debug, Default)]
pub struct ResamplingStats {
    pub iterations: u64,
    /// Nodes with distributions, summed over iterations.
    pub nodes_used: u64,
    /// Seconds spent building distributions (visibility rays included).
    pub build_seconds: f64,
    /// Node-to-light-vertex pairs evaluated, and those found visible.
    pub pairs: u64,
    pub visible_pairs: u64,
}

/// Shards of [`NodeCounts`]: worker threads beyond this many share one.
const COUNT_SHARDS: usize = 8;

/// Camera vertices mapped to each node so far in a render (002 N_mapped), counted per worker
/// thread (shard) and summed when an iteration begins: one count per camera vertex, and with
/// one shared array both threads would write the same cache lines. The sums do not depend on
/// which thread counted what, so the image does not depend on the thread count.
#[derive(Default)]
struct NodeCounts {
    nodes: usize,
    /// Shard s's count of node n at `s stride + n`; `stride` is a multiple of 8 counts (a cache
    /// line) with a line to spare, so no two shards share a line.
    stride: usize,
    counts: Vec<AtomicU64>,
}

impl NodeCounts {
    fn new(nodes: usize) -> Self {
        let stride = nodes.div_ceil(8) * 8 + 8;
        NodeCounts {
            nodes,
            stride,
            counts: (0..COUNT_SHARDS * stride)
                .map(|_| AtomicU64::new(0))
                .collect(),
        }
    }

    #[inline]
    fn add(&self, node: usize) {
        let shard = rayon::current_thread_index().unwrap_or(0) % COUNT_SHARDS;
        self.counts[shard * self.stride + node].fetch_add(1, Ordering::Relaxed);
    }

    /// Per node, summed over the shards.
    fn totals(&self) -> Vec<u64> {
        (0..self.nodes)
            .map(|n| {
                (0..COUNT_SHARDS)
                    .map(|s| self.counts[s * self.stride + n].load(Ordering::Relaxed))
                    .sum()
            })
            .collect()
    }

    fn reset(&self) {
        for c in &self.counts {
            c.store(0, Ordering::Relaxed);
        }
    }
}

/// SkelBPT's connection policy: builds the distributions per iteration and resamples.
pub struct SkeletonResampler {
    settings: ResamplingSettings,
    /// None: renders as `bdpt` (see the module docs).
    skeleton: Option<NodeSkeleton>,
    /// Camera vertices mapped to each node so far in this render (002 N_mapped).
    mapped: NodeCounts,
    stats: Mutex<ResamplingStats>,
    occlusion: OcclusionTally,
}

impl SkeletonResampler {
    fn plain(settings: ResamplingSettings) -> Self {
        SkeletonResampler {
            settings,
            skeleton: None,
            mapped: NodeCounts::default(),
            stats: Mutex::new(ResamplingStats::default()),
            occlusion: OcclusionTally::default(),
        }
    }

    fn stats(&self) -> ResamplingStats {
        *self.stats.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Nodes that get distributions this iteration (002 §4.4).
    fn accepted_nodes(&self) -> Vec<bool> {
        let counts = self.mapped.totals();
        let total: u64 = counts.iter().sum();
        if total == 0 {
            return vec![false; counts.len()];
        }
        let mean = total as f64 / counts.len() as f64;
        let threshold = self.settings.accept as f64 * mean;
        counts.iter().map(|&c| c as f64 > threshold).collect()
    }

    fn build_tables(&self, scene: &Scene, skeleton: &NodeSkeleton, paths: &LightPaths) -> Tables {
        let anchors: Vec<Anchor> = skeleton
            .positions
            .iter()
            .map(|&p| Anchor { p, surface: None })
            .collect();
        let accepted = self.accepted_nodes();
        let (tables, visible_pairs) =
            build_tables(scene, &anchors, &accepted, paths, self.settings.subset);
        let mut stats = self.stats.lock().unwrap_or_else(|e| e.into_inner());
        stats.iterations += 1;
        stats.nodes_used += tables.table_count() as u64;
        stats.pairs += tables.cdfs.len() as u64;
        stats.visible_pairs += visible_pairs;
        tables
    }
}

impl ConnectionPolicy for SkeletonResampler {
    fn connection_count(&self, light_paths: usize) -> f32 {
        if self.skeleton.is_some() {
            self.settings.connection_count(light_paths)
        } else {
            1.0
        }
    }

    fn begin_iteration(
        &self,
        scene: &Scene,
        paths: &LightPaths,
        sample_index: u32,
    ) -> Result<(Option<Box<dyn Any + Send + Sync>>, u64)> {
        let Some(skeleton) = &self.skeleton else {
            return Ok((None, 0));
        };
        if sample_index == 0 {
            // A new render: counts and statistics start over.
            self.mapped.reset();
            *self.stats.lock().unwrap_or_else(|e| e.into_inner()) = ResamplingStats::default();
            self.occlusion.reset();
        }
        let start = Instant::now();
        let tables = self.build_tables(scene, skeleton, paths);
        let rays = (tables.cdfs.len()) as u64;
        self.stats
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .build_seconds += start.elapsed().as_secs_f64();
        Ok((Some(Box::new(tables)), rays))
    }

    fn layers(&self) -> Vec<String> {
        distribution_layers(self.settings.images)
    }

    /// Without a skeleton: `bdpt`'s own light subpath (pixel index modulo their number).
    fn connect(
        &self,
        vertex: &CameraVertex,
        light_paths: usize,
        rng: &mut Sampler,
        connect: &mut dyn FnMut(usize, f32),
    ) {
        UniformPerPixel.connect(vertex, light_paths, rng, connect);
    }

    fn connect_vertex(
        &self,
        vertex: &CameraVertex,
        paths: &LightPaths,
        rng: &mut Sampler,
        connect: &mut dyn FnMut(usize, usize, f32) -> Connection,
    ) {
        let (Some(skeleton), Some(tables)) = (
            &self.skeleton,
            paths
                .policy_data
                .as_ref()
                .and_then(|d| d.downcast_ref::<Tables>()),
        ) else {
            // The default: every vertex of the pixel's own subpath.
            connect_whole_subpaths(self, vertex, paths, rng, connect);
            return;
        };
        let node = skeleton.node_of(vertex.si);
        if let Some(n) = node {
            self.mapped.add(n as usize);
        }
        let table = node.map_or(NO_TABLE, |n| tables.anchor_table[n as usize]);
        tables.resample(vertex, table, rng, &self.occlusion, connect);
    }
}

/// Fraction of [`OPENNESS_RAYS`] directions (a Fibonacci sphere) from `p` that leave the
/// scene: 0 inside a closed room, about one half above an open floor.
fn escape_fraction(scene: &Scene, p: Vec3) -> f32 {
    let golden = std::f32::consts::PI * (3.0 - 5.0f32.sqrt());
    let escaped = (0..OPENNESS_RAYS)
        .filter(|&k| {
            let z = 1.0 - (2.0 * k as f32 + 1.0) / OPENNESS_RAYS as f32;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = golden * k as f32;
            let dir = Vec3::new(r * phi.cos(), r * phi.sin(), z);
            scene.intersect(&Ray::new(p, dir, f32::INFINITY)).is_none()
        })
        .count();
    escaped as f32 / OPENNESS_RAYS as f32
}

/// The `bdpt_skeleton` integrator (module docs).
pub struct BdptSkeleton {
    settings: IntegratorSettings,
    bdpt: Bdpt,
    resampler: Arc<SkeletonResampler>,
    prepared_for: Option<Fingerprint>,
}

impl BdptSkeleton {
    pub fn new(settings: IntegratorSettings) -> Result<Self> {
        let mut bdpt = Bdpt::new(settings);
        if let Some(n) = settings.light_paths {
            bdpt = bdpt.with_light_paths(n as usize)?;
        }
        let resampler = Arc::new(SkeletonResampler::plain(settings.resampling));
        bdpt.set_policy(Box::new(resampler.clone()));
        Ok(BdptSkeleton {
            settings,
            bdpt,
            resampler,
            prepared_for: None,
        })
    }

    /// Also renders the image of every (s, t) strategy (`Bdpt::with_strategy_images`), for
    /// the per-strategy error split of `examples/strategy_variance.rs`.
    pub fn with_strategy_images(mut self, max_length: u32) -> Result<Self> {
        self.bdpt = self.bdpt.with_strategy_images(max_length)?;
        Ok(self)
    }

    /// Whether the render resamples (false: it renders exactly `bdpt`'s image).
    pub fn resamples(&self) -> bool {
        self.resampler.skeleton.is_some()
    }

    /// Statistics of the last render (002 Table 4: nodes used per iteration; resampling cost).
    pub fn stats(&self) -> ResamplingStats {
        self.resampler.stats()
    }

    /// Why the scene surely has no use for a skeleton, decided from the pilot light subpaths
    /// and the camera before the costly analysis: the subpaths left no vertex (no node can see
    /// one), or the scene is open at every probe point (the camera, midpoints of camera rays to
    /// their first hits and of the pilot subpaths' segments): each sees the outside in at least
    /// [`ENCLOSED_ESCAPE_FRACTION`] of its directions. One enclosed probe leaves the decision
    /// to the skeleton's nodes ([`BdptSkeleton::build_skeleton`]).
    fn refuse_early(scene: &Scene, camera: &Camera, pilot: &LightPaths) -> Option<String> {
        if pilot.vertices.is_empty() {
            return Some(format!(
                "renders as bdpt: none of its {PILOT_LIGHT_PATHS} pilot light subpaths reaches a \
                 surface"
            ));
        }
        let frame = camera.frame(1.0);
        let mut probes = vec![frame.eye];
        let side = PROBE_CAMERA_RAYS_PER_AXIS;
        for k in 0..side * side {
            let film = Vec2::new(
                ((k % side) as f32 + 0.5) / side as f32,
                ((k / side) as f32 + 0.5) / side as f32,
            );
            let ray = frame.generate_ray(film, Vec2::splat(0.5));
            if let Some(si) = scene.intersect(&ray) {
                probes.push((ray.origin + si.p) * 0.5);
            }
        }
        let segments = pilot.ranges.iter().flat_map(|&(a, b)| {
            let v = &pilot.vertices[a as usize..b as usize];
            v.windows(2).map(|w| (w[0].si.p + w[1].si.p) * 0.5)
        });
        probes.extend(segments.take(PROBE_SEGMENTS));
        let open = probes
            .par_iter()
            .all(|&p| escape_fraction(scene, p) >= ENCLOSED_ESCAPE_FRACTION);
        open.then(|| {
            format!(
                "renders as bdpt: no usable skeleton (an open scene: every one of {} probe \
                 points, the camera and points along camera rays and pilot light subpaths, sees \
                 the outside in at least {:.0} % of its directions)",
                probes.len(),
                100.0 * ENCLOSED_ESCAPE_FRACTION
            )
        })
    }

    /// The skeleton, or why there is none to use.
    fn build_skeleton(
        &self,
        scene: &Scene,
        progress: &dyn Fn(&str, f64) -> bool,
        stages: &mut Vec<StageTime>,
    ) -> Result<std::result::Result<NodeSkeleton, String>> {
        let skeleton = match NodeSkeleton::build(
            scene,
            self.settings.skeleton.resolution,
            progress,
            stages,
        )? {
            Ok(s) => s,
            Err(why) => return Ok(Err(why)),
        };
        let enclosed = skeleton
            .positions
            .par_iter()
            .filter(|&&p| escape_fraction(scene, p) < ENCLOSED_ESCAPE_FRACTION)
            .count();
        if enclosed == 0 {
            return Ok(Err(format!(
                "an open scene: every one of its {} nodes sees the outside in at least {:.0} % \
                 of its directions",
                skeleton.positions.len(),
                100.0 * ENCLOSED_ESCAPE_FRACTION
            )));
        }
        Ok(Ok(skeleton))
    }

    /// The pilot set of light subpaths (deterministic for the scene).
    fn pilot_light_paths(&self, scene: &Scene) -> LightPaths {
        let camera = scene.camera().copied().or_else(|| {
            let b = scene.bounds();
            let centre = (b.min + b.max) * 0.5;
            Camera::look_at(
                centre + Vec3::Z * (b.max - b.min).length().max(1.0),
                centre,
                Vec3::Y,
                45.0,
            )
            .ok()
        });
        let Some(camera) = camera else {
            return LightPaths {
                vertices: Vec::new(),
                ranges: Vec::new(),
                policy_data: None,
            };
        };
        let view = View {
            frame: camera.frame(1.0),
            width: 16,
            height: 16,
            sampler: Default::default(),
        };
        self.bdpt
            .trace_light_paths(scene, &view, PILOT_SEED, 0, PILOT_LIGHT_PATHS)
            .0
    }

    /// Nodes that see at least one vertex of the pilot light subpaths.
    fn nodes_seeing_light(scene: &Scene, skeleton: &NodeSkeleton, paths: &LightPaths) -> usize {
        skeleton
            .positions
            .par_iter()
            .filter(|&&node| {
                paths.vertices.iter().any(|y| {
                    let d = node - y.si.p;
                    d.dot(y.si.ng) * y.si.wo.dot(y.si.ng) > 0.0
                        && !scene.occluded(&y.si.spawn_ray_to(node, Vec3::ZERO, Vec3::ZERO))
                })
            })
            .count()
    }
}

impl Integrator for BdptSkeleton {
    fn name(&self) -> &'static str {
        "bdpt_skeleton"
    }

    fn layers(&self) -> Vec<String> {
        self.bdpt.layers()
    }

    fn prepare(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        progress: &dyn Fn(&str, f64) -> bool,
    ) -> Result<Precomputation> {
        self.prepared_for = None;
        let mut stages = Vec::new();
        let mut notes = Vec::new();
        let mut resampler = SkeletonResampler::plain(self.settings.resampling);
        let t = Instant::now();
        let pilot = self.pilot_light_paths(scene);
        let early = Self::refuse_early(scene, camera, &pilot);
        stages.push(StageTime {
            stage: "pilot light subpaths, openness probes",
            seconds: t.elapsed().as_secs_f64(),
        });
        let skeleton = match early {
            Some(why) => Err(why),
            None => self
                .build_skeleton(scene, progress, &mut stages)?
                .map_err(|why| format!("renders as bdpt: no usable skeleton ({why})")),
        };
        match skeleton {
            Err(why) => notes.push(why),
            Ok(skeleton) => {
                let t = Instant::now();
                let seeing = Self::nodes_seeing_light(scene, &skeleton, &pilot);
                stages.push(StageTime {
                    stage: "nodes seeing the pilot's light vertices",
                    seconds: t.elapsed().as_secs_f64(),
                });
                let nodes = skeleton.positions.len();
                if seeing == 0 {
                    notes.push(format!(
                        "renders as bdpt: none of the {nodes} skeleton nodes sees \
                         a vertex of {PILOT_LIGHT_PATHS} pilot light subpaths"
                    ));
                } else {
                    notes.push(format!(
                        "{nodes} filtered skeleton nodes, {seeing} see pilot light \
                         vertices; resampling from {} light subpaths, accept {}",
                        self.settings.resampling.subset, self.settings.resampling.accept
                    ));
                    resampler.mapped = NodeCounts::new(nodes);
                    resampler.skeleton = Some(skeleton);
                }
            }
        }
        self.resampler = Arc::new(resampler);
        self.bdpt.set_policy(Box::new(self.resampler.clone()));
        self.prepared_for = Some(Fingerprint::of(scene));
        Ok(Precomputation { stages, notes })
    }

    fn check_prepared(&self, scene: &Scene) -> Result<()> {
        if self.prepared_for == Some(Fingerprint::of(scene)) {
            Ok(())
        } else {
            Err(Error::invalid(
                "bdpt_skeleton must be prepared for this scene before rendering it",
            ))
        }
    }

    fn uses_iterations(&self) -> bool {
        true
    }

    fn begin_iteration(
        &self,
        scene: &Scene,
        view: &View,
        seed: u64,
        sample_index: u32,
    ) -> Result<Iteration> {
        self.bdpt.begin_iteration(scene, view, seed, sample_index)
    }

    fn sample(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        ctx: &SampleContext,
    ) -> PixelSample {
        self.bdpt.sample(scene, ray, rng, counters, ctx)
    }

    fn render_notes(&self) -> Vec<String> {
        let s = self.stats();
        if !self.resamples() || s.iterations == 0 {
            return Vec::new();
        }
        let it = s.iterations as f64;
        vec![
            format!(
                "{:.1} of {} nodes used per iteration, resampling {:.2} ms and {:.0} \
                 node-vertex visibility rays per iteration ({:.1} % visible)",
                s.nodes_used as f64 / it,
                self.resampler.mapped.nodes,
                1e3 * s.build_seconds / it,
                s.pairs as f64 / it,
                100.0 * s.visible_pairs as f64 / s.pairs.max(1) as f64
            ),
            self.resampler.occlusion.note(),
        ]
    }
}

/// `bdpt_skeleton` in the integrator registry: the resampling's `subset`, `accept` and
/// `images`, and the skeleton's `resolution` and `voxel_budget`.
pub(super) const REGISTRATION: super::Registration = super::Registration {
    name: "bdpt_skeleton",
    set_option: |settings, option| {
        match option.key {
            "resolution" | "voxel_budget" => settings.skeleton.set(option.key, option.value)?,
            "subset" | "accept" | "images" | "count" => {
                settings.resampling.set(option.key, option.value)?
            }
            _ => return Ok(false),
        }
        Ok(true)
    },
    create: |settings| Ok(Box::new(BdptSkeleton::new(settings)?)),
    adaptive_mis: &[],
};
