// Sphere tracing of one object over its field octree (Hart 1996), its normals, shadow
// penumbrae and exits: the functions of src/trace/sphere.rs, src/trace/crossing.rs and
// src/trace/normal.rs, step for step. Samples of a march are evaluated with the tape of the
// leaf the walk is in (field.wgsl), probes and normals with the tape of the leaf holding the
// point, and the whole tape outside the octree's box.

// trace::epsilon_at: ε(t) = ε₀ + ε₁·max(t, 0).
fn epsilon_at(t: f32) -> f32 {
    return globals.epsilon + globals.epsilon_per_unit * max(t, 0.0);
}

// trace::crossing::confirm: a candidate where f < ε(t) is a hit only where the ray crosses the
// surface (Kalra & Barr 1989: a sign change, narrowed by bisection); otherwise the march goes on.
// Probes evaluate the field by point location, as FieldCursor::eval.
struct Candidate {
    hit: bool,
    t: f32,
}

const MAX_BISECTIONS: u32 = 24u;

// crossing::bisect: narrows (outside: f > 0, inside: f ≤ 0) to ε/2, returns the outside end.
fn sdf_bisect(object: u32, o: vec3<f32>, d: vec3<f32>, outside_in: f32, inside_in: f32, steps: ptr<function, u32>) -> f32 {
    var outside = outside_in;
    var inside = inside_in;
    for (var i = 0u; i < MAX_BISECTIONS; i = i + 1u) {
        if inside - outside <= 0.5 * epsilon_at(outside) {
            break;
        }
        let mid = 0.5 * (outside + inside);
        let f = field_eval(object, o + d * mid);
        *steps = *steps + 1u;
        if f <= 0.0 {
            inside = mid;
        } else {
            outside = mid;
        }
    }
    return outside;
}

fn sdf_confirm(object: u32, o: vec3<f32>, d: vec3<f32>, t: f32, f: f32, t1: f32, steps: ptr<function, u32>) -> Candidate {
    if f <= 0.0 {
        return Candidate(true, t);
    }
    let eps = epsilon_at(t);
    let ts = min(t + eps, t1);
    if ts <= t {
        return Candidate(false, t + eps);
    }
    let fs = field_eval(object, o + d * ts);
    *steps = *steps + 1u;
    if fs <= 0.0 {
        return Candidate(true, sdf_bisect(object, o, d, t, ts, steps));
    }
    let slope = (fs - f) / (ts - t);
    if slope < 0.0 {
        let tp = min(ts + fs / -slope + eps, t1);
        if tp > ts {
            let fp = field_eval(object, o + d * tp);
            *steps = *steps + 1u;
            if fp <= 0.0 {
                return Candidate(true, sdf_bisect(object, o, d, ts, tp, steps));
            }
        }
    }
    return Candidate(false, ts + max(fs, eps));
}

struct TraceResult {
    hit: bool,
    t: f32,
    steps: u32,
}

// sphere::next_up: the next float above x ≥ 0.
fn next_up(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(max(x, 0.0)) + 1u);
}

// sphere::Part: a part of the ray marched with one tape (a leaf's, or the whole tape's
// outside the tree) and how fast the field may fall along the ray there (field::Leaf::fall);
// `valid` is false when none is left.
struct Part {
    tape: TapeRef,
    fall: f32,
    everywhere: f32,
    start: f32,
    end: f32,
    valid: bool,
}

// sphere::Phase.
const PHASE_WHOLE: u32 = 0u;
const PHASE_BEFORE: u32 = 1u;
const PHASE_WALK: u32 = 2u;
const PHASE_AFTER: u32 = 3u;
const PHASE_DONE: u32 = 4u;

// sphere::Parts: the parts of [t0, t1] in order: the whole tape before the tree's box, the
// leaves of the walk (field_walk) that are not empty, the whole tape beyond the box; one
// whole-tape part where the leaves save little (field::FieldOctree::marched_whole).
struct Parts {
    object: u32,
    direction: vec3<f32>,
    everywhere: f32,
    phase: u32,
    t1: f32,
    enter: f32,
    leave: f32,
}

// Parts::new.
fn parts_new(object: u32, o: vec3<f32>, d: vec3<f32>, t0: f32, t1: f32) -> Parts {
    let obj = objects[object];
    let everywhere = gradient_fall(obj.outside_graded, obj.outside_lo, obj.outside_hi, d);
    var parts = Parts(object, d, everywhere, PHASE_WHOLE, t1, t0, t1);
    if obj.field_root != NONE && obj.marched_whole == 0u {
        let iv = ray_interval(obj.field_lo, obj.field_hi, o, d, t0, t1);
        if iv.hit {
            field_walk_begin(object, o, d, t0, iv.t1);
            if t0 < iv.t0 {
                parts.phase = PHASE_BEFORE;
            } else {
                parts.phase = PHASE_WALK;
            }
            parts.enter = iv.t0;
            parts.leave = iv.t1;
        }
    }
    return parts;
}

// Parts::whole_part: the whole tape, its fall bounded by the object's gradient enclosure
// outside the tree (field::ObjectField::outside), the same bound the parts hold for
// anywhere (computed once per ray, in parts_new).
fn whole_part(parts: ptr<function, Parts>, start: f32, end: f32) -> Part {
    let fall = (*parts).everywhere;
    return Part(objects[(*parts).object].distance, fall, fall, start, end, true);
}

// Parts::next: the next part for a march now at t.
fn parts_next(parts: ptr<function, Parts>, t: f32) -> Part {
    let object = (*parts).object;
    while (*parts).phase != PHASE_DONE {
        switch (*parts).phase {
            case PHASE_WHOLE: {
                (*parts).phase = PHASE_DONE;
                return whole_part(parts, t, (*parts).t1);
            }
            case PHASE_BEFORE: {
                (*parts).phase = PHASE_WALK;
                return whole_part(parts, t, (*parts).enter);
            }
            case PHASE_WALK: {
                let x = field_next_leaf();
                if x.leaf == NONE {
                    (*parts).phase = PHASE_AFTER;
                } else {
                    let leaf = field_leaves[x.leaf];
                    if !(x.exit < t || leaf.verdict == VERDICT_EMPTY) {
                        return Part(field_tapes[leaf.tape], leaf_fall(leaf, (*parts).direction), (*parts).everywhere, max(t, x.enter), min(x.exit, (*parts).t1), true);
                    }
                }
            }
            case PHASE_AFTER: {
                (*parts).phase = PHASE_DONE;
                if (*parts).leave < (*parts).t1 {
                    return whole_part(parts, max(t, next_up((*parts).leave)), (*parts).t1);
                }
            }
            default: {}
        }
    }
    return Part(objects[object].distance, 1.0, 1.0, 0.0, 0.0, false);
}

// field::Leaf::fall.
fn leaf_fall(leaf: FieldLeafRecord, d: vec3<f32>) -> f32 {
    return gradient_fall(leaf.graded, leaf.gradient_lo, leaf.gradient_hi, d);
}

// field::fall_along_reference: the largest −d·g over a gradient enclosure, at least 0,
// rounded up (1, the global bound, without an enclosure).
fn gradient_fall(graded: u32, lo: vec3<f32>, hi: vec3<f32>, d: vec3<f32>) -> f32 {
    if graded == 0u {
        return 1.0;
    }
    let m = min(lo * d, hi * d);
    let f = -(m.x + m.y + m.z);
    return max(f + abs(f) * FALL_ROUNDING, 0.0);
}

// sphere::hart_step: d, or d/fall kept ε/4 short within the part where the field falls by
// less than 1 per unit along the ray, or d/everywhere anywhere.
fn hart_step(f: f32, part: Part, t: f32, eps: f32) -> f32 {
    var step = f;
    if part.fall < 1.0 {
        step = max(step, min(f / part.fall - HART_STEP_MARGIN * eps, part.end - t));
    }
    if part.everywhere < 1.0 {
        var reach = 3.4028235e38;
        if part.everywhere > 0.0 {
            reach = f / part.everywhere - HART_STEP_MARGIN * eps;
        }
        step = max(step, reach);
    }
    return step;
}

// sphere::Stretch: how a march over one part ended.
const STRETCH_HIT: u32 = 0u;
const STRETCH_LEFT: u32 = 1u;
const STRETCH_SPENT: u32 = 2u;
const STRETCH_CLEAR: u32 = 3u;

struct Stretch {
    kind: u32,
    t: f32,
}

// sphere::Sample: a march's last sample, for the convexity bound's chords; NO_SAMPLE stands
// for Sample::NONE (t = −∞, h = ∞: WGSL has no infinities, and no chord reaches from there).
struct Sample {
    t: f32,
    h: f32,
}
const NO_SAMPLE = Sample(-3.4028235e38, 3.4028235e38);

// sphere::ConvexBound::new: the largest rounding error of a convex field's values on the
// march of o + t·d over [t0, t1] (|p|∞ is largest at an end); negative for a field without
// the bound.
fn convex_error(object: u32, o: vec3<f32>, d: vec3<f32>, t0: f32, t1: f32) -> f32 {
    let obj = objects[object];
    if obj.convex == 0u {
        return -1.0;
    }
    let a = abs(o + t0 * d);
    let b = abs(o + t1 * d);
    let reach = max(max(max(a.x, a.y), a.z), max(max(b.x, b.y), b.z));
    return obj.convex_relative * (obj.convex_scale + reach);
}

// sphere::ConvexBound::stays_off: whether no sample after h at t can come below ε, the chord
// from `before` rising past ε's growth (with 2⁻¹⁰ to spare) while h − 2e stays above ε(t).
fn stays_off(error: f32, before: Sample, t: f32, h: f32) -> bool {
    if error < 0.0 || !(h > before.h) {
        return false;
    }
    let spare = 1.0 + 1.0 / 1024.0;
    let a = h - 2.0 * error;
    let rise = h - before.h - 2.0 * error;
    let run = t - before.t;
    return a >= spare * epsilon_at(t) && rise >= spare * globals.epsilon_per_unit * run && run > 0.0;
}

// sphere::march_part: Hart's march over one part; `chord` holds the march's last sample
// (kept across parts) for the convexity bound of error `error` (negative: none).
fn march_part(object: u32, part: Part, o: vec3<f32>, d: vec3<f32>, t1: f32, steps: ptr<function, u32>, error: f32, chord: ptr<function, Sample>) -> Stretch {
    var t = part.start;
    while t <= part.end {
        if *steps >= globals.max_steps {
            return Stretch(STRETCH_SPENT, t);
        }
        let f = tape_eval(part.tape, o + d * t);
        *steps = *steps + 1u;
        let eps = epsilon_at(t);
        if f < eps {
            *chord = NO_SAMPLE;
            let c = sdf_confirm(object, o, d, t, f, t1, steps);
            if c.hit {
                return Stretch(STRETCH_HIT, c.t);
            }
            t = c.t;
        } else {
            if stays_off(error, *chord, t, f) {
                return Stretch(STRETCH_CLEAR, t);
            }
            *chord = Sample(t, f);
            t = t + hart_step(f, part, t, eps);
        }
    }
    return Stretch(STRETCH_LEFT, t);
}

// sphere::trace_hart: the parts of [t0, t1] marched in order, each with its own tape; where
// f < ε(t) the candidate is confirmed (sdf_confirm); a miss past t1 or after max_steps
// evaluations.
fn sdf_trace(object: u32, o: vec3<f32>, d: vec3<f32>, t0: f32, t1: f32) -> TraceResult {
    var parts = parts_new(object, o, d, t0, t1);
    let error = convex_error(object, o, d, t0, t1);
    var chord = NO_SAMPLE;
    var t = t0;
    var steps = 0u;
    loop {
        let part = parts_next(&parts, t);
        if !part.valid {
            break;
        }
        let s = march_part(object, part, o, d, t1, &steps, error, &chord);
        if s.kind == STRETCH_HIT {
            return TraceResult(true, s.t, steps);
        }
        if s.kind == STRETCH_SPENT || s.kind == STRETCH_CLEAR {
            break;
        }
        t = s.t;
        if t > t1 {
            break;
        }
    }
    return TraceResult(false, t, steps);
}

// sphere::Along: the leaf at increasing parameters t along a ray (the walk's, field_walk),
// none outside the tree.
struct Along {
    // the walk may still meet leaves
    walking: bool,
    // the last leaf met (leaf NONE: none)
    current: Crossed,
}

// Along::new: the walk over [t0, t1].
fn along_new(object: u32, o: vec3<f32>, d: vec3<f32>, t0: f32, t1: f32) -> Along {
    let walking = objects[object].field_root != NONE;
    if walking {
        field_walk_begin(object, o, d, t0, t1);
    }
    return Along(walking, crossed_none());
}

// Along::at: the leaf at t (t never decreasing between calls), or leaf NONE outside the tree.
fn along_at(along: ptr<function, Along>, t: f32) -> Crossed {
    let c = (*along).current;
    if c.leaf != NONE && t <= c.exit {
        if t >= c.enter {
            return c;
        }
        return crossed_none();
    }
    while (*along).walking {
        let n = field_next_leaf();
        if n.leaf == NONE {
            (*along).walking = false;
            (*along).current = crossed_none();
        } else if !(n.exit < t) {
            (*along).current = n;
            if t >= n.enter {
                return n;
            }
            return crossed_none();
        }
    }
    return crossed_none();
}

// Along::tape: the tape valid at t.
fn along_tape(along: ptr<function, Along>, object: u32, t: f32) -> TapeRef {
    let c = along_at(along, t);
    if c.leaf == NONE {
        return objects[object].distance;
    }
    return field_tapes[field_leaves[c.leaf].tape];
}

// sphere::penumbra: Quilez's soft-shadow estimate min(k·h/t), or with `improved` the closest
// approach between the last two samples; 0 when a sample is within ε(t) of the surface. The
// samples are the whole tape's (no leaf skipped), each with the tape of its leaf.
fn sdf_penumbra(object: u32, o: vec3<f32>, d: vec3<f32>, t0: f32, t1: f32, k: f32, improved: bool) -> f32 {
    var along = along_new(object, o, d, t0, t1);
    var res = 1.0;
    // f32::INFINITY of the CPU: h*h/(2·previous) is then 0, as with an infinite previous.
    var previous = 3.4028235e38;
    var first = true;
    var t = t0;
    for (var i = 0u; i < globals.max_steps; i = i + 1u) {
        let h = tape_eval(along_tape(&along, object, t), o + d * t);
        if h < epsilon_at(t) {
            return 0.0;
        }
        var y = 0.0;
        if !first {
            y = h * h / (2.0 * previous);
        }
        var estimate: f32;
        if improved && (first || y <= previous) {
            let dist = sqrt(max(h * h - y * y, 0.0));
            estimate = k * dist / max(t - y, 1e-6);
        } else {
            estimate = k * h / max(t, 1e-6);
        }
        res = min(res, estimate);
        previous = h;
        first = false;
        t = t + h;
        if t > t1 || res < 1e-4 {
            break;
        }
    }
    return clamp(res, 0.0, 1.0);
}

// sphere::exit: from inside a solid to where the ray leaves it, by steps of 0.9·|f|; a leaf
// proven full is left at once. A negative result when the ray is still inside after
// max_steps or t1.
fn sdf_exit(object: u32, o: vec3<f32>, d: vec3<f32>, t0: f32, t1: f32) -> f32 {
    var along = along_new(object, o, d, t0, t1);
    var t = t0;
    var steps = 0u;
    var skips = 0u;
    while steps < globals.max_steps && skips < MAX_SKIPS {
        let c = along_at(&along, t);
        var tape = objects[object].distance;
        if c.leaf != NONE {
            let leaf = field_leaves[c.leaf];
            if leaf.verdict == VERDICT_FULL {
                // inside at every point of the leaf: on to just past where the ray leaves it
                t = next_up(max(t, c.exit));
                skips = skips + 1u;
                if t > t1 {
                    return -1.0;
                }
                continue;
            }
            tape = field_tapes[leaf.tape];
        }
        let f = -tape_eval(tape, o + d * t);
        steps = steps + 1u;
        if f < epsilon_at(t) {
            return t;
        }
        t = t + 0.9 * f;
        if t > t1 {
            return -1.0;
        }
    }
    return -1.0;
}

// normal::step_for: a few ε(t), never below NORMAL_STEP_FLOOR nor NORMAL_RELATIVE_STEP times
// p's largest coordinate (both generated from normal.rs).
fn normal_step(t: f32, p: vec3<f32>) -> f32 {
    let a = abs(p);
    return max(max(2.0 * epsilon_at(t), NORMAL_STEP_FLOOR), max(a.x, max(a.y, a.z)) * NORMAL_RELATIVE_STEP);
}

// normal::central and normal::tetrahedral: the gradient estimate at p with step h, each
// point evaluated with the tape of the leaf holding it.
fn sdf_gradient(object: u32, p: vec3<f32>, h: f32) -> vec3<f32> {
    if globals.normals == NORMALS_TETRAHEDRAL {
        let k0 = vec3<f32>(1.0, -1.0, -1.0);
        let k1 = vec3<f32>(-1.0, -1.0, 1.0);
        let k2 = vec3<f32>(-1.0, 1.0, -1.0);
        let k3 = vec3<f32>(1.0, 1.0, 1.0);
        let g = k0 * field_eval(object, p + k0 * h) + k1 * field_eval(object, p + k1 * h)
            + k2 * field_eval(object, p + k2 * h) + k3 * field_eval(object, p + k3 * h);
        return g / (4.0 * h);
    }
    let gx = field_eval(object, p + vec3<f32>(h, 0.0, 0.0)) - field_eval(object, p - vec3<f32>(h, 0.0, 0.0));
    let gy = field_eval(object, p + vec3<f32>(0.0, h, 0.0)) - field_eval(object, p - vec3<f32>(0.0, h, 0.0));
    let gz = field_eval(object, p + vec3<f32>(0.0, 0.0, h)) - field_eval(object, p - vec3<f32>(0.0, 0.0, h));
    return vec3<f32>(gx, gy, gz) / (2.0 * h);
}

// glam's try_normalize: the unit vector, or +y when the length is 0 or not finite (so the
// centre of a sphere gives +y rather than NaN).
fn normalize_or_y(g: vec3<f32>) -> vec3<f32> {
    let l = length(g);
    let r = 1.0 / l;
    if l > 0.0 && r > 0.0 && r < 3.4028235e38 {
        return g * r;
    }
    return vec3<f32>(0.0, 1.0, 0.0);
}
