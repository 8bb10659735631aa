//! Conservative (26-separating) surface voxelization: every voxel whose closed box meets a
//! triangle is occupied, so no straight path can cross a wall without entering an occupied
//! voxel, however thin the wall. Decided per voxel by the separating-axis test of
//! Akenine-Möller (2001) in f64 grid coordinates, with the box widened by `BOX_SLACK` voxels
//! so that rounding in the world-to-grid transform can only add voxels, never drop one.

use rayon::prelude::*;

use super::grid::{AtomicVoxelSet, VoxelGrid, VoxelSet};

/// Widening of each voxel box, in voxels, absorbing the rounding of the world-to-grid
/// transform (relative 1e-16 of coordinates that are at most 2^31): conservative by
/// construction.
pub const BOX_SLACK: f64 = 1e-9;

type P = [f64; 3];

#[inline]
fn sub(a: P, b: P) -> P {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
fn dot(a: P, b: P) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
fn cross(a: P, b: P) -> P {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// True when triangle `t` meets the closed axis-aligned box of centre `c` and half-size `h`
/// (separating-axis theorem: box normals, triangle normal, nine edge-cross axes). Touching
/// counts as meeting.
pub fn triangle_meets_box(t: [P; 3], c: P, h: f64) -> bool {
    let v = [sub(t[0], c), sub(t[1], c), sub(t[2], c)];
    for i in 0..3 {
        let lo = v[0][i].min(v[1][i]).min(v[2][i]);
        let hi = v[0][i].max(v[1][i]).max(v[2][i]);
        if lo > h || hi < -h {
            return false;
        }
    }
    let e = [sub(v[1], v[0]), sub(v[2], v[1]), sub(v[0], v[2])];
    let n = cross(e[0], e[1]);
    if dot(n, v[0]).abs() > h * (n[0].abs() + n[1].abs() + n[2].abs()) {
        return false;
    }
    for edge in e {
        for axis in 0..3 {
            let mut u = [0.0; 3];
            u[axis] = 1.0;
            let a = cross(edge, u);
            let r = h * (a[0].abs() + a[1].abs() + a[2].abs());
            let p = [dot(a, v[0]), dot(a, v[1]), dot(a, v[2])];
            if p[0].min(p[1]).min(p[2]) > r || p[0].max(p[1]).max(p[2]) < -r {
                return false;
            }
        }
    }
    true
}

/// The separating-axis test of [`triangle_meets_box`] with everything that depends only on the
/// triangle computed once: per candidate box it costs one dot product and two comparisons per
/// axis. The algebra is the same (the projection of v_i − c on an axis a is a·v_i − a·c); the
/// rounding differs by a few ulps, far inside `BOX_SLACK`.
struct TriangleTest {
    lo: P,
    hi: P,
    /// Triangle normal, n·v0 and the box's projection radius per unit half-size.
    n: P,
    d: f64,
    rn: f64,
    /// The nine edge-cross axes: axis, min and max of a·v_i, projection radius per half-size.
    axes: [(P, f64, f64, f64); 9],
}

impl TriangleTest {
    fn new(t: [P; 3]) -> TriangleTest {
        let lo = [0, 1, 2].map(|i| t[0][i].min(t[1][i]).min(t[2][i]));
        let hi = [0, 1, 2].map(|i| t[0][i].max(t[1][i]).max(t[2][i]));
        let e = [sub(t[1], t[0]), sub(t[2], t[1]), sub(t[0], t[2])];
        let n = cross(e[0], e[1]);
        let mut axes = [([0.0; 3], 0.0, 0.0, 0.0); 9];
        for (k, edge) in e.iter().enumerate() {
            for axis in 0..3 {
                let mut u = [0.0; 3];
                u[axis] = 1.0;
                let a = cross(*edge, u);
                let p = [dot(a, t[0]), dot(a, t[1]), dot(a, t[2])];
                axes[3 * k + axis] = (
                    a,
                    p[0].min(p[1]).min(p[2]),
                    p[0].max(p[1]).max(p[2]),
                    a[0].abs() + a[1].abs() + a[2].abs(),
                );
            }
        }
        TriangleTest {
            lo,
            hi,
            n,
            d: dot(n, t[0]),
            rn: n[0].abs() + n[1].abs() + n[2].abs(),
            axes,
        }
    }

    /// Whether the triangle meets the closed box of centre `c` and half-size `h`.
    #[inline]
    fn meets(&self, c: P, h: f64) -> bool {
        if (0..3).any(|i| self.lo[i] - c[i] > h || self.hi[i] - c[i] < -h) {
            return false;
        }
        if (self.d - dot(self.n, c)).abs() > h * self.rn {
            return false;
        }
        self.axes.iter().all(|&(a, pmin, pmax, ra)| {
            let ac = dot(a, c);
            let r = h * ra;
            !(pmin - ac > r || pmax - ac < -r)
        })
    }
}

/// Inclusive voxel range along one axis touched by the closed interval [lo, hi].
#[inline]
fn voxel_range(lo: f64, hi: f64, n: usize) -> Option<(usize, usize)> {
    let a = (lo - BOX_SLACK).floor().max(0.0);
    let b = (hi + BOX_SLACK).floor().min(n as f64 - 1.0);
    (a <= b).then_some((a as usize, b as usize))
}

/// Marks the voxels a triangle (in grid coordinates) meets. Iterates over columns along the
/// triangle's dominant normal axis and tests only the voxels its plane crosses in each column,
/// so large tilted triangles cost their area, not their bounding box.
fn voxelize_triangle(grid: &VoxelGrid, t: [P; 3], out: &AtomicVoxelSet) {
    let dims = grid.dims;
    let mut range = [(0usize, 0usize); 3];
    for i in 0..3 {
        let lo = t[0][i].min(t[1][i]).min(t[2][i]);
        let hi = t[0][i].max(t[1][i]).max(t[2][i]);
        match voxel_range(lo, hi, dims[i]) {
            Some(r) => range[i] = r,
            None => return,
        }
    }
    let n = cross(sub(t[1], t[0]), sub(t[2], t[0]));
    let k = if n[0].abs() >= n[1].abs() && n[0].abs() >= n[2].abs() {
        0
    } else if n[1].abs() >= n[2].abs() {
        1
    } else {
        2
    };
    let (a, b) = ((k + 1) % 3, (k + 2) % 3);
    let h = 0.5 + BOX_SLACK;
    let d = dot(n, t[0]);
    let test = TriangleTest::new(t);
    for i in range[a].0..=range[a].1 {
        for j in range[b].0..=range[b].1 {
            // Extent of the plane along k over the column's (widened) square.
            let (mut k_lo, mut k_hi) = (range[k].0, range[k].1);
            if n[k] != 0.0 {
                let mut lo = f64::INFINITY;
                let mut hi = f64::NEG_INFINITY;
                for (ca, cb) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
                    let pa = i as f64 + ca * (1.0 + 2.0 * BOX_SLACK) - BOX_SLACK;
                    let pb = j as f64 + cb * (1.0 + 2.0 * BOX_SLACK) - BOX_SLACK;
                    let pk = (d - n[a] * pa - n[b] * pb) / n[k];
                    lo = lo.min(pk);
                    hi = hi.max(pk);
                }
                // Guard the division's rounding with one extra voxel each side; the exact
                // test below decides.
                match voxel_range(lo - 1e-6, hi + 1e-6, dims[k]) {
                    Some((l, u)) => {
                        k_lo = k_lo.max(l);
                        k_hi = k_hi.min(u);
                    }
                    None => continue,
                }
            }
            if k_lo > k_hi {
                continue;
            }
            for m in k_lo..=k_hi {
                let mut c = [0usize; 3];
                c[a] = i;
                c[b] = j;
                c[k] = m;
                let centre = [c[0] as f64 + 0.5, c[1] as f64 + 0.5, c[2] as f64 + 0.5];
                if test.meets(centre, h) {
                    out.set(grid.index(c[0], c[1], c[2]));
                }
            }
        }
    }
}

/// Voxelizes triangles given in world space, in parallel.
pub fn voxelize(grid: &VoxelGrid, triangles: &[[crate::math::Vec3; 3]]) -> VoxelSet {
    let out = AtomicVoxelSet::new(grid.len());
    triangles.par_iter().for_each(|t| {
        let g = t.map(|p| grid.to_grid(p));
        voxelize_triangle(grid, g, &out);
    });
    VoxelSet::from_atomic(out.words, grid.len())
}

/// Voxelizes triangles already in grid coordinates (tests and callers with their own transform).
pub fn voxelize_grid_space(grid: &VoxelGrid, triangles: &[[P; 3]]) -> VoxelSet {
    let out = AtomicVoxelSet::new(grid.len());
    triangles
        .par_iter()
        .for_each(|&t| voxelize_triangle(grid, t, &out));
    VoxelSet::from_atomic(out.words, grid.len())
}

/// Marks as occupied every free voxel that cannot be reached from the grid's boundary through
/// 6-connected free voxels: the inside of closed objects is then not "empty space".
pub fn fill_interiors(grid: &VoxelGrid, occupied: &mut VoxelSet) -> usize {
    let [nx, ny, nz] = grid.dims;
    let mut outside = VoxelSet::new(grid.len());
    let mut stack = Vec::new();
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                if x == 0 || y == 0 || z == 0 || x == nx - 1 || y == ny - 1 || z == nz - 1 {
                    let i = grid.index(x, y, z);
                    if !occupied.get(i) && !outside.get(i) {
                        outside.set(i);
                        stack.push(i);
                    }
                }
            }
        }
    }
    while let Some(i) = stack.pop() {
        let [x, y, z] = grid.coords(i);
        let mut visit = |j: usize| {
            if !occupied.get(j) && !outside.get(j) {
                outside.set(j);
                stack.push(j);
            }
        };
        if x > 0 {
            visit(i - 1);
        }
        if x + 1 < nx {
            visit(i + 1);
        }
        if y > 0 {
            visit(i - nx);
        }
        if y + 1 < ny {
            visit(i + nx);
        }
        if z > 0 {
            visit(i - nx * ny);
        }
        if z + 1 < nz {
            visit(i + nx * ny);
        }
    }
    let mut filled = 0;
    for i in 0..grid.len() {
        if !occupied.get(i) && !outside.get(i) {
            occupied.set(i);
            filled += 1;
        }
    }
    filled
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    fn grid(n: usize) -> VoxelGrid {
        VoxelGrid {
            dims: [n, n, n],
            origin: [0.0; 3],
            voxel_size: 1.0,
        }
    }

    /// Exact oracle: coordinates are multiples of 1/16 in [0, 16], so every product in the
    /// separating-axis test is exact in f64 and touching is decided exactly.
    fn oracle(g: &VoxelGrid, t: [P; 3]) -> VoxelSet {
        let mut s = VoxelSet::new(g.len());
        for i in 0..g.len() {
            let c = g.coords(i);
            if triangle_meets_box(
                t,
                [c[0] as f64 + 0.5, c[1] as f64 + 0.5, c[2] as f64 + 0.5],
                0.5,
            ) {
                s.set(i);
            }
        }
        s
    }

    fn dyadic(rng: &mut Rng, n: usize) -> f64 {
        rng.below((n * 16) as u32 + 1) as f64 / 16.0
    }

    fn check(g: &VoxelGrid, t: [P; 3]) {
        let got = voxelize_grid_space(g, &[t]);
        let want = oracle(g, t);
        for i in 0..g.len() {
            assert!(
                !want.get(i) || got.get(i),
                "voxel {:?} meets {t:?} but was not marked",
                g.coords(i)
            );
            // Not over-conservative: anything marked is within the slack of the triangle.
            if got.get(i) && !want.get(i) {
                let c = g.coords(i);
                assert!(triangle_meets_box(
                    t,
                    [c[0] as f64 + 0.5, c[1] as f64 + 0.5, c[2] as f64 + 0.5],
                    0.5 + 1e-6
                ));
            }
        }
    }

    #[test]
    fn conservative_on_random_and_adversarial_triangles() {
        let g = grid(12);
        let mut rng = Rng::new(77, 0);
        for _ in 0..300 {
            let t = [0, 1, 2].map(|_| {
                [
                    dyadic(&mut rng, 12),
                    dyadic(&mut rng, 12),
                    dyadic(&mut rng, 12),
                ]
            });
            check(&g, t);
        }
        // Slivers and small triangles.
        for _ in 0..200 {
            let a = [
                dyadic(&mut rng, 11),
                dyadic(&mut rng, 11),
                dyadic(&mut rng, 11),
            ];
            let b = [a[0] + 1.0 / 16.0, a[1] + rng.below(16) as f64 / 16.0, a[2]];
            let c = [
                a[0] + 3.0 / 16.0,
                a[1] + 2.0 / 16.0,
                a[2] + rng.below(3) as f64 / 16.0,
            ];
            check(&g, [a, b, c]);
        }
        // Axis-aligned triangles lying exactly on voxel boundaries, and edges along grid lines.
        for k in 0..3 {
            for off in [0.0, 3.0, 5.5, 12.0] {
                let mut p = [[1.0, 2.0, 0.0], [9.0, 2.0, 0.0], [1.0, 8.0, 0.0]];
                for v in p.iter_mut() {
                    v.rotate_right(k);
                    v[k] = off;
                }
                check(&g, p);
            }
        }
        check(&g, [[3.0, 3.0, 3.0], [3.0, 3.0, 3.0], [3.0, 3.0, 3.0]]); // a point on a corner
        check(&g, [[3.0, 3.0, 3.0], [7.0, 3.0, 3.0], [7.0, 3.0, 3.0]]); // a segment on an edge
        check(&g, [[0.0, 0.0, 0.0], [12.0, 12.0, 12.0], [12.0, 0.0, 12.0]]); // big and tilted
    }

    /// A one-voxel corner point is marked in all eight voxels sharing it.
    #[test]
    fn grid_corner_touches_eight_voxels() {
        let g = grid(4);
        let s = voxelize_grid_space(&g, &[[[2.0, 2.0, 2.0], [2.0, 2.0, 2.0], [2.0, 2.0, 2.0]]]);
        assert_eq!(s.count(), 8);
    }

    #[test]
    fn interiors_of_closed_boxes_are_filled() {
        let g = grid(10);
        // A closed cube [2, 8]^3 from 12 triangles.
        let c = |x: f64, y: f64, z: f64| [x, y, z];
        let (a, b) = (2.0, 8.0);
        let quads = [
            [c(a, a, a), c(b, a, a), c(b, b, a), c(a, b, a)],
            [c(a, a, b), c(b, a, b), c(b, b, b), c(a, b, b)],
            [c(a, a, a), c(b, a, a), c(b, a, b), c(a, a, b)],
            [c(a, b, a), c(b, b, a), c(b, b, b), c(a, b, b)],
            [c(a, a, a), c(a, b, a), c(a, b, b), c(a, a, b)],
            [c(b, a, a), c(b, b, a), c(b, b, b), c(b, a, b)],
        ];
        let tris: Vec<[P; 3]> = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        let mut s = voxelize_grid_space(&g, &tris);
        let shell = s.count();
        // Shell: voxels 1..=8 touched on the boundary planes; interior 3..=6 free.
        assert_eq!(shell, 8 * 8 * 8 - 4 * 4 * 4);
        let filled = fill_interiors(&g, &mut s);
        assert_eq!(filled, 4 * 4 * 4);
        assert_eq!(s.count(), 8 * 8 * 8);
    }
}
