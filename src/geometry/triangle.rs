//! Watertight ray-triangle intersection (Woop, Benthin, Wald, "Watertight Ray/Triangle
//! Intersection", JCGT 2013), with pbrt-v4's conservative lower bound on t so that a ray
//! leaving a surface is never reported to hit it again at t ~ 0.

use crate::math::{gamma, Vec3};

/// Per-ray constants of the watertight test: the permutation that makes the largest direction
/// component z, and the shear that maps the direction to +z.
#[derive(Clone, Copy, Debug)]
pub struct RayPrecomp {
    origin: Vec3,
    kx: usize,
    ky: usize,
    kz: usize,
    sx: f32,
    sy: f32,
    sz: f32,
}

impl RayPrecomp {
    #[inline]
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        let a = dir.abs();
        let kz = if a.x > a.y {
            if a.x > a.z {
                0
            } else {
                2
            }
        } else if a.y > a.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        if dir[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let sz = 1.0 / dir[kz];
        RayPrecomp {
            origin,
            kx,
            ky,
            kz,
            sx: dir[kx] * sz,
            sy: dir[ky] * sz,
            sz,
        }
    }
}

/// Distance and barycentrics (of vertices 1 and 2) of a hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleHit {
    pub t: f32,
    pub b1: f32,
    pub b2: f32,
}

/// Intersects a ray with triangle (p0, p1, p2) in (0, t_max). Edges and vertices shared by two
/// triangles are hit by at least one of them (watertightness); degenerate triangles never hit.
#[inline(always)]
pub fn intersect_triangle(
    r: &RayPrecomp,
    p0: Vec3,
    p1: Vec3,
    p2: Vec3,
    t_max: f32,
) -> Option<TriangleHit> {
    let (kx, ky, kz) = (r.kx, r.ky, r.kz);
    let a = p0 - r.origin;
    let b = p1 - r.origin;
    let c = p2 - r.origin;
    let ax = a[kx] - r.sx * a[kz];
    let ay = a[ky] - r.sy * a[kz];
    let bx = b[kx] - r.sx * b[kz];
    let by = b[ky] - r.sy * b[kz];
    let cx = c[kx] - r.sx * c[kz];
    let cy = c[ky] - r.sy * c[kz];

    let mut e0 = bx * cy - by * cx;
    let mut e1 = cx * ay - cy * ax;
    let mut e2 = ax * by - ay * bx;
    // Exactly zero edge functions are re-evaluated in double precision: this is what makes
    // the test watertight on shared edges.
    if e0 == 0.0 || e1 == 0.0 || e2 == 0.0 {
        e0 = (bx as f64 * cy as f64 - by as f64 * cx as f64) as f32;
        e1 = (cx as f64 * ay as f64 - cy as f64 * ax as f64) as f32;
        e2 = (ax as f64 * by as f64 - ay as f64 * bx as f64) as f32;
    }
    if (e0 < 0.0 || e1 < 0.0 || e2 < 0.0) && (e0 > 0.0 || e1 > 0.0 || e2 > 0.0) {
        return None;
    }
    let det = e0 + e1 + e2;
    if det == 0.0 {
        return None;
    }
    let az = r.sz * a[kz];
    let bz = r.sz * b[kz];
    let cz = r.sz * c[kz];
    let t_scaled = e0 * az + e1 * bz + e2 * cz;
    if det < 0.0 && (t_scaled >= 0.0 || t_scaled < t_max * det) {
        return None;
    }
    if det > 0.0 && (t_scaled <= 0.0 || t_scaled > t_max * det) {
        return None;
    }
    let inv_det = 1.0 / det;
    let t = t_scaled * inv_det;
    if !(t < t_max) {
        return None;
    }

    // Conservative bound on the error of t (pbrt-v4 §6.8.7): reject hits that may really lie
    // at t <= 0.
    let max_zt = az.abs().max(bz.abs()).max(cz.abs());
    let delta_z = gamma(3) * max_zt;
    let max_xt = ax.abs().max(bx.abs()).max(cx.abs());
    let max_yt = ay.abs().max(by.abs()).max(cy.abs());
    let delta_x = gamma(5) * (max_xt + max_zt);
    let delta_y = gamma(5) * (max_yt + max_zt);
    let delta_e = 2.0 * (gamma(2) * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt);
    let max_e = e0.abs().max(e1.abs()).max(e2.abs());
    let delta_t =
        3.0 * (gamma(3) * max_e * max_zt + delta_e * max_zt + delta_z * max_e) * inv_det.abs();
    if t <= delta_t {
        return None;
    }
    Some(TriangleHit {
        t,
        b1: e1 * inv_det,
        b2: e2 * inv_det,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    #[test]
    fn hits_centre_and_reports_barycentrics() {
        let (p0, p1, p2) = (
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        );
        let o = Vec3::new(0.25, 0.5, 1.0);
        let r = RayPrecomp::new(o, -Vec3::Z);
        let h = intersect_triangle(&r, p0, p1, p2, f32::INFINITY).unwrap();
        assert!((h.t - 1.0).abs() < 1e-6);
        assert!((h.b1 - 0.25).abs() < 1e-6 && (h.b2 - 0.5).abs() < 1e-6);
        assert!(intersect_triangle(&r, p0, p1, p2, 0.99).is_none());
        // Behind the origin.
        let r = RayPrecomp::new(o, Vec3::Z);
        assert!(intersect_triangle(&r, p0, p1, p2, f32::INFINITY).is_none());
    }

    #[test]
    fn degenerate_triangles_never_hit() {
        let r = RayPrecomp::new(Vec3::new(0.5, 0.0, 1.0), -Vec3::Z);
        let p = Vec3::new(0.5, 0.0, 0.0);
        assert!(intersect_triangle(&r, p, p, p, f32::INFINITY).is_none());
        assert!(
            intersect_triangle(&r, Vec3::ZERO, Vec3::X, Vec3::X * 2.0, f32::INFINITY).is_none()
        );
    }

    /// Rays aimed exactly at the shared edge or shared vertex of a fan of triangles must hit
    /// at least one of them: no cracks.
    #[test]
    fn shared_edges_and_vertices_are_watertight() {
        let mut rng = Rng::new(21, 0);
        for scale in [1e-4f32, 1.0, 1e4] {
            // A fan of 6 triangles around a centre vertex.
            let c = Vec3::new(0.3, -0.2, 0.1) * scale;
            let ring: Vec<Vec3> = (0..6)
                .map(|i| {
                    let a = i as f32 / 6.0 * std::f32::consts::TAU + 0.1;
                    c + Vec3::new(a.cos(), a.sin(), 0.05 * (i as f32 - 2.5)) * scale
                })
                .collect();
            let tris: Vec<[Vec3; 3]> = (0..6).map(|i| [c, ring[i], ring[(i + 1) % 6]]).collect();
            for _ in 0..20_000 {
                // Target: the centre vertex, or a point on a random shared edge.
                let k = rng.below(7) as usize;
                let target = if k == 6 {
                    c
                } else {
                    c + (ring[k] - c) * rng.uniform()
                };
                let dir = crate::math::warp::uniform_sphere(rng.uniform2());
                // Steeper than the fan's slope, starting above the fan inside its footprint,
                // so the ray must cross the surface exactly once.
                let dir = if dir.z > 0.0 { -dir } else { dir };
                if dir.z > -0.5 {
                    continue;
                }
                let origin = target - dir * scale * 0.5;
                let r = RayPrecomp::new(origin, dir);
                let hit = tris
                    .iter()
                    .any(|t| intersect_triangle(&r, t[0], t[1], t[2], f32::INFINITY).is_some());
                assert!(hit, "ray through a shared edge/vertex missed at scale {scale}: target {target:?}, dir {dir:?}");
            }
        }
    }
}
