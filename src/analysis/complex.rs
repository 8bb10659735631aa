//! The cubical complex of the empty space (000 §5.2, eq. 148-149): the closure of the closed
//! unit cubes of the empty voxels, stored as one byte per lattice vertex.
//!
//! # Layout
//!
//! A lattice vertex v = (x, y, z), 0 <= x <= w (and so on for a w x h x d voxel grid), owns
//! eight cells, one bit each: the point v, the edges [v, v+ex], [v, v+ey], [v, v+ez], the
//! squares with lower corner v spanning xy, yz and xz, and the cube [v, v+(1,1,1)], which is
//! voxel v. A cell is named by its owner vertex and its *span*, the set of axes it extends
//! along (bit 0 = x, 1 = y, 2 = z); its dimension is the size of the span.
//!
//! The byte array has one extra layer of vertices on every side (internal coordinate =
//! vertex coordinate + 1), always empty, so that the neighbours v - e_a and v + e_a of any real
//! vertex are valid indices and boundary tests need no branches. Cells that would stick out of
//! the grid are never set.
//!
//! # Connectivity convention
//!
//! The complex is the closure of *closed* cubes. Two empty voxels that share only an edge or a
//! corner therefore share that edge or corner in the complex and are connected: the empty space
//! is 26-connected and, dually, the solid is 6-connected (a solid region separates the empty
//! space only if it is a 6-connected wall). This is the convention of the whole skeleton: its
//! b0, b1, b2 are those of this complex, and [`Complex::betti`] computes them on the complex, so
//! the skeleton and the reported topology of the empty space always agree. A wall made of
//! voxels that only touch diagonally lets the skeleton through; [`diagonal_contacts`] counts
//! the lattice vertices where empty voxels meet only diagonally so such leaks can be reported.
//! The node map (Algorithm 5) propagates through 6-connected voxels, as the thesis does, and
//! then across diagonal contacts too, so that it covers every component of this complex that
//! holds a node (see [`super::skeleton::node_map`]).

use rayon::prelude::*;

use super::grid::VoxelSet;

/// Bit of each cell in a vertex byte.
pub const POINT: u8 = 1;
pub const X_EDGE: u8 = 2;
pub const Y_EDGE: u8 = 4;
pub const Z_EDGE: u8 = 8;
pub const XY_SQUARE: u8 = 16;
pub const YZ_SQUARE: u8 = 32;
pub const XZ_SQUARE: u8 = 64;
pub const CUBE: u8 = 128;
pub const EDGES: u8 = X_EDGE | Y_EDGE | Z_EDGE;
pub const SQUARES: u8 = XY_SQUARE | YZ_SQUARE | XZ_SQUARE;

/// Bit of the cell with a given span (bit 0 = x, bit 1 = y, bit 2 = z).
pub const SPAN_BIT: [u8; 8] = [
    POINT, X_EDGE, Y_EDGE, XY_SQUARE, Z_EDGE, XZ_SQUARE, YZ_SQUARE, CUBE,
];

/// Dimension of a span.
#[inline]
pub fn span_dim(span: u8) -> u32 {
    span.count_ones()
}

/// Topological summary: Betti numbers over GF(2) and the Euler characteristic.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Betti {
    pub b0: usize,
    pub b1: usize,
    pub b2: usize,
    pub euler: i64,
}

/// Per byte: points - edges + squares - cubes.
const fn euler_table() -> [i8; 256] {
    let mut t = [0i8; 256];
    let mut b = 0;
    while b < 256 {
        let mut s = 0i8;
        let mut span = 0;
        while span < 8 {
            if b as u8 & SPAN_BIT[span] != 0 {
                s += if (span as u8).count_ones() % 2 == 0 {
                    1
                } else {
                    -1
                };
            }
            span += 1;
        }
        t[b] = s;
        b += 1;
    }
    t
}
const EULER: [i8; 256] = euler_table();

/// Byte of a vertex from the emptiness of its eight surrounding voxels: bit s of `pattern` is
/// set when voxel v - s is empty (s a subset of axes, as a span). The cell of span m is present
/// iff some empty voxel contains it, i.e. some s disjoint from m has its bit set.
const fn closure_table() -> [u8; 256] {
    let mut t = [0u8; 256];
    let mut p = 0;
    while p < 256 {
        let mut byte = 0u8;
        let mut m = 0;
        while m < 8 {
            let mut s = 0;
            while s < 8 {
                if s & m == 0 && p & (1 << s) != 0 {
                    byte |= SPAN_BIT[m];
                }
                s += 1;
            }
            m += 1;
        }
        t[p] = byte;
        p += 1;
    }
    t
}
const CLOSURE: [u8; 256] = closure_table();

/// A cubical complex on the lattice of a voxel grid, one byte per vertex (see the module
/// documentation for the layout).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Complex {
    /// Voxel dimensions (w, h, d); vertices run over 0..=w and so on.
    dims: [usize; 3],
    /// Size of the internal (padded) vertex array along each axis: dims + 2.
    size: [usize; 3],
    /// Index offset of one step along each axis in the internal array.
    stride: [usize; 3],
    bits: Vec<u8>,
}

impl Complex {
    /// An empty complex over a grid of `dims` voxels.
    pub fn empty(dims: [usize; 3]) -> Complex {
        let size = dims.map(|d| d + 2);
        Complex {
            dims,
            size,
            stride: [1, size[0], size[0] * size[1]],
            bits: vec![0; size[0] * size[1] * size[2]],
        }
    }

    /// The closure of the closed cubes of the voxels for which `is_empty(voxel index)` holds
    /// (voxel index = x + w (y + h z), as in [`super::VoxelGrid`]).
    pub fn from_voxels(dims: [usize; 3], is_empty: impl Fn(usize) -> bool + Sync) -> Complex {
        let mut c = Complex::empty(dims);
        let (size, [w, h, d]) = (c.size, dims);
        let slab = size[0] * size[1];
        c.bits
            .par_chunks_mut(slab)
            .enumerate()
            .for_each(|(iz, out)| {
                if iz == 0 || iz > d + 1 {
                    return;
                }
                let z = iz - 1;
                for y in 0..=h {
                    for x in 0..=w {
                        let mut pattern = 0usize;
                        for s in 0..8usize {
                            let (dx, dy, dz) = (s & 1, (s >> 1) & 1, (s >> 2) & 1);
                            if x < dx || y < dy || z < dz {
                                continue;
                            }
                            let (vx, vy, vz) = (x - dx, y - dy, z - dz);
                            if vx < w && vy < h && vz < d && is_empty(vx + w * (vy + h * vz)) {
                                pattern |= 1 << s;
                            }
                        }
                        out[(x + 1) + size[0] * (y + 1)] = CLOSURE[pattern];
                    }
                }
            });
        c
    }

    /// The complex of the empty space: the closure of the voxels not in `occupied`.
    pub fn from_occupied(dims: [usize; 3], occupied: &VoxelSet) -> Complex {
        Complex::from_voxels(dims, |i| !occupied.get(i))
    }

    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Internal index of lattice vertex (x, y, z), 0 <= x <= w.
    #[inline]
    pub fn vertex(&self, x: usize, y: usize, z: usize) -> usize {
        (x + 1) + self.stride[1] * (y + 1) + self.stride[2] * (z + 1)
    }

    /// Lattice coordinates of an internal index (may be -1 or w+1 on the padding layer).
    #[inline]
    pub fn coords(&self, i: usize) -> [isize; 3] {
        let x = i % self.size[0];
        let yz = i / self.size[0];
        [
            x as isize - 1,
            (yz % self.size[1]) as isize - 1,
            (yz / self.size[1]) as isize - 1,
        ]
    }

    #[inline]
    pub fn stride(&self) -> [usize; 3] {
        self.stride
    }

    /// Number of entries of the internal array.
    pub fn len(&self) -> usize {
        self.bits.len()
    }

    pub fn is_empty(&self) -> bool {
        self.bits.iter().all(|&b| b == 0)
    }

    /// The raw vertex bytes (internal layout).
    pub fn bytes(&self) -> &[u8] {
        &self.bits
    }

    #[inline]
    pub fn byte(&self, i: usize) -> u8 {
        self.bits[i]
    }

    /// Whether the cell of span `span` owned by internal vertex `i` is present.
    #[inline]
    pub fn has(&self, i: usize, span: u8) -> bool {
        self.bits[i] & SPAN_BIT[span as usize] != 0
    }

    /// Whether the cell is inside the grid (it may be set).
    pub fn valid(&self, i: usize, span: u8) -> bool {
        let c = self.coords(i);
        (0..3).all(|a| {
            c[a] >= 0
                && (c[a] as usize) <= self.dims[a]
                && (span & (1 << a) == 0 || (c[a] as usize) < self.dims[a])
        })
    }

    /// Adds a cell and all its faces.
    pub fn insert_closed(&mut self, i: usize, span: u8) {
        debug_assert!(self.valid(i, span));
        for sub in 0..8u8 {
            if sub & span != sub {
                continue;
            }
            // Faces of span `sub` sit at i + sum of strides over any subset of span \ sub.
            let rest = span & !sub;
            for shift in 0..8u8 {
                if shift & rest != shift {
                    continue;
                }
                let j = i
                    + (0..3)
                        .filter(|a| shift & (1 << a) != 0)
                        .map(|a| self.stride[a])
                        .sum::<usize>();
                self.bits[j] |= SPAN_BIT[sub as usize];
            }
        }
    }

    /// Adds one cell (the caller keeps the complex closed).
    pub(crate) fn add_cell(&mut self, i: usize, span: u8) {
        self.bits[i] |= SPAN_BIT[span as usize];
    }

    /// Removes one cell (the caller keeps the complex closed).
    #[cfg(test)]
    pub(crate) fn remove(&mut self, i: usize, span: u8) {
        self.bits[i] &= !SPAN_BIT[span as usize];
    }

    /// Number of cells of each dimension (points, edges, squares, cubes).
    pub fn counts(&self) -> [usize; 4] {
        self.bits
            .par_chunks(1 << 16)
            .map(|chunk| {
                let mut n = [0usize; 4];
                for &b in chunk {
                    n[0] += (b & POINT).count_ones() as usize;
                    n[1] += (b & EDGES).count_ones() as usize;
                    n[2] += (b & SQUARES).count_ones() as usize;
                    n[3] += (b & CUBE).count_ones() as usize;
                }
                n
            })
            .reduce(
                || [0; 4],
                |a, b| [a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3]],
            )
    }

    /// Euler characteristic: points - edges + squares - cubes.
    pub fn euler(&self) -> i64 {
        self.bits
            .par_chunks(1 << 16)
            .map(|c| c.iter().map(|&b| EULER[b as usize] as i64).sum::<i64>())
            .sum()
    }

    /// Whether every present cell has all its faces present.
    pub fn is_closed(&self) -> bool {
        (0..self.bits.len()).all(|i| {
            let b = self.bits[i];
            (0..8u8).all(|span| {
                if b & SPAN_BIT[span as usize] == 0 {
                    return true;
                }
                (0..3).all(|a| {
                    if span & (1 << a) == 0 {
                        return true;
                    }
                    let face = span & !(1 << a);
                    self.has(i, face) && self.has(i + self.stride[a], face)
                })
            })
        })
    }

    /// Whether every cell of `self` is a cell of `other` (same grid).
    pub fn is_subcomplex_of(&self, other: &Complex) -> bool {
        self.dims == other.dims
            && self
                .bits
                .iter()
                .zip(&other.bits)
                .all(|(&a, &b)| a & !b == 0)
    }

    /// Number of connected components: union-find over vertices joined by present edges
    /// (every cell contains a vertex and the complex is closed, so this is b0).
    pub fn b0(&self) -> usize {
        let n = self.bits.len();
        let mut uf = UnionFind::new(n);
        for i in 0..n {
            let b = self.bits[i];
            for a in 0..3 {
                if b & SPAN_BIT[1 << a] != 0 {
                    uf.union(i, i + self.stride[a]);
                }
            }
        }
        (0..n)
            .filter(|&i| self.bits[i] & POINT != 0 && uf.find(i) == i)
            .count()
    }

    /// Labels of the connected components of the complement of the complex, one per cube
    /// position of the internal array (present cubes get `u32::MAX`). The complement is
    /// the union of the open cells not in the complex; since an absent cell's cofaces are all
    /// absent (closure), each component contains open cubes, and two cubes that share an absent
    /// square are in the same component: 6-connectivity through absent squares. The padding
    /// layer belongs to the unbounded component, which gets label 0.
    pub fn complement_labels(&self) -> (Vec<u32>, usize) {
        let n = self.bits.len();
        let mut uf = UnionFind::new(n);
        let [sx, sy, sz] = self.size;
        for z in 0..sz {
            for y in 0..sy {
                for x in 0..sx {
                    let i = x + sx * (y + sy * z);
                    if self.bits[i] & CUBE != 0 {
                        continue;
                    }
                    let c = [x, y, z];
                    for a in 0..3 {
                        if c[a] + 1 >= self.size[a] {
                            continue;
                        }
                        let j = i + self.stride[a];
                        // The square between cube i and cube j is owned by j, spanning the
                        // two other axes.
                        if self.bits[j] & SPAN_BIT[7 ^ (1 << a)] == 0 {
                            uf.union(i, j);
                        }
                    }
                }
            }
        }
        let mut label = vec![u32::MAX; n];
        let mut root_label = vec![u32::MAX; n];
        let outside = uf.find(0);
        root_label[outside] = 0;
        let mut count = 1u32;
        for i in 0..n {
            if self.bits[i] & CUBE != 0 {
                continue;
            }
            let r = uf.find(i);
            if root_label[r] == u32::MAX {
                root_label[r] = count;
                count += 1;
            }
            label[i] = root_label[r];
        }
        (label, count as usize)
    }

    /// b2 by Alexander duality: the number of bounded components of the complement.
    pub fn b2(&self) -> usize {
        self.complement_labels().1 - 1
    }

    /// Betti numbers: b0 by union-find, b2 by bounded complement components, b1 = b0 + b2 - χ
    /// (b3 = 0 for a proper subset of R³).
    pub fn betti(&self) -> Betti {
        let euler = self.euler();
        let (b0, b2) = rayon::join(|| self.b0(), || self.b2());
        let b1 = b0 as i64 + b2 as i64 - euler;
        assert!(b1 >= 0, "negative b1: b0 {b0} b2 {b2} euler {euler}");
        Betti {
            b0,
            b1: b1 as usize,
            b2,
            euler,
        }
    }

    /// Betti numbers from the ranks of the GF(2) boundary matrices (a test oracle for small
    /// grids: b_k = n_k - rank ∂_k - rank ∂_{k+1}).
    pub fn betti_gf2(&self) -> [usize; 4] {
        // Cells of each dimension, as (internal index, span).
        let mut cells: [Vec<(usize, u8)>; 4] = Default::default();
        for i in 0..self.bits.len() {
            for span in 0..8u8 {
                if self.has(i, span) {
                    cells[span_dim(span) as usize].push((i, span));
                }
            }
        }
        let position = |k: usize, cell: (usize, u8)| -> usize {
            cells[k]
                .binary_search(&cell)
                .expect("face of a present cell is present")
        };
        let mut rank = [0usize; 5];
        for k in 1..4 {
            // Rows: k-cells, as bit sets over the (k-1)-cells.
            let words = cells[k - 1].len().div_ceil(64);
            let mut rows: Vec<Vec<u64>> = cells[k]
                .iter()
                .map(|&(i, span)| {
                    let mut row = vec![0u64; words];
                    for a in 0..3 {
                        if span & (1 << a) == 0 {
                            continue;
                        }
                        let face = span & !(1 << a);
                        for j in [i, i + self.stride[a]] {
                            let p = position(k - 1, (j, face));
                            row[p >> 6] ^= 1 << (p & 63);
                        }
                    }
                    row
                })
                .collect();
            rank[k] = gf2_rank(&mut rows, words);
        }
        let mut b = [0usize; 4];
        for k in 0..4 {
            b[k] = cells[k].len() - rank[k] - rank[k + 1];
        }
        b
    }
}

/// Rank of a set of GF(2) row vectors (destroys them).
fn gf2_rank(rows: &mut [Vec<u64>], words: usize) -> usize {
    let mut rank = 0;
    for col in 0..words * 64 {
        let (w, bit) = (col >> 6, 1u64 << (col & 63));
        let Some(p) = (rank..rows.len()).find(|&r| rows[r][w] & bit != 0) else {
            continue;
        };
        rows.swap(rank, p);
        let pivot = rows[rank].clone();
        for r in 0..rows.len() {
            if r != rank && rows[r][w] & bit != 0 {
                for (x, y) in rows[r].iter_mut().zip(&pivot) {
                    *x ^= y;
                }
            }
        }
        rank += 1;
    }
    rank
}

/// Number of 6-connected components among the empty voxels of a 2x2x2 block (bit s = voxel
/// at offset s, s a subset of axes).
const fn block_components(pattern: usize) -> u32 {
    let mut seen = 0usize;
    let mut comps = 0;
    let mut s = 0;
    while s < 8 {
        if pattern & (1 << s) != 0 && seen & (1 << s) == 0 {
            comps += 1;
            // Flood within the block: neighbours differ by one axis bit.
            let mut stack = 1usize << s;
            seen |= 1 << s;
            while stack != 0 {
                let t = stack.trailing_zeros() as usize;
                stack &= !(1 << t);
                let mut a = 0;
                while a < 3 {
                    let u = t ^ (1 << a);
                    if pattern & (1 << u) != 0 && seen & (1 << u) == 0 {
                        seen |= 1 << u;
                        stack |= 1 << u;
                    }
                    a += 1;
                }
            }
        }
        s += 1;
    }
    comps
}

const fn pinch_table() -> [bool; 256] {
    let mut t = [false; 256];
    let mut p = 0;
    while p < 256 {
        t[p] = block_components(p) > 1;
        p += 1;
    }
    t
}
const PINCH: [bool; 256] = pinch_table();

/// Number of interior lattice vertices where the empty voxels of the surrounding 2x2x2 block
/// form more than one 6-connected group: places where empty voxels touch only along an edge
/// or at a corner, which the closed-cube complex treats as passages (see the module docs).
pub fn diagonal_contacts(dims: [usize; 3], occupied: &VoxelSet) -> usize {
    let [w, h, d] = dims;
    if w < 2 || h < 2 || d < 2 {
        return 0;
    }
    (1..d)
        .into_par_iter()
        .map(|z| {
            let mut n = 0;
            for y in 1..h {
                for x in 1..w {
                    let mut p = 0usize;
                    for s in 0..8usize {
                        let (vx, vy, vz) = (x - (s & 1), y - ((s >> 1) & 1), z - ((s >> 2) & 1));
                        if !occupied.get(vx + w * (vy + h * vz)) {
                            p |= 1 << s;
                        }
                    }
                    n += PINCH[p] as usize;
                }
            }
            n
        })
        .sum()
}

/// Union-find with path halving and union by index (deterministic roots).
pub(crate) struct UnionFind {
    parent: Vec<u32>,
}

impl UnionFind {
    pub fn new(n: usize) -> Self {
        UnionFind {
            parent: (0..n as u32).collect(),
        }
    }

    #[inline]
    pub fn find(&mut self, mut i: usize) -> usize {
        while self.parent[i] as usize != i {
            let p = self.parent[i] as usize;
            self.parent[i] = self.parent[p];
            i = self.parent[i] as usize;
        }
        i
    }

    /// Joins two sets; returns false if they were already one. The smaller root wins.
    pub fn union(&mut self, a: usize, b: usize) -> bool {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra == rb {
            return false;
        }
        let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
        self.parent[hi] = lo as u32;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    fn random_empty(dims: [usize; 3], density: f32, rng: &mut Rng) -> VoxelSet {
        VoxelSet::random(dims[0] * dims[1] * dims[2], density, rng)
    }

    #[test]
    fn single_cube_and_counts() {
        let c = Complex::from_voxels([1, 1, 1], |_| true);
        assert_eq!(c.counts(), [8, 12, 6, 1]);
        assert_eq!(c.euler(), 1);
        assert!(c.is_closed());
        assert_eq!(
            c.betti(),
            Betti {
                b0: 1,
                b1: 0,
                b2: 0,
                euler: 1
            }
        );
        assert_eq!(c.betti_gf2(), [1, 0, 0, 0]);
        // DGtal's diamond fixture: the L1 ball of radius 3 minus its centre (62 voxels).
        let dims = [7, 7, 7];
        let c = Complex::from_voxels(dims, |i| {
            let (x, y, z) = (i % 7, (i / 7) % 7, i / 49);
            let r = x.abs_diff(3) + y.abs_diff(3) + z.abs_diff(3);
            (1..=3).contains(&r)
        });
        assert_eq!(c.counts(), [160, 360, 264, 62]);
        assert_eq!(c.euler(), 2);
        assert_eq!(c.betti_gf2(), [1, 0, 1, 0]);
        assert_eq!(
            c.betti(),
            Betti {
                b0: 1,
                b1: 0,
                b2: 1,
                euler: 2
            }
        );
    }

    #[test]
    fn diagonal_contact_connects() {
        // Two empty voxels meeting along an edge only: one component in the complex, and one
        // diagonal contact reported.
        let dims = [2, 2, 1];
        let mut occ = VoxelSet::new(4);
        occ.set(1);
        occ.set(2);
        let c = Complex::from_occupied(dims, &occ);
        assert_eq!(c.betti().b0, 1);
        let dims = [2, 2, 2];
        let mut occ = VoxelSet::new(8);
        for i in [1, 2, 4, 7] {
            occ.set(i);
        }
        // Voxels 0, 3, 5, 6 are pairwise diagonal: 4 components of 6-connectivity, one vertex.
        assert_eq!(diagonal_contacts(dims, &occ), 1);
        assert_eq!(Complex::from_occupied(dims, &occ).betti().b0, 1);
    }

    #[test]
    fn betti_matches_gf2_oracle_on_random_grids() {
        let mut rng = Rng::new(6, 1);
        for case in 0..60 {
            let dims = [2 + (case % 5), 2 + (case * 7 % 4), 1 + (case * 3 % 5)];
            let density = [0.3f32, 0.5, 0.7, 0.85][case % 4];
            let empty = random_empty(dims, density, &mut rng);
            let c = Complex::from_voxels(dims, |i| empty.get(i));
            assert!(c.is_closed());
            let b = c.betti();
            let g = c.betti_gf2();
            assert_eq!([b.b0, b.b1, b.b2, 0], g, "{dims:?} density {density}");
        }
    }
}
