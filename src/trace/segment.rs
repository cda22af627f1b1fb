//! Segment tracing: a stepper bounding the field over whole stretches of a ray with intervals.
//!
//! After Galin, Guérin, Paris & Peytavie, "Segment Tracing Using Local Lipschitz Bounds",
//! Eurographics 2020; the enclosures come from [`crate::sdf::interval`].

use super::crossing::{self, Candidate};
use super::step::{TraceResult, epsilon_at};
use crate::accel::field::FieldCursor;
use crate::geom::Ray;
use crate::scene::TracerSettings;
use crate::sdf::interval::{IntervalRegisters, Slope, eval_segment};
use std::cell::RefCell;

thread_local! {
    /// Interval registers (4 KiB) kept per thread rather than cleared per ray.
    static SLOPE_REGS: RefCell<IntervalRegisters<Slope>> = RefCell::new(IntervalRegisters::new());
}

/// A segment step shorter than this many Hart steps did not pay for its evaluation.
const USEFUL: f32 = 2.0;

/// Most Hart steps taken between two segment tries.
const MAX_BACKOFF: u32 = 8;

/// Marches from t0 towards t1 by candidate segments [t, t + s] (Galin et al. 2020, §4). Over
/// the segment's bounding box, [`eval_segment`] encloses f and its slope ∂f/∂t in [g_lo, g_hi];
/// with d = f(t) from a point evaluation, f(t + u) ≥ d + g_lo·u on the segment (the mean-value
/// theorem).
///
/// - If that stays positive to the segment's end, or the value enclosure is positive, the
///   segment holds no surface: the march jumps to its end and doubles s.
/// - Otherwise the first root lies no nearer than u = d/(−g_lo), the step of the paper's local
///   Lipschitz bound λ = −g_lo (only the field's fall along the ray matters, so the one-sided
///   bound is used, not max |∂f/∂t|). On a plane it is the exact distance to the crossing, where
///   Hart's steps shrink geometrically. The step is never shorter than Hart's d (the field is
///   1-Lipschitz), and the next segment is twice the step.
/// - A segment whose step gains less than [`USEFUL`] Hart steps did not pay for its
///   evaluation (loose enclosures near edges and in repeated domains): the next few steps are
///   Hart's, more after each useless segment (up to [`MAX_BACKOFF`]), so the stepper costs
///   little more than Hart's where intervals do not help.
///
/// Where d < ε(t) the candidate is confirmed exactly as Hart's ([`crossing::confirm`]), so the
/// hits agree up to where in the ε band each stepper arrives. Every segment evaluation counts
/// as one evaluation in `steps` and in `intervals`. Point samples use the field octree's leaf
/// tapes; a segment inside one leaf is enclosed with that leaf's tape, any other with the
/// whole tape.
pub fn trace_segment(
    field: &mut FieldCursor,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
) -> TraceResult {
    SLOPE_REGS.with(|sr| march(field, ray, t0, t1, s, &mut sr.borrow_mut()))
}

fn march(
    field: &mut FieldCursor,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
    sregs: &mut IntervalRegisters<Slope>,
) -> TraceResult {
    let mut t = t0;
    let (mut steps, mut intervals) = (0, 0);
    // The first candidate is the whole interval: a ray that passes far from the surface
    // crosses an object's bounds with one enclosure.
    let mut seg = t1 - t0;
    // Hart steps still to take before the next segment is tried, and how many to take after
    // the next useless one: where the enclosures are loose (near edges, inside repeated
    // domains) a segment costs an evaluation and gains nothing, so they are tried less and
    // less often there; a useful one resets the back-off.
    let (mut wait, mut backoff) = (0u32, 1u32);
    let result = |t, steps, intervals| TraceResult {
        t,
        steps,
        intervals,
    };
    while steps < s.max_steps {
        let p = ray.at(t);
        let region = field.region(p);
        let d = region.tape.eval_in(p, field.regs);
        steps += 1;
        let eps = epsilon_at(s, t);
        if d < eps {
            match crossing::confirm(field, ray, t, d, t1, s, &mut steps) {
                Candidate::Hit(t) => return result(Some(t), steps, intervals),
                Candidate::Continue(next) => {
                    t = next;
                    seg = eps;
                    if t > t1 {
                        break;
                    }
                    continue;
                }
            }
        }
        // Hart's step alone leaves the interval: nothing to find before t1.
        if t + d > t1 {
            break;
        }
        let len = seg.max(2.0 * d).min(t1 - t);
        if len <= d || wait > 0 || steps >= s.max_steps {
            wait = wait.saturating_sub(1);
            t += d;
            seg = seg.max(2.0 * d);
            continue;
        }
        let end = ray.at(t + len);
        let tape = match region.cell {
            Some(c) if c.contains(p) && c.contains(end) => c.tape,
            _ => field.whole_tape(),
        };
        let g = eval_segment(tape, p, end, ray.direction, sregs);
        steps += 1;
        intervals += 1;
        // Rounding of the sample positions and of the tape's own evaluation: keep a fraction
        // of ε short of what the enclosures allow.
        let margin = 0.25 * eps;
        if g.v.lo > 0.0 || d + g.d.lo * len > margin {
            t += len;
            seg = 2.0 * len;
            backoff = 1;
            if t >= t1 {
                break;
            }
            continue;
        }
        let u = if g.d.lo < 0.0 { d / -g.d.lo } else { len };
        let step = (u - margin).max(d);
        if step < USEFUL * d {
            wait = backoff;
            backoff = (2 * backoff).min(MAX_BACKOFF);
        } else {
            backoff = 1;
        }
        t += step;
        seg = 2.0 * step;
    }
    result(None, steps, intervals)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;
    use crate::scene::Stepper;
    use crate::sdf::tape::{Registers, Tape};
    use crate::trace::sphere::trace_hart;
    use glam::Vec3;
    use proptest::prelude::*;
    use std::path::Path;

    /// Whether the ray crosses below 0 within `len` after t (dense sampling).
    fn crosses(tape: &Tape, ray: &Ray, t: f32, len: f32, regs: &mut Registers) -> bool {
        (0..4000).any(|k| tape.eval_in(ray.at(t + len * k as f32 / 4000.0), regs) < 0.0)
    }

    /// On a sampling of every shipped scene's pixels, object by object over the ray's
    /// interval in its bounds, Segment finds the hits Hart finds, in the same ε band. A
    /// disagreement is allowed only where the two cannot agree by construction: Hart runs out
    /// of steps (grazing rays), or the ray comes within ε of a surface without crossing it
    /// (one stepper samples that stretch, the other steps over it).
    #[test]
    fn segment_finds_the_hits_hart_finds_on_every_shipped_scene() {
        let mut regs = Registers::new();
        for (name, scene) in crate::scene::shipped_scenes() {
            let s = TracerSettings {
                stepper: Stepper::Segment,
                ..scene.tracer
            };
            // The camera's rays through the centres of a 64×48 image.
            let rays: Vec<_> = (0..64 * 48)
                .map(|i| {
                    let (u, v) = ((i % 64) as f32 + 0.5, (i / 64) as f32 + 0.5);
                    scene.camera.ray(u / 64.0, v / 48.0, 64.0 / 48.0)
                })
                .collect();
            let mut hits = 0;
            for (i, ray) in rays.iter().enumerate() {
                for object in &scene.objects {
                    let Some((t0, t1)) = object.bounds().ray_interval(ray, 0.0, s.max_distance)
                    else {
                        continue;
                    };
                    let tape = &object.lowered.distance;
                    let hart = trace_hart(
                        &mut FieldCursor::whole(tape, &mut regs),
                        ray,
                        t0,
                        t1,
                        &scene.tracer,
                    );
                    let seg =
                        trace_segment(&mut FieldCursor::whole(tape, &mut regs), ray, t0, t1, &s);
                    assert!(seg.intervals <= seg.steps && seg.steps <= s.max_steps);
                    match (seg.t, hart.t) {
                        (Some(a), Some(b)) => {
                            assert!(
                                tape.eval_in(ray.at(a), &mut regs) < epsilon_at(&s, a),
                                "{name} ray {i} {}: Segment stops outside the ε band",
                                object.name
                            );
                            assert!(
                                (a - b).abs() < 0.05,
                                "{name} ray {i} {}: {a} vs Hart {b}",
                                object.name
                            );
                            hits += 1;
                        }
                        (None, None) => {}
                        (Some(t), None) | (None, Some(t)) => {
                            let explained = hart.steps >= s.max_steps
                                || seg.steps >= s.max_steps
                                || !crosses(tape, ray, t, 1.0, &mut regs);
                            assert!(
                                explained,
                                "{name} ray {i} {}: Segment {seg:?} vs Hart {hart:?}",
                                object.name
                            );
                        }
                    }
                }
            }
            assert!(hits > 0, "{name}: no hit at all");
        }
    }

    fn thin_scene(shape: &str) -> Scene {
        let src = format!(
            "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40),
                   objects: [(shape: {shape})],
                   tracer: (epsilon: 3e-5, epsilon_per_unit: 1e-5, max_steps: 100000))"
        );
        Scene::from_source(&src, Path::new("thin.ron")).unwrap_or_else(|e| panic!("{e}"))
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        /// A slab a few ε thick, tilted, or a hollow sphere's wall as thin, crossed by rays
        /// from far away at any angle: the enclosures over a long segment see a sliver, and a
        /// segment that straddles it must not be declared empty. Every ray that really enters
        /// the wall (its chord reaches 4ε inside) hits it, at the first entry. (A step budget
        /// large enough for rays that run inside the slab's plane: the property is about
        /// skipping, not about the budget.)
        #[test]
        fn segment_never_skips_a_thin_wall(
            thickness in 2e-4f32..2e-2,
            tilt in prop_oneof![Just(0.0f32), 0.0f32..80.0],
            shell in any::<bool>(),
            o in prop::array::uniform3(-1.0f32..1.0),
            target in prop::array::uniform2(-1.5f32..1.5),
        ) {
            let scene = thin_scene(&if shell {
                // a hollow sphere: the ray crosses its wall twice and must stop at the first
                format!("Onion(thickness: {thickness}, shape: Sphere(radius: 1.4))")
            } else {
                let slab = format!("Box(half_extents: (1.5, {thickness}, 1.5))");
                format!("Transform(rotate: ({tilt}, 0, 0), shape: {slab})")
            });
            let object = &scene.objects[0];
            let tape = &object.lowered.distance;
            let origin = Vec3::new(o[0] * 8.0, o[1] * 8.0 + 10.0, o[2] * 8.0);
            let ray = Ray::new(origin, Vec3::new(target[0], 0.0, target[1]) - origin);
            let mut regs = Registers::new();
            let s = TracerSettings { stepper: Stepper::Segment, ..scene.tracer };
            // From the ray's origin, not from the slab's tight bounds: the first segments are
            // long and reach across the slab.
            let (t0, t1) = (0.0, 40.0);
            // the entry, and how deep the ray gets (dense sampling of the exact box field)
            let n = 200_000;
            let (mut entry, mut depth) = (None, 0.0f32);
            for k in 0..=n {
                let t = t0 + (t1 - t0) * k as f32 / n as f32;
                let f = tape.eval_in(ray.at(t), &mut regs);
                if f < 0.0 && entry.is_none() {
                    entry = Some(t);
                }
                depth = depth.max(-f);
            }
            let seg = trace_segment(&mut FieldCursor::whole(tape, &mut regs), &ray, t0, t1, &s);
            if depth > 4.0 * epsilon_at(&s, t1) {
                let entry = entry.unwrap();
                let t = seg.t;
                prop_assert!(t.is_some(), "skipped the wall: {seg:?}, entry {entry}");
                let tol = 2.0 * (t1 - t0) / n as f32 + 1e-3;
                prop_assert!((t.unwrap() - entry).abs() < tol, "hit {t:?}, entry {entry}");
            }
            if let (Some(t), None) = (seg.t, entry) {
                // no crossing on the ray: only a near miss within the ε band may stop it
                let f = tape.eval_in(ray.at(t), &mut regs);
                prop_assert!(f < epsilon_at(&s, t), "hit at {t} where f = {f}");
            }
        }
    }
}
