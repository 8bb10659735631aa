//! Rays, triangle intersection and the BVH.
//!
//! Intersection is watertight (Woop, Benthin and Wald 2013) so light cannot leak through the
//! shared edges of a closed mesh, and every hit carries a bound on its floating-point error so
//! that spawned rays start just outside the surface without a per-scene epsilon
//! (Pharr, Jakob and Humphreys, pbrt-v4 §6.8).

mod binned;
mod bvh;
mod convert;
mod sah;
mod triangle;

#[cfg(target_arch = "x86_64")]
pub(crate) use bvh::has_x86_64_v3;
pub use bvh::{BuildMethod, BuildProfile, Bvh, BvhQuality};
pub use triangle::{intersect_triangle, RayPrecomp, TriangleHit};

use crate::math::{gamma, next_float_towards, Vec3};

/// A ray with unit direction and an exclusive upper bound `t_max`. Origins are offset off
/// surfaces before a ray is built (see [`offset_ray_origin`]), so the lower bound is always 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: Vec3,
    pub dir: Vec3,
    pub t_max: f32,
}

impl Ray {
    pub fn new(origin: Vec3, dir: Vec3, t_max: f32) -> Self {
        Ray { origin, dir, t_max }
    }

    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// The closest hit of a ray: distance, global triangle index and barycentrics of vertices 1
/// and 2 (vertex 0 has `1 - b1 - b2`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub triangle: u32,
    pub b1: f32,
    pub b2: f32,
}

/// Conservative absolute error of a point interpolated from triangle vertices with
/// barycentrics (b0, b1, b2) (pbrt-v4 eq. 6.29).
#[inline]
pub fn barycentric_point_error(p: [Vec3; 3], b: [f32; 3]) -> Vec3 {
    ((p[0] * b[0]).abs() + (p[1] * b[1]).abs() + (p[2] * b[2]).abs()) * gamma(7)
}

/// Moves `p` along the geometric normal `n` by the projection of its error box, towards the
/// side `w` points to, then rounds away from the surface: the spawned ray cannot re-hit the
/// surface it leaves, at any scene scale.
#[inline(always)]
pub fn offset_ray_origin(p: Vec3, p_error: Vec3, n: Vec3, w: Vec3) -> Vec3 {
    let d = n.abs().dot(p_error);
    let offset = if w.dot(n) < 0.0 { -(n * d) } else { n * d };
    // One ulp further per axis, away from the surface (branch-free: this runs three times per
    // bounce, with random signs).
    next_float_towards(p + offset, offset)
}

/// Fraction of a shadow ray's length that is not tested, so the ray stops short of the surface
/// it is aimed at (pbrt's `ShadowEpsilon`). Both ends are already offset off their surfaces.
pub const SHADOW_EPSILON: f32 = 1e-4;

/// Axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds3 {
    pub min: Vec3,
    pub max: Vec3,
}

impl Default for Bounds3 {
    fn default() -> Self {
        Bounds3::EMPTY
    }
}

impl Bounds3 {
    pub const EMPTY: Bounds3 = Bounds3 {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    pub fn union_point(self, p: Vec3) -> Self {
        Bounds3 {
            min: self.min.min(p),
            max: self.max.max(p),
        }
    }

    pub fn union(self, b: Bounds3) -> Self {
        Bounds3 {
            min: self.min.min(b.min),
            max: self.max.max(b.max),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x
    }

    pub fn diagonal(&self) -> Vec3 {
        if self.is_empty() {
            Vec3::ZERO
        } else {
            self.max - self.min
        }
    }

    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// Centre and radius of a sphere enclosing the box.
    pub fn bounding_sphere(&self) -> (Vec3, f32) {
        if self.is_empty() {
            return (Vec3::ZERO, 0.0);
        }
        (self.center(), self.diagonal().length() * 0.5)
    }
}
