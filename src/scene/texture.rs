//! Diffuse colour textures (`map_Kd`): stored as linear RGB floats, looked up bilinearly with
//! wrapping.

use crate::error::{Error, Result};
use crate::math::{Rgb, Vec2};
use std::path::Path;

#[derive(Clone, Debug)]
pub struct Texture {
    pub width: u32,
    pub height: u32,
    /// Row-major, row 0 at the top of the image, linear RGB.
    pub texels: Vec<Rgb>,
}

/// sRGB transfer function to linear.
#[inline]
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

impl Texture {
    /// A texture from linear RGB texels; checks the size and that values are finite and >= 0.
    pub fn new(width: u32, height: u32, texels: Vec<Rgb>) -> Result<Self> {
        if width == 0 || height == 0 || texels.len() != width as usize * height as usize {
            return Err(Error::invalid(format!(
                "texture of {width}x{height} needs {} texels, got {}",
                width as usize * height as usize,
                texels.len()
            )));
        }
        if let Some(i) = texels
            .iter()
            .position(|t| !crate::math::is_finite3(*t) || t.min_element() < 0.0)
        {
            return Err(Error::invalid(format!(
                "texel {i} is {} (must be finite and >= 0)",
                texels[i]
            )));
        }
        Ok(Texture {
            width,
            height,
            texels,
        })
    }

    /// Loads an 8-bit PNG or JPEG file, decoding sRGB to linear.
    pub fn load(path: &Path) -> Result<Self> {
        // Decoded 8-bit image (at most 4 channels), its RGB copy and the linear texels.
        let reader = crate::limits::open_image_checked(
            path,
            "texture",
            crate::limits::MAX_TEXTURE_PIXELS,
            4 + 3 + 12,
            crate::limits::DEFAULT_MEMORY_BUDGET,
        )?;
        let img = reader.decode().map_err(|e| match e {
            image::ImageError::IoError(io) => Error::io(path, io),
            other => Error::parse(path, "", other.to_string()),
        })?;
        let rgb = img.to_rgb8();
        let lut: Vec<f32> = (0..256).map(|v| srgb_to_linear(v as f32 / 255.0)).collect();
        let texels = rgb
            .pixels()
            .map(|p| Rgb::new(lut[p[0] as usize], lut[p[1] as usize], lut[p[2] as usize]))
            .collect();
        Texture::new(rgb.width(), rgb.height(), texels)
    }

    /// Bilinear lookup; uv (0, 0) is the bottom-left corner, as in OBJ files; wraps.
    pub fn lookup(&self, uv: Vec2) -> Rgb {
        let (w, h) = (self.width as i64, self.height as i64);
        let x = uv.x * w as f32 - 0.5;
        let y = (1.0 - uv.y) * h as f32 - 0.5;
        if !x.is_finite() || !y.is_finite() {
            return self.texels[0];
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let at = |i: i64, j: i64| self.texels[(j.rem_euclid(h) * w + i.rem_euclid(w)) as usize];
        let (x0, y0) = (x0 as i64, y0 as i64);
        (at(x0, y0) * (1.0 - fx) + at(x0 + 1, y0) * fx) * (1.0 - fy)
            + (at(x0, y0 + 1) * (1.0 - fx) + at(x0 + 1, y0 + 1) * fx) * fy
    }

    pub fn memory_bytes(&self) -> usize {
        self.texels.len() * std::mem::size_of::<Rgb>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookup_wraps_and_interpolates() {
        let t = Texture::new(2, 1, vec![Rgb::ZERO, Rgb::ONE]).unwrap();
        assert_eq!(t.lookup(Vec2::new(0.25, 0.5)), Rgb::ZERO);
        assert_eq!(t.lookup(Vec2::new(0.75, 0.5)), Rgb::ONE);
        assert!((t.lookup(Vec2::new(0.5, 0.5)) - Rgb::splat(0.5)).length() < 1e-6);
        assert_eq!(t.lookup(Vec2::new(1.25, 3.5)), Rgb::ZERO);
        assert!(Texture::new(2, 2, vec![Rgb::ZERO]).is_err());
        assert!(Texture::new(1, 1, vec![Rgb::splat(f32::NAN)]).is_err());
    }
}
