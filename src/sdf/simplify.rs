//! Region specialisation: the tape a box needs, found by interval evaluation.
//!
//! Over a box, an interval evaluation of the SSA program ([`crate::sdf::interval`]) shows
//! which branch of each `min`, `max`, `select` and `|·|` every point of the box takes; the
//! others are dropped, constants are folded (a clamp decided to 1 makes a smooth blend's
//! weights constant, and the blend collapses to one child), and dead code goes — fidget's
//! `simplify`, libfive's tape pruning, Keeter's "Massively Parallel Rendering of Complex
//! Closed-Form Implicit Surfaces" (SIGGRAPH 2020) §4. The enclosures contain what the point
//! interpreter computes (not only the exact reals), so a decided branch is the one the
//! interpreter takes at every point of the box: the specialised tape returns there exactly
//! the bits of the whole tape (up to the sign of a zero). An enclosure above zero proves the
//! box empty, one below zero proves it full.
//!
//! [`Simplifier::gradient`] encloses ∇f over a box (three slope enclosures, forward-mode
//! differentiation on intervals): along a ray of direction d the field then falls by at most
//! max over the box of −d·∇f per unit, which lets a tracer step farther than the global
//! 1-Lipschitz bound allows — to the crossing at once on a plane.

use crate::sdf::interval::{Domain, Interval, Slope, apply_domain};
use crate::sdf::ssa::{Builder, M, SsaTape, V};
use crate::sdf::tape::{Op, Shape};
use glam::Vec3;

/// What a box holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Verdict {
    /// f > 0 at every point: outside the solid, no surface.
    Empty,
    /// f < 0 at every point: inside the solid, no surface.
    Full,
    /// The surface may pass through.
    Surface,
}

/// A program specialised to a box.
#[derive(Debug, Clone)]
pub struct Specialised {
    /// The simplified program: equal to the original at every point of the box.
    pub program: SsaTape,
    /// Operations the distance depends on (inputs excluded).
    pub len: usize,
    /// An enclosure of the field over the box.
    pub value: Interval,
    /// Empty, full, or possibly crossed by the surface.
    pub verdict: Verdict,
}

/// How an operation resolved over the box.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Choice {
    /// Both operands may matter.
    Both,
    /// The result is the first operand (`a`).
    A,
    /// The result is the second operand (`b`; for `Select`, `b` too).
    B,
    /// The result is the immediate (`min(a, k)` with a ≥ k everywhere).
    Imm,
    /// The result is −a (`|a|` with a ≤ 0 everywhere).
    NegA,
    /// The result is a constant (a `floor` on one step of its staircase).
    Const(u32),
}

/// A deliberate error, for tests that must see a wrong simplification fail.
#[doc(hidden)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Fault {
    /// None: the simplifier as it is.
    #[default]
    None,
    /// Every decided two-way choice keeps the other branch.
    WrongBranch,
}

/// Scratch buffers reused across specialisations.
#[derive(Debug, Default)]
pub struct Simplifier {
    #[doc(hidden)]
    pub fault: Fault,
    values: Vec<Interval>,
    choices: Vec<Choice>,
    live: Vec<bool>,
    map: Vec<u32>,
}

impl Simplifier {
    /// Fresh buffers.
    pub fn new() -> Self {
        Self::default()
    }

    /// Interval evaluation of `program` over the box, recording the choices.
    fn evaluate(&mut self, program: &SsaTape, lo: Vec3, hi: Vec3) -> Interval {
        let n = program.ops.len();
        self.values.clear();
        self.values.resize(n, Interval::point(0.0));
        self.choices.clear();
        self.choices.resize(n, Choice::Both);
        for (i, op) in program.ops.iter().enumerate() {
            let v = |k: u32| self.values[k as usize];
            let (value, choice) = match op.op {
                Op::Input => {
                    let axis = op.imm as usize;
                    (
                        Interval::point(lo[axis]).hull(Interval::point(hi[axis])),
                        Choice::Both,
                    )
                }
                Op::MatLoad | Op::MatMix => (Interval::point(0.0), Choice::Both),
                _ => {
                    let (a, b, c) = (v(op.a), v(op.b), v(op.c));
                    let value = apply_domain(op.op, a, b, c, op.imm());
                    let choice = match (decide(op.op, a, b, c, op.imm()), self.fault) {
                        (Choice::A, Fault::WrongBranch) if op.op.shape() != Shape::WithImm => {
                            Choice::B
                        }
                        (Choice::B, Fault::WrongBranch) => Choice::A,
                        (choice, _) => choice,
                    };
                    (value, choice)
                }
            };
            self.values[i] = value;
            self.choices[i] = choice;
        }
        self.values[program.result as usize]
    }

    /// The program specialised to the box [lo, hi].
    pub fn specialise(&mut self, program: &SsaTape, lo: Vec3, hi: Vec3) -> Specialised {
        let value = self.evaluate(program, lo, hi);
        let verdict = if value.lo > 0.0 {
            Verdict::Empty
        } else if value.hi < 0.0 {
            Verdict::Full
        } else {
            Verdict::Surface
        };
        // Liveness through the choices only.
        let n = program.ops.len();
        self.live.clear();
        self.live.resize(n, false);
        self.live[program.result as usize] = true;
        if let Some(m) = program.material {
            self.live[m as usize] = true;
        }
        for i in (0..n).rev() {
            if !self.live[i] {
                continue;
            }
            let op = &program.ops[i];
            match self.choices[i] {
                Choice::A | Choice::NegA => self.live[op.a as usize] = true,
                Choice::B => self.live[op.b as usize] = true,
                Choice::Imm | Choice::Const(_) => {}
                Choice::Both => {
                    op.for_each_value_operand(|v| self.live[v as usize] = true);
                    if op.op == Op::MatMix {
                        self.live[op.a as usize] = true;
                        self.live[op.b as usize] = true;
                    }
                }
            }
        }
        // Rebuild the live operations through the folding builder.
        let mut b = Builder::without_sharing(n);
        self.map.clear();
        self.map.resize(n, 0);
        for i in 0..n {
            if !self.live[i] {
                continue;
            }
            let op = &program.ops[i];
            let map = &self.map;
            let m = |v: u32| map[v as usize];
            let out = match self.choices[i] {
                Choice::A => m(op.a),
                Choice::B => m(op.b),
                Choice::Imm => b.konst(op.imm()).0,
                Choice::NegA => b.unary(Op::Neg, V(m(op.a))).0,
                Choice::Const(bits) => b.konst(f32::from_bits(bits)).0,
                Choice::Both => {
                    // x·0 = 0 exactly where x is finite (the zero's sign aside): a weight that
                    // folded to 0 drops the branch it multiplies.
                    let zero_product = match op.op.shape() {
                        Shape::Binary if op.op == Op::Mul => {
                            let (ka, kb) = (b.constant(V(m(op.a))), b.constant(V(m(op.b))));
                            (ka == Some(0.0) && self.values[op.b as usize].is_finite())
                                || (kb == Some(0.0) && self.values[op.a as usize].is_finite())
                        }
                        Shape::WithImm if op.op == Op::MulImm => {
                            op.imm() == 0.0 && self.values[op.a as usize].is_finite()
                        }
                        _ => false,
                    };
                    if zero_product {
                        b.konst(0.0).0
                    } else {
                        b.rebuild(op, m)
                    }
                }
            };
            self.map[i] = out;
        }
        let result = V(self.map[program.result as usize]);
        let material = program.material.map(|m| M(self.map[m as usize]));
        let program = b.finish(result, material);
        // Folding may leave an operation unused (an identity made it redundant); the
        // operations are not renumbered (the next specialisation and the register allocator
        // skip dead ones), only counted.
        let len = program.live_into(false, &mut self.live);
        Specialised {
            len,
            program,
            value,
            verdict,
        }
    }

    /// Enclosures of ∂f/∂x, ∂f/∂y and ∂f/∂z over the box (forward-mode differentiation on
    /// intervals), or `None` where the field may jump there as far as intervals can tell.
    pub fn gradient(&mut self, program: &SsaTape, lo: Vec3, hi: Vec3) -> Option<[Interval; 3]> {
        let mut slopes = vec![Slope::constant(0.0); program.ops.len()];
        let mut out = [Interval::point(0.0); 3];
        for (axis, o) in out.iter_mut().enumerate() {
            for (i, op) in program.ops.iter().enumerate() {
                slopes[i] = match op.op {
                    Op::Input => {
                        let k = op.imm as usize;
                        Slope {
                            v: Interval::point(lo[k]).hull(Interval::point(hi[k])),
                            d: Interval::point(if k == axis { 1.0 } else { 0.0 }),
                        }
                    }
                    Op::MatLoad | Op::MatMix => Slope::constant(0.0),
                    _ => {
                        let s = |k: u32| slopes[k as usize];
                        apply_domain(op.op, s(op.a), s(op.b), s(op.c), op.imm())
                    }
                };
            }
            let d = slopes[program.result as usize].d;
            if !d.is_finite() {
                return None;
            }
            *o = d;
        }
        Some(out)
    }

    /// An upper bound on |∇f| over the box (∞ where the field may jump there), from
    /// [`Self::gradient`].
    pub fn lipschitz(&mut self, program: &SsaTape, lo: Vec3, hi: Vec3) -> f32 {
        let Some(g) = self.gradient(program, lo, hi) else {
            return f32::INFINITY;
        };
        let sum: f32 = g
            .iter()
            .map(|d| {
                let m = d.lo.abs().max(d.hi.abs());
                m * m
            })
            .sum();
        // rounded up: the bound may only grow
        let l = sum.sqrt();
        l + l * 4.0 * f32::EPSILON
    }
}

/// Which operand an operation returns at every point whose operands lie in `a`, `b`, `c`.
fn decide(op: Op, a: Interval, b: Interval, c: Interval, imm: f32) -> Choice {
    // The point interpreter computes min as (a < b || b is NaN) ? a : b and max alike; an
    // enclosure that may hold a NaN is the whole line, which decides nothing.
    match op {
        Op::Min if a.hi < b.lo => Choice::A,
        Op::Min if b.hi < a.lo => Choice::B,
        Op::Max if a.lo > b.hi => Choice::A,
        Op::Max if b.lo > a.hi => Choice::B,
        Op::MinImm if a.hi < imm => Choice::A,
        Op::MinImm if imm < a.lo => Choice::Imm,
        Op::MaxImm if a.lo > imm => Choice::A,
        Op::MaxImm if imm > a.hi => Choice::Imm,
        Op::Select if c.lo > 0.0 => Choice::A,
        Op::Select if c.hi <= 0.0 => Choice::B,
        Op::Abs if a.lo >= 0.0 => Choice::A,
        Op::Abs if a.hi <= 0.0 => Choice::NegA,
        Op::Floor if a.is_finite() && a.lo.floor() == a.hi.floor() => {
            Choice::Const(a.lo.floor().to_bits())
        }
        _ => Choice::Both,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use crate::sdf::conformance::parse_node;
    use crate::sdf::lower;

    fn program(src: &str) -> SsaTape {
        lower(&parse_node(src), &|_| Some(0), 0).unwrap().program
    }

    #[test]
    fn a_union_keeps_the_near_shape_only() {
        let p = program(
            "Union([Sphere(radius: 0.5), Transform(translate: (3, 0, 0), shape: Sphere(radius: 0.5)),
                    Transform(translate: (6, 0, 0), shape: Sphere(radius: 0.5))])",
        );
        let mut s = Simplifier::new();
        let whole = p.compile().unwrap();
        let (lo, hi) = (Vec3::new(2.5, -0.5, -0.5), Vec3::new(3.5, 0.5, 0.5));
        let sp = s.specialise(&p, lo, hi);
        let tape = sp.program.compile().unwrap();
        assert_eq!(sp.verdict, Verdict::Surface);
        assert!(
            tape.len() * 2 < whole.len(),
            "{} of {}",
            tape.len(),
            whole.len()
        );
        let mut rng = Rng::new(1);
        for _ in 0..1000 {
            let q = rng.in_box(lo, hi);
            assert_eq!(tape.eval(q).to_bits(), whole.eval(q).to_bits(), "{q}");
        }
        // far from every sphere: empty; inside one: full
        let e = s.specialise(&p, Vec3::new(1.0, 2.0, 2.0), Vec3::new(2.0, 3.0, 3.0));
        assert_eq!(e.verdict, Verdict::Empty);
        let f = s.specialise(&p, Vec3::splat(-0.1), Vec3::splat(0.1));
        assert_eq!(f.verdict, Verdict::Full);
    }

    #[test]
    fn a_decided_smooth_union_collapses_to_one_child() {
        let p = program(
            "SmoothUnion(k: 0.2, shapes: [Sphere(radius: 0.5),
                Transform(translate: (3, 0, 0), shape: Box(half_extents: (0.5, 0.5, 0.5)))])",
        );
        let whole = p.compile().unwrap();
        let mut s = Simplifier::new();
        let (lo, hi) = (Vec3::new(2.4, -0.6, -0.6), Vec3::new(3.6, 0.6, 0.6));
        let sp = s.specialise(&p, lo, hi);
        let box_alone =
            program("Transform(translate: (3, 0, 0), shape: Box(half_extents: (0.5, 0.5, 0.5)))");
        assert_eq!(sp.program.live_len(), box_alone.live_len());
        let tape = sp.program.compile().unwrap();
        let mut rng = Rng::new(2);
        for _ in 0..1000 {
            let q = rng.in_box(lo, hi);
            let (a, b) = (tape.eval(q), whole.eval(q));
            assert!(a == b, "{q}: {a} vs {b}");
        }
    }

    #[test]
    fn lipschitz_bounds_the_gradient_and_is_tight_for_a_sphere() {
        let p = program("Sphere(radius: 1)");
        let mut s = Simplifier::new();
        let l = s.lipschitz(&p, Vec3::new(2.0, 2.0, 2.0), Vec3::new(2.1, 2.1, 2.1));
        assert!((1.0..1.1).contains(&l), "{l}");
        let g = program(
            "Implicit(expr: \"sin(3*x)*cos(3*y) + sin(3*y)*cos(3*z) + sin(3*z)*cos(3*x)\",
                      lipschitz: 7.35, half_extents: (1, 1, 1))",
        );
        // a small box inside: |∇(f/7.35)| well below 1
        let l = s.lipschitz(&g, Vec3::new(0.1, 0.2, 0.3), Vec3::new(0.12, 0.22, 0.32));
        assert!(l < 0.9, "{l}");
        let tape = g.compile().unwrap();
        for q in [Vec3::new(0.1, 0.2, 0.3), Vec3::new(0.11, 0.21, 0.31)] {
            assert!(tape.gradient(q, 1e-3).length() <= l + 1e-3);
        }
    }
}
