//! PCG32 (O'Neill 2014): small state, good statistical quality, and cheap to seed per pixel
//! and per sample so that images do not depend on the number of threads.

/// A PCG32 random number generator (XSH-RR output, 64-bit state).
#[derive(Clone, Debug)]
pub struct Rng {
    state: u64,
    inc: u64,
}

const MULT: u64 = 6364136223846793005;

impl Rng {
    /// A generator on stream `stream` started from `seed`. Different streams are independent
    /// sequences, which is how each pixel sample gets its own.
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut rng = Rng {
            state: 0,
            inc: (stream << 1) | 1,
        };
        rng.next_u32();
        rng.state = rng.state.wrapping_add(seed);
        rng.next_u32();
        rng
    }

    /// The generator for one pixel sample: a hash of (seed, pixel, sample index) picks the
    /// stream, so the same sample always sees the same numbers whichever thread runs it.
    pub fn for_sample(seed: u64, pixel_index: u64, sample_index: u64) -> Self {
        let key =
            mix64(seed ^ mix64(pixel_index.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ sample_index));
        Rng::new(mix64(key ^ 0xD1B5_4A32_D192_ED03), key)
    }

    #[inline]
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(MULT).wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }

    /// Uniform float in [0, 1): 24 random mantissa bits, so the result is never 1.
    #[inline]
    pub fn uniform(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    #[inline]
    pub fn uniform2(&mut self) -> glam::Vec2 {
        glam::Vec2::new(self.uniform(), self.uniform())
    }

    /// Uniform integer in [0, n) without modulo bias (Lemire's method).
    pub fn below(&mut self, n: u32) -> u32 {
        assert!(n > 0);
        loop {
            let m = self.next_u32() as u64 * n as u64;
            let low = m as u32;
            if low >= n || low >= n.wrapping_neg() % n {
                return (m >> 32) as u32;
            }
        }
    }
}

/// SplitMix64 finaliser: a bijective 64-bit mixer.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_is_in_unit_interval_with_correct_mean() {
        let mut rng = Rng::new(7, 3);
        let n = 200_000;
        let mut sum = 0.0f64;
        for _ in 0..n {
            let u = rng.uniform();
            assert!((0.0..1.0).contains(&u));
            sum += u as f64;
        }
        assert!((sum / n as f64 - 0.5).abs() < 0.005);
    }

    #[test]
    fn streams_differ_and_are_reproducible() {
        let a: Vec<u32> = (0..4)
            .map({
                let mut r = Rng::for_sample(1, 2, 3);
                move |_| r.next_u32()
            })
            .collect();
        let b: Vec<u32> = (0..4)
            .map({
                let mut r = Rng::for_sample(1, 2, 3);
                move |_| r.next_u32()
            })
            .collect();
        let c: Vec<u32> = (0..4)
            .map({
                let mut r = Rng::for_sample(1, 2, 4);
                move |_| r.next_u32()
            })
            .collect();
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn below_is_in_range() {
        let mut rng = Rng::new(1, 1);
        let mut counts = [0u32; 7];
        for _ in 0..70_000 {
            counts[rng.below(7) as usize] += 1;
        }
        for c in counts {
            assert!((c as i32 - 10_000).abs() < 500, "{counts:?}");
        }
    }
}
