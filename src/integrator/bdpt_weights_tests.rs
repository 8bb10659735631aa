//! The MIS weights bdpt computes in O(1) per connection, from the partial sums carried along
//! each subpath, must equal the heuristic evaluated over every strategy's pdf of the same
//! path, computed here explicitly vertex by vertex (Veach 1997 §10.2, 000 eq. 122).
//!
//! The integrator traces real light subpaths and camera paths in a scene with diffuse, glossy,
//! mirror and glass surfaces under area, point, spot and directional lights, with Russian
//! roulette; a [`PathObserver`] records every vertex and every estimate, and each estimate's
//! weight is compared with the explicit one for the full path it belongs to. The explicit
//! weights of all strategies of each path sum to one, so the integrator's do too.
//!
//! The explicit model, for a path x_0 (camera or lens point) ... x_k (on a light) and strategy
//! (s, t) with s + t = k + 1 (camera vertices x_0..x_{t-1}, light vertices x_t..x_k):
//! p_{s,t} = prod_{i=1}^{t-1} Pc(i) * prod_{i=t}^{k} Pl(i), times the number of samples the
//! strategy takes per camera path: the number of light subpaths when t = 1 (the image gets
//! that many light-tracing samples per camera sample), the connection policy's count for
//! s >= 2, t >= 2 (1 by default, N when every camera vertex connects to all N subpaths). Pc(i) is the
//! area density of x_i sampled from x_{i-1} by the camera side, Pl(i) from x_{i+1} by the light
//! side: BSDF pdf times continuation probability times cos / distance^2 (camera rays: d^2 /
//! cos^3; emission: the light's direction density; directional lights: the disk density times
//! cos, no distance). Dirac densities count a delta: through a specular vertex j towards x_n
//! they are cos_j cos_n / dist^2 * eta_n^2, eta_n the refractive index on x_n's side: the
//! delta of the specular map in projected solid angle, which étendue conservation makes the
//! same both ways once scaled by eta^2, times the geometry term. (The discrete lobe
//! probability is the same both ways and cancels.) Delta lights add a delta at their
//! position or direction. Only the strategies with the most deltas have non-zero weight.
//! Connections at a specular vertex have no density. The camera's own point (pinhole or
//! uniform lens) has the same density in every strategy and is left out. Cosines use shading
//! normals, as the integrator's do.

use super::*;
use crate::light::{EnvStrategy, Light, LightDesc};
use crate::math::{INV_4PI, INV_PI, PI};
use crate::scene::{Camera, Material, MeshDesc, SceneBuilder};

/// One vertex of a recorded full path.
#[derive(Clone, Copy, Debug)]
enum PathPoint {
    /// x_0: the eye or the lens point.
    Camera(Vec3),
    Surface(SurfaceInteraction),
    /// x_k: a point of light `index` (unused for directional lights).
    Light(usize, Vec3),
    /// x_k on environment light `index`: the unit direction from x_{k-1} towards it.
    Sky(usize, Vec3),
}

/// An estimate the integrator made, with its full path x_0..x_k.
struct Recorded {
    estimate: Estimate,
    path: Vec<PathPoint>,
}

/// Records subpaths and turns every estimate into its full path.
struct Recorder<'a> {
    scene: &'a Scene,
    /// Light end (a light point or a sky direction) and surface vertices of each light
    /// subpath traced so far.
    light_paths: Vec<(PathPoint, Vec<SurfaceInteraction>)>,
    camera: Vec<PathPoint>,
    tracing_light: bool,
    recorded: Vec<Recorded>,
}

impl Recorder<'_> {
    fn light_part(&self, path: usize, s: u32) -> Vec<PathPoint> {
        let (end, surfaces) = &self.light_paths[path];
        let mut part: Vec<PathPoint> = surfaces[..s as usize - 1]
            .iter()
            .rev()
            .map(|si| PathPoint::Surface(*si))
            .collect();
        part.push(*end);
        part
    }
}

impl PathObserver for Recorder<'_> {
    fn light_start(&mut self, light: usize, point: Vec3, dir: Vec3) {
        let end = match self.scene.lights()[light] {
            Light::Environment { .. } => PathPoint::Sky(light, -dir),
            _ => PathPoint::Light(light, point),
        };
        self.light_paths.push((end, Vec::new()));
    }

    fn light_vertex(&mut self, si: &SurfaceInteraction) {
        self.light_paths.last_mut().unwrap().1.push(*si);
    }

    fn camera_vertex(&mut self, p: Vec3, si: Option<&SurfaceInteraction>) {
        self.camera.push(match si {
            None => PathPoint::Camera(p),
            Some(si) => PathPoint::Surface(*si),
        });
    }

    fn estimate(&mut self, e: &Estimate, end: Endpoint) {
        let path = if self.tracing_light {
            let Endpoint::Lens(lens) = end else {
                panic!("light tracing without a lens point")
            };
            assert_eq!(e.t, 1);
            let mut path = vec![PathPoint::Camera(lens)];
            path.extend(self.light_part(self.light_paths.len() - 1, e.s));
            path
        } else {
            if let (0, Endpoint::Sky(light, dir)) = (e.s, end) {
                // The sky is the camera path's last vertex, past its surface vertices.
                let mut path = self.camera[..e.t as usize - 1].to_vec();
                path.push(PathPoint::Sky(light, dir));
                assert_eq!(path.len() as u32, e.t);
                self.recorded.push(Recorded { estimate: *e, path });
                return;
            }
            let mut path = self.camera[..e.t as usize].to_vec();
            match (e.s, end) {
                (0, Endpoint::None) => {
                    let PathPoint::Surface(si) = path.pop().unwrap() else {
                        panic!("s = 0 ends on a surface")
                    };
                    let light = self.scene.triangle_light(si.triangle).unwrap();
                    path.push(PathPoint::Light(light, si.p));
                }
                (1, Endpoint::Light(light, point)) => path.push(PathPoint::Light(light, point)),
                (1, Endpoint::Sky(light, dir)) => path.push(PathPoint::Sky(light, dir)),
                (s, Endpoint::LightPath(j)) if s >= 2 => path.extend(self.light_part(j, s)),
                other => panic!("unexpected estimate {other:?}"),
            }
            path
        };
        assert_eq!(path.len() as u32, e.s + e.t);
        self.recorded.push(Recorded { estimate: *e, path });
    }
}

/// A density with its number of Dirac factors.
#[derive(Clone, Copy, Debug)]
struct Density {
    value: f64,
    deltas: u32,
}

impl Density {
    const ONE: Density = Density {
        value: 1.0,
        deltas: 0,
    };
    const ZERO: Density = Density {
        value: 0.0,
        deltas: 0,
    };

    fn finite(value: f64) -> Self {
        Density { value, deltas: 0 }
    }

    fn delta(value: f64) -> Self {
        Density { value, deltas: 1 }
    }

    fn times(self, o: Density) -> Density {
        Density {
            value: self.value * o.value,
            deltas: self.deltas + o.deltas,
        }
    }
}

/// The explicit model's settings, and deliberate mistakes in it (to show the comparison
/// catches a wrong weight).
#[derive(Clone, Copy, Debug)]
struct Model {
    mis: MisHeuristic,
    /// How light sampling picks environment directions.
    env: EnvStrategy,
    n_light: f64,
    /// Samples of each connection strategy (s >= 2, t >= 2) per camera path.
    n_conn: f64,
    /// Include the Russian-roulette continuation probabilities.
    roulette: bool,
    /// Include cos / dist^2 in densities through specular vertices (else 1, as pbrt-v3's
    /// remapping does).
    specular_geometry: bool,
    /// A light field's direct-sampling density of its image-plane point is restricted
    /// sampling's from the receiver (else, wrongly, emission's density of that point).
    field_direct_at_receiver: bool,
}

struct Explicit<'a> {
    scene: &'a Scene,
    view: &'a View,
    model: Model,
    path: &'a [PathPoint],
}

impl Explicit<'_> {
    fn k(&self) -> usize {
        self.path.len() - 1
    }

    fn pos(&self, i: usize) -> Vec3 {
        match self.path[i] {
            PathPoint::Camera(p) | PathPoint::Light(_, p) => p,
            PathPoint::Surface(si) => si.p,
            PathPoint::Sky(..) => panic!("the sky has no position"),
        }
    }

    fn bsdf(&self, i: usize) -> Option<Bsdf> {
        match &self.path[i] {
            PathPoint::Surface(si) => Some(self.scene.bsdf(si)),
            _ => None,
        }
    }

    fn is_delta_surface(&self, i: usize) -> bool {
        self.bsdf(i).is_some_and(|b| b.is_delta())
    }

    fn light_index(&self) -> usize {
        match self.path[self.k()] {
            PathPoint::Light(l, _) | PathPoint::Sky(l, _) => l,
            _ => panic!("path must end on a light"),
        }
    }

    fn light(&self) -> &Light {
        &self.scene.lights()[self.light_index()]
    }

    fn pick(&self) -> f64 {
        self.scene.light_sampler().unwrap().pmf(self.light_index()) as f64
    }

    fn is_sky(&self, i: usize) -> bool {
        matches!(self.path[i], PathPoint::Sky(..))
    }

    /// Unit direction from x_from to x_to (towards or from infinity for a directional light).
    fn dir(&self, from: usize, to: usize) -> Vec3 {
        if let PathPoint::Sky(_, w) = self.path[to] {
            return w;
        }
        if let PathPoint::Sky(_, w) = self.path[from] {
            return -w;
        }
        let travel = |i: usize| match self.path[i] {
            PathPoint::Light(l, _) => match self.scene.lights()[l] {
                Light::Directional { direction, .. } => Some(direction),
                _ => None,
            },
            _ => None,
        };
        if let Some(d) = travel(to) {
            return -d;
        }
        if let Some(d) = travel(from) {
            return d;
        }
        (self.pos(to) - self.pos(from)).normalize()
    }

    fn dist2(&self, a: usize, b: usize) -> f64 {
        (self.pos(a) - self.pos(b)).length_squared() as f64
    }

    /// |normal . direction to `towards`| at vertex i (area lights: their normal).
    fn cos(&self, i: usize, towards: usize) -> f64 {
        let n = match self.path[i] {
            PathPoint::Surface(si) => si.ns,
            PathPoint::Light(l, _) => match self.scene.lights()[l] {
                Light::Area { normal, .. } => normal,
                _ => panic!("cosine at a delta light"),
            },
            PathPoint::Camera(_) => panic!("cosine at the camera"),
            PathPoint::Sky(..) => panic!("cosine at the sky"),
        };
        n.dot(self.dir(i, towards)).abs() as f64
    }

    fn continuation(&self, b: &Bsdf) -> f64 {
        if self.model.roulette {
            continuation(b) as f64
        } else {
            1.0
        }
    }

    /// Density of sampling x_to from x_from (a surface) that was reached from x_prev.
    fn scatter_density(&self, prev: usize, from: usize, to: usize) -> Density {
        let b = self.bsdf(from).expect("scattering at a surface");
        let PathPoint::Surface(si) = self.path[from] else {
            unreachable!()
        };
        let cont = self.continuation(&b);
        let frame = si.shading_frame();
        let wo = frame.to_local(self.dir(from, prev));
        let wi = frame.to_local(self.dir(from, to));
        // Towards the sky the measure is the solid angle: no geometry term at its end.
        let sky = self.is_sky(to);
        if b.is_delta() {
            let geometry = if self.model.specular_geometry {
                // Refraction: eta^2 on the side of `to` (front side 1, back side the
                // dielectric's index).
                let eta_to = match b {
                    Bsdf::Dielectric { eta } if wi.z < 0.0 => eta as f64,
                    _ => 1.0,
                };
                let at_to = if sky {
                    1.0
                } else {
                    self.cos(to, from) / self.dist2(from, to)
                };
                self.cos(from, to) * at_to * eta_to * eta_to
            } else {
                1.0
            };
            return Density::delta(cont * geometry);
        }
        if sky {
            return Density::finite(b.pdf(wo, wi) as f64 * cont);
        }
        Density::finite(b.pdf(wo, wi) as f64 * cont * self.cos(to, from) / self.dist2(from, to))
    }

    /// Pc(i): x_i sampled by the camera side.
    fn camera_density(&self, i: usize) -> Density {
        if i == self.k() && self.light().is_delta() {
            return Density::ZERO; // a camera path never hits a delta light
        }
        if i == 1 {
            let dir = self.dir(0, 1);
            let cos = dir.dot(self.view.frame.forward) as f64;
            let d = self.view.frame.image_plane_distance(self.view.height) as f64;
            let pdf_w = d * d / (cos * cos * cos);
            return Density::finite(pdf_w * self.cos(1, 0) / self.dist2(0, 1));
        }
        self.scatter_density(i - 2, i - 1, i)
    }

    /// Pl(i): x_i sampled by the light side.
    fn light_density(&self, i: usize) -> Density {
        let k = self.k();
        let pick = self.pick();
        if i == k {
            return match *self.light() {
                Light::Area { area, .. } => Density::finite(pick / area as f64),
                // Emission picks the direction first, by the map's emission strategy.
                Light::Environment { ref map, .. } => Density::finite(
                    pick * map.pdf(
                        self.model.env.for_emission(),
                        Vec3::ZERO,
                        self.dir(i - 1, i),
                    ) as f64,
                ),
                // Emission picks the image-plane point x_k and the direction of the ray from
                // the filter plane through it together: their joint density (area on the
                // image plane times solid angle there; `light_density(k - 1)` converts the
                // solid angle to area at x_{k-1}). A finite density, though no ray hits x_k.
                Light::LightField { .. } => Density::finite(
                    pick * self.light().emission_pdf_at(
                        self.model.env,
                        self.pos(k),
                        self.dir(k, k - 1),
                    ) as f64,
                ),
                _ => Density::delta(pick), // a point's position or a direction
            };
        }
        if i + 1 == k {
            let to_vertex = self.dir(k, i);
            let area_factor = |pdf_w: f64| pdf_w * self.cos(i, k) / self.dist2(i, k);
            return match *self.light() {
                Light::Area { normal, .. } => {
                    let c = normal.dot(to_vertex).max(0.0) as f64;
                    Density::finite(area_factor(c * INV_PI as f64))
                }
                Light::Point { .. } => Density::finite(area_factor(INV_4PI as f64)),
                Light::Spot {
                    direction,
                    cos_outer,
                    ..
                } => {
                    let inside = direction.dot(to_vertex) >= cos_outer;
                    let pdf = if inside {
                        1.0 / (2.0 * PI as f64 * (1.0 - cos_outer as f64))
                    } else {
                        0.0
                    };
                    Density::finite(area_factor(pdf))
                }
                Light::Directional {
                    direction,
                    scene_radius,
                    ..
                } => {
                    let PathPoint::Surface(si) = self.path[i] else {
                        unreachable!()
                    };
                    let r = scene_radius as f64;
                    Density::finite(si.ns.dot(direction).abs() as f64 / (PI as f64 * r * r))
                }
                Light::Photometric {
                    frame, ref profile, ..
                } => Density::finite(area_factor(
                    profile.direction_pdf(frame.to_local(to_vertex)) as f64,
                )),
                // Then the ray's origin, uniform on the disk of the bounding sphere facing it:
                // like a directional light.
                Light::Environment { scene_radius, .. } => {
                    let r = scene_radius as f64;
                    Density::finite(self.cos(i, k) / (PI as f64 * r * r))
                }
                // The emitted ray's direction density at the image-plane point x_k (in
                // `light_density(k)`, with its area density) converted to area here.
                Light::LightField { .. } => Density::finite(self.cos(i, k) / self.dist2(i, k)),
            };
        }
        self.scatter_density(i + 2, i + 1, i)
    }

    /// p_{s,t} of this path.
    fn strategy_density(&self, s: usize) -> Density {
        let k = self.k();
        let t = k + 1 - s;
        if k == 1 {
            return if s == 0 { Density::ONE } else { Density::ZERO };
        }
        if s == 0 {
            if !matches!(self.light(), Light::Area { .. } | Light::Environment { .. }) {
                return Density::ZERO;
            }
            return (1..=k).fold(Density::ONE, |p, i| p.times(self.camera_density(i)));
        }
        // Connection between x_{t-1} and x_t: neither end may be specular.
        if (t >= 2 && self.is_delta_surface(t - 1)) || (s >= 2 && self.is_delta_surface(t)) {
            return Density::ZERO;
        }
        let camera = (1..t).fold(Density::ONE, |p, i| p.times(self.camera_density(i)));
        let light = if let (1, Light::Environment { map, .. }) = (s, self.light()) {
            // Direct sampling picks the sky's direction by the light-sampling strategy, for
            // the camera vertex's shading normal facing where its path came from.
            let PathPoint::Surface(si) = self.path[k - 1] else {
                unreachable!()
            };
            let towards_camera = self.dir(k - 1, k - 2);
            let n = if si.ns.dot(towards_camera) < 0.0 {
                -si.ns
            } else {
                si.ns
            };
            Density::finite(self.pick() * map.pdf(self.model.env, n, self.dir(k - 1, k)) as f64)
        } else if let (1, Light::LightField { .. }) = (s, self.light()) {
            // Direct sampling picks the image-plane point by restricted sampling, whose
            // density depends on the receiver x_{k-1}: not emission's density of x_k.
            let light = self.light();
            let area = if self.model.field_direct_at_receiver {
                light.direct_pdf_area_from(self.pos(k - 1), self.pos(k))
            } else {
                let emit = light.emission_pdf_at(self.model.env, self.pos(k), self.dir(k, k - 1));
                light.split_emission_pdf(self.pos(k), emit).0
            };
            Density::finite(self.pick() * area as f64)
        } else {
            (t..=k).fold(Density::ONE, |p, i| p.times(self.light_density(i)))
        };
        let mut p = camera.times(light);
        if t == 1 {
            p.value *= self.model.n_light;
        } else if s >= 2 {
            p.value *= self.model.n_conn;
        }
        p
    }

    /// Weights of every strategy s = 0..=k of this path.
    fn weights(&self) -> Vec<f64> {
        let densities: Vec<Density> = (0..=self.k()).map(|s| self.strategy_density(s)).collect();
        let most = densities
            .iter()
            .filter(|d| d.value > 0.0)
            .map(|d| d.deltas)
            .max()
            .unwrap_or(0);
        let power = |d: &Density| {
            if d.deltas != most || !(d.value > 0.0) {
                0.0
            } else {
                match self.model.mis {
                    MisHeuristic::Balance | MisHeuristic::Auto | MisHeuristic::Optimal => d.value,
                    MisHeuristic::Power => d.value * d.value,
                }
            }
        };
        let sum: f64 = densities.iter().map(power).sum();
        densities.iter().map(|d| power(d) / sum).collect()
    }
}

/// A box open at the top: glossy floor, diffuse back wall, mirror left wall, sharp glossy right
/// wall, a glass slab, a small area light, and point, spot and directional lights; with `sky`,
/// also the interior's sky map (a sun, and per-normal face balancing in direct sampling); with
/// `field`, also a light-field luminaire ([`test_light_field`]). The floor and the area light
/// have tilted vertex normals, so shading and geometric normals differ.
fn test_scene(sky: bool, field: bool) -> Scene {
    let mut b = SceneBuilder::new();
    if field {
        b.add_light(LightDesc::LightField {
            position: Vec3::new(0.3, 0.6, 0.2),
            direction: -Vec3::Y,
            x_axis: Vec3::new(1.0, 0.0, 0.3),
            scale: Rgb::ONE,
            field: std::sync::Arc::new(test_light_field()),
        })
        .unwrap();
    }
    if sky {
        b.set_environment(Some(std::sync::Arc::new(
            crate::scene::interior_sky().unwrap(),
        )));
    }
    let wall = b
        .add_material(Material::diffuse(Rgb::new(0.7, 0.6, 0.5)))
        .unwrap();
    let glossy = b
        .add_material(Material::glossy(Rgb::splat(0.3), Rgb::splat(0.5), 50.0))
        .unwrap();
    let sharp = b
        .add_material(Material::glossy(Rgb::splat(0.2), Rgb::splat(0.7), 1e3))
        .unwrap();
    let mirror = b.add_material(Material::mirror(Rgb::splat(0.9))).unwrap();
    let glass = b.add_material(Material::dielectric(1.5)).unwrap();
    let light = b
        .add_material(Material::emissive(Rgb::splat(15.0)))
        .unwrap();
    let v = Vec3::new;
    // `tilt`: vertex normals leaning away from the geometric normal (shading normals).
    let mut quad_with = |p: [Vec3; 4], m: u32, tilt: Option<Vec3>| {
        b.add_mesh(MeshDesc {
            positions: p.to_vec(),
            normals: tilt.map_or(Vec::new(), |n| vec![n.normalize(); 4]),
            indices: vec![[0, 1, 2], [0, 2, 3]],
            materials: vec![m],
            ..Default::default()
        })
        .unwrap();
    };
    let (a, c) = (-1.0, 1.0);
    quad_with(
        [v(a, a, a), v(a, a, c), v(c, a, c), v(c, a, a)],
        glossy,
        Some(v(0.15, 1.0, -0.1)),
    );
    quad_with(
        [
            v(-0.2, 0.9, -0.5),
            v(0.2, 0.9, -0.5),
            v(0.2, 0.9, -0.1),
            v(-0.2, 0.9, -0.1),
        ],
        light,
        Some(v(0.3, -1.0, 0.2)),
    );
    let mut quad = |p: [Vec3; 4], m: u32| quad_with(p, m, None);
    quad([v(a, a, a), v(c, a, a), v(c, c, a), v(a, c, a)], wall);
    quad([v(a, a, a), v(a, c, a), v(a, c, c), v(a, a, c)], mirror);
    quad([v(c, a, a), v(c, a, c), v(c, c, c), v(c, c, a)], sharp);
    quad(
        [
            v(-0.3, -0.2, -0.3),
            v(0.3, -0.2, -0.3),
            v(0.3, -0.2, 0.3),
            v(-0.3, -0.2, 0.3),
        ],
        glass,
    );
    b.add_light(LightDesc::Point {
        position: v(0.5, 0.5, 0.0),
        intensity: Rgb::splat(2.0),
    })
    .unwrap();
    b.add_light(LightDesc::Spot {
        position: v(-0.5, 0.8, 0.5),
        direction: v(0.2, -1.0, -0.3),
        intensity: Rgb::splat(4.0),
        inner_degrees: 15.0,
        outer_degrees: 35.0,
    })
    .unwrap();
    b.add_light(LightDesc::Directional {
        direction: v(0.3, -1.0, -0.2),
        irradiance: Rgb::splat(1.5),
    })
    .unwrap();
    b.add_light(LightDesc::Photometric {
        position: v(-0.6, 0.85, -0.4),
        direction: v(0.1, -1.0, 0.2),
        c0: v(1.0, 0.0, 0.0),
        intensity: Rgb::splat(0.02),
        profile: std::sync::Arc::new(crate::light::photometric::test_profile()),
    })
    .unwrap();
    b.build().unwrap()
}

/// A small light field whose radiance varies with the ray's place and direction, so its
/// images differ and restricted sampling's density of an image-plane point changes with the
/// receiver (as the light subpaths' MIS sums must follow).
fn test_light_field() -> crate::light::LightField {
    use crate::light::{FilterBasis, LightField, LightFieldLayout};
    let half = 0.12;
    let spacing = 2.0 * half / 4.0;
    let layout = LightFieldLayout {
        nodes: [9, 9],
        node_min: Vec2::splat(-half - 2.0 * spacing),
        node_spacing: Vec2::splat(spacing),
        basis: FilterBasis::Quadratic,
        plane_distance: 0.2,
        image_min: Vec2::splat(-half - 0.3),
        image_max: Vec2::splat(half + 0.3),
        resolution: [16, 16],
    };
    LightField::bake(layout, 3, |u, s| {
        if u.x.abs() > half || u.y.abs() > half {
            return Rgb::ZERO;
        }
        let d = s - u;
        let lobe = (1.0 - 8.0 * (d.x - 0.05).powi(2)).max(0.0) + 0.2;
        let place = 1.5 + 3.0 * u.x + 0.5 * (30.0 * u.y).sin();
        Rgb::new(lobe * place, 0.5 * lobe, place) * 20.0
    })
    .unwrap()
}

/// Traces `n_light` light subpaths and `camera_paths` camera paths through random pixels,
/// recording every estimate with its full path.
fn record(
    scene: &Scene,
    camera: &Camera,
    bdpt: &Bdpt,
    n_light: usize,
    camera_paths: usize,
    seed: u64,
) -> (View, Vec<Recorded>) {
    let view = View {
        frame: camera.frame(1.0),
        width: 24,
        height: 24,
        sampler: Default::default(),
    };
    let mut rec = Recorder {
        scene,
        light_paths: Vec::new(),
        camera: Vec::new(),
        tracing_light: true,
        recorded: Vec::new(),
    };
    let mut paths = LightPaths {
        vertices: Vec::new(),
        ranges: Vec::new(),
        policy_data: None,
    };
    let mut out = LightTracingOutput::default();
    for k in 0..n_light {
        let mut rng = Sampler::independent(Rng::new(seed, k as u64));
        let start = paths.vertices.len() as u32;
        let before = rec.light_paths.len();
        bdpt.trace_light_path(
            scene,
            &view,
            bdpt.counts(n_light),
            &mut rng,
            &mut paths.vertices,
            &mut out,
            &mut rec,
        );
        if rec.light_paths.len() == before {
            // No emission: an empty path.
            rec.light_paths
                .push((PathPoint::Light(0, Vec3::ZERO), Vec::new()));
        }
        paths.ranges.push((start, paths.vertices.len() as u32));
    }
    rec.tracing_light = false;
    let mut rng = Sampler::independent(Rng::new(seed ^ 0x00CA_3E5A, 99));
    for _ in 0..camera_paths {
        let (x, y) = (rng.below(view.width), rng.below(view.height));
        let pixel_index = (y * view.width + x) as u64;
        rec.camera.clear();
        let ctx = SampleContext {
            pixel_index,
            sample_index: 0,
            view: &view,
            iteration: Some(&paths),
            layers: &[],
        };
        let film = Vec2::new(
            (x as f32 + rng.uniform()) / view.width as f32,
            (y as f32 + rng.uniform()) / view.height as f32,
        );
        let ray = view.frame.generate_ray(film, rng.uniform2());
        let mut counters = TraceCounters::default();
        bdpt.sample_observed(scene, ray, &mut rng, &mut counters, &ctx, &mut rec);
    }
    (view, rec.recorded)
}

/// Largest difference between the integrator's weights and the model's, and how many
/// estimates of each kind were checked.
#[derive(Debug, Default)]
struct Comparison {
    max_error: f64,
    /// Estimates whose weight differs by more than 1e-4.
    over_1e4: usize,
    worst: String,
    checked: usize,
    light_tracing: usize,
    emitter_hits: usize,
    connections: usize,
    through_specular: usize,
    delta_lights: usize,
    /// Paths ending on the environment.
    sky: usize,
    /// Paths ending on a light field, and those of them sampled by direct sampling (s = 1).
    field: usize,
    field_direct: usize,
}

fn compare(scene: &Scene, view: &View, recorded: &[Recorded], model: Model) -> Comparison {
    let mut c = Comparison::default();
    for r in recorded {
        let e = &r.estimate;
        let explicit = Explicit {
            scene,
            view,
            model,
            path: &r.path,
        };
        let weights = explicit.weights();
        let sum: f64 = weights.iter().sum();
        assert!((sum - 1.0).abs() < 1e-9, "weights sum to {sum}");
        let expected = weights[e.s as usize];
        let error = (e.weight as f64 - expected).abs();
        assert!(e.weight.is_finite() && (0.0..=1.0).contains(&e.weight));
        if error > c.max_error {
            c.max_error = error;
            c.worst = format!(
                "({}, {}) integrator {} explicit {expected} (all strategies {weights:?})",
                e.s, e.t, e.weight
            );
        }
        if error > 1e-4 {
            c.over_1e4 += 1;
        }
        if error > TOLERANCE && std::env::var("BDPT_DEBUG").is_ok() {
            let kinds: Vec<String> = r
                .path
                .iter()
                .map(|p| match p {
                    PathPoint::Camera(_) => "C".to_string(),
                    PathPoint::Surface(si) => format!(
                        "{}{}",
                        si.material,
                        if scene.bsdf(si).is_delta() { "d" } else { "" }
                    ),
                    PathPoint::Light(l, _) => format!("L{l}"),
                    PathPoint::Sky(l, _) => format!("S{l}"),
                })
                .collect();
            eprintln!(
                "({},{}) {:?} int {} exp {expected} {:?}",
                e.s, e.t, kinds, e.weight, weights
            );
        }
        c.checked += 1;
        match (e.s, e.t) {
            (_, 1) => c.light_tracing += 1,
            (0, _) => c.emitter_hits += 1,
            (s, _) if s >= 2 => c.connections += 1,
            _ => {}
        }
        if (1..explicit.k()).any(|i| explicit.is_delta_surface(i)) {
            c.through_specular += 1;
        }
        if explicit.light().is_delta() {
            c.delta_lights += 1;
        }
        if explicit.is_sky(explicit.k()) {
            c.sky += 1;
        }
        if matches!(explicit.light(), Light::LightField { .. }) {
            c.field += 1;
            c.field_direct += (e.s == 1) as usize;
        }
    }
    c
}

fn model(settings: &IntegratorSettings, n_light: usize, n_conn: usize) -> Model {
    Model {
        mis: settings.mis.unwrap_or_default(),
        env: settings.env,
        n_light: n_light as f64,
        n_conn: n_conn as f64,
        roulette: true,
        specular_geometry: true,
        field_direct_at_receiver: true,
    }
}

/// Tolerance on a weight. The integrator works in f32 with the traced ray directions; the
/// model in f64 with directions between hit points, which differ by the hit points' rounding:
/// through glossy lobes of exponent 1000 that moves a few weights in 10^4 by up to ~3e-3.
/// The mistakes `weight_comparison_catches_wrong_weights` makes move weights by more than 0.05.
const TOLERANCE: f64 = 5e-3;

/// Most estimates agree far better: at most one in a thousand may differ by more than 1e-4.
fn assert_close(label: &str, c: &Comparison) {
    assert!(c.max_error < TOLERANCE, "{label}: {c:?}");
    assert!(c.over_1e4 * 1000 <= c.checked, "{label}: {c:?}");
}

#[test]
fn recursive_weights_equal_explicit_weights_and_sum_to_one() {
    let pinhole = Camera::look_at(
        Vec3::new(0.0, 0.2, 3.0),
        Vec3::new(0.0, -0.2, 0.0),
        Vec3::Y,
        50.0,
    )
    .unwrap();
    let lens = pinhole.with_thin_lens(0.15, 2.8).unwrap();
    for (sky, field) in [(false, false), (true, false), (false, true)] {
        let scene = test_scene(sky, field);
        for (camera, mis, n_light, all) in [
            (pinhole, MisHeuristic::Power, 1500, false),
            (pinhole, MisHeuristic::Balance, 2000, false),
            (lens, MisHeuristic::Power, 1500, false),
            // Every camera vertex connected to all light subpaths (000 eq. 185): the
            // connections count N samples, as SkelBPT's and ICBPT's resampled ones do.
            (pinhole, MisHeuristic::Power, 40, true),
            (pinhole, MisHeuristic::Balance, 40, true),
        ] {
            let settings = IntegratorSettings {
                max_depth: 6,
                mis: Some(mis),
                ..Default::default()
            };
            let mut bdpt = Bdpt::new(settings).with_light_paths(n_light).unwrap();
            let n_conn = if all {
                bdpt = bdpt.with_policy(Box::new(AllLightPaths));
                n_light
            } else {
                1
            };
            let camera_paths = if all { 1500 } else { 8000 };
            let (view, recorded) = record(&scene, &camera, &bdpt, n_light, camera_paths, 11);
            let c = compare(&scene, &view, &recorded, model(&settings, n_light, n_conn));
            let label = format!(
                "{mis:?}, {n_light} light paths, lens {}, all paths {all}, sky {sky}, \
                 field {field}",
                camera.lens_radius
            );
            assert_close(&label, &c);
            if sky {
                assert!(
                    c.sky >= 200,
                    "{label}: only {} paths to the sky: {c:?}",
                    c.sky
                );
            }
            if field {
                assert!(
                    c.field >= 200 && c.field_direct >= 50,
                    "{label}: only {} paths from the light field ({} sampled directly): {c:?}",
                    c.field,
                    c.field_direct
                );
            }
            if all {
                // Few light subpaths, but every camera vertex connects to each of them.
                assert!(c.connections > 10_000, "{label}: {c:?}");
                continue;
            }
            // Every kind of strategy and path was exercised.
            assert!(c.checked > 5000, "{label}: {c:?}");
            for (what, n) in [
                ("light tracing", c.light_tracing),
                ("emitter hits", c.emitter_hits),
                ("connections", c.connections),
                ("paths through specular vertices", c.through_specular),
                ("delta lights", c.delta_lights),
            ] {
                assert!(n >= 50, "{label}: only {n} {what}: {c:?}");
            }
        }
    }
}

/// The comparison can fail: a model with a plausible mistake disagrees with the integrator
/// (in the scene with the light field, so that its mistake can be made too).
#[test]
fn weight_comparison_catches_wrong_weights() {
    let scene = test_scene(false, true);
    let camera = Camera::look_at(
        Vec3::new(0.0, 0.2, 3.0),
        Vec3::new(0.0, -0.2, 0.0),
        Vec3::Y,
        50.0,
    )
    .unwrap();
    let settings = IntegratorSettings {
        max_depth: 6,
        ..Default::default()
    };
    let n_light = 300;
    let bdpt = Bdpt::new(settings).with_light_paths(n_light).unwrap();
    let (view, recorded) = record(&scene, &camera, &bdpt, n_light, 3000, 5);
    let right = model(&settings, n_light, 1);
    assert_close("right model", &compare(&scene, &view, &recorded, right));
    for (what, wrong) in [
        (
            "without Russian roulette",
            Model {
                roulette: false,
                ..right
            },
        ),
        (
            "one light subpath",
            Model {
                n_light: 1.0,
                ..right
            },
        ),
        (
            "connections counted as light tracing is",
            Model {
                n_conn: n_light as f64,
                ..right
            },
        ),
        (
            "balance heuristic",
            Model {
                mis: MisHeuristic::Balance,
                ..right
            },
        ),
        (
            "densities through specular vertices remapped to 1",
            Model {
                specular_geometry: false,
                ..right
            },
        ),
        (
            "the light field's direct density taken as emission's",
            Model {
                field_direct_at_receiver: false,
                ..right
            },
        ),
    ] {
        let c = compare(&scene, &view, &recorded, wrong);
        assert!(c.max_error > 0.05, "a model {what} was not caught: {c:?}");
    }
}

#[test]
fn strategy_indices_enumerate_the_layers() {
    let list = strategies(7);
    for (i, &(s, t)) in list.iter().enumerate() {
        assert_eq!(strategy_index(s, t), i, "({s}, {t})");
    }
    assert_eq!(list.len(), strategy_index(0, 9));
    assert_eq!(strategy_layer_name(2, 3, true), "s2_t3_weighted");
}
