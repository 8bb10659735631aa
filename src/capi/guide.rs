//! `lacuna_skeleton_guide` and `lacuna_guide_query`: skeleton-guided direction sampling for a
//! host's own path tracer, in the shape of Open PGL (docs/capi-conventions.md, rule 17): one immutable guide per
//! scene, one reusable query per worker thread, random numbers from the host, and every sampled
//! direction with the exact density of the whole skeleton mixture.

use std::ffi::c_void;
use std::sync::Arc;

use super::boundary::{self, lacuna_status, CapiError};
use super::buffer::{
    arc_clone, arc_into_handle, arc_release, arc_retain, arg, box_free, out_ptr, write_out,
};
use super::job::stage_progress;
use super::job::{lacuna_progress_callback, lacuna_render_job};
use super::scene::lacuna_scene;
use super::types::lacuna_vec3;
use crate::guide::{GuideQuery, SkeletonGuide};
use crate::integrator::IntegratorSettings;
use crate::math::{Vec2, Vec3};

/// The skeleton guide of a scene (000 chapter 9): the skeleton of its empty space, importance
/// nodes found by light tracing, shortest paths and importance points.
///
/// Refcounted (`lacuna_skeleton_guide_retain`/`_release`); keeps its scene alive. Immutable:
/// every function may be called from any number of threads at once.
pub struct lacuna_skeleton_guide {
    scene: Arc<lacuna_scene>,
    guide: SkeletonGuide,
}

/// The skeleton sampling distribution at one surface point: initialise it at a point, then
/// sample directions and evaluate densities there.
///
/// Single owner (`lacuna_guide_query_new`/`lacuna_guide_query_free`); keeps its guide alive.
/// Not thread-safe: give each worker thread its own query and reuse it from point to point.
pub struct lacuna_guide_query {
    guide: Arc<lacuna_skeleton_guide>,
    query: GuideQuery,
}

/// Figures of a skeleton guide.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct lacuna_skeleton_guide_info {
    /// Nodes of the filtered skeleton, and of the skeleton before filtering.
    pub nodes: u32,
    pub raw_nodes: u32,
    /// Importance nodes kept (the most powerful of those that received light).
    pub importance_nodes: u32,
    /// Nodes with at least one lobe (a path to an importance node).
    pub guided_nodes: u32,
    /// Analysis grid size in voxels.
    pub grid: [u32; 3],
    pub memory_bytes: usize,
    /// Wall-clock time of the whole precomputation.
    pub seconds: f64,
}

/// Builds the skeleton guide of `scene` with the skeleton settings of `settings` (a render job
/// whose `lacuna_render_job_set_skeleton_*` setters chose them, or one a scene file configured,
/// with the options of its integrator name applied over them, as in
/// `"path_skeleton:directions=lobes"`; NULL for the defaults). `progress` (may be NULL) is called
/// between stages on the calling thread; returning false cancels (`LACUNA_STATUS_CANCELLED`). Runs
/// on the scene context's worker threads. On success `*out_guide` receives a new reference.
/// Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_skeleton_guide_build(
    scene: *const lacuna_scene,
    settings: *const lacuna_render_job,
    progress: lacuna_progress_callback,
    user_data: *mut c_void,
    out_guide: *mut *mut lacuna_skeleton_guide,
) -> lacuna_status {
    boundary::status("lacuna_skeleton_guide_build", |call| {
        // SAFETY: NULL or a live scene.
        let s = unsafe { arg(scene, "scene") }?;
        call.context(&s.ctx);
        let out = out_ptr(out_guide, "out_guide")?;
        let skeleton = if settings.is_null() {
            let mut defaults = IntegratorSettings::default();
            defaults.apply_file(&s.settings)?;
            defaults.skeleton
        } else {
            // SAFETY: a live job (checked non-NULL).
            unsafe { arg(settings, "settings") }?.skeleton_settings()?
        };
        let report = stage_progress(progress, user_data);
        // The camera a job on this scene renders with by default: the scene's, else the
        // automatic framing (square image), so the training sees that view.
        let camera = s
            .scene
            .camera()
            .copied()
            .unwrap_or_else(|| crate::scene::auto_camera(s.scene.bounds(), 1.0));
        let pool = s.ctx.pool()?;
        let guide =
            pool.install(|| SkeletonGuide::build(&s.scene, Some(&camera), &skeleton, &report))?;
        // SAFETY: the scene handle is live (checked above); the guide keeps one reference.
        let scene_ref = unsafe { arc_clone(scene) };
        let handle = arc_into_handle(lacuna_skeleton_guide {
            scene: scene_ref,
            guide,
        });
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, handle) };
        Ok(())
    })
}

/// Adds a reference. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_skeleton_guide_retain(guide: *const lacuna_skeleton_guide) {
    boundary::value("lacuna_skeleton_guide_retain", (), |_| {
        // SAFETY: NULL or a live guide.
        unsafe { arc_retain(guide) };
        Ok(())
    })
}

/// Drops a reference; the last one frees the guide. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_skeleton_guide_release(guide: *const lacuna_skeleton_guide) {
    boundary::value("lacuna_skeleton_guide_release", (), |_| {
        // SAFETY: NULL or a live guide; the caller gives up one reference.
        unsafe { arc_release(guide) };
        Ok(())
    })
}

/// Writes the guide's figures to `*out_info`. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_skeleton_guide_get_info(
    guide: *const lacuna_skeleton_guide,
    out_info: *mut lacuna_skeleton_guide_info,
) -> lacuna_status {
    boundary::status("lacuna_skeleton_guide_get_info", |call| {
        // SAFETY: NULL or a live guide.
        let g = unsafe { arg(guide, "guide") }?;
        call.context(&g.scene.ctx);
        let out = out_ptr(out_info, "out_info")?;
        let s = &g.guide;
        let info = lacuna_skeleton_guide_info {
            nodes: s.node_count() as u32,
            raw_nodes: s.raw_node_count() as u32,
            importance_nodes: s.importance_nodes().len() as u32,
            guided_nodes: s.guided_node_count() as u32,
            grid: s.grid().dims.map(|d| d as u32),
            memory_bytes: s.memory_bytes(),
            seconds: s.total_seconds(),
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, info) };
        Ok(())
    })
}

/// Creates a query on `guide` (kept alive by the query), unguided until initialised.
/// Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_guide_query_new(
    guide: *const lacuna_skeleton_guide,
    out_query: *mut *mut lacuna_guide_query,
) -> lacuna_status {
    boundary::status("lacuna_guide_query_new", |call| {
        // SAFETY: NULL or a live guide.
        let g = unsafe { arg(guide, "guide") }?;
        call.context(&g.scene.ctx);
        let out = out_ptr(out_query, "out_query")?;
        let query = Box::new(lacuna_guide_query {
            // SAFETY: a live guide handle (checked above).
            guide: unsafe { arc_clone(guide) },
            query: GuideQuery::new(),
        });
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, Box::into_raw(query)) };
        Ok(())
    })
}

/// Frees a query. NULL is a no-op.
#[no_mangle]
pub unsafe extern "C" fn lacuna_guide_query_free(query: *mut lacuna_guide_query) {
    boundary::value("lacuna_guide_query_free", (), |_| {
        // SAFETY: NULL or a query from `lacuna_guide_query_new`, not used afterwards.
        unsafe { box_free(query) };
        Ok(())
    })
}

/// Sets the query up at surface point `position` with geometric normal `normal` (non-zero,
/// either orientation) and incident direction `incident` (non-zero, pointing from the point
/// back to where the path came from). `*out_guided` (may be NULL) says whether any skeleton
/// lobe applies there; where none does (no path to light along the skeleton, every importance
/// point below the surface or hidden from the point), sample the BSDF alone. Do not guide at
/// delta BSDFs (perfect mirrors and glass): no mixture with a Dirac lobe has a density.
#[no_mangle]
pub unsafe extern "C" fn lacuna_guide_query_init(
    query: *mut lacuna_guide_query,
    position: lacuna_vec3,
    normal: lacuna_vec3,
    incident: lacuna_vec3,
    out_guided: *mut bool,
) -> lacuna_status {
    boundary::status("lacuna_guide_query_init", |call| {
        // SAFETY: NULL or a live query owned by the caller, used by one thread at a time.
        let q = unsafe { query.as_mut() }.ok_or_else(|| CapiError::null("query"))?;
        call.context(&q.guide.scene.ctx);
        let p = position.finite("position")?;
        let n = unit(normal, "normal")?;
        let w = unit(incident, "incident")?;
        // The host's point carries its own rounding error, unknown here: a relative bound of
        // a few ulps of the coordinates keeps the visibility test's ray off the surface.
        let p_error = p.abs() * (8.0 * f32::EPSILON) + Vec3::splat(f32::MIN_POSITIVE);
        let g = &q.guide;
        q.query.init(&g.guide, &g.scene.scene, p, p_error, n, w);
        if !out_guided.is_null() {
            // SAFETY: non-NULL, writable per the contract.
            unsafe { write_out(out_guided, q.query.guiding_probability() > 0.0) };
        }
        Ok(())
    })
}

fn unit(v: lacuna_vec3, name: &str) -> Result<Vec3, CapiError> {
    let v = v.finite(name)?;
    let u = v.normalize_or_zero();
    if u == Vec3::ZERO {
        return Err(CapiError::invalid(format!(
            "`{name}` must be a non-zero vector"
        )));
    }
    Ok(u)
}

/// Probability of sampling the skeleton instead of the BSDF at the current point: the
/// guide's `c_skel` where the query is guided, 0 elsewhere (and before any init). A host's
/// one-sample MIS draws the skeleton with this probability `c` and the BSDF otherwise, and
/// divides by `c * p_skel + (1 - c) * p_bsdf` whichever it drew (000 eq. 168-170).
#[no_mangle]
pub unsafe extern "C" fn lacuna_guide_query_guiding_probability(
    query: *const lacuna_guide_query,
    out_probability: *mut f32,
) -> lacuna_status {
    boundary::status("lacuna_guide_query_guiding_probability", |call| {
        // SAFETY: NULL or a live query.
        let q = unsafe { arg(query, "query") }?;
        call.context(&q.guide.scene.ctx);
        let out = out_ptr(out_probability, "out_probability")?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, q.query.guiding_probability()) };
        Ok(())
    })
}

fn unit_interval(u: f32, name: &str) -> Result<f32, CapiError> {
    if (0.0..1.0).contains(&u) {
        Ok(u)
    } else {
        Err(CapiError::invalid(format!(
            "`{name}` {u} must be in [0, 1)"
        )))
    }
}

/// Samples the skeleton mixture at the current point from the host's random numbers `u0`
/// (picks a lobe), `u1`, `u2` (the direction in it), each in [0, 1): writes the unit direction
/// and its solid-angle density under the whole mixture (the value
/// `lacuna_guide_query_pdf` gives). `LACUNA_STATUS_INVALID_OPERATION` when the query is not
/// guided at its point.
#[no_mangle]
pub unsafe extern "C" fn lacuna_guide_query_sample(
    query: *const lacuna_guide_query,
    u0: f32,
    u1: f32,
    u2: f32,
    out_direction: *mut lacuna_vec3,
    out_pdf: *mut f32,
) -> lacuna_status {
    boundary::status("lacuna_guide_query_sample", |call| {
        // SAFETY: NULL or a live query.
        let q = unsafe { arg(query, "query") }?;
        call.context(&q.guide.scene.ctx);
        let out_d = out_ptr(out_direction, "out_direction")?;
        let out_p = out_ptr(out_pdf, "out_pdf")?;
        let u = [
            unit_interval(u0, "u0")?,
            unit_interval(u1, "u1")?,
            unit_interval(u2, "u2")?,
        ];
        if q.query.guiding_probability() == 0.0 {
            return Err(CapiError::operation(
                "the query is not guided at its point: sample the BSDF alone",
            ));
        }
        let (w, pdf) = q
            .query
            .sample(u[0], Vec2::new(u[1], u[2]))
            .ok_or_else(|| CapiError::operation("no direction for these random numbers"))?;
        // SAFETY: both checked non-NULL, writable per the contract.
        unsafe {
            write_out(
                out_d,
                lacuna_vec3 {
                    x: w.x,
                    y: w.y,
                    z: w.z,
                },
            );
            write_out(out_p, pdf);
        }
        Ok(())
    })
}

/// Solid-angle density of the skeleton mixture at the current point in direction `direction`
/// (non-zero; normalised here): 0 where no lobe reaches, and 0 everywhere when not guided.
#[no_mangle]
pub unsafe extern "C" fn lacuna_guide_query_pdf(
    query: *const lacuna_guide_query,
    direction: lacuna_vec3,
    out_pdf: *mut f32,
) -> lacuna_status {
    boundary::status("lacuna_guide_query_pdf", |call| {
        // SAFETY: NULL or a live query.
        let q = unsafe { arg(query, "query") }?;
        call.context(&q.guide.scene.ctx);
        let out = out_ptr(out_pdf, "out_pdf")?;
        let w = unit(direction, "direction")?;
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, q.query.pdf(w)) };
        Ok(())
    })
}
