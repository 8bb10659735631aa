//! Vertex-connection resampling shared by SkelBPT (`bdpt_skeleton`, anchors at skeleton
//! nodes) and ICBPT (`bdpt_ic`, anchors at importance records): one iteration's
//! distributions over the light vertices of the first N light subpaths, one per anchor and
//! light subpath length (`guide::resampling`), and the resampled connection of a camera
//! vertex to one light vertex of each length.

use std::sync::atomic::{AtomicU64, Ordering};

use rayon::prelude::*;

use super::bdpt::{CameraVertex, Connection, LightPaths};
use crate::guide::resampling::{combined_distribution, sample_cdf, Origin};
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
}

impl Tables {
    fn lengths(&self) -> usize {
        self.len_start.len() - 1
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
                let (i, q) = sample_cdf(cdf, u);
                (i, q, Origin::from_u8(self.origins[base + a + i]))
            };
            let (j, v) = self.entries[a + i];
            let c = connect(j as usize, v as usize, 1.0 / (n as f32 * q));
            if let Some(cell) = vertex.layers.get(origin as usize) {
                cell.set(cell.get() + c.added);
            }
            if tallied {
                tally.connections[kind].fetch_add(1, Ordering::Relaxed);
                tally.occluded[kind].fetch_add(c.occluded as u64, Ordering::Relaxed);
            }
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
    let visible_pairs = AtomicU64::new(0);
    if e > 0 {
        cdfs.par_chunks_mut(e)
            .zip(origins.par_chunks_mut(e))
            .zip(chosen.par_iter())
            .for_each(|((cdf, origin), &k)| {
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
