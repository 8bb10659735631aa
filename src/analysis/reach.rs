//! Where a point may map to a node at all ([`may_map_to`]): a per-voxel mask that lets a
//! guide skip [`map_point`](super::map_point) (eq. 151-155) where no node it cares about is within reach.
//! A mask rather than a cache of `map_point`'s answers: most surface points' neighbourhoods map
//! to several nodes, so a cache saves little, while the mask skips the mapping entirely where
//! nothing is guided.

use rayon::prelude::*;

use super::{VoxelGrid, UNDEFINED_NODE};

/// Voxels from which [`map_point`](super::map_point) may return a node for which `wanted`
/// holds, by the neighbourhoods eq. 151-155 (as `map_point` implements them) can read from
/// a point p in voxel v_x with any normal and incident direction:
/// - the first search and the last resort read the 26-neighbourhood of v_x: wanted if a
///   wanted node is mapped within one voxel of v_x (`near`);
/// - the searches along n⁺ (steps s = 1, 2, 3, centre floor(g + s n⁺)) run only when the
///   first found no mapped neighbour o of v_x with o·n⁺ > 0, i.e. n⁺ lies in the cone
///   {n : o·n <= 0 for every mapped o}; where v_x has mapped neighbours on every side (open
///   space) that cone is {0} and they never run. Otherwise the centre's offset d from v_x
///   satisfies s n⁺ in (d - 1, d + 1) per axis (g lies in [v_x, v_x + 1)), so d is possible
///   only if that box (clipped by the sign constraints of the mapped face neighbours) meets
///   the sphere of radius s and no mapped neighbour's half-space o·x <= 0 misses it; then
///   v_x is wanted if `near` holds at the centre.
///
/// A superset of the exact set (the cone is tested per constraint, not jointly; tolerances
/// cover f32 rounding): where this is false, the point maps to no wanted node (or to none),
/// without searching. Unlike a plain distance mask (every voxel within 4 voxels of a wanted
/// one), it drops the voxels of open space more than one voxel from a wanted node and wall
/// voxels whose searches along n⁺ lead away from it (and, to stay a superset under rounding,
/// allows centres 4 voxels away inside thick walls).
pub fn may_map_to(grid: &VoxelGrid, map: &[u32], wanted: impl Fn(u32) -> bool + Sync) -> Vec<bool> {
    may_map_to_where(grid, map, wanted, |_| true)
}

/// [`may_map_to`] at the voxels where `asked` holds, false elsewhere: the costly search test
/// runs only where the answer is wanted (the training asks only where its vertices fell).
pub fn may_map_to_where(
    grid: &VoxelGrid,
    map: &[u32],
    wanted: impl Fn(u32) -> bool + Sync,
    asked: impl Fn(usize) -> bool + Sync,
) -> Vec<bool> {
    let len = map.len();
    let wanted_voxel = bits_where(len, |k| map[k] != UNDEFINED_NODE && wanted(map[k]));
    let mut reach = vec![false; len];
    // No wanted node (a guide switched off): nothing to search from.
    if wanted_voxel.iter().all(|&w| w == 0) {
        return reach;
    }
    let near = dilate(grid, &wanted_voxel, 1);
    // A search's centre lies within 3 voxels of v_x (4 with a unit normal rounded above 1),
    // so `far` bounds where the cone test can succeed and skips it far from every wanted node.
    let far = dilate(grid, &near, 4);
    // The cone test's geometry depends on the voxel's mapped neighbours alone: the offsets it
    // allows are found once per distinct neighbourhood, then looked up per voxel.
    let tested: Vec<(usize, u32)> = (0..far.len())
        .into_par_iter()
        .flat_map_iter(|w| ones(far[w] & !near[w], w).filter(|&k| asked(k)))
        .map(|k| (k, mapped_neighbours(grid, map, k)))
        .collect();
    let mut masks: Vec<u32> = tested.iter().map(|&(_, m)| m).collect();
    masks.par_sort_unstable();
    masks.dedup();
    let offsets: Vec<Vec<[i64; 3]>> = masks.par_iter().map(|&m| search_offsets(m)).collect();
    let dims = grid.dims.map(|d| d as i64);
    let found: Vec<usize> = tested
        .par_iter()
        .filter(|&&(k, m)| {
            let v = grid.coords(k).map(|c| c as i64);
            let i = masks
                .binary_search(&m)
                .expect("every tested mask is listed");
            offsets[i].iter().any(|d| {
                // The centre's neighbourhood within the grid is within that of the centre
                // clamped to the grid.
                let c = [0, 1, 2].map(|a| (v[a] + d[a]).clamp(0, dims[a] - 1) as usize);
                bit(&near, grid.index(c[0], c[1], c[2]))
            })
        })
        .map(|&(k, _)| k)
        .collect();
    for k in (0..near.len()).flat_map(|w| ones(near[w], w)) {
        reach[k] = asked(k);
    }
    for k in found {
        reach[k] = true;
    }
    reach
}

/// One bit per voxel in index order, 64 to a word (bit k % 64 of word k / 64); the bits past
/// the grid's voxels are 0.
type Bits = Vec<u64>;

/// The voxels of `0..len` where `f` holds, as [`Bits`].
fn bits_where(len: usize, f: impl Fn(usize) -> bool + Sync) -> Bits {
    (0..len.div_ceil(64))
        .into_par_iter()
        .map(|w| {
            (w * 64..len.min(w * 64 + 64))
                .filter(|&k| f(k))
                .fold(0u64, |b, k| b | 1 << (k % 64))
        })
        .collect()
}

#[inline]
fn bit(bits: &[u64], k: usize) -> bool {
    bits[k / 64] >> (k % 64) & 1 == 1
}

/// The voxel indices of the set bits of `word`, the `w`-th word of a [`Bits`].
fn ones(mut word: u64, w: usize) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (word != 0).then(|| {
            let b = word.trailing_zeros() as usize;
            word &= word - 1;
            w * 64 + b
        })
    })
}

/// Box dilation by `radius` voxels per axis: a voxel is set when a set voxel lies within
/// `radius` of it along each axis. The box of radius r is r boxes of radius 1 added
/// together, so it is `radius` steps of dilation by one voxel, each of which ORs, per axis,
/// the bits moved by that axis's stride in both directions onto the set, 64 voxels per word
/// operation. Moves across a line's or a slice's end are masked off (the voxels with no
/// neighbour on that side); along z they fall off the grid's ends.
fn dilate(grid: &VoxelGrid, bits: &[u64], radius: usize) -> Bits {
    let [nx, ny, nz] = grid.dims;
    let len = grid.len();
    let words = len.div_ceil(64);
    // Every voxel of the grid, and per axis the voxels with a neighbour below / above.
    let mut all = vec![!0u64; words];
    if len % 64 != 0 {
        all[words - 1] = (1 << (len % 64)) - 1;
    }
    let clear = |mask: &mut Bits, k: usize| mask[k / 64] &= !(1 << (k % 64));
    let (mut below_x, mut above_x) = (all.clone(), all.clone());
    for line in 0..ny * nz {
        clear(&mut below_x, line * nx);
        clear(&mut above_x, line * nx + nx - 1);
    }
    let (mut below_y, mut above_y) = (all.clone(), all.clone());
    for z in 0..nz {
        for x in 0..nx {
            clear(&mut below_y, grid.index(x, 0, z));
            clear(&mut above_y, grid.index(x, ny - 1, z));
        }
    }
    let axes = [
        (1, &below_x, &above_x),
        (nx, &below_y, &above_y),
        (nx * ny, &all, &all),
    ];
    let mut bits = bits.to_vec();
    for _ in 0..radius {
        for &(stride, below, above) in &axes {
            let input = bits;
            bits = (0..words)
                .into_par_iter()
                .with_min_len(1024)
                .map(|w| {
                    input[w]
                        | (moved_up(&input, w, stride) & below[w])
                        | (moved_down(&input, w, stride) & above[w])
                })
                .collect();
        }
    }
    bits
}

/// Word `w` of `bits` moved up by `n` positions (bit k of the result is bit k - n; zeros
/// below 0).
#[inline]
fn moved_up(bits: &[u64], w: usize, n: usize) -> u64 {
    let word = |i: usize| w.checked_sub(i).map_or(0, |j| bits[j]);
    let (q, r) = (n / 64, n % 64);
    if r == 0 {
        word(q)
    } else {
        word(q) << r | word(q + 1) >> (64 - r)
    }
}

/// Word `w` of `bits` moved down by `n` positions (bit k of the result is bit k + n; zeros
/// past the end).
#[inline]
fn moved_down(bits: &[u64], w: usize, n: usize) -> u64 {
    let word = |i: usize| bits.get(w + i).copied().unwrap_or(0);
    let (q, r) = (n / 64, n % 64);
    if r == 0 {
        word(q)
    } else {
        word(q) >> r | word(q + 1) << (64 - r)
    }
}

/// Slack of the geometric tests (grid units): `map_point` works in f32 / f64 with a unit
/// normal rounded to f32, so the boundaries are widened rather than trusted.
const SLACK: f64 = 1e-3;

/// Bit `(dz + 1) 9 + (dy + 1) 3 + (dx + 1)` of voxel `k`'s neighbour at offset (dx, dy, dz)
/// (itself excluded) is set when that neighbour is inside the grid and mapped.
fn mapped_neighbours(grid: &VoxelGrid, map: &[u32], k: usize) -> u32 {
    let dims = grid.dims.map(|d| d as i64);
    let v = grid.coords(k).map(|c| c as i64);
    let inside = |p: [i64; 3]| (0..3).all(|a| p[a] >= 0 && p[a] < dims[a]);
    let mut mask = 0;
    for dz in -1..=1i64 {
        for dy in -1..=1i64 {
            for dx in -1..=1i64 {
                let w = [v[0] + dx, v[1] + dy, v[2] + dz];
                if [dx, dy, dz] != [0, 0, 0]
                    && inside(w)
                    && map[grid.index(w[0] as usize, w[1] as usize, w[2] as usize)]
                        != UNDEFINED_NODE
                {
                    mask |= 1 << ((dz + 1) * 9 + (dy + 1) * 3 + (dx + 1));
                }
            }
        }
    }
    mask
}

/// The offsets d from v_x on which one of `map_point`'s searches along n⁺ (steps 1-3) may
/// be centred, for a voxel whose mapped neighbours are `mask` ([`mapped_neighbours`]; see
/// [`may_map_to`]): [`centre_offsets`] of the offsets the mask's bits stand for.
fn search_offsets(mask: u32) -> Vec<[i64; 3]> {
    let mut mapped_storage = [[0i64; 3]; 26];
    let mut mapped_count = 0;
    for bit in (0..27).filter(|b| mask & (1 << b) != 0) {
        let b = bit as i64;
        mapped_storage[mapped_count] = [b % 3 - 1, (b / 3) % 3 - 1, b / 9 - 1];
        mapped_count += 1;
    }
    centre_offsets(&mapped_storage[..mapped_count])
}

/// The offsets d from v_x on which one of `map_point`'s searches along n⁺ (steps 1-3) may
/// be centred, for a voxel whose mapped neighbours are at the offsets `mapped`: the
/// geometry of the cone test ([`may_map_to`]), whatever `near` holds at the centres.
fn centre_offsets(mapped: &[[i64; 3]]) -> Vec<[i64; 3]> {
    let mut offsets = Vec::new();
    // Per axis, the range of x = s n⁺ the face neighbours allow: a mapped +e_a means
    // n⁺_a <= 0 (else it would have been found facing; its score is n⁺_a, exact in f32),
    // a mapped -e_a means n⁺_a >= 0. Then floor(g_a + s n⁺_a) <= v_a exactly.
    let mut limit = [[-3.0 - SLACK, 3.0 + SLACK]; 3];
    for o in mapped {
        if o.iter().filter(|&&c| c != 0).count() == 1 {
            let a = (0..3).find(|&a| o[a] != 0).expect("a face offset");
            if o[a] > 0 {
                limit[a][1] = limit[a][1].min(0.0);
            } else {
                limit[a][0] = limit[a][0].max(0.0);
            }
        }
    }
    if (0..3).any(|a| limit[a][0] > limit[a][1]) {
        return offsets;
    }
    let d_range = |a: usize| -> (i64, i64) {
        // d - 1 < x < d + 1 for some x in limit[a].
        (
            (limit[a][0] - 1.0).floor() as i64 + 1,
            (limit[a][1] + 1.0).ceil() as i64 - 1,
        )
    };
    let ranges = [d_range(0), d_range(1), d_range(2)];
    for dz in ranges[2].0..=ranges[2].1 {
        for dy in ranges[1].0..=ranges[1].1 {
            for dx in ranges[0].0..=ranges[0].1 {
                let d = [dx, dy, dz];
                let mut lo = [0.0f64; 3];
                let mut hi = [0.0f64; 3];
                let mut empty = false;
                for a in 0..3 {
                    lo[a] = (d[a] as f64 - 1.0 - SLACK).max(limit[a][0]);
                    hi[a] = (d[a] as f64 + 1.0 + SLACK).min(limit[a][1]);
                    empty |= lo[a] > hi[a];
                }
                if empty {
                    continue;
                }
                // Every mapped neighbour's half-space o·x <= 0 must meet the box.
                let misses = mapped.iter().any(|o| {
                    (0..3)
                        .map(|a| (o[a] as f64 * lo[a]).min(o[a] as f64 * hi[a]))
                        .sum::<f64>()
                        > SLACK
                });
                if misses {
                    continue;
                }
                // Squared distances from 0 to the box's nearest and farthest points.
                let nearest: f64 = (0..3)
                    .map(|a| {
                        if lo[a] > 0.0 {
                            lo[a] * lo[a]
                        } else if hi[a] < 0.0 {
                            hi[a] * hi[a]
                        } else {
                            0.0
                        }
                    })
                    .sum();
                let farthest: f64 = (0..3).map(|a| (lo[a] * lo[a]).max(hi[a] * hi[a])).sum();
                let on_a_sphere = (1..=3).any(|s| {
                    let s = s as f64;
                    nearest <= (s + SLACK).powi(2) && farthest >= (s - SLACK).powi(2)
                });
                if on_a_sphere {
                    offsets.push(d);
                }
            }
        }
    }
    offsets
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::map_point;
    use crate::math::{Rng, Vec3};

    /// The dilation against its definition: set where a set voxel lies within the radius
    /// along every axis (a box), on random flags of every density, on grids whose lines and
    /// slices are shorter and longer than a word.
    #[test]
    fn dilate_matches_a_brute_force_box() {
        let mut rng = Rng::new(3, 0);
        for dims in [[7usize, 5, 6], [67, 3, 4], [1, 9, 70], [3, 1, 1]] {
            let grid = VoxelGrid {
                dims,
                origin: [0.0, 0.0, 0.0],
                voxel_size: 1.0,
            };
            for density in [0.0, 0.01, 0.1, 0.5] {
                let flags: Vec<bool> = (0..grid.len()).map(|_| rng.uniform() < density).collect();
                for radius in [0, 1, 2, 4] {
                    let fast = flags_of(
                        &dilate(&grid, &bits_where(grid.len(), |k| flags[k]), radius),
                        grid.len(),
                    );
                    for (k, &f) in fast.iter().enumerate() {
                        let v = grid.coords(k);
                        let mut any = false;
                        for (j, &set) in flags.iter().enumerate() {
                            let w = grid.coords(j);
                            any |= set && (0..3).all(|a| v[a].abs_diff(w[a]) <= radius);
                        }
                        assert_eq!(
                            f, any,
                            "voxel {v:?} of {dims:?}, radius {radius}, density {density}"
                        );
                    }
                }
            }
        }
    }

    /// The voxels of `bits` as flags, checking that the bits past `len` are 0.
    fn flags_of(bits: &[u64], len: usize) -> Vec<bool> {
        assert_eq!(bits.len(), len.div_ceil(64));
        assert!(
            (len..bits.len() * 64).all(|k| !bit(bits, k)),
            "bits past the end"
        );
        (0..len).map(|k| bit(bits, k)).collect()
    }

    /// The cone test run directly at voxel `k`: its mapped neighbours read from `map`, `near`
    /// read at each clamped centre. The oracle of `may_map_to_matches_the_direct_cone_test`,
    /// which checks what `may_map_to_where` adds to the geometry (the neighbourhood masks
    /// and their bits, the offsets shared per mask, the clamping); the geometry itself
    /// ([`centre_offsets`]) is shared, and checked against `map_point`'s searches by
    /// `search_offsets_hold_every_centre_a_search_can_take`.
    fn searches_along_normal_reach_directly(
        grid: &VoxelGrid,
        map: &[u32],
        near: &[bool],
        k: usize,
    ) -> bool {
        let dims = grid.dims.map(|d| d as i64);
        let v = grid.coords(k).map(|c| c as i64);
        let inside = |p: [i64; 3]| (0..3).all(|a| p[a] >= 0 && p[a] < dims[a]);
        let mut mapped = Vec::new();
        for dz in -1..=1i64 {
            for dy in -1..=1i64 {
                for dx in -1..=1i64 {
                    let o = [dx, dy, dz];
                    let w = [v[0] + dx, v[1] + dy, v[2] + dz];
                    if o != [0, 0, 0]
                        && inside(w)
                        && map[grid.index(w[0] as usize, w[1] as usize, w[2] as usize)]
                            != UNDEFINED_NODE
                    {
                        mapped.push(o);
                    }
                }
            }
        }
        centre_offsets(&mapped).iter().any(|d| {
            let c = [0, 1, 2].map(|a| (v[a] + d[a]).clamp(0, dims[a] - 1) as usize);
            near[grid.index(c[0], c[1], c[2])]
        })
    }

    /// [`search_offsets`] against the searches of `map_point` they stand for, by brute
    /// force: for a voxel v_x = 0 with mapped neighbours `mask`, every unit normal n⁺ (f32,
    /// as `map_point` normalises it) that faces no mapped neighbour (o·n⁺ <= 0 in f32, the
    /// first search's test), every point g in the voxel and every step s = 1-3, the centre
    /// floor(g + s n⁺) must be one of the offsets. Masks: none, every neighbour, walls
    /// (the neighbours on one side of a plane, open or closed), corners (two walls), and
    /// those with neighbours dropped at random; normals: random, and lattice directions
    /// (on the cones' boundaries).
    #[test]
    fn search_offsets_hold_every_centre_a_search_can_take() {
        let mut rng = Rng::new(5, 2);
        let neighbours: Vec<[i64; 3]> = (0..27)
            .map(|b: i64| [b % 3 - 1, (b / 3) % 3 - 1, b / 9 - 1])
            .filter(|o| *o != [0, 0, 0])
            .collect();
        let bit_of = |o: [i64; 3]| 1u32 << ((o[2] + 1) * 9 + (o[1] + 1) * 3 + (o[0] + 1));
        let dot = |a: [i64; 3], b: [i64; 3]| (0..3).map(|i| a[i] * b[i]).sum::<i64>();
        let side = |m: [i64; 3], closed: bool| -> u32 {
            neighbours
                .iter()
                .filter(|&&o| dot(o, m) > 0 || (closed && dot(o, m) == 0))
                .map(|&o| bit_of(o))
                .fold(0, |a, b| a | b)
        };
        let every = neighbours.iter().map(|&o| bit_of(o)).fold(0, |a, b| a | b);
        let mut masks = vec![0u32, every];
        for &m in &neighbours {
            masks.push(side(m, false));
            masks.push(side(m, true));
            for &m2 in neighbours.iter().filter(|&&m2| dot(m, m2) == 0) {
                masks.push(side(m, false) | side(m2, false));
            }
        }
        for i in 0..masks.len() {
            for _ in 0..3 {
                let kept = neighbours
                    .iter()
                    .filter(|_| rng.uniform() < 0.7)
                    .map(|&o| bit_of(o))
                    .fold(0, |a, b| a | b);
                masks.push(masks[i] & kept);
            }
        }
        masks.sort_unstable();
        masks.dedup();
        let mut normals: Vec<Vec3> = (-3..=3i64)
            .flat_map(|z| (-3..=3i64).flat_map(move |y| (-3..=3i64).map(move |x| [x, y, z])))
            .filter(|d| *d != [0, 0, 0])
            .map(|d| Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32).normalize())
            .collect();
        normals.extend(
            (0..2000).map(|_| crate::math::warp::uniform_sphere(rng.uniform2()).normalize()),
        );
        // Points of the voxel: its corners (0 and the last f64 below 1 per axis) and random.
        let below_one = 1.0 - f64::EPSILON / 2.0;
        let mut points: Vec<[f64; 3]> = (0..8)
            .map(|c| [0, 1, 2].map(|a| if c >> a & 1 == 1 { below_one } else { 0.0 }))
            .collect();
        points.extend((0..8).map(|_| {
            [
                rng.uniform() as f64,
                rng.uniform() as f64,
                rng.uniform() as f64,
            ]
        }));
        let (mut facing, mut far) = (0, 0);
        for &mask in &masks {
            let offsets = search_offsets(mask);
            let mapped: Vec<[i64; 3]> = neighbours
                .iter()
                .copied()
                .filter(|&o| mask & bit_of(o) != 0)
                .collect();
            for &n in &normals {
                let faces_a_mapped_neighbour = mapped
                    .iter()
                    .any(|o| Vec3::new(o[0] as f32, o[1] as f32, o[2] as f32).dot(n) > 0.0);
                if faces_a_mapped_neighbour {
                    continue;
                }
                facing += 1;
                for g in &points {
                    for s in 1..=3 {
                        let d = [0, 1, 2].map(|a| (g[a] + s as f64 * n[a] as f64).floor() as i64);
                        far += usize::from(d.iter().any(|c| c.abs() > 1));
                        assert!(
                            offsets.contains(&d),
                            "mask {mask:#x}: normal {n}, point {g:?}, step {s} centre {d:?} \
                             not among {offsets:?}"
                        );
                    }
                }
            }
        }
        // Every neighbour mapped: no normal escapes the first search.
        assert!(search_offsets(every).is_empty());
        assert!(
            facing > 10_000 && far > 10_000,
            "{facing} normals, {far} far centres"
        );
    }

    /// [`may_map_to_where`] (offsets per distinct neighbourhood) gives the answer of the cone
    /// test run directly at every voxel, on random maps of several densities and wanted sets.
    #[test]
    fn may_map_to_matches_the_direct_cone_test() {
        let grid = VoxelGrid {
            dims: [17, 13, 11],
            origin: [0.0, 0.0, 0.0],
            voxel_size: 1.0,
        };
        let mut rng = Rng::new(11, 4);
        for solid in [0.1, 0.3, 0.5, 0.7] {
            let map: Vec<u32> = (0..grid.len())
                .map(|_| {
                    if rng.uniform() < solid {
                        UNDEFINED_NODE
                    } else {
                        (rng.uniform() * 6.0) as u32
                    }
                })
                .collect();
            for wanted in [0u32, 3, 5] {
                let want = |n: u32| n == wanted;
                let got = may_map_to_where(&grid, &map, want, |k| k % 5 != 1);
                let flags: Vec<bool> = map
                    .iter()
                    .map(|&m| m != UNDEFINED_NODE && want(m))
                    .collect();
                let near = dilate(&grid, &bits_where(grid.len(), |k| flags[k]), 1);
                let far = flags_of(&dilate(&grid, &near, 4), grid.len());
                let near = flags_of(&near, grid.len());
                let mut searched = 0;
                for (k, &g) in got.iter().enumerate() {
                    let direct = k % 5 != 1
                        && (near[k]
                            || (far[k]
                                && searches_along_normal_reach_directly(&grid, &map, &near, k)));
                    searched += usize::from(!near[k] && direct);
                    assert_eq!(g, direct, "voxel {k}, solid {solid}, wanted {wanted}");
                }
                assert!(
                    solid < 0.5 || searched > 0,
                    "solid {solid}: no search succeeded"
                );
            }
        }
    }

    #[test]
    fn may_map_to_covers_every_point_that_reaches_a_node() {
        let grid = VoxelGrid {
            dims: [30, 20, 12],
            origin: [0.0, 0.0, 0.0],
            voxel_size: 0.5,
        };
        let mut rng = Rng::new(3, 9);
        let map: Vec<u32> = (0..30 * 20 * 12)
            .map(|k| {
                let [x, y, z] = grid.coords(k);
                if rng.uniform() < 0.3 {
                    UNDEFINED_NODE
                } else if (4..8).contains(&x) && (5..9).contains(&y) && z < 6 {
                    2
                } else {
                    (x / 10) as u32 * 3 + 1
                }
            })
            .collect();
        let reach = may_map_to(&grid, &map, |n| n == 2);
        assert!(reach.iter().any(|&r| !r) && reach.iter().any(|&r| r));
        // Asked at every third voxel: the same answer there, false elsewhere.
        let asked = may_map_to_where(&grid, &map, |n| n == 2, |k| k % 3 == 0);
        for (k, (&a, &r)) in asked.iter().zip(&reach).enumerate() {
            assert_eq!(a, k % 3 == 0 && r, "voxel {k}");
        }
        // No wanted node: nothing may map to one.
        assert!(may_map_to(&grid, &map, |_| false).iter().all(|&r| !r));
        let lo = Vec3::splat(-0.5);
        let hi = Vec3::new(15.5, 10.5, 6.5);
        let mut hits = 0;
        for _ in 0..200_000 {
            let u = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform());
            let p = lo + (hi - lo) * u;
            let normal = crate::math::warp::uniform_sphere(rng.uniform2());
            let incident = crate::math::warp::uniform_sphere(rng.uniform2());
            if map_point(&grid, &map, p, normal, incident) == Some(2) {
                let v = grid.to_grid(p).map(|x| x.floor() as i64);
                if (0..3).all(|a| v[a] >= 0 && v[a] < grid.dims[a] as i64) {
                    assert!(reach[grid.index(v[0] as usize, v[1] as usize, v[2] as usize)]);
                    hits += 1;
                }
            }
        }
        assert!(hits > 100, "{hits}");
    }

    /// Walls of one to five voxels between rooms of different nodes: the searches along n⁺
    /// reach through the thin walls, not the thick ones; every point that maps to the
    /// wanted node is inside the mask, and the mask holds fewer empty voxels than the 5-voxel
    /// box that bounds it.
    #[test]
    fn may_map_to_covers_points_next_to_walls_and_is_tighter_than_a_box() {
        let grid = VoxelGrid {
            dims: [40, 12, 10],
            origin: [0.0, 0.0, 0.0],
            voxel_size: 1.0,
        };
        // Rooms along x, separated by solid slabs 1..5 voxels thick; room i is node i.
        let mut node_of_x = [UNDEFINED_NODE; 40];
        let (mut x, mut node, mut thickness) = (0usize, 0u32, 1usize);
        while x < 40 {
            for cell in node_of_x.iter_mut().skip(x).take(4) {
                *cell = node;
            }
            x += 4 + thickness;
            node += 1;
            thickness = thickness % 5 + 1;
        }
        let map: Vec<u32> = (0..grid.len())
            .map(|k| {
                let [x, y, z] = grid.coords(k);
                // A solid floor, and a pillar in room 2.
                if z == 0 || (node_of_x[x] == 2 && (5..7).contains(&y) && z < 6) {
                    UNDEFINED_NODE
                } else {
                    node_of_x[x]
                }
            })
            .collect();
        let (mut tight_total, mut loose_total) = (0, 0);
        for wanted in 0..node {
            let reach = may_map_to(&grid, &map, |n| n == wanted);
            // Within 5 voxels at most (a centre 4 voxels away only with |n| rounded above 1,
            // which a 4-voxel box would ignore), and tighter than that box in the empty
            // space, where it also marked the neighbouring rooms' voxels.
            let flags: Vec<bool> = map.iter().map(|&m| m == wanted).collect();
            let boxed = flags_of(
                &dilate(&grid, &bits_where(grid.len(), |k| flags[k]), 5),
                grid.len(),
            );
            assert!(reach.iter().zip(&boxed).all(|(&r, &b)| !r || b));
            let open = |flags: &[bool]| {
                (0..grid.len())
                    .filter(|&k| flags[k] && map[k] != UNDEFINED_NODE)
                    .count()
            };
            let (tight, loose) = (open(&reach), open(&boxed));
            tight_total += tight;
            loose_total += loose;
            let mut rng = Rng::new(11, wanted as u64);
            let mut hits = 0;
            for _ in 0..100_000 {
                let u = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform());
                let p = Vec3::new(40.0, 12.0, 10.0) * u;
                // Normals near the axes too: the searches along n⁺ run into walls.
                let normal = if rng.uniform() < 0.5 {
                    let axis = [Vec3::X, Vec3::Y, Vec3::Z][(rng.uniform() * 3.0) as usize % 3];
                    (axis + 0.2 * crate::math::warp::uniform_sphere(rng.uniform2())).normalize()
                } else {
                    crate::math::warp::uniform_sphere(rng.uniform2())
                };
                let incident = crate::math::warp::uniform_sphere(rng.uniform2());
                if map_point(&grid, &map, p, normal, incident) == Some(wanted) {
                    let v = grid.to_grid(p).map(|x| x.floor() as usize);
                    let k = grid.index(v[0].min(39), v[1].min(11), v[2].min(9));
                    assert!(
                        reach[k],
                        "node {wanted}: point {p} maps to it outside the mask"
                    );
                    hits += 1;
                }
            }
            assert!(hits > 100, "node {wanted}: {hits}");
        }
        assert!(
            tight_total < loose_total,
            "{tight_total} of {loose_total} empty voxels"
        );
    }
}
