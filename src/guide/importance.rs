//! Where the guide aims, found at build: emitted power per node by light tracing
//! (eq. 171-176), shortest paths along the filtered skeleton (Dijkstra, §9.2.1), and each
//! path's opening (its bottleneck, the opening's size and its rectangle), then the lobes of
//! a node from all of these ([`node_lobes`]).
//!
//! # Aiming through the opening (a variant of eq. 162, `aim=opening`)
//!
//! The thesis motivates eq. 162 as "the point to aim at to get towards the importance node"
//! (000 §9.3, 004). The centre of the prefix visible *from the node* is a good such point in
//! open space, but where the way to the light leaves a room through a narrow opening it lies
//! inside the room: the nodes beyond the opening are hidden from the node's position (the
//! medial axis runs through the room's middle), so the prefix stops short and the lobes of
//! the whole room converge on a point in its middle (the Veach door, BENCHMARKS.md "Why the
//! door gains nothing"). What a surface point x should aim at is the opening itself, and what
//! matters is whether *x* sees it, not whether the node does. So each lobe also keeps the
//! path's **bottleneck**: the first node of smallest maximal-ball radius on the whole
//! shortest path (after the node itself, at most `MAX_BOTTLENECK_SEARCH` nodes: a walk along
//! the Dijkstra tree, no rays), provided the path narrows there (a ball at least
//! `OPENING_NARROWING` times wider comes before it; a corridor has no opening), and the size
//! of the opening there: the radius of the disc of its area across the path, measured with
//! `OPENING_RAYS` rays at precomputation (a maximal ball measures only an opening's
//! narrowest width, and the door's gap is a slit as tall as the door). At a point x with
//! `aim=opening` the lobe aims at the bottleneck when x sees it (one shadow ray with the
//! visibility test) and it is above the surface, with the automatic strength taken from that
//! radius at the bottleneck's distance from x (the lobe as wide as the opening looks from
//! x); otherwise it falls back to the importance point of eq. 162 (a second shadow ray). Which target a lobe takes is
//! decided per point before any sampling, from x alone, so sampling and the pdf see the same
//! mixture and the estimator stays unbiased whatever the aim.
//!
//! # Sampling the opening itself (`aim=portal`)
//!
//! A round lobe fits a slit badly: the Veach door's gap is 15 units wide and as tall as the
//! door (its maximal ball has radius 7.6, the disc of its area 60.7), so a lobe either
//! wastes most samples beside it or misses most of it. With `aim=portal` the precomputation
//! also fits each bottleneck's cross-section as a planar rectangle (`opening_rectangle`):
//! its plane is the one of least cross-section area among normals within 75° of the path's
//! direction (paths often cross a slit obliquely, and a plane normal to the path would cut
//! it lengthwise), its axes the principal axes of the outline in that plane, its extents
//! one ray each way along them. At a point x that sees the bottleneck (the shadow ray of
//! `aim=opening`) the lobe becomes directions uniform in the rectangle's solid angle (the
//! spherical rectangle of Ureña, Fajardo and King 2013, `math::warp::SphericalRectangle`),
//! whose density at any direction is exact (1 / solid angle where the ray from x crosses
//! the rectangle, else 0). Where the rectangle covers wall as well as gap, the estimator
//! stays unbiased: BSDF sampling covers every direction, and the mixture density is exact.
//! Elsewhere (x does not see the bottleneck, lies in the rectangle's plane, or the path has
//! no opening) the lobe is the one of `aim=opening`. The strength does not apply to a
//! rectangle (`c_skel=learned` learns the probability alone).

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use rayon::prelude::*;

use super::lobes::{GuideLobe, ImportanceNode, Portal};
use super::settings::{LobeAim, SkeletonGuideSettings};
use crate::analysis::{map_point, Graph, VoxelGrid};
use crate::geometry::{offset_ray_origin, Ray, SHADOW_EPSILON};
use crate::math::{luminance, Frame, Rng, Vec2, Vec3};
use crate::scene::Scene;

/// Longest visible prefix averaged into an importance point. Eq. 162 takes the whole visible
/// prefix; in long open spaces (Sibenik's nave) that means hundreds of shadow rays per node and
/// lobe (3 s of Sibenik's precomputation under load), while the nodes beyond the first few
/// dozen only move the point further along the same line of sight.
const MAX_PREFIX: u32 = 24;

/// Seed of the light-tracing pass (the guide is a deterministic function of the scene).
const LIGHT_TRACING_SEED: u64 = 0x5ce1_e70a;
/// Rays per parallel chunk of the light-tracing pass.
const LIGHT_CHUNK: u32 = 4096;

/// Eq. 176 for every node at once: the emitted power (luminance) arriving on the surfaces
/// mapped to each node, from `light_rays` rays leaving the lights. Deterministic (fixed seed,
/// per-chunk streams, chunk sums added in chunk order).
pub(super) fn trace_light_power(
    scene: &Scene,
    grid: &VoxelGrid,
    node_map: &[u32],
    nodes: usize,
    settings: &SkeletonGuideSettings,
) -> Vec<f64> {
    let Some(sampler) = scene.light_sampler() else {
        return vec![0.0; nodes];
    };
    let n = settings.light_rays;
    let chunks = n.div_ceil(LIGHT_CHUNK);
    let partial: Vec<Vec<f64>> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let mut sums = vec![0.0f64; nodes];
            let mut rng = Rng::new(LIGHT_TRACING_SEED, c as u64);
            let count = LIGHT_CHUNK.min(n - c * LIGHT_CHUNK);
            for _ in 0..count {
                let (index, pmf) = sampler.sample(rng.uniform());
                let light = &scene.lights()[index];
                let Some(e) = light.sample_emission(rng.uniform2(), rng.uniform2()) else {
                    continue;
                };
                let weight = luminance(e.value) as f64 / (e.pdf_emit as f64 * pmf as f64);
                if !(weight.is_finite() && weight > 0.0) {
                    continue;
                }
                let origin = offset_ray_origin(e.origin, e.origin_error, e.normal, e.dir);
                let Some(si) = scene.intersect(&Ray::new(origin, e.dir, f32::INFINITY)) else {
                    continue;
                };
                if let Some(node) = map_point(grid, node_map, si.p, si.ng, si.wo) {
                    sums[node as usize] += weight;
                }
            }
            sums
        })
        .collect();
    let mut power = vec![0.0f64; nodes];
    for sums in partial {
        for (p, s) in power.iter_mut().zip(sums) {
            *p += s;
        }
    }
    for p in &mut power {
        *p /= n as f64;
    }
    power
}

/// Neighbours of each node with the Euclidean length of the edge.
pub(super) fn weighted_adjacency(graph: &Graph) -> Vec<Vec<(u32, f32)>> {
    let mut adj = vec![Vec::new(); graph.nodes.len()];
    for &[a, b] in &graph.edges {
        let d = graph.nodes[a as usize]
            .position
            .distance(graph.nodes[b as usize].position);
        adj[a as usize].push((b, d));
        adj[b as usize].push((a, d));
    }
    adj
}

/// Shortest paths from every node to one source.
pub(super) struct ShortestPaths {
    /// Graph distance to the source (infinite when unreachable).
    distance: Vec<f32>,
    /// Next node on the way to the source (`u32::MAX` at the source and when unreachable).
    next: Vec<u32>,
}

#[derive(PartialEq)]
struct Queued(f32, u32);

impl Eq for Queued {}

impl Ord for Queued {
    // Reversed: BinaryHeap is a max-heap and Dijkstra pops the nearest node.
    fn cmp(&self, other: &Self) -> Ordering {
        other.0.total_cmp(&self.0).then(other.1.cmp(&self.1))
    }
}

impl PartialOrd for Queued {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

pub(super) fn dijkstra(adjacency: &[Vec<(u32, f32)>], source: u32) -> ShortestPaths {
    let n = adjacency.len();
    let mut distance = vec![f32::INFINITY; n];
    let mut next = vec![u32::MAX; n];
    let mut heap = BinaryHeap::new();
    distance[source as usize] = 0.0;
    heap.push(Queued(0.0, source));
    while let Some(Queued(d, u)) = heap.pop() {
        if d > distance[u as usize] {
            continue;
        }
        for &(v, w) in &adjacency[u as usize] {
            let nd = d + w;
            if nd < distance[v as usize] {
                distance[v as usize] = nd;
                next[v as usize] = u;
                heap.push(Queued(nd, v));
            }
        }
    }
    ShortestPaths { distance, next }
}

/// True when nothing blocks the straight segment between two points of the empty space.
pub(super) fn visible(scene: &Scene, a: Vec3, b: Vec3) -> bool {
    let d = b - a;
    let len = d.length();
    if len == 0.0 {
        return true;
    }
    !scene.occluded(&Ray::new(a, d / len, len * (1.0 - SHADOW_EPSILON)))
}

/// Longest stretch of a shortest path searched for its bottleneck (no rays are traced: a
/// walk along the tree).
const MAX_BOTTLENECK_SEARCH: u32 = 256;

/// A path's narrowest ball is an opening when the path has passed a ball at least this many
/// times wider before reaching it (a room narrowing into a door), not a corridor's small
/// variations of width. On the Veach door the gap's ball (7.6) follows the camera room's
/// (60.1): 7.9x; in the two rooms 8x; along the corridor at most 1.3x.
const OPENING_NARROWING: f32 = 2.0;

/// The bottleneck of the shortest path from node `k` in `tree`: position and radius of the
/// first node of smallest maximal ball after `k` (radii are whole voxels, so ties are common:
/// the first is the way into the narrow part), and the path's direction there (from the node
/// before it to the node after it, or to it at the path's end). None when the path has no
/// node after `k` or does not narrow by `OPENING_NARROWING` before its smallest ball.
fn bottleneck(graph: &Graph, tree: &ShortestPaths, k: usize) -> Option<(Vec3, f32, Vec3)> {
    let mut best: Option<(Vec3, f32, Vec3, f32)> = None;
    let mut previous = graph.nodes[k].position;
    let mut widest = graph.nodes[k].radius;
    let mut current = k as u32;
    let mut steps = 0;
    while tree.next[current as usize] != u32::MAX && steps < MAX_BOTTLENECK_SEARCH {
        current = tree.next[current as usize];
        let n = &graph.nodes[current as usize];
        let narrower = match best {
            Some((_, r, _, _)) => n.radius < r,
            None => true,
        };
        if narrower {
            let after = tree.next[current as usize];
            let ahead = if after == u32::MAX {
                n.position
            } else {
                graph.nodes[after as usize].position
            };
            let along = (ahead - previous).normalize_or_zero();
            best = Some((n.position, n.radius, along, widest));
        }
        widest = widest.max(n.radius);
        previous = n.position;
        steps += 1;
    }
    best.filter(|&(_, r, _, wider)| wider >= OPENING_NARROWING * r)
        .map(|(at, r, along, _)| (at, r, along))
}

/// Rays cast across the path at a bottleneck to measure its opening.
const OPENING_RAYS: u32 = 16;

/// The radius of the disc with the area of the opening at `centre` across the path direction
/// `along`: `OPENING_RAYS` rays in the plane normal to `along` (each at most `cap` long) give
/// the opening's outline, a polygon of area `sum d_j d_(j+1) sin(2 pi / N) / 2`. A maximal
/// ball measures an opening's narrowest width; the door's gap is a slit as tall as the door
/// and a few voxels wide, which a lobe as wide as the ball would cover only a sliver of.
/// At least `ball` (the opening is no smaller than its inscribed ball).
fn opening_radius(scene: &Scene, centre: Vec3, along: Vec3, ball: f32, cap: f32) -> f32 {
    if along == Vec3::ZERO {
        return ball;
    }
    let frame = Frame::from_z(along);
    let step = 2.0 * std::f32::consts::PI / OPENING_RAYS as f32;
    let reach: Vec<f32> = (0..OPENING_RAYS)
        .map(|j| {
            let (sin, cos) = (j as f32 * step).sin_cos();
            let dir = frame.to_world(Vec3::new(cos, sin, 0.0));
            scene
                .intersect(&Ray::new(centre, dir, cap))
                .map_or(cap, |hit| hit.t)
        })
        .collect();
    let area: f32 = (0..reach.len())
        .map(|j| reach[j] * reach[(j + 1) % reach.len()])
        .sum::<f32>()
        * 0.5
        * step.sin();
    (area / std::f32::consts::PI).sqrt().max(ball)
}

/// Rays cast across the path at a bottleneck to find the principal axes of its opening.
const PORTAL_RAYS: u32 = 64;
/// Plane normals tried for a portal (module docs: the path's direction at the bottleneck is
/// a poor normal where the path crosses a slit obliquely), with cosines down to
/// `PORTAL_TILT_COS` to the path's direction (75°).
const PORTAL_NORMALS: u32 = 96;
const PORTAL_TILT_COS: f32 = 0.25;
/// Rays per tried normal to measure the cross-section's area.
const PORTAL_AREA_RAYS: u32 = 32;

/// Distance from `centre` along `dir` to the first surface, at most `cap`.
fn reach(scene: &Scene, centre: Vec3, dir: Vec3, cap: f32) -> f32 {
    scene
        .intersect(&Ray::new(centre, dir, cap))
        .map_or(cap, |hit| hit.t)
}

/// Area of the opening's outline in the plane through `centre` normal to `normal`, from
/// `rays` rays (the polygon of `opening_radius`).
fn cross_section_area(scene: &Scene, centre: Vec3, normal: Vec3, rays: u32, cap: f32) -> f32 {
    let frame = Frame::from_z(normal);
    let step = 2.0 * std::f32::consts::PI / rays as f32;
    let d: Vec<f32> = (0..rays)
        .map(|j| {
            let (sin, cos) = (j as f32 * step).sin_cos();
            reach(scene, centre, frame.to_world(Vec3::new(cos, sin, 0.0)), cap)
        })
        .collect();
    (0..d.len())
        .map(|j| d[j] * d[(j + 1) % d.len()])
        .sum::<f32>()
        * 0.5
        * step.sin()
}

/// The opening's cross-section at `centre` fitted as a rectangle. Its plane is the one of
/// least cross-section area among `PORTAL_NORMALS` normals around the path direction `along`
/// (a slit crossed obliquely is cut square, not along its length); in it `PORTAL_RAYS` rays
/// (each at most `cap` long) outline the opening, the outline's second moments about `centre`
/// give its principal axes, and one ray each way along both axes its extents (a slit's length
/// measured along the slit, not by the ray that happens to come closest to its axis). None
/// when `along` is zero.
fn opening_rectangle(scene: &Scene, centre: Vec3, along: Vec3, cap: f32) -> Option<Portal> {
    if along == Vec3::ZERO {
        return None;
    }
    let around = Frame::from_z(along);
    let golden = std::f32::consts::PI * (3.0 - 5.0f32.sqrt());
    let mut normal = along;
    let mut least = cross_section_area(scene, centre, along, PORTAL_AREA_RAYS, cap);
    for i in 0..PORTAL_NORMALS {
        // A Fibonacci spiral over the cap of normals within the tilt bound.
        let cos = 1.0 - (1.0 - PORTAL_TILT_COS) * (i as f32 + 0.5) / PORTAL_NORMALS as f32;
        let sin = (1.0 - cos * cos).max(0.0).sqrt();
        let phi = golden * i as f32;
        let n = around.to_world(Vec3::new(sin * phi.cos(), sin * phi.sin(), cos));
        let area = cross_section_area(scene, centre, n, PORTAL_AREA_RAYS, cap);
        if area < least {
            least = area;
            normal = n;
        }
    }
    let frame = Frame::from_z(normal);
    let step = 2.0 * std::f64::consts::PI / PORTAL_RAYS as f64;
    let (mut sxx, mut sxy, mut syy) = (0.0f64, 0.0f64, 0.0f64);
    for j in 0..PORTAL_RAYS {
        let (sin, cos) = (j as f64 * step).sin_cos();
        let dir = frame.to_world(Vec3::new(cos as f32, sin as f32, 0.0));
        let d = reach(scene, centre, dir, cap) as f64;
        let (qx, qy) = (d * cos, d * sin);
        sxx += qx * qx;
        sxy += qx * qy;
        syy += qy * qy;
    }
    let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let (sin, cos) = (theta.sin() as f32, theta.cos() as f32);
    let u = frame.to_world(Vec3::new(cos, sin, 0.0)).normalize();
    let v = normal.cross(u).normalize();
    let [u_plus, u_minus, v_plus, v_minus] = [u, -u, v, -v].map(|d| reach(scene, centre, d, cap));
    Some(Portal::new(
        centre + 0.5 * (u_plus - u_minus) * u + 0.5 * (v_plus - v_minus) * v,
        u,
        v,
        0.5 * Vec2::new(u_plus + u_minus, v_plus + v_minus),
    ))
}

/// Longest side of a portal, in maximal-ball radii of its bottleneck (an opening into open
/// space has no measurable extent; a larger rectangle only wastes samples on walls).
const PORTAL_CAP: f32 = 64.0;

/// The measured openings of the bottlenecks, shared by the nodes' lobes: every node upstream
/// of a door reaches it along the same path segment, so the door's opening (its radius, and
/// with `aim=portal` its rectangle, about 3,200 rays) would otherwise be measured again for
/// every such node and lobe. The measurements are pure functions of the key (bottleneck
/// position, path direction, ball radius, bit for bit), so which thread fills an entry first
/// changes nothing: the guide stays identical across thread counts.
#[derive(Default)]
pub(super) struct OpeningFits {
    fits: std::sync::Mutex<std::collections::HashMap<OpeningKey, OpeningFit>>,
}

/// Bits of a bottleneck's position, path direction and ball radius.
type OpeningKey = [u32; 7];
/// The opening's area-equivalent radius and, with `aim=portal`, its rectangle.
type OpeningFit = (f32, Option<Portal>);

impl OpeningFits {
    /// The opening's radius ([`opening_radius`]) and, with `aim=portal`, its rectangle
    /// ([`opening_rectangle`]) at bottleneck `at` crossed along `along`, of maximal ball `ball`.
    fn get(
        &self,
        scene: &Scene,
        settings: &SkeletonGuideSettings,
        at: Vec3,
        along: Vec3,
        ball: f32,
    ) -> OpeningFit {
        let key: OpeningKey = [
            at.x.to_bits(),
            at.y.to_bits(),
            at.z.to_bits(),
            along.x.to_bits(),
            along.y.to_bits(),
            along.z.to_bits(),
            ball.to_bits(),
        ];
        let lock = || {
            self.fits
                .lock()
                .unwrap_or_else(|poisoned| poisoned.into_inner())
        };
        if let Some(&fit) = lock().get(&key) {
            return fit;
        }
        // Measured outside the lock (the other thread may measure the same key meanwhile:
        // same result).
        let fit = (
            opening_radius(scene, at, along, ball, 16.0 * ball),
            (settings.aim == LobeAim::Portal)
                .then(|| opening_rectangle(scene, at, along, PORTAL_CAP * ball))
                .flatten(),
        );
        lock().insert(key, fit);
        fit
    }
}

/// The lobes of node `k`: selection weights (eq. 164-165) and importance points (eq. 162).
pub(super) fn node_lobes(
    scene: &Scene,
    graph: &Graph,
    k: usize,
    importance: &[ImportanceNode],
    trees: &[ShortestPaths],
    settings: &SkeletonGuideSettings,
    openings: &OpeningFits,
) -> Vec<GuideLobe> {
    let node = &graph.nodes[k];
    let mut candidates: Vec<(f64, usize)> = importance
        .iter()
        .zip(trees)
        .enumerate()
        .filter(|(_, (_, tree))| tree.distance[k].is_finite())
        .map(|(i, (imp, tree))| {
            let d = tree.distance[k].max(node.radius).max(1e-30) as f64;
            (imp.power as f64 / (d * d), i)
        })
        .filter(|(w, _)| *w > 0.0 && w.is_finite())
        .collect();
    candidates.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    candidates.truncate(settings.max_lobes as usize);
    let total: f64 = candidates.iter().map(|c| c.0).sum();
    let mut lobes: Vec<GuideLobe> = Vec::with_capacity(candidates.len());
    for (weight, i) in candidates {
        let tree = &trees[i];
        let from = node.position;
        let mut sum = from;
        let mut count = 1u32;
        let mut radius = node.radius;
        let mut current = k as u32;
        while tree.next[current as usize] != u32::MAX && count < MAX_PREFIX {
            current = tree.next[current as usize];
            let n = &graph.nodes[current as usize];
            if !visible(scene, from, n.position) {
                break;
            }
            sum += n.position;
            count += 1;
            radius = radius.min(n.radius);
        }
        let point = sum / count as f32;
        let (opening, opening_radius, portal) = match bottleneck(graph, tree, k) {
            Some((at, ball, along)) => {
                let (radius, portal) = openings.get(scene, settings, at, along, ball);
                (at, radius, portal)
            }
            None => (point, radius, None),
        };
        let probability = (weight / total) as f32;
        // Shortest paths to several importance nodes often share their visible prefix (every
        // way out of a room goes through its door): their lobes are one lobe, and keeping them
        // apart would cost one shadow ray and one lobe evaluation each per vertex for nothing.
        if let Some(same) = lobes.iter_mut().find(|l| {
            l.point == point
                && l.radius == radius
                && l.opening == opening
                && l.opening_radius == opening_radius
                && l.portal == portal
        }) {
            same.probability += probability;
            continue;
        }
        lobes.push(GuideLobe {
            point,
            radius,
            probability,
            importance: i as u32,
            distance: tree.distance[k],
            opening,
            opening_radius,
            portal,
        });
    }
    lobes.sort_by(|a, b| b.probability.total_cmp(&a.probability));
    lobes
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dijkstra_finds_shortest_paths_and_unreachable_nodes() {
        // 0 - 1 - 2 and 0 - 3 - 2 with the second route shorter; node 4 is isolated.
        let adj = vec![
            vec![(1, 1.0), (3, 0.5)],
            vec![(0, 1.0), (2, 1.0)],
            vec![(1, 1.0), (3, 0.6)],
            vec![(0, 0.5), (2, 0.6)],
            vec![],
        ];
        let sp = dijkstra(&adj, 2);
        assert_eq!(sp.distance[2], 0.0);
        assert!((sp.distance[0] - 1.1).abs() < 1e-6);
        assert_eq!(sp.next[0], 3);
        assert_eq!(sp.next[3], 2);
        assert_eq!(sp.next[2], u32::MAX);
        assert!(sp.distance[4].is_infinite() && sp.next[4] == u32::MAX);
    }
}
