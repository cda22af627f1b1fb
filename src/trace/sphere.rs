//! Hart's sphere tracing (J. C. Hart, "Sphere tracing: a geometric method for the antialiased
//! ray tracing of implicit surfaces", The Visual Computer 12, 1996, §2).

use super::epsilon_at;
use crate::geom::Ray;
use crate::scene::TracerSettings;
use crate::sdf::tape::{Registers, Tape};

/// Outcome of tracing one ray against one tape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraceResult {
    /// Hit distance, if the ray came within ε(t) of the surface inside the interval.
    pub t: Option<f32>,
    /// Distance evaluations spent.
    pub steps: u32,
}

/// Marches from t0 towards t1 by the field value: the field is 1-Lipschitz (every node of the
/// lowered tape is step-corrected), so an unbounding sphere of radius f(p) around p contains no
/// surface and the step never skips one (Hart 1996, Theorem 1). Stops with a hit when
/// f < ε(t), with a miss past t1 or after `max_steps` evaluations.
pub fn trace(
    tape: &Tape,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
    regs: &mut Registers,
) -> TraceResult {
    let mut t = t0;
    let mut steps = 0;
    while steps < s.max_steps {
        let d = tape.eval_in(ray.at(t), regs);
        steps += 1;
        if d < epsilon_at(s, t) {
            return TraceResult { t: Some(t), steps };
        }
        t += d;
        if t > t1 {
            break;
        }
    }
    TraceResult { t: None, steps }
}
