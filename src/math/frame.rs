//! Orthonormal frames: BSDFs and lobes work in a local frame whose z axis is the normal or the
//! lobe axis.

use glam::Vec3;

/// An orthonormal basis (s, t, n).
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    pub s: Vec3,
    pub t: Vec3,
    pub n: Vec3,
}

impl Frame {
    /// A frame around unit vector `n`, built without branches on near-parallel axes
    /// (Duff et al. 2017, "Building an orthonormal basis, revisited").
    pub fn from_z(n: Vec3) -> Self {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Frame { s, t, n }
    }

    #[inline]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }

    #[inline]
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.s * v.x + self.t * v.y + self.n * v.z
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    #[test]
    fn frames_are_orthonormal_for_any_axis() {
        let mut rng = Rng::new(3, 0);
        let mut axes = vec![
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            -Vec3::Y,
            Vec3::new(0.0, 0.0, -1.0 + 1e-7).normalize(),
        ];
        for _ in 0..1000 {
            axes.push(crate::math::warp::uniform_sphere(rng.uniform2()));
        }
        for n in axes {
            let f = Frame::from_z(n);
            assert!((f.s.length() - 1.0).abs() < 1e-4);
            assert!((f.t.length() - 1.0).abs() < 1e-4);
            assert!(
                f.s.dot(f.t).abs() < 1e-4 && f.s.dot(f.n).abs() < 1e-4 && f.t.dot(f.n).abs() < 1e-4
            );
            let v = Vec3::new(0.3, -0.5, 0.8);
            assert!((f.to_local(f.to_world(v)) - v).length() < 1e-5);
        }
    }
}
