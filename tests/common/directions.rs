//! Chi-square test of a direction sampler against its pdf over a sphere grid, shared by the
//! guide's sampling tests (the skeleton lobes and the learned histograms).

use glam::DVec3;
use lacuna::math::Vec3;

use super::chi2::assert_chi2;
use super::sphere::SphereGrid;

/// Directions drawn per chi-square test.
pub const SAMPLES: usize = 200_000;

pub fn to64(v: Vec3) -> DVec3 {
    DVec3::new(v.x as f64, v.y as f64, v.z as f64)
}

pub fn to32(v: DVec3) -> Vec3 {
    Vec3::new(v.x as f32, v.y as f32, v.z as f32)
}

/// Draws `SAMPLES` directions with `sample` (from `rng`: a `Sampler` or a bare `Rng`) (None: no direction, its own cell) and compares
/// their counts per cell of `grid` with `pdf`'s quadrature by chi-square; returns the pdf's
/// integral over the sphere (at most 1; the rest is the chance of no direction).
pub fn chi2_directions<R>(
    name: &str,
    grid: &SphereGrid,
    mut rng: R,
    mut sample: impl FnMut(&mut R) -> Option<Vec3>,
    pdf: impl Fn(Vec3) -> f64,
) -> f64 {
    let probs = grid.integrate(|w| pdf(to32(w)));
    let integral: f64 = probs.iter().sum();
    assert!(
        integral <= 1.0 + 1e-3,
        "{name}: pdf integrates to {integral}"
    );
    let mut observed = vec![0u64; grid.cells() + 1];
    for _ in 0..SAMPLES {
        match sample(&mut rng) {
            Some(w) => observed[grid.cell_of(to64(w))] += 1,
            None => observed[grid.cells()] += 1,
        }
    }
    let n = SAMPLES as f64;
    let mut expected: Vec<f64> = probs.iter().map(|p| p * n).collect();
    expected.push((1.0 - integral).max(0.0) * n);
    assert_chi2(name, &observed, &expected);
    integral
}
