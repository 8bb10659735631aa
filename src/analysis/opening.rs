//! Opening maps: for every empty voxel, the radius of the largest maximal ball of the empty
//! space that contains it — the local thickness of the space light travels through.
//!
//! The 26-opening (chessboard balls) is computed exactly in O(N) by the six line-dilation scans
//! of 000 Algorithms 6-7, which also record each voxel's ball centre: the opening forest
//! (Definition 10.7). The 1-opening (L1 balls, used by the skeleton's decenterness map, 000
//! §6.2.2) is computed level by level from the largest radius down, with pruning.

use rayon::prelude::*;

use super::grid::for_each_line;

/// The 26-opening map and an opening forest.
#[derive(Clone, Debug)]
pub struct OpeningMap {
    /// Omega_inf: 0 on occupied voxels.
    pub opening: Vec<u32>,
    /// Omega_f: index of the centre of a maximal ball of radius `opening` containing the voxel
    /// (the voxel itself exactly when its own ball is the largest, i.e. it is a forest root).
    pub center: Vec<u32>,
}

impl OpeningMap {
    pub fn memory_bytes(&self) -> usize {
        (self.opening.len() + self.center.len()) * 4
    }

    pub fn is_root(&self, i: usize) -> bool {
        self.opening[i] > 0 && self.center[i] as usize == i
    }
}

/// One ball in the dilation queue: radius, centre and the first index it no longer covers.
#[derive(Clone, Copy)]
struct Ball {
    radius: u32,
    center: u32,
    end: usize,
}

/// Algorithm 7 (dilateLine): dilates a line of (radius, centre) pairs in the direction of
/// increasing index, keeping a deque of candidate balls with decreasing radii and increasing
/// ends, so every voxel is pushed and popped at most once. The current voxel's own ball wins
/// ties, which makes forest roots exactly the voxels whose opening equals their distance.
fn dilate_line(line: &mut [(u32, u32)], queue: &mut std::collections::VecDeque<Ball>) {
    queue.clear();
    for i in 0..line.len() {
        let (radius, center) = line[i];
        let cur = Ball {
            radius,
            center,
            end: i + radius as usize,
        };
        if cur.radius == 0 {
            queue.clear();
        } else if queue.front().is_some_and(|f| f.end == i) {
            queue.pop_front();
        }
        match queue.front() {
            None => queue.push_back(cur),
            Some(front) if cur.radius >= front.radius => {
                queue.clear();
                queue.push_back(cur);
            }
            Some(_) => {
                while queue.back().is_some_and(|b| cur.radius >= b.radius) {
                    queue.pop_back();
                }
                if queue.back().is_some_and(|b| b.end < cur.end) {
                    queue.push_back(cur);
                }
            }
        }
        let front = queue
            .front()
            .expect("queue holds at least the current ball");
        line[i] = (front.radius, front.center);
    }
}

/// Algorithm 6: the 26-opening map and forest from the 26-distance map (0 = occupied). Each
/// axis is one parallel pass over its lines, dilating forward then backward. (The scan
/// bounds of Algorithm 6's y loop read "[w...h]" in the text; it is [1...h].)
pub fn opening_map_26(dims: [usize; 3], distance: &[u32]) -> OpeningMap {
    let n = dims[0] * dims[1] * dims[2];
    assert_eq!(distance.len(), n);
    let mut data: Vec<(u32, u32)> = distance
        .par_iter()
        .enumerate()
        .map(|(i, &d)| (d, i as u32))
        .collect();
    for axis in 0..3 {
        for_each_line(
            dims,
            axis,
            &mut data,
            std::collections::VecDeque::new,
            |queue, line| {
                dilate_line(line, queue);
                line.reverse();
                dilate_line(line, queue);
                line.reverse();
            },
        );
    }
    OpeningMap {
        opening: data.par_iter().map(|p| p.0).collect(),
        center: data.par_iter().map(|p| p.1).collect(),
    }
}

/// The L1 opening map (granulometry with octahedral balls) from the L1 distance map:
/// Omega_1(x) = max { D_1(y) : d_1(x, y) < D_1(y) }.
///
/// Levels r = max D_1 .. 1 are processed in decreasing order; level r floods from the voxels of
/// distance exactly r with a budget of r - 1 steps, assigning r to voxels not assigned yet. A
/// voxel reached with a budget no larger than one it was already expanded with is not expanded
/// again: everything within that budget already received a larger level. 6-connected steps
/// through empty voxels are L1 steps. Only centres of maximal balls seed a level: a voxel with
/// a 6-neighbour one farther from the solid has its ball inside that neighbour's larger ball
/// (d_1 = 1 <= (r + 1) - r), which floods the same voxels first with a larger value and at
/// least the same budget. The grid is padded with one layer of solid so that steps need no
/// bounds test.
pub fn opening_map_l1(dims: [usize; 3], distance_l1: &[u32]) -> Vec<u32> {
    opening_l1(dims, distance_l1, false, None).0
}

/// [`opening_map_l1`] and the L1 decenterness Ω1 − D1 (000 §6.2.2) together, both written in
/// the same pass over the flood's result.
pub fn opening_and_decenterness_l1(dims: [usize; 3], distance_l1: &[u32]) -> (Vec<u32>, Vec<u32>) {
    opening_l1(dims, distance_l1, false, None)
}

/// [`opening_and_decenterness_l1`], with 32-bit flood words even when 16 bits would do if
/// `wide`, and the flood split into `pieces` (by default [`flood_pieces`]); the result does not
/// depend on either.
fn opening_l1(
    dims: [usize; 3],
    distance_l1: &[u32],
    wide: bool,
    pieces: Option<usize>,
) -> (Vec<u32>, Vec<u32>) {
    let max_d = max_distance(distance_l1);
    let pieces = pieces
        .unwrap_or_else(|| flood_pieces(dims, max_d, wide))
        .clamp(1, dims.into_iter().max().unwrap_or(1).max(1));
    // 16-bit distances, state and levels halve the memory traffic of the flood when the
    // distances fit.
    if !wide && max_d < u16::MAX as usize - 1 {
        opening_l1_words::<u16>(dims, distance_l1, max_d, pieces)
    } else {
        opening_l1_words::<u32>(dims, distance_l1, max_d, pieces)
    }
}

/// The largest finite distance of a map (0 if none).
fn max_distance(distance_l1: &[u32]) -> usize {
    distance_l1
        .par_iter()
        .copied()
        .filter(|&d| d != u32::MAX)
        .max()
        .unwrap_or(0) as usize
}

/// Grids with fewer voxels than this are flooded in one piece (splitting costs a pass over the
/// grid per piece).
const MIN_VOXELS_PER_FLOOD_PIECE: usize = 1 << 16;

/// How many pieces the L1 flood is split into on the current rayon pool: one per thread, but
/// at most 4 (each piece holds two flood words per voxel of the whole grid; 2 with 32-bit
/// words), with slabs along the longest axis at least twice the largest distance thick (the
/// margin a piece also floods on each side, see [`opening_l1_pieces`]), and not below
/// [`MIN_VOXELS_PER_FLOOD_PIECE`] voxels each.
fn flood_pieces(dims: [usize; 3], max_d: usize, wide: bool) -> usize {
    let n = dims[0] * dims[1] * dims[2];
    let extent = dims.into_iter().max().unwrap_or(0);
    let cap = if wide || max_d >= u16::MAX as usize - 1 {
        2
    } else {
        4
    };
    rayon::current_num_threads()
        .min(cap)
        .min(extent / (2 * max_d).max(1))
        .min(n / MIN_VOXELS_PER_FLOOD_PIECE)
        .max(1)
}

/// One piece of a split flood: the voxels it answers for, `[lo, hi)` along the split axis, and
/// the padded opening it flooded (exact on those voxels).
struct Piece<W> {
    lo: usize,
    hi: usize,
    opening: Vec<W>,
}

/// The body of [`opening_l1`] with flood words `W` (which hold every distance up to `max_d`).
///
/// With more than one piece the grid is cut along its longest axis into slabs of about equal
/// flood work (weighed by the sum of D1 per slice: a voxel is expanded about as many times as
/// it is far from the solid), and each slab is flooded on its own, concurrently, with its own
/// state and levels: from every maximal-ball centre whose ball reaches the slab, through the
/// slab and a margin of `max_d − 1` slices on each side (voxels beyond the margin count as
/// solid). This is exact on the slab: a ball reaching it has its centre within the margin, and
/// a ball (all empty) and an axis slab both contain the monotone lattice paths between their
/// points, so the restricted flood still reaches ball ∩ (slab + margin) in d1 steps, and the
/// pruning argument of [`opening_map_l1`] holds inside it. The opening is a maximum over balls,
/// so which piece floods which ball does not matter: the result equals the single flood's.
fn opening_l1_words<W: Word>(
    dims: [usize; 3],
    distance_l1: &[u32],
    max_d: usize,
    pieces: usize,
) -> (Vec<u32>, Vec<u32>) {
    let [nx, ny, nz] = dims;
    let n = nx * ny * nz;
    assert_eq!(distance_l1.len(), n);
    let (px, py) = (nx + 2, ny + 2);
    let plane = px * py;
    let padded = |x: usize, y: usize, z: usize| (x + 1) + px * (y + 1) + plane * (z + 1);
    let len = plane * (nz + 2);
    // The padded distances (solid padding; an infinite distance, which only a grid without any
    // occupied voxel has, becomes W::SOLID and is no centre).
    let mut dist = vec![W::ZERO; len];
    dist.par_chunks_mut(plane)
        .enumerate()
        .for_each(|(pz, dist)| {
            if pz == 0 || pz > nz {
                return;
            }
            for y in 0..ny {
                let row = &distance_l1[nx * (y + ny * (pz - 1))..][..nx];
                let start = 1 + px * (y + 1);
                for (x, &d) in row.iter().enumerate() {
                    dist[start + x] = if d == u32::MAX { W::SOLID } else { W::of(d) };
                }
            }
        });
    let steps = [1, px, plane];
    // Maximal-ball centres by level (counting sort). A row's centres: no 6-neighbour one farther
    // from the solid. The six neighbour rows are slices as long as the row, so the loop needs no
    // bounds tests.
    let row_centres = |row: usize, out: &mut Vec<u32>| {
        let at = |o: usize| &dist[o..o + nx];
        let (c, x0, x1) = (at(row), at(row - 1), at(row + 1));
        let (y0, y1, z0, z1) = (at(row - px), at(row + px), at(row - plane), at(row + plane));
        for x in 0..nx {
            let d = c[x];
            // Wrapping: `d` may be the largest word (no solid anywhere); SOLID rejects it below.
            let up = d.get().wrapping_add(1);
            if d != W::ZERO
                && d != W::SOLID
                && x0[x].get() != up
                && x1[x].get() != up
                && y0[x].get() != up
                && y1[x].get() != up
                && z0[x].get() != up
                && z1[x].get() != up
            {
                out.push((row + x) as u32);
            }
        }
    };
    let centres: Vec<u32> = (0..nz)
        .into_par_iter()
        .flat_map_iter(|z| {
            let mut out = Vec::new();
            for y in 0..ny {
                row_centres(padded(0, y, z), &mut out);
            }
            out
        })
        .collect();
    let mut first = vec![0usize; max_d + 2];
    for &i in &centres {
        first[dist[i as usize].get() as usize + 1] += 1;
    }
    for r in 0..=max_d {
        first[r + 1] += first[r];
    }
    let mut by_level = vec![0u32; centres.len()];
    let mut fill = first.clone();
    for &i in &centres {
        let r = dist[i as usize].get() as usize;
        by_level[fill[r]] = i;
        fill[r] += 1;
    }
    drop(dist);
    let axis = (0..3).max_by_key(|&a| (dims[a], a)).unwrap_or(0);
    // Coordinate along the split axis of a padded index.
    let coord = |i: usize| match axis {
        0 => i % px - 1,
        1 => (i / px) % py - 1,
        _ => i / plane - 1,
    };
    let bounds = slab_bounds(dims, axis, distance_l1, pieces);
    let margin = max_d.saturating_sub(1);
    let flood_slab = |k: usize| -> Piece<W> {
        let (lo, hi) = (bounds[k], bounds[k + 1]);
        let region = (lo.saturating_sub(margin), (hi + margin).min(dims[axis]));
        // The flood's initial state (see `flood`): solid voxels, the padding and the voxels
        // outside the region count as expanded with an unbounded budget.
        let mut state = vec![W::SOLID; len];
        state
            .par_chunks_mut(plane)
            .enumerate()
            .for_each(|(pz, state)| {
                if pz == 0 || pz > nz || (axis == 2 && !(region.0..region.1).contains(&(pz - 1))) {
                    return;
                }
                for y in 0..ny {
                    if axis == 1 && !(region.0..region.1).contains(&y) {
                        continue;
                    }
                    let row = &distance_l1[nx * (y + ny * (pz - 1))..][..nx];
                    let start = 1 + px * (y + 1);
                    let (x0, x1) = if axis == 0 { region } else { (0, nx) };
                    for x in x0..x1 {
                        if row[x] != 0 {
                            state[start + x] = W::ZERO;
                        }
                    }
                }
            });
        // The centres whose ball (radius r: voxels closer than r) reaches the slab, by level.
        let opening = if pieces == 1 {
            flood::<W>(state, &by_level, &first, max_d, steps)
        } else {
            let mut mine = Vec::new();
            let mut mine_first = vec![0usize; max_d + 2];
            for r in 1..=max_d {
                mine.extend(by_level[first[r]..first[r + 1]].iter().filter(|&&i| {
                    let c = coord(i as usize);
                    c + r > lo && c < hi + r - 1
                }));
                mine_first[r + 1] = mine.len();
            }
            flood::<W>(state, &mine, &mine_first, max_d, steps)
        };
        Piece { lo, hi, opening }
    };
    let floods: Vec<Piece<W>> = (0..pieces).into_par_iter().map(flood_slab).collect();
    // Ω1 and Ω1 − D1 on the unpadded grid, row by row, each voxel from the piece of its slab.
    let mut out = vec![0u32; n];
    let mut decenterness = vec![0u32; n];
    out.par_chunks_mut(nx.max(1))
        .zip(decenterness.par_chunks_mut(nx.max(1)))
        .enumerate()
        .for_each(|(r, (row, dc))| {
            let (y, z) = (r % ny, r / ny);
            let d = &distance_l1[r * nx..][..nx];
            for piece in &floods {
                let (x0, x1) = match axis {
                    0 => (piece.lo, piece.hi),
                    1 if (piece.lo..piece.hi).contains(&y) => (0, nx),
                    2 if (piece.lo..piece.hi).contains(&z) => (0, nx),
                    _ => continue,
                };
                let flooded = &piece.opening[padded(0, y, z)..][..nx];
                for x in x0..x1 {
                    let o = flooded[x].get();
                    row[x] = o;
                    dc[x] = o.saturating_sub(d[x]);
                }
            }
        });
    (out, decenterness)
}

/// Slab bounds along `axis` (`pieces + 1` increasing values from 0 to the grid's extent) that
/// cut the sum of the distances into about equal parts.
fn slab_bounds(dims: [usize; 3], axis: usize, distance_l1: &[u32], pieces: usize) -> Vec<usize> {
    let extent = dims[axis];
    assert!(pieces >= 1 && pieces <= extent.max(1));
    let [nx, ny, _] = dims;
    let mut weight = vec![0u64; extent];
    if pieces > 1 {
        weight = distance_l1
            .par_chunks(nx.max(1))
            .enumerate()
            .fold(
                || vec![0u64; extent],
                |mut w, (r, row)| {
                    let add = |d: u32| if d == u32::MAX { 0 } else { d as u64 };
                    match axis {
                        0 => w.iter_mut().zip(row).for_each(|(w, &d)| *w += add(d)),
                        1 => w[r % ny] += row.iter().map(|&d| add(d)).sum::<u64>(),
                        _ => w[r / ny] += row.iter().map(|&d| add(d)).sum::<u64>(),
                    }
                    w
                },
            )
            .reduce(
                || vec![0u64; extent],
                |mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(a, b)| *a += b);
                    a
                },
            );
    }
    let total: u64 = weight.iter().sum();
    let mut bounds = vec![0usize];
    let mut sum = 0u64;
    for c in 1..extent {
        sum += weight[c - 1];
        let k = bounds.len();
        // Cut before slice c once the slices before it hold k/pieces of the weight, or when
        // exactly one slice is left for each slab still to come.
        if k < pieces && (sum * pieces as u64 >= k as u64 * total || extent - c == pieces - k) {
            bounds.push(c);
        }
    }
    bounds.push(extent);
    bounds
}

/// A level or budget word of the L1 flood (u16 when the distances fit, u32 otherwise).
trait Word: Copy + Ord + Send + Sync {
    const ZERO: Self;
    const SOLID: Self;
    fn of(v: u32) -> Self;
    fn get(self) -> u32;
}

impl Word for u16 {
    const ZERO: Self = 0;
    const SOLID: Self = u16::MAX;
    fn of(v: u32) -> Self {
        v as u16
    }
    fn get(self) -> u32 {
        self as u32
    }
}

impl Word for u32 {
    const ZERO: Self = 0;
    const SOLID: Self = u32::MAX;
    fn of(v: u32) -> Self {
        v
    }
    fn get(self) -> u32 {
        self
    }
}

/// The level-by-level flood of [`opening_map_l1`] on the padded grid, from the initial state
/// (per voxel: the largest remaining budget it was expanded with, plus one; 0 = never; solid
/// voxels count as expanded with an unbounded budget, so one test rejects both); returns the
/// padded opening map.
///
/// The inner loops index `state` and `opening` without bounds checks (a quarter of the flood's
/// instructions were bounds tests). Sound because every listed voxel lies inside the one-voxel
/// padding, so its six neighbours lie in the grid: a voxel is listed or marked only when its state
/// is at most the budget, which the padding's state, `W::SOLID` (larger than every budget, as
/// `max_d < W::SOLID − 1`), never is; the padding is set solid here.
fn flood<W: Word>(
    mut state: Vec<W>,
    by_level: &[u32],
    first: &[usize],
    max_d: usize,
    steps: [usize; 3],
) -> Vec<W> {
    let len = state.len();
    if max_d == 0 {
        return vec![W::ZERO; len];
    }
    let (px, plane) = (steps[1], steps[2]);
    assert!(steps[0] == 1 && px >= 3 && plane % px == 0 && plane / px >= 3);
    assert!(len % plane == 0 && len / plane >= 3 && max_d < W::SOLID.get() as usize - 1);
    state[..plane].fill(W::SOLID);
    state[len - plane..].fill(W::SOLID);
    for slab in state.chunks_exact_mut(plane) {
        slab[..px].fill(W::SOLID);
        slab[plane - px..].fill(W::SOLID);
        for row in slab.chunks_exact_mut(px) {
            row[0] = W::SOLID;
            row[px - 1] = W::SOLID;
        }
    }
    let mut opening: Vec<W> = vec![W::ZERO; len];
    // A round lists a voxel at most once (it is marked first) and each listed voxel lists at
    // most its six neighbours, so a round needs min(6 x frontier, len) entries, reserved before
    // it; the rounds write the spare capacity (no growth or length updates per voxel). Reserving
    // per round keeps the lists as large as the widest round, not the whole grid per piece.
    let mut frontier: Vec<u32> = Vec::new();
    let mut next: Vec<u32> = Vec::new();
    for r in (1..=max_d).rev() {
        frontier.clear();
        let level = W::of(r as u32);
        let mut budget = r as u32 - 1;
        for &i in &by_level[first[r]..first[r + 1]] {
            if state[i as usize].get() <= budget {
                state[i as usize] = W::of(budget + 1);
                frontier.push(i);
            }
        }
        while !frontier.is_empty() {
            next.clear();
            next.reserve((6 * frontier.len()).min(len));
            let spare = next.spare_capacity_mut();
            let mut listed = 0;
            let (below, mark) = (W::of(budget.wrapping_sub(1)), W::of(budget));
            for &i in &frontier {
                let i = i as usize;
                // SAFETY: `i` is a listed voxel, inside the padding (see above).
                let o = unsafe { opening.get_unchecked_mut(i) };
                if *o == W::ZERO {
                    *o = level;
                }
                if budget == 0 {
                    continue;
                }
                let around = [
                    i - steps[0],
                    i + steps[0],
                    i - steps[1],
                    i + steps[1],
                    i - steps[2],
                    i + steps[2],
                ];
                if budget == 1 {
                    // The last step: a neighbour reached with budget 0 only takes the level,
                    // so it is marked here instead of being listed for one more round.
                    for j in around {
                        // SAFETY: `j` is a neighbour of a listed voxel, so in the grid.
                        let s = unsafe { state.get_unchecked_mut(j) };
                        if *s == W::ZERO {
                            *s = mark;
                            // SAFETY: as above.
                            let o = unsafe { opening.get_unchecked_mut(j) };
                            if *o == W::ZERO {
                                *o = level;
                            }
                        }
                    }
                    continue;
                }
                for j in around {
                    // SAFETY: `j` is a neighbour of a listed voxel, so in the grid.
                    let s = unsafe { state.get_unchecked_mut(j) };
                    if *s <= below {
                        *s = mark;
                        spare[listed].write(j as u32);
                        listed += 1;
                    }
                }
            }
            // SAFETY: the first `listed` entries of the spare capacity were written above.
            unsafe { next.set_len(listed) };
            if budget <= 1 {
                break;
            }
            budget -= 1;
            std::mem::swap(&mut frontier, &mut next);
        }
    }
    opening
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::distance::{distance_map, voxel_distance, Metric, Outside};
    use crate::analysis::grid::VoxelSet;
    use crate::math::Rng;

    fn random_set(dims: [usize; 3], density: f32, rng: &mut Rng) -> VoxelSet {
        VoxelSet::random(dims[0] * dims[1] * dims[2], density, rng)
    }

    /// Brute force of Definition 10.4 (or its L1 analogue): the largest D(y) over balls
    /// {x : d(x, y) < D(y)} containing x.
    fn brute_opening(dims: [usize; 3], d: &[u32], metric: Metric) -> Vec<u32> {
        let n = d.len();
        (0..n)
            .map(|x| {
                (0..n)
                    .filter(|&y| {
                        d[y] > 0
                            && d[y] != u32::MAX
                            && voxel_distance(dims, x, y, metric) < d[y] as u64
                    })
                    .map(|y| d[y])
                    .max()
                    .unwrap_or(0)
            })
            .collect()
    }

    #[test]
    fn openings_equal_brute_force_and_forest_is_valid() {
        let mut rng = Rng::new(8, 8);
        for dims in [[6, 5, 4], [12, 9, 7], [20, 3, 9]] {
            for density in [0.03f32, 0.1, 0.3] {
                let occ = random_set(dims, density, &mut rng);
                for outside in [Outside::Solid, Outside::Empty] {
                    let d26 = distance_map(dims, &occ, Metric::Chessboard, outside, false).values;
                    if d26.contains(&u32::MAX) {
                        continue;
                    }
                    let om = opening_map_26(dims, &d26);
                    assert_eq!(
                        om.opening,
                        brute_opening(dims, &d26, Metric::Chessboard),
                        "{dims:?} {density}"
                    );
                    for x in 0..d26.len() {
                        if d26[x] == 0 {
                            continue;
                        }
                        let c = om.center[x] as usize;
                        // Definition 10.7: the parent's ball has the voxel's opening as radius
                        // and contains it; a voxel is its own parent iff opening = distance.
                        assert_eq!(d26[c], om.opening[x]);
                        assert!(voxel_distance(dims, x, c, Metric::Chessboard) < d26[c] as u64);
                        assert_eq!(c == x, om.opening[x] == d26[x]);
                    }
                    let d1 = distance_map(dims, &occ, Metric::L1, outside, false).values;
                    let want = brute_opening(dims, &d1, Metric::L1);
                    assert_eq!(opening_map_l1(dims, &d1), want, "L1 {dims:?}");
                    let (wide, dc) = opening_l1(dims, &d1, true, None);
                    assert_eq!(wide, want, "L1 wide {dims:?}");
                    let want_dc: Vec<u32> = want
                        .iter()
                        .zip(&d1)
                        .map(|(o, d)| o.saturating_sub(*d))
                        .collect();
                    assert_eq!(dc, want_dc, "decenterness {dims:?}");
                    assert_eq!(opening_and_decenterness_l1(dims, &d1).1, want_dc);
                    // The flood split into slabs (along the longest axis) gives the same maps.
                    for pieces in [2, 3, 4, 7] {
                        for wide in [false, true] {
                            let (split, dc) = opening_l1(dims, &d1, wide, Some(pieces));
                            assert_eq!(split, want, "L1 {dims:?} {pieces} pieces");
                            assert_eq!(dc, want_dc, "decenterness {dims:?} {pieces} pieces");
                        }
                    }
                }
            }
        }
    }

    /// The split flood on grids large enough to be split on 2 and 3 threads, with empty space
    /// along the cuts and balls across them, equals the single flood, whatever the thread count
    /// and the axis of the cut.
    #[test]
    fn split_flood_equals_single_flood_on_1_2_3_threads() {
        let mut rng = Rng::new(9, 2);
        for dims in [[130, 40, 41], [41, 130, 40], [40, 41, 130]] {
            for density in [0.004f32, 0.02] {
                let occ = random_set(dims, density, &mut rng);
                let d1 = distance_map(dims, &occ, Metric::L1, Outside::Solid, false).values;
                let max_d = max_distance(&d1);
                let single = opening_l1(dims, &d1, false, Some(1));
                for threads in [1, 2, 3] {
                    let pool = rayon::ThreadPoolBuilder::new()
                        .num_threads(threads)
                        .build()
                        .unwrap();
                    let pieces = pool.install(|| flood_pieces(dims, max_d, false));
                    assert_eq!(pieces, threads, "{dims:?} {density} max_d {max_d}");
                    let got = pool.install(|| opening_and_decenterness_l1(dims, &d1));
                    assert!(got == single, "{dims:?} {density} {threads} threads");
                }
            }
        }
    }

    /// Slab bounds are increasing, cover the axis, and follow the weight.
    #[test]
    fn slab_bounds_cover_the_axis() {
        let dims = [5, 12, 3];
        let mut d = vec![0u32; 5 * 12 * 3];
        // All the weight in slices y = 9 and 10.
        for z in 0..3 {
            for x in 0..5 {
                d[x + 5 * (9 + 12 * z)] = 4;
                d[x + 5 * (10 + 12 * z)] = 4;
            }
        }
        assert_eq!(slab_bounds(dims, 1, &d, 1), vec![0, 12]);
        assert_eq!(slab_bounds(dims, 1, &d, 2), vec![0, 10, 12]);
        let b = slab_bounds(dims, 1, &d, 4);
        assert_eq!(b, vec![0, 9, 10, 11, 12]);
        let b = slab_bounds(dims, 0, &vec![0; d.len()], 5);
        assert_eq!(b, vec![0, 1, 2, 3, 4, 5]);
    }
}
