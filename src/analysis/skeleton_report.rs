//! Outputs of the skeleton for people: OBJ line sets, PLY with a radius per vertex, a view of
//! the scene with the skeleton drawn over it, and a false-colour view of the node map on the
//! visible surfaces.

use std::fmt::Write as _;
use std::path::Path;

use rayon::prelude::*;

use super::skeleton::{Graph, Skeleton};
use crate::error::{Error, Result};
use crate::film::write_png_rgb;
use crate::geometry::Ray;
use crate::light::environment::Portal;
use crate::math::{Rgb, Vec2, Vec3};
use crate::scene::{auto_camera, CameraFrame, Scene};

fn write(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).map_err(|e| Error::io(path, e))
}

/// The graph as an OBJ file: one `v` per node, one `l` per edge.
pub fn skeleton_obj(g: &Graph, title: &str) -> String {
    let mut s = format!(
        "# Lacuna {title}: {} nodes, {} edges (one polyline per edge)\n",
        g.nodes.len(),
        g.edges.len()
    );
    for n in &g.nodes {
        let _ = writeln!(s, "v {} {} {}", n.position.x, n.position.y, n.position.z);
    }
    for &[a, b] in &g.edges {
        let _ = writeln!(s, "l {} {}", a + 1, b + 1);
    }
    s
}

/// The graph as an ASCII PLY file with a `radius` (world units) per vertex and an `edge`
/// element.
pub fn skeleton_ply(g: &Graph, title: &str) -> String {
    let mut s = format!(
        "ply\nformat ascii 1.0\ncomment Lacuna {title}; radius = maximal-ball radius (world units)\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float radius\n\
         element edge {}\nproperty int vertex1\nproperty int vertex2\nend_header\n",
        g.nodes.len(),
        g.edges.len()
    );
    for n in &g.nodes {
        let _ = writeln!(
            s,
            "{} {} {} {}",
            n.position.x, n.position.y, n.position.z, n.radius
        );
    }
    for &[a, b] in &g.edges {
        let _ = writeln!(s, "{a} {b}");
    }
    s
}

/// A distinct colour per index (golden-ratio hue walk).
fn index_colour(i: u32) -> Rgb {
    let h = (i as f32 * 0.618_034).fract() * 6.0;
    let x = 1.0 - ((h % 2.0) - 1.0).abs();
    let (r, g, b) = match h as u32 {
        0 => (1.0, x, 0.0),
        1 => (x, 1.0, 0.0),
        2 => (0.0, 1.0, x),
        3 => (0.0, x, 1.0),
        4 => (x, 0.0, 1.0),
        _ => (1.0, 0.0, x),
    };
    Rgb::new(0.15 + 0.85 * r, 0.15 + 0.85 * g, 0.15 + 0.85 * b)
}

/// Cool-to-warm ramp for node radii.
fn radius_colour(t: f32) -> Rgb {
    let t = t.clamp(0.0, 1.0);
    Rgb::new(t.sqrt(), 0.3 + 0.5 * (1.0 - (2.0 * t - 1.0).abs()), 1.0 - t)
}

const WIDTH: u32 = 800;
const HEIGHT: u32 = 600;

struct View {
    frame: CameraFrame,
    /// Per pixel: distance to the first surface (infinite if none), shade, node of the hit.
    depth: Vec<f32>,
    shade: Vec<f32>,
    node: Vec<Option<u32>>,
}

/// The scene from its camera (pinhole), per pixel; with `skeleton`, the node each hit maps to.
fn cast(scene: &Scene, skeleton: Option<&Skeleton>) -> View {
    let aspect = WIDTH as f32 / HEIGHT as f32;
    let camera = scene
        .camera()
        .copied()
        .unwrap_or_else(|| auto_camera(scene.bounds(), aspect));
    let frame = camera.frame(aspect);
    let pixels: Vec<(f32, f32, Option<u32>)> = (0..WIDTH * HEIGHT)
        .into_par_iter()
        .map(|i| {
            let film = Vec2::new(
                ((i % WIDTH) as f32 + 0.5) / WIDTH as f32,
                ((i / WIDTH) as f32 + 0.5) / HEIGHT as f32,
            );
            // Pinhole ray (matching `project`), whatever the camera's lens.
            let ndc = Vec2::new(2.0 * film.x - 1.0, 1.0 - 2.0 * film.y);
            let dir = (frame.forward + frame.right * ndc.x + frame.up * ndc.y).normalize();
            let ray = Ray::new(frame.eye, dir, f32::INFINITY);
            match scene.intersect(&ray) {
                Some(si) => {
                    let cos = si.ng.dot(si.wo).abs();
                    let node = skeleton.and_then(|s| s.map_point(si.p, si.ng, si.wo));
                    (si.t * ray.dir.length(), 0.2 + 0.7 * cos, node)
                }
                None => (f32::INFINITY, 0.0, None),
            }
        })
        .collect();
    View {
        frame,
        depth: pixels.iter().map(|p| p.0).collect(),
        shade: pixels.iter().map(|p| p.1).collect(),
        node: pixels.iter().map(|p| p.2).collect(),
    }
}

impl View {
    /// Pixel and visibility of a world point.
    fn pixel(&self, p: Vec3) -> Option<(usize, bool)> {
        let (film, _) = self.frame.project(p)?;
        let (x, y) = (
            (film.x * WIDTH as f32) as usize,
            (film.y * HEIGHT as f32) as usize,
        );
        let i = y.min(HEIGHT as usize - 1) * WIDTH as usize + x.min(WIDTH as usize - 1);
        let d = (p - self.frame.eye).length();
        Some((i, d <= self.depth[i] * 1.002 + 1e-3))
    }
}

/// Writes `skeleton.png` (the scene seen from its camera, grey by facing ratio, with the raw
/// skeleton's edges drawn over it — hidden parts dimmed — and the filtered nodes as discs whose
/// size and colour follow their radius) and `node_map.png` (each visible surface point
/// coloured by the filtered node it maps to through eq. 151-155; black = no node).
pub fn write_skeleton_images(dir: &Path, scene: &Scene, skeleton: &Skeleton) -> Result<()> {
    let view = cast(scene, Some(skeleton));
    let (w, h) = (WIDTH as usize, HEIGHT as usize);
    let mut img: Vec<Rgb> = view.shade.iter().map(|&s| Rgb::splat(s * 0.6)).collect();
    let blend = |img: &mut Vec<Rgb>, i: usize, c: Rgb, a: f32| {
        img[i] = img[i] * (1.0 - a) + c * a;
    };
    let g = &skeleton.raw;
    for &[a, b] in &g.edges {
        let (pa, pb) = (g.nodes[a as usize].position, g.nodes[b as usize].position);
        let steps = match (view.frame.project(pa), view.frame.project(pb)) {
            (Some((fa, _)), Some((fb, _))) => {
                (((fa - fb) * Vec2::new(WIDTH as f32, HEIGHT as f32)).length() * 1.5) as usize + 2
            }
            _ => 16,
        };
        for k in 0..=steps {
            let p = pa.lerp(pb, k as f32 / steps as f32);
            if let Some((i, visible)) = view.pixel(p) {
                if visible {
                    img[i] = Rgb::new(1.0, 0.85, 0.1);
                } else {
                    blend(&mut img, i, Rgb::new(1.0, 0.6, 0.1), 0.35);
                }
            }
        }
    }
    let f = &skeleton.filtered.graph;
    let max_r = f
        .nodes
        .iter()
        .map(|n| n.radius)
        .fold(0.0f32, f32::max)
        .max(1e-6);
    let focal = view.frame.image_plane_distance(HEIGHT);
    for n in &f.nodes {
        let Some((film, _)) = view.frame.project(n.position) else {
            continue;
        };
        let dist = (n.position - view.frame.eye).length().max(1e-6);
        // A fifth of the projected ball, kept between 2 and 14 pixels.
        let r = (0.2 * n.radius * focal / dist).clamp(2.0, 14.0);
        let (cx, cy) = (film.x * WIDTH as f32, film.y * HEIGHT as f32);
        let visible = view.pixel(n.position).is_some_and(|(_, v)| v);
        let colour = radius_colour(n.radius / max_r);
        for y in (cy - r).floor().max(0.0) as usize..((cy + r).ceil() as usize).min(h) {
            for x in (cx - r).floor().max(0.0) as usize..((cx + r).ceil() as usize).min(w) {
                let d = Vec2::new(x as f32 + 0.5 - cx, y as f32 + 0.5 - cy).length();
                if d <= r {
                    let edge = d > r - 1.2;
                    let c = if edge { Rgb::ZERO } else { colour };
                    blend(&mut img, y * w + x, c, if visible { 1.0 } else { 0.4 });
                }
            }
        }
    }
    write_png_rgb(&dir.join("skeleton.png"), WIDTH, HEIGHT, &img, 0.0)?;

    let map: Vec<Rgb> = view
        .node
        .iter()
        .zip(&view.shade)
        .map(|(n, &s)| match n {
            Some(n) => index_colour(*n) * (0.35 + 0.65 * s),
            None => Rgb::ZERO,
        })
        .collect();
    write_png_rgb(&dir.join("node_map.png"), WIDTH, HEIGHT, &map, 0.0)
}

/// Colour of the window portals' outlines in [`window_portal_overlay`].
pub const PORTAL_OUTLINE: Rgb = Rgb::new(0.1, 0.9, 1.0);

/// The scene seen from its camera (grey by facing ratio) with each window portal's rectangle
/// over it: its inside tinted where no surface hides it, its outline in [`PORTAL_OUTLINE`]
/// everywhere (a window portal lies mid-way through the wall, where the reveal hides its
/// edges); `WIDTH` x `HEIGHT` pixels, row by row.
pub fn window_portal_overlay(scene: &Scene, portals: &[Portal]) -> Vec<Rgb> {
    let view = cast(scene, None);
    let mut img: Vec<Rgb> = view.shade.iter().map(|&s| Rgb::splat(s * 0.6)).collect();
    let frame = &view.frame;
    for (k, px) in img.iter_mut().enumerate() {
        let ndc = Vec2::new(
            2.0 * ((k as u32 % WIDTH) as f32 + 0.5) / WIDTH as f32 - 1.0,
            1.0 - 2.0 * ((k as u32 / WIDTH) as f32 + 0.5) / HEIGHT as f32,
        );
        let dir = (frame.forward + frame.right * ndc.x + frame.up * ndc.y).normalize();
        let seen = portals.iter().any(|p| {
            let n = p.edge_u.cross(p.edge_v);
            let t = (p.corner - frame.eye).dot(n) / dir.dot(n);
            let q = frame.eye + dir * t - p.corner;
            let (a, b) = (
                q.dot(p.edge_u) / p.edge_u.length_squared(),
                q.dot(p.edge_v) / p.edge_v.length_squared(),
            );
            t > 0.0 && t <= view.depth[k] && (0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b)
        });
        if seen {
            *px = *px * 0.55 + PORTAL_OUTLINE * 0.45;
        }
    }
    let size = Vec2::new(WIDTH as f32, HEIGHT as f32);
    for p in portals {
        let c = [
            p.corner,
            p.corner + p.edge_u,
            p.corner + p.edge_u + p.edge_v,
            p.corner + p.edge_v,
        ];
        for e in 0..4 {
            let (a, b) = (c[e], c[(e + 1) % 4]);
            let n = match (frame.project(a), frame.project(b)) {
                (Some((fa, _)), Some((fb, _))) => (((fa - fb) * size).length() * 1.5) as usize + 2,
                _ => 64,
            };
            for k in 0..=n {
                if let Some((i, _)) = view.pixel(a.lerp(b, k as f32 / n as f32)) {
                    img[i] = PORTAL_OUTLINE;
                }
            }
        }
    }
    img
}

/// Writes `window_portals.png` ([`window_portal_overlay`]) into `dir`.
pub fn write_window_portal_image(dir: &Path, scene: &Scene, portals: &[Portal]) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let img = window_portal_overlay(scene, portals);
    write_png_rgb(&dir.join("window_portals.png"), WIDTH, HEIGHT, &img, 0.0)
}

/// Writes `skeleton.obj`, `skeleton_filtered.obj`, `skeleton.ply` and `skeleton_filtered.ply`
/// into `dir`, and the two images when a scene is given.
pub fn write_skeleton(dir: &Path, scene: Option<&Scene>, skeleton: &Skeleton) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let f = &skeleton.filtered.graph;
    write(
        &dir.join("skeleton.obj"),
        &skeleton_obj(&skeleton.raw, "curvilinear skeleton"),
    )?;
    write(
        &dir.join("skeleton_filtered.obj"),
        &skeleton_obj(f, "filtered skeleton"),
    )?;
    write(
        &dir.join("skeleton.ply"),
        &skeleton_ply(&skeleton.raw, "curvilinear skeleton"),
    )?;
    write(
        &dir.join("skeleton_filtered.ply"),
        &skeleton_ply(f, "filtered skeleton"),
    )?;
    if let Some(scene) = scene {
        write_skeleton_images(dir, scene, skeleton)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The interior's four windows show in the overlay, in the outline colour; without
    /// portals no pixel has it.
    #[test]
    fn the_window_portals_are_drawn_over_the_view() {
        let scene = crate::scene::interior_builder().unwrap().build().unwrap();
        let found =
            super::super::window_portals(&scene, &super::super::WindowPortalSettings::default())
                .unwrap();
        assert_eq!(found.portals.len(), 4);
        let outlined = |img: &[Rgb]| img.iter().filter(|&&c| c == PORTAL_OUTLINE).count();
        let with = window_portal_overlay(&scene, &found.portals);
        assert_eq!(with.len(), (WIDTH * HEIGHT) as usize);
        assert!(outlined(&with) > 100, "{} outline pixels", outlined(&with));
        assert_eq!(outlined(&window_portal_overlay(&scene, &[])), 0);
    }
}
