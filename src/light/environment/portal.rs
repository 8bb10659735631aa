//! Portal-masked environment sampling (B. Bitterli, J. Novák, W. Jarosz, "Portal-masked
//! environment map sampling", EGSR 2015): in an interior lit by the sky through windows, most
//! directions the environment's own density draws hit walls. Given the window rectangles
//! (portals), light sampling at a point draws only directions through the portals it can see,
//! in proportion to the environment's radiance there, with an exact density.
//!
//! Each portal has a *rectified image*: directions on its outward side parametrised by the two
//! angles alpha = atan(w.u / w.n), beta = atan(w.v / w.n) in its frame (u, v along the edges, n
//! outward). Seen from any point behind the portal, the rectangle is an axis-aligned rectangle
//! [alpha0, alpha1] x [beta0, beta1] of that image (the paper's key observation), so sampling the
//! environment restricted to the portal is sampling a piecewise-constant 2-D density over a
//! sub-rectangle of a fixed table. The table's cells hold luminance x the Jacobian
//! d omega / d(alpha, beta) = (w_n^2 + w_u^2)(w_n^2 + w_v^2) / w_n (for unit w), so the density
//! is proportional to the radiance per solid angle. A summed-area table, which is bilinear
//! inside each cell for a piecewise-constant function, gives the mass of any sub-rectangle in
//! O(1) and both the marginal (in alpha) and the conditional (in beta, within one column) by
//! binary search: the sampled density is exactly cell value / sub-rectangle mass, including
//! the cells the rectangle cuts.
//!
//! Several portals: at a point, each visible portal is picked with probability proportional
//! to its mass there, and the density of a direction is the mixture over the portals its ray
//! crosses; a share [`FALLBACK_SHARE`] of the samples comes from [`FALLBACK`] (see there why).
//! Where no portal is visible (a point outside, or behind every window) the sampler
//! falls back to [`FALLBACK`], so the density stays a function of the point and the direction
//! alone. Directions through no portal have density zero here: BSDF sampling reaches them
//! and MIS weighs them 1, so the estimate stays unbiased; occlusion is left to the shadow ray.

use rayon::prelude::*;

use super::{EnvSample, EnvStrategy, EnvironmentMap};
use crate::error::{Error, Result};
use crate::math::{luminance, Vec2, Vec3, PI};

/// What light sampling uses where no portal is visible.
pub const FALLBACK: EnvStrategy = EnvStrategy::LatLong;

/// Share of the samples drawn by [`FALLBACK`] where portals are visible. The portals a point
/// sees are decided by the side of their planes alone, so a point outdoors sees the windows
/// of the far walls "from inside", through the house: without this share (and without an
/// [`InteriorMask`], which hand-listed portals lack) the sunlit ground outside, which lights
/// the rooms, would find the sun only by BSDF sampling (unbiased, but so heavy-tailed that
/// renders of the interior read 17 % low at 8 seeds x 16 x 16 pixels x 32 samples).
pub const FALLBACK_SHARE: f32 = 0.25;

/// Cells per side of each portal's rectified image (0.7 degrees a cell, the sky map's texel
/// size at 512 x 256).
pub const RECTIFIED_RESOLUTION: usize = 256;

/// Most portals a sampler takes (per-point masses live on the stack).
pub const MAX_PORTALS: usize = 64;

/// Gather points per cell side when filling the rectified image.
const GATHER: usize = 3;

/// A cell's value is at least this fraction of its brightest gather point, so a sun a cell
/// wide is not averaged away (the estimate is unbiased whatever the density; this is variance).
const FLOOR: f32 = 0.25;

/// A window rectangle: `corner` + s `edge_u` + t `edge_v` for s, t in [0, 1], light coming in
/// from its `outward` side.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Portal {
    pub corner: Vec3,
    pub edge_u: Vec3,
    pub edge_v: Vec3,
    /// Unit normal toward the outside (the environment).
    pub outward: Vec3,
}

impl Portal {
    /// A portal from a corner, two orthogonal edges and any vector on its outward side (only
    /// the side is used: the normal is the edges' cross product, oriented that way).
    pub fn new(corner: Vec3, edge_u: Vec3, edge_v: Vec3, outward_side: Vec3) -> Result<Self> {
        let finite = [corner, edge_u, edge_v, outward_side]
            .iter()
            .all(|v| v.is_finite());
        let (lu, lv) = (edge_u.length(), edge_v.length());
        if !(finite && lu > 0.0 && lv > 0.0) {
            return Err(Error::invalid(
                "portal: corner and edges must be finite, the edges non-zero",
            ));
        }
        if edge_u.dot(edge_v).abs() > 1e-3 * lu * lv {
            return Err(Error::invalid(
                "portal: the two edges must be orthogonal (a rectangle)",
            ));
        }
        let n = edge_u.cross(edge_v).normalize();
        let side = n.dot(outward_side);
        if !(side.abs() > 0.0) {
            return Err(Error::invalid(
                "portal: the outward side must not lie in the portal's plane",
            ));
        }
        Ok(Portal {
            corner,
            edge_u,
            edge_v,
            outward: if side > 0.0 { n } else { -n },
        })
    }

    pub fn center(&self) -> Vec3 {
        self.corner + 0.5 * (self.edge_u + self.edge_v)
    }

    pub fn area(&self) -> f32 {
        self.edge_u.length() * self.edge_v.length()
    }
}

/// One portal's frame and rectified image.
#[derive(Clone, Debug)]
struct PortalTable {
    corner: Vec3,
    /// Unit edge directions, outward normal, edge lengths.
    eu: Vec3,
    ev: Vec3,
    n: Vec3,
    lu: f32,
    lv: f32,
    /// Cell values, row-major with alpha along a row: `cells[j * RES + i]`.
    cells: Vec<f32>,
    /// Summed-area table: `sat[j * (RES + 1) + i]` = sum of cells i' < i, j' < j.
    sat: Vec<f64>,
}

/// The part of one portal's rectified image seen from a point, in cell units.
#[derive(Clone, Copy, Debug)]
struct Window {
    a: [f32; 2],
    b: [f32; 2],
}

const RES: usize = RECTIFIED_RESOLUTION;

/// The cell a cell coordinate in [0, RES] falls in (the last for RES itself).
#[inline]
fn cell_index(x: f32) -> usize {
    // x >= 0, so truncation is the floor (and NaN becomes 0).
    (x as usize).min(RES - 1)
}

/// The arctangent to within 2.5e-7 rad (Cephes' `atanf`: reduction to |x| <= tan(pi/8) and a
/// degree-9 odd polynomial). libm's `atanf` took a quarter of a portal render's
/// instructions (four per portal for each point's windows, one per portal for each pdf); the
/// sampler uses this one everywhere it maps directions to cells, so windows, samples and
/// densities agree with each other as before.
#[inline]
fn atan(x: f32) -> f32 {
    const TAN_3PI_8: f32 = 2.414_213_5;
    const TAN_PI_8: f32 = 0.414_213_57;
    let t = x.abs();
    let (offset, r) = if t > TAN_3PI_8 {
        (0.5 * PI, -1.0 / t)
    } else if t > TAN_PI_8 {
        (0.25 * PI, (t - 1.0) / (t + 1.0))
    } else {
        (0.0, t)
    };
    let z = r * r;
    let poly = ((8.053_744_5e-2 * z - 1.387_768_6e-1) * z + 1.997_771_1e-1) * z - 3.333_295e-1;
    let y = offset + (poly * z * r + r);
    if x < 0.0 {
        -y
    } else {
        y
    }
}

/// Cell coordinate of an angle in (-pi/2, pi/2).
fn to_cell(angle: f32) -> f32 {
    ((angle / PI + 0.5) * RES as f32).clamp(0.0, RES as f32)
}

fn to_angle(cell: f32) -> f32 {
    (cell / RES as f32 - 0.5) * PI
}

/// d omega / d(alpha, beta) at unit direction (wu, wv, wn) of a portal's frame.
fn jacobian(wu: f32, wv: f32, wn: f32) -> f32 {
    let n2 = wn * wn;
    (n2 + wu * wu) * (n2 + wv * wv) / wn
}

/// The unit direction (portal frame) of angles (alpha, beta).
fn local_direction(alpha: f32, beta: f32) -> Vec3 {
    let (sa, ca) = alpha.sin_cos();
    let (sb, cb) = beta.sin_cos();
    // (tan a, tan b, 1) scaled by cos a cos b.
    Vec3::new(sa * cb, ca * sb, ca * cb).normalize()
}

impl PortalTable {
    fn build(map: &EnvironmentMap, portal: &Portal) -> Self {
        let (lu, lv) = (portal.edge_u.length(), portal.edge_v.length());
        let (eu, ev, n) = (portal.edge_u / lu, portal.edge_v / lv, portal.outward);
        let mut cells = vec![0f32; RES * RES];
        cells.par_chunks_mut(RES).enumerate().for_each(|(j, row)| {
            for (i, cell) in row.iter_mut().enumerate() {
                let (mut sum, mut max) = (0f32, 0f32);
                for ga in 0..GATHER {
                    for gb in 0..GATHER {
                        let alpha = to_angle(i as f32 + (ga as f32 + 0.5) / GATHER as f32);
                        let beta = to_angle(j as f32 + (gb as f32 + 0.5) / GATHER as f32);
                        let d = local_direction(alpha, beta);
                        let w = eu * d.x + ev * d.y + n * d.z;
                        let value = luminance(map.radiance(w)).max(0.0) * jacobian(d.x, d.y, d.z);
                        sum += value;
                        max = max.max(value);
                    }
                }
                let v = (sum / (GATHER * GATHER) as f32).max(FLOOR * max);
                *cell = if v.is_finite() { v } else { 0.0 };
            }
        });
        let stride = RES + 1;
        let mut sat = vec![0f64; stride * stride];
        for j in 0..RES {
            let mut row = 0f64;
            for i in 0..RES {
                row += cells[j * RES + i] as f64;
                sat[(j + 1) * stride + i + 1] = sat[j * stride + i + 1] + row;
            }
        }
        PortalTable {
            corner: portal.corner,
            eu,
            ev,
            n,
            lu,
            lv,
            cells,
            sat,
        }
    }

    /// The integral of the image over [0, i] x [0, b] for a whole number of columns `i`
    /// (two table reads: the marginal's binary search only evaluates these).
    #[inline]
    fn column_prefix(&self, i: usize, b: f32) -> f64 {
        let stride = RES + 1;
        let j = cell_index(b);
        let fb = (b - j as f32) as f64;
        (1.0 - fb) * self.sat[j * stride + i] + fb * self.sat[(j + 1) * stride + i]
    }

    /// The integral of the (continuous, piecewise-constant) image over [0, a] x [0, b].
    #[inline]
    fn integral(&self, a: f32, b: f32) -> f64 {
        let i = cell_index(a);
        let fa = (a - i as f32) as f64;
        (1.0 - fa) * self.column_prefix(i, b) + fa * self.column_prefix(i + 1, b)
    }

    fn mass(&self, w: &Window) -> f64 {
        self.integral(w.a[1], w.b[1])
            - self.integral(w.a[0], w.b[1])
            - self.integral(w.a[1], w.b[0])
            + self.integral(w.a[0], w.b[0])
    }

    /// The portal as seen from `p`: None when `p` is not behind it (on its inner side).
    fn window(&self, p: Vec3) -> Option<Window> {
        let q = p - self.corner;
        let d = -q.dot(self.n);
        if !(d > 1e-5 * (self.lu + self.lv)) {
            return None;
        }
        let (pu, pv) = (q.dot(self.eu), q.dot(self.ev));
        let a = [to_cell(atan(-pu / d)), to_cell(atan((self.lu - pu) / d))];
        let b = [to_cell(atan(-pv / d)), to_cell(atan((self.lv - pv) / d))];
        (a[1] > a[0] && b[1] > b[0]).then_some(Window { a, b })
    }

    /// Draws cell coordinates (a, b) in the window with density cell / mass.
    fn sample(&self, w: &Window, mass: f64, u: Vec2) -> (f32, f32) {
        // Marginal in a: G(a) = integral over [b0, b1] of columns up to a. The binary search
        // evaluates it at whole columns only (`column_prefix`), the ends by `integral`.
        let g = |a: f32| {
            let i = a as usize;
            if a == i as f32 {
                self.column_prefix(i, w.b[1]) - self.column_prefix(i, w.b[0])
            } else {
                self.integral(a, w.b[1]) - self.integral(a, w.b[0])
            }
        };
        let target = g(w.a[0]) + u.x as f64 * mass;
        let a = invert(w.a, target, g);
        let i = cell_index(a);
        // Conditional in b within column i: C(b) = the column's integral up to b.
        let column = |b: f32| self.column_prefix(i + 1, b) - self.column_prefix(i, b);
        let c0 = column(w.b[0]);
        let target_b = c0 + u.y as f64 * (column(w.b[1]) - c0);
        let b = invert(w.b, target_b, column);
        (a, b)
    }

    #[inline]
    fn cell(&self, a: f32, b: f32) -> f32 {
        self.cells[cell_index(b) * RES + cell_index(a)]
    }

    /// Angles of world direction `dir` in the portal's frame, with its Jacobian; None on the
    /// inner side.
    fn angles(&self, dir: Vec3) -> Option<(f32, f32, f32)> {
        let (wu, wv, wn) = (dir.dot(self.eu), dir.dot(self.ev), dir.dot(self.n));
        if !(wn > 0.0) {
            return None;
        }
        // atan2(wu, wn) with wn > 0.
        Some((
            to_cell(atan(wu / wn)),
            to_cell(atan(wv / wn)),
            jacobian(wu, wv, wn),
        ))
    }

    fn world(&self, a: f32, b: f32) -> Vec3 {
        let d = local_direction(to_angle(a), to_angle(b));
        (self.eu * d.x + self.ev * d.y + self.n * d.z).normalize()
    }
}

/// Inverts a non-decreasing function `f` that is linear between integer cell coordinates, on
/// `range`: the x with f(x) = target (clamped to the range).
fn invert(range: [f32; 2], target: f64, f: impl Fn(f32) -> f64) -> f32 {
    let (lo, hi) = (range[0], range[1]);
    // Integer breakpoints strictly inside the range; binary search the last with f <= target.
    // lo, hi >= 0: truncation is the floor (no libm call).
    let hi_ceil = if hi == (hi as i64) as f32 {
        hi as i64
    } else {
        hi as i64 + 1
    };
    let (mut first, mut last) = (lo as i64 + 1, hi_ceil - 1);
    let mut start = lo;
    while first <= last {
        let mid = (first + last) / 2;
        if f(mid as f32) <= target {
            start = mid as f32;
            first = mid + 1;
        } else {
            last = mid - 1;
        }
    }
    let end = ((start as i64) as f32 + 1.0).min(hi);
    let (f0, f1) = (f(start), f(end));
    let t = if f1 > f0 {
        ((target - f0) / (f1 - f0)) as f32
    } else {
        0.5
    };
    (start + t.clamp(0.0, 1.0) * (end - start)).clamp(lo, hi)
}

/// Where portals apply: a voxel grid of the points inside (rooms, and the surfaces around
/// them). Elsewhere, outdoors, light sampling uses [`FALLBACK`] alone: a point outdoors is on
/// the inner side of the far walls' windows and would waste portal samples on the house.
#[derive(Clone, Debug)]
pub struct InteriorMask {
    pub origin: Vec3,
    pub voxel_size: f32,
    pub dims: [usize; 3],
    /// One flag per voxel, x fastest.
    pub inside: Vec<bool>,
}

impl InteriorMask {
    fn contains(&self, p: Vec3) -> bool {
        let g = (p - self.origin) / self.voxel_size;
        if !(g.min_element() >= 0.0) {
            return false;
        }
        let c = [g.x as usize, g.y as usize, g.z as usize];
        if c[0] >= self.dims[0] || c[1] >= self.dims[1] || c[2] >= self.dims[2] {
            return false;
        }
        self.inside[c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])]
    }
}

/// The portals one point sees: their indices, windows and masses, and the total mass (0 when
/// none is visible). Light sampling at a vertex and the density of a BSDF-sampled ray that
/// leaves it need the same, so the last point's is kept per thread ([`SEEN`]).
#[derive(Clone, Copy)]
struct Seen {
    /// The sampler ([`PortalSampler::id`]) and the point (bit patterns) it is for.
    sampler: u64,
    point: [u32; 3],
    len: usize,
    index: [u8; MAX_PORTALS],
    window: [Window; MAX_PORTALS],
    mass: [f64; MAX_PORTALS],
    total: f64,
}

impl Seen {
    const EMPTY: Seen = Seen {
        sampler: 0,
        point: [0; 3],
        len: 0,
        index: [0; MAX_PORTALS],
        window: [Window {
            a: [0.0; 2],
            b: [0.0; 2],
        }; MAX_PORTALS],
        mass: [0.0; MAX_PORTALS],
        total: 0.0,
    };

    fn visible(&self) -> impl Iterator<Item = (usize, &Window, f64)> {
        (0..self.len).map(|k| (self.index[k] as usize, &self.window[k], self.mass[k]))
    }
}

thread_local! {
    /// The portals seen from the last point queried on this thread (keyed by sampler and
    /// point, so a hit is exactly what recomputing would give).
    static SEEN: std::cell::RefCell<Seen> = const { std::cell::RefCell::new(Seen::EMPTY) };
}

/// Identifiers of built samplers (0 is the empty cache's).
static NEXT_SAMPLER_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

/// The rectified images of a set of portals, for one environment map.
#[derive(Clone, Debug)]
pub struct PortalSampler {
    portals: Vec<Portal>,
    tables: Vec<PortalTable>,
    interior: Option<InteriorMask>,
    build_seconds: f64,
    /// Distinguishes this sampler's entries in [`SEEN`] (a clone has the same tables).
    id: u64,
}

impl PortalSampler {
    /// Builds the rectified image of each portal (in parallel).
    pub fn build(map: &EnvironmentMap, portals: &[Portal]) -> Result<Self> {
        Self::build_masked(map, portals, None)
    }

    /// [`build`](Self::build), the portals applying only inside `interior` (all points
    /// without).
    pub fn build_masked(
        map: &EnvironmentMap,
        portals: &[Portal],
        interior: Option<InteriorMask>,
    ) -> Result<Self> {
        if portals.len() > MAX_PORTALS {
            return Err(Error::invalid(format!(
                "{} environment portals: at most {MAX_PORTALS} are supported",
                portals.len()
            )));
        }
        let started = std::time::Instant::now();
        let tables = portals.iter().map(|p| PortalTable::build(map, p)).collect();
        Ok(PortalSampler {
            portals: portals.to_vec(),
            tables,
            interior,
            build_seconds: started.elapsed().as_secs_f64(),
            id: NEXT_SAMPLER_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
        })
    }

    pub fn portals(&self) -> &[Portal] {
        &self.portals
    }

    pub fn build_seconds(&self) -> f64 {
        self.build_seconds
    }

    pub fn memory_bytes(&self) -> usize {
        self.tables
            .iter()
            .map(|t| t.cells.len() * 4 + t.sat.len() * 8)
            .sum()
    }

    /// Calls `f` with the portals seen from `p`, computed unless this thread's last query
    /// was the same point of this sampler.
    fn with_seen<R>(&self, p: Vec3, f: impl FnOnce(&Seen) -> R) -> R {
        let point = p.to_array().map(f32::to_bits);
        SEEN.with(|cell| {
            let mut seen = cell.borrow_mut();
            if seen.sampler != self.id || seen.point != point {
                self.compute_seen(p, &mut seen);
                seen.sampler = self.id;
                seen.point = point;
            }
            f(&seen)
        })
    }

    /// Each visible portal's window and mass seen from `p`, and their total.
    fn compute_seen(&self, p: Vec3, seen: &mut Seen) {
        seen.len = 0;
        seen.total = 0.0;
        if self.interior.as_ref().is_some_and(|m| !m.contains(p)) {
            return;
        }
        for (k, t) in self.tables.iter().enumerate() {
            if let Some(w) = t.window(p) {
                let m = t.mass(&w);
                if m > 0.0 {
                    let slot = seen.len;
                    seen.index[slot] = k as u8;
                    seen.window[slot] = w;
                    seen.mass[slot] = m;
                    seen.len += 1;
                    seen.total += m;
                }
            }
        }
    }

    /// Samples a direction at point `p` (facing normal `n`, for the fallback).
    pub fn sample(&self, map: &EnvironmentMap, p: Vec3, n: Vec3, u: Vec2) -> Option<EnvSample> {
        self.with_seen(p, |seen| self.sample_seen(seen, map, n, u))
    }

    fn sample_seen(
        &self,
        seen: &Seen,
        map: &EnvironmentMap,
        n: Vec3,
        u: Vec2,
    ) -> Option<EnvSample> {
        if !(seen.total > 0.0) {
            return map.sample(FALLBACK, n, u);
        }
        // One-sample mixture: the fallback with probability FALLBACK_SHARE (u.x rescaled).
        if u.x < FALLBACK_SHARE {
            let ux = (u.x / FALLBACK_SHARE).min(1.0 - f32::EPSILON / 2.0);
            let s = map.sample(FALLBACK, n, Vec2::new(ux, u.y))?;
            let pdf = FALLBACK_SHARE * s.pdf + (1.0 - FALLBACK_SHARE) * self.pdf_given(seen, s.wi);
            return (pdf > 0.0 && pdf.is_finite()).then_some(EnvSample { pdf, ..s });
        }
        let ux = ((u.x - FALLBACK_SHARE) / (1.0 - FALLBACK_SHARE)).min(1.0 - f32::EPSILON / 2.0);
        // Pick a portal by mass with u.x, reusing the rest of u.x for the sample.
        let mut target = ux as f64 * seen.total;
        let mut chosen = None;
        for (k, window, mass) in seen.visible() {
            chosen = Some((k, window, mass));
            if target < mass {
                break;
            }
            target -= mass;
        }
        let (k, window, mass) = chosen?;
        let ux = ((target / mass) as f32).clamp(0.0, 1.0 - f32::EPSILON / 2.0);
        let (a, b) = self.tables[k].sample(window, mass, Vec2::new(ux, u.y));
        let wi = self.tables[k].world(a, b);
        let pdf = FALLBACK_SHARE * map.pdf(FALLBACK, n, wi)
            + (1.0 - FALLBACK_SHARE) * self.pdf_given(seen, wi);
        (pdf > 0.0 && pdf.is_finite()).then(|| EnvSample {
            wi,
            radiance: map.radiance(wi),
            pdf,
        })
    }

    /// Solid-angle density of [`sample`](Self::sample) at `p` drawing world direction `w`.
    pub fn pdf(&self, map: &EnvironmentMap, p: Vec3, n: Vec3, w: Vec3) -> f32 {
        let portal_pdf = self.with_seen(p, |seen| {
            (seen.total > 0.0).then(|| self.pdf_given(seen, w))
        });
        match portal_pdf {
            None => map.pdf(FALLBACK, n, w),
            Some(pdf) => FALLBACK_SHARE * map.pdf(FALLBACK, n, w) + (1.0 - FALLBACK_SHARE) * pdf,
        }
    }

    /// The density of the portal part of the mixture (all its samples through a visible
    /// portal) at world direction `w`.
    fn pdf_given(&self, seen: &Seen, w: Vec3) -> f32 {
        // Density in (a, b) cell units -> (alpha, beta): times (RES / pi)^2.
        let cell_scale = (RES as f64 / PI as f64).powi(2);
        let mut pdf = 0f64;
        for (k, window, _) in seen.visible() {
            let t = &self.tables[k];
            let Some((a, b, jac)) = t.angles(w) else {
                continue;
            };
            if a < window.a[0] || a > window.a[1] || b < window.b[0] || b > window.b[1] {
                continue;
            }
            // The portal's share m / total times its density cell / m.
            pdf += t.cell(a, b) as f64 / seen.total * cell_scale / jac as f64;
        }
        pdf as f32
    }
}

#[cfg(test)]
mod tests {
    use super::super::{EnvImage, EnvSettings};
    use super::*;
    use crate::math::{Rgb, Rng};

    /// A sky-like map: a gradient plus a bright small sun, so the density is far from uniform.
    fn test_map() -> EnvironmentMap {
        let (w, h) = (64, 32);
        let mut pixels = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let sun = if (x as i32 - 40).abs() <= 1 && (y as i32 - 12).abs() <= 1 {
                    200.0
                } else {
                    0.0
                };
                let sky = 1.0 + 2.0 * (1.0 - y as f32 / h as f32) + 0.5 * (x as f32 / w as f32);
                pixels.push(Rgb::new(sky + sun, sky * 0.9 + sun, sky * 0.7 + sun));
            }
        }
        EnvironmentMap::new(
            EnvImage::from_pixels(w, h, pixels).unwrap(),
            EnvSettings::default(),
        )
        .unwrap()
    }

    fn window(corner: Vec3, eu: Vec3, ev: Vec3, out: Vec3) -> Portal {
        Portal::new(corner, eu, ev, out).unwrap()
    }

    /// Two windows of different sizes in different walls of a room around the origin, and one
    /// whose outside the test point is on (which must never be sampled).
    fn portals() -> Vec<Portal> {
        vec![
            window(
                Vec3::new(-1.0, 0.2, -2.0),
                Vec3::new(2.0, 0.0, 0.0),
                Vec3::new(0.0, 1.2, 0.0),
                Vec3::NEG_Z,
            ),
            window(
                Vec3::new(2.0, 0.5, 0.3),
                Vec3::new(0.0, 0.0, 0.5),
                Vec3::new(0.0, 0.6, 0.0),
                Vec3::X,
            ),
            window(
                Vec3::new(-3.0, 0.0, -1.0),
                Vec3::new(0.0, 0.0, 1.0),
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::X,
            ),
        ]
    }

    /// Chi-square of the sampled directions against the pdf integrated over lat-long bins
    /// (with 8x8 sub-points per bin), and the pdf's integral over the sphere.
    fn chi_square(portals: &[Portal], p: Vec3) -> (f64, usize, f64) {
        let map = test_map();
        let sampler = PortalSampler::build(&map, portals).unwrap();
        let (bins_theta, bins_phi) = (24usize, 48usize);
        let bin_of = |w: Vec3| {
            let theta = w.y.clamp(-1.0, 1.0).acos();
            let phi = w.z.atan2(w.x) + PI;
            let i = ((theta / PI) * bins_theta as f32).min(bins_theta as f32 - 1.0) as usize;
            let j = ((phi / (2.0 * PI)) * bins_phi as f32).min(bins_phi as f32 - 1.0) as usize;
            i * bins_phi + j
        };
        let n = 200_000usize;
        let mut observed = vec![0f64; bins_theta * bins_phi];
        let mut rng = Rng::new(7, 0);
        for _ in 0..n {
            let s = sampler.sample(&map, p, Vec3::ZERO, rng.uniform2()).unwrap();
            assert!(s.pdf.is_finite() && s.pdf > 0.0);
            let again = sampler.pdf(&map, p, Vec3::ZERO, s.wi);
            assert!(
                (again - s.pdf).abs() <= 1e-3 * s.pdf,
                "{again} vs {}",
                s.pdf
            );
            observed[bin_of(s.wi)] += 1.0;
        }
        let sub = 48usize;
        let mut expected = vec![0f64; bins_theta * bins_phi];
        let mut integral = 0f64;
        for i in 0..bins_theta * sub {
            let theta = (i as f64 + 0.5) / (bins_theta * sub) as f64 * PI as f64;
            for j in 0..bins_phi * sub {
                let phi = (j as f64 + 0.5) / (bins_phi * sub) as f64 * 2.0 * PI as f64 - PI as f64;
                let w = Vec3::new(
                    (theta.sin() * phi.cos()) as f32,
                    theta.cos() as f32,
                    (theta.sin() * phi.sin()) as f32,
                );
                let d_omega = theta.sin()
                    * (PI as f64 / (bins_theta * sub) as f64)
                    * (2.0 * PI as f64 / (bins_phi * sub) as f64);
                let mass = sampler.pdf(&map, p, Vec3::ZERO, w) as f64 * d_omega;
                integral += mass;
                expected[bin_of(w)] += mass * n as f64;
            }
        }
        let (mut chi2, mut dof) = (0f64, 0usize);
        let (mut pooled_o, mut pooled_e) = (0f64, 0f64);
        for (o, e) in observed.iter().zip(&expected) {
            if *e < 20.0 {
                pooled_o += o;
                pooled_e += e;
            } else {
                chi2 += (o - e) * (o - e) / e;
                dof += 1;
            }
        }
        if pooled_e > 20.0 {
            chi2 += (pooled_o - pooled_e).powi(2) / pooled_e;
            dof += 1;
        } else {
            assert!(
                pooled_o < 40.0,
                "{pooled_o} samples where the pdf puts {pooled_e}"
            );
        }
        (chi2, dof, integral)
    }

    /// The chi-square bound at about p = 1e-4 for `dof` degrees of freedom (Wilson-Hilferty).
    fn chi2_bound(dof: usize) -> f64 {
        let k = dof as f64;
        let z = 3.72;
        k * (1.0 - 2.0 / (9.0 * k) + z * (2.0 / (9.0 * k)).sqrt()).powi(3)
    }

    #[test]
    fn one_portal_pdf_agrees_with_sampling() {
        let (chi2, dof, integral) = chi_square(&portals()[..1], Vec3::new(0.3, 0.9, 0.4));
        assert!(
            (integral - 1.0).abs() < 0.01,
            "pdf integrates to {integral}"
        );
        assert!(chi2 < chi2_bound(dof), "chi2 {chi2} with {dof} dof");
    }

    #[test]
    fn several_portals_pdf_agrees_with_sampling() {
        let (chi2, dof, integral) = chi_square(&portals(), Vec3::new(0.3, 0.9, 0.4));
        assert!(
            (integral - 1.0).abs() < 0.01,
            "pdf integrates to {integral}"
        );
        assert!(chi2 < chi2_bound(dof), "chi2 {chi2} with {dof} dof");
    }

    #[test]
    fn directions_miss_the_visible_portals_only_by_the_fallback_share() {
        let map = test_map();
        let all = portals();
        let sampler = PortalSampler::build(&map, &all).unwrap();
        let p = Vec3::new(0.3, 0.9, 0.4);
        let mut rng = Rng::new(3, 0);
        let mut crossing = 0;
        for _ in 0..10_000 {
            let s = sampler.sample(&map, p, Vec3::ZERO, rng.uniform2()).unwrap();
            let through = all[..2].iter().any(|portal| {
                let t = (portal.corner - p).dot(portal.outward) / s.wi.dot(portal.outward);
                let h = p + s.wi * t - portal.corner;
                let (su, sv) = (
                    h.dot(portal.edge_u) / portal.edge_u.length_squared(),
                    h.dot(portal.edge_v) / portal.edge_v.length_squared(),
                );
                t > 0.0 && (-1e-3..=1.001).contains(&su) && (-1e-3..=1.001).contains(&sv)
            });
            if through {
                crossing += 1;
            } else {
                // Drawn by the fallback share, and only its density there (to the lat-long
                // density's own f32 precision near the poles, where 1 / sin(theta) is large).
                let fallback = FALLBACK_SHARE * map.pdf(FALLBACK, Vec3::ZERO, s.wi);
                assert!(
                    (s.pdf - fallback).abs() <= 5e-3 * fallback,
                    "{s:?}: {fallback}"
                );
            }
        }
        let expected = (1.0 - FALLBACK_SHARE) * 10_000.0;
        assert!(
            crossing as f32 >= expected - 300.0,
            "{crossing} of 10000 through portals"
        );
        // A point outside every portal's inner side falls back to the whole map.
        let outside = Vec3::new(10.0, 0.5, -10.0);
        let s = sampler
            .sample(&map, outside, Vec3::ZERO, Vec2::new(0.3, 0.6))
            .unwrap();
        let expected = map.pdf(FALLBACK, Vec3::ZERO, s.wi);
        assert!((sampler.pdf(&map, outside, Vec3::ZERO, s.wi) - expected).abs() <= 1e-6 * expected);
    }

    #[test]
    fn the_arctangent_is_within_float_precision() {
        let mut worst = 0f64;
        for k in -200_000..=200_000 {
            // Dense near 0 and tan(pi/8), tan(3 pi/8), out to 1e4 and beyond.
            let x = (k as f64 / 2_000.0).powi(3) as f32;
            let err = (atan(x) as f64 - (x as f64).atan()).abs();
            worst = worst.max(err);
        }
        for x in [
            f32::MAX,
            f32::INFINITY,
            1e-30,
            0.0,
            -0.0,
            0.414_213_57,
            2.414_213_5,
        ] {
            worst = worst.max((atan(x) as f64 - (x as f64).atan()).abs());
            worst = worst.max((atan(-x) as f64 + (x as f64).atan()).abs());
        }
        assert!(worst < 2.5e-7, "worst error {worst:e} rad");
        assert!(atan(f32::NAN).is_nan());
    }

    #[test]
    fn bad_portals_are_refused() {
        let z = Vec3::ZERO;
        assert!(Portal::new(z, Vec3::X, Vec3::ZERO, Vec3::Z).is_err());
        assert!(Portal::new(z, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Z).is_err());
        assert!(Portal::new(z, Vec3::X, Vec3::Y, Vec3::X).is_err());
        assert!(Portal::new(Vec3::splat(f32::NAN), Vec3::X, Vec3::Y, Vec3::Z).is_err());
        let p = Portal::new(z, Vec3::X, Vec3::Y, Vec3::NEG_Z).unwrap();
        assert_eq!(p.outward, Vec3::NEG_Z);
    }
}
