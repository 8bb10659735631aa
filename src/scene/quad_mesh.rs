//! Triangle meshes made of quads and axis-aligned boxes: the building blocks of the procedural
//! scenes (the family `rooms:SEED`, the interior).

use crate::math::Vec3;

/// Positions and triangles, grown a quad or a box at a time.
#[derive(Default)]
pub(super) struct QuadMesh {
    pub(super) positions: Vec<Vec3>,
    pub(super) indices: Vec<[u32; 3]>,
}

impl QuadMesh {
    /// Quad a-b-c-d, counter-clockwise seen from its front.
    pub(super) fn quad(&mut self, a: Vec3, b: Vec3, c: Vec3, d: Vec3) {
        let i = self.positions.len() as u32;
        self.positions.extend([a, b, c, d]);
        self.indices.push([i, i + 1, i + 2]);
        self.indices.push([i, i + 2, i + 3]);
    }

    /// The axis-aligned box from corner `a` to corner `b`, its sides facing outward.
    pub(super) fn cuboid(&mut self, a: Vec3, b: Vec3) {
        let p = Vec3::new;
        self.quad(
            p(a.x, a.y, b.z),
            p(b.x, a.y, b.z),
            p(b.x, b.y, b.z),
            p(a.x, b.y, b.z),
        );
        self.quad(
            p(b.x, a.y, a.z),
            p(a.x, a.y, a.z),
            p(a.x, b.y, a.z),
            p(b.x, b.y, a.z),
        );
        self.quad(
            p(b.x, a.y, b.z),
            p(b.x, a.y, a.z),
            p(b.x, b.y, a.z),
            p(b.x, b.y, b.z),
        );
        self.quad(
            p(a.x, a.y, a.z),
            p(a.x, a.y, b.z),
            p(a.x, b.y, b.z),
            p(a.x, b.y, a.z),
        );
        self.quad(
            p(a.x, b.y, b.z),
            p(b.x, b.y, b.z),
            p(b.x, b.y, a.z),
            p(a.x, b.y, a.z),
        );
        self.quad(
            p(a.x, a.y, a.z),
            p(b.x, a.y, a.z),
            p(b.x, a.y, b.z),
            p(a.x, a.y, b.z),
        );
    }
}
