//! `lacuna_scene`: the committed, immutable scene, and ray queries on it.

use std::sync::Arc;

use super::boundary::{self, lacuna_status, CapiError, CapiResult};
use super::buffer::{arc_release, arc_retain, arg, out_ptr, read_arg, read_strided, write_out};
use super::context::lacuna_context;
use super::types::*;
use crate::geometry::{Hit, Ray};
use crate::math::Vec3;
use crate::scene::{RenderSettingsFile, Scene};

/// A committed scene: immutable geometry, materials, lights, camera and acceleration
/// structure.
///
/// Refcounted (`lacuna_scene_retain`/`lacuna_scene_release`); it keeps its context alive, and
/// render jobs and films keep it alive. Thread-safe: every function taking a
/// `const lacuna_scene*` may be called from any number of threads at once.
pub struct lacuna_scene {
    pub(crate) ctx: Arc<lacuna_context>,
    pub(crate) scene: Scene,
    pub(crate) settings: RenderSettingsFile,
    pub(crate) label: String,
    /// Global index of each mesh's first triangle.
    mesh_first: Vec<u32>,
}

impl lacuna_scene {
    pub(crate) fn new(
        ctx: Arc<lacuna_context>,
        scene: Scene,
        settings: RenderSettingsFile,
        label: String,
    ) -> Self {
        let mut first = 0u32;
        let mesh_first = scene
            .meshes()
            .iter()
            .map(|m| {
                let f = first;
                first += m.indices.len() as u32;
                f
            })
            .collect();
        lacuna_scene {
            ctx,
            scene,
            settings,
            label,
            mesh_first,
        }
    }

    fn hit_to_c(&self, hit: Option<Hit>) -> lacuna_hit {
        let Some(h) = hit else {
            return lacuna_hit::MISS;
        };
        // The last mesh whose first triangle is <= h.triangle (empty meshes share a start).
        let mesh = self.mesh_first.partition_point(|&f| f <= h.triangle) - 1;
        let n = self.scene.geometric_normal(h.triangle);
        lacuna_hit {
            t: h.t,
            u: h.b1,
            v: h.b2,
            triangle: h.triangle,
            mesh: mesh as u32,
            mesh_triangle: h.triangle - self.mesh_first[mesh],
            geometric_normal: n.to_array(),
        }
    }
}

/// Checks a ray from C; `index` names it in a batch.
fn ray_from_c(r: &lacuna_ray, index: Option<usize>) -> CapiResult<Ray> {
    let which = || index.map_or("ray".to_string(), |i| format!("rays[{i}]"));
    let origin = Vec3::from(r.origin);
    let dir = Vec3::from(r.direction);
    if !origin.is_finite() {
        return Err(CapiError::invalid(format!(
            "{} origin {origin} must be finite",
            which()
        )));
    }
    if !dir.is_finite() || dir == Vec3::ZERO {
        return Err(CapiError::invalid(format!(
            "{} direction {dir} must be finite and non-zero",
            which()
        )));
    }
    if r.tmax.is_nan() || r.tmax < 0.0 {
        return Err(CapiError::invalid(format!(
            "{} tmax {} must be >= 0 (infinity allowed)",
            which(),
            r.tmax
        )));
    }
    if r.flags != 0 {
        return Err(CapiError::invalid(format!(
            "{} flags {:#x} must be 0 (reserved)",
            which(),
            r.flags
        )));
    }
    Ok(Ray::new(origin, dir, r.tmax))
}

/// Fills `*ray` with defaults: origin 0, direction +Z, tmax = +infinity, flags 0. NULL is a
/// no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_ray_init(ray: *mut lacuna_ray) {
    boundary::value("lacuna_ray_init", (), |_| {
        if !ray.is_null() {
            // SAFETY: non-NULL and writable per the contract.
            unsafe {
                write_out(
                    ray,
                    lacuna_ray {
                        origin: [0.0; 3],
                        tmax: f32::INFINITY,
                        direction: [0.0, 0.0, 1.0],
                        flags: 0,
                    },
                )
            };
        }
        Ok(())
    })
}

/// Fills `*hit` as a miss (indices `LACUNA_INVALID_INDEX`, t = +infinity). NULL is a no-op.
/// Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_hit_init(hit: *mut lacuna_hit) {
    boundary::value("lacuna_hit_init", (), |_| {
        if !hit.is_null() {
            // SAFETY: non-NULL and writable per the contract.
            unsafe { write_out(hit, lacuna_hit::MISS) };
        }
        Ok(())
    })
}

/// Adds a reference to `scene`. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_retain(scene: *const lacuna_scene) {
    boundary::value("lacuna_scene_retain", (), |_| {
        // SAFETY: NULL or a live scene.
        unsafe { arc_retain(scene) };
        Ok(())
    })
}

/// Drops a reference to `scene`; the last one destroys it. NULL is a no-op. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_release(scene: *const lacuna_scene) {
    boundary::value("lacuna_scene_release", (), |_| {
        // SAFETY: NULL or a live scene; the caller gives up one reference.
        unsafe { arc_release(scene) };
        Ok(())
    })
}

/// Finds the closest hit of `*ray` in (0, tmax) and writes it to `*out_hit` (a miss is written
/// as `lacuna_hit_init` does). Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_intersect(
    scene: *const lacuna_scene,
    ray: *const lacuna_ray,
    out_hit: *mut lacuna_hit,
) -> lacuna_status {
    boundary::status("lacuna_scene_intersect", |call| {
        // SAFETY: NULL or a live scene.
        let s = unsafe { arg(scene, "scene") }?;
        call.context(&s.ctx);
        // SAFETY: NULL or a readable ray.
        let r = ray_from_c(&unsafe { read_arg(ray, "ray") }?, None)?;
        let out = out_ptr(out_hit, "out_hit")?;
        let hit = s.hit_to_c(s.scene.intersect_hit(&r));
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, hit) };
        Ok(())
    })
}

/// Tells whether anything lies on `*ray` in (0, tmax): writes true to `*out_occluded` if so.
/// Faster than `lacuna_scene_intersect` (stops at the first hit found). Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_occluded(
    scene: *const lacuna_scene,
    ray: *const lacuna_ray,
    out_occluded: *mut bool,
) -> lacuna_status {
    boundary::status("lacuna_scene_occluded", |call| {
        // SAFETY: NULL or a live scene.
        let s = unsafe { arg(scene, "scene") }?;
        call.context(&s.ctx);
        // SAFETY: NULL or a readable ray.
        let r = ray_from_c(&unsafe { read_arg(ray, "ray") }?, None)?;
        let out = out_ptr(out_occluded, "out_occluded")?;
        let occluded = s.scene.occluded(&r);
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, occluded) };
        Ok(())
    })
}

/// Checks a batch's arguments and reads its rays.
///
/// # Safety
/// As for the batch functions.
unsafe fn read_rays(
    rays: *const lacuna_ray,
    ray_stride: usize,
    count: usize,
) -> CapiResult<Vec<Ray>> {
    // SAFETY: forwarded contract: `count` rays every `ray_stride` bytes are readable.
    let raw: Vec<lacuna_ray> = unsafe { read_strided(rays.cast(), ray_stride, count, "rays") }?;
    raw.iter()
        .enumerate()
        .map(|(i, r)| ray_from_c(r, Some(i)))
        .collect()
}

/// Checks an output array of `count` elements of `size` bytes every `stride` bytes.
fn out_array<T>(ptr: *mut T, stride: usize, count: usize, name: &str) -> CapiResult<usize> {
    let size = std::mem::size_of::<T>();
    let stride = if stride == 0 { size } else { stride };
    if stride < size {
        return Err(CapiError::invalid(format!(
            "`{name}` stride {stride} bytes is smaller than one element ({size} bytes)"
        )));
    }
    if count > 0 && ptr.is_null() {
        return Err(CapiError::null(name));
    }
    if count > 0 {
        (count - 1)
            .checked_mul(stride)
            .and_then(|s| s.checked_add(size))
            .and_then(|s| (ptr as usize).checked_add(s))
            .ok_or_else(|| {
                CapiError::range(format!(
                    "`{name}`: {count} elements every {stride} bytes exceed the address space"
                ))
            })?;
    }
    Ok(stride)
}

/// Closest hits of `count` rays, found every `ray_stride` bytes from `rays` (0 = packed),
/// written to `hits` every `hit_stride` bytes (0 = packed). Runs on the context's worker
/// threads. Every ray is checked before any is traced; on failure nothing is written. A count
/// of 0 accepts NULL arrays. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_intersect_batch(
    scene: *const lacuna_scene,
    rays: *const lacuna_ray,
    ray_stride: usize,
    count: usize,
    hits: *mut lacuna_hit,
    hit_stride: usize,
) -> lacuna_status {
    boundary::status("lacuna_scene_intersect_batch", |call| {
        // SAFETY: NULL or a live scene.
        let s = unsafe { arg(scene, "scene") }?;
        call.context(&s.ctx);
        let hs = out_array(hits, hit_stride, count, "hits")?;
        // SAFETY: forwarded contract.
        let rays = unsafe { read_rays(rays, ray_stride, count) }?;
        let mut found = vec![None; rays.len()];
        s.ctx
            .pool()?
            .install(|| s.scene.bvh().intersect_batch(&rays, &mut found));
        for (i, h) in found.into_iter().enumerate() {
            // SAFETY: `hits` holds `count` elements every `hs` bytes (checked above and
            // promised by the caller); unaligned writes need no alignment.
            unsafe {
                write_out(
                    hits.cast::<u8>().add(i * hs).cast::<lacuna_hit>(),
                    s.hit_to_c(h),
                )
            };
        }
        Ok(())
    })
}

/// Occlusion of `count` rays (see `lacuna_scene_occluded`), written to `out_occluded`, one
/// `bool` each, packed. Runs on the context's worker threads. Every ray is checked before any
/// is traced; on failure nothing is written. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_occluded_batch(
    scene: *const lacuna_scene,
    rays: *const lacuna_ray,
    ray_stride: usize,
    count: usize,
    out_occluded: *mut bool,
) -> lacuna_status {
    boundary::status("lacuna_scene_occluded_batch", |call| {
        // SAFETY: NULL or a live scene.
        let s = unsafe { arg(scene, "scene") }?;
        call.context(&s.ctx);
        out_array(out_occluded, 0, count, "out_occluded")?;
        // SAFETY: forwarded contract.
        let rays = unsafe { read_rays(rays, ray_stride, count) }?;
        let mut occluded = vec![false; rays.len()];
        s.ctx
            .pool()?
            .install(|| s.scene.bvh().occluded_batch(&rays, &mut occluded));
        for (i, o) in occluded.into_iter().enumerate() {
            // SAFETY: `out_occluded` holds `count` bools (checked non-NULL above, size
            // promised by the caller).
            unsafe { write_out(out_occluded.add(i), o) };
        }
        Ok(())
    })
}

/// Writes the bytes held by each structure of the scene to `*out_report`. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_get_memory_report(
    scene: *const lacuna_scene,
    out_report: *mut lacuna_memory_report,
) -> lacuna_status {
    boundary::status("lacuna_scene_get_memory_report", |call| {
        // SAFETY: NULL or a live scene.
        let s = unsafe { arg(scene, "scene") }?;
        call.context(&s.ctx);
        let out = out_ptr(out_report, "out_report")?;
        let m = s.scene.memory();
        let report = lacuna_memory_report {
            meshes: m.meshes,
            bvh: m.bvh,
            textures: m.textures,
            lights: m.lights,
            total: m.total(),
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, report) };
        Ok(())
    })
}

/// Writes the scene's figures (counts, bounds, build time) to `*out_stats`. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_scene_get_stats(
    scene: *const lacuna_scene,
    out_stats: *mut lacuna_scene_stats,
) -> lacuna_status {
    boundary::status("lacuna_scene_get_stats", |call| {
        // SAFETY: NULL or a live scene.
        let s = unsafe { arg(scene, "scene") }?;
        call.context(&s.ctx);
        let out = out_ptr(out_stats, "out_stats")?;
        let st = s.scene.stats();
        let b = s.scene.bounds();
        let stats = lacuna_scene_stats {
            meshes: s.scene.meshes().len(),
            triangles: st.triangles,
            degenerate_triangles_skipped: st.degenerate_triangles_skipped,
            lights: s.scene.lights().len(),
            materials: s.scene.materials().len(),
            bvh_nodes: st.bvh_nodes,
            bvh_build_seconds: st.bvh_seconds,
            bounds_min: b.min.into(),
            bounds_max: b.max.into(),
        };
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, stats) };
        Ok(())
    })
}
