//! Perspective camera with look-at placement, vertical field of view and an optional thin lens.
//! Camera space looks down -Z with +Y up (right-handed).

use crate::error::{Error, Result};
use crate::geometry::Ray;
use crate::math::{is_finite3, warp, Vec2, Vec3};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    pub up: Vec3,
    /// Vertical field of view in degrees, in (0, 180).
    pub vfov_degrees: f32,
    /// Radius of the thin lens; 0 is a pinhole.
    pub lens_radius: f32,
    /// Distance to the plane in focus (used when `lens_radius > 0`).
    pub focus_distance: f32,
}

impl Camera {
    /// A pinhole camera; validates that the placement defines a frame.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3, vfov_degrees: f32) -> Result<Self> {
        let c = Camera {
            eye,
            target,
            up,
            vfov_degrees,
            lens_radius: 0.0,
            focus_distance: (target - eye).length(),
        };
        c.validate()?;
        Ok(c)
    }

    pub fn with_thin_lens(mut self, lens_radius: f32, focus_distance: f32) -> Result<Self> {
        self.lens_radius = lens_radius;
        self.focus_distance = focus_distance;
        self.validate()?;
        Ok(self)
    }

    pub fn validate(&self) -> Result<()> {
        if !is_finite3(self.eye) || !is_finite3(self.target) || !is_finite3(self.up) {
            return Err(Error::invalid(format!(
                "camera eye {}, target {} and up {} must be finite",
                self.eye, self.target, self.up
            )));
        }
        let forward = self.target - self.eye;
        if forward.length_squared() == 0.0 {
            return Err(Error::invalid(format!(
                "camera eye and target are the same point {}",
                self.eye
            )));
        }
        if !(self.up.length_squared() > 0.0) {
            return Err(Error::invalid(format!(
                "camera up {} is the zero vector: give a direction (e.g. 0,1,0)",
                self.up
            )));
        }
        if forward
            .normalize()
            .cross(self.up.normalize_or_zero())
            .length()
            < 1e-6
        {
            return Err(Error::invalid(format!(
                "camera up {} is parallel to the view direction {}",
                self.up, forward
            )));
        }
        if !(self.vfov_degrees > 0.0 && self.vfov_degrees < 180.0) {
            return Err(Error::invalid(format!(
                "vertical field of view {} must be in (0, 180) degrees",
                self.vfov_degrees
            )));
        }
        if !(self.lens_radius >= 0.0 && self.lens_radius.is_finite()) {
            return Err(Error::invalid(format!(
                "lens radius {} must be >= 0",
                self.lens_radius
            )));
        }
        if self.lens_radius > 0.0 && !(self.focus_distance > 0.0 && self.focus_distance.is_finite())
        {
            return Err(Error::invalid(format!(
                "focus distance {} must be > 0",
                self.focus_distance
            )));
        }
        Ok(())
    }

    /// The precomputed frame for an image of the given aspect ratio (width / height).
    pub fn frame(&self, aspect: f32) -> CameraFrame {
        let forward = (self.target - self.eye).normalize();
        let right = forward.cross(self.up).normalize();
        let up = right.cross(forward);
        let tan_half = (self.vfov_degrees.to_radians() * 0.5).tan();
        CameraFrame {
            eye: self.eye,
            forward,
            right: right * tan_half * aspect,
            up: up * tan_half,
            lens_radius: self.lens_radius,
            focus_distance: self.focus_distance,
        }
    }
}

/// A camera ready to generate rays.
#[derive(Clone, Copy, Debug)]
pub struct CameraFrame {
    pub eye: Vec3,
    pub forward: Vec3,
    /// Scaled so that film x in [-1, 1] spans the image width.
    pub right: Vec3,
    pub up: Vec3,
    pub lens_radius: f32,
    pub focus_distance: f32,
}

impl CameraFrame {
    /// Film position in [0, 1)^2 of a world point seen through a pinhole camera, with the
    /// cosine between the view direction and the direction to the point; `None` behind the
    /// camera or outside the image.
    pub fn project(&self, p: Vec3) -> Option<(Vec2, f32)> {
        let v = p - self.eye;
        let z = v.dot(self.forward);
        if !(z > 0.0) {
            return None;
        }
        let ndc_x = v.dot(self.right) / (z * self.right.length_squared());
        let ndc_y = v.dot(self.up) / (z * self.up.length_squared());
        let film = Vec2::new(0.5 * (ndc_x + 1.0), 0.5 * (1.0 - ndc_y));
        if !(film.x >= 0.0 && film.x < 1.0 && film.y >= 0.0 && film.y < 1.0) {
            return None;
        }
        Some((film, z / v.length()))
    }

    /// The point of the lens chosen by `u` in [0, 1)^2 (uniform over the lens disk, as
    /// `generate_ray` picks it); the eye itself for a pinhole.
    pub fn lens_point(&self, u: Vec2) -> Vec3 {
        if self.lens_radius <= 0.0 {
            return self.eye;
        }
        let d = warp::concentric_disk(u) * self.lens_radius;
        self.eye + self.right.normalize() * d.x + self.up.normalize() * d.y
    }

    /// Inverse of `generate_ray` for a given lens point: the film position of the camera ray
    /// that leaves `lens_point` towards the world point `p`, with the cosine between that ray
    /// and the view direction; `None` behind the lens or outside the image. For a pinhole
    /// (`lens_point` = eye) this is `project`.
    ///
    /// A thin lens sends every ray through the film point's image on the plane in focus, so the
    /// film position is the pinhole projection of the point where the ray meets that plane.
    pub fn project_from_lens(&self, lens_point: Vec3, p: Vec3) -> Option<(Vec2, f32)> {
        if self.lens_radius <= 0.0 {
            return self.project(p);
        }
        let dir = (p - lens_point).normalize();
        let cos = dir.dot(self.forward);
        if !(cos > 0.0) {
            return None;
        }
        let focus_point = lens_point + dir * (self.focus_distance / cos);
        let (film, _) = self.project(focus_point)?;
        Some((film, cos))
    }

    /// Distance from the pinhole to the image plane measured in pixels, for an image `height`
    /// pixels high: the plane on which one pixel has unit area.
    pub fn image_plane_distance(&self, height: u32) -> f32 {
        0.5 * height as f32 / self.up.length()
    }

    /// True for a thin lens, whose rays need a lens position; a pinhole camera ignores it.
    #[inline]
    pub fn has_lens(&self) -> bool {
        self.lens_radius > 0.0
    }

    /// The ray through film position `film` in [0, 1)^2 (x to the right, y downwards), with
    /// `lens` in [0, 1)^2 choosing the point on the lens.
    pub fn generate_ray(&self, film: Vec2, lens: Vec2) -> Ray {
        let ndc = Vec2::new(2.0 * film.x - 1.0, 1.0 - 2.0 * film.y);
        let dir = (self.forward + self.right * ndc.x + self.up * ndc.y).normalize();
        if !self.has_lens() {
            return Ray::new(self.eye, dir, f32::INFINITY);
        }
        let focus_point = self.eye + dir * (self.focus_distance / dir.dot(self.forward));
        let origin = self.lens_point(lens);
        Ray::new(origin, (focus_point - origin).normalize(), f32::INFINITY)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_ray_looks_at_target_and_fov_is_vertical() {
        let c = Camera::look_at(
            Vec3::new(0.0, 1.0, 4.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::Y,
            90.0,
        )
        .unwrap();
        let f = c.frame(2.0);
        let r = f.generate_ray(Vec2::splat(0.5), Vec2::ZERO);
        assert!((r.dir - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-6);
        // Top edge at 45 degrees up (vfov 90).
        let top = f.generate_ray(Vec2::new(0.5, 0.0), Vec2::ZERO);
        assert!((top.dir.y - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-5);
        // Left edge: aspect 2 gives tan = 2.
        let left = f.generate_ray(Vec2::new(0.0, 0.5), Vec2::ZERO);
        assert!((left.dir.x / -left.dir.z + 2.0).abs() < 1e-5);
    }

    #[test]
    fn thin_lens_rays_converge_on_the_focus_plane() {
        let c = Camera::look_at(Vec3::ZERO, -Vec3::Z, Vec3::Y, 40.0)
            .unwrap()
            .with_thin_lens(0.1, 5.0)
            .unwrap();
        let f = c.frame(1.0);
        let a = f.generate_ray(Vec2::new(0.3, 0.6), Vec2::new(0.1, 0.9));
        let b = f.generate_ray(Vec2::new(0.3, 0.6), Vec2::new(0.8, 0.2));
        let pa = a.at((5.0 - a.origin.dot(-Vec3::Z)) / a.dir.dot(-Vec3::Z));
        let pb = b.at((5.0 - b.origin.dot(-Vec3::Z)) / b.dir.dot(-Vec3::Z));
        assert!((pa - pb).length() < 1e-4);
    }

    /// `project_from_lens` finds the film position `generate_ray` started from, for pinholes
    /// and thin lenses, and the cosine of the ray with the view direction.
    #[test]
    fn projection_from_the_lens_inverts_ray_generation() {
        let pinhole = Camera::look_at(Vec3::new(1.0, 2.0, 3.0), Vec3::ZERO, Vec3::Y, 50.0).unwrap();
        for camera in [pinhole, pinhole.with_thin_lens(0.2, 2.5).unwrap()] {
            let f = camera.frame(1.5);
            let mut rng = crate::math::Rng::new(7, 1);
            for _ in 0..1000 {
                let film = rng.uniform2();
                let lens = rng.uniform2();
                let ray = f.generate_ray(film, lens);
                let origin = f.lens_point(lens);
                assert!((origin - ray.origin).length() < 1e-6);
                let p = ray.at(0.5 + 10.0 * rng.uniform());
                let (back, cos) = f.project_from_lens(origin, p).expect("in view");
                assert!((back - film).length() < 2e-4, "{film} -> {back}");
                assert!((cos - ray.dir.dot(f.forward)).abs() < 1e-5);
            }
            // Behind the lens.
            assert!(f.project_from_lens(f.eye, f.eye - f.forward).is_none());
        }
    }

    #[test]
    fn bad_cameras_are_rejected() {
        assert!(Camera::look_at(Vec3::ZERO, Vec3::ZERO, Vec3::Y, 40.0).is_err());
        assert!(Camera::look_at(Vec3::ZERO, Vec3::Y, Vec3::Y, 40.0).is_err());
        assert!(Camera::look_at(Vec3::ZERO, Vec3::X, Vec3::Y, 180.0).is_err());
        assert!(Camera::look_at(Vec3::splat(f32::NAN), Vec3::X, Vec3::Y, 40.0).is_err());
    }
}
