//! Ground truth: closed-form ray intersections (and, behind the `embree` feature, Embree 4).
pub mod analytic;
#[cfg(feature = "embree")]
pub mod embree;
pub mod query;
