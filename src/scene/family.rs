//! A procedural family of interiors, `rooms:SEED`: scenes no default was tuned on, for tests,
//! benchmarks and peers (written as OBJ + MTL + a scene file with [`FamilyScene::write_files`]).
//!
//! Each seed gives rooms on a grid (1 to 4 columns, 1 to 3 rows, at least two rooms) of random
//! widths and depths, walls 0.1 thick. Every pair of neighbouring rooms is joined by a random
//! spanning tree of doors (0.7 to 1.2 wide, 2 high, at a random place along the wall); the other
//! neighbours get an opening of random width and height with probability 0.3. One to three
//! square lights (0.3 to 0.9 wide, emitting downwards just under the ceiling height) hang in
//! random rooms; the camera stands in a random room looking at one of its doorways or across it.
//! Every surface is diffuse with albedo 0.7. About one seed in four is open: either roofless
//! (no ceiling) or with one outer side missing onto a large ground plane, so that much of the
//! light leaves the scene.
//!
//! Everything follows from the seed alone (PCG32 on stream `FAMILY_STREAM`), so `rooms:17`
//! is the same scene on every machine. [`FamilyScene::description`] says how many openings
//! separate the camera's room from each light's room (breadth-first over the room graph), which
//! is how benchmarks select the scenes where light must find its way through doors.

use std::collections::VecDeque;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::quad_mesh::QuadMesh;
use super::{Camera, Material, MeshDesc, SceneBuilder};
use crate::error::{Error, Result};
use crate::math::{Rgb, Rng, Vec3};

/// Wall thickness (metres).
const WALL: f32 = 0.1;
/// Door height (metres).
const DOOR_HEIGHT: f32 = 2.0;
/// Diffuse albedo of every surface.
const ALBEDO: f32 = 0.7;
/// Power of each light (radiance times area), so small lights are brighter.
const LIGHT_RADIANCE_AREA: f32 = 12.0;
/// Random stream of the generator (any constant: it only separates it from other users).
const FAMILY_STREAM: u64 = 0x0072_6f6f_6d73;
/// Half the side of the ground plane of scenes open to the outside (metres).
const OUTSIDE: f32 = 40.0;

/// How a family scene is open to the outside.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Openness {
    /// Walls, floor and ceiling all round.
    Closed,
    /// No ceiling.
    Roofless,
    /// The outer wall on the +x side is missing and the floor extends far outside.
    OpenSide,
}

impl Openness {
    pub fn name(self) -> &'static str {
        match self {
            Openness::Closed => "closed",
            Openness::Roofless => "roofless",
            Openness::OpenSide => "open-side",
        }
    }
}

/// An opening in the wall between two neighbouring rooms.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Opening {
    /// The two rooms (indices `row * columns + column`).
    pub rooms: [usize; 2],
    /// Width and height (metres).
    pub width: f32,
    pub height: f32,
    /// Whether it is one of the spanning tree's doors (else an extra opening).
    pub door: bool,
}

/// A square light hanging under the ceiling, facing down.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FamilyLight {
    pub room: usize,
    pub center: Vec3,
    /// Side (metres).
    pub size: f32,
    /// Emitted radiance (grey).
    pub radiance: f32,
    /// Openings between the camera's room and this light's room (0: the same room).
    pub openings_from_camera: u32,
}

/// One scene of the family: its plan and its camera; [`FamilyScene::builder`] makes the scene.
#[derive(Clone, Debug)]
pub struct FamilyScene {
    pub seed: u64,
    pub columns: usize,
    pub rows: usize,
    /// Column boundaries along x (`columns + 1`) and row boundaries along z (`rows + 1`).
    pub xs: Vec<f32>,
    pub zs: Vec<f32>,
    pub height: f32,
    pub openness: Openness,
    pub openings: Vec<Opening>,
    pub lights: Vec<FamilyLight>,
    pub camera_room: usize,
    pub camera: Camera,
    /// Wall pieces as boxes (min, max), outer walls, posts and lintels included.
    boxes: Vec<(Vec3, Vec3)>,
    /// Where each opening is along its wall: (wall position, start along the wall).
    placements: Vec<(f32, f32)>,
}

impl FamilyScene {
    /// The scene of `seed`.
    pub fn generate(seed: u64) -> FamilyScene {
        let mut rng = Rng::new(seed, FAMILY_STREAM);
        let mut uniform = |a: f32, b: f32| a + (b - a) * rng.uniform();
        let (columns, rows) = loop {
            let c = 1 + (uniform(0.0, 4.0) as usize).min(3);
            let r = 1 + (uniform(0.0, 3.0) as usize).min(2);
            if c * r >= 2 {
                break (c, r);
            }
        };
        let mut xs = vec![0.0];
        for _ in 0..columns {
            xs.push(xs.last().unwrap() + uniform(3.0, 5.5));
        }
        let mut zs = vec![0.0];
        for _ in 0..rows {
            zs.push(zs.last().unwrap() + uniform(3.0, 5.5));
        }
        let height = uniform(2.5, 3.2);
        let openness = match (uniform(0.0, 8.0) as u32).min(7) {
            0 => Openness::Roofless,
            1 => Openness::OpenSide,
            _ => Openness::Closed,
        };
        let mut rng = Rng::new(seed ^ 0x5eed, FAMILY_STREAM);
        let mut plan = FamilyScene {
            seed,
            columns,
            rows,
            xs,
            zs,
            height,
            openness,
            openings: Vec::new(),
            lights: Vec::new(),
            camera_room: 0,
            camera: Camera::look_at(Vec3::ZERO, Vec3::Z, Vec3::Y, 60.0).expect("valid"),
            boxes: Vec::new(),
            placements: Vec::new(),
        };
        plan.place_openings(&mut rng);
        plan.place_walls();
        plan.place_lights_and_camera(&mut rng);
        plan
    }

    /// The number of rooms.
    pub fn room_count(&self) -> usize {
        self.columns * self.rows
    }

    /// (x0, x1, z0, z1) of room `r`'s floor inside the walls.
    pub fn room_extent(&self, r: usize) -> (f32, f32, f32, f32) {
        let (i, j) = (r % self.columns, r / self.columns);
        let h = WALL / 2.0;
        (
            self.xs[i] + h,
            self.xs[i + 1] - h,
            self.zs[j] + h,
            self.zs[j + 1] - h,
        )
    }

    /// The fewest openings between the camera's room and any light's room.
    pub fn min_openings_to_light(&self) -> u32 {
        self.lights
            .iter()
            .map(|l| l.openings_from_camera)
            .min()
            .unwrap_or(0)
    }

    /// One line: size, openness, openings and lights with their distance from the camera.
    pub fn description(&self) -> String {
        let doors = self.openings.iter().filter(|o| o.door).count();
        let mut s = format!(
            "rooms:{}: {}x{} rooms, {}, {} doors and {} other openings, camera in room {}, lights",
            self.seed,
            self.columns,
            self.rows,
            self.openness.name(),
            doors,
            self.openings.len() - doors,
            self.camera_room
        );
        for l in &self.lights {
            let _ = write!(
                s,
                " [room {}, {} openings from the camera]",
                l.room, l.openings_from_camera
            );
        }
        s
    }

    fn place_openings(&mut self, rng: &mut Rng) {
        let (c, r) = (self.columns, self.rows);
        // Neighbour pairs (a, b) with a < b.
        let mut pairs = Vec::new();
        for j in 0..r {
            for i in 0..c {
                let a = j * c + i;
                if i + 1 < c {
                    pairs.push((a, a + 1));
                }
                if j + 1 < r {
                    pairs.push((a, a + c));
                }
            }
        }
        // A random spanning tree (random edge order, union-find) gets the doors.
        let mut order: Vec<usize> = (0..pairs.len()).collect();
        for k in (1..order.len()).rev() {
            let m = rng.below(k as u32 + 1) as usize;
            order.swap(k, m);
        }
        let mut parent: Vec<usize> = (0..c * r).collect();
        fn root(p: &mut [usize], mut x: usize) -> usize {
            while p[x] != x {
                p[x] = p[p[x]];
                x = p[x];
            }
            x
        }
        let mut chosen = vec![None; pairs.len()];
        for &e in &order {
            let (a, b) = pairs[e];
            let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
            if ra != rb {
                parent[ra] = rb;
                chosen[e] = Some(true);
            } else if rng.uniform() < 0.3 {
                chosen[e] = Some(false);
            }
        }
        for (e, &(a, b)) in pairs.iter().enumerate() {
            let Some(door) = chosen[e] else { continue };
            // Neighbours in one row share a wall at x = xs[i + 1], running along z.
            let along_x = b == a + 1 && a / c == b / c;
            let (lo, hi) = if along_x {
                let j = a / c;
                (self.zs[j], self.zs[j + 1])
            } else {
                let i = a % c;
                (self.xs[i], self.xs[i + 1])
            };
            let room = hi - lo - WALL - 0.4;
            let (width, height) = if door {
                (0.7 + 0.5 * rng.uniform(), DOOR_HEIGHT)
            } else {
                (
                    0.5 + (room - 0.5) * rng.uniform(),
                    1.0 + (self.height - 1.0) * rng.uniform(),
                )
            };
            let width = width.min(room);
            let start = lo + WALL / 2.0 + 0.2 + (room - width) * rng.uniform();
            let wall = if along_x {
                self.xs[a % c + 1]
            } else {
                self.zs[a / c + 1]
            };
            self.openings.push(Opening {
                rooms: [a, b],
                width,
                height,
                door,
            });
            self.placements.push((wall, start));
        }
    }

    /// The wall boxes: posts at every grid corner, and between posts a solid segment or one
    /// cut by its opening (left, right, lintel).
    fn place_walls(&mut self) {
        let (c, r) = (self.columns, self.rows);
        let h = WALL / 2.0;
        let top = self.height;
        let mut boxes = Vec::new();
        for &x in &self.xs {
            for &z in &self.zs {
                boxes.push((Vec3::new(x - h, 0.0, z - h), Vec3::new(x + h, top, z + h)));
            }
        }
        let open_side = self.openness == Openness::OpenSide;
        // Walls at x = xs[i], segments along z (rows).
        for (i, &x) in self.xs.iter().enumerate() {
            if open_side && i == c {
                continue;
            }
            for j in 0..r {
                let opening = (i > 0 && i < c).then(|| {
                    let a = j * c + i - 1;
                    self.opening_between(a, a + 1)
                });
                let (z0, z1) = (self.zs[j] + h, self.zs[j + 1] - h);
                wall_segment(
                    &mut boxes,
                    opening.flatten(),
                    top,
                    z0,
                    z1,
                    |along, y0, y1| (Vec3::new(x - h, y0, along.0), Vec3::new(x + h, y1, along.1)),
                );
            }
        }
        // Walls at z = zs[j], segments along x (columns).
        for (j, &z) in self.zs.iter().enumerate() {
            for i in 0..c {
                let opening = (j > 0 && j < r).then(|| {
                    let a = (j - 1) * c + i;
                    self.opening_between(a, a + c)
                });
                let (x0, x1) = (self.xs[i] + h, self.xs[i + 1] - h);
                wall_segment(
                    &mut boxes,
                    opening.flatten(),
                    top,
                    x0,
                    x1,
                    |along, y0, y1| (Vec3::new(along.0, y0, z - h), Vec3::new(along.1, y1, z + h)),
                );
            }
        }
        self.boxes = boxes;
    }

    /// (start, end, height) of the opening between rooms `a` and `b`, if any.
    fn opening_between(&self, a: usize, b: usize) -> Option<(f32, f32, f32)> {
        self.openings
            .iter()
            .zip(&self.placements)
            .find(|(o, _)| o.rooms == [a, b])
            .map(|(o, &(_, start))| (start, start + o.width, o.height))
    }

    /// Rooms reachable from `from` through openings: the number of openings crossed.
    fn openings_from(&self, from: usize) -> Vec<u32> {
        let mut dist = vec![u32::MAX; self.room_count()];
        dist[from] = 0;
        let mut queue = VecDeque::from([from]);
        while let Some(a) = queue.pop_front() {
            for o in &self.openings {
                let b = match o.rooms {
                    [x, y] if x == a => y,
                    [x, y] if y == a => x,
                    _ => continue,
                };
                if dist[b] == u32::MAX {
                    dist[b] = dist[a] + 1;
                    queue.push_back(b);
                }
            }
        }
        dist
    }

    fn place_lights_and_camera(&mut self, rng: &mut Rng) {
        let rooms = self.room_count();
        self.camera_room = rng.below(rooms as u32) as usize;
        let dist = self.openings_from(self.camera_room);
        let count = 1 + rng.below(3) as usize;
        for _ in 0..count {
            let room = rng.below(rooms as u32) as usize;
            let (x0, x1, z0, z1) = self.room_extent(room);
            let size = 0.3 + 0.6 * rng.uniform();
            let margin = size / 2.0 + 0.3;
            let x = x0 + margin + (x1 - x0 - 2.0 * margin) * rng.uniform();
            let z = z0 + margin + (z1 - z0 - 2.0 * margin) * rng.uniform();
            self.lights.push(FamilyLight {
                room,
                center: Vec3::new(x, self.height - 0.02, z),
                size,
                radiance: LIGHT_RADIANCE_AREA / (size * size),
                openings_from_camera: dist[room],
            });
        }
        // The camera: inside its room, 0.4 from the walls, looking at one of the room's
        // openings (the first choice) or at a random point across the room.
        let (x0, x1, z0, z1) = self.room_extent(self.camera_room);
        let eye = Vec3::new(
            x0 + 0.4 + (x1 - x0 - 0.8) * rng.uniform(),
            1.2 + 0.6 * rng.uniform(),
            z0 + 0.4 + (z1 - z0 - 0.8) * rng.uniform(),
        );
        let doorways: Vec<Vec3> = self
            .openings
            .iter()
            .zip(&self.placements)
            .filter(|(o, _)| o.rooms.contains(&self.camera_room))
            .map(|(o, &(wall, start))| {
                let mid = start + o.width / 2.0;
                let y = o.height.min(DOOR_HEIGHT) * 0.5;
                if o.rooms[1] == o.rooms[0] + 1
                    && o.rooms[0] / self.columns == o.rooms[1] / self.columns
                {
                    Vec3::new(wall, y, mid)
                } else {
                    Vec3::new(mid, y, wall)
                }
            })
            .collect();
        let target = if !doorways.is_empty() && rng.uniform() < 0.7 {
            doorways[rng.below(doorways.len() as u32) as usize]
        } else {
            // Across the room: the far half from the eye.
            let cx = (x0 + x1) / 2.0;
            let cz = (z0 + z1) / 2.0;
            Vec3::new(
                2.0 * cx - eye.x,
                0.8 + 0.6 * rng.uniform(),
                2.0 * cz - eye.z,
            )
        };
        let target = if (target - eye).length() < 0.5 {
            eye + Vec3::new(1.0, -0.2, 0.3)
        } else {
            target
        };
        let fov = 50.0 + 20.0 * rng.uniform();
        self.camera = Camera::look_at(eye, target, Vec3::Y, fov).expect("eye differs from target");
    }

    /// Triangle meshes: (name, material index, positions, triangles); materials 0 walls,
    /// 1 light.
    fn meshes(&self) -> Vec<NamedMesh> {
        let (xmax, zmax) = (*self.xs.last().unwrap(), *self.zs.last().unwrap());
        let h = WALL / 2.0;
        let mut walls = QuadMesh::default();
        let (fx0, fx1, fz0, fz1) = if self.openness == Openness::OpenSide {
            (-OUTSIDE, xmax + OUTSIDE, -OUTSIDE, zmax + OUTSIDE)
        } else {
            (-h, xmax + h, -h, zmax + h)
        };
        walls.cuboid(Vec3::new(fx0, -WALL, fz0), Vec3::new(fx1, 0.0, fz1));
        if self.openness != Openness::Roofless {
            walls.cuboid(
                Vec3::new(-h, self.height, -h),
                Vec3::new(xmax + h, self.height + WALL, zmax + h),
            );
        }
        for &(a, b) in &self.boxes {
            walls.cuboid(a, b);
        }
        let mut lights = QuadMesh::default();
        for l in &self.lights {
            let s = l.size / 2.0;
            let c = l.center;
            // Counter-clockwise seen from below: faces -y.
            lights.quad(
                Vec3::new(c.x - s, c.y, c.z - s),
                Vec3::new(c.x + s, c.y, c.z - s),
                Vec3::new(c.x + s, c.y, c.z + s),
                Vec3::new(c.x - s, c.y, c.z + s),
            );
        }
        vec![
            ("walls", 0, walls.positions, walls.indices),
            ("lights", 1, lights.positions, lights.indices),
        ]
    }

    /// The scene's builder, camera included.
    pub fn builder(&self) -> Result<SceneBuilder> {
        let mut b = SceneBuilder::new();
        let wall = b.add_material(Material {
            name: "wall".into(),
            ..Material::diffuse(Rgb::splat(ALBEDO))
        })?;
        let mut light_materials = Vec::new();
        for (k, l) in self.lights.iter().enumerate() {
            light_materials.push(b.add_material(Material {
                name: format!("light{k}"),
                ..Material::emissive(Rgb::splat(l.radiance))
            })?);
        }
        for (name, material, positions, indices) in self.meshes() {
            if material == 0 {
                b.add_mesh(MeshDesc {
                    name: name.into(),
                    positions,
                    indices,
                    materials: vec![wall],
                    ..Default::default()
                })?;
            } else {
                // Two triangles per light, each light its own material (radiance).
                let materials = (0..indices.len()).map(|t| light_materials[t / 2]).collect();
                b.add_mesh(MeshDesc {
                    name: name.into(),
                    positions,
                    indices,
                    materials,
                    ..Default::default()
                })?;
            }
        }
        b.set_camera(self.camera)?;
        Ok(b)
    }

    /// Writes `rooms-SEED.obj`, `rooms-SEED.mtl` and `rooms-SEED.json` (a scene file with the
    /// camera) into `dir`, so that other renderers can load the same scene. Returns the scene
    /// file's path.
    pub fn write_files(&self, dir: &Path) -> Result<PathBuf> {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        let stem = format!("rooms-{}", self.seed);
        let mut mtl = format!(
            "# {}\nnewmtl wall\nKd {ALBEDO} {ALBEDO} {ALBEDO}\n",
            self.description()
        );
        for (k, l) in self.lights.iter().enumerate() {
            let _ = write!(
                mtl,
                "newmtl light{k}\nKd 0 0 0\nKe {r} {r} {r}\n",
                r = l.radiance
            );
        }
        let mut obj = format!("# {}\nmtllib {stem}.mtl\n", self.description());
        let mut base = 1;
        for (name, material, positions, indices) in self.meshes() {
            let _ = writeln!(obj, "o {name}");
            for p in &positions {
                let _ = writeln!(obj, "v {} {} {}", p.x, p.y, p.z);
            }
            for (t, tri) in indices.iter().enumerate() {
                if t % 2 == 0 {
                    let m = if material == 0 {
                        "wall".to_string()
                    } else {
                        format!("light{}", t / 2)
                    };
                    if t == 0 || material != 0 {
                        let _ = writeln!(obj, "usemtl {m}");
                    }
                }
                let _ = writeln!(
                    obj,
                    "f {} {} {}",
                    tri[0] as usize + base,
                    tri[1] as usize + base,
                    tri[2] as usize + base
                );
            }
            base += positions.len();
        }
        let c = &self.camera;
        let json = format!(
            "{{\n  \"objects\": [{{ \"obj\": \"{stem}.obj\" }}],\n  \"camera\": {{ \"eye\": [{}, {}, {}], \"target\": [{}, {}, {}], \"up\": [0, 1, 0], \"fov\": {} }}\n}}\n",
            c.eye.x, c.eye.y, c.eye.z, c.target.x, c.target.y, c.target.z, c.vfov_degrees
        );
        let write = |name: String, text: &str| {
            let path = dir.join(name);
            std::fs::write(&path, text).map_err(|e| Error::io(&path, e))?;
            Ok::<PathBuf, Error>(path)
        };
        write(format!("{stem}.obj"), &obj)?;
        write(format!("{stem}.mtl"), &mtl)?;
        write(format!("{stem}.json"), &json)
    }
}

/// A mesh of the family: (name, material index, positions, triangles).
type NamedMesh = (&'static str, u32, Vec<Vec3>, Vec<[u32; 3]>);

/// Parses a family scene name `rooms:SEED`.
pub fn parse_family_name(name: &str) -> Option<u64> {
    name.strip_prefix("rooms:")?.parse().ok()
}

/// The boxes of one wall segment from `lo` to `hi` along the wall, cut by `opening` (start,
/// end, height); `make` turns (along range, y0, y1) into a box.
fn wall_segment(
    boxes: &mut Vec<(Vec3, Vec3)>,
    opening: Option<(f32, f32, f32)>,
    top: f32,
    lo: f32,
    hi: f32,
    make: impl Fn((f32, f32), f32, f32) -> (Vec3, Vec3),
) {
    match opening {
        None => boxes.push(make((lo, hi), 0.0, top)),
        Some((a, b, height)) => {
            if a > lo {
                boxes.push(make((lo, a), 0.0, top));
            }
            if b < hi {
                boxes.push(make((b, hi), 0.0, top));
            }
            if height < top {
                boxes.push(make((a, b), height, top));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_scene_and_every_room_reachable() {
        for seed in 0..64 {
            let a = FamilyScene::generate(seed);
            let b = FamilyScene::generate(seed);
            assert_eq!(a.description(), b.description());
            assert_eq!(a.boxes, b.boxes);
            assert!(a.room_count() >= 2);
            assert!((1..=3).contains(&a.lights.len()));
            assert!(a.openings.iter().filter(|o| o.door).count() == a.room_count() - 1);
            let dist = a.openings_from(a.camera_room);
            assert!(dist.iter().all(|&d| d != u32::MAX), "rooms:{seed}");
            // The camera stands inside its room, below the ceiling.
            let (x0, x1, z0, z1) = a.room_extent(a.camera_room);
            let e = a.camera.eye;
            assert!(e.x > x0 && e.x < x1 && e.z > z0 && e.z < z1 && e.y < a.height);
            assert!(a.builder().unwrap().build().is_ok());
            // Every opening lies within its wall, between the posts.
            for (o, &(_, start)) in a.openings.iter().zip(&a.placements) {
                let [r0, r1] = o.rooms;
                let (x0, x1, z0, z1) = a.room_extent(r0);
                let (lo, hi) = if r1 == r0 + 1 && r0 / a.columns == r1 / a.columns {
                    (z0, z1)
                } else {
                    (x0, x1)
                };
                assert!(start >= lo && start + o.width <= hi, "rooms:{seed} {o:?}");
            }
        }
    }

    #[test]
    fn the_family_has_open_scenes_and_deep_ones() {
        let scenes: Vec<FamilyScene> = (0..64).map(FamilyScene::generate).collect();
        assert!(scenes.iter().any(|s| s.openness == Openness::Roofless));
        assert!(scenes.iter().any(|s| s.openness == Openness::OpenSide));
        assert!(
            scenes
                .iter()
                .filter(|s| s.min_openings_to_light() >= 2)
                .count()
                >= 5
        );
        assert_eq!(parse_family_name("rooms:17"), Some(17));
        assert_eq!(parse_family_name("rooms:x"), None);
    }

    /// The OBJ written for peers loads back with the same triangle count and light count.
    #[test]
    fn written_files_load_back() {
        let scene = FamilyScene::generate(3);
        let dir = std::env::temp_dir().join(format!("lacuna-family-{}", std::process::id()));
        let json = scene.write_files(&dir).unwrap();
        let loaded = super::super::load_scene_file(&json).unwrap();
        let from_file = loaded.builder.build().unwrap();
        let direct = scene.builder().unwrap().build().unwrap();
        assert_eq!(from_file.triangle_count(), direct.triangle_count());
        assert_eq!(from_file.lights().len(), direct.lights().len());
        assert_eq!(
            from_file.camera().unwrap().eye,
            direct.camera().unwrap().eye
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
