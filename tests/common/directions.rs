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
    rng: R,
    sample: impl FnMut(&mut R) -> Option<Vec3>,
    pdf: impl Fn(Vec3) -> f64,
) -> f64 {
    let probs = grid.integrate(|w| pdf(to32(w)));
    chi2_direction_counts(name, grid, probs, rng, sample)
}

/// [`chi2_directions`] with the pdf's integral over each cell of `grid` given (`probs`, in
/// the grid's cell order): for a pdf the adaptive quadrature cannot follow, such as one with
/// many discontinuities.
pub fn chi2_direction_counts<R>(
    name: &str,
    grid: &SphereGrid,
    probs: Vec<f64>,
    mut rng: R,
    mut sample: impl FnMut(&mut R) -> Option<Vec3>,
) -> f64 {
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

/// Random surface points of a scene with their geometric normal and a random incident
/// direction on the normal's side (or the other side, half of the time).
pub fn surface_points(
    scene: &lacuna::scene::Scene,
    count: usize,
    seed: u64,
) -> Vec<(Vec3, Vec3, Vec3, Vec3)> {
    let mut rng = lacuna::math::Rng::new(seed, 3);
    let bounds = scene.bounds();
    let mut out = Vec::new();
    while out.len() < count {
        // A random ray from a random point inside the bounds.
        let u = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform());
        let o = bounds.min + (bounds.max - bounds.min) * u;
        let d = lacuna::math::warp::uniform_sphere(rng.uniform2());
        let ray = lacuna::geometry::Ray::new(o, d, f32::INFINITY);
        if let Some(si) = scene.intersect(&ray) {
            out.push((si.p, si.p_error, si.ng, si.wo));
        }
    }
    out
}
