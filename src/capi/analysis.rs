//! `lacuna_analysis`: the empty-space analysis of a committed scene (voxelization, distance and
//! opening maps, opening-forest regions and portals), with point queries and portal sampling.

use std::ffi::c_void;
use std::sync::Arc;

use super::boundary::{self, lacuna_status, CapiError};
use super::buffer::{
    arc_clone, arc_into_handle, arc_release, arc_retain, arg, out_ptr, read_arg, write_out,
};
use super::job::lacuna_progress_callback;
use super::job::stage_progress;
use super::scene::lacuna_scene;
use super::types::{lacuna_vec3, LACUNA_INVALID_INDEX};
use crate::analysis::{Analysis, AnalysisSettings, Outside, Resolution};
use crate::math::Vec2;

/// Treat the inside of closed objects as occupied.
pub const LACUNA_ANALYSIS_FILL_INTERIORS: u32 = 1;
/// Treat the outside of the grid as empty (default: solid).
pub const LACUNA_ANALYSIS_OUTSIDE_EMPTY: u32 = 2;
/// Also compute the L1 and Euclidean distance maps, the L1 opening and the decenterness map.
pub const LACUNA_ANALYSIS_ALL_MAPS: u32 = 4;

/// The analysed empty space of a scene.
///
/// Refcounted (`lacuna_analysis_retain`/`lacuna_analysis_release`); keeps its scene alive.
/// Immutable: every function may be called from any number of threads at once.
pub struct lacuna_analysis {
    scene: Arc<lacuna_scene>,
    analysis: Analysis,
}

impl lacuna_analysis {
    pub(crate) fn scene(&self) -> &lacuna_scene {
        &self.scene
    }

    pub(crate) fn inner(&self) -> &Analysis {
        &self.analysis
    }
}

/// One opening-forest region.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct lacuna_region {
    /// Opening (chessboard radius, in voxels) of the region's root voxels.
    pub opening: u32,
    pub root_voxels: u32,
    pub voxels: u64,
    /// Mean position of its voxels (world).
    pub centroid: lacuna_vec3,
}

/// The voxel faces separating two neighbouring regions `region_a < region_b`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct lacuna_portal {
    pub region_a: u32,
    pub region_b: u32,
    pub faces: u32,
    /// World area.
    pub area: f32,
    /// Area-weighted mean of the face centres (world).
    pub center: lacuna_vec3,
    /// Mean normal from region a into region b (zero when the faces cancel out).
    pub normal: lacuna_vec3,
}

/// Bytes held by each structure of an analysis.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct lacuna_analysis_memory {
    pub occupancy: usize,
    pub distance: usize,
    pub opening: usize,
    pub labels: usize,
    pub portals: usize,
    pub extra_maps: usize,
    pub total: usize,
}

/// Analyses the empty space of `scene`. The grid has `longest_axis_voxels` voxels along the
/// longest side of the scene bounds, or, when that is 0, cubic voxels of edge `voxel_size`
/// (world units). `memory_budget_bytes` (0 = 4 GiB) refuses grids whose structures would need
/// more (`LACUNA_STATUS_OVER_BUDGET`, nothing allocated). `flags` combines
/// `LACUNA_ANALYSIS_*`. `progress` (may be NULL) is called between stages with the fraction
/// done, on the calling thread; returning false cancels (`LACUNA_STATUS_CANCELLED`). Runs on the
/// scene context's worker threads. On success `*out_analysis` receives a new reference.
/// Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_analysis_build(
    scene: *const lacuna_scene,
    longest_axis_voxels: u32,
    voxel_size: f32,
    memory_budget_bytes: u64,
    flags: u32,
    progress: lacuna_progress_callback,
    user_data: *mut c_void,
    out_analysis: *mut *mut lacuna_analysis,
) -> lacuna_status {
    boundary::status("lacuna_analysis_build", |call| {
        // SAFETY: NULL or a live scene.
        let s = unsafe { arg(scene, "scene") }?;
        call.context(&s.ctx);
        let out = out_ptr(out_analysis, "out_analysis")?;
        let known = LACUNA_ANALYSIS_FILL_INTERIORS
            | LACUNA_ANALYSIS_OUTSIDE_EMPTY
            | LACUNA_ANALYSIS_ALL_MAPS;
        if flags & !known != 0 {
            return Err(CapiError::invalid(format!(
                "flags {flags:#x} has unknown bits {:#x}",
                flags & !known
            )));
        }
        let resolution = if longest_axis_voxels > 0 {
            Resolution::LongestAxis(longest_axis_voxels)
        } else if voxel_size.is_finite() && voxel_size > 0.0 {
            Resolution::VoxelSize(voxel_size as f64)
        } else {
            return Err(CapiError::invalid(format!(
                "give longest_axis_voxels > 0 or a finite voxel_size > 0 (got {longest_axis_voxels} and {voxel_size})"
            )));
        };
        let settings = AnalysisSettings {
            resolution,
            fill_interiors: flags & LACUNA_ANALYSIS_FILL_INTERIORS != 0,
            outside: if flags & LACUNA_ANALYSIS_OUTSIDE_EMPTY != 0 {
                Outside::Empty
            } else {
                Outside::Solid
            },
            all_maps: flags & LACUNA_ANALYSIS_ALL_MAPS != 0,
            memory_budget: if memory_budget_bytes == 0 {
                4 << 30
            } else {
                memory_budget_bytes
            },
            ..Default::default()
        };
        let report = stage_progress(progress, user_data);
        let pool = s.ctx.pool()?;
        let analysis = pool.install(|| Analysis::build(&s.scene, &settings, &report))?;
        // SAFETY: the scene handle is live (checked above); the analysis keeps one reference.
        let scene_ref = unsafe { arc_clone(scene) };
        let handle = arc_into_handle(lacuna_analysis {
            scene: scene_ref,
            analysis,
        });
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, handle) };
        Ok(())
    })
}

/// Adds a reference. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_analysis_retain(analysis: *const lacuna_analysis) {
    boundary::value("lacuna_analysis_retain", (), |_| {
        // SAFETY: NULL or a live analysis.
        unsafe { arc_retain(analysis) };
        Ok(())
    })
}

/// Drops a reference; the last one frees the analysis. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_analysis_release(analysis: *const lacuna_analysis) {
    boundary::value("lacuna_analysis_release", (), |_| {
        // SAFETY: NULL or a live analysis; the caller gives up one reference.
        unsafe { arc_release(analysis) };
        Ok(())
    })
}

/// Grid size in voxels (`out_dims`: 3 values x, y, z), voxel edge length and grid origin
/// (world). Any output may be NULL when not wanted. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_analysis_grid(
    analysis: *const lacuna_analysis,
    out_dims: *mut u32,
    out_voxel_size: *mut f32,
    out_origin: *mut lacuna_vec3,
) -> lacuna_status {
    boundary::status("lacuna_analysis_grid", |call| {
        // SAFETY: NULL or a live analysis.
        let a = unsafe { arg(analysis, "analysis") }?;
        call.context(&a.scene.ctx);
        let g = &a.analysis.grid;
        // SAFETY (all three): NULL is skipped; otherwise writable per the contract.
        if !out_dims.is_null() {
            unsafe { write_out(out_dims.cast::<[u32; 3]>(), g.dims.map(|d| d as u32)) };
        }
        if !out_voxel_size.is_null() {
            unsafe { write_out(out_voxel_size, g.voxel_size as f32) };
        }
        if !out_origin.is_null() {
            unsafe {
                write_out(
                    out_origin,
                    lacuna_vec3 {
                        x: g.origin[0] as f32,
                        y: g.origin[1] as f32,
                        z: g.origin[2] as f32,
                    },
                )
            };
        }
        Ok(())
    })
}

/// The 26-opening (voxels) and region label at world point `point`. A point in an occupied
/// voxel gets opening 0 and label `LACUNA_INVALID_INDEX`; a point outside the grid fails with
/// `LACUNA_STATUS_OUT_OF_RANGE`. Either output may be NULL. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_analysis_query(
    analysis: *const lacuna_analysis,
    point_world: *const lacuna_vec3,
    out_opening: *mut u32,
    out_label: *mut u32,
) -> lacuna_status {
    boundary::status("lacuna_analysis_query", |call| {
        // SAFETY: NULL or a live analysis.
        let a = unsafe { arg(analysis, "analysis") }?;
        call.context(&a.scene.ctx);
        // SAFETY: NULL or readable.
        let p = unsafe { read_arg(point_world, "point") }?.finite("point")?;
        let voxel =
            a.analysis.grid.voxel_at(p).ok_or_else(|| {
                CapiError::range(format!("point {p} is outside the analysis grid"))
            })?;
        let opening = a.analysis.opening.opening[voxel];
        let label = a.analysis.labels[voxel];
        // SAFETY: NULL is skipped; otherwise writable per the contract.
        if !out_opening.is_null() {
            unsafe { write_out(out_opening, opening) };
        }
        if !out_label.is_null() {
            unsafe {
                write_out(
                    out_label,
                    if label == crate::analysis::NO_REGION {
                        LACUNA_INVALID_INDEX
                    } else {
                        label
                    },
                )
            };
        }
        Ok(())
    })
}

/// Numbers of regions and portals. Either output may be NULL. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_analysis_counts(
    analysis: *const lacuna_analysis,
    out_regions: *mut usize,
    out_portals: *mut usize,
) -> lacuna_status {
    boundary::status("lacuna_analysis_counts", |call| {
        // SAFETY: NULL or a live analysis.
        let a = unsafe { arg(analysis, "analysis") }?;
        call.context(&a.scene.ctx);
        // SAFETY: NULL is skipped; otherwise writable per the contract.
        if !out_regions.is_null() {
            unsafe { write_out(out_regions, a.analysis.regions.len()) };
        }
        if !out_portals.is_null() {
            unsafe { write_out(out_portals, a.analysis.portals.len()) };
        }
        Ok(())
    })
}

/// Region `index` (0 <= index < the region count). Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_analysis_region(
    analysis: *const lacuna_analysis,
    index: usize,
    out_region: *mut lacuna_region,
) -> lacuna_status {
    boundary::status("lacuna_analysis_region", |call| {
        // SAFETY: NULL or a live analysis.
        let a = unsafe { arg(analysis, "analysis") }?;
        call.context(&a.scene.ctx);
        let out = out_ptr(out_region, "out_region")?;
        let r = a.analysis.regions.get(index).ok_or_else(|| {
            CapiError::range(format!(
                "region index {index} out of range ({} regions)",
                a.analysis.regions.len()
            ))
        })?;
        let region = lacuna_region {
            opening: r.opening,
            root_voxels: r.root_voxels,
            voxels: r.voxels,
            centroid: r.centroid.into(),
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, region) };
        Ok(())
    })
}

/// Portal `index` (0 <= index < the portal count). Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_analysis_portal(
    analysis: *const lacuna_analysis,
    index: usize,
    out_portal: *mut lacuna_portal,
) -> lacuna_status {
    boundary::status("lacuna_analysis_portal", |call| {
        // SAFETY: NULL or a live analysis.
        let a = unsafe { arg(analysis, "analysis") }?;
        call.context(&a.scene.ctx);
        let out = out_ptr(out_portal, "out_portal")?;
        let p = a.analysis.portals.get(index).ok_or_else(|| {
            CapiError::range(format!(
                "portal index {index} out of range ({} portals)",
                a.analysis.portals.len()
            ))
        })?;
        let portal = lacuna_portal {
            region_a: p.regions.0,
            region_b: p.regions.1,
            faces: p.faces.len() as u32,
            area: p.area,
            center: p.center.into(),
            normal: p.normal.into(),
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, portal) };
        Ok(())
    })
}

/// Samples a point uniformly on portal `index` with random numbers `u` (face choice) and
/// `u1`, `u2` (position on the face), all in [0, 1): writes the point, the face normal (from
/// region a into region b) and the density with respect to area (1 / portal area). Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_analysis_sample_portal(
    analysis: *const lacuna_analysis,
    index: usize,
    u: f32,
    u1: f32,
    u2: f32,
    out_point: *mut lacuna_vec3,
    out_normal: *mut lacuna_vec3,
    out_pdf_area: *mut f32,
) -> lacuna_status {
    boundary::status("lacuna_analysis_sample_portal", |call| {
        // SAFETY: NULL or a live analysis.
        let a = unsafe { arg(analysis, "analysis") }?;
        call.context(&a.scene.ctx);
        for (name, v) in [("u", u), ("u1", u1), ("u2", u2)] {
            if !(0.0..1.0).contains(&v) {
                return Err(CapiError::invalid(format!(
                    "{name} = {v} must be in [0, 1)"
                )));
            }
        }
        let (op, on, opdf) = (
            out_ptr(out_point, "out_point")?,
            out_ptr(out_normal, "out_normal")?,
            out_ptr(out_pdf_area, "out_pdf_area")?,
        );
        if index >= a.analysis.portals.len() {
            return Err(CapiError::range(format!(
                "portal index {index} out of range ({} portals)",
                a.analysis.portals.len()
            )));
        }
        let (p, n, pdf) = a.analysis.sample_portal(index, u, Vec2::new(u1, u2))?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe {
            write_out(op, p.into());
            write_out(on, n.into());
            write_out(opdf, pdf);
        }
        Ok(())
    })
}

/// Bytes held by each structure, and the analysis's total build time in seconds (either
/// output may be NULL). Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_analysis_stats(
    analysis: *const lacuna_analysis,
    out_memory: *mut lacuna_analysis_memory,
    out_seconds: *mut f64,
) -> lacuna_status {
    boundary::status("lacuna_analysis_stats", |call| {
        // SAFETY: NULL or a live analysis.
        let a = unsafe { arg(analysis, "analysis") }?;
        call.context(&a.scene.ctx);
        let m = a.analysis.memory();
        // SAFETY: NULL is skipped; otherwise writable per the contract.
        if !out_memory.is_null() {
            unsafe {
                write_out(
                    out_memory,
                    lacuna_analysis_memory {
                        occupancy: m.occupancy,
                        distance: m.distance,
                        opening: m.opening,
                        labels: m.labels,
                        portals: m.portals,
                        extra_maps: m.extra_maps,
                        total: m.total(),
                    },
                )
            };
        }
        if !out_seconds.is_null() {
            unsafe { write_out(out_seconds, a.analysis.total_seconds()) };
        }
        Ok(())
    })
}
