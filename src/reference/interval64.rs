//! Certified f64 interval evaluation of a tape: outward-rounded enclosures of every [`Op`], the
//! referee's own arithmetic (independent of the tracer's f32 evaluators and of
//! [`crate::sdf::interval`]), with min/max/select pruning for sub-boxes.
//!
//! An enclosure `[lo, hi]` of an operation on intervals contains the exact real result of the
//! operation for every choice of real operands in the operand intervals (the inclusion
//! property of interval arithmetic, Moore 1966; Mitchell 1990, "Robust ray intersection with
//! interval arithmetic", §2). Rounding is made outward by stepping each bound one ulp away
//! after the round-to-nearest operation: +, −, ×, ÷ and √ are correctly rounded in IEEE 754,
//! so the exact result lies within half an ulp of the computed one. The library's `exp`, `ln`,
//! `sin`, `cos`, `tan` and `powf` are not correctly rounded; glibc states errors of at most a
//! few ulps for them, and we widen their results by [`LIBM_REL_ERROR`] (16 ulps) relative to
//! the result, plus the smallest normal number, on top of the monotonic and periodic range
//! reasoning that picks which argument bounds matter.
//!
//! The tape's immediates are `f32` and convert to `f64` exactly, so the function enclosed is
//! the real-valued function the tape denotes, which the tracer approximates in f32. Where that
//! function is undefined (√ or ln of a negative, a division by an interval holding 0) the
//! enclosure is the whole line, so no claim rests on a value the tape does not define.

use crate::sdf::interval::{Domain, apply_domain};
use crate::sdf::tape::{Op, Shape, Tape};

/// Relative error allowed for the library's transcendental functions: 16 ulps of f64
/// (2⁻⁴⁸), several times the few ulps glibc documents for `exp`, `log`, `sin`, `cos`, `tan`
/// and `pow`.
pub const LIBM_REL_ERROR: f64 = 3.552_713_678_800_501e-15;

/// A closed interval of reals, `lo ≤ hi`, bounds possibly infinite; never NaN.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    /// Lower bound.
    pub lo: f64,
    /// Upper bound.
    pub hi: f64,
}

/// The next f64 towards −∞ (−∞ and NaN stay): `f64::next_down`, written out for the crate's
/// minimum Rust version.
pub fn down(x: f64) -> f64 {
    if x.is_nan() || x == f64::NEG_INFINITY {
        return x;
    }
    if x == 0.0 {
        return -f64::from_bits(1);
    }
    let b = x.to_bits();
    f64::from_bits(if x > 0.0 { b - 1 } else { b + 1 })
}

/// The next f64 towards +∞ (+∞ and NaN stay).
pub fn up(x: f64) -> f64 {
    -down(-x)
}

/// `v` widened down by the library error bound.
fn lib_down(v: f64) -> f64 {
    down(v - v.abs() * LIBM_REL_ERROR - f64::MIN_POSITIVE)
}

/// `v` widened up by the library error bound.
fn lib_up(v: f64) -> f64 {
    up(v + v.abs() * LIBM_REL_ERROR + f64::MIN_POSITIVE)
}

// The names are the tape's operations' (and `Domain`'s, which these implement for the
// evaluator); `std::ops` would hide the outward rounding behind `+`.
#[allow(clippy::should_implement_trait)]
impl Interval {
    /// The whole real line (what an undefined or unbounded result encloses to).
    pub const ENTIRE: Interval = Interval {
        lo: f64::NEG_INFINITY,
        hi: f64::INFINITY,
    };

    /// `[lo, hi]`; NaN bounds or `lo > hi` give [`Self::ENTIRE`].
    pub fn new(lo: f64, hi: f64) -> Interval {
        if lo <= hi {
            Interval { lo, hi }
        } else {
            Interval::ENTIRE
        }
    }

    /// The degenerate interval `[x, x]` (ENTIRE for NaN).
    pub fn point(x: f64) -> Interval {
        Interval::new(x, x)
    }

    /// Whether `x` lies in the interval.
    pub fn contains(self, x: f64) -> bool {
        self.lo <= x && x <= self.hi
    }

    /// The smallest interval holding both.
    pub fn hull(self, o: Interval) -> Interval {
        Interval::new(self.lo.min(o.lo), self.hi.max(o.hi))
    }

    /// A 2π-periodic function with a maximum 1 at `peak` + 2kπ and minimum −1 at `peak` + π
    /// + 2kπ, monotonic between.
    fn periodic(self, f: fn(f64) -> f64, peak: f64) -> Interval {
        use std::f64::consts::{PI, TAU};
        if !(self.lo.is_finite() && self.hi.is_finite()) || self.hi - self.lo >= TAU {
            return Interval::new(-1.0, 1.0);
        }
        // Beyond 2⁴⁰ the reduction of the argument by a rounded 2π is no longer trusted.
        if self.lo.abs().max(self.hi.abs()) > 1.0e12 {
            return Interval::new(-1.0, 1.0);
        }
        // A margin far above the rounding of k·2π for |a| ≤ 10¹².
        let margin = 1e-3;
        // Is an extremum point centre + 2kπ within the interval (grown by the margin)? The
        // first one at or after lo is the k or k + 1 below, up to rounding.
        let has = |centre: f64| {
            let k = ((self.lo - centre) / TAU).floor();
            (-1..=2).any(|j| {
                let x = centre + (k + j as f64) * TAU;
                x >= self.lo - margin && x <= self.hi + margin
            })
        };
        let (a, b) = (f(self.lo), f(self.hi));
        let mut lo = lib_down(a.min(b));
        let mut hi = lib_up(a.max(b));
        if has(peak) {
            hi = 1.0;
        }
        if has(peak + PI) {
            lo = -1.0;
        }
        Interval::new(lo.max(-1.0), hi.min(1.0))
    }
}

/// Which operand of a min, max or select is decided over a box (for pruning).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Choice {
    /// Either may be the result.
    Both,
    /// The first operand is the result everywhere in the box.
    First,
    /// The second operand (or the immediate) is the result everywhere in the box.
    Second,
}

/// One instruction of a [`Program`]: the tape's, decoded.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Ins {
    op: Op,
    out: u8,
    a: u8,
    b: u8,
    /// The third register (`Select`, `Hypot3`).
    c: u8,
    imm: f32,
    /// For a fused smooth minimum ([`fuse_smooth_min`], `op` is then `Min`): the blend
    /// radius k; 0 for a plain instruction.
    smooth: f32,
}

/// A tape's value instructions, for interval evaluation over boxes, shrinkable to a box
/// ([`Program::prune`]): the min/max/select branches that cannot matter inside a box are cut,
/// and so is everything only they read (after Duff 1992, "Interval arithmetic and recursive
/// subdivision for implicit functions and constructive solid geometry"; fidget's and
/// libfive's tape simplification do the same).
#[derive(Debug, Clone, PartialEq)]
pub struct Program {
    ins: Vec<Ins>,
    result: u8,
}

/// Scratch registers for [`Program::eval`].
pub type Registers = [Interval; crate::sdf::tape::MAX_REGISTERS];

/// Fresh scratch registers.
pub fn registers() -> Box<Registers> {
    Box::new([Interval::ENTIRE; crate::sdf::tape::MAX_REGISTERS])
}

impl Program {
    /// The value instructions of `tape` (material operations dropped: they write material
    /// registers only).
    pub fn new(tape: &Tape) -> Program {
        let ins = tape
            .instrs()
            .iter()
            .filter(|i| !i.op().is_material())
            .map(|i| Ins {
                op: i.op(),
                out: i.out(),
                a: i.a(),
                b: i.b(),
                c: i.imm_bits() as u8,
                imm: i.imm(),
                smooth: 0.0,
            })
            .collect();
        Program {
            ins: fuse_smooth_min(ins, tape.result()),
            result: tape.result(),
        }
    }

    /// Number of instructions.
    pub fn len(&self) -> usize {
        self.ins.len()
    }

    /// Whether the result is an input register.
    pub fn is_empty(&self) -> bool {
        self.ins.is_empty()
    }

    /// An enclosure of the tape's value over the box `x × y × z`.
    pub fn eval(&self, x: Interval, y: Interval, z: Interval, r: &mut Registers) -> Interval {
        self.eval_choosing(x, y, z, r, |_, _| {})
    }

    /// [`Self::eval`], telling `choose` the decided operand of each min, max and select.
    fn eval_choosing(
        &self,
        x: Interval,
        y: Interval,
        z: Interval,
        r: &mut Registers,
        mut choose: impl FnMut(usize, Choice),
    ) -> Interval {
        r[0] = x;
        r[1] = y;
        r[2] = z;
        for (k, i) in self.ins.iter().enumerate() {
            let a = r[i.a as usize];
            let b = r[i.b as usize];
            let c = r[i.c as usize];
            let imm = Interval::point(i.imm as f64);
            let pick = |first_wins: bool, second_wins: bool| {
                if first_wins {
                    Choice::First
                } else if second_wins {
                    Choice::Second
                } else {
                    Choice::Both
                }
            };
            let v = match i.op {
                Op::Min if i.smooth > 0.0 => {
                    // decided where |x − y| ≥ k: h is 0 (x) or 1 (y) there
                    let diff = a.sub(b);
                    let radius = i.smooth as f64;
                    choose(k, pick(diff.hi <= -radius, diff.lo >= radius));
                    smooth_min(a, b, i.smooth, i.imm)
                }
                Op::Min | Op::MinImm => {
                    let b = if i.op == Op::Min { b } else { imm };
                    choose(k, pick(a.hi < b.lo, b.hi < a.lo));
                    a.min(b)
                }
                Op::Max | Op::MaxImm => {
                    let b = if i.op == Op::Max { b } else { imm };
                    choose(k, pick(a.lo > b.hi, b.lo > a.hi));
                    a.max(b)
                }
                Op::Select => {
                    // c > 0 picks a; c ≤ 0 (or NaN, which the enclosure excludes) picks b
                    let ch = pick(c.lo > 0.0, c.hi <= 0.0);
                    choose(k, ch);
                    match ch {
                        Choice::First => a,
                        Choice::Second => b,
                        Choice::Both => a.hull(b),
                    }
                }
                op => apply(op, a, b, c, i.imm),
            };
            r[i.out as usize] = v;
        }
        r[self.result as usize]
    }

    /// The enclosure over the box, and the program cut down to what can matter inside it: a
    /// min, max or select whose operand is decided becomes a copy of it, and instructions
    /// nothing live reads are dropped (backward liveness over the registers).
    pub fn prune(
        &self,
        x: Interval,
        y: Interval,
        z: Interval,
        r: &mut Registers,
    ) -> (Interval, Option<Program>) {
        let mut choices: Vec<(usize, Choice)> = Vec::new();
        let v = self.eval_choosing(x, y, z, r, |k, c| {
            if c != Choice::Both {
                choices.push((k, c));
            }
        });
        if choices.is_empty() {
            return (v, None);
        }
        let mut ins = self.ins.clone();
        for (k, c) in choices {
            let i = &mut ins[k];
            match (i.op, c) {
                (Op::Select, Choice::Second) | (Op::Min | Op::Max, Choice::Second) => {
                    i.a = i.b;
                    i.op = Op::Copy;
                }
                (Op::MinImm | Op::MaxImm, Choice::Second) => i.op = Op::Const,
                _ => i.op = Op::Copy,
            }
        }
        fold_decided(&mut ins);
        let mut live = [false; crate::sdf::tape::MAX_REGISTERS];
        live[self.result as usize] = true;
        let mut keep = vec![false; ins.len()];
        for (k, i) in ins.iter().enumerate().rev() {
            if !live[i.out as usize] {
                continue;
            }
            keep[k] = true;
            live[i.out as usize] = false;
            match i.op.shape() {
                Shape::Nullary => {}
                Shape::Unary | Shape::WithImm => live[i.a as usize] = true,
                Shape::Binary => {
                    live[i.a as usize] = true;
                    live[i.b as usize] = true;
                }
                Shape::Ternary => {
                    live[i.a as usize] = true;
                    live[i.b as usize] = true;
                    live[i.c as usize] = true;
                }
                Shape::MatLoad | Shape::MatMix => {}
            }
        }
        let ins = ins
            .into_iter()
            .zip(keep)
            .filter_map(|(i, k)| k.then_some(i))
            .collect();
        (
            v,
            Some(Program {
                ins,
                result: self.result,
            }),
        )
    }
}

/// Quilez's polynomial smooth minimum as the tape computes it (`crate::sdf::lower::shapes::
/// smooth_min`): h = clamp(½ + c·(x − y), 0, 1), f = x(1 − h) + y·h − k·h(1 − h), with c the
/// tape's f32 value of 1/(2k).
fn smooth_min_point(x: Interval, y: Interval, k: f32, c: f32) -> Interval {
    let h = x
        .sub(y)
        .mul(Interval::point(c as f64))
        .add(Interval::point(0.5))
        .max(Interval::point(0.0))
        .min(Interval::point(1.0));
    let om = Interval::point(1.0).sub(h);
    x.mul(om)
        .add(y.mul(h))
        .sub(h.mul(Interval::point(k as f64)).mul(om))
}

/// The enclosure of the smooth minimum over the box x × y. Evaluated op by op, x(1 − h) + y·h
/// loses the cancellation between its terms (the dependency problem: far from the surface,
/// where |x| is large and h undecided, the enclosure grows by |x|·width(h) per blend, and a
/// chain of 60 blends encloses everything). But f is nondecreasing in x and in y: with
/// c = 1/(2k), ∂f/∂x = 1 − h and ∂f/∂y = h, so its range over a box is [f(x.lo, y.lo),
/// f(x.hi, y.hi)], each end evaluated on point intervals. The tape's c is 1/(2k) rounded to
/// f32: with s = 1 − 2kc, ∂f/∂x = 1 − h + (½ − h)·s (and ∂f/∂y likewise) dips below 0 by at most
/// |s|/2, over a stretch of x − y at most |s|/(2c) long, so each end moves by at most
/// s²/(4c); we widen by 2·s²/c.
fn smooth_min(x: Interval, y: Interval, k: f32, c: f32) -> Interval {
    let s = 1.0 - 2.0 * k as f64 * c as f64;
    let eta = up(2.0 * s * s / (c as f64).abs()) + f64::MIN_POSITIVE;
    let lo = smooth_min_point(Interval::point(x.lo), Interval::point(y.lo), k, c).lo;
    let hi = smooth_min_point(Interval::point(x.hi), Interval::point(y.hi), k, c).hi;
    Interval::new(down(lo - eta), up(hi + eta))
}

/// Replaces each smooth minimum of the tape — the twelve instructions
/// `crate::sdf::lower::shapes::smooth_min` emits, matched by their data flow, with their
/// scratch registers dead afterwards — by one fused instruction that [`smooth_min`] encloses
/// tightly. Anything that does not match exactly is left as it is.
fn fuse_smooth_min(ins: Vec<Ins>, result: u8) -> Vec<Ins> {
    let mut out = Vec::with_capacity(ins.len());
    let mut j = 0;
    while j < ins.len() {
        if let Some(fused) = match_smooth_min(&ins, j, result) {
            out.push(fused);
            j += SMOOTH_MIN_LEN;
        } else {
            out.push(ins[j]);
            j += 1;
        }
    }
    out
}

/// Instructions of one smooth minimum.
const SMOOTH_MIN_LEN: usize = 12;

/// The registers an instruction reads.
fn reads(i: &Ins) -> arrayvec::ArrayVec<u8, 3> {
    let mut r = arrayvec::ArrayVec::new();
    match i.op.shape() {
        Shape::Unary | Shape::WithImm => r.push(i.a),
        Shape::Binary => r.extend([i.a, i.b]),
        Shape::Ternary => r.extend([i.a, i.b, i.c]),
        Shape::Nullary | Shape::MatLoad | Shape::MatMix => {}
    }
    r
}

/// The fused smooth minimum starting at `ins[j]`, if the twelve instructions there are one.
fn match_smooth_min(ins: &[Ins], j: usize, result: u8) -> Option<Ins> {
    let block = ins.get(j..j + SMOOTH_MIN_LEN)?;
    // Symbolic values of the registers: what the block has computed in each.
    #[derive(Clone, Copy, PartialEq)]
    enum V {
        X,
        Y,
        D,
        T1,
        T2,
        T3,
        H,
        Om,
        Xs,
        Ys,
        Mix,
        Kh,
        Bump,
        Out,
    }
    let mut sym = [None::<V>; crate::sdf::tape::MAX_REGISTERS];
    let (x, y) = (block[0].a, block[0].b);
    if x == y || block[0].op != Op::Sub {
        return None;
    }
    sym[x as usize] = Some(V::X);
    sym[y as usize] = Some(V::Y);
    let s = |sym: &[Option<V>], r: u8| sym[r as usize];
    let pair = |sym: &[Option<V>], i: &Ins, p: V, q: V| {
        (s(sym, i.a) == Some(p) && s(sym, i.b) == Some(q))
            || (s(sym, i.a) == Some(q) && s(sym, i.b) == Some(p))
    };
    let c = block[1].imm;
    let k = block[9].imm;
    let mut clamp_seen = (false, false);
    for (n, i) in block.iter().enumerate() {
        let a = s(&sym, i.a);
        let v = match (n, i.op) {
            (0, Op::Sub) if a == Some(V::X) && s(&sym, i.b) == Some(V::Y) => V::D,
            (1, Op::MulImm) if a == Some(V::D) => V::T1,
            (2, Op::AddImm) if a == Some(V::T1) && i.imm == 0.5 => V::T2,
            (3, Op::MaxImm) if a == Some(V::T2) && i.imm == 0.0 => {
                clamp_seen.0 = true;
                V::T3
            }
            (3, Op::MinImm) if a == Some(V::T2) && i.imm == 1.0 => {
                clamp_seen.1 = true;
                V::T3
            }
            (4, Op::MinImm) if a == Some(V::T3) && i.imm == 1.0 && clamp_seen.0 => V::H,
            (4, Op::MaxImm) if a == Some(V::T3) && i.imm == 0.0 && clamp_seen.1 => V::H,
            (5, Op::RsubImm) if a == Some(V::H) && i.imm == 1.0 => V::Om,
            (6, Op::Mul) if pair(&sym, i, V::X, V::Om) => V::Xs,
            (7, Op::Mul) if pair(&sym, i, V::Y, V::H) => V::Ys,
            (8, Op::Add) if pair(&sym, i, V::Xs, V::Ys) => V::Mix,
            (9, Op::MulImm) if a == Some(V::H) => V::Kh,
            (10, Op::Mul) if pair(&sym, i, V::Kh, V::Om) => V::Bump,
            (11, Op::Sub) if a == Some(V::Mix) && s(&sym, i.b) == Some(V::Bump) => V::Out,
            _ => return None,
        };
        sym[i.out as usize] = Some(v);
    }
    // k > 0 and c = 1/(2k) up to f32 rounding, as the lowering writes them.
    if !(k > 0.0 && ((2.0 * k as f64 * c as f64) - 1.0).abs() < 1e-6) {
        return None;
    }
    let out = block[11].out;
    // Every other register the block wrote must be dead after it: the fused instruction
    // writes only `out`.
    let written: Vec<u8> = block[..11]
        .iter()
        .map(|i| i.out)
        .filter(|&r| r != out)
        .collect();
    for &r in &written {
        if r == result {
            return None;
        }
        for later in &ins[j + SMOOTH_MIN_LEN..] {
            if reads(later).contains(&r) {
                return None;
            }
            if later.out == r {
                break;
            }
        }
    }
    Some(Ins {
        op: Op::Min,
        out,
        a: x,
        b: y,
        c: 0,
        imm: c,
        smooth: k,
    })
}

/// Folds what the decided branches leave constant: a smooth minimum whose blend factor h is
/// decided to 0 computes x·(1 − 0) + y·0 − k·0·1, and only once y·0 is known to be 0 does y
/// stop being read (Quilez's polynomial form is written so that these products are exact).
/// Only exact rewrites are made — x·0 = 0, x·1 = x, x ± 0 = x, and a constant difference that
/// f64 and the f32 immediate hold exactly — so the enclosures stay certified.
fn fold_decided(ins: &mut [Ins]) {
    let mut known = [None::<f64>; crate::sdf::tape::MAX_REGISTERS];
    for i in ins.iter_mut() {
        let (ka, kb) = (known[i.a as usize], known[i.b as usize]);
        let imm = i.imm as f64;
        let set = |i: &mut Ins, op: Op, a: u8, value: f32| {
            i.op = op;
            i.a = a;
            i.imm = value;
        };
        match i.op {
            Op::Mul if ka == Some(0.0) || kb == Some(0.0) => set(i, Op::Const, i.a, 0.0),
            Op::Mul if ka == Some(1.0) => set(i, Op::Copy, i.b, 0.0),
            Op::Mul if kb == Some(1.0) => set(i, Op::Copy, i.a, 0.0),
            Op::MulImm if ka == Some(0.0) || imm == 0.0 => set(i, Op::Const, i.a, 0.0),
            Op::MulImm if imm == 1.0 => set(i, Op::Copy, i.a, 0.0),
            Op::Add if ka == Some(0.0) => set(i, Op::Copy, i.b, 0.0),
            Op::Add | Op::Sub if kb == Some(0.0) => set(i, Op::Copy, i.a, 0.0),
            Op::AddImm | Op::SubImm if imm == 0.0 => set(i, Op::Copy, i.a, 0.0),
            Op::RsubImm => {
                if let Some(c) = ka {
                    let r = imm - c;
                    // exact in f64 (Knuth's two-sum error is 0) and as an f32 immediate
                    let (bb, aa) = (r - imm, r - (r - imm));
                    if (imm - aa) + (-c - bb) == 0.0 && (r as f32) as f64 == r {
                        set(i, Op::Const, i.a, r as f32);
                    }
                }
            }
            _ => {}
        }
        known[i.out as usize] = match i.op {
            Op::Const => Some(i.imm as f64),
            Op::Copy => known[i.a as usize],
            _ => None,
        };
    }
}

/// The enclosure of one value operation over interval operands: `c` is the third register of
/// `Select` and `Hypot3`, `imm` the immediate. The dispatch from [`Op`] to an operation is the
/// interval evaluators' one ([`apply_domain`]); the arithmetic is this module's.
pub fn apply(op: Op, a: Interval, b: Interval, c: Interval, imm: f32) -> Interval {
    apply_domain(op, a, b, c, imm)
}

/// The tape's operations on f64 intervals, each rounded outward (for [`apply_domain`], and
/// called directly by the search with [`Domain`] in scope).
impl Domain for Interval {
    fn constant(x: f32) -> Self {
        Interval::point(x as f64)
    }
    /// a + b, rounded outward.
    fn add(self, b: Interval) -> Interval {
        Interval::new(down(self.lo + b.lo), up(self.hi + b.hi))
    }
    /// a − b, rounded outward.
    fn sub(self, b: Interval) -> Interval {
        Interval::new(down(self.lo - b.hi), up(self.hi - b.lo))
    }
    /// a · b, rounded outward (0 · ∞ counts as 0, as in IEEE 1788: a bound that is infinite
    /// stands for arbitrarily large finite values).
    fn mul(self, b: Interval) -> Interval {
        let p = |x: f64, y: f64| {
            let v = x * y;
            if v.is_nan() { 0.0 } else { v }
        };
        let c = [
            p(self.lo, b.lo),
            p(self.lo, b.hi),
            p(self.hi, b.lo),
            p(self.hi, b.hi),
        ];
        let lo = c.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = c.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Interval::new(down(lo), up(hi))
    }
    fn scale(self, k: f32) -> Self {
        Interval::mul(self, Interval::point(k as f64))
    }
    /// a², rounded outward (tighter than a · a when a holds 0).
    fn sqr(self) -> Interval {
        let m = self.abs();
        Interval::new(down(m.lo * m.lo).max(0.0), up(m.hi * m.hi))
    }
    /// a / b, rounded outward; the whole line when b holds 0.
    fn div(self, b: Interval) -> Interval {
        if b.contains(0.0) {
            return Interval::ENTIRE;
        }
        let c = [
            self.lo / b.lo,
            self.lo / b.hi,
            self.hi / b.lo,
            self.hi / b.hi,
        ];
        if c.iter().any(|v| v.is_nan()) {
            return Interval::ENTIRE;
        }
        let lo = c.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = c.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Interval::new(down(lo), up(hi))
    }
    /// min(a, b) (exact).
    fn min(self, b: Interval) -> Interval {
        Interval::new(self.lo.min(b.lo), self.hi.min(b.hi))
    }
    /// max(a, b) (exact).
    fn max(self, b: Interval) -> Interval {
        Interval::new(self.lo.max(b.lo), self.hi.max(b.hi))
    }
    /// aᵇ for a ≥ 0 (the tape's `Pow`): monotonic in a for each fixed b and in b for each
    /// fixed a, so its extremes over the box are at the corners. Over the part of a where it
    /// is defined (a ≥ 0, as for [`Self::sqrt`]), the whole line if none.
    fn pow(self, b: Interval) -> Interval {
        if self.hi < 0.0 {
            return Interval::ENTIRE;
        }
        let a0 = self.lo.max(0.0);
        let c = [
            a0.powf(b.lo),
            a0.powf(b.hi),
            self.hi.powf(b.lo),
            self.hi.powf(b.hi),
        ];
        if c.iter().any(|v| v.is_nan()) {
            return Interval::ENTIRE;
        }
        let lo = c.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = c.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Interval::new(lib_down(lo).max(0.0), lib_up(hi))
    }
    /// −a (exact).
    fn neg(self) -> Interval {
        Interval::new(-self.hi, -self.lo)
    }
    /// |a| (exact).
    fn abs(self) -> Interval {
        if self.lo >= 0.0 {
            self
        } else if self.hi <= 0.0 {
            self.neg()
        } else {
            Interval::new(0.0, (-self.lo).max(self.hi))
        }
    }
    /// √a, rounded outward, over the part of a where it is defined; the whole line if none.
    fn sqrt(self) -> Interval {
        if self.hi < 0.0 {
            return Interval::ENTIRE;
        }
        // Where part of the box lies below 0, √ is undefined there (NaN in the tracer's f32):
        // the enclosure covers the points where it is defined (a lower bound below 0 is often
        // only the overestimate of an argument that is ≥ 0, a sum of squares say).
        Interval::new(down(self.lo.max(0.0).sqrt()).max(0.0), up(self.hi.sqrt()))
    }
    /// sin a: the values at the ends, and ±1 where a peak or trough of sin may lie inside
    /// (found with a margin, so a rounding of the period can only add a bound, never lose
    /// one).
    fn sin(self) -> Interval {
        self.periodic(f64::sin, std::f64::consts::FRAC_PI_2)
    }
    /// cos a: as [`Self::sin`], with the peaks at 2kπ.
    fn cos(self) -> Interval {
        self.periodic(f64::cos, 0.0)
    }
    /// tan a: increasing between its poles π/2 + kπ; the whole line where a pole may lie
    /// inside (found with a margin, as for [`Self::sin`]).
    fn tan(self) -> Interval {
        use std::f64::consts::{FRAC_PI_2, PI};
        if !(self.lo.is_finite() && self.hi.is_finite())
            || self.hi - self.lo >= PI
            || self.lo.abs().max(self.hi.abs()) > 1.0e12
        {
            return Interval::ENTIRE;
        }
        let margin = 1e-9 * (1.0 + self.lo.abs().max(self.hi.abs()));
        let k = ((self.lo - FRAC_PI_2) / PI).floor();
        let pole = (0..3).any(|j| {
            let x = FRAC_PI_2 + (k + j as f64) * PI;
            x >= self.lo - margin && x <= self.hi + margin
        });
        if pole {
            return Interval::ENTIRE;
        }
        Interval::new(lib_down(self.lo.tan()), lib_up(self.hi.tan()))
    }
    /// eᵃ: increasing, widened by the library's error.
    fn exp(self) -> Interval {
        Interval::new(lib_down(self.lo.exp()).max(0.0), lib_up(self.hi.exp()))
    }
    /// ln a: increasing on (0, ∞), ln 0 = −∞; over the part of a where it is defined (as for
    /// [`Self::sqrt`]), the whole line if none.
    fn ln(self) -> Interval {
        if self.hi < 0.0 {
            return Interval::ENTIRE;
        }
        let lo = if self.lo <= 0.0 {
            f64::NEG_INFINITY
        } else {
            lib_down(self.lo.ln())
        };
        Interval::new(lo, lib_up(self.hi.ln()))
    }
    /// ⌊a⌋ (exact).
    fn floor(self) -> Interval {
        Interval::new(self.lo.floor(), self.hi.floor())
    }
    fn select(c: Self, a: Self, b: Self) -> Self {
        if c.lo > 0.0 {
            a
        } else if c.hi <= 0.0 {
            b
        } else {
            a.hull(b)
        }
    }
    fn hypot(self, b: Self) -> Self {
        sum_of_squares(&[self, b]).sqrt()
    }
    fn hypot3(self, b: Self, c: Self) -> Self {
        sum_of_squares(&[self, b, c]).sqrt()
    }
}

/// Σ xᵢ², rounded outward and never below 0 (a sum of squares is not negative, whatever the
/// outward rounding of a zero sum says).
fn sum_of_squares(xs: &[Interval]) -> Interval {
    let s = xs.iter().fold(Interval::point(0.0), |s, x| s.add(x.sqr()));
    Interval::new(s.lo.max(0.0), s.hi)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// A real number as f64 computes it (correctly rounded, or the library's function): what
    /// the enclosures are tested against, through the same dispatch.
    #[derive(Debug, Clone, Copy)]
    struct Exact(f64);

    impl Domain for Exact {
        fn constant(x: f32) -> Self {
            Exact(x as f64)
        }
        fn add(self, o: Self) -> Self {
            Exact(self.0 + o.0)
        }
        fn sub(self, o: Self) -> Self {
            Exact(self.0 - o.0)
        }
        fn mul(self, o: Self) -> Self {
            Exact(self.0 * o.0)
        }
        fn scale(self, k: f32) -> Self {
            Exact(self.0 * k as f64)
        }
        fn sqr(self) -> Self {
            Exact(self.0 * self.0)
        }
        fn div(self, o: Self) -> Self {
            Exact(self.0 / o.0)
        }
        fn min(self, o: Self) -> Self {
            Exact(self.0.min(o.0))
        }
        fn max(self, o: Self) -> Self {
            Exact(self.0.max(o.0))
        }
        fn pow(self, e: Self) -> Self {
            Exact(self.0.powf(e.0))
        }
        fn neg(self) -> Self {
            Exact(-self.0)
        }
        fn abs(self) -> Self {
            Exact(self.0.abs())
        }
        fn sqrt(self) -> Self {
            Exact(self.0.sqrt())
        }
        fn sin(self) -> Self {
            Exact(self.0.sin())
        }
        fn cos(self) -> Self {
            Exact(self.0.cos())
        }
        fn tan(self) -> Self {
            Exact(self.0.tan())
        }
        fn exp(self) -> Self {
            Exact(self.0.exp())
        }
        fn ln(self) -> Self {
            Exact(self.0.ln())
        }
        fn floor(self) -> Self {
            Exact(self.0.floor())
        }
        fn select(c: Self, a: Self, b: Self) -> Self {
            if c.0 > 0.0 { a } else { b }
        }
        fn hypot(self, b: Self) -> Self {
            Exact((self.0 * self.0 + b.0 * b.0).sqrt())
        }
        fn hypot3(self, b: Self, c: Self) -> Self {
            Exact((self.0 * self.0 + b.0 * b.0 + c.0 * c.0).sqrt())
        }
    }

    fn exact(op: Op, a: f64, b: f64, c: f64, imm: f32) -> f64 {
        apply_domain(op, Exact(a), Exact(b), Exact(c), imm).0
    }

    /// A random interval of the kind `op` is defined on: non-negative operands for √, ln and
    /// powers, and a mix of wide and narrow ones, far and near 0.
    fn operand(rng: &mut Rng, op: Op) -> Interval {
        let scale = [0.01, 1.0, 10.0, 300.0][rng.below(4) as usize];
        let mid = (rng.uniform() * 2.0 - 1.0) * scale;
        let half = rng.uniform() * scale * 0.5;
        let (lo, hi) = (mid - half, mid + half);
        match op {
            Op::Sqrt | Op::Ln | Op::Pow | Op::PowImm => {
                Interval::new(lo.abs().min(hi.abs()), hi.abs().max(lo.abs()))
            }
            Op::Exp => Interval::new(lo.clamp(-50.0, 50.0), hi.clamp(-50.0, 50.0)),
            _ => Interval::new(lo, hi),
        }
    }

    /// Every value operation: the exact result at 200 points spread densely over random
    /// operand boxes (both ends included) lies in the enclosure — the inclusion property.
    #[test]
    fn every_op_encloses_dense_samples() {
        let mut rng = Rng::new(11);
        let mut checked = 0usize;
        for &op in Op::ALL {
            if matches!(op, Op::MatLoad | Op::MatMix | Op::Input) {
                continue;
            }
            for _ in 0..300 {
                let a = operand(&mut rng, op);
                let b = match op {
                    // exponents of a modest size (10¹⁰⁰ overflows nothing but the test's f64)
                    Op::Pow => {
                        let o = operand(&mut rng, Op::Add);
                        Interval::new(o.lo.clamp(-3.0, 3.0), o.hi.clamp(-3.0, 3.0))
                    }
                    _ => operand(&mut rng, op),
                };
                let c = operand(&mut rng, op);
                let imm = match op {
                    Op::PowImm => rng.range_f32(-1.0, 3.0),
                    _ => rng.range_f32(-5.0, 5.0),
                };
                let e = apply(op, a, b, c, imm);
                assert!(e.lo <= e.hi, "{op:?}: {e:?}");
                for k in 0..=200 {
                    let s = |iv: Interval, j: usize| {
                        let w = ((k * (j + 1) * 7919) % 201) as f64 / 200.0;
                        (iv.lo + (iv.hi - iv.lo) * w).clamp(iv.lo, iv.hi)
                    };
                    let (x, y, z) = (s(a, 0), s(b, 1), s(c, 2));
                    let v = exact(op, x, y, z, imm);
                    if v.is_nan() {
                        // undefined there (a division by 0 over 0): no claim to check
                        continue;
                    }
                    assert!(
                        e.contains(v),
                        "{op:?}({x}, {y}, {z}; {}) = {v} outside {e:?} (a {a:?}, b {b:?}, c {c:?})",
                        imm
                    );
                    checked += 1;
                }
            }
        }
        assert!(checked > 1_000_000, "{checked}");
    }

    /// sin and cos hit ±1 exactly when a peak or trough lies inside, and stay tight when not.
    #[test]
    fn sin_and_cos_find_their_extremes() {
        use std::f64::consts::{FRAC_PI_2, PI};
        let s = Interval::new(FRAC_PI_2 - 0.1, FRAC_PI_2 + 0.1).sin();
        assert_eq!(s.hi, 1.0);
        assert!(s.lo > 0.99 && s.lo < (FRAC_PI_2 - 0.1).sin());
        let c = Interval::new(PI - 0.1 + 200.0 * PI, PI + 0.1 + 200.0 * PI).cos();
        assert_eq!(c.lo, -1.0);
        let t = Interval::new(0.1, 0.2).sin();
        assert!(
            t.lo <= 0.1f64.sin() && t.hi >= 0.2f64.sin() && t.hi < 0.2,
            "{t:?}"
        );
        assert_eq!(Interval::new(1.0, 2.0).tan(), Interval::ENTIRE);
        assert!(Interval::new(0.0, 1.0).tan().hi < 1.6);
    }

    /// A program pruned to a box near one member of a smooth union of spheres drops the far
    /// members (the decided blends fold away), and over sub-boxes it encloses what the whole
    /// program encloses at every sampled point.
    #[test]
    fn pruning_drops_far_members_and_keeps_the_enclosure() {
        let members: Vec<String> = (0..8)
            .map(|i| {
                format!(
                    "Transform(translate: ({}, 0, 0), shape: Sphere(radius: 0.3))",
                    i
                )
            })
            .collect();
        let src = format!(
            "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40),
                   objects: [(shape: SmoothUnion(k: 0.1, shapes: [{}]))])",
            members.join(", ")
        );
        let scene = crate::scene::Scene::from_source(&src, std::path::Path::new("prune.ron"))
            .unwrap_or_else(|e| panic!("{e}"));
        let whole = Program::new(&scene.objects[0].lowered.distance);
        let mut r = registers();
        let b = |lo: f64, hi: f64| Interval::new(lo, hi);
        let (v, pruned) = whole.prune(b(2.7, 3.3), b(-0.3, 0.3), b(-0.3, 0.3), &mut r);
        let pruned = pruned.expect("decided blends");
        assert!(
            pruned.len() * 3 < whole.len(),
            "{} of {}",
            pruned.len(),
            whole.len()
        );
        let mut rng = Rng::new(3);
        for _ in 0..2000 {
            let p = [2.7, -0.3, -0.3].map(|lo| lo + 0.6 * rng.uniform());
            let pt = |k: usize| Interval::point(p[k]);
            let exact = whole.eval(pt(0), pt(1), pt(2), &mut r);
            let cut = pruned.eval(pt(0), pt(1), pt(2), &mut r);
            assert!(
                v.lo <= exact.lo && exact.hi <= v.hi,
                "{exact:?} outside {v:?}"
            );
            assert!(
                cut.lo <= exact.hi && exact.lo <= cut.hi,
                "at {p:?}: pruned {cut:?}, whole {exact:?}"
            );
        }
    }

    /// The fused smooth minimum encloses the tape's twelve-instruction formula at dense
    /// samples of random boxes, and the fusion happens on a lowered smooth union.
    #[test]
    fn the_fused_smooth_minimum_encloses_its_formula() {
        let mut rng = Rng::new(5);
        for _ in 0..2000 {
            let k = rng.range_f32(0.001, 1.0);
            let c = 0.5 / k;
            let x = operand(&mut rng, Op::Add);
            let y = operand(&mut rng, Op::Add);
            let e = smooth_min(x, y, k, c);
            for n in 0..=50 {
                let w = n as f64 / 50.0;
                let (px, py) = (
                    (x.lo + (x.hi - x.lo) * w).clamp(x.lo, x.hi),
                    (y.lo + (y.hi - y.lo) * (1.0 - w)).clamp(y.lo, y.hi),
                );
                let h = (0.5 + c as f64 * (px - py)).clamp(0.0, 1.0);
                let f = px * (1.0 - h) + py * h - k as f64 * h * (1.0 - h);
                // the f64 formula itself rounds: within a few ulps of the exact value
                let slack = 1e-15 * (px.abs() + py.abs() + k as f64);
                assert!(
                    e.lo - slack <= f && f <= e.hi + slack,
                    "smin({px}, {py}; {k}) = {f} outside {e:?}"
                );
            }
        }
        let src = "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40),
            objects: [(shape: SmoothUnion(k: 0.1, shapes: [Sphere(radius: 0.3),
                Transform(translate: (0.5, 0, 0), shape: Sphere(radius: 0.3))]))])";
        let scene = crate::scene::Scene::from_source(src, std::path::Path::new("smin.ron"))
            .unwrap_or_else(|e| panic!("{e}"));
        let p = Program::new(&scene.objects[0].lowered.distance);
        assert!(p.ins.iter().any(|i| i.smooth > 0.0), "{:?}", p.ins);
    }

    /// Rounding is outward: 0.1 + 0.2 is not an f64, so the enclosure of the sum of the
    /// points has width, and holds the exact decimal sum.
    #[test]
    fn rounding_is_outward() {
        let s = Interval::point(0.1).add(Interval::point(0.2));
        assert!(s.lo < s.hi);
        assert!(s.lo <= 0.3 && s.hi >= 0.30000000000000004);
        assert_eq!(down(0.0), -f64::from_bits(1));
        assert_eq!(up(-f64::from_bits(1)), 0.0);
        assert_eq!(up(1.0), 1.0 + f64::EPSILON);
        assert_eq!(down(f64::NEG_INFINITY), f64::NEG_INFINITY);
        assert_eq!(Interval::new(f64::NAN, 1.0), Interval::ENTIRE);
        assert_eq!(
            Interval::new(0.0, 0.0).mul(Interval::ENTIRE),
            Interval::new(-f64::from_bits(1), f64::from_bits(1))
        );
    }
}
