//! Watertight ray-triangle intersection (Woop, Benthin, Wald, "Watertight Ray/Triangle
//! Intersection", JCGT 2013), with pbrt-v4's conservative lower bound on t so that a ray
//! leaving a surface is never reported to hit it again at t ~ 0.

use glam::Vec4;

use crate::math::{gamma, Vec3};

/// Per-ray constants of the watertight test: the permutation that makes the largest direction
/// component z, and the shear that maps the direction to +z.
#[derive(Clone, Copy, Debug)]
pub struct RayPrecomp {
    origin: Vec3,
    /// Kept for the double-precision re-test of hits too close to call in f32.
    dir: Vec3,
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
        RayPrecomp::with_reciprocal(origin, dir, dir.recip())
    }

    /// The same constants from `recip = 1 / dir` (per component, unclamped) that the caller
    /// has already computed: BVH queries share it with their node test, which saves a
    /// division per query.
    #[inline(always)]
    pub fn with_reciprocal(origin: Vec3, dir: Vec3, recip: Vec3) -> Self {
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
        // (kz + 1) % 3 and (kz + 2) % 3, swapped so that the shear keeps the winding; padded
        // arrays masked to 0..4 as in `intersect_triangle`. Written as selects, not as a
        // lookup table: the table was built on the stack at every query.
        let mut kx = if kz == 2 { 0 } else { kz + 1 };
        let mut ky = if kz == 0 { 2 } else { kz - 1 };
        let dir4 = [dir.x, dir.y, dir.z, 0.0];
        if dir4[kz & 3] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let sz = [recip.x, recip.y, recip.z, 0.0][kz & 3];
        RayPrecomp {
            origin,
            dir,
            kx,
            ky,
            kz,
            sx: dir4[kx & 3] * sz,
            sy: dir4[ky & 3] * sz,
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
    // Axis indices masked to 0..4 on 4-element arrays: no bounds check and no branch per
    // access (glam's `Vec3` indexing is a match; it was about a third of this test's
    // instructions). `RayPrecomp` keeps them in 0..3.
    let (kx, ky, kz) = (r.kx & 3, r.ky & 3, r.kz & 3);
    let padded = |v: Vec3| [v.x, v.y, v.z, 0.0];
    let a = padded(p0 - r.origin);
    let b = padded(p1 - r.origin);
    let c = padded(p2 - r.origin);
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
    // Error of the sheared x = a[kx] - sx * a[kz] (likewise y). pbrt bounds it by
    // gamma(5) * (max_xt + max_zt), i.e. it takes |sx * a[kz]| <= max_zt. For a ray grazing a
    // plane that contains its dominant axis (a wall hit at 1e-5 rad), x is tiny while z is
    // not, the bound is 1e5 times too large, and so is delta_t: hits far out along the ray
    // were rejected (issue 2's grazing misses). Re-derived with the product term kept:
    // a[kx] and a[kz] round once, sx twice (1/d, times d), the product and the difference
    // once each, so |error| <= gamma(2)|x| + gamma(6)|sx a[kz]| up to second-order terms;
    // gamma(5) and gamma(7) cover those and the rounding of this bound itself.
    let max_kz = a[kz].abs().max(b[kz].abs()).max(c[kz].abs());
    let delta_x = gamma(5) * max_xt + gamma(7) * (r.sx.abs() * max_kz);
    let delta_y = gamma(5) * max_yt + gamma(7) * (r.sy.abs() * max_kz);
    let delta_e = 2.0 * (gamma(2) * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt);
    let max_e = e0.abs().max(e1.abs()).max(e2.abs());
    let delta_t =
        3.0 * (gamma(3) * max_e * max_zt + delta_e * max_zt + delta_z * max_e) * inv_det.abs();
    if t <= delta_t {
        // Too close to call in f32: grazing rays (det -> 0) have a large bound even far from
        // the origin. Re-test in f64, whose bound is 2^29 times smaller; rays leaving a
        // surface are still rejected there (their true t is <= 0).
        return intersect_triangle_f64(r, p0, p1, p2, t_max);
    }
    Some(TriangleHit {
        t,
        b1: e1 * inv_det,
        b2: e2 * inv_det,
    })
}

/// Four triangles in structure-of-arrays form, one per SIMD lane, so that a BVH leaf's
/// triangles are tested against a ray together ([`intersect_triangle_block`]) instead of one
/// after another. `v[vertex][axis]` holds that coordinate of that vertex for the four lanes;
/// axis 3 is padding (so that the ray's axis permutation indexes with `k & 3`, without a
/// bounds check), `v[0][3]` carries the lanes' triangle ids as bits (see
/// [`TriangleBlock::id`]) and `v[1][3]` lane 0 the bit mask of the occupied lanes (see
/// [`TriangleBlock::lanes`]). Unused lanes hold a degenerate triangle.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
pub struct TriangleBlock {
    v: [[Vec4; 4]; 3],
}

const _: () = assert!(std::mem::size_of::<TriangleBlock>() == 192);

impl Default for TriangleBlock {
    fn default() -> Self {
        TriangleBlock {
            v: [[Vec4::ZERO; 4]; 3],
        }
    }
}

impl TriangleBlock {
    /// Puts triangle `p` with id `id` in `lane` (0..4).
    pub fn set(&mut self, lane: usize, p: [Vec3; 3], id: u32) {
        for (vertex, point) in p.iter().enumerate() {
            self.v[vertex][0][lane] = point.x;
            self.v[vertex][1][lane] = point.y;
            self.v[vertex][2][lane] = point.z;
        }
        self.v[0][3][lane] = f32::from_bits(id);
        self.v[1][3][0] = f32::from_bits(self.lanes() | 1 << lane);
    }

    /// Bit `lane` set for each lane given a triangle by [`TriangleBlock::set`]. A test of a
    /// whole block passes this rather than `0xf`: an empty lane's degenerate triangle has
    /// zero edge functions, which would send every such test down the double-precision
    /// re-evaluation of [`intersect_triangle_block`] (it answers the same, but costs about
    /// 120 instructions).
    #[inline(always)]
    pub fn lanes(&self) -> u32 {
        self.v[1][3].x.to_bits()
    }

    /// The triangle in `lane`.
    pub fn triangle(&self, lane: usize) -> [Vec3; 3] {
        let v = &self.v;
        std::array::from_fn(|i| Vec3::new(v[i][0][lane], v[i][1][lane], v[i][2][lane]))
    }

    /// The id given to [`TriangleBlock::set`] for `lane`.
    #[inline(always)]
    pub fn id(&self, lane: usize) -> u32 {
        // Read in place (`to_array` copied the four ids on the stack first).
        let ids: &[f32; 4] = self.v[0][3].as_ref();
        ids[lane & 3].to_bits()
    }
}

/// A ray's constants of the watertight test splatted across the four lanes of a
/// [`TriangleBlock`]: the origin's coordinates in the permuted axis order and the shear.
#[derive(Clone, Copy, Debug)]
pub struct RayLanes {
    ox: Vec4,
    oy: Vec4,
    oz: Vec4,
    sx: Vec4,
    sy: Vec4,
    sz: Vec4,
}

impl RayLanes {
    #[inline(always)]
    pub fn new(r: &RayPrecomp) -> Self {
        let o = [r.origin.x, r.origin.y, r.origin.z, 0.0];
        RayLanes {
            ox: Vec4::splat(o[r.kx & 3]),
            oy: Vec4::splat(o[r.ky & 3]),
            oz: Vec4::splat(o[r.kz & 3]),
            sx: Vec4::splat(r.sx),
            sy: Vec4::splat(r.sy),
            sz: Vec4::splat(r.sz),
        }
    }
}

/// The hits of a [`TriangleBlock`]: bit `lane` of `mask` set where that lane's triangle is
/// hit, with its distance and barycentrics in `t`, `b1`, `b2` (undefined elsewhere).
#[derive(Clone, Copy, Debug)]
pub struct BlockHits {
    pub mask: u32,
    pub t: [f32; 4],
    pub b1: [f32; 4],
    pub b2: [f32; 4],
}

impl BlockHits {
    pub const MISS: BlockHits = BlockHits {
        mask: 0,
        t: [0.0; 4],
        b1: [0.0; 4],
        b2: [0.0; 4],
    };
}

/// [`intersect_triangle`] on the triangles of `block` whose bit is set in `lanes`, all four
/// at once: the same arithmetic in the same order lane by lane (SSE on x86-64, which every
/// x86-64 CPU has), so every lane answers exactly as the one-triangle test does with the same
/// `t_max`, including its double-precision re-evaluation of zero edge functions and its
/// double-precision re-test of hits within the f32 error bound (both rare, done per lane).
#[inline(always)]
pub fn intersect_triangle_block(
    r: &RayPrecomp,
    l: &RayLanes,
    block: &TriangleBlock,
    lanes: u32,
    t_max: f32,
) -> BlockHits {
    let mut hits = BlockHits::MISS;
    hits.mask = intersect_triangle_block_into(r, l, block, lanes, t_max, &mut hits);
    hits
}

/// [`intersect_triangle_block`] writing the distances and barycentrics into the caller's
/// `hits` (left as they were when no lane passes the edge test) and returning the hit mask
/// (`hits.mask` is not written). A closest-hit query keeps one `BlockHits` for all its
/// blocks: a returned one was copied once more on the stack per block (about 12
/// instructions).
#[inline(always)]
pub fn intersect_triangle_block_into(
    r: &RayPrecomp,
    l: &RayLanes,
    block: &TriangleBlock,
    lanes: u32,
    t_max: f32,
    hits: &mut BlockHits,
) -> u32 {
    let (kx, ky, kz) = (r.kx & 3, r.ky & 3, r.kz & 3);
    let v = &block.v;
    let zero = Vec4::ZERO;
    // Vertex coordinates relative to the origin, in the permuted axis order.
    let a = [v[0][kx] - l.ox, v[0][ky] - l.oy, v[0][kz] - l.oz];
    let b = [v[1][kx] - l.ox, v[1][ky] - l.oy, v[1][kz] - l.oz];
    let c = [v[2][kx] - l.ox, v[2][ky] - l.oy, v[2][kz] - l.oz];
    let ax = a[0] - l.sx * a[2];
    let ay = a[1] - l.sy * a[2];
    let bx = b[0] - l.sx * b[2];
    let by = b[1] - l.sy * b[2];
    let cx = c[0] - l.sx * c[2];
    let cy = c[1] - l.sy * c[2];

    let mut e0 = bx * cy - by * cx;
    let mut e1 = cx * ay - cy * ax;
    let mut e2 = ax * by - ay * bx;
    let zero_edge = (e0.cmpeq(zero) | e1.cmpeq(zero) | e2.cmpeq(zero)).bitmask() & lanes;
    if zero_edge != 0 {
        (e0, e1, e2) = edges_f64(zero_edge, [ax, ay, bx, by, cx, cy], [e0, e1, e2]);
    }
    let negative = e0.cmplt(zero) | e1.cmplt(zero) | e2.cmplt(zero);
    let positive = e0.cmpgt(zero) | e1.cmpgt(zero) | e2.cmpgt(zero);
    // Most blocks a ray reaches have no triangle it passes through: stop before the
    // distances.
    if !(negative & positive).bitmask() & lanes == 0 {
        return 0;
    }
    let det = e0 + e1 + e2;
    let az = l.sz * a[2];
    let bz = l.sz * b[2];
    let cz = l.sz * c[2];
    let t_scaled = e0 * az + e1 * bz + e2 * cz;
    let t_max4 = Vec4::splat(t_max);
    let bound = t_max4 * det;
    let out_negative = det.cmplt(zero) & (t_scaled.cmpge(zero) | t_scaled.cmplt(bound));
    let out_positive = det.cmpgt(zero) & (t_scaled.cmple(zero) | t_scaled.cmpgt(bound));
    let inv_det = Vec4::ONE / det;
    let t = t_scaled * inv_det;
    let rejected = (negative & positive) | det.cmpeq(zero) | out_negative | out_positive;
    let mut mask = !rejected.bitmask() & t.cmplt(t_max4).bitmask() & lanes;
    hits.t = t.to_array();
    hits.b1 = (e1 * inv_det).to_array();
    hits.b2 = (e2 * inv_det).to_array();
    if mask == 0 {
        return 0;
    }

    // The conservative bound on t of `intersect_triangle`, lane by lane.
    let max_zt = az.abs().max(bz.abs()).max(cz.abs());
    let delta_z = Vec4::splat(gamma(3)) * max_zt;
    let max_xt = ax.abs().max(bx.abs()).max(cx.abs());
    let max_yt = ay.abs().max(by.abs()).max(cy.abs());
    let max_kz = a[2].abs().max(b[2].abs()).max(c[2].abs());
    let (g2, g3, g5, g7) = (
        Vec4::splat(gamma(2)),
        Vec4::splat(gamma(3)),
        Vec4::splat(gamma(5)),
        Vec4::splat(gamma(7)),
    );
    let delta_x = g5 * max_xt + g7 * (l.sx.abs() * max_kz);
    let delta_y = g5 * max_yt + g7 * (l.sy.abs() * max_kz);
    let delta_e = Vec4::splat(2.0) * (g2 * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt);
    let max_e = e0.abs().max(e1.abs()).max(e2.abs());
    let delta_t = Vec4::splat(3.0)
        * (g3 * max_e * max_zt + delta_e * max_zt + delta_z * max_e)
        * inv_det.abs();
    let close = t.cmple(delta_t).bitmask() & mask;
    if close != 0 {
        mask &= !close;
        mask |= retest_f64(r, block, close, t_max, hits);
    }
    mask
}

/// The zero-edge rule of [`intersect_triangle`] for the lanes in `lanes`: all three edge
/// functions of those lanes re-evaluated in double precision.
#[cold]
#[inline(never)]
fn edges_f64(lanes: u32, sheared: [Vec4; 6], edges: [Vec4; 3]) -> (Vec4, Vec4, Vec4) {
    let [ax, ay, bx, by, cx, cy] = sheared.map(|v| v.as_dvec4().to_array());
    let mut e = edges.map(|v| v.to_array());
    for lane in 0..4 {
        if lanes & (1 << lane) != 0 {
            e[0][lane] = (bx[lane] * cy[lane] - by[lane] * cx[lane]) as f32;
            e[1][lane] = (cx[lane] * ay[lane] - cy[lane] * ax[lane]) as f32;
            e[2][lane] = (ax[lane] * by[lane] - ay[lane] * bx[lane]) as f32;
        }
    }
    let [e0, e1, e2] = e.map(Vec4::from_array);
    (e0, e1, e2)
}

/// The double-precision re-test of [`intersect_triangle`] for the lanes in `lanes`; writes
/// their hits into `hits` and returns the lanes that hit.
#[cold]
#[inline(never)]
fn retest_f64(
    r: &RayPrecomp,
    block: &TriangleBlock,
    lanes: u32,
    t_max: f32,
    hits: &mut BlockHits,
) -> u32 {
    let mut mask = 0;
    for lane in 0..4 {
        if lanes & (1 << lane) == 0 {
            continue;
        }
        let [p0, p1, p2] = block.triangle(lane);
        if let Some(h) = intersect_triangle_f64(r, p0, p1, p2, t_max) {
            hits.t[lane] = h.t;
            hits.b1[lane] = h.b1;
            hits.b2[lane] = h.b2;
            mask |= 1 << lane;
        }
    }
    mask
}

/// Higham's gamma_n for f64.
fn gamma_f64(n: i32) -> f64 {
    let e = f64::EPSILON * 0.5;
    (n as f64 * e) / (1.0 - n as f64 * e)
}

/// The same test as [`intersect_triangle`] in double precision, for the rare hits whose f32
/// error bound on t does not exclude t <= 0. Same permutation and shear, same bound
/// (pbrt-v4 §6.8.7 with the shear term of `intersect_triangle`), in f64 roundings; the
/// inputs are the f32 values, so its answer is about the same ray and triangle.
#[cold]
#[inline(never)]
fn intersect_triangle_f64(
    r: &RayPrecomp,
    p0: Vec3,
    p1: Vec3,
    p2: Vec3,
    t_max: f32,
) -> Option<TriangleHit> {
    let (kx, ky, kz) = (r.kx, r.ky, r.kz);
    let d = r.dir.as_dvec3();
    let o = r.origin.as_dvec3();
    let sz = 1.0 / d[kz];
    let (sx, sy) = (d[kx] * sz, d[ky] * sz);
    let a = p0.as_dvec3() - o;
    let b = p1.as_dvec3() - o;
    let c = p2.as_dvec3() - o;
    let (ax, ay) = (a[kx] - sx * a[kz], a[ky] - sy * a[kz]);
    let (bx, by) = (b[kx] - sx * b[kz], b[ky] - sy * b[kz]);
    let (cx, cy) = (c[kx] - sx * c[kz], c[ky] - sy * c[kz]);
    let e0 = bx * cy - by * cx;
    let e1 = cx * ay - cy * ax;
    let e2 = ax * by - ay * bx;
    if (e0 < 0.0 || e1 < 0.0 || e2 < 0.0) && (e0 > 0.0 || e1 > 0.0 || e2 > 0.0) {
        return None;
    }
    let det = e0 + e1 + e2;
    if det == 0.0 {
        return None;
    }
    let (az, bz, cz) = (sz * a[kz], sz * b[kz], sz * c[kz]);
    let inv_det = 1.0 / det;
    let t = (e0 * az + e1 * bz + e2 * cz) * inv_det;
    if !(t > 0.0 && t < t_max as f64) {
        return None;
    }
    let max_zt = az.abs().max(bz.abs()).max(cz.abs());
    let delta_z = gamma_f64(3) * max_zt;
    let max_xt = ax.abs().max(bx.abs()).max(cx.abs());
    let max_yt = ay.abs().max(by.abs()).max(cy.abs());
    let max_kz = a[kz].abs().max(b[kz].abs()).max(c[kz].abs());
    let delta_x = gamma_f64(5) * max_xt + gamma_f64(7) * (sx.abs() * max_kz);
    let delta_y = gamma_f64(5) * max_yt + gamma_f64(7) * (sy.abs() * max_kz);
    let delta_e = 2.0 * (gamma_f64(2) * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt);
    let max_e = e0.abs().max(e1.abs()).max(e2.abs());
    let delta_t =
        3.0 * (gamma_f64(3) * max_e * max_zt + delta_e * max_zt + delta_z * max_e) * inv_det.abs();
    // The f32 distance must also be positive and below t_max.
    let t32 = t as f32;
    if t <= delta_t || !(t32 > 0.0 && t32 < t_max) {
        return None;
    }
    Some(TriangleHit {
        t: t32,
        b1: (e1 * inv_det) as f32,
        b2: (e2 * inv_det) as f32,
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

    /// The four-lane test answers every lane exactly as the one-triangle test does (same
    /// hit or miss, bit-identical t and barycentrics), on random, degenerate, shared-edge,
    /// axis-aligned, grazing and surface-leaving rays, so that the zero-edge and f64 re-test
    /// paths of both are exercised, with random lane masks and t_max.
    #[test]
    fn block_test_matches_one_triangle_test() {
        let mut rng = Rng::new(7, 3);
        let mut compared = 0usize;
        let mut hits = 0usize;
        for scale in [1e-4f32, 1.0, 1e4] {
            for i in 0..40_000 {
                let random_point = |rng: &mut Rng| {
                    Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 2.0 - Vec3::ONE
                };
                // A fan around a grid point: shared edges and vertices, axis-aligned planes.
                let c = (random_point(&mut rng) * 4.0).round() * scale;
                let mut tris: Vec<[Vec3; 3]> = (0..4)
                    .map(|_| {
                        let mut p = [c, c + random_point(&mut rng) * scale, Vec3::ZERO];
                        p[2] = c + random_point(&mut rng) * scale;
                        if i % 3 == 0 {
                            // Axis plane: one coordinate shared by all three vertices.
                            let k = rng.below(3) as usize;
                            for v in &mut p {
                                v[k] = c[k];
                            }
                        }
                        p
                    })
                    .collect();
                if i % 7 == 0 {
                    tris[rng.below(4) as usize] = [c, c, c + Vec3::X * scale];
                }
                let target_tri = tris[rng.below(4) as usize];
                let (o, d) = match i % 4 {
                    // Leaving a triangle from a point on it (t ~ 0: the f64 re-test).
                    0 => {
                        let (b0, b1) = crate::math::warp::uniform_triangle(rng.uniform2());
                        let o = target_tri[0] * b0
                            + target_tri[1] * b1
                            + target_tri[2] * (1.0 - b0 - b1);
                        (o, crate::math::warp::uniform_sphere(rng.uniform2()))
                    }
                    // Through the shared vertex or an edge, often along an axis.
                    1 => {
                        let target = c + (target_tri[1] - c) * rng.uniform();
                        let d = if rng.uniform() < 0.5 {
                            let k = rng.below(3) as usize;
                            let mut d = Vec3::ZERO;
                            d[k] = if rng.uniform() < 0.5 { 1.0 } else { -1.0 };
                            d
                        } else {
                            crate::math::warp::uniform_sphere(rng.uniform2())
                        };
                        (target - d * scale * 2.0, d)
                    }
                    // Grazing: along the triangle's plane, tilted by a tiny angle.
                    2 => {
                        let n = (target_tri[1] - target_tri[0])
                            .cross(target_tri[2] - target_tri[0])
                            .normalize_or_zero();
                        let u = (target_tri[1] - target_tri[0]).normalize_or_zero();
                        let d = (u + n * 1e-4 * (rng.uniform() - 0.5)).normalize_or(Vec3::X);
                        (target_tri[0] - d * scale, d)
                    }
                    _ => (
                        random_point(&mut rng) * 3.0 * scale,
                        crate::math::warp::uniform_sphere(rng.uniform2()),
                    ),
                };
                let r = RayPrecomp::new(o, d);
                let lanes_r = RayLanes::new(&r);
                let mut block = TriangleBlock::default();
                for (lane, t) in tris.iter().enumerate() {
                    block.set(lane, *t, lane as u32 + 10);
                }
                let lanes = rng.below(16) | if i % 2 == 0 { 0xf } else { 0 };
                let t_max = if i % 5 == 0 {
                    rng.uniform() * 3.0 * scale
                } else {
                    f32::INFINITY
                };
                let got = intersect_triangle_block(&r, &lanes_r, &block, lanes, t_max);
                assert_eq!(got.mask & !lanes, 0);
                for (lane, t) in tris.iter().enumerate() {
                    assert_eq!(block.triangle(lane), *t);
                    assert_eq!(block.id(lane), lane as u32 + 10);
                    if lanes & (1 << lane) == 0 {
                        continue;
                    }
                    compared += 1;
                    let want = intersect_triangle(&r, t[0], t[1], t[2], t_max);
                    let have = (got.mask & (1 << lane) != 0).then(|| TriangleHit {
                        t: got.t[lane],
                        b1: got.b1[lane],
                        b2: got.b2[lane],
                    });
                    let bits = |h: Option<TriangleHit>| {
                        h.map(|h| (h.t.to_bits(), h.b1.to_bits(), h.b2.to_bits()))
                    };
                    assert_eq!(
                        bits(have),
                        bits(want),
                        "scale {scale}, case {i}, lane {lane}: {have:?} vs {want:?}, o {o:?}, d {d:?}, tri {t:?}"
                    );
                    hits += want.is_some() as usize;
                }
            }
        }
        assert!(compared > 200_000 && hits > 10_000, "{compared} {hits}");
    }

    /// Double-precision Moller-Trumbore on the exact f32 inputs: (t, b1, b2) of the line
    /// through the ray crossing the triangle's plane, whether inside the triangle or not.
    fn reference_f64(o: Vec3, d: Vec3, p: [Vec3; 3]) -> Option<(f64, f64, f64)> {
        let v = |a: Vec3| [a.x as f64, a.y as f64, a.z as f64];
        let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let (o, d) = (v(o), v(d));
        let (p0, p1, p2) = (v(p[0]), v(p[1]), v(p[2]));
        let (e1, e2) = (sub(p1, p0), sub(p2, p0));
        let pv = cross(d, e2);
        let det = dot(e1, pv);
        if det == 0.0 {
            return None;
        }
        let s = sub(o, p0);
        let b1 = dot(s, pv) / det;
        let q = cross(s, e1);
        let b2 = dot(d, q) / det;
        let t = dot(e2, q) / det;
        Some((t, b1, b2))
    }

    /// Issue 2's one-triangle reproduction of the Embree cross-check's grazing misses: a ray
    /// about 1e-5 rad off a wall's plane, hitting it at t = 0.667 well inside the triangle,
    /// was rejected because the conservative lower bound on t grew past 0.667 (the shear's
    /// rounding was bounded by the ray's whole z extent instead of its tiny x part).
    #[test]
    fn grazing_hit_far_from_the_origin_is_found() {
        let p = [
            Vec3::new(1.0, 0.75, -0.375),
            Vec3::new(1.0, 0.875, -0.25),
            Vec3::new(1.0, 0.75, -0.25),
        ];
        let (b1, b2) = (0.41f32, 0.49f32);
        let target = p[0] * (1.0 - b1 - b2) + p[1] * b1 + p[2] * b2;
        let mut checked = 0;
        for dx in [8.5e-6f32, 1e-5, 1e-6, 1e-7, 1e-4, 1e-3, 1e-2, -1e-5] {
            let d = Vec3::new(dx, 0.691, -0.723).normalize();
            let o = target - d * 0.667;
            let r = RayPrecomp::new(o, d);
            let h = intersect_triangle(&r, p[0], p[1], p[2], f32::INFINITY);
            let (t_ref, rb1, rb2) = reference_f64(o, d, p).unwrap();
            // The origin's rounding moves the true crossing by up to about 1e-7 / dx: judge
            // by the exact crossing of the f32 ray, and only where it is clearly inside.
            if rb1.min(rb2).min(1.0 - rb1 - rb2) < 0.02 {
                continue;
            }
            checked += 1;
            let h = h.unwrap_or_else(|| panic!("dx {dx}: missed, reference t {t_ref}"));
            assert!(
                (h.t as f64 - t_ref).abs() < 1e-3,
                "dx {dx}: t {} vs {t_ref}",
                h.t
            );
        }
        assert!(checked >= 6, "{checked}");
    }

    /// Grazing rays aimed at points well inside random triangles, at every scale, hit them at
    /// the distance a double-precision test finds. Two families: triangles in an axis plane
    /// (walls, floors: the Embree cross-check's misses), down to 1e-7 rad; and arbitrarily
    /// oriented ones, down to 1e-5 rad. For the latter, f32 itself cannot tell inside from
    /// outside within about 4e-7 / angle (in barycentrics) of an edge: the sheared coordinates
    /// round by an ulp of the vertex coordinates while the triangle's projection is only
    /// `angle` times its size wide; points closer than that to an edge are not asked for.
    #[test]
    fn grazing_rays_hit_like_double_precision() {
        let mut rng = Rng::new(99, 4);
        let mut checked = [0usize; 2];
        for scale in [1e-4f32, 1.0, 1e4] {
            for i in 0..60_000 {
                let axis_plane = i % 2 == 0;
                let c = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 4.0 * scale;
                let mut p = [
                    c,
                    c + crate::math::warp::uniform_sphere(rng.uniform2()) * scale,
                    c + crate::math::warp::uniform_sphere(rng.uniform2()) * scale,
                ];
                if axis_plane {
                    let k = rng.below(3) as usize;
                    for v in &mut p {
                        v[k] = c[k];
                    }
                }
                let n = (p[1] - p[0]).cross(p[2] - p[0]);
                if n.length() < 0.1 * scale * scale {
                    continue; // sliver: no clear inside
                }
                let n = n.normalize();
                let (b0, b1) = crate::math::warp::uniform_triangle(rng.uniform2());
                let target = p[0] * b0 + p[1] * b1 + p[2] * (1.0 - b0 - b1);
                // A unit direction in the plane, tilted out of it by `angle`.
                let in_plane = crate::math::Frame::from_z(n);
                let phi = rng.uniform() * std::f32::consts::TAU;
                let u = in_plane.s * phi.cos() + in_plane.t * phi.sin();
                let angles: &[f32] = if axis_plane {
                    &[1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2]
                } else {
                    &[1e-5, 1e-4, 1e-3, 1e-2]
                };
                let angle = angles[(i / 2) % angles.len()];
                let side = if rng.uniform() < 0.5 { 1.0 } else { -1.0 };
                let d = (u * angle.cos() + n * (side * angle.sin())).normalize();
                let o = target - d * ((0.2 + 3.0 * rng.uniform()) * scale);
                // The f32 origin moves the true crossing: judge by the exact one.
                let Some((t_ref, rb1, rb2)) = reference_f64(o, d, p) else {
                    continue;
                };
                let margin = if axis_plane {
                    0.01
                } else {
                    0.01 + 4e-7 / angle as f64
                };
                if rb1.min(rb2).min(1.0 - rb1 - rb2) < margin || t_ref < 0.01 * scale as f64 {
                    continue;
                }
                checked[axis_plane as usize] += 1;
                let r = RayPrecomp::new(o, d);
                let h =
                    intersect_triangle(&r, p[0], p[1], p[2], f32::INFINITY).unwrap_or_else(|| {
                        panic!(
                            "scale {scale}, angle {angle}, axis plane {axis_plane}: missed \
                             {p:?} from {o:?} along {d:?}, reference t {t_ref}"
                        )
                    });
                // f32 distances of grazing hits are good to about an ulp of the coordinates
                // over the angle.
                let tol = 1e-4 * t_ref + 1e-6 * (t_ref + scale as f64) / angle as f64;
                assert!(
                    (h.t as f64 - t_ref).abs() <= tol,
                    "scale {scale}, angle {angle}: t {} vs {t_ref}",
                    h.t
                );
            }
        }
        assert!(checked[0] > 40_000 && checked[1] > 40_000, "{checked:?}");
    }

    /// The other side of the t bound: rays leaving a point of a plane made of several exactly
    /// coplanar triangles (origin offset as the renderer does), at grazing angles down to
    /// 1e-8 rad, near shared edges and vertices, never hit a triangle of that plane.
    #[test]
    fn grazing_rays_leaving_a_plane_never_hit_it() {
        let mut rng = Rng::new(7, 8);
        // Coordinates with 12 significant bits: 0.5 x + 0.25 y is then exact in f32, so the
        // tilted plane's vertices lie exactly on it.
        // Scales are powers of two (about 1e-4 and 1e4) for the same reason.
        let q = |v: f32| (v * 4096.0).round() / 4096.0;
        for scale in [1.0f32 / 8192.0, 1.0, 8192.0] {
            for tilted in [false, true] {
                let height = |x: f32, y: f32| if tilted { 0.5 * x + 0.25 * y } else { 0.375 };
                // A 3 x 3 grid of quads, each split in two: triangles share edges and vertices.
                let vtx = |i: usize, j: usize| {
                    let (x, y) = (q(i as f32 * 0.3125), q(j as f32 * 0.375));
                    Vec3::new(x, y, height(x, y)) * scale
                };
                let mut tris = Vec::new();
                for i in 0..3 {
                    for j in 0..3 {
                        tris.push([vtx(i, j), vtx(i + 1, j), vtx(i + 1, j + 1)]);
                        tris.push([vtx(i, j), vtx(i + 1, j + 1), vtx(i, j + 1)]);
                    }
                }
                let n = (tris[0][1] - tris[0][0])
                    .cross(tris[0][2] - tris[0][0])
                    .normalize();
                let frame = crate::math::Frame::from_z(n);
                for k in 0..30_000 {
                    let t = tris[rng.below(tris.len() as u32) as usize];
                    // Vertices, edge points and interior points.
                    let (b0, b1) = match k % 3 {
                        0 => [(1.0, 0.0), (0.0, 1.0), (0.0, 0.0)][rng.below(3) as usize],
                        1 => {
                            let u = rng.uniform();
                            [(u, 1.0 - u), (0.0, u), (u, 0.0)][rng.below(3) as usize]
                        }
                        _ => crate::math::warp::uniform_triangle(rng.uniform2()),
                    };
                    let b = [b0, b1, 1.0 - b0 - b1];
                    let p = t[0] * b[0] + t[1] * b[1] + t[2] * b[2];
                    let err = crate::geometry::barycentric_point_error(t, b);
                    let phi = rng.uniform() * std::f32::consts::TAU;
                    let u = frame.s * phi.cos() + frame.t * phi.sin();
                    let angle = [1e-8f32, 1e-7, 1e-6, 1e-5, 1e-4, 1e-2][k % 6];
                    let side = if rng.uniform() < 0.5 { 1.0 } else { -1.0 };
                    let d = (u * angle.cos() + n * (side * angle.sin())).normalize();
                    let o = crate::geometry::offset_ray_origin(p, err, n, d);
                    let r = RayPrecomp::new(o, d);
                    for (ti, tri) in tris.iter().enumerate() {
                        let h = intersect_triangle(&r, tri[0], tri[1], tri[2], f32::INFINITY);
                        assert!(
                            h.is_none(),
                            "scale {scale}, tilted {tilted}, angle {angle}: ray {o:?} {d:?} \
                             leaving triangle {t:?} hit triangle {ti} at {:?}",
                            h
                        );
                    }
                }
            }
        }
    }
}
