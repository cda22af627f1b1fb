//! Acceleration: which objects a ray can meet, and over which parametric interval.
//!
//! Every SDF object has conservative world bounds; a ray sphere-traces an object only inside
//! the interval where it crosses those bounds. Unbounded objects (planes, infinite repetition)
//! span the whole ray. The candidates are scanned linearly here; the meshes issue replaces the
//! scan with a BVH over the same bounds without changing this interface.

use crate::geom::{Aabb, Ray};
use crate::scene::SdfObject;
use std::ops::ControlFlow;

/// Culling structure over the SDF objects of a scene.
#[derive(Debug, Clone)]
pub struct SdfAccel {
    bounds: Vec<Aabb>,
}

impl SdfAccel {
    /// Builds over the objects' world bounds.
    pub fn new(objects: &[SdfObject]) -> Self {
        SdfAccel {
            bounds: objects.iter().map(|o| o.bounds()).collect(),
        }
    }

    /// Calls `visit(object, t_enter, t_exit)` for every object whose bounds the ray crosses
    /// within [tmin, tmax], in object order; `visit` may stop the walk. The interval is passed
    /// by `&mut` so a closest-hit query can shrink `tmax` as it finds hits.
    pub fn visit(
        &self,
        ray: &Ray,
        tmin: f32,
        tmax: &mut f32,
        visit: impl FnMut(usize, f32, f32, &mut f32) -> ControlFlow<()>,
    ) {
        self.visit_within(ray, tmin, tmax, 0.0, visit)
    }

    /// Like [`SdfAccel::visit`], with every object's bounds grown by `margin`: queries that
    /// look at the field *near* surfaces (soft-shadow penumbrae) need the rays that pass
    /// close to an object, not only those that cross its bounds.
    pub fn visit_within(
        &self,
        ray: &Ray,
        tmin: f32,
        tmax: &mut f32,
        margin: f32,
        mut visit: impl FnMut(usize, f32, f32, &mut f32) -> ControlFlow<()>,
    ) {
        for (i, b) in self.bounds.iter().enumerate() {
            let b = if margin > 0.0 { b.expand(margin) } else { *b };
            if let Some((t0, t1)) = b.ray_interval(ray, tmin, *tmax) {
                if visit(i, t0, t1, tmax).is_break() {
                    return;
                }
            }
        }
    }
}
