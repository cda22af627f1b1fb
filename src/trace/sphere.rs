//! Hart's sphere tracing (J. C. Hart, "Sphere tracing: a geometric method for the antialiased
//! ray tracing of implicit surfaces", The Visual Computer 12, 1996, §2), and the opt-in
//! over-relaxed stepper of Keinert et al. 2014 ("Enhanced Sphere Tracing", STAG 2014, §3.1).

use super::epsilon_at;
use crate::geom::Ray;
use crate::scene::{Stepper, TracerSettings};
use crate::sdf::tape::{Registers, Tape};

/// Outcome of tracing one ray against one tape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraceResult {
    /// Hit distance, if the ray came within ε(t) of the surface inside the interval.
    pub t: Option<f32>,
    /// Distance evaluations spent.
    pub steps: u32,
}

/// Marches from t0 towards t1 with the scene's stepper (`tracer.stepper`): [`trace_hart`] by
/// default, [`trace_relaxed`] when asked for.
pub fn trace(
    tape: &Tape,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
    regs: &mut Registers,
) -> TraceResult {
    match s.stepper {
        Stepper::Hart => trace_hart(tape, ray, t0, t1, s, regs),
        Stepper::Relaxed(omega) => trace_relaxed(tape, ray, t0, t1, s, omega, regs),
    }
}

/// Marches from t0 towards t1 by the field value: the field is 1-Lipschitz (every node of the
/// lowered tape is step-corrected), so an unbounding sphere of radius f(p) around p contains no
/// surface and the step never skips one (Hart 1996, Theorem 1). Stops with a hit when
/// f < ε(t), with a miss past t1 or after `max_steps` evaluations.
pub fn trace_hart(
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

/// Over-relaxed sphere tracing (Keinert, Schäfer, Korndörfer, Ganse & Stamminger, "Enhanced
/// Sphere Tracing", STAG 2014, §3.1 and listing 1): step by ω·f(p) with 1 ≤ ω < 2. The step
/// from p to p' = p + ω·f(p)·d skips no surface when the unbounding spheres of p and p'
/// overlap, |f(p)| + |f(p')| ≥ ω·f(p), since together they then cover the segment. When they
/// do not, p' is discarded (its evaluation is the price of the gamble), the march resumes with
/// Hart's safe step f(p) from p, and — as in the paper's listing — the rest of the ray is
/// traced with ω = 1. A hit is only accepted at a point reached by a verified step, so the hit
/// is the first crossing along the ray, as Hart's is; the two differ by where inside the
/// ε band they stop. Relaxed steps are clamped to t1 so that the check also covers the end of
/// the interval.
pub fn trace_relaxed(
    tape: &Tape,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
    omega: f32,
    regs: &mut Registers,
) -> TraceResult {
    let mut omega = omega;
    let mut t = t0;
    let mut steps = 0;
    // The last accepted sample (parameter and field value) and whether the step from it to t
    // was relaxed (and so must be verified).
    let (mut prev_t, mut prev_d, mut unverified) = (t0, 0.0f32, false);
    while steps < s.max_steps {
        let d = tape.eval_in(ray.at(t), regs);
        steps += 1;
        if unverified && prev_d + d.abs() < t - prev_t {
            omega = 1.0;
            unverified = false;
            t = prev_t + prev_d;
            continue;
        }
        if d < epsilon_at(s, t) {
            return TraceResult { t: Some(t), steps };
        }
        // Hart's step alone leaves the interval: nothing to find before t1.
        if t + d > t1 {
            break;
        }
        prev_t = t;
        prev_d = d;
        unverified = omega > 1.0;
        t = (t + omega * d).min(t1);
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
