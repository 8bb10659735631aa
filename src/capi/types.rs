//! Plain C structs and the enums whose values C passes as `uint32_t` (validated on arrival).

use super::boundary::{CapiError, CapiResult};
use crate::math::{Rgb, Vec3};

/// A 3D point or vector.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct lacuna_vec3 {
    pub x: f32,
    pub y: f32,
    pub z: f32,
}

/// A linear sRGB colour (radiance, albedo or intensity depending on the call).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct lacuna_rgb {
    pub r: f32,
    pub g: f32,
    pub b: f32,
}

impl lacuna_vec3 {
    pub(crate) fn finite(self, name: &str) -> CapiResult<Vec3> {
        let v = Vec3::new(self.x, self.y, self.z);
        if v.is_finite() {
            Ok(v)
        } else {
            Err(CapiError::invalid(format!(
                "`{name}` ({}, {}, {}) must be finite",
                self.x, self.y, self.z
            )))
        }
    }
}

impl From<Vec3> for lacuna_vec3 {
    fn from(v: Vec3) -> Self {
        lacuna_vec3 {
            x: v.x,
            y: v.y,
            z: v.z,
        }
    }
}

impl lacuna_rgb {
    pub(crate) fn finite(self, name: &str) -> CapiResult<Rgb> {
        let v = Rgb::new(self.r, self.g, self.b);
        if v.is_finite() {
            Ok(v)
        } else {
            Err(CapiError::invalid(format!(
                "`{name}` ({}, {}, {}) must be finite",
                self.r, self.g, self.b
            )))
        }
    }
}

/// Index value meaning "none" (e.g. `lacuna_hit.triangle` of a ray that hit nothing).
pub const LACUNA_INVALID_INDEX: u32 = u32::MAX;

/// A ray for the scene queries. The layout (32 bytes, 4-byte aligned) never changes with build
/// options. Fill it with `lacuna_ray_init()` then set the fields.
///
/// The ray covers the open interval (0, tmax) of `origin + t * direction`. `direction` need
/// not be unit length: distances are measured in units of its length. `origin` and
/// `direction` must be finite and `direction` non-zero; `tmax` must not be NaN or negative
/// (infinity is fine). `flags` is reserved and must be 0.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct lacuna_ray {
    pub origin: [f32; 3],
    pub tmax: f32,
    pub direction: [f32; 3],
    pub flags: u32,
}

/// The closest hit of a ray. The layout (36 bytes, 4-byte aligned) never changes with build
/// options. A ray that hits nothing gets `triangle == mesh == mesh_triangle ==
/// LACUNA_INVALID_INDEX` and `t` = +infinity.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct lacuna_hit {
    /// Ray parameter of the hit, in units of the ray direction's length.
    pub t: f32,
    /// Barycentric coordinates of vertices 1 and 2 (vertex 0 has `1 - u - v`).
    pub u: f32,
    pub v: f32,
    /// Global triangle index (meshes in the order they were added, triangles in order).
    pub triangle: u32,
    /// Index of the mesh, as returned when it was added.
    pub mesh: u32,
    /// Index of the triangle within its mesh (degenerate triangles skipped while loading are
    /// not counted).
    pub mesh_triangle: u32,
    /// Unit geometric normal on the triangle's front side (see the scene conventions).
    pub geometric_normal: [f32; 3],
}

impl lacuna_hit {
    pub(crate) const MISS: lacuna_hit = lacuna_hit {
        t: f32::INFINITY,
        u: 0.0,
        v: 0.0,
        triangle: LACUNA_INVALID_INDEX,
        mesh: LACUNA_INVALID_INDEX,
        mesh_triangle: LACUNA_INVALID_INDEX,
        geometric_normal: [0.0; 3],
    };
}

/// Bytes held by each structure of a committed scene.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct lacuna_memory_report {
    /// Vertex, index and per-triangle data.
    pub meshes: usize,
    /// The acceleration structure.
    pub bvh: usize,
    pub textures: usize,
    /// Lights and the light sampler.
    pub lights: usize,
    /// Sum of the above.
    pub total: usize,
}

/// Figures from building a scene.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct lacuna_scene_stats {
    pub meshes: usize,
    pub triangles: usize,
    pub degenerate_triangles_skipped: usize,
    pub lights: usize,
    pub materials: usize,
    pub bvh_nodes: usize,
    pub bvh_build_seconds: f64,
    /// Axis-aligned bounds of all triangles (min > max when the scene is empty).
    pub bounds_min: lacuna_vec3,
    pub bounds_max: lacuna_vec3,
}

/// Figures of a finished (or cancelled) render.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct lacuna_render_stats {
    pub seconds: f64,
    /// Samples per pixel reached.
    pub spp: u32,
    pub passes: u32,
    pub samples: u64,
    pub rays: u64,
    pub cancelled: bool,
    /// Seconds the integrator's per-scene precomputation took before the render (the skeleton
    /// guide of `path_skeleton`; 0 for integrators that need none). Not part of `seconds`.
    pub precompute_seconds: f64,
}

/// Estimated errors of an image (mean absolute error, root mean square error, relative MSE).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct lacuna_image_errors {
    pub mae: f64,
    pub rmse: f64,
    pub rel_mse: f64,
}

/// Reflection models (`lacuna_scene_builder_add_material`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_material_kind {
    /// Lambertian, albedo DIFFUSE (default 0.5 grey).
    Diffuse = 0,
    /// Modified Phong: DIFFUSE + SPECULAR lobe with EXPONENT (DIFFUSE + SPECULAR <= 1).
    Glossy = 1,
    /// Perfect mirror with reflectance SPECULAR.
    Mirror = 2,
    /// Smooth glass with index of refraction IOR.
    Dielectric = 3,
    /// Frosted glass: index of refraction IOR, GGX microfacet width ROUGHNESS (default 0.3).
    RoughDielectric = 4,
}

/// Colour parameters of a material (`lacuna_scene_builder_set_material_rgb`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_material_rgb {
    /// Diffuse albedo, each channel in [0, 1].
    Diffuse = 0,
    /// Specular reflectance, each channel in [0, 1].
    Specular = 1,
    /// Emitted radiance (W sr^-1 m^-2), >= 0: triangles using the material become area lights.
    Emission = 2,
}

/// Scalar parameters of a material (`lacuna_scene_builder_set_material_float`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_material_float {
    /// Phong exponent in [0, 1e6].
    Exponent = 0,
    /// Index of refraction, > 0.
    Ior = 1,
    /// GGX width alpha of ROUGH_DIELECTRIC in [0, 1] (below 1e-3 rendered as 1e-3).
    Roughness = 2,
}

/// What to do with zero-area triangles (`lacuna_scene_builder_set_degenerate_policy`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_degenerate_policy {
    /// Refuse the mesh (the default).
    Error = 0,
    /// Drop them and count them in `lacuna_scene_stats`.
    Skip = 1,
}

/// Acceleration structure build quality (`lacuna_scene_builder_set_bvh_quality`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_bvh_quality {
    Fast = 0,
    /// The default.
    Medium = 1,
    High = 2,
}

/// Multiple importance sampling heuristic (`lacuna_render_job_set_mis_heuristic`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_mis_heuristic {
    Balance = 0,
    /// Power heuristic, exponent 2 (the default).
    Power = 1,
    /// `env_direct` and `path`: the split of light and BSDF samples of thesis 001 chapter 5
    /// (a warm-up, then the rest split by the estimated fraction; per shading point in
    /// `env_direct`, per pixel in `path`). Other integrators refuse it when the render starts
    /// (`LACUNA_STATUS_INVALID_ARGUMENT`).
    Auto = 2,
    /// `env_direct` only: optimal MIS weights (Kondapaneni et al. 2019), estimated on a
    /// warm-up half of the samples. Other integrators (`path` among them) refuse it as for
    /// `Auto`.
    Optimal = 3,
}

/// The one mapping between the C values and the Rust heuristics, both ways.
impl From<lacuna_mis_heuristic> for crate::integrator::MisHeuristic {
    fn from(h: lacuna_mis_heuristic) -> Self {
        match h {
            lacuna_mis_heuristic::Balance => Self::Balance,
            lacuna_mis_heuristic::Power => Self::Power,
            lacuna_mis_heuristic::Auto => Self::Auto,
            lacuna_mis_heuristic::Optimal => Self::Optimal,
        }
    }
}

impl From<crate::integrator::MisHeuristic> for lacuna_mis_heuristic {
    fn from(h: crate::integrator::MisHeuristic) -> Self {
        use crate::integrator::MisHeuristic;
        match h {
            MisHeuristic::Balance => Self::Balance,
            MisHeuristic::Power => Self::Power,
            MisHeuristic::Auto => Self::Auto,
            MisHeuristic::Optimal => Self::Optimal,
        }
    }
}

/// How `lacuna_render_job_compare` runs its contenders
/// (`lacuna_render_job_set_compare_schedule`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_compare_schedule {
    /// One after the other, each with all of the job's threads (the default); the order
    /// rotates each run.
    Sequential = 0,
    /// All at once, each with the job's thread count, for the same wall-clock time: on a
    /// shared machine whose load changes, every contender meets the same load, so their
    /// ratios hold where one-after-the-other runs can be moved by a change between them.
    Concurrent = 1,
}

/// The one mapping between the C values and the Rust schedules, both ways.
impl From<lacuna_compare_schedule> for crate::compare::Schedule {
    fn from(s: lacuna_compare_schedule) -> Self {
        match s {
            lacuna_compare_schedule::Sequential => Self::Sequential,
            lacuna_compare_schedule::Concurrent => Self::Concurrent,
        }
    }
}

impl From<crate::compare::Schedule> for lacuna_compare_schedule {
    fn from(s: crate::compare::Schedule) -> Self {
        use crate::compare::Schedule;
        match s {
            Schedule::Sequential => Self::Sequential,
            Schedule::Concurrent => Self::Concurrent,
        }
    }
}

/// Numbers of the pixel samples (`lacuna_render_job_set_sampler`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_sampler {
    /// Owen-scrambled Sobol points, stratified over each pixel's samples (best at powers of
    /// two samples per pixel).
    Sobol = 0,
    /// Independent random numbers per pixel sample (the default).
    Independent = 1,
}

/// Film channels (`lacuna_film_read`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_film_channel {
    /// Mean radiance, 3 floats (RGB) per pixel.
    Radiance = 0,
    /// Mean first-hit albedo, 3 floats.
    Albedo = 1,
    /// Mean first-hit shading normal, 3 floats (not renormalised; zero where nothing was hit).
    Normal = 2,
    /// Mean first-hit distance, 1 float (zero where nothing was hit).
    Depth = 3,
    /// Camera samples taken, 1 float per pixel.
    SampleCount = 4,
}

/// Layout of an environment map handed over as floats (`lacuna_environment_new_from_buffer`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_environment_layout {
    /// Latitude-longitude, width = 2 x height, row 0 at the zenith, the middle column straight
    /// ahead (-Z for a Y-up map), +X a quarter turn to the right.
    LatLong = 0,
    /// Horizontal cross of cube faces, width = 4/3 x height: -X, -Z, +X, +Z in the middle
    /// row, +Y above -Z, -Y below it; black outside the faces.
    CubeCross = 1,
}

/// How light sampling picks environment directions (`lacuna_render_job_set_environment_strategy`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_environment_strategy {
    /// Classic 2-D piecewise-constant sampling of the lat-long map.
    LatLong = 0,
    /// Per-face cube-map CDFs, samples split evenly between the faces.
    CubeUniform = 1,
    /// Per-face cube-map CDFs, faces chosen by their power.
    CubePower = 2,
    /// Per-face cube-map CDFs with per-normal dynamic face balancing.
    CubeDynamic = 3,
    /// No light sampling of the environment: only BSDF sampling finds it.
    Bsdf = 4,
    /// Only directions through the window portals the shading point sees (portal-masked
    /// sampling, Bitterli et al. 2015), with a quarter of the samples by `LatLong`; the
    /// portals are those the scene lists, or else those the analysis finds (built on first
    /// use). Where the point sees no portal (outdoors, or behind every window), as
    /// `LatLong`. Renders: `path` and `path_skeleton` only (others refuse the job).
    Portals = 5,
    /// The strategy of the map's own layout (the default): `LatLong` for a lat-long map,
    /// `CubeDynamic` for a cube map. `env_direct` takes it as `CubeDynamic`, its per-face
    /// estimator.
    Auto = 6,
}

/// The world axis that is up for an environment map.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum lacuna_up_axis {
    Y = 0,
    Z = 1,
}

/// Converts a `uint32_t` from C into one of the enums above, naming the argument on failure.
macro_rules! c_enum {
    ($ty:ident { $($variant:ident),+ $(,)? }) => {
        impl $ty {
            pub(crate) fn from_c(value: u32, name: &str) -> CapiResult<Self> {
                $(
                    if value == $ty::$variant as u32 {
                        return Ok($ty::$variant);
                    }
                )+
                Err(CapiError::invalid(format!(
                    "`{name}` = {value} is not a valid {} (expected one of {})",
                    stringify!($ty),
                    [$($ty::$variant as u32),+]
                        .iter()
                        .map(u32::to_string)
                        .collect::<Vec<_>>()
                        .join(", ")
                )))
            }
        }
    };
}

c_enum!(lacuna_material_kind {
    Diffuse,
    Glossy,
    Mirror,
    Dielectric,
    RoughDielectric
});
c_enum!(lacuna_material_rgb {
    Diffuse,
    Specular,
    Emission
});
c_enum!(lacuna_material_float {
    Exponent,
    Ior,
    Roughness
});
c_enum!(lacuna_degenerate_policy { Error, Skip });
c_enum!(lacuna_bvh_quality { Fast, Medium, High });
c_enum!(lacuna_mis_heuristic {
    Balance,
    Power,
    Auto,
    Optimal
});
c_enum!(lacuna_sampler { Sobol, Independent });
c_enum!(lacuna_compare_schedule {
    Sequential,
    Concurrent
});
c_enum!(lacuna_environment_layout { LatLong, CubeCross });
c_enum!(lacuna_environment_strategy {
    LatLong,
    CubeUniform,
    CubePower,
    CubeDynamic,
    Bsdf,
    Portals,
    Auto
});
c_enum!(lacuna_up_axis { Y, Z });
c_enum!(lacuna_film_channel {
    Radiance,
    Albedo,
    Normal,
    Depth,
    SampleCount
});
