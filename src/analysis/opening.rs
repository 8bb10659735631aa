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
    opening_l1(dims, distance_l1, false).0
}

/// [`opening_map_l1`] and the L1 decenterness Ω1 − D1 (000 §6.2.2) together, both written in
/// the same pass over the flood's result.
pub fn opening_and_decenterness_l1(dims: [usize; 3], distance_l1: &[u32]) -> (Vec<u32>, Vec<u32>) {
    opening_l1(dims, distance_l1, false)
}

/// [`opening_and_decenterness_l1`], with 32-bit flood words even when 16 bits would do if
/// `wide`.
fn opening_l1(dims: [usize; 3], distance_l1: &[u32], wide: bool) -> (Vec<u32>, Vec<u32>) {
    let max_d = distance_l1
        .par_iter()
        .copied()
        .filter(|&d| d != u32::MAX)
        .max()
        .unwrap_or(0) as usize;
    // 16-bit distances, state and levels halve the memory traffic of the flood when the
    // distances fit.
    if !wide && max_d < u16::MAX as usize - 1 {
        opening_l1_words::<u16>(dims, distance_l1, max_d)
    } else {
        opening_l1_words::<u32>(dims, distance_l1, max_d)
    }
}

/// The body of [`opening_l1`] with flood words `W` (which hold every distance up to `max_d`).
fn opening_l1_words<W: Word>(
    dims: [usize; 3],
    distance_l1: &[u32],
    max_d: usize,
) -> (Vec<u32>, Vec<u32>) {
    let [nx, ny, nz] = dims;
    let n = nx * ny * nz;
    assert_eq!(distance_l1.len(), n);
    let (px, py) = (nx + 2, ny + 2);
    let plane = px * py;
    let padded = |x: usize, y: usize, z: usize| (x + 1) + px * (y + 1) + plane * (z + 1);
    // The padded distances (solid padding; an infinite distance, which only a grid without any
    // occupied voxel has, becomes W::SOLID and is no centre) and the flood's initial state
    // (see `flood`), in one pass.
    let len = plane * (nz + 2);
    let mut dist = vec![W::ZERO; len];
    let mut state = vec![W::SOLID; len];
    dist.par_chunks_mut(plane)
        .zip(state.par_chunks_mut(plane))
        .enumerate()
        .for_each(|(pz, (dist, state))| {
            if pz == 0 || pz > nz {
                return;
            }
            for y in 0..ny {
                let row = &distance_l1[nx * (y + ny * (pz - 1))..][..nx];
                let start = 1 + px * (y + 1);
                for (x, &d) in row.iter().enumerate() {
                    dist[start + x] = if d == u32::MAX { W::SOLID } else { W::of(d) };
                    if d != 0 {
                        state[start + x] = W::ZERO;
                    }
                }
            }
        });
    let steps = [1, px, plane];
    // Maximal-ball centres by level (counting sort).
    let is_centre = |i: usize| {
        let d = dist[i];
        d != W::ZERO
            && d != W::SOLID
            && steps
                .iter()
                .all(|&s| dist[i - s].get() != d.get() + 1 && dist[i + s].get() != d.get() + 1)
    };
    let centres: Vec<u32> = (0..nz)
        .into_par_iter()
        .flat_map_iter(|z| {
            let mut out = Vec::new();
            for y in 0..ny {
                let row = padded(0, y, z);
                out.extend((row..row + nx).filter(|&i| is_centre(i)).map(|i| i as u32));
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
    let opening = flood::<W>(state, &by_level, &first, max_d, steps);
    // Ω1 and Ω1 − D1 on the unpadded grid, row by row.
    let mut out = vec![0u32; n];
    let mut decenterness = vec![0u32; n];
    out.par_chunks_mut(nx.max(1))
        .zip(decenterness.par_chunks_mut(nx.max(1)))
        .enumerate()
        .for_each(|(r, (row, dc))| {
            let (y, z) = (r % ny, r / ny);
            let flooded = &opening[padded(0, y, z)..][..nx];
            let d = &distance_l1[r * nx..][..nx];
            for x in 0..nx {
                let o = flooded[x].get();
                row[x] = o;
                dc[x] = o.saturating_sub(d[x]);
            }
        });
    (out, decenterness)
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
fn flood<W: Word>(
    mut state: Vec<W>,
    by_level: &[u32],
    first: &[usize],
    max_d: usize,
    steps: [usize; 3],
) -> Vec<W> {
    let mut opening: Vec<W> = vec![W::ZERO; state.len()];
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
            let (below, mark) = (W::of(budget.wrapping_sub(1)), W::of(budget));
            for &i in &frontier {
                let i = i as usize;
                if opening[i] == W::ZERO {
                    opening[i] = level;
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
                        if state[j] == W::ZERO {
                            state[j] = mark;
                            if opening[j] == W::ZERO {
                                opening[j] = level;
                            }
                        }
                    }
                    continue;
                }
                for j in around {
                    if state[j] <= below {
                        state[j] = mark;
                        next.push(j as u32);
                    }
                }
            }
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
        let n = dims[0] * dims[1] * dims[2];
        let mut s = VoxelSet::new(n);
        for i in 0..n {
            if rng.uniform() < density {
                s.set(i);
            }
        }
        s
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
                    let (wide, dc) = opening_l1(dims, &d1, true);
                    assert_eq!(wide, want, "L1 wide {dims:?}");
                    let want_dc: Vec<u32> = want
                        .iter()
                        .zip(&d1)
                        .map(|(o, d)| o.saturating_sub(*d))
                        .collect();
                    assert_eq!(dc, want_dc, "decenterness {dims:?}");
                    assert_eq!(opening_and_decenterness_l1(dims, &d1).1, want_dc);
                }
            }
        }
    }
}
