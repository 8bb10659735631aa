//! Writing a film: EXR (float32 radiance, AOVs and layers, with the render's metadata in the
//! header) and PNG (sRGB preview), through [`crate::image_file`].

use std::path::Path;

use exr::prelude as x;

use super::Film;
use crate::error::Result;
use crate::image_file::{write_exr_channels, write_png_rgb, ExrMetadata};
use crate::math::Rgb;

impl Film {
    /// Writes mean radiance as R, G, B (float32), the AOVs as `albedo.*`, `normal.*` and
    /// `depth.Z` channels and the integrator's layers as `NAME.R/G/B`, with `metadata` in the
    /// header.
    pub fn write_exr(&self, path: &Path, metadata: &ExrMetadata) -> Result<()> {
        let (w, h) = (self.width() as usize, self.height() as usize);
        let radiance = self.radiance();
        let albedo = self.albedo();
        let normal = self.normal();
        let depth = self.depth();
        let channel = |name: &str, data: &[Rgb], c: usize| {
            x::AnyChannel::new(
                name,
                x::FlatSamples::F32(data.iter().map(|p| p[c]).collect()),
            )
        };
        let channels: Vec<x::AnyChannel<x::FlatSamples>> = vec![
            channel("R", &radiance, 0),
            channel("G", &radiance, 1),
            channel("B", &radiance, 2),
            channel("albedo.R", &albedo, 0),
            channel("albedo.G", &albedo, 1),
            channel("albedo.B", &albedo, 2),
            channel("normal.X", &normal, 0),
            channel("normal.Y", &normal, 1),
            channel("normal.Z", &normal, 2),
            x::AnyChannel::new("depth.Z", x::FlatSamples::F32(depth)),
        ];
        let mut channels = channels;
        for (index, name) in self.layer_names().iter().enumerate() {
            let pixels = self.layer(index);
            for (c, suffix) in ["R", "G", "B"].iter().enumerate() {
                channels.push(channel(&format!("{name}.{suffix}"), &pixels, c));
            }
        }
        write_exr_channels(path, (w, h), channels, metadata)
    }

    /// Writes an 8-bit sRGB PNG of the radiance scaled by 2^exposure (clamped, no tone curve
    /// beyond the sRGB transfer function).
    pub fn write_png(&self, path: &Path, exposure: f32) -> Result<()> {
        write_png_rgb(
            path,
            self.width(),
            self.height(),
            &self.radiance(),
            exposure,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::film::PixelSample;
    use crate::image_file::read_exr_rgb;

    #[test]
    fn exr_round_trip_keeps_pixels_and_metadata() {
        let mut f = Film::new(3, 2);
        f.add_sample(
            2,
            1,
            &PixelSample {
                radiance: Rgb::new(1.5, 2.5, 1e4),
                ..Default::default()
            },
        );
        let dir = std::env::temp_dir().join(format!("lacuna-exr-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.exr");
        let meta = ExrMetadata::default().with("spp", 16).with("seed", 7);
        f.write_exr(&path, &meta).unwrap();
        let img = read_exr_rgb(&path).unwrap();
        assert_eq!((img.width, img.height), (3, 2));
        assert_eq!(img.pixels[5], Rgb::new(1.5, 2.5, 1e4));
        assert_eq!(img.metadata.get("spp"), Some("16"));
        assert_eq!(img.metadata.get("seed"), Some("7"));
        f.write_png(&dir.join("t.png"), 0.0).unwrap();
        assert!(read_exr_rgb(&dir.join("missing.exr")).is_err());
        std::fs::write(dir.join("bad.exr"), b"not an exr").unwrap();
        assert!(read_exr_rgb(&dir.join("bad.exr")).is_err());
    }

    /// Identical films with identical metadata give identical files. The `exr` crate stores
    /// custom attributes in a `HashMap` with a fresh random hasher per map, so before the
    /// header was sorted, twelve attributes came out in a different order almost every time.
    #[test]
    fn identical_renders_give_identical_exr_files() {
        let mut f = Film::new(4, 3);
        f.add_sample(
            1,
            2,
            &PixelSample {
                radiance: Rgb::new(0.25, 0.5, 2.0),
                ..Default::default()
            },
        );
        let meta = (0..12).fold(ExrMetadata::default(), |m, i| {
            m.with(&format!("key{i}"), i * 7)
        });
        let dir = std::env::temp_dir().join(format!("lacuna-exr-det-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let files: Vec<Vec<u8>> = (0..4)
            .map(|i| {
                let path = dir.join(format!("{i}.exr"));
                f.write_exr(&path, &meta).unwrap();
                std::fs::read(&path).unwrap()
            })
            .collect();
        for other in &files[1..] {
            assert!(
                other == &files[0],
                "EXR bytes differ between identical writes"
            );
        }
        // Still a valid file with every attribute, and the header really is sorted.
        let img = read_exr_rgb(&dir.join("0.exr")).unwrap();
        assert_eq!(img.metadata.entries.len(), 12);
        assert_eq!(img.metadata.get("key11"), Some("77"));
        assert_eq!(img.pixels[2 * 4 + 1], Rgb::new(0.25, 0.5, 2.0));
        let header = String::from_utf8_lossy(&files[0]);
        let keys: Vec<usize> = (0..12)
            .map(|i| header.find(&format!("lacuna:key{i}\0")).unwrap())
            .collect();
        let order = [0, 1, 10, 11, 2, 3, 4, 5, 6, 7, 8, 9]; // byte order of the names
        assert!(
            order.windows(2).all(|w| keys[w[0]] < keys[w[1]]),
            "{keys:?}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
