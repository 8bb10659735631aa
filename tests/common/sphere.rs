//! A tensor grid over the sphere in (cos theta, phi), with per-cell adaptive Gauss-Legendre
//! quadrature. Directions are binned in the frame they are given in (for BSDFs, the shading
//! frame, so the horizon cos theta = 0 is a cell edge and no cell straddles the discontinuity
//! of a one-sided pdf).
//!
//! A narrow lobe (a Phong exponent of 10^4 has an angular width of ~0.01 rad) would fall inside
//! one coarse cell, where the chi-square test cannot see its shape and a fixed quadrature rule
//! can miss it entirely. `refine_lobe` therefore adds edges around the lobe axis: cells of a
//! fraction of the lobe width over several widths in theta and in phi. Cells of the resulting
//! grid are small where the density varies quickly, so both the test's resolution and the
//! quadrature follow the lobe.

use glam::DVec3;
use std::f64::consts::PI;

/// 5-point Gauss-Legendre rule on [-1, 1]: exact for polynomials of degree 9.
const GL_NODES: [f64; 5] = [
    -0.906_179_845_938_664,
    -0.538_469_310_105_683_1,
    0.0,
    0.538_469_310_105_683_1,
    0.906_179_845_938_664,
];
const GL_WEIGHTS: [f64; 5] = [
    0.236_926_885_056_189_1,
    0.478_628_670_499_366_5,
    0.568_888_888_888_888_9,
    0.478_628_670_499_366_5,
    0.236_926_885_056_189_1,
];

/// Unit direction with cosine `c` to +z and azimuth `phi`.
pub fn direction(c: f64, phi: f64) -> DVec3 {
    let s = (1.0 - c * c).max(0.0).sqrt();
    DVec3::new(s * phi.cos(), s * phi.sin(), c)
}

/// Azimuth of `w` in [0, 2 pi).
pub fn azimuth(w: DVec3) -> f64 {
    let p = w.y.atan2(w.x);
    if p < 0.0 {
        p + 2.0 * PI
    } else {
        p
    }
}

#[derive(Clone, Debug)]
pub struct SphereGrid {
    /// Ascending, from -1 to 1.
    pub cos_edges: Vec<f64>,
    /// Ascending, from 0 to 2 pi.
    pub phi_edges: Vec<f64>,
}

impl SphereGrid {
    /// `n_cos` cells uniform in cos theta (even, so that the horizon is an edge) by `n_phi`.
    pub fn uniform(n_cos: usize, n_phi: usize) -> Self {
        assert!(n_cos >= 2 && n_cos % 2 == 0 && n_phi >= 1);
        SphereGrid {
            cos_edges: (0..=n_cos)
                .map(|i| -1.0 + 2.0 * i as f64 / n_cos as f64)
                .collect(),
            phi_edges: (0..=n_phi)
                .map(|j| 2.0 * PI * j as f64 / n_phi as f64)
                .collect(),
        }
    }

    /// Adds edges resolving a lobe of angular standard deviation `sigma` around unit `axis`:
    /// `steps` cells from the axis out to `widths` sigma on each side, in theta and (unless
    /// the lobe covers a pole) in phi, then cells growing geometrically outwards so that the quadrature also follows the
    /// lobe's tail. Lobes wider than the coarse cells need nothing.
    pub fn refine_lobe(&mut self, axis: DVec3, sigma: f64, widths: f64, steps: usize) {
        let radius = widths * sigma;
        if radius > 0.6 {
            return;
        }
        let axis = axis.normalize();
        let theta = axis.z.clamp(-1.0, 1.0).acos();
        let phi = azimuth(axis);
        let mut radii: Vec<f64> = (1..=steps)
            .map(|k| radius * k as f64 / steps as f64)
            .collect();
        let mut r = radius * 1.6;
        while r < 0.6 {
            radii.push(r);
            r *= 1.6;
        }
        self.cos_edges.push(theta.cos());
        self.phi_edges.push(phi);
        for r in radii {
            for t in [theta - r, theta + r] {
                if (0.0..=PI).contains(&t) {
                    self.cos_edges.push(t.cos());
                }
            }
            // Half-width in phi of the cap of angular radius r, unless it covers a pole.
            if theta - r > 0.0 && theta + r < PI {
                let s = r.sin() / theta.sin();
                if s < 1.0 {
                    let half = s.asin();
                    for p in [phi - half, phi + half] {
                        self.phi_edges.push(p.rem_euclid(2.0 * PI));
                    }
                }
            }
        }
        self.tidy();
    }

    pub fn tidy(&mut self) {
        for (edges, lo, hi) in [
            (&mut self.cos_edges, -1.0, 1.0),
            (&mut self.phi_edges, 0.0, 2.0 * PI),
        ] {
            for e in edges.iter_mut() {
                *e = e.clamp(lo, hi);
            }
            edges.sort_by(f64::total_cmp);
            edges.dedup_by(|a, b| (*a - *b).abs() < 1e-12);
            // Keep the exact end points.
            edges[0] = lo;
            *edges.last_mut().unwrap() = hi;
        }
    }

    pub fn n_cos(&self) -> usize {
        self.cos_edges.len() - 1
    }

    pub fn n_phi(&self) -> usize {
        self.phi_edges.len() - 1
    }

    pub fn cells(&self) -> usize {
        self.n_cos() * self.n_phi()
    }

    /// The cell containing direction `w` (need not be normalized).
    pub fn cell_of(&self, w: DVec3) -> usize {
        let c = (w.z / w.length()).clamp(-1.0, 1.0);
        let p = azimuth(w);
        let i = self
            .cos_edges
            .partition_point(|&e| e <= c)
            .saturating_sub(1)
            .min(self.n_cos() - 1);
        let j = self
            .phi_edges
            .partition_point(|&e| e <= p)
            .saturating_sub(1)
            .min(self.n_phi() - 1);
        i * self.n_phi() + j
    }

    /// Integral of `f` over each cell by the midpoint rule on `k` x `k` points per cell (in
    /// cos theta and phi): for an integrand with many discontinuities (the face-irradiance
    /// pdf, piecewise over voxel faces), where the adaptive rule of [`Self::integrate`] would
    /// split without end; its error falls as 1 / k along the discontinuities.
    pub fn integrate_midpoint(&self, f: impl Fn(DVec3) -> f64, k: usize) -> Vec<f64> {
        let mut out = Vec::with_capacity(self.cells());
        for i in 0..self.n_cos() {
            let (c0, c1) = (self.cos_edges[i], self.cos_edges[i + 1]);
            for j in 0..self.n_phi() {
                let (p0, p1) = (self.phi_edges[j], self.phi_edges[j + 1]);
                let (dc, dp) = ((c1 - c0) / k as f64, (p1 - p0) / k as f64);
                let mut sum = 0.0;
                for a in 0..k {
                    for b in 0..k {
                        sum += f(direction(
                            c0 + (a as f64 + 0.5) * dc,
                            p0 + (b as f64 + 0.5) * dp,
                        ));
                    }
                }
                out.push(sum * dc * dp);
            }
        }
        out
    }

    /// Integral of `f` over each cell with respect to solid angle (dw = dcos dphi).
    pub fn integrate(&self, f: impl Fn(DVec3) -> f64) -> Vec<f64> {
        let mut out = Vec::with_capacity(self.cells());
        for i in 0..self.n_cos() {
            let (c0, c1) = (self.cos_edges[i], self.cos_edges[i + 1]);
            for j in 0..self.n_phi() {
                let (p0, p1) = (self.phi_edges[j], self.phi_edges[j + 1]);
                let whole = gauss_cell(&f, c0, c1, p0, p1);
                out.push(adaptive_cell(&f, c0, c1, p0, p1, whole, 5));
            }
        }
        out
    }
}

/// Tensor Gauss-Legendre rule over [c0, c1] x [p0, p1].
fn gauss_cell(f: &impl Fn(DVec3) -> f64, c0: f64, c1: f64, p0: f64, p1: f64) -> f64 {
    let (cm, ch) = (0.5 * (c0 + c1), 0.5 * (c1 - c0));
    let (pm, ph) = (0.5 * (p0 + p1), 0.5 * (p1 - p0));
    let mut sum = 0.0;
    for (a, wa) in GL_NODES.iter().zip(GL_WEIGHTS) {
        for (b, wb) in GL_NODES.iter().zip(GL_WEIGHTS) {
            sum += wa * wb * f(direction(cm + ch * a, pm + ph * b));
        }
    }
    sum * ch * ph
}

/// Splits the cell in four until the split changes the estimate by less than a relative
/// 1e-4 (or an absolute 1e-10), or `depth` runs out. (A pdf evaluated in f32 is itself only
/// accurate to ~1e-7 n relative for a lobe of exponent n, so tighter tolerances only recurse.)
fn adaptive_cell(
    f: &impl Fn(DVec3) -> f64,
    c0: f64,
    c1: f64,
    p0: f64,
    p1: f64,
    whole: f64,
    depth: u32,
) -> f64 {
    let (cm, pm) = (0.5 * (c0 + c1), 0.5 * (p0 + p1));
    let quads = [
        (c0, cm, p0, pm),
        (c0, cm, pm, p1),
        (cm, c1, p0, pm),
        (cm, c1, pm, p1),
    ];
    let parts = quads.map(|(a, b, c, d)| gauss_cell(f, a, b, c, d));
    let sum: f64 = parts.iter().sum();
    if depth == 0 || (sum - whole).abs() <= 1e-4 * sum.abs() + 1e-10 {
        return sum;
    }
    quads
        .iter()
        .zip(parts)
        .map(|(&(a, b, c, d), part)| adaptive_cell(f, a, b, c, d, part, depth - 1))
        .sum()
}
