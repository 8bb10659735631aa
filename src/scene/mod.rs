//! The scene: meshes, materials, textures, lights, camera and the BVH over them.
//!
//! Conventions, written once: right-handed world; radiance in W sr^-1 m^-2 as linear sRGB;
//! triangles are counter-clockwise seen from their front; when a mesh has vertex normals, a
//! triangle's front is the side its vertex normals point to (its geometric normal is flipped to
//! agree), otherwise the winding decides. Emissive triangles emit from their front only.
//! Camera space looks down -Z.

mod builder;
mod builtin;
mod camera;
mod corridor;
mod family;
mod file;
mod interaction;
mod interior;
mod material;
pub mod microfacet;
mod obj;
mod quad_mesh;
mod texture;

pub use builder::{DegeneratePolicy, MeshDesc, SceneBuilder};
pub use builtin::two_rooms_builder;
pub use camera::{Camera, CameraFrame};
pub use corridor::{corridor_builder, corridor_render_settings};
pub use family::{parse_family_name, FamilyLight, FamilyScene, Opening, Openness};
pub(crate) use file::json_error;
pub use file::{
    auto_camera, convert_layout, load_scene_arg, load_scene_file, LoadedScene, RenderSettingsFile,
};
pub use interaction::SurfaceInteraction;
pub use interior::{
    interior_builder, interior_many_windows_builder, interior_sky, interior_small_windows,
    interior_windows, write_interior_files, WindowAperture, MAX_SMALL_WINDOWS,
};
pub use material::{
    fresnel_dielectric, Bsdf, BsdfSample, Material, MaterialKind, TextureId, Transport,
};
pub use obj::{load_obj, ObjReport, DEFAULT_MATERIAL_NAME};
pub use texture::{srgb_to_linear, Texture};

use std::sync::{Arc, OnceLock};

use crate::geometry::{barycentric_point_error, Bounds3, Bvh, Hit, Ray};
use crate::light::environment::{InteriorMask, Portal, PortalSampler};
use crate::light::{
    EnvStrategy, EnvironmentMap, Light, LightSample, LightSampler, TriangleSampling,
};
use crate::math::{Frame, Rgb, Vec2, Vec3};

/// A triangle mesh as stored in the scene.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub name: String,
    pub positions: Vec<Vec3>,
    pub normals: Option<Vec<Vec3>>,
    pub uvs: Option<Vec<Vec2>>,
    pub indices: Vec<[u32; 3]>,
    /// Material index of each triangle.
    pub materials: Vec<u32>,
}

/// Where a global triangle index points.
#[derive(Clone, Copy, Debug)]
struct TriangleRef {
    mesh: u32,
    local: u32,
}

/// Memory held by each structure of a scene, in bytes.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MemoryReport {
    pub meshes: usize,
    pub bvh: usize,
    pub textures: usize,
    pub lights: usize,
}

impl MemoryReport {
    pub fn total(&self) -> usize {
        self.meshes + self.bvh + self.textures + self.lights
    }
}

/// Figures from building the scene.
#[derive(Clone, Debug, Default)]
pub struct BuildStats {
    pub triangles: usize,
    pub degenerate_triangles_skipped: usize,
    pub bvh_seconds: f64,
    pub bvh_nodes: usize,
}

/// Where the window portals of `env=portals` come from: those listed by hand (scene file
/// `portals`), or, when none is, those the analysis finds if `automatic`.
#[derive(Clone, Debug, PartialEq)]
pub struct PortalSettings {
    pub listed: Vec<Portal>,
    pub automatic: bool,
}

impl Default for PortalSettings {
    fn default() -> Self {
        PortalSettings {
            listed: Vec::new(),
            automatic: true,
        }
    }
}

/// The portal sampler a scene settled on (see [`Scene::env_portals_or_init`]).
#[derive(Clone, Debug)]
pub struct EnvPortals {
    /// None when there are no portals (or no environment): light sampling uses the fallback.
    pub sampler: Option<Arc<PortalSampler>>,
    /// Whether the portals came from the analysis (else from the scene's list).
    pub automatic: bool,
}

/// An immutable, committed scene. `Send + Sync`: any number of threads may query it.
///
/// Geometry, materials and the BVH are shared (`Arc`) so that [`Scene::with_environment`] can
/// light the same scene with a new environment map without copying them.
pub struct Scene {
    meshes: Arc<Vec<Mesh>>,
    triangles: Arc<Vec<TriangleRef>>,
    /// Unit geometric normal of each global triangle, oriented as the conventions above say.
    geometric_normals: Arc<Vec<Vec3>>,
    materials: Arc<Vec<Material>>,
    textures: Arc<Vec<Texture>>,
    bvh: Arc<Bvh>,
    lights: Vec<Light>,
    light_sampler: Option<LightSampler>,
    /// Index in `lights` of the environment map, if any.
    environment: Option<u32>,
    /// Light index of each global triangle (`u32::MAX` when it does not emit); empty when the
    /// scene has no area lights.
    triangle_light: Arc<Vec<u32>>,
    camera: Option<Camera>,
    portals: Arc<PortalSettings>,
    /// Built once, by the first integrator that asks (`env=portals`), for this scene's
    /// environment map.
    env_portals: OnceLock<EnvPortals>,
    bounds: Bounds3,
    stats: BuildStats,
}

impl Scene {
    pub fn meshes(&self) -> &[Mesh] {
        &self.meshes
    }

    pub fn materials(&self) -> &[Material] {
        &self.materials
    }

    pub fn textures(&self) -> &[Texture] {
        &self.textures
    }

    pub fn lights(&self) -> &[Light] {
        &self.lights
    }

    pub fn light_sampler(&self) -> Option<&LightSampler> {
        self.light_sampler.as_ref()
    }

    /// The same scene lit by environment map `map` instead of its own (`None`: no map).
    /// Everything but the lights and the light sampler is shared; O(lights).
    pub fn with_environment(&self, map: Option<Arc<EnvironmentMap>>) -> Scene {
        // The environment is always the last light, so area-light indices stay valid.
        let mut lights: Vec<Light> = self
            .lights
            .iter()
            .filter(|l| !matches!(l, Light::Environment { .. }))
            .cloned()
            .collect();
        let environment = map.map(|m| {
            lights.push(builder::environment_light(m, &self.bounds));
            (lights.len() - 1) as u32
        });
        Scene {
            meshes: self.meshes.clone(),
            triangles: self.triangles.clone(),
            geometric_normals: self.geometric_normals.clone(),
            materials: self.materials.clone(),
            textures: self.textures.clone(),
            bvh: self.bvh.clone(),
            light_sampler: LightSampler::new(&lights),
            lights,
            environment,
            triangle_light: self.triangle_light.clone(),
            camera: self.camera,
            portals: self.portals.clone(),
            env_portals: OnceLock::new(),
            bounds: self.bounds,
            stats: self.stats.clone(),
        }
    }

    /// The environment map and its index among the lights.
    #[inline]
    pub fn environment(&self) -> Option<(usize, &EnvironmentMap)> {
        let i = self.environment? as usize;
        match &self.lights[i] {
            Light::Environment { map, .. } => Some((i, map)),
            _ => None,
        }
    }

    /// The window portals listed by hand, and whether automatic ones are allowed.
    pub fn portal_settings(&self) -> &PortalSettings {
        &self.portals
    }

    /// The environment's portal sampler, built on the first call: from the portals listed by
    /// hand, or when there are none and automatic portals are allowed, from those `find`
    /// returns with the interior they apply in (the analysis lives above the scene, so the
    /// integrator hands it in).
    pub fn env_portals_or_init(
        &self,
        find: impl FnOnce(&Scene) -> crate::error::Result<(Vec<Portal>, Option<InteriorMask>)>,
    ) -> crate::error::Result<&EnvPortals> {
        if let Some(p) = self.env_portals.get() {
            return Ok(p);
        }
        let (portals, interior, automatic) = if !self.portals.listed.is_empty() {
            (self.portals.listed.clone(), None, false)
        } else if self.portals.automatic && self.environment().is_some() {
            let (portals, interior) = find(self)?;
            (portals, interior, true)
        } else {
            (Vec::new(), None, false)
        };
        let sampler = match self.environment() {
            Some((_, map)) if !portals.is_empty() => Some(Arc::new(PortalSampler::build_masked(
                map, &portals, interior,
            )?)),
            _ => None,
        };
        Ok(self
            .env_portals
            .get_or_init(|| EnvPortals { sampler, automatic }))
    }

    /// The portal sampler, once [`env_portals_or_init`](Self::env_portals_or_init) built one.
    #[inline]
    pub fn env_portals(&self) -> Option<&PortalSampler> {
        self.env_portals.get()?.sampler.as_deref()
    }

    /// The density with which light sampling with strategy `env` at `point` (facing normal
    /// `normal`) draws environment direction `dir`, the light's pmf excluded; 0 without an
    /// environment.
    #[inline]
    pub fn environment_pdf_at(
        &self,
        env: EnvStrategy,
        point: Vec3,
        normal: Vec3,
        dir: Vec3,
    ) -> f32 {
        let Some((_, map)) = self.environment() else {
            return 0.0;
        };
        match (env, self.env_portals()) {
            (EnvStrategy::Portals, Some(portals)) => portals.pdf(map, point, normal, dir),
            _ => map.pdf(env, normal, dir),
        }
    }

    pub fn camera(&self) -> Option<&Camera> {
        self.camera.as_ref()
    }

    pub fn bounds(&self) -> Bounds3 {
        self.bounds
    }

    pub fn stats(&self) -> &BuildStats {
        &self.stats
    }

    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    pub fn bvh(&self) -> &Bvh {
        &self.bvh
    }

    /// The three vertices of global triangle `tri`.
    pub fn triangle_vertices(&self, tri: u32) -> [Vec3; 3] {
        let r = self.triangles[tri as usize];
        let m = &self.meshes[r.mesh as usize];
        let idx = m.indices[r.local as usize];
        [
            m.positions[idx[0] as usize],
            m.positions[idx[1] as usize],
            m.positions[idx[2] as usize],
        ]
    }

    pub fn geometric_normal(&self, tri: u32) -> Vec3 {
        self.geometric_normals[tri as usize]
    }

    /// The light a triangle belongs to, if it emits.
    #[inline]
    pub fn triangle_light(&self, tri: u32) -> Option<usize> {
        match self.triangle_light.get(tri as usize) {
            Some(&l) if l != u32::MAX => Some(l as usize),
            _ => None,
        }
    }

    pub fn memory(&self) -> MemoryReport {
        let meshes = self
            .meshes
            .iter()
            .map(|m| {
                m.positions.len() * 12
                    + m.normals.as_ref().map_or(0, |n| n.len() * 12)
                    + m.uvs.as_ref().map_or(0, |u| u.len() * 8)
                    + m.indices.len() * 12
                    + m.materials.len() * 4
            })
            .sum::<usize>()
            + self.triangles.len() * std::mem::size_of::<TriangleRef>()
            + self.geometric_normals.len() * 12;
        MemoryReport {
            meshes,
            bvh: self.bvh.memory_bytes(),
            textures: self.textures.iter().map(Texture::memory_bytes).sum(),
            lights: self.lights.len() * std::mem::size_of::<Light>()
                + self.triangle_light.len() * 4
                + self
                    .light_sampler
                    .as_ref()
                    .map_or(0, LightSampler::memory_bytes)
                + self.environment().map_or(0, |(_, e)| e.memory_bytes()),
        }
    }

    /// Closest hit of a ray.
    #[inline]
    pub fn intersect_hit(&self, ray: &Ray) -> Option<Hit> {
        self.bvh.intersect(ray)
    }

    /// True when anything blocks the ray in (0, t_max).
    #[inline]
    pub fn occluded(&self, ray: &Ray) -> bool {
        self.bvh.occluded(ray)
    }

    /// Closest hit of a ray with everything a shader needs.
    #[inline(always)]
    pub fn intersect(&self, ray: &Ray) -> Option<SurfaceInteraction> {
        let hit = self.bvh.intersect(ray)?;
        Some(self.interaction(ray, &hit))
    }

    /// Builds the surface interaction of a hit.
    #[inline(always)]
    pub fn interaction(&self, ray: &Ray, hit: &Hit) -> SurfaceInteraction {
        let r = self.triangles[hit.triangle as usize];
        let m = &self.meshes[r.mesh as usize];
        let idx = m.indices[r.local as usize];
        let (i0, i1, i2) = (idx[0] as usize, idx[1] as usize, idx[2] as usize);
        let p = [m.positions[i0], m.positions[i1], m.positions[i2]];
        let b = [1.0 - hit.b1 - hit.b2, hit.b1, hit.b2];
        let point = p[0] * b[0] + p[1] * b[1] + p[2] * b[2];
        let ng = self.geometric_normals[hit.triangle as usize];
        let ns = match &m.normals {
            Some(n) => {
                let s = n[i0] * b[0] + n[i1] * b[1] + n[i2] * b[2];
                let s = s.normalize_or_zero();
                if s == Vec3::ZERO {
                    ng
                } else {
                    s
                }
            }
            None => ng,
        };
        let uv = match &m.uvs {
            Some(t) => t[i0] * b[0] + t[i1] * b[1] + t[i2] * b[2],
            None => Vec2::new(hit.b1, hit.b2),
        };
        SurfaceInteraction {
            p: point,
            p_error: barycentric_point_error(p, b),
            ng,
            ns,
            uv,
            wo: -ray.dir,
            t: hit.t,
            triangle: hit.triangle,
            material: m.materials[r.local as usize],
        }
    }

    /// The BSDF at an interaction (texture lookups resolved).
    #[inline(always)]
    pub fn bsdf(&self, si: &SurfaceInteraction) -> Bsdf {
        let mat = &self.materials[si.material as usize];
        let diffuse = match mat.diffuse_texture {
            Some(t) => self.textures[t as usize].lookup(si.uv) * mat.diffuse,
            None => mat.diffuse,
        };
        mat.bsdf(diffuse)
    }

    /// Radiance emitted by the surface of `si` towards `si.wo`.
    #[inline]
    pub fn emitted(&self, si: &SurfaceInteraction) -> Rgb {
        match self.triangle_light(si.triangle) {
            Some(l) => self.lights[l].emitted(si.wo),
            None => Rgb::ZERO,
        }
    }

    /// The unshadowed part of one next-event sample at `si` (shading `frame`, `bsdf`, `wo_local`
    /// = `si.wo` in that frame): a light picked by power with `u.x`, a point or direction on
    /// it from `u` with `u.x` rescaled within the chosen light's share
    /// ([`LightSampler::sample_reuse`], so a stratified `u` stays stratified over each light),
    /// and the BSDF term f |cos| toward it. `env` and `triangles` say how environment maps and
    /// emissive triangles are sampled ([`Light::sample_with`]). None when it cannot contribute (no
    /// lights, no sample, the light on the other side of the geometric surface from the one
    /// the shading frame scatters to ([`SurfaceInteraction::scatters_toward`]), or a zero BSDF
    /// term). The caller
    /// traces the shadow ray ([`unoccluded`](Self::unoccluded)) and weights the result.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub fn sample_light_toward(
        &self,
        si: &SurfaceInteraction,
        frame: &Frame,
        bsdf: &Bsdf,
        wo_local: Vec3,
        env: EnvStrategy,
        triangles: TriangleSampling,
        u: Vec2,
    ) -> Option<LightTowardSample> {
        let (index, pmf, u_light) = self.light_sampler()?.sample_reuse(u.x);
        let u = Vec2::new(u_light, u.y);
        let sample = self.sample_light_at(index, si.p, si.facing_normal(), env, triangles, u)?;
        let wi_local = frame.to_local(sample.wi);
        if !si.scatters_toward(sample.wi, wo_local, wi_local) {
            return None;
        }
        let f_cos = bsdf.eval(wo_local, wi_local, Transport::Radiance) * wi_local.z.abs();
        (f_cos != Rgb::ZERO).then_some(LightTowardSample {
            sample,
            pmf,
            wi_local,
            f_cos,
        })
    }

    /// Samples light `index` for a receiver at `point` (facing normal `normal`, zero when
    /// unknown): [`Light::sample_with`], except that with `env=portals` the environment is
    /// drawn through the window portals `point` sees, once they are built
    /// ([`env_portals_or_init`](Self::env_portals_or_init)).
    #[inline(always)]
    pub fn sample_light_at(
        &self,
        index: usize,
        point: Vec3,
        normal: Vec3,
        env: EnvStrategy,
        triangles: TriangleSampling,
        u: Vec2,
    ) -> Option<LightSample> {
        match (env, self.env_portals()) {
            (EnvStrategy::Portals, Some(portals)) if Some(index as u32) == self.environment => {
                let (_, map) = self.environment()?;
                let s = portals.sample(map, point, normal, u)?;
                Some(LightSample::from_environment(s, point))
            }
            _ => self.lights[index].sample_with(point, normal, env, triangles, u),
        }
    }

    /// Whether nothing blocks the segment from a surface point to a sampled light point.
    #[inline(always)]
    pub fn unoccluded(&self, si: &SurfaceInteraction, sample: &LightSample) -> bool {
        let ray = if sample.distance.is_infinite() {
            si.spawn_ray(sample.wi)
        } else {
            si.spawn_ray_to(sample.point, sample.point_error, sample.normal)
        };
        // Next-event shadow rays of one path come one after another on one thread.
        !self.bvh.occluded_coherent(&ray)
    }
}

/// One next-event sample before its shadow ray ([`Scene::sample_light_toward`]).
#[derive(Clone, Copy, Debug)]
pub struct LightTowardSample {
    pub sample: LightSample,
    /// Probability of having picked this light.
    pub pmf: f32,
    /// The light direction in the shading frame.
    pub wi_local: Vec3,
    /// f(wo, wi) |cos(wi)|.
    pub f_cos: Rgb,
}
