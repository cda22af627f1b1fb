//! Ground truth: closed-form ray intersections, meshes of SDF objects extracted by our own
//! mesher, and (behind the `embree` feature) Embree 4 tracing both.
pub mod analytic;
#[cfg(feature = "embree")]
pub mod embree;
pub mod mesher;
pub mod query;
