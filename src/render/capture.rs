//! Baking a modelled luminaire into a light field (`lacuna capture-luminaire`,
//! docs/light-field.md "Capturing a luminaire"): the luminaire is a scene file (its geometry,
//! materials and own emitter) with a `capture` block placing the two planes; every texel of
//! every image is the Monte Carlo estimate of the light field's coefficient, the radiance along
//! each sampled line estimated by the `path` integrator on the luminaire alone.
//!
//! For basis function m (node n_m) and image pixel P, the layout's coefficient is
//! (docs/light-field.md, `LightField::bake`)
//!
//!   C_m(P) = 1/|P| integral_P integral_F E(u -> s) Phi_m(u) / (h_x h_y) du ds,
//!   E(u -> s) = L(u -> s) delta^2 / |s - u|^4 (|s - u| the 3-D distance between the planes),
//!
//! the pixel average of the lumped projection. Drawing s uniformly in P and u with density
//! Phi_m / (h_x h_y) (the B-spline's own inverse CDF) makes the mean of
//! L(u -> s) delta^2 / d^4 an unbiased estimate of it; L(u -> s) is one `path` sample along the
//! ray from s back through u into the luminaire (what leaves the luminaire along that line).

use std::path::Path;
use std::time::Instant;

use rayon::prelude::*;
use serde::Deserialize;

use crate::error::{Error, Result};
use crate::geometry::Ray;
use crate::integrator::{self, IntegratorSettings, SampleContext, TraceCounters, View};
use crate::light::{FilterBasis, LightField, LightFieldLayout};
use crate::math::{
    Frame, PixelSampler, Rgb, SamplerKind, Vec2, Vec3, FILM_DIMENSION, FIRST_INTEGRATOR_DIMENSION,
    LENS_DIMENSION,
};
use crate::scene::{load_scene_file, Camera, Scene};
use crate::workers::WorkerPool;

/// Largest number of paths per texel a capture may ask for.
pub const MAX_CAPTURE_SAMPLES: u32 = 1 << 16;

/// The `capture` block of a luminaire file: the light field's frame in the file's coordinates
/// (as a scene's `light_field` light places it), its layout (the fields of the EXR's
/// attributes) and the path tracing.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CaptureBlock {
    #[serde(default)]
    #[allow(dead_code)]
    comment: Option<serde_json::Value>,
    position: [f32; 3],
    direction: [f32; 3],
    #[serde(default)]
    x_axis: [f32; 3],
    plane_distance: f32,
    nodes: [u32; 2],
    node_min: [f32; 2],
    node_spacing: [f32; 2],
    #[serde(default = "quadratic")]
    basis: String,
    image_min: [f32; 2],
    image_max: [f32; 2],
    resolution: [u32; 2],
    #[serde(default = "default_samples")]
    samples: u32,
    #[serde(default = "default_max_depth")]
    max_depth: u32,
}

fn quadratic() -> String {
    "quadratic".into()
}

fn default_samples() -> u32 {
    64
}

fn default_max_depth() -> u32 {
    16
}

/// The file's top level as the capture reads it: only `capture`; the rest is the scene file's.
#[derive(Deserialize)]
struct LuminaireFile {
    capture: Option<serde_json::Value>,
}

/// How to capture: where the planes are, their layout, paths per texel.
#[derive(Clone, Debug, PartialEq)]
pub struct CaptureSettings {
    /// The light field's local origin (on the filter plane) in the luminaire's coordinates.
    pub position: Vec3,
    /// Where the recorded light travels (the field's +z).
    pub direction: Vec3,
    /// The field's local +x (made perpendicular to `direction`; zero: any).
    pub x_axis: Vec3,
    pub layout: LightFieldLayout,
    /// Paths per texel (per image pixel of each basis function).
    pub samples: u32,
    /// Bounces of the paths inside the luminaire.
    pub max_depth: u32,
    pub seed: u64,
    /// Worker threads (`None`: all cores).
    pub threads: Option<usize>,
}

impl CaptureSettings {
    /// The same span of nodes (first to last node) with `nodes` basis functions per axis.
    pub fn with_nodes(mut self, nodes: [u32; 2]) -> Self {
        for axis in 0..2 {
            let (old, new) = (self.layout.nodes[axis], nodes[axis]);
            if old > 1 && new > 1 {
                self.layout.node_spacing[axis] *= (old - 1) as f32 / (new - 1) as f32;
            }
        }
        self.layout.nodes = nodes;
        self
    }

    pub fn validate(&self) -> Result<()> {
        self.layout.validate()?;
        let finite = |v: Vec3| v.is_finite();
        if !finite(self.position) || !finite(self.x_axis) {
            return Err(Error::invalid("capture position and x_axis must be finite"));
        }
        if !(self.direction.is_finite() && self.direction.length_squared() > 0.0) {
            return Err(Error::invalid(format!(
                "capture direction {} must be finite and not zero",
                self.direction
            )));
        }
        if !(1..=MAX_CAPTURE_SAMPLES).contains(&self.samples) {
            return Err(Error::invalid(format!(
                "capture samples {} must be 1 to {MAX_CAPTURE_SAMPLES}",
                self.samples
            )));
        }
        if !(1..=crate::limits::MAX_DEPTH).contains(&self.max_depth) {
            return Err(Error::invalid(format!(
                "capture max_depth {} must be 1 to {}",
                self.max_depth,
                crate::limits::MAX_DEPTH
            )));
        }
        if let Some(0) = self.threads {
            return Err(Error::invalid("thread count must be at least 1"));
        }
        Ok(())
    }

    /// The frame of the field, as the `light_field` light builds it from the same axes.
    fn frame(&self) -> Frame {
        crate::light::light_field_frame(self.direction, self.x_axis)
    }
}

/// A luminaire loaded from its file: its scene (built) and the capture block's settings.
pub struct Luminaire {
    pub scene: Scene,
    pub settings: CaptureSettings,
}

/// Loads a luminaire file (docs/light-field.md): a scene file with a `capture` block. Syntax
/// and schema errors name the line; an invalid capture value names `capture`; a luminaire
/// without an emitter, or with geometry on the receiver side of the image plane, is refused.
pub fn load_luminaire(path: &Path) -> Result<Luminaire> {
    let loaded = load_scene_file(path)?;
    // The scene file was read and parsed above: the file is JSON of bounded size.
    let bytes = crate::limits::read_file_bounded(
        path,
        "luminaire file",
        crate::limits::MAX_SCENE_FILE_BYTES,
    )?;
    let text = String::from_utf8_lossy(&bytes);
    let text = text.trim_start_matches('\u{feff}');
    let file: LuminaireFile =
        serde_json::from_str(text).map_err(|e| crate::scene::json_error(path, &e))?;
    let Some(block) = file.capture else {
        return Err(Error::parse(
            path,
            "capture",
            "missing: a luminaire file is a scene file with a \"capture\" object placing the light field's planes (docs/light-field.md)",
        ));
    };
    let block: CaptureBlock =
        serde_json::from_value(block).map_err(|e| Error::parse(path, "capture", e.to_string()))?;
    let invalid = |e: Error| match e {
        Error::InvalidArgument(m) => Error::parse(path, "capture", m),
        other => other,
    };
    let settings = CaptureSettings {
        position: Vec3::from(block.position),
        direction: Vec3::from(block.direction),
        x_axis: Vec3::from(block.x_axis),
        layout: LightFieldLayout {
            nodes: block.nodes,
            node_min: Vec2::from(block.node_min),
            node_spacing: Vec2::from(block.node_spacing),
            basis: FilterBasis::parse(&block.basis).map_err(invalid)?,
            plane_distance: block.plane_distance,
            image_min: Vec2::from(block.image_min),
            image_max: Vec2::from(block.image_max),
            resolution: block.resolution,
        },
        samples: block.samples,
        max_depth: block.max_depth,
        seed: 0,
        threads: None,
    };
    settings.validate().map_err(invalid)?;
    let scene = loaded.builder.build().map_err(|e| match e {
        Error::InvalidArgument(m) => Error::parse(path, "", m),
        other => other,
    })?;
    check_luminaire(&scene, &settings).map_err(|m| Error::parse(path, "", m))?;
    Ok(Luminaire { scene, settings })
}

/// A luminaire must emit, and all of it must lie before the image plane (local z < delta):
/// the capture traces from the image plane backwards, and the field lights only what lies
/// beyond it.
fn check_luminaire(scene: &Scene, settings: &CaptureSettings) -> std::result::Result<(), String> {
    if scene.lights().is_empty() {
        return Err("the luminaire has no emitter (give a shape an emissive material)".into());
    }
    // Paths reach a point or spot light only by light sampling, which mirrors and glass
    // block: their reflections and refractions would be missing from the field.
    if scene
        .lights()
        .iter()
        .any(|l| !matches!(l, crate::light::Light::Area { .. }))
    {
        return Err("a luminaire's emitters must be emissive shapes, not lights: paths find point, spot, directional and photometric lights only by light sampling, which the luminaire's mirrors and glass block".into());
    }
    if scene.environment().is_some() {
        return Err(
            "a luminaire file must not have an environment (it would be baked into the field)"
                .into(),
        );
    }
    let frame = settings.frame();
    let delta = settings.layout.plane_distance;
    let mut furthest = f32::NEG_INFINITY;
    for tri in 0..scene.triangle_count() as u32 {
        for p in scene.triangle_vertices(tri) {
            furthest = furthest.max(frame.to_local(p - settings.position).z);
        }
    }
    if furthest >= delta {
        return Err(format!(
            "the luminaire reaches {furthest} along the capture direction, past the image plane at plane_distance {delta}: move the planes or raise plane_distance"
        ));
    }
    Ok(())
}

/// What a capture cost.
#[derive(Clone, Debug)]
pub struct CaptureStats {
    pub seconds: f64,
    /// Paths traced (texels x samples) and rays they shot.
    pub paths: u64,
    pub rays: u64,
    /// The light field's memory once built (images, luminance, summed-area tables).
    pub field_bytes: usize,
    /// The luminaire scene's memory (meshes, BVH, lights).
    pub scene_bytes: usize,
}

/// Bakes the light field of `scene` (the luminaire) with `settings`.
pub fn capture(scene: &Scene, settings: &CaptureSettings) -> Result<(LightField, CaptureStats)> {
    settings.validate()?;
    let start = Instant::now();
    let integrator = integrator::create(
        "path",
        IntegratorSettings {
            max_depth: settings.max_depth,
            ..Default::default()
        },
    )?;
    let layout = &settings.layout;
    let frame = settings.frame();
    let to_world = |local: Vec3| settings.position + frame.to_world(local);
    let delta = layout.plane_distance;
    let (rx, ry) = (layout.resolution[0], layout.resolution[1]);
    let pixel_size = (layout.image_max - layout.image_min) / Vec2::new(rx as f32, ry as f32);
    let per_image = layout.pixels_per_image();
    // The path tracer reads the view only for per-pixel state `path` does not keep by default;
    // any view serves.
    let camera = Camera::look_at(Vec3::ZERO, Vec3::Z, Vec3::Y, 45.0)?;
    let view = View {
        frame: camera.frame(1.0),
        width: rx,
        height: ry,
        sampler: Default::default(),
    };
    let pool = WorkerPool::new(settings.threads, Some("capture"))
        .map_err(|e| Error::invalid(format!("worker pool: {e}")))?;
    // One work item per image row of one basis function: images x rows items.
    let rows: Vec<(Vec<Rgb>, u64)> = pool.install(|| {
        (0..layout.image_count() * ry as usize)
            .into_par_iter()
            .map(|item| {
                let (m, y) = (item / ry as usize, (item % ry as usize) as u32);
                let (i, j) = (m as u32 % layout.nodes[0], m as u32 / layout.nodes[0]);
                let node = layout.node_point(i, j);
                let mut counters = TraceCounters::default();
                let mut row = Vec::with_capacity(rx as usize);
                for x in 0..rx {
                    let texel = (m * per_image) as u64 + y as u64 * rx as u64 + x as u64;
                    let pixel_sampler = PixelSampler::new(SamplerKind::Sobol, settings.seed, texel);
                    let corner = layout.image_min + pixel_size * Vec2::new(x as f32, y as f32);
                    let mut sum = [0f64; 3];
                    for k in 0..settings.samples {
                        let mut rng = pixel_sampler.sample(k);
                        rng.set_dimension(FILM_DIMENSION);
                        let s = corner + pixel_size * rng.uniform2();
                        rng.set_dimension(LENS_DIMENSION);
                        let t = rng.uniform2();
                        let u = node
                            + layout.node_spacing
                                * Vec2::new(layout.basis.sample(t.x), layout.basis.sample(t.y));
                        rng.set_dimension(FIRST_INTEGRATOR_DIMENSION);
                        let from = to_world(Vec3::new(s.x, s.y, delta));
                        let through = to_world(Vec3::new(u.x, u.y, 0.0));
                        let Some(dir) = (through - from).try_normalize() else {
                            continue;
                        };
                        let ctx = SampleContext {
                            pixel_index: texel,
                            sample_index: k,
                            view: &view,
                            iteration: None,
                            layers: &[],
                        };
                        let ray = Ray::new(from, dir, f32::INFINITY);
                        let radiance = integrator
                            .sample(scene, ray, &mut rng, &mut counters, &ctx)
                            .radiance;
                        if !radiance.is_finite() {
                            continue;
                        }
                        let d2 = (s - u).length_squared() + delta * delta;
                        let w = (delta * delta / (d2 * d2)) as f64;
                        for c in 0..3 {
                            sum[c] += radiance[c] as f64 * w;
                        }
                    }
                    let n = settings.samples as f64;
                    row.push(Rgb::new(
                        (sum[0] / n) as f32,
                        (sum[1] / n) as f32,
                        (sum[2] / n) as f32,
                    ));
                }
                (row, counters.rays)
            })
            .collect()
    });
    let mut pixels = Vec::with_capacity(layout.image_count() * per_image);
    let mut rays = 0;
    for (row, r) in rows {
        pixels.extend(row);
        rays += r;
    }
    let field = LightField::new(layout.clone(), pixels).map_err(|e| {
        Error::invalid(format!(
            "the capture recorded no light ({e}): do the planes face the luminaire's opening?"
        ))
    })?;
    let stats = CaptureStats {
        seconds: start.elapsed().as_secs_f64(),
        paths: (layout.image_count() * per_image) as u64 * settings.samples as u64,
        rays,
        field_bytes: field.memory_bytes(),
        scene_bytes: scene.memory().total(),
    };
    Ok((field, stats))
}
