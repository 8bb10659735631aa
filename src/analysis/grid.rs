//! The voxel grid over a scene: dimensions, the world-to-grid transform, and a dense bit set of
//! occupied voxels.

use std::sync::atomic::{AtomicU64, Ordering};

use crate::error::{Error, Result};
use crate::geometry::Bounds3;
use crate::math::Vec3;

/// How the resolution of a grid is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Resolution {
    /// Cubic voxels of this edge length (world units).
    VoxelSize(f64),
    /// This many voxels along the longest axis of the (padded) bounds.
    LongestAxis(u32),
    /// At most this many voxels in total.
    VoxelBudget(u64),
}

/// A regular grid of cubic voxels. Voxel (x, y, z) spans
/// `origin + size * [x, x+1] x [y, y+1] x [z, z+1]`; index = x + nx (y + ny z).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VoxelGrid {
    pub dims: [usize; 3],
    pub origin: [f64; 3],
    pub voxel_size: f64,
}

impl VoxelGrid {
    /// A grid covering `bounds` plus `padding` voxels on every side.
    pub fn new(bounds: Bounds3, resolution: Resolution, padding: u32) -> Result<Self> {
        if bounds.is_empty() || !bounds.min.is_finite() || !bounds.max.is_finite() {
            return Err(Error::invalid(
                "cannot build a voxel grid over empty or non-finite bounds",
            ));
        }
        let ext = bounds.diagonal().as_dvec3();
        let longest = ext.max_element().max(1e-30);
        let pad = padding as f64;
        let size = match resolution {
            Resolution::VoxelSize(s) => {
                if !(s > 0.0 && s.is_finite()) {
                    return Err(Error::invalid(format!("voxel size {s} must be positive")));
                }
                s
            }
            Resolution::LongestAxis(n) => {
                if n == 0 {
                    return Err(Error::invalid(
                        "longest-axis voxel count must be at least 1",
                    ));
                }
                longest / n as f64
            }
            Resolution::VoxelBudget(b) => {
                if b == 0 {
                    return Err(Error::invalid("voxel budget must be at least 1"));
                }
                // Largest size whose padded grid fits: solve prod(ext/s + 2 pad) <= b by bisection.
                let count = |s: f64| {
                    (0..3)
                        .map(|i| (ext[i] / s).ceil().max(1.0) + 2.0 * pad)
                        .product::<f64>()
                };
                let (mut lo, mut hi) = (longest * 1e-6, longest * 2.0);
                for _ in 0..100 {
                    let mid = (lo * hi).sqrt();
                    if count(mid) > b as f64 {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                hi
            }
        };
        let mut dims = [0usize; 3];
        let mut origin = [0.0f64; 3];
        for i in 0..3 {
            let n = (ext[i] / size).ceil().max(1.0);
            // Centre the scene inside its voxels, then pad.
            let slack = n * size - ext[i];
            origin[i] = bounds.min[i] as f64 - 0.5 * slack - pad * size;
            let total = n + 2.0 * pad;
            if total > (1u64 << 31) as f64 {
                return Err(Error::invalid(format!(
                    "voxel grid axis {i} would have {total} voxels"
                )));
            }
            dims[i] = total as usize;
        }
        Ok(VoxelGrid {
            dims,
            origin,
            voxel_size: size,
        })
    }

    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    #[inline]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        x + self.dims[0] * (y + self.dims[1] * z)
    }

    #[inline]
    pub fn coords(&self, index: usize) -> [usize; 3] {
        let x = index % self.dims[0];
        let yz = index / self.dims[0];
        [x, yz % self.dims[1], yz / self.dims[1]]
    }

    /// Continuous grid coordinates of a world point (voxel (x, y, z) spans [x, x+1) ...).
    #[inline]
    pub fn to_grid(&self, p: Vec3) -> [f64; 3] {
        // Written out: `[0, 1, 2].map(..)` stays a call to `array::try_map` in the guided
        // path tracer's vertex set-up (about 40 instructions per point).
        [
            (p.x as f64 - self.origin[0]) / self.voxel_size,
            (p.y as f64 - self.origin[1]) / self.voxel_size,
            (p.z as f64 - self.origin[2]) / self.voxel_size,
        ]
    }

    /// Integer voxel coordinates of a world point: `floor(to_grid(p))` per axis, exactly as
    /// `x.floor() as i64` (which may lie outside the grid), without `floor`: this build's
    /// target has no SSE4.1 `roundsd`, so `f64::floor` is a libm call, and the guided path
    /// tracer asks this two or three times per vertex ([`floor_to_i64`]).
    #[inline]
    pub fn voxel_of(&self, p: Vec3) -> [i64; 3] {
        floor3_to_i64(self.to_grid(p))
    }

    /// World position of a grid point.
    #[inline]
    pub fn to_world(&self, g: [f64; 3]) -> Vec3 {
        Vec3::new(
            (self.origin[0] + g[0] * self.voxel_size) as f32,
            (self.origin[1] + g[1] * self.voxel_size) as f32,
            (self.origin[2] + g[2] * self.voxel_size) as f32,
        )
    }

    /// Centre of a voxel in world space.
    pub fn voxel_center(&self, index: usize) -> Vec3 {
        let c = self.coords(index);
        self.to_world([c[0] as f64 + 0.5, c[1] as f64 + 0.5, c[2] as f64 + 0.5])
    }

    /// The voxel containing a world point, if inside the grid.
    pub fn voxel_at(&self, p: Vec3) -> Option<usize> {
        let g = self.to_grid(p);
        let mut c = [0usize; 3];
        for i in 0..3 {
            if !(g[i] >= 0.0 && g[i] < self.dims[i] as f64) {
                return None;
            }
            c[i] = g[i] as usize;
        }
        Some(self.index(c[0], c[1], c[2]))
    }
}

/// A dense set of voxels, one bit each.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct VoxelSet {
    words: Vec<u64>,
    len: usize,
}

impl VoxelSet {
    pub fn new(len: usize) -> Self {
        VoxelSet {
            words: vec![0; len.div_ceil(64)],
            len,
        }
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    #[inline]
    pub fn get(&self, i: usize) -> bool {
        self.words[i >> 6] >> (i & 63) & 1 == 1
    }

    #[inline]
    /// A test set of `len` voxels, each occupied with probability `density` (one draw per voxel
    /// in index order, so a seed gives the same set everywhere).
    #[cfg(test)]
    pub(crate) fn random(len: usize, density: f32, rng: &mut crate::math::Rng) -> Self {
        let mut s = VoxelSet::new(len);
        for i in 0..len {
            if rng.uniform() < density {
                s.set(i);
            }
        }
        s
    }

    pub fn set(&mut self, i: usize) {
        // `bits` reads zeros past the length only if nothing is ever set there.
        debug_assert!(i < self.len, "bit {i} of a set of {}", self.len);
        self.words[i >> 6] |= 1 << (i & 63);
    }

    /// Bits i..i + n (n < 64, i < len) as the low bits of a word: bit k is `get(i + k)`, and
    /// bits past the set's length read 0.
    #[inline]
    pub fn bits(&self, i: usize, n: u32) -> u64 {
        debug_assert!(n < 64 && i < self.len);
        let (w, s) = (i >> 6, (i & 63) as u32);
        let mut v = self.words[w] >> s;
        // s > 0 here, since n < 64.
        if s + n > 64 {
            v |= self.words.get(w + 1).map_or(0, |&next| next << (64 - s));
        }
        v & ((1 << n) - 1)
    }

    /// [`crate::math::prefetch`] of the word holding bit `i` (nothing past the end).
    #[inline]
    pub fn prefetch(&self, i: usize) {
        if let Some(w) = self.words.get(i >> 6) {
            crate::math::prefetch(w);
        }
    }

    /// The set of the indices where `flags` is true.
    pub fn from_flags(flags: &[bool]) -> Self {
        let mut s = VoxelSet::new(flags.len());
        for (i, _) in flags.iter().enumerate().filter(|(_, &f)| f) {
            s.set(i);
        }
        s
    }

    pub fn count(&self) -> usize {
        self.words.iter().map(|w| w.count_ones() as usize).sum()
    }

    pub fn memory_bytes(&self) -> usize {
        self.words.len() * 8
    }

    pub(crate) fn from_atomic(words: Vec<AtomicU64>, len: usize) -> Self {
        VoxelSet {
            words: words.into_iter().map(|w| w.into_inner()).collect(),
            len,
        }
    }
}

/// A bit set that many threads can add to at once.
pub(crate) struct AtomicVoxelSet {
    pub words: Vec<AtomicU64>,
}

impl AtomicVoxelSet {
    pub fn new(len: usize) -> Self {
        AtomicVoxelSet {
            words: (0..len.div_ceil(64)).map(|_| AtomicU64::new(0)).collect(),
        }
    }

    #[inline]
    pub fn set(&self, i: usize) {
        self.words[i >> 6].fetch_or(1 << (i & 63), Ordering::Relaxed);
    }
}

/// `x.floor() as i64` for every f64, bit for bit, without `f64::floor` (a libm call without
/// SSE4.1): the saturating truncation `x as i64` is the floor wherever it is not above x;
/// where it is (negative non-integers), the floor is one less. Saturation agrees with the
/// floor's own cast: NaN gives 0 in both; infinities and magnitudes beyond i64 give
/// i64::MIN / MAX (the saturating subtraction keeps MIN at MIN); from 2^53 on every f64 is an
/// integer, so the truncation is exact.
#[inline]
pub fn floor_to_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// [`floor_to_i64`] of each coordinate (written out: `g.map(floor_to_i64)` stays a call to
/// `array::try_map` where the guided path tracer maps its vertices).
#[inline]
pub fn floor3_to_i64(g: [f64; 3]) -> [i64; 3] {
    [floor_to_i64(g[0]), floor_to_i64(g[1]), floor_to_i64(g[2])]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bit_windows_equal_single_bits() {
        let mut rng = crate::math::Rng::new(21, 2);
        for len in [1usize, 3, 63, 64, 65, 130, 200] {
            let mut set = VoxelSet::new(len);
            for i in 0..len {
                if rng.uniform() < 0.5 {
                    set.set(i);
                }
            }
            for i in 0..len {
                for n in [1u32, 3, 4, 17, 63] {
                    let want = (0..n as usize)
                        .filter(|&k| i + k < len && set.get(i + k))
                        .fold(0u64, |w, k| w | 1 << k);
                    assert_eq!(set.bits(i, n), want, "len {len} i {i} n {n}");
                }
            }
        }
    }

    #[test]
    fn floor_to_i64_is_the_floor_cast_bit_for_bit() {
        let mut edge = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            -1.0 + f64::EPSILON,
            1.0 - f64::EPSILON / 2.0,
            -f64::MIN_POSITIVE,
            f64::MIN_POSITIVE,
            2f64.powi(52) + 0.5,
            -(2f64.powi(52) + 0.5),
            2f64.powi(53),
            -(2f64.powi(53)) - 2.0,
            2f64.powi(63),
            -(2f64.powi(63)),
            2f64.powi(63) - 1024.0,
            -(2f64.powi(63)) - 2048.0,
            1e300,
            -1e300,
            f64::MAX,
            f64::MIN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            -f64::NAN,
        ];
        // Near every integer of a range, both sides, and random values of all magnitudes.
        for i in -70i64..70 {
            let x = i as f64;
            // The neighbours by bits (f64::next_up needs Rust 1.86; rust-version is 1.80).
            let (up, down) = if i == 0 {
                (f64::from_bits(1), -f64::from_bits(1))
            } else if i > 0 {
                (
                    f64::from_bits(x.to_bits() + 1),
                    f64::from_bits(x.to_bits() - 1),
                )
            } else {
                (
                    f64::from_bits(x.to_bits() - 1),
                    f64::from_bits(x.to_bits() + 1),
                )
            };
            edge.extend([x, up, down, x + 0.25, x - 0.25]);
        }
        let mut rng = crate::math::Rng::new(11, 3);
        for _ in 0..100_000 {
            let bits = ((rng.next_u32() as u64) << 32) | rng.next_u32() as u64;
            edge.push(f64::from_bits(bits));
            edge.push((rng.uniform() as f64 - 0.5) * 600.0);
        }
        for x in edge {
            assert_eq!(
                floor_to_i64(x),
                x.floor() as i64,
                "{x:e} ({:#x})",
                x.to_bits()
            );
        }
    }

    #[test]
    fn resolutions_cover_the_bounds() {
        let b = Bounds3 {
            min: Vec3::new(-1.0, 0.0, 2.0),
            max: Vec3::new(3.0, 1.0, 2.5),
        };
        let g = VoxelGrid::new(b, Resolution::LongestAxis(64), 1).unwrap();
        assert_eq!(g.dims, [66, 18, 10]);
        assert!((g.voxel_size - 4.0 / 64.0).abs() < 1e-12);
        // Voxels are half-open, so the max corner itself is probed just inside.
        for p in [b.min, b.max - Vec3::splat(1e-4), b.center()] {
            let v = g.voxel_at(p).unwrap();
            let c = g.coords(v);
            assert!(
                c.iter().zip(g.dims).all(|(&c, d)| c >= 1 && c < d - 1),
                "{p} -> {c:?}"
            );
        }
        let g = VoxelGrid::new(b, Resolution::VoxelBudget(100_000), 1).unwrap();
        assert!(g.len() <= 100_000 && g.len() > 50_000, "{:?}", g.dims);
        let g = VoxelGrid::new(b, Resolution::VoxelSize(0.5), 0).unwrap();
        assert_eq!(g.dims, [8, 2, 1]);
        assert!(VoxelGrid::new(b, Resolution::VoxelSize(0.0), 0).is_err());
        assert!(VoxelGrid::new(Bounds3::EMPTY, Resolution::LongestAxis(8), 0).is_err());
        assert_eq!(g.index(3, 1, 0), 11);
        assert_eq!(g.coords(11), [3, 1, 0]);
    }
}

/// A raw pointer that may be shared between threads; used only by [`for_each_line`], whose
/// tasks write disjoint index sets.
#[derive(Clone, Copy)]
struct SharedPtr<T>(*mut T);
// SAFETY: the pointer is only dereferenced by `for_each_line`, where each task reads and
// writes a set of indices that no other task touches (see there).
unsafe impl<T: Send> Send for SharedPtr<T> {}
unsafe impl<T: Send> Sync for SharedPtr<T> {}

/// Runs `f` on every line of `data` (a dims[0] x dims[1] x dims[2] array, x fastest) along
/// `axis`, in parallel. `f` gets the line as a contiguous slice (gathered into a per-task
/// buffer for strided axes and written back afterwards) and a per-task scratch state.
pub(crate) fn for_each_line<T, S>(
    dims: [usize; 3],
    axis: usize,
    data: &mut [T],
    init: impl Fn() -> S + Sync + Send,
    f: impl Fn(&mut S, &mut [T]) + Sync + Send,
) where
    T: Copy + Send + Sync + Default,
{
    use rayon::prelude::*;
    let [nx, ny, nz] = dims;
    assert_eq!(data.len(), nx * ny * nz);
    match axis {
        0 => data
            .par_chunks_mut(nx.max(1))
            .for_each_init(&init, |s, line| f(s, line)),
        1 => data.par_chunks_mut((nx * ny).max(1)).for_each_init(
            || (init(), vec![T::default(); ny]),
            |(s, buf), slab| {
                for x in 0..nx {
                    for y in 0..ny {
                        buf[y] = slab[x + nx * y];
                    }
                    f(s, buf);
                    for y in 0..ny {
                        slab[x + nx * y] = buf[y];
                    }
                }
            },
        ),
        _ => {
            let ptr = SharedPtr(data.as_mut_ptr());
            let stride = nx * ny;
            (0..ny).into_par_iter().for_each_init(
                || (init(), vec![T::default(); nz]),
                |(s, buf), y| {
                    // Rebinding moves the whole `SharedPtr` (which is `Send`) into the closure
                    // instead of its raw-pointer field (which is not).
                    #[allow(clippy::redundant_locals)]
                    let ptr = ptr;
                    for x in 0..nx {
                        let start = x + nx * y;
                        for (z, b) in buf.iter_mut().enumerate() {
                            // SAFETY: index start + stride*z < nx*ny*nz = data.len(); the task for
                            // row y touches only indices with this y, so no two tasks alias, and
                            // `data` is exclusively borrowed for the whole call.
                            *b = unsafe { *ptr.0.add(start + stride * z) };
                        }
                        f(s, buf);
                        for (z, b) in buf.iter().enumerate() {
                            // SAFETY: as above.
                            unsafe { *ptr.0.add(start + stride * z) = *b };
                        }
                    }
                },
            )
        }
    }
}
