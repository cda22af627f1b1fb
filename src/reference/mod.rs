//! Ground truth: closed-form ray intersections in f64, meshes of SDF objects extracted by our
//! own mesher, Embree 4 tracing both (behind the `embree` feature), and the ray-by-ray
//! validation of a backend against a referee.
pub mod analytic;
pub mod certified;
pub mod check;
#[cfg(feature = "embree")]
pub mod embree;
pub mod interval64;
pub mod mesher;
#[cfg(feature = "embree")]
pub mod shading;
pub mod validate;
