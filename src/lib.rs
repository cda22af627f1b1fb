//! hytrace: a hybrid renderer of triangle meshes and sphere-traced signed distance functions.
//!
//! The modules follow the pipeline:
//! [`scene`] (RON files → validated scene) → [`sdf`] (SDF trees lowered to one tape format) →
//! [`accel`] (which objects a ray may meet) → [`trace`] (sphere tracing, normals, hit and
//! occlusion queries) → [`shade`] (materials and lights) → [`render`] (backends and image
//! output) → [`gpu`] (the same on wgpu) and [`viewer`] (the interactive window);
//! [`reference`] holds the ground truth (closed forms and Embree 4).
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
pub mod viewer;
