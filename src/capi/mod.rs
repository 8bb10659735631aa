//! Lacuna's stable C API: the only place in the crate with `extern "C"`.
//!
//! The conventions are those of `docs/capi-conventions.md`: one `lacuna_` prefix, opaque handles,
//! refcounted shared objects (`_retain`/`_release` over `Arc`) and single-owner builders and jobs
//! (`_new`/`_free` over `Box`), `lacuna_status` return codes with out-parameters written only on
//! success, a thread-local last-error message, an optional error callback per context, and every
//! body under one panic boundary ([`boundary::boundary`]). Every argument is validated.
//!
//! This layer converts, validates, calls the library and maps errors; it has no rendering logic.
//! `include/lacuna.h` is generated from these files by cbindgen (see `tests/header.rs`).

#![allow(non_camel_case_types)]
// Every entry point dereferences raw pointers after checking them for NULL; the contract each
// pointer must meet is written in the function's doc comment (it becomes the header's doc).
#![allow(clippy::missing_safety_doc)]

mod analysis;
mod boundary;
mod buffer;
mod builder;
mod compare;
mod context;
mod environment;
mod film;
mod guide;
mod job;
mod light_field;
mod light_sampler;
mod mesh;
mod photometric;
mod resampling;
mod scene;
mod skeleton;
mod surface;
mod types;
mod version;

pub use analysis::*;
pub use boundary::{
    debug_trigger_worker_panic, lacuna_debug_trigger_panic, lacuna_last_error_message,
    lacuna_status, lacuna_status_string,
};
pub use builder::*;
pub use compare::*;
pub use context::*;
pub use environment::*;
pub use film::*;
pub use guide::*;
pub use job::*;
pub use light_field::*;
pub use light_sampler::*;
pub use mesh::*;
pub use photometric::*;
pub use resampling::*;
pub use scene::*;
pub use skeleton::*;
pub use surface::*;
pub use types::*;
pub use version::*;
