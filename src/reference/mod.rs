//! Ground truth: closed-form ray intersections (and, behind the `embree` feature, Embree 4).
pub mod analytic;
