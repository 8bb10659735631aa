//! `SceneBuilder`: collects and validates everything a scene is made of, then builds the
//! immutable `Scene` (BVH, lights, light sampler). Every input is checked; a bad one gives an
//! error naming it, never a panic.

use std::sync::Arc;
use std::time::Instant;

use super::{BuildStats, Camera, Material, Mesh, Scene, Texture, TriangleRef};
use crate::error::{Error, Result};
use crate::geometry::{Bounds3, Bvh, BvhQuality};
use crate::light::{EnvironmentMap, Light, LightDesc, LightSampler};
use crate::math::{is_finite3, Vec2, Vec3};

/// What to do with zero-area triangles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DegeneratePolicy {
    /// Refuse the mesh (the default for data handed over by a program).
    #[default]
    Error,
    /// Drop them and count them in `BuildStats` (real assets contain a few).
    Skip,
}

/// A mesh as handed to the builder.
#[derive(Clone, Debug, Default)]
pub struct MeshDesc {
    pub name: String,
    pub positions: Vec<Vec3>,
    /// One per position, or empty.
    pub normals: Vec<Vec3>,
    /// One per position, or empty.
    pub uvs: Vec<Vec2>,
    pub indices: Vec<[u32; 3]>,
    /// One material index per triangle, or a single one for the whole mesh.
    pub materials: Vec<u32>,
}

/// Largest accepted coordinate magnitude. Far beyond any real scene (the renderer is tested
/// at scales 1e-4 to 1e4), and small enough that the BVH builders' surface areas (squares of
/// extents, summed over nodes) stay finite in f32: obvhs's PLOC build indexes out of bounds on
/// triangles near 1e29, where those areas overflow.
pub const MAX_COORDINATE: f32 = 1e15;

#[derive(Default)]
pub struct SceneBuilder {
    meshes: Vec<Mesh>,
    materials: Vec<Material>,
    textures: Vec<Texture>,
    lights: Vec<LightDesc>,
    environment: Option<Arc<EnvironmentMap>>,
    camera: Option<Camera>,
    portals: super::PortalSettings,
    degenerate_policy: DegeneratePolicy,
    bvh_quality: BvhQuality,
    degenerate_skipped: usize,
}

impl SceneBuilder {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn set_degenerate_policy(&mut self, policy: DegeneratePolicy) {
        self.degenerate_policy = policy;
    }

    pub fn degenerate_policy(&self) -> DegeneratePolicy {
        self.degenerate_policy
    }

    /// Zero-area triangles dropped so far under `DegeneratePolicy::Skip`.
    pub fn degenerate_skipped(&self) -> usize {
        self.degenerate_skipped
    }

    pub fn set_bvh_quality(&mut self, quality: BvhQuality) {
        self.bvh_quality = quality;
    }

    pub fn material_count(&self) -> usize {
        self.materials.len()
    }

    pub fn materials_mut(&mut self) -> &mut [Material] {
        &mut self.materials
    }

    pub fn has_camera(&self) -> bool {
        self.camera.is_some()
    }

    pub fn texture_count(&self) -> usize {
        self.textures.len()
    }

    /// Adds a texture and returns its index.
    pub fn add_texture(&mut self, texture: Texture) -> u32 {
        self.textures.push(texture);
        (self.textures.len() - 1) as u32
    }

    /// Adds a material (validated) and returns its index.
    pub fn add_material(&mut self, material: Material) -> Result<u32> {
        material.validate(self.textures.len())?;
        self.materials.push(material);
        Ok((self.materials.len() - 1) as u32)
    }

    /// Replaces material `index` (validated): scene files override loaded materials this way.
    pub fn set_material(&mut self, index: u32, material: Material) -> Result<()> {
        material.validate(self.textures.len())?;
        let n = self.materials.len();
        let slot = self.materials.get_mut(index as usize).ok_or_else(|| {
            Error::invalid(format!(
                "material index {index} out of range ({n} materials)"
            ))
        })?;
        *slot = material;
        Ok(())
    }

    pub fn add_light(&mut self, light: LightDesc) -> Result<()> {
        light.validate()?;
        self.lights.push(light);
        Ok(())
    }

    /// Sets (or with `None` removes) the environment map lighting the scene from infinity.
    pub fn set_environment(&mut self, map: Option<Arc<EnvironmentMap>>) {
        self.environment = map;
    }

    /// The window portals for environment light (`env=portals`): listed by hand, and whether
    /// the analysis may find them when none is listed.
    pub fn set_portals(&mut self, portals: super::PortalSettings) {
        self.portals = portals;
    }

    pub fn environment(&self) -> Option<&Arc<EnvironmentMap>> {
        self.environment.as_ref()
    }

    pub fn set_camera(&mut self, camera: Camera) -> Result<()> {
        camera.validate()?;
        self.camera = Some(camera);
        Ok(())
    }

    /// Adds a mesh after checking every value; returns its index.
    pub fn add_mesh(&mut self, desc: MeshDesc) -> Result<u32> {
        let name = if desc.name.is_empty() {
            format!("mesh {}", self.meshes.len())
        } else {
            desc.name.clone()
        };
        let nv = desc.positions.len();
        if let Some(i) = desc.positions.iter().position(|p| !is_finite3(*p)) {
            return Err(Error::invalid(format!(
                "{name}: position {i} is {} (must be finite)",
                desc.positions[i]
            )));
        }
        if let Some(i) = desc
            .positions
            .iter()
            .position(|p| p.abs().max_element() > MAX_COORDINATE)
        {
            return Err(Error::invalid(format!(
                "{name}: position {i} is {} (coordinates must be within +-{MAX_COORDINATE:e})",
                desc.positions[i]
            )));
        }
        if !desc.normals.is_empty() && desc.normals.len() != nv {
            return Err(Error::invalid(format!(
                "{name}: {} normals for {nv} positions",
                desc.normals.len()
            )));
        }
        if let Some(i) = desc.normals.iter().position(|n| !is_finite3(*n)) {
            return Err(Error::invalid(format!(
                "{name}: normal {i} is {} (must be finite)",
                desc.normals[i]
            )));
        }
        if !desc.uvs.is_empty() && desc.uvs.len() != nv {
            return Err(Error::invalid(format!(
                "{name}: {} uvs for {nv} positions",
                desc.uvs.len()
            )));
        }
        if let Some(i) = desc
            .uvs
            .iter()
            .position(|t| !(t.x.is_finite() && t.y.is_finite()))
        {
            return Err(Error::invalid(format!(
                "{name}: uv {i} is {} (must be finite)",
                desc.uvs[i]
            )));
        }
        let nt = desc.indices.len();
        if desc.materials.len() != nt && desc.materials.len() != 1 {
            return Err(Error::invalid(format!(
                "{name}: {} material indices for {nt} triangles (give one per triangle or one for all)",
                desc.materials.len()
            )));
        }
        if let Some(&m) = desc
            .materials
            .iter()
            .find(|&&m| m as usize >= self.materials.len())
        {
            return Err(Error::invalid(format!(
                "{name}: material index {m} out of range ({} materials)",
                self.materials.len()
            )));
        }
        let mut indices = Vec::with_capacity(nt);
        let mut materials = Vec::with_capacity(nt);
        for (t, tri) in desc.indices.iter().enumerate() {
            if let Some(&i) = tri.iter().find(|&&i| i as usize >= nv) {
                return Err(Error::invalid(format!(
                    "{name}: triangle {t} has vertex index {i} out of range ({nv} positions)"
                )));
            }
            let p = tri.map(|i| desc.positions[i as usize]);
            if (p[1] - p[0]).cross(p[2] - p[0]).length_squared() == 0.0 {
                match self.degenerate_policy {
                    DegeneratePolicy::Error => {
                        return Err(Error::invalid(format!(
                            "{name}: triangle {t} {tri:?} is degenerate (zero area)"
                        )));
                    }
                    DegeneratePolicy::Skip => {
                        self.degenerate_skipped += 1;
                        continue;
                    }
                }
            }
            indices.push(*tri);
            materials.push(if desc.materials.len() == 1 {
                desc.materials[0]
            } else {
                desc.materials[t]
            });
        }
        let normals = if desc.normals.is_empty() {
            None
        } else {
            Some(desc.normals.iter().map(|n| n.normalize_or_zero()).collect())
        };
        self.meshes.push(Mesh {
            name,
            positions: desc.positions,
            normals,
            uvs: if desc.uvs.is_empty() {
                None
            } else {
                Some(desc.uvs)
            },
            indices,
            materials,
        });
        Ok((self.meshes.len() - 1) as u32)
    }

    /// Builds the scene: orients normals, builds the BVH, makes emissive triangles area lights
    /// and the power-proportional light sampler. Only what the content needs is built.
    pub fn build(self) -> Result<Scene> {
        let mut triangles = Vec::new();
        let mut vertices = Vec::new();
        let mut geometric_normals = Vec::new();
        let mut bounds = Bounds3::EMPTY;
        for (mi, m) in self.meshes.iter().enumerate() {
            for (ti, idx) in m.indices.iter().enumerate() {
                let p = idx.map(|i| m.positions[i as usize]);
                let mut ng = (p[1] - p[0]).cross(p[2] - p[0]).normalize();
                if let Some(n) = &m.normals {
                    let avg = n[idx[0] as usize] + n[idx[1] as usize] + n[idx[2] as usize];
                    if avg.dot(ng) < 0.0 {
                        ng = -ng;
                    }
                }
                bounds = p.iter().fold(bounds, |b, &q| b.union_point(q));
                triangles.push(TriangleRef {
                    mesh: mi as u32,
                    local: ti as u32,
                });
                vertices.push(p);
                geometric_normals.push(ng);
            }
        }
        if triangles.len() > u32::MAX as usize - 1 {
            return Err(Error::invalid(format!(
                "{} triangles exceed the limit of 2^32 - 2",
                triangles.len()
            )));
        }
        let start = Instant::now();
        let bvh = Bvh::build(&vertices, self.bvh_quality);
        let bvh_seconds = start.elapsed().as_secs_f64();

        let mut lights = Vec::new();
        let mut triangle_light = Vec::new();
        for (g, tref) in triangles.iter().enumerate() {
            let m = &self.meshes[tref.mesh as usize];
            let mat = &self.materials[m.materials[tref.local as usize] as usize];
            if mat.is_emissive() {
                if triangle_light.is_empty() {
                    triangle_light = vec![u32::MAX; triangles.len()];
                }
                let p = vertices[g];
                let area = 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length();
                triangle_light[g] = lights.len() as u32;
                lights.push(Light::Area {
                    triangle: g as u32,
                    p,
                    normal: geometric_normals[g],
                    area,
                    radiance: mat.emission,
                });
            }
        }
        for desc in &self.lights {
            lights.push(Light::from_desc(desc, &bounds));
        }
        let environment = self.environment.map(|map| {
            lights.push(environment_light(map, &bounds));
            (lights.len() - 1) as u32
        });
        let light_sampler = LightSampler::new(&lights);
        let stats = BuildStats {
            triangles: triangles.len(),
            degenerate_triangles_skipped: self.degenerate_skipped,
            bvh_seconds,
            bvh_nodes: bvh.node_count(),
        };
        Ok(Scene {
            meshes: Arc::new(self.meshes),
            triangles: Arc::new(triangles),
            geometric_normals: Arc::new(geometric_normals),
            materials: Arc::new(self.materials),
            textures: Arc::new(self.textures),
            bvh: Arc::new(bvh),
            lights,
            light_sampler,
            environment,
            triangle_light: Arc::new(triangle_light),
            camera: self.camera,
            portals: Arc::new(self.portals),
            env_portals: Default::default(),
            bounds,
            stats,
        })
    }
}

/// The environment as a light around the scene's bounding sphere (a unit sphere at the
/// origin when the scene has no geometry).
pub(super) fn environment_light(map: Arc<EnvironmentMap>, bounds: &Bounds3) -> Light {
    let (center, radius) = if bounds.is_empty() {
        (Vec3::ZERO, 1.0)
    } else {
        bounds.bounding_sphere()
    };
    Light::Environment {
        map,
        scene_center: center,
        scene_radius: radius.max(1e-6),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one_triangle(corner: f32) -> MeshDesc {
        MeshDesc {
            name: "tri".into(),
            positions: vec![Vec3::new(corner, 0.0, 0.0), Vec3::X, Vec3::Y],
            indices: vec![[0, 1, 2]],
            materials: vec![0],
            ..Default::default()
        }
    }

    #[test]
    fn positions_must_be_finite_and_within_the_coordinate_bound() {
        let mut builder = SceneBuilder::new();
        builder
            .add_material(Material::diffuse(crate::math::Rgb::splat(0.5)))
            .unwrap();
        assert!(builder.add_mesh(one_triangle(-1e4)).is_ok());
        for bad in [f32::NAN, f32::INFINITY, 1e29, -2e15] {
            let message = builder.add_mesh(one_triangle(bad)).unwrap_err().to_string();
            assert!(message.contains("tri: position 0"), "{message}");
        }
    }
}
