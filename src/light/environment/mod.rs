//! Environment-map lights (H. Lu, *Importance sampling of realistic light sources*, PhD
//! thesis 2014, "001" in `docs/references.md`: chapter 3; background §2.7.2): radiance arriving from
//! infinitely far away, stored as a lat-long or cube-map image, with light-based importance
//! sampling by the classic 2-D lat-long density or by per-face cube-map CDFs with the
//! per-normal dynamic face balancing of the thesis, each with its exact pdf so that it
//! combines with BSDF sampling by MIS.
//!
//! The map has its own frame with +Y up; `up` names the world axis that is up (most scenes
//! are Y-up, the pg2015 veach door is Z-up) and `rotate_degrees` turns the map about it. The
//! sampling structures depend only on the image: they are built lazily, for the strategies a
//! render uses, and rebuilt in place when the host hands over a new image of the same layout.

mod direction_sampling;
mod grid;
mod image;
mod portal;

pub use direction_sampling::{Balancing, CubeSampler, LatLongSampler};
pub use grid::Grid;
pub use image::{describe, EnvImage, MAX_TEXELS};
pub use portal::{InteriorMask, Portal, PortalSampler, FALLBACK as PORTAL_FALLBACK, MAX_PORTALS};

use std::path::Path;
use std::sync::OnceLock;
use std::time::Instant;

use glam::Mat3;

use crate::error::{Error, Result};
use crate::math::{Rgb, Vec2, Vec3};

/// How a light-sampling strategy picks environment directions.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum EnvStrategy {
    /// The strategy of the map's own layout ([`EnvironmentMap::resolve`]): `LatLong` for a
    /// lat-long map, `CubeDynamic` for a cube map. A density on the other layout weighs
    /// resampled texels and loses at equal time (BENCHMARKS.md, "Environment-map lights").
    #[default]
    Auto,
    /// Classic 2-D piecewise-constant sampling of the lat-long map with the sin(theta) factor.
    LatLong,
    /// Per-face cube-map CDFs, samples split evenly between faces (mu_f = 1/6).
    CubeUniform,
    /// Per-face cube-map CDFs, faces chosen by their power (one global CDF in effect).
    CubePower,
    /// Per-face cube-map CDFs with per-normal dynamic balancing mu_f(n) (001 eq. 3.4).
    CubeDynamic,
    /// Never sample the environment: only BSDF sampling finds it (for validation).
    BsdfOnly,
    /// Only directions through the window portals a point sees (`portal.rs`, Bitterli et al.
    /// 2015), where the scene has portals and the integrator knows the point;
    /// [`PORTAL_FALLBACK`] elsewhere (and in [`EnvironmentMap::sample`], which has no point).
    Portals,
}

impl EnvStrategy {
    pub const NAMES: &'static [&'static str] = &[
        "auto",
        "latlong",
        "cube-uniform",
        "cube-power",
        "cube-dynamic",
        "bsdf",
        "portals",
    ];

    pub fn parse(name: &str) -> Result<Self> {
        Ok(match name {
            "auto" => EnvStrategy::Auto,
            "latlong" => EnvStrategy::LatLong,
            "cube-uniform" => EnvStrategy::CubeUniform,
            "cube-power" => EnvStrategy::CubePower,
            "cube-dynamic" => EnvStrategy::CubeDynamic,
            "bsdf" => EnvStrategy::BsdfOnly,
            "portals" => EnvStrategy::Portals,
            other => {
                return Err(Error::invalid(format!(
                    "unknown environment sampling strategy '{other}' (expected one of {})",
                    Self::NAMES.join(", ")
                )))
            }
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            EnvStrategy::Auto => "auto",
            EnvStrategy::LatLong => "latlong",
            EnvStrategy::CubeUniform => "cube-uniform",
            EnvStrategy::CubePower => "cube-power",
            EnvStrategy::CubeDynamic => "cube-dynamic",
            EnvStrategy::BsdfOnly => "bsdf",
            EnvStrategy::Portals => "portals",
        }
    }

    /// The face balancing of a cube strategy (None for `Auto`: resolve it against the map
    /// first, [`EnvironmentMap::resolve`]).
    pub fn balancing(self) -> Option<Balancing> {
        match self.map_strategy() {
            EnvStrategy::CubeUniform => Some(Balancing::Uniform),
            EnvStrategy::CubePower => Some(Balancing::Power),
            EnvStrategy::CubeDynamic => Some(Balancing::Dynamic),
            _ => None,
        }
    }

    /// The whole-map strategy behind this one: itself, or for `Portals` the portal
    /// sampler's fallback (what the map alone samples with; the portals are the scene's).
    /// `Auto` stays `Auto`: only the map knows its layout.
    pub fn map_strategy(self) -> EnvStrategy {
        match self {
            EnvStrategy::Portals => PORTAL_FALLBACK,
            other => other,
        }
    }

    /// The normal-independent strategy that starts light subpaths (there is no receiver):
    /// the lat-long density for `LatLong`, the cube CDFs balanced by power otherwise. `Auto`
    /// stays `Auto`, which the map resolves with no normal: lat-long, or cube-dynamic, whose
    /// balance without a normal is by power.
    pub fn for_emission(self) -> EnvStrategy {
        match self {
            EnvStrategy::Auto => EnvStrategy::Auto,
            EnvStrategy::LatLong => EnvStrategy::LatLong,
            _ => EnvStrategy::CubePower,
        }
    }
}

/// Which world axis is up for the map (its row 0 / the +Y face).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum UpAxis {
    #[default]
    Y,
    Z,
}

impl UpAxis {
    pub fn parse(name: &str) -> Result<Self> {
        match name {
            "y" | "Y" | "+y" => Ok(UpAxis::Y),
            "z" | "Z" | "+z" => Ok(UpAxis::Z),
            other => Err(Error::invalid(format!(
                "environment up axis '{other}' must be y or z"
            ))),
        }
    }
}

/// How the map is placed and shown.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnvSettings {
    /// Radiance multiplier.
    pub scale: f32,
    /// Rotation about the up axis, counter-clockwise seen from above.
    pub rotate_degrees: f32,
    pub up: UpAxis,
    /// Whether camera rays that escape see the map (it lights the scene either way).
    pub visible: bool,
}

impl Default for EnvSettings {
    fn default() -> Self {
        EnvSettings {
            scale: 1.0,
            rotate_degrees: 0.0,
            up: UpAxis::Y,
            visible: true,
        }
    }
}

impl EnvSettings {
    pub fn validate(&self) -> Result<()> {
        if !(self.scale.is_finite() && self.scale >= 0.0) {
            return Err(Error::invalid(format!(
                "environment scale {} must be finite and >= 0",
                self.scale
            )));
        }
        if !self.rotate_degrees.is_finite() {
            return Err(Error::invalid(format!(
                "environment rotation {} must be finite",
                self.rotate_degrees
            )));
        }
        Ok(())
    }

    /// World-to-map rotation.
    fn world_to_map(&self) -> Mat3 {
        // Map +Y = world up; for Z-up worlds the map's -Z (its centre) looks along world +Y.
        let base = match self.up {
            UpAxis::Y => Mat3::IDENTITY,
            // (x, y, z) -> (x, z, -y)
            UpAxis::Z => Mat3::from_cols(Vec3::X, Vec3::NEG_Z, Vec3::Y),
        };
        Mat3::from_rotation_y(-self.rotate_degrees.to_radians()) * base
    }
}

/// A sampled environment direction.
#[derive(Clone, Copy, Debug)]
pub struct EnvSample {
    /// Unit world direction towards the environment.
    pub wi: Vec3,
    pub radiance: Rgb,
    /// Solid-angle density.
    pub pdf: f32,
}

/// An environment map ready for lookups and sampling.
#[derive(Debug)]
pub struct EnvironmentMap {
    image: EnvImage,
    settings: EnvSettings,
    to_local: Mat3,
    to_world: Mat3,
    /// Integral of scaled luminance over the sphere (W m^-2 sr^-1 x sr).
    luminance_integral: f32,
    latlong: OnceLock<LatLongSampler>,
    cube: OnceLock<CubeSampler>,
    /// Seconds spent in the last build or rebuild of each structure (lat-long, cube).
    build_seconds: [f64; 2],
}

impl Clone for EnvironmentMap {
    fn clone(&self) -> Self {
        EnvironmentMap {
            image: self.image.clone(),
            settings: self.settings,
            to_local: self.to_local,
            to_world: self.to_world,
            luminance_integral: self.luminance_integral,
            latlong: self.latlong.clone(),
            cube: self.cube.clone(),
            build_seconds: self.build_seconds,
        }
    }
}

impl EnvironmentMap {
    pub fn new(image: EnvImage, settings: EnvSettings) -> Result<Self> {
        settings.validate()?;
        let to_local = settings.world_to_map();
        let luminance_integral = (image.luminance_integral() * settings.scale as f64) as f32;
        if !luminance_integral.is_finite() {
            return Err(Error::invalid(
                "environment map: its total radiance overflows (scale it down)",
            ));
        }
        Ok(EnvironmentMap {
            image,
            settings,
            to_local,
            to_world: to_local.transpose(),
            luminance_integral,
            latlong: OnceLock::new(),
            cube: OnceLock::new(),
            build_seconds: [0.0; 2],
        })
    }

    /// Loads an `.exr` or `.hdr` map (2:1 lat-long or 4:3 horizontal cross).
    pub fn load(path: &Path, settings: EnvSettings) -> Result<Self> {
        EnvironmentMap::new(EnvImage::load(path)?, settings)
    }

    pub fn image(&self) -> &EnvImage {
        &self.image
    }

    pub fn settings(&self) -> &EnvSettings {
        &self.settings
    }

    /// Changes placement and visibility (the sampling structures stay valid: they live in
    /// the map's frame).
    pub fn set_settings(&mut self, settings: EnvSettings) -> Result<()> {
        settings.validate()?;
        let old_scale = self.settings.scale;
        self.settings = settings;
        self.to_local = settings.world_to_map();
        self.to_world = self.to_local.transpose();
        if old_scale != settings.scale {
            self.luminance_integral =
                (self.image.luminance_integral() * settings.scale as f64) as f32;
        }
        Ok(())
    }

    /// Integral of luminance over all directions (for the power of the light).
    pub fn luminance_integral(&self) -> f32 {
        self.luminance_integral
    }

    pub fn visible_to_camera(&self) -> bool {
        self.settings.visible
    }

    /// Radiance arriving from world direction `w` (unit).
    #[inline]
    pub fn radiance(&self, w: Vec3) -> Rgb {
        self.image.lookup(self.to_local * w) * self.settings.scale
    }

    /// The lat-long density (built on first use, on the calling thread; `prepare` builds it
    /// in parallel beforehand).
    pub fn latlong(&self) -> &LatLongSampler {
        self.latlong
            .get_or_init(|| LatLongSampler::build(&self.image, false))
    }

    /// The cube-map densities (built on first use, on the calling thread; `prepare` builds
    /// them in parallel beforehand).
    pub fn cube(&self) -> &CubeSampler {
        self.cube
            .get_or_init(|| CubeSampler::build(&self.image, false))
    }

    /// The whole-map strategy `strategy` samples this map with: `Auto` becomes the strategy
    /// of the map's own layout, `Portals` its fallback ([`EnvStrategy::map_strategy`]).
    pub fn resolve(&self, strategy: EnvStrategy) -> EnvStrategy {
        match strategy.map_strategy() {
            EnvStrategy::Auto => match self.image.grid() {
                Grid::LatLong { .. } => EnvStrategy::LatLong,
                Grid::Cube { .. } => EnvStrategy::CubeDynamic,
            },
            other => other,
        }
    }

    /// Builds the structures `strategy` needs now rather than during the first samples,
    /// timing the build.
    pub fn prepare(&mut self, strategy: EnvStrategy) {
        for s in [strategy, strategy.for_emission()] {
            match self.resolve(s) {
                EnvStrategy::LatLong if self.latlong.get().is_none() => {
                    let t = Instant::now();
                    let built = LatLongSampler::new(&self.image);
                    self.build_seconds[0] = t.elapsed().as_secs_f64();
                    let _ = self.latlong.set(built);
                }
                EnvStrategy::CubeUniform | EnvStrategy::CubePower | EnvStrategy::CubeDynamic
                    if self.cube.get().is_none() =>
                {
                    let t = Instant::now();
                    let built = CubeSampler::new(&self.image);
                    self.build_seconds[1] = t.elapsed().as_secs_f64();
                    let _ = self.cube.set(built);
                }
                _ => {}
            }
        }
    }

    /// Seconds of the last (re)build of the lat-long and cube structures (0 when not built).
    pub fn build_seconds(&self) -> [f64; 2] {
        self.build_seconds
    }

    /// Replaces the texels by new ones of the same layout and rebuilds the structures that
    /// exist, in place. Returns the seconds spent rebuilding (validation excluded).
    pub fn update(&mut self, texels: &[Rgb]) -> Result<f64> {
        self.image.replace(texels)?;
        self.luminance_integral =
            (self.image.luminance_integral() * self.settings.scale as f64) as f32;
        let start = Instant::now();
        if let Some(s) = self.latlong.get_mut() {
            let t = Instant::now();
            s.rebuild(&self.image);
            self.build_seconds[0] = t.elapsed().as_secs_f64();
        }
        if let Some(s) = self.cube.get_mut() {
            let t = Instant::now();
            s.rebuild(&self.image);
            self.build_seconds[1] = t.elapsed().as_secs_f64();
        }
        Ok(start.elapsed().as_secs_f64())
    }

    /// Unit normal in the map's frame, or zero.
    fn local_normal(&self, n: Vec3) -> Vec3 {
        if n == Vec3::ZERO {
            Vec3::ZERO
        } else {
            (self.to_local * n).normalize_or_zero()
        }
    }

    /// The face proportions mu_f a cube strategy uses at a receiver with world normal `n`
    /// (zero when unknown).
    pub fn face_balance(&self, balancing: Balancing, n: Vec3) -> [f32; 6] {
        self.cube().balance(balancing, self.local_normal(n))
    }

    /// Samples a direction for a receiver whose shading normal (facing the outgoing
    /// direction) is `n`, or zero when there is none.
    pub fn sample(&self, strategy: EnvStrategy, n: Vec3, u: Vec2) -> Option<EnvSample> {
        let (local, pdf) = match self.resolve(strategy) {
            EnvStrategy::BsdfOnly => return None,
            EnvStrategy::LatLong => self.latlong().sample(u)?,
            cube => {
                let mu = self.face_balance(cube.balancing().expect("cube strategy"), n);
                self.cube().sample(&mu, u)?
            }
        };
        Some(EnvSample {
            wi: (self.to_world * local).normalize(),
            radiance: self.image.lookup(local) * self.settings.scale,
            pdf,
        })
    }

    /// Solid-angle pdf of `sample(strategy, n, ..)` producing world direction `w`.
    pub fn pdf(&self, strategy: EnvStrategy, n: Vec3, w: Vec3) -> f32 {
        let local = self.to_local * w;
        match self.resolve(strategy) {
            EnvStrategy::BsdfOnly => 0.0,
            EnvStrategy::LatLong => self.latlong().pdf(local),
            cube => {
                let mu = self.face_balance(cube.balancing().expect("cube strategy"), n);
                self.cube().pdf(&mu, local)
            }
        }
    }

    /// Converts a world direction to the map's frame (for per-face estimators).
    pub fn to_local(&self, w: Vec3) -> Vec3 {
        self.to_local * w
    }

    /// Converts a direction of the map's frame to the world.
    pub fn to_world(&self, local: Vec3) -> Vec3 {
        self.to_world * local
    }

    /// Radiance from a direction of the map's frame.
    pub fn radiance_local(&self, local: Vec3) -> Rgb {
        self.image.lookup(local) * self.settings.scale
    }

    pub fn memory_bytes(&self) -> usize {
        std::mem::size_of_val(self.image.texels())
            + self.latlong.get().map_or(0, LatLongSampler::memory_bytes)
            + self.cube.get().map_or(0, CubeSampler::memory_bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    fn map(grid: Grid) -> EnvironmentMap {
        let image = direction_sampling::tests::test_image(grid);
        EnvironmentMap::new(image, EnvSettings::default()).unwrap()
    }

    /// `auto` samples and weighs exactly as the strategy of the map's layout, for receivers
    /// and for emission (no normal).
    #[test]
    fn auto_is_the_strategy_of_the_maps_layout() {
        let lat_long = map(Grid::LatLong {
            width: 32,
            height: 16,
        });
        let cube = map(Grid::Cube { face: 8 });
        assert_eq!(lat_long.resolve(EnvStrategy::Auto), EnvStrategy::LatLong);
        assert_eq!(cube.resolve(EnvStrategy::Auto), EnvStrategy::CubeDynamic);
        assert_eq!(cube.resolve(EnvStrategy::Portals), PORTAL_FALLBACK);
        assert_eq!(cube.resolve(EnvStrategy::CubePower), EnvStrategy::CubePower);
        assert_eq!(EnvStrategy::default(), EnvStrategy::Auto);
        assert_eq!(EnvStrategy::parse("auto").unwrap(), EnvStrategy::Auto);
        let mut rng = Rng::new(3, 3);
        for (m, native, emission) in [
            (&lat_long, EnvStrategy::LatLong, EnvStrategy::LatLong),
            (&cube, EnvStrategy::CubeDynamic, EnvStrategy::CubePower),
        ] {
            for i in 0..2000 {
                let n = if i % 4 == 0 {
                    Vec3::ZERO
                } else {
                    crate::math::warp::uniform_sphere(rng.uniform2())
                };
                let expected = if n == Vec3::ZERO { emission } else { native };
                let u = rng.uniform2();
                let auto = m.sample(EnvStrategy::Auto, n, u).unwrap();
                let same = m.sample(expected, n, u).unwrap();
                assert_eq!(auto.wi, same.wi);
                assert_eq!(auto.pdf, same.pdf);
                let w = crate::math::warp::uniform_sphere(rng.uniform2());
                assert_eq!(m.pdf(EnvStrategy::Auto, n, w), m.pdf(expected, n, w));
            }
        }
    }
}
