//! The two texel layouts of an environment map over the sphere of directions, in the map's
//! local frame (+Y up): latitude-longitude (row 0 at the zenith) and the cube map (faces +X,
//! -X, +Y, -Y, +Z, -Z). Everything here is geometry only: which texel a direction falls in,
//! where a texel is, how much solid angle it covers. Images and sampling densities are built
//! on it.

use crate::math::{Vec3, PI};

/// A texel layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Grid {
    /// `width` columns of azimuth by `height` rows of polar angle; row 0 touches +Y.
    LatLong { width: usize, height: usize },
    /// Six square faces of `face` x `face` texels, stored face after face in [`FACES`] order.
    Cube { face: usize },
}

/// A cube face seen from inside the cube: its axis and the directions of its texel columns
/// (`right`) and of decreasing rows (`up`). The horizontal cross has -X, -Z, +X, +Z in its
/// middle row, +Y above -Z and -Y below it, and these bases make its edges meet.
#[derive(Clone, Copy, Debug)]
pub struct Face {
    pub forward: Vec3,
    pub right: Vec3,
    pub up: Vec3,
}

pub const FACES: [Face; 6] = [
    // +X
    Face {
        forward: Vec3::X,
        right: Vec3::Z,
        up: Vec3::Y,
    },
    // -X
    Face {
        forward: Vec3::NEG_X,
        right: Vec3::NEG_Z,
        up: Vec3::Y,
    },
    // +Y
    Face {
        forward: Vec3::Y,
        right: Vec3::X,
        up: Vec3::Z,
    },
    // -Y
    Face {
        forward: Vec3::NEG_Y,
        right: Vec3::X,
        up: Vec3::NEG_Z,
    },
    // +Z
    Face {
        forward: Vec3::Z,
        right: Vec3::NEG_X,
        up: Vec3::Y,
    },
    // -Z
    Face {
        forward: Vec3::NEG_Z,
        right: Vec3::X,
        up: Vec3::Y,
    },
];

/// Position of each face in the horizontal cross (4 x 3 faces): (column, row).
pub const CROSS_POSITION: [(usize, usize); 6] = [(2, 1), (0, 1), (1, 0), (1, 2), (3, 1), (1, 1)];

/// Direction of lat-long coordinates (u, v) in [0, 1]^2: v = theta / pi from +Y, u = 1/2 +
/// phi / (2 pi) with phi = 0 towards -Z and phi = pi/2 towards +X (the middle of the image
/// is straight ahead for a default camera looking down -Z, +X is to its right).
#[inline]
pub fn latlong_direction(u: f32, v: f32) -> Vec3 {
    let theta = PI * v;
    let phi = 2.0 * PI * (u - 0.5);
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    Vec3::new(st * sp, ct, -st * cp)
}

/// Lat-long coordinates (u, v) of a unit direction.
#[inline]
pub fn latlong_coordinates(d: Vec3) -> (f32, f32) {
    let v = d.y.clamp(-1.0, 1.0).acos() * (1.0 / PI);
    let u = 0.5 + d.x.atan2(-d.z) * (0.5 / PI);
    (u, v)
}

/// Face and face coordinates (s, t) in [-1, 1]^2 of a direction (need not be unit); s grows
/// along the face's `right`, t along its `-up` (down the rows).
#[inline]
pub fn cube_coordinates(d: Vec3) -> (usize, f32, f32) {
    let a = d.abs();
    let face = if a.x >= a.y && a.x >= a.z {
        if d.x >= 0.0 {
            0
        } else {
            1
        }
    } else if a.y >= a.z {
        if d.y >= 0.0 {
            2
        } else {
            3
        }
    } else if d.z >= 0.0 {
        4
    } else {
        5
    };
    let f = &FACES[face];
    let inv = 1.0 / d.dot(f.forward);
    (
        face,
        (d.dot(f.right) * inv).clamp(-1.0, 1.0),
        (-d.dot(f.up) * inv).clamp(-1.0, 1.0),
    )
}

/// The (not normalized) direction of face coordinates (s, t): its length squared is
/// 1 + s^2 + t^2.
#[inline]
pub fn cube_direction(face: usize, s: f32, t: f32) -> Vec3 {
    let f = &FACES[face];
    f.forward + f.right * s - f.up * t
}

/// Solid angle of the part of a cube face [-1, s] x [-1, t] seen from the centre, up to a
/// constant: the antiderivative atan(s t / sqrt(1 + s^2 + t^2)) of (1 + s^2 + t^2)^(-3/2).
fn cube_area_element(s: f64, t: f64) -> f64 {
    (s * t).atan2((1.0 + s * s + t * t).sqrt())
}

impl Grid {
    pub fn texel_count(&self) -> usize {
        match *self {
            Grid::LatLong { width, height } => width * height,
            Grid::Cube { face } => 6 * face * face,
        }
    }

    /// The texel containing a unit direction.
    #[inline]
    pub fn texel_of(&self, d: Vec3) -> usize {
        match *self {
            Grid::LatLong { width, height } => {
                let (u, v) = latlong_coordinates(d);
                let col = ((u * width as f32) as usize).min(width - 1);
                let row = ((v * height as f32) as usize).min(height - 1);
                row * width + col
            }
            Grid::Cube { face } => {
                let (f, s, t) = cube_coordinates(d);
                let n = face as f32;
                let col = (((s + 1.0) * 0.5 * n) as usize).min(face - 1);
                let row = (((t + 1.0) * 0.5 * n) as usize).min(face - 1);
                (f * face + row) * face + col
            }
        }
    }

    /// Unit direction of the point of texel `i` at fractional position (a, b) in [0, 1]^2
    /// (column, row); (0.5, 0.5) is its centre.
    pub fn texel_point(&self, i: usize, a: f32, b: f32) -> Vec3 {
        match *self {
            Grid::LatLong { width, height } => {
                let (row, col) = (i / width, i % width);
                latlong_direction(
                    (col as f32 + a) / width as f32,
                    (row as f32 + b) / height as f32,
                )
            }
            Grid::Cube { face } => {
                let f = i / (face * face);
                let (row, col) = ((i / face) % face, i % face);
                let s = 2.0 * (col as f32 + a) / face as f32 - 1.0;
                let t = 2.0 * (row as f32 + b) / face as f32 - 1.0;
                cube_direction(f, s, t).normalize()
            }
        }
    }

    /// Exact solid angle of texel `i`.
    pub fn texel_solid_angle(&self, i: usize) -> f64 {
        match *self {
            Grid::LatLong { width, height } => {
                let row = i / width;
                let t0 = std::f64::consts::PI * row as f64 / height as f64;
                let t1 = std::f64::consts::PI * (row + 1) as f64 / height as f64;
                2.0 * std::f64::consts::PI / width as f64 * (t0.cos() - t1.cos())
            }
            Grid::Cube { face } => {
                let (row, col) = ((i / face) % face, i % face);
                let e = |k: usize| 2.0 * k as f64 / face as f64 - 1.0;
                let (s0, s1, t0, t1) = (e(col), e(col + 1), e(row), e(row + 1));
                cube_area_element(s1, t1) - cube_area_element(s0, t1) - cube_area_element(s1, t0)
                    + cube_area_element(s0, t0)
            }
        }
    }

    /// The factor that turns a texel's luminance into its sampling weight, proportional to
    /// its solid angle as approximated at its centre: sin(theta) for lat-long; for cube maps
    /// the "practical method" of 001 eq. 3.13, (1 + s0^2 + t0^2)^(-3/2) at the texel centre
    /// (both up to a constant per grid, which the normalisation removes).
    pub fn weight_factor(&self, i: usize) -> f32 {
        match *self {
            Grid::LatLong { width, height } => {
                let row = i / width;
                (PI * (row as f32 + 0.5) / height as f32).sin()
            }
            Grid::Cube { face } => {
                let (row, col) = ((i / face) % face, i % face);
                let s = 2.0 * (col as f32 + 0.5) / face as f32 - 1.0;
                let t = 2.0 * (row as f32 + 0.5) / face as f32 - 1.0;
                (1.0 + s * s + t * t).powf(-1.5)
            }
        }
    }

    /// Angular radius of a cap around the texel's centre that contains the whole texel.
    pub fn texel_radius(&self, i: usize) -> f32 {
        let c = self.texel_point(i, 0.5, 0.5);
        match *self {
            // The farthest point of a lat-long texel from its centre is a corner or, near a
            // pole, the middle of its edge nearer the pole; check both (plus a margin for the
            // azimuthal bulge of the edge).
            Grid::LatLong { .. } => {
                let mut r = 0.0f32;
                for (a, b) in [
                    (0.0, 0.0),
                    (1.0, 0.0),
                    (0.0, 1.0),
                    (1.0, 1.0),
                    (0.5, 0.0),
                    (0.5, 1.0),
                ] {
                    r = r.max(angle(c, self.texel_point(i, a, b)));
                }
                r * 1.01 + 1e-6
            }
            // A spherical quadrilateral smaller than a hemisphere lies within the cap
            // through its farthest corner.
            Grid::Cube { .. } => {
                let mut r = 0.0f32;
                for (a, b) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
                    r = r.max(angle(c, self.texel_point(i, a, b)));
                }
                r * 1.01 + 1e-6
            }
        }
    }
}

/// Angle between two unit vectors, accurate also for small angles.
#[inline]
pub fn angle(a: Vec3, b: Vec3) -> f32 {
    2.0 * ((a - b).length() * 0.5).clamp(0.0, 1.0).asin()
}

/// Calls `f` with every texel of a `width` x `height` lat-long grid that may intersect the
/// cap of angular radius `radius` around unit direction `center` (conservatively: every
/// texel meeting the cap's bounding range in theta and phi).
pub fn latlong_texels_near(
    width: usize,
    height: usize,
    center: Vec3,
    radius: f32,
    mut f: impl FnMut(usize),
) {
    let (uc, vc) = latlong_coordinates(center);
    let theta = vc * PI;
    let (t0, t1) = (theta - radius, theta + radius);
    let row_of = |t: f32| ((t / PI * height as f32).floor() as isize).clamp(0, height as isize - 1);
    let (r0, r1) = (row_of(t0) as usize, row_of(t1) as usize);
    let all_columns = t0 <= 0.0 || t1 >= PI || {
        let s = radius.sin() / theta.sin();
        s >= 1.0
    };
    if all_columns {
        for row in r0..=r1 {
            for col in 0..width {
                f(row * width + col);
            }
        }
        return;
    }
    // Half-width in azimuth of a cap not containing a pole.
    let half = (radius.sin() / theta.sin()).asin() / (2.0 * PI);
    let c0 = ((uc - half) * width as f32).floor() as isize;
    let c1 = ((uc + half) * width as f32).floor() as isize;
    let span = (c1 - c0 + 1).min(width as isize);
    for row in r0..=r1 {
        for k in 0..span {
            let col = (c0 + k).rem_euclid(width as isize) as usize;
            f(row * width + col);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::warp::uniform_sphere;
    use crate::math::Rng;

    #[test]
    fn latlong_round_trip_and_orientation() {
        let mut rng = Rng::new(3, 0);
        for _ in 0..10_000 {
            let d = uniform_sphere(rng.uniform2());
            let (u, v) = latlong_coordinates(d);
            assert!((latlong_direction(u, v) - d).length() < 1e-4);
        }
        assert!((latlong_direction(0.5, 0.5) - Vec3::NEG_Z).length() < 1e-6);
        assert!((latlong_direction(0.75, 0.5) - Vec3::X).length() < 1e-6);
        assert!((latlong_direction(0.3, 0.0) - Vec3::Y).length() < 1e-6);
    }

    #[test]
    fn cube_round_trip_and_face_bases() {
        for f in &FACES {
            assert!((f.forward.cross(f.up) - f.right).length() < 1e-6);
        }
        let mut rng = Rng::new(4, 0);
        for _ in 0..10_000 {
            let d = uniform_sphere(rng.uniform2());
            let (face, s, t) = cube_coordinates(d);
            assert!((cube_direction(face, s, t).normalize() - d).length() < 1e-5);
        }
    }

    #[test]
    fn solid_angles_sum_to_the_sphere() {
        for grid in [
            Grid::LatLong {
                width: 64,
                height: 32,
            },
            Grid::Cube { face: 16 },
        ] {
            let total: f64 = (0..grid.texel_count())
                .map(|i| grid.texel_solid_angle(i))
                .sum();
            assert!(
                (total - 4.0 * std::f64::consts::PI).abs() < 1e-9,
                "{grid:?} {total}"
            );
        }
    }

    #[test]
    fn texels_lie_in_their_caps_and_caps_find_their_neighbours() {
        let mut rng = Rng::new(5, 0);
        for grid in [
            Grid::LatLong {
                width: 32,
                height: 16,
            },
            Grid::Cube { face: 8 },
        ] {
            for i in 0..grid.texel_count() {
                let c = grid.texel_point(i, 0.5, 0.5);
                let r = grid.texel_radius(i);
                assert_eq!(grid.texel_of(c), i);
                for _ in 0..20 {
                    let u = rng.uniform2();
                    let p = grid.texel_point(i, u.x, u.y);
                    assert!(angle(c, p) <= r, "{grid:?} texel {i}");
                }
            }
        }
        // Every lat-long texel holding a point of a cap is visited.
        let (w, h) = (32, 16);
        let grid = Grid::LatLong {
            width: w,
            height: h,
        };
        for _ in 0..500 {
            let c = uniform_sphere(rng.uniform2());
            let r = 0.02 + 0.3 * rng.uniform();
            let mut seen = vec![false; w * h];
            latlong_texels_near(w, h, c, r, |t| seen[t] = true);
            for _ in 0..200 {
                let p = uniform_sphere(rng.uniform2());
                if angle(c, p) <= r {
                    assert!(seen[grid.texel_of(p)]);
                }
            }
        }
    }
}
