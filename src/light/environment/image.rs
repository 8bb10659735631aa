//! Environment-map images: radiance texels on a [`Grid`], loaded from OpenEXR (`exr` crate)
//! or Radiance `.hdr` (`image` crate), validated, converted between layouts, looked up by
//! direction (nearest texel: the radiance is piecewise constant over texels, like the
//! sampling densities built on it).

use std::path::Path;

use super::grid::{Grid, CROSS_POSITION};
use crate::error::{Error, Result};
use crate::math::{luminance, Rgb, Vec3};

/// Largest number of texels accepted (u32 indices, and 3 GiB of f32 RGB).
pub const MAX_TEXELS: usize = crate::limits::MAX_ENV_TEXELS;

/// Radiance texels on a layout.
#[derive(Clone, Debug)]
pub struct EnvImage {
    grid: Grid,
    texels: Vec<Rgb>,
    /// Texel components that were negative and were clamped to zero.
    clamped: usize,
}

impl EnvImage {
    /// Takes texels in the grid's storage order (lat-long: row-major from the zenith row; cube:
    /// face after face in `FACES` order, each row-major). NaN or infinite components are an
    /// error naming the first one; negative components (ringing of lossy compression) are
    /// clamped to zero and counted in [`EnvImage::clamped`].
    pub fn new(grid: Grid, mut texels: Vec<Rgb>) -> Result<Self> {
        check_grid(grid)?;
        if texels.len() != grid.texel_count() {
            return Err(Error::invalid(format!(
                "environment map: {} texels for a {} layout of {} texels",
                texels.len(),
                describe(grid),
                grid.texel_count()
            )));
        }
        let clamped = sanitize(grid, &mut texels)?;
        Ok(EnvImage {
            grid,
            texels,
            clamped,
        })
    }

    /// Reads an image of `width` x `height` RGB pixels laid out as a 2:1 lat-long map or a
    /// 4:3 horizontal cross.
    pub fn from_pixels(width: usize, height: usize, pixels: Vec<Rgb>) -> Result<Self> {
        if width == 0 || height == 0 || pixels.len() != width * height {
            return Err(Error::invalid(format!(
                "environment map: {} pixels for a {width}x{height} image",
                pixels.len()
            )));
        }
        if width == 2 * height {
            return EnvImage::new(Grid::LatLong { width, height }, pixels);
        }
        if 3 * width == 4 * height && width % 4 == 0 {
            let face = width / 4;
            check_grid(Grid::Cube { face })?;
            let mut texels = Vec::with_capacity(6 * face * face);
            for &(cx, cy) in &CROSS_POSITION {
                for row in 0..face {
                    let start = (cy * face + row) * width + cx * face;
                    texels.extend_from_slice(&pixels[start..start + face]);
                }
            }
            return EnvImage::new(Grid::Cube { face }, texels);
        }
        Err(Error::invalid(format!(
            "environment map: a {width}x{height} image is neither a 2:1 latitude-longitude map nor a 4:3 horizontal cross of cube faces"
        )))
    }

    /// An environment image from a decoded image (an `.hdr` file, or one compiled in; layout
    /// from the aspect ratio).
    pub fn from_decoded(img: image::DynamicImage) -> Result<Self> {
        let (w, h, pixels) = rgb_texels(img);
        EnvImage::from_pixels(w, h, pixels)
    }

    /// Loads an `.exr` or `.hdr` file (layout from the aspect ratio).
    pub fn load(path: &Path) -> Result<Self> {
        Self::load_within(
            path,
            crate::limits::effective_memory_budget(crate::limits::DEFAULT_MEMORY_BUDGET),
        )
    }

    /// [`EnvImage::load`] refusing, from the file's header and before decoding, images over
    /// [`MAX_TEXELS`] or needing more than `budget` bytes.
    pub fn load_within(path: &Path, budget: u64) -> Result<Self> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        let (w, h, pixels) = match ext.as_deref() {
            Some("exr") => {
                let img = crate::image_file::read_exr_rgb_within(path, budget)?;
                (img.width as usize, img.height as usize, img.pixels)
            }
            Some("hdr") => {
                // Decoded f32 RGB, and the texel copy.
                let img = crate::limits::open_image_checked(
                    path,
                    "environment map",
                    MAX_TEXELS as u64,
                    24,
                    budget,
                )?
                .decode()
                .map_err(|e| Error::parse(path, "", e.to_string()))?;
                rgb_texels(img)
            }
            _ => {
                return Err(Error::invalid(format!(
                    "environment map {}: expected an .exr or .hdr file",
                    path.display()
                )))
            }
        };
        EnvImage::from_pixels(w, h, pixels).map_err(|e| match e {
            Error::InvalidArgument(m) => Error::parse(path, "", m),
            other => other,
        })
    }

    pub fn grid(&self) -> Grid {
        self.grid
    }

    pub fn texels(&self) -> &[Rgb] {
        &self.texels
    }

    /// Negative texel components clamped to zero when the image was made.
    pub fn clamped(&self) -> usize {
        self.clamped
    }

    /// Replaces the texels with new ones of the same layout (validated as in `new`).
    pub fn replace(&mut self, texels: &[Rgb]) -> Result<()> {
        if texels.len() != self.texels.len() {
            return Err(Error::invalid(format!(
                "environment map update: {} texels, but the map has {} ({})",
                texels.len(),
                self.texels.len(),
                describe(self.grid)
            )));
        }
        let mut new = texels.to_vec();
        self.clamped = sanitize(self.grid, &mut new)?;
        self.texels = new;
        Ok(())
    }

    /// Radiance towards a unit direction of the local frame.
    #[inline]
    pub fn lookup(&self, d: Vec3) -> Rgb {
        self.texels[self.grid.texel_of(d)]
    }

    /// Integral of luminance over the sphere, with exact texel solid angles.
    pub fn luminance_integral(&self) -> f64 {
        self.texels
            .iter()
            .enumerate()
            .map(|(i, &c)| luminance(c) as f64 * self.grid.texel_solid_angle(i))
            .sum()
    }

    /// Resamples the map onto another layout: each new texel is the mean of 4 x 4 point
    /// lookups, a box filter that keeps the radiance of regions larger than a texel.
    pub fn convert(&self, grid: Grid) -> Result<EnvImage> {
        check_grid(grid)?;
        const K: usize = 4;
        let texels = (0..grid.texel_count())
            .map(|i| {
                let mut sum = Rgb::ZERO;
                for a in 0..K {
                    for b in 0..K {
                        let d = grid.texel_point(
                            i,
                            (a as f32 + 0.5) / K as f32,
                            (b as f32 + 0.5) / K as f32,
                        );
                        sum += self.lookup(d);
                    }
                }
                sum / (K * K) as f32
            })
            .collect();
        EnvImage::new(grid, texels)
    }

    /// The map as a 2:1 lat-long image or a 4:3 horizontal cross (black outside the faces),
    /// ready to write as an EXR.
    pub fn to_pixels(&self) -> (usize, usize, Vec<Rgb>) {
        match self.grid {
            Grid::LatLong { width, height } => (width, height, self.texels.clone()),
            Grid::Cube { face } => {
                let (w, h) = (4 * face, 3 * face);
                let mut pixels = vec![Rgb::ZERO; w * h];
                for (f, &(cx, cy)) in CROSS_POSITION.iter().enumerate() {
                    for row in 0..face {
                        let src = (f * face + row) * face;
                        let dst = (cy * face + row) * w + cx * face;
                        pixels[dst..dst + face].copy_from_slice(&self.texels[src..src + face]);
                    }
                }
                (w, h, pixels)
            }
        }
    }
}

pub fn describe(grid: Grid) -> String {
    match grid {
        Grid::LatLong { width, height } => format!("{width}x{height} lat-long"),
        Grid::Cube { face } => format!("cube map of 6x{face}x{face}"),
    }
}

fn check_grid(grid: Grid) -> Result<()> {
    let ok = match grid {
        Grid::LatLong { width, height } => width >= 2 && height >= 1,
        Grid::Cube { face } => face >= 1,
    };
    let n = match grid {
        Grid::LatLong { width, height } => width.checked_mul(height),
        Grid::Cube { face } => face.checked_mul(face).and_then(|f| f.checked_mul(6)),
    };
    let too_many = !matches!(n, Some(n) if n <= MAX_TEXELS);
    if !ok || too_many {
        return Err(Error::invalid(format!(
            "environment map: {} must have at least 2x1 (lat-long) or 1x1 (cube face) and at most 2^28 texels",
            describe(grid)
        )));
    }
    Ok(())
}

/// Rejects NaN and infinite components, clamps negative ones to zero; returns the count
/// clamped.
fn sanitize(grid: Grid, texels: &mut [Rgb]) -> Result<usize> {
    if let Some(i) = texels.iter().position(|c| !crate::math::is_finite3(*c)) {
        let bad = texels
            .iter()
            .filter(|c| !crate::math::is_finite3(**c))
            .count();
        return Err(Error::invalid(format!(
            "environment map: texel {} is {} ({bad} texels with NaN or infinite values; the map must be finite)",
            texel_name(grid, i),
            texels[i]
        )));
    }
    let mut clamped = 0;
    for c in texels.iter_mut() {
        for k in 0..3 {
            if c[k] < 0.0 {
                c[k] = 0.0;
                clamped += 1;
            }
        }
    }
    Ok(clamped)
}

fn texel_name(grid: Grid, i: usize) -> String {
    match grid {
        Grid::LatLong { width, .. } => format!("(x {}, y {})", i % width, i / width),
        Grid::Cube { face } => format!(
            "(face {}, x {}, y {})",
            ["+X", "-X", "+Y", "-Y", "+Z", "-Z"][i / (face * face)],
            i % face,
            (i / face) % face
        ),
    }
}

/// Width, height and linear RGB texels of a decoded image.
fn rgb_texels(img: image::DynamicImage) -> (usize, usize, Vec<Rgb>) {
    let img = img.into_rgb32f();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let pixels = img
        .pixels()
        .map(|p| Rgb::new(p.0[0], p.0[1], p.0[2]))
        .collect();
    (w, h, pixels)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_texels_are_rejected_or_clamped() {
        let grid = Grid::LatLong {
            width: 4,
            height: 2,
        };
        let mut t = vec![Rgb::ONE; 8];
        t[5] = Rgb::new(1.0, f32::NAN, 0.0);
        let e = EnvImage::new(grid, t.clone()).unwrap_err().to_string();
        assert!(e.contains("(x 1, y 1)") && e.contains("NaN"), "{e}");
        t[5] = Rgb::new(-1.0, 0.5, -0.1);
        let img = EnvImage::new(grid, t).unwrap();
        assert_eq!(img.clamped(), 2);
        assert_eq!(img.texels()[5], Rgb::new(0.0, 0.5, 0.0));
        assert!(EnvImage::new(grid, vec![Rgb::ONE; 7]).is_err());
        assert!(EnvImage::from_pixels(5, 3, vec![Rgb::ONE; 15]).is_err());
        assert!(EnvImage::from_pixels(0, 0, vec![]).is_err());
    }

    #[test]
    fn cross_round_trip_and_conversion_keeps_power() {
        let face = 8;
        let grid = Grid::Cube { face };
        let texels: Vec<Rgb> = (0..grid.texel_count())
            .map(|i| Rgb::splat((i % 7) as f32 + (i / (face * face)) as f32))
            .collect();
        let img = EnvImage::new(grid, texels).unwrap();
        let (w, h, pixels) = img.to_pixels();
        let back = EnvImage::from_pixels(w, h, pixels).unwrap();
        assert_eq!(back.texels(), img.texels());
        // A smooth map keeps its integral through both conversions.
        let ll = Grid::LatLong {
            width: 64,
            height: 32,
        };
        let smooth: Vec<Rgb> = (0..ll.texel_count())
            .map(|i| {
                let d = ll.texel_point(i, 0.5, 0.5);
                Rgb::splat(1.0 + d.y + 0.5 * d.x * d.x)
            })
            .collect();
        let img = EnvImage::new(ll, smooth).unwrap();
        let cube = img.convert(Grid::Cube { face: 16 }).unwrap();
        let again = cube.convert(ll).unwrap();
        let (a, b, c) = (
            img.luminance_integral(),
            cube.luminance_integral(),
            again.luminance_integral(),
        );
        assert!(
            (a - b).abs() < 0.01 * a && (a - c).abs() < 0.01 * a,
            "{a} {b} {c}"
        );
    }
}
