//! `vpl`: instant radiosity (Keller 1997; 000 §4.1.4, lines 1356-1436), a fast preview.
//!
//! Each sample index ("pass") traces `count` light subpaths with `bdpt`'s light tracing
//! ([`Bdpt::trace_light_paths`], without its splats onto the camera); every stored vertex is a
//! virtual point light (VPL). A camera path follows delta surfaces to its first non-delta
//! vertex x, which gets
//! - direct light by next-event estimation ([`estimator::sample_direct_light`]), and
//! - indirect light from every VPL y of the pass with an exact shadow ray:
//!   `T_y f_y(y -> x) f_x(x -> y) G(x, y) / 1`, T_y the VPL's light-subpath throughput (the
//!   pass's subpaths are one sample each of the light transport, so their VPLs together are
//!   one unbiased estimate of the indirect light at every point).
//!
//! # Clamping and its compensation
//!
//! `G = |cos_x| |cos_y| / d^2` (shading cosines) is unbounded where x and y are close: the
//! estimate's variance is infinite and the image shows bright blotches. With `clamp = r > 0`,
//! the VPL term uses `min(G, b)` with `b = 1 / (r D)^2`, D the diagonal of the scene's bounds
//! (a term clamped at distance r D). When G exceeds b the clamped term is computed as
//! `T f_y f_x b`, so no tiny distance divides anything. Clamping removes energy (the image is
//! darker near corners): biased.
//!
//! `compensate=true` adds back what was clamped (Kollig & Keller 2004, "Illumination in the
//! presence of weak singularities"). Write c(x, y) = min(1, b / G(x, y)); the VPLs estimate
//! the integral of the indirect integrand times c, and one BSDF-sampled direction from x
//! estimates the integral times (1 - c): it finds the surface point y along that direction and
//! continues there with weight (1 - c(x, y)) f_x |cos_x| / p, estimating the light leaving y
//! towards x by this same estimator (next-event estimation, VPLs, compensation), without y's
//! emission, which next-event estimation at x counted. A delta surface hit this way has no
//! VPL (c = 0): the continuation goes through it with weight 1, and there the emitters found
//! behind it count (no light sample reaches through a delta surface). The sum is unbiased
//! whatever b; far from corners 1 - c = 0 and the continuation ends at once.
//!
//! Without compensation the paths VPLs cannot represent are missing too: light reaching a
//! non-delta vertex by way of a delta surface (caustics seen on a diffuse wall). The image is
//! unbiased only with compensation (or with `clamp=0` on scenes without delta surfaces);
//! [`VplOptions::bias`] says which.
//!
//! # Skeleton visibility (`visibility=skeleton`; 000 chapter 8, eq. 158-161)
//!
//! Eq. 158 sums `I(y) M(y, z) V(y, z) G*(y, z)` over the VPLs y (G* the geometry term without
//! visibility); eq. 159 replaces `V(y, z)` by `V_f(n_y, z)`, the filtered visibility between
//! the VPL's skeleton node n_y (the filtered node its surface point maps to, eq. 151-155) and
//! z, read with PCF from n_y's cube shadow map (`skeleton_shadow`). Grouping the VPLs by node
//! (eq. 160) factors it out of each group's sum (eq. 161): at a shading point, a group whose
//! `V_f` is 0 is skipped whole, and the others add `V_f` times their unshadowed sum, with no
//! shadow ray at all. With `verify=0` this is the thesis's approximation as it is: the node
//! sits in the middle of the empty space, not at the VPL, so a VPL that sees z from behind
//! an obstacle the node sees past (or the reverse) is lit (or shadowed) wrongly; and the
//! map's PCF softens the shadow edges. On the door that errs by 0.64-0.87 of the VPL light
//! at the pairs (tests/vpl.rs prints the split): the map's own reading (texel size, depth
//! bias, PCF) a third, the node seeing the point otherwise than its VPL two thirds, VPLs
//! their node does not see at all little.
//!
//! # Verification (`verify=P`, default [`DEFAULT_VERIFY`])
//!
//! Where the maps are unsure, a shadow ray decides, traced with probability P and weighted
//! 1 / P (Russian roulette, unbiased against always tracing it; its random number a hash
//! of the two points, so the same for any thread count):
//! - the node behind z's surface (it cannot stand in for a VPL in front of it; the map
//!   itself reads 0 there, where a depth bias would let light through a thin wall);
//! - the PCF kernel straddling a shadow edge (0 < V_f < 1);
//! - the *receiver* map disagreeing: the map of z's own node (at half the resolution, built
//!   for the nodes the view's surfaces map to, and only those: never a node map built by
//!   an earlier pass or render) read at the VPL gives the other verdict. A
//!   group its node's map skips is still read this way where the receiver map sees the
//!   group's node, since the node's view differs from its VPLs' (parallax).
//!
//! On the door this cuts the error to 0.09-0.14 of the light, with a shadow ray for a
//! quarter of the pairs (before the roulette). The image stays biased: the pairs both maps
//! agree on wrongly (mostly visible pairs both call occluded: the image is darker).
//!
//! # Map sites (`sites=K`; default 0, the node maps above)
//!
//! The node stands mid-room, far from VPLs near a door's gap, and sees the point otherwise
//! than they do (parallax): on the door two thirds of the maps' error, and after
//! verification most of what is left (visible pairs both maps call occluded). With
//! `sites=K` a VPL's visibility is read from the map of its *site* instead: the skeleton
//! grid's cell of K^3 voxels holding the empty voxel its surface point maps through (the
//! voxel of eq. 151-155, on the side the surface faces), together with that voxel's node
//! (so a wall through the cell makes two sites). The site's map stands at the centre of the
//! empty voxel of the site nearest their centroid: within K voxels of its VPLs, in the free
//! space they face. A site is a function of the scene alone (never of which VPLs came
//! first), so its map is made when a site first carries a VPL and kept as node maps are,
//! within the same budget; it is lazy (`CubeShadowMap::lazy`: a texel is traced when a
//! lookup first reads it, the same depth as a map built whole), and a site's group, a VPL
//! or a few, reads its map only once one of them faces the shading point. A VPL its site's centre does not see (one ray
//! per VPL and pass), or whose site got no map, keeps its node's map (or exact rays). The
//! skeleton still groups the VPLs (a group per site, skipped whole where its map reads 0,
//! eq. 161) and gives the receiver maps of the verification. Finer sites cost more maps
//! (door, two passes of 64 subpaths: K = 4, 8, 16 made 357, 285, 159 maps), and a pass
//! costs 2-3x one with node maps, whose groups are skipped whole (BENCHMARKS.md).
//!
//! VPLs mapped to no node, and those of nodes the memory budget left without a map, keep
//! exact shadow rays. The maps are made when a node first carries VPLs (in
//! `begin_iteration`) and kept for later passes and renders of the same scene; all are lazy
//! (a texel traced by the lookup that first reads it, in the render's time), so a pass pays
//! only for the texels its shading points read. Chapter 7's visibility clusters are not built
//! (`visibility=clusters` is refused): docs/vpl-visibility.md gives the measurements.
//!
//! # Importance-driven selection (`select=importance`, the default)
//!
//! After Georgiev & Slusallek 2010 ("Simple and robust iterative importance sampling of
//! virtual point lights"). Where most VPLs cannot light what the camera sees (the door:
//! the light room holds most of them, and 6 % of the VPL / pixel pairs are visible), a pass
//! spends most of its work, and skeleton visibility most of its bias, on them. So a pass
//! traces `candidates` x `count` light subpaths (each VPL's throughput divided by all of
//! them) and keeps each candidate VPL with probability `p = clamp(e / t, p_min, 1)`,
//! weighting it by 1 / p (Russian roulette: the expectation is the plain estimator's with
//! the same candidates, clamp and compensation, so `compensate=true` stays unbiased). Its
//! importance e is its light (luminance, the clamped term, exact shadow rays) at `probes`
//! camera probe points: the first non-delta vertices of a grid of pixel centres, with the
//! throughput of the delta surfaces before them, traced with fixed numbers. t is set from
//! the pass's candidates so that the probabilities sum to one `candidates`-th of them
//! ([`acceptance_probabilities`]): a function of the candidates, never of an acceptance
//! draw; each draw is a hash of the seed, the pass and the candidate's index (the same
//! image for any thread count). Every kept VPL lighting the probes carries about the same
//! importance t; `p_min` keeps those lighting no probe (which may still light pixels
//! between probes or points behind delta surfaces) reachable, at weight at most 1 / p_min.
//! Candidates too long for any path of `max_depth` are dropped (they light nothing).
//! `select=uniform` keeps every VPL of `count` subpaths. With skeleton visibility,
//! `probe_maps=true` reads a probe's visibility of a candidate from the receiver map of the
//! probe's node where that map is sure (0 or 1), a shadow ray otherwise: the selection's
//! rays were a fifth to a third of a one-second pass on the door (BENCHMARKS.md). Still
//! unbiased against the plain estimator (the acceptance probabilities are any function of
//! the candidates); the map's parallax makes some importances wrong, which costs variance.
//!
//! # Interleaved sampling (`interleave=N`; Keller & Heidrich 2001)
//!
//! A pass of 64 VPLs leaves the VPL light blotchy, and at 128x96 a second buys only 6-20
//! passes. With `interleave=N` a pass traces N² VPL sets (set k of pass s drawn as sample
//! index s N² + k, so N = 1 is the plain estimator bit for bit) and pixel (x, y) gathers
//! only set (x mod N, y mod N): the shadow rays per pixel stay those of one set. The pass
//! is then traced for every pixel in `begin_iteration` (in parallel, each pixel's ray and
//! numbers those the render loop would draw, [`View::sampler`]), and each pixel's indirect
//! light, everything past its first non-delta vertex x (x's VPL light and, with
//! `compensate=true`, the continuation from x), is filtered by a discontinuity buffer
//! ([`filter_indirect`]): demodulated by the diffuse albedo of x times the throughput of the
//! delta vertices before it, averaged over the pixels of the N x N window around it whose x
//! has the same material behind as many delta vertices, a normal within about 25 degrees,
//! a depth within 10 % and lies within 2 % of the depth of the other's tangent plane
//! (renormalized over those: the window holds each set once), and multiplied back by the
//! pixel's own modulation (textures stay sharp). Direct light and emission are never
//! filtered. The compensation's continuation is filtered with the VPL light: both estimate
//! the indirect light at x (their sum the unclamped one), and the continuation, one BSDF
//! path per pixel, is the noisier part. `sample` then hands back the filtered pixel.
//! The filter averages neighbours' indirect light: the image is biased (a blur of the
//! indirect light over the block where the geometry agrees), which [`VplOptions::bias`]
//! says. The pass's samples are held in memory (a [`PixelSample`] per pixel).
//!
//! Every pass draws new VPLs from the seed and the sample index, so the image converges as
//! passes accumulate, and the light subpaths are traced in fixed chunks: the same image for
//! any thread count (the shadow maps are a function of the geometry alone).
//!
//! # Time budgets
//!
//! A pass is one sample per pixel of `count` light subpaths and may cost a good part of a
//! one-second budget. Under a time budget the render loop sizes the passes
//! ([`crate::render::next_pass_size`]): the first has `count` subpaths per VPL set, the
//! later ones `size` x `count`, planned from the measured cost so that the passes fill the
//! budget. Each pass stays an unbiased sample of its own (its VPLs' throughput divided by
//! its own subpaths), and the render loop weights each by its size (about the inverse of its
//! variance; weights that depend on the clock only keep the mean). A time-budgeted image is
//! then a function of the seed and the sizes the clock chose; sample-budget renders keep
//! size 1.

use std::sync::Arc;

use super::bdpt::{shading_correction, Bdpt};
use super::node_skeleton::{Fingerprint, NodeSkeleton};
use super::skeleton_shadow::{CubeShadowMap, Site, SkeletonShadowMaps, MIN_SHADOW_RESOLUTION};
use super::{Integrator, IntegratorSettings, Iteration, SampleContext, SpecOption, TraceCounters};
use super::{Precomputation, Registration, View};
use crate::error::{Error, Result};
use crate::film::PixelSample;
use crate::geometry::Ray;
use crate::guide::{estimator, RenderEstimator};
use crate::math::{Frame, Rgb, Sampler, Vec3, FIRST_INTEGRATOR_DIMENSION};
use crate::scene::{Bsdf, Camera, Scene, SurfaceInteraction, Transport};

/// Default texels per face edge of a skeleton shadow map (the thesis used 128; 64 costs a
/// quarter of the rays to build, which a one-second preview needs).
pub const DEFAULT_SHADOW_RESOLUTION: u32 = 64;
/// Largest `shadow_res`: one map of 2048^2 per face is 96 MiB.
pub const MAX_SHADOW_RESOLUTION: u32 = 2048;
/// Default `verify`: at 128x96 in 1 s, 0.25 had the lowest RMSE on the door and the ajar
/// door among 0.1, 0.25, 0.5 and 1 (0.1 the lowest MAE on the door, but rare 10x weights in
/// the ajar door's image; BENCHMARKS.md, `vpl` section).
pub const DEFAULT_VERIFY: f32 = 0.25;
/// Default memory for the shadow maps (MiB): 680 maps of 64^2 per face.
pub const DEFAULT_SHADOW_BUDGET_MB: u32 = 64;
/// Default `candidates` of `select=importance`: candidate light subpaths per kept one.
pub const DEFAULT_CANDIDATES: u32 = 8;
/// Default `p_min` of `select=importance`: the least acceptance probability of a candidate.
pub const DEFAULT_P_MIN: f32 = 0.02;
/// Largest `candidates`.
pub const MAX_CANDIDATES: u32 = 256;
/// Default `probes` of `select=importance`: camera probe points (a 9 x 8 grid at 4:3).
pub const DEFAULT_PROBES: u32 = 64;
/// Largest `probes`.
pub const MAX_PROBES: u32 = 4096;
/// Default `interleave` (pixel blocks of N x N, module docs "Interleaved sampling").
pub const DEFAULT_INTERLEAVE: u32 = 1;
/// Largest `interleave`: 64 VPL sets per pass.
pub const MAX_INTERLEAVE: u32 = 8;
/// Default `light_samples`: next-event samples per non-delta camera-path vertex.
pub const DEFAULT_LIGHT_SAMPLES: u32 = 1;
/// Largest `light_samples`.
pub const MAX_LIGHT_SAMPLES: u32 = 64;
/// Default `sites`: 0, the thesis's node maps.
pub const DEFAULT_SITES: u32 = 0;
/// Largest `sites` (voxels per site's edge).
pub const MAX_SITES: u32 = 64;

/// How a pass picks its VPLs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VplSelect {
    /// Every vertex of `count` light subpaths.
    Uniform,
    /// The vertices of `candidates` x `count` light subpaths thinned by Russian roulette on
    /// their estimated light at the camera's probe points (module docs, "Importance-driven
    /// selection").
    Importance,
}

impl VplSelect {
    pub fn parse(value: &str) -> Result<Self> {
        match value {
            "uniform" => Ok(VplSelect::Uniform),
            "importance" => Ok(VplSelect::Importance),
            _ => Err(Error::invalid(format!(
                "vpl: select={value} is not one of: uniform, importance"
            ))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            VplSelect::Uniform => "uniform",
            VplSelect::Importance => "importance",
        }
    }
}

/// Which shadow test the VPL term uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VplVisibility {
    /// A shadow ray per VPL and shading point: the reference.
    Exact,
    /// The filtered visibility of the VPL's skeleton node read from its cube shadow map
    /// (000 chapter 8, eq. 159-161; module docs): no shadow ray, biased.
    Skeleton,
}

impl VplVisibility {
    pub fn parse(value: &str) -> Result<Self> {
        match value {
            "exact" => Ok(VplVisibility::Exact),
            "skeleton" => Ok(VplVisibility::Skeleton),
            "clusters" => Err(Error::invalid(
                "vpl: visibility=clusters is not implemented: measured not to pay, on the door 99.8 % of the VPL / point pairs and 86-90 % of the light cross clusters, where only the gates' occlusion-blind cones would stand in (docs/vpl-visibility.md); use exact or skeleton",
            )),
            _ => Err(Error::invalid(format!(
                "vpl: visibility={value} is not one of: exact, skeleton"
            ))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            VplVisibility::Exact => "exact",
            VplVisibility::Skeleton => "skeleton",
        }
    }
}

/// `vpl`'s own options (`vpl:count=N:clamp=R:compensate=true|false:visibility=exact|skeleton`,
/// with skeleton visibility `shadow_res=N:shadow_budget_mb=M:verify=P:sites=K`; the skeleton's `resolution` and
/// `voxel_budget` are the skeleton guide's options; `select=uniform|importance` with
/// `candidates=K:p_min=P:probes=N:probe_maps=true|false`; `interleave=N`; `light_samples=N`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VplOptions {
    /// Light subpaths per pass; each leaves a VPL at every non-delta surface it reaches.
    pub count: u32,
    /// Clamping distance as a fraction of the scene's bounding diagonal: the geometry term is
    /// capped at `1 / (clamp D)^2`. 0 turns clamping off.
    pub clamp: f32,
    /// Adds back what clamping removed with a path-traced continuation (module docs): unbiased.
    pub compensate: bool,
    pub visibility: VplVisibility,
    /// `visibility=skeleton`: texels per face edge of each node's cube shadow map, at most.
    pub shadow_res: u32,
    /// `visibility=skeleton`: memory for the shadow maps, in MiB; lowers the resolution, then
    /// the number of maps ([`SkeletonShadowMaps`]).
    pub shadow_budget_mb: u32,
    /// `visibility=skeleton`: the probability of tracing the shadow ray of a pair the maps
    /// are unsure of (module docs; Russian roulette, so no bias against tracing them all);
    /// 0 keeps the thesis's maps alone (eq. 159), faster and far more biased.
    pub verify: f32,
    /// How a pass picks its VPLs (module docs).
    pub select: VplSelect,
    /// `select=importance`: candidate light subpaths traced per pass, as a multiple of `count`.
    pub candidates: u32,
    /// `select=importance`: the least acceptance probability, so that every VPL stays
    /// reachable (its weight at most 1 / `p_min`).
    pub p_min: f32,
    /// `select=importance`: about how many camera probe points estimate a candidate's light
    /// (a grid of pixel centres with the image's aspect).
    pub probes: u32,
    /// `select=importance` with `visibility=skeleton` and `verify` > 0: a probe's shadow ray
    /// to a candidate is replaced by its node's receiver map read at the candidate where that
    /// map is sure (reads 0 or 1); a ray where it is unsure or the probe's node has none. The
    /// importance only sets acceptance probabilities, so the estimator stays unbiased against
    /// the plain one; a wrong reading raises the variance instead (module docs).
    pub probe_maps: bool,
    /// Interleaved sampling (module docs): each pass traces `interleave`² VPL sets, pixel
    /// (x, y) gathers set (x mod N, y mod N), and the VPL light is then filtered over N x N
    /// pixel blocks by a geometry-aware filter. 1: one set, no filter.
    pub interleave: u32,
    /// Next-event samples per non-delta vertex of the camera path, averaged (the direct
    /// light, which the VPLs do not carry; unbiased for any count).
    pub light_samples: u32,
    /// `visibility=skeleton`: 0 reads each VPL's visibility from its node's map (the
    /// thesis); K > 0 from the map of its *site* (module docs, "Map sites"), a cell of K^3
    /// skeleton voxels on the VPL's side of the surface, where the site sees the VPL.
    pub sites: u32,
}

impl Default for VplOptions {
    fn default() -> Self {
        VplOptions {
            count: 64,
            clamp: 0.1,
            compensate: false,
            visibility: VplVisibility::Exact,
            shadow_res: DEFAULT_SHADOW_RESOLUTION,
            shadow_budget_mb: DEFAULT_SHADOW_BUDGET_MB,
            verify: DEFAULT_VERIFY,
            select: VplSelect::Importance,
            candidates: DEFAULT_CANDIDATES,
            p_min: DEFAULT_P_MIN,
            probes: DEFAULT_PROBES,
            probe_maps: false,
            interleave: DEFAULT_INTERLEAVE,
            light_samples: DEFAULT_LIGHT_SAMPLES,
            sites: DEFAULT_SITES,
        }
    }
}

impl VplOptions {
    /// Sets the option `key` from `value`: `Ok(false)` when `vpl` has no such option.
    pub fn set(&mut self, key: &str, value: &str) -> Result<bool> {
        match key {
            "count" => {
                let n = value.parse::<u32>().map_err(|_| {
                    Error::invalid(format!(
                        "vpl: count={value} must be a positive integer (light subpaths per pass)"
                    ))
                })?;
                self.count = n;
            }
            "clamp" => {
                let r = value.parse::<f32>().map_err(|_| {
                    Error::invalid(format!(
                        "vpl: clamp={value} must be a number (a fraction of the scene's diagonal, 0 = off)"
                    ))
                })?;
                self.clamp = r;
            }
            "compensate" => {
                self.compensate = match value {
                    "true" | "1" | "on" => true,
                    "false" | "0" | "off" => false,
                    _ => {
                        return Err(Error::invalid(format!(
                            "vpl: compensate={value} must be true or false"
                        )))
                    }
                }
            }
            "verify" => {
                self.verify = value.parse::<f32>().map_err(|_| {
                    Error::invalid(format!(
                        "vpl: verify={value} must be a probability in [0, 1] (0 = the maps alone)"
                    ))
                })?;
            }
            "visibility" => self.visibility = VplVisibility::parse(value)?,
            "select" => self.select = VplSelect::parse(value)?,
            "candidates" => {
                self.candidates = value.parse::<u32>().map_err(|_| {
                    Error::invalid(format!(
                        "vpl: candidates={value} must be a positive integer (candidate light subpaths per kept one)"
                    ))
                })?;
            }
            "probes" => {
                self.probes = value.parse::<u32>().map_err(|_| {
                    Error::invalid(format!(
                        "vpl: probes={value} must be a positive integer (camera probe points)"
                    ))
                })?;
            }
            "probe_maps" => {
                self.probe_maps = value.parse::<bool>().map_err(|_| {
                    Error::invalid(format!(
                        "vpl: probe_maps={value} must be true or false (probes' visibility from the receiver maps)"
                    ))
                })?;
            }
            "p_min" => {
                self.p_min = value.parse::<f32>().map_err(|_| {
                    Error::invalid(format!(
                        "vpl: p_min={value} must be a probability in (0, 1] (the least acceptance probability)"
                    ))
                })?;
            }
            "shadow_res" => {
                self.shadow_res = value.parse::<u32>().map_err(|_| {
                    Error::invalid(format!(
                        "vpl: shadow_res={value} must be an integer (texels per cube face edge)"
                    ))
                })?;
            }
            "interleave" => {
                self.interleave = value.parse::<u32>().map_err(|_| {
                    Error::invalid(format!(
                        "vpl: interleave={value} must be an integer in 1..={MAX_INTERLEAVE} (N x N pixel blocks)"
                    ))
                })?;
            }
            "light_samples" => {
                self.light_samples = value.parse::<u32>().map_err(|_| {
                    Error::invalid(format!(
                        "vpl: light_samples={value} must be an integer in 1..={MAX_LIGHT_SAMPLES} (next-event samples per vertex)"
                    ))
                })?;
            }
            "sites" => {
                self.sites = value.parse::<u32>().map_err(|_| {
                    Error::invalid(format!(
                        "vpl: sites={value} must be an integer in 0..={MAX_SITES} (skeleton voxels per map site's edge, 0 = node maps)"
                    ))
                })?;
            }
            "shadow_budget_mb" => {
                self.shadow_budget_mb = value.parse::<u32>().map_err(|_| {
                    Error::invalid(format!(
                        "vpl: shadow_budget_mb={value} must be an integer (MiB for the shadow maps)"
                    ))
                })?;
            }
            _ => return Ok(false),
        }
        self.validate()?;
        Ok(true)
    }

    pub fn validate(&self) -> Result<()> {
        if self.count == 0 {
            return Err(Error::invalid(
                "vpl: count must be at least 1 light subpath per pass",
            ));
        }
        crate::limits::check_light_paths(
            "vpl: count (light subpaths per pass)",
            self.count as u64,
        )?;
        if !(self.clamp >= 0.0 && self.clamp.is_finite()) {
            return Err(Error::invalid(format!(
                "vpl: clamp={} must be a finite number >= 0 (0 = off)",
                self.clamp
            )));
        }
        if !(MIN_SHADOW_RESOLUTION..=MAX_SHADOW_RESOLUTION).contains(&self.shadow_res) {
            return Err(Error::invalid(format!(
                "vpl: shadow_res={} must be within {MIN_SHADOW_RESOLUTION}..={MAX_SHADOW_RESOLUTION} texels per cube face edge",
                self.shadow_res
            )));
        }
        if !(0.0..=1.0).contains(&self.verify) {
            return Err(Error::invalid(format!(
                "vpl: verify={} must be a probability in [0, 1] (0 = the maps alone)",
                self.verify
            )));
        }
        if !(1..=MAX_CANDIDATES).contains(&self.candidates) {
            return Err(Error::invalid(format!(
                "vpl: candidates={} must be within 1..={MAX_CANDIDATES}",
                self.candidates
            )));
        }
        crate::limits::check_light_paths(
            "vpl: count x candidates (candidate light subpaths per pass)",
            self.count as u64 * self.candidates as u64,
        )?;
        if !(1..=MAX_PROBES).contains(&self.probes) {
            return Err(Error::invalid(format!(
                "vpl: probes={} must be within 1..={MAX_PROBES}",
                self.probes
            )));
        }
        if !(self.p_min > 0.0 && self.p_min <= 1.0) {
            return Err(Error::invalid(format!(
                "vpl: p_min={} must be a probability in (0, 1] (the least acceptance probability)",
                self.p_min
            )));
        }
        if !(1..=MAX_INTERLEAVE).contains(&self.interleave) {
            return Err(Error::invalid(format!(
                "vpl: interleave={} must be within 1..={MAX_INTERLEAVE} (N x N pixel blocks)",
                self.interleave
            )));
        }
        if !(1..=MAX_LIGHT_SAMPLES).contains(&self.light_samples) {
            return Err(Error::invalid(format!(
                "vpl: light_samples={} must be within 1..={MAX_LIGHT_SAMPLES} (next-event samples per vertex)",
                self.light_samples
            )));
        }
        if self.sites > MAX_SITES {
            return Err(Error::invalid(format!(
                "vpl: sites={} must be within 0..={MAX_SITES} (skeleton voxels per map site's edge, 0 = node maps)",
                self.sites
            )));
        }
        crate::limits::check_memory_budget(
            "vpl: shadow_budget_mb",
            (self.shadow_budget_mb as u64) << 20,
        )?;
        Ok(())
    }

    /// Why an image rendered with these options is biased, or None when it is not (for the
    /// render summary and the EXR metadata).
    pub fn bias(&self) -> Option<String> {
        let estimator = self.estimator_bias();
        if self.interleave <= 1 {
            return estimator;
        }
        let n = self.interleave;
        let blur = format!(
            "biased: interleaved sampling (interleave={n}) averages the VPL light over {n}x{n} pixel blocks of similar normal, depth and material (a blur of the indirect light; direct light and emission unfiltered)"
        );
        Some(match estimator {
            Some(other) => format!("{blur}; also {other}"),
            None => blur,
        })
    }

    /// [`Self::bias`] of the per-pixel estimator, without interleaved sampling's filter.
    fn estimator_bias(&self) -> Option<String> {
        if self.visibility == VplVisibility::Skeleton {
            return Some(format!(
                "biased: skeleton visibility (each VPL's shadow ray replaced by the filtered visibility of {} cube shadow map, 000 eq. 159{}){}",
                if self.sites > 0 {
                    format!("its map site's (sites={})", self.sites)
                } else {
                    "its skeleton node's".to_string()
                },
                if self.verify > 0.0 {
                    ", shadow rays where the maps disagree or are unsure"
                } else {
                    ""
                },
                if self.compensate || self.clamp == 0.0 {
                    String::new()
                } else {
                    format!("; VPL geometry term clamped at distance {} of the scene diagonal", self.clamp)
                }
            ));
        }
        if self.compensate {
            return None;
        }
        Some(if self.clamp > 0.0 {
            format!(
                "biased: VPL geometry term clamped at distance {} of the scene diagonal without compensation (darker near corners; light through delta surfaces onto non-delta ones missing); compensate=true makes it unbiased",
                self.clamp
            )
        } else {
            "biased on scenes with delta surfaces: light through them onto non-delta surfaces is missing without compensation (compensate=true makes it unbiased)".to_string()
        })
    }
}

/// Sampler slots of one vertex: the light sample's 2-D, then three for the BSDF direction
/// (component choice, 2-D).
const SLOTS_PER_VERTEX: u32 = 4;
const LIGHT_SLOT: u32 = 0;
const DIRECTION_SLOT: u32 = 1;

fn slot(depth: u32, k: u32) -> u32 {
    FIRST_INTEGRATOR_DIMENSION + depth * SLOTS_PER_VERTEX + k
}

/// Sampler slot of the `j`-th (j >= 1) light sample of `light_samples` at `depth`: past
/// every slot a path of `max_depth` uses, so that `light_samples=1` keeps its numbers.
fn extra_light_slot(max_depth: u32, depth: u32, j: u32) -> u32 {
    slot(max_depth + 1, 0) + depth * MAX_LIGHT_SAMPLES + j
}

/// One virtual point light: a stored light-subpath vertex with its BSDF resolved.
struct Vpl {
    si: SurfaceInteraction,
    bsdf: Bsdf,
    frame: Frame,
    /// `si.wo` (towards the light subpath's previous vertex) in `frame`.
    wo_local: Vec3,
    throughput: Rgb,
    /// [`facing_normal`] of `si`.
    facing: Vec3,
    /// Segments from the light to this vertex.
    path_len: u32,
}

/// VPLs `start..end` of a pass, all of skeleton node `node` (or [`EXACT_GROUP`]), and the
/// shadow map that stands for their visibility: their node's, or with `sites=K` their site's
/// (None: exact shadow rays).
struct VplGroup {
    node: u32,
    map: Option<Arc<CubeShadowMap>>,
    /// A site's group (`sites=K`): a VPL or a few, so a shading point finds one it faces
    /// before reading the map.
    site: bool,
    start: usize,
    end: usize,
}

/// Pixel centres (columns, rows) scanned at most for the receiver maps
/// ([`VplIntegrator::ensure_receiver_maps`]).
const RECEIVER_SCAN: [u32; 2] = [64, 48];

/// The group of the VPLs tested with exact shadow rays.
const EXACT_GROUP: u32 = u32::MAX;

/// The VPLs of one pass, grouped by skeleton node (one group with exact visibility), sorted
/// by subpath length within a group so that a vertex that may use only the shorter ones
/// stops early.
struct VplSet {
    vpls: Vec<Vpl>,
    groups: Vec<VplGroup>,
    /// The cap on the geometry term (infinite without clamping).
    bound: f32,
    /// With `verify`: the nodes with a receiver map for this render's view, sorted
    /// ([`VplIntegrator::ensure_receiver_maps`]); a shading point of another node has no
    /// receiver side, whatever maps earlier passes or renders built.
    receivers: Arc<Vec<u32>>,
}

impl VplSet {
    /// The receiver map of shading point `si`'s node (the two-sided test's receiver side),
    /// None where this render's view gave its node none.
    #[inline]
    fn receiver<'a>(
        &self,
        shadow: &'a SkeletonShadowMaps,
        si: &SurfaceInteraction,
    ) -> Option<&'a super::CubeShadowMap> {
        let node = shadow.node_of(si)?;
        self.receivers
            .binary_search(&node)
            .ok()
            .and_then(|_| shadow.receiver_map(node))
    }
}

/// A pass of interleaved sampling ([`VplIntegrator::interleaved_pass`]): its N² VPL sets
/// and every pixel's filtered sample, row-major, for `width` x `height`.
struct InterleavedPass {
    width: u32,
    height: u32,
    pixels: Vec<PixelSample>,
    sets: Vec<VplSet>,
}

/// A camera path's radiance split at its first non-delta vertex x: `direct` (emission and
/// environment before x, x's own next-event estimation), `indirect` (x's VPL light and,
/// with compensation, everything the continuation from x adds), and x's description for
/// the geometry-aware filter (None when the path has no non-delta vertex).
#[derive(Clone, Copy, Default)]
struct Split {
    direct: Rgb,
    indirect: Rgb,
    first: Option<FirstVertex>,
}

impl Split {
    /// Adds a term of the path's radiance: to `indirect` once past x.
    #[inline]
    fn add(&mut self, value: Rgb) {
        if self.first.is_some() {
            self.indirect += value;
        } else {
            self.direct += value;
        }
    }
}

/// The first non-delta vertex of a camera path, as the discontinuity buffer sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct FirstVertex {
    p: Vec3,
    /// The shading normal turned towards the camera path.
    normal: Vec3,
    /// The camera path's length to x (through its delta vertices).
    distance: f32,
    material: u32,
    /// Delta vertices before x.
    delta_vertices: u32,
    /// What the indirect light is demodulated by: the throughput of the delta vertices
    /// before x times x's diffuse albedo ([`Bsdf::albedo_hint`]).
    modulation: Rgb,
}

/// Least cosine between the normals of two pixels the filter averages (about 25 degrees).
const FILTER_NORMAL_COS: f32 = 0.9;
/// Largest difference of the camera path's length to two pixels the filter averages, and
/// largest distance of each one's point from the other's tangent plane, as fractions of
/// the path's length (a step of depth or a parallel surface behind).
const FILTER_DEPTH_TOLERANCE: f32 = 0.1;
const FILTER_PLANE_TOLERANCE: f32 = 0.02;
/// Modulation below this (a black albedo channel) is not divided by.
const FILTER_MIN_MODULATION: f32 = 1e-4;

/// Whether the filter may average pixel `b`'s demodulated indirect light into pixel `a`'s:
/// the same material behind as many delta vertices, a similar normal, a similar depth and
/// each point near the other's tangent plane.
fn similar(a: &FirstVertex, b: &FirstVertex) -> bool {
    let depth = a.distance.max(b.distance);
    a.material == b.material
        && a.delta_vertices == b.delta_vertices
        && a.normal.dot(b.normal) >= FILTER_NORMAL_COS
        && (a.distance - b.distance).abs() <= FILTER_DEPTH_TOLERANCE * depth
        && (b.p - a.p).dot(a.normal).abs() <= FILTER_PLANE_TOLERANCE * a.distance
        && (a.p - b.p).dot(b.normal).abs() <= FILTER_PLANE_TOLERANCE * b.distance
}

/// Interleaved sampling's geometry-aware filter (a discontinuity buffer; module docs): each
/// pixel's indirect light is its modulation times the mean of the demodulated indirect
/// light (indirect / modulation, per channel) of the pixels of the N x N window around it
/// that are [`similar`] (itself always), the window shifted inside the image at its edges
/// so that it holds each of the N² VPL sets once. A channel whose modulation is below
/// [`FILTER_MIN_MODULATION`] is neither divided (the pixel keeps its own value) nor
/// averaged in. `pixels` is row-major, `width` x `height`; the result is too.
fn filter_indirect(width: u32, height: u32, n: u32, pixels: &[Split]) -> Vec<Rgb> {
    use rayon::prelude::*;
    // The window's first column (row) for a pixel at x (y) of a side of `len` pixels.
    let start = |x: u32, len: u32| x.saturating_sub(n / 2).min(len.saturating_sub(n));
    (0..width * height)
        .into_par_iter()
        .map(|i| {
            let own = &pixels[i as usize];
            let Some(a) = own.first else {
                return own.indirect;
            };
            let (x, y) = (i % width, i / width);
            let (x0, y0) = (start(x, width), start(y, height));
            let (mut sum, mut count) = ([0.0f32; 3], [0u32; 3]);
            for wy in y0..(y0 + n).min(height) {
                for wx in x0..(x0 + n).min(width) {
                    let other = &pixels[(wy * width + wx) as usize];
                    let Some(b) = other.first.filter(|b| similar(&a, b)) else {
                        continue;
                    };
                    for c in 0..3 {
                        if b.modulation[c] > FILTER_MIN_MODULATION {
                            sum[c] += other.indirect[c] / b.modulation[c];
                            count[c] += 1;
                        }
                    }
                }
            }
            let mut out = own.indirect;
            for c in 0..3 {
                if a.modulation[c] > FILTER_MIN_MODULATION && count[c] > 0 {
                    out[c] = a.modulation[c] * sum[c] / count[c] as f32;
                }
            }
            out
        })
        .collect()
}

/// VPL v's light at x without visibility, `T f_y f_x min(G, bound)` (module docs), None when
/// it is zero or the two do not face each other.
#[inline]
fn unshadowed(
    bound: f32,
    si: &SurfaceInteraction,
    bsdf: &Bsdf,
    frame: &Frame,
    wo_local: Vec3,
    v: &Vpl,
) -> Option<Rgb> {
    let d = v.si.p - si.p;
    let dist2 = d.length_squared();
    if !(dist2 > 0.0) {
        return None;
    }
    let dir = d / dist2.sqrt();
    let wi_x = frame.to_local(dir);
    let f_x = bsdf.eval(wo_local, wi_x, Transport::Radiance);
    let wi_y = v.frame.to_local(-dir);
    // Both ends must scatter to the side the connection leaves by.
    if !si.scatters_toward(dir, wo_local, wi_x) || !v.si.scatters_toward(-dir, v.wo_local, wi_y) {
        return None;
    }
    let f_y = v.bsdf.eval(v.wo_local, wi_y, Transport::Importance)
        * shading_correction(&v.si, v.si.wo, -dir);
    let cosines = wi_x.z.abs() * wi_y.z.abs();
    if f_x == Rgb::ZERO || f_y == Rgb::ZERO || cosines == 0.0 {
        return None;
    }
    // min(G, b) without dividing by a tiny distance when the cap applies.
    let g = if cosines >= bound * dist2 {
        bound
    } else {
        cosines / dist2
    };
    let value = v.throughput * f_x * f_y * g;
    (crate::math::is_finite3(value) && value != Rgb::ZERO).then_some(value)
}

/// The side of `si`'s surface it scatters to: its geometric normal turned towards `si.wo`.
#[inline]
fn facing_normal(si: &SurfaceInteraction) -> Vec3 {
    if si.wo.dot(si.ng) >= 0.0 {
        si.ng
    } else {
        -si.ng
    }
}

/// The filtered visibility `V_f` of `map`'s node at `si` (eq. 159), or None where, with
/// `verify`, the node cannot stand in for its VPLs there and shadow rays decide: the node
/// behind `si`'s surface, or the PCF kernel straddling a shadow edge (0 < V_f < 1).
#[inline]
fn node_verdict(
    scene: &Scene,
    map: &super::CubeShadowMap,
    si: &SurfaceInteraction,
    verify: bool,
) -> Option<f32> {
    let facing = facing_normal(si);
    if verify && (map.centre() - si.p).dot(facing) <= 0.0 {
        return None;
    }
    let v = map.visibility(scene, si.p, facing);
    (!verify || v == 0.0 || v == 1.0).then_some(v)
}

/// A uniform number in [0, 1) for the pair of shading point `si` and VPL `v`: a hash of
/// their positions, so the same for any thread count.
#[inline]
fn pair_uniform(si: &SurfaceInteraction, v: &Vpl) -> f32 {
    let bits = |p: Vec3| {
        crate::math::mix64(u64::from(p.x.to_bits()) | u64::from(p.y.to_bits()) << 32)
            ^ u64::from(p.z.to_bits())
    };
    let h = crate::math::mix64(bits(si.p) ^ crate::math::mix64(bits(v.si.p)));
    (h >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
}

/// Whether the receiver map `r` sees the centre of node map `map` (a group the node's map
/// skips may still hold VPLs the receiver sees only then, in the two-sided test).
#[inline]
fn sees_node(scene: &Scene, r: &super::CubeShadowMap, map: Option<&super::CubeShadowMap>) -> bool {
    map.is_some_and(|m| {
        let towards = r.centre() - m.centre();
        towards.length_squared() > 0.0 && r.visibility(scene, m.centre(), towards.normalize()) > 0.5
    })
}

/// The visibility skeleton visibility gives VPL `v` at a shading point (module docs), None
/// for a shadow ray: `node` is its group's [`node_verdict`] there (None: a shadow ray), and
/// `receiver` the map of the shading point's own node, read at the VPL; where the two maps
/// disagree, a shadow ray decides.
#[inline]
fn pair_verdict(
    scene: &Scene,
    node: Option<f32>,
    receiver: Option<&super::CubeShadowMap>,
    v: &Vpl,
) -> Option<f32> {
    let g = node?;
    match receiver {
        Some(m) if (m.visibility(scene, v.si.p, v.facing) > 0.5) != (g > 0.5) => None,
        _ => Some(g),
    }
}

/// Delta surfaces a probe's camera ray follows, at most, to its first non-delta vertex.
const PROBE_MAX_DELTA: u32 = 4;
/// Random streams of the probes' delta bounces and of the acceptance decisions (apart from
/// the light subpaths' and the pixels').
const PROBE_STREAM: u64 = 0x5AE1_7C0B_E6A3_21F5;
const SELECT_STREAM: u64 = 0x3C9D_0E84_B1F2_6A17;

/// A camera probe point of `select=importance`: the first non-delta vertex of a pixel
/// centre's camera path, with the throughput of the delta surfaces before it.
struct Probe {
    si: SurfaceInteraction,
    bsdf: Bsdf,
    frame: Frame,
    wo_local: Vec3,
    beta: Rgb,
}

/// The probe points of `view`: one per cell of a grid of about `count` pixel centres (with
/// the image's aspect, at most one per pixel) whose camera ray reaches a non-delta surface
/// (through at most [`PROBE_MAX_DELTA`] delta ones, sampled with fixed numbers), and the
/// rays traced. Deterministic.
fn probes(scene: &Scene, view: &View, count: u32) -> (Vec<Probe>, u64) {
    let aspect = view.width.max(1) as f32 / view.height.max(1) as f32;
    let cols = ((count as f32 * aspect).sqrt().round() as u32).clamp(1, view.width.max(1));
    let rows = (count.div_ceil(cols)).clamp(1, view.height.max(1));
    let mut rays = 0u64;
    let mut out = Vec::new();
    for k in 0..cols * rows {
        let film = crate::math::Vec2::new(
            ((k % cols) as f32 + 0.5) / cols as f32,
            ((k / cols) as f32 + 0.5) / rows as f32,
        );
        let mut ray = view.frame.generate_ray(film, crate::math::Vec2::ZERO);
        let mut rng = Sampler::independent(crate::math::Rng::for_sample(PROBE_STREAM, k as u64, 0));
        let mut beta = Rgb::ONE;
        for _ in 0..=PROBE_MAX_DELTA {
            rays += 1;
            let Some(si) = scene.intersect(&ray) else {
                break;
            };
            let bsdf = scene.bsdf(&si);
            let frame = si.shading_frame();
            let wo_local = frame.to_local(si.wo);
            if !bsdf.is_delta() {
                out.push(Probe {
                    si,
                    bsdf,
                    frame,
                    wo_local,
                    beta,
                });
                break;
            }
            let Some(bs) = bsdf.sample_from(wo_local, &mut rng, Transport::Radiance) else {
                break;
            };
            if !(bs.pdf > 0.0) {
                break;
            }
            beta *= bs.f * (bs.wi.z.abs() / bs.pdf);
            if !crate::math::is_finite3(beta) || beta == Rgb::ZERO {
                break;
            }
            ray = si.spawn_ray(frame.to_world(bs.wi));
        }
    }
    (out, rays)
}

/// VPL `v`'s light at the probes (luminance, geometry term capped at `bound`): the
/// importance of `select=importance`, with the shadow rays it traced. Visibility by exact
/// shadow rays, or (`probe_maps`) by the probe's receiver map in `maps` where it reads 0
/// or 1.
fn probe_estimate(
    scene: &Scene,
    probes: &[Probe],
    maps: &[Option<&CubeShadowMap>],
    bound: f32,
    v: &Vpl,
) -> (f32, u64) {
    let mut sum = 0.0f32;
    let mut rays = 0u64;
    for (i, p) in probes.iter().enumerate() {
        let Some(value) = unshadowed(bound, &p.si, &p.bsdf, &p.frame, p.wo_local, v) else {
            continue;
        };
        let light = crate::math::luminance(p.beta * value);
        if !(light > 0.0) {
            continue;
        }
        let sure = maps.get(i).copied().flatten().and_then(|m| {
            let f = m.visibility(scene, v.si.p, v.facing);
            (f == 0.0 || f == 1.0).then_some(f == 1.0)
        });
        let visible = sure.unwrap_or_else(|| {
            rays += 1;
            !scene.occluded(&p.si.spawn_ray_to(v.si.p, v.si.p_error, v.si.ng))
        });
        if visible {
            sum += light;
        }
    }
    (if sum.is_finite() { sum } else { 0.0 }, rays)
}

/// The acceptance probabilities `p_i = clamp(e_i / t, p_min, 1)` of candidates with
/// importance `estimates` (>= 0), t chosen so that `sum p_i` is `expected` (Georgiev &
/// Slusallek 2010, with the target from the pass's candidates rather than the previous
/// pass's: the probabilities are a function of the candidates, never of an acceptance
/// draw, so accepting with `p_i` and weighting by `1 / p_i` is unbiased). Where even
/// `t -> 0` keeps fewer than `expected` (few candidates with a non-zero estimate), those
/// are all kept and the others share the rest evenly (at least `p_min`); with no non-zero
/// estimate at all, every candidate gets `expected / n`, at least `p_min`.
pub(crate) fn acceptance_probabilities(estimates: &[f32], expected: f32, p_min: f32) -> Vec<f32> {
    let n = estimates.len();
    let expected = f64::from(expected);
    let p_min64 = f64::from(p_min);
    let positive: Vec<f64> = estimates
        .iter()
        .map(|&e| f64::from(e))
        .filter(|&e| e > 0.0)
        .collect();
    let zeros = (n - positive.len()) as f64;
    if expected >= n as f64 {
        return vec![1.0; n];
    }
    let even = |p: f64| p.clamp(p_min64, 1.0) as f32;
    if positive.is_empty() {
        return vec![even(expected / n as f64); n];
    }
    let all_kept = positive.len() as f64;
    if all_kept + p_min64 * zeros >= expected {
        // sum_i clamp(e_i / t, p_min, 1) falls from all_kept + p_min zeros (t at the least
        // positive estimate) to n p_min (t at the largest over p_min): bisection on log t.
        let kept = |t: f64| {
            positive
                .iter()
                .map(|&e| (e / t).clamp(p_min64, 1.0))
                .sum::<f64>()
                + p_min64 * zeros
        };
        let lo_e = positive.iter().copied().fold(f64::INFINITY, f64::min);
        let hi_e = positive.iter().copied().fold(0.0, f64::max);
        let (mut lo, mut hi) = (lo_e.ln(), (hi_e / p_min64).ln());
        for _ in 0..64 {
            let mid = 0.5 * (lo + hi);
            if kept(mid.exp()) > expected {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let t = (0.5 * (lo + hi)).exp();
        estimates
            .iter()
            .map(|&e| (f64::from(e) / t).clamp(p_min64, 1.0) as f32)
            .collect()
    } else {
        let rest = even((expected - all_kept) / zeros.max(1.0));
        estimates
            .iter()
            .map(|&e| if e > 0.0 { 1.0 } else { rest })
            .collect()
    }
}

/// Whether candidate `index` of pass `sample_index` is accepted with probability `p`: a
/// uniform number from the seed, the pass and the index, so the same for any thread count.
fn accepted(seed: u64, sample_index: u32, index: usize, p: f32) -> bool {
    p >= 1.0
        || crate::math::Rng::for_sample(seed ^ SELECT_STREAM, index as u64, sample_index as u64)
            .uniform()
            < p
}

/// Light subpaths per VPL set of a pass of `size` (1: `count`; at least 1, and within the
/// limit on light subpaths with the `candidates`).
fn sized_subpaths(count: u32, candidates: u32, size: f32) -> u32 {
    let most = crate::limits::MAX_LIGHT_PATHS / candidates.max(1);
    ((count as f32 * size).round() as u32).clamp(1, most.max(1))
}

/// The pass sizes of time-budgeted renders other than 1, for the render notes.
#[derive(Default)]
struct PassSizeStats(std::sync::Mutex<(u32, f32, f32)>);

impl PassSizeStats {
    fn record(&self, size: f32) {
        if size != 1.0 {
            let mut s = self.0.lock().unwrap_or_else(|e| e.into_inner());
            *s = if s.0 == 0 {
                (1, size, size)
            } else {
                (s.0 + 1, s.1.min(size), s.2.max(size))
            };
        }
    }

    fn note(&self, count: u32) -> Option<String> {
        let (passes, least, most) = *self.0.lock().unwrap_or_else(|e| e.into_inner());
        (passes > 0).then(|| {
            format!(
                "vpl passes sized to the time budget: {passes} of {least:.2}-{most:.2} x count={count} light subpaths"
            )
        })
    }
}

pub struct VplIntegrator {
    settings: IntegratorSettings,
    options: VplOptions,
    light: Bdpt,
    /// `visibility=skeleton`: the shadow maps (None: exact rays, for want of a skeleton).
    shadow: Option<Arc<SkeletonShadowMaps>>,
    /// The scene `prepare` ran for (skeleton visibility needs it).
    prepared_for: Option<Fingerprint>,
    selection_stats: SelectionStats,
    pass_sizes: PassSizeStats,
    /// `select=importance`: the probe points of the last scene and view rendered, built once
    /// per render rather than every pass.
    probes: std::sync::Mutex<Option<ProbeCache>>,
}

/// The probe points of one scene and view ([`VplIntegrator::cached_probes`]).
struct ProbeCache {
    scene: Fingerprint,
    view: [u32; 16],
    probes: Arc<Vec<Probe>>,
}

/// The bits of everything of `view` that moves a probe point.
fn view_key(view: &View) -> [u32; 16] {
    let f = &view.frame;
    let v = |a: Vec3| [a.x, a.y, a.z].map(f32::to_bits);
    let [e, d, r, u] = [v(f.eye), v(f.forward), v(f.right), v(f.up)];
    [
        e[0],
        e[1],
        e[2],
        d[0],
        d[1],
        d[2],
        r[0],
        r[1],
        r[2],
        u[0],
        u[1],
        u[2],
        f.lens_radius.to_bits(),
        f.focus_distance.to_bits(),
        view.width,
        view.height,
    ]
}

/// What `select=importance` kept over a render, for its note.
#[derive(Default)]
struct SelectionStats {
    passes: std::sync::atomic::AtomicU64,
    candidates: std::sync::atomic::AtomicU64,
    kept: std::sync::atomic::AtomicU64,
    /// Candidates no probe receives light from.
    unseen: std::sync::atomic::AtomicU64,
}

impl SelectionStats {
    fn record(&self, candidates: usize, kept: usize, importance: &[f32]) {
        use std::sync::atomic::Ordering::Relaxed;
        self.passes.fetch_add(1, Relaxed);
        self.candidates.fetch_add(candidates as u64, Relaxed);
        self.kept.fetch_add(kept as u64, Relaxed);
        let unseen = importance.iter().filter(|&&e| e == 0.0).count();
        self.unseen.fetch_add(unseen as u64, Relaxed);
    }

    fn note(&self) -> Option<String> {
        use std::sync::atomic::Ordering::Relaxed;
        let passes = self.passes.load(Relaxed);
        (passes > 0).then(|| {
            let per = |x: &std::sync::atomic::AtomicU64| x.load(Relaxed) as f64 / passes as f64;
            format!(
                "vpl importance selection: {:.0} of {:.0} candidate VPLs kept per VPL set ({:.0} lighting no probe), {passes} sets (interleave² per pass)",
                per(&self.kept),
                per(&self.candidates),
                per(&self.unseen)
            )
        })
    }
}

impl VplIntegrator {
    pub fn new(settings: IntegratorSettings) -> Result<Self> {
        settings.vpl.validate()?;
        let light = Bdpt::new(settings)
            .with_light_paths(settings.vpl.count as usize)?
            .without_light_tracing();
        Ok(VplIntegrator {
            settings,
            options: settings.vpl,
            light,
            shadow: None,
            prepared_for: None,
            selection_stats: SelectionStats::default(),
            pass_sizes: PassSizeStats::default(),
            probes: std::sync::Mutex::new(None),
        })
    }

    /// The probe points of `scene` seen through `view` (built on the first pass of a render,
    /// then kept while the scene and view stay), and the rays their building traced now.
    fn cached_probes(&self, scene: &Scene, view: &View) -> (Arc<Vec<Probe>>, u64) {
        let (fingerprint, key) = (Fingerprint::of(scene), view_key(view));
        let mut cache = self.probes.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(c) = cache
            .as_ref()
            .filter(|c| c.scene == fingerprint && c.view == key)
        {
            return (Arc::clone(&c.probes), 0);
        }
        let (built, rays) = probes(scene, view, self.options.probes);
        let built = Arc::new(built);
        *cache = Some(ProbeCache {
            scene: fingerprint,
            view: key,
            probes: Arc::clone(&built),
        });
        (built, rays)
    }

    fn estimator(&self) -> RenderEstimator {
        RenderEstimator {
            mis: self.settings.mis.unwrap_or_default(),
            // `triangles=` is `path`'s option; `vpl` samples emissive triangles by area.
            triangles: crate::light::TriangleSampling::default(),
            env: self.settings.env,
        }
    }

    /// The cap on the geometry term for `scene` (module docs).
    fn bound(&self, scene: &Scene) -> f32 {
        let diagonal = scene.bounds().diagonal().length();
        let r = self.options.clamp * diagonal;
        if r > 0.0 {
            1.0 / (r * r)
        } else {
            f32::INFINITY
        }
    }

    /// Sorts `vpls` into groups (module docs): by skeleton node with skeleton visibility
    /// (building the maps of nodes that carry VPLs for the first time), the VPLs of no node
    /// or no map in one exact group; by subpath length within a group. Stable: the order
    /// stays a function of the seed alone.
    fn group(&self, scene: &Scene, vpls: &mut Vec<Vpl>) -> (Vec<VplGroup>, u64) {
        let Some(shadow) = &self.shadow else {
            vpls.sort_by_key(|v| v.path_len);
            return (
                vec![VplGroup {
                    node: EXACT_GROUP,
                    map: None,
                    site: false,
                    start: 0,
                    end: vpls.len(),
                }],
                0,
            );
        };
        let cell = self.options.sites;
        let mut rays = 0;
        // With sites, each VPL's site whose map stands where the site sees the VPL (one ray
        // each); the others keep their node's map. The sites' maps are made once here
        // (`distinct` sorted) and looked up again for the groups below.
        let wanted: Vec<Option<Site>> = if cell > 0 {
            vpls.iter().map(|v| shadow.site_of(&v.si, cell)).collect()
        } else {
            vec![None; vpls.len()]
        };
        let mut distinct: Vec<Site> = wanted.iter().flatten().copied().collect();
        distinct.sort_unstable();
        distinct.dedup();
        let site_maps = shadow.ensure_sites(&distinct);
        let site_map = |s: Site| {
            let i = distinct.binary_search(&s).ok()?;
            site_maps[i].as_ref()
        };
        let sites: Vec<Option<Site>> = vpls
            .iter()
            .zip(wanted)
            .map(|(v, site)| {
                site.and_then(site_map).and_then(|m| {
                    rays += 1;
                    let to = v.si.spawn_ray_to(m.centre(), Vec3::ZERO, Vec3::ZERO);
                    (!scene.occluded(&to)).then_some(site?)
                })
            })
            .collect();
        let nodes: Vec<u32> = vpls
            .iter()
            .map(|v| shadow.node_of(&v.si).unwrap_or(EXACT_GROUP))
            .collect();
        let mut carrying: Vec<u32> = nodes
            .iter()
            .zip(&sites)
            .filter(|&(&n, site)| n != EXACT_GROUP && site.is_none())
            .map(|(&n, _)| n)
            .collect();
        carrying.sort_unstable();
        carrying.dedup();
        shadow.ensure(&carrying);
        let mut keyed: Vec<(u32, Option<Site>, Vpl)> = nodes
            .into_iter()
            .zip(sites)
            .map(|(n, site)| match site {
                Some(site) => (n, Some(site)),
                None if shadow.map(n).is_some() => (n, None),
                None => (EXACT_GROUP, None),
            })
            .zip(std::mem::take(vpls))
            .map(|((n, site), v)| (n, site, v))
            .collect();
        keyed.sort_by_key(|(node, site, v)| (*node, *site, v.path_len));
        let mut groups: Vec<VplGroup> = Vec::new();
        let mut last: Option<(u32, Option<Site>)> = None;
        for (i, (node, site, v)) in keyed.into_iter().enumerate() {
            match groups.last_mut() {
                Some(g) if last == Some((node, site)) => g.end = i + 1,
                _ => {
                    let map = match site {
                        Some(site) => site_map(site).cloned(),
                        None => shadow.map(node).cloned(),
                    };
                    groups.push(VplGroup {
                        node,
                        map,
                        site: site.is_some(),
                        start: i,
                        end: i + 1,
                    })
                }
            }
            last = Some((node, site));
            vpls.push(v);
        }
        (groups, rays)
    }

    /// With `verify`, builds the maps of the nodes the view's visible surfaces map to (the
    /// receiver side of the two-sided test), found from a grid of at most
    /// [`RECEIVER_SCAN`] pixel centres; after the VPLs' nodes, within the same budget. A
    /// shading point whose node has none uses its VPLs' nodes' maps alone. Returns the
    /// nodes that have a receiver map, sorted: a function of the view and the scene only
    /// (and of the budget), so that every pass of every render of this view reads the same
    /// receiver maps.
    fn ensure_receiver_maps(&self, scene: &Scene, view: &View) -> Vec<u32> {
        let Some(shadow) = self.shadow.as_deref().filter(|_| self.options.verify > 0.0) else {
            return Vec::new();
        };
        let (cols, rows) = (
            view.width.min(RECEIVER_SCAN[0]),
            view.height.min(RECEIVER_SCAN[1]),
        );
        let mut nodes: Vec<u32> = (0..cols * rows)
            .filter_map(|k| {
                let film = crate::math::Vec2::new(
                    ((k % cols) as f32 + 0.5) / cols as f32,
                    ((k / cols) as f32 + 0.5) / rows as f32,
                );
                let ray = view.frame.generate_ray(film, crate::math::Vec2::ZERO);
                shadow.node_of(&scene.intersect(&ray)?)
            })
            .collect();
        nodes.sort_unstable();
        nodes.dedup();
        shadow.ensure_receivers(&nodes);
        nodes.retain(|&n| shadow.receiver_map(n).is_some());
        nodes
    }

    /// `select=importance` (module docs): keeps each candidate of `vpls` with its
    /// [`acceptance_probabilities`] for about one `candidates`-th of them, its throughput
    /// divided by the probability; drops those too long for any path of `max_depth`
    /// segments. Returns the rays traced.
    fn select(
        &self,
        scene: &Scene,
        probes: &[Probe],
        seed: u64,
        sample_index: u32,
        bound: f32,
        vpls: &mut Vec<Vpl>,
    ) -> u64 {
        use rayon::prelude::*;
        // A VPL of j segments is gathered at most by the first vertex, as j + 2 segments.
        let longest = self.settings.max_depth.saturating_sub(1);
        vpls.retain(|v| v.path_len <= longest);
        // `probe_maps`: each probe's receiver map (made before the VPL sets by
        // `begin_sized_iteration`: those of the view's nodes, a function of view and scene).
        let maps: Vec<Option<&CubeShadowMap>> = match self.shadow.as_deref() {
            Some(shadow) if self.options.probe_maps && self.options.verify > 0.0 => probes
                .iter()
                .map(|p| shadow.receiver_map(shadow.node_of(&p.si)?))
                .collect(),
            _ => Vec::new(),
        };
        let estimates: Vec<(f32, u64)> = vpls
            .par_iter()
            .map(|v| probe_estimate(scene, probes, &maps, bound, v))
            .collect();
        let rays = estimates.iter().map(|e| e.1).sum::<u64>();
        let importance: Vec<f32> = estimates.iter().map(|e| e.0).collect();
        let expected = vpls.len() as f32 / self.options.candidates as f32;
        let p = acceptance_probabilities(&importance, expected, self.options.p_min);
        let candidates = vpls.len();
        let mut index = 0usize;
        vpls.retain_mut(|v| {
            let i = index;
            index += 1;
            let keep = accepted(seed, sample_index, i, p[i]);
            if keep {
                v.throughput /= p[i];
            }
            keep
        });
        self.selection_stats
            .record(candidates, vpls.len(), &importance);
        rays
    }

    /// The VPLs of one set (module docs): `subpaths` light subpaths of sample index `index`
    /// (`candidates` x `subpaths` thinned by `select=importance` on `probes`), grouped.
    /// Returns the rays traced.
    fn vpl_set(
        &self,
        scene: &Scene,
        view: &View,
        probes: Option<&[Probe]>,
        seed: u64,
        index: u32,
        subpaths: u32,
    ) -> (VplSet, u64) {
        let count = subpaths as usize
            * if probes.is_some() {
                self.options.candidates as usize
            } else {
                1
            };
        let (paths, out) = self
            .light
            .trace_light_paths(scene, view, seed, index, count);
        let mut vpls: Vec<Vpl> = paths
            .vertices
            .iter()
            .map(|v| {
                let frame = v.si.shading_frame();
                Vpl {
                    si: v.si,
                    bsdf: scene.bsdf(&v.si),
                    frame,
                    wo_local: frame.to_local(v.si.wo),
                    throughput: v.throughput / count as f32,
                    facing: facing_normal(&v.si),
                    path_len: v.path_len,
                }
            })
            .collect();
        let bound = self.bound(scene);
        let mut rays = out.rays();
        if let Some(probes) = probes {
            rays += self.select(scene, probes, seed, index, bound, &mut vpls);
        }
        let (groups, group_rays) = self.group(scene, &mut vpls);
        rays += group_rays;
        (
            VplSet {
                vpls,
                groups,
                bound,
                receivers: Arc::default(),
            },
            rays,
        )
    }

    /// Interleaved sampling's pass (module docs): every pixel's sample of `sample_index`,
    /// traced as the render loop would (its ray and numbers from the render's pixel sampler)
    /// with the VPL set of its place in the N x N block, then its indirect light filtered
    /// ([`filter_indirect`]). In parallel over the pixels, each a function of the seed and
    /// the pixel: the same image for any thread count. Returns the samples, row-major, and
    /// the rays traced.
    fn interleaved_pass(
        &self,
        scene: &Scene,
        view: &View,
        seed: u64,
        sample_index: u32,
        sets: &[VplSet],
    ) -> (Vec<PixelSample>, u64) {
        use rayon::prelude::*;
        let (w, n) = (view.width, self.options.interleave);
        let traced: Vec<(PixelSample, Split, u64)> = (0..view.width * view.height)
            .into_par_iter()
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let sampler = crate::math::PixelSampler::new(view.sampler, seed, u64::from(i));
                let mut rng = sampler.sample(sample_index);
                let ray = view.primary_ray(x, y, &mut rng);
                let set = &sets[((y % n) * n + x % n) as usize];
                let mut counters = TraceCounters::default();
                let (sample, split) = self.trace(scene, set, ray, &mut rng, &mut counters);
                (sample, split, counters.rays)
            })
            .collect();
        let rays = traced.iter().map(|t| t.2).sum();
        let splits: Vec<Split> = traced.iter().map(|t| t.1).collect();
        let indirect = filter_indirect(view.width, view.height, n, &splits);
        let pixels = traced
            .into_iter()
            .zip(indirect)
            .map(|((sample, split, _), indirect)| PixelSample {
                radiance: split.direct + indirect,
                ..sample
            })
            .collect();
        (pixels, rays)
    }

    /// Light from every VPL of at most `max_len` segments at x (shading `frame`, `wo_local`).
    #[allow(clippy::too_many_arguments)]
    fn gather(
        &self,
        scene: &Scene,
        set: &VplSet,
        si: &SurfaceInteraction,
        bsdf: &Bsdf,
        frame: &Frame,
        wo_local: Vec3,
        max_len: u32,
        counters: &mut TraceCounters,
    ) -> Rgb {
        let shadow = self.shadow.as_deref();
        let verify = self.options.verify;
        let checked = verify > 0.0;
        // The receiver side of the two-sided test: the map of the shading point's own node.
        let receiver = shadow.filter(|_| checked).and_then(|s| set.receiver(s, si));
        let mut sum = Rgb::ZERO;
        for group in &set.groups {
            // eq. 161: the group's filtered visibility, and the whole group skipped at 0
            // (unless the receiver's map may still see some of its VPLs).
            let map = group.map.as_deref();
            let group_verdict = || {
                let node = map.and_then(|m| node_verdict(scene, m, si, checked));
                let skip = node == Some(0.0) && !receiver.is_some_and(|r| sees_node(scene, r, map));
                (node, skip)
            };
            // A node's group is read first (most are skipped whole); a site's when one of
            // its few VPLs faces x.
            let mut verdict = (!group.site).then(group_verdict);
            if verdict.is_some_and(|(_, skip)| skip) {
                continue;
            }
            let vpls = set.vpls[group.start..group.end]
                .iter()
                .take_while(|v| v.path_len <= max_len);
            for v in vpls {
                let mut value = None;
                if group.site {
                    value = unshadowed(set.bound, si, bsdf, frame, wo_local, v);
                    if value.is_none() {
                        continue;
                    }
                }
                let (node, skip) = *verdict.get_or_insert_with(group_verdict);
                if skip {
                    break;
                }
                let visibility = pair_verdict(scene, node, receiver, v);
                if visibility == Some(0.0) {
                    continue;
                }
                let Some(value) =
                    value.or_else(|| unshadowed(set.bound, si, bsdf, frame, wo_local, v))
                else {
                    continue;
                };
                match visibility {
                    Some(f) => sum += value * f,
                    None => {
                        // A verification ray (not an exact group's) by Russian roulette.
                        let q = if map.is_some() { verify } else { 1.0 };
                        if q < 1.0 && pair_uniform(si, v) >= q {
                            continue;
                        }
                        counters.rays += 1;
                        let shadow = si.spawn_ray_to(v.si.p, v.si.p_error, v.si.ng);
                        if !scene.occluded(&shadow) {
                            sum += value / q;
                        }
                    }
                }
            }
        }
        sum
    }

    /// One camera path (module docs), and its radiance split at the first non-delta vertex
    /// for interleaved sampling's filter (the sample's radiance is summed as without it).
    fn trace(
        &self,
        scene: &Scene,
        set: &VplSet,
        mut ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
    ) -> (PixelSample, Split) {
        let mut out = PixelSample::default();
        let mut radiance = Rgb::ZERO;
        let mut split = Split::default();
        // Along the camera path to the first non-delta vertex: its length and delta vertices.
        let (mut distance, mut delta_vertices) = (0.0f32, 0u32);
        let mut beta = Rgb::ONE;
        // Emitters and the environment found along the path count only where no light sample
        // could have found them: from the camera and behind delta surfaces.
        let mut count_emission = true;
        let mut depth = 0u32;
        let max_depth = self.settings.max_depth;
        let estimator = self.estimator();
        let mut hit = {
            counters.rays += 1;
            scene.intersect(&ray)
        };
        loop {
            let Some(si) = hit else {
                if count_emission {
                    if let Some((_, env)) = scene.environment() {
                        if depth > 0 || env.visible_to_camera() {
                            let e = beta * env.radiance(ray.dir);
                            radiance += e;
                            split.add(e);
                        }
                    }
                }
                break;
            };
            let bsdf = scene.bsdf(&si);
            if split.first.is_none() {
                distance += (si.p - ray.origin).length();
            }
            if depth == 0 {
                out.hit = true;
                out.depth = si.t;
                out.normal = si.ns;
                out.albedo = bsdf.albedo_hint();
            }
            if count_emission {
                let e = beta * scene.emitted(&si);
                radiance += e;
                split.add(e);
            }
            if depth >= max_depth {
                break;
            }
            let frame = si.shading_frame();
            let wo_local = frame.to_local(si.wo);
            if !bsdf.is_delta() {
                let samples = self.options.light_samples;
                let mut direct: Option<Rgb> = None;
                for j in 0..samples {
                    rng.set_dimension(if j == 0 {
                        slot(depth, LIGHT_SLOT)
                    } else {
                        extra_light_slot(max_depth, depth, j)
                    });
                    if let Some(light) = estimator::sample_direct_light(
                        scene,
                        &si,
                        &frame,
                        &bsdf,
                        wo_local,
                        &estimator,
                        rng.uniform2(),
                        &mut counters.rays,
                    ) {
                        *direct.get_or_insert(Rgb::ZERO) += light.unweighted();
                    }
                }
                if let Some(direct) = direct {
                    let e = if samples == 1 {
                        beta * direct
                    } else {
                        beta * (direct / samples as f32)
                    };
                    radiance += e;
                    split.add(e);
                }
                if split.first.is_none() {
                    // Everything from here on is this vertex's indirect light.
                    split.first = Some(FirstVertex {
                        p: si.p,
                        normal: si.facing_normal(),
                        distance,
                        material: si.material,
                        delta_vertices,
                        modulation: beta * bsdf.albedo_hint(),
                    });
                }
                // A VPL of j segments makes a path of (depth + 1) + 1 + j segments.
                let max_len = max_depth - depth;
                if max_len >= 2 {
                    let gathered = self.gather(
                        scene,
                        set,
                        &si,
                        &bsdf,
                        &frame,
                        wo_local,
                        max_len - 1,
                        counters,
                    );
                    let e = beta * gathered;
                    radiance += e;
                    split.add(e);
                }
                if !self.options.compensate {
                    break;
                }
            }
            // A delta surface, or the compensation's continuation.
            rng.set_dimension(slot(depth, DIRECTION_SLOT));
            let Some(bs) = bsdf.sample_from(wo_local, rng, Transport::Radiance) else {
                break;
            };
            let wi = frame.to_world(bs.wi);
            let reflected = bs.wi.z * wo_local.z > 0.0;
            let same_side = wi.dot(si.ng) * si.wo.dot(si.ng) > 0.0;
            if reflected != same_side || !(bs.pdf > 0.0) {
                break;
            }
            ray = si.spawn_ray(wi);
            counters.rays += 1;
            hit = scene.intersect(&ray);
            let mut weight = bs.f * (bs.wi.z.abs() / bs.pdf);
            if bsdf.is_delta() {
                count_emission = true;
                delta_vertices += 1;
            } else {
                count_emission = false;
                // The share the VPLs left out: 1 - min(1, b / G) at the point found (0 past
                // the scene: an escaped direction is next-event estimation's).
                let Some(y) = &hit else {
                    break;
                };
                if !scene.bsdf(y).is_delta() {
                    // G as `gather` computes it for a VPL at y: the same split of the
                    // integrand, so the two parts sum to it exactly.
                    let d = y.p - si.p;
                    let dist2 = d.length_squared();
                    let dir = d / dist2.sqrt();
                    let cosines = si.ns.dot(dir).abs() * y.ns.dot(dir).abs();
                    let scaled_bound = set.bound * dist2;
                    if !(cosines > scaled_bound) {
                        break;
                    }
                    weight *= 1.0 - scaled_bound / cosines;
                }
            }
            beta *= weight;
            if !crate::math::is_finite3(beta) || beta == Rgb::ZERO {
                break;
            }
            depth += 1;
        }
        out.radiance = radiance;
        (out, split)
    }
}

impl Integrator for VplIntegrator {
    fn name(&self) -> &'static str {
        "vpl"
    }

    fn bias(&self) -> Option<String> {
        self.options.bias()
    }

    fn uses_iterations(&self) -> bool {
        true
    }

    fn prepare(
        &mut self,
        scene: &Scene,
        _camera: &Camera,
        progress: &dyn Fn(&str, f64) -> bool,
    ) -> Result<Precomputation> {
        self.shadow = None;
        self.prepared_for = None;
        self.selection_stats = SelectionStats::default();
        self.pass_sizes = PassSizeStats::default();
        *self.probes.get_mut().unwrap_or_else(|e| e.into_inner()) = None;
        let mut pre = Precomputation::default();
        if self.options.visibility == VplVisibility::Skeleton {
            match NodeSkeleton::build(
                scene,
                self.settings.skeleton.resolution,
                progress,
                &mut pre.stages,
            )? {
                Ok(skeleton) => {
                    let budget = crate::limits::effective_memory_budget(
                        (self.options.shadow_budget_mb as u64) << 20,
                    );
                    let maps = SkeletonShadowMaps::new(skeleton, self.options.shadow_res, budget);
                    pre.notes.push(maps.budget_note());
                    self.shadow = Some(Arc::new(maps));
                }
                Err(why) => pre
                    .notes
                    .push(format!("exact shadow rays: no usable skeleton ({why})")),
            }
        }
        self.prepared_for = Some(Fingerprint::of(scene));
        Ok(pre)
    }

    fn check_prepared(&self, scene: &Scene) -> Result<()> {
        if self.options.visibility != VplVisibility::Skeleton
            || self.prepared_for == Some(Fingerprint::of(scene))
        {
            Ok(())
        } else {
            Err(Error::invalid(
                "vpl:visibility=skeleton must be prepared for this scene before rendering it",
            ))
        }
    }

    fn render_notes(&self) -> Vec<String> {
        self.shadow
            .iter()
            .map(|s| s.cost_note())
            .chain(self.selection_stats.note())
            .chain(self.pass_sizes.note(self.options.count))
            .collect()
    }

    fn begin_iteration(
        &self,
        scene: &Scene,
        view: &View,
        seed: u64,
        sample_index: u32,
    ) -> Result<Iteration> {
        self.begin_sized_iteration(scene, view, seed, sample_index, 1.0)
    }

    fn sized_iterations(&self) -> bool {
        true
    }

    /// A pass of `size` x `count` light subpaths per VPL set (module docs, "Time budgets").
    fn begin_sized_iteration(
        &self,
        scene: &Scene,
        view: &View,
        seed: u64,
        sample_index: u32,
        size: f32,
    ) -> Result<Iteration> {
        let subpaths = sized_subpaths(self.options.count, self.options.candidates, size);
        self.pass_sizes.record(size);
        let n = self.options.interleave;
        let (probes, mut rays) = match self.options.select {
            VplSelect::Importance => {
                let (p, r) = self.cached_probes(scene, view);
                (Some(p), r)
            }
            VplSelect::Uniform => (None, 0),
        };
        // `probe_maps` reads the receiver maps in the selection: made first (the same maps
        // as after the sets, a function of view and scene; only the budget's order moves).
        let early_receivers = (self.options.probe_maps && probes.is_some())
            .then(|| self.ensure_receiver_maps(scene, view));
        // Set k of pass s draws its light subpaths and acceptances as sample index
        // s N² + k (unique per set and pass below 2^32 / N² passes; s itself for N = 1).
        let mut sets = Vec::with_capacity((n * n) as usize);
        for k in 0..n * n {
            let index = sample_index.wrapping_mul(n * n).wrapping_add(k);
            let (set, r) = self.vpl_set(
                scene,
                view,
                probes.as_ref().map(|p| p.as_slice()),
                seed,
                index,
                subpaths,
            );
            rays += r;
            sets.push(set);
        }
        let receivers =
            Arc::new(early_receivers.unwrap_or_else(|| self.ensure_receiver_maps(scene, view)));
        for set in &mut sets {
            set.receivers = Arc::clone(&receivers);
        }
        if n == 1 {
            return Ok(Iteration {
                data: sets
                    .pop()
                    .map(|s| Box::new(s) as Box<dyn std::any::Any + Send + Sync>),
                rays,
                ..Default::default()
            });
        }
        let (pixels, r) = self.interleaved_pass(scene, view, seed, sample_index, &sets);
        Ok(Iteration {
            data: Some(Box::new(InterleavedPass {
                width: view.width,
                height: view.height,
                pixels,
                sets,
            })),
            rays: rays + r,
            ..Default::default()
        })
    }

    fn sample(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Sampler,
        counters: &mut TraceCounters,
        ctx: &SampleContext,
    ) -> PixelSample {
        let empty = VplSet {
            vpls: Vec::new(),
            groups: Vec::new(),
            bound: f32::INFINITY,
            receivers: Arc::default(),
        };
        if let Some(pass) = ctx
            .iteration
            .and_then(|d| d.downcast_ref::<InterleavedPass>())
        {
            // The render loop's pixel sample, traced and filtered in `begin_iteration`.
            let v = ctx.view;
            if (v.width, v.height) == (pass.width, pass.height) {
                if let Some(s) = pass.pixels.get(ctx.pixel_index as usize) {
                    return *s;
                }
            }
            // Another caller's view: the pixel's own set, unfiltered.
            let n = self.options.interleave as u64;
            let w = u64::from(v.width.max(1));
            let (x, y) = (ctx.pixel_index % w, ctx.pixel_index / w);
            let set = &pass.sets[((y % n) * n + x % n) as usize];
            return self.trace(scene, set, ray, rng, counters).0;
        }
        let set = ctx
            .iteration
            .and_then(|d| d.downcast_ref::<VplSet>())
            .unwrap_or(&empty);
        self.trace(scene, set, ray, rng, counters).0
    }
}

/// How often skeleton visibility agrees with exact visibility over VPL / shading point pairs,
/// and where the differences come from ([`VplIntegrator::visibility_agreement`]).
///
/// A pair's skeleton verdict `V_f(n, z) > 1/2` stands in for the shadow ray's `V(y, z)`
/// through two approximations, told apart by a third test, a ray from the node's centre to the
/// point, `V(n, z)`: the map reads the node's view (`V_f` against `V(n, z)`: texel size, depth
/// bias, PCF), and the node's view stands in for the VPL's (`V(n, z)` against `V(y, z)`),
/// split by whether the node sees its VPL at all.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct VisibilityAgreement {
    /// Pairs that face each other (a non-zero unshadowed term) with the VPL's node mapped.
    pub pairs: u64,
    /// Pairs where `V_f > 1/2` is the shadow ray's verdict.
    pub agreeing: u64,
    /// Pairs a shadow ray finds unoccluded, and those of them with `V_f > 1/2`.
    pub visible: u64,
    pub visible_agreeing: u64,
    /// VPLs of the pass, and those whose node has a shadow map.
    pub vpls: u64,
    pub mapped_vpls: u64,
    /// Mapped VPLs that their node does not see (a ray between them is blocked).
    pub unseen_vpls: u64,
    /// Mean of |V_f - V| over the pairs.
    pub mean_abs_difference: f64,
    /// Pairs where the node cannot stand in for the VPL and a shadow ray decides (those
    /// count as agreeing, with `V_f = V`).
    pub exact_rays: u64,
    /// Disagreeing pairs by cause: the map's verdict is not the node's ray's (the map's own
    /// error), or it is and the node sees the point otherwise than the VPL, the node not
    /// seeing its VPL ("unseen") or seeing it ("parallax").
    pub map_errors: u64,
    pub unseen_errors: u64,
    pub parallax_errors: u64,
    /// The light of the pairs, `sum w V` (w the luminance of the pair's clamped unshadowed
    /// term), and its error `sum w (V_f - V)` split the same way: `V_f - V(n, z)` the map's,
    /// `V(n, z) - V` the node's (unseen or parallax), each as [excess, deficit] (the sums of
    /// the positive and of the negative parts, the latter as a positive number).
    pub light: f64,
    /// For chapter 7's visibility clusters, which take every pair within a cluster as
    /// visible: the pairs whose shading point maps to the VPL's own node (the finest
    /// clusters the skeleton gives; merging nodes into clusters only adds pairs), those of
    /// them visible, and the light a cluster would add at the occluded ones, `sum w (1 - V)`;
    /// and the exact light between different nodes, `sum w V`, which only the gates'
    /// cones could carry.
    pub same_node_pairs: u64,
    pub same_node_visible: u64,
    pub same_node_excess: f64,
    pub other_node_light: f64,
    pub map_bias: [f64; 2],
    pub unseen_bias: [f64; 2],
    pub parallax_bias: [f64; 2],
}

impl VisibilityAgreement {
    pub fn rate(&self) -> f64 {
        self.agreeing as f64 / self.pairs.max(1) as f64
    }

    /// The rate a constant map (every pair visible, or every one occluded) would score.
    pub fn constant_rate(&self) -> f64 {
        let v = self.visible as f64 / self.pairs.max(1) as f64;
        v.max(1.0 - v)
    }

    /// The mean of the agreement rates over the visible pairs and over the occluded ones:
    /// 1/2 for any constant map however unbalanced the pairs (on the door, 94 % of the facing
    /// pairs are occluded, so the plain rate of an all-occluded map is 0.94).
    pub fn balanced_rate(&self) -> f64 {
        let occluded = self.pairs - self.visible;
        let occluded_agreeing = self.agreeing - self.visible_agreeing;
        0.5 * (self.visible_agreeing as f64 / self.visible.max(1) as f64
            + occluded_agreeing as f64 / occluded.max(1) as f64)
    }

    /// The bias of skeleton visibility relative to the exact light of the pairs,
    /// `sum w (V_f - V) / sum w V`.
    pub fn relative_bias(&self) -> f64 {
        let net = |b: [f64; 2]| b[0] - b[1];
        (net(self.map_bias) + net(self.unseen_bias) + net(self.parallax_bias))
            / self.light.max(f64::MIN_POSITIVE)
    }

    /// The mean relative error of the light, `sum w |V_f - V| / sum w V`: at most the sum of
    /// the parts' excesses and deficits over the light.
    pub fn relative_error_bound(&self) -> f64 {
        let both = |b: [f64; 2]| b[0] + b[1];
        (both(self.map_bias) + both(self.unseen_bias) + both(self.parallax_bias))
            / self.light.max(f64::MIN_POSITIVE)
    }

    fn merge(&mut self, o: &VisibilityAgreement) {
        self.pairs += o.pairs;
        self.agreeing += o.agreeing;
        self.visible += o.visible;
        self.visible_agreeing += o.visible_agreeing;
        self.mean_abs_difference += o.mean_abs_difference;
        self.exact_rays += o.exact_rays;
        self.map_errors += o.map_errors;
        self.unseen_errors += o.unseen_errors;
        self.parallax_errors += o.parallax_errors;
        self.light += o.light;
        self.same_node_pairs += o.same_node_pairs;
        self.same_node_visible += o.same_node_visible;
        self.same_node_excess += o.same_node_excess;
        self.other_node_light += o.other_node_light;
        for (a, b) in [
            (&mut self.map_bias, o.map_bias),
            (&mut self.unseen_bias, o.unseen_bias),
            (&mut self.parallax_bias, o.parallax_bias),
        ] {
            a[0] += b[0];
            a[1] += b[1];
        }
    }
}

/// Adds `w d` to the excess (d > 0) or the deficit (d < 0) of `bias`.
fn add_signed(bias: &mut [f64; 2], w: f64, d: f64) {
    if d > 0.0 {
        bias[0] += w * d;
    } else {
        bias[1] -= w * d;
    }
}

impl VplIntegrator {
    /// Compares skeleton visibility with a shadow ray over every pair of a VPL of pass
    /// `sample_index` (whose node has a map) and the first non-delta surface point of a pixel
    /// centre of `view`, among the pairs with a non-zero unshadowed term, and finds the cause
    /// of each difference ([`VisibilityAgreement`]). Needs `prepare` with
    /// `visibility=skeleton`.
    pub fn visibility_agreement(
        &self,
        scene: &Scene,
        view: &View,
        seed: u64,
        sample_index: u32,
    ) -> Result<VisibilityAgreement> {
        use rayon::prelude::*;
        self.check_prepared(scene)?;
        let Some(shadow) = &self.shadow else {
            return Err(Error::invalid(
                "vpl: visibility agreement needs visibility=skeleton with a usable skeleton",
            ));
        };
        let iteration = self.begin_iteration(scene, view, seed, sample_index)?;
        let set = iteration
            .data
            .as_ref()
            .and_then(|d| d.downcast_ref::<VplSet>())
            .ok_or_else(|| Error::invalid("vpl: no VPL set"))?;
        // Each mapped VPL with its node and the node's map, and whether the node sees it.
        let mapped: Vec<(&Vpl, u32, &super::CubeShadowMap, bool)> = set
            .groups
            .iter()
            .filter_map(|g| g.map.as_deref().map(|m| (g, m)))
            .flat_map(|(g, m)| set.vpls[g.start..g.end].iter().map(move |v| (v, g.node, m)))
            .map(|(v, n, m)| {
                let sees = !scene.occluded(&v.si.spawn_ray_to(m.centre(), Vec3::ZERO, Vec3::ZERO));
                (v, n, m, sees)
            })
            .collect();
        let (w, h) = (view.width, view.height);
        let verify = self.options.verify > 0.0;
        let pixel_point = |k: u32| {
            let film = crate::math::Vec2::new(
                ((k % w) as f32 + 0.5) / w as f32,
                ((k / w) as f32 + 0.5) / h as f32,
            );
            scene.intersect(&view.frame.generate_ray(film, crate::math::Vec2::ZERO))
        };
        let per_pixel: Vec<VisibilityAgreement> = (0..w * h)
            .into_par_iter()
            .map(|k| {
                let mut tally = VisibilityAgreement::default();
                let Some(si) = pixel_point(k) else {
                    return tally;
                };
                let bsdf = scene.bsdf(&si);
                if bsdf.is_delta() {
                    return tally;
                }
                let frame = si.shading_frame();
                let wo_local = frame.to_local(si.wo);
                let receiver = verify.then(|| set.receiver(shadow, &si)).flatten();
                let own_node = shadow.node_of(&si);
                for &(v, node, map, sees) in &mapped {
                    if unshadowed(f32::INFINITY, &si, &bsdf, &frame, wo_local, v).is_none() {
                        continue;
                    }
                    let weight = unshadowed(set.bound, &si, &bsdf, &frame, wo_local, v)
                        .map_or(0.0, |c| f64::from(crate::math::luminance(c)));
                    let exact = !scene.occluded(&si.spawn_ray_to(v.si.p, v.si.p_error, v.si.ng));
                    let verdict =
                        pair_verdict(scene, node_verdict(scene, map, &si, verify), receiver, v);
                    tally.exact_rays += u64::from(verdict.is_none());
                    let filtered = verdict.unwrap_or(f32::from(u8::from(exact)));
                    let from_node = (map.centre() - si.p).dot(facing_normal(&si)) > 0.0
                        && !scene.occluded(&si.spawn_ray_to(map.centre(), Vec3::ZERO, Vec3::ZERO));
                    let [e, n] = [exact, from_node].map(|b| f64::from(u8::from(b)));
                    tally.pairs += 1;
                    tally.agreeing += u64::from((filtered > 0.5) == exact);
                    tally.visible += u64::from(exact);
                    tally.visible_agreeing += u64::from(exact && filtered > 0.5);
                    tally.mean_abs_difference += (f64::from(filtered) - e).abs();
                    if (filtered > 0.5) != exact {
                        if (filtered > 0.5) != from_node {
                            tally.map_errors += 1;
                        } else if sees {
                            tally.parallax_errors += 1;
                        } else {
                            tally.unseen_errors += 1;
                        }
                    }
                    tally.light += weight * e;
                    if own_node == Some(node) {
                        tally.same_node_pairs += 1;
                        tally.same_node_visible += u64::from(exact);
                        tally.same_node_excess += weight * (1.0 - e);
                    } else {
                        tally.other_node_light += weight * e;
                    }
                    if verdict.is_none() {
                        continue;
                    }
                    add_signed(&mut tally.map_bias, weight, f64::from(filtered) - n);
                    let node_bias = if sees {
                        &mut tally.parallax_bias
                    } else {
                        &mut tally.unseen_bias
                    };
                    add_signed(node_bias, weight, n - e);
                }
                tally
            })
            .collect();
        let mut out = VisibilityAgreement {
            vpls: set.vpls.len() as u64,
            mapped_vpls: mapped.len() as u64,
            unseen_vpls: mapped.iter().filter(|m| !m.3).count() as u64,
            ..Default::default()
        };
        for tally in &per_pixel {
            out.merge(tally);
        }
        out.mean_abs_difference /= out.pairs.max(1) as f64;
        Ok(out)
    }
}

/// `vpl` in the integrator registry.
pub(super) const REGISTRATION: Registration = Registration {
    name: "vpl",
    set_option: |settings, option: &SpecOption| match option.key {
        // The skeleton of `visibility=skeleton`, at the skeleton guide's resolution options.
        "resolution" | "voxel_budget" => settings
            .skeleton
            .set(option.key, option.value)
            .map(|()| true),
        _ => settings.vpl.set(option.key, option.value),
    },
    create: |settings| Ok(Box::new(VplIntegrator::new(settings)?)),
    adaptive_mis: &[],
};

#[cfg(test)]
mod tests {
    use super::*;

    /// The mean of `xs` and its standard error.
    fn mean_and_error(xs: &[f64]) -> (f64, f64) {
        let n = xs.len() as f64;
        let mean = xs.iter().sum::<f64>() / n;
        let var = xs.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1.0);
        (mean, (var / n).sqrt())
    }

    /// The Russian roulette of `verify=P` is unbiased against tracing every verification ray
    /// (`verify=1`): at each pixel's first surface point of the two rooms (48x36 pixels, four
    /// passes of 64 light subpaths), the same VPLs gathered at P and at 1 differ only by the
    /// roulette, so the mean difference must be zero within its standard error. The pairs the
    /// maps are unsure of carry enough light that a wrong weight (none, losing (1 - P) of
    /// their light) would be off by many standard errors, which the test checks too; and the
    /// hash traces a fraction P of those pairs, within binomial error.
    #[test]
    fn verification_roulette_is_unbiased_and_traces_a_fraction_p() {
        let scene = crate::scene::two_rooms_builder().unwrap().build().unwrap();
        let camera = *scene.camera().unwrap();
        let (_, settings) = super::super::parse_spec(
            "vpl:visibility=skeleton:verify=1:select=uniform",
            Default::default(),
        )
        .unwrap();
        let mut vpl = VplIntegrator::new(settings).unwrap();
        vpl.prepare(&scene, &camera, &|_, _| true).unwrap();
        let shadow = vpl.shadow.clone().expect("the two rooms have a skeleton");
        let (w, h) = (48u32, 36u32);
        let view = View {
            frame: camera.frame(w as f32 / h as f32),
            width: w,
            height: h,
            sampler: Default::default(),
        };
        let points: Vec<SurfaceInteraction> = (0..w * h)
            .filter_map(|k| {
                let film = crate::math::Vec2::new(
                    ((k % w) as f32 + 0.5) / w as f32,
                    ((k / w) as f32 + 0.5) / h as f32,
                );
                scene.intersect(&view.frame.generate_ray(film, crate::math::Vec2::ZERO))
            })
            .filter(|si| !scene.bsdf(si).is_delta())
            .collect();
        for p in [0.25f32, 0.1] {
            let (mut differences, mut unsure_light) = (Vec::new(), Vec::new());
            let (mut unsure, mut traced) = (0u64, 0u64);
            for pass in 0..4 {
                let iteration = vpl.begin_iteration(&scene, &view, 1, pass).unwrap();
                let set = iteration.data.as_ref().unwrap();
                let set = set.downcast_ref::<VplSet>().unwrap();
                for si in &points {
                    let bsdf = scene.bsdf(si);
                    let frame = si.shading_frame();
                    let wo_local = frame.to_local(si.wo);
                    let mut counters = TraceCounters::default();
                    let mut gathered = |verify: f32| {
                        vpl.options.verify = verify;
                        let g = vpl.gather(
                            &scene,
                            set,
                            si,
                            &bsdf,
                            &frame,
                            wo_local,
                            u32::MAX,
                            &mut counters,
                        );
                        f64::from(crate::math::luminance(g))
                    };
                    differences.push(gathered(p) - gathered(1.0));
                    // The pairs `gather` leaves to the roulette, and their exact light.
                    let receiver = set.receiver(&shadow, si);
                    let mut light = 0.0;
                    for group in &set.groups {
                        let Some(map) = group.map.as_deref() else {
                            continue;
                        };
                        let node = node_verdict(&scene, map, si, true);
                        if node == Some(0.0)
                            && !receiver.is_some_and(|r| sees_node(&scene, r, Some(map)))
                        {
                            continue;
                        }
                        for v in &set.vpls[group.start..group.end] {
                            if pair_verdict(&scene, node, receiver, v).is_some() {
                                continue;
                            }
                            let Some(value) = unshadowed(set.bound, si, &bsdf, &frame, wo_local, v)
                            else {
                                continue;
                            };
                            unsure += 1;
                            traced += u64::from(pair_uniform(si, v) < p);
                            let ray = si.spawn_ray_to(v.si.p, v.si.p_error, v.si.ng);
                            if !scene.occluded(&ray) {
                                light += f64::from(crate::math::luminance(value));
                            }
                        }
                    }
                    unsure_light.push(light);
                }
            }
            vpl.options.verify = 1.0;
            let (mean, error) = mean_and_error(&differences);
            let (light, _) = mean_and_error(&unsure_light);
            let unweighted_bias = -(1.0 - f64::from(p)) * light;
            let rate = traced as f64 / unsure as f64;
            let rate_error = (f64::from(p) * (1.0 - f64::from(p)) / unsure as f64).sqrt();
            println!(
                "verify={p}: mean difference from verify=1 {mean:.3e} +- {error:.3e} \
                 (z {:.2}) over {} points; without the 1/P weight {unweighted_bias:.3e} \
                 (z {:.1}); {traced} of {unsure} unsure pairs traced ({rate:.4}, z {:.2})",
                mean / error,
                differences.len(),
                unweighted_bias / error,
                (rate - f64::from(p)) / rate_error,
            );
            assert!(
                error > 0.0 && unsure > 10_000,
                "verify={p}: too few unsure pairs"
            );
            assert!(mean.abs() < 4.0 * error, "verify={p}: biased roulette");
            assert!(
                unweighted_bias.abs() > 10.0 * error,
                "verify={p}: the unsure pairs carry too little light to test the weight"
            );
            assert!(
                (rate - f64::from(p)).abs() < 4.0 * rate_error,
                "verify={p}: the hash traces {rate} of the unsure pairs"
            );
        }
    }

    /// A pixel of a synthetic G-buffer for [`filter_indirect`]: on the plane through `p`
    /// with normal `normal`, seen at `distance`, demodulated indirect light `light` under
    /// albedo `albedo`.
    fn pixel(p: Vec3, normal: Vec3, distance: f32, albedo: Rgb, light: f32) -> Split {
        Split {
            direct: Rgb::splat(100.0),
            indirect: albedo * light,
            first: Some(FirstVertex {
                p,
                normal,
                distance,
                material: 0,
                delta_vertices: 0,
                modulation: albedo,
            }),
        }
    }

    /// The geometry-aware filter averages only across similar pixels: on an 8x8 buffer of
    /// four quadrants (left half a wall at depth 1, facing the camera; top right the same
    /// wall's plane 2 units behind; bottom right a floor, its normal at 90 degrees), each
    /// quadrant's demodulated light constant but different, the filtered light of every
    /// pixel is its own quadrant's, for N = 2, 3, 4 (the windows straddle the quadrants'
    /// borders); a different material or delta path is not averaged either. Within one
    /// quadrant, noise is averaged: each pixel's filtered light is the mean over its window
    /// (shifted inside the image at the edges), times its own albedo (demodulation keeps a
    /// texture); a black albedo channel keeps its own value.
    #[test]
    fn the_filter_does_not_cross_depth_normal_or_material_discontinuities() {
        let (w, h) = (8u32, 8u32);
        let z = Vec3::new(0.0, 0.0, 1.0);
        let y = Vec3::new(0.0, 1.0, 0.0);
        let quadrant = |x: u32, row: u32| match (x < w / 2, row < h / 2) {
            (true, _) => 0,
            (false, true) => 1,
            (false, false) => 2,
        };
        let texture = |x: u32, _row: u32| Rgb::new(0.2 + 0.1 * (x % 3) as f32, 0.5, 0.0);
        let buffer: Vec<Split> = (0..w * h)
            .map(|i| {
                let (x, row) = (i % w, i / w);
                let at = Vec3::new(x as f32 * 0.01, row as f32 * 0.01, 0.0);
                match quadrant(x, row) {
                    0 => pixel(at + z, -z, 1.0, texture(x, row), 1.0),
                    1 => pixel(at + 3.0 * z, -z, 3.0, texture(x, row), 5.0),
                    _ => pixel(at + z, y, 1.0, texture(x, row), 9.0),
                }
            })
            .collect();
        let light = [1.0f32, 5.0, 9.0];
        for n in [2u32, 3, 4] {
            let filtered = filter_indirect(w, h, n, &buffer);
            for i in 0..w * h {
                let (x, row) = (i % w, i / w);
                let want = texture(x, row) * light[quadrant(x, row)];
                let got = filtered[i as usize];
                assert!(
                    (got - want).abs().max_element() < 1e-5,
                    "N = {n}, pixel ({x}, {row}): {got} against {want}"
                );
            }
        }
        // A different material, or a path behind a delta vertex, on the same plane.
        for change in 0..2 {
            let mut b = buffer.clone();
            for i in [0usize, 1, 8, 9] {
                let f = b[i].first.as_mut().unwrap();
                if change == 0 {
                    f.material = 7;
                } else {
                    f.delta_vertices = 1;
                }
                b[i].indirect = f.modulation * 20.0;
            }
            let filtered = filter_indirect(w, h, 2, &b);
            assert!((filtered[0] - b[0].indirect).abs().max_element() < 1e-5);
            assert!((filtered[2] - buffer[2].indirect).abs().max_element() < 1e-5);
        }
        // Noise within one flat region: the window mean, the region mean kept.
        let mut rng = crate::math::Rng::for_sample(5, 0, 0);
        let noisy: Vec<Split> = (0..w * h)
            .map(|i| {
                let (x, row) = (i % w, i / w);
                let at = Vec3::new(x as f32 * 0.01, row as f32 * 0.01, 1.0);
                pixel(at, -z, 1.0, texture(x, row), 4.0 * rng.uniform())
            })
            .collect();
        for n in [2u32, 4] {
            let filtered = filter_indirect(w, h, n, &noisy);
            let demodulated = |i: u32| {
                noisy[i as usize].indirect.x / noisy[i as usize].first.unwrap().modulation.x
            };
            for i in 0..w * h {
                let (x, row) = (i % w, i / w);
                let x0 = x.saturating_sub(n / 2).min(w - n);
                let y0 = row.saturating_sub(n / 2).min(h - n);
                let mean = (y0..y0 + n)
                    .flat_map(|wy| (x0..x0 + n).map(move |wx| wy * w + wx))
                    .map(demodulated)
                    .sum::<f32>()
                    / (n * n) as f32;
                let want = texture(x, row).x * mean;
                assert!((filtered[i as usize].x - want).abs() < 1e-5, "N = {n}");
            }
        }
    }

    /// `select=importance`'s roulette: every probability within [p_min, 1], their sum the
    /// expected count, larger estimates never less likely; and over many draws of
    /// [`accepted`], the weighted sum `sum_i x_i [accepted_i] / p_i` averages the unselected
    /// sum `sum_i x_i` within its standard error, for estimates proportional to the values,
    /// unrelated to them, and all zero (the values include some with a zero estimate, which
    /// only `p_min` keeps reachable). Without the 1 / p weight the mean is far off.
    #[test]
    fn importance_selection_is_unbiased_and_respects_p_min() {
        let n = 400usize;
        let mut rng = crate::math::Rng::for_sample(11, 0, 0);
        let values: Vec<f64> = (0..n)
            .map(|i| {
                if i % 5 == 0 {
                    0.0
                } else {
                    f64::from(rng.uniform()) * 3.0
                }
            })
            .collect();
        let proportional: Vec<f32> = values
            .iter()
            .enumerate()
            .map(|(i, &x)| if i % 7 == 0 { 0.0 } else { x as f32 })
            .collect();
        let unrelated: Vec<f32> = (0..n).map(|_| rng.uniform().powi(4)).collect();
        let zero = vec![0.0f32; n];
        let exact: f64 = values.iter().sum();
        for (label, estimates) in [
            ("proportional", &proportional),
            ("unrelated", &unrelated),
            ("zero", &zero),
        ] {
            for (expected, p_min) in [(50.0f32, 0.05f32), (100.0, 0.02), (390.0, 0.1)] {
                let p = acceptance_probabilities(estimates, expected, p_min);
                assert_eq!(p.len(), n);
                assert!(
                    p.iter().all(|&q| (p_min..=1.0).contains(&q)),
                    "{label}: a probability outside [p_min, 1]"
                );
                let sum: f32 = p.iter().sum();
                assert!(
                    (sum - expected).abs() < 1e-2 * expected,
                    "{label}: expected {expected}, probabilities sum to {sum}"
                );
                for i in 0..n {
                    for j in 0..n {
                        if estimates[i] > estimates[j] {
                            assert!(p[i] >= p[j], "{label}: p not monotone in the estimate");
                        }
                    }
                }
                let draws = 4000u32;
                let (mut weighted, mut unweighted) = (Vec::new(), Vec::new());
                for pass in 0..draws {
                    let (mut w, mut u) = (0.0, 0.0);
                    for i in 0..n {
                        if accepted(3, pass, i, p[i]) {
                            w += values[i] / f64::from(p[i]);
                            u += values[i];
                        }
                    }
                    weighted.push(w);
                    unweighted.push(u);
                }
                let (mean, error) = mean_and_error(&weighted);
                let (plain, _) = mean_and_error(&unweighted);
                println!(
                    "{label}, expected {expected}, p_min {p_min}: weighted mean {mean:.3} +- {error:.3} against {exact:.3} (z {:.2}); unweighted {plain:.3}",
                    (mean - exact) / error.max(1e-12)
                );
                assert!(
                    (mean - exact).abs() <= 4.0 * error + 1e-9 * exact,
                    "{label}: weighted mean {mean} +- {error} against {exact}"
                );
                assert!(
                    (plain - exact).abs() > 10.0 * error,
                    "{label}: the weight is not tested"
                );
            }
        }
    }

    /// Few candidates with a non-zero estimate: those are all kept and the rest share the
    /// remainder; more expected than candidates keeps all.
    #[test]
    fn importance_selection_fills_the_count_when_few_candidates_are_seen() {
        let mut e = vec![0.0f32; 100];
        e[3] = 1.0;
        e[50] = 0.01;
        let p = acceptance_probabilities(&e, 20.0, 0.05);
        assert_eq!((p[3], p[50]), (1.0, 1.0));
        assert!(p.iter().all(|&q| q >= 0.05));
        assert!((p.iter().sum::<f32>() - 20.0).abs() < 1e-3);
        assert!(acceptance_probabilities(&e, 200.0, 0.05)
            .iter()
            .all(|&q| q == 1.0));
    }
}
