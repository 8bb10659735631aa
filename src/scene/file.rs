//! Lacuna's JSON scene files (documented in `docs/scene-format.md`): OBJ files to load with
//! optional transforms, inline shapes (quads, disks, spheres; for emitters the OBJ files lack),
//! a camera, lights, material overrides by name and render settings. Every object is strict
//! (`deny_unknown_fields`), so a misspelt field is an error rather than silently ignored.
//!
//! [`load_scene_file`] fills a [`SceneBuilder`] and returns it with the render settings; the
//! caller builds. Paths in the file are relative to the file's folder.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Mat4, Vec4};
use serde::{Deserialize, Deserializer, Serialize};

use super::obj::{load_obj, ObjReport};
use super::{Camera, Material, MaterialKind, MeshDesc, SceneBuilder, Texture};
use crate::error::{Error, Result};
use crate::geometry::Bounds3;
use crate::light::environment::{EnvImage, Grid};
use crate::light::{
    EnvSettings, EnvironmentMap, LightDesc, LightField, PhotometricProfile, UpAxis,
};
use crate::math::{Frame, Rgb, Vec2, Vec3, PI};

/// Render settings a scene file may carry; every field is optional (the caller decides the
/// defaults and command-line overrides).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderSettingsFile {
    pub width: Option<u32>,
    pub height: Option<u32>,
    /// Samples per pixel.
    pub spp: Option<u32>,
    /// Maximum number of bounces.
    pub max_depth: Option<u32>,
    /// Integrator name (e.g. "path").
    pub integrator: Option<String>,
    pub seed: Option<u64>,
    /// Pixel sampler: "sobol" (the default) or "independent".
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sampler: Option<String>,
    /// Time budget in seconds (render until it runs out instead of a fixed spp).
    pub time: Option<f64>,
    /// Options of `path_skeleton`'s guide by name (`c_skel`, `strength`, `resolution`, ...:
    /// see `guide::SkeletonGuideSettings::set`), numbers, strings or booleans. Kept raw: the
    /// integrator settings validate them where they are applied
    /// (`integrator::IntegratorSettings::apply_file`), naming this file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub skeleton: Option<BTreeMap<String, serde_json::Value>>,
    /// Options of the vertex-connection resampling of `bdpt_skeleton` and `bdpt_ic` by name
    /// (`subset`, `accept`, `images`, `density`, `count`: see `guide::ResamplingSettings::set`), kept
    /// raw as `skeleton` is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resampling: Option<BTreeMap<String, serde_json::Value>>,
    /// The scene file these settings came from (none for built-in scenes), so that an error
    /// in an option found when it is applied names the file.
    #[serde(skip)]
    pub source: Option<PathBuf>,
}

/// Options of an object as (key, text) pairs, in key order.
fn options_as_text(map: &Option<BTreeMap<String, serde_json::Value>>) -> Vec<(String, String)> {
    map.iter()
        .flatten()
        .map(|(k, v)| {
            let text = match v {
                serde_json::Value::String(s) => s.clone(),
                other => other.to_string(),
            };
            (k.clone(), text)
        })
        .collect()
}

impl RenderSettingsFile {
    /// The `skeleton` options as (key, text) pairs, in key order.
    pub fn skeleton_options(&self) -> Vec<(String, String)> {
        options_as_text(&self.skeleton)
    }

    /// The `resampling` options as (key, text) pairs, in key order.
    pub fn resampling_options(&self) -> Vec<(String, String)> {
        options_as_text(&self.resampling)
    }
}

/// A scene file loaded into a builder, not yet built.
pub struct LoadedScene {
    pub builder: SceneBuilder,
    pub settings: RenderSettingsFile,
    /// Non-fatal problems of the scene file and of the OBJ files it loaded.
    pub warnings: Vec<String>,
    /// What each OBJ file added, in file order.
    pub objects: Vec<ObjReport>,
}

// ---------------------------------------------------------------------------------------------
// The file's schema.

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    /// Free text (or anything): ignored. JSON has no comments.
    #[serde(default)]
    #[allow(dead_code)]
    comment: Option<serde_json::Value>,
    #[serde(default)]
    objects: Vec<ObjectSpec>,
    #[serde(default)]
    shapes: Vec<ShapeSpec>,
    camera: Option<CameraSpec>,
    #[serde(default)]
    lights: Vec<LightSpec>,
    environment: Option<EnvironmentSpec>,
    /// Window portals for `env=portals`, listed by hand (then none is searched for).
    #[serde(default)]
    portals: Vec<PortalSpec>,
    /// Whether `env=portals` may find window portals from the analysis when none is listed.
    #[serde(default = "yes")]
    auto_portals: bool,
    #[serde(default)]
    materials: BTreeMap<String, MaterialSpec>,
    #[serde(default)]
    render: RenderSettingsFile,
    /// A luminaire file's placement of its light field's planes, read by
    /// `lacuna capture-luminaire` (docs/light-field.md); rendering ignores it, so a luminaire
    /// file renders as a scene.
    #[serde(default)]
    #[allow(dead_code)]
    capture: Option<serde_json::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ObjectSpec {
    #[serde(default)]
    #[allow(dead_code)]
    comment: Option<serde_json::Value>,
    /// Path of the OBJ file, relative to the scene file.
    obj: String,
    transform: Option<TransformSpec>,
}

/// Either `matrix` alone, or any of `scale`, `rotate`, `translate` (applied in that order).
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct TransformSpec {
    translate: Option<[f32; 3]>,
    rotate: Option<RotateSpec>,
    scale: Option<ScaleSpec>,
    /// Row-major 4x4 matrix applied to column vectors (translation in the last column).
    matrix: Option<[[f32; 4]; 4]>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RotateSpec {
    axis: [f32; 3],
    degrees: f32,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum ScaleSpec {
    Uniform(f32),
    PerAxis([f32; 3]),
}

/// A colour: `[r, g, b]` or one number for grey.
#[derive(Deserialize, Clone, Copy)]
#[serde(untagged)]
enum Colour {
    Grey(f32),
    Rgb([f32; 3]),
}

impl Colour {
    fn rgb(self) -> Rgb {
        match self {
            Colour::Grey(v) => Rgb::splat(v),
            Colour::Rgb(c) => Rgb::from(c),
        }
    }
}

/// A window portal: `corner` + s `edge_u` + t `edge_v` (s, t in [0, 1]), the environment on
/// its `outward` side.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PortalSpec {
    corner: [f32; 3],
    edge_u: [f32; 3],
    edge_v: [f32; 3],
    outward: [f32; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraSpec {
    eye: [f32; 3],
    target: [f32; 3],
    #[serde(default = "default_up")]
    up: [f32; 3],
    /// Vertical field of view in degrees.
    fov: f32,
    lens_radius: Option<f32>,
    focus_distance: Option<f32>,
}

fn default_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
enum LightSpec {
    Point {
        position: [f32; 3],
        intensity: Colour,
    },
    Spot {
        position: [f32; 3],
        direction: [f32; 3],
        intensity: Colour,
        inner_degrees: f32,
        outer_degrees: f32,
    },
    Directional {
        direction: [f32; 3],
        irradiance: Colour,
    },
    /// A measured luminaire from an IES LM-63 or EULUMDAT file (relative to the scene file):
    /// radiant intensity `intensity` times the file's candela. `direction` is where the
    /// profile's nadir points, `c0` the axis of its C0 plane (optional).
    #[serde(alias = "ies")]
    Photometric {
        file: PathBuf,
        position: [f32; 3],
        direction: [f32; 3],
        #[serde(default)]
        c0: [f32; 3],
        #[serde(default = "white")]
        intensity: Colour,
    },
    /// A light-field luminaire from an EXR mosaic (docs/light-field.md; relative to the scene
    /// file): its local origin at `position`, light travelling along `direction`, its local x
    /// axis toward `x_axis` (optional), radiance times `scale`.
    #[serde(rename = "light_field")]
    LightField {
        file: PathBuf,
        position: [f32; 3],
        direction: [f32; 3],
        #[serde(default)]
        x_axis: [f32; 3],
        #[serde(default = "white")]
        scale: Colour,
    },
}

fn white() -> Colour {
    Colour::Grey(1.0)
}

/// An environment map: `file` (.exr or .hdr, 2:1 lat-long or 4:3 horizontal cross).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct EnvironmentSpec {
    file: PathBuf,
    #[serde(default = "one")]
    scale: f32,
    /// Degrees about the up axis.
    #[serde(default)]
    rotate: f32,
    /// "y" or "z".
    #[serde(default = "default_env_up")]
    up: String,
    #[serde(default = "yes")]
    visible: bool,
    /// Resample to "latlong" or "cube" after loading.
    layout: Option<String>,
}

fn one() -> f32 {
    1.0
}

fn yes() -> bool {
    true
}

fn default_env_up() -> String {
    "y".into()
}

impl EnvironmentSpec {
    fn load(&self, dir: &Path) -> Result<EnvironmentMap> {
        let settings = EnvSettings {
            scale: self.scale,
            rotate_degrees: self.rotate,
            up: UpAxis::parse(&self.up)?,
            visible: self.visible,
        };
        settings.validate()?;
        let mut image = EnvImage::load(&dir.join(&self.file))?;
        if let Some(layout) = &self.layout {
            image = convert_layout(&image, layout)?;
        }
        EnvironmentMap::new(image, settings)
    }
}

/// Resamples an environment image to "latlong" (4F x 2F for faces of F) or "cube" (faces of
/// width / 4); the same layout is returned unchanged.
pub fn convert_layout(image: &EnvImage, layout: &str) -> Result<EnvImage> {
    let grid = image.grid();
    let target = match (layout, grid) {
        ("latlong", Grid::LatLong { .. }) | ("cube", Grid::Cube { .. }) => return Ok(image.clone()),
        ("latlong", Grid::Cube { face }) => Grid::LatLong {
            width: 4 * face,
            height: 2 * face,
        },
        ("cube", Grid::LatLong { width, .. }) => Grid::Cube {
            face: (width / 4).max(1),
        },
        (other, _) => {
            return Err(Error::invalid(format!(
                "environment layout '{other}' must be latlong or cube"
            )))
        }
    };
    image.convert(target)
}

#[derive(Deserialize, Clone, Copy)]
#[serde(rename_all = "lowercase")]
enum KindSpec {
    Diffuse,
    Glossy,
    Mirror,
    Dielectric,
    #[serde(rename = "rough_dielectric")]
    RoughDielectric,
}

/// Material fields, all optional: an override changes only the fields it gives.
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct MaterialSpec {
    /// For shapes: the material's name (overrides can then target it too).
    name: Option<String>,
    kind: Option<KindSpec>,
    diffuse: Option<Colour>,
    /// Image path relative to the scene file; `null` removes the texture.
    #[serde(default, deserialize_with = "present")]
    diffuse_texture: Option<Option<String>>,
    specular: Option<Colour>,
    exponent: Option<f32>,
    ior: Option<f32>,
    roughness: Option<f32>,
    emission: Option<Colour>,
}

/// Distinguishes an absent field (`None`) from an explicit `null` (`Some(None)`).
fn present<'de, D: Deserializer<'de>>(
    d: D,
) -> std::result::Result<Option<Option<String>>, D::Error> {
    Option::<String>::deserialize(d).map(Some)
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
enum ShapeSpec {
    /// Four corners, counter-clockwise seen from the front; `normal` (optional) picks the
    /// front side instead.
    Quad {
        name: Option<String>,
        corners: [[f32; 3]; 4],
        normal: Option<[f32; 3]>,
        #[serde(default)]
        material: MaterialSpec,
    },
    /// A flat disk facing `normal`, as a polygon of `segments` sides with the disk's area.
    Disk {
        name: Option<String>,
        center: [f32; 3],
        normal: [f32; 3],
        radius: f32,
        segments: Option<u32>,
        #[serde(default)]
        material: MaterialSpec,
    },
    /// A sphere with outward-facing triangles (`segments` around the equator).
    Sphere {
        name: Option<String>,
        center: [f32; 3],
        radius: f32,
        segments: Option<u32>,
        #[serde(default)]
        material: MaterialSpec,
    },
}

// ---------------------------------------------------------------------------------------------
// Loading.

/// A scene as a command line names it: a built-in scene (`two-rooms`, `corridor`, a family
/// scene `rooms:SEED`) unless a
/// file of that name exists, an `.obj` file (no camera, no settings), or a `.json` scene file.
/// Returns the loaded scene and a label for messages; one place for the `lacuna` command and
/// the examples.
pub fn load_scene_arg(path: &Path) -> Result<(LoadedScene, String)> {
    let builtin = |builder, settings| LoadedScene {
        builder,
        settings,
        warnings: Vec::new(),
        objects: Vec::new(),
    };
    if !path.exists() {
        match path.to_str() {
            Some("two-rooms") => {
                let scene = builtin(super::two_rooms_builder()?, RenderSettingsFile::default());
                return Ok((scene, "two-rooms".into()));
            }
            Some("interior") => {
                let scene = builtin(super::interior_builder()?, RenderSettingsFile::default());
                return Ok((scene, "interior".into()));
            }
            Some(name) if name.starts_with("interior:windows=") => {
                let count = name["interior:windows=".len()..]
                    .parse::<usize>()
                    .map_err(|_| {
                        Error::invalid(format!("{name}: the window count must be an integer"))
                    })?;
                let scene = builtin(
                    super::interior_many_windows_builder(count)?,
                    RenderSettingsFile::default(),
                );
                return Ok((scene, name.to_string()));
            }
            Some("corridor") => {
                let scene = builtin(
                    super::corridor_builder()?,
                    super::corridor_render_settings(),
                );
                return Ok((scene, "corridor".into()));
            }
            Some(name) => {
                if let Some(seed) = super::parse_family_name(name) {
                    let family = super::FamilyScene::generate(seed);
                    let scene = builtin(family.builder()?, RenderSettingsFile::default());
                    return Ok((scene, name.into()));
                }
            }
            None => {}
        }
    }
    let label = path.display().to_string();
    let extension = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match extension.as_deref() {
        Some("obj") => {
            let mut builder = SceneBuilder::new();
            let report = load_obj(path, &mut builder, None)?;
            let scene = LoadedScene {
                builder,
                settings: RenderSettingsFile::default(),
                warnings: report.warnings.clone(),
                objects: vec![report],
            };
            Ok((scene, label))
        }
        Some("json") => Ok((load_scene_file(path)?, label)),
        _ => Err(Error::invalid(format!(
            "scene {label}: expected an .obj or .json file, or a built-in scene (two-rooms, corridor, interior, rooms:SEED)"
        ))),
    }
}

/// Loads a JSON scene file into a builder. Syntax and schema errors give [`Error::Parse`] with
/// `line L column C` and serde's message (which names the field); invalid values give
/// [`Error::Parse`] with the field path as location (e.g. `lights[1]`); OBJ problems come from
/// [`load_obj`]. Without a camera, [`auto_camera`] frames the scene (with a warning).
pub fn load_scene_file(path: &Path) -> Result<LoadedScene> {
    let bytes =
        crate::limits::read_file_bounded(path, "scene file", crate::limits::MAX_SCENE_FILE_BYTES)?;
    // A byte-order mark (written by some editors) is not JSON, but says nothing wrong.
    let bytes = super::obj::strip_bom(&bytes);
    let text = std::str::from_utf8(bytes).map_err(|e| {
        let at = e.valid_up_to();
        let line = 1 + bytes[..at].iter().filter(|&&b| b == b'\n').count();
        Error::parse(
            path,
            format!("line {line}"),
            format!("not UTF-8 text (invalid byte at offset {at}): a scene file is JSON"),
        )
    })?;
    let file: SceneFile = serde_json::from_str(text).map_err(|e| json_error(path, &e))?;
    let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    // Invalid values become parse errors located in the scene file; I/O and parse errors of
    // the files it names (OBJ, MTL, textures) keep their own path.
    let fail = |loc: String, e: Error| match e {
        Error::InvalidArgument(m) => Error::parse(path, loc, m),
        other => other,
    };

    let mut settings = file.render;
    settings.source = Some(path.to_path_buf());
    check_settings(&settings).map_err(|(loc, msg)| Error::parse(path, loc, msg))?;

    let mut builder = SceneBuilder::new();
    let mut warnings = Vec::new();
    let mut objects = Vec::new();
    let mut bounds = Bounds3::EMPTY;
    // Every named material, for the overrides.
    let mut named: Vec<(String, u32)> = Vec::new();
    let mut textures: HashMap<PathBuf, u32> = HashMap::new();

    for (i, o) in file.objects.iter().enumerate() {
        let transform = match &o.transform {
            Some(t) => Some(
                t.matrix()
                    .map_err(|m| Error::parse(path, format!("objects[{i}].transform"), m))?,
            ),
            None => None,
        };
        let obj_path = dir.join(&o.obj);
        let report = load_obj(&obj_path, &mut builder, transform)
            .map_err(|e| fail(format!("objects[{i}]"), e))?;
        bounds = bounds.union(report.bounds);
        named.extend(report.materials.iter().cloned());
        warnings.extend(report.warnings.iter().cloned());
        objects.push(report);
    }

    let mut shape_triangles = 0u64;
    for (i, s) in file.shapes.iter().enumerate() {
        shape_triangles += s.triangle_count();
        let limit = crate::limits::MAX_SHAPE_TRIANGLES;
        if shape_triangles > limit {
            return Err(Error::parse(
                path,
                format!("shapes[{i}]"),
                format!("shapes[0..={i}] make {shape_triangles} triangles, over the limit of {limit} for the inline shapes of a scene file"),
            ));
        }
    }
    for (i, s) in file.shapes.iter().enumerate() {
        let loc = format!("shapes[{i}]");
        let (desc, spec) = shape_mesh(s, i).map_err(|m| Error::parse(path, loc.clone(), m))?;
        let mut material = Material {
            name: spec.name.clone().unwrap_or_else(|| format!("shape {i}")),
            ..Material::default()
        };
        apply_material(&mut material, spec, &dir, &mut builder, &mut textures)
            .map_err(|e| fail(format!("{loc}.material"), e))?;
        let name = material.name.clone();
        let m = builder
            .add_material(material)
            .map_err(|e| fail(format!("{loc}.material"), e))?;
        named.push((name, m));
        for p in &desc.positions {
            bounds = bounds.union_point(*p);
        }
        builder
            .add_mesh(MeshDesc {
                materials: vec![m],
                ..desc
            })
            .map_err(|e| fail(loc.clone(), e))?;
    }

    for (name, spec) in &file.materials {
        let loc = format!("materials.{name}");
        let targets: Vec<u32> = named
            .iter()
            .filter(|(n, _)| n == name)
            .map(|&(_, i)| i)
            .collect();
        if targets.is_empty() {
            return Err(Error::parse(
                path,
                loc,
                format!("no loaded material is named '{name}'"),
            ));
        }
        if spec.kind.is_some() || spec.diffuse.is_some() || spec.specular.is_some() {
            // The loader's notes on this material's colours no longer apply.
            let prefix = format!("material '{name}': K");
            warnings.retain(|w| !w.starts_with(&prefix));
        }
        for idx in targets {
            let mut m = builder.materials_mut()[idx as usize].clone();
            apply_material(&mut m, spec, &dir, &mut builder, &mut textures)
                .map_err(|e| fail(loc.clone(), e))?;
            builder
                .set_material(idx, m)
                .map_err(|e| fail(loc.clone(), e))?;
        }
    }

    for (i, l) in file.lights.iter().enumerate() {
        let desc = l.desc(&dir).map_err(|e| fail(format!("lights[{i}]"), e))?;
        builder
            .add_light(desc)
            .map_err(|e| fail(format!("lights[{i}]"), e))?;
    }

    let mut listed = Vec::with_capacity(file.portals.len());
    for (i, p) in file.portals.iter().enumerate() {
        let v = |a: [f32; 3]| Vec3::new(a[0], a[1], a[2]);
        let portal = crate::light::environment::Portal::new(
            v(p.corner),
            v(p.edge_u),
            v(p.edge_v),
            v(p.outward),
        )
        .map_err(|e| fail(format!("portals[{i}]"), e))?;
        listed.push(portal);
    }
    if listed.len() > crate::light::environment::MAX_PORTALS {
        return Err(fail(
            "portals".into(),
            Error::invalid(format!(
                "{} portals: at most {} are supported",
                listed.len(),
                crate::light::environment::MAX_PORTALS
            )),
        ));
    }
    builder.set_portals(super::PortalSettings {
        listed,
        automatic: file.auto_portals,
    });

    if let Some(e) = &file.environment {
        let map = e.load(&dir).map_err(|e| fail("environment".into(), e))?;
        if map.image().clamped() > 0 {
            warnings.push(format!(
                "{}: environment map {}: {} negative texel values clamped to 0",
                path.display(),
                e.file.display(),
                map.image().clamped()
            ));
        }
        builder.set_environment(Some(std::sync::Arc::new(map)));
    }

    match &file.camera {
        Some(c) => {
            let camera = c.camera().map_err(|e| fail("camera".into(), e))?;
            builder
                .set_camera(camera)
                .map_err(|e| fail("camera".into(), e))?;
        }
        None => {
            let aspect = match (settings.width, settings.height) {
                (Some(w), Some(h)) => w as f32 / h as f32,
                _ => 1.0,
            };
            builder.set_camera(auto_camera(bounds, aspect))?;
            warnings.push(format!(
                "{}: no camera given; framed the scene automatically",
                path.display()
            ));
        }
    }

    Ok(LoadedScene {
        builder,
        settings,
        warnings,
        objects,
    })
}

/// A serde_json error as `Error::Parse` with "line L column C" and the message alone.
pub(crate) fn json_error(path: &Path, e: &serde_json::Error) -> Error {
    let full = e.to_string();
    let suffix = format!(" at line {} column {}", e.line(), e.column());
    let message = full.strip_suffix(&suffix).unwrap_or(&full).to_string();
    Error::parse(
        path,
        format!("line {} column {}", e.line(), e.column()),
        message,
    )
}

fn check_settings(s: &RenderSettingsFile) -> std::result::Result<(), (String, String)> {
    let positive = |name: &str, v: Option<u32>, max: u32| match v {
        Some(v) if v == 0 || v > max => Err((
            format!("render.{name}"),
            format!("{name} {v} must be in 1..={max}"),
        )),
        _ => Ok(()),
    };
    positive("width", s.width, 1 << 16)?;
    positive("height", s.height, 1 << 16)?;
    positive("spp", s.spp, u32::MAX)?;
    if let Some(t) = s.time {
        if !(t > 0.0 && t.is_finite()) {
            return Err((
                "render.time".into(),
                format!("time {t} must be a positive number of seconds"),
            ));
        }
    }
    if let Some(name) = &s.sampler {
        crate::math::SamplerKind::parse(name)
            .map_err(|e| ("render.sampler".to_string(), e.to_string()))?;
    }
    if let Some(i) = &s.integrator {
        if i.is_empty() {
            return Err((
                "render.integrator".into(),
                "integrator name is empty".into(),
            ));
        }
    }
    Ok(())
}

impl TransformSpec {
    fn matrix(&self) -> std::result::Result<Mat4, String> {
        let m = if let Some(rows) = self.matrix {
            if self.translate.is_some() || self.rotate.is_some() || self.scale.is_some() {
                return Err("give either matrix or translate/rotate/scale, not both".into());
            }
            if rows[3] != [0.0, 0.0, 0.0, 1.0] {
                return Err(format!(
                    "matrix must be affine: last row {:?} should be [0, 0, 0, 1]",
                    rows[3]
                ));
            }
            Mat4::from_cols_array_2d(&rows).transpose()
        } else {
            let s = match self.scale {
                None => Vec3::ONE,
                Some(ScaleSpec::Uniform(s)) => Vec3::splat(s),
                Some(ScaleSpec::PerAxis(s)) => Vec3::from(s),
            };
            let r = match &self.rotate {
                None => Mat4::IDENTITY,
                Some(r) => {
                    let axis = Vec3::from(r.axis);
                    if !(axis.is_finite() && axis.length_squared() > 0.0 && r.degrees.is_finite()) {
                        return Err(format!(
                            "rotate axis {axis} must be finite and non-zero and degrees finite"
                        ));
                    }
                    Mat4::from_axis_angle(axis.normalize(), r.degrees.to_radians())
                }
            };
            let t = Vec3::from(self.translate.unwrap_or([0.0; 3]));
            Mat4::from_translation(t) * r * Mat4::from_scale(s)
        };
        if !m.is_finite() || m.row(3) != Vec4::W {
            return Err(format!("transform {m} must be finite and affine"));
        }
        crate::limits::check_transform_scale(glam::Mat3::from_mat4(m))?;
        Ok(m)
    }
}

impl CameraSpec {
    fn camera(&self) -> Result<Camera> {
        let c = Camera::look_at(
            Vec3::from(self.eye),
            Vec3::from(self.target),
            Vec3::from(self.up),
            self.fov,
        )?;
        if self.lens_radius.is_some() || self.focus_distance.is_some() {
            let lens = self.lens_radius.unwrap_or(0.0);
            let focus = self.focus_distance.unwrap_or(c.focus_distance);
            return c.with_thin_lens(lens, focus);
        }
        Ok(c)
    }
}

impl LightSpec {
    /// The light, with any file it names read relative to `dir`.
    fn desc(&self, dir: &Path) -> Result<LightDesc> {
        Ok(match *self {
            LightSpec::Point {
                position,
                intensity,
            } => LightDesc::Point {
                position: Vec3::from(position),
                intensity: intensity.rgb(),
            },
            LightSpec::Spot {
                position,
                direction,
                intensity,
                inner_degrees,
                outer_degrees,
            } => LightDesc::Spot {
                position: Vec3::from(position),
                direction: Vec3::from(direction),
                intensity: intensity.rgb(),
                inner_degrees,
                outer_degrees,
            },
            LightSpec::Directional {
                direction,
                irradiance,
            } => LightDesc::Directional {
                direction: Vec3::from(direction),
                irradiance: irradiance.rgb(),
            },
            LightSpec::Photometric {
                ref file,
                position,
                direction,
                c0,
                intensity,
            } => LightDesc::Photometric {
                position: Vec3::from(position),
                direction: Vec3::from(direction),
                c0: Vec3::from(c0),
                intensity: intensity.rgb(),
                profile: Arc::new(PhotometricProfile::from_file(&dir.join(file))?),
            },
            LightSpec::LightField {
                ref file,
                position,
                direction,
                x_axis,
                scale,
            } => LightDesc::LightField {
                position: Vec3::from(position),
                direction: Vec3::from(direction),
                x_axis: Vec3::from(x_axis),
                scale: scale.rgb(),
                field: Arc::new(LightField::from_file(&dir.join(file))?),
            },
        })
    }
}

/// Changes the fields `spec` gives. Textures are loaded once per path (relative to `dir`).
fn apply_material(
    m: &mut Material,
    spec: &MaterialSpec,
    dir: &Path,
    builder: &mut SceneBuilder,
    textures: &mut HashMap<PathBuf, u32>,
) -> Result<()> {
    if let Some(n) = &spec.name {
        m.name = n.clone();
    }
    if let Some(k) = spec.kind {
        m.kind = match k {
            KindSpec::Diffuse => MaterialKind::Diffuse,
            KindSpec::Glossy => MaterialKind::Glossy,
            KindSpec::Mirror => MaterialKind::Mirror,
            KindSpec::Dielectric => MaterialKind::Dielectric,
            KindSpec::RoughDielectric => MaterialKind::RoughDielectric,
        };
    }
    if let Some(c) = spec.diffuse {
        m.diffuse = c.rgb();
    }
    match &spec.diffuse_texture {
        None => {}
        Some(None) => m.diffuse_texture = None,
        Some(Some(file)) => {
            let full = dir.join(file);
            let idx = match textures.get(&full) {
                Some(&i) => i,
                None => {
                    let i = builder.add_texture(Texture::load(&full)?);
                    textures.insert(full, i);
                    i
                }
            };
            m.diffuse_texture = Some(idx);
        }
    }
    if let Some(c) = spec.specular {
        m.specular = c.rgb();
    }
    if let Some(e) = spec.exponent {
        m.exponent = e;
    }
    if let Some(i) = spec.ior {
        m.ior = i;
    }
    if let Some(r) = spec.roughness {
        m.roughness = r;
    }
    if let Some(c) = spec.emission {
        m.emission = c.rgb();
    }
    Ok(())
}

fn finite3(v: [f32; 3], what: &str) -> std::result::Result<Vec3, String> {
    let v = Vec3::from(v);
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("{what} {v} must be finite"))
    }
}

fn unit3(v: [f32; 3], what: &str) -> std::result::Result<Vec3, String> {
    let v = finite3(v, what)?;
    if v.length_squared() == 0.0 {
        return Err(format!("{what} must be non-zero"));
    }
    Ok(v.normalize())
}

fn positive(v: f32, what: &str) -> std::result::Result<f32, String> {
    if v > 0.0 && v.is_finite() {
        Ok(v)
    } else {
        Err(format!("{what} {v} must be positive"))
    }
}

/// The triangles of an inline shape (material left to the caller) and its material spec.
impl ShapeSpec {
    /// Triangles the shape makes (as [`shape_mesh`] builds it), before it is built.
    fn triangle_count(&self) -> u64 {
        match self {
            ShapeSpec::Quad { .. } => 2,
            ShapeSpec::Disk { segments, .. } => segments.unwrap_or(64) as u64,
            ShapeSpec::Sphere { segments, .. } => {
                let slices = segments.unwrap_or(48) as u64;
                2 * slices * (slices / 2).max(2)
            }
        }
    }
}

fn shape_mesh(
    s: &ShapeSpec,
    index: usize,
) -> std::result::Result<(MeshDesc, &MaterialSpec), String> {
    let mesh_name = |n: &Option<String>| n.clone().unwrap_or_else(|| format!("shape {index}"));
    match s {
        ShapeSpec::Quad {
            name,
            corners,
            normal,
            material,
        } => {
            let p = corners
                .iter()
                .map(|c| finite3(*c, "corner"))
                .collect::<std::result::Result<Vec<_>, _>>()?;
            let geometric = (p[1] - p[0]).cross(p[2] - p[0]);
            if geometric.length_squared() == 0.0 {
                return Err("quad corners 0, 1, 2 are collinear".into());
            }
            let mut indices = vec![[0, 1, 2], [0, 2, 3]];
            let mut normals = Vec::new();
            if let Some(n) = normal {
                let n = unit3(*n, "quad normal")?;
                if geometric.dot(n) < 0.0 {
                    indices = vec![[0, 2, 1], [0, 3, 2]];
                }
                normals = vec![n; 4];
            }
            Ok((
                MeshDesc {
                    name: mesh_name(name),
                    positions: p,
                    normals,
                    uvs: vec![
                        Vec2::new(0.0, 0.0),
                        Vec2::new(1.0, 0.0),
                        Vec2::new(1.0, 1.0),
                        Vec2::new(0.0, 1.0),
                    ],
                    indices,
                    materials: Vec::new(),
                },
                material,
            ))
        }
        ShapeSpec::Disk {
            name,
            center,
            normal,
            radius,
            segments,
            material,
        } => {
            let c = finite3(*center, "disk center")?;
            let n = unit3(*normal, "disk normal")?;
            let r = positive(*radius, "disk radius")?;
            let k = segments.unwrap_or(64);
            if !(3..=4096).contains(&k) {
                return Err(format!("disk segments {k} must be in 3..=4096"));
            }
            // The polygon's circumradius is enlarged so that its area equals the disk's.
            let step = 2.0 * PI / k as f32;
            let rp = r * (2.0 * PI / (k as f32 * step.sin())).sqrt();
            let frame = Frame::from_z(n);
            let mut positions = vec![c];
            let mut uvs = vec![Vec2::splat(0.5)];
            for i in 0..k {
                let a = i as f32 * step;
                let (s, co) = a.sin_cos();
                positions.push(c + frame.to_world(Vec3::new(co, s, 0.0)) * rp);
                uvs.push(Vec2::new(0.5 + 0.5 * co, 0.5 + 0.5 * s));
            }
            let indices = (0..k).map(|i| [0, 1 + i, 1 + (i + 1) % k]).collect();
            let normals = vec![n; positions.len()];
            Ok((
                MeshDesc {
                    name: mesh_name(name),
                    positions,
                    normals,
                    uvs,
                    indices,
                    materials: Vec::new(),
                },
                material,
            ))
        }
        ShapeSpec::Sphere {
            name,
            center,
            radius,
            segments,
            material,
        } => {
            let c = finite3(*center, "sphere center")?;
            let r = positive(*radius, "sphere radius")?;
            let slices = segments.unwrap_or(48);
            if !(4..=2048).contains(&slices) {
                return Err(format!("sphere segments {slices} must be in 4..=2048"));
            }
            let stacks = (slices / 2).max(2);
            let mut positions = Vec::new();
            let mut normals = Vec::new();
            let mut uvs = Vec::new();
            // Rings from the north pole (stack 0) to the south pole (stack `stacks`), with a
            // duplicated seam column so that uvs wrap.
            for j in 0..=stacks {
                let theta = PI * j as f32 / stacks as f32;
                for i in 0..=slices {
                    let phi = 2.0 * PI * i as f32 / slices as f32;
                    let d = Vec3::new(
                        theta.sin() * phi.cos(),
                        theta.cos(),
                        -theta.sin() * phi.sin(),
                    );
                    positions.push(c + d * r);
                    normals.push(d);
                    uvs.push(Vec2::new(
                        i as f32 / slices as f32,
                        1.0 - j as f32 / stacks as f32,
                    ));
                }
            }
            let row = slices + 1;
            let mut indices = Vec::new();
            for j in 0..stacks {
                for i in 0..slices {
                    let a = j * row + i;
                    let b = a + row;
                    // Counter-clockwise seen from outside.
                    if j != 0 {
                        indices.push([a, b, a + 1]);
                    }
                    if j != stacks - 1 {
                        indices.push([a + 1, b, b + 1]);
                    }
                }
            }
            Ok((
                MeshDesc {
                    name: mesh_name(name),
                    positions,
                    normals,
                    uvs,
                    indices,
                    materials: Vec::new(),
                },
                material,
            ))
        }
    }
}

/// A camera framing `bounds` for an image of the given aspect ratio (width / height): it looks
/// from the +Z side, 15 degrees above the centre, with a 40 degree vertical field of view, far
/// enough that the bounding sphere is in view. An empty box gives a camera at (0, 0, 5) looking
/// at the origin.
pub fn auto_camera(bounds: Bounds3, aspect: f32) -> Camera {
    const VFOV: f32 = 40.0;
    let fallback = Camera {
        eye: Vec3::new(0.0, 0.0, 5.0),
        target: Vec3::ZERO,
        up: Vec3::Y,
        vfov_degrees: VFOV,
        lens_radius: 0.0,
        focus_distance: 5.0,
    };
    if bounds.is_empty() || !bounds.min.is_finite() || !bounds.max.is_finite() {
        return fallback;
    }
    let aspect = if aspect > 0.0 && aspect.is_finite() {
        aspect
    } else {
        1.0
    };
    let (center, r) = bounds.bounding_sphere();
    let r = if r > 0.0 { r } else { 1.0 };
    let half_v = (VFOV * 0.5).to_radians();
    let half_h = (half_v.tan() * aspect).atan();
    let half = half_v.min(half_h);
    let distance = r / half.sin();
    let elevation = 15f32.to_radians();
    let dir = Vec3::new(0.0, elevation.sin(), elevation.cos());
    let eye = center + dir * distance;
    if !eye.is_finite() {
        return fallback;
    }
    Camera {
        eye,
        target: center,
        up: Vec3::Y,
        vfov_degrees: VFOV,
        lens_radius: 0.0,
        focus_distance: distance,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::light::Light;
    use std::fs;

    /// A command-line scene argument: built-in names, .obj and .json files, and a clear
    /// error for anything else.
    #[test]
    fn scene_argument_resolves_builtins_and_files() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        for name in ["two-rooms", "corridor", "rooms:5"] {
            let (loaded, label) = load_scene_arg(Path::new(name)).unwrap();
            assert_eq!(label, name);
            assert!(loaded.builder.build().is_ok());
        }
        let obj = root.join("scenes/cornell-box/CornellBox-Original.obj");
        let (loaded, _) = load_scene_arg(&obj).unwrap();
        assert_eq!(loaded.objects.len(), 1);
        let json = root.join("scenes/cornell-box/cornell-box.json");
        let (loaded, _) = load_scene_arg(&json).unwrap();
        assert_eq!(loaded.settings.width, Some(512));
        let err = load_scene_arg(Path::new("no-such-scene.txt"))
            .err()
            .unwrap();
        assert!(err.to_string().contains("no-such-scene.txt"), "{err}");
    }

    struct TempDir(PathBuf);

    impl TempDir {
        fn new(tag: &str) -> Self {
            use std::sync::atomic::{AtomicUsize, Ordering};
            static COUNTER: AtomicUsize = AtomicUsize::new(0);
            let dir = std::env::temp_dir().join(format!(
                "lacuna-file-{tag}-{}-{}",
                std::process::id(),
                COUNTER.fetch_add(1, Ordering::Relaxed)
            ));
            let _ = fs::remove_dir_all(&dir);
            fs::create_dir_all(&dir).unwrap();
            TempDir(dir)
        }

        fn write(&self, name: &str, content: &str) -> PathBuf {
            let p = self.0.join(name);
            if let Some(parent) = p.parent() {
                fs::create_dir_all(parent).unwrap();
            }
            fs::write(&p, content).unwrap();
            p
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = fs::remove_dir_all(&self.0);
        }
    }

    const BOX_OBJ: &str =
        "mtllib box.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nusemtl wall\nf 1 2 3 4\n";
    const BOX_MTL: &str = "newmtl wall\nKd 0.5 0.5 0.5\n";

    fn parse_err(r: Result<LoadedScene>) -> (PathBuf, String, String) {
        match r {
            Err(Error::Parse {
                path,
                location,
                message,
            }) => (path, location, message),
            Err(e) => panic!("expected a Parse error, got {e}"),
            Ok(_) => panic!("expected a Parse error, got a scene"),
        }
    }

    #[test]
    fn every_feature_of_the_format_loads() {
        let dir = TempDir::new("full");
        dir.write("models/box.obj", BOX_OBJ);
        dir.write("models/box.mtl", BOX_MTL);
        let img = image::RgbImage::from_pixel(1, 1, image::Rgb([255, 255, 255]));
        img.save(dir.0.join("white.png")).unwrap();
        let json = r#"{
          "comment": ["any", "text"],
          "objects": [
            { "obj": "models/box.obj" },
            { "obj": "models/box.obj", "comment": "second copy",
              "transform": { "scale": 2, "rotate": { "axis": [0, 0, 1], "degrees": 90 }, "translate": [10, 0, 0] } },
            { "obj": "models/box.obj",
              "transform": { "matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -5], [0, 0, 0, 1]] } }
          ],
          "shapes": [
            { "type": "quad", "name": "lamp", "corners": [[0, 3, 0], [1, 3, 0], [1, 3, 1], [0, 3, 1]],
              "normal": [0, -1, 0], "material": { "name": "lamp_mat", "diffuse": 0, "emission": [5, 6, 7] } },
            { "type": "disk", "center": [0, 2, 0], "normal": [1, 0, 0], "radius": 0.5, "segments": 16,
              "material": { "emission": 3 } },
            { "type": "sphere", "center": [0, 0, 3], "radius": 0.25, "segments": 8 },
            { "type": "sphere", "center": [0, 0, -3], "radius": 0.25, "segments": 8,
              "material": { "name": "frost", "kind": "rough_dielectric", "ior": 1.45, "roughness": 0.4 } }
          ],
          "camera": { "eye": [0, 1, 5], "target": [0, 1, 0], "fov": 45, "lens_radius": 0.01, "focus_distance": 4 },
          "lights": [
            { "type": "point", "position": [0, 1, 1], "intensity": [1, 2, 3] },
            { "type": "spot", "position": [0, 2, 0], "direction": [0, -1, 0], "intensity": 10,
              "inner_degrees": 20, "outer_degrees": 30 },
            { "type": "directional", "direction": [0, -1, -1], "irradiance": 2 }
          ],
          "materials": {
            "wall": { "kind": "glossy", "diffuse": [0.5, 0.4, 0.3], "specular": 0.2, "exponent": 30,
                      "diffuse_texture": "white.png" },
            "lamp_mat": { "emission": 8 }
          },
          "render": { "width": 320, "height": 240, "spp": 64, "max_depth": 8, "integrator": "path",
                      "seed": 3, "sampler": "independent", "time": 1.5, "skeleton": { "c_skel": 0.25, "strength": 16 },
                      "resampling": { "subset": 64, "accept": 0.5 } }
        }"#;
        let path = dir.write("scene.json", json);
        let loaded = load_scene_file(&path).unwrap();
        assert_eq!(
            loaded.settings,
            RenderSettingsFile {
                width: Some(320),
                height: Some(240),
                spp: Some(64),
                max_depth: Some(8),
                integrator: Some("path".into()),
                seed: Some(3),
                sampler: Some("independent".into()),
                time: Some(1.5),
                skeleton: Some(
                    [
                        ("c_skel".to_string(), serde_json::json!(0.25)),
                        ("strength".to_string(), serde_json::json!(16)),
                    ]
                    .into_iter()
                    .collect()
                ),
                resampling: Some(
                    [
                        ("accept".to_string(), serde_json::json!(0.5)),
                        ("subset".to_string(), serde_json::json!(64)),
                    ]
                    .into_iter()
                    .collect()
                ),
                source: Some(path.clone()),
            }
        );
        assert_eq!(
            loaded.settings.skeleton_options(),
            vec![
                ("c_skel".to_string(), "0.25".to_string()),
                ("strength".to_string(), "16".to_string())
            ]
        );
        assert_eq!(loaded.objects.len(), 3);
        // scale 2, rotate 90 degrees about z, translate x 10: (1, 0, 0) -> (10, 2, 0).
        let b1 = loaded.objects[1].bounds;
        assert!(
            (b1.min - Vec3::new(8.0, 0.0, 0.0)).length() < 1e-5,
            "{b1:?}"
        );
        assert!(
            (b1.max - Vec3::new(10.0, 2.0, 0.0)).length() < 1e-5,
            "{b1:?}"
        );
        assert_eq!(loaded.objects[2].bounds.min.z, -5.0);
        let mut builder = loaded.builder;
        let mats = builder.materials_mut().to_vec();
        let frost = mats.iter().find(|m| m.name == "frost").unwrap();
        assert_eq!(
            (frost.kind, frost.ior, frost.roughness),
            (MaterialKind::RoughDielectric, 1.45, 0.4)
        );
        let walls: Vec<&Material> = mats.iter().filter(|m| m.name == "wall").collect();
        assert_eq!(walls.len(), 3, "one per loaded copy of the OBJ");
        for w in walls {
            assert_eq!(w.kind, MaterialKind::Glossy);
            assert_eq!(w.diffuse, Rgb::new(0.5, 0.4, 0.3));
            assert_eq!((w.specular, w.exponent), (Rgb::splat(0.2), 30.0));
            assert_eq!(w.diffuse_texture, Some(0));
        }
        assert_eq!(builder.texture_count(), 1);
        let lamp = mats.iter().find(|m| m.name == "lamp_mat").unwrap();
        assert_eq!((lamp.emission, lamp.diffuse), (Rgb::splat(8.0), Rgb::ZERO));
        let scene = builder.build().unwrap();
        let cam = scene.camera().unwrap();
        assert_eq!(
            (cam.vfov_degrees, cam.lens_radius, cam.focus_distance),
            (45.0, 0.01, 4.0)
        );
        let areas: Vec<&Light> = scene
            .lights()
            .iter()
            .filter(|l| matches!(l, Light::Area { .. }))
            .collect();
        assert_eq!(areas.len(), 2 + 16, "quad + disk triangles");
        assert_eq!(scene.lights().len(), 2 + 16 + 3);
        // The lamp quad faces -y although its corners wind towards +y.
        let lamp_normals: Vec<Vec3> = scene
            .lights()
            .iter()
            .filter_map(|l| match l {
                Light::Area {
                    normal, radiance, ..
                } if *radiance == Rgb::splat(8.0) => Some(*normal),
                _ => None,
            })
            .collect();
        assert_eq!(lamp_normals.len(), 2);
        assert!(lamp_normals.iter().all(|n| (*n + Vec3::Y).length() < 1e-6));
        // The disk polygon has the disk's area and faces +x.
        let disk_area: f32 = scene
            .lights()
            .iter()
            .filter_map(|l| match l {
                Light::Area {
                    area,
                    normal,
                    radiance,
                    ..
                } if *radiance == Rgb::splat(3.0) => {
                    assert!((*normal - Vec3::X).length() < 1e-5);
                    Some(*area)
                }
                _ => None,
            })
            .sum();
        assert!((disk_area - PI * 0.25).abs() < 1e-4, "{disk_area}");
    }

    #[test]
    fn sphere_is_closed_and_faces_outwards() {
        let spec = ShapeSpec::Sphere {
            name: None,
            center: [1.0, 2.0, 3.0],
            radius: 2.0,
            segments: Some(24),
            material: MaterialSpec::default(),
        };
        let (mesh, _) = shape_mesh(&spec, 0).unwrap();
        let c = Vec3::new(1.0, 2.0, 3.0);
        let mut volume = 0.0;
        for t in &mesh.indices {
            let p = t.map(|i| mesh.positions[i as usize] - c);
            let n = (p[1] - p[0]).cross(p[2] - p[0]);
            assert!(n.length() > 0.0, "no degenerate triangles");
            assert!(n.dot(p[0] + p[1] + p[2]) > 0.0, "outward winding");
            volume += p[0].dot(p[1].cross(p[2])) / 6.0;
        }
        let exact = 4.0 / 3.0 * PI * 8.0;
        assert!(volume > 0.9 * exact && volume < exact, "{volume}");
    }

    #[test]
    fn json_syntax_errors_give_line_and_column() {
        let dir = TempDir::new("syntax");
        let path = dir.write(
            "s.json",
            "{\n  \"camera\": {\n    \"eye\": [0, 0, 1],,\n  }\n}\n",
        );
        let (p, loc, msg) = parse_err(load_scene_file(&path));
        assert_eq!(p, path);
        assert!(loc.starts_with("line 3 column"), "{loc}");
        assert!(!msg.contains("at line"), "{msg}");
    }

    #[test]
    fn unknown_and_missing_fields_are_named() {
        let dir = TempDir::new("fields");
        let path = dir.write(
            "u.json",
            "{\n \"render\": { \"width\": 10, \"heigth\": 5 }\n}",
        );
        let (_, loc, msg) = parse_err(load_scene_file(&path));
        assert!(loc.starts_with("line 2 column"), "{loc}");
        assert!(msg.contains("unknown field `heigth`"), "{msg}");

        let path = dir.write("t.json", "{ \"cameras\": {} }");
        let (_, _, msg) = parse_err(load_scene_file(&path));
        assert!(msg.contains("`cameras`"), "{msg}");

        let path = dir.write(
            "m.json",
            "{ \"camera\": { \"eye\": [0, 0, 1], \"fov\": 40 } }",
        );
        let (_, _, msg) = parse_err(load_scene_file(&path));
        assert!(msg.contains("missing field `target`"), "{msg}");

        let path = dir.write(
            "l.json",
            "{ \"lights\": [ { \"type\": \"point\", \"position\": [0, 0, 0], \"intensity\": 1, \"radius\": 2 } ] }",
        );
        let (_, _, msg) = parse_err(load_scene_file(&path));
        assert!(msg.contains("`radius`"), "{msg}");

        let path = dir.write("k.json", "{ \"lights\": [ { \"type\": \"area\" } ] }");
        let (_, _, msg) = parse_err(load_scene_file(&path));
        assert!(msg.contains("`area`"), "{msg}");
    }

    #[test]
    fn invalid_values_name_the_field() {
        let dir = TempDir::new("values");
        dir.write("box.obj", BOX_OBJ);
        dir.write("box.mtl", BOX_MTL);
        let cases = [
            (
                r#"{"camera": {"eye": [0,0,0], "target": [0,0,0], "fov": 40}}"#,
                "camera",
            ),
            (
                r#"{"lights": [{"type": "point", "position": [0,0,0], "intensity": -1}]}"#,
                "lights[0]",
            ),
            (
                r#"{"objects": [{"obj": "box.obj"}], "materials": {"nope": {"ior": 1.2}}}"#,
                "materials.nope",
            ),
            (
                r#"{"objects": [{"obj": "box.obj"}], "materials": {"wall": {"kind": "glossy", "specular": 0.9}}}"#,
                "materials.wall",
            ),
            (
                r#"{"objects": [{"obj": "box.obj", "transform": {"scale": 0}}]}"#,
                "objects[0].transform",
            ),
            (
                r#"{"objects": [{"obj": "box.obj", "transform": {"scale": 2, "matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}}]}"#,
                "objects[0].transform",
            ),
            (
                r#"{"objects": [{"obj": "box.obj", "transform": {"matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,1,1]]}}]}"#,
                "objects[0].transform",
            ),
            (
                r#"{"shapes": [{"type": "disk", "center": [0,0,0], "normal": [0,0,0], "radius": 1}]}"#,
                "shapes[0]",
            ),
            (
                r#"{"shapes": [{"type": "sphere", "center": [0,0,0], "radius": 1, "material": {"diffuse": 2}}]}"#,
                "shapes[0].material",
            ),
            (r#"{"render": {"width": 0}}"#, "render.width"),
            (r#"{"render": {"time": -1}}"#, "render.time"),
            (r#"{"render": {"sampler": "halton"}}"#, "render.sampler"),
        ];
        for (json, loc) in cases {
            let path = dir.write("v.json", json);
            let (p, l, msg) = parse_err(load_scene_file(&path));
            assert_eq!(p, path);
            assert_eq!(l, loc, "{json}: {msg}");
        }
        // A missing OBJ is an Io error naming the OBJ.
        let path = dir.write("o.json", r#"{"objects": [{"obj": "missing.obj"}]}"#);
        match load_scene_file(&path) {
            Err(Error::Io { path: p, .. }) => assert_eq!(p, dir.0.join("missing.obj")),
            other => panic!("{:?}", other.err()),
        }
        // A malformed OBJ is a Parse error naming the OBJ and line.
        dir.write("bad.obj", "v 0 0 0\nv 1 0 0\nf 1 2 3\n");
        let path = dir.write("b.json", r#"{"objects": [{"obj": "bad.obj"}]}"#);
        let (p, l, _) = parse_err(load_scene_file(&path));
        assert_eq!((p, l.as_str()), (dir.0.join("bad.obj"), "line 3"));
        // A missing texture named by the scene file is an Io error naming the texture.
        let path = dir.write(
            "x.json",
            r#"{"objects": [{"obj": "box.obj"}], "materials": {"wall": {"diffuse_texture": "no.png"}}}"#,
        );
        match load_scene_file(&path) {
            Err(Error::Io { path: p, .. }) => assert_eq!(p, dir.0.join("no.png")),
            other => panic!("{:?}", other.err()),
        }
        // A missing scene file is an Io error naming it.
        assert!(matches!(
            load_scene_file(&dir.0.join("none.json")),
            Err(Error::Io { .. })
        ));
    }

    #[test]
    fn matrix_and_trs_agree() {
        let trs: TransformSpec = serde_json::from_str(
            r#"{"translate": [1, 2, 3], "rotate": {"axis": [0, 1, 0], "degrees": 90}, "scale": [2, 3, 4]}"#,
        )
        .unwrap();
        let m = trs.matrix().unwrap();
        // x axis scaled by 2 then rotated 90 degrees about y: (2, 0, 0) -> (0, 0, -2).
        let p = m.transform_point3(Vec3::X);
        assert!((p - Vec3::new(1.0, 2.0, 1.0)).length() < 1e-5, "{p}");
        let rows = m.transpose().to_cols_array_2d();
        let json = format!("{{\"matrix\": {}}}", serde_json::to_string(&rows).unwrap());
        let mat: TransformSpec = serde_json::from_str(&json).unwrap();
        assert!(mat.matrix().unwrap().abs_diff_eq(m, 1e-6));
    }

    #[test]
    fn auto_camera_frames_the_whole_box() {
        for (bounds, aspect) in [
            (
                Bounds3 {
                    min: Vec3::new(-1.0, 0.0, -1.0),
                    max: Vec3::new(1.0, 2.0, 1.0),
                },
                1.0,
            ),
            (
                Bounds3 {
                    min: Vec3::new(-100.0, -5.0, -3.0),
                    max: Vec3::new(300.0, 40.0, 7.0),
                },
                2.0,
            ),
            (
                Bounds3 {
                    min: Vec3::splat(3.0),
                    max: Vec3::new(3.0, 9.0, 3.0),
                },
                0.5,
            ),
        ] {
            let cam = auto_camera(bounds, aspect);
            cam.validate().unwrap();
            assert!(cam.eye.z > bounds.max.z && cam.eye.y > bounds.center().y);
            let f = cam.frame(aspect);
            for i in 0..8 {
                let corner = Vec3::new(
                    if i & 1 == 0 {
                        bounds.min.x
                    } else {
                        bounds.max.x
                    },
                    if i & 2 == 0 {
                        bounds.min.y
                    } else {
                        bounds.max.y
                    },
                    if i & 4 == 0 {
                        bounds.min.z
                    } else {
                        bounds.max.z
                    },
                );
                let d = corner - f.eye;
                let z = d.dot(f.forward);
                assert!(z > 0.0);
                let x = d.dot(f.right) / f.right.length_squared() / z;
                let y = d.dot(f.up) / f.up.length_squared() / z;
                assert!(
                    x.abs() <= 1.0 && y.abs() <= 1.0,
                    "corner {corner} at ({x}, {y})"
                );
            }
        }
        let empty = auto_camera(Bounds3::EMPTY, 1.0);
        empty.validate().unwrap();
    }

    #[test]
    fn no_camera_means_auto_camera_with_warning() {
        let dir = TempDir::new("auto");
        dir.write("box.obj", BOX_OBJ);
        dir.write("box.mtl", BOX_MTL);
        let path = dir.write(
            "a.json",
            r#"{"objects": [{"obj": "box.obj"}], "render": {"width": 200, "height": 100}}"#,
        );
        let loaded = load_scene_file(&path).unwrap();
        assert!(loaded.warnings.iter().any(|w| w.contains("no camera")));
        let scene = loaded.builder.build().unwrap();
        let expected = auto_camera(scene.bounds(), 2.0);
        assert_eq!(scene.camera(), Some(&expected));
    }

    /// The example in docs/scene-format.md is valid.
    #[test]
    fn documented_example_loads() {
        let doc =
            fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/scene-format.md"))
                .unwrap();
        let start = doc.find("```json\n").expect("a json block") + "```json\n".len();
        let end = start + doc[start..].find("```").unwrap();
        let dir = TempDir::new("doc");
        dir.write(
            "room.obj",
            "mtllib room.mtl\nv 0 0 0\nv 1 0 0\nv 1 0 -1\nv 0 0 -1\nusemtl floor\nf 1 2 3 4\nusemtl glass\nf 1 3 2\n",
        );
        dir.write(
            "room.mtl",
            "newmtl floor\nKd 0.5 0.5 0.5\nnewmtl glass\nillum 7\nNi 1.5\n",
        );
        dir.write("teapot.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
        let path = dir.write("example.json", &doc[start..end]);
        let loaded = load_scene_file(&path).unwrap();
        loaded.builder.build().unwrap();
    }

    fn repo_scene(rel: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("scenes")
            .join(rel)
    }

    fn load_repo_scene(rel: &str) -> (crate::scene::Scene, LoadedScene) {
        let mut loaded = load_scene_file(&repo_scene(rel)).unwrap();
        let builder = std::mem::take(&mut loaded.builder);
        (builder.build().unwrap(), loaded)
    }

    #[test]
    fn repository_cornell_box_loads() {
        let (scene, loaded) = load_repo_scene("cornell-box/cornell-box.json");
        assert_eq!(scene.triangle_count(), 36);
        assert_eq!(scene.lights().len(), 2);
        assert!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
        let cam = scene.camera().unwrap();
        assert_eq!(cam.eye, Vec3::new(0.0, 1.0, 3.9));
        assert_eq!(
            (loaded.settings.width, loaded.settings.max_depth),
            (Some(512), Some(8))
        );
    }

    #[test]
    fn repository_veach_ajar_loads() {
        let (scene, loaded) = load_repo_scene("veach-ajar-bitterli/veach-ajar-bitterli.json");
        assert_eq!(
            scene.triangle_count() + loaded.objects[0].degenerate_skipped,
            4546
        );
        // One quad light facing -z (towards the door), radiance 1000.
        let lights: Vec<&Light> = scene.lights().iter().collect();
        assert_eq!(lights.len(), 2);
        for l in lights {
            match l {
                Light::Area {
                    normal, radiance, ..
                } => {
                    assert!((*normal + Vec3::Z).length() < 1e-5);
                    assert_eq!(*radiance, Rgb::splat(1000.0));
                }
                other => panic!("{other:?}"),
            }
        }
        assert_eq!(scene.textures().len(), 3, "{:?}", loaded.warnings);
    }

    #[test]
    fn repository_veach_door_lamp_faces_the_door() {
        let (scene, loaded) = load_repo_scene("veach-door-pg2015/veach-door-pg2015.json");
        assert_eq!(
            scene.triangle_count() + loaded.objects[0].degenerate_skipped,
            20764
        );
        let areas: Vec<Vec3> = scene
            .lights()
            .iter()
            .filter_map(|l| match l {
                Light::Area { normal, .. } => Some(*normal),
                _ => None,
            })
            .collect();
        assert_eq!(areas.len(), 2);
        // The door is at y ~ 72..74.5, the lamp at y = 321.8: it must emit towards -y.
        assert!(
            areas.iter().all(|n| (*n + Vec3::Y).length() < 1e-5),
            "{areas:?}"
        );
        let mats = scene.materials();
        let copper = mats.iter().find(|m| m.name == "copper").unwrap();
        assert_eq!(copper.kind, MaterialKind::Mirror);
        let glass = mats.iter().find(|m| m.name == "glass").unwrap();
        assert_eq!(glass.kind, MaterialKind::Dielectric);
        assert!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
    }

    #[test]
    fn repository_sibenik_loads() {
        let (scene, loaded) = load_repo_scene("sibenik/sibenik.json");
        let disk_triangles = 2 * 64;
        assert_eq!(
            scene.triangle_count() + loaded.objects[0].degenerate_skipped,
            73564 + disk_triangles
        );
        assert_eq!(scene.lights().len(), disk_triangles);
    }

    /// 262k triangles: about a second in release mode, far slower unoptimised.
    #[test]
    #[cfg_attr(debug_assertions, ignore = "large scene: run with --release")]
    fn repository_sponza_loads() {
        let loaded = load_scene_file(&repo_scene("crytek-sponza/crytek-sponza.json")).unwrap();
        let r = &loaded.objects[0];
        assert_eq!(r.triangles + r.degenerate_skipped, 262_267);
        assert_eq!(r.degenerate_skipped, 7);
        let scene = loaded.builder.build().unwrap();
        assert_eq!(scene.lights().len(), 1);
        assert!(scene.camera().is_some());
    }
}
