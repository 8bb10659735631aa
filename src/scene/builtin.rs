//! The built-in scene rendered when the command line is given nothing: two rooms joined by an
//! ajar door, lit only from the far room, so that the camera room is lit almost entirely by
//! light that squeezed through the gap — the case Lacuna is built for. It lives in the binary
//! (no files needed) and doubles as a test scene.
//!
//! Layout (metres, Y up): the camera room spans z in [0, 4], the far room z in [-4.1, -0.1];
//! between them a wall 0.1 thick with a doorway x in [1.5, 2.4], y in [0, 2]. The door panel is
//! hinged at x = 1.5 on the camera-room side and opened 25 degrees into the camera room.

use super::{Camera, Material, MeshDesc, SceneBuilder};
use crate::error::Result;
use crate::math::{Rgb, Vec3};

/// Room extents.
const X0: f32 = 0.0;
const X1: f32 = 4.0;
const Y1: f32 = 2.5;
const Z_FAR: f32 = -4.1;
const Z_NEAR: f32 = 4.0;
const WALL_FAR_SIDE: f32 = -0.1;
const DOOR_X0: f32 = 1.5;
const DOOR_X1: f32 = 2.4;
const DOOR_Y1: f32 = 2.0;

/// Collects quads into one mesh per material.
struct Quads {
    positions: Vec<Vec3>,
    indices: Vec<[u32; 3]>,
}

impl Quads {
    fn new() -> Self {
        Quads {
            positions: Vec::new(),
            indices: Vec::new(),
        }
    }

    /// Adds quad a-b-c-d (counter-clockwise seen from its front).
    fn quad(&mut self, a: Vec3, b: Vec3, c: Vec3, d: Vec3) {
        let i = self.positions.len() as u32;
        self.positions.extend([a, b, c, d]);
        self.indices.push([i, i + 1, i + 2]);
        self.indices.push([i, i + 2, i + 3]);
    }

    /// Adds an axis-aligned box with outward-facing sides, transformed by `f`.
    fn cuboid(&mut self, min: Vec3, max: Vec3, f: impl Fn(Vec3) -> Vec3) {
        let p = |x: f32, y: f32, z: f32| f(Vec3::new(x, y, z));
        let (a, b) = (min, max);
        self.quad(
            p(a.x, a.y, b.z),
            p(b.x, a.y, b.z),
            p(b.x, b.y, b.z),
            p(a.x, b.y, b.z),
        ); // +z
        self.quad(
            p(b.x, a.y, a.z),
            p(a.x, a.y, a.z),
            p(a.x, b.y, a.z),
            p(b.x, b.y, a.z),
        ); // -z
        self.quad(
            p(b.x, a.y, b.z),
            p(b.x, a.y, a.z),
            p(b.x, b.y, a.z),
            p(b.x, b.y, b.z),
        ); // +x
        self.quad(
            p(a.x, a.y, a.z),
            p(a.x, a.y, b.z),
            p(a.x, b.y, b.z),
            p(a.x, b.y, a.z),
        ); // -x
        self.quad(
            p(a.x, b.y, b.z),
            p(b.x, b.y, b.z),
            p(b.x, b.y, a.z),
            p(a.x, b.y, a.z),
        ); // +y
        self.quad(
            p(a.x, a.y, a.z),
            p(b.x, a.y, a.z),
            p(b.x, a.y, b.z),
            p(a.x, a.y, b.z),
        ); // -y
    }

    fn add_to(self, builder: &mut SceneBuilder, name: &str, material: u32) -> Result<()> {
        builder
            .add_mesh(MeshDesc {
                name: name.into(),
                positions: self.positions,
                indices: self.indices,
                materials: vec![material],
                ..Default::default()
            })
            .map(|_| ())
    }
}

/// A vertical rectangle in the plane z = `z`, spanning x0..x1, y0..y1, facing +z or -z.
fn wall_z(q: &mut Quads, z: f32, x0: f32, x1: f32, y0: f32, y1: f32, facing_positive: bool) {
    let (a, b, c, d) = (
        Vec3::new(x0, y0, z),
        Vec3::new(x1, y0, z),
        Vec3::new(x1, y1, z),
        Vec3::new(x0, y1, z),
    );
    if facing_positive {
        q.quad(a, b, c, d);
    } else {
        q.quad(b, a, d, c);
    }
}

/// The builder of the built-in scene (camera included), ready to `build()`.
pub fn two_rooms_builder() -> Result<SceneBuilder> {
    let mut b = SceneBuilder::new();
    let wall = b.add_material(Material {
        name: "wall".into(),
        ..Material::diffuse(Rgb::splat(0.7))
    })?;
    let floor = b.add_material(Material {
        name: "floor".into(),
        ..Material::glossy(Rgb::new(0.45, 0.35, 0.25), Rgb::splat(0.15), 60.0)
    })?;
    let door = b.add_material(Material {
        name: "door".into(),
        ..Material::diffuse(Rgb::new(0.55, 0.3, 0.15))
    })?;
    let table = b.add_material(Material {
        name: "table".into(),
        ..Material::glossy(Rgb::new(0.1, 0.25, 0.45), Rgb::splat(0.3), 300.0)
    })?;
    let light = b.add_material(Material {
        name: "light".into(),
        ..Material::emissive(Rgb::new(120.0, 108.0, 90.0))
    })?;

    // Shell: floor, ceiling, side and end walls, all facing inwards.
    let mut floor_q = Quads::new();
    floor_q.quad(
        Vec3::new(X0, 0.0, Z_NEAR),
        Vec3::new(X1, 0.0, Z_NEAR),
        Vec3::new(X1, 0.0, Z_FAR),
        Vec3::new(X0, 0.0, Z_FAR),
    );
    floor_q.add_to(&mut b, "floor", floor)?;

    let mut walls = Quads::new();
    walls.quad(
        Vec3::new(X0, Y1, Z_FAR),
        Vec3::new(X1, Y1, Z_FAR),
        Vec3::new(X1, Y1, Z_NEAR),
        Vec3::new(X0, Y1, Z_NEAR),
    );
    walls.quad(
        Vec3::new(X0, 0.0, Z_NEAR),
        Vec3::new(X0, 0.0, Z_FAR),
        Vec3::new(X0, Y1, Z_FAR),
        Vec3::new(X0, Y1, Z_NEAR),
    );
    walls.quad(
        Vec3::new(X1, 0.0, Z_FAR),
        Vec3::new(X1, 0.0, Z_NEAR),
        Vec3::new(X1, Y1, Z_NEAR),
        Vec3::new(X1, Y1, Z_FAR),
    );
    wall_z(&mut walls, Z_FAR, X0, X1, 0.0, Y1, true);
    wall_z(&mut walls, Z_NEAR, X0, X1, 0.0, Y1, false);

    // Dividing wall with the doorway: both faces (left, right, lintel) and the jambs.
    for (z, facing_positive) in [(0.0, true), (WALL_FAR_SIDE, false)] {
        wall_z(&mut walls, z, X0, DOOR_X0, 0.0, Y1, facing_positive);
        wall_z(&mut walls, z, DOOR_X1, X1, 0.0, Y1, facing_positive);
        wall_z(
            &mut walls,
            z,
            DOOR_X0,
            DOOR_X1,
            DOOR_Y1,
            Y1,
            facing_positive,
        );
    }
    let (zf, zn) = (WALL_FAR_SIDE, 0.0);
    walls.quad(
        Vec3::new(DOOR_X0, 0.0, zn),
        Vec3::new(DOOR_X0, 0.0, zf),
        Vec3::new(DOOR_X0, DOOR_Y1, zf),
        Vec3::new(DOOR_X0, DOOR_Y1, zn),
    );
    walls.quad(
        Vec3::new(DOOR_X1, 0.0, zf),
        Vec3::new(DOOR_X1, 0.0, zn),
        Vec3::new(DOOR_X1, DOOR_Y1, zn),
        Vec3::new(DOOR_X1, DOOR_Y1, zf),
    );
    walls.quad(
        Vec3::new(DOOR_X0, DOOR_Y1, zn),
        Vec3::new(DOOR_X0, DOOR_Y1, zf),
        Vec3::new(DOOR_X1, DOOR_Y1, zf),
        Vec3::new(DOOR_X1, DOOR_Y1, zn),
    );
    walls.add_to(&mut b, "walls", wall)?;

    // Door panel: 0.88 wide, 1.98 high, 4 cm thick, hinged at the doorway's left edge on the
    // camera-room face, swung 25 degrees into the camera room.
    let angle = 25f32.to_radians();
    let (s, c) = angle.sin_cos();
    let hinge = Vec3::new(DOOR_X0 + 0.01, 0.0, 0.0);
    let rotate = move |p: Vec3| {
        let d = p - hinge;
        hinge + Vec3::new(d.x * c - d.z * s, d.y, d.x * s + d.z * c)
    };
    let mut door_q = Quads::new();
    door_q.cuboid(
        Vec3::new(DOOR_X0 + 0.01, 0.005, -0.045),
        Vec3::new(DOOR_X0 + 0.89, 1.985, -0.005),
        rotate,
    );
    door_q.add_to(&mut b, "door", door)?;

    // A table in the camera room, lit only indirectly.
    let mut table_q = Quads::new();
    table_q.cuboid(Vec3::new(0.3, 0.0, 1.6), Vec3::new(1.1, 0.75, 2.6), |p| p);
    table_q.add_to(&mut b, "table", table)?;

    // Ceiling light in the far room, facing down.
    let mut light_q = Quads::new();
    light_q.quad(
        Vec3::new(1.5, Y1 - 0.01, -3.2),
        Vec3::new(2.5, Y1 - 0.01, -3.2),
        Vec3::new(2.5, Y1 - 0.01, -2.4),
        Vec3::new(1.5, Y1 - 0.01, -2.4),
    );
    light_q.add_to(&mut b, "light", light)?;

    b.set_camera(Camera::look_at(
        Vec3::new(3.7, 1.5, 3.7),
        Vec3::new(1.7, 1.0, 0.0),
        Vec3::Y,
        55.0,
    )?)?;
    Ok(b)
}
