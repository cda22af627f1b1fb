//! What every stepper shares: the hit threshold, the outcome of a march, and moving a ray
//! through the leaves of an object's field octree.

use crate::accel::field::{Cell, FieldCursor, Region};
use crate::geom::Ray;
use crate::scene::TracerSettings;
use crate::sdf::simplify::Verdict;
use glam::Vec3;

/// The hit threshold at distance t: ε(t) = ε₀ + ε₁·t, a cone of roughly one pixel's footprint
/// when ε₁ ≈ tan(fov/2)/height (Hart 1996, §4.2 uses a fixed ε; the growth keeps far-away
/// surfaces from costing the full step budget).
#[inline]
pub fn epsilon_at(s: &TracerSettings, t: f32) -> f32 {
    s.epsilon + s.epsilon_per_unit * t.max(0.0)
}

/// Outcome of tracing one ray against one object.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraceResult {
    /// Hit distance, if the ray came within ε(t) of the surface inside the interval.
    pub t: Option<f32>,
    /// Distance evaluations spent, point and interval ones alike.
    pub steps: u32,
    /// Of `steps`, the interval (segment) evaluations of segment tracing.
    pub intervals: u32,
}

impl TraceResult {
    /// The outcome of a stepper that evaluates the field at points only.
    pub fn of_points(t: Option<f32>, steps: u32) -> Self {
        TraceResult {
            t,
            steps,
            intervals: 0,
        }
    }
}

/// A ray with its reciprocal direction, for leaf exits.
#[derive(Debug, Clone, Copy)]
pub struct Marching<'a> {
    /// The ray.
    pub ray: &'a Ray,
    /// 1/direction, componentwise.
    pub inv_dir: Vec3,
}

impl<'a> Marching<'a> {
    /// Prepares a ray.
    pub fn new(ray: &'a Ray) -> Self {
        Marching {
            ray,
            inv_dir: ray.direction.recip(),
        }
    }

    /// The first parameter past t at which the ray has left `cell` (where it leaves the box,
    /// nudged on until the point is outside it): how a march skips a leaf.
    #[inline]
    pub fn past(&self, cell: &Cell, t: f32) -> f32 {
        let e = cell.exit(self.ray, self.inv_dir).max(t);
        let mut nudge = (e.abs() * 4.0 * f32::EPSILON).max(1e-7);
        for _ in 0..8 {
            let next = e + nudge;
            if !cell.contains(self.ray.at(next)) {
                return next;
            }
            nudge *= 8.0;
        }
        e + nudge
    }

    /// Where the ray leaves `cell`.
    #[inline]
    pub fn exit(&self, cell: &Cell) -> f32 {
        cell.exit(self.ray, self.inv_dir)
    }
}

/// Most leaves a march may skip: every leaf along the ray at the finest depth, a few times
/// over (a bound on the loop, never reached by a sane ray).
pub const MAX_SKIPS: u32 = 4 * 3 * (1 << crate::accel::field::MAX_DEPTH);

/// The region at the ray's point t, and whether it is a leaf proven to be of `kind`.
#[inline]
pub fn region_at<'f>(cursor: &mut FieldCursor<'f, '_>, m: &Marching, t: f32) -> (Vec3, Region<'f>) {
    let p = m.ray.at(t);
    (p, cursor.region(p))
}

/// Whether a region is a leaf proven to be `kind`.
#[inline]
pub fn is(region: &Region, kind: Verdict) -> bool {
    region.cell.is_some_and(|c| c.leaf.verdict == kind)
}
