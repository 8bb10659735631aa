//! Small test geometry built quad by quad: one quad helper, and the open box (floor, back and
//! side walls, open towards the camera and the ceiling) that several agreement scenes share.

use lacuna::math::Vec3;
use lacuna::scene::{MeshDesc, SceneBuilder};

/// Adds the quad `corners` (two triangles, 0-1-2 and 0-2-3) with `material`.
pub fn quad(b: &mut SceneBuilder, corners: [Vec3; 4], material: u32) {
    b.add_mesh(MeshDesc {
        positions: corners.to_vec(),
        indices: vec![[0, 1, 2], [0, 2, 3]],
        materials: vec![material],
        ..Default::default()
    })
    .unwrap();
}

/// Materials of an [`open_box`]'s four faces.
pub struct OpenBoxMaterials {
    pub floor: u32,
    pub back: u32,
    pub left: u32,
    pub right: u32,
}

/// The faces of [-1, 1]^3 at y = -1 (floor), z = -1 (back), x = -1 and x = 1, facing inwards;
/// the box is open at z = 1 (towards the camera) and y = 1 (the ceiling).
pub fn open_box(b: &mut SceneBuilder, m: OpenBoxMaterials) {
    let v = Vec3::new;
    quad(
        b,
        [
            v(-1., -1., -1.),
            v(-1., -1., 1.),
            v(1., -1., 1.),
            v(1., -1., -1.),
        ],
        m.floor,
    );
    quad(
        b,
        [
            v(-1., -1., -1.),
            v(1., -1., -1.),
            v(1., 1., -1.),
            v(-1., 1., -1.),
        ],
        m.back,
    );
    quad(
        b,
        [
            v(-1., -1., -1.),
            v(-1., 1., -1.),
            v(-1., 1., 1.),
            v(-1., -1., 1.),
        ],
        m.left,
    );
    quad(
        b,
        [
            v(1., -1., -1.),
            v(1., -1., 1.),
            v(1., 1., 1.),
            v(1., 1., -1.),
        ],
        m.right,
    );
}
