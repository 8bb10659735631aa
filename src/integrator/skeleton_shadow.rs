//! Skeleton shadow maps (000 chapter 8, lines 2435-2540): a cube shadow map per node of the
//! filtered skeleton, read with percentage-closer filtering (PCF) to give the filtered
//! visibility `V_f(n, z)` between node n and a shading point z (eq. 159-161).
//!
//! The thesis renders its maps on the GPU; here each texel is one ray cast from the node on
//! the CPU, storing the distance to the first surface along the texel's centre direction (a
//! radial depth, not a projective z: no near plane to choose). The maps depend only on the
//! static geometry, so a node's map is made once, the first time a VPL maps to it, and kept
//! ([`SkeletonShadowMaps`]). `vpl`'s verification also reads *receiver* maps, at half the
//! resolution, of the nodes the view's surfaces map to; both kinds share the memory budget.
//! [`SkeletonShadowMaps`] makes every map lazy ([`CubeShadowMap::lazy`]): a texel is traced
//! when a lookup first reads it, with the depth a whole build gives, so the images are those
//! of whole maps while a one-second preview pays only for the texels its lookups read (on
//! the door 29 % of the node and receiver maps' texels; BENCHMARKS.md, issue 36).
//!
//! # Memory budget
//!
//! A map of `R` texels per face edge holds up to `6 R^2` f32 depths (the thesis: 128, about
//! 400 kB), stored in tiles of 8^2 texels allocated when a lookup first reads one of their
//! texels: a lazy map holds the tiles its lookups read (on the door a site map a sixth of
//! its tiles, BENCHMARKS.md, issue 36) and a table of its tiles. The budget counts what the
//! maps hold. The resolution is planned for the worst case, every filtered node mapped and
//! every tile allocated: it is halved (not below [`MIN_SHADOW_RESOLUTION`]) until that
//! fits. A new map is made only while the budget has room for it whole (so that its tiles
//! fit), in the order nodes and sites first carry VPLs; the VPLs of those refused keep exact
//! shadow rays. A tile the budget has no room for is not stored: its texels are traced at
//! every read (the same depths). Which maps are made is thus a function of the passes alone
//! (tiles are of one size, so the bytes held after a pass do not depend on which thread
//! asked first). The render notes say what happened.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

use rayon::prelude::*;

use super::node_skeleton::NodeSkeleton;
use crate::geometry::Ray;
use crate::math::Vec3;
use crate::scene::{Scene, SurfaceInteraction};

/// The smallest resolution the memory budget may lower the maps to (texels per face edge).
pub const MIN_SHADOW_RESOLUTION: u32 = 8;
/// Texels on each side of the nearest one that PCF compares (a 3x3 kernel).
const PCF_RADIUS: i64 = 1;
/// Cap on the slope (tan of the incidence angle) in the depth bias: beyond about 63 degrees
/// the lookup may shadow a lit grazing surface (acne) rather than let light through a wall
/// (with a cap of 8, the door's occluded VPL / point pairs read as visible 1.5x as often:
/// the agreement test of tests/vpl.rs fell from 0.90 to 0.86).
const MAX_SLOPE: f32 = 2.0;
/// Relative depth tolerance for rounding and the surface's own thickness in f32.
const RELATIVE_EPSILON: f32 = 1e-3;

/// Texels per edge of a map's storage tile. A tile is allocated when a lookup first reads one
/// of its texels, so a lazy map holds about what its lookups read (a 3x3 PCF kernel falls in
/// one to four tiles), not its `6 R^2` texels.
const TILE_EDGE: usize = 8;
const TILE_TEXELS: usize = TILE_EDGE * TILE_EDGE;
/// A tile's texels, row-major: the f32 bits of their depths, [`UNTRACED`] where not traced
/// yet.
type Tile = [AtomicU32; TILE_TEXELS];
/// A tile's place in its map: unset until one of its texels is first read, then the tile, or
/// None when the memory budget had no room for it (its texels are then traced at every read:
/// the same depths, at a ray per read).
type TileSlot = OnceLock<Option<Box<Tile>>>;
const TILE_BYTES: u64 = std::mem::size_of::<Tile>() as u64;

/// The memory of the maps that share a budget (their tile tables and their tiles), with its
/// limit: tiles are allocated by the render threads, so the count is atomic.
pub struct MapMemory {
    limit: u64,
    used: AtomicU64,
}

impl MapMemory {
    pub fn new(limit: u64) -> Self {
        MapMemory {
            limit,
            used: AtomicU64::new(0),
        }
    }

    /// Bytes held.
    pub fn used(&self) -> u64 {
        self.used.load(Ordering::Relaxed)
    }

    /// Bytes left below the limit.
    pub fn left(&self) -> u64 {
        self.limit.saturating_sub(self.used())
    }

    /// Counts `bytes` if they fit below the limit. All tiles have one size, so the bytes held
    /// after a pass are the same whichever threads asked first.
    fn try_reserve(&self, bytes: u64) -> bool {
        self.used
            .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |u| {
                (u + bytes <= self.limit).then_some(u + bytes)
            })
            .is_ok()
    }
}

/// One node's cube shadow map: six faces of `resolution`^2 radial depths, stored in tiles of
/// [`TILE_EDGE`]^2 texels allocated as lookups first read them.
pub struct CubeShadowMap {
    centre: Vec3,
    resolution: u32,
    /// Tiles per face edge (the last row and column may hang over the face).
    tiles_per_edge: usize,
    /// The tiles, face-major, then row, then column. A texel holds `f32::INFINITY` where the
    /// ray left the scene. A texel's depth is a function of the map's centre and the texel
    /// alone, so threads that trace it at once store the same.
    tiles: Box<[TileSlot]>,
    /// Texels traced and stored (a map built whole counts none).
    traced: AtomicU64,
    /// Texel rays traced for tiles the budget had no room for.
    untiled: AtomicU64,
    /// Tiles allocated.
    stored_tiles: AtomicU64,
    memory: Arc<MapMemory>,
}

/// The bits of a texel not traced yet: a NaN no ray's distance gives.
const UNTRACED: u32 = 0x7fc0_beef;

/// The face of direction `d` (0: +x, 1: -x, 2: +y, 3: -y, 4: +z, 5: -z) and its coordinates
/// (u, v) in [-1, 1] on that face: `d[b] / |d[a]|`, `d[c] / |d[a]|` for the major axis a and
/// the two others (b, c) = (a + 1, a + 2) mod 3.
#[inline]
fn face_coordinates(d: Vec3) -> (usize, f32, f32) {
    let m = d.abs();
    let a = if m.x >= m.y && m.x >= m.z {
        0
    } else if m.y >= m.z {
        1
    } else {
        2
    };
    let c = d.to_array();
    let major = c[a];
    let face = 2 * a + usize::from(major < 0.0);
    let inv = 1.0 / major.abs();
    (face, c[(a + 1) % 3] * inv, c[(a + 2) % 3] * inv)
}

/// The unit direction through (u, v) of `face` (the inverse of [`face_coordinates`]).
#[inline]
fn face_direction(face: usize, u: f32, v: f32) -> Vec3 {
    let a = face / 2;
    let sign = if face % 2 == 0 { 1.0 } else { -1.0 };
    let mut c = [0.0f32; 3];
    c[a] = sign;
    c[(a + 1) % 3] = u;
    c[(a + 2) % 3] = v;
    Vec3::from_array(c).normalize()
}

impl CubeShadowMap {
    fn tiles_per_edge(resolution: u32) -> usize {
        (resolution as usize).div_ceil(TILE_EDGE)
    }

    /// Bytes of a map's tile table, held from its making.
    fn table_bytes(resolution: u32) -> u64 {
        (6 * Self::tiles_per_edge(resolution).pow(2) * std::mem::size_of::<TileSlot>()) as u64
    }

    /// Bytes of one map of `resolution` texels per face edge with every tile allocated (the
    /// most it may hold).
    pub fn bytes_for(resolution: u32) -> u64 {
        Self::table_bytes(resolution)
            + 6 * Self::tiles_per_edge(resolution).pow(2) as u64 * TILE_BYTES
    }

    /// Casts one ray per texel from `centre` (in parallel over texel rows).
    pub fn build(scene: &Scene, centre: Vec3, resolution: u32) -> CubeShadowMap {
        let map = Self::lazy(centre, resolution);
        let r = resolution as usize;
        (0..6 * r).into_par_iter().for_each(|row| {
            let (face, j) = (row / r, row % r);
            for i in 0..r {
                if let Some(texel) = map.texel(face, i, j) {
                    texel.store(map.trace(scene, face, i, j).to_bits(), Ordering::Relaxed);
                }
            }
        });
        map
    }

    /// A map whose texels are traced when first read ([`Self::visibility`]): it costs the
    /// rays of the texels the shading points look up, not of all `6 resolution^2` (map
    /// sites, most of whose view no shading point lies in), and the memory of their tiles.
    /// The same depths as [`Self::build`]'s. Its memory is its own, unbounded.
    pub fn lazy(centre: Vec3, resolution: u32) -> CubeShadowMap {
        Self::lazy_within(centre, resolution, Arc::new(MapMemory::new(u64::MAX)))
    }

    /// [`Self::lazy`] counting its table and tiles in `memory`: its table is counted whatever
    /// the limit (the caller checks the room), a tile only if it fits.
    pub fn lazy_within(centre: Vec3, resolution: u32, memory: Arc<MapMemory>) -> CubeShadowMap {
        let tiles_per_edge = Self::tiles_per_edge(resolution);
        memory
            .used
            .fetch_add(Self::table_bytes(resolution), Ordering::Relaxed);
        CubeShadowMap {
            centre,
            resolution,
            tiles_per_edge,
            tiles: (0..6 * tiles_per_edge * tiles_per_edge)
                .map(|_| OnceLock::new())
                .collect(),
            traced: AtomicU64::new(0),
            untiled: AtomicU64::new(0),
            stored_tiles: AtomicU64::new(0),
            memory,
        }
    }

    /// The depth of texel (i, j) of `face`: the distance to the first surface along the
    /// direction through the texel's centre.
    fn trace(&self, scene: &Scene, face: usize, i: usize, j: usize) -> f32 {
        let to_face = |i: usize| (i as f32 + 0.5) / self.resolution as f32 * 2.0 - 1.0;
        let dir = face_direction(face, to_face(i), to_face(j));
        scene
            .intersect_hit(&Ray::new(self.centre, dir, f32::INFINITY))
            .map_or(f32::INFINITY, |hit| hit.t)
    }

    /// Texel (i, j) of `face`, its tile allocated first if it is not yet; None when the
    /// budget has no room for the tile.
    #[inline]
    fn texel(&self, face: usize, i: usize, j: usize) -> Option<&AtomicU32> {
        let t = self.tiles_per_edge;
        let slot = &self.tiles[(face * t + j / TILE_EDGE) * t + i / TILE_EDGE];
        let tile = slot.get_or_init(|| {
            self.memory.try_reserve(TILE_BYTES).then(|| {
                self.stored_tiles.fetch_add(1, Ordering::Relaxed);
                Box::new(std::array::from_fn(|_| AtomicU32::new(UNTRACED)))
            })
        });
        Some(&tile.as_ref()?[(j % TILE_EDGE) * TILE_EDGE + i % TILE_EDGE])
    }

    /// The depth of texel (i, j) of `face`, traced first if it is not yet.
    #[inline]
    fn depth_at(&self, scene: &Scene, face: usize, i: usize, j: usize) -> f32 {
        let Some(texel) = self.texel(face, i, j) else {
            self.untiled.fetch_add(1, Ordering::Relaxed);
            return self.trace(scene, face, i, j);
        };
        let bits = texel.load(Ordering::Relaxed);
        if bits != UNTRACED {
            return f32::from_bits(bits);
        }
        let d = self.trace(scene, face, i, j);
        texel.store(d.to_bits(), Ordering::Relaxed);
        self.traced.fetch_add(1, Ordering::Relaxed);
        d
    }

    /// Texels of a lazy map traced and stored so far.
    pub fn traced_texels(&self) -> u64 {
        self.traced.load(Ordering::Relaxed)
    }

    /// Texel rays traced at reads of tiles the budget had no room for.
    pub fn untiled_texel_rays(&self) -> u64 {
        self.untiled.load(Ordering::Relaxed)
    }

    /// Tiles allocated so far, of [`Self::tile_count`].
    pub fn stored_tiles(&self) -> u64 {
        self.stored_tiles.load(Ordering::Relaxed)
    }

    pub fn tile_count(&self) -> usize {
        self.tiles.len()
    }

    pub fn centre(&self) -> Vec3 {
        self.centre
    }

    pub fn resolution(&self) -> u32 {
        self.resolution
    }

    /// Bytes held: the tile table and the tiles allocated.
    pub fn memory_bytes(&self) -> u64 {
        Self::table_bytes(self.resolution) + self.stored_tiles() * TILE_BYTES
    }

    /// The filtered visibility `V_f` in [0, 1] between the map's centre and surface point `p`
    /// of geometric normal `ng`, turned to the side p scatters to (0 when the centre is on
    /// the other side): the fraction of the 3x3 texels around the nearest one (clamped
    /// to its face) whose depth is at least `p`'s distance less a slope-scaled bias.
    ///
    /// The bias: a neighbour texel k texels away sees the plane through p at a depth that
    /// differs from |p - centre| by about `|p - centre| k (2 / R) tan(theta)`, theta the
    /// incidence angle on the plane, (2 / R) a texel's angle at the face centre (smaller
    /// towards the corners). With k up to 1.5 (the kernel's radius and the sub-texel
    /// offset), the tolerance is that, capped in slope ([`MAX_SLOPE`]), plus one texel's
    /// worth for a surface that is not quite planar and a relative epsilon.
    pub fn visibility(&self, scene: &Scene, p: Vec3, ng: Vec3) -> f32 {
        let d = p - self.centre;
        let distance = d.length();
        if !(distance > 0.0) {
            return 1.0;
        }
        let dir = d / distance;
        // The node behind the surface (as `ng` faces) cannot see it, however thin the
        // surface: no depth bias lets light through it.
        if ng.dot(dir) >= 0.0 {
            return 0.0;
        }
        let cos = ng.dot(dir).abs().clamp(1e-6, 1.0);
        let slope = ((1.0 - cos * cos).max(0.0).sqrt() / cos).min(MAX_SLOPE);
        let texel_angle = 2.0 / self.resolution as f32;
        let tolerance = distance * (texel_angle * (1.5 * slope + 1.0) + RELATIVE_EPSILON);
        let (face, u, v) = face_coordinates(dir);
        let r = self.resolution as i64;
        let texel = |x: f32| (((x + 1.0) * 0.5 * self.resolution as f32) as i64).clamp(0, r - 1);
        let (ci, cj) = (texel(u), texel(v));
        let mut lit = 0u32;
        let mut total = 0u32;
        for j in (cj - PCF_RADIUS).max(0)..=(cj + PCF_RADIUS).min(r - 1) {
            for i in (ci - PCF_RADIUS).max(0)..=(ci + PCF_RADIUS).min(r - 1) {
                total += 1;
                let depth = self.depth_at(scene, face, i as usize, j as usize);
                if depth + tolerance >= distance {
                    lit += 1;
                }
            }
        }
        lit as f32 / total as f32
    }
}

/// A map site of `vpl:sites=K`: a cell of K^3 voxels of the skeleton's grid (`cell` holds its
/// coordinates and K) and a filtered node, standing for the empty voxels of the cell that map
/// to that node (one side of a wall through the cell).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Site {
    pub cell: [u32; 4],
    pub node: u32,
}

/// What the shadow maps cost so far (for the render notes).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ShadowMapStats {
    /// Nodes with a map, and with a receiver map.
    pub maps: usize,
    pub receiver_maps: usize,
    /// Sites with a map (`vpl:sites=K`).
    pub site_maps: usize,
    /// Nodes that carried VPLs but got no map (over the budget): exact rays for their VPLs.
    pub refused: usize,
    /// Bytes the maps hold (tile tables and allocated tiles).
    pub bytes: u64,
}

/// The shadow maps of the filtered skeleton's nodes, built when a node first carries VPLs.
pub struct SkeletonShadowMaps {
    skeleton: NodeSkeleton,
    resolution: u32,
    /// Resolution asked for, before the budget.
    requested: u32,
    /// Most maps the budget holds at `resolution`.
    max_maps: usize,
    /// What the maps hold, within the budget (its limit).
    memory: Arc<MapMemory>,
    /// Per node: unset until it carried a VPL, then its map or None (over the budget).
    maps: Vec<OnceLock<Option<Arc<CubeShadowMap>>>>,
    /// Per node: the map read at VPLs from the shading points the node maps, at
    /// [`Self::receiver_resolution`] (`vpl`'s two-sided test); built as `maps`.
    receivers: Vec<OnceLock<Option<Arc<CubeShadowMap>>>>,
    /// `vpl:sites=K`: the maps of the sites ([`Site`]) that carried VPLs, None over the
    /// budget or where the site has no empty voxel.
    sites: Mutex<HashMap<Site, Option<Arc<CubeShadowMap>>>>,
    stats: Mutex<ShadowMapStats>,
}

impl SkeletonShadowMaps {
    /// Maps of at most `requested` texels per face edge for the nodes of `skeleton`, within
    /// `budget_bytes` (module docs).
    pub(super) fn new(skeleton: NodeSkeleton, requested: u32, budget_bytes: u64) -> Self {
        let nodes = skeleton.positions.len() as u64;
        let mut resolution = requested;
        while resolution > MIN_SHADOW_RESOLUTION
            && nodes * CubeShadowMap::bytes_for(resolution) > budget_bytes
        {
            resolution = (resolution / 2).max(MIN_SHADOW_RESOLUTION);
        }
        let max_maps = (budget_bytes / CubeShadowMap::bytes_for(resolution)).min(nodes) as usize;
        SkeletonShadowMaps {
            maps: (0..nodes).map(|_| OnceLock::new()).collect(),
            receivers: (0..nodes).map(|_| OnceLock::new()).collect(),
            sites: Mutex::new(HashMap::new()),
            skeleton,
            resolution,
            requested,
            max_maps,
            memory: Arc::new(MapMemory::new(budget_bytes)),
            stats: Mutex::new(ShadowMapStats::default()),
        }
    }

    pub fn node_count(&self) -> usize {
        self.maps.len()
    }

    pub fn resolution(&self) -> u32 {
        self.resolution
    }

    /// The position of filtered node `node` (its map's centre).
    pub fn node_position(&self, node: u32) -> Vec3 {
        self.skeleton.positions[node as usize]
    }

    /// The filtered node of a VPL's surface point (eq. 151-155).
    pub fn node_of(&self, si: &SurfaceInteraction) -> Option<u32> {
        self.skeleton.node_of(si)
    }

    /// Makes the (lazy) maps of the `nodes` (sorted, distinct) that have none yet; nodes
    /// beyond the budget, in the order given, get None. Deterministic: which nodes
    /// get maps depends only on the order in which nodes first carry VPLs.
    pub fn ensure(&self, nodes: &[u32]) {
        self.ensure_in(&self.maps, self.resolution, nodes);
    }

    /// [`Self::ensure`] for the receiver maps ([`Self::receiver_map`]), within the same
    /// budget.
    pub fn ensure_receivers(&self, nodes: &[u32]) {
        self.ensure_in(&self.receivers, self.receiver_resolution(), nodes);
    }

    /// Texels per face edge of a receiver map: half a node's (it only sorts VPLs into seen
    /// and unseen, and every shading point's node needs one).
    pub fn receiver_resolution(&self) -> u32 {
        (self.resolution / 2).max(MIN_SHADOW_RESOLUTION)
    }

    fn ensure_in(
        &self,
        slots: &[OnceLock<Option<Arc<CubeShadowMap>>>],
        resolution: u32,
        nodes: &[u32],
    ) {
        let mut stats = self.stats.lock().unwrap_or_else(|e| e.into_inner());
        let missing: Vec<u32> = nodes
            .iter()
            .copied()
            .filter(|&n| slots[n as usize].get().is_none())
            .collect();
        if missing.is_empty() {
            return;
        }
        let room = ((self.memory.left() / CubeShadowMap::bytes_for(resolution)) as usize)
            .min(missing.len());
        let (build, refuse) = missing.split_at(room);
        for &n in build {
            let map = CubeShadowMap::lazy_within(
                self.skeleton.positions[n as usize],
                resolution,
                Arc::clone(&self.memory),
            );
            let _ = slots[n as usize].set(Some(Arc::new(map)));
        }
        for &n in refuse {
            let _ = slots[n as usize].set(None);
        }
        if std::ptr::eq(slots, &self.maps[..]) {
            stats.maps += build.len();
        } else {
            stats.receiver_maps += build.len();
        }
        stats.refused += refuse.len();
    }

    /// Node `node`'s receiver map, None when it has none (not built yet, or over the
    /// budget). Never its full map: whether that exists depends on which passes ran before.
    #[inline]
    pub fn receiver_map(&self, node: u32) -> Option<&CubeShadowMap> {
        self.receivers.get(node as usize)?.get()?.as_deref()
    }

    /// Node `node`'s map, None when it has none (not built yet, or over the budget).
    #[inline]
    pub fn map(&self, node: u32) -> Option<&Arc<CubeShadowMap>> {
        self.maps.get(node as usize)?.get()?.as_ref()
    }

    /// The site of a VPL's surface point with sites of `cell` voxels per edge
    /// (`vpl:sites=K`): the cell of the empty voxel the point maps through (eq. 151-155's
    /// voxel, on the side the surface faces) and that voxel's node.
    pub fn site_of(&self, si: &SurfaceInteraction, cell: u32) -> Option<Site> {
        let sk = &self.skeleton;
        let k = sk.voxel_of(si)?;
        let c = sk.grid.coords(k).map(|x| (x / cell as usize) as u32);
        Some(Site {
            cell: [c[0], c[1], c[2], cell],
            node: sk.node_map[k],
        })
    }

    /// Where a site's map stands: among the empty voxels of the site's cell that map to its
    /// node, the centre of the one nearest their centroid (inside the free space the site's
    /// VPLs face, as far from the cell's walls as its voxels go). None when it has none.
    pub fn site_centre(&self, site: Site) -> Option<Vec3> {
        let sk = &self.skeleton;
        let [cx, cy, cz, k] = site.cell.map(|x| x as usize);
        let dims = sk.grid.dims;
        let mut voxels = Vec::new();
        for z in cz * k..((cz + 1) * k).min(dims[2]) {
            for y in cy * k..((cy + 1) * k).min(dims[1]) {
                for x in cx * k..((cx + 1) * k).min(dims[0]) {
                    let i = sk.grid.index(x, y, z);
                    if sk.node_map[i] == site.node {
                        voxels.push(i);
                    }
                }
            }
        }
        if voxels.is_empty() {
            return None;
        }
        let centroid = voxels
            .iter()
            .fold(Vec3::ZERO, |a, &i| a + sk.grid.voxel_center(i))
            / voxels.len() as f32;
        voxels
            .iter()
            .map(|&i| sk.grid.voxel_center(i))
            .min_by(|a, b| {
                (*a - centroid)
                    .length_squared()
                    .total_cmp(&(*b - centroid).length_squared())
            })
    }

    /// The maps of `sites` (sorted, distinct), making those that have none yet at the node
    /// maps' resolution, within the same budget (sites beyond it, in the order given, get
    /// None for good, as nodes do). Deterministic as [`Self::ensure`]. The maps are lazy
    /// ([`CubeShadowMap::lazy`]): their texels are traced as the lookups need them.
    pub fn ensure_sites(&self, sites: &[Site]) -> Vec<Option<Arc<CubeShadowMap>>> {
        let mut table = self.sites.lock().unwrap_or_else(|e| e.into_inner());
        let missing: Vec<(Site, Option<Vec3>)> = sites
            .iter()
            .filter(|s| !table.contains_key(s))
            .map(|&s| (s, self.site_centre(s)))
            .collect();
        if !missing.is_empty() {
            let mut stats = self.stats.lock().unwrap_or_else(|e| e.into_inner());
            let per_map = CubeShadowMap::bytes_for(self.resolution);
            let mut left = self.memory.left();
            let mut build = Vec::new();
            for &(site, centre) in &missing {
                match centre {
                    Some(c) if left >= per_map => {
                        left -= per_map;
                        build.push((site, c));
                    }
                    Some(_) => {
                        stats.refused += 1;
                        table.insert(site, None);
                    }
                    None => {
                        table.insert(site, None);
                    }
                }
            }
            for &(site, centre) in &build {
                let map =
                    CubeShadowMap::lazy_within(centre, self.resolution, Arc::clone(&self.memory));
                table.insert(site, Some(Arc::new(map)));
            }
            stats.site_maps += build.len();
        }
        sites
            .iter()
            .map(|s| table.get(s).cloned().flatten())
            .collect()
    }

    pub fn stats(&self) -> ShadowMapStats {
        ShadowMapStats {
            bytes: self.memory.used(),
            ..*self.stats.lock().unwrap_or_else(|e| e.into_inner())
        }
    }

    /// How the budget shaped the maps, for the precomputation notes.
    pub fn budget_note(&self) -> String {
        let mb = |b: u64| b as f64 / (1 << 20) as f64;
        let nodes = self.maps.len();
        let per_map = CubeShadowMap::bytes_for(self.resolution);
        let mut note = format!(
            "skeleton shadow maps: {nodes} filtered nodes, {r}^2 texels per face ({:.2} MB per map)",
            mb(per_map),
            r = self.resolution
        );
        if self.resolution < self.requested {
            note += &format!(
                ", lowered from {} by the budget of {:.0} MB",
                self.requested,
                mb(self.memory.limit)
            );
        }
        if self.max_maps < nodes {
            note += &format!(
                "; the budget holds {} whole maps (lazy maps hold only the tiles their lookups \
                 read): VPLs of nodes beyond it use exact shadow rays",
                self.max_maps
            );
        }
        note
    }

    /// The cost so far, for the render notes: the maps made, the texels their lookups traced
    /// (every map is lazy) and the tiles that hold them.
    pub fn cost_note(&self) -> String {
        let s = self.stats();
        let sites = self.sites.lock().unwrap_or_else(|e| e.into_inner());
        let maps: Vec<&CubeShadowMap> = self
            .maps
            .iter()
            .chain(&self.receivers)
            .filter_map(|m| m.get()?.as_deref())
            .chain(sites.values().flatten().map(|m| &**m))
            .collect();
        let sum = |f: fn(&CubeShadowMap) -> u64| -> u64 { maps.iter().map(|m| f(m)).sum() };
        let texels = sum(CubeShadowMap::traced_texels);
        let tiles = sum(CubeShadowMap::stored_tiles);
        let of_tiles = sum(|m| m.tile_count() as u64);
        let untiled = sum(CubeShadowMap::untiled_texel_rays);
        let (r, rr) = (self.resolution as u64, self.receiver_resolution() as u64);
        let of = 6 * ((s.maps + s.site_maps) as u64 * r * r + s.receiver_maps as u64 * rr * rr);
        let mut note = format!(
            "skeleton shadow maps: {} node maps ({r}^2 per face){}{}, {texels} of their texels \
             traced when first read ({:.1} per cent), held in {tiles} tiles of {TILE_EDGE}^2 \
             ({:.1} per cent), {:.2} MB",
            s.maps,
            if s.receiver_maps > 0 {
                format!(", {} receiver maps ({rr}^2)", s.receiver_maps)
            } else {
                String::new()
            },
            if s.site_maps > 0 {
                format!(", {} site maps", s.site_maps)
            } else {
                String::new()
            },
            100.0 * texels as f64 / of.max(1) as f64,
            100.0 * tiles as f64 / of_tiles.max(1) as f64,
            s.bytes as f64 / (1 << 20) as f64,
        );
        if untiled > 0 {
            note += &format!("; {untiled} texel rays for tiles over the budget");
        }
        if s.refused > 0 {
            note += &format!(
                "; {} nodes over the budget used exact shadow rays",
                s.refused
            );
        }
        note
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn face_coordinates_invert_face_direction() {
        for face in 0..6 {
            for &(u, v) in &[(0.0, 0.0), (0.5, -0.25), (-0.9, 0.9), (0.99, 0.01)] {
                let d = face_direction(face, u, v);
                let (f, u2, v2) = face_coordinates(d * 3.0);
                assert_eq!(f, face);
                assert!(
                    (u - u2).abs() < 1e-5 && (v - v2).abs() < 1e-5,
                    "{face} {u} {v}"
                );
            }
        }
    }

    /// A lazy map holds the tiles its lookups read, and counts them in its memory; tiles the
    /// budget has no room for are traced at each read and give the same visibility.
    #[test]
    fn lazy_maps_hold_the_tiles_they_read_within_the_budget() {
        let scene = crate::scene::two_rooms_builder().unwrap().build().unwrap();
        let centre = Vec3::new(2.5, 1.25, 2.0);
        let built = CubeShadowMap::build(&scene, centre, 32);
        assert_eq!(built.stored_tiles(), built.tile_count() as u64);
        assert_eq!(built.memory_bytes(), CubeShadowMap::bytes_for(32));
        let room = 3;
        let memory = Arc::new(MapMemory::new(
            CubeShadowMap::table_bytes(32) + room * TILE_BYTES,
        ));
        let tight = CubeShadowMap::lazy_within(centre, 32, Arc::clone(&memory));
        let free = CubeShadowMap::lazy(centre, 32);
        let mut rng = crate::math::Rng::new(3, 1);
        for _ in 0..40 {
            let dir = crate::math::warp::uniform_sphere(rng.uniform2());
            let Some(si) = scene.intersect(&Ray::new(centre, dir, f32::INFINITY)) else {
                continue;
            };
            let v = built.visibility(&scene, si.p, -dir);
            assert_eq!(tight.visibility(&scene, si.p, -dir), v);
            assert_eq!(free.visibility(&scene, si.p, -dir), v);
        }
        assert_eq!(tight.stored_tiles(), room);
        assert!(tight.untiled_texel_rays() > 0);
        assert_eq!(memory.used(), tight.memory_bytes());
        assert_eq!(free.untiled_texel_rays(), 0);
        let (stored, tiles) = (free.stored_tiles(), free.tile_count() as u64);
        println!(
            "{stored} of {tiles} tiles stored, {} texels",
            free.traced_texels()
        );
        assert!(stored > room && stored < tiles);
        assert!(free.memory_bytes() < CubeShadowMap::bytes_for(32));
    }

    /// In the two-room scene, from a point of the camera room's empty space, the map's PCF
    /// visibility agrees with a shadow ray: the floor right below and the ceiling read 1, the
    /// floor under the table and the far room's floor behind the wall read 0, and over random surface points the verdicts (V_f > 1/2
    /// against the ray's) agree almost everywhere (they can differ only within a texel or two
    /// of a shadow's edge).
    #[test]
    fn pcf_lookup_agrees_with_a_ray_in_the_two_rooms() {
        let scene = crate::scene::two_rooms_builder().unwrap().build().unwrap();
        let centre = Vec3::new(2.5, 1.25, 2.0);
        let map = CubeShadowMap::build(&scene, centre, 128);
        assert_eq!(map.tile_count(), 6 * 16 * 16);
        assert_eq!(
            map.visibility(&scene, Vec3::new(2.5, 0.0, 2.0), Vec3::Y),
            1.0
        );
        // The same point as the underside of the floor: the centre is behind it.
        assert_eq!(
            map.visibility(&scene, Vec3::new(2.5, 0.0, 2.0), -Vec3::Y),
            0.0
        );
        assert_eq!(
            map.visibility(&scene, Vec3::new(3.5, 2.5, 3.5), -Vec3::Y),
            1.0
        );
        // Behind the side of the table (x = 1.1, top at y = 0.75).
        assert_eq!(
            map.visibility(&scene, Vec3::new(0.7, 0.0, 2.1), Vec3::Y),
            0.0
        );
        // The segment to it crosses z = 0 at x = 2.9: the wall beside the doorway.
        assert_eq!(
            map.visibility(&scene, Vec3::new(3.5, 0.0, -3.0), Vec3::Y),
            0.0
        );
        let b = scene.bounds();
        let size = b.max - b.min;
        let (mut agree, mut total, mut visible) = (0, 0, 0);
        let mut rng = crate::math::Rng::new(7, 1);
        for _ in 0..4000 {
            // Surface points found from a random point of the bounds in a random direction.
            let origin = b.min + size * Vec3::new(rng.uniform(), rng.uniform(), rng.uniform());
            let dir = crate::math::warp::uniform_sphere(rng.uniform2());
            let Some(si) = scene.intersect(&Ray::new(origin, dir, f32::INFINITY)) else {
                continue;
            };
            // The side seen from the origin, and the centre in front of it.
            let facing = if si.ng.dot(dir) < 0.0 { si.ng } else { -si.ng };
            let ray_visible = (centre - si.p).dot(facing) > 0.0
                && !scene.occluded(&si.spawn_ray_to(centre, Vec3::ZERO, Vec3::ZERO));
            let v = map.visibility(&scene, si.p, facing);
            assert!((0.0..=1.0).contains(&v));
            total += 1;
            visible += usize::from(ray_visible);
            agree += usize::from((v > 0.5) == ray_visible);
        }
        let rate = agree as f64 / total as f64;
        println!("PCF against rays: {agree} of {total} agree ({rate:.4}), {visible} visible");
        assert!(total > 2000 && visible > total / 10 && visible < total * 9 / 10);
        assert!(rate > 0.97, "agreement {rate} over {total} points");
    }
}
