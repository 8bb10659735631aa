//! A deliberately naive ParDirCollapse with the Algorithm 3 constraint (test oracle).
//!
//! It follows the printed algorithms literally and rescans every cell of the complex for every
//! sub-step, so it is too slow for scenes but easy to check by eye: the fast [`super::thinning`]
//! must produce the same complex, the same constraint set and the same dates after every
//! iteration. The definitions are those documented in [`super::thinning`]:
//!
//! - iteration l computes L = the closure of the cofaces of every free pair (f, g) with g ∉ W;
//! - then, for t = x, y, z, s = −, +, d = 3, 2, 1, removes every pair that is free at the start
//!   of the sub-step, has direction t, orientation s, dim f = d, g ∉ W and f ∈ L;
//! - Birth(e) = the number of iterations after which e has no square or is gone; Death = the
//!   iteration that removes the cell;
//! - at the start of iteration l a born, present edge joins W (with its points) when
//!   l − Birth(e) > DC1cc(e) + Birth(e) − D1cc(e).

use super::complex::{Complex, CUBE, SPAN_BIT};
use super::thinning::NEVER;

pub(crate) struct Oracle<'a> {
    pub complex: Complex,
    /// (L1 distance, L1 decenterness) per voxel, or no constraint.
    pub maps: Option<(&'a [u32], &'a [u32])>,
    pub inhibit: Vec<u8>,
    pub birth: Vec<u32>,
    pub death: Vec<u32>,
    pub iteration: u32,
}

impl<'a> Oracle<'a> {
    pub fn new(complex: Complex, maps: Option<(&'a [u32], &'a [u32])>) -> Self {
        let n = complex.len();
        let mut o = Oracle {
            complex,
            maps,
            inhibit: vec![0; n],
            birth: vec![NEVER; 3 * n],
            death: vec![NEVER; 8 * n],
            iteration: 0,
        };
        o.record_births(0);
        o
    }

    fn stride(&self) -> [usize; 3] {
        self.complex.stride()
    }

    /// Present cofaces of cell (i, span), as (vertex, span).
    fn cofaces(&self, i: usize, span: u8) -> Vec<(usize, u8)> {
        let s = self.stride();
        let mut out = Vec::new();
        for b in 0..3 {
            if span & (1 << b) != 0 {
                continue;
            }
            let up = span | 1 << b;
            for j in [i, i.wrapping_sub(s[b])] {
                if j < self.complex.len() && self.complex.has(j, up) {
                    out.push((j, up));
                }
            }
        }
        out
    }

    /// Every free pair (f, g) with g ∉ W, as ((f vertex, f span), (g vertex, g span)).
    fn free_pairs(&self) -> Vec<((usize, u8), (usize, u8))> {
        let mut out = Vec::new();
        for i in 0..self.complex.len() {
            for span in 0..7u8 {
                if !self.complex.has(i, span) || self.inhibit[i] & SPAN_BIT[span as usize] != 0 {
                    continue;
                }
                let c = self.cofaces(i, span);
                if c.len() == 1 {
                    out.push((c[0], (i, span)));
                }
            }
        }
        out
    }

    /// Edges present, not yet born and without a square are born at `l`.
    fn record_births(&mut self, l: u32) {
        for i in 0..self.complex.len() {
            for a in 0..3 {
                let span = 1u8 << a;
                if self.complex.has(i, span)
                    && self.birth[3 * i + a] == NEVER
                    && self.cofaces(i, span).is_empty()
                {
                    self.birth[3 * i + a] = l;
                }
            }
        }
    }

    /// D1cc and DC1cc of an edge: maxima over the voxels that contain it.
    fn edge_maps(&self, i: usize, axis: usize) -> (i64, i64) {
        let (d1, dc) = self.maps.unwrap();
        let dims = self.complex.dims();
        let c = self.complex.coords(i);
        let (mut d, mut e) = (0i64, 0i64);
        for s in 0..8usize {
            if s & (1 << axis) != 0 {
                continue;
            }
            let v: Vec<isize> = (0..3).map(|a| c[a] - ((s >> a) & 1) as isize).collect();
            if (0..3).all(|a| v[a] >= 0 && (v[a] as usize) < dims[a]) {
                let k = v[0] as usize + dims[0] * (v[1] as usize + dims[1] * v[2] as usize);
                d = d.max(d1[k] as i64);
                e = e.max(dc[k] as i64);
            }
        }
        (d, e)
    }

    fn apply_constraints(&mut self, l: u32) {
        if self.maps.is_none() {
            return;
        }
        let s = self.stride();
        for i in 0..self.complex.len() {
            for a in 0..3 {
                let span = 1u8 << a;
                let b = self.birth[3 * i + a];
                if !self.complex.has(i, span)
                    || b == NEVER
                    || self.inhibit[i] & SPAN_BIT[span as usize] != 0
                {
                    continue;
                }
                let (d, dc) = self.edge_maps(i, a);
                if l as i64 - b as i64 > dc + b as i64 - d {
                    self.inhibit[i] |= SPAN_BIT[span as usize] | SPAN_BIT[0];
                    self.inhibit[i + s[a]] |= SPAN_BIT[0];
                }
            }
        }
    }

    /// One iteration; false (nothing changed but the constraint set) when no pair is free.
    pub fn iterate(&mut self, observer: &mut dyn FnMut(&Complex)) -> bool {
        let l = self.iteration + 1;
        self.apply_constraints(l);
        let pairs = self.free_pairs();
        if pairs.is_empty() {
            return false;
        }
        let s = self.stride();
        // L: closure of the cofaces of the free pairs.
        let mut border = vec![0u8; self.complex.len()];
        for &((f, fs), _) in &pairs {
            for shift in 0..8u8 {
                if shift & fs != shift {
                    continue;
                }
                let off: usize = (0..3).filter(|a| shift & (1 << a) != 0).map(|a| s[a]).sum();
                for sub in 0..8u8 {
                    if sub & (fs & !shift) == sub {
                        border[f + off] |= SPAN_BIT[sub as usize];
                    }
                }
            }
        }
        for axis in 0..3usize {
            for positive in [false, true] {
                for dim in [3u32, 2, 1] {
                    let step: Vec<_> = self
                        .free_pairs()
                        .into_iter()
                        .filter(|&((f, fs), (g, gs))| {
                            let direction = fs == gs | (1 << axis);
                            // Orientation +: g is the upper face of f (owned by f + e_axis).
                            let side = if positive { g == f + s[axis] } else { g == f };
                            direction
                                && side
                                && fs.count_ones() == dim
                                && border[f] & SPAN_BIT[fs as usize] != 0
                        })
                        .collect();
                    for &((f, fs), (g, gs)) in &step {
                        self.complex.remove(f, fs);
                        self.complex.remove(g, gs);
                        self.death[8 * f + fs as usize] = l;
                        self.death[8 * g + gs as usize] = l;
                        for (c, cs) in [(f, fs), (g, gs)] {
                            if cs.count_ones() == 1
                                && self.birth[3 * c + cs.trailing_zeros() as usize] == NEVER
                            {
                                self.birth[3 * c + cs.trailing_zeros() as usize] = l;
                            }
                        }
                    }
                    observer(&self.complex);
                }
            }
        }
        self.record_births(l);
        self.iteration = l;
        true
    }

    pub fn run(&mut self, observer: &mut dyn FnMut(&Complex)) {
        while self.iterate(observer) {}
    }

    /// Removes one square (a piercing), recording its death and the births it causes.
    pub fn remove_square(&mut self, i: usize, span: u8) {
        debug_assert!(span.count_ones() == 2 && self.complex.byte(i) & CUBE == 0);
        self.complex.remove(i, span);
        self.death[8 * i + span as usize] = self.iteration;
        self.record_births(self.iteration);
    }
}
