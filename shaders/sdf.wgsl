// Sphere tracing of one tape (Hart 1996), its normals, shadow penumbrae and exits: the
// functions of src/trace/sphere.rs and src/trace/normal.rs, step for step.

// trace::epsilon_at: ε(t) = ε₀ + ε₁·max(t, 0).
fn epsilon_at(t: f32) -> f32 {
    return globals.epsilon + globals.epsilon_per_unit * max(t, 0.0);
}

// trace::crossing::confirm: a candidate where f < ε(t) is a hit only where the ray crosses the
// surface (Kalra & Barr 1989: a sign change, narrowed by bisection); otherwise the march goes on.
struct Candidate {
    hit: bool,
    t: f32,
}

const MAX_BISECTIONS: u32 = 24u;

// crossing::bisect: narrows (outside: f > 0, inside: f ≤ 0) to ε/2, returns the outside end.
fn sdf_bisect(tape: TapeRef, o: vec3<f32>, d: vec3<f32>, outside_in: f32, inside_in: f32, steps: ptr<function, u32>) -> f32 {
    var outside = outside_in;
    var inside = inside_in;
    for (var i = 0u; i < MAX_BISECTIONS; i = i + 1u) {
        if inside - outside <= 0.5 * epsilon_at(outside) {
            break;
        }
        let mid = 0.5 * (outside + inside);
        let f = tape_eval(tape, o + d * mid);
        *steps = *steps + 1u;
        if f <= 0.0 {
            inside = mid;
        } else {
            outside = mid;
        }
    }
    return outside;
}

fn sdf_confirm(tape: TapeRef, o: vec3<f32>, d: vec3<f32>, t: f32, f: f32, t1: f32, steps: ptr<function, u32>) -> Candidate {
    if f <= 0.0 {
        return Candidate(true, t);
    }
    let eps = epsilon_at(t);
    let ts = min(t + eps, t1);
    if ts <= t {
        return Candidate(false, t + eps);
    }
    let fs = tape_eval(tape, o + d * ts);
    *steps = *steps + 1u;
    if fs <= 0.0 {
        return Candidate(true, sdf_bisect(tape, o, d, t, ts, steps));
    }
    let slope = (fs - f) / (ts - t);
    if slope < 0.0 {
        let tp = min(ts + fs / -slope + eps, t1);
        if tp > ts {
            let fp = tape_eval(tape, o + d * tp);
            *steps = *steps + 1u;
            if fp <= 0.0 {
                return Candidate(true, sdf_bisect(tape, o, d, ts, tp, steps));
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

// sphere::trace_hart: march from t0 by the field value; where f < ε(t) the candidate is
// confirmed by crossing::confirm (below); a miss past t1 or after max_steps evaluations.
fn sdf_trace(tape: TapeRef, o: vec3<f32>, d: vec3<f32>, t0: f32, t1: f32) -> TraceResult {
    var t = t0;
    var steps = 0u;
    while steps < globals.max_steps {
        let f = tape_eval(tape, o + d * t);
        steps = steps + 1u;
        if f < epsilon_at(t) {
            let c = sdf_confirm(tape, o, d, t, f, t1, &steps);
            if c.hit {
                return TraceResult(true, c.t, steps);
            }
            t = c.t;
        } else {
            t = t + f;
        }
        if t > t1 {
            break;
        }
    }
    return TraceResult(false, t, steps);
}

// sphere::penumbra: Quilez's soft-shadow estimate min(k·h/t), or with `improved` the closest
// approach between the last two samples; 0 when a sample is within ε(t) of the surface.
fn sdf_penumbra(tape: TapeRef, o: vec3<f32>, d: vec3<f32>, t0: f32, t1: f32, k: f32, improved: bool) -> f32 {
    var res = 1.0;
    // f32::INFINITY of the CPU: h*h/(2·previous) is then 0, as with an infinite previous.
    var previous = 3.4028235e38;
    var first = true;
    var t = t0;
    for (var i = 0u; i < globals.max_steps; i = i + 1u) {
        let h = tape_eval(tape, o + d * t);
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

// sphere::exit: from inside a solid to where the ray leaves it, by steps of 0.9·|f|; a
// negative result when the ray is still inside after max_steps or t1.
fn sdf_exit(tape: TapeRef, o: vec3<f32>, d: vec3<f32>, t0: f32, t1: f32) -> f32 {
    var t = t0;
    for (var i = 0u; i < globals.max_steps; i = i + 1u) {
        let f = -tape_eval(tape, o + d * t);
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

// normal::step_for: a few ε(t), never below 1e-4.
fn normal_step(t: f32) -> f32 {
    return max(2.0 * epsilon_at(t), 1e-4);
}

// normal::central and normal::tetrahedral: the gradient estimate at p with step h.
fn sdf_gradient(tape: TapeRef, p: vec3<f32>, h: f32) -> vec3<f32> {
    if globals.normals == NORMALS_TETRAHEDRAL {
        let k0 = vec3<f32>(1.0, -1.0, -1.0);
        let k1 = vec3<f32>(-1.0, -1.0, 1.0);
        let k2 = vec3<f32>(-1.0, 1.0, -1.0);
        let k3 = vec3<f32>(1.0, 1.0, 1.0);
        let g = k0 * tape_eval(tape, p + k0 * h) + k1 * tape_eval(tape, p + k1 * h)
            + k2 * tape_eval(tape, p + k2 * h) + k3 * tape_eval(tape, p + k3 * h);
        return g / (4.0 * h);
    }
    let gx = tape_eval(tape, p + vec3<f32>(h, 0.0, 0.0)) - tape_eval(tape, p - vec3<f32>(h, 0.0, 0.0));
    let gy = tape_eval(tape, p + vec3<f32>(0.0, h, 0.0)) - tape_eval(tape, p - vec3<f32>(0.0, h, 0.0));
    let gz = tape_eval(tape, p + vec3<f32>(0.0, 0.0, h)) - tape_eval(tape, p - vec3<f32>(0.0, 0.0, h));
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
