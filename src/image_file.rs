//! RGB image files: EXR (float32, with a render's `lacuna:*` metadata in the header) and
//! 8-bit sRGB PNG. Reading is bounded by the memory budget of [`crate::limits`], so that an
//! environment map, a reference image or a film all go through one guarded reader. Below the
//! film and the lights in the layers: both use it, neither through the other.

use std::collections::HashMap;
use std::path::Path;

use exr::prelude::{self as x, AttributeValue, ReadChannels, ReadLayers, Text, WritableImage};

use crate::error::{Error, Result};
use crate::math::Rgb;

/// Facts about a render stored in an EXR header (as `lacuna:*` string attributes).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExrMetadata {
    pub entries: Vec<(String, String)>,
}

impl ExrMetadata {
    pub fn with(mut self, key: &str, value: impl ToString) -> Self {
        self.entries.push((key.to_string(), value.to_string()));
        self
    }

    pub fn get(&self, key: &str) -> Option<&str> {
        self.entries
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
}

/// An RGB float image read from an EXR file.
#[derive(Clone, Debug)]
pub struct ExrImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<Rgb>,
    pub metadata: ExrMetadata,
}

const PREFIX: &str = "lacuna:";

/// Writes linear RGB pixels (row-major) as a float32 R, G, B EXR with `metadata` in the header.
pub fn write_exr_rgb(
    path: &Path,
    width: u32,
    height: u32,
    pixels: &[Rgb],
    metadata: &ExrMetadata,
) -> Result<()> {
    let channel = |name: &str, c: usize| {
        x::AnyChannel::new(
            name,
            x::FlatSamples::F32(pixels.iter().map(|p| p[c]).collect()),
        )
    };
    let channels = vec![channel("R", 0), channel("G", 1), channel("B", 2)];
    write_exr_channels(path, (width as usize, height as usize), channels, metadata)
}

pub(crate) fn write_exr_channels(
    path: &Path,
    size: (usize, usize),
    channels: Vec<x::AnyChannel<x::FlatSamples>>,
    metadata: &ExrMetadata,
) -> Result<()> {
    let mut attributes = x::LayerAttributes {
        software_name: Some(Text::from(concat!("Lacuna ", env!("CARGO_PKG_VERSION")))),
        ..Default::default()
    };
    // A HashMap because `exr` wants one: `sort_header_attributes` fixes the order on disk.
    let mut other = HashMap::new();
    for (k, v) in &metadata.entries {
        let key = format!("{PREFIX}{k}");
        other.insert(
            Text::new_or_none(&key)
                .ok_or_else(|| Error::invalid(format!("EXR attribute name {key}")))?,
            text(v)?,
        );
    }
    attributes.other = other;
    let layer = x::Layer::new(
        size,
        attributes,
        x::Encoding::FAST_LOSSLESS,
        x::AnyChannels::sort(x::SmallVec::from_vec(channels)),
    );
    let mut bytes = Vec::new();
    x::Image::from_layer(layer)
        .write()
        .to_buffered(std::io::Cursor::new(&mut bytes))
        .map_err(|e| exr_error(path, e))?;
    sort_header_attributes(&mut bytes)
        .ok_or_else(|| Error::invalid("the EXR encoder wrote a header Lacuna cannot parse"))?;
    std::fs::write(path, &bytes).map_err(|e| Error::io(path, e))
}

/// Sorts the attributes of a single-part EXR header by name, in place.
///
/// Why: the `exr` crate keeps custom attributes in a `HashMap` with a random per-map hasher
/// and writes them in its iteration order, so two identical renders gave files that differed
/// byte for byte. The EXR format leaves attribute order free, and sorting only permutes the
/// header's bytes: its length, and so every chunk offset after it, stays the same.
/// Returns `None` when `bytes` is not a header this parser understands (left untouched).
fn sort_header_attributes(bytes: &mut [u8]) -> Option<()> {
    const MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];
    const MULTIPART: u8 = 0x10;
    if bytes.len() < 8 || bytes[..4] != MAGIC || bytes[5] & MULTIPART != 0 {
        return None;
    }
    let start = 8;
    let mut attributes: Vec<std::ops::Range<usize>> = Vec::new();
    let mut pos = start;
    // Each attribute: name NUL, type name NUL, i32 little-endian size, value. A NUL ends the list.
    while *bytes.get(pos)? != 0 {
        let begin = pos;
        let name_end = pos + bytes[pos..].iter().position(|&b| b == 0)?;
        let type_end = name_end + 1 + bytes[name_end + 1..].iter().position(|&b| b == 0)?;
        let size_at = type_end + 1;
        let size = i32::from_le_bytes(bytes.get(size_at..size_at + 4)?.try_into().ok()?);
        pos = size_at + 4 + usize::try_from(size).ok()?;
        if pos > bytes.len() {
            return None;
        }
        attributes.push(begin..pos);
    }
    let name = |r: &std::ops::Range<usize>| {
        let b = &bytes[r.clone()];
        &b[..b.iter().position(|&c| c == 0).unwrap_or(b.len())]
    };
    let mut sorted = attributes.clone();
    sorted.sort_by(|a, b| name(a).cmp(name(b)));
    let header: Vec<u8> = sorted
        .iter()
        .flat_map(|r| bytes[r.clone()].iter().copied())
        .collect();
    bytes[start..pos].copy_from_slice(&header);
    Some(())
}

/// Writes linear RGB pixels as an 8-bit sRGB PNG.
pub fn write_png_rgb(
    path: &Path,
    width: u32,
    height: u32,
    pixels: &[Rgb],
    exposure: f32,
) -> Result<()> {
    let scale = 2f32.powf(exposure);
    let bytes: Vec<u8> = pixels
        .iter()
        .flat_map(|p| {
            let v = *p * scale;
            [encode_srgb(v.x), encode_srgb(v.y), encode_srgb(v.z)]
        })
        .collect();
    image::save_buffer(path, &bytes, width, height, image::ColorType::Rgb8).map_err(|e| match e {
        image::ImageError::IoError(io) => Error::io(path, io),
        other => Error::invalid(format!("{}: {other}", path.display())),
    })
}

/// Linear value to an 8-bit sRGB code (NaN maps to 0).
pub fn encode_srgb(v: f32) -> u8 {
    let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
    let s = if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

/// EXR text is Latin-1: other characters (a file name that is not UTF-8 shows U+FFFD, or any
/// non-Latin script) are written as '?', so that a finished render is never lost to its label.
fn text(v: &str) -> Result<AttributeValue> {
    let latin1: String = v
        .chars()
        .map(|c| if (c as u32) < 256 { c } else { '?' })
        .collect();
    Text::new_or_none(&latin1)
        .map(AttributeValue::Text)
        .ok_or_else(|| Error::invalid(format!("EXR attribute value '{v}' is not storable")))
}

fn exr_error(path: &Path, e: exr::error::Error) -> Error {
    match e {
        exr::error::Error::Io(io) => Error::io(path, io),
        other => Error::parse(path, "", other.to_string()),
    }
}

/// Reads the R, G, B channels (any sample type) of the first layer of an EXR file, with the
/// `lacuna:*` attributes Lacuna wrote.
pub fn read_exr_rgb(path: &Path) -> Result<ExrImage> {
    read_exr_rgb_within(
        path,
        crate::limits::effective_memory_budget(crate::limits::DEFAULT_MEMORY_BUDGET),
    )
}

/// [`read_exr_rgb`] refusing, from the headers alone and before any pixel is decoded, a file
/// whose layers would need more than `budget` bytes or more than
/// [`crate::limits::MAX_ENV_TEXELS`] pixels (a 74-byte header can claim terapixels).
pub fn read_exr_rgb_within(path: &Path, budget: u64) -> Result<ExrImage> {
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| exr_error(path, e))?;
    let mut bytes = 0u64;
    for header in meta.headers.iter() {
        let (w, h) = (header.layer_size.width(), header.layer_size.height());
        let pixels = w as u64 * h as u64;
        let limit = crate::limits::MAX_ENV_TEXELS as u64;
        if pixels > limit {
            return Err(Error::parse(
                path,
                "header",
                format!("a {w}x{h} layer is over the limit of {limit} pixels"),
            ));
        }
        // Decoded channels as stored (at most 4 bytes a sample), their f32 copies and the RGB
        // result.
        let per_pixel = 4 * header.channels.list.len() as u64 + 12 + 12;
        bytes = bytes.saturating_add(pixels.saturating_mul(per_pixel));
        // The reader allocates each block at the size its header allows before reading it (a
        // tile header can claim tiles far larger than the image): count a block twice, as
        // read and as decompressed.
        let block_pixels = match header.blocks {
            exr::meta::BlockDescription::Tiles(tiles) => {
                tiles.tile_size.width() as u64 * tiles.tile_size.height() as u64
            }
            exr::meta::BlockDescription::ScanLines => {
                header.compression.scan_lines_per_block() as u64 * w as u64
            }
        };
        let block_bytes = block_pixels.saturating_mul(header.channels.bytes_per_pixel as u64);
        bytes = bytes.saturating_add(block_bytes.saturating_mul(2));
    }
    crate::limits::check_bytes(|| format!("EXR image {}", path.display()), bytes, budget)?;
    let image = x::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| exr_error(path, e))?;
    let layer = &image.layer_data;
    let (w, h) = (layer.size.width(), layer.size.height());
    let find = |name: &str| {
        layer
            .channel_data
            .list
            .iter()
            .find(|c| c.name.to_string() == name)
            .map(|c| c.sample_data.values_as_f32().collect::<Vec<f32>>())
            .ok_or_else(|| Error::parse(path, "", format!("no channel {name}")))
    };
    let (r, g, b) = (find("R")?, find("G")?, find("B")?);
    let pixels = (0..w * h).map(|i| Rgb::new(r[i], g[i], b[i])).collect();
    let mut metadata = ExrMetadata::default();
    let mut entries: Vec<(String, String)> = layer
        .attributes
        .other
        .iter()
        .filter_map(|(k, v)| {
            let k = k.to_string();
            match (k.strip_prefix(PREFIX), v) {
                (Some(key), AttributeValue::Text(t)) => Some((key.to_string(), t.to_string())),
                _ => None,
            }
        })
        .collect();
    entries.sort();
    metadata.entries = entries;
    Ok(ExrImage {
        width: w as u32,
        height: h as u32,
        pixels,
        metadata,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Header sorting refuses what it cannot parse instead of scrambling it.
    #[test]
    fn header_sorting_rejects_malformed_input() {
        let mut not_exr = b"not an exr file".to_vec();
        assert!(sort_header_attributes(&mut not_exr).is_none());
        let mut truncated = vec![
            0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0, b'a', 0, b'i', b'n', b't', 0, 9,
        ];
        assert!(sort_header_attributes(&mut truncated).is_none());
        let mut huge = vec![
            0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0, b'a', 0, b'i', 0, 100, 0, 0, 0, 0,
        ];
        assert!(sort_header_attributes(&mut huge).is_none());
        let mut two = vec![0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0];
        two.extend_from_slice(b"b\0t\0\x01\0\0\0Ba\0t\0\x01\0\0\0A\0");
        sort_header_attributes(&mut two).unwrap();
        assert_eq!(&two[8..], b"a\0t\0\x01\0\0\0Ab\0t\0\x01\0\0\0B\0");
    }

    #[test]
    fn srgb_encoding_is_clamped_and_monotone() {
        assert_eq!(encode_srgb(0.0), 0);
        assert_eq!(encode_srgb(1.0), 255);
        assert_eq!(encode_srgb(7.0), 255);
        assert_eq!(encode_srgb(f32::NAN), 0);
        assert_eq!(encode_srgb(0.5), 188);
    }
}
