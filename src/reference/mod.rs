//! Ground truth: closed-form ray intersections in f64, Embree 4 (behind the `embree` feature),
//! and the ray-by-ray validation of a backend against a referee.
pub mod analytic;
#[cfg(feature = "embree")]
pub mod embree;
pub mod query;
#[cfg(feature = "embree")]
pub mod shading;
pub mod validate;
