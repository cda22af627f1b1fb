//! Hart's sphere tracing (J. C. Hart, "Sphere tracing: a geometric method for the antialiased
//! ray tracing of implicit surfaces", The Visual Computer 12, 1996, §2).

use super::crossing::{self, Candidate};
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
/// surface and the step never skips one (Hart 1996, Theorem 1). Where f < ε(t) the candidate
/// is confirmed by a sign change and placed at the crossing ([`crossing::confirm`]); a miss
/// past t1 or after `max_steps` evaluations.
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
            match crossing::confirm(tape, ray, t, d, t1, s, regs, &mut steps) {
                Candidate::Hit(t) => return TraceResult { t: Some(t), steps },
                Candidate::Continue(next) => t = next,
            }
        } else {
            t += d;
        }
        if t > t1 {
            break;
        }
    }
    TraceResult { t: None, steps }
}

/// Light visibility along a shadow ray through one tape, from Quilez's penumbra estimate
/// ("soft shadows in raymarched SDFs", 2010): the smallest k·h/t met along the ray, where h is
/// the field and t the distance travelled, approximates the fraction of a light cone of
/// half-angle ~1/k left unblocked. The `improved` variant estimates the closest approach
/// between the last two samples (y = h²/(2h'), d = √(h² − y²), k·d/(t − y)), which removes
/// the banding of the plain estimate. Returns 1 (lit) down to 0 (blocked); a sample within
/// ε(t) of the surface is a hit and returns 0.
#[allow(clippy::too_many_arguments)]
pub fn penumbra(
    tape: &Tape,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
    k: f32,
    improved: bool,
    regs: &mut Registers,
) -> f32 {
    let mut res: f32 = 1.0;
    let mut previous = f32::INFINITY;
    let mut t = t0;
    for _ in 0..s.max_steps {
        let h = tape.eval_in(ray.at(t), regs);
        if h < epsilon_at(s, t) {
            return 0.0;
        }
        // The unbounding spheres of the last two samples meet on a circle whose plane lies y
        // behind the current sample; the closest approach to the surface is estimated there.
        // Only between the two samples (y ≤ h') does that geometry hold: where the field grows
        // as fast as the step (h ≈ 2h', the ray heading straight away), y would land behind
        // the previous sample and d collapse to 0, a false dark speck; use k·h/t there.
        let y = h * h / (2.0 * previous);
        let estimate = if improved && y <= previous {
            let d = (h * h - y * y).max(0.0).sqrt();
            k * d / (t - y).max(1e-6)
        } else {
            k * h / t.max(1e-6)
        };
        res = res.min(estimate);
        previous = h;
        t += h;
        if t > t1 || res < 1e-4 {
            break;
        }
    }
    res.clamp(0.0, 1.0)
}

/// Marches from inside a solid to where the ray leaves it: inside, −f bounds the distance to
/// the surface, so steps of 0.9·|f| (a step scale below 1 for bound fields whose interior
/// values are less reliable) never cross it. Returns the exit distance, or `None` if the ray
/// is still inside after `max_steps` or t1.
pub fn exit(
    tape: &Tape,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
    regs: &mut Registers,
) -> Option<f32> {
    let mut t = t0;
    for _ in 0..s.max_steps {
        let d = -tape.eval_in(ray.at(t), regs);
        if d < epsilon_at(s, t) {
            return Some(t);
        }
        t += 0.9 * d;
        if t > t1 {
            return None;
        }
    }
    None
}
