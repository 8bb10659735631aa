//! The film: per-pixel sums of radiance samples with their counts, plus the auxiliary
//! outputs (AOVs) a denoiser or a host wants: first-hit albedo, shading normal and depth.
//! Sums are kept in f64 so that long progressive renders do not lose precision.
//!
//! An integrator may also declare named RGB *layers* (e.g. bidirectional path tracing's
//! per-strategy images): they are summed and averaged exactly like the radiance, so a layer is
//! a per-pixel mean over the same samples, and a cancelled pass drops them together.

pub mod metrics;
mod output;

/// Image files are read and written by [`crate::image_file`]; re-exported for the film's users.
pub use crate::image_file::{
    encode_srgb, read_exr_rgb, read_exr_rgb_within, write_exr_rgb, write_png_rgb, ExrImage,
    ExrMetadata,
};
pub use metrics::{image_errors, largest_pixel_ratio, ImageErrors};

use crate::error::Result;
use crate::limits;
use crate::math::Rgb;

/// What one camera sample contributes to its pixel.
#[derive(Clone, Copy, Debug, Default)]
pub struct PixelSample {
    pub radiance: Rgb,
    /// First-hit albedo, shading normal and distance; `hit` is false when the camera ray
    /// escaped.
    pub albedo: Rgb,
    pub normal: Rgb,
    pub depth: f32,
    pub hit: bool,
}

/// Per-pixel accumulation of one pass or of a whole render.
#[derive(Clone, Debug)]
pub struct Film {
    width: u32,
    height: u32,
    radiance: Vec<[f64; 3]>,
    albedo: Vec<[f32; 3]>,
    normal: Vec<[f32; 3]>,
    depth: Vec<f32>,
    /// Camera samples taken per pixel.
    samples: Vec<u32>,
    /// Camera samples that hit a surface (AOVs are averaged over these).
    hits: Vec<u32>,
    /// Names of the integrator's layers, and their sums (pixel-major: all layers of pixel 0,
    /// then of pixel 1, ...).
    layer_names: Vec<String>,
    layers: Vec<[f64; 3]>,
}

impl Film {
    pub fn new(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Film {
            width,
            height,
            radiance: vec![[0.0; 3]; n],
            albedo: vec![[0.0; 3]; n],
            normal: vec![[0.0; 3]; n],
            depth: vec![0.0; n],
            samples: vec![0; n],
            hits: vec![0; n],
            layer_names: Vec::new(),
            layers: Vec::new(),
        }
    }

    /// A film that also accumulates the named layers.
    pub fn with_layers(width: u32, height: u32, names: &[String]) -> Self {
        let mut film = Film::new(width, height);
        film.layers = vec![[0.0; 3]; film.samples.len() * names.len()];
        film.layer_names = names.to_vec();
        film
    }

    /// Bytes a `width` x `height` film with `layer_count` layers holds.
    pub fn memory_bytes_for(width: u32, height: u32, layer_count: usize) -> u64 {
        width as u64 * height as u64 * (PER_PIXEL_BYTES + 24 * layer_count as u64)
    }

    /// Checks that a `width` x `height` film with `layers` strategy images has sides within
    /// [`crate::limits::MAX_FILM_SIDE`] and fits `budget` bytes, before anything is allocated.
    pub fn check_budget(width: u32, height: u32, layers: usize, budget: u64) -> Result<()> {
        limits::check_film_side(width, height)?;
        limits::check_bytes(
            || {
                if layers > 0 {
                    format!("a {width}x{height} film with {layers} strategy images")
                } else {
                    format!("a {width}x{height} film")
                }
            },
            Film::memory_bytes_for(width, height, layers),
            budget,
        )
    }

    pub fn layer_names(&self) -> &[String] {
        &self.layer_names
    }

    /// Index of the layer called `name`.
    pub fn layer_index(&self, name: &str) -> Option<usize> {
        self.layer_names.iter().position(|n| n == name)
    }

    /// Adds one camera sample's layer values to pixel (x, y) (the sample itself is counted by
    /// `add_sample`). Non-finite values are dropped, as for radiance.
    pub fn add_layer_values(&mut self, x: u32, y: u32, values: &[Rgb]) {
        debug_assert_eq!(values.len(), self.layer_names.len());
        let base = self.index(x, y) * self.layer_names.len();
        for (sum, v) in self.layers[base..].iter_mut().zip(values) {
            if crate::math::is_finite3(*v) {
                for c in 0..3 {
                    sum[c] += v[c] as f64;
                }
            }
        }
    }

    /// Adds to one layer of a pixel without counting a sample (the layer's share of a splat).
    pub fn add_layer_splat(&mut self, layer: usize, pixel_index: usize, value: Rgb) {
        let n = self.layer_names.len();
        if layer < n && pixel_index < self.samples.len() && crate::math::is_finite3(value) {
            let sum = &mut self.layers[pixel_index * n + layer];
            for c in 0..3 {
                sum[c] += value[c] as f64;
            }
        }
    }

    /// Mean of layer `layer` per pixel, row-major (like `radiance`).
    pub fn layer(&self, layer: usize) -> Vec<Rgb> {
        let n = self.layer_names.len();
        assert!(layer < n, "layer {layer} of {n}");
        self.samples
            .iter()
            .enumerate()
            .map(|(i, &count)| {
                let r = self.layers[i * n + layer];
                let k = count.max(1) as f64;
                Rgb::new((r[0] / k) as f32, (r[1] / k) as f32, (r[2] / k) as f32)
            })
            .collect()
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    #[inline]
    fn index(&self, x: u32, y: u32) -> usize {
        y as usize * self.width as usize + x as usize
    }

    /// Adds one camera sample. Non-finite radiance is dropped (counted as a black sample) so
    /// that no NaN or infinity ever reaches a pixel.
    pub fn add_sample(&mut self, x: u32, y: u32, s: &PixelSample) {
        let i = self.index(x, y);
        self.samples[i] += 1;
        if crate::math::is_finite3(s.radiance) {
            for c in 0..3 {
                self.radiance[i][c] += s.radiance[c] as f64;
            }
        }
        if s.hit {
            self.hits[i] += 1;
            for c in 0..3 {
                self.albedo[i][c] += s.albedo[c];
                self.normal[i][c] += s.normal[c];
            }
            self.depth[i] += s.depth;
        }
    }

    /// Adds radiance to a pixel without counting a sample (light-tracing splats, whose
    /// per-iteration scaling is already applied). Non-finite values are dropped.
    pub fn add_splat(&mut self, pixel_index: usize, value: Rgb) {
        if crate::math::is_finite3(value) && pixel_index < self.radiance.len() {
            for c in 0..3 {
                self.radiance[pixel_index][c] += value[c] as f64;
            }
        }
    }

    /// Adds the pixels of `tile` (a film of the tile's size, with the same layers) at offset
    /// (x0, y0).
    pub fn merge_tile(&mut self, x0: u32, y0: u32, tile: &Film) {
        assert_eq!(self.layer_names.len(), tile.layer_names.len());
        for ty in 0..tile.height {
            for tx in 0..tile.width {
                let (x, y) = (x0 + tx, y0 + ty);
                if x >= self.width || y >= self.height {
                    continue;
                }
                let (i, j) = (self.index(x, y), tile.index(tx, ty));
                for c in 0..3 {
                    self.radiance[i][c] += tile.radiance[j][c];
                    self.albedo[i][c] += tile.albedo[j][c];
                    self.normal[i][c] += tile.normal[j][c];
                }
                self.depth[i] += tile.depth[j];
                self.samples[i] += tile.samples[j];
                self.hits[i] += tile.hits[j];
                let n = tile.layer_names.len();
                if n > 0 {
                    let (dst, src) = (&mut self.layers[i * n..(i + 1) * n], &tile.layers[j * n..]);
                    for (d, s) in dst.iter_mut().zip(src) {
                        for c in 0..3 {
                            d[c] += s[c];
                        }
                    }
                }
            }
        }
    }

    /// Adds every pixel of another film of the same size.
    pub fn merge(&mut self, other: &Film) {
        assert_eq!((self.width, self.height), (other.width, other.height));
        assert_eq!(self.layer_names, other.layer_names);
        self.merge_tile(0, 0, other);
    }

    /// Multiplies the radiance and layer sums by `factor` (sample counts and AOVs kept): a
    /// pass weighted in a mean of passes of unequal sizes (the render loop's sized passes).
    pub fn scale_radiance(&mut self, factor: f64) {
        for v in self.radiance.iter_mut().chain(self.layers.iter_mut()) {
            for c in v.iter_mut() {
                *c *= factor;
            }
        }
    }

    /// Mean radiance of a pixel (zero before any sample).
    pub fn pixel(&self, x: u32, y: u32) -> Rgb {
        let i = self.index(x, y);
        let n = self.samples[i].max(1) as f64;
        let r = self.radiance[i];
        Rgb::new((r[0] / n) as f32, (r[1] / n) as f32, (r[2] / n) as f32)
    }

    pub fn samples(&self, x: u32, y: u32) -> u32 {
        self.samples[self.index(x, y)]
    }

    /// Smallest per-pixel sample count.
    pub fn min_samples(&self) -> u32 {
        self.samples.iter().copied().min().unwrap_or(0)
    }

    pub fn total_samples(&self) -> u64 {
        self.samples.iter().map(|&s| s as u64).sum()
    }

    /// Mean radiance of every pixel, row-major.
    pub fn radiance(&self) -> Vec<Rgb> {
        (0..self.height)
            .flat_map(|y| (0..self.width).map(move |x| (x, y)))
            .map(|(x, y)| self.pixel(x, y))
            .collect()
    }

    fn aov_mean(&self, buf: &[[f32; 3]]) -> Vec<Rgb> {
        buf.iter()
            .zip(&self.hits)
            .map(|(v, &h)| {
                if h > 0 {
                    Rgb::from(*v) / h as f32
                } else {
                    Rgb::ZERO
                }
            })
            .collect()
    }

    /// Mean first-hit albedo per pixel.
    pub fn albedo(&self) -> Vec<Rgb> {
        self.aov_mean(&self.albedo)
    }

    /// Mean first-hit shading normal per pixel (not renormalised; zero where nothing was hit).
    pub fn normal(&self) -> Vec<Rgb> {
        self.aov_mean(&self.normal)
    }

    /// Mean first-hit distance per pixel; zero where nothing was hit.
    pub fn depth(&self) -> Vec<f32> {
        self.depth
            .iter()
            .zip(&self.hits)
            .map(|(&d, &h)| if h > 0 { d / h as f32 } else { 0.0 })
            .collect()
    }

    pub fn memory_bytes(&self) -> usize {
        Film::memory_bytes_for(self.width, self.height, self.layer_names.len()) as usize
    }
}

/// Radiance (f64 x 3), albedo and normal (f32 x 3), depth, sample and hit counts.
const PER_PIXEL_BYTES: u64 = 24 + 12 + 12 + 4 + 4 + 4;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn film_budget_names_the_size_and_the_budget() {
        let budget = limits::DEFAULT_MEMORY_BUDGET;
        let e = Film::check_budget(65536, 65536, 0, budget).unwrap_err();
        let text = e.to_string();
        assert!(
            text.contains("65536x65536") && text.contains("8589934592"),
            "{text}"
        );
        assert!(Film::check_budget(512, 512, 0, budget).is_ok());
        assert!(Film::check_budget(65537, 1, 0, u64::MAX).is_err());
    }

    #[test]
    fn accumulates_means_and_drops_non_finite_samples() {
        let mut f = Film::new(2, 1);
        f.add_sample(
            0,
            0,
            &PixelSample {
                radiance: Rgb::ONE,
                ..Default::default()
            },
        );
        f.add_sample(
            0,
            0,
            &PixelSample {
                radiance: Rgb::splat(3.0),
                ..Default::default()
            },
        );
        f.add_sample(
            1,
            0,
            &PixelSample {
                radiance: Rgb::splat(f32::NAN),
                ..Default::default()
            },
        );
        assert_eq!(f.pixel(0, 0), Rgb::splat(2.0));
        assert_eq!(f.pixel(1, 0), Rgb::ZERO);
        assert_eq!(f.samples(1, 0), 1);
        let mut tile = Film::new(1, 1);
        tile.add_sample(
            0,
            0,
            &PixelSample {
                radiance: Rgb::splat(4.0),
                hit: true,
                depth: 2.0,
                ..Default::default()
            },
        );
        f.merge_tile(1, 0, &tile);
        assert_eq!(f.pixel(1, 0), Rgb::splat(2.0));
        assert_eq!(f.depth()[1], 2.0);
        assert_eq!(f.total_samples(), 4);
    }
}
