//! Outputs of an analysis for people: a JSON summary, per-region statistics, false-colour PNG
//! slices of the opening map and labels, and portals as an OBJ file a DCC tool can open.

use std::fmt::Write as _;
use std::path::Path;

use super::pipeline::Analysis;
use super::regions::{face_center, NO_REGION};
use crate::error::{Error, Result};
use crate::film::write_png_rgb;
use crate::math::{Rgb, Vec3};

fn write(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).map_err(|e| Error::io(path, e))
}

/// The JSON summary: dims, empty voxels, regions, portals, seconds per stage, memory.
pub fn summary_json(a: &Analysis) -> String {
    let stages: serde_json::Map<String, serde_json::Value> = a
        .timings
        .iter()
        .map(|t| (t.stage.to_string(), serde_json::json!(t.seconds)))
        .collect();
    let m = a.memory();
    serde_json::to_string_pretty(&serde_json::json!({
        "dims": a.grid.dims,
        "voxel_size": a.grid.voxel_size,
        "origin": a.grid.origin,
        "empty_voxels": a.empty_voxels(),
        "interior_voxels_filled": a.interior_voxels_filled,
        "regions": a.regions.len(),
        "portals": a.portals.len(),
        "seconds": stages,
        "total_seconds": a.total_seconds(),
        "memory_bytes": {
            "occupancy": m.occupancy, "distance": m.distance, "opening": m.opening,
            "labels": m.labels, "portals": m.portals, "extra_maps": m.extra_maps, "total": m.total()
        }
    }))
    .expect("JSON of plain values")
}

/// A distinct, stable colour per label (golden-ratio hue walk).
fn label_colour(label: u32) -> Rgb {
    if label == NO_REGION {
        return Rgb::ZERO;
    }
    let h = (label as f32 * 0.618_034).fract() * 6.0;
    let x = 1.0 - ((h % 2.0) - 1.0).abs();
    let (r, g, b) = match h as u32 {
        0 => (1.0, x, 0.0),
        1 => (x, 1.0, 0.0),
        2 => (0.0, 1.0, x),
        3 => (0.0, x, 1.0),
        4 => (x, 0.0, 1.0),
        _ => (1.0, 0.0, x),
    };
    Rgb::new(0.1 + 0.8 * r, 0.1 + 0.8 * g, 0.1 + 0.8 * b) * 0.8
}

/// Dark-to-bright ramp for scalar maps (0 = black).
fn ramp(t: f32) -> Rgb {
    let t = t.clamp(0.0, 1.0);
    Rgb::new(t.powf(0.6), t.powf(1.5), (1.0 - t) * t * 2.5 + t.powi(4))
}

/// Writes a slice perpendicular to `axis` at index `k`, scaled up by nearest neighbour so the
/// shorter side is at least 256 pixels. Rows go down the second in-plane axis.
fn write_slice(
    dir: &Path,
    name: &str,
    a: &Analysis,
    axis: usize,
    k: usize,
    colour: &dyn Fn(usize) -> Rgb,
) -> Result<()> {
    let (u, v) = match axis {
        0 => (2, 1),
        1 => (0, 2),
        _ => (0, 1),
    };
    let (w, h) = (a.grid.dims[u], a.grid.dims[v]);
    let scale = (256 / w.min(h).max(1)).clamp(1, 16);
    let (pw, ph) = (w * scale, h * scale);
    let mut pixels = Vec::with_capacity(pw * ph);
    for py in 0..ph {
        for px in 0..pw {
            let mut c = [0usize; 3];
            c[axis] = k;
            c[u] = px / scale;
            c[v] = h - 1 - py / scale;
            pixels.push(colour(a.grid.index(c[0], c[1], c[2])));
        }
    }
    write_png_rgb(&dir.join(name), pw as u32, ph as u32, &pixels, 0.0)
}

/// Writes `summary.json`, `regions.csv`, `portals.obj` and mid-slices of the opening map and
/// labels along each axis into `dir` (no slices for an analysis without the regions).
pub fn write_analysis(dir: &Path, a: &Analysis) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    write(&dir.join("summary.json"), &summary_json(a))?;

    let mut csv = String::from(
        "region,opening_voxels,opening_world,root_voxels,voxels,centroid_x,centroid_y,centroid_z\n",
    );
    for (i, r) in a.regions.iter().enumerate() {
        let _ = writeln!(
            csv,
            "{i},{},{:.6},{},{},{:.6},{:.6},{:.6}",
            r.opening,
            r.opening as f64 * a.grid.voxel_size,
            r.root_voxels,
            r.voxels,
            r.centroid.x,
            r.centroid.y,
            r.centroid.z
        );
    }
    write(&dir.join("regions.csv"), &csv)?;

    let mut obj = String::from("# Lacuna opening portals: one group per pair of neighbouring regions, one quad per voxel face.\n");
    let half = (a.grid.voxel_size * 0.5) as f32;
    let mut vertex = 1usize;
    for p in &a.portals {
        let _ = writeln!(obj, "g portal_{}_{}", p.regions.0, p.regions.1);
        for f in &p.faces {
            let c = face_center(&a.grid, f);
            let axis = f.axis as usize;
            let (s, t) = ((axis + 1) % 3, (axis + 2) % 3);
            let mut du = Vec3::ZERO;
            du[s] = half;
            let mut dv = Vec3::ZERO;
            dv[t] = half;
            for corner in [c - du - dv, c + du - dv, c + du + dv, c - du + dv] {
                let _ = writeln!(obj, "v {} {} {}", corner.x, corner.y, corner.z);
            }
            let _ = writeln!(
                obj,
                "f {} {} {} {}",
                vertex,
                vertex + 1,
                vertex + 2,
                vertex + 3
            );
            vertex += 4;
        }
    }
    write(&dir.join("portals.obj"), &obj)?;

    if !a.has_regions {
        return Ok(());
    }
    let max_opening = a.opening.opening.iter().copied().max().unwrap_or(1).max(1) as f32;
    for axis in 0..3 {
        let k = a.grid.dims[axis] / 2;
        let name = ["x", "y", "z"][axis];
        write_slice(dir, &format!("opening_{name}.png"), a, axis, k, &|i| {
            ramp(a.opening.opening[i] as f32 / max_opening)
        })?;
        write_slice(dir, &format!("labels_{name}.png"), a, axis, k, &|i| {
            label_colour(a.labels[i])
        })?;
    }
    Ok(())
}
