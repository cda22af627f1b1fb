//! Tracing: sphere tracing of SDF tapes, normals, and the scene's closest-hit and occlusion queries.

pub mod normal;
pub mod sphere;

use crate::accel::SdfAccel;
use crate::geom::Ray;
use crate::scene::{Scene, TracerSettings};
use crate::sdf::tape::Registers;
use glam::Vec3;
use std::ops::ControlFlow;

/// The closest intersection of a ray with the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter (distance along the unit direction).
    pub t: f32,
    /// Index of the object hit.
    pub object: usize,
    /// Unit surface normal (pointing out of the solid).
    pub normal: Vec3,
    /// Sphere-tracing steps spent on this ray, over all objects tried.
    pub steps: u32,
}

/// The hit threshold at distance t: ε(t) = ε₀ + ε₁·t, a cone of roughly one pixel's footprint
/// when ε₁ ≈ tan(fov/2)/height (Hart 1996, §4.2 uses a fixed ε; the growth keeps far-away
/// surfaces from costing the full step budget).
#[inline]
pub fn epsilon_at(s: &TracerSettings, t: f32) -> f32 {
    s.epsilon + s.epsilon_per_unit * t.max(0.0)
}

/// Answers ray queries against a scene's SDF objects on the CPU.
pub struct SceneTracer<'a> {
    scene: &'a Scene,
    accel: SdfAccel,
}

impl<'a> SceneTracer<'a> {
    /// Prepares the acceleration structure.
    pub fn new(scene: &'a Scene) -> Self {
        SceneTracer {
            scene,
            accel: SdfAccel::new(&scene.objects),
        }
    }

    /// The scene being traced.
    pub fn scene(&self) -> &Scene {
        self.scene
    }

    /// The closest hit in (tmin, tmax), with its normal.
    pub fn closest_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<Hit> {
        let s = &self.scene.tracer;
        let mut regs = Registers::new();
        let mut best: Option<(f32, usize)> = None;
        let mut steps = 0;
        let mut limit = tmax.min(s.max_distance);
        self.accel.visit(ray, tmin, &mut limit, |i, t0, t1, limit| {
            let tape = &self.scene.objects[i].lowered.distance;
            let r = sphere::trace(tape, ray, t0, t1, s, &mut regs);
            steps += r.steps;
            if let Some(t) = r.t {
                if best.is_none_or(|(bt, _)| t < bt) {
                    best = Some((t, i));
                    *limit = t;
                }
            }
            ControlFlow::Continue(())
        });
        best.map(|(t, object)| {
            let tape = &self.scene.objects[object].lowered.distance;
            let p = ray.at(t);
            let h = normal::step_for(s, t);
            Hit {
                t,
                object,
                normal: normal::estimate(tape, p, h, s.normals, &mut regs),
                steps,
            }
        })
    }

    /// Whether anything blocks the ray within (tmin, tmax) (shadow rays): stops at the first
    /// object hit, in any order.
    pub fn occluded(&self, ray: &Ray, tmin: f32, tmax: f32) -> bool {
        let s = &self.scene.tracer;
        let mut regs = Registers::new();
        let mut blocked = false;
        let mut limit = tmax.min(s.max_distance);
        self.accel.visit(ray, tmin, &mut limit, |i, t0, t1, _| {
            let tape = &self.scene.objects[i].lowered.distance;
            if sphere::trace(tape, ray, t0, t1, s, &mut regs).t.is_some() {
                blocked = true;
                return ControlFlow::Break(());
            }
            ControlFlow::Continue(())
        });
        blocked
    }
}
