//! The peer section's ground truth: an f64 evaluator of SSA tapes and dense sampling along rays.
//!
//! Deliberately independent of both renderers: no Lipschitz bound, no interval arithmetic, no
//! octree, no f32. A pixel is a hit when any of the evenly spaced samples along its ray, inside
//! an object's bounds, has a negative value. Its one assumption is that no feature is thinner
//! than the sample spacing (half a voxel at the default density), which is also what both
//! renderers need to see it.

use crate::sdf::ssa::{SsaOp, SsaTape};
use crate::sdf::tape::Op;

/// Points evaluated together: every operation runs over this many samples before the next
/// one, so the interpreter's dispatch is paid once per batch and the arithmetic vectorises.
pub const BATCH: usize = 32;

/// The distance part of an [`SsaTape`] in f64: its live operations, renumbered.
#[derive(Debug, Clone)]
pub struct F64Program {
    ops: Vec<SsaOp>,
    result: usize,
}

impl F64Program {
    /// The distance of `tape` (material operations dropped, dead code removed).
    pub fn new(tape: &SsaTape) -> F64Program {
        let d = tape.distance_only();
        let live = d.live();
        let mut map = vec![u32::MAX; d.ops.len()];
        let mut ops = Vec::new();
        for (i, op) in d.ops.iter().enumerate() {
            if !live[i] && op.op != Op::Input {
                continue;
            }
            let m = |v: u32| map.get(v as usize).copied().unwrap_or(0);
            let mut o = *op;
            match op.op.shape() {
                crate::sdf::tape::Shape::Nullary | crate::sdf::tape::Shape::MatLoad => {}
                _ => {
                    o.a = m(op.a);
                    o.b = m(op.b);
                    o.c = m(op.c);
                }
            }
            map[i] = ops.len() as u32;
            ops.push(o);
        }
        let result = map.get(d.result as usize).copied().unwrap_or(0) as usize;
        F64Program { ops, result }
    }

    /// Operations evaluated per point (inputs included).
    pub fn len(&self) -> usize {
        self.ops.len()
    }

    /// Whether the program is only its inputs.
    pub fn is_empty(&self) -> bool {
        self.ops.len() <= 3
    }

    /// The value at one point.
    pub fn eval(&self, p: [f64; 3]) -> f64 {
        let mut regs = Vec::new();
        let mut out = [0.0];
        self.eval_batch(&[p[0]], &[p[1]], &[p[2]], &mut regs, &mut out);
        out[0]
    }

    /// Values at up to [`BATCH`] points (`out[i]` for point i); `regs` is scratch.
    pub fn eval_batch(
        &self,
        x: &[f64],
        y: &[f64],
        z: &[f64],
        regs: &mut Vec<f64>,
        out: &mut [f64],
    ) {
        let n = x.len().min(BATCH).min(out.len());
        regs.resize(self.ops.len() * BATCH, 0.0);
        for (i, op) in self.ops.iter().enumerate() {
            let (done, rest) = regs.split_at_mut(i * BATCH);
            let r = &mut rest[..n];
            let at = |v: u32| &done[v as usize * BATCH..v as usize * BATCH + n];
            let k = f64::from(op.imm());
            match op.op {
                Op::Input => {
                    let src = match op.imm {
                        0 => x,
                        1 => y,
                        _ => z,
                    };
                    r.copy_from_slice(&src[..n]);
                }
                Op::Const => r.fill(k),
                Op::Copy => r.copy_from_slice(at(op.a)),
                Op::Neg => unary(r, at(op.a), |a| -a),
                Op::Abs => unary(r, at(op.a), f64::abs),
                Op::Sqrt => unary(r, at(op.a), f64::sqrt),
                Op::Square => unary(r, at(op.a), |a| a * a),
                Op::Floor => unary(r, at(op.a), f64::floor),
                Op::Sin => unary(r, at(op.a), f64::sin),
                Op::Cos => unary(r, at(op.a), f64::cos),
                Op::Tan => unary(r, at(op.a), f64::tan),
                Op::Exp => unary(r, at(op.a), f64::exp),
                Op::Ln => unary(r, at(op.a), f64::ln),
                Op::Add => binary(r, at(op.a), at(op.b), |a, b| a + b),
                Op::Sub => binary(r, at(op.a), at(op.b), |a, b| a - b),
                Op::Mul => binary(r, at(op.a), at(op.b), |a, b| a * b),
                Op::Div => binary(r, at(op.a), at(op.b), |a, b| a / b),
                Op::Min => binary(r, at(op.a), at(op.b), f64::min),
                Op::Max => binary(r, at(op.a), at(op.b), f64::max),
                Op::Pow => binary(r, at(op.a), at(op.b), pow),
                Op::Hypot => binary(r, at(op.a), at(op.b), |a, b| (a * a + b * b).sqrt()),
                Op::AddImm => unary(r, at(op.a), |a| a + k),
                Op::SubImm => unary(r, at(op.a), |a| a - k),
                Op::RsubImm => unary(r, at(op.a), |a| k - a),
                Op::MulImm => unary(r, at(op.a), |a| a * k),
                Op::DivImm => unary(r, at(op.a), |a| a / k),
                Op::RdivImm => unary(r, at(op.a), |a| k / a),
                Op::MinImm => unary(r, at(op.a), |a| a.min(k)),
                Op::MaxImm => unary(r, at(op.a), |a| a.max(k)),
                Op::PowImm => unary(r, at(op.a), |a| pow(a, k)),
                Op::Select => {
                    let (a, b, c) = (at(op.a), at(op.b), at(op.c));
                    for i in 0..n {
                        r[i] = if c[i] > 0.0 { a[i] } else { b[i] };
                    }
                }
                Op::Hypot3 => {
                    let (a, b, c) = (at(op.a), at(op.b), at(op.c));
                    for i in 0..n {
                        r[i] = (a[i] * a[i] + b[i] * b[i] + c[i] * c[i]).sqrt();
                    }
                }
                // Not in a distance program (see `new`).
                Op::MatLoad | Op::MatMix => r.fill(0.0),
            }
        }
        out[..n].copy_from_slice(&regs[self.result * BATCH..self.result * BATCH + n]);
    }
}

/// aᵇ as the tape defines it: a⁰ = 1, NaN for a < 0.
fn pow(a: f64, b: f64) -> f64 {
    if b == 0.0 {
        1.0
    } else if a < 0.0 {
        f64::NAN
    } else {
        a.powf(b)
    }
}

fn unary(r: &mut [f64], a: &[f64], f: impl Fn(f64) -> f64) {
    for (r, a) in r.iter_mut().zip(a) {
        *r = f(*a);
    }
}

fn binary(r: &mut [f64], a: &[f64], b: &[f64], f: impl Fn(f64, f64) -> f64) {
    for ((r, a), b) in r.iter_mut().zip(a).zip(b) {
        *r = f(*a, *b);
    }
}

/// One object as the ground truth sees it: its program and its world-space bounds.
#[derive(Debug, Clone)]
pub struct TruthObject {
    /// The distance program.
    pub program: F64Program,
    /// Conservative bounds of the surface (samples outside are skipped).
    pub min: [f64; 3],
    /// See `min`.
    pub max: [f64; 3],
}

/// Whether the ray x = `x`, y = `y`, z from `z_top` down to `z_top − depth` meets the surface of
/// any object: `samples` evenly spaced samples (at the centres of equal steps), front to back,
/// inside each object's bounds; stops at the first negative one.
pub fn ray_hits(
    objects: &[TruthObject],
    x: f64,
    y: f64,
    z_top: f64,
    depth: f64,
    samples: usize,
    regs: &mut Vec<f64>,
) -> bool {
    let dz = depth / samples as f64;
    let xs = [x; BATCH];
    let ys = [y; BATCH];
    let mut zs = [0.0; BATCH];
    let mut out = [0.0; BATCH];
    for o in objects {
        if x < o.min[0] || x > o.max[0] || y < o.min[1] || y > o.max[1] {
            continue;
        }
        // Sample indices k with z_top − (k + ½)·dz inside [min z, max z].
        let first = (((z_top - o.max[2]) / dz - 0.5).floor().max(0.0)) as usize;
        let last = (((z_top - o.min[2]) / dz - 0.5).ceil().max(0.0) as usize).min(samples);
        let mut k = first;
        while k < last {
            let n = (last - k).min(BATCH);
            for (i, z) in zs[..n].iter_mut().enumerate() {
                *z = z_top - ((k + i) as f64 + 0.5) * dz;
            }
            o.program
                .eval_batch(&xs[..n], &ys[..n], &zs[..n], regs, &mut out[..n]);
            if out[..n].iter().any(|&v| v < 0.0) {
                return true;
            }
            k += n;
        }
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;
    use crate::sdf::tape::Registers;
    use glam::Vec3;

    #[test]
    fn the_f64_program_agrees_with_the_tape_on_every_shipped_scene() {
        let mut rng = crate::rng::Rng::new(11);
        let mut regs = Registers::new();
        for (name, scene) in crate::scene::shipped_scenes() {
            for o in &scene.objects {
                let f = F64Program::new(&o.lowered.program);
                let b = o.bounds();
                let (lo, hi) = if b.is_finite() {
                    (b.min - 0.5, b.max + 0.5)
                } else {
                    (Vec3::splat(-5.0), Vec3::splat(5.0))
                };
                for _ in 0..200 {
                    let p = Vec3::new(
                        rng.range_f32(lo.x, hi.x),
                        rng.range_f32(lo.y, hi.y),
                        rng.range_f32(lo.z, hi.z),
                    );
                    let ours = o.lowered.distance.eval_in(p, &mut regs);
                    let exact = f.eval([p.x as f64, p.y as f64, p.z as f64]);
                    let tol = 1e-4 * (1.0 + exact.abs());
                    assert!(
                        (ours as f64 - exact).abs() <= tol,
                        "{name}/{}: {ours} against {exact} at {p}",
                        o.name
                    );
                }
            }
        }
    }

    #[test]
    fn dense_sampling_finds_a_sphere_and_misses_beside_it() {
        let scene = Scene::from_source(
            "Scene(camera: Orthographic(position: (0, 0, 3), look_at: (0, 0, 0), height: 2), \
             objects: [(shape: Sphere(radius: 0.5), translate: (0.2, 0, 0))])",
            std::path::Path::new("<test>"),
        )
        .unwrap();
        let o = &scene.objects[0];
        let b = o.bounds();
        let obj = TruthObject {
            program: F64Program::new(&o.lowered.program),
            min: b.min.as_dvec3().to_array(),
            max: b.max.as_dvec3().to_array(),
        };
        let mut regs = Vec::new();
        let objs = [obj];
        assert!(ray_hits(&objs, 0.2, 0.0, 1.0, 2.0, 256, &mut regs));
        assert!(ray_hits(&objs, 0.6, 0.2, 1.0, 2.0, 256, &mut regs));
        assert!(!ray_hits(&objs, -0.35, 0.0, 1.0, 2.0, 256, &mut regs));
        assert!(!ray_hits(&objs, 0.2, 0.6, 1.0, 2.0, 256, &mut regs));
    }
}
