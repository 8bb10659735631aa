//! A point on a surface where a ray landed, with everything shading needs.

use crate::geometry::{offset_ray_origin, Ray, SHADOW_EPSILON};
use crate::math::{Frame, Vec2, Vec3};

#[derive(Clone, Copy, Debug)]
pub struct SurfaceInteraction {
    pub p: Vec3,
    /// Bound on the absolute floating-point error of `p`.
    pub p_error: Vec3,
    /// Unit geometric normal (the triangle's front side).
    pub ng: Vec3,
    /// Unit shading normal (interpolated vertex normals, or `ng`).
    pub ns: Vec3,
    pub uv: Vec2,
    /// Unit direction back along the incoming ray.
    pub wo: Vec3,
    pub t: f32,
    pub triangle: u32,
    pub material: u32,
}

impl SurfaceInteraction {
    /// The shading frame (z = shading normal).
    pub fn shading_frame(&self) -> Frame {
        Frame::from_z(self.ns)
    }

    /// Whether a connection leaving in direction `wi` (world) scatters on the side of the
    /// geometric surface that the shading frame says: on `wo`'s side when `wi_local` and
    /// `wo_local` share a hemisphere (reflection), across it otherwise (transmission). Shading
    /// normals can disagree with the geometry near silhouettes, and would let light through
    /// walls. Opaque BSDFs are zero across, so for them this is "wi on wo's side".
    #[inline]
    pub fn scatters_toward(&self, wi: Vec3, wo_local: Vec3, wi_local: Vec3) -> bool {
        let sides = wi.dot(self.ng) * self.wo.dot(self.ng);
        if wo_local.z * wi_local.z > 0.0 {
            sides > 0.0
        } else {
            sides < 0.0
        }
    }

    /// The shading normal turned to the side of `wo`: the hemisphere the (opaque) BSDFs
    /// reflect into, which per-normal light sampling balances its samples for.
    #[inline]
    pub fn facing_normal(&self) -> Vec3 {
        if self.ns.dot(self.wo) < 0.0 {
            -self.ns
        } else {
            self.ns
        }
    }

    /// A ray leaving the surface in direction `dir`, starting just off the side `dir` points to.
    #[inline]
    pub fn spawn_ray(&self, dir: Vec3) -> Ray {
        Ray::new(
            offset_ray_origin(self.p, self.p_error, self.ng, dir),
            dir,
            f32::INFINITY,
        )
    }

    /// A shadow ray towards a point `to` (itself on a surface with normal `to_normal` and
    /// error `to_error`) that stops just short of it.
    #[inline(always)]
    pub fn spawn_ray_to(&self, to: Vec3, to_error: Vec3, to_normal: Vec3) -> Ray {
        let from = offset_ray_origin(self.p, self.p_error, self.ng, to - self.p);
        let to = offset_ray_origin(to, to_error, to_normal, from - to);
        let d = to - from;
        let len = d.length();
        if len == 0.0 {
            return Ray::new(from, self.ng, 0.0);
        }
        Ray::new(from, d / len, len * (1.0 - SHADOW_EPSILON))
    }
}
