//! Hart's sphere tracing (J. C. Hart, "Sphere tracing: a geometric method for the antialiased
//! ray tracing of implicit surfaces", The Visual Computer 12, 1996, §2), the opt-in
//! over-relaxed steppers of Keinert et al. 2014 ("Enhanced Sphere Tracing", STAG 2014, §3.1),
//! soft-shadow penumbrae and exits, all over an object's field octree
//! ([`crate::accel::field`]): every sample is evaluated with the tape specialised to the leaf
//! holding it, and leaves proven empty are skipped without an evaluation.

use super::crossing::{self, Candidate};
use super::step::{MAX_SKIPS, Marching, TraceResult, epsilon_at, is, region_at};
use crate::accel::field::{Crossed, FieldCursor, RayWalk};
use crate::geom::Ray;
use crate::scene::TracerSettings;
use crate::sdf::simplify::Verdict;
use crate::sdf::tape::Tape;
use glam::Vec3;

/// Marches from t0 towards t1 by the field value: the field is 1-Lipschitz (every node of the
/// lowered tape is step-corrected), so an unbounding sphere of radius f(p) around p contains no
/// surface and the step never skips one (Hart 1996, Theorem 1). Over an octree the march walks
/// the leaves along the ray ([`RayWalk`]): empty leaves are passed without an evaluation, each
/// other leaf is marched with its own tape, by f/fall where the leaf's gradient enclosure
/// shows the field falling slower than 1 along the ray ([`hart_step`], up to its exit). Where
/// f < ε(t) the candidate is confirmed by a sign change and placed at the crossing
/// ([`crossing::confirm`]); a miss past t1 or after `max_steps` evaluations.
pub fn trace_hart(
    field: &mut FieldCursor,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
) -> TraceResult {
    let mut steps = 0;
    let outcome = hart(field, ray, t0, t1, s, &mut steps);
    TraceResult::of_points(outcome, steps)
}

/// How a march over one stretch of the ray ended.
pub(crate) enum Stretch {
    /// A confirmed hit.
    Hit(f32),
    /// Past the stretch's end, at this t.
    Left(f32),
    /// The step budget is spent.
    Spent,
}

/// A part of a ray marched with one tape: a leaf's, or the whole tape's outside the tree.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Part<'f> {
    /// The tape valid there.
    pub tape: &'f Tape,
    /// How fast the field may fall along the ray there (1, the global bound, outside leaves
    /// with a gradient enclosure).
    pub fall: f32,
    /// Where the march starts (the current t, or the part's start if later).
    pub start: f32,
    /// Where it ends.
    pub end: f32,
}

/// The parts of [t0, t1] a ray is marched over, in order, given the march's current t: the
/// whole tape before the tree's box (an unbounded object clipped to the scene), the leaves of
/// the walk that are not empty, the whole tape beyond the box.
pub(crate) struct Parts<'f> {
    whole: &'f Tape,
    direction: Vec3,
    walk: Option<RayWalk<'f>>,
    phase: Phase,
    t1: f32,
    enter: f32,
    leave: f32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// One whole-tape part over [t0, t1] (no tree, or the ray misses its box).
    Whole,
    /// The whole tape up to the tree's box.
    Before,
    /// The leaves.
    Walk,
    /// The whole tape after the box.
    After,
    /// Nothing left.
    Done,
}

impl<'f> Parts<'f> {
    /// The parts of [t0, t1] along `ray` for the field of `cursor`.
    pub fn new(cursor: &FieldCursor<'f, '_>, ray: &Ray, t0: f32, t1: f32) -> Self {
        let whole = cursor.whole_tape();
        let mut parts = Parts {
            whole,
            direction: ray.direction,
            walk: None,
            phase: Phase::Whole,
            t1,
            enter: t0,
            leave: t1,
        };
        if let Some(tree) = cursor.octree() {
            if let Some((enter, leave)) = tree.bounds().ray_interval(ray, t0, t1) {
                parts.walk = Some(RayWalk::new(tree, ray, t0, leave));
                parts.phase = if t0 < enter {
                    Phase::Before
                } else {
                    Phase::Walk
                };
                parts.enter = enter;
                parts.leave = leave;
            }
        }
        parts
    }

    /// The next part for a march now at t, or `None` when nothing is left before t1.
    #[inline]
    pub fn next(&mut self, t: f32) -> Option<Part<'f>> {
        loop {
            match self.phase {
                Phase::Whole => {
                    self.phase = Phase::Done;
                    return Some(self.whole_part(t, self.t1));
                }
                Phase::Before => {
                    self.phase = Phase::Walk;
                    return Some(self.whole_part(t, self.enter));
                }
                Phase::Walk => {
                    let walk = self.walk.as_mut().expect("a walk in the walk phase");
                    match walk.next_leaf() {
                        Some(x) if x.exit < t || x.leaf.verdict == Verdict::Empty => {}
                        Some(x) => {
                            return Some(Part {
                                tape: x.tape,
                                fall: x.leaf.fall(self.direction),
                                start: t.max(x.enter),
                                end: x.exit.min(self.t1),
                            });
                        }
                        None => self.phase = Phase::After,
                    }
                }
                Phase::After => {
                    self.phase = Phase::Done;
                    if self.leave < self.t1 {
                        return Some(self.whole_part(t.max(next_up(self.leave)), self.t1));
                    }
                }
                Phase::Done => return None,
            }
        }
    }

    fn whole_part(&self, start: f32, end: f32) -> Part<'f> {
        Part {
            tape: self.whole,
            fall: 1.0,
            start,
            end,
        }
    }
}

/// The fraction of ε(t) by which a step lengthened by a leaf's fall stops short of it.
pub const HART_STEP_MARGIN: f32 = 0.25;

/// One step from a sample of value d ≥ ε(t) in `part`: Hart's d, or, where the leaf's
/// gradient enclosure shows the field falling by at most `fall` < 1 per unit along the ray,
/// d/fall within the leaf — no surface lies nearer (the field cannot reach 0 sooner), on a
/// plane it is the crossing itself — kept ε/4 short, as segment tracing keeps its steps
/// (Galin et al. 2020), so that rounding never lands past the crossing. Beyond the leaf the
/// global bound allows d.
#[inline]
pub(crate) fn hart_step(d: f32, part: &Part, t: f32, eps: f32) -> f32 {
    if part.fall < 1.0 {
        d.max((d / part.fall - HART_STEP_MARGIN * eps).min(part.end - t))
    } else {
        d
    }
}

/// Hart's march over one part.
#[inline]
fn march_part(
    field: &mut FieldCursor,
    part: &Part,
    ray: &Ray,
    t1: f32,
    s: &TracerSettings,
    steps: &mut u32,
) -> Stretch {
    let mut t = part.start;
    while t <= part.end {
        if *steps >= s.max_steps {
            return Stretch::Spent;
        }
        let d = part.tape.eval_in(ray.at(t), field.regs);
        *steps += 1;
        let eps = epsilon_at(s, t);
        if d < eps {
            match crossing::confirm(field, ray, t, d, t1, s, steps) {
                Candidate::Hit(t) => return Stretch::Hit(t),
                Candidate::Continue(next) => t = next,
            }
        } else {
            t += hart_step(d, part, t, eps);
        }
    }
    Stretch::Left(t)
}

fn hart(
    field: &mut FieldCursor,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
    steps: &mut u32,
) -> Option<f32> {
    let mut parts = Parts::new(field, ray, t0, t1);
    let mut t = t0;
    while let Some(part) = parts.next(t) {
        match march_part(field, &part, ray, t1, s, steps) {
            Stretch::Hit(t) => return Some(t),
            Stretch::Spent => return None,
            Stretch::Left(next) => t = next,
        }
        if t > t1 {
            return None;
        }
    }
    None
}

/// The next float above x ≥ 0.
#[inline]
pub(crate) fn next_up(x: f32) -> f32 {
    f32::from_bits(x.max(0.0).to_bits() + 1)
}

/// The tape valid at increasing parameters t along a ray: the leaves of the walk, the whole
/// tape outside the tree's box.
pub(crate) struct Along<'f> {
    walk: Option<RayWalk<'f>>,
    current: Option<Crossed<'f>>,
    whole: &'f Tape,
}

impl<'f> Along<'f> {
    /// The tapes along `ray` over [t0, t1] for the field of `field`.
    pub fn new(field: &FieldCursor<'f, '_>, ray: &Ray, t0: f32, t1: f32) -> Self {
        Along {
            walk: field.octree().map(|tree| RayWalk::new(tree, ray, t0, t1)),
            current: None,
            whole: field.whole_tape(),
        }
    }

    /// The leaf at t (t never decreasing between calls), or `None` outside the tree.
    #[inline]
    fn at(&mut self, t: f32) -> Option<Crossed<'f>> {
        if let Some(c) = self.current {
            if t <= c.exit {
                return (t >= c.enter).then_some(c);
            }
        }
        let walk = self.walk.as_mut()?;
        loop {
            match walk.next_leaf() {
                Some(c) if c.exit < t => continue,
                Some(c) => {
                    self.current = Some(c);
                    return (t >= c.enter).then_some(c);
                }
                None => {
                    self.walk = None;
                    self.current = None;
                    return None;
                }
            }
        }
    }

    /// The tape valid at t.
    #[inline]
    pub fn tape(&mut self, t: f32) -> &'f Tape {
        match self.at(t) {
            Some(c) => c.tape,
            None => self.whole,
        }
    }
}

/// How an over-relaxed march chooses ω.
#[derive(Debug, Clone, Copy)]
enum Relaxation {
    /// A fixed ω, dropped to 1 for the rest of the ray after the first failed step.
    Fixed(f32),
    /// ω from the field's slope along the ray; one Hart step after each failed step.
    Slope,
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
    field: &mut FieldCursor,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
    omega: f32,
) -> TraceResult {
    trace_over_relaxed(field, ray, t0, t1, s, Relaxation::Fixed(omega))
}

/// Largest relaxation [`trace_adaptive`] uses: below 2, where the overlap test stops being
/// able to accept a step at all.
const MAX_ADAPTIVE_OMEGA: f32 = 1.9;

/// Over-relaxed sphere tracing with a relaxation factor taken from the field's slope along the
/// ray. If the field falls by g per unit of t (g ≤ 1 for a 1-Lipschitz field), a step ω·f(p)
/// lands where the field is f(p)·(1 − g·ω), and the overlap test of [`trace_relaxed`] accepts
/// it while ω ≤ 2/(1 + g): so ω = 2/(1 + g) is the longest step the test can pass on a plane
/// (ω → 2 for grazing rays, where Hart's steps shrink geometrically; ω = 1 head-on). g is
/// estimated from the last two samples (after Bálint & Valasek, "Accelerating Sphere
/// Tracing", Eurographics 2018 short papers, which derive the step from the same planar
/// assumption). Safety does not depend on the estimate: every relaxed step is verified, and a
/// failed one falls back to Hart's step from the last verified sample, as in
/// [`trace_relaxed`]; the next step is then Hart's too.
pub fn trace_adaptive(
    field: &mut FieldCursor,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
) -> TraceResult {
    trace_over_relaxed(field, ray, t0, t1, s, Relaxation::Slope)
}

/// The march shared by [`trace_relaxed`] and [`trace_adaptive`]: relaxed steps verified by the
/// overlap test, a failed one replaced by Hart's step from the last verified sample, and
/// candidates confirmed as Hart's are ([`crossing::confirm`]; a near miss counts as a failure).
/// A verified sample in an empty leaf leaves it at once, as Hart's march does.
fn trace_over_relaxed(
    field: &mut FieldCursor,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
    relaxation: Relaxation,
) -> TraceResult {
    let m = Marching::new(ray);
    let mut relaxation = relaxation;
    let mut t = t0;
    let (mut steps, mut skips) = (0, 0);
    // The last verified sample, whether the step from it to t is relaxed (unverified), whether
    // there is a sample before it to take the slope from, and whether t was reached by a
    // fallback (then the next step is Hart's).
    let (mut prev_t, mut prev_d) = (t0, 0.0f32);
    let (mut unverified, mut have_prev, mut fell_back) = (false, false, false);
    while steps < s.max_steps && skips < MAX_SKIPS {
        let (p, region) = region_at(field, &m, t);
        if !unverified && is(&region, Verdict::Empty) {
            t = m.past(&region.cell.expect("a leaf"), t);
            skips += 1;
            have_prev = false;
            if t > t1 {
                break;
            }
            continue;
        }
        let d = region.tape.eval_in(p, field.regs);
        steps += 1;
        let failed = unverified && prev_d + d.abs() < t - prev_t;
        let near_miss = !failed
            && d < epsilon_at(s, t)
            && match crossing::confirm(field, ray, t, d, t1, s, &mut steps) {
                Candidate::Hit(t) => return TraceResult::of_points(Some(t), steps),
                Candidate::Continue(next) => {
                    t = next;
                    true
                }
            };
        if failed || near_miss {
            if failed {
                t = prev_t + prev_d;
            }
            unverified = false;
            fell_back = true;
            if let Relaxation::Fixed(_) = relaxation {
                relaxation = Relaxation::Fixed(1.0);
            }
            if t > t1 {
                break;
            }
            continue;
        }
        // Hart's step alone leaves the interval: nothing to find before t1.
        if t + d > t1 {
            break;
        }
        let omega = match relaxation {
            Relaxation::Fixed(omega) => omega,
            Relaxation::Slope if have_prev && !fell_back => {
                let slope = ((prev_d - d) / (t - prev_t)).clamp(0.0, 1.0);
                (2.0 / (1.0 + slope)).min(MAX_ADAPTIVE_OMEGA)
            }
            Relaxation::Slope => 1.0,
        };
        prev_t = t;
        prev_d = d;
        have_prev = true;
        fell_back = false;
        unverified = omega > 1.0;
        t = (t + omega * d).min(t1);
    }
    TraceResult::of_points(None, steps)
}

/// Light visibility along a shadow ray through one object, from Quilez's penumbra estimate
/// ("soft shadows in raymarched SDFs", 2010): the smallest k·h/t met along the ray, where h is
/// the field and t the distance travelled, approximates the fraction of a light cone of
/// half-angle ~1/k left unblocked. The `improved` variant estimates the closest approach
/// between the last two samples (y = h²/(2h'), d = √(h² − y²), k·d/(t − y)), which removes
/// the banding of the plain estimate. Returns 1 (lit) down to 0 (blocked); a sample within
/// ε(t) of the surface is a hit and returns 0. Every sample is taken where the whole tape's
/// march takes it (no leaf is skipped: the estimate is a minimum over the samples, and other
/// samples would give another minimum), with the leaves' shorter tapes, which return the
/// whole tape's values there.
#[allow(clippy::too_many_arguments)]
pub fn penumbra(
    field: &mut FieldCursor,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
    k: f32,
    improved: bool,
) -> f32 {
    let mut along = Along::new(field, ray, t0, t1);
    let mut res: f32 = 1.0;
    let mut previous = f32::INFINITY;
    let mut t = t0;
    for _ in 0..s.max_steps {
        let h = along.tape(t).eval_in(ray.at(t), field.regs);
        if h < epsilon_at(s, t) {
            return 0.0;
        }
        res = res.min(penumbra_estimate(h, previous, t, k, improved));
        previous = h;
        t += h;
        if t > t1 || res < 1e-4 {
            break;
        }
    }
    res.clamp(0.0, 1.0)
}

/// Quilez's estimate at a sample of value h at t, the previous sample's value being `previous`.
#[inline]
pub(crate) fn penumbra_estimate(h: f32, previous: f32, t: f32, k: f32, improved: bool) -> f32 {
    // The unbounding spheres of the last two samples meet on a circle whose plane lies y
    // behind the current sample; the closest approach to the surface is estimated there.
    // Only between the two samples (y ≤ h') does that geometry hold: where the field grows
    // as fast as the step (h ≈ 2h', the ray heading straight away), y would land behind
    // the previous sample and d collapse to 0, a false dark speck; use k·h/t there.
    let y = h * h / (2.0 * previous);
    if improved && y <= previous {
        let d = (h * h - y * y).max(0.0).sqrt();
        k * d / (t - y).max(1e-6)
    } else {
        k * h / t.max(1e-6)
    }
}

/// Marches from inside a solid to where the ray leaves it: inside, −f bounds the distance to
/// the surface, so steps of 0.9·|f| (a step scale below 1 for bound fields whose interior
/// values are less reliable) never cross it; a leaf proven full is left at once. Returns the
/// exit distance, or `None` if the ray is still inside after `max_steps` or t1.
pub fn exit(
    field: &mut FieldCursor,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
) -> Option<f32> {
    let mut along = Along::new(field, ray, t0, t1);
    let mut t = t0;
    let (mut steps, mut skips) = (0, 0);
    while steps < s.max_steps && skips < MAX_SKIPS {
        let tape = match along.at(t) {
            Some(c) if c.leaf.verdict == Verdict::Full => {
                // inside at every point of the leaf: on to just past where the ray leaves it
                t = next_up(t.max(c.exit));
                skips += 1;
                if t > t1 {
                    return None;
                }
                continue;
            }
            Some(c) => c.tape,
            None => along.whole,
        };
        let d = -tape.eval_in(ray.at(t), field.regs);
        steps += 1;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;
    use crate::scene::Stepper;
    use crate::sdf::tape::Registers;
    use crate::trace::epsilon_at;
    use glam::Vec3;
    use std::path::Path;

    /// A ground plane, a sphere and a thin box: head-on, grazing and near-miss rays.
    fn scene() -> Scene {
        let src = "Scene(
            camera: Perspective(position: (0, 1, 6), look_at: (0, 0, 0), fov: 50),
            objects: [
                (shape: Plane(normal: (0, 1, 0), offset: -1)),
                (shape: Sphere(radius: 1), translate: (0, 0, 0)),
                (shape: Box(half_extents: (2, 0.05, 0.05)), translate: (0, 1.3, 0)),
            ],
        )";
        Scene::from_source(src, Path::new("stepper-test.ron")).unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn relaxed_steppers_find_the_hits_hart_finds() {
        let scene = scene();
        let mut regs = Registers::new();
        let mut rng = crate::rng::Rng::new(17);
        let steppers = [
            Stepper::Relaxed(1.2),
            Stepper::Relaxed(1.9),
            Stepper::Adaptive,
            Stepper::Segment,
        ];
        let mut hits = 0;
        for i in 0..3000 {
            let o = Vec3::new(rng.range_f32(-3.0, 3.0), rng.range_f32(-0.5, 3.0), 6.0);
            // Every third ray nearly parallel to the ground: Hart's worst case.
            let target = if i % 3 == 0 {
                Vec3::new(rng.range_f32(-3.0, 3.0), -0.9, -20.0)
            } else {
                rng.vec3_in(-1.5, 1.5)
            };
            let ray = Ray::new(o, target - o);
            for object in &scene.objects {
                let tape = &object.lowered.distance;
                let hart = trace_hart(
                    &mut FieldCursor::whole(tape, &mut regs),
                    &ray,
                    0.0,
                    40.0,
                    &scene.tracer,
                );
                for st in steppers {
                    let s = TracerSettings {
                        stepper: st,
                        ..scene.tracer
                    };
                    let r = crate::trace::trace(
                        &mut FieldCursor::whole(tape, &mut regs),
                        &ray,
                        0.0,
                        40.0,
                        &s,
                    );
                    if r.t.is_some() != hart.t.is_some() {
                        // Only two things may tell them apart: the step budget (Hart runs out
                        // of steps on grazing rays sooner), or a ray that comes within ε of
                        // the surface without crossing it (one stepper samples that stretch,
                        // the other steps over it).
                        let (miss, t_hit) = match (r.t, hart.t) {
                            (None, Some(t)) => (r, t),
                            (Some(t), _) => (hart, t),
                            _ => unreachable!(),
                        };
                        let crosses = (0..2000).any(|k| {
                            tape.eval_in(ray.at(t_hit + k as f32 * 5e-4), &mut regs) < 0.0
                        });
                        assert!(
                            miss.steps == s.max_steps || !crosses,
                            "{st:?} ray {i}: {r:?} vs Hart {hart:?}"
                        );
                        continue;
                    }
                    if let (Some(a), Some(b)) = (r.t, hart.t) {
                        // Both stop inside the ε band of the same crossing: the field is
                        // below ε at both points.
                        assert!(tape.eval_in(ray.at(a), &mut regs) < epsilon_at(&s, a));
                        assert!((a - b).abs() < 0.05, "{st:?} ray {i}: {a} vs {b}");
                        hits += 1;
                    }
                }
            }
        }
        assert!(hits > 3000, "{hits}");
    }

    #[test]
    fn stepper_is_read_from_the_scene_file_and_checked() {
        let src = |stepper: &str| {
            format!(
                "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40),
                objects: [(shape: Sphere(radius: 1))], tracer: (stepper: {stepper}))"
            )
        };
        let load = |st: &str| Scene::from_source(&src(st), Path::new("stepper.ron"));
        assert_eq!(load("Hart").unwrap().tracer.stepper, Stepper::Hart);
        assert_eq!(
            load("Relaxed(1.5)").unwrap().tracer.stepper,
            Stepper::Relaxed(1.5)
        );
        assert_eq!(load("Adaptive").unwrap().tracer.stepper, Stepper::Adaptive);
        assert_eq!(load("Segment").unwrap().tracer.stepper, Stepper::Segment);
        let default = Scene::from_source(
            "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40), objects: [])",
            Path::new("default.ron"),
        )
        .unwrap();
        assert_eq!(
            default.tracer.stepper,
            Stepper::Hart,
            "Hart stays the default"
        );
        for bad in ["Relaxed(2.0)", "Relaxed(0.5)", "Relaxed(NaN)"] {
            let e = load(bad).expect_err(bad).to_string();
            assert!(
                e.contains("stepper.ron") && e.contains("relaxation"),
                "{bad}: {e}"
            );
        }
    }

    #[test]
    fn relaxed_steps_stay_inside_the_interval() {
        // A thin box just before t1: a relaxed step past t1 must not skip it.
        let scene = scene();
        let tape = &scene.objects[2].lowered.distance;
        let mut regs = Registers::new();
        let ray = Ray::new(Vec3::new(0.0, 1.3, 6.0), -Vec3::Z);
        let hart = trace_hart(
            &mut FieldCursor::whole(tape, &mut regs),
            &ray,
            0.0,
            5.96,
            &scene.tracer,
        );
        assert!(hart.t.is_some());
        for st in [Stepper::Relaxed(1.9), Stepper::Adaptive, Stepper::Segment] {
            let s = TracerSettings {
                stepper: st,
                ..scene.tracer
            };
            let r = crate::trace::trace(
                &mut FieldCursor::whole(tape, &mut regs),
                &ray,
                0.0,
                5.96,
                &s,
            );
            assert!(r.t.is_some(), "{st:?}");
            assert!(
                crate::trace::trace(&mut FieldCursor::whole(tape, &mut regs), &ray, 0.0, 5.9, &s)
                    .t
                    .is_none(),
                "{st:?}"
            );
        }
    }
}
