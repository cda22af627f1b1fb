//! hytrace: a hybrid renderer of triangle meshes and sphere-traced signed distance functions.
//!
//! The modules follow the pipeline:
//! [`scene`] (RON files → validated scene) → [`sdf`] (SDF trees lowered to one tape format) →
//! [`accel`] (which objects a ray may meet) → [`trace`] (sphere tracing, normals, hit and
//! occlusion queries) → [`shade`] (materials and lights) → [`render`] (backends and image
//! output); [`reference`] holds the ground truth (closed forms, later Embree).
#![warn(missing_docs)]

pub mod accel;
pub mod bench;
pub mod geom;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod reference;
pub mod render;
pub mod rng;
pub mod scene;
pub mod sdf;
pub mod shade;
pub mod trace;
