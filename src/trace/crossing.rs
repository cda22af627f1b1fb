//! Confirming a sphere tracer's hit: the ray must actually cross the surface where the field
//! fell below ε, and the hit is then placed at that crossing.
//!
//! Hart's test (1996, §2) stops wherever f(p) < ε(t). That is right for an exact distance,
//! except at silhouettes: a ray passing within ε of a thin object never reaches its surface
//! but stops anyway, so thin parts grow by ε on every side (on the shipped scenes ~1% of a torus
//! tube's rays, where Embree's closed form misses). For a distance *bound* — an implicit f/λ with
//! |∇f| ≪ λ — f < ε holds in a band much wider than ε, and stopping at its edge puts the hit far
//! in front of the surface (up to a unit on the quartic torus of `implicit.ron`).
//!
//! So a candidate is confirmed the way Kalra and Barr confirm a root ("Guaranteed ray
//! intersections with implicit surfaces", SIGGRAPH 1989): find a sign change and narrow it by
//! bisection. The field's slope along the ray, a secant over one ε, predicts where the crossing
//! lies (a Newton step); a probe just past it that finds f ≤ 0 brackets a crossing, and bisection
//! narrows the bracket to ε/2, returning its outside end. If neither the secant nor the probe
//! finds the inside, the ray has not met the surface here (a near miss, or a prediction the
//! curvature spoiled): the march goes on by max(f, ε) from the secant's end, so it cannot skip
//! more than ε of surface — the band Hart's test accepts anyway.

use super::step::epsilon_at;
use crate::accel::field::FieldCursor;
use crate::geom::Ray;
use crate::scene::TracerSettings;

/// What a candidate hit turned out to be.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Candidate {
    /// A crossing: the hit distance (within ε/2 in front of the surface).
    Hit(f32),
    /// No crossing here: continue the march from this distance.
    Continue(f32),
}

/// Bisection steps at most (the bracket shrinks below ε/2 long before).
const MAX_BISECTIONS: u32 = 24;

/// Confirms the candidate at `t`, where the field is `d < ε(t)`, before `t1`. Adds the
/// evaluations spent to `steps`.
pub fn confirm(
    field: &mut FieldCursor,
    ray: &Ray,
    t: f32,
    d: f32,
    t1: f32,
    s: &TracerSettings,
    steps: &mut u32,
) -> Candidate {
    let mut check = match Confirmation::start(t, d, t1, s) {
        Progress::Evaluate(c) => c,
        Progress::Decided(answer) => return answer,
    };
    loop {
        let value = field.eval(ray.at(check.at()));
        *steps += 1;
        check = match check.feed(value, t1, s) {
            Progress::Evaluate(c) => c,
            Progress::Decided(answer) => return answer,
        };
    }
}

/// A confirmation under way, one field value at a time: [`confirm`] drives it point after
/// point, and a bundle of rays drives many at once, their points evaluated together
/// ([`super::packet`]), with the same sequence of points and so the same answer.
#[derive(Debug, Clone, Copy)]
pub struct Confirmation {
    stage: Stage,
    /// ε at the candidate.
    eps: f32,
}

#[derive(Debug, Clone, Copy)]
enum Stage {
    /// Waiting for the field at `ts`, one ε past the candidate at `t` (where it was `d`).
    Secant { t: f32, d: f32, ts: f32 },
    /// Waiting for the field at `tp`, Newton's prediction from the secant (`ds` at `ts`).
    Probe { ts: f32, ds: f32, tp: f32 },
    /// Waiting for the field at the middle of the bracket; `done` halvings so far.
    Bisect {
        outside: f32,
        inside: f32,
        done: u32,
    },
}

/// What a confirmation needs next.
#[derive(Debug, Clone, Copy)]
pub enum Progress {
    /// The field at [`Confirmation::at`].
    Evaluate(Confirmation),
    /// Nothing: the candidate is decided.
    Decided(Candidate),
}

impl Confirmation {
    /// Starts confirming the candidate at `t`, where the field is `d < ε(t)`, before `t1`.
    pub fn start(t: f32, d: f32, t1: f32, s: &TracerSettings) -> Progress {
        // Already inside (the ray starts in the solid, or a bound field let a step
        // overshoot): the crossing is behind; keep Hart's answer.
        if d <= 0.0 {
            return Progress::Decided(Candidate::Hit(t));
        }
        let eps = epsilon_at(s, t);
        // The secant over one ε.
        let ts = (t + eps).min(t1);
        if ts <= t {
            return Progress::Decided(Candidate::Continue(t + eps));
        }
        Progress::Evaluate(Confirmation {
            stage: Stage::Secant { t, d, ts },
            eps,
        })
    }

    /// [`Self::start`] writing the confirmation into `slot` (left as it was when the
    /// candidate is decided at once), for a caller that keeps it in a lane's state: the
    /// fields are stored where the next step reads them, one by one, rather than built in a
    /// temporary and copied over in wider words (which a later read of a field cannot
    /// forward from the stores that made it: a stall that was a tenth of a bundle's time).
    #[inline]
    pub fn start_in(
        slot: &mut Option<Confirmation>,
        t: f32,
        d: f32,
        t1: f32,
        s: &TracerSettings,
    ) -> Option<Candidate> {
        match Self::start(t, d, t1, s) {
            Progress::Evaluate(c) => {
                *slot = Some(c);
                None
            }
            Progress::Decided(answer) => Some(answer),
        }
    }

    /// [`Self::feed`] in place: the next confirmation replaces this one, or the candidate
    /// is decided (this one is then left as it was, for the caller to clear).
    #[inline]
    pub fn feed_in(&mut self, value: f32, t1: f32, s: &TracerSettings) -> Option<Candidate> {
        match self.feed(value, t1, s) {
            Progress::Evaluate(next) => {
                *self = next;
                None
            }
            Progress::Decided(answer) => Some(answer),
        }
    }

    /// The ray parameter whose field value [`Self::feed`] wants.
    #[inline]
    pub fn at(&self) -> f32 {
        match self.stage {
            Stage::Secant { ts, .. } => ts,
            Stage::Probe { tp, .. } => tp,
            Stage::Bisect {
                outside, inside, ..
            } => 0.5 * (outside + inside),
        }
    }

    /// The next step, given the field `value` at [`Self::at`].
    #[inline]
    pub fn feed(self, value: f32, t1: f32, s: &TracerSettings) -> Progress {
        let eps = self.eps;
        match self.stage {
            Stage::Secant { t, d, ts } => {
                let ds = value;
                if ds <= 0.0 {
                    return self.bisect(t, ts, 0, s);
                }
                let slope = (ds - d) / (ts - t);
                if slope < 0.0 {
                    // Newton's prediction of the crossing, probed one ε past.
                    let tp = (ts + ds / -slope + eps).min(t1);
                    if tp > ts {
                        return Progress::Evaluate(Confirmation {
                            stage: Stage::Probe { ts, ds, tp },
                            eps,
                        });
                    }
                }
                // From ts the field guarantees a free step of ds; step at least ε.
                Progress::Decided(Candidate::Continue(ts + ds.max(eps)))
            }
            Stage::Probe { ts, ds, tp } => {
                if value <= 0.0 {
                    return self.bisect(ts, tp, 0, s);
                }
                Progress::Decided(Candidate::Continue(ts + ds.max(eps)))
            }
            Stage::Bisect {
                outside,
                inside,
                done,
            } => {
                let mid = 0.5 * (outside + inside);
                let (outside, inside) = if value <= 0.0 {
                    (outside, mid)
                } else {
                    (mid, inside)
                };
                self.bisect(outside, inside, done + 1, s)
            }
        }
    }

    /// Narrows a bracket (`outside`: f > 0, `inside`: f ≤ 0) to ε/2 and answers its outside
    /// end: the next halving, or the answer once the bracket is narrow enough.
    #[inline]
    fn bisect(self, outside: f32, inside: f32, done: u32, s: &TracerSettings) -> Progress {
        if done >= MAX_BISECTIONS || inside - outside <= 0.5 * epsilon_at(s, outside) {
            return Progress::Decided(Candidate::Hit(outside));
        }
        Progress::Evaluate(Confirmation {
            stage: Stage::Bisect {
                outside,
                inside,
                done,
            },
            eps: self.eps,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;
    use glam::Vec3;
    use std::path::Path;

    fn scene(shape: &str, eps: f32) -> Scene {
        let src = format!(
            "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40),
                   objects: [(shape: {shape})],
                   tracer: (epsilon: {eps}, epsilon_per_unit: 0, max_steps: 4096))"
        );
        Scene::from_source(&src, Path::new("crossing-test.ron")).unwrap_or_else(|e| panic!("{e}"))
    }

    fn trace(scene: &Scene, ray: &Ray) -> Option<f32> {
        let tracer = crate::trace::SceneTracer::new(scene);
        tracer.closest_hit(ray, 0.0, 100.0).map(|h| h.t)
    }

    #[test]
    fn a_ray_passing_within_epsilon_of_a_sphere_misses_it() {
        let s = scene("Sphere(radius: 1)", 1e-2);
        // Passes the unit sphere at distance 1 + ε/2: Hart's test alone calls it a hit.
        let ray = Ray::new(Vec3::new(1.005, 0.0, 5.0), Vec3::NEG_Z);
        assert_eq!(trace(&s, &ray), None);
        // A ray that does cross, just inside the silhouette, still hits.
        let ray = Ray::new(Vec3::new(0.995, 0.0, 5.0), Vec3::NEG_Z);
        let t = trace(&s, &ray).expect("hit");
        let exact = 5.0 - (1.0f32 - 0.995 * 0.995).sqrt();
        assert!((t - exact).abs() < 1e-2, "{t} vs {exact}");
    }

    #[test]
    fn a_loose_bound_is_hit_at_its_surface_not_at_the_edge_of_its_band() {
        // The unit sphere as an implicit with a deliberately loose λ = 40: f/λ < ε holds
        // 40ε/|∇f| ≈ 20ε in front of the surface.
        let s = scene(
            "Implicit(expr: \"x*x + y*y + z*z - 1\", lipschitz: 40, half_extents: (1.1, 1.1, 1.1))",
            1e-3,
        );
        for x in [0.0f32, 0.5, 0.9, 0.99] {
            let ray = Ray::new(Vec3::new(x, 0.0, 5.0), Vec3::NEG_Z);
            let t = trace(&s, &ray).expect("hit");
            let exact = 5.0 - (1.0 - x * x).sqrt();
            // Within ε/2 in front along the normal, i.e. ε/(2|n·d|) along the ray.
            let cos = (1.0 - x * x).sqrt();
            assert!(
                t <= exact + 1e-4 && exact - t <= 0.5e-3 / cos + 1e-4,
                "x = {x}: t = {t}, exact {exact}"
            );
        }
    }
}
