//! Hart's sphere tracing (J. C. Hart, "Sphere tracing: a geometric method for the antialiased
//! ray tracing of implicit surfaces", The Visual Computer 12, 1996, §2), the opt-in
//! over-relaxed steppers of Keinert et al. 2014 ("Enhanced Sphere Tracing", STAG 2014, §3.1),
//! soft-shadow penumbrae and exits, all over an object's field octree
//! ([`crate::accel::field`]): every sample is evaluated with the tape specialised to the leaf
//! holding it, and leaves proven empty are skipped without an evaluation — or, where the
//! leaves save little of a short whole tape, with the whole tape, which has the same values
//! ([`Parts`]).

use super::crossing::{self, Candidate};
use super::step::{MAX_SKIPS, Marching, TraceResult, epsilon_at, is, region_at};
use crate::accel::field::{Crossed, FieldCursor, ObjectField, RayWalk, RoundingModel, WalkStack};
use crate::geom::Ray;
use crate::scene::TracerSettings;
use crate::sdf::simplify::Verdict;
use crate::sdf::tape::Registers;
use crate::sdf::tape::Tape;
use glam::Vec3;

/// Marches from t0 towards t1 by the field value: the field is 1-Lipschitz (every node of the
/// lowered tape is step-corrected), so an unbounding sphere of radius f(p) around p contains no
/// surface and the step never skips one (Hart 1996, Theorem 1). Over an octree the march walks
/// the leaves along the ray ([`RayWalk`]; unless they save little, see [`Parts`]): empty
/// leaves are passed without an evaluation, each
/// other leaf is marched with its own tape, by f/fall where the leaf's gradient enclosure
/// shows the field falling slower than 1 along the ray ([`hart_step`], up to its exit), and
/// outside the tree by the object's gradient enclosure over all of space (a plane's: one step
/// to the ground). Where f < ε(t) the candidate is confirmed by a sign change and placed at
/// the crossing ([`crossing::confirm`]); a miss past t1 or after `max_steps` evaluations, or
/// once a convex field's chord shows the ray heading away from its surface ([`ConvexBound`]).
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
    /// No later sample can come within ε of the surface ([`ConvexBound::stays_off`]).
    Clear,
}

/// A part of a ray marched with one tape: a leaf's, or the whole tape's outside the tree.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Part<'f> {
    /// The tape valid there.
    pub tape: &'f Tape,
    /// How fast the field may fall along the ray there (1, the global bound, where no
    /// gradient enclosure says less).
    pub fall: f32,
    /// How fast it may fall along the ray anywhere: the bound of its gradient enclosure over
    /// all of space ([`crate::accel::field::ObjectField::outside`]), below 1 on a plane.
    pub everywhere: f32,
    /// Where the march starts (the current t, or the part's start if later).
    pub start: f32,
    /// Where it ends.
    pub end: f32,
}

/// The parts of [t0, t1] a ray is marched over, in order, given the march's current t: the
/// whole tape before the tree's box (an unbounded object clipped to the scene), the leaves of
/// the walk that are not empty, the whole tape beyond the box. A field whose leaves save
/// less than half of a short whole tape ([`crate::accel::field::FieldOctree::marched_whole`])
/// is one whole-tape part over [t0, t1], its steps lengthened by the object's gradient
/// enclosure over all of space (a plane's: one step to the ground).
pub(crate) struct Parts<'f, 's> {
    whole: &'f Tape,
    /// How fast the field may fall along the ray outside the tree.
    whole_fall: f32,
    direction: Vec3,
    walk: Option<RayWalk<'f, 's>>,
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

impl<'f, 's> Parts<'f, 's> {
    /// The parts of [t0, t1] along `ray` for the field of `cursor`, the walk's frames on
    /// `stack`.
    #[inline]
    pub fn new(
        cursor: &FieldCursor<'f, '_>,
        ray: &Ray,
        t0: f32,
        t1: f32,
        stack: &'s mut WalkStack,
    ) -> Self {
        // Every field is found first and the parts made in one expression, so that they are
        // stored where the caller keeps them: built in a local and changed there, they were
        // copied out in wider words than they were written in, before those stores could
        // forward (a stall on every lane of a bundle).
        let crossing = cursor
            .octree()
            .filter(|tree| !tree.marched_whole())
            .and_then(|tree| Some((tree, tree.bounds().ray_interval(ray, t0, t1)?)));
        let (walk, phase, enter, leave) = match crossing {
            Some((tree, (enter, leave))) => (
                Some(RayWalk::new(tree, ray, t0, leave, stack)),
                if t0 < enter {
                    Phase::Before
                } else {
                    Phase::Walk
                },
                enter,
                leave,
            ),
            None => (None, Phase::Whole, t0, t1),
        };
        Parts {
            whole: cursor.whole_tape(),
            whole_fall: cursor.fall_outside(ray.direction),
            direction: ray.direction,
            walk,
            phase,
            t1,
            enter,
            leave,
        }
    }

    /// The next part for a march now at t, or `None` when nothing is left before t1.
    /// Always inlined: returned through memory, the part was read back in wider words than
    /// it was written in, before those stores could forward (a stall on every leaf a lane
    /// enters).
    #[inline(always)]
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
                    walk.skip_to(t);
                    match walk.next_nonempty_leaf() {
                        Some(x) if x.exit < t => {}
                        Some(x) => {
                            return Some(Part {
                                tape: x.tape,
                                fall: x.leaf.fall(self.direction),
                                everywhere: self.whole_fall,
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
            fall: self.whole_fall,
            everywhere: self.whole_fall,
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
/// global bound allows d, and the field's bound over all of space d/`everywhere` (kept as
/// short): a ray towards a ground plane reaches it in one step from wherever it starts,
/// where it used to stop at the edge of each part (two to three more samples per ground
/// pixel of csg.ron), and a ray heading away from it, whose field never falls, steps past
/// any end at once.
#[inline]
pub(crate) fn hart_step(d: f32, part: &Part, t: f32, eps: f32) -> f32 {
    let mut step = d;
    if part.fall < 1.0 {
        step = step.max((d / part.fall - HART_STEP_MARGIN * eps).min(part.end - t));
    }
    if part.everywhere < 1.0 {
        let reach = if part.everywhere > 0.0 {
            d / part.everywhere - HART_STEP_MARGIN * eps
        } else {
            f32::MAX
        };
        step = step.max(reach);
    }
    step
}

/// Hart's march over one part. `chord` holds the march's last sample (kept across parts)
/// for the convexity bound, when the field has one.
#[inline]
#[allow(clippy::too_many_arguments)]
fn march_part(
    field: &mut FieldCursor,
    part: &Part,
    ray: &Ray,
    t1: f32,
    s: &TracerSettings,
    steps: &mut u32,
    bound: Option<ConvexBound>,
    chord: &mut Sample,
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
            *chord = Sample::NONE;
            match crossing::confirm(field, ray, t, d, t1, s, steps) {
                Candidate::Hit(t) => return Stretch::Hit(t),
                Candidate::Continue(next) => t = next,
            }
        } else {
            if bound.is_some_and(|b| b.stays_off(*chord, t, d, s)) {
                return Stretch::Clear;
            }
            *chord = Sample { t, h: d };
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
    let mut stack = WalkStack::new();
    let mut parts = Parts::new(field, ray, t0, t1, &mut stack);
    let bound = field
        .convex()
        .map(|model| ConvexBound::new(model, ray, t0, t1));
    let mut chord = Sample::NONE;
    let mut t = t0;
    while let Some(part) = parts.next(t) {
        match march_part(field, &part, ray, t1, s, steps, bound, &mut chord) {
            Stretch::Hit(t) => return Some(t),
            Stretch::Spent | Stretch::Clear => return None,
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
pub(crate) struct Along<'f, 's> {
    walk: Option<RayWalk<'f, 's>>,
    current: Option<Crossed<'f>>,
    whole: &'f Tape,
}

impl<'f, 's> Along<'f, 's> {
    /// The tapes along `ray` over [t0, t1] for the field of `field`, the walk's frames on
    /// `stack`.
    #[inline]
    pub fn new(
        field: &FieldCursor<'f, '_>,
        ray: &Ray,
        t0: f32,
        t1: f32,
        stack: &'s mut WalkStack,
    ) -> Self {
        Along {
            walk: field
                .octree()
                .map(|tree| RayWalk::new(tree, ray, t0, t1, stack)),
            current: None,
            whole: field.whole_tape(),
        }
    }

    /// [`Self::new`] for a penumbra march: the whole tape alone where it is short (see
    /// [`crate::accel::field::SHORT_TAPE`]); the values are the same.
    #[inline]
    pub fn for_penumbra(
        field: &FieldCursor<'f, '_>,
        ray: &Ray,
        t0: f32,
        t1: f32,
        stack: &'s mut WalkStack,
    ) -> Self {
        match field.short_whole_tape() {
            Some(whole) => Along {
                walk: None,
                current: None,
                whole,
            },
            None => Self::new(field, ray, t0, t1, stack),
        }
    }

    /// The leaf at t (t never decreasing between calls), or `None` outside the tree.
    #[inline]
    fn at(&mut self, t: f32) -> Option<Crossed<'f>> {
        if let Some(c) = self.current
            && t <= c.exit
        {
            return (t >= c.enter).then_some(c);
        }
        let walk = self.walk.as_mut()?;
        walk.skip_to(t);
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
    let mut stack = WalkStack::new();
    let mut along = Along::for_penumbra(field, ray, t0, t1, &mut stack);
    let bound = field
        .convex()
        .map(|model| ConvexBound::new(model, ray, t0, t1));
    let mut res: f32 = 1.0;
    let mut previous = Sample::NONE;
    let mut t = t0;
    for _ in 0..s.max_steps {
        let h = along.tape(t).eval_in(ray.at(t), field.regs);
        if h < epsilon_at(s, t) {
            return 0.0;
        }
        res = res.min(penumbra_estimate(h, previous.h, t, k, improved));
        if bound.is_some_and(|b| b.settles(previous, t, h, res, k, s)) {
            break;
        }
        previous = Sample { t, h };
        t += h;
        if t > t1 || res < 1e-4 {
            break;
        }
    }
    res.clamp(0.0, 1.0)
}

/// A line under every value a march computes along a ray's interval [t0, t1], from one
/// sample at t0 before any march starts. A convex field whose gradient lies in the enclosure
/// [`ObjectField::slopes`] everywhere (a ground plane) falls along the ray no faster than
/// that enclosure allows: f(t) ≥ f(t0) + σ·(t − t0), σ the least of g·d over it (the mean
/// value theorem). With every computed value within e of the exact field (its
/// [`RoundingModel`] at the farther end of the interval, as [`ConvexBound`] takes it), each
/// computed sample is at least h₀ − 2e + σ·(t − t0). Since only the line is known, not the
/// steps, this serves the rays that ask for the answer alone: shadow rays leaving the
/// ground are then no lanes of a bundle at all, where each cost a walk's set-up and two
/// samples (12–15 % of the frames of the shipped scenes with a ground plane). (The leaf's
/// enclosure at t0, with the tangent of a convex field, would serve any convex object, but
/// the lookup cost hybrid.ron's frames 8 % and gained the showcase less: its leaves are
/// mostly one per object, with enclosures too wide to tell.)
#[derive(Debug, Clone, Copy)]
struct LineBelow {
    t0: f64,
    /// h₀ − 2e.
    at_t0: f64,
    /// σ.
    slope: f64,
}

impl LineBelow {
    /// The line for `ray` over [t0, t1], when `field` has one.
    fn of(
        field: &ObjectField,
        ray: &Ray,
        t0: f32,
        t1: f32,
        regs: &mut Registers,
    ) -> Option<LineBelow> {
        let (Some(model), Some([lo, hi])) = (field.convex, field.slopes) else {
            return None;
        };
        if !(t0 <= t1 && t1.is_finite() && t0.is_finite()) {
            return None;
        }
        let d = ray.direction;
        // products of two f32s are exact in f64; the sums' rounding (2⁻⁵³ relative) is far
        // below what the callers' margins leave
        let slope: f64 = (0..3)
            .map(|a| (lo[a] as f64 * d[a] as f64).min(hi[a] as f64 * d[a] as f64))
            .sum();
        let error = ConvexBound::new(model, ray, t0, t1).error as f64;
        let h0 = field.whole.eval_in(ray.at(t0), regs) as f64;
        // a NaN sample fails every comparison with the line
        Some(LineBelow {
            t0: t0 as f64,
            at_t0: h0 - 2.0 * error,
            slope,
        })
    }

    fn at(&self, t: f32) -> f64 {
        self.at_t0 + self.slope * (t as f64 - self.t0)
    }

    /// Whether the line stays above ε(t), with [`SPARE`], over [t0, t1]: at both ends is
    /// enough, ε being convex in t.
    fn clears_epsilon(&self, t0: f32, t1: f32, s: &TracerSettings) -> bool {
        let clear = |t: f32| self.at(t) >= SPARE as f64 * epsilon_at(s, t) as f64;
        clear(t0) && clear(t1)
    }
}

/// Whether Hart's march over [t0, t1] through `field` misses for certain ([`LineBelow`]): no
/// computed sample comes below ε.
pub(crate) fn misses_from_start(
    field: &ObjectField,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
    regs: &mut Registers,
) -> bool {
    LineBelow::of(field, ray, t0, t1, regs).is_some_and(|line| line.clears_epsilon(t0, t1, s))
}

/// Whether the penumbra march of sharpness k over [t0, t1] through `field` returns 1 for
/// certain ([`LineBelow`]), so that the object darkens nothing: no sample comes below ε,
/// and every estimate is at least k·h/(√2·max(t, 10⁻⁶)) (both of Quilez's forms, as
/// [`ConvexBound`] shows), h being above the line; that ratio is linear, then a linear
/// fraction, over t, so its least value is at t0, 10⁻⁶ or t1, and at least
/// [`SETTLED_MARGIN`] there leaves every estimate above 1 with room for its rounding.
pub(crate) fn unshaded_from_start(
    field: &ObjectField,
    ray: &Ray,
    t0: f32,
    t1: f32,
    k: f32,
    s: &TracerSettings,
    regs: &mut Registers,
) -> bool {
    let Some(line) = LineBelow::of(field, ray, t0, t1, regs) else {
        return false;
    };
    let lit = |t: f32| {
        let estimate = k as f64 * line.at(t) / (std::f64::consts::SQRT_2 * t.max(1e-6) as f64);
        estimate >= SETTLED_MARGIN as f64
    };
    line.clears_epsilon(t0, t1, s) && lit(t0) && lit(t1) && lit(1e-6_f32.clamp(t0, t1))
}

/// What the convexity bound keeps to spare over ε(t) and ε₁ for the rounding of ε(t) itself
/// and of the chord's margin and slope.
const SPARE: f32 = 1.0 + 1.0 / 1024.0;

/// How far above the darkness reached so far the convexity bound must show every later
/// estimate: above √2 (the improved estimate's worst case against k·h/t), with room for its
/// own rounding.
const SETTLED_MARGIN: f32 = 1.5;

/// A march's sample: the field's computed value h at t.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Sample {
    /// Where along the ray.
    pub t: f32,
    /// The value there.
    pub h: f32,
}

impl Sample {
    /// Before the first sample: t = −∞ (no chord yet) and h = ∞.
    pub(crate) const NONE: Sample = Sample {
        t: f32::NEG_INFINITY,
        h: f32::INFINITY,
    };
}

/// What ends a march through a convex field early with the answer the whole march gives:
/// Hart's march (a miss) once the ray heads away from the surface, and a penumbra march
/// (its value) once no later sample can darken it. Along a line a convex f lies above the
/// extension of every chord: from samples
/// (t₋, h₋) and (t, h), f(t') ≥ f(t) + σ·(t' − t) for all t' ≥ t, σ the chord's slope. With
/// every computed value within e of the exact field (its [`RoundingModel`], at the march's
/// farthest point from the origin, one of its ends: |p|∞ is convex along the ray), each later
/// computed sample is at least a + σ'·(t' − t), with a = h − 2e and σ' = (h − h₋ − 2e)/(t − t₋),
/// and its ratio to t' at least min(a/t, σ') (a linear function over t' is monotone). Quilez's
/// estimate is k·h/t, or in the improved form k·d/(t − y) ≥ k·h/(√2·t) (where it applies,
/// y ≤ h₋ gives h² ≤ 2h₋², so d² = h² − y² ≥ h²/2). So when k·min(a/t, σ') ≥ 1.5·res, no later
/// sample lowers res; a ≥ ε(t) and σ' ≥ ε's growth per unit keep each one off the surface; the
/// march's value is res already. On a ground plane a shadow ray's march is then two samples
/// instead of the tens that climb away from the surface by geometric steps; the same holds of
/// a camera ray that passed an object without touching it and a hard shadow ray leaving the
/// object it starts on. Hart's march hits where a sample comes below ε(t) = ε₀ + ε₁·t: with
/// a ≥ ε(t) and σ' ≥ ε₁ (each with 2⁻¹⁰ to spare for the rounding of ε itself) every later
/// sample stays above ε(t'), so the march ends where it stands with the miss it would reach.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ConvexBound {
    /// e: the largest rounding error of a value computed on the march.
    error: f32,
}

impl ConvexBound {
    /// The bound for a march of `ray` over [t0, t1] through a convex field whose values
    /// round as `model` says.
    pub(crate) fn new(model: RoundingModel, ray: &Ray, t0: f32, t1: f32) -> Self {
        let reach = |t: f32| ray.at(t).abs().max_element();
        ConvexBound {
            error: model.error(reach(t0).max(reach(t1))),
        }
    }

    /// Whether no sample of a march after h at t (the sample before being `before`) can
    /// come below ε: the march can end with a miss. The chord's margin a = h − 2e and its
    /// rise over its run bound every later computed sample from below; a ≥ ε(t) and a slope
    /// of at least ε₁ keep each one above ε, with 2⁻¹⁰ to spare for ε's own rounding. (Hart's
    /// march asks at every step, so the slope is compared as rise against run, without a
    /// division.)
    #[inline]
    pub(crate) fn stays_off(&self, before: Sample, t: f32, h: f32, s: &TracerSettings) -> bool {
        // most samples of a march towards a surface fall: one comparison settles those (a
        // NaN sample goes on, to fail the comparisons below)
        if h <= before.h {
            return false;
        }
        // before.t = −∞ before the second sample: the run is ∞ and no rise reaches it
        let a = h - 2.0 * self.error;
        let rise = h - before.h - 2.0 * self.error;
        let run = t - before.t;
        a >= SPARE * epsilon_at(s, t) && rise >= SPARE * s.epsilon_per_unit * run && run > 0.0
    }

    /// Whether a penumbra march can stop at its sample h at t, the sample before being
    /// `before`, darkness `res` being reached with its estimate included: no later sample
    /// comes below ε ([`Self::stays_off`]), and none lowers the estimate, k·min(a/t, σ') being
    /// at least 1.5·res.
    #[inline]
    pub(crate) fn settles(
        &self,
        before: Sample,
        t: f32,
        h: f32,
        res: f32,
        k: f32,
        s: &TracerSettings,
    ) -> bool {
        // t ≥ 1e-5 keeps the estimates' floor on their denominators (1e-6) out of play
        t >= 1e-5 && self.stays_off(before, t, h, s) && {
            let a = h - 2.0 * self.error;
            let slope = (h - before.h - 2.0 * self.error) / (t - before.t);
            k * (a / t).min(slope) >= SETTLED_MARGIN * res
        }
    }
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
    let mut stack = WalkStack::new();
    let mut along = Along::new(field, ray, t0, t1, &mut stack);
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
    use crate::scene::{Shadow, Stepper};
    use crate::sdf::tape::Registers;
    use crate::trace::ShadowQuery;
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
    /// Convex shapes of every kind the convexity rule admits, placed and combined.
    const CONVEX: &[&str] = &[
        "Sphere(radius: 0.8)",
        "Box(half_extents: (1.0, 0.3, 0.6))",
        "RoundBox(half_extents: (30, 0.1, 30), radius: 0.05)",
        "Plane(normal: (0.2, 1, 0.1), offset: -0.5)",
        "Cylinder(half_height: 0.7, radius: 0.4)",
        "Cone(half_height: 0.6, bottom_radius: 0.7, top_radius: 0.1)",
        "Capsule(a: (-0.5, 0, 0), b: (0.5, 0.3, 0), radius: 0.25)",
        "Ellipsoid(radii: (1.0, 0.4, 0.6))",
        "Octahedron(size: 0.9)",
        "HexPrism(radius: 0.5, half_length: 0.8)",
        "Transform(translate: (3, -1, 2), rotate: (20, 40, 10), scale: 1.7, shape: Box(half_extents: (0.5, 0.5, 0.2)))",
        "Scale(factors: (2, 0.5, 1), shape: Sphere(radius: 0.6))",
        "Round(radius: 0.1, shape: Box(half_extents: (0.4, 0.4, 0.4)))",
        "Intersection([Sphere(radius: 1), Box(half_extents: (0.7, 2, 0.7))])",
        "SmoothIntersection(k: 0.3, shapes: [Sphere(radius: 1), Transform(translate: (0.5, 0, 0), shape: Sphere(radius: 1))])",
    ];

    /// Whether the chord bound of [`ConvexBound`] holds for three computed samples of `tape`
    /// along `ray` at t₋ < t < t': ĥ' ≥ (ĥ − 2e) + σ'·(t' − t).
    fn chord_bound_holds(tape: &Tape, model: RoundingModel, ray: &Ray, ts: [f32; 3]) -> bool {
        let h = ts.map(|t| tape.eval(ray.at(t)));
        let reach = |t: f32| ray.at(t).abs().max_element();
        let e = model.error(reach(ts[0]).max(reach(ts[2])));
        let slope = (h[1] - h[0] - 2.0 * e) / (ts[1] - ts[0]);
        h[2] >= h[1] - 2.0 * e + slope * (ts[2] - ts[1])
    }

    /// Random triples t₋ < t < t' on random lines, close together (where rounding decides)
    /// and far apart.
    fn chord_checks(tape: &Tape, model: RoundingModel, seed: u64) -> (usize, usize) {
        let mut rng = crate::rng::Rng::new(seed);
        let (mut checked, mut failed) = (0, 0);
        for i in 0..20_000 {
            let o =
                rng.vec3_in(-4.0, 4.0) + Vec3::new(0.0, 0.0, if i % 2 == 0 { 0.0 } else { 25.0 });
            let ray = Ray::new(o, rng.direction());
            let t0 = rng.range_f32(0.0, 8.0);
            let gap = 10f32.powf(rng.range_f32(-4.5, 0.5));
            let ts = [
                t0,
                t0 + gap,
                t0 + gap + 10f32.powf(rng.range_f32(-4.5, 1.0)),
            ];
            checked += 1;
            if !chord_bound_holds(tape, model, &ray, ts) {
                failed += 1;
            }
        }
        (checked, failed)
    }

    #[test]
    fn convex_fields_lie_above_their_chords_within_their_rounding_model() {
        for (k, src) in CONVEX.iter().enumerate() {
            let node = crate::sdf::conformance::parse_node(src);
            assert!(node.is_convex(), "{src} is convex");
            let tape = crate::sdf::conformance::distance_tape(&node);
            let (checked, failed) = chord_checks(&tape, RoundingModel::of(&tape), 5 + k as u64);
            assert_eq!(failed, 0, "{src}: {failed} of {checked} chord bounds fail");
        }
        // the check has teeth: a torus, or a union, is not convex
        for src in [
            "Torus(major: 1, minor: 0.3)",
            "Union([Sphere(radius: 0.5), Transform(translate: (1.5, 0, 0), shape: Sphere(radius: 0.5))])",
        ] {
            let node = crate::sdf::conformance::parse_node(src);
            assert!(!node.is_convex(), "{src} is not convex");
            let tape = crate::sdf::conformance::distance_tape(&node);
            let (_, failed) = chord_checks(&tape, RoundingModel::of(&tape), 3);
            assert!(failed > 0, "{src}: every chord bound holds");
        }
    }

    /// Every penumbra through the objects of `scene`, marched with and without the convexity
    /// bound, alone and in packets: the same bits. Returns the queries made and how many of
    /// them came out partly shadowed.
    fn penumbrae_agree(scene: &Scene, seed: u64) -> (usize, usize) {
        let tracer = crate::trace::SceneTracer::new(scene);
        let mut plain = crate::trace::SceneTracer::new(scene);
        for f in &mut plain.fields {
            f.convex = None;
        }
        assert!(
            tracer.fields.iter().any(|f| f.convex.is_some()),
            "the scene has a convex object"
        );
        let mut rng = crate::rng::Rng::new(seed);
        let cam = &scene.camera;
        let mut queries = Vec::new();
        for _ in 0..1500 {
            let ray = cam.ray(rng.next_f32(), rng.next_f32(), 4.0 / 3.0);
            let Some(hit) = tracer.closest_hit(&ray, 0.0, f32::INFINITY) else {
                continue;
            };
            let p = ray.at(hit.t);
            for _ in 0..4 {
                let mut d = rng.direction();
                if d.dot(hit.normal) < 0.0 {
                    d = -d;
                }
                let offset = 10f32.powf(rng.range_f32(-4.0, -2.0));
                let k = [2.0, 8.0, 16.0, 48.0][queries.len() % 4];
                queries.push(ShadowQuery {
                    ray: Ray::new(p + hit.normal * offset, d),
                    tmin: 0.0,
                    tmax: rng.range_f32(0.5, 30.0),
                    shadow: if queries.len() % 2 == 0 {
                        Shadow::Soft(k)
                    } else {
                        Shadow::SoftImproved(k)
                    },
                });
            }
        }
        let mut bundled = vec![0.0; queries.len()];
        let mut bundled_plain = vec![0.0; queries.len()];
        tracer.visibilities(&queries, &mut bundled);
        plain.visibilities(&queries, &mut bundled_plain);
        let mut partial = 0;
        for (i, q) in queries.iter().enumerate() {
            let with = tracer.visibility(&q.ray, q.tmin, q.tmax, q.shadow);
            let without = plain.visibility(&q.ray, q.tmin, q.tmax, q.shadow);
            assert_eq!(with.to_bits(), without.to_bits(), "query {i}: {q:?}");
            assert_eq!(
                bundled[i].to_bits(),
                bundled_plain[i].to_bits(),
                "bundled query {i}"
            );
            assert_eq!(
                bundled[i].to_bits(),
                with.to_bits(),
                "bundled against alone, query {i}"
            );
            if with > 0.0 && with < 1.0 {
                partial += 1;
            }
        }
        (queries.len(), partial)
    }

    /// The convex shapes of [`CONVEX`] in a grid over a ground plane, seen from above.
    fn convex_shapes_on_a_plane() -> Scene {
        let objects: Vec<String> = CONVEX
            .iter()
            .enumerate()
            .map(|(i, src)| {
                let (x, z) = ((i % 5) as f32 * 2.2 - 4.4, (i / 5) as f32 * 2.2 - 2.2);
                format!("(shape: Transform(translate: ({x}, 0.2, {z}), shape: {src})),")
            })
            .collect();
        let src = format!(
            "Scene(camera: Perspective(position: (0, 6, 9), look_at: (0, 0, 0), fov: 60),
                objects: [(shape: Plane(normal: (0, 1, 0), offset: -1)), {}])",
            objects.join("\n")
        );
        Scene::from_source(&src, Path::new("convex.ron")).unwrap_or_else(|e| panic!("{e}"))
    }

    /// Hart's marches through every object of `scene` with and without the convexity bound,
    /// alone and in bundles: camera rays, and rays leaving the surfaces they hit (as shadow
    /// rays do). The same hits to the bit, never more steps with the bound, and the bundles'
    /// answers (steps included) are the rays' alone. Returns the steps taken with and
    /// without the bound.
    fn hart_marches_agree(scene: &Scene, seed: u64) -> (u64, u64) {
        use crate::trace::packet::{BUNDLE, Lane, PacketScratch, trace_hart_packet};
        let tracer = crate::trace::SceneTracer::new(scene);
        let mut regs = Registers::new();
        let mut rng = crate::rng::Rng::new(seed);
        let mut lanes = Vec::new();
        for _ in 0..600 {
            let ray = scene.camera.ray(rng.next_f32(), rng.next_f32(), 4.0 / 3.0);
            lanes.push(Lane {
                ray,
                t0: 0.0,
                t1: 40.0,
            });
            if let Some(hit) = tracer.closest_hit(&ray, 0.0, f32::INFINITY) {
                let mut d = rng.direction();
                if d.dot(hit.normal) < 0.0 {
                    d = -d;
                }
                let offset = 10f32.powf(rng.range_f32(-4.0, -2.0));
                let p = ray.at(hit.t) + hit.normal * offset;
                lanes.push(Lane {
                    ray: Ray::new(p, d),
                    t0: 0.0,
                    t1: rng.range_f32(0.5, 30.0),
                });
            }
        }
        let (mut with_bound, mut without) = (0, 0);
        let mut scratch = PacketScratch::new();
        for field in &tracer.fields {
            let mut plain = field.clone();
            plain.convex = None;
            for bundle in lanes.chunks(BUNDLE) {
                let mut packed = vec![TraceResult::of_points(None, 0); bundle.len()];
                trace_hart_packet(field, bundle, &scene.tracer, &mut scratch, &mut packed);
                for (l, packed) in bundle.iter().zip(&packed) {
                    let alone = trace_hart(
                        &mut field.cursor(&mut regs),
                        &l.ray,
                        l.t0,
                        l.t1,
                        &scene.tracer,
                    );
                    let whole = trace_hart(
                        &mut plain.cursor(&mut regs),
                        &l.ray,
                        l.t0,
                        l.t1,
                        &scene.tracer,
                    );
                    assert_eq!(
                        alone.t.map(f32::to_bits),
                        whole.t.map(f32::to_bits),
                        "{l:?}"
                    );
                    assert!(alone.steps <= whole.steps, "{l:?}");
                    assert_eq!(
                        (packed.t.map(f32::to_bits), packed.steps),
                        (alone.t.map(f32::to_bits), alone.steps),
                        "bundled against alone: {l:?}"
                    );
                    with_bound += alone.steps as u64;
                    without += whole.steps as u64;
                }
            }
        }
        (with_bound, without)
    }

    #[test]
    fn the_convexity_bound_ends_hart_s_misses_with_the_whole_march_s_answer() {
        let scene = convex_shapes_on_a_plane();
        let (with_bound, without) = hart_marches_agree(&scene, 21);
        // the bound has teeth: rays leaving the ground and passing the shapes end early
        // (about 40 % fewer steps here)
        assert!(
            4 * with_bound < 3 * without,
            "{with_bound} steps with the bound, {without} without"
        );
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes");
        for name in ["showcase", "shadows", "primitives", "csg", "glass"] {
            let scene =
                Scene::load(&dir.join(format!("{name}.ron"))).unwrap_or_else(|e| panic!("{e}"));
            hart_marches_agree(&scene, 22);
        }
    }

    #[test]
    fn a_march_told_a_miss_or_no_shade_from_its_first_sample_gives_it() {
        // A tilted ground; a tilted slab (two planes' intersection: convex, but its
        // gradient enclosure the box of both normals) and a sphere (the unit cube), never
        // told.
        let src = "Scene(camera: Perspective(position: (0, 2, 6), look_at: (0, 0, 0), fov: 60),
            objects: [(shape: Transform(rotate: (3, 0, 4), shape: Plane(normal: (0, 1, 0), offset: -1))),
                      (shape: Transform(rotate: (10, 30, -20), shape: Intersection([
                          Plane(normal: (0, 1, 0), offset: 0.2),
                          Plane(normal: (0, -1, 0), offset: 0.2)]))),
                      (shape: Sphere(radius: 0.5))])";
        let scene =
            Scene::from_source(src, Path::new("slabs.ron")).unwrap_or_else(|e| panic!("{e}"));
        let tracer = crate::trace::SceneTracer::new(&scene);
        let s = &scene.tracer;
        assert!(tracer.fields[0].slopes.is_some());
        assert!(tracer.fields[1].slopes.is_none() && tracer.fields[2].slopes.is_none());
        let mut regs = Registers::new();
        let mut rng = crate::rng::Rng::new(17);
        for (object, field) in tracer.fields.iter().enumerate() {
            let (mut told, mut misses, mut hits, mut lit) = (0, 0, 0, 0);
            for _ in 0..4000 {
                // a point on the surface (found by a march from above or below), lifted off
                // it by up to six ε as shadow rays are, then any direction
                let above = Vec3::new(rng.range_f32(-2.0, 2.0), 3.0, rng.range_f32(-2.0, 2.0));
                let down = Ray::new(above, Vec3::new(rng.range_f32(-0.3, 0.3), -1.0, 0.1));
                let Some(t) = trace_hart(&mut field.cursor(&mut regs), &down, 0.0, 10.0, s).t
                else {
                    continue;
                };
                let lift = rng.range_f32(0.0, 6.0) * epsilon_at(s, t);
                let origin = down.at(t) + Vec3::new(0.0, lift, 0.0);
                let dir = Vec3::new(
                    rng.range_f32(-1.0, 1.0),
                    rng.range_f32(-1.0, 1.0),
                    rng.range_f32(-1.0, 1.0),
                );
                if dir.length() < 0.1 {
                    continue;
                }
                let ray = Ray::new(origin, dir.normalize());
                let t1 = rng.range_f32(0.5, 60.0);
                let march = trace_hart(&mut field.cursor(&mut regs), &ray, 0.0, t1, s);
                if misses_from_start(field, &ray, 0.0, t1, s, &mut regs) {
                    assert_eq!(march.t, None, "object {object}: {ray:?} up to {t1}");
                    told += 1;
                }
                for (k, improved) in [(2.0, false), (12.0, true), (64.0, true)] {
                    if unshaded_from_start(field, &ray, 0.0, t1, k, s, &mut regs) {
                        let mut cursor = field.cursor(&mut regs);
                        let value = penumbra(&mut cursor, &ray, 0.0, t1, s, k, improved);
                        assert_eq!(value, 1.0, "object {object}, k {k}: {ray:?} up to {t1}");
                        lit += 1;
                    }
                }
                match march.t {
                    Some(_) => hits += 1,
                    None => misses += 1,
                }
            }
            assert!(hits > 50, "object {object}: only {hits} rays hit");
            if object == 0 {
                // most rays that leave a plane are told (not those that leave it by less
                // than the margins)
                assert!(
                    2 * told > misses,
                    "object {object}: {told} of {misses} misses told"
                );
                // and the penumbrae of most of them, over three sharpnesses
                assert!(
                    lit > misses,
                    "object {object}: {lit} penumbrae of {misses} told"
                );
            } else {
                assert_eq!((told, lit), (0, 0));
            }
        }
    }

    #[test]
    fn hart_walks_the_leaves_only_where_they_save_much_of_the_tape() {
        // a torus: every crossed leaf keeps its whole short tape, marched whole; fidget's
        // gyroid sphere: its one leaf drops the sphere and the box (20 of 41 instructions),
        // and 64 tiles: a long tape; both walked leaf by leaf
        let torus = "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40), objects: [(shape: Torus(major: 0.6, minor: 0.2))])";
        let gyroid = format!(
            "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40), \
             objects: [(shape: {})])",
            crate::sdf::conformance::FIDGET_GYROID_SPHERE
        );
        let load = |src: &str| {
            Scene::from_source(src, Path::new("t.ron")).unwrap_or_else(|e| panic!("{e}"))
        };
        let cases = [
            ("torus", load(torus), true),
            ("gyroid sphere", load(&gyroid), false),
            (
                "64 tiles",
                crate::accel::field::tests::tiles_scene(8, 8),
                false,
            ),
        ];
        for (name, scene, whole) in cases {
            let tracer = crate::trace::SceneTracer::new(&scene);
            let field = &tracer.fields[0];
            let tree = field.octree.as_ref().expect("an octree");
            let stats = tree.stats();
            assert_eq!(tree.marched_whole(), whole, "{name}: {stats:?}");
            assert_eq!(
                field.whole.len() <= crate::accel::field::SHORT_TAPE
                    && 2.0 * stats.mean_surface_tape >= field.whole.len() as f64,
                whole,
                "{name}: {} instructions, {stats:?}",
                field.whole.len()
            );
            let mut regs = Registers::new();
            let cursor = field.cursor(&mut regs);
            // a ray through the middle of the object, across its box
            let ray = Ray::new(
                Vec3::new(-1.5, 0.013, 0.02),
                Vec3::new(1.0, 0.05, 0.01).normalize(),
            );
            let mut stack = WalkStack::new();
            let mut parts = Parts::new(&cursor, &ray, 0.0, 4.0, &mut stack);
            let mut seen = Vec::new();
            let mut t = 0.0f32;
            while let Some(part) = parts.next(t) {
                seen.push((std::ptr::eq(part.tape, &field.whole), part.start, part.end));
                t = next_up(part.end);
            }
            if whole {
                assert_eq!(seen, vec![(true, 0.0, 4.0)], "{name}");
            } else {
                let leaves = seen.iter().filter(|(whole, _, _)| !whole).count();
                assert!(leaves >= 1, "{name}: {seen:?}");
            }
        }
    }

    #[test]
    fn a_ray_reaches_a_plane_beyond_its_octree_in_a_few_steps() {
        // A tilted ground and one small sphere: the plane's octree covers the scene's box
        // grown by half its size, and a grazing camera ray meets the ground far beyond it.
        let src = "Scene(camera: Perspective(position: (0, 2, 0), look_at: (0, 0, -10), fov: 60),
            objects: [(shape: Transform(rotate: (3, 0, 4), shape: Plane(normal: (0, 1, 0), offset: 0))),
                      (shape: Sphere(radius: 0.5))])";
        let scene =
            Scene::from_source(src, Path::new("plane.ron")).unwrap_or_else(|e| panic!("{e}"));
        let tracer = crate::trace::SceneTracer::new(&scene);
        let ground = &tracer.fields[0];
        // the plane's gradient is its normal everywhere: an enclosure a few ulps wide
        let [lo, hi] = ground.outside;
        let normal = Vec3::from(lo);
        assert!(
            (Vec3::from(hi) - normal).abs().max_element() < 1e-6,
            "{:?}",
            ground.outside
        );
        assert!(
            (normal.length() - 1.0).abs() < 1e-6 && normal.y > 0.99,
            "{normal:?}"
        );
        let mut plain = ground.clone();
        plain.outside = crate::accel::field::ANY_GRADIENT;
        let mut regs = Registers::new();
        for k in 0..20 {
            let dir = Vec3::new(0.02 * k as f32 - 0.2, -0.03 - 0.002 * k as f32, -1.0).normalize();
            let ray = Ray::new(Vec3::new(0.0, 2.0, 0.0), dir);
            let fast = trace_hart(
                &mut ground.cursor(&mut regs),
                &ray,
                0.0,
                200.0,
                &scene.tracer,
            );
            let slow = trace_hart(
                &mut plain.cursor(&mut regs),
                &ray,
                0.0,
                200.0,
                &scene.tracer,
            );
            let (Some(t), Some(t_slow)) = (fast.t, slow.t) else {
                panic!("ray {k} misses the ground: {fast:?}, {slow:?}");
            };
            // the analytic crossing of the tilted plane
            let exact = -ray.origin.dot(normal) / dir.dot(normal);
            let band = 2.0 * epsilon_at(&scene.tracer, exact) / -dir.dot(normal);
            assert!((t - exact).abs() <= band, "ray {k}: {t} against {exact}");
            assert!(
                (t_slow - exact).abs() <= band,
                "ray {k}: {t_slow} against {exact}"
            );
            assert!(fast.steps <= 5, "ray {k}: {} steps", fast.steps);
            assert!(
                slow.steps > 4 * fast.steps,
                "ray {k}: {} and {}",
                slow.steps,
                fast.steps
            );
        }
    }

    #[test]
    fn a_ray_crossing_a_plane_s_octree_reaches_the_plane_beyond_in_one_step() {
        // Rays that start inside the plane's octree (the sphere's box grown) and meet the
        // ground far beyond it: the plane's bound over all of space carries the first step
        // past the leaf's end to the crossing (one or two samples, then the confirmation's
        // three), where the leaf's bound alone stopped at the leaf's exit, and the whole
        // tape's beyond the tree took one more (seven evaluations).
        let src = "Scene(camera: Perspective(position: (0, 2, 0), look_at: (0, 0, -10), fov: 60),
            objects: [(shape: Transform(rotate: (3, 0, 4), shape: Plane(normal: (0, 1, 0), offset: -1))),
                      (shape: Sphere(radius: 0.5))])";
        let scene =
            Scene::from_source(src, Path::new("plane.ron")).unwrap_or_else(|e| panic!("{e}"));
        let tracer = crate::trace::SceneTracer::new(&scene);
        let ground = &tracer.fields[0];
        let tree = ground.octree.as_ref().expect("the plane's octree");
        let mut regs = Registers::new();
        let normal = Vec3::from(ground.outside[0]);
        for k in 0..20 {
            let origin = Vec3::new(0.05 * k as f32 - 0.5, 0.3, 0.2);
            assert!(
                tree.locate(origin).is_some(),
                "ray {k} starts outside the tree"
            );
            let dir = Vec3::new(0.01 * k as f32 - 0.1, -0.05, -1.0).normalize();
            let ray = Ray::new(origin, dir);
            let r = trace_hart(
                &mut ground.cursor(&mut regs),
                &ray,
                0.0,
                200.0,
                &scene.tracer,
            );
            let t =
                r.t.unwrap_or_else(|| panic!("ray {k} misses the ground: {r:?}"));
            // the tilted plane n·p = −1
            let exact = -(ray.origin.dot(normal) + 1.0) / dir.dot(normal);
            let band = 2.0 * epsilon_at(&scene.tracer, exact) / -dir.dot(normal);
            assert!((t - exact).abs() <= band, "ray {k}: {t} against {exact}");
            assert!(r.steps <= 5, "ray {k}: {} steps", r.steps);
        }
    }

    #[test]
    fn the_convexity_bound_ends_penumbra_marches_with_the_whole_march_s_value() {
        let scene = convex_shapes_on_a_plane();
        let (n, partial) = penumbrae_agree(&scene, 11);
        assert!(
            partial * 20 > n,
            "only {partial} of {n} penumbrae are partial"
        );
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes");
        for name in ["showcase", "shadows", "primitives", "csg", "glass"] {
            let scene =
                Scene::load(&dir.join(format!("{name}.ron"))).unwrap_or_else(|e| panic!("{e}"));
            penumbrae_agree(&scene, 12);
        }
    }
}
