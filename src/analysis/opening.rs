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
/// distance exactly r (a larger ball contains the smaller one of the same centre) with a budget
/// of r - 1 steps, assigning r to voxels not assigned yet. A voxel reached with a budget no
/// larger than one it was already expanded with is not expanded again: everything within that
/// budget already received a larger level. 6-connected steps through empty voxels are L1 steps.
pub fn opening_map_l1(dims: [usize; 3], distance_l1: &[u32]) -> Vec<u32> {
    let n = dims[0] * dims[1] * dims[2];
    let max_d = distance_l1
        .iter()
        .copied()
        .filter(|&d| d != u32::MAX)
        .max()
        .unwrap_or(0) as usize;
    let mut by_level: Vec<Vec<u32>> = vec![Vec::new(); max_d + 1];
    for (i, &d) in distance_l1.iter().enumerate() {
        if d > 0 && d != u32::MAX {
            by_level[d as usize].push(i as u32);
        }
    }
    let mut opening = vec![0u32; n];
    // Largest remaining budget a voxel was expanded with, plus one (0 = never).
    let mut expanded = vec![0u32; n];
    let mut frontier: Vec<u32> = Vec::new();
    let mut next: Vec<u32> = Vec::new();
    let (sx, sy) = (dims[0], dims[0] * dims[1]);
    for r in (1..=max_d).rev() {
        frontier.clear();
        for &i in &by_level[r] {
            let budget = r as u32 - 1;
            if expanded[i as usize] <= budget {
                expanded[i as usize] = budget + 1;
                frontier.push(i);
            }
        }
        let mut budget = r as u32 - 1;
        loop {
            for &i in &frontier {
                if opening[i as usize] == 0 {
                    opening[i as usize] = r as u32;
                }
            }
            if budget == 0 || frontier.is_empty() {
                break;
            }
            budget -= 1;
            next.clear();
            for &i in &frontier {
                let i = i as usize;
                let (x, y, z) = (i % sx, (i / sx) % dims[1], i / sy);
                let mut push = |j: usize| {
                    if distance_l1[j] > 0 && expanded[j] <= budget {
                        expanded[j] = budget + 1;
                        next.push(j as u32);
                    }
                };
                if x > 0 {
                    push(i - 1);
                }
                if x + 1 < dims[0] {
                    push(i + 1);
                }
                if y > 0 {
                    push(i - sx);
                }
                if y + 1 < dims[1] {
                    push(i + sx);
                }
                if z > 0 {
                    push(i - sy);
                }
                if z + 1 < dims[2] {
                    push(i + sy);
                }
            }
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
                    assert_eq!(
                        opening_map_l1(dims, &d1),
                        brute_opening(dims, &d1, Metric::L1),
                        "L1 {dims:?}"
                    );
                }
            }
        }
    }
}
