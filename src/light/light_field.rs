//! Light-field luminaires: the near field of a real lamp recorded on two parallel planes
//! (Goesele et al. 2003), sampled toward a shading point with restricted CDFs and per-image
//! balancing (H. Lu, *Importance sampling of realistic light sources*, 2014, chapter 4; thesis
//! 001 in docs/references.md).
//!
//! In the light's frame the *filter plane* F is z = 0 and carries the reconstruction basis
//! Phi_m (tensor B-splines on a regular grid of nodes); the *image plane* I is z = delta and
//! carries one image C_m per basis function. Light travels toward +z. The radiance along the
//! ray through u on F and s on I is (thesis eq. 2.18 and 4.1)
//!
//!   L(u -> s) = |s - u|^4 / delta^2 * sum_m C_m(s) Phi_m(u),
//!
//! so that C_m(s) = <E(. -> s), Phi_m> / (h_x h_y) for the differential irradiance
//! E(u -> s) = L cos^2 / d^2 (eq. 2.19-2.20 with the basis as its own filter, eq. 4.19, and the
//! Gram matrix of eq. 4.20 lumped to its row sums: B-splines are a partition of unity, so the
//! lumped projection keeps the emitted power exactly; see [`LightField::bake`]).
//!
//! The light is seen from receivers beyond the image plane (z > delta); it is not an object
//! rays can hit, so light sampling is the only strategy that finds it (its samples carry
//! `delta: true`, MIS weight 1) while the density stays the exact solid-angle pdf.

use std::path::Path;

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::image_file::{self, ExrMetadata};
use crate::math::{luminance, AliasTable, Rgb, Vec2, Vec3};

/// The reconstruction basis on the filter plane: tensor products of centred cardinal
/// B-splines. The thesis uses quadratic B-splines (section 4.6); the linear one (a tent,
/// bilinear in 2-D) is Heidrich et al.'s canned light source and is cheaper to bake.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FilterBasis {
    Linear,
    Quadratic,
}

impl FilterBasis {
    pub const NAMES: &'static [&'static str] = &["linear", "quadratic"];

    pub fn parse(name: &str) -> Result<Self> {
        match name {
            "linear" => Ok(FilterBasis::Linear),
            "quadratic" => Ok(FilterBasis::Quadratic),
            other => Err(Error::invalid(format!(
                "unknown light-field basis '{other}' (expected linear or quadratic)"
            ))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            FilterBasis::Linear => "linear",
            FilterBasis::Quadratic => "quadratic",
        }
    }

    /// Half-width of the support, in node spacings.
    pub fn radius(self) -> f32 {
        match self {
            FilterBasis::Linear => 1.0,
            FilterBasis::Quadratic => 1.5,
        }
    }

    /// The 1-D basis at `t` node spacings from its node (integral 1).
    #[inline]
    pub fn eval(self, t: f32) -> f32 {
        let a = t.abs();
        match self {
            FilterBasis::Linear => (1.0 - a).max(0.0),
            FilterBasis::Quadratic => {
                if a < 0.5 {
                    0.75 - a * a
                } else if a < 1.5 {
                    0.5 * (1.5 - a) * (1.5 - a)
                } else {
                    0.0
                }
            }
        }
    }

    /// Integral of the 1-D basis from -radius to `t` (what [`sample`](Self::sample) inverts).
    #[cfg(test)]
    fn cdf(self, t: f32) -> f32 {
        let r = self.radius();
        let t = t.clamp(-r, r);
        match self {
            FilterBasis::Linear => {
                if t <= 0.0 {
                    0.5 * (1.0 + t) * (1.0 + t)
                } else {
                    1.0 - 0.5 * (1.0 - t) * (1.0 - t)
                }
            }
            FilterBasis::Quadratic => {
                if t <= -0.5 {
                    (t + 1.5).powi(3) / 6.0
                } else if t <= 0.5 {
                    // 1/6 at -0.5, plus the integral of 0.75 - x^2 from -0.5.
                    1.0 / 6.0 + 0.75 * (t + 0.5) - (t.powi(3) + 0.125) / 3.0
                } else {
                    1.0 - (1.5 - t).powi(3) / 6.0
                }
            }
        }
    }

    /// Inverts the basis's cdf: `t` with density `eval(t)` from `u` in [0, 1).
    pub fn sample(self, u: f32) -> f32 {
        match self {
            FilterBasis::Linear => {
                if u < 0.5 {
                    (2.0 * u).sqrt() - 1.0
                } else {
                    1.0 - (2.0 * (1.0 - u)).sqrt()
                }
            }
            FilterBasis::Quadratic => {
                // The cdf's three cubic pieces inverted in closed form. Outer pieces:
                // (t + 1.5)^3 / 6 = u, and its mirror. Middle piece (|t| <= 0.5):
                // u = 1/2 + 3t/4 - t^3/3, i.e. t^3 - 9t/4 + 3(u - 1/2) = 0, a depressed cubic
                // with three real roots; the trigonometric form's middle root (k = 1) is the
                // one in [-0.5, 0.5].
                let u = u.clamp(0.0, 1.0);
                if u <= 1.0 / 6.0 {
                    (6.0 * u).cbrt() - 1.5
                } else if u >= 5.0 / 6.0 {
                    1.5 - (6.0 * (1.0 - u)).cbrt()
                } else {
                    // With p = -9/4 and q = 3(u - 1/2): t = 2 sqrt(-p/3) cos(acos(c) / 3 - 2 pi / 3),
                    // 2 sqrt(-p/3) = sqrt(3) and c = 3q/(2p) sqrt(-3/p) = (1 - 2u) 2 / sqrt(3).
                    let c = ((1.0 - 2.0 * u) * 2.0 / 3f32.sqrt()).clamp(-1.0, 1.0);
                    let t = 3f32.sqrt() * ((c.acos() - 2.0 * std::f32::consts::PI) / 3.0).cos();
                    t.clamp(-0.5, 0.5)
                }
            }
        }
    }
}

/// Where the two planes and the images are, in the light's frame (metres).
#[derive(Clone, Debug, PartialEq)]
pub struct LightFieldLayout {
    /// Basis functions (and images) along x and y of the filter plane.
    pub nodes: [u32; 2],
    /// The node of the first basis function, and the spacing h of the grid.
    pub node_min: Vec2,
    pub node_spacing: Vec2,
    pub basis: FilterBasis,
    /// delta: the distance from the filter plane to the image plane.
    pub plane_distance: f32,
    /// The rectangle on the image plane every image covers.
    pub image_min: Vec2,
    pub image_max: Vec2,
    /// Pixels of each image along x and y.
    pub resolution: [u32; 2],
}

/// Largest number of basis functions along one axis.
pub const MAX_NODES: u32 = 1024;

impl LightFieldLayout {
    pub fn validate(&self) -> Result<()> {
        let [nx, ny] = self.nodes;
        let [rx, ry] = self.resolution;
        if !(1..=MAX_NODES).contains(&nx) || !(1..=MAX_NODES).contains(&ny) {
            return Err(Error::invalid(format!(
                "light-field nodes {nx}x{ny} must be 1 to {MAX_NODES} per axis"
            )));
        }
        if rx == 0 || ry == 0 {
            return Err(Error::invalid(format!(
                "light-field image resolution {rx}x{ry} must be at least 1x1"
            )));
        }
        let pixels = nx as u64 * ny as u64 * rx as u64 * ry as u64;
        if pixels > crate::limits::MAX_ENV_TEXELS as u64 {
            return Err(Error::invalid(format!(
                "a light field of {pixels} pixels is over the limit of {}",
                crate::limits::MAX_ENV_TEXELS
            )));
        }
        let finite2 = |v: Vec2| v.x.is_finite() && v.y.is_finite();
        if !finite2(self.node_min) || !finite2(self.image_min) || !finite2(self.image_max) {
            return Err(Error::invalid("light-field corners must be finite"));
        }
        if !(self.node_spacing.x > 0.0 && self.node_spacing.y > 0.0 && finite2(self.node_spacing)) {
            return Err(Error::invalid(format!(
                "light-field node spacing {} must be finite and > 0",
                self.node_spacing
            )));
        }
        if !(self.plane_distance > 0.0 && self.plane_distance.is_finite()) {
            return Err(Error::invalid(format!(
                "light-field plane distance {} must be finite and > 0",
                self.plane_distance
            )));
        }
        if !(self.image_max.x > self.image_min.x && self.image_max.y > self.image_min.y) {
            return Err(Error::invalid(format!(
                "light-field image rectangle {} to {} is empty",
                self.image_min, self.image_max
            )));
        }
        Ok(())
    }

    pub fn image_count(&self) -> usize {
        self.nodes[0] as usize * self.nodes[1] as usize
    }

    pub fn pixels_per_image(&self) -> usize {
        self.resolution[0] as usize * self.resolution[1] as usize
    }

    fn pixel_size(&self) -> Vec2 {
        (self.image_max - self.image_min)
            / Vec2::new(self.resolution[0] as f32, self.resolution[1] as f32)
    }

    /// The node of basis function (`i`, `j`).
    fn node(&self, i: usize, j: usize) -> Vec2 {
        self.node_min + self.node_spacing * Vec2::new(i as f32, j as f32)
    }

    /// The point of the image plane at the centre of pixel (`x`, `y`).
    pub fn pixel_centre(&self, x: u32, y: u32) -> Vec2 {
        self.image_min + self.pixel_size() * Vec2::new(x as f32 + 0.5, y as f32 + 0.5)
    }

    /// The filter-plane point at the centre of basis function (`i`, `j`).
    pub fn node_point(&self, i: u32, j: u32) -> Vec2 {
        self.node(i as usize, j as usize)
    }
}

/// How [`LightField::sample_image_point`] picks a point of the image plane.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LightFieldSampling {
    /// An image from the table of the receiver's cell ([`ImageChoiceGrid`]), then a point
    /// proportional to C_m within the image's restricted box (thesis eq. 4.12, 4.14).
    #[default]
    Restricted,
    /// An image with probability A_m(p) / A(p) (per-image balancing, eq. 4.16, at every
    /// receiver), then a point as `Restricted` picks it.
    Balanced,
    /// Every image whose restricted box is not empty with the same probability, then a point
    /// uniformly in that box: the thesis's baseline of Figure 4.14.
    Uniform,
}

/// A light field ready for sampling: the images, their luminance and a summed-area table of
/// the luminance per image.
#[derive(Clone, Debug)]
pub struct LightField {
    layout: LightFieldLayout,
    /// Image m = j * nodes[0] + i, each row-major with y rows.
    colour: Vec<Rgb>,
    weight: Vec<f32>,
    /// Per image, (resolution[0] + 1) x (resolution[1] + 1) sums of `weight` over
    /// [0, x) x [0, y) pixels, row-major with y rows (f64: a sum over a megapixel image keeps
    /// the precision of its small differences).
    sat: Vec<f64>,
    /// Emission: an image with probability proportional to its luminance sum.
    image_choice: AliasTable,
    /// Sum of `weight` over every pixel of every image.
    weight_sum: f64,
    /// Restricted sampling's image choice per receiver cell.
    choice_grid: ImageChoiceGrid,
}

/// Rectangle [x0, x1] x [y0, y1] in pixel coordinates of one image.
#[derive(Clone, Copy, Debug)]
struct PixelBox {
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
}

impl PixelBox {
    fn contains(&self, x: f64, y: f64) -> bool {
        (self.x0..=self.x1).contains(&x) && (self.y0..=self.y1).contains(&y)
    }

    fn area(&self) -> f64 {
        (self.x1 - self.x0) * (self.y1 - self.y0)
    }
}

/// A continuous pixel coordinate split for the summed-area table's bilinear interpolation:
/// the knot below it (clamped to the table's last pixel) and the fraction past that knot.
#[derive(Clone, Copy, Debug)]
struct Knot {
    i: usize,
    f: f64,
}

impl Knot {
    /// `x` on an axis of `n` pixels.
    #[inline]
    fn new(x: f64, n: usize) -> Self {
        let i = (x.max(0.0) as usize).min(n - 1);
        Knot { i, f: x - i as f64 }
    }
}

impl LightField {
    /// A light field from its layout and its images' pixels: image m = j * nodes[0] + i
    /// (basis function (i, j)), each `resolution[0]` x `resolution[1]` row-major with row y at
    /// the image plane's y. Every value must be finite and >= 0, and one positive.
    pub fn new(layout: LightFieldLayout, pixels: Vec<Rgb>) -> Result<Self> {
        layout.validate()?;
        let expected = layout.image_count() * layout.pixels_per_image();
        if pixels.len() != expected {
            return Err(Error::invalid(format!(
                "a {}x{} light field of {}x{} images needs {expected} pixels, got {}",
                layout.nodes[0],
                layout.nodes[1],
                layout.resolution[0],
                layout.resolution[1],
                pixels.len()
            )));
        }
        if let Some(i) = pixels
            .iter()
            .position(|c| !(c.is_finite() && c.min_element() >= 0.0))
        {
            return Err(Error::invalid(format!(
                "light-field pixel {i} is {} (must be finite and >= 0)",
                pixels[i]
            )));
        }
        let weight: Vec<f32> = pixels.iter().map(|&c| luminance(c)).collect();
        let (rx, ry) = (layout.resolution[0] as usize, layout.resolution[1] as usize);
        let per_image = (rx + 1) * (ry + 1);
        let mut sat = vec![0f64; layout.image_count() * per_image];
        let mut sums = Vec::with_capacity(layout.image_count());
        for m in 0..layout.image_count() {
            let w = &weight[m * rx * ry..(m + 1) * rx * ry];
            let t = &mut sat[m * per_image..(m + 1) * per_image];
            for y in 0..ry {
                let mut row = 0f64;
                for x in 0..rx {
                    row += w[y * rx + x] as f64;
                    t[(y + 1) * (rx + 1) + x + 1] = t[y * (rx + 1) + x + 1] + row;
                }
            }
            sums.push(t[per_image - 1]);
        }
        let weight_sum: f64 = sums.iter().sum();
        let image_choice = AliasTable::new(&sums.iter().map(|&s| s as f32).collect::<Vec<_>>())
            .filter(|_| weight_sum > 0.0)
            .ok_or_else(|| Error::invalid("every light-field pixel is zero"))?;
        let mut field = LightField {
            layout,
            colour: pixels,
            weight,
            sat,
            image_choice,
            weight_sum,
            choice_grid: ImageChoiceGrid::default(),
        };
        field.choice_grid = ImageChoiceGrid::build(&field);
        Ok(field)
    }

    /// Bakes a light field from the radiance `radiance(u, s)` of the ray from filter-plane
    /// point u to image-plane point s: C_m(s) = <E(. -> s), Phi_m> / (h_x h_y) with
    /// E = L delta^2 / d^4 (eq. 4.19, Gram matrix lumped), at each pixel centre, the inner
    /// product by the midpoint rule with `per_spacing` points per node spacing and axis.
    pub fn bake(
        layout: LightFieldLayout,
        per_spacing: u32,
        radiance: impl Fn(Vec2, Vec2) -> Rgb,
    ) -> Result<Self> {
        layout.validate()?;
        let per_spacing = per_spacing.max(1) as usize;
        let basis = layout.basis;
        let r = basis.radius();
        let steps = (2.0 * r * per_spacing as f32).round() as usize;
        // Offsets (in node spacings) of the quadrature points and their basis weights.
        let taps: Vec<(f32, f32)> = (0..steps)
            .map(|k| {
                let t = -r + (k as f32 + 0.5) / per_spacing as f32;
                (t, basis.eval(t) / per_spacing as f32)
            })
            .collect();
        let delta = layout.plane_distance;
        let h = layout.node_spacing;
        let (rx, ry) = (layout.resolution[0], layout.resolution[1]);
        let mut pixels = Vec::with_capacity(layout.image_count() * layout.pixels_per_image());
        for j in 0..layout.nodes[1] as usize {
            for i in 0..layout.nodes[0] as usize {
                let node = layout.node(i, j);
                for y in 0..ry {
                    for x in 0..rx {
                        let s = layout.pixel_centre(x, y);
                        let mut c = Rgb::ZERO;
                        for &(ty, wy) in &taps {
                            for &(tx, wx) in &taps {
                                let u = node + h * Vec2::new(tx, ty);
                                let d2 = (s - u).length_squared() + delta * delta;
                                c += radiance(u, s) * (wx * wy * delta * delta / (d2 * d2));
                            }
                        }
                        pixels.push(c);
                    }
                }
            }
        }
        Self::new(layout, pixels)
    }

    pub fn layout(&self) -> &LightFieldLayout {
        &self.layout
    }

    pub fn pixels(&self) -> &[Rgb] {
        &self.colour
    }

    pub fn memory_bytes(&self) -> usize {
        self.colour.len() * 12
            + self.weight.len() * 4
            + self.sat.len() * 8
            + self.choice_grid.cumulative.len() * 8
    }

    /// Emitted power (luminance): the integral of E over both planes,
    /// h_x h_y sum_m integral C_m (each B-spline integrates to h_x h_y).
    pub fn power(&self) -> f32 {
        let h = self.layout.node_spacing;
        let pixel = self.layout.pixel_size();
        (self.weight_sum * (h.x * h.y * pixel.x * pixel.y) as f64) as f32
    }

    /// Radiance along the ray from `u` on the filter plane to `s` on the image plane
    /// (eq. 4.1).
    pub fn radiance(&self, u: Vec2, s: Vec2) -> Rgb {
        let Some(pixel) = self.pixel_index(s) else {
            return Rgb::ZERO;
        };
        let l = &self.layout;
        let mut sum = Rgb::ZERO;
        self.for_each_basis(u, |m, phi| {
            sum += self.colour[m * l.pixels_per_image() + pixel] * phi;
        });
        let d2 = (s - u).length_squared() + l.plane_distance * l.plane_distance;
        sum * (d2 * d2 / (l.plane_distance * l.plane_distance))
    }

    /// Calls `f(m, Phi_m(u))` for every basis function not zero at `u`.
    fn for_each_basis(&self, u: Vec2, mut f: impl FnMut(usize, f32)) {
        let l = &self.layout;
        let r = l.basis.radius();
        let t = (u - l.node_min) / l.node_spacing;
        let range = |t: f32, n: u32| {
            let lo = (t - r).ceil().max(0.0);
            let hi = (t + r).floor().min(n as f32 - 1.0);
            (lo as i64, hi as i64)
        };
        let (i0, i1) = range(t.x, l.nodes[0]);
        let (j0, j1) = range(t.y, l.nodes[1]);
        for j in j0..=j1 {
            let py = l.basis.eval(t.y - j as f32);
            if py <= 0.0 {
                continue;
            }
            for i in i0..=i1 {
                let px = l.basis.eval(t.x - i as f32);
                if px > 0.0 {
                    f(j as usize * l.nodes[0] as usize + i as usize, px * py);
                }
            }
        }
    }

    /// Index of the pixel holding image-plane point `s` (the same in every image).
    fn pixel_index(&self, s: Vec2) -> Option<usize> {
        let (x, y) = self.to_pixels(s);
        let (rx, ry) = (self.layout.resolution[0], self.layout.resolution[1]);
        if !(0.0..=rx as f64).contains(&x) || !(0.0..=ry as f64).contains(&y) {
            return None;
        }
        let xi = (x as usize).min(rx as usize - 1);
        let yi = (y as usize).min(ry as usize - 1);
        Some(yi * rx as usize + xi)
    }

    fn to_pixels(&self, s: Vec2) -> (f64, f64) {
        let l = &self.layout;
        let p = l.pixel_size();
        (
            (s.x - l.image_min.x) as f64 / p.x as f64,
            (s.y - l.image_min.y) as f64 / p.y as f64,
        )
    }

    fn pixels_to_plane(&self, x: f64, y: f64) -> Vec2 {
        let l = &self.layout;
        let p = l.pixel_size();
        Vec2::new(
            (l.image_min.x as f64 + x * p.x as f64) as f32,
            (l.image_min.y as f64 + y * p.y as f64) as f32,
        )
    }

    /// The point of the filter plane on the line from receiver `p` (local, z > delta) through
    /// image-plane point `s`.
    pub fn filter_point(&self, p: Vec3, s: Vec2) -> Vec2 {
        let delta = self.layout.plane_distance;
        let k = p.z / (p.z - delta);
        let pxy = Vec2::new(p.x, p.y);
        pxy + (s - pxy) * k
    }

    /// The box of image `m` whose points s see the support of Phi_m from `p` (eq. 4.11),
    /// clipped to the image; `None` when empty.
    ///
    /// Eq. 4.11 as extracted reads s = delta / (delta + Delta) (p - u), which drops a term:
    /// with F at z = 0, I at z = delta and p at z = delta + Delta, the line from u to p meets I
    /// at s = u + (p - u) delta / (delta + Delta). The map is increasing in u, so the support's
    /// corners give the box's corners.
    fn restricted_box(&self, p: Vec3, m: usize) -> Option<PixelBox> {
        let l = &self.layout;
        let (i, j) = (m % l.nodes[0] as usize, m / l.nodes[0] as usize);
        let k = l.plane_distance / p.z;
        let (x0, x1) = self.box_side(0, i, p.x, k)?;
        let (y0, y1) = self.box_side(1, j, p.y, k)?;
        Some(PixelBox { x0, x1, y0, y1 })
    }

    /// One side of a restricted box ([`restricted_box`](Self::restricted_box)): along `axis`
    /// (0: x, 1: y), the interval in pixels, clipped to the image, of the basis functions of
    /// node index `n` on that axis, seen from the receiver's coordinate `p` on it with
    /// k = delta / p_z; `None` when empty. A box is the product of its two sides, so the
    /// images of one node column share their x side and those of one row their y side.
    /// The same operations as [`pixel_box`](Self::pixel_box) of the box's corners, one axis.
    #[inline]
    fn box_side(&self, axis: usize, n: usize, p: f32, k: f32) -> Option<(f64, f64)> {
        let l = &self.layout;
        let node = l.node_min[axis] + l.node_spacing[axis] * n as f32;
        let half = l.node_spacing[axis] * l.basis.radius();
        let (lo, hi) = (node - half, node + half);
        let (s_lo, s_hi) = (lo + (p - lo) * k, hi + (p - hi) * k);
        let pixel = l.pixel_size()[axis] as f64;
        let resolution = l.resolution[axis] as f64;
        let to_pixels = |s: f32| ((s - l.image_min[axis]) as f64 / pixel).clamp(0.0, resolution);
        let (a, b) = (to_pixels(s_lo), to_pixels(s_hi));
        (b > a).then_some((a, b))
    }

    /// The image-plane rectangle [`s_lo`, `s_hi`] in pixels, clipped to the image; None where
    /// nothing of it is left.
    fn pixel_box(&self, s_lo: Vec2, s_hi: Vec2) -> Option<PixelBox> {
        let (x0, y0) = self.to_pixels(s_lo);
        let (x1, y1) = self.to_pixels(s_hi);
        let l = &self.layout;
        let (rx, ry) = (l.resolution[0] as f64, l.resolution[1] as f64);
        let b = PixelBox {
            x0: x0.clamp(0.0, rx),
            x1: x1.clamp(0.0, rx),
            y0: y0.clamp(0.0, ry),
            y1: y1.clamp(0.0, ry),
        };
        (b.x1 > b.x0 && b.y1 > b.y0).then_some(b)
    }

    /// Image `m`'s summed-area table.
    #[inline]
    fn sat_image(&self, m: usize) -> &[f64] {
        let per_image =
            (self.layout.resolution[0] as usize + 1) * (self.layout.resolution[1] as usize + 1);
        &self.sat[m * per_image..(m + 1) * per_image]
    }

    /// The summed-area table `t` of an image at the continuous pixel point split into knots
    /// (`x`, `y`): the integral of the luminance over [0, x) x [0, y). Exact by bilinear
    /// interpolation, as the integral of a piecewise-constant function is bilinear within each
    /// pixel. Points sharing a coordinate split it once.
    #[inline(always)]
    fn sat_knots(&self, t: &[f64], x: Knot, y: Knot) -> f64 {
        let width = self.layout.resolution[0] as usize + 1;
        // Both rows in one slice: one bounds check.
        let r = &t[y.i * width + x.i..][..width + 2];
        let bottom = r[0] * (1.0 - x.f) + r[1] * x.f;
        let top = r[width] * (1.0 - x.f) + r[width + 1] * x.f;
        bottom * (1.0 - y.f) + top * y.f
    }

    /// Image `m`'s restricted box for the receiver of grid coordinates (`a`, `t`)
    /// ([`ImageChoiceGrid`]): [lo t + a, hi t + a], in pixels, clipped to the image.
    fn a_t_box(&self, m: usize, a_lo: Vec2, a_hi: Vec2, t_lo: f32, t_hi: f32) -> Option<PixelBox> {
        let l = &self.layout;
        let (i, j) = (m % l.nodes[0] as usize, m / l.nodes[0] as usize);
        let half = l.node_spacing * l.basis.radius();
        let (lo, hi) = (l.node(i, j) - half, l.node(i, j) + half);
        let s_lo = (lo * t_lo).min(lo * t_hi) + a_lo;
        let s_hi = (hi * t_lo).max(hi * t_hi) + a_hi;
        self.pixel_box(s_lo, s_hi)
    }

    /// A_m at the receiver of grid coordinates (`a`, `t`).
    fn a_t_box_integral(&self, m: usize, a: Vec2, t: f32) -> f64 {
        self.a_t_box(m, a, a, t, t)
            .map_or(0.0, |b| self.box_integral(m, &b))
    }

    /// U_m: the luminance of image `m` over the union of its restricted boxes for every
    /// receiver of the grid cell from `lo` to `hi` in (a_x, a_y, t), padded by a pixel each
    /// side so that rounding cannot put a receiver's box outside it.
    fn union_box_integral(&self, m: usize, lo: Vec3, hi: Vec3) -> f64 {
        let pixel = self.layout.pixel_size();
        let a_lo = Vec2::new(lo.x, lo.y) - pixel;
        let a_hi = Vec2::new(hi.x, hi.y) + pixel;
        self.a_t_box(m, a_lo, a_hi, lo.z, hi.z)
            .map_or(0.0, |b| self.box_integral(m, &b))
    }

    /// A_m(p) in pixel units: the luminance of image `m` integrated over box `b` (eq. 4.14).
    fn box_integral(&self, m: usize, b: &PixelBox) -> f64 {
        let (rx, ry) = (
            self.layout.resolution[0] as usize,
            self.layout.resolution[1] as usize,
        );
        let (x0, x1) = (Knot::new(b.x0, rx), Knot::new(b.x1, rx));
        let (y0, y1) = (Knot::new(b.y0, ry), Knot::new(b.y1, ry));
        self.box_integral_knots(self.sat_image(m), x0, x1, y0, y1)
    }

    /// [`box_integral`](Self::box_integral) in table `t` over the box of corners split into
    /// knots.
    #[inline(always)]
    fn box_integral_knots(&self, t: &[f64], x0: Knot, x1: Knot, y0: Knot, y1: Knot) -> f64 {
        self.sat_knots(t, x1, y1) - self.sat_knots(t, x0, y1) - self.sat_knots(t, x1, y0)
            + self.sat_knots(t, x0, y0)
    }

    /// The weight of each image for `strategy` from `p`: A_m(p) (restricted) or the box's
    /// presence (uniform), with its box.
    fn image_weight(
        &self,
        p: Vec3,
        m: usize,
        strategy: LightFieldSampling,
    ) -> Option<(f64, PixelBox)> {
        let b = self.restricted_box(p, m)?;
        let w = match strategy {
            LightFieldSampling::Balanced | LightFieldSampling::Restricted => {
                self.box_integral(m, &b)
            }
            LightFieldSampling::Uniform => 1.0,
        };
        (w > 0.0).then_some((w, b))
    }

    /// Every image's weight from `p` for `strategy`, with its box (images with none left
    /// out): the one pass over the images a sample and its pdf share.
    fn image_weights(&self, p: Vec3, strategy: LightFieldSampling) -> Vec<(usize, f64, PixelBox)> {
        if !(p.z > self.layout.plane_distance) || !p.is_finite() {
            return Vec::new();
        }
        (0..self.layout.image_count())
            .filter_map(|m| self.image_weight(p, m, strategy).map(|(w, b)| (m, w, b)))
            .collect()
    }

    /// Samples a point of the image plane as seen from receiver `p` (light-local, beyond the
    /// image plane: z > delta) with `strategy`; returns it with its density in area measure
    /// on the image plane (the one [`image_point_pdf`](Self::image_point_pdf) gives).
    ///
    /// Per-image balancing (eq. 4.16) gives image m K_m = round(K A_m / A) of K samples; with
    /// one sample at a time (a path tracer's next-event estimate) its unbiased form is picking
    /// m with probability A_m / A. (Rounding K_m to an integer, as eq. 4.16 does, would drop
    /// images with K A_m / A < 1/2 and bias the estimate.)
    pub fn sample_image_point(
        &self,
        p: Vec3,
        strategy: LightFieldSampling,
        u: Vec2,
    ) -> Option<(Vec2, f32)> {
        if strategy == LightFieldSampling::Restricted {
            return self.sample_restricted(p, u);
        }
        let weights = self.image_weights(p, strategy);
        let total: f64 = weights.iter().map(|&(_, w, _)| w).sum();
        if !(total > 0.0) {
            return None;
        }
        // The image whose share of [0, total) holds u.x, and u.x stretched within it.
        let target = u.x as f64 * total;
        let mut acc = 0.0;
        let mut chosen = None;
        for &(m, w, b) in &weights {
            chosen = Some((m, b, ((target - acc) / w).clamp(0.0, 1.0)));
            if target < acc + w {
                break;
            }
            acc += w;
        }
        let (m, b, ux) = chosen?;
        let (x, y) = match strategy {
            LightFieldSampling::Balanced | LightFieldSampling::Restricted => {
                self.sample_in_box(m, &b, ux, u.y as f64)?
            }
            LightFieldSampling::Uniform => {
                (b.x0 + ux * (b.x1 - b.x0), b.y0 + u.y as f64 * (b.y1 - b.y0))
            }
        };
        let s = self.pixels_to_plane(x, y);
        let pdf = self.pdf_from_weights(&weights, strategy, s);
        (pdf > 0.0 && pdf.is_finite()).then_some((s, pdf))
    }

    /// Area density on the image plane with which [`sample_image_point`](Self::sample_image_point)
    /// picks `s` from `p`: sum over the images whose box holds s of C_m(s) / A(p) (restricted;
    /// the mixture of eq. 4.14 over the choice of eq. 4.16), or of 1 / (n |box_m|) (uniform).
    pub fn image_point_pdf(&self, p: Vec3, strategy: LightFieldSampling, s: Vec2) -> f32 {
        if strategy == LightFieldSampling::Restricted {
            return self.restricted_pdf(p, s);
        }
        self.pdf_from_weights(&self.image_weights(p, strategy), strategy, s)
    }

    /// [`image_point_pdf`](Self::image_point_pdf) from the images' weights.
    fn pdf_from_weights(
        &self,
        weights: &[(usize, f64, PixelBox)],
        strategy: LightFieldSampling,
        s: Vec2,
    ) -> f32 {
        let Some(pixel) = self.pixel_index(s) else {
            return 0.0;
        };
        let (x, y) = self.to_pixels(s);
        let (mut total, mut density) = (0.0f64, 0.0f64);
        for &(m, w, b) in weights {
            total += w;
            if b.contains(x, y) {
                density += match strategy {
                    LightFieldSampling::Balanced | LightFieldSampling::Restricted => {
                        self.weight[m * self.layout.pixels_per_image() + pixel] as f64
                    }
                    LightFieldSampling::Uniform => 1.0 / b.area(),
                };
            }
        }
        let pixel_area = {
            let ps = self.layout.pixel_size();
            ps.x as f64 * ps.y as f64
        };
        let pdf = match strategy {
            LightFieldSampling::Balanced | LightFieldSampling::Restricted if total > 0.0 => {
                density / total
            }
            LightFieldSampling::Uniform if !weights.is_empty() => density / weights.len() as f64,
            _ => 0.0,
        };
        (pdf / pixel_area) as f32
    }

    /// Restricted sampling with the image chosen from the table of `p`'s cell
    /// ([`ImageChoiceGrid`]): O(log n) in the number of images instead of weighing every
    /// image's box at every receiver. The density is that of
    /// [`restricted_pdf`](Self::restricted_pdf).
    fn sample_restricted(&self, p: Vec3, u: Vec2) -> Option<(Vec2, f32)> {
        let cell = self.choice_grid.cell_of(&self.layout, p)?;
        let (m, ux) = self.choice_grid.choose(cell, u.x as f64)?;
        let b = self.restricted_box(p, m)?;
        let (x, y) = self.sample_in_box(m, &b, ux, u.y as f64)?;
        let s = self.pixels_to_plane(x, y);
        let pdf = self.restricted_pdf(p, s);
        (pdf > 0.0 && pdf.is_finite()).then_some((s, pdf))
    }

    /// Area density on the image plane with which [`sample_restricted`](Self::sample_restricted)
    /// picks `s` from `p`: sum over the images m whose restricted box holds s of
    /// q_c(m) C_m(s) / A_m(p), q_c the image probabilities of `p`'s cell. Only the basis
    /// functions whose support holds the filter-plane point of the line from p through s
    /// have s in their box (at most 3 x 3 for the quadratic basis), so this is O(1).
    fn restricted_pdf(&self, p: Vec3, s: Vec2) -> f32 {
        let l = &self.layout;
        let Some(cell) = self.choice_grid.cell_of(l, p) else {
            return 0.0;
        };
        let Some(pixel) = self.pixel_index(s) else {
            return 0.0;
        };
        let (x, y) = self.to_pixels(s);
        // Candidates one node wider than the support each side: the exact test is the box's.
        let t = (self.filter_point(p, s) - l.node_min) / l.node_spacing;
        let reach = l.basis.radius() + 1.0;
        let range = |t: f32, n: u32| {
            let lo = (t - reach).ceil().max(0.0) as i64;
            let hi = (t + reach).floor().min(n as f32 - 1.0) as i64;
            (lo, hi)
        };
        let (i0, i1) = range(t.x, l.nodes[0]);
        let (j0, j1) = range(t.y, l.nodes[1]);
        let (rx, ry) = (l.resolution[0] as usize, l.resolution[1] as usize);
        // The x sides of the candidates' boxes that hold x, split into knots once for every
        // row of images (a finite t spans at most 2 reach + 1 <= 6 nodes; a wider range, only
        // from a non-finite t, computes the rest on the fly).
        let k = l.plane_distance / p.z;
        let x_side = |i: i64| {
            self.box_side(0, i as usize, p.x, k)
                .filter(|&(x0, x1)| (x0..=x1).contains(&x))
                .map(|(x0, x1)| (Knot::new(x0, rx), Knot::new(x1, rx)))
        };
        const CACHED: usize = 8;
        let mut x_sides = [None; CACHED];
        for (i, side) in (i0..=i1).zip(x_sides.iter_mut()) {
            *side = x_side(i);
        }
        let mut density = 0f64;
        for j in j0..=j1 {
            let Some((y0, y1)) = self
                .box_side(1, j as usize, p.y, k)
                .filter(|&(y0, y1)| (y0..=y1).contains(&y))
            else {
                continue;
            };
            let (y0, y1) = (Knot::new(y0, ry), Knot::new(y1, ry));
            for i in i0..=i1 {
                let n = (i - i0) as usize;
                let Some((x0, x1)) = (if n < CACHED { x_sides[n] } else { x_side(i) }) else {
                    continue;
                };
                let m = j as usize * l.nodes[0] as usize + i as usize;
                let q = self.choice_grid.probability(cell, m);
                if q <= 0.0 {
                    continue;
                }
                let a = self.box_integral_knots(self.sat_image(m), x0, x1, y0, y1);
                if a > 0.0 {
                    density += q * self.weight[m * l.pixels_per_image() + pixel] as f64 / a;
                }
            }
        }
        let ps = l.pixel_size();
        (density / (ps.x as f64 * ps.y as f64)) as f32
    }

    /// Samples (x, y) in pixel units proportionally to image `m`'s luminance within `b`
    /// (eq. 4.12 re-derived): the marginal in x must be the luminance integrated over
    /// [y0, y1] only, not over the whole column as eq. 4.10's cdf_m(s) is, or the density
    /// would not be C_m / A_m as eq. 4.14 states. Both 1-D inversions read the summed-area
    /// table: G(x) = S(x, y1) - S(x, y0) is the restricted marginal's CDF (up to G(x0)), linear
    /// within a pixel column; given the column, S(c + 1, y) - S(c, y) is the conditional's.
    ///
    /// At the knots (integer x or y) the table is read without interpolation along that axis:
    /// the same values as interpolating with a zero (or, at the far edge, unit) fraction.
    fn sample_in_box(&self, m: usize, b: &PixelBox, ux: f64, uy: f64) -> Option<(f64, f64)> {
        let (rx, ry) = (
            self.layout.resolution[0] as usize,
            self.layout.resolution[1] as usize,
        );
        let width = rx + 1;
        let t = self.sat_image(m);
        let (y0, y1) = (Knot::new(b.y0, ry), Knot::new(b.y1, ry));
        let g = |x: f64| {
            let x = Knot::new(x, rx);
            self.sat_knots(t, x, y1) - self.sat_knots(t, x, y0)
        };
        let column_at = |x: usize, y: Knot| {
            let r = y.i * width + x;
            t[r] * (1.0 - y.f) + t[r + width] * y.f
        };
        let g_knot = |x: i64| column_at(x as usize, y1) - column_at(x as usize, y0);
        let x = invert_piecewise_linear(g, g_knot, b.x0, b.x1, ux)?;
        let column = (x.floor().max(0.0) as usize).min(rx - 1);
        let (c0, c1) = (
            Knot::new(column as f64, rx),
            Knot::new(column as f64 + 1.0, rx),
        );
        let h = |y: f64| {
            let y = Knot::new(y, ry);
            self.sat_knots(t, c1, y) - self.sat_knots(t, c0, y)
        };
        let h_knot = |y: i64| {
            let r = y as usize * width + column;
            t[r + 1] - t[r]
        };
        let y = invert_piecewise_linear(h, h_knot, b.y0, b.y1, uy)?;
        Some((x, y))
    }

    /// Samples a ray leaving the light: an image with probability proportional to its
    /// luminance sum, s on the image plane proportional to it (`u_pos`), u on the filter plane
    /// proportional to the image's basis function (`u_dir`). Returns (s, u, density in area on
    /// the image plane times solid angle at s).
    pub fn sample_emission(&self, u_pos: Vec2, u_dir: Vec2) -> Option<(Vec2, Vec2, f32)> {
        let l = &self.layout;
        let (m, ux) = self.image_choice.sample_reuse(u_pos.x);
        let whole = PixelBox {
            x0: 0.0,
            x1: l.resolution[0] as f64,
            y0: 0.0,
            y1: l.resolution[1] as f64,
        };
        let (x, y) = self.sample_in_box(m, &whole, ux as f64, u_pos.y as f64)?;
        let s = self.pixels_to_plane(x, y);
        let (i, j) = (m % l.nodes[0] as usize, m / l.nodes[0] as usize);
        let t = Vec2::new(l.basis.sample(u_dir.x), l.basis.sample(u_dir.y));
        let u = l.node(i, j) + l.node_spacing * t;
        let pdf = self.emission_pdf(s, u);
        (pdf > 0.0 && pdf.is_finite()).then_some((s, u, pdf))
    }

    /// Density of [`sample_emission`](Self::sample_emission) choosing the ray from `u` through
    /// `s`: sum_m C_m(s) Phi_m(u) / (h_x h_y sum_m integral C_m) in area x area, times
    /// d^2 / cos (a patch du at u subtends du cos / d^2 at s).
    pub fn emission_pdf(&self, s: Vec2, u: Vec2) -> f32 {
        let l = &self.layout;
        let Some(pixel) = self.pixel_index(s) else {
            return 0.0;
        };
        let mut sum = 0f64;
        self.for_each_basis(u, |m, phi| {
            sum += (self.weight[m * l.pixels_per_image() + pixel] * phi) as f64;
        });
        let h = l.node_spacing;
        let ps = l.pixel_size();
        let area_area = sum / (self.weight_sum * (h.x * h.y * ps.x * ps.y) as f64);
        let d2 = (s - u).length_squared() + l.plane_distance * l.plane_distance;
        let cos = l.plane_distance / d2.sqrt();
        (area_area * (d2 / cos) as f64) as f32
    }

    /// Area density on the image plane of the origin `s` of [`sample_emission`](Self::sample_emission)'s
    /// rays: sum_m C_m(s) / sum_m integral C_m.
    pub fn emission_origin_pdf(&self, s: Vec2) -> f32 {
        let l = &self.layout;
        let Some(pixel) = self.pixel_index(s) else {
            return 0.0;
        };
        let sum: f64 = (0..l.image_count())
            .map(|m| self.weight[m * l.pixels_per_image() + pixel] as f64)
            .sum();
        let ps = l.pixel_size();
        (sum / (self.weight_sum * (ps.x * ps.y) as f64)) as f32
    }

    /// Reads a light field stored as one EXR mosaic (docs/light-field.md): I/O errors name
    /// the file, malformed content is a parse error naming the attribute.
    pub fn from_file(path: &Path) -> Result<Self> {
        let image = image_file::read_exr_rgb(path)?;
        let parse_error = |e: Error| match e {
            Error::InvalidArgument(message) => Error::parse(path, "", message),
            other => other,
        };
        let layout = layout_from_metadata(&image.metadata)
            .map_err(|(key, message)| Error::parse(path, key, message))?;
        let (nx, ny) = (layout.nodes[0] as usize, layout.nodes[1] as usize);
        let (rx, ry) = (layout.resolution[0] as usize, layout.resolution[1] as usize);
        if image.width as usize != nx * rx || image.height as usize != ny * ry {
            return Err(Error::parse(
                path,
                "",
                format!(
                    "a mosaic of {nx}x{ny} images of {rx}x{ry} pixels must be {}x{}, the file is {}x{}",
                    nx * rx,
                    ny * ry,
                    image.width,
                    image.height
                ),
            ));
        }
        let mut pixels = Vec::with_capacity(image.pixels.len());
        for j in 0..ny {
            for i in 0..nx {
                for y in 0..ry {
                    let row = (j * ry + y) * nx * rx + i * rx;
                    pixels.extend_from_slice(&image.pixels[row..row + rx]);
                }
            }
        }
        Self::new(layout, pixels).map_err(parse_error)
    }

    /// Writes the light field as an EXR mosaic readable by [`from_file`](Self::from_file).
    pub fn write(&self, path: &Path) -> Result<()> {
        let l = &self.layout;
        let (nx, ny) = (l.nodes[0] as usize, l.nodes[1] as usize);
        let (rx, ry) = (l.resolution[0] as usize, l.resolution[1] as usize);
        let mut mosaic = vec![Rgb::ZERO; self.colour.len()];
        for j in 0..ny {
            for i in 0..nx {
                let m = j * nx + i;
                for y in 0..ry {
                    let row = (j * ry + y) * nx * rx + i * rx;
                    let from = m * rx * ry + y * rx;
                    mosaic[row..row + rx].copy_from_slice(&self.colour[from..from + rx]);
                }
            }
        }
        let pair = |v: Vec2| format!("{} {}", v.x, v.y);
        let metadata = ExrMetadata::default()
            .with("light_field", FORMAT_VERSION)
            .with("light_field.nodes", format!("{nx} {ny}"))
            .with("light_field.node_min", pair(l.node_min))
            .with("light_field.node_spacing", pair(l.node_spacing))
            .with("light_field.basis", l.basis.name())
            .with("light_field.plane_distance", l.plane_distance)
            .with("light_field.image_min", pair(l.image_min))
            .with("light_field.image_max", pair(l.image_max))
            .with("light_field.resolution", format!("{rx} {ry}"));
        image_file::write_exr_rgb(path, (nx * rx) as u32, (ny * ry) as u32, &mosaic, &metadata)
    }
}

/// Restricted sampling's image choice, tabled per receiver cell so that a light sample does
/// not weigh every image (per-image balancing at each receiver, eq. 4.16, costs O(images)).
///
/// A receiver p (light-local, z > delta) sees the support [lo, hi] of Phi_m through the box
/// [lo t + a, hi t + a] of the image plane, with t = 1 - delta / p_z in (0, 1) and
/// a = p_xy delta / p_z (where the line from the frame's origin to p crosses I). The cells are
/// a regular grid over (a_x, a_y, t); over a cell each box stays within the union of its boxes
/// at the cell's corners, whose luminance integral U_m(c) bounds A_m(p) for every p in the
/// cell. Image m is chosen with probability
///
///   q_c(m) = (1 - DEFENSIVE) W_m(c) / sum W + DEFENSIVE U_m(c) / sum U,
///
/// W_m(c) the mean of A_m at 8 points inside the cell (the balancing of eq. 4.16, sampled).
/// The bound keeps q_c(m) > 0 wherever A_m(p) > 0 for some p in the cell, so no light is
/// missed; the density ([`LightField::restricted_pdf`]) reads q_c(m) from the same cell.
#[derive(Clone, Debug, Default)]
struct ImageChoiceGrid {
    /// Cells along a_x, a_y and t.
    cells: [usize; 3],
    /// The corner of the grid in a, and the size of a cell in a.
    a_min: Vec2,
    a_size: Vec2,
    /// Per cell, the images' cumulative (unnormalised) probabilities: image_count + 1
    /// entries from 0, so that q_c(m) = (C[m + 1] - C[m]) / C[n].
    cumulative: Vec<f64>,
    images: usize,
}

/// Share of the image choice spread by the cell's bound (see [`ImageChoiceGrid`]).
const DEFENSIVE: f64 = 0.1;
/// Cells along t, and at most along each axis of a.
const T_CELLS: usize = 8;
const MAX_A_CELLS: usize = 32;
/// At most this many table entries (cells x images); fields with more images get fewer cells,
/// down to one (images chosen by their bound over every receiver).
const MAX_TABLE_ENTRIES: usize = 1 << 22;

impl ImageChoiceGrid {
    fn build(field: &LightField) -> Self {
        let l = &field.layout;
        let n = l.image_count();
        let half = l.node_spacing * l.basis.radius();
        let lo = l.node_min - half;
        let hi = l.node(l.nodes[0] as usize - 1, l.nodes[1] as usize - 1) + half;
        // A box meets the image rectangle only if a lies in [image_min - hi t, image_max - lo t]
        // for some t in (0, 1); one pixel of margin each side absorbs rounding.
        let pixel = l.pixel_size();
        let a_min = l.image_min - hi.max(Vec2::ZERO) - pixel;
        let a_max = l.image_max - lo.min(Vec2::ZERO) + pixel;
        let span = a_max - a_min;
        // Cells about as wide in a as a box of the nearest receivers (radius h t, t near 1),
        // so that a box moves by about its own size across a cell.
        let budget = (MAX_TABLE_ENTRIES / (n + 1)).max(1);
        let wanted = |span: f32, h: f32| {
            ((span / (h * l.basis.radius())).ceil() as usize).clamp(1, MAX_A_CELLS)
        };
        let mut a_cells = [
            wanted(span.x, l.node_spacing.x),
            wanted(span.y, l.node_spacing.y),
        ];
        let mut t_cells = T_CELLS;
        while a_cells[0] * a_cells[1] * t_cells > budget {
            if a_cells[0] > 1 || a_cells[1] > 1 {
                a_cells = [a_cells[0].div_ceil(2), a_cells[1].div_ceil(2)];
            } else {
                t_cells = 1;
            }
        }
        let mut grid = ImageChoiceGrid {
            cells: [a_cells[0], a_cells[1], t_cells],
            a_min,
            a_size: span / Vec2::new(a_cells[0] as f32, a_cells[1] as f32),
            cumulative: Vec::new(),
            images: n,
        };
        let [cx, cy, _] = grid.cells;
        // Cells are independent: built in parallel (the two fields of a room take about
        // 0.2 s each on one core).
        let tables: Vec<Vec<f64>> = (0..cx * cy * t_cells)
            .into_par_iter()
            .map(|cell| {
                let (ix, iy, it) = (cell % cx, (cell / cx) % cy, cell / (cx * cy));
                grid.cell_table(field, ix, iy, it)
            })
            .collect();
        grid.cumulative = tables.concat();
        grid
    }

    /// One cell's cumulative image probabilities (image_count + 1 entries from 0).
    fn cell_table(&self, field: &LightField, ix: usize, iy: usize, it: usize) -> Vec<f64> {
        let n = self.images;
        let (c_lo, c_hi) = self.cell_bounds(ix, iy, it);
        let mut bound = vec![0f64; n];
        let mut typical = vec![0f64; n];
        for m in 0..n {
            bound[m] = field.union_box_integral(m, c_lo, c_hi);
            if bound[m] > 0.0 {
                for k in 0..8 {
                    let f = |bit: usize| if k & bit == 0 { 0.25 } else { 0.75 };
                    let a = Vec2::new(
                        c_lo.x + f(1) * (c_hi.x - c_lo.x),
                        c_lo.y + f(2) * (c_hi.y - c_lo.y),
                    );
                    let t = c_lo.z + f(4) * (c_hi.z - c_lo.z);
                    typical[m] += field.a_t_box_integral(m, a, t) / 8.0;
                }
            }
        }
        let (sum_bound, sum_typical): (f64, f64) = (bound.iter().sum(), typical.iter().sum());
        let mut cumulative = Vec::with_capacity(n + 1);
        let mut acc = 0f64;
        cumulative.push(0.0);
        for m in 0..n {
            let q = if sum_bound > 0.0 {
                let spread = DEFENSIVE * bound[m] / sum_bound;
                if sum_typical > 0.0 {
                    (1.0 - DEFENSIVE) * typical[m] / sum_typical + spread
                } else {
                    spread / DEFENSIVE
                }
            } else {
                0.0
            };
            acc += q;
            cumulative.push(acc);
        }
        cumulative
    }

    /// The cell's corners in (a_x, a_y, t).
    fn cell_bounds(&self, ix: usize, iy: usize, it: usize) -> (Vec3, Vec3) {
        let a0 = self.a_min + self.a_size * Vec2::new(ix as f32, iy as f32);
        let a1 = a0 + self.a_size;
        let t_size = 1.0 / self.cells[2] as f32;
        (
            Vec3::new(a0.x, a0.y, it as f32 * t_size),
            Vec3::new(a1.x, a1.y, (it + 1) as f32 * t_size),
        )
    }

    /// The cell of receiver `p` (light-local); `None` in front of the image plane. Receivers
    /// beyond the grid in a take its edge cell (their boxes miss the image: nothing to choose).
    fn cell_of(&self, l: &LightFieldLayout, p: Vec3) -> Option<usize> {
        if !(p.z > l.plane_distance) || !p.is_finite() {
            return None;
        }
        let k = l.plane_distance / p.z;
        let a = Vec2::new(p.x, p.y) * k;
        let index = |v: f32, n: usize| (v.max(0.0) as usize).min(n - 1);
        let g = (a - self.a_min) / self.a_size;
        let ix = index(g.x, self.cells[0]);
        let iy = index(g.y, self.cells[1]);
        let it = index((1.0 - k) * self.cells[2] as f32, self.cells[2]);
        Some((it * self.cells[1] + iy) * self.cells[0] + ix)
    }

    fn table(&self, cell: usize) -> &[f64] {
        &self.cumulative[cell * (self.images + 1)..(cell + 1) * (self.images + 1)]
    }

    /// q_c(m).
    fn probability(&self, cell: usize, m: usize) -> f64 {
        let c = self.table(cell);
        let total = c[self.images];
        if total > 0.0 {
            (c[m + 1] - c[m]) / total
        } else {
            0.0
        }
    }

    /// An image with probability q_c(m) from `u` in [0, 1), and `u` stretched within its share.
    fn choose(&self, cell: usize, u: f64) -> Option<(usize, f64)> {
        let c = self.table(cell);
        let total = c[self.images];
        if !(total > 0.0) {
            return None;
        }
        let target = u.clamp(0.0, 1.0) * total;
        // The image m with C[m] <= target < C[m + 1] (never an empty share).
        let m = c[1..]
            .partition_point(|&v| v <= target)
            .min(self.images - 1);
        let (c0, c1) = (c[m], c[m + 1]);
        (c1 > c0).then(|| (m, ((target - c0) / (c1 - c0)).clamp(0.0, 1.0)))
    }
}

/// The value of the `lacuna:light_field` attribute this version writes and reads.
pub const FORMAT_VERSION: &str = "1";

/// The layout from a mosaic's `lacuna:light_field.*` attributes; errors name the attribute.
fn layout_from_metadata(
    meta: &ExrMetadata,
) -> std::result::Result<LightFieldLayout, (String, String)> {
    let get = |key: &str| {
        meta.get(key).ok_or_else(|| {
            (
                format!("lacuna:{key}"),
                "missing: not a Lacuna light field".to_string(),
            )
        })
    };
    let version = get("light_field")?;
    if version != FORMAT_VERSION {
        return Err((
            "lacuna:light_field".into(),
            format!("version {version} is not supported (expected {FORMAT_VERSION})"),
        ));
    }
    fn numbers<T: std::str::FromStr>(
        key: &str,
        text: &str,
    ) -> std::result::Result<[T; 2], (String, String)> {
        let bad = || {
            (
                format!("lacuna:{key}"),
                format!("'{text}' is not two numbers"),
            )
        };
        let mut it = text.split_whitespace().map(|w| w.parse::<T>());
        match (it.next(), it.next(), it.next()) {
            (Some(Ok(a)), Some(Ok(b)), None) => Ok([a, b]),
            _ => Err(bad()),
        }
    }
    let vec2 = |key: &str| -> std::result::Result<Vec2, (String, String)> {
        let [x, y] = numbers::<f32>(key, get(key)?)?;
        Ok(Vec2::new(x, y))
    };
    let distance_text = get("light_field.plane_distance")?;
    let plane_distance = distance_text.trim().parse::<f32>().map_err(|_| {
        (
            "lacuna:light_field.plane_distance".to_string(),
            format!("'{distance_text}' is not a number"),
        )
    })?;
    let basis = FilterBasis::parse(get("light_field.basis")?)
        .map_err(|e| ("lacuna:light_field.basis".to_string(), e.to_string()))?;
    let layout = LightFieldLayout {
        nodes: numbers::<u32>("light_field.nodes", get("light_field.nodes")?)?,
        node_min: vec2("light_field.node_min")?,
        node_spacing: vec2("light_field.node_spacing")?,
        basis,
        plane_distance,
        image_min: vec2("light_field.image_min")?,
        image_max: vec2("light_field.image_max")?,
        resolution: numbers::<u32>("light_field.resolution", get("light_field.resolution")?)?,
    };
    layout
        .validate()
        .map_err(|e| ("lacuna:light_field".to_string(), e.to_string()))?;
    Ok(layout)
}

/// Inverts a non-decreasing, piecewise-linear (between integers) function `f` on [a, b]:
/// the x with f(x) - f(a) = u (f(b) - f(a)), found by bisection on the integer knots and then
/// linearly. `f_knot(k)` must be `f(k as f64)` (to the bit) at the knots k in [floor(a),
/// ceil(b)], for a cheaper read there. `None` when f does not increase on [a, b].
fn invert_piecewise_linear(
    f: impl Fn(f64) -> f64,
    f_knot: impl Fn(i64) -> f64,
    a: f64,
    b: f64,
    u: f64,
) -> Option<f64> {
    let (fa, fb) = (f(a), f(b));
    if !(fb > fa) {
        return None;
    }
    let target = fa + u.clamp(0.0, 1.0) * (fb - fa);
    // The last knot k in [floor(a), ceil(b) - 1] with f(max(k, a)) < target: the piece from
    // max(k, a) to min(k + 1, b) holds the target and rises. Every knot probed lies strictly
    // inside (a, b). The values read at lo and at hi + 1 serve the last piece.
    let (mut lo, mut hi) = (
        a.floor() as i64,
        (b.ceil() as i64 - 1).max(a.floor() as i64),
    );
    let (mut f_lo, mut f_above) = (None, None);
    while lo < hi {
        let mid = (lo + hi + 1) / 2;
        let f_mid = f_knot(mid);
        if f_mid < target {
            lo = mid;
            f_lo = Some(f_mid);
        } else {
            hi = mid - 1;
            f_above = Some(f_mid);
        }
    }
    let x0 = (lo as f64).max(a);
    let x1 = (lo as f64 + 1.0).min(b);
    let f0 = match f_lo {
        _ if x0 == a => fa,
        Some(v) => v,
        None => f_knot(lo),
    };
    let f1 = match f_above {
        _ if x1 == b => fb,
        Some(v) => v,
        None => f_knot(lo + 1),
    };
    let x = if f1 > f0 {
        x0 + (target - f0) / (f1 - f0) * (x1 - x0)
    } else {
        0.5 * (x0 + x1)
    };
    Some(x.clamp(x0, x1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    #[test]
    fn basis_integrates_to_one_and_sampling_inverts_its_cdf() {
        for basis in [FilterBasis::Linear, FilterBasis::Quadratic] {
            let r = basis.radius();
            let n = 30_000;
            let integral: f32 = (0..n)
                .map(|k| {
                    basis.eval(-r + 2.0 * r * (k as f32 + 0.5) / n as f32) * 2.0 * r / n as f32
                })
                .sum();
            assert!((integral - 1.0).abs() < 1e-4, "{basis:?}: {integral}");
            assert!((basis.cdf(r) - 1.0).abs() < 1e-6 && basis.cdf(-r).abs() < 1e-6);
            for k in 0..100 {
                let u = (k as f32 + 0.5) / 100.0;
                let t = basis.sample(u);
                assert!(
                    (basis.cdf(t) - u).abs() < 1e-4,
                    "{basis:?}: cdf({t}) vs {u}"
                );
            }
        }
        // The quadratic cdf's pieces meet.
        let q = FilterBasis::Quadratic;
        assert!((q.cdf(-0.5) - 1.0 / 6.0).abs() < 1e-6);
        assert!((q.cdf(0.5) - 5.0 / 6.0).abs() < 1e-6);
    }

    #[test]
    fn summed_area_table_integrates_boxes_exactly() {
        let layout = LightFieldLayout {
            nodes: [1, 1],
            node_min: Vec2::ZERO,
            node_spacing: Vec2::ONE,
            basis: FilterBasis::Linear,
            plane_distance: 1.0,
            image_min: Vec2::ZERO,
            image_max: Vec2::new(4.0, 3.0),
            resolution: [4, 3],
        };
        let pixels: Vec<Rgb> = (0..12).map(|i| Rgb::splat(i as f32)).collect();
        let f = LightField::new(layout, pixels).unwrap();
        // [0.5, 2.25] x [0.5, 2.5]: rows 0 (values 0-3) and 2 (8-11) half, row 1 (4-7) whole.
        let b = PixelBox {
            x0: 0.5,
            x1: 2.25,
            y0: 0.5,
            y1: 2.5,
        };
        let row = |v: [f64; 3]| 0.5 * v[0] + v[1] + 0.25 * v[2];
        let expected =
            0.5 * row([0.0, 1.0, 2.0]) + row([4.0, 5.0, 6.0]) + 0.5 * row([8.0, 9.0, 10.0]);
        let lum = luminance(Rgb::ONE) as f64;
        assert!((f.box_integral(0, &b) - expected * lum).abs() < 1e-5);
        let mut rng = Rng::new(1, 0);
        for _ in 0..1000 {
            let (x, y) = f
                .sample_in_box(0, &b, rng.uniform() as f64, rng.uniform() as f64)
                .unwrap();
            assert!(b.contains(x, y), "({x}, {y}) outside the box");
            assert!(x >= 1.0 || y >= 1.0, "({x}, {y}) in the zero pixel");
        }
    }

    /// The summed-area table read by interpolating both axes, whatever the point.
    fn plain_sat_at(f: &LightField, m: usize, x: f64, y: f64) -> f64 {
        let (rx, ry) = (
            f.layout.resolution[0] as usize,
            f.layout.resolution[1] as usize,
        );
        let t = &f.sat[m * (rx + 1) * (ry + 1)..];
        let xi = (x.max(0.0) as usize).min(rx - 1);
        let yi = (y.max(0.0) as usize).min(ry - 1);
        let (fx, fy) = (x - xi as f64, y - yi as f64);
        let at = |a: usize, b: usize| t[b * (rx + 1) + a];
        let bottom = at(xi, yi) * (1.0 - fx) + at(xi + 1, yi) * fx;
        let top = at(xi, yi + 1) * (1.0 - fx) + at(xi + 1, yi + 1) * fx;
        bottom * (1.0 - fy) + top * fy
    }

    /// Bisection reading `f` at every probe.
    fn plain_invert(f: impl Fn(f64) -> f64, a: f64, b: f64, u: f64) -> Option<f64> {
        let (fa, fb) = (f(a), f(b));
        if !(fb > fa) {
            return None;
        }
        let target = fa + u.clamp(0.0, 1.0) * (fb - fa);
        let (mut lo, mut hi) = (
            a.floor() as i64,
            (b.ceil() as i64 - 1).max(a.floor() as i64),
        );
        while lo < hi {
            let mid = (lo + hi + 1) / 2;
            if f((mid as f64).max(a)) < target {
                lo = mid;
            } else {
                hi = mid - 1;
            }
        }
        let x0 = (lo as f64).max(a);
        let x1 = (lo as f64 + 1.0).min(b);
        let (f0, f1) = (f(x0), f(x1));
        let x = if f1 > f0 {
            x0 + (target - f0) / (f1 - f0) * (x1 - x0)
        } else {
            0.5 * (x0 + x1)
        };
        Some(x.clamp(x0, x1))
    }

    fn plain_sample_in_box(
        f: &LightField,
        m: usize,
        b: &PixelBox,
        ux: f64,
        uy: f64,
    ) -> Option<(f64, f64)> {
        let g = |x: f64| plain_sat_at(f, m, x, b.y1) - plain_sat_at(f, m, x, b.y0);
        let x = plain_invert(g, b.x0, b.x1, ux)?;
        let column = (x.floor().max(0.0) as usize).min(f.layout.resolution[0] as usize - 1);
        let (c0, c1) = (column as f64, column as f64 + 1.0);
        let h = |y: f64| plain_sat_at(f, m, c1, y) - plain_sat_at(f, m, c0, y);
        let y = plain_invert(h, b.y0, b.y1, uy)?;
        Some((x, y))
    }

    /// The restricted density summed over every image, each box from its corners.
    fn plain_restricted_pdf(f: &LightField, p: Vec3, s: Vec2) -> f32 {
        let l = &f.layout;
        let Some(cell) = f.choice_grid.cell_of(l, p) else {
            return 0.0;
        };
        let Some(pixel) = f.pixel_index(s) else {
            return 0.0;
        };
        let (x, y) = f.to_pixels(s);
        let mut density = 0f64;
        for m in 0..l.image_count() {
            let q = f.choice_grid.probability(cell, m);
            let (i, j) = (m % l.nodes[0] as usize, m / l.nodes[0] as usize);
            let half = l.node_spacing * l.basis.radius();
            let (lo, hi) = (l.node(i, j) - half, l.node(i, j) + half);
            let k = l.plane_distance / p.z;
            let pxy = Vec2::new(p.x, p.y);
            let Some(b) = f.pixel_box(lo + (pxy - lo) * k, hi + (pxy - hi) * k) else {
                continue;
            };
            if q <= 0.0 || !b.contains(x, y) {
                continue;
            }
            let a = plain_sat_at(f, m, b.x1, b.y1)
                - plain_sat_at(f, m, b.x0, b.y1)
                - plain_sat_at(f, m, b.x1, b.y0)
                + plain_sat_at(f, m, b.x0, b.y0);
            if a > 0.0 {
                density += q * f.weight[m * l.pixels_per_image() + pixel] as f64 / a;
            }
        }
        let ps = l.pixel_size();
        (density / (ps.x as f64 * ps.y as f64)) as f32
    }

    /// The summed-area reads at the knots, the boxes built one side at a time and the pdf's
    /// window of candidate images give the same numbers, to the bit, as their plain forms.
    #[test]
    fn restricted_sampling_matches_its_plain_form_to_the_bit() {
        let layout = LightFieldLayout {
            nodes: [6, 5],
            node_min: Vec2::new(-0.25, -0.2),
            node_spacing: Vec2::new(0.1, 0.1),
            basis: FilterBasis::Quadratic,
            plane_distance: 0.3,
            image_min: Vec2::new(-0.8, -0.7),
            image_max: Vec2::new(0.8, 0.9),
            resolution: [13, 11],
        };
        let mut rng = Rng::new(7, 0);
        let pixels: Vec<Rgb> = (0..layout.image_count() * layout.pixels_per_image())
            .map(|_| {
                // Some zero pixels, so that boxes and columns can be empty.
                let v = rng.uniform();
                Rgb::splat(if v < 0.2 { 0.0 } else { v * v * 10.0 })
            })
            .collect();
        let f = LightField::new(layout.clone(), pixels).unwrap();
        let whole = PixelBox {
            x0: 0.0,
            x1: 13.0,
            y0: 0.0,
            y1: 11.0,
        };
        let (mut samples, mut densities) = (0, 0);
        for _ in 0..3000 {
            let p = Vec3::new(
                2.0 * rng.uniform() - 1.0,
                2.0 * rng.uniform() - 1.0,
                0.3 + 1.5 * rng.uniform() + 1e-3,
            );
            let m = (rng.uniform() * layout.image_count() as f32) as usize % layout.image_count();
            let (ux, uy) = (rng.uniform() as f64, rng.uniform() as f64);
            for b in [f.restricted_box(p, m), Some(whole)].into_iter().flatten() {
                let fast = f.sample_in_box(m, &b, ux, uy);
                let plain = plain_sample_in_box(&f, m, &b, ux, uy);
                let bits = |v: Option<(f64, f64)>| v.map(|(x, y)| (x.to_bits(), y.to_bits()));
                assert_eq!(
                    bits(fast),
                    bits(plain),
                    "image {m}, box {b:?}, u ({ux}, {uy})"
                );
                samples += fast.is_some() as usize;
            }
            let s = match f.sample_restricted(p, Vec2::new(rng.uniform(), rng.uniform())) {
                Some((s, _)) => s,
                None => Vec2::new(2.0 * rng.uniform() - 1.0, 2.0 * rng.uniform() - 1.0),
            };
            let (fast, plain) = (f.restricted_pdf(p, s), plain_restricted_pdf(&f, p, s));
            assert_eq!(
                fast.to_bits(),
                plain.to_bits(),
                "p {p}, s {s}: {fast} vs {plain}"
            );
            densities += (fast > 0.0) as usize;
        }
        assert!(
            samples > 2000 && densities > 1000,
            "{samples} samples, {densities} densities"
        );
    }

    #[test]
    fn invalid_layouts_and_pixels_are_refused() {
        let good = LightFieldLayout {
            nodes: [2, 2],
            node_min: Vec2::ZERO,
            node_spacing: Vec2::ONE,
            basis: FilterBasis::Quadratic,
            plane_distance: 1.0,
            image_min: Vec2::ZERO,
            image_max: Vec2::ONE,
            resolution: [2, 2],
        };
        let pixels = || vec![Rgb::ONE; 16];
        assert!(LightField::new(good.clone(), pixels()).is_ok());
        assert!(LightField::new(good.clone(), vec![Rgb::ONE; 15]).is_err());
        assert!(LightField::new(good.clone(), vec![Rgb::ZERO; 16]).is_err());
        let mut nan = pixels();
        nan[3] = Rgb::new(f32::NAN, 0.0, 0.0);
        assert!(LightField::new(good.clone(), nan).is_err());
        for bad in [
            LightFieldLayout {
                plane_distance: 0.0,
                ..good.clone()
            },
            LightFieldLayout {
                nodes: [0, 2],
                ..good.clone()
            },
            LightFieldLayout {
                node_spacing: Vec2::new(1.0, -1.0),
                ..good.clone()
            },
            LightFieldLayout {
                image_max: Vec2::new(0.0, 1.0),
                ..good.clone()
            },
        ] {
            assert!(LightField::new(bad, pixels()).is_err());
        }
    }
}
