//! Portal-guided ray sampling (000 §10.4.1, lines 3033-3070, "shortest paths strategy"),
//! made unbiased and smooth.
//!
//! # Build ([`PortalGuide::build`])
//!
//! The analysis cuts the empty space into opening-forest regions joined by portals (000
//! §10.3.3-10.3.4, `analysis::regions`). The regions that hold a light are found (an emissive
//! triangle's points, offset a voxel along its emitting side; a point light's position; for an
//! environment or a directional light, every region touching the grid's border, the outside).
//! A multi-source Dijkstra over the region graph, an edge per portal weighted by the distance
//! from one region's centroid through the portal's centre to the other's, gives every region
//! the portal that leads one step toward the nearest light: its *next portal*. Each portal is
//! fitted with a rectangle: the faces of its most common axis, their extent across that axis,
//! at their mean plane (a portal is a set of voxel faces; a rectangle is what the spherical
//! rectangle sampler can sample in solid angle).
//!
//! # Query ([`PortalQuery`])
//!
//! The thesis sampled the next portal of the point's own region uniformly by area, and saw
//! discontinuities at region borders (the strategy jumps) and fireflies (rays that miss the
//! portal could only come from BSDF sampling, without MIS). Here:
//! - *Smooth across borders.* A point x (offset half a voxel along its facing normal n) weighs
//!   the empty voxels of a window of `smoothing` voxels around it with a separable tent
//!   `prod_k max(0, 1 - |x_k - c_k| / r)` (c the voxel centre, r the window radius), counting
//!   only voxels in front of the surface (`(c - x) . n > 0`: a thin wall's other side is
//!   another room). Each voxel's weight goes to its region. The tent is continuous in x, so the
//!   mixture below changes continuously inside a region and across region borders; it jumps
//!   only where the normal does (edges, where the BSDF jumps too).
//! - *The mixture.* Regions with a next portal give their weight to that portal's rectangle,
//!   merged per portal; a rectangle the point cannot see in front of its surface (all corners
//!   behind the tangent plane, or the point in its plane) gets none. With `g` the guided
//!   weight over the window's total (light regions and regions with no path keep theirs), the
//!   guiding probability is `c = c_portal g` and the lobes' selection probabilities are their
//!   weights over the guided weight. Each lobe samples its rectangle uniformly in solid angle
//!   ([`warp::SphericalRectangle`]), so its density is exact for any direction: 1 / (solid
//!   angle) through the rectangle, 0 elsewhere.
//! - *MIS.* The integrator combines the query with BSDF sampling by one-sample MIS
//!   ([`super::sample_bsdf_or_guide`]): every direction's density is `c p_portal + (1 - c)
//!   p_bsdf`, so a direction that misses every portal keeps its BSDF density and stays
//!   reachable (`c < 1` always), and next-event estimation weighs against the same mixture.
//!
//! The query is a function of the point and its normal alone (never of the path), so the
//! estimator is unbiased whatever the analysis says; a poor analysis costs variance only.

use std::collections::BinaryHeap;

use super::face_irradiance::{FaceIrradiance, FaceQuery, FaceScore, FaceTraining, MAX_FACE_LOBES};
use super::mixture::{pick_lobe, DirectionGuide};
use super::settings::RenderEstimator;
use crate::analysis::{Analysis, AnalysisSettings, Resolution, NO_REGION};
use crate::error::{Error, Result};
use crate::light::Light;
use crate::math::{warp, Vec2, Vec3};
use crate::scene::{Camera, Scene};
use crate::timing::StageTime;

/// Most portal lobes a query holds (a window of radius 2 voxels rarely meets more regions).
pub const MAX_PORTAL_LOBES: usize = 8;

/// How `path_portal` picks the portals it samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PortalStrategy {
    /// The portal toward the light along the region graph's shortest-path tree (000 §10.4.1).
    Shortest,
    /// Per-region distributions over the faces of the opening border learned from training
    /// paths (000 §10.4.2; [`super::face_irradiance`]).
    Irradiance,
}

impl PortalStrategy {
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "shortest" => Ok(PortalStrategy::Shortest),
            "irradiance" => Ok(PortalStrategy::Irradiance),
            _ => Err(Error::invalid(format!(
                "unknown portal strategy '{s}' (shortest, irradiance)"
            ))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            PortalStrategy::Shortest => "shortest",
            PortalStrategy::Irradiance => "irradiance",
        }
    }
}

/// Options of `path_portal` (`path_portal:strategy=shortest:c_portal=0.5:...`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PortalGuideSettings {
    pub strategy: PortalStrategy,
    /// Probability of sampling the portals where the whole window is guided (else the BSDF);
    /// in [0, 1).
    pub c_portal: f32,
    /// Voxels along the longest axis of the analysis grid.
    pub resolution: u32,
    /// Radius of the smoothing window, in voxels (> 0).
    pub smoothing: f32,
    /// A bound on how much more than `path` a guided path may weigh (infinite: none). At each
    /// vertex the render lowers c to `1 - rho / ratio_max`, rho the product of p_bsdf / p over
    /// the path's earlier directions, as `path_skeleton` does (its
    /// `SkeletonGuideSettings::ratio_max` says why: without it, the directions the BSDF draws
    /// where the portals are not weigh up to 1 / (1 - c) of `path`'s at every vertex, and the
    /// product makes a heavy tail at large c). c then depends on the path's prefix only, and
    /// every density of the vertex is the mixture at that c: unbiased.
    pub ratio_max: f32,
    /// Which portal of a region's shortest path a point aims at: the next one (the thesis),
    /// or the last one, the portal into the light's region (the thesis's SIS3-SIS4 forced the
    /// door's portal everywhere and saw the least noise; a region's next portal is often an
    /// internal border of the same room that leads no light).
    pub aim: PortalAim,
    /// `strategy=irradiance`'s options.
    pub faces: FaceSettings,
}

/// [`PortalGuideSettings::aim`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PortalAim {
    Next,
    Last,
    /// The portal of least area on the shortest path (the bottleneck: a door's gap).
    Narrowest,
}

/// `strategy=irradiance`'s own options ([`super::face_irradiance`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceSettings {
    /// Camera paths of the training.
    pub training_paths: u32,
    /// The learned share of a region's face distribution (the rest is uniform), in [0, 1].
    pub face_mix: f32,
    /// Distance threshold d_t as a fraction of the scene's diagonal: faces nearer than that
    /// along the direction are left to BSDF sampling (the thesis used 0.01).
    pub d_t: f32,
    /// Orientation threshold o_t: faces crossed at |cos| below it are left to BSDF sampling
    /// (the thesis used 0.5).
    pub o_t: f32,
    /// What a face's probability is proportional to.
    pub score: FaceScore,
}

impl Default for FaceSettings {
    fn default() -> Self {
        FaceSettings {
            training_paths: 16384,
            face_mix: 0.8,
            d_t: 0.0,
            o_t: 0.0,
            score: FaceScore::Flux,
        }
    }
}

impl Default for PortalGuideSettings {
    fn default() -> Self {
        PortalGuideSettings {
            strategy: PortalStrategy::Shortest,
            c_portal: 0.5,
            resolution: 96,
            smoothing: 2.0,
            ratio_max: super::settings::AUTO_RATIO_MAX,
            aim: PortalAim::Next,
            faces: FaceSettings::default(),
        }
    }
}

/// The option names [`PortalGuideSettings::set`] takes.
pub const PORTAL_OPTION_NAMES: &[&str] = &[
    "strategy",
    "c_portal",
    "resolution",
    "smoothing",
    "ratio_max",
    "aim",
    "training_paths",
    "face_mix",
    "d_t",
    "o_t",
    "face_score",
];

impl PortalGuideSettings {
    /// Sets one option by name; `Ok(false)` for a key it does not take. An invalid value
    /// leaves the settings as they were.
    pub fn set(&mut self, key: &str, value: &str) -> Result<bool> {
        let mut next = *self;
        let number = |v: &str| {
            v.parse::<f32>()
                .map_err(|_| Error::invalid(format!("path_portal: {key}={v} is not a number")))
        };
        match key {
            "strategy" => next.strategy = PortalStrategy::parse(value)?,
            "c_portal" => next.c_portal = number(value)?,
            "resolution" => {
                next.resolution = value.parse::<u32>().map_err(|_| {
                    Error::invalid(format!("path_portal: resolution={value} is not an integer"))
                })?
            }
            "smoothing" => next.smoothing = number(value)?,
            "ratio_max" => {
                next.ratio_max = if value == "none" {
                    f32::INFINITY
                } else {
                    number(value)?
                }
            }
            "aim" => {
                next.aim = match value {
                    "next" => PortalAim::Next,
                    "last" => PortalAim::Last,
                    "narrowest" => PortalAim::Narrowest,
                    _ => {
                        return Err(Error::invalid(format!(
                            "path_portal: aim={value} must be next, last or narrowest"
                        )))
                    }
                }
            }
            "training_paths" => {
                next.faces.training_paths = value.parse::<u32>().map_err(|_| {
                    Error::invalid(format!(
                        "path_portal: training_paths={value} is not an integer"
                    ))
                })?
            }
            "face_mix" => next.faces.face_mix = number(value)?,
            "d_t" => next.faces.d_t = number(value)?,
            "o_t" => next.faces.o_t = number(value)?,
            "face_score" => {
                next.faces.score = match value {
                    "flux" => FaceScore::Flux,
                    "radiance" => FaceScore::Radiance,
                    _ => {
                        return Err(Error::invalid(format!(
                            "path_portal: face_score={value} must be flux or radiance"
                        )))
                    }
                }
            }
            _ => return Ok(false),
        }
        next.validate()?;
        *self = next;
        Ok(true)
    }

    pub fn validate(&self) -> Result<()> {
        if !(self.c_portal.is_finite() && (0.0..1.0).contains(&self.c_portal)) {
            return Err(Error::invalid(format!(
                "path_portal: c_portal={} must be in [0, 1) (directions through no portal must stay reachable by BSDF sampling)",
                self.c_portal
            )));
        }
        if !(8..=1024).contains(&self.resolution) {
            return Err(Error::invalid(format!(
                "path_portal: resolution={} must be in [8, 1024]",
                self.resolution
            )));
        }
        if !(self.smoothing.is_finite() && (0.5..=8.0).contains(&self.smoothing)) {
            return Err(Error::invalid(format!(
                "path_portal: smoothing={} must be in [0.5, 8] voxels",
                self.smoothing
            )));
        }
        if !(self.ratio_max >= 1.0) {
            return Err(Error::invalid(format!(
                "path_portal: ratio_max={} must be at least 1 (or none)",
                self.ratio_max
            )));
        }
        let f = &self.faces;
        if !(1..=1 << 24).contains(&f.training_paths) {
            return Err(Error::invalid(format!(
                "path_portal: training_paths={} must be in [1, 16777216]",
                f.training_paths
            )));
        }
        if !(f.face_mix.is_finite() && (0.0..=1.0).contains(&f.face_mix)) {
            return Err(Error::invalid(format!(
                "path_portal: face_mix={} must be in [0, 1]",
                f.face_mix
            )));
        }
        if !(f.d_t.is_finite() && (0.0..=1.0).contains(&f.d_t)) {
            return Err(Error::invalid(format!(
                "path_portal: d_t={} must be in [0, 1] (a fraction of the scene's diagonal)",
                f.d_t
            )));
        }
        if !(f.o_t.is_finite() && (0.0..1.0).contains(&f.o_t)) {
            return Err(Error::invalid(format!(
                "path_portal: o_t={} must be in [0, 1) (a cosine)",
                f.o_t
            )));
        }
        Ok(())
    }
}

/// A portal's rectangle, set up once for every point that sees it.
#[derive(Clone, Copy, Debug)]
pub struct PortalRectangle {
    pub corner: Vec3,
    pub edge_u: Vec3,
    pub edge_v: Vec3,
    frame: warp::RectangleFrame,
}

impl PortalRectangle {
    fn new(corner: Vec3, edge_u: Vec3, edge_v: Vec3) -> Option<Self> {
        let (lu, lv) = (edge_u.length(), edge_v.length());
        let frame = warp::RectangleFrame::new(corner, edge_u / lu, edge_v / lv, lu, lv)?;
        Some(PortalRectangle {
            corner,
            edge_u,
            edge_v,
            frame,
        })
    }

    pub fn center(&self) -> Vec3 {
        self.corner + 0.5 * (self.edge_u + self.edge_v)
    }

    /// Whether some corner lies strictly in front of the plane through `p` of normal `n`.
    fn in_front_of(&self, p: Vec3, n: Vec3) -> bool {
        [
            self.corner,
            self.corner + self.edge_u,
            self.corner + self.edge_v,
            self.corner + self.edge_u + self.edge_v,
        ]
        .iter()
        .any(|&c| (c - p).dot(n) > 0.0)
    }
}

/// Why a guide guides nothing (the render summary says it; the integrator then renders
/// `path`'s samples).
#[derive(Clone, Debug, PartialEq)]
pub enum Unguided {
    /// No light lies in an empty region (no lights, or all inside occupied voxels).
    NoLightRegion,
    /// Every region holds a light or reaches none through portals (one room, an open scene).
    NoPortalPath,
    /// The regions guided toward a light hold less than [`OPEN_SCENE_FRACTION`] of the empty
    /// voxels (this share, in %): pockets of an open scene, not rooms.
    Open(f32),
    /// `strategy=irradiance`: no training path left any region through its border.
    NoTrainedFace,
}

/// Below this share of the empty voxels in guided regions a scene is open
/// ([`Unguided::Open`]): guiding its pockets costs more per sample than it can gain.
pub const OPEN_SCENE_FRACTION: f32 = 0.05;

impl std::fmt::Display for Unguided {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Unguided::NoLightRegion => {
                f.write_str("no light lies in an empty region of the analysis")
            }
            Unguided::NoPortalPath => f.write_str(
                "every region holds a light or reaches none through a portal (one room or an open scene)",
            ),
            Unguided::NoTrainedFace => f.write_str(
                "no training path carried light out of a region through its border",
            ),
            Unguided::Open(percent) => write!(
                f,
                "the regions guided toward a light hold {percent:.1} % of the empty space, under {} %: an open scene",
                OPEN_SCENE_FRACTION * 100.0
            ),
        }
    }
}

/// The shortest-paths portal guide of a scene (module docs).
pub struct PortalGuide {
    analysis: Analysis,
    settings: PortalGuideSettings,
    /// Per region: the index (into `rectangles`) of its next portal toward a light.
    next: Vec<Option<u32>>,
    /// Per portal of the analysis (same order): its rectangle.
    rectangles: Vec<Option<PortalRectangle>>,
    light_regions: usize,
    guided_regions: usize,
    /// Share of the empty voxels in guided regions.
    guided_fraction: f32,
    timings: Vec<StageTime>,
    /// `strategy=irradiance`: the regions' face distributions.
    faces: Option<FaceIrradiance>,
    /// Which scene it was built for (its address and triangle count).
    scene_key: (usize, usize),
}

impl PortalGuide {
    /// Runs the analysis (regions only) and builds the shortest-path tree of its regions.
    /// `strategy=irradiance` trains its face distributions with camera paths: `training`
    /// gives the camera and the render's light sampling and depth (required there).
    pub fn build(
        scene: &Scene,
        settings: &PortalGuideSettings,
        training: Option<(&Camera, RenderEstimator, u32)>,
        progress: &dyn Fn(&str, f64) -> bool,
    ) -> Result<PortalGuide> {
        settings.validate()?;
        if settings.strategy == PortalStrategy::Irradiance && training.is_none() {
            return Err(Error::invalid(
                "path_portal: strategy=irradiance trains with camera paths: it needs the camera",
            ));
        }
        let analysis = Analysis::build(
            scene,
            &AnalysisSettings {
                resolution: Resolution::LongestAxis(settings.resolution),
                // Not filled: a closed room is itself the inside of a closed surface.
                ..AnalysisSettings::default()
            },
            progress,
        )?;
        let started = std::time::Instant::now();
        let light_regions = light_regions(&analysis, scene);
        let rectangles: Vec<Option<PortalRectangle>> = analysis
            .portals
            .iter()
            .map(|p| portal_rectangle(&analysis, p))
            .collect();
        let mut next = next_portals(&analysis, &light_regions, &rectangles);
        if settings.aim != PortalAim::Next {
            next = chain_portals(&analysis, &next, settings.aim);
        }
        let mut timings = analysis.timings.clone();
        timings.push(StageTime {
            stage: "portal guide (light regions, shortest paths, rectangles)",
            seconds: started.elapsed().as_secs_f64(),
        });
        let faces = match training {
            Some((camera, estimator, max_depth))
                if settings.strategy == PortalStrategy::Irradiance =>
            {
                let started = std::time::Instant::now();
                let f = &settings.faces;
                let bounds = scene.bounds();
                let diagonal = (bounds.max - bounds.min).length();
                let faces = FaceIrradiance::build(
                    &analysis,
                    scene,
                    &FaceTraining {
                        camera,
                        estimator,
                        max_depth,
                        paths: f.training_paths,
                        face_mix: f.face_mix,
                        score: f.score,
                    },
                    f.d_t * diagonal,
                    f.o_t,
                )?;
                timings.push(StageTime {
                    stage: "face irradiance (borders, training paths, distributions)",
                    seconds: started.elapsed().as_secs_f64(),
                });
                Some(faces)
            }
            _ => None,
        };
        let empty: u64 = analysis.regions.iter().map(|r| r.voxels).sum();
        let guided: u64 = analysis
            .regions
            .iter()
            .zip(&next)
            .filter(|(_, n)| n.is_some())
            .map(|(r, _)| r.voxels)
            .sum();
        Ok(PortalGuide {
            guided_fraction: guided as f32 / empty.max(1) as f32,
            guided_regions: next.iter().filter(|n| n.is_some()).count(),
            light_regions: light_regions.iter().filter(|&&l| l).count(),
            analysis,
            settings: *settings,
            next,
            rectangles,
            timings,
            faces,
            scene_key: scene_key(scene),
        })
    }

    pub fn built_for(&self, scene: &Scene) -> bool {
        self.scene_key == scene_key(scene)
    }

    /// None when some point is guided; else why none is.
    pub fn unguided(&self) -> Option<Unguided> {
        if let Some(faces) = &self.faces {
            return (faces.guided_regions == 0).then_some(Unguided::NoTrainedFace);
        }
        if self.light_regions == 0 {
            Some(Unguided::NoLightRegion)
        } else if self.guided_regions == 0 {
            Some(Unguided::NoPortalPath)
        } else if self.guided_fraction < OPEN_SCENE_FRACTION {
            Some(Unguided::Open(100.0 * self.guided_fraction))
        } else {
            None
        }
    }

    pub fn settings(&self) -> &PortalGuideSettings {
        &self.settings
    }

    pub fn timings(&self) -> &[StageTime] {
        &self.timings
    }

    pub fn analysis(&self) -> &Analysis {
        &self.analysis
    }

    /// A line for the render summary.
    pub fn note(&self) -> String {
        let g = &self.analysis.grid;
        let faces = self.faces.as_ref().map_or(String::new(), |f| {
            format!(
                "; face irradiance: {} regions trained by {} paths, face_mix {}, d_t {}, o_t {}, {:.1} MiB",
                f.guided_regions,
                f.training_paths,
                self.settings.faces.face_mix,
                self.settings.faces.d_t,
                self.settings.faces.o_t,
                f.memory_bytes() as f64 / (1024.0 * 1024.0)
            )
        });
        format!(
            "portal guide ({}): grid {}x{}x{}, {} regions, {} portals, {} light regions, {} regions guided toward a light ({:.1} % of the empty space), c_portal {}, smoothing {} voxels, ratio_max {}, aim {:?}{}",
            self.settings.strategy.name(),
            g.dims[0],
            g.dims[1],
            g.dims[2],
            self.analysis.regions.len(),
            self.analysis.portals.len(),
            self.light_regions,
            self.guided_regions,
            100.0 * self.guided_fraction,
            self.settings.c_portal,
            self.settings.smoothing,
            self.settings.ratio_max,
            self.settings.aim,
            faces
        )
    }

    /// The rectangle of portal `portal` of the analysis (None where none was fitted).
    pub fn rectangle(&self, portal: u32) -> Option<&PortalRectangle> {
        self.rectangles.get(portal as usize)?.as_ref()
    }

    /// The next portal's rectangle of `region` (None for a light region or one with no path).
    pub fn next_rectangle(&self, region: u32) -> Option<&PortalRectangle> {
        let k = (*self.next.get(region as usize)?)?;
        self.rectangles[k as usize].as_ref()
    }

    /// Calls `each(region, weight)` for the empty voxels of the smoothing window around
    /// surface point `p` (facing normal `n`) in front of its surface, with their tent weights
    /// (module docs, "Query"); returns the weights' sum.
    fn window(&self, p: Vec3, n: Vec3, mut each: impl FnMut(u32, f32)) -> f32 {
        let grid = &self.analysis.grid;
        let h = grid.voxel_size as f32;
        let x = p + 0.5 * h * n;
        let r = self.settings.smoothing;
        let g = grid.to_grid(x);
        let lo = g.map(|c| (c - r as f64 - 0.5).ceil() as i64);
        let hi = g.map(|c| (c + r as f64 - 0.5).floor() as i64);
        let mut total = 0.0f32;
        for k in lo[2].max(0)..=hi[2].min(grid.dims[2] as i64 - 1) {
            let wz = 1.0 - ((g[2] - (k as f64 + 0.5)).abs() as f32 / r);
            if wz <= 0.0 {
                continue;
            }
            for j in lo[1].max(0)..=hi[1].min(grid.dims[1] as i64 - 1) {
                let wy = 1.0 - ((g[1] - (j as f64 + 0.5)).abs() as f32 / r);
                if wy <= 0.0 {
                    continue;
                }
                for i in lo[0].max(0)..=hi[0].min(grid.dims[0] as i64 - 1) {
                    let wx = 1.0 - ((g[0] - (i as f64 + 0.5)).abs() as f32 / r);
                    if wx <= 0.0 {
                        continue;
                    }
                    let v = grid.index(i as usize, j as usize, k as usize);
                    let label = self.analysis.labels[v];
                    if label == NO_REGION {
                        continue;
                    }
                    let centre = grid.to_world([i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5]);
                    if (centre - p).dot(n) <= 0.0 {
                        continue;
                    }
                    let w = wx * wy * wz;
                    total += w;
                    each(label, w);
                }
            }
        }
        total
    }

    /// The face distributions of `strategy=irradiance` (None for `shortest`).
    pub fn faces(&self) -> Option<&FaceIrradiance> {
        self.faces.as_ref()
    }

    /// An unguided face query of this guide (`strategy=irradiance`; None for `shortest`).
    pub fn face_query(&self) -> Option<FaceQuery<'_>> {
        Some(FaceQuery::new(self.faces.as_ref()?, &self.analysis))
    }

    /// Sets a face query up at surface point `p` with facing normal `n`
    /// (`strategy=irradiance`): the trained regions of the smoothing window, by weight;
    /// c = c_portal times their share of the window's weight.
    pub fn init_face_query(&self, query: &mut FaceQuery, p: Vec3, n: Vec3) {
        query.clear();
        let Some(faces) = self.faces.as_ref() else {
            return;
        };
        query.x = p;
        let mut guided = 0.0f32;
        let (regions, weights, count) = (&mut query.regions, &mut query.weights, &mut query.count);
        let total = self.window(p, n, |label, w| {
            if !faces.guides(label) {
                return;
            }
            if let Some(j) = regions[..*count].iter().position(|&r| r == label) {
                weights[j] += w;
                guided += w;
            } else if *count < MAX_FACE_LOBES {
                regions[*count] = label;
                weights[*count] = w;
                *count += 1;
                guided += w;
            }
        });
        if !(total > 0.0 && guided > 0.0) {
            query.clear();
            return;
        }
        for w in &mut query.weights[..query.count] {
            *w /= guided;
        }
        query.c = self.settings.c_portal * (guided / total).min(1.0);
    }

    /// Sets `query` up at surface point `p` with facing normal `n` (module docs, "Query").
    pub fn init_query(&self, query: &mut PortalQuery, p: Vec3, n: Vec3) {
        query.clear();
        // (portal index, weight) of the guided regions, and the window's total weight.
        let mut lobes: [(u32, f32); MAX_PORTAL_LOBES] = [(u32::MAX, 0.0); MAX_PORTAL_LOBES];
        let mut count = 0usize;
        let total = self.window(p, n, |label, w| {
            let Some(portal) = self.next[label as usize] else {
                return;
            };
            if let Some(slot) = lobes[..count].iter_mut().find(|l| l.0 == portal) {
                slot.1 += w;
            } else if count < MAX_PORTAL_LOBES {
                lobes[count] = (portal, w);
                count += 1;
            }
        });
        if !(total > 0.0) {
            return;
        }
        // The rectangles the point sees in front of its surface; the others' weight stays
        // unguided.
        let mut kept = 0.0f32;
        for &(portal, w) in &lobes[..count] {
            let Some(rect) = self.rectangles[portal as usize].as_ref() else {
                continue;
            };
            if !rect.in_front_of(p, n) {
                continue;
            }
            let slot = &mut query.lobes[query.count];
            if !rect.frame.seen_from_into(p, &mut slot.rect) {
                continue;
            }
            slot.weight = w;
            slot.portal = portal;
            query.count += 1;
            kept += w;
        }
        if query.count == 0 || !(kept > 0.0) {
            query.count = 0;
            return;
        }
        for l in &mut query.lobes[..query.count] {
            l.weight /= kept;
        }
        query.c = self.settings.c_portal * (kept / total).min(1.0);
    }
}

fn scene_key(scene: &Scene) -> (usize, usize) {
    (scene as *const Scene as usize, scene.triangle_count())
}

/// One lobe of a query: a portal's rectangle seen from the point and its selection probability.
#[derive(Clone, Debug)]
struct PortalLobe {
    rect: warp::SphericalRectangle,
    weight: f32,
    portal: u32,
}

/// The portal mixture at one point ([`PortalGuide::init_query`]); one per worker thread,
/// reused at every vertex.
#[derive(Clone, Debug)]
pub struct PortalQuery {
    lobes: [PortalLobe; MAX_PORTAL_LOBES],
    count: usize,
    c: f32,
}

impl Default for PortalQuery {
    fn default() -> Self {
        Self::new()
    }
}

impl PortalQuery {
    pub const fn new() -> Self {
        PortalQuery {
            lobes: [const {
                PortalLobe {
                    rect: warp::SphericalRectangle::empty(),
                    weight: 0.0,
                    portal: u32::MAX,
                }
            }; MAX_PORTAL_LOBES],
            count: 0,
            c: 0.0,
        }
    }

    /// Unguided (guiding probability 0).
    pub fn clear(&mut self) {
        self.count = 0;
        self.c = 0.0;
    }

    /// Lowers the guiding probability to at most `c` (`ratio_max`).
    pub fn cap_guiding_probability(&mut self, c: f32) {
        if self.c > c {
            self.c = c.max(0.0);
        }
    }

    /// The active lobes: (portal index in the analysis, selection probability).
    pub fn lobes(&self) -> impl Iterator<Item = (u32, f32)> + '_ {
        self.lobes[..self.count]
            .iter()
            .map(|l| (l.portal, l.weight))
    }
}

impl DirectionGuide for PortalQuery {
    fn guiding_probability(&self) -> f32 {
        if self.count > 0 {
            self.c
        } else {
            0.0
        }
    }

    fn sample(&self, u_select: f32, u: Vec2) -> Option<(Vec3, f32)> {
        if self.count == 0 {
            return None;
        }
        let (chosen, _) = pick_lobe(self.lobes[..self.count].iter().map(|l| l.weight), u_select);
        let w = self.lobes[chosen].rect.sample(u);
        let pdf = self.pdf(w);
        (pdf > 0.0 && pdf.is_finite()).then_some((w, pdf))
    }

    fn pdf(&self, w: Vec3) -> f32 {
        self.lobes[..self.count]
            .iter()
            .map(|l| l.weight * l.rect.pdf(w))
            .sum()
    }
}

/// The label of the empty voxel at `p`, or of the nearest empty one among its 26 neighbours.
fn label_near(analysis: &Analysis, p: Vec3) -> Option<u32> {
    if let Some(l) = analysis.label_at(p) {
        return Some(l);
    }
    let h = analysis.grid.voxel_size as f32;
    let mut best: Option<(f32, u32)> = None;
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let d = Vec3::new(dx as f32, dy as f32, dz as f32) * h;
                if let Some(l) = analysis.label_at(p + d) {
                    let len = d.length();
                    if best.map_or(true, |(b, _)| len < b) {
                        best = Some((len, l));
                    }
                }
            }
        }
    }
    best.map(|(_, l)| l)
}

/// Which regions hold a light (module docs, "Build").
fn light_regions(analysis: &Analysis, scene: &Scene) -> Vec<bool> {
    let mut lit = vec![false; analysis.regions.len()];
    let h = analysis.grid.voxel_size as f32;
    let mut outside = false;
    for light in scene.lights() {
        match light {
            Light::Area { p, normal, .. } => {
                for (a, b) in [
                    (1.0 / 3.0, 1.0 / 3.0),
                    (2.0 / 3.0, 1.0 / 6.0),
                    (1.0 / 6.0, 2.0 / 3.0),
                    (1.0 / 6.0, 1.0 / 6.0),
                ] {
                    let q = p[0] * a + p[1] * b + p[2] * (1.0 - a - b);
                    if let Some(l) = label_near(analysis, q + *normal * h) {
                        lit[l as usize] = true;
                    }
                }
            }
            Light::Point { position, .. }
            | Light::Spot { position, .. }
            | Light::Photometric { position, .. }
            // A light-field luminaire's origin lies on its filter plane, in the room it lights.
            | Light::LightField { position, .. } => {
                if let Some(l) = label_near(analysis, *position) {
                    lit[l as usize] = true;
                }
            }
            Light::Directional { .. } | Light::Environment { .. } => outside = true,
        }
    }
    if outside {
        let grid = &analysis.grid;
        for (i, &l) in analysis.labels.iter().enumerate() {
            if l == NO_REGION || lit[l as usize] {
                continue;
            }
            let c = grid.coords(i);
            if (0..3).any(|k| c[k] == 0 || c[k] + 1 == grid.dims[k]) {
                lit[l as usize] = true;
            }
        }
    }
    lit
}

/// A portal's rectangle (module docs, "Build").
fn portal_rectangle(
    analysis: &Analysis,
    portal: &crate::analysis::Portal,
) -> Option<PortalRectangle> {
    let grid = &analysis.grid;
    let mut per_axis = [0usize; 3];
    for f in &portal.faces {
        per_axis[f.axis as usize] += 1;
    }
    let axis = (0..3).max_by_key(|&k| per_axis[k])?;
    let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
    let mut lo = [i64::MAX; 3];
    let mut hi = [i64::MIN; 3];
    let mut plane = 0f64;
    for f in portal.faces.iter().filter(|f| f.axis as usize == axis) {
        let c = grid.coords(f.voxel as usize);
        for k in [ua, va] {
            lo[k] = lo[k].min(c[k] as i64);
            hi[k] = hi[k].max(c[k] as i64 + 1);
        }
        plane += c[axis] as f64 + 1.0;
    }
    plane /= per_axis[axis] as f64;
    let mut g = [0f64; 3];
    g[axis] = plane;
    g[ua] = lo[ua] as f64;
    g[va] = lo[va] as f64;
    let corner = grid.to_world(g);
    let h = grid.voxel_size as f32;
    let mut eu = Vec3::ZERO;
    eu[ua] = (hi[ua] - lo[ua]) as f32 * h;
    let mut ev = Vec3::ZERO;
    ev[va] = (hi[va] - lo[va]) as f32 * h;
    PortalRectangle::new(corner, eu, ev)
}

/// Per region, the portal one step along a shortest path to the nearest light region (None
/// for light regions and regions with no path): multi-source Dijkstra over the region graph.
fn next_portals(
    analysis: &Analysis,
    light: &[bool],
    rectangles: &[Option<PortalRectangle>],
) -> Vec<Option<u32>> {
    let n = analysis.regions.len();
    let mut adjacency: Vec<Vec<(u32, u32, f32)>> = vec![Vec::new(); n];
    for (k, portal) in analysis.portals.iter().enumerate() {
        if rectangles[k].is_none() {
            continue;
        }
        let (a, b) = portal.regions;
        let (ca, cb) = (
            analysis.regions[a as usize].centroid,
            analysis.regions[b as usize].centroid,
        );
        let w = (ca - portal.center).length() + (portal.center - cb).length();
        adjacency[a as usize].push((b, k as u32, w));
        adjacency[b as usize].push((a, k as u32, w));
    }
    #[derive(PartialEq)]
    struct Entry(f32, u32);
    impl Eq for Entry {}
    impl PartialOrd for Entry {
        fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
            Some(self.cmp(other))
        }
    }
    impl Ord for Entry {
        // A min-heap on the distance, ties by region index (deterministic).
        fn cmp(&self, other: &Self) -> std::cmp::Ordering {
            other
                .0
                .total_cmp(&self.0)
                .then_with(|| other.1.cmp(&self.1))
        }
    }
    let mut distance = vec![f32::INFINITY; n];
    let mut next: Vec<Option<u32>> = vec![None; n];
    let mut heap = BinaryHeap::new();
    for (r, &l) in light.iter().enumerate() {
        if l {
            distance[r] = 0.0;
            heap.push(Entry(0.0, r as u32));
        }
    }
    while let Some(Entry(d, r)) = heap.pop() {
        if d > distance[r as usize] {
            continue;
        }
        for &(s, portal, w) in &adjacency[r as usize] {
            let ds = d + w;
            if ds < distance[s as usize] {
                distance[s as usize] = ds;
                next[s as usize] = Some(portal);
                heap.push(Entry(ds, s));
            }
        }
    }
    next
}

/// Per region, the portal of its shortest path (following the next portals) that `aim`
/// names: the last one (into the light's region) or the one of least area.
fn chain_portals(analysis: &Analysis, next: &[Option<u32>], aim: PortalAim) -> Vec<Option<u32>> {
    (0..next.len() as u32)
        .map(|r| {
            let (mut at, mut last) = (r, None::<u32>);
            // The tree has no cycle; the bound only guards against a broken one.
            for _ in 0..next.len() {
                let Some(k) = next[at as usize] else { break };
                let area = |k: u32| analysis.portals[k as usize].area;
                if aim == PortalAim::Last || last.map_or(true, |l| area(k) < area(l)) {
                    last = Some(k);
                }
                let (a, b) = analysis.portals[k as usize].regions;
                at = if a == at { b } else { a };
            }
            last
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_two_rooms_are_guided_toward_the_lit_room() {
        let scene = crate::scene::two_rooms_builder().unwrap().build().unwrap();
        let guide = PortalGuide::build(&scene, &PortalGuideSettings::default(), None, &|_, _| true)
            .unwrap();
        assert!(guide.unguided().is_none(), "{}", guide.note());
        // Every region with a next portal leads, step by step, to a light region.
        for r in 0..guide.analysis.regions.len() as u32 {
            let mut at = r;
            let mut steps = 0;
            while let Some(k) = guide.next[at as usize] {
                let (a, b) = guide.analysis.portals[k as usize].regions;
                at = if a == at { b } else { a };
                steps += 1;
                assert!(steps <= guide.analysis.regions.len(), "a cycle from {r}");
            }
        }
    }

    #[test]
    fn settings_are_validated() {
        let mut s = PortalGuideSettings::default();
        assert!(s.set("c_portal", "1").is_err());
        assert!(s.set("c_portal", "0.3").unwrap());
        assert!(s.set("smoothing", "0").is_err());
        assert!(s.set("resolution", "4").is_err());
        assert!(s.set("strategy", "irradiance").unwrap());
        assert!(s.set("face_mix", "1.5").is_err());
        assert!(s.set("o_t", "1").is_err());
        assert!(s.set("d_t", "-0.1").is_err());
        assert!(s.set("training_paths", "0").is_err());
        assert!(s.set("face_score", "radiance").unwrap());
        assert!(s.set("face_score", "power").is_err());
        assert!(s.set("strategy", "nearest").is_err());
        assert!(!s.set("strength", "2").unwrap());
    }
}
