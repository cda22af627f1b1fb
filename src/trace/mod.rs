//! Tracing: sphere tracing of SDF tapes, normals, and the scene's closest-hit and occlusion queries.

pub mod normal;
pub mod sphere;

use crate::accel::SdfAccel;
use crate::geom::Ray;
use crate::scene::{Scene, Shadow, TracerSettings};
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
    /// |∇f| at the hit as the normal estimator measured it: 1 for an exact field, below 1
    /// for a conservative bound, above 1 for a broken one (the `gradient` debug view).
    pub gradient: f32,
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
            let (n, gradient) = normal::estimate(tape, p, h, s.normals, &mut regs);
            Hit {
                t,
                object,
                normal: n,
                gradient,
                steps,
            }
        })
    }

    /// The fraction of light arriving along a shadow ray over (tmin, tmax): 0 or 1 for hard
    /// shadows, the penumbra estimate for soft ones. The penumbra of the scene (the minimum
    /// of the objects' fields) is the minimum of the objects' penumbrae, since min over t of
    /// k·min_i(h_i)/t = min over i of min over t of k·h_i/t.
    pub fn visibility(&self, ray: &Ray, tmin: f32, tmax: f32, shadow: Shadow) -> f32 {
        let (k, improved) = match shadow {
            Shadow::None => return 1.0,
            Shadow::Hard => return if self.occluded(ray, tmin, tmax) { 0.0 } else { 1.0 },
            Shadow::Soft(k) => (k, false),
            Shadow::SoftImproved(k) => (k, true),
        };
        let s = &self.scene.tracer;
        let mut regs = Registers::new();
        let mut res: f32 = 1.0;
        let mut limit = tmax.min(s.max_distance);
        // k·h/t < 1 only where h < t/k ≤ limit/k: objects farther than that from the ray
        // cannot darken it, nearer ones can even when the ray misses their bounds.
        let margin = limit / k;
        self.accel.visit_within(ray, tmin, &mut limit, margin, |i, t0, t1, _| {
            let tape = &self.scene.objects[i].lowered.distance;
            // the penumbra counts distance from the shadow ray's origin, not from the bounds
            let v = sphere::penumbra(tape, ray, t0, t1, s, k, improved, &mut regs);
            res = res.min(v);
            if res <= 0.0 {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        });
        // Quilez smooths the estimate with smoothstep to hide its piecewise-linear falloff.
        res * res * (3.0 - 2.0 * res)
    }

    /// The scene's distance field at p (the minimum over objects), looking only as far as
    /// `reach`: objects whose bounds are farther away contribute their bounds distance, which
    /// is a lower bound and never below `reach`.
    pub fn distance(&self, p: Vec3, reach: f32) -> f32 {
        let mut regs = Registers::new();
        let mut d = f32::INFINITY;
        for o in &self.scene.objects {
            let b = o.bounds();
            let lower = if b.is_finite() { b.signed_distance(p) } else { f32::NEG_INFINITY };
            d = d.min(if lower > reach { lower } else { o.lowered.distance.eval_in(p, &mut regs) });
        }
        d
    }

    /// The distance at which a ray that starts inside `object` leaves it, with the outward
    /// normal there.
    pub fn exit(&self, object: usize, ray: &Ray, tmax: f32) -> Option<(f32, Vec3)> {
        let s = &self.scene.tracer;
        let tape = &self.scene.objects[object].lowered.distance;
        let mut regs = Registers::new();
        let t = sphere::exit(tape, ray, 0.0, tmax.min(s.max_distance), s, &mut regs)?;
        let n = normal::estimate(tape, ray.at(t), normal::step_for(s, t), s.normals, &mut regs).0;
        Some((t, n))
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
