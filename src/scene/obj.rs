//! Wavefront OBJ + MTL loading into a [`SceneBuilder`].
//!
//! Parsing is done by the `tobj` crate (triangulated, single index per vertex). Before `tobj`
//! sees a file, a light line-by-line pre-scan checks the statements that matter (numbers,
//! face indices, material statements) so that a malformed file gives an [`Error::Parse`] naming
//! the file and the line, and normalises a few harmless variants `tobj` would reject or
//! misread (leading whitespace, tabs after `usemtl`, one-component colours, `l` polylines).
//!
//! Polygons with more than three vertices are fan-triangulated by `tobj`, which is wrong for
//! concave polygons. The repository's scenes are triangulated already (the corridor's concave
//! floor and ceiling are ear-clipped in its OBJ, and the corridor is rebuilt procedurally
//! anyway); the report counts the polygons that were fanned.
//!
//! MTL mapping (per material):
//! - `Kd` diffuse (default 0.5, or 1 when only `map_Kd` is given), `Ks` specular, `Ns` Phong
//!   exponent, `Ni` index of refraction (default 1.5), `d` dissolve (or `1 - Tr`), `Ke`
//!   emitted radiance, `map_Kd` diffuse texture (relative to the MTL file's folder, loaded once
//!   per path; a texture that cannot be loaded is a warning, the material keeps `Kd`).
//! - kind: `illum` 3 or 5 with `Ks > 0` is a mirror (reflectance `Ks`); `illum` 4, 6, 7 or
//!   dissolve < 1 is a dielectric (`Ni`), rough (frosted) when the PBR extension's roughness
//!   `Pr` is above 0, with GGX width alpha = `Pr`^2 (the exporters' perceptual roughness, as
//!   Blender writes it; `Pr` is clamped to [0, 1]); otherwise `Ks > 0` gives a glossy (modified Phong)
//!   material, scaled down with a warning when `Kd + Ks > 1`; otherwise diffuse.
//! - colours outside [0, 1] are clamped with a warning. Objects without a material (or naming
//!   an unknown one, a warning) get a grey diffuse default.
//!
//! Zero-area triangles are skipped and counted (`DegeneratePolicy::Skip` while loading).

use std::cell::RefCell;
use std::collections::HashMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

use glam::{Mat3, Mat4, Vec4};

use super::{DegeneratePolicy, Material, MaterialKind, MeshDesc, SceneBuilder, Texture};
use crate::error::{Error, Result};
use crate::geometry::Bounds3;
use crate::math::{Rgb, Vec2, Vec3};

/// What loading one OBJ file added to the builder.
#[derive(Clone, Debug)]
pub struct ObjReport {
    pub path: PathBuf,
    /// Meshes added (one per object/group and material).
    pub meshes: usize,
    /// Triangles added (degenerate ones excluded).
    pub triangles: usize,
    pub vertices: usize,
    /// Zero-area triangles that were dropped.
    pub degenerate_skipped: usize,
    /// Polygons with more than four vertices that were fan-triangulated.
    pub polygons_fanned: usize,
    /// Builder index of every material the file's meshes use, with its MTL name
    /// (`"default"` for the fallback material).
    pub materials: Vec<(String, u32)>,
    /// Textures loaded (each distinct path once).
    pub textures: usize,
    /// Bounds of the added geometry (after the transform).
    pub bounds: Bounds3,
    /// Non-fatal problems: missing MTL or texture files, unknown material names, clamped or
    /// rescaled colours, dropped attributes.
    pub warnings: Vec<String>,
}

impl ObjReport {
    fn new(path: &Path) -> Self {
        ObjReport {
            path: path.to_path_buf(),
            meshes: 0,
            triangles: 0,
            vertices: 0,
            degenerate_skipped: 0,
            polygons_fanned: 0,
            materials: Vec::new(),
            textures: 0,
            bounds: Bounds3::EMPTY,
            warnings: Vec::new(),
        }
    }
}

/// Name of the material given to faces without a (known) material.
pub const DEFAULT_MATERIAL_NAME: &str = "default";

/// Loads `path` (and the MTL files it names) into `builder`, optionally transforming
/// positions by `transform` (normals by its inverse transpose). A missing OBJ file is an
/// [`Error::Io`]; malformed OBJ or MTL content is an [`Error::Parse`] naming the file and line.
pub fn load_obj(
    path: &Path,
    builder: &mut SceneBuilder,
    transform: Option<Mat4>,
) -> Result<ObjReport> {
    let xf = match transform {
        Some(m) => Some(Xform::new(m)?),
        None => None,
    };
    let bytes =
        crate::limits::read_file_bounded(path, "OBJ file", crate::limits::MAX_OBJ_FILE_BYTES)?;
    check_text(&bytes, path, "an OBJ file")?;
    let text = String::from_utf8_lossy(strip_bom(&bytes));
    let scan = prescan_obj(&text, path)?;

    let obj_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let state = RefCell::new(MtlState {
        raw_names: raw_mtllib_names(&bytes),
        ..Default::default()
    });
    // tobj's optional features (merging, reordering) add fields: keep the struct update.
    #[allow(clippy::needless_update)]
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    let loaded = catch_unwind(AssertUnwindSafe(|| {
        tobj::load_obj_buf(
            &mut std::io::Cursor::new(scan.text.as_bytes()),
            &options,
            |mtl| load_mtl_file(&obj_dir, mtl, &state),
        )
    }));
    let state = state.into_inner();
    if let Some(err) = state.fatal {
        return Err(err);
    }
    let (models, materials) = match loaded {
        Ok(Ok(r)) => r,
        Ok(Err(e)) => return Err(Error::parse(path, "", format!("OBJ parser: {e}"))),
        Err(_) => {
            return Err(Error::parse(
                path,
                "",
                "OBJ parser panicked on this input (malformed file)",
            ))
        }
    };
    // When every MTL failed tobj reports the last error; the failures are warnings already.
    let materials = materials.unwrap_or_default();

    let mut report = ObjReport {
        polygons_fanned: scan.polygons_fanned,
        warnings: state.warnings,
        ..ObjReport::new(path)
    };
    report.warnings.extend(scan.warnings);
    let known: std::collections::HashSet<&str> =
        materials.iter().map(|m| m.name.as_str()).collect();
    for (name, line) in &scan.usemtl {
        if !known.contains(name.as_str()) {
            report.warnings.push(format!(
                "{}:line {line}: usemtl '{name}' names no material in the MTL files; using the grey default",
                path.display()
            ));
        }
    }
    if scan.polygons_fanned > 0 {
        report.warnings.push(format!(
            "{}: {} polygons with more than 4 vertices were fan-triangulated (wrong if concave)",
            path.display(),
            scan.polygons_fanned
        ));
    }

    let previous_policy = builder.degenerate_policy();
    builder.set_degenerate_policy(DegeneratePolicy::Skip);
    let skipped_before = builder.degenerate_skipped();
    let result = add_models(
        path,
        builder,
        xf.as_ref(),
        &models,
        &materials,
        &state.material_dirs,
        &mut report,
    );
    report.degenerate_skipped = builder.degenerate_skipped() - skipped_before;
    builder.set_degenerate_policy(previous_policy);
    result?;
    if report.triangles == 0 {
        report
            .warnings
            .push(format!("{}: no triangles", path.display()));
    }
    Ok(report)
}

/// An affine transform for positions and its inverse transpose for normals.
struct Xform {
    m: Mat4,
    normal: Mat3,
    flips: bool,
}

impl Xform {
    fn new(m: Mat4) -> Result<Self> {
        if !m.is_finite() {
            return Err(Error::invalid(format!("OBJ transform {m} must be finite")));
        }
        if m.row(3) != Vec4::new(0.0, 0.0, 0.0, 1.0) {
            return Err(Error::invalid(format!(
                "OBJ transform must be affine (last row 0 0 0 1), got {}",
                m.row(3)
            )));
        }
        let linear = Mat3::from_mat4(m);
        crate::limits::check_transform_scale(linear)
            .map_err(|e| Error::invalid(format!("OBJ {e}")))?;
        let det = linear.determinant();
        Ok(Xform {
            m,
            normal: linear.inverse().transpose(),
            flips: det < 0.0,
        })
    }
}

/// Converts tobj's models into builder meshes.
fn add_models(
    path: &Path,
    builder: &mut SceneBuilder,
    xf: Option<&Xform>,
    models: &[tobj::Model],
    materials: &[tobj::Material],
    material_dirs: &[PathBuf],
    report: &mut ObjReport,
) -> Result<()> {
    // tobj material index -> builder material index (created on first use).
    let mut material_map: HashMap<Option<usize>, u32> = HashMap::new();
    let mut textures: HashMap<PathBuf, Option<u32>> = HashMap::new();
    let mut failed_textures: Vec<FailedTexture> = Vec::new();
    for model in models {
        let mesh = &model.mesh;
        let nv = mesh.positions.len() / 3;
        let nt = mesh.indices.len() / 3;
        if nt == 0 || nv == 0 {
            continue;
        }
        let material_id = mesh.material_id.filter(|&i| i < materials.len());
        let mat_index = match material_map.get(&material_id) {
            Some(&i) => i,
            None => {
                let (name, material) = match material_id {
                    Some(i) => {
                        let dir = material_dirs.get(i).cloned().unwrap_or_default();
                        let m = convert_material(
                            &materials[i],
                            &dir,
                            builder,
                            (&mut textures, &mut failed_textures),
                            report,
                        );
                        (materials[i].name.clone(), m)
                    }
                    None => (
                        DEFAULT_MATERIAL_NAME.to_string(),
                        Material {
                            name: DEFAULT_MATERIAL_NAME.to_string(),
                            ..Material::default()
                        },
                    ),
                };
                let idx = builder
                    .add_material(material)
                    .map_err(|e| Error::parse(path, "", invalid_message(e)))?;
                material_map.insert(material_id, idx);
                report.materials.push((name, idx));
                idx
            }
        };

        let mut positions: Vec<Vec3> = mesh
            .positions
            .chunks_exact(3)
            .map(|p| Vec3::new(p[0], p[1], p[2]))
            .collect();
        let mut normals: Vec<Vec3> = if mesh.normals.len() == nv * 3 {
            mesh.normals
                .chunks_exact(3)
                .map(|n| Vec3::new(n[0], n[1], n[2]))
                .collect()
        } else {
            if !mesh.normals.is_empty() {
                report.warnings.push(format!(
                    "{}: object '{}' gives normals for only some vertices; normals dropped",
                    path.display(),
                    model.name
                ));
            }
            Vec::new()
        };
        let uvs: Vec<Vec2> = if mesh.texcoords.len() == nv * 2 {
            mesh.texcoords
                .chunks_exact(2)
                .map(|t| Vec2::new(t[0], t[1]))
                .collect()
        } else {
            if !mesh.texcoords.is_empty() {
                report.warnings.push(format!(
                    "{}: object '{}' gives texture coordinates for only some vertices; dropped",
                    path.display(),
                    model.name
                ));
            }
            Vec::new()
        };
        let mut indices: Vec<[u32; 3]> = mesh
            .indices
            .chunks_exact(3)
            .map(|t| [t[0], t[1], t[2]])
            .collect();
        if let Some(xf) = xf {
            for p in &mut positions {
                *p = xf.m.transform_point3(*p);
            }
            for n in &mut normals {
                *n = (xf.normal * *n).normalize_or_zero();
            }
            if xf.flips {
                // A mirroring transform reverses the winding; restore the front side.
                for t in &mut indices {
                    t.swap(1, 2);
                }
            }
        }
        for p in &positions {
            report.bounds = report.bounds.union_point(*p);
        }
        let before = builder.degenerate_skipped();
        builder
            .add_mesh(MeshDesc {
                name: model.name.clone(),
                positions,
                normals,
                uvs,
                indices,
                materials: vec![mat_index],
            })
            .map_err(|e| Error::parse(path, "", invalid_message(e)))?;
        report.meshes += 1;
        report.vertices += nv;
        report.triangles += nt - (builder.degenerate_skipped() - before);
    }
    report.textures = textures.values().filter(|t| t.is_some()).count();
    if let Some(w) = failed_textures_warning(&failed_textures) {
        report.warnings.push(w);
    }
    Ok(())
}

/// A `map_Kd` texture that could not be loaded: its path, the first material naming it, and
/// why.
struct FailedTexture {
    path: PathBuf,
    material: String,
    error: String,
}

/// How many failed textures the summary warning names.
const FAILED_TEXTURES_NAMED: usize = 3;

/// One warning for every texture that could not be loaded, naming the count and the first few:
/// a scene shipped without its textures (Crytek Sponza here) would otherwise print one line per
/// material at every load.
fn failed_textures_warning(failed: &[FailedTexture]) -> Option<String> {
    let first = failed.first()?;
    let named: Vec<String> = failed
        .iter()
        .take(FAILED_TEXTURES_NAMED)
        .map(|f| format!("{} (material '{}')", f.path.display(), f.material))
        .collect();
    let more = match failed.len().saturating_sub(FAILED_TEXTURES_NAMED) {
        0 => String::new(),
        n => format!(" and {n} more"),
    };
    let count = match failed.len() {
        1 => "1 map_Kd texture".to_string(),
        n => format!("{n} map_Kd textures"),
    };
    Some(format!(
        "{count} not loaded, their materials use Kd: {}{more}; first error: {}",
        named.join(", "),
        first.error
    ))
}

fn invalid_message(e: Error) -> String {
    match e {
        Error::InvalidArgument(m) => m,
        other => other.to_string(),
    }
}

fn clamp_colour(c: Rgb, what: &str, name: &str, warnings: &mut Vec<String>) -> Rgb {
    let clamped = c.clamp(Rgb::ZERO, Rgb::ONE);
    if clamped != c {
        warnings.push(format!("material '{name}': {what} {c} clamped to [0, 1]"));
    }
    clamped
}

fn rgb(c: [f32; 3]) -> Rgb {
    Rgb::new(c[0], c[1], c[2])
}

/// Maps one MTL material to a Lacuna material (see the module documentation).
fn convert_material(
    m: &tobj::Material,
    mtl_dir: &Path,
    builder: &mut SceneBuilder,
    (textures, failed_textures): (&mut HashMap<PathBuf, Option<u32>>, &mut Vec<FailedTexture>),
    report: &mut ObjReport,
) -> Material {
    let name = m.name.as_str();
    let warnings = &mut report.warnings;
    let texture = m
        .diffuse_texture
        .as_deref()
        .and_then(texture_file_name)
        .and_then(|file| {
            let full = if Path::new(&file).is_absolute() {
                PathBuf::from(&file)
            } else {
                mtl_dir.join(&file)
            };
            *textures
                .entry(full.clone())
                .or_insert_with(|| match Texture::load(&full) {
                    Ok(t) => Some(builder.add_texture(t)),
                    Err(e) => {
                        // Reported once for all textures, after every material is converted.
                        failed_textures.push(FailedTexture {
                            path: full.clone(),
                            material: name.to_string(),
                            error: e.to_string(),
                        });
                        None
                    }
                })
        });
    let default_kd = if texture.is_some() { 1.0 } else { 0.5 };
    let mut kd = clamp_colour(
        m.diffuse.map(rgb).unwrap_or(Rgb::splat(default_kd)),
        "Kd",
        name,
        warnings,
    );
    let mut ks = clamp_colour(
        m.specular.map(rgb).unwrap_or(Rgb::ZERO),
        "Ks",
        name,
        warnings,
    );
    let number = |key: &str| -> Option<f32> {
        m.unknown_param
            .get(key)
            .and_then(|v| v.split_whitespace().last())
            .and_then(|v| v.parse::<f32>().ok())
            .filter(|v| v.is_finite())
    };
    let emission = m
        .emissive
        .map(rgb)
        .or_else(|| {
            m.unknown_param.get("Ke").and_then(|v| {
                let c: Vec<f32> = v
                    .split_whitespace()
                    .filter_map(|x| x.parse().ok())
                    .collect();
                match c.len() {
                    1 => Some(Rgb::splat(c[0])),
                    n if n >= 3 => Some(Rgb::new(c[0], c[1], c[2])),
                    _ => None,
                }
            })
        })
        .unwrap_or(Rgb::ZERO);
    let emission = if emission.is_finite() && emission.min_element() >= 0.0 {
        emission
    } else {
        warnings.push(format!(
            "material '{name}': Ke {emission} must be finite and >= 0; clamped"
        ));
        emission.max(Rgb::ZERO).min(Rgb::splat(f32::MAX))
    };
    let dissolve = m
        .dissolve
        .or_else(|| number("Tr").map(|tr| 1.0 - tr))
        .unwrap_or(1.0);
    let mut ior = m.optical_density.unwrap_or(1.5);
    if !(ior > 0.0 && ior.is_finite()) {
        warnings.push(format!(
            "material '{name}': Ni {ior} must be positive; using 1.5"
        ));
        ior = 1.5;
    }
    let exponent = m.shininess.unwrap_or(1.0).clamp(0.0, 1e6);
    let pr = number("Pr").unwrap_or(0.0).clamp(0.0, 1.0);
    let illum = m.illumination_model;
    let has_ks = ks.max_element() > 0.0;
    let kind = if matches!(illum, Some(3 | 5)) && has_ks {
        MaterialKind::Mirror
    } else if (matches!(illum, Some(4 | 6 | 7)) || dissolve < 1.0) && pr > 0.0 {
        MaterialKind::RoughDielectric
    } else if matches!(illum, Some(4 | 6 | 7)) || dissolve < 1.0 {
        MaterialKind::Dielectric
    } else if has_ks {
        MaterialKind::Glossy
    } else {
        MaterialKind::Diffuse
    };
    match kind {
        MaterialKind::Glossy => {
            let sum = (kd + ks).max_element();
            if sum > 1.0 {
                let s = 1.0 / sum;
                warnings.push(format!(
                    "material '{name}': Kd + Ks = {} exceeds 1; both scaled by {s:.4} to conserve energy",
                    kd + ks
                ));
                kd *= s;
                ks *= s;
            }
        }
        MaterialKind::Mirror => kd = Rgb::ZERO,
        MaterialKind::Dielectric | MaterialKind::RoughDielectric => {
            kd = Rgb::ZERO;
            ks = Rgb::ZERO;
        }
        MaterialKind::Diffuse => ks = Rgb::ZERO,
    }
    Material {
        name: m.name.clone(),
        kind,
        diffuse: kd,
        diffuse_texture: if matches!(kind, MaterialKind::Diffuse | MaterialKind::Glossy) {
            texture
        } else {
            None
        },
        specular: ks,
        exponent,
        ior,
        roughness: pr * pr,
        emission,
    }
}

/// The file name of an MTL texture statement: skips `-option value...` prefixes and turns
/// Windows separators into `/`.
fn texture_file_name(statement: &str) -> Option<String> {
    let tokens: Vec<&str> = statement.split_whitespace().collect();
    let mut i = 0;
    while i < tokens.len() && tokens[i].starts_with('-') && tokens[i].parse::<f32>().is_err() {
        let option = tokens[i];
        i += 1;
        if option == "-imfchan" || option == "-type" {
            i += 1;
            continue;
        }
        let mut taken = 0;
        while i < tokens.len()
            && taken < 3
            && (tokens[i].parse::<f32>().is_ok() || tokens[i] == "on" || tokens[i] == "off")
        {
            i += 1;
            taken += 1;
        }
    }
    let first = tokens.get(i)?;
    // The name runs to the end of the statement (it may contain spaces).
    let start = first.as_ptr() as usize - statement.as_ptr() as usize;
    Some(statement[start..].trim().replace('\\', "/"))
}

#[derive(Default)]
struct MtlState {
    /// Folder of each material tobj has received so far, in tobj's order.
    material_dirs: Vec<PathBuf>,
    warnings: Vec<String>,
    fatal: Option<Error>,
    /// `mtllib` names that are not UTF-8, as written (the text tobj sees has them replaced),
    /// keyed by that replaced text.
    raw_names: Vec<(String, PathBuf)>,
}

/// The `mtllib` names of an OBJ file that are not valid UTF-8, keyed by their lossy text, so
/// that a material library with such a name is still found.
fn raw_mtllib_names(bytes: &[u8]) -> Vec<(String, PathBuf)> {
    let mut names = Vec::new();
    for line in bytes.split(|&b| b == b'\n') {
        let line = line.trim_ascii();
        let Some(rest) = line.strip_prefix(b"mtllib") else {
            continue;
        };
        let rest = rest.trim_ascii();
        if rest.is_empty() || std::str::from_utf8(rest).is_ok() {
            continue;
        }
        #[cfg(unix)]
        {
            use std::os::unix::ffi::OsStrExt;
            let lossy = String::from_utf8_lossy(rest).trim().to_string();
            names.push((lossy, PathBuf::from(std::ffi::OsStr::from_bytes(rest))));
        }
    }
    names
}

/// tobj's material loader: reads, checks and normalises an MTL file.
fn load_mtl_file(obj_dir: &Path, mtl: &Path, state: &RefCell<MtlState>) -> tobj::MTLLoadResult {
    let mut state = state.borrow_mut();
    if state.fatal.is_some() {
        return Err(tobj::LoadError::GenericFailure);
    }
    let written = mtl.to_string_lossy().replace('\\', "/");
    let written = written.trim();
    let raw = state
        .raw_names
        .iter()
        .find(|(lossy, _)| lossy == written)
        .map(|(_, raw)| obj_dir.join(raw));
    if written.is_empty() {
        state
            .warnings
            .push("mtllib statement without a file name ignored".to_string());
        return Err(tobj::LoadError::OpenFileFailed);
    }
    // `mtllib a.mtl b.mtl` names several files; a single name may also contain spaces.
    let whole = obj_dir.join(written);
    let files: Vec<PathBuf> = if let Some(raw) = raw {
        vec![raw]
    } else if whole.is_file() || !written.contains(char::is_whitespace) {
        vec![whole]
    } else {
        written
            .split_whitespace()
            .map(|f| obj_dir.join(f))
            .collect()
    };
    let mut all: Vec<tobj::Material> = Vec::new();
    for file in files {
        let bytes =
            crate::limits::read_file_bounded(&file, "MTL file", crate::limits::MAX_OBJ_FILE_BYTES)
                .and_then(|b| check_text(&b, &file, "an MTL file").map(|()| b));
        let bytes = match bytes {
            Ok(b) => b,
            Err(e) => {
                let reason = match e {
                    Error::Io { source, .. } => source.to_string(),
                    other => other.to_string(),
                };
                state.warnings.push(format!(
                    "{}: material library not read ({reason}); its materials fall back to the grey default",
                    file.display()
                ));
                continue;
            }
        };
        let text = String::from_utf8_lossy(strip_bom(&bytes));
        let normalised = match prescan_mtl(&text, &file) {
            Ok(t) => t,
            Err(e) => {
                state.fatal = Some(e);
                return Err(tobj::LoadError::MaterialParseError);
            }
        };
        let parsed =
            catch_unwind(|| tobj::load_mtl_buf(&mut std::io::Cursor::new(normalised.as_bytes())));
        match parsed {
            Ok(Ok((mats, _))) => {
                let dir = file.parent().map(Path::to_path_buf).unwrap_or_default();
                for m in mats {
                    all.push(m);
                    state.material_dirs.push(dir.clone());
                }
            }
            Ok(Err(e)) => {
                state.fatal = Some(Error::parse(&file, "", format!("MTL parser: {e}")));
                return Err(tobj::LoadError::MaterialParseError);
            }
            Err(_) => {
                state.fatal = Some(Error::parse(
                    &file,
                    "",
                    "MTL parser panicked on this input (malformed file)",
                ));
                return Err(tobj::LoadError::MaterialParseError);
            }
        }
    }
    if all.is_empty() {
        return Err(tobj::LoadError::OpenFileFailed);
    }
    let map = all
        .iter()
        .enumerate()
        .map(|(i, m)| (m.name.clone(), i))
        .collect();
    Ok((all, map))
}

/// Result of the OBJ pre-scan: the normalised text for tobj and what to check afterwards.
struct ObjScan {
    text: String,
    usemtl: Vec<(String, usize)>,
    polygons_fanned: usize,
    warnings: Vec<String>,
}

/// A UTF-8 byte-order mark, which some editors write, is not part of the first statement.
pub(crate) fn strip_bom(bytes: &[u8]) -> &[u8] {
    bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes)
}

/// OBJ and MTL files are text: a NUL byte means a binary file (an image renamed `.obj`,
/// random bytes), refused with the line where it appears instead of parsed into nothing.
fn check_text(bytes: &[u8], path: &Path, what: &str) -> Result<()> {
    if let Some(at) = bytes.iter().position(|&b| b == 0) {
        let line = 1 + bytes[..at].iter().filter(|&&b| b == b'\n').count();
        return Err(Error::parse(
            path,
            location(line),
            format!("binary data (a NUL byte at offset {at}): this is not {what}"),
        ));
    }
    Ok(())
}

fn location(line: usize) -> String {
    format!("line {line}")
}

/// Splits a trimmed line into its keyword and the (trimmed) rest.
fn keyword(line: &str) -> (&str, &str) {
    match line.find(char::is_whitespace) {
        Some(i) => (&line[..i], line[i..].trim()),
        None => (line, ""),
    }
}

fn parse_finite(token: &str) -> Option<f32> {
    token.parse::<f32>().ok().filter(|v| v.is_finite())
}

/// Parses exactly the numbers of a statement; the message names what is wrong.
fn numbers(rest: &str, what: &str) -> std::result::Result<Vec<f32>, String> {
    rest.split_whitespace()
        .map(|t| match t.parse::<f32>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => Err(format!("{what}: '{t}' is not a finite number")),
            Err(_) => Err(format!("{what}: '{t}' is not a number")),
        })
        .collect()
}

/// Checks an OBJ file line by line and returns a normalised copy for tobj.
fn prescan_obj(text: &str, path: &Path) -> Result<ObjScan> {
    let mut out = String::with_capacity(text.len() + 64);
    let mut counts = [0usize; 3]; // v, vt, vn
    let mut forward: Vec<(usize, usize, usize)> = Vec::new(); // (line, kind, index)
    let mut usemtl: Vec<(String, usize)> = Vec::new();
    let mut seen_usemtl: std::collections::HashSet<String> = Default::default();
    let mut short_faces = 0usize;
    let mut polylines = 0usize;
    let mut polygons_fanned = 0usize;
    const KIND: [&str; 3] = ["vertex", "texture coordinate", "normal"];
    const KIND_PLURAL: [&str; 3] = ["vertices", "texture coordinates", "normals"];
    for (i, raw) in text.lines().enumerate() {
        let n = i + 1;
        let err = |msg: String| Error::parse(path, location(n), msg);
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            out.push('\n');
            continue;
        }
        let (kw, rest) = keyword(line);
        // Data statements may end with a comment.
        let data = rest.split('#').next().unwrap_or("").trim();
        match kw {
            "v" => {
                let v = numbers(data, "vertex position").map_err(err)?;
                match v.len() {
                    3 | 6 => {}
                    4 if v[3] != 0.0 => {}
                    4 => return Err(err("vertex position: w is zero".into())),
                    k => {
                        return Err(err(format!(
                            "vertex position: expected 3 coordinates (optionally w, or r g b), found {k} numbers"
                        )))
                    }
                }
                counts[0] += 1;
                out.push_str("v ");
                out.push_str(data);
            }
            "vt" => {
                let v = numbers(data, "texture coordinate").map_err(err)?;
                if v.is_empty() || v.len() > 3 {
                    return Err(err(format!(
                        "texture coordinate: expected 1 to 3 numbers, found {}",
                        v.len()
                    )));
                }
                counts[1] += 1;
                out.push_str(&format!("vt {} {}", v[0], v.get(1).copied().unwrap_or(0.0)));
            }
            "vn" => {
                let v = numbers(data, "normal").map_err(err)?;
                if v.len() != 3 {
                    return Err(err(format!(
                        "normal: expected 3 numbers, found {}",
                        v.len()
                    )));
                }
                counts[2] += 1;
                out.push_str("vn ");
                out.push_str(data);
            }
            "f" => {
                let mut vertices = 0;
                for token in data.split_whitespace() {
                    vertices += 1;
                    let parts: Vec<&str> = token.split('/').collect();
                    if parts.len() > 3 {
                        return Err(err(format!(
                            "face vertex '{token}': expected v, v/vt, v//vn or v/vt/vn"
                        )));
                    }
                    for (k, part) in parts.iter().enumerate() {
                        if part.is_empty() {
                            if k == 0 {
                                return Err(err(format!(
                                    "face vertex '{token}' has no position index"
                                )));
                            }
                            continue;
                        }
                        let idx: i64 = part.parse().map_err(|_| {
                            err(format!(
                                "face vertex '{token}': {} index '{part}' is not an integer",
                                KIND[k]
                            ))
                        })?;
                        if idx == 0 {
                            return Err(err(format!(
                                "face vertex '{token}': {} index 0 (OBJ indices start at 1)",
                                KIND[k]
                            )));
                        }
                        if idx < 0 {
                            if idx.unsigned_abs() as usize > counts[k] {
                                return Err(err(format!(
                                    "face vertex '{token}': relative {} index {idx} points before the first of the {} defined so far",
                                    KIND[k], counts[k]
                                )));
                            }
                        } else if idx as u64 > counts[k] as u64 {
                            if idx as u64 > u32::MAX as u64 {
                                return Err(err(format!(
                                    "face vertex '{token}': {} index {idx} out of range",
                                    KIND[k]
                                )));
                            }
                            forward.push((n, k, idx as usize));
                        }
                    }
                }
                match vertices {
                    0 => return Err(err("face without vertices".into())),
                    1 | 2 => {
                        short_faces += 1;
                        out.push('\n');
                        continue;
                    }
                    3 | 4 => {}
                    _ => polygons_fanned += 1,
                }
                out.push_str("f ");
                out.push_str(data);
            }
            "l" | "p" => {
                // tobj would turn a polyline of 3+ points into a triangle: drop it.
                polylines += 1;
            }
            "o" | "g" => {
                out.push_str(kw);
                if !rest.is_empty() {
                    out.push(' ');
                    out.push_str(rest);
                }
            }
            "usemtl" => {
                if rest.is_empty() {
                    return Err(err("usemtl without a material name".into()));
                }
                if seen_usemtl.insert(rest.to_string()) {
                    usemtl.push((rest.to_string(), n));
                }
                out.push_str("usemtl ");
                out.push_str(rest);
            }
            "mtllib" => {
                if !rest.is_empty() {
                    out.push_str("mtllib ");
                    out.push_str(rest);
                }
            }
            _ => out.push_str(line),
        }
        out.push('\n');
    }
    for (line, k, idx) in forward {
        if idx > counts[k] {
            return Err(Error::parse(
                path,
                location(line),
                format!(
                    "face {} index {idx} out of range (the file has {} {})",
                    KIND[k], counts[k], KIND_PLURAL[k]
                ),
            ));
        }
    }
    let mut warnings = Vec::new();
    if short_faces > 0 {
        warnings.push(format!(
            "{}: {short_faces} faces with fewer than 3 vertices ignored",
            path.display()
        ));
    }
    if polylines > 0 {
        warnings.push(format!(
            "{}: {polylines} line/point statements ignored",
            path.display()
        ));
    }
    Ok(ObjScan {
        text: out,
        usemtl,
        polygons_fanned,
        warnings,
    })
}

/// Checks an MTL file line by line and returns a normalised copy for tobj.
fn prescan_mtl(text: &str, path: &Path) -> Result<String> {
    let mut out = String::with_capacity(text.len() + 64);
    for (i, raw) in text.lines().enumerate() {
        let n = i + 1;
        let err = |msg: String| Error::parse(path, location(n), msg);
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            out.push('\n');
            continue;
        }
        let (kw, rest) = keyword(line);
        // Numeric statements may carry a trailing comment ("Kd 0.6 0.1 0.1 # red").
        let numeric = rest.split('#').next().unwrap_or("").trim();
        match kw {
            "newmtl" => {
                if rest.is_empty() {
                    return Err(err("newmtl without a material name".into()));
                }
                out.push_str("newmtl ");
                out.push_str(rest);
            }
            "Ka" | "Kd" | "Ks" | "Ke" => {
                let first = numeric.split_whitespace().next().unwrap_or("");
                if first == "spectral" || first == "xyz" {
                    return Err(err(format!(
                        "{kw}: '{first}' colours are not supported (give r g b)"
                    )));
                }
                let c = numbers(numeric, kw).map_err(err)?;
                let c = match c.len() {
                    1 => [c[0]; 3],
                    3 => [c[0], c[1], c[2]],
                    k => return Err(err(format!("{kw}: expected 1 or 3 numbers, found {k}"))),
                };
                out.push_str(&format!("{kw} {} {} {}", c[0], c[1], c[2]));
            }
            "Ns" | "Ni" | "d" | "Tr" => {
                // `d -halo 0.5`: the value is the last token.
                let value = numeric.split_whitespace().last().unwrap_or("");
                let v = parse_finite(value)
                    .ok_or_else(|| err(format!("{kw}: expected a number, found '{numeric}'")))?;
                out.push_str(&format!("{kw} {v}"));
            }
            "illum" => {
                let v: u8 = numeric.parse().ok().filter(|v| *v <= 10).ok_or_else(|| {
                    err(format!(
                        "illum: expected an integer 0 to 10, found '{numeric}'"
                    ))
                })?;
                out.push_str(&format!("illum {v}"));
            }
            k if k.starts_with("map_") || k == "bump" || k == "disp" || k == "decal" => {
                if rest.is_empty() {
                    return Err(err(format!("{kw} without a file name")));
                }
                out.push_str(kw);
                out.push(' ');
                out.push_str(rest);
            }
            _ => {
                // Unknown statements go to tobj's `unknown_param`.
                out.push_str(kw);
                if !rest.is_empty() {
                    out.push(' ');
                    out.push_str(rest);
                }
            }
        }
        out.push('\n');
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::fs;

    /// A fresh, empty folder under the system temp dir, removed when dropped.
    pub(crate) struct TempDir(pub PathBuf);

    impl TempDir {
        pub(crate) fn new(tag: &str) -> Self {
            use std::sync::atomic::{AtomicUsize, Ordering};
            static COUNTER: AtomicUsize = AtomicUsize::new(0);
            let dir = std::env::temp_dir().join(format!(
                "lacuna-{tag}-{}-{}",
                std::process::id(),
                COUNTER.fetch_add(1, Ordering::Relaxed)
            ));
            let _ = fs::remove_dir_all(&dir);
            fs::create_dir_all(&dir).unwrap();
            TempDir(dir)
        }

        pub(crate) fn write(&self, name: &str, content: &str) -> PathBuf {
            let p = self.0.join(name);
            fs::write(&p, content).unwrap();
            p
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = fs::remove_dir_all(&self.0);
        }
    }

    const QUADS_MTL: &str = "\
newmtl matte
Kd 0.2 0.4 0.6
newmtl shiny
Kd 0.5 0.5 0.5
Ks 0.3 0.3 0.3
Ns 50
newmtl hot
Kd 0.6 0.6 0.6
Ks 0.7 0.2 0.2
Ns 20
newmtl chrome
illum 3
Kd 0.1 0.1 0.1
Ks 0.9 0.8 0.7
newmtl glass
illum 7
Ni 1.33
Kd 0 0 0
Ks 1 1 1
newmtl see_through
Kd 0.8 0.8 0.8
d 0.4
Ni 1.2
newmtl tr_glass
Kd 0.8 0.8 0.8
Tr 0.5
newmtl frosted
illum 7
Ni 1.45
Pr 0.6
newmtl lamp
Kd 0 0 0
Ke 10 20 30
newmtl textured
map_Kd tex.png
newmtl textured_again
Kd 0.5 0.5 0.5
map_Kd -s 1 1 1 tex.png
newmtl broken_texture
Kd 0.3 0.3 0.3
map_Kd does_not_exist.png
";

    /// An OBJ with one quad per material plus one without material.
    fn quads_obj(materials: &[&str]) -> String {
        let mut s = String::from("mtllib quads.mtl\n");
        for (i, m) in materials.iter().enumerate() {
            let x = i as f32 * 2.0;
            s += &format!(
                "o {m}\nv {x} 0 0\nv {} 0 0\nv {} 1 0\nv {x} 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl {m}\nf -4/-4 -3/-3 -2/-2 -1/-1\n",
                x + 1.0,
                x + 1.0
            );
        }
        // Before any `usemtl`: this triangle has no material.
        s.insert_str(0, "o bare\nv 0 5 0\nv 1 5 0\nv 1 6 0\nf -3 -2 -1\n");
        s
    }

    fn write_texture(dir: &TempDir) {
        let img = image::RgbImage::from_fn(2, 2, |x, y| {
            image::Rgb([(x * 255) as u8, (y * 255) as u8, 0])
        });
        img.save(dir.0.join("tex.png")).unwrap();
    }

    fn material<'a>(b: &'a mut SceneBuilder, r: &ObjReport, name: &str) -> &'a Material {
        let idx = r.materials.iter().find(|(n, _)| n == name).unwrap().1;
        &b.materials_mut()[idx as usize]
    }

    /// Missing textures (a scene shipped without them) give one warning naming how many and
    /// the first few, not one per material; a texture shared by two materials counts once.
    #[test]
    fn missing_textures_are_reported_once() {
        let dir = TempDir::new("obj-missing-tex");
        let names: Vec<String> = (0..6).map(|i| format!("m{i}")).collect();
        let mut mtl = String::new();
        for (i, n) in names.iter().enumerate() {
            // m4 and m5 share one missing file.
            mtl += &format!(
                "newmtl {n}\nKd 0.3 0.3 0.3\nmap_Kd textures/gone{}.png\n",
                i.min(4)
            );
        }
        dir.write("quads.mtl", &mtl);
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let path = dir.write("quads.obj", &quads_obj(&refs));
        let mut b = SceneBuilder::new();
        let r = load_obj(&path, &mut b, None).unwrap();
        let texture_warnings: Vec<&String> = r
            .warnings
            .iter()
            .filter(|w| w.contains("texture"))
            .collect();
        assert_eq!(texture_warnings.len(), 1, "{:?}", r.warnings);
        let w = texture_warnings[0];
        assert!(w.starts_with("5 map_Kd textures not loaded"), "{w}");
        for i in 0..3 {
            assert!(w.contains(&format!("gone{i}.png (material 'm{i}')")), "{w}");
        }
        assert!(!w.contains("gone3.png") && w.contains("and 2 more"), "{w}");
        assert_eq!(r.textures, 0);
        for n in &names {
            let m = material(&mut b, &r, n).clone();
            assert_eq!((m.diffuse_texture, m.diffuse), (None, Rgb::splat(0.3)));
        }
    }

    #[test]
    fn mtl_features_map_to_materials() {
        let dir = TempDir::new("obj-mtl");
        write_texture(&dir);
        dir.write("quads.mtl", QUADS_MTL);
        let names = [
            "matte",
            "shiny",
            "hot",
            "chrome",
            "glass",
            "see_through",
            "tr_glass",
            "frosted",
            "lamp",
            "textured",
            "textured_again",
            "broken_texture",
        ];
        let obj = quads_obj(&names);
        let path = dir.write("quads.obj", &obj);
        let mut b = SceneBuilder::new();
        let r = load_obj(&path, &mut b, None).unwrap();
        assert_eq!(r.meshes, names.len() + 1);
        assert_eq!(r.triangles, names.len() * 2 + 1);
        assert_eq!(r.textures, 1, "tex.png loaded once: {:?}", r.warnings);
        assert_eq!(b.texture_count(), 1);

        let m = material(&mut b, &r, "matte").clone();
        assert_eq!(m.kind, MaterialKind::Diffuse);
        assert_eq!(m.diffuse, Rgb::new(0.2, 0.4, 0.6));
        let m = material(&mut b, &r, "shiny").clone();
        assert_eq!(m.kind, MaterialKind::Glossy);
        assert_eq!((m.specular, m.exponent), (Rgb::splat(0.3), 50.0));
        let m = material(&mut b, &r, "hot").clone();
        assert_eq!(m.kind, MaterialKind::Glossy);
        assert!(((m.diffuse + m.specular).max_element() - 1.0).abs() < 1e-5);
        assert!((m.specular.x / m.diffuse.x - 0.7 / 0.6).abs() < 1e-4);
        assert!(r
            .warnings
            .iter()
            .any(|w| w.contains("'hot'") && w.contains("scaled")));
        let m = material(&mut b, &r, "chrome").clone();
        assert_eq!(m.kind, MaterialKind::Mirror);
        assert_eq!(m.specular, Rgb::new(0.9, 0.8, 0.7));
        let m = material(&mut b, &r, "glass").clone();
        assert_eq!((m.kind, m.ior), (MaterialKind::Dielectric, 1.33));
        let m = material(&mut b, &r, "see_through").clone();
        assert_eq!((m.kind, m.ior), (MaterialKind::Dielectric, 1.2));
        let m = material(&mut b, &r, "tr_glass").clone();
        assert_eq!((m.kind, m.ior), (MaterialKind::Dielectric, 1.5));
        let m = material(&mut b, &r, "frosted").clone();
        assert_eq!((m.kind, m.ior), (MaterialKind::RoughDielectric, 1.45));
        assert!((m.roughness - 0.36).abs() < 1e-6);
        let m = material(&mut b, &r, "lamp").clone();
        assert_eq!(m.emission, Rgb::new(10.0, 20.0, 30.0));
        assert!(m.is_emissive());
        let m = material(&mut b, &r, "textured").clone();
        assert_eq!((m.diffuse_texture, m.diffuse), (Some(0), Rgb::ONE));
        let m = material(&mut b, &r, "textured_again").clone();
        assert_eq!((m.diffuse_texture, m.diffuse), (Some(0), Rgb::splat(0.5)));
        let m = material(&mut b, &r, "broken_texture").clone();
        assert_eq!((m.diffuse_texture, m.diffuse), (None, Rgb::splat(0.3)));
        assert!(r
            .warnings
            .iter()
            .any(|w| w.contains("broken_texture") && w.contains("does_not_exist.png")));
        let m = material(&mut b, &r, DEFAULT_MATERIAL_NAME).clone();
        assert_eq!(
            (m.kind, m.diffuse),
            (MaterialKind::Diffuse, Rgb::splat(0.5))
        );

        let scene = b.build().unwrap();
        assert_eq!(scene.lights().len(), 2, "the lamp quad is two area lights");
        // Texture coordinates survive.
        assert!(scene
            .meshes()
            .iter()
            .all(|m| m.name == "bare" || m.uvs.is_some()));
    }

    #[test]
    fn unknown_material_and_missing_mtl_are_warnings() {
        let dir = TempDir::new("obj-warn");
        let path = dir.write(
            "a.obj",
            "mtllib nowhere.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl ghost\nf 1 2 3\n",
        );
        let mut b = SceneBuilder::new();
        let r = load_obj(&path, &mut b, None).unwrap();
        assert_eq!(r.triangles, 1);
        assert_eq!(r.materials, vec![(DEFAULT_MATERIAL_NAME.to_string(), 0)]);
        assert!(r.warnings.iter().any(|w| w.contains("nowhere.mtl")));
        assert!(r
            .warnings
            .iter()
            .any(|w| w.contains("ghost") && w.contains("line 5")));
    }

    #[test]
    fn transform_moves_positions_and_normals() {
        let dir = TempDir::new("obj-xf");
        let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nvn 1 1 1\nf 1//1 2//1 3//2\n";
        let path = dir.write("t.obj", obj);
        let m = Mat4::from_translation(Vec3::new(10.0, 0.0, 0.0))
            * Mat4::from_scale(Vec3::new(2.0, 1.0, 1.0));
        let mut b = SceneBuilder::new();
        let r = load_obj(&path, &mut b, Some(m)).unwrap();
        assert_eq!(r.bounds.min, Vec3::new(10.0, 0.0, 0.0));
        assert_eq!(r.bounds.max, Vec3::new(12.0, 1.0, 0.0));
        let scene = b.build().unwrap();
        let mesh = &scene.meshes()[0];
        let p: Vec<Vec3> = mesh.positions.clone();
        assert!(p.contains(&Vec3::new(12.0, 0.0, 0.0)));
        let normals = mesh.normals.as_ref().unwrap();
        // (1,1,1) under scale (2,1,1): inverse transpose gives (1/2, 1, 1), normalised.
        let expected = Vec3::new(0.5, 1.0, 1.0).normalize();
        assert!(normals.iter().any(|n| (*n - expected).length() < 1e-6));
        assert!(normals.iter().any(|n| (*n - Vec3::Z).length() < 1e-6));

        // A mirroring transform keeps the front side (winding restored).
        let path = dir.write("w.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
        let mut b = SceneBuilder::new();
        load_obj(
            &path,
            &mut b,
            Some(Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0))),
        )
        .unwrap();
        let scene = b.build().unwrap();
        assert!((scene.geometric_normal(0) - Vec3::Z).length() < 1e-6);

        let mut b = SceneBuilder::new();
        assert!(matches!(
            load_obj(&path, &mut b, Some(Mat4::from_scale(Vec3::ZERO))),
            Err(Error::InvalidArgument(_))
        ));
    }

    #[test]
    fn missing_file_is_io_error_with_path() {
        let dir = TempDir::new("obj-missing");
        let path = dir.0.join("nope.obj");
        match load_obj(&path, &mut SceneBuilder::new(), None) {
            Err(Error::Io { path: p, .. }) => assert_eq!(p, path),
            other => panic!("expected Io error, got {other:?}"),
        }
    }

    fn parse_error(r: Result<ObjReport>) -> (PathBuf, String, String) {
        match r {
            Err(Error::Parse {
                path,
                location,
                message,
            }) => (path, location, message),
            other => panic!("expected Parse error, got {other:?}"),
        }
    }

    #[test]
    fn malformed_obj_names_file_and_line() {
        let dir = TempDir::new("obj-bad");
        let cases = [
            ("v 0 0 0\nv 1 0 0\nv 0 x 0\nf 1 2 3\n", "line 3", "'x'"),
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n",
                "line 4",
                "out of range",
            ),
            ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n", "line 4", "-4"),
            ("v 0 0 0\nv 1 0\n", "line 2", "found 2"),
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2 3\n",
                "line 4",
                "texture coordinate",
            ),
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\n\n\nf 0 1 2\n",
                "line 6",
                "index 0",
            ),
            ("v 0 0 1e39\n", "line 1", "finite"),
            ("v 0 0 0\nvn 0 0\n", "line 2", "normal"),
            ("v 0 0 0\nf 1/a 1 1\n", "line 2", "'a'"),
            ("usemtl\n", "line 1", "usemtl"),
        ];
        for (text, loc, needle) in cases {
            let path = dir.write("bad.obj", text);
            let (p, l, m) = parse_error(load_obj(&path, &mut SceneBuilder::new(), None));
            assert_eq!(p, path);
            assert_eq!(l, loc, "{text:?}: {m}");
            assert!(
                m.contains(needle),
                "{text:?}: message {m:?} lacks {needle:?}"
            );
        }
    }

    #[test]
    fn malformed_mtl_names_the_mtl_file_and_line() {
        let dir = TempDir::new("mtl-bad");
        let obj = dir.write(
            "m.obj",
            "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n",
        );
        for (text, loc, needle) in [
            ("newmtl a\nKd 0.5 0.5\n", "line 2", "Kd"),
            ("newmtl a\n\nNs high\n", "line 3", "Ns"),
            ("newmtl a\nillum 2.5\n", "line 2", "illum"),
            ("newmtl\n", "line 1", "newmtl"),
            ("newmtl a\nmap_Kd\n", "line 2", "map_Kd"),
            ("newmtl a\nKe 1 inf 1\n", "line 2", "finite"),
        ] {
            let mtl = dir.write("m.mtl", text);
            let (p, l, m) = parse_error(load_obj(&obj, &mut SceneBuilder::new(), None));
            assert_eq!(p, mtl);
            assert_eq!(l, loc, "{text:?}: {m}");
            assert!(m.contains(needle), "{text:?}: {m}");
        }
        // Variants tobj alone would reject or panic on are accepted.
        dir.write("m.mtl", "  newmtl a\n\tKd 0.5 # grey\n\tKe 2\n");
        let mut b = SceneBuilder::new();
        let r = load_obj(&obj, &mut b, None).unwrap();
        assert_eq!(material(&mut b, &r, "a").diffuse, Rgb::splat(0.5));
        assert_eq!(material(&mut b, &r, "a").emission, Rgb::splat(2.0));
    }

    #[test]
    fn degenerate_triangles_are_skipped_and_counted() {
        let dir = TempDir::new("obj-degen");
        let path = dir.write(
            "d.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\nf 1 1 3\n",
        );
        let mut b = SceneBuilder::new();
        let r = load_obj(&path, &mut b, None).unwrap();
        assert_eq!((r.triangles, r.degenerate_skipped), (1, 2));
        // The builder's own policy is restored.
        assert_eq!(b.degenerate_policy(), DegeneratePolicy::Error);
        assert_eq!(b.build().unwrap().stats().degenerate_triangles_skipped, 2);
    }

    #[test]
    fn texture_statement_options_are_skipped() {
        assert_eq!(texture_file_name("a b.png").as_deref(), Some("a b.png"));
        assert_eq!(
            texture_file_name("-s 1 1 1 -bm 0.5 tex\\wood.png").as_deref(),
            Some("tex/wood.png")
        );
        assert_eq!(
            texture_file_name("-imfchan r -clamp on x.png").as_deref(),
            Some("x.png")
        );
        assert_eq!(texture_file_name("-s 1 1"), None);
    }

    /// Deterministic garbling of valid OBJ/MTL text: truncations, replaced and deleted
    /// characters, spliced tokens. Loading must never panic (the guard around tobj would turn
    /// a panic into a "panicked" parse error, which the test also rejects).
    #[test]
    fn garbled_input_never_panics() {
        let dir = TempDir::new("obj-fuzz");
        let obj = "mtllib f.mtl\no a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\nusemtl m\nf 1/1/1 2/2/1 3/3/1\nf 2/2/1 4/1/1 3/3/1\ng b\nusemtl n\nf -1 -2 -3 -4\n";
        let mtl = "newmtl m\nKd 0.5 0.5 0.5\nKs 0.2 0.2 0.2\nNs 10\nillum 2\nmap_Kd t.png\nnewmtl n\nKe 1 1 1\nd 0.5\nTr 0.5\n";
        let tokens = [
            "",
            " ",
            "/",
            "//",
            "-",
            "-1",
            "0",
            "1e40",
            "nan",
            "inf",
            "-9999999999999999999",
            "99999",
            "f",
            "v",
            "vt",
            "vn",
            "usemtl",
            "Kd",
            "\t",
            "#",
            "\n",
            "é",
            "\u{0}",
            "4294967296",
            "-2147483648",
            "l 1 2 3",
            "illum 300",
            "map_Kd",
        ];
        let mut rng = crate::math::Rng::new(7, 0);
        let mut failures = Vec::new();
        let mut run = |obj_text: &str, mtl_text: &str| {
            let p = dir.write("f.obj", obj_text);
            dir.write("f.mtl", mtl_text);
            let mut b = SceneBuilder::new();
            match load_obj(&p, &mut b, None) {
                Err(e) if e.to_string().contains("panicked") => {
                    failures.push((obj_text.to_string(), mtl_text.to_string()))
                }
                Ok(_) => {
                    // Whatever was accepted must build.
                    b.build().unwrap();
                }
                Err(_) => {}
            }
        };
        for cut in (0..obj.len()).step_by(3) {
            run(&obj[..cut], mtl);
        }
        for cut in (0..mtl.len()).step_by(3) {
            run(obj, &mtl[..cut]);
        }
        for _ in 0..400 {
            let garble = |s: &str, rng: &mut crate::math::Rng| -> String {
                let mut s: Vec<char> = s.chars().collect();
                for _ in 0..1 + rng.below(4) {
                    let at = rng.below(s.len() as u32 + 1) as usize;
                    let t = tokens[rng.below(tokens.len() as u32) as usize];
                    match rng.below(3) {
                        0 => {
                            s.splice(at..at, t.chars());
                        }
                        1 if at < s.len() => {
                            s.remove(at);
                        }
                        _ => {
                            let end = (at + 1).min(s.len());
                            s.splice(at..end, t.chars());
                        }
                    }
                }
                s.into_iter().collect()
            };
            let o = garble(obj, &mut rng);
            let m = garble(mtl, &mut rng);
            run(&o, mtl);
            run(obj, &m);
        }
        assert!(
            failures.is_empty(),
            "inputs that made tobj panic: {failures:?}"
        );
    }

    fn repo_scene(rel: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("scenes")
            .join(rel)
    }

    #[test]
    fn cornell_box_obj_loads() {
        let mut b = SceneBuilder::new();
        let r = load_obj(
            &repo_scene("cornell-box/CornellBox-Original.obj"),
            &mut b,
            None,
        )
        .unwrap();
        assert_eq!((r.triangles, r.degenerate_skipped), (36, 0));
        assert!(r.warnings.is_empty(), "{:?}", r.warnings);
        assert_eq!(material(&mut b, &r, "light").emission, Rgb::splat(17.0));
        assert_eq!(
            material(&mut b, &r, "leftWall").diffuse,
            Rgb::new(0.63, 0.065, 0.05)
        );
        let scene = b.build().unwrap();
        assert_eq!(scene.lights().len(), 2);
    }
}
