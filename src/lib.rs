//! Lacuna: an embeddable, physically based renderer that analyses the empty space of a scene.
//!
//! Data flows from a [`scene::SceneBuilder`] (validated input) to an immutable
//! [`scene::Scene`], through an integrator, into a [`film::Film`]. See `ARCHITECTURE.md` (module map, layers) and
//! `docs/design.md` (principles).

pub mod analysis;
pub mod capi;
pub mod compare;
pub mod error;
pub mod film;
pub mod geometry;
pub mod guide;
pub mod image_file;
pub mod integrator;
pub mod light;
pub mod limits;
pub mod math;
pub mod render;
pub mod scene;
pub mod timing;
pub mod workers;

pub use error::{Error, Result};
