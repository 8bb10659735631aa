//! Sampling densities over the directions of an environment map, each with its exact pdf:
//!
//! - [`LatLongSampler`]: the classic 2-D piecewise-constant density over a lat-long grid,
//!   texels weighted by luminance x sin(theta) (pbrt's infinite area light), pdf with respect
//!   to solid angle p(u, v) / (2 pi^2 sin theta).
//! - [`CubeSampler`]: one tabulated 2-D CDF per cube face (001 §3.3.2, eq. 3.3), texels
//!   weighted by luminance x the texel's solid angle at its centre (eq. 3.13), and the
//!   balancing of samples across faces: uniform (mu_f = 1/6), by face power, or per normal with
//!   the pseudo form factor mu_f(n) (eq. 3.4).
//!
//! A density may be built on a grid other than the image's own (a cube density over a
//! lat-long image): a texel's weight is then the mean luminance at 3 x 3 points of it, but at
//! least a quarter of the brightest image texel that may overlap it (found through bounding
//! caps, a superset of the true overlaps). The floor keeps radiance over density bounded next
//! to a sun a few texels wide, and the density positive wherever the radiance is. Both tables
//! depend only on the two grids: they are computed once, and a new image of the same layout
//! re-weights with plain loads.

use rayon::prelude::*;

use super::grid::{self, cube_coordinates, cube_direction, latlong_texels_near, Grid};
use super::image::EnvImage;
use crate::math::{luminance, Distribution2D, Vec2, Vec3, PI};

/// Gather points per texel side when densities and image use different grids.
const GATHER: usize = 3;
const GATHER2: usize = GATHER * GATHER;

/// How the texel weights of a density grid are read from an image.
#[derive(Clone, Debug)]
struct Weights {
    grid: Grid,
    image_grid: Grid,
    /// Per grid texel, its solid-angle factor (`Grid::weight_factor`).
    factor: Vec<f32>,
    /// When the grids differ: `GATHER2` image texel indices per grid texel (for the mean)...
    gather: Option<Vec<u32>>,
    /// ... and every image texel that may overlap it, as offsets into a list of indices (a
    /// superset from bounding caps: for the conservative bound).
    overlap: Option<(Vec<u32>, Vec<u32>)>,
    /// Scratch: weights of the last build.
    values: Vec<f32>,
}

/// A grid texel's weight is at least this fraction of its brightest overlapping image texel:
/// inside it, radiance over density is then at most 1 / FLOOR times what it would be for a
/// density proportional to that texel's luminance (a mean of gather points alone may miss a
/// sliver of a sun 1e5 over the sky and sample it 1e5 times too rarely).
const FLOOR: f32 = 0.25;

/// Smallest number of items per rayon job: 1 to run in parallel, everything in one job to run
/// on the calling thread. Structures built lazily inside a render run on the calling thread:
/// a worker waiting in a parallel loop could otherwise pick up a render task that asks for
/// the same structure, re-entering its one-time initialisation.
fn min_len(parallel: bool) -> usize {
    if parallel {
        1
    } else {
        usize::MAX
    }
}

impl Weights {
    fn new(grid: Grid, image: &EnvImage, parallel: bool) -> Self {
        let n = grid.texel_count();
        let factor = (0..n).map(|i| grid.weight_factor(i)).collect();
        let image_grid = image.grid();
        let differ = image_grid != grid;
        // Geometry only, computed once per pair of grids (in parallel: ~1M trigonometric
        // lookups for a 512 x 256 map).
        let gather = differ.then(|| {
            let mut g = vec![0u32; n * GATHER2];
            g.par_chunks_mut(GATHER2)
                .with_min_len(min_len(parallel))
                .enumerate()
                .for_each(|(i, out)| {
                    for a in 0..GATHER {
                        for b in 0..GATHER {
                            let d = grid.texel_point(
                                i,
                                (a as f32 + 0.5) / GATHER as f32,
                                (b as f32 + 0.5) / GATHER as f32,
                            );
                            out[a * GATHER + b] = image_grid.texel_of(d) as u32;
                        }
                    }
                });
            g
        });
        let overlap = differ.then(|| overlaps(grid, image_grid, parallel));
        Weights {
            grid,
            image_grid,
            factor,
            gather,
            overlap,
            values: vec![0.0; n],
        }
    }

    /// Computes the texel weights of `image` (whose grid must be the one given to `new`):
    /// luminance x solid-angle factor on the image's own grid; on another grid, the larger of
    /// the mean over the gather points and `FLOOR` x the brightest overlapping image texel
    /// (so the density is positive wherever the radiance is).
    fn compute(&mut self, image: &EnvImage, parallel: bool) {
        assert_eq!(image.grid(), self.image_grid);
        let texels = image.texels();
        match (&self.gather, &self.overlap) {
            (Some(g), Some((offsets, list))) => {
                let lum: Vec<f32> = texels.iter().map(|&c| luminance(c).max(0.0)).collect();
                self.values
                    .par_iter_mut()
                    .with_min_len(min_len(parallel))
                    .enumerate()
                    .for_each(|(i, v)| {
                        let sum: f32 = g[i * GATHER2..(i + 1) * GATHER2]
                            .iter()
                            .map(|&k| lum[k as usize])
                            .sum();
                        let range = offsets[i] as usize..offsets[i + 1] as usize;
                        let max = list[range]
                            .iter()
                            .map(|&k| lum[k as usize])
                            .fold(0.0f32, f32::max);
                        *v = (sum / GATHER2 as f32).max(FLOOR * max) * self.factor[i];
                    });
            }
            _ => {
                for ((v, &f), &c) in self.values.iter_mut().zip(&self.factor).zip(texels) {
                    *v = luminance(c).max(0.0) * f;
                }
            }
        }
    }
}

/// For each texel of `grid`, the texels of `image_grid` that may overlap it (one grid is
/// lat-long, the other a cube): every pair whose lat-long texel meets the bounding cap of the
/// cube texel, which includes every pair that truly overlaps. As (offsets, indices).
fn overlaps(grid: Grid, image_grid: Grid, parallel: bool) -> (Vec<u32>, Vec<u32>) {
    let csr = |lists: Vec<Vec<u32>>| {
        let mut offsets = Vec::with_capacity(lists.len() + 1);
        let mut indices = Vec::with_capacity(lists.iter().map(Vec::len).sum());
        offsets.push(0u32);
        for l in lists {
            indices.extend_from_slice(&l);
            offsets.push(indices.len() as u32);
        }
        (offsets, indices)
    };
    match (grid, image_grid) {
        (Grid::Cube { .. }, Grid::LatLong { width, height }) => {
            let lists: Vec<Vec<u32>> = (0..grid.texel_count())
                .into_par_iter()
                .with_min_len(min_len(parallel))
                .map(|i| {
                    let mut l = Vec::new();
                    latlong_texels_near(
                        width,
                        height,
                        grid.texel_point(i, 0.5, 0.5),
                        grid.texel_radius(i),
                        |k| l.push(k as u32),
                    );
                    l
                })
                .collect();
            csr(lists)
        }
        (Grid::LatLong { width, height }, Grid::Cube { .. }) => {
            // Enumerate from the cube side, then invert.
            let per_cube: Vec<Vec<u32>> = (0..image_grid.texel_count())
                .into_par_iter()
                .with_min_len(min_len(parallel))
                .map(|k| {
                    let mut l = Vec::new();
                    latlong_texels_near(
                        width,
                        height,
                        image_grid.texel_point(k, 0.5, 0.5),
                        image_grid.texel_radius(k),
                        |i| l.push(i as u32),
                    );
                    l
                })
                .collect();
            let mut lists = vec![Vec::new(); grid.texel_count()];
            for (k, l) in per_cube.iter().enumerate() {
                for &i in l {
                    lists[i as usize].push(k as u32);
                }
            }
            csr(lists)
        }
        _ => unreachable!("densities on another grid pair a lat-long and a cube grid"),
    }
}

/// The classic 2-D piecewise-constant density over a lat-long grid.
#[derive(Clone, Debug)]
pub struct LatLongSampler {
    width: usize,
    height: usize,
    weights: Weights,
    distribution: Distribution2D,
}

impl LatLongSampler {
    /// Over the image's own grid when it is lat-long, else over a 4F x 2F grid for faces of F.
    pub fn new(image: &EnvImage) -> Self {
        Self::build(image, true)
    }

    /// `new`, on the calling thread only unless `parallel`.
    pub fn build(image: &EnvImage, parallel: bool) -> Self {
        let grid = match image.grid() {
            g @ Grid::LatLong { .. } => g,
            Grid::Cube { face } => Grid::LatLong {
                width: 4 * face,
                height: 2 * face,
            },
        };
        let Grid::LatLong { width, height } = grid else {
            unreachable!()
        };
        let mut weights = Weights::new(grid, image, parallel);
        weights.compute(image, parallel);
        let distribution = Distribution2D::new(&weights.values, width, height);
        LatLongSampler {
            width,
            height,
            weights,
            distribution,
        }
    }

    /// Re-weights from an image of the same layout, reusing every table.
    pub fn rebuild(&mut self, image: &EnvImage) {
        self.weights.compute(image, true);
        self.distribution.rebuild(&self.weights.values);
    }

    pub fn grid(&self) -> Grid {
        self.weights.grid
    }

    /// True when some direction has positive density (the map is not black).
    pub fn is_lit(&self) -> bool {
        self.distribution.integral() > 0.0
    }

    /// A local direction and its solid-angle pdf.
    pub fn sample(&self, u: Vec2) -> Option<(Vec3, f32)> {
        if !self.is_lit() {
            return None;
        }
        let (p, pdf_uv) = self.distribution.sample(u);
        let d = grid::latlong_direction(p.x, p.y);
        let sin_theta = (PI * p.y).sin();
        let pdf = pdf_uv / (2.0 * PI * PI * sin_theta);
        (pdf_uv > 0.0 && sin_theta > 0.0 && pdf.is_finite()).then_some((d, pdf))
    }

    /// Solid-angle pdf of `sample` producing unit local direction `d`.
    pub fn pdf(&self, d: Vec3) -> f32 {
        if !self.is_lit() {
            return 0.0;
        }
        let (u, v) = grid::latlong_coordinates(d);
        let sin_theta = (PI * v).sin();
        if sin_theta <= 0.0 {
            return 0.0;
        }
        let col = ((u * self.width as f32) as usize).min(self.width - 1);
        let row = ((v * self.height as f32) as usize).min(self.height - 1);
        let pdf_uv = self.distribution.pdf(Vec2::new(
            (col as f32 + 0.5) / self.width as f32,
            (row as f32 + 0.5) / self.height as f32,
        ));
        let pdf = pdf_uv / (2.0 * PI * PI * sin_theta);
        if pdf.is_finite() {
            pdf
        } else {
            0.0
        }
    }

    pub fn memory_bytes(&self) -> usize {
        self.distribution.memory_bytes() + weights_bytes(&self.weights)
    }
}

fn weights_bytes(w: &Weights) -> usize {
    (w.factor.len()
        + w.values.len()
        + w.gather.as_ref().map_or(0, Vec::len)
        + w.overlap.as_ref().map_or(0, |(o, l)| o.len() + l.len()))
        * 4
}

/// How samples are shared between the six faces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Balancing {
    /// mu_f = 1/6: the thesis's baseline ("uniform balancing").
    Uniform,
    /// mu_f proportional to the face's power I_f: the same density as one global CDF.
    Power,
    /// mu_f(n) = F_f(n) I_f / sum_g F_g(n) I_g with the pseudo form factor
    /// F_f(n) = sum over the face's four corners c of max(0, <n, c>) (001 eq. 3.4).
    Dynamic,
}

/// Per-face tabulated CDFs over a cube grid.
#[derive(Clone, Debug)]
pub struct CubeSampler {
    face: usize,
    weights: Weights,
    faces: Vec<Distribution2D>,
    /// Sum of texel weights of each face, I_f (proportional to its power).
    power: [f32; 6],
}

/// Corners of the cube, normalized, and the four corners of each face.
const INV_SQRT3: f32 = 0.577_350_26;
const CORNERS: [Vec3; 8] = [
    Vec3::new(-INV_SQRT3, -INV_SQRT3, -INV_SQRT3),
    Vec3::new(INV_SQRT3, -INV_SQRT3, -INV_SQRT3),
    Vec3::new(-INV_SQRT3, INV_SQRT3, -INV_SQRT3),
    Vec3::new(INV_SQRT3, INV_SQRT3, -INV_SQRT3),
    Vec3::new(-INV_SQRT3, -INV_SQRT3, INV_SQRT3),
    Vec3::new(INV_SQRT3, -INV_SQRT3, INV_SQRT3),
    Vec3::new(-INV_SQRT3, INV_SQRT3, INV_SQRT3),
    Vec3::new(INV_SQRT3, INV_SQRT3, INV_SQRT3),
];
/// Corner indices (bit 0 = +x, bit 1 = +y, bit 2 = +z) of each face in `FACES` order.
const FACE_CORNERS: [[usize; 4]; 6] = [
    [1, 3, 5, 7], // +X
    [0, 2, 4, 6], // -X
    [2, 3, 6, 7], // +Y
    [0, 1, 4, 5], // -Y
    [4, 5, 6, 7], // +Z
    [0, 1, 2, 3], // -Z
];

impl CubeSampler {
    /// Over the image's own faces when it is a cube map, else over faces of width / 4.
    pub fn new(image: &EnvImage) -> Self {
        Self::build(image, true)
    }

    /// `new`, on the calling thread only unless `parallel`.
    pub fn build(image: &EnvImage, parallel: bool) -> Self {
        let face = match image.grid() {
            Grid::Cube { face } => face,
            Grid::LatLong { width, .. } => (width / 4).max(1),
        };
        let mut weights = Weights::new(Grid::Cube { face }, image, parallel);
        weights.compute(image, parallel);
        let n = face * face;
        let faces: Vec<Distribution2D> = (0..6)
            .map(|f| Distribution2D::new(&weights.values[f * n..(f + 1) * n], face, face))
            .collect();
        let mut sampler = CubeSampler {
            face,
            weights,
            faces,
            power: [0.0; 6],
        };
        sampler.update_power();
        sampler
    }

    /// Re-weights from an image of the same layout: six prefix sums, no allocation but the
    /// marginals' few bytes.
    pub fn rebuild(&mut self, image: &EnvImage) {
        self.weights.compute(image, true);
        let n = self.face * self.face;
        for (f, d) in self.faces.iter_mut().enumerate() {
            d.rebuild(&self.weights.values[f * n..(f + 1) * n]);
        }
        self.update_power();
    }

    fn update_power(&mut self) {
        for f in 0..6 {
            // `integral` is the mean weight; all faces have the same texel count.
            self.power[f] = self.faces[f].integral();
        }
    }

    pub fn face_size(&self) -> usize {
        self.face
    }

    /// I_f of each face (relative units).
    pub fn face_power(&self) -> [f32; 6] {
        self.power
    }

    /// The proportion of samples mu_f for each face; all zero when no lit face can reach a
    /// receiver with normal `n` (then every direction has zero density). `n` is a unit
    /// normal in the local frame, or zero when unknown (then `Dynamic` acts as `Power`).
    pub fn balance(&self, balancing: Balancing, n: Vec3) -> [f32; 6] {
        let mut mu = [0.0f32; 6];
        match balancing {
            Balancing::Uniform => return [1.0 / 6.0; 6],
            Balancing::Power => mu = self.power,
            Balancing::Dynamic if n == Vec3::ZERO => mu = self.power,
            Balancing::Dynamic => {
                let dots = CORNERS.map(|c| n.dot(c).max(0.0));
                for f in 0..6 {
                    let form: f32 = FACE_CORNERS[f].iter().map(|&c| dots[c]).sum();
                    mu[f] = form * self.power[f];
                }
            }
        }
        let total: f32 = mu.iter().sum();
        if total > 0.0 && total.is_finite() {
            for m in &mut mu {
                *m /= total;
            }
            mu
        } else {
            [0.0; 6]
        }
    }

    /// A direction on face `f` with its solid-angle pdf pdf_L(w | f) (eq. 3.3, with the
    /// exact Jacobian (1 + s^2 + t^2)^(3/2) of the face-to-sphere map at the sample).
    pub fn sample_face(&self, f: usize, u: Vec2) -> Option<(Vec3, f32)> {
        let (p, pdf_st) = self.faces[f].sample(u);
        let (s, t) = (2.0 * p.x - 1.0, 2.0 * p.y - 1.0);
        let d = cube_direction(f, s, t);
        let len2 = d.length_squared();
        // Density over [-1, 1]^2 is pdf_st / 4.
        let pdf = 0.25 * pdf_st * len2 * len2.sqrt();
        (pdf > 0.0 && pdf.is_finite()).then(|| (d / len2.sqrt(), pdf))
    }

    /// The face of unit local direction `d` and pdf_L(d | face).
    pub fn face_pdf(&self, d: Vec3) -> (usize, f32) {
        let (f, s, t) = cube_coordinates(d);
        let n = self.face as f32;
        let col = (((s + 1.0) * 0.5 * n) as usize).min(self.face - 1);
        let row = (((t + 1.0) * 0.5 * n) as usize).min(self.face - 1);
        let pdf_st = self.faces[f].pdf(Vec2::new((col as f32 + 0.5) / n, (row as f32 + 0.5) / n));
        let len2 = 1.0 + s * s + t * t;
        (f, 0.25 * pdf_st * len2 * len2.sqrt())
    }

    /// One direction: a face picked with probability mu_f, then a direction on it. The pdf
    /// is mu_f pdf_L(w | f) (eq. 3.2 for a single sample).
    pub fn sample(&self, mu: &[f32; 6], u: Vec2) -> Option<(Vec3, f32)> {
        let mut acc = 0.0f32;
        let last = (0..6).rev().find(|&f| mu[f] > 0.0)?;
        for f in 0..6 {
            if mu[f] <= 0.0 {
                continue;
            }
            if u.x < acc + mu[f] || f == last {
                let ux = ((u.x - acc) / mu[f]).clamp(0.0, 1.0 - f32::EPSILON);
                let (d, pdf) = self.sample_face(f, Vec2::new(ux, u.y))?;
                return Some((d, mu[f] * pdf));
            }
            acc += mu[f];
        }
        None
    }

    /// Solid-angle pdf of `sample` with face proportions `mu` producing unit local `d`.
    pub fn pdf(&self, mu: &[f32; 6], d: Vec3) -> f32 {
        let (f, p) = self.face_pdf(d);
        mu[f] * p
    }

    pub fn memory_bytes(&self) -> usize {
        self.faces
            .iter()
            .map(Distribution2D::memory_bytes)
            .sum::<usize>()
            + weights_bytes(&self.weights)
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::math::{Rgb, Rng};

    /// A map with structure on every face and a bright spot.
    pub(in crate::light::environment) fn test_image(grid: Grid) -> EnvImage {
        let texels = (0..grid.texel_count())
            .map(|i| {
                let d = grid.texel_point(i, 0.5, 0.5);
                let spot = if d.dot(Vec3::new(0.6, 0.64, 0.48)) > 0.995 {
                    500.0
                } else {
                    0.0
                };
                Rgb::new(1.0 + d.x.max(0.0), 0.5 + d.y * d.y, 0.2) + Rgb::splat(spot)
            })
            .collect();
        EnvImage::new(grid, texels).unwrap()
    }

    #[test]
    fn face_balancing_is_conservative_and_normalized() {
        let img = test_image(Grid::Cube { face: 8 });
        let s = CubeSampler::new(&img);
        let mut rng = Rng::new(1, 1);
        for _ in 0..1000 {
            let n = crate::math::warp::uniform_sphere(rng.uniform2());
            let mu = s.balance(Balancing::Dynamic, n);
            assert!((mu.iter().sum::<f32>() - 1.0).abs() < 1e-5);
            // A face with a direction in front of n gets samples.
            for f in 0..6 {
                let ahead = (0..20).any(|_| {
                    let u = rng.uniform2();
                    cube_direction(f, 2.0 * u.x - 1.0, 2.0 * u.y - 1.0).dot(n) > 0.0
                });
                if ahead {
                    assert!(mu[f] > 0.0, "face {f} normal {n}");
                }
            }
        }
    }

    #[test]
    fn samples_carry_their_pdf() {
        for img in [
            test_image(Grid::Cube { face: 8 }),
            test_image(Grid::LatLong {
                width: 32,
                height: 16,
            }),
        ] {
            let cube = CubeSampler::new(&img);
            let ll = LatLongSampler::new(&img);
            let mut rng = Rng::new(2, 2);
            let mu = cube.balance(Balancing::Dynamic, Vec3::new(0.0, 0.8, 0.6));
            let mut mismatches = 0;
            for _ in 0..20_000 {
                let (d, p) = cube.sample(&mu, rng.uniform2()).unwrap();
                assert!((d.length() - 1.0).abs() < 1e-5);
                if (cube.pdf(&mu, d) - p).abs() > 1e-3 * p {
                    mismatches += 1;
                }
                let (d, p) = ll.sample(rng.uniform2()).unwrap();
                if (ll.pdf(d) - p).abs() > 1e-3 * p {
                    mismatches += 1;
                }
            }
            // Only samples on a texel edge may round into the neighbour.
            assert!(mismatches < 20, "{mismatches}");
        }
    }

    #[test]
    fn rebuild_equals_a_fresh_build() {
        let grid = Grid::LatLong {
            width: 32,
            height: 16,
        };
        let a = test_image(grid);
        let mut b = a.clone();
        let texels: Vec<Rgb> = a
            .texels()
            .iter()
            .map(|c| Rgb::new(c.z, c.y, c.x) * 2.0)
            .collect();
        b.replace(&texels).unwrap();
        let mut cube = CubeSampler::new(&a);
        let mut ll = LatLongSampler::new(&a);
        cube.rebuild(&b);
        ll.rebuild(&b);
        let (fresh_cube, fresh_ll) = (CubeSampler::new(&b), LatLongSampler::new(&b));
        let mut rng = Rng::new(3, 3);
        for _ in 0..1000 {
            let d = crate::math::warp::uniform_sphere(rng.uniform2());
            let mu = [1.0 / 6.0; 6];
            assert_eq!(cube.pdf(&mu, d), fresh_cube.pdf(&mu, d));
            assert_eq!(ll.pdf(d), fresh_ll.pdf(d));
        }
    }

    #[test]
    fn densities_are_positive_wherever_the_map_is_lit() {
        // A single lit lat-long texel near the pole, far smaller than a cube texel's gather
        // spacing, and a single lit cube texel for the lat-long density.
        let ll = Grid::LatLong {
            width: 64,
            height: 32,
        };
        let mut t = vec![Rgb::ZERO; ll.texel_count()];
        t[64 + 17] = Rgb::ONE;
        t[ll.texel_count() / 2 + 40] = Rgb::ONE;
        let img = EnvImage::new(ll, t).unwrap();
        let cube = CubeSampler::new(&img);
        let mut rng = Rng::new(4, 4);
        for k in [64 + 17, ll.texel_count() / 2 + 40] {
            for _ in 0..2000 {
                let u = rng.uniform2();
                let d = ll.texel_point(k, u.x, u.y);
                assert!(cube.pdf(&[1.0 / 6.0; 6], d) > 0.0);
            }
        }
        let cg = Grid::Cube { face: 4 };
        let mut t = vec![Rgb::ZERO; cg.texel_count()];
        t[2 * 16 + 5] = Rgb::ONE;
        let img = EnvImage::new(cg, t).unwrap();
        let ll = LatLongSampler::new(&img);
        for _ in 0..2000 {
            let u = rng.uniform2();
            let d = cg.texel_point(2 * 16 + 5, u.x, u.y);
            assert!(ll.pdf(d) > 0.0);
        }
    }
}
