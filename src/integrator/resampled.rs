//! Vertex-connection resampling shared by SkelBPT (`bdpt_skeleton`, anchors at skeleton
//! nodes) and ICBPT (`bdpt_ic`, anchors at importance records): one iteration's
//! distributions over the light vertices of the first N light subpaths, one per anchor and
//! light subpath length (`guide::resampling`), and the resampled connection of a camera
//! vertex to one light vertex of each length.

use std::sync::atomic::{AtomicU64, Ordering};

use rayon::prelude::*;

use super::bdpt::{CameraVertex, Connection, LightPaths};
use crate::guide::resampling::{
    cdf_guide, combined_distribution, guide_buckets, sample_cdf_guided, Origin,
};
use crate::math::{luminance, Sampler, Vec3};
use crate::scene::Scene;

/// The per-distribution images (`images=true`): one layer per resampling distribution and one
/// for the uniform fallback (002 Figure 10).
pub(super) fn distribution_layers(images: bool) -> Vec<String> {
    if images {
        Origin::ALL
            .iter()
            .map(|o| o.layer_name().to_string())
            .collect()
    } else {
        Vec::new()
    }
}

/// No distribution: the vertex resamples uniformly.
pub(super) const NO_TABLE: u32 = u32::MAX;
/// Connections are tallied for occlusion at every this many pixels only (a sample that keeps
/// shared counters out of the hot path).
const OCCLUSION_TALLY_EVERY: u64 = 16;

/// Resampled connections and those whose shadow ray was blocked, over a render, by whether
/// they came from an anchor's distribution (0) or the uniform fallback (1); tallied at every
/// [`OCCLUSION_TALLY_EVERY`]th pixel.
#[derive(Default)]
pub(super) struct OcclusionTally {
    connections: [AtomicU64; 2],
    occluded: [AtomicU64; 2],
}

impl OcclusionTally {
    pub fn reset(&self) {
        for c in self.connections.iter().chain(&self.occluded) {
            c.store(0, Ordering::Relaxed);
        }
    }

    /// A line for the render notes.
    pub fn note(&self) -> String {
        let part = |k: usize| {
            let n = self.connections[k].load(Ordering::Relaxed);
            let o = self.occluded[k].load(Ordering::Relaxed);
            if n == 0 {
                "none".to_string()
            } else {
                format!("{:.1} % of {n} occluded", 100.0 * o as f64 / n as f64)
            }
        };
        format!(
            "resampled connections (every {OCCLUSION_TALLY_EVERY}th pixel): from distributions \
             {}, from the uniform fallback {}",
            part(0),
            part(1)
        )
    }
}

/// A point distributions are built for.
#[derive(Clone, Copy, Debug)]
pub(super) struct Anchor {
    pub p: Vec3,
    /// On a surface (an importance record); `None` in free space (a skeleton node).
    pub surface: Option<AnchorSurface>,
}

/// The surface an [`Anchor`] lies on.
#[derive(Clone, Copy, Debug)]
pub(super) struct AnchorSurface {
    pub p_error: Vec3,
    /// Geometric normal.
    pub ng: Vec3,
    /// The direction the eye came from: an opaque anchor is left on that side only.
    pub wo: Vec3,
    /// Its BSDF refracts ([`Bsdf::transmits`](crate::scene::Bsdf::transmits)): either side.
    pub transmits: bool,
}

/// Whether a connection may leave a surface point (geometric normal `ng`, reached from `wo`)
/// in direction `d`: on `wo`'s side, or on either side where its BSDF refracts. (The exact
/// test of a given pair of directions is `SurfaceInteraction::scatters_toward`; this is its
/// union over both lobes, which is what p_V needs before any direction is sampled.)
fn may_leave(d: Vec3, ng: Vec3, wo: Vec3, transmits: bool) -> bool {
    let sides = d.dot(ng) * wo.dot(ng);
    sides > 0.0 || (transmits && sides < 0.0)
}

/// One iteration's distributions.
pub(super) struct Tables {
    /// Light subpaths resampled from (N).
    pub subset: usize,
    /// Light vertices of the subset by segments from the light: those of length l are
    /// `entries[len_start[l - 1]..len_start[l]]`, as (subpath, vertex index in the pool).
    pub entries: Vec<(u32, u32)>,
    pub len_start: Vec<u32>,
    /// Per anchor: its table, or [`NO_TABLE`].
    pub anchor_table: Vec<u32>,
    /// Table k: `cdfs[k E..(k + 1) E]` (E = entries.len()), one CDF per length range, and
    /// each entry's distribution.
    pub cdfs: Vec<f32>,
    pub origins: Vec<u8>,
    /// Table k's guide tables (`guide::resampling::cdf_guide`), one per length: that of length
    /// l is `guides[k G + guide_start[l - 1]..k G + guide_start[l]]` (G = the last
    /// `guide_start`).
    pub guides: Vec<u32>,
    pub guide_start: Vec<u32>,
}

impl Tables {
    fn lengths(&self) -> usize {
        self.len_start.len() - 1
    }

    /// Guide-table entries per table.
    fn guide_len(&self) -> usize {
        *self.guide_start.last().unwrap_or(&0) as usize
    }

    /// Anchors with a distribution.
    pub fn table_count(&self) -> usize {
        self.cdfs.len().checked_div(self.entries.len()).unwrap_or(0)
    }

    /// Connects `vertex` to light vertices of each length it may use: with probability
    /// n / N, n of the N subpaths having a vertex of that length, to one picked from table
    /// `table` (uniformly for [`NO_TABLE`]) with probability q, with the factor 1 / (n q)
    /// (over both choices the expected factor of each vertex is 1 / N: unbiased). Adds what
    /// each connection gave to the vertex's layer of the distribution it came from.
    ///
    /// The first choice makes as many connections per length, on average, as `bdpt`'s own
    /// subpath gives (a subpath has a vertex of that length with probability n / N): always
    /// connecting would trace a shadow ray per length for the long lengths few subpaths reach,
    /// each worth little (002 connects always; measured slower, BENCHMARKS.md issue 31).
    pub fn resample(
        &self,
        vertex: &CameraVertex,
        table: u32,
        rng: &mut Sampler,
        tally: &OcclusionTally,
        connect: &mut dyn FnMut(usize, usize, f32) -> Connection,
    ) {
        let tallied = vertex.pixel_index % OCCLUSION_TALLY_EVERY == 0;
        let kind = (table == NO_TABLE) as usize;
        let e = self.entries.len();
        let subset = self.subset as f32;
        let lengths = self.lengths().min(vertex.max_light_segments as usize);
        // All lengths are picked before any is connected (the connections draw no numbers, so
        // the picks and the image are the same): the picks' loads from the tables and the
        // light vertices are then independent of each other and of the shadow rays, and their
        // cache misses overlap instead of each waiting behind a connection.
        let mut picks = [Pick::default(); PICK_BATCH];
        let mut count = 0;
        for l in 0..lengths {
            let (a, b) = (self.len_start[l] as usize, self.len_start[l + 1] as usize);
            if a == b {
                continue;
            }
            let n = b - a;
            // Connect with probability n / N (see above).
            if rng.uniform() * subset >= n as f32 {
                continue;
            }
            let u = rng.uniform();
            let (i, q, origin) = if table == NO_TABLE {
                (
                    ((u * n as f32) as usize).min(n - 1),
                    1.0 / n as f32,
                    Origin::Fallback,
                )
            } else {
                let base = table as usize * e;
                let cdf = &self.cdfs[base + a..base + b];
                let g = table as usize * self.guide_len();
                let guide = &self.guides
                    [g + self.guide_start[l] as usize..g + self.guide_start[l + 1] as usize];
                let (i, q) = sample_cdf_guided(cdf, guide, u);
                // Read only for the per-distribution images.
                let origin = if vertex.layers.is_empty() {
                    Origin::Fallback
                } else {
                    Origin::from_u8(self.origins[base + a + i])
                };
                (i, q, origin)
            };
            let (j, v) = self.entries[a + i];
            picks[count] = Pick {
                subpath: j,
                vertex: v,
                factor: 1.0 / (n as f32 * q),
                origin,
            };
            count += 1;
            if count == PICK_BATCH {
                self.connect_picks(&picks, vertex, kind, tallied, tally, connect);
                count = 0;
            }
        }
        self.connect_picks(&picks[..count], vertex, kind, tallied, tally, connect);
    }

    /// Connects `vertex` to picked light vertices, in order ([`Tables::resample`]).
    fn connect_picks(
        &self,
        picks: &[Pick],
        vertex: &CameraVertex,
        kind: usize,
        tallied: bool,
        tally: &OcclusionTally,
        connect: &mut dyn FnMut(usize, usize, f32) -> Connection,
    ) {
        for p in picks {
            let c = connect(p.subpath as usize, p.vertex as usize, p.factor);
            if let Some(cell) = vertex.layers.get(p.origin as usize) {
                cell.set(cell.get() + c.added);
            }
            if tallied {
                tally.connections[kind].fetch_add(1, Ordering::Relaxed);
                tally.occluded[kind].fetch_add(c.occluded as u64, Ordering::Relaxed);
            }
        }
    }
}

/// Picks [`Tables::resample`] makes before connecting them.
const PICK_BATCH: usize = 8;

/// A light vertex picked for a connection: its subpath, its index in the pool, the factor.
#[derive(Clone, Copy)]
struct Pick {
    subpath: u32,
    vertex: u32,
    factor: f32,
    origin: Origin,
}

impl Default for Pick {
    fn default() -> Self {
        Pick {
            subpath: 0,
            vertex: 0,
            factor: 0.0,
            origin: Origin::Fallback,
        }
    }
}

/// Builds the distributions of the anchors marked in `used` over the vertices of the first
/// `subset` light subpaths (002 §4.2: p_V by a shadow ray between anchor and vertex, p_U by
/// luminance over squared distance, p_C uniform; max heuristic). Returns them with the number
/// of anchor-vertex pairs found visible.
pub(super) fn build_tables(
    scene: &Scene,
    anchors: &[Anchor],
    used: &[bool],
    paths: &LightPaths,
    subset: u32,
) -> (Tables, u64) {
    let subset = (subset as usize).min(paths.ranges.len());
    let longest = paths.vertices.iter().map(|v| v.path_len).max().unwrap_or(0) as usize;
    let mut per_len: Vec<Vec<(u32, u32)>> = vec![Vec::new(); longest];
    for (j, &(a, b)) in paths.ranges[..subset].iter().enumerate() {
        for v in a..b {
            let len = paths.vertices[v as usize].path_len as usize;
            per_len[len - 1].push((j as u32, v));
        }
    }
    let mut entries = Vec::new();
    let mut len_start = vec![0u32];
    for list in per_len {
        entries.extend(list);
        len_start.push(entries.len() as u32);
    }
    let mut anchor_table = vec![NO_TABLE; anchors.len()];
    let chosen: Vec<usize> = (0..anchors.len()).filter(|&k| used[k]).collect();
    for (t, &k) in chosen.iter().enumerate() {
        anchor_table[k] = t as u32;
    }
    let e = entries.len();
    // Per entry: whether its vertex's BSDF refracts ([`may_leave`]).
    let transmits: Vec<bool> = entries
        .iter()
        .map(|&(_, v)| scene.bsdf(&paths.vertices[v as usize].si).transmits())
        .collect();
    let mut cdfs = vec![0.0f32; chosen.len() * e];
    let mut origins = vec![0u8; chosen.len() * e];
    // Per length: K + 1 guide entries for its n entries (none for an empty length).
    let mut guide_start = vec![0u32];
    for l in 0..len_start.len() - 1 {
        let n = (len_start[l + 1] - len_start[l]) as usize;
        let size = if n == 0 { 0 } else { guide_buckets(n) + 1 };
        guide_start.push(guide_start[l] + size as u32);
    }
    let guide_len = guide_start[guide_start.len() - 1] as usize;
    let mut guides = vec![0u32; chosen.len() * guide_len];
    let visible_pairs = AtomicU64::new(0);
    if e > 0 {
        cdfs.par_chunks_mut(e)
            .zip(origins.par_chunks_mut(e))
            .zip(guides.par_chunks_mut(guide_len.max(1)))
            .zip(chosen.par_iter())
            .for_each(|(((cdf, origin), guide), &k)| {
                let anchor = anchors[k];
                let mut weights = vec![0.0f32; e];
                let mut visible = vec![false; e];
                let mut seen = 0u64;
                for (i, &(_, v)) in entries.iter().enumerate() {
                    let y = &paths.vertices[v as usize];
                    let d = anchor.p - y.si.p;
                    let dist2 = d.length_squared().max(1e-12);
                    let w = luminance(y.throughput).max(0.0) / dist2;
                    weights[i] = if w.is_finite() { w } else { 0.0 };
                    // A connection must be able to leave the vertex towards the anchor and
                    // a surface anchor towards the vertex ([`may_leave`]), and the segment
                    // must be unoccluded.
                    let leaves_vertex = may_leave(d, y.si.ng, y.si.wo, transmits[i]);
                    visible[i] = leaves_vertex
                        && match anchor.surface {
                            None => !scene.occluded(&y.si.spawn_ray_to(
                                anchor.p,
                                Vec3::ZERO,
                                Vec3::ZERO,
                            )),
                            Some(a) => {
                                may_leave(-d, a.ng, a.wo, a.transmits)
                                    && !scene
                                        .occluded(&y.si.spawn_ray_to(anchor.p, a.p_error, a.ng))
                            }
                        };
                    seen += visible[i] as u64;
                }
                for l in 0..len_start.len() - 1 {
                    let (a, b) = (len_start[l] as usize, len_start[l + 1] as usize);
                    combined_distribution(
                        &weights[a..b],
                        &visible[a..b],
                        &mut cdf[a..b],
                        &mut origin[a..b],
                    );
                    if a < b {
                        let (ga, gb) = (guide_start[l] as usize, guide_start[l + 1] as usize);
                        cdf_guide(&cdf[a..b], &mut guide[ga..gb]);
                    }
                }
                visible_pairs.fetch_add(seen, Ordering::Relaxed);
            });
    }
    (
        Tables {
            subset,
            entries,
            len_start,
            anchor_table,
            cdfs,
            origins,
            guides,
            guide_start,
        },
        visible_pairs.into_inner(),
    )
}

#[cfg(test)]
mod tests {
    use super::may_leave;
    use crate::math::Vec3;

    /// An opaque surface is left on the side it was reached from only; a refracting one on
    /// either side; never along the surface's plane.
    #[test]
    fn connections_leave_opaque_surfaces_on_the_eyes_side_and_refracting_ones_on_both() {
        let (ng, from_above) = (Vec3::Y, Vec3::new(0.3, 0.8, 0.1).normalize());
        let (up, down) = (Vec3::new(0.1, 1.0, 0.0), Vec3::new(0.1, -1.0, 0.0));
        assert!(may_leave(up, ng, from_above, false));
        assert!(!may_leave(down, ng, from_above, false));
        assert!(may_leave(up, ng, from_above, true));
        assert!(may_leave(down, ng, from_above, true));
        // Reached from below (the back side): mirrored.
        assert!(may_leave(down, ng, -from_above, false));
        assert!(!may_leave(up, ng, -from_above, false));
        // In the plane: no side.
        assert!(!may_leave(Vec3::X, ng, from_above, true));
    }
}
