//! Per-pixel-sample random numbers: either independent PCG32 numbers ([`Rng`]) or
//! Owen-scrambled Sobol points in the manner of Burley, "Practical Hash-based Owen Scrambling"
//! (JCGT 2020), which stratify each pixel's samples and so lower the error at equal sample
//! counts while staying unbiased.
//!
//! The Sobol sampler is *padded* 2-D: every dimension slot `d` (a 1-D or 2-D request) draws
//! from its own copy of the first two Sobol dimensions, the (0,2)-sequence, with
//! - its own shuffle of the sample index (a nested uniform scramble of the index's bits, low
//!   digits scrambled under the high ones), so that slots of one sample are decorrelated and
//!   yet the first `2^m` samples of a pixel still use one aligned block of `2^m` Sobol indices,
//!   i.e. a (0,m,2)-net;
//! - its own nested uniform (Owen) scramble of the point, which keeps the net property and
//!   makes every point uniform on [0,1)^2 (so estimates are unbiased);
//!
//! all keyed by a hash of (seed, pixel, slot), so the numbers depend only on (seed, pixel,
//! sample index, slot): any thread count and any split into passes gives the same image.
//! Integrators that consume slots in a fixed layout ([`Sampler::set_dimension`]) get each slot
//! stratified over the pixel's samples; any other use still gets uniform, independent-looking
//! numbers, one fresh slot per request.

use super::{mix64, Rng};
use crate::error::{Error, Result};
use glam::Vec2;

/// Dimension slot of the position in the pixel (2-D), drawn by the camera.
pub const FILM_DIMENSION: u32 = 0;
/// Dimension slot of the position on the lens (2-D), drawn by the camera.
pub const LENS_DIMENSION: u32 = 1;
/// The first slot an integrator's `Integrator::sample` sees: the camera's slots come first.
pub const FIRST_INTEGRATOR_DIMENSION: u32 = 2;

/// Which numbers pixel samples draw.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SamplerKind {
    /// Owen-scrambled Sobol (0,2)-sequence pairs, one per dimension slot: lower error per
    /// sample, and 1.8x less time to `path`'s error on the Cornell box (BENCHMARKS.md). The default.
    #[default]
    Sobol,
    /// Independent PCG32 numbers per pixel sample.
    Independent,
}

impl SamplerKind {
    pub const NAMES: &'static [&'static str] = &["sobol", "independent"];

    pub fn parse(name: &str) -> Result<Self> {
        match name {
            "sobol" => Ok(SamplerKind::Sobol),
            "independent" => Ok(SamplerKind::Independent),
            other => Err(Error::invalid(format!(
                "unknown sampler '{other}' (expected sobol or independent)"
            ))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            SamplerKind::Sobol => "sobol",
            SamplerKind::Independent => "independent",
        }
    }
}

/// The numbers of one pixel sample. `uniform`, `uniform2` and `below` each take the next
/// dimension slot; `set_dimension` moves to a given slot (a no-op for independent numbers,
/// which have no slots).
#[derive(Clone, Debug)]
pub struct Sampler {
    sequence: Sequence,
}

/// Where a sampler's numbers come from: a PCG stream, or the Sobol sequence at one sample.
#[derive(Clone, Debug)]
enum Sequence {
    Independent(Rng),
    Sobol {
        /// Hash of (seed, pixel): the key of every slot's shuffle and scrambles.
        pixel_key: u64,
        /// The sample index with its bits reversed, as the shuffle takes it (once per sample
        /// rather than once per request: bit reversal is a dozen instructions on x86-64).
        reversed_index: u32,
        dimension: u32,
    },
}

/// Domain separator of the Sobol sampler's pixel keys (so they differ from PCG streams).
const SOBOL_DOMAIN: u64 = 0x5B0B_A11E_D5EE_D000;

/// What the samples of one pixel share: the render loop makes one per pixel and asks it for
/// each sample's [`Sampler`], so the pixel's hash is computed once rather than per sample.
#[derive(Clone, Copy, Debug)]
pub struct PixelSampler {
    kind: SamplerKind,
    seed: u64,
    pixel_index: u64,
    /// Sobol: hash of (seed, pixel), the key of every slot's shuffle and scrambles.
    pixel_key: u64,
}

impl PixelSampler {
    /// The samples of pixel `pixel_index` (row-major) for `seed`.
    #[inline]
    pub fn new(kind: SamplerKind, seed: u64, pixel_index: u64) -> Self {
        let pixel_key = match kind {
            SamplerKind::Independent => 0,
            SamplerKind::Sobol => {
                mix64(mix64(seed ^ SOBOL_DOMAIN) ^ pixel_index.wrapping_mul(0x9E37_79B9_7F4A_7C15))
            }
        };
        PixelSampler {
            kind,
            seed,
            pixel_index,
            pixel_key,
        }
    }

    /// The numbers of sample `sample_index` of this pixel (those of [`Sampler::new`]).
    #[inline]
    pub fn sample(&self, sample_index: u32) -> Sampler {
        match self.kind {
            SamplerKind::Independent => Sampler::independent(Rng::for_sample(
                self.seed,
                self.pixel_index,
                sample_index as u64,
            )),
            SamplerKind::Sobol => Sampler {
                sequence: Sequence::Sobol {
                    pixel_key: self.pixel_key,
                    reversed_index: sample_index.reverse_bits(),
                    dimension: 0,
                },
            },
        }
    }
}

impl Sampler {
    /// The numbers of sample `sample_index` of pixel `pixel_index` (row-major) for `seed`.
    /// `Independent` gives exactly the numbers of [`Rng::for_sample`].
    pub fn new(kind: SamplerKind, seed: u64, pixel_index: u64, sample_index: u32) -> Self {
        PixelSampler::new(kind, seed, pixel_index).sample(sample_index)
    }

    /// Independent numbers from `rng` (for paths not tied to a pixel sample, such as light
    /// subpaths).
    pub fn independent(rng: Rng) -> Self {
        Sampler {
            sequence: Sequence::Independent(rng),
        }
    }

    /// The next request takes slot `dimension`. Integrators give each use of a number a fixed
    /// slot (camera, then per bounce BSDF, light, roulette ...), so that a slot means the same
    /// thing in every sample of a pixel and its stratification helps that one integral.
    #[inline]
    pub fn set_dimension(&mut self, dimension: u32) {
        if let Sequence::Sobol { dimension: d, .. } = &mut self.sequence {
            *d = dimension;
        }
    }

    /// Passes over the request [`Sampler::uniform`] would answer, without computing it: for
    /// numbers a caller does not need (a Lambertian BSDF's component choice, a pinhole
    /// camera's lens position). Every later request gets what it would have got had the
    /// number been drawn, so skipping changes no image.
    #[inline]
    pub fn skip_uniform(&mut self) {
        match &mut self.sequence {
            Sequence::Independent(rng) => {
                rng.next_u32();
            }
            Sequence::Sobol { dimension, .. } => *dimension += 1,
        }
    }

    /// Passes over the request [`Sampler::uniform2`] would answer (see [`Sampler::skip_uniform`]).
    #[inline]
    pub fn skip_uniform2(&mut self) {
        match &mut self.sequence {
            Sequence::Independent(rng) => {
                rng.next_u32();
                rng.next_u32();
            }
            Sequence::Sobol { dimension, .. } => *dimension += 1,
        }
    }

    /// Uniform float in [0, 1).
    #[inline]
    pub fn uniform(&mut self) -> f32 {
        match &mut self.sequence {
            Sequence::Independent(rng) => rng.uniform(),
            Sequence::Sobol { .. } => to_unit(self.uniform_bits()),
        }
    }

    /// Uniform point in [0, 1)^2; with Sobol, a (0,2)-sequence pair stratified over the
    /// pixel's samples.
    #[inline(always)]
    pub fn uniform2(&mut self) -> Vec2 {
        match &mut self.sequence {
            Sequence::Independent(rng) => rng.uniform2(),
            Sequence::Sobol {
                pixel_key,
                reversed_index,
                dimension,
            } => {
                let keys = slot_keys(*pixel_key, *dimension);
                *dimension += 1;
                let (x, y) = sobol_owen_pair(*reversed_index, keys);
                Vec2::new(to_unit(x), to_unit(y))
            }
        }
    }

    /// Uniform integer in [0, n).
    pub fn below(&mut self, n: u32) -> u32 {
        assert!(n > 0);
        match &mut self.sequence {
            Sequence::Independent(rng) => rng.below(n),
            // 32 scrambled bits times n: a bias below n / 2^32, stratified like `uniform`.
            Sequence::Sobol { .. } => {
                let u = self.uniform_bits();
                ((u as u64 * n as u64) >> 32) as u32
            }
        }
    }

    /// 32 bits of the next 1-D slot (Sobol only).
    #[inline]
    fn uniform_bits(&mut self) -> u32 {
        match &mut self.sequence {
            Sequence::Independent(rng) => rng.next_u32(),
            Sequence::Sobol {
                pixel_key,
                reversed_index,
                dimension,
            } => {
                let keys = slot_keys(*pixel_key, *dimension);
                *dimension += 1;
                sobol_owen_1d(*reversed_index, keys)
            }
        }
    }
}

/// The three 32-bit keys of one dimension slot: index shuffle, x and y scrambles.
#[derive(Clone, Copy, Debug)]
struct SlotKeys {
    shuffle: u32,
    x: u32,
    y: u32,
}

#[inline]
fn slot_keys(pixel_key: u64, dimension: u32) -> SlotKeys {
    let h = mix64(pixel_key ^ (dimension as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
    SlotKeys {
        shuffle: h as u32,
        x: (h >> 32) as u32,
        // The high half of another odd multiple of the well-mixed h: a third key for the
        // price of one multiplication.
        y: (h.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32) as u32,
    }
}

/// Value of a 1-D request: Sobol dimension 0 (van der Corput) of the shuffled index,
/// Owen-scrambled, as a 32-bit fraction. `reversed_index` is the sample index bit-reversed.
#[inline]
fn sobol_owen_1d(reversed_index: u32, keys: SlotKeys) -> u32 {
    let index = shuffle_reversed_index(reversed_index, keys.shuffle);
    // Van der Corput's fraction bits are the index's bits reversed, so in reversed (least
    // significant digit first) form the point is the index itself.
    owen_scramble_reversed(index, keys.x).reverse_bits()
}

/// Point of a 2-D request: Sobol dimensions 0 and 1 of the shuffled index, each
/// Owen-scrambled with its own key, as 32-bit fractions.
#[inline]
fn sobol_owen_pair(reversed_index: u32, keys: SlotKeys) -> (u32, u32) {
    let index = shuffle_reversed_index(reversed_index, keys.shuffle);
    let x = owen_scramble_reversed(index, keys.x);
    let y = owen_scramble_reversed(sobol1_reversed(index), keys.y);
    // Both back to fraction order with one 64-bit reversal (which also swaps the halves).
    let both = ((y as u64) | ((x as u64) << 32)).reverse_bits();
    (both as u32, (both >> 32) as u32)
}

/// Shuffles sample indices (given bit-reversed): a nested uniform scramble of the index where
/// each bit is flipped by a hash of the bits *above* it. The first `2^m` indices go to `2^m`
/// indices sharing their high bits (one aligned block), so a pixel's first `2^m` samples remain
/// a (0,m,2)-net whatever the key, while different keys give different orders (decorrelating
/// slots).
#[inline]
fn shuffle_reversed_index(reversed_index: u32, key: u32) -> u32 {
    laine_karras(reversed_index, key).reverse_bits()
}

/// Owen scrambling of a fraction given in reversed form (bit 0 = the first binary digit
/// after the point); returns the scrambled fraction, still reversed.
#[inline]
fn owen_scramble_reversed(reversed_fraction: u32, key: u32) -> u32 {
    laine_karras(reversed_fraction, key)
}

/// A keyed bijection of u32 in which output bit k is input bit k flipped by a function of the
/// input bits below k and the key: a nested uniform scramble of digits in least-significant-
/// first order (Laine and Karras 2011). Every step has that property (adding the key;
/// `x ^= x * even`, whose bit k sees only bits below k; `x *= odd`, i.e. `x += x * even`).
/// The steps and multipliers are Nathan Vegdahl's improved hash (2021), which scrambles the
/// high bits better than Burley's original four xor-multiplies.
#[inline]
fn laine_karras(mut x: u32, key: u32) -> u32 {
    x ^= x.wrapping_mul(0x3D20_ADEA);
    x = x.wrapping_add(key);
    x = x.wrapping_mul((key >> 16) | 1);
    x ^= x.wrapping_mul(0x0552_6C56);
    x ^= x.wrapping_mul(0x53A2_2864);
    x
}

/// Sobol dimension 1 of `index`, in reversed form (bit j = the (j+1)-th binary digit). Its
/// generator matrix is Pascal's triangle mod 2: digit j is the xor of the index bits k with
/// C(k, j) odd, i.e. (Lucas) with j's bits a subset of k's. That superset xor over the five
/// bit positions of k is five shift-and-mask steps.
#[inline]
fn sobol1_reversed(index: u32) -> u32 {
    let mut v = index;
    v ^= (v >> 1) & 0x5555_5555;
    v ^= (v >> 2) & 0x3333_3333;
    v ^= (v >> 4) & 0x0F0F_0F0F;
    v ^= (v >> 8) & 0x00FF_00FF;
    v ^= (v >> 16) & 0x0000_FFFF;
    v
}

/// Top 24 bits of a 32-bit fraction as a float in [0, 1) (exact, never 1).
#[inline]
fn to_unit(fraction: u32) -> f32 {
    (fraction >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sobol dimension 1 by its direction numbers v_1 = 1/2, v_k = v_{k-1} ^ (v_{k-1} / 2).
    fn sobol1_by_direction_numbers(index: u32) -> u32 {
        let mut v = 1u32 << 31;
        let mut out = 0;
        for k in 0..32 {
            if index >> k & 1 == 1 {
                out ^= v;
            }
            v ^= v >> 1;
        }
        out
    }

    #[test]
    fn sobol_dimension_one_matches_its_direction_numbers() {
        let mut rng = Rng::new(3, 1);
        for i in (0..4096).chain((0..4096).map(|_| rng.next_u32())) {
            assert_eq!(
                sobol1_reversed(i).reverse_bits(),
                sobol1_by_direction_numbers(i)
            );
        }
    }

    #[test]
    fn laine_karras_is_a_nested_scramble() {
        // Bit k of the output may depend only on bits 0..=k of the input: changing bits above
        // k must leave bits 0..=k alone.
        let mut rng = Rng::new(5, 2);
        for _ in 0..2000 {
            let (x, key, k) = (rng.next_u32(), rng.next_u32(), rng.below(31));
            let low = (2u32 << k) - 1;
            let y = x ^ (rng.next_u32() & !low);
            assert_eq!(laine_karras(x, key) & low, laine_karras(y, key) & low);
        }
    }

    #[test]
    fn shuffled_prefixes_are_aligned_blocks() {
        let mut rng = Rng::new(8, 3);
        for m in 0..12 {
            let key = rng.next_u32();
            let mut got: Vec<u32> = (0..1u32 << m)
                .map(|i| shuffle_reversed_index(i.reverse_bits(), key))
                .collect();
            got.sort_unstable();
            let base = got[0];
            assert_eq!(base % (1 << m), 0, "m {m}");
            assert!(got.iter().enumerate().all(|(j, &g)| g == base + j as u32));
        }
    }

    #[test]
    fn independent_matches_the_per_sample_rng() {
        let mut a = Sampler::new(SamplerKind::Independent, 4, 77, 9);
        let mut b = Rng::for_sample(4, 77, 9);
        for _ in 0..8 {
            a.set_dimension(3);
            assert_eq!(a.uniform(), b.uniform());
            assert_eq!(a.uniform2(), b.uniform2());
        }
    }

    #[test]
    fn slots_are_addressable_in_any_order() {
        let mut a = Sampler::new(SamplerKind::Sobol, 1, 2, 3);
        let seq: Vec<f32> = (0..6).map(|_| a.uniform()).collect();
        let mut b = Sampler::new(SamplerKind::Sobol, 1, 2, 3);
        for d in (0..6).rev() {
            b.set_dimension(d);
            assert_eq!(b.uniform(), seq[d as usize]);
        }
    }

    #[test]
    fn skipping_a_request_leaves_the_later_ones_alone() {
        for kind in [SamplerKind::Sobol, SamplerKind::Independent] {
            let mut drawn = Sampler::new(kind, 6, 41, 5);
            let mut skipped = Sampler::new(kind, 6, 41, 5);
            for round in 0..4 {
                if round % 2 == 0 {
                    drawn.uniform();
                    skipped.skip_uniform();
                } else {
                    drawn.uniform2();
                    skipped.skip_uniform2();
                }
                assert_eq!(drawn.uniform2(), skipped.uniform2(), "{kind:?}");
                assert_eq!(drawn.uniform(), skipped.uniform(), "{kind:?}");
            }
        }
    }

    #[test]
    fn pixel_samplers_give_the_numbers_of_sampler_new() {
        for kind in [SamplerKind::Sobol, SamplerKind::Independent] {
            let pixel = PixelSampler::new(kind, 9, 1234);
            for index in [0, 1, 7, 1000] {
                let (mut a, mut b) = (pixel.sample(index), Sampler::new(kind, 9, 1234, index));
                for _ in 0..5 {
                    assert_eq!(a.uniform2(), b.uniform2());
                    assert_eq!(a.uniform(), b.uniform());
                }
            }
        }
    }

    #[test]
    fn kinds_parse_and_name() {
        for &n in SamplerKind::NAMES {
            assert_eq!(SamplerKind::parse(n).unwrap().name(), n);
        }
        assert!(SamplerKind::parse("halton").is_err());
    }
}
