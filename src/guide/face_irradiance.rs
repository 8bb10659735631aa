//! The face-irradiance strategy of `path_portal` (000 §10.4.2, lines 3072-3090), made
//! unbiased.
//!
//! # What the thesis does
//!
//! Each opening-forest region has an *opening border*: the voxel faces between one of its
//! voxels and a voxel that is not (another region, an occupied voxel, or the grid's outside).
//! Before each iteration one BSDF-sampled path per pixel estimates the irradiance at every
//! face; each region gets a discrete distribution over its border's faces. A point picks a face
//! of its region's border by that distribution and a point on the face uniformly; thresholds
//! d_t (distance) and o_t (orientation) send too close or too grazing choices to the
//! neighbouring region's border.
//!
//! # What Lacuna does
//!
//! - *Training* ([`FaceIrradiance::build`]): `training_paths` camera paths of `path`'s own
//!   estimator (BSDF sampling, next-event estimation, power-heuristic MIS) before the render.
//!   For each segment of a path, the radiance it carries back toward its origin (the path's
//!   later contributions over the throughput along the segment, in luminance) is added to every
//!   border face the segment crosses out of a region. A region's distribution is that sum per
//!   face, mixed with `1 - face_mix` of uniform over its faces; a region no training segment
//!   left has none (unguided). The sum is a flux through the face, the thesis's "irradiance"
//!   up to the face's fixed area (`face_score=radiance` scores the mean radiance by the
//!   face's solid angle from the region's centroid instead, [`FaceScore`]).
//! - *Exact density.* A direction w from x is drawn from region R's border through the first
//!   border face of R the ray x + t w crosses *out of* R ([`first exits`](FaceIrradiance::march)):
//!   the face chosen and the point on it give w, and the sample is kept only if the ray's first
//!   exit from R is the chosen face (a ray that leaves R earlier, or re-enters it, would be
//!   counted twice otherwise). So the density of w is exactly
//!   `p_R(f) t^2 / (A |cos|)`, f the first exit face, t the distance to it, A its area, cos the
//!   angle between w and the face's axis: one march through the grid gives it. Rejected
//!   samples return no direction; the density is then sub-normalised, which one-sample MIS
//!   handles (the estimator divides by the same density the directions are drawn with; a
//!   rejected draw contributes nothing).
//! - *Thresholds.* The thesis's redirect to the neighbour's border would need, at every point,
//!   the mass of all faces that fail the thresholds from there (a sum over the whole border per
//!   vertex) to give an exact density. Here a face fails from x along w if the crossing is
//!   nearer than `d_t` or `|cos| < o_t` (the thesis's orientation test used the direction to the
//!   face's centre; the direction itself keeps the density a function of x and w), and its
//!   directions are left to BSDF sampling. The neighbouring regions are mixed in by the
//!   smoothing window instead (below). The thesis's text says "larger than d_t" and "greater
//!   than o_t", while its explanation is "too close, or at a grazing angle": the tests here
//!   follow the explanation.
//! - *Smooth across region borders.* As for the shortest-paths strategy
//!   ([`super::portal_guide`], "Query"): the regions of the voxels in a tent window around the
//!   point are mixed with their tent weights, so the strategy changes continuously across a
//!   region border instead of jumping.

use super::mixture::{pick_lobe, DirectionGuide};
use super::settings::RenderEstimator;
use crate::analysis::{Analysis, NO_REGION};
use crate::error::Result;
use crate::math::{luminance, Rgb, Rng, Sampler, Vec2, Vec3};
use crate::scene::{Camera, Scene, Transport};

use super::estimator;

/// Most regions a query mixes.
pub const MAX_FACE_LOBES: usize = 8;
/// Label of the grid's outside in a march.
const OUTSIDE: u32 = u32::MAX - 1;
/// Camera paths per chunk of the training (the fixed work partition: deterministic sums).
const TRAINING_CHUNK: u32 = 512;
const TRAINING_SEED: u64 = 0xface_1220;
/// Width / height of the training's image (the render's is not known yet).
const TRAINING_ASPECT: f32 = 4.0 / 3.0;

/// What the training traces with: the render's camera, light sampling and depth.
#[derive(Clone, Copy)]
pub struct FaceTraining<'a> {
    pub camera: &'a Camera,
    pub estimator: RenderEstimator,
    pub max_depth: u32,
    pub paths: u32,
    /// The learned share of a region's distribution (the rest is uniform over its faces).
    pub face_mix: f32,
    pub score: FaceScore,
}

/// What a face's probability in its region's distribution is proportional to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaceScore {
    /// The radiance the training carried through it, summed (the thesis's irradiance: faces
    /// the BSDF samples cross often weigh more).
    Flux,
    /// The mean radiance of its crossings times its projected solid angle seen from the
    /// region's centroid: the density a point near the centroid then gets is about the
    /// radiance it sees, where `flux` over-weights distant faces by their squared distance
    /// (their solid angle is small, the density through them large). Measured no better than
    /// `flux` on the door scenes (BENCHMARKS.md), so not the default.
    Radiance,
}

/// The per-region face distributions of a scene (module docs).
pub struct FaceIrradiance {
    /// Per voxel: its slot among the border voxels, or `u32::MAX`.
    border_slot: Vec<u32>,
    /// Per border slot: its voxel index.
    border_voxels: Vec<u32>,
    /// Per face (slot * 6 + direction, direction = axis * 2 + (1 if positive)): its
    /// probability in its region's distribution (0 for faces inside a region).
    face_probability: Vec<f32>,
    /// Per region: its faces and their cumulative probabilities (empty: unguided).
    region_faces: Vec<Vec<u32>>,
    region_cdf: Vec<Vec<f32>>,
    /// Thresholds in grid units (distance) and cosine.
    d_t: f32,
    o_t: f32,
    pub training_paths: u32,
    pub guided_regions: usize,
}

impl FaceIrradiance {
    /// Finds the borders, trains their distributions and builds them.
    pub fn build(
        analysis: &Analysis,
        scene: &Scene,
        training: &FaceTraining,
        d_t_world: f32,
        o_t: f32,
    ) -> Result<FaceIrradiance> {
        let grid = &analysis.grid;
        let labels = &analysis.labels;
        let mut border_slot = vec![u32::MAX; labels.len()];
        let mut border_voxels = Vec::new();
        for (v, &l) in labels.iter().enumerate() {
            if l == NO_REGION {
                continue;
            }
            if (0..6).any(|d| neighbour_label(analysis, v, d) != l) {
                border_slot[v] = border_voxels.len() as u32;
                border_voxels.push(v as u32);
            }
        }
        let mut guide = FaceIrradiance {
            border_slot,
            border_voxels,
            face_probability: Vec::new(),
            region_faces: vec![Vec::new(); analysis.regions.len()],
            region_cdf: vec![Vec::new(); analysis.regions.len()],
            d_t: d_t_world / grid.voxel_size as f32,
            o_t,
            training_paths: training.paths,
            guided_regions: 0,
        };
        let (flux, crossings) = guide.train(analysis, scene, training);
        guide.face_probability = vec![0.0; guide.border_voxels.len() * 6];
        for (slot, &v) in guide.border_voxels.iter().enumerate() {
            let l = labels[v as usize];
            for d in 0..6 {
                if neighbour_label(analysis, v as usize, d) != l {
                    guide.region_faces[l as usize].push(slot as u32 * 6 + d as u32);
                }
            }
        }
        let mut score = flux;
        if training.score == FaceScore::Radiance {
            for (r, faces) in guide.region_faces.iter().enumerate() {
                let centroid = grid.to_grid(analysis.regions[r].centroid);
                for &f in faces {
                    let n = crossings[f as usize];
                    if n == 0 {
                        continue;
                    }
                    let c = grid.coords(guide.border_voxels[(f / 6) as usize] as usize);
                    let d = (f % 6) as usize;
                    let mut centre = [c[0] as f64 + 0.5, c[1] as f64 + 0.5, c[2] as f64 + 0.5];
                    centre[d / 2] += if d % 2 == 1 { 0.5 } else { -0.5 };
                    let to: [f64; 3] = std::array::from_fn(|k| centre[k] - centroid[k]);
                    let distance2 = (to[0] * to[0] + to[1] * to[1] + to[2] * to[2]).max(1.0);
                    let cos = (to[d / 2].abs() / distance2.sqrt()).max(0.1);
                    score[f as usize] = score[f as usize] / n as f64 * cos / distance2;
                }
            }
        }
        let flux = score;
        for r in 0..analysis.regions.len() {
            let faces = &guide.region_faces[r];
            let mass: f64 = faces.iter().map(|&f| flux[f as usize]).sum();
            if !(mass > 0.0) || !mass.is_finite() {
                guide.region_faces[r].clear();
                continue;
            }
            let uniform = (1.0 - training.face_mix as f64) / faces.len() as f64;
            let mut acc = 0.0f64;
            let mut cdf = Vec::with_capacity(faces.len());
            for &f in faces {
                let p = training.face_mix as f64 * flux[f as usize] / mass + uniform;
                guide.face_probability[f as usize] = p as f32;
                acc += p;
                cdf.push(acc as f32);
            }
            // The last entry is 1 up to rounding; make the search's end exact.
            if let Some(last) = cdf.last_mut() {
                *last = 1.0;
            }
            guide.region_cdf[r] = cdf;
            guide.guided_regions += 1;
        }
        Ok(guide)
    }

    /// Whether region `r` has a distribution.
    pub fn guides(&self, r: u32) -> bool {
        !self.region_cdf[r as usize].is_empty()
    }

    /// The faces of region `r`'s border that its distribution samples (empty: unguided),
    /// as ids for [`Self::face_probability`] and [`Self::face_rectangle`].
    pub fn region_faces(&self, r: u32) -> &[u32] {
        &self.region_faces[r as usize]
    }

    /// Probability of face `face` in its region's distribution.
    pub fn face_probability(&self, face: u32) -> f32 {
        self.face_probability[face as usize]
    }

    /// Face `face` as a world rectangle: (corner, edge u, edge v).
    pub fn face_rectangle(&self, analysis: &Analysis, face: u32) -> (Vec3, Vec3, Vec3) {
        let grid = &analysis.grid;
        let c = grid.coords(self.border_voxels[(face / 6) as usize] as usize);
        let d = (face % 6) as usize;
        let axis = d / 2;
        let mut y = [c[0] as f64, c[1] as f64, c[2] as f64];
        y[axis] += (d % 2) as f64;
        let corner = grid.to_world(y);
        let mut eu = Vec3::ZERO;
        eu[(axis + 1) % 3] = grid.voxel_size as f32;
        let mut ev = Vec3::ZERO;
        ev[(axis + 2) % 3] = grid.voxel_size as f32;
        (corner, eu, ev)
    }

    /// Memory of the tables, in bytes.
    pub fn memory_bytes(&self) -> usize {
        self.border_slot.len() * 4
            + self.border_voxels.len() * 4
            + self.face_probability.len() * 4
            + self.region_faces.iter().map(|f| f.len() * 8).sum::<usize>()
    }

    /// The training (module docs): per face, the flux the training segments carried out of a
    /// region through it.
    fn train(
        &self,
        analysis: &Analysis,
        scene: &Scene,
        training: &FaceTraining,
    ) -> (Vec<f64>, Vec<u32>) {
        use rayon::prelude::*;
        let frame = training.camera.frame(TRAINING_ASPECT);
        let chunks = training.paths.div_ceil(TRAINING_CHUNK);
        let per_chunk: Vec<Vec<(u32, (f64, u32))>> = (0..chunks)
            .into_par_iter()
            .map(|c| {
                let mut sums: std::collections::HashMap<u32, (f64, u32)> = Default::default();
                let mut segments = Vec::new();
                let mut contributions = Vec::new();
                for i in c * TRAINING_CHUNK..((c + 1) * TRAINING_CHUNK).min(training.paths) {
                    let mut rng = Rng::new(TRAINING_SEED, i as u64);
                    let ray = frame.generate_ray(rng.uniform2(), rng.uniform2());
                    let mut sampler = Sampler::independent(rng);
                    trace_training_path(
                        scene,
                        ray,
                        &mut sampler,
                        training,
                        &mut segments,
                        &mut contributions,
                    );
                    // Radiance along segment k: the contributions from vertex k + 1 on.
                    let mut later = 0.0f32;
                    let mut suffix = vec![0.0f32; contributions.len() + 1];
                    for d in (0..contributions.len()).rev() {
                        later += contributions[d];
                        suffix[d] = later;
                    }
                    for (k, s) in segments.iter().enumerate() {
                        let carried = suffix.get(k + 1).copied().unwrap_or(0.0);
                        if !(carried > 0.0 && s.throughput > 0.0) {
                            continue;
                        }
                        let radiance = (carried / s.throughput) as f64;
                        if !radiance.is_finite() {
                            continue;
                        }
                        self.crossings(analysis, s.origin, s.dir, s.length, |face| {
                            let e = sums.entry(face).or_insert((0.0, 0));
                            e.0 += radiance;
                            e.1 += 1;
                        });
                    }
                }
                let mut list: Vec<(u32, (f64, u32))> = sums.into_iter().collect();
                list.sort_unstable_by_key(|e| e.0);
                list
            })
            .collect();
        let mut flux = vec![0f64; self.border_voxels.len() * 6];
        let mut crossings = vec![0u32; self.border_voxels.len() * 6];
        for list in per_chunk {
            for (f, (s, n)) in list {
                flux[f as usize] += s;
                crossings[f as usize] += n;
            }
        }
        (flux, crossings)
    }

    /// Calls `each` with every border face the segment from `origin` along unit `dir` (world
    /// length `length`, may be infinite) crosses out of a region.
    fn crossings(
        &self,
        analysis: &Analysis,
        origin: Vec3,
        dir: Vec3,
        length: f32,
        mut each: impl FnMut(u32),
    ) {
        let t_end = (length / analysis.grid.voxel_size as f32) as f64;
        walk(analysis, origin, dir, |v, label, next, d, t| {
            if t > t_end {
                return false;
            }
            if label != NO_REGION && next != label {
                let slot = self.border_slot[v];
                if slot != u32::MAX {
                    each(slot * 6 + d as u32);
                }
            }
            true
        });
    }

    /// The density of each lobe's region at direction `w` from `x` (module docs, "Exact
    /// density"): `out[j]` for `regions[j]`, with the face it exits through.
    fn march(
        &self,
        analysis: &Analysis,
        x: Vec3,
        w: Vec3,
        regions: &[u32],
        out: &mut [(f32, u32)],
    ) {
        let mut open = regions.len();
        for o in out.iter_mut() {
            *o = (0.0, u32::MAX);
        }
        let mut done = [false; MAX_FACE_LOBES];
        walk(analysis, x, w, |v, label, next, d, t| {
            for (j, &r) in regions.iter().enumerate() {
                if done[j] || label != r || next == r {
                    continue;
                }
                done[j] = true;
                open -= 1;
                let cos = w[d / 2].abs();
                let slot = self.border_slot[v];
                if slot == u32::MAX || (t as f32) < self.d_t || cos < self.o_t || !(cos > 0.0) {
                    continue;
                }
                let face = slot * 6 + d as u32;
                let p = self.face_probability[face as usize];
                out[j] = (p * (t * t) as f32 / cos, face);
            }
            open > 0
        });
    }
}

/// The label of the voxel next to `v` in direction `d` (axis d / 2, positive if d is odd);
/// [`OUTSIDE`] past the grid.
fn neighbour_label(analysis: &Analysis, v: usize, d: usize) -> u32 {
    let grid = &analysis.grid;
    let mut c = grid.coords(v);
    let axis = d / 2;
    if d % 2 == 1 {
        if c[axis] + 1 >= grid.dims[axis] {
            return OUTSIDE;
        }
        c[axis] += 1;
    } else {
        if c[axis] == 0 {
            return OUTSIDE;
        }
        c[axis] -= 1;
    }
    analysis.labels[grid.index(c[0], c[1], c[2])]
}

/// Walks the voxels along the ray from `origin` along unit `dir` (3-D DDA), calling
/// `step(voxel, its label, next voxel's label, face direction, t)` for each face crossed, t the
/// distance to the crossing in voxels; stops when `step` returns false or at the grid's edge
/// (whose crossing is reported, next label [`OUTSIDE`]). Nothing for an origin outside the grid.
fn walk(
    analysis: &Analysis,
    origin: Vec3,
    dir: Vec3,
    mut step: impl FnMut(usize, u32, u32, usize, f64) -> bool,
) {
    let grid = &analysis.grid;
    let g = grid.to_grid(origin);
    let mut v = [0i64; 3];
    for k in 0..3 {
        v[k] = g[k].floor() as i64;
        if v[k] < 0 || v[k] >= grid.dims[k] as i64 {
            return;
        }
    }
    let w = [dir.x as f64, dir.y as f64, dir.z as f64];
    let mut t_max = [f64::INFINITY; 3];
    let mut t_delta = [f64::INFINITY; 3];
    let mut stepk = [0i64; 3];
    for k in 0..3 {
        if w[k] > 0.0 {
            stepk[k] = 1;
            t_max[k] = (v[k] as f64 + 1.0 - g[k]) / w[k];
            t_delta[k] = 1.0 / w[k];
        } else if w[k] < 0.0 {
            stepk[k] = -1;
            t_max[k] = (v[k] as f64 - g[k]) / w[k];
            t_delta[k] = -1.0 / w[k];
        }
    }
    let bound = grid.dims.iter().sum::<usize>() + 3;
    for _ in 0..bound {
        let k = if t_max[0] <= t_max[1] && t_max[0] <= t_max[2] {
            0
        } else if t_max[1] <= t_max[2] {
            1
        } else {
            2
        };
        if !t_max[k].is_finite() {
            return;
        }
        let index = grid.index(v[0] as usize, v[1] as usize, v[2] as usize);
        let label = analysis.labels[index];
        let mut n = v;
        n[k] += stepk[k];
        let inside = n[k] >= 0 && n[k] < grid.dims[k] as i64;
        let next = if inside {
            analysis.labels[grid.index(n[0] as usize, n[1] as usize, n[2] as usize)]
        } else {
            OUTSIDE
        };
        let d = 2 * k + (stepk[k] > 0) as usize;
        if !step(index, label, next, d, t_max[k]) || !inside {
            return;
        }
        v = n;
        t_max[k] += t_delta[k];
    }
}

/// One segment of a training path: from a surface vertex, with the luminance of the path's
/// throughput along it (the bounce at its origin included).
struct Segment {
    origin: Vec3,
    dir: Vec3,
    length: f32,
    throughput: f32,
}

/// A training path (module docs): its segments from surface vertices and, per vertex depth,
/// the luminance of what it contributed (emission found, next-event estimation at the vertex,
/// the environment found leaving the vertex before).
fn trace_training_path(
    scene: &Scene,
    mut ray: crate::geometry::Ray,
    rng: &mut Sampler,
    training: &FaceTraining,
    segments: &mut Vec<Segment>,
    contributions: &mut Vec<f32>,
) {
    segments.clear();
    contributions.clear();
    let estimator = &training.estimator;
    let mis = estimator.mis;
    let mut beta = Rgb::ONE;
    let (mut prev_delta, mut prev_pdf) = (true, 0.0f32);
    let (mut prev_point, mut prev_normal) = (ray.origin, Vec3::ZERO);
    let mut depth = 0u32;
    loop {
        contributions.push(0.0);
        let Some(si) = scene.intersect(&ray) else {
            if depth > 0 {
                if let Some((le, light_pdf)) =
                    estimator::environment_along(scene, prev_point, prev_normal, ray.dir, estimator)
                {
                    let w = if prev_delta {
                        1.0
                    } else {
                        mis.weight(prev_pdf, light_pdf)
                    };
                    contributions[depth as usize] += luminance(beta * le * w);
                }
                if let Some(s) = segments.last_mut() {
                    s.length = f32::INFINITY;
                }
            }
            break;
        };
        if let Some(s) = segments.last_mut() {
            s.length = si.t;
        }
        let le = scene.emitted(&si);
        if le != Rgb::ZERO && depth > 0 {
            let w = if prev_delta {
                1.0
            } else {
                let light_pdf = estimator::emitter_light_pdf(scene, prev_point, &si, estimator);
                mis.weight(prev_pdf, light_pdf)
            };
            contributions[depth as usize] += luminance(beta * le * w);
        }
        if depth >= training.max_depth {
            break;
        }
        let bsdf = scene.bsdf(&si);
        let frame = si.shading_frame();
        let wo_local = frame.to_local(si.wo);
        if !bsdf.is_delta() {
            let mut shadow_rays = 0;
            if let Some(light) = estimator::sample_direct_light(
                scene,
                &si,
                &frame,
                &bsdf,
                wo_local,
                estimator,
                rng.uniform2(),
                &mut shadow_rays,
            ) {
                let direction_pdf = if light.delta {
                    0.0
                } else {
                    bsdf.pdf(wo_local, light.wi_local)
                };
                contributions[depth as usize] +=
                    luminance(beta * light.weighted(light.weight(mis, direction_pdf)));
            }
        }
        let Some(bs) = bsdf.sample_from(wo_local, rng, Transport::Radiance) else {
            break;
        };
        let wi = frame.to_world(bs.wi);
        beta *= bs.f * (bs.wi.z.abs() / bs.pdf);
        if !crate::math::is_finite3(beta) || beta == Rgb::ZERO {
            break;
        }
        segments.push(Segment {
            origin: si.p,
            dir: wi,
            length: 0.0,
            throughput: luminance(beta),
        });
        prev_delta = bs.delta;
        prev_pdf = bs.pdf;
        prev_point = si.p;
        prev_normal = si.facing_normal();
        ray = si.spawn_ray(wi);
        depth += 1;
        if depth >= 3 {
            let q = (1.0 - beta.max_element()).max(0.05);
            if rng.uniform() < q {
                break;
            }
            beta /= 1.0 - q;
            if let Some(s) = segments.last_mut() {
                s.throughput /= 1.0 - q;
            }
        }
    }
    // A segment whose end was never reached (the path ended at its origin's bounce) carries
    // nothing known.
    segments.retain(|s| s.length > 0.0);
}

/// The face mixture at one point ([`FaceIrradiance`] through `PortalGuide::init_face_query`).
pub struct FaceQuery<'a> {
    pub(super) faces: &'a FaceIrradiance,
    pub(super) analysis: &'a Analysis,
    pub(super) x: Vec3,
    pub(super) regions: [u32; MAX_FACE_LOBES],
    pub(super) weights: [f32; MAX_FACE_LOBES],
    pub(super) count: usize,
    pub(super) c: f32,
}

impl<'a> FaceQuery<'a> {
    pub fn new(faces: &'a FaceIrradiance, analysis: &'a Analysis) -> Self {
        FaceQuery {
            faces,
            analysis,
            x: Vec3::ZERO,
            regions: [NO_REGION; MAX_FACE_LOBES],
            weights: [0.0; MAX_FACE_LOBES],
            count: 0,
            c: 0.0,
        }
    }

    /// Unguided (guiding probability 0).
    pub fn clear(&mut self) {
        self.count = 0;
        self.c = 0.0;
    }

    /// Lowers the guiding probability to at most `c` (`ratio_max`).
    pub fn cap_guiding_probability(&mut self, c: f32) {
        if self.c > c {
            self.c = c.max(0.0);
        }
    }

    /// The active lobes: (region, selection probability).
    pub fn lobes(&self) -> impl Iterator<Item = (u32, f32)> + '_ {
        (0..self.count).map(|j| (self.regions[j], self.weights[j]))
    }

    /// Per lobe, the face through which the ray along `w` first leaves the lobe's region
    /// (`u32::MAX`: none, or one the thresholds leave to BSDF sampling).
    pub fn exit_faces(&self, w: Vec3) -> Vec<u32> {
        let (_, exits) = self.density(w);
        (0..self.count)
            .map(|j| {
                if exits[j].0 > 0.0 {
                    exits[j].1
                } else {
                    u32::MAX
                }
            })
            .collect()
    }

    /// The mixture's density and each lobe's exit face at `w`.
    fn density(&self, w: Vec3) -> (f32, [(f32, u32); MAX_FACE_LOBES]) {
        let mut out = [(0.0f32, u32::MAX); MAX_FACE_LOBES];
        self.faces.march(
            self.analysis,
            self.x,
            w,
            &self.regions[..self.count],
            &mut out[..self.count],
        );
        let pdf = (0..self.count).map(|j| self.weights[j] * out[j].0).sum();
        (pdf, out)
    }
}

impl DirectionGuide for FaceQuery<'_> {
    fn guiding_probability(&self) -> f32 {
        if self.count > 0 {
            self.c
        } else {
            0.0
        }
    }

    fn sample(&self, u_select: f32, u: Vec2) -> Option<(Vec3, f32)> {
        if self.count == 0 {
            return None;
        }
        // The lobe, then the face with the same number rescaled to the lobe's interval.
        let (chosen, u_face) = pick_lobe(self.weights[..self.count].iter().copied(), u_select);
        let cdf = &self.faces.region_cdf[self.regions[chosen] as usize];
        let k = cdf.partition_point(|&c| c <= u_face).min(cdf.len() - 1);
        let face = self.faces.region_faces[self.regions[chosen] as usize][k];
        let voxel = self.faces.border_voxels[(face / 6) as usize] as usize;
        let d = (face % 6) as usize;
        let grid = &self.analysis.grid;
        let c = grid.coords(voxel);
        let axis = d / 2;
        let mut y = [c[0] as f64, c[1] as f64, c[2] as f64];
        y[axis] += (d % 2) as f64;
        y[(axis + 1) % 3] += u.x as f64;
        y[(axis + 2) % 3] += u.y as f64;
        let to = grid.to_world(y) - self.x;
        let length = to.length();
        if !(length > 0.0) {
            return None;
        }
        let w = to / length;
        let (pdf, exits) = self.density(w);
        // Kept only if the ray leaves the chosen region first through the chosen face.
        if exits[chosen].1 != face || !(exits[chosen].0 > 0.0) || !(pdf.is_finite()) {
            return None;
        }
        Some((w, pdf))
    }

    fn pdf(&self, w: Vec3) -> f32 {
        if self.count == 0 {
            return 0.0;
        }
        self.density(w).0
    }
}
