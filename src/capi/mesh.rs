//! `lacuna_mesh`: a triangle mesh description filled from strided host buffers (copied), then
//! added to a scene builder with `lacuna_scene_builder_add_mesh`.

use std::ffi::c_char;

use super::boundary::{self, lacuna_status};
use super::buffer::{arg, box_free, out_ptr, read_strided, str_arg, write_out};
use crate::math::{Vec2, Vec3};
use crate::scene::MeshDesc;

/// A triangle mesh description: positions, optional normals and uvs, triangle indices and
/// material indices, each copied from the host's buffers when set (the host's buffers may be
/// freed right after the call).
///
/// Single owner (`lacuna_mesh_new`/`lacuna_mesh_free`). Not thread-safe: one thread at a time
/// may use a mesh. It can be added to any number of builders, any number of times.
pub struct lacuna_mesh {
    pub(crate) desc: MeshDesc,
}

/// Creates an empty mesh description (no triangles, material 0). Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn lacuna_mesh_new(out_mesh: *mut *mut lacuna_mesh) -> lacuna_status {
    boundary::status("lacuna_mesh_new", |_| {
        let out = out_ptr(out_mesh, "out_mesh")?;
        let mesh = Box::into_raw(Box::new(lacuna_mesh {
            desc: MeshDesc {
                materials: vec![0],
                ..Default::default()
            },
        }));
        // SAFETY: checked non-NULL, writable per the contract.
        unsafe { write_out(out, mesh) };
        Ok(())
    })
}

/// Frees a mesh description. NULL is a no-op.
#[no_mangle]
pub unsafe extern "C" fn lacuna_mesh_free(mesh: *mut lacuna_mesh) {
    boundary::value("lacuna_mesh_free", (), |_| {
        // SAFETY: NULL or a mesh from `lacuna_mesh_new`, not used afterwards.
        unsafe { box_free(mesh) };
        Ok(())
    })
}

/// Runs `f` on the mesh behind a non-NULL handle.
///
/// # Safety
/// `mesh` must be NULL or a live mesh not used by another thread.
unsafe fn with_mesh(
    function: &'static str,
    mesh: *mut lacuna_mesh,
    f: impl FnOnce(&mut MeshDesc) -> super::boundary::CapiResult<()>,
) -> lacuna_status {
    boundary::status(function, |_| {
        // SAFETY: NULL or a live mesh used by this thread only (caller's contract).
        let m = unsafe { mesh.as_mut() }.ok_or_else(|| super::boundary::CapiError::null("mesh"))?;
        f(&mut m.desc)
    })
}

/// Sets the mesh's name (UTF-8, used in error messages). Copied.
#[no_mangle]
pub unsafe extern "C" fn lacuna_mesh_set_name(
    mesh: *mut lacuna_mesh,
    name: *const c_char,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_mesh("lacuna_mesh_set_name", mesh, |m| {
            m.name = str_arg(name, "name")?.to_string();
            Ok(())
        })
    }
}

/// Copies `vertex_count` positions, 3 floats each, found every `byte_stride` bytes from
/// `positions` (0 = packed, 12 bytes). No alignment is required. Values are checked when the
/// mesh is added (they must be finite).
#[no_mangle]
pub unsafe extern "C" fn lacuna_mesh_set_positions(
    mesh: *mut lacuna_mesh,
    positions: *const f32,
    byte_stride: usize,
    vertex_count: usize,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_mesh("lacuna_mesh_set_positions", mesh, |m| {
            let p: Vec<[f32; 3]> =
                read_strided(positions.cast(), byte_stride, vertex_count, "positions")?;
            m.positions = p.into_iter().map(Vec3::from).collect();
            Ok(())
        })
    }
}

/// Copies per-vertex normals, 3 floats each (0 = packed); their count must equal the vertex
/// count when the mesh is added. A count of 0 removes them.
#[no_mangle]
pub unsafe extern "C" fn lacuna_mesh_set_normals(
    mesh: *mut lacuna_mesh,
    normals: *const f32,
    byte_stride: usize,
    count: usize,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_mesh("lacuna_mesh_set_normals", mesh, |m| {
            let n: Vec<[f32; 3]> = read_strided(normals.cast(), byte_stride, count, "normals")?;
            m.normals = n.into_iter().map(Vec3::from).collect();
            Ok(())
        })
    }
}

/// Copies per-vertex texture coordinates, 2 floats each (0 = packed, 8 bytes); their count must
/// equal the vertex count when the mesh is added. A count of 0 removes them.
#[no_mangle]
pub unsafe extern "C" fn lacuna_mesh_set_uvs(
    mesh: *mut lacuna_mesh,
    uvs: *const f32,
    byte_stride: usize,
    count: usize,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_mesh("lacuna_mesh_set_uvs", mesh, |m| {
            let t: Vec<[f32; 2]> = read_strided(uvs.cast(), byte_stride, count, "uvs")?;
            m.uvs = t.into_iter().map(Vec2::from).collect();
            Ok(())
        })
    }
}

/// Copies `triangle_count` triangles, 3 vertex indices (`uint32_t`) each, found every
/// `byte_stride` bytes (0 = packed, 12 bytes). Indices are range-checked when the mesh is added.
/// Triangles are counter-clockwise seen from their front.
#[no_mangle]
pub unsafe extern "C" fn lacuna_mesh_set_indices(
    mesh: *mut lacuna_mesh,
    indices: *const u32,
    byte_stride: usize,
    triangle_count: usize,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_mesh("lacuna_mesh_set_indices", mesh, |m| {
            m.indices = read_strided(indices.cast(), byte_stride, triangle_count, "indices")?;
            Ok(())
        })
    }
}

/// Copies one material index (`uint32_t`) per triangle, found every `byte_stride` bytes
/// (0 = packed). The count must equal the triangle count when the mesh is added; the indices
/// are checked against the builder's materials then.
#[no_mangle]
pub unsafe extern "C" fn lacuna_mesh_set_materials(
    mesh: *mut lacuna_mesh,
    materials: *const u32,
    byte_stride: usize,
    count: usize,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_mesh("lacuna_mesh_set_materials", mesh, |m| {
            if count == 0 {
                return Err(super::boundary::CapiError::invalid(
                    "material count 0: give one per triangle, or use lacuna_mesh_set_material",
                ));
            }
            m.materials = read_strided(materials.cast(), byte_stride, count, "materials")?;
            Ok(())
        })
    }
}

/// Gives every triangle of the mesh material `material` (checked when the mesh is added).
#[no_mangle]
pub unsafe extern "C" fn lacuna_mesh_set_material(
    mesh: *mut lacuna_mesh,
    material: u32,
) -> lacuna_status {
    // SAFETY: forwarded contract.
    unsafe {
        with_mesh("lacuna_mesh_set_material", mesh, |m| {
            m.materials = vec![material];
            Ok(())
        })
    }
}

/// Reads the vertex and triangle counts set so far.
#[no_mangle]
pub unsafe extern "C" fn lacuna_mesh_get_counts(
    mesh: *const lacuna_mesh,
    out_vertex_count: *mut usize,
    out_triangle_count: *mut usize,
) -> lacuna_status {
    boundary::status("lacuna_mesh_get_counts", |_| {
        // SAFETY: NULL or a live mesh.
        let m = unsafe { arg(mesh, "mesh") }?;
        let ov = out_ptr(out_vertex_count, "out_vertex_count")?;
        let ot = out_ptr(out_triangle_count, "out_triangle_count")?;
        // SAFETY: both checked non-NULL, writable per the contract.
        unsafe {
            write_out(ov, m.desc.positions.len());
            write_out(ot, m.desc.indices.len());
        }
        Ok(())
    })
}
