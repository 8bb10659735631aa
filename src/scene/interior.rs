//! The built-in interior (`interior`): a small house lit by the sky through windows of several
//! sizes, the case portal-masked environment sampling is for. Walls, floor and ceiling are
//! diffuse boxes 0.2 m thick, so that the windows are apertures with depth and the analysis
//! sees them as openings between the rooms and the outside.
//!
//! Layout (metres, Y up): the house spans x in [0, 8], z in [0, 6], y in [-0.2, 2.9] (floor
//! slab y in [-0.2, 0], ceiling slab y in [2.7, 2.9]); outer walls 0.2 thick. A partition at
//! x in [5, 5.2] splits it into the living room (west, three windows) and a back room (east)
//! reached only through the inner door in the partition; the back room has one small window.
//! [`INTERIOR_WINDOWS`] lists the window apertures; a ground plane surrounds the house. The
//! sky map is `scenes/envmaps/sky.hdr` (Poly Haven, CC0), compiled in so the scene needs no
//! files.

use std::sync::Arc;

use super::quad_mesh::QuadMesh;
use super::{Camera, Material, MeshDesc, SceneBuilder};
use crate::error::{Error, Result};
use crate::light::environment::EnvImage;
use crate::light::{EnvSettings, EnvironmentMap};
use crate::math::{Rgb, Vec3};

/// One window aperture: its centre (in the middle of the wall's thickness), its half-extents
/// along the two in-plane axes (world axes, the lower index first) and the outward normal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WindowAperture {
    pub center: Vec3,
    pub half_extents: [f32; 2],
    /// Unit outward normal (a world axis).
    pub outward: Vec3,
}

const WALL: f32 = 0.2;
const HOUSE_X: f32 = 8.0;
const HOUSE_Z: f32 = 6.0;
const CEILING: f32 = 2.7;
const PARTITION_X0: f32 = 5.0;
const PARTITION_X1: f32 = 5.2;
/// Inner door in the partition: z and y extents.
const DOOR_Z: [f32; 2] = [4.2, 5.1];
const DOOR_Y1: f32 = 2.0;

/// The windows: (wall, centre along the wall, sill height, width, height). Walls: 0 = south
/// (z = 0), 1 = west (x = 0), 2 = north (z = 6).
const WINDOWS: [(u8, f32, f32, f32, f32); 4] = [
    (0, 2.4, 0.8, 2.4, 1.4), // living room, large, facing south
    (1, 3.0, 1.0, 1.0, 1.0), // living room, medium, facing west
    (2, 1.4, 1.2, 0.6, 0.8), // living room, narrow, facing north
    (2, 6.6, 1.5, 0.6, 0.6), // back room, small, facing north
];

/// One window: (wall, centre along the wall, sill height, width, height), as [`WINDOWS`].
type Window = (u8, f32, f32, f32, f32);

/// Most windows of [`interior_many_windows_builder`].
pub const MAX_SMALL_WINDOWS: usize = 50;

/// `n` small windows (0.3 m square, two rows at sills 0.7 m and 1.5 m, 0.6 m apart) taken in
/// turn from the living room's south, west and north walls and the back room's north wall.
fn small_windows(n: usize) -> Vec<Window> {
    // (wall, first centre, last centre along it)
    let walls: [(u8, f32, f32); 4] = [(0, 0.6, 4.6), (1, 0.6, 5.4), (2, 0.6, 4.6), (2, 5.6, 7.6)];
    let mut per_wall: Vec<Vec<Window>> = walls
        .iter()
        .map(|&(wall, first, last)| {
            let mut list = Vec::new();
            let mut along = first;
            while along <= last + 1e-3 {
                for sill in [0.7, 1.5] {
                    list.push((wall, along, sill, 0.3, 0.3));
                }
                along += 0.6;
            }
            list.reverse();
            list
        })
        .collect();
    let mut out = Vec::new();
    while out.len() < n && per_wall.iter().any(|l| !l.is_empty()) {
        for list in &mut per_wall {
            if out.len() < n {
                if let Some(w) = list.pop() {
                    out.push(w);
                }
            }
        }
    }
    out
}

/// The modelled window apertures, for tests of portal detection.
pub fn interior_windows() -> Vec<WindowAperture> {
    apertures(&WINDOWS)
}

/// The window apertures of [`interior_many_windows_builder`]`(n)`.
pub fn interior_small_windows(n: usize) -> Vec<WindowAperture> {
    apertures(&small_windows(n))
}

fn apertures(windows: &[Window]) -> Vec<WindowAperture> {
    windows
        .iter()
        .map(|&(wall, along, sill, w, h)| {
            let cy = sill + h / 2.0;
            match wall {
                0 => WindowAperture {
                    center: Vec3::new(along, cy, WALL / 2.0),
                    half_extents: [w / 2.0, h / 2.0],
                    outward: Vec3::NEG_Z,
                },
                1 => WindowAperture {
                    center: Vec3::new(WALL / 2.0, cy, along),
                    half_extents: [h / 2.0, w / 2.0],
                    outward: Vec3::NEG_X,
                },
                _ => WindowAperture {
                    center: Vec3::new(along, cy, HOUSE_Z - WALL / 2.0),
                    half_extents: [w / 2.0, h / 2.0],
                    outward: Vec3::Z,
                },
            }
        })
        .collect()
}

/// Axis-aligned boxes of one material.
struct Boxes {
    mesh: QuadMesh,
}

impl Boxes {
    fn new() -> Self {
        Boxes {
            mesh: QuadMesh::default(),
        }
    }

    /// Quad a-b-c-d, counter-clockwise seen from its front.
    fn quad(&mut self, a: Vec3, b: Vec3, c: Vec3, d: Vec3) {
        self.mesh.quad(a, b, c, d);
    }

    /// A closed box with outward-facing sides; empty boxes are skipped.
    fn cuboid(&mut self, min: Vec3, max: Vec3) {
        if (max - min).min_element() > 0.0 {
            self.mesh.cuboid(min, max);
        }
    }

    /// A wall slab from `min` to `max` with rectangular holes through its thin axis `normal`
    /// (0 = x, 2 = z): the slab is cut into boxes along its length axis at every hole edge,
    /// and each piece that overlaps holes keeps only what lies below, between and above them.
    fn wall_with_holes(
        &mut self,
        min: Vec3,
        max: Vec3,
        normal: usize,
        holes: &[(f32, f32, f32, f32)],
    ) {
        let length = 2 - normal; // the in-plane horizontal axis
        let mut cuts = vec![min[length], max[length]];
        for &(l0, l1, _, _) in holes {
            cuts.extend([l0, l1]);
        }
        cuts.sort_by(f32::total_cmp);
        cuts.dedup();
        for w in cuts.windows(2) {
            let (l0, l1) = (w[0], w[1]);
            let mut lo = min;
            let mut hi = max;
            lo[length] = l0;
            hi[length] = l1;
            let mid = 0.5 * (l0 + l1);
            // The holes over this piece, bottom first: the wall between and around them.
            let mut spans: Vec<(f32, f32)> = holes
                .iter()
                .filter(|h| h.0 < mid && mid < h.1)
                .map(|h| (h.2, h.3))
                .collect();
            spans.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mut from = lo;
            for (y0, y1) in spans {
                let mut to = hi;
                to.y = y0;
                self.cuboid(from, to);
                from.y = y1;
            }
            self.cuboid(from, hi);
        }
    }

    fn add_to(self, builder: &mut SceneBuilder, name: &str, material: u32) -> Result<()> {
        builder
            .add_mesh(MeshDesc {
                name: name.into(),
                positions: self.mesh.positions,
                indices: self.mesh.indices,
                materials: vec![material],
                ..Default::default()
            })
            .map(|_| ())
    }
}

/// The sky map compiled in (scenes/envmaps/sky.hdr, CC0).
const SKY_HDR: &[u8] = include_bytes!("../../scenes/envmaps/sky.hdr");

/// The sky environment of the interior: the map with the sun placed so that it shines
/// through the large south window (rotation about Y).
pub fn interior_sky() -> Result<EnvironmentMap> {
    let img = image::load_from_memory_with_format(SKY_HDR, image::ImageFormat::Hdr)
        .map_err(|e| Error::invalid(format!("built-in sky map: {e}")))?;
    let image = EnvImage::from_decoded(img)?;
    EnvironmentMap::new(
        image,
        EnvSettings {
            rotate_degrees: INTERIOR_SKY_ROTATION,
            ..EnvSettings::default()
        },
    )
}

/// Degrees the sky map is turned about Y in the interior.
pub const INTERIOR_SKY_ROTATION: f32 = 0.0;

/// The builder of the built-in interior (camera and sky included), ready to `build()`.
pub fn interior_builder() -> Result<SceneBuilder> {
    house_builder(&WINDOWS)
}

/// The interior with `n` (1..=[`MAX_SMALL_WINDOWS`]) small windows instead of its four
/// (`interior:windows=N`): many small openings, for the cost of window detection and of
/// portal-masked sampling as windows multiply.
pub fn interior_many_windows_builder(n: usize) -> Result<SceneBuilder> {
    if !(1..=MAX_SMALL_WINDOWS).contains(&n) {
        return Err(Error::invalid(format!(
            "interior:windows={n}: the count must be in [1, {MAX_SMALL_WINDOWS}]"
        )));
    }
    house_builder(&small_windows(n))
}

fn house_builder(windows: &[Window]) -> Result<SceneBuilder> {
    let mut b = SceneBuilder::new();
    let wall = b.add_material(Material {
        name: "wall".into(),
        ..Material::diffuse(Rgb::splat(0.7))
    })?;
    let floor = b.add_material(Material {
        name: "floor".into(),
        ..Material::diffuse(Rgb::new(0.5, 0.4, 0.3))
    })?;
    let ground = b.add_material(Material {
        name: "ground".into(),
        ..Material::diffuse(Rgb::new(0.25, 0.3, 0.2))
    })?;
    let furniture = b.add_material(Material {
        name: "furniture".into(),
        ..Material::diffuse(Rgb::new(0.2, 0.35, 0.55))
    })?;

    let mut walls = Boxes::new();
    let holes_of = |w: u8| -> Vec<(f32, f32, f32, f32)> {
        windows
            .iter()
            .filter(|win| win.0 == w)
            .map(|&(_, along, sill, width, height)| {
                (
                    along - width / 2.0,
                    along + width / 2.0,
                    sill,
                    sill + height,
                )
            })
            .collect()
    };
    // South and north walls span the full length; west and east walls fit between them.
    walls.wall_with_holes(
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(HOUSE_X, CEILING, WALL),
        2,
        &holes_of(0),
    );
    walls.wall_with_holes(
        Vec3::new(0.0, 0.0, HOUSE_Z - WALL),
        Vec3::new(HOUSE_X, CEILING, HOUSE_Z),
        2,
        &holes_of(2),
    );
    walls.wall_with_holes(
        Vec3::new(0.0, 0.0, WALL),
        Vec3::new(WALL, CEILING, HOUSE_Z - WALL),
        0,
        &holes_of(1),
    );
    walls.cuboid(
        Vec3::new(HOUSE_X - WALL, 0.0, WALL),
        Vec3::new(HOUSE_X, CEILING, HOUSE_Z - WALL),
    );
    // The partition with the inner door (a hole from the floor up).
    walls.wall_with_holes(
        Vec3::new(PARTITION_X0, 0.0, WALL),
        Vec3::new(PARTITION_X1, CEILING, HOUSE_Z - WALL),
        0,
        &[(DOOR_Z[0], DOOR_Z[1], 0.0, DOOR_Y1)],
    );
    // Ceiling slab.
    walls.cuboid(
        Vec3::new(0.0, CEILING, 0.0),
        Vec3::new(HOUSE_X, CEILING + WALL, HOUSE_Z),
    );
    walls.add_to(&mut b, "walls", wall)?;

    let mut floor_q = Boxes::new();
    floor_q.cuboid(Vec3::new(0.0, -WALL, 0.0), Vec3::new(HOUSE_X, 0.0, HOUSE_Z));
    floor_q.add_to(&mut b, "floor", floor)?;

    // Ground around the house, 6 m beyond it on every side.
    let mut ground_q = Boxes::new();
    let g = 6.0;
    ground_q.quad(
        Vec3::new(-g, -WALL, HOUSE_Z + g),
        Vec3::new(HOUSE_X + g, -WALL, HOUSE_Z + g),
        Vec3::new(HOUSE_X + g, -WALL, -g),
        Vec3::new(-g, -WALL, -g),
    );
    ground_q.add_to(&mut b, "ground", ground)?;

    // A table in the living room and a cabinet in the back room.
    let mut furniture_q = Boxes::new();
    furniture_q.cuboid(Vec3::new(1.6, 0.0, 2.2), Vec3::new(3.0, 0.75, 3.2));
    furniture_q.cuboid(Vec3::new(6.6, 0.0, 2.0), Vec3::new(7.8, 1.2, 2.6));
    furniture_q.add_to(&mut b, "furniture", furniture)?;

    b.set_environment(Some(Arc::new(interior_sky()?)));
    b.set_camera(Camera::look_at(
        Vec3::new(0.8, 1.6, 5.4),
        Vec3::new(5.5, 1.0, 2.5),
        Vec3::Y,
        65.0,
    )?)?;
    Ok(b)
}

/// Writes the interior as `interior.obj`, `interior.mtl` and `interior.json` (a scene file
/// with the camera and the sky map, `../envmaps/sky.hdr`) into `dir`, so that the scene file
/// in `scenes/interior/` is this code's output (tests/portals.rs checks it is). Returns the
/// scene file's path.
pub fn write_interior_files(dir: &std::path::Path) -> Result<std::path::PathBuf> {
    use std::fmt::Write as _;
    let scene = interior_builder()?.build()?;
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let header = "# Lacuna's built-in interior (src/scene/interior.rs, write_interior_files)\n";
    let mut mtl = String::from(header);
    for m in scene.materials() {
        let d = m.diffuse;
        let _ = writeln!(mtl, "newmtl {}\nKd {} {} {}", m.name, d.x, d.y, d.z);
    }
    let mut obj = format!("{header}mtllib interior.mtl\n");
    let mut base = 1;
    for mesh in scene.meshes() {
        let _ = writeln!(obj, "o {}", mesh.name);
        for p in &mesh.positions {
            let _ = writeln!(obj, "v {} {} {}", p.x, p.y, p.z);
        }
        let _ = writeln!(
            obj,
            "usemtl {}",
            scene.materials()[mesh.materials[0] as usize].name
        );
        for t in &mesh.indices {
            let _ = writeln!(
                obj,
                "f {} {} {}",
                t[0] as usize + base,
                t[1] as usize + base,
                t[2] as usize + base
            );
        }
        base += mesh.positions.len();
    }
    let c = scene.camera().expect("the interior has a camera");
    let json = format!(
        "{{\n  \"comment\": \"Lacuna's built-in interior (lacuna render interior), written by src/scene/interior.rs (write_interior_files): a house lit by the sky through four windows; the back room is reached only through the inner door. Window portals for path:env=portals are found automatically; list them under portals to set them by hand.\",\n  \"objects\": [{{ \"obj\": \"interior.obj\" }}],\n  \"environment\": {{ \"file\": \"../envmaps/sky.hdr\", \"rotate\": {INTERIOR_SKY_ROTATION} }},\n  \"camera\": {{ \"eye\": [{}, {}, {}], \"target\": [{}, {}, {}], \"up\": [0, 1, 0], \"fov\": {} }}\n}}\n",
        c.eye.x, c.eye.y, c.eye.z, c.target.x, c.target.y, c.target.z, c.vfov_degrees
    );
    let write = |name: &str, text: &str| {
        let path = dir.join(name);
        std::fs::write(&path, text).map_err(|e| Error::io(&path, e))?;
        Ok::<std::path::PathBuf, Error>(path)
    };
    write("interior.obj", &obj)?;
    write("interior.mtl", &mtl)?;
    write("interior.json", &json)
}
