//! ICBPT (002 §5, lines 198-200): importance caching (Georgiev et al. 2012) adapted to
//! bidirectional path tracing, the baseline SkelBPT is measured against.
//!
//! Each iteration traces, before anything else, the eye subpaths of d x (pixels) random pixels
//! (independent of the iteration's own camera paths) and keeps their non-specular surface
//! vertices as importance records. After `bdpt` traces the light subpaths, every record gets
//! the distributions SkelBPT gives a skeleton node (`resampled::build_tables`: p_V by a
//! shadow ray from the record, p_U, p_C, max heuristic). A camera vertex z_{t-1}, t >= 2,
//! resamples from its nearest record whose normal is within [`RECORD_COS`] of its own (a
//! record on the wall does not serve the floor next to it), or uniformly when none is. The
//! MIS weights count the resampled connections as N samples, as SkelBPT's do; t = 1 is not
//! resampled.
//!
//! Nearest-record lookup uses a uniform grid over the records' bounds searched ring by ring
//! (exact nearest): a few hundred to a few thousand records are rebuilt every iteration, so a
//! grid costs no dependency and its build is a counting sort.

use std::any::Any;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use rayon::prelude::*;

use super::bdpt::{
    CameraVertex, Connection, ConnectionPolicy, LightPaths, PathObserver, UniformPerPixel,
};
use super::resampled::{
    build_tables, distribution_layers, Anchor, AnchorSurface, OcclusionTally, Tables, NO_TABLE,
};
use super::{
    Bdpt, Integrator, IntegratorSettings, Iteration, ResamplingStats, SampleContext, TraceCounters,
    View,
};
use crate::error::Result;
use crate::film::PixelSample;
use crate::geometry::Ray;
use crate::guide::ResamplingSettings;
use crate::math::{Rng, Sampler, Vec3};
use crate::scene::{Scene, SurfaceInteraction};

/// Random-number stream of the record subpaths (apart from the pixels' and the light's).
const RECORD_STREAM: u64 = 0x1c0b_9a7e_55d2_3f41;
/// A record serves a camera vertex whose facing normal is within this cosine of its own.
const RECORD_COS: f32 = 0.5;

/// Importance records and their lookup grid.
struct Records {
    anchors: Vec<Anchor>,
    positions: Vec<Vec3>,
    /// Facing normal of each record (the side its eye came from).
    normals: Vec<Vec3>,
    grid: RecordGrid,
}

/// A uniform grid of record indices (counting-sorted by cell).
struct RecordGrid {
    lo: Vec3,
    cell: f32,
    dims: [i32; 3],
    /// Cell c holds `items[start[c]..start[c + 1]]`.
    start: Vec<u32>,
    items: Vec<u32>,
}

impl RecordGrid {
    fn new(points: &[Vec3]) -> Self {
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for &p in points {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        if points.is_empty() {
            (lo, hi) = (Vec3::ZERO, Vec3::ZERO);
        }
        let extent = (hi - lo).max_element().max(1e-6);
        // About two records per cell along the longest side's cube root, at most 64 cells.
        let per_axis = ((points.len() as f32).cbrt() * 2.0).ceil().clamp(1.0, 64.0);
        let cell = extent / per_axis;
        let dims = ((hi - lo) / cell)
            .to_array()
            .map(|d| (d.floor() as i32 + 1).clamp(1, 65));
        let mut grid = RecordGrid {
            lo,
            cell,
            dims,
            start: Vec::new(),
            items: Vec::new(),
        };
        let cells = (dims[0] * dims[1] * dims[2]) as usize;
        let index: Vec<usize> = points.iter().map(|&p| grid.flat(grid.coords(p))).collect();
        let mut start = vec![0u32; cells + 1];
        for &c in &index {
            start[c + 1] += 1;
        }
        for c in 0..cells {
            start[c + 1] += start[c];
        }
        let mut fill = start.clone();
        let mut items = vec![0u32; points.len()];
        for (i, &c) in index.iter().enumerate() {
            items[fill[c] as usize] = i as u32;
            fill[c] += 1;
        }
        grid.start = start;
        grid.items = items;
        grid
    }

    fn coords(&self, p: Vec3) -> [i32; 3] {
        let c = ((p - self.lo) / self.cell).to_array();
        [0, 1, 2].map(|a| (c[a].floor() as i32).clamp(0, self.dims[a] - 1))
    }

    fn flat(&self, c: [i32; 3]) -> usize {
        ((c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]) as usize
    }

    /// The nearest record to `p` that `accept` takes, searching rings of cells outwards
    /// until no closer one can remain (a cell of ring r is at least (r - 1) cells away).
    fn nearest(
        &self,
        p: Vec3,
        positions: &[Vec3],
        accept: impl Fn(usize) -> bool,
    ) -> Option<usize> {
        let c = self.coords(p);
        let mut best: Option<(f32, usize)> = None;
        let rings = self.dims.iter().copied().max().unwrap_or(1);
        for r in 0..=rings {
            for z in (c[2] - r).max(0)..=(c[2] + r).min(self.dims[2] - 1) {
                for y in (c[1] - r).max(0)..=(c[1] + r).min(self.dims[1] - 1) {
                    for x in (c[0] - r).max(0)..=(c[0] + r).min(self.dims[0] - 1) {
                        let ring = (x - c[0]).abs().max((y - c[1]).abs()).max((z - c[2]).abs());
                        if ring != r {
                            continue;
                        }
                        let cell = self.flat([x, y, z]);
                        for &i in
                            &self.items[self.start[cell] as usize..self.start[cell + 1] as usize]
                        {
                            let i = i as usize;
                            let d2 = (positions[i] - p).length_squared();
                            if best.map_or(true, |(b, _)| d2 < b) && accept(i) {
                                best = Some((d2, i));
                            }
                        }
                    }
                }
            }
            if let Some((d2, _)) = best {
                let reach = r as f32 * self.cell;
                if d2 <= reach * reach {
                    break;
                }
            }
        }
        best.map(|(_, i)| i)
    }
}

/// Collects the non-specular surface vertices of a record subpath.
struct RecordObserver<'a> {
    scene: &'a Scene,
    records: Vec<SurfaceInteraction>,
}

impl PathObserver for RecordObserver<'_> {
    fn camera_vertex(&mut self, _p: Vec3, si: Option<&SurfaceInteraction>) {
        if let Some(si) = si {
            if !self.scene.bsdf(si).is_delta() {
                self.records.push(*si);
            }
        }
    }
}

/// One iteration's records and distributions.
struct IcIteration {
    records: Arc<Records>,
    tables: Tables,
}

/// ICBPT's connection policy.
struct IcResampler {
    settings: ResamplingSettings,
    /// The records of the iteration being prepared, handed from the integrator's
    /// `begin_iteration` (which sees the view) to the policy's (which sees the light subpaths).
    pending: Mutex<Option<Arc<Records>>>,
    stats: Mutex<ResamplingStats>,
    occlusion: OcclusionTally,
}

impl IcResampler {
    fn stats(&self) -> std::sync::MutexGuard<'_, ResamplingStats> {
        self.stats.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl ConnectionPolicy for IcResampler {
    fn connection_count(&self, light_paths: usize) -> f32 {
        self.settings.connection_count(light_paths)
    }

    fn begin_iteration(
        &self,
        scene: &Scene,
        paths: &LightPaths,
        _sample_index: u32,
    ) -> Result<(Option<Box<dyn Any + Send + Sync>>, u64)> {
        let records = self
            .pending
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take()
            .unwrap_or_else(|| {
                Arc::new(Records {
                    anchors: Vec::new(),
                    positions: Vec::new(),
                    normals: Vec::new(),
                    grid: RecordGrid::new(&[]),
                })
            });
        let start = Instant::now();
        let used = vec![true; records.anchors.len()];
        let (tables, visible) =
            build_tables(scene, &records.anchors, &used, paths, self.settings.subset);
        let rays = tables.cdfs.len() as u64;
        let mut stats = self.stats();
        stats.iterations += 1;
        stats.nodes_used += tables.table_count() as u64;
        stats.pairs += tables.cdfs.len() as u64;
        stats.visible_pairs += visible;
        stats.build_seconds += start.elapsed().as_secs_f64();
        Ok((Some(Box::new(IcIteration { records, tables })), rays))
    }

    fn layers(&self) -> Vec<String> {
        distribution_layers(self.settings.images)
    }

    /// Unused: `connect_vertex` picks the vertices; without the iteration's tables (never
    /// the case in a render) the pixel's own subpath, as `bdpt`.
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
        let Some(it) = paths
            .policy_data
            .as_ref()
            .and_then(|d| d.downcast_ref::<IcIteration>())
        else {
            return;
        };
        let n = vertex.si.facing_normal();
        let records = &it.records;
        let record = records.grid.nearest(vertex.si.p, &records.positions, |i| {
            records.normals[i].dot(n) > RECORD_COS
        });
        let table = record.map_or(NO_TABLE, |r| it.tables.anchor_table[r]);
        it.tables
            .resample(vertex, table, rng, &self.occlusion, connect);
    }
}

/// The `bdpt_ic` integrator (module docs).
pub struct BdptIc {
    settings: IntegratorSettings,
    bdpt: Bdpt,
    resampler: Arc<IcResampler>,
}

impl BdptIc {
    pub fn new(settings: IntegratorSettings) -> Result<Self> {
        let mut bdpt = Bdpt::new(settings);
        if let Some(n) = settings.light_paths {
            bdpt = bdpt.with_light_paths(n as usize)?;
        }
        let resampler = Arc::new(IcResampler {
            settings: settings.resampling,
            pending: Mutex::new(None),
            stats: Mutex::new(ResamplingStats::default()),
            occlusion: OcclusionTally::default(),
        });
        bdpt.set_policy(Box::new(resampler.clone()));
        Ok(BdptIc {
            settings,
            bdpt,
            resampler,
        })
    }

    /// Statistics of the last render (records per iteration in `nodes_used`).
    pub fn stats(&self) -> ResamplingStats {
        *self.resampler.stats()
    }

    /// The importance records of one iteration: the non-specular vertices of the eye subpaths
    /// of d x (pixels) random pixels, traced with their own random numbers.
    fn trace_records(&self, scene: &Scene, view: &View, seed: u64, sample_index: u32) -> Records {
        let pixels = view.width as u64 * view.height as u64;
        let count = ((self.settings.resampling.density as f64 * pixels as f64).round() as u64)
            .clamp(1, pixels.max(1));
        let per_path: Vec<Vec<SurfaceInteraction>> = (0..count)
            .into_par_iter()
            .map(|k| {
                let mut rng = Sampler::independent(Rng::for_sample(
                    seed ^ RECORD_STREAM,
                    k,
                    sample_index as u64,
                ));
                let pixel = ((rng.uniform() as f64 * pixels as f64) as u64).min(pixels - 1);
                let (x, y) = (
                    (pixel % view.width as u64) as u32,
                    (pixel / view.width as u64) as u32,
                );
                let ray = view.primary_ray(x, y, &mut rng);
                let mut observer = RecordObserver {
                    scene,
                    records: Vec::new(),
                };
                let ctx = SampleContext {
                    pixel_index: pixel,
                    sample_index: 0,
                    view,
                    iteration: None,
                    layers: &[],
                };
                let mut counters = TraceCounters::default();
                self.bdpt
                    .sample_observed(scene, ray, &mut rng, &mut counters, &ctx, &mut observer);
                observer.records
            })
            .collect();
        let records: Vec<SurfaceInteraction> = per_path.into_iter().flatten().collect();
        let anchors: Vec<Anchor> = records
            .iter()
            .map(|si| Anchor {
                p: si.p,
                surface: Some(AnchorSurface {
                    p_error: si.p_error,
                    ng: si.ng,
                    wo: si.wo,
                    transmits: scene.bsdf(si).transmits(),
                }),
            })
            .collect();
        let positions: Vec<Vec3> = records.iter().map(|si| si.p).collect();
        Records {
            anchors,
            normals: records.iter().map(|si| si.facing_normal()).collect(),
            grid: RecordGrid::new(&positions),
            positions,
        }
    }
}

impl Integrator for BdptIc {
    fn name(&self) -> &'static str {
        "bdpt_ic"
    }

    fn layers(&self) -> Vec<String> {
        self.bdpt.layers()
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
        if sample_index == 0 {
            *self.resampler.stats() = ResamplingStats::default();
            self.resampler.occlusion.reset();
        }
        let start = Instant::now();
        let records = Arc::new(self.trace_records(scene, view, seed, sample_index));
        self.resampler.stats().build_seconds += start.elapsed().as_secs_f64();
        *self
            .resampler
            .pending
            .lock()
            .unwrap_or_else(|e| e.into_inner()) = Some(records);
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
        if s.iterations == 0 {
            return Vec::new();
        }
        let it = s.iterations as f64;
        vec![
            format!(
                "{:.1} importance records per iteration (density {}), records and resampling \
                 {:.2} ms and {:.0} record-vertex visibility rays per iteration ({:.1} % visible)",
                s.nodes_used as f64 / it,
                self.settings.resampling.density,
                1e3 * s.build_seconds / it,
                s.pairs as f64 / it,
                100.0 * s.visible_pairs as f64 / s.pairs.max(1) as f64
            ),
            self.resampler.occlusion.note(),
        ]
    }
}

/// `bdpt_ic` in the integrator registry: the resampling's `subset`, `density` and `images`.
pub(super) const REGISTRATION: super::Registration = super::Registration {
    name: "bdpt_ic",
    set_option: |settings, option| {
        match option.key {
            "subset" | "density" | "images" | "count" => {
                settings.resampling.set(option.key, option.value)?
            }
            _ => return Ok(false),
        }
        Ok(true)
    },
    create: |settings| Ok(Box::new(BdptIc::new(settings)?)),
    adaptive_mis: &[],
};
