//! Compressed 8-wide BVH (obvhs CWBVH, PLOC build) over triangles, with the triangles copied
//! into BVH leaf order so traversal touches memory sequentially, and Lacuna's own watertight
//! triangle test inside the traversal loop.

use glam::{UVec2, Vec3A};
use obvhs::cwbvh::node::{extract_byte64, CwBvhNode};
use obvhs::cwbvh::{builder::build_cwbvh_from_tris, CwBvh};
use obvhs::ray::Ray as BvhRay;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;
use rayon::prelude::*;

use super::{intersect_triangle, Hit, Ray, RayPrecomp};
use crate::math::Vec3;

/// Build quality: a trade between build time and traversal speed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BvhQuality {
    /// Shortest build (interactive edits).
    Fast,
    /// The default: close to Embree's build time with faster traversal (obvhs "medium").
    #[default]
    Medium,
    /// Spatial pre-splits and more reinsertion: best traversal, slower build.
    High,
}

impl BvhQuality {
    fn params(self) -> BvhBuildParams {
        match self {
            BvhQuality::Fast => BvhBuildParams::fast_build(),
            BvhQuality::Medium => BvhBuildParams::medium_build(),
            BvhQuality::High => BvhBuildParams::slow_build(),
        }
    }
}

/// Triangle vertices in leaf order, padded to 16-byte vectors.
#[derive(Clone, Copy, Debug)]
struct LeafTriangle {
    p0: Vec3A,
    p1: Vec3A,
    p2: Vec3A,
}

/// The acceleration structure of a scene. Immutable and `Sync`: queries may run from any number
/// of threads.
pub struct Bvh {
    cwbvh: CwBvh,
    /// `leaf_tris[i]` is the triangle referenced by leaf slot `i`.
    leaf_tris: Vec<LeafTriangle>,
    /// Global triangle index of leaf slot `i`.
    leaf_ids: Vec<u32>,
}

impl Bvh {
    /// Builds the BVH over triangles given as vertex triples (global triangle order).
    pub fn build(triangles: &[[Vec3; 3]], quality: BvhQuality) -> Bvh {
        if triangles.is_empty() {
            return Bvh {
                cwbvh: CwBvh::default(),
                leaf_tris: Vec::new(),
                leaf_ids: Vec::new(),
            };
        }
        let tris: Vec<Triangle> = triangles
            .par_iter()
            .map(|t| Triangle {
                v0: t[0].into(),
                v1: t[1].into(),
                v2: t[2].into(),
            })
            .collect();
        let mut build_time = std::time::Duration::ZERO;
        let cwbvh = build_cwbvh_from_tris(&tris, quality.params(), &mut build_time);
        let leaf_ids = cwbvh.primitive_indices.clone();
        let leaf_tris = leaf_ids
            .par_iter()
            .map(|&i| {
                let t = &tris[i as usize];
                LeafTriangle {
                    p0: t.v0,
                    p1: t.v1,
                    p2: t.v2,
                }
            })
            .collect();
        Bvh {
            cwbvh,
            leaf_tris,
            leaf_ids,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.leaf_ids.is_empty()
    }

    /// Bytes held by nodes and leaf data.
    pub fn memory_bytes(&self) -> usize {
        self.cwbvh.nodes.len() * std::mem::size_of::<obvhs::cwbvh::node::CwBvhNode>()
            + self.cwbvh.primitive_indices.len() * 4
            + self.leaf_tris.len() * std::mem::size_of::<LeafTriangle>()
            + self.leaf_ids.len() * 4
    }

    pub fn node_count(&self) -> usize {
        self.cwbvh.nodes.len()
    }

    /// Closest hit in (0, ray.t_max).
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        if self.is_empty() || !(ray.t_max > 0.0) {
            return None;
        }
        let pre = RayPrecomp::new(ray.origin, ray.dir);
        let mut traverse_ray = BvhRay::new(ray.origin.into(), ray.dir.into(), 0.0, ray.t_max);
        let mut best: Option<(u32, super::TriangleHit)> = None;
        let mut state = self.cwbvh.new_traversal(traverse_ray.direction);
        let mut node;
        obvhs::traverse!(
            self.cwbvh,
            node,
            state,
            intersect_node(node, &traverse_ray, state.oct_inv4),
            {
                let slot = state.primitive_id as usize;
                let t = &self.leaf_tris[slot];
                if let Some(h) = intersect_triangle(
                    &pre,
                    t.p0.into(),
                    t.p1.into(),
                    t.p2.into(),
                    traverse_ray.tmax,
                ) {
                    traverse_ray.tmax = h.t;
                    best = Some((state.primitive_id, h));
                }
            }
        );
        best.map(|(slot, h)| Hit {
            t: h.t,
            triangle: self.leaf_ids[slot as usize],
            b1: h.b1,
            b2: h.b2,
        })
    }

    /// True when anything lies on the ray in (0, ray.t_max): stops at the first hit found.
    pub fn occluded(&self, ray: &Ray) -> bool {
        if self.is_empty() || !(ray.t_max > 0.0) {
            return false;
        }
        let pre = RayPrecomp::new(ray.origin, ray.dir);
        let traverse_ray = BvhRay::new(ray.origin.into(), ray.dir.into(), 0.0, ray.t_max);
        let mut state = self.cwbvh.new_traversal(traverse_ray.direction);
        let mut node;
        let mut hit = false;
        'outer: {
            obvhs::traverse!(
                self.cwbvh,
                node,
                state,
                intersect_node(node, &traverse_ray, state.oct_inv4),
                {
                    let t = &self.leaf_tris[state.primitive_id as usize];
                    if intersect_triangle(
                        &pre,
                        t.p0.into(),
                        t.p1.into(),
                        t.p2.into(),
                        traverse_ray.tmax,
                    )
                    .is_some()
                    {
                        hit = true;
                        break 'outer;
                    }
                }
            );
        }
        hit
    }

    /// Closest hits of many rays, in parallel; `out[i]` answers `rays[i]`.
    pub fn intersect_batch(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
        assert_eq!(rays.len(), out.len());
        rays.par_chunks(256)
            .zip(out.par_chunks_mut(256))
            .for_each(|(r, o)| {
                for (ray, slot) in r.iter().zip(o) {
                    *slot = self.intersect(ray);
                }
            });
    }

    /// Occlusion of many rays, in parallel.
    pub fn occluded_batch(&self, rays: &[Ray], out: &mut [bool]) {
        assert_eq!(rays.len(), out.len());
        rays.par_chunks(256)
            .zip(out.par_chunks_mut(256))
            .for_each(|(r, o)| {
                for (ray, slot) in r.iter().zip(o) {
                    *slot = self.occluded(ray);
                }
            });
    }
}

/// Ray against the eight quantized child boxes of a node; returns the traversal hit mask in
/// obvhs's layout. We use our own instead of `CwBvhNode::intersect_ray` because that one clamps
/// the entry distance to an absolute 1e-4, which culls every box closer than 1e-4 to the ray
/// origin: geometry at small scales, and walls meeting at a corner, would be missed. Here the
/// interval is (0, t_max], widened by the rounding error of the slab computation
/// (pbrt-v4 §6.8.2), so the box test is conservative at every scale.
#[inline(always)]
fn intersect_node(node: &CwBvhNode, ray: &BvhRay, oct_inv4: u32) -> u32 {
    let extent = node.compute_extent();
    let dir_inv = extent * ray.inv_direction;
    let origin = (Vec3A::from(node.p) - ray.origin) * ray.inv_direction;
    let (child_bits8, bit_index8) = node.get_child_and_index_bits(oct_inv4);
    fn pick<'a>(lo: &'a [u8; 8], hi: &'a [u8; 8], negative: bool) -> (&'a [u8; 8], &'a [u8; 8]) {
        if negative {
            (hi, lo)
        } else {
            (lo, hi)
        }
    }
    // The slab order must follow the sign of the inverse direction: a -0.0 component has a
    // negative (infinite) inverse although `-0.0 < 0.0` is false.
    let (x_near, x_far) = pick(
        &node.child_min_x,
        &node.child_max_x,
        ray.inv_direction.x < 0.0,
    );
    let (y_near, y_far) = pick(
        &node.child_min_y,
        &node.child_max_y,
        ray.inv_direction.y < 0.0,
    );
    let (z_near, z_far) = pick(
        &node.child_min_z,
        &node.child_max_z,
        ray.inv_direction.z < 0.0,
    );
    let t_max_ray = ray.tmax;
    let widen = 1.0 + 2.0 * crate::math::gamma(3);
    let mut hit = [false; 8];
    for c in 0..8 {
        let t0x = x_near[c] as f32 * dir_inv.x + origin.x;
        let t1x = x_far[c] as f32 * dir_inv.x + origin.x;
        let t0y = y_near[c] as f32 * dir_inv.y + origin.y;
        let t1y = y_far[c] as f32 * dir_inv.y + origin.y;
        let t0z = z_near[c] as f32 * dir_inv.z + origin.z;
        let t1z = z_far[c] as f32 * dir_inv.z + origin.z;
        let t_enter = t0x.max(t0y).max(t0z).max(0.0);
        let t_exit = (t1x.min(t1y).min(t1z) * widen).min(t_max_ray);
        hit[c] = t_enter <= t_exit;
    }
    let mut mask = 0u32;
    for (c, &h) in hit.iter().enumerate() {
        if h {
            mask |= extract_byte64(child_bits8, c) << extract_byte64(bit_index8, c);
        }
    }
    mask
}

// The traversal macro names `UVec2` unqualified.
#[allow(unused_imports)]
use UVec2 as _;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{warp, Rng};

    fn random_triangles(n: usize, rng: &mut Rng) -> Vec<[Vec3; 3]> {
        (0..n)
            .map(|_| {
                let c = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 10.0;
                let s = 0.3 + rng.uniform();
                [
                    c,
                    c + warp::uniform_sphere(rng.uniform2()) * s,
                    c + warp::uniform_sphere(rng.uniform2()) * s,
                ]
            })
            .collect()
    }

    /// The BVH answers exactly what testing every triangle answers, at every scene scale and
    /// for rays starting right next to geometry.
    #[test]
    fn bvh_matches_brute_force() {
        let mut rng = Rng::new(17, 1);
        let unit_tris = random_triangles(2000, &mut rng);
        for scale in [1e-4f32, 1.0, 1e4] {
            let tris: Vec<[Vec3; 3]> = unit_tris.iter().map(|t| t.map(|p| p * scale)).collect();
            for quality in [BvhQuality::Fast, BvhQuality::Medium, BvhQuality::High] {
                let bvh = Bvh::build(&tris, quality);
                for i in 0..3000 {
                    let o = if i % 2 == 0 {
                        (Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 12.0 - Vec3::ONE)
                            * scale
                    } else {
                        // Just off a random triangle: the nearest geometry is far below 1e-4.
                        let t = tris[rng.below(tris.len() as u32) as usize];
                        let (b0, b1) = warp::uniform_triangle(rng.uniform2());
                        t[0] * b0
                            + t[1] * b1
                            + t[2] * (1.0 - b0 - b1)
                            + warp::uniform_sphere(rng.uniform2()) * (1e-3 * scale)
                    };
                    let d = warp::uniform_sphere(rng.uniform2());
                    let t_max = if rng.uniform() < 0.5 {
                        f32::INFINITY
                    } else {
                        rng.uniform() * 10.0 * scale
                    };
                    let ray = Ray::new(o, d, t_max);
                    let pre = RayPrecomp::new(o, d);
                    let brute = tris
                        .iter()
                        .enumerate()
                        .filter_map(|(i, t)| {
                            intersect_triangle(&pre, t[0], t[1], t[2], t_max).map(|h| (i, h))
                        })
                        .min_by(|a, b| a.1.t.total_cmp(&b.1.t));
                    let got = bvh.intersect(&ray);
                    assert_eq!(
                        got.map(|h| h.t),
                        brute.map(|b| b.1.t),
                        "scale {scale}, {quality:?}"
                    );
                    assert_eq!(got.map(|h| h.triangle as usize), brute.map(|b| b.0));
                    assert_eq!(bvh.occluded(&ray), brute.is_some());
                }
            }
        }
    }

    /// Directions with negative zero components (common from cross products) still hit.
    #[test]
    fn negative_zero_direction_components_hit() {
        let mut rng = Rng::new(3, 3);
        let tris = random_triangles(500, &mut rng);
        let bvh = Bvh::build(&tris, BvhQuality::Medium);
        for t in &tris {
            let target = (t[0] + t[1] + t[2]) / 3.0;
            for (dir, offset) in [
                (Vec3::new(1.0, -0.0, -0.0), Vec3::new(-20.0, 0.0, 0.0)),
                (Vec3::new(-0.0, -1.0, 0.0), Vec3::new(0.0, 20.0, 0.0)),
                (Vec3::new(-0.0, -0.0, 1.0), Vec3::new(0.0, 0.0, -20.0)),
            ] {
                let ray = Ray::new(target + offset, dir, f32::INFINITY);
                let pre = RayPrecomp::new(ray.origin, ray.dir);
                let brute = tris
                    .iter()
                    .filter_map(|t| intersect_triangle(&pre, t[0], t[1], t[2], f32::INFINITY))
                    .map(|h| h.t)
                    .fold(f32::INFINITY, f32::min);
                assert_eq!(
                    bvh.intersect(&ray).map_or(f32::INFINITY, |h| h.t),
                    brute,
                    "{dir}"
                );
            }
        }
    }

    #[test]
    fn empty_bvh_misses() {
        let bvh = Bvh::build(&[], BvhQuality::Medium);
        let ray = Ray::new(Vec3::ZERO, Vec3::X, f32::INFINITY);
        assert!(bvh.intersect(&ray).is_none());
        assert!(!bvh.occluded(&ray));
    }
}
