//! The "corridor" test scene of Noel and Biri (Pacific Graphics 2015), rebuilt from its
//! geometric description: the original OBJ has no license, so it is not shipped; its
//! coordinates (metres-like, Y up) are restated here as a floor plan.
//!
//! The corridor is a box 7.5 high over the rectangle x in [-13.1972, 7.38623],
//! z in [-6.1727, 10.7213], split by two partition walls into a serpentine of three bays:
//! - bay A, z in [-6.1727, -1.10852] (the camera's);
//! - partition 1, z in [-1.10852, -0.478412], attached to the x = 7.38623 wall and ending at
//!   x = -7.61244, so bay A opens into bay B at the low-x end;
//! - bay B, z in [-0.478412, 3.86231];
//! - partition 2, z in [3.86231, 4.53909], attached to the x = -13.1972 wall and ending at
//!   x = 1.91587, so bay B opens into bay C at the high-x end;
//! - bay C, z in [4.53909, 10.7213], holding the light: a 2 x 2 quad at x = -7.8,
//!   y in [2.5, 4.5], z in [6.5, 8.5], emitting towards -X (at the bay's far end wall).
//!
//! Light reaches the camera's bay only after at least three diffuse bounces. The original
//! gives the quad an emission of 100000 in the pg2015 renderer's own units; Lacuna reads that
//! value as a radiance ([`LIGHT_RADIANCE`], W sr^-1 m^-2) because it gives a sensible image
//! (see its doc), as the same reading does for pg2015's Sibenik lights.
//! The wall colours are the placeholders of the shipped MTL (the original MTL is lost): beige
//! everywhere except the x = 7.38623 wall of bays B and C, which is red.

use super::{Camera, Material, MeshDesc, SceneBuilder};
use crate::error::Result;
use crate::math::{Rgb, Vec3};
use crate::scene::RenderSettingsFile;

const X_MIN: f32 = -13.1972;
const X_MAX: f32 = 7.38623;
const Z_MIN: f32 = -6.1727;
const Z_MAX: f32 = 10.7213;
const HEIGHT: f32 = 7.5;
/// Partition 1 (from the x = X_MAX wall): z range and free end.
const P1_Z: (f32, f32) = (-1.10852, -0.478412);
const P1_X_END: f32 = -7.61244;
/// Partition 2 (from the x = X_MIN wall): z range and free end.
const P2_Z: (f32, f32) = (3.86231, 4.53909);
const P2_X_END: f32 = 1.91587;

/// Emitted radiance of the light quad (grey), pg2015's emission value. Measured with the path
/// tracer (max depth 8, 16k samples per pixel at 32 x 32), the far-from-light view then has a
/// mean pixel value of about 0.47 (median about 0.2): bay A is lit only by light that went
/// round both partitions, so most of the 4 x 100000 x pi W the quad emits stays in bay C.
pub const LIGHT_RADIANCE: f32 = 100_000.0;

const BEIGE: Rgb = Rgb::new(0.8, 0.75, 0.6);
const RED: Rgb = Rgb::new(0.7, 0.1, 0.1);

/// The floor plan: corners in (x, z), counter-clockwise in the sense that the wall normal
/// (b - a) x Y of each edge a -> b points into the corridor.
fn outline() -> [(f32, f32); 12] {
    [
        (X_MAX, Z_MIN),
        (X_MAX, P1_Z.0),
        (P1_X_END, P1_Z.0),
        (P1_X_END, P1_Z.1),
        (X_MAX, P1_Z.1),
        (X_MAX, Z_MAX),
        (X_MIN, Z_MAX),
        (X_MIN, P2_Z.1),
        (P2_X_END, P2_Z.1),
        (P2_X_END, P2_Z.0),
        (X_MIN, P2_Z.0),
        (X_MIN, Z_MIN),
    ]
}

/// Index of the outline edge that is red (x = X_MAX, bays B and C).
const RED_EDGE: usize = 4;

/// The floor area as axis-aligned rectangles (x0, x1, z0, z1): the three bays and the two
/// openings beside the partitions.
fn floor_rectangles() -> [(f32, f32, f32, f32); 5] {
    [
        (X_MIN, X_MAX, Z_MIN, P1_Z.0),
        (X_MIN, P1_X_END, P1_Z.0, P1_Z.1),
        (X_MIN, X_MAX, P1_Z.1, P2_Z.0),
        (P2_X_END, X_MAX, P2_Z.0, P2_Z.1),
        (X_MIN, X_MAX, P2_Z.1, Z_MAX),
    ]
}

/// Quads collected into one mesh.
#[derive(Default)]
struct Quads {
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    indices: Vec<[u32; 3]>,
}

impl Quads {
    /// Planar quad a-b-c-d, counter-clockwise seen from its front. Corners are given exactly
    /// (not as sums of edge vectors) so that shared edges coincide bit for bit.
    fn quad(&mut self, a: Vec3, b: Vec3, c: Vec3, d: Vec3) {
        let i = self.positions.len() as u32;
        let n = (b - a).cross(d - a).normalize();
        self.positions.extend([a, b, c, d]);
        self.normals.extend([n; 4]);
        self.indices.push([i, i + 1, i + 2]);
        self.indices.push([i, i + 2, i + 3]);
    }

    fn mesh(self, name: &str, material: u32) -> MeshDesc {
        MeshDesc {
            name: name.to_string(),
            positions: self.positions,
            normals: self.normals,
            uvs: Vec::new(),
            indices: self.indices,
            materials: vec![material],
        }
    }
}

/// The corridor with the pg2015 "far-from-light" camera (vertical field of view 45 degrees,
/// meant for 512 x 512, see [`corridor_render_settings`]). Every surface faces into the
/// corridor; the light faces -X.
pub fn corridor_builder() -> Result<SceneBuilder> {
    let mut b = SceneBuilder::new();
    let beige = b.add_material(Material {
        name: "beige".into(),
        ..Material::diffuse(BEIGE)
    })?;
    let red = b.add_material(Material {
        name: "red".into(),
        ..Material::diffuse(RED)
    })?;
    let light = b.add_material(Material {
        name: "light".into(),
        ..Material::emissive(Rgb::splat(LIGHT_RADIANCE))
    })?;

    let corners = outline();
    let mut walls = Quads::default();
    let mut red_walls = Quads::default();
    for i in 0..corners.len() {
        let (ax, az) = corners[i];
        let (bx, bz) = corners[(i + 1) % corners.len()];
        let target = if i == RED_EDGE {
            &mut red_walls
        } else {
            &mut walls
        };
        // Front = (b - a) x Y, which for this outline points into the corridor.
        target.quad(
            Vec3::new(ax, 0.0, az),
            Vec3::new(bx, 0.0, bz),
            Vec3::new(bx, HEIGHT, bz),
            Vec3::new(ax, HEIGHT, az),
        );
    }
    for (x0, x1, z0, z1) in floor_rectangles() {
        // Floor faces +Y, ceiling faces -Y.
        walls.quad(
            Vec3::new(x0, 0.0, z0),
            Vec3::new(x0, 0.0, z1),
            Vec3::new(x1, 0.0, z1),
            Vec3::new(x1, 0.0, z0),
        );
        walls.quad(
            Vec3::new(x0, HEIGHT, z0),
            Vec3::new(x1, HEIGHT, z0),
            Vec3::new(x1, HEIGHT, z1),
            Vec3::new(x0, HEIGHT, z1),
        );
    }
    b.add_mesh(walls.mesh("corridor_beige", beige))?;
    b.add_mesh(red_walls.mesh("corridor_red", red))?;

    let mut lamp = Quads::default();
    // (+Z edge) x (+Y edge) = -X.
    lamp.quad(
        Vec3::new(-7.8, 2.5, 6.5),
        Vec3::new(-7.8, 2.5, 8.5),
        Vec3::new(-7.8, 4.5, 8.5),
        Vec3::new(-7.8, 4.5, 6.5),
    );
    b.add_mesh(lamp.mesh("light_quad", light))?;

    b.set_camera(Camera::look_at(
        Vec3::new(4.126_035, 4.318_193, -3.597_138),
        Vec3::new(3.131_397, 4.318_193, -3.634_933),
        Vec3::new(-0.096_195_4, 0.995_355_7, -0.003_655_3),
        45.0,
    )?)?;
    Ok(b)
}

/// The pg2015 framebuffer (512 x 512) and Lacuna's usual max depth of 8.
pub fn corridor_render_settings() -> RenderSettingsFile {
    RenderSettingsFile {
        width: Some(512),
        height: Some(512),
        max_depth: Some(8),
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Ray;
    use crate::light::Light;

    #[test]
    fn corridor_matches_the_documented_layout() {
        let scene = corridor_builder().unwrap().build().unwrap();
        // Same triangle count as the pg2015 OBJ: 12 walls, 5 floor and 5 ceiling rectangles,
        // the light quad.
        assert_eq!(scene.triangle_count(), 46);
        let b = scene.bounds();
        assert_eq!(b.min, Vec3::new(X_MIN, 0.0, Z_MIN));
        assert_eq!(b.max, Vec3::new(X_MAX, HEIGHT, Z_MAX));
        // The floor is the polygon of the outline (shoelace area).
        let c = outline();
        let polygon: f32 = (0..c.len())
            .map(|i| {
                let (a, b) = (c[i], c[(i + 1) % c.len()]);
                a.0 * b.1 - b.0 * a.1
            })
            .sum::<f32>()
            * 0.5;
        let rects: f32 = floor_rectangles()
            .iter()
            .map(|(x0, x1, z0, z1)| (x1 - x0) * (z1 - z0))
            .sum();
        assert!((polygon.abs() - rects).abs() < 1e-3, "{polygon} vs {rects}");

        let lights = scene.lights();
        assert_eq!(lights.len(), 2);
        let mut area = 0.0;
        for l in lights {
            match l {
                Light::Area {
                    normal,
                    area: a,
                    radiance,
                    ..
                } => {
                    assert!((*normal + Vec3::X).length() < 1e-6);
                    assert_eq!(*radiance, Rgb::splat(LIGHT_RADIANCE));
                    area += a;
                }
                other => panic!("{other:?}"),
            }
        }
        assert!((area - 4.0).abs() < 1e-5);
        let cam = scene.camera().unwrap();
        assert!(cam.eye.z > Z_MIN && cam.eye.z < P1_Z.0, "camera in bay A");
    }

    /// Every wall, floor and ceiling triangle faces into the corridor: a ray from a point
    /// inside, along the normal, first hits the other side of the corridor or a light, never
    /// escapes.
    #[test]
    fn surfaces_face_inwards_and_the_shell_is_closed() {
        let scene = corridor_builder().unwrap().build().unwrap();
        for t in 0..scene.triangle_count() as u32 {
            let p = scene.triangle_vertices(t);
            let centre = (p[0] + p[1] + p[2]) / 3.0;
            // `+ 0` turns -0 components into +0: the BVH node test currently loses rays
            // whose direction has a -0 component.
            let n = scene.geometric_normal(t) + Vec3::ZERO;
            let origin = centre + n * 1e-3;
            let hit = scene.intersect_hit(&Ray::new(origin, n, f32::INFINITY));
            assert!(
                hit.is_some(),
                "triangle {t} at {centre} faces outwards ({n})"
            );
        }
        // Rays in many directions from inside each bay never escape.
        let mut rng = crate::math::Rng::new(1, 2);
        for origin in [
            Vec3::new(0.0, 3.0, -3.0),
            Vec3::new(-5.0, 3.0, 1.5),
            Vec3::new(-2.0, 3.0, 8.0),
        ] {
            for _ in 0..2000 {
                let d = crate::math::warp::uniform_sphere(rng.uniform2());
                assert!(
                    scene
                        .intersect_hit(&Ray::new(origin, d, f32::INFINITY))
                        .is_some(),
                    "ray from {origin} along {d} escaped"
                );
            }
        }
    }
}
