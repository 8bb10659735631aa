//! `lacuna_skeleton`: the curvilinear skeleton of an analysed empty space (thinning, piercing,
//! the filtered skeleton, the node map), with node and edge enumeration, surface-point mapping
//! (eq. 151-155 of L. Noël's thesis, "000" in `docs/references.md`) and OBJ / PLY export.

use std::ffi::{c_char, c_void};
use std::sync::Arc;

use super::analysis::lacuna_analysis;
use super::boundary::{self, lacuna_status, CapiError};
use super::buffer::{
    arc_clone, arc_into_handle, arc_release, arc_retain, arg, out_ptr, read_arg, str_arg, write_out,
};
use super::job::lacuna_progress_callback;
use super::job::stage_progress;
use super::types::{lacuna_vec3, LACUNA_INVALID_INDEX};
use crate::analysis::{skeleton_obj, skeleton_ply, Graph, Skeleton, SkeletonSettings};

/// Thin on the calling thread only (the result is identical; default: the context's workers).
pub const LACUNA_SKELETON_SEQUENTIAL: u32 = 1;
/// Also compute the Betti numbers of the empty space (`lacuna_skeleton_get_info`).
pub const LACUNA_SKELETON_TOPOLOGY: u32 = 2;

/// The curvilinear skeleton, one node per point of the thinned complex.
pub const LACUNA_SKELETON_GRAPH_RAW: u32 = 0;
/// The filtered skeleton (maximal-ball clusters, 000 Algorithm 4); the node map and
/// `lacuna_skeleton_map_point` refer to its nodes.
pub const LACUNA_SKELETON_GRAPH_FILTERED: u32 = 1;

/// Wavefront OBJ: one `v` per node, one `l` per edge.
pub const LACUNA_SKELETON_FORMAT_OBJ: u32 = 0;
/// ASCII PLY: vertices with a `radius` property (world units) and an `edge` element.
pub const LACUNA_SKELETON_FORMAT_PLY: u32 = 1;

/// The skeleton of the empty space of an analysis.
///
/// Refcounted (`lacuna_skeleton_retain`/`lacuna_skeleton_release`); keeps its analysis (and so
/// its scene) alive. Immutable: every function may be called from any number of threads at
/// once.
pub struct lacuna_skeleton {
    /// Held only to keep the analysis (and its scene's context) alive.
    analysis: Arc<lacuna_analysis>,
    skeleton: Skeleton,
}

/// A skeleton node.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct lacuna_skeleton_node {
    /// World position (a voxel corner of the analysis grid).
    pub position: lacuna_vec3,
    /// Radius of the largest ball centred on the node's voxel that holds no occupied voxel
    /// centre (exact Euclidean distance, world units).
    pub radius: f32,
    /// Number of edges at the node.
    pub degree: u32,
    /// For a raw node: the filtered node it belongs to; for a filtered node: its own index.
    pub filtered: u32,
}

/// Sizes and topology of a skeleton.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct lacuna_skeleton_info {
    pub raw_nodes: usize,
    pub raw_edges: usize,
    pub filtered_nodes: usize,
    pub filtered_edges: usize,
    /// Connected components and cycle rank (edges - nodes + components) of the raw graph; the
    /// filtered graph has the same.
    pub components: usize,
    pub cycle_rank: usize,
    /// Whether the empty-space Betti numbers below were computed (`LACUNA_SKELETON_TOPOLOGY`).
    pub has_topology: bool,
    pub b0: usize,
    pub b1: usize,
    pub b2: usize,
    pub euler: i64,
    /// Wall-clock seconds of the skeleton stages.
    pub seconds: f64,
}

fn graph(s: &lacuna_skeleton, which: u32) -> Result<&Graph, CapiError> {
    match which {
        LACUNA_SKELETON_GRAPH_RAW => Ok(&s.skeleton.raw),
        LACUNA_SKELETON_GRAPH_FILTERED => Ok(&s.skeleton.filtered.graph),
        _ => Err(CapiError::invalid(format!(
            "graph {which} is not LACUNA_SKELETON_GRAPH_RAW (0) or LACUNA_SKELETON_GRAPH_FILTERED (1)"
        ))),
    }
}

/// Builds the skeleton of `analysis`'s empty space. The thinning has no parameter (000
/// Algorithm 3); `flags` combines `LACUNA_SKELETON_*`. An analysis built with
/// `LACUNA_ANALYSIS_ALL_MAPS` and a solid outside lends its maps; otherwise they are computed
/// here. `progress` (may be NULL) is called between stages with the fraction done, on the
/// calling thread; returning false cancels (`LACUNA_STATUS_CANCELLED`, nothing written). Runs
/// on the scene context's worker threads. On success `*out_skeleton` receives a new reference.
/// Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_skeleton_build(
    analysis: *const lacuna_analysis,
    flags: u32,
    progress: lacuna_progress_callback,
    user_data: *mut c_void,
    out_skeleton: *mut *mut lacuna_skeleton,
) -> lacuna_status {
    boundary::status("lacuna_skeleton_build", |call| {
        // SAFETY: NULL or a live analysis.
        let a = unsafe { arg(analysis, "analysis") }?;
        let ctx = &a.scene().ctx;
        call.context(ctx);
        let out = out_ptr(out_skeleton, "out_skeleton")?;
        let known = LACUNA_SKELETON_SEQUENTIAL | LACUNA_SKELETON_TOPOLOGY;
        if flags & !known != 0 {
            return Err(CapiError::invalid(format!(
                "flags {flags:#x} has unknown bits {:#x}",
                flags & !known
            )));
        }
        let settings = SkeletonSettings {
            parallel: flags & LACUNA_SKELETON_SEQUENTIAL == 0,
            topology: flags & LACUNA_SKELETON_TOPOLOGY != 0,
        };
        let report = stage_progress(progress, user_data);
        let pool = ctx.pool()?;
        let skeleton = pool.install(|| Skeleton::build(a.inner(), &settings, &report))?;
        // SAFETY: the analysis handle is live (checked above); the skeleton keeps a reference.
        let analysis_ref = unsafe { arc_clone(analysis) };
        let handle = arc_into_handle(lacuna_skeleton {
            analysis: analysis_ref,
            skeleton,
        });
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, handle) };
        Ok(())
    })
}

/// Adds a reference. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_skeleton_retain(skeleton: *const lacuna_skeleton) {
    boundary::value("lacuna_skeleton_retain", (), |_| {
        // SAFETY: NULL or a live skeleton.
        unsafe { arc_retain(skeleton) };
        Ok(())
    })
}

/// Drops a reference; the last one frees the skeleton. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_skeleton_release(skeleton: *const lacuna_skeleton) {
    boundary::value("lacuna_skeleton_release", (), |_| {
        // SAFETY: NULL or a live skeleton; the caller gives up one reference.
        unsafe { arc_release(skeleton) };
        Ok(())
    })
}

/// Sizes, topology and build time of the skeleton. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_skeleton_get_info(
    skeleton: *const lacuna_skeleton,
    out_info: *mut lacuna_skeleton_info,
) -> lacuna_status {
    boundary::status("lacuna_skeleton_get_info", |call| {
        // SAFETY: NULL or a live skeleton.
        let s = unsafe { arg(skeleton, "skeleton") }?;
        call.context(&s.analysis.scene().ctx);
        let out = out_ptr(out_info, "out_info")?;
        let k = &s.skeleton;
        let e = k.empty_space.unwrap_or_default();
        let info = lacuna_skeleton_info {
            raw_nodes: k.raw.nodes.len(),
            raw_edges: k.raw.edges.len(),
            filtered_nodes: k.filtered.graph.nodes.len(),
            filtered_edges: k.filtered.graph.edges.len(),
            components: k.raw.components(),
            cycle_rank: k.raw.cycle_rank(),
            has_topology: k.empty_space.is_some(),
            b0: e.b0,
            b1: e.b1,
            b2: e.b2,
            euler: e.euler,
            seconds: k.total_seconds(),
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, info) };
        Ok(())
    })
}

/// Node `index` of graph `graph` (`LACUNA_SKELETON_GRAPH_*`; 0 <= index < its node count).
/// Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_skeleton_get_node(
    skeleton: *const lacuna_skeleton,
    graph: u32,
    index: usize,
    out_node: *mut lacuna_skeleton_node,
) -> lacuna_status {
    boundary::status("lacuna_skeleton_get_node", |call| {
        // SAFETY: NULL or a live skeleton.
        let s = unsafe { arg(skeleton, "skeleton") }?;
        call.context(&s.analysis.scene().ctx);
        let out = out_ptr(out_node, "out_node")?;
        let g = self::graph(s, graph)?;
        let n = g.nodes.get(index).ok_or_else(|| {
            CapiError::range(format!(
                "node index {index} out of range ({} nodes)",
                g.nodes.len()
            ))
        })?;
        let degree = g
            .edges
            .iter()
            .filter(|e| e[0] as usize == index || e[1] as usize == index)
            .count() as u32;
        let filtered = if graph == LACUNA_SKELETON_GRAPH_RAW {
            s.skeleton.filtered.cluster_of[index]
        } else {
            index as u32
        };
        let node = lacuna_skeleton_node {
            position: n.position.into(),
            radius: n.radius,
            degree,
            filtered,
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, node) };
        Ok(())
    })
}

/// Edge `index` of graph `graph` (0 <= index < its edge count): its two node indices, the
/// smaller first (`out_nodes`: 2 values). Edges are sorted. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_skeleton_get_edge(
    skeleton: *const lacuna_skeleton,
    graph: u32,
    index: usize,
    out_nodes: *mut u32,
) -> lacuna_status {
    boundary::status("lacuna_skeleton_get_edge", |call| {
        // SAFETY: NULL or a live skeleton.
        let s = unsafe { arg(skeleton, "skeleton") }?;
        call.context(&s.analysis.scene().ctx);
        let out = out_ptr(out_nodes, "out_nodes")?;
        let g = self::graph(s, graph)?;
        let e = g.edges.get(index).ok_or_else(|| {
            CapiError::range(format!(
                "edge index {index} out of range ({} edges)",
                g.edges.len()
            ))
        })?;
        // SAFETY: checked non-NULL, writable for 2 values per the contract.
        unsafe { write_out(out.cast::<[u32; 2]>(), *e) };
        Ok(())
    })
}

/// The filtered node of a surface point (000 eq. 151-155): `point` on a surface with normal
/// `normal` (either orientation), seen from `incident` (pointing from the point towards where
/// the path comes from; any length). Writes `LACUNA_INVALID_INDEX` when no empty voxel next to
/// the point maps to a node. A point outside the analysis grid fails with
/// `LACUNA_STATUS_OUT_OF_RANGE`; non-finite vectors and a zero normal are invalid. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_skeleton_map_point(
    skeleton: *const lacuna_skeleton,
    point: *const lacuna_vec3,
    normal: *const lacuna_vec3,
    incident: *const lacuna_vec3,
    out_node: *mut u32,
) -> lacuna_status {
    boundary::status("lacuna_skeleton_map_point", |call| {
        // SAFETY: NULL or a live skeleton.
        let s = unsafe { arg(skeleton, "skeleton") }?;
        call.context(&s.analysis.scene().ctx);
        // SAFETY (all three): NULL or readable.
        let p = unsafe { read_arg(point, "point") }?.finite("point")?;
        let n = unsafe { read_arg(normal, "normal") }?.finite("normal")?;
        let w = unsafe { read_arg(incident, "incident") }?.finite("incident")?;
        let out = out_ptr(out_node, "out_node")?;
        if n.length_squared() == 0.0 {
            return Err(CapiError::invalid("`normal` is the zero vector"));
        }
        if s.skeleton.grid.voxel_at(p).is_none() {
            return Err(CapiError::range(format!(
                "point {p} is outside the analysis grid"
            )));
        }
        let node = s
            .skeleton
            .map_point(p, n, w)
            .unwrap_or(LACUNA_INVALID_INDEX);
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, node) };
        Ok(())
    })
}

/// Writes graph `graph` to the file `path` (UTF-8) as `format` (`LACUNA_SKELETON_FORMAT_*`).
/// Fails with `LACUNA_STATUS_IO` when the file cannot be written. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_skeleton_export(
    skeleton: *const lacuna_skeleton,
    graph: u32,
    format: u32,
    path: *const c_char,
) -> lacuna_status {
    boundary::status("lacuna_skeleton_export", |call| {
        // SAFETY: NULL or a live skeleton.
        let s = unsafe { arg(skeleton, "skeleton") }?;
        call.context(&s.analysis.scene().ctx);
        // SAFETY: NULL or a NUL-terminated string.
        let path = unsafe { str_arg(path, "path") }?;
        let g = self::graph(s, graph)?;
        let title = if graph == LACUNA_SKELETON_GRAPH_RAW {
            "curvilinear skeleton"
        } else {
            "filtered skeleton"
        };
        let text = match format {
            LACUNA_SKELETON_FORMAT_OBJ => skeleton_obj(g, title),
            LACUNA_SKELETON_FORMAT_PLY => skeleton_ply(g, title),
            _ => {
                return Err(CapiError::invalid(format!(
                    "format {format} is not LACUNA_SKELETON_FORMAT_OBJ (0) or LACUNA_SKELETON_FORMAT_PLY (1)"
                )))
            }
        };
        std::fs::write(path, text).map_err(|e| crate::error::Error::io(path, e))?;
        Ok(())
    })
}
