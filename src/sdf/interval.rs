//! Interval arithmetic over the tape: enclosures of a field and of its slope along a ray.
//!
//! Every [`Op`] is evaluated on intervals, lane by lane, for a sample point known only to lie in
//! an axis-aligned box (Moore, "Interval Analysis", 1966; the inclusion property of natural
//! interval extensions, as used for implicit surfaces by Mitchell, "Robust ray intersection with
//! interval arithmetic", Graphics Interface 1990, and Snyder, "Interval analysis for computer
//! graphics", SIGGRAPH 1992). [`eval_box`] gives an interval containing f(p) for every p in the
//! box.
//!
//! [`eval_segment`] carries, beside each value interval, an enclosure of the value's derivative
//! along one direction d (forward-mode automatic differentiation on intervals, Rall 1981). For
//! the segment of a ray inside the box, the derivative enclosure [g_lo, g_hi] bounds ∂f/∂t, the
//! local Lipschitz bound that segment tracing steps by (Galin, Guérin, Paris & Peytavie,
//! "Segment Tracing Using Local Lipschitz Bounds", Eurographics 2020, §4). Where an op jumps
//! inside the box (`Floor` crossing an integer, `Select` whose condition changes sign, a pole of
//! `Div` or `Tan`), the mean-value theorem no longer holds and the derivative enclosure is the
//! whole line; the value enclosure stays valid.
//!
//! Soundness: bounds are computed in f32 and widened outwards by one ulp after every operation
//! (four for the transcendental functions, whose library results are not correctly rounded), so
//! they contain the exact real result of each op on the interval's reals. An interval that may
//! hold a NaN of the point interpreter (`√` or `ln` of a negative, `pow` of a negative base,
//! `0/0`) is the whole line: `min`/`max` in the point interpreter drop a NaN operand, and only the
//! whole line stays an enclosure of whatever they return then. Material ops (absent from
//! distance tapes) are skipped.

use crate::sdf::tape::{IMM, MAX_REGISTERS, Op, Tape};
use glam::Vec3;
use std::f32::consts::{FRAC_PI_2, PI, TAU};

/// A closed interval [lo, hi] of reals; [−∞, ∞] is "anything, NaN included".
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    /// Lower bound.
    pub lo: f32,
    /// Upper bound.
    pub hi: f32,
}

/// Moves a bound up by one ulp (∞ and NaN stay); `f32::next_up` is newer than the MSRV.
#[inline]
fn up(x: f32) -> f32 {
    if x.is_nan() || x == f32::INFINITY {
        x
    } else if x == 0.0 {
        f32::from_bits(1)
    } else if x > 0.0 {
        f32::from_bits(x.to_bits() + 1)
    } else {
        f32::from_bits(x.to_bits() - 1)
    }
}

/// Moves a bound down by one ulp (−∞ and NaN stay).
#[inline]
fn down(x: f32) -> f32 {
    -up(-x)
}

impl Interval {
    /// The whole real line.
    pub const WHOLE: Interval = Interval {
        lo: f32::NEG_INFINITY,
        hi: f32::INFINITY,
    };

    /// The single point x.
    #[inline]
    pub fn point(x: f32) -> Self {
        Interval { lo: x, hi: x }
    }

    /// [lo, hi] widened by one ulp on each side; the whole line if a bound is NaN or they are
    /// out of order (the only ways a NaN of the bounds' own arithmetic can show up).
    #[inline]
    fn out(lo: f32, hi: f32) -> Self {
        if lo <= hi {
            Interval {
                lo: down(lo),
                hi: up(hi),
            }
        } else {
            Self::WHOLE
        }
    }

    /// [lo, hi] as given (exact results: min, max, negation, |·|, floor).
    #[inline]
    fn exact(lo: f32, hi: f32) -> Self {
        if lo <= hi {
            Interval { lo, hi }
        } else {
            Self::WHOLE
        }
    }

    /// Widened by four ulps on each side (library transcendental functions).
    #[inline]
    fn out4(lo: f32, hi: f32) -> Self {
        let w = Self::out(lo, hi);
        Self::out(down(down(down(w.lo))), up(up(up(w.hi))))
    }

    /// Whether x lies inside (NaN lies only in the whole line).
    pub fn contains(&self, x: f32) -> bool {
        if x.is_nan() {
            *self == Self::WHOLE
        } else {
            self.lo <= x && x <= self.hi
        }
    }

    /// Whether every bound is finite.
    pub fn is_finite(&self) -> bool {
        self.lo.is_finite() && self.hi.is_finite()
    }

    /// The smallest interval holding both.
    #[inline]
    pub fn hull(self, o: Self) -> Self {
        Interval {
            lo: self.lo.min(o.lo),
            hi: self.hi.max(o.hi),
        }
    }

    /// The common part, or `self` if they are disjoint (callers intersect two enclosures of
    /// the same quantity, which cannot be disjoint but for rounding).
    #[inline]
    fn meet(self, o: Self) -> Self {
        let (lo, hi) = (self.lo.max(o.lo), self.hi.min(o.hi));
        if lo <= hi { Interval { lo, hi } } else { self }
    }

    /// sin(x + phase), with the phase only moving where the extremes lie (not added to x,
    /// which would round).
    fn periodic(self, phase: f32) -> Self {
        // Extremes of sin(x + phase) at x = π/2 − phase + kπ; tested with a small slack, so
        // that rounding in locating them can only widen the result.
        let slack = 1e-6 * (1.0 + self.lo.abs().max(self.hi.abs()));
        if !self.is_finite() || self.hi - self.lo + 2.0 * slack >= TAU {
            return Interval { lo: -1.0, hi: 1.0 };
        }
        let f = |x: f32| if phase == 0.0 { x.sin() } else { x.cos() };
        let (a, b) = (f(self.lo), f(self.hi));
        let (mut lo, mut hi) = (a.min(b), a.max(b));
        let first = FRAC_PI_2 - phase;
        let k0 = ((self.lo - slack - first) / PI).ceil();
        let mut k = k0;
        while first + k * PI <= self.hi + slack {
            // even k: a peak of the sine; odd k: a trough
            if (k as i64).rem_euclid(2) == 0 {
                hi = 1.0;
            } else {
                lo = -1.0;
            }
            k += 1.0;
            if k - k0 > 2.0 {
                break;
            }
        }
        let w = Self::out4(lo, hi);
        Interval {
            lo: w.lo.max(-1.0),
            hi: w.hi.min(1.0),
        }
    }
}

/// A value enclosure with an enclosure of its derivative along one direction (forward-mode
/// differentiation on intervals).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Slope {
    /// Enclosure of the value over the box.
    pub v: Interval,
    /// Enclosure of the directional derivative over the box; the whole line where the value
    /// may jump inside the box.
    pub d: Interval,
}

/// The elementary operations of the tape on one lane, for the interval evaluators.
pub trait Domain: Copy {
    /// A constant.
    fn constant(x: f32) -> Self;
    /// a + b
    fn add(self, o: Self) -> Self;
    /// a − b
    fn sub(self, o: Self) -> Self;
    /// a · b
    fn mul(self, o: Self) -> Self;
    /// a · k for a constant k
    fn scale(self, k: f32) -> Self;
    /// a²
    fn sqr(self) -> Self;
    /// a / b
    fn div(self, o: Self) -> Self;
    /// min(a, b)
    fn min(self, o: Self) -> Self;
    /// max(a, b)
    fn max(self, o: Self) -> Self;
    /// a^b
    fn pow(self, e: Self) -> Self;
    /// −a
    fn neg(self) -> Self;
    /// |a|
    fn abs(self) -> Self;
    /// √a
    fn sqrt(self) -> Self;
    /// sin a
    fn sin(self) -> Self;
    /// cos a
    fn cos(self) -> Self;
    /// tan a
    fn tan(self) -> Self;
    /// eᵃ
    fn exp(self) -> Self;
    /// ln a
    fn ln(self) -> Self;
    /// ⌊a⌋
    fn floor(self) -> Self;
    /// (c > 0) ? a : b
    fn select(c: Self, a: Self, b: Self) -> Self;
    /// Euclidean length of the lanes.
    fn length(lanes: &[Self]) -> Self {
        lanes
            .iter()
            .fold(Self::constant(0.0), |s, x| s.add(x.sqr()))
            .sqrt()
    }
}

impl Domain for Interval {
    fn constant(x: f32) -> Self {
        Interval::point(x)
    }

    #[inline]
    fn add(self, o: Self) -> Self {
        Self::out(self.lo + o.lo, self.hi + o.hi)
    }

    #[inline]
    fn sub(self, o: Self) -> Self {
        Self::out(self.lo - o.hi, self.hi - o.lo)
    }

    #[inline]
    fn neg(self) -> Self {
        Interval {
            lo: -self.hi,
            hi: -self.lo,
        }
    }

    #[inline]
    fn mul(self, o: Self) -> Self {
        // 0·∞ is NaN in floats but 0 for the reals a bound ±∞ stands for.
        let m = |a: f32, b: f32| {
            let p = a * b;
            if p.is_nan() { 0.0 } else { p }
        };
        let (a, b, c, d) = (
            m(self.lo, o.lo),
            m(self.lo, o.hi),
            m(self.hi, o.lo),
            m(self.hi, o.hi),
        );
        Self::out(a.min(b).min(c.min(d)), a.max(b).max(c.max(d)))
    }

    /// x·k for a constant k.
    #[inline]
    fn scale(self, k: f32) -> Self {
        self.mul(Self::point(k))
    }

    /// x², tighter than x·x when x straddles 0.
    #[inline]
    fn sqr(self) -> Self {
        let (a, b) = (self.lo * self.lo, self.hi * self.hi);
        if self.lo >= 0.0 || self.hi <= 0.0 {
            Self::out(a.min(b), a.max(b))
        } else {
            Interval {
                lo: 0.0,
                hi: up(a.max(b)),
            }
        }
    }

    #[inline]
    fn div(self, o: Self) -> Self {
        if o.lo > 0.0 || o.hi < 0.0 {
            let (a, b, c, d) = (
                self.lo / o.lo,
                self.lo / o.hi,
                self.hi / o.lo,
                self.hi / o.hi,
            );
            // ∞/∞ (NaN) only for unbounded operands: give up then.
            if a.is_nan() || b.is_nan() || c.is_nan() || d.is_nan() {
                return Self::WHOLE;
            }
            Self::out(a.min(b).min(c.min(d)), a.max(b).max(c.max(d)))
        } else {
            // A divisor that may be 0: a pole, or 0/0.
            Self::WHOLE
        }
    }

    #[inline]
    fn min(self, o: Self) -> Self {
        Interval {
            lo: self.lo.min(o.lo),
            hi: self.hi.min(o.hi),
        }
    }

    #[inline]
    fn max(self, o: Self) -> Self {
        Interval {
            lo: self.lo.max(o.lo),
            hi: self.hi.max(o.hi),
        }
    }

    #[inline]
    fn abs(self) -> Self {
        if self.lo >= 0.0 {
            self
        } else if self.hi <= 0.0 {
            self.neg()
        } else {
            Interval {
                lo: 0.0,
                hi: (-self.lo).max(self.hi),
            }
        }
    }

    #[inline]
    fn sqrt(self) -> Self {
        if self.lo < 0.0 {
            return Self::WHOLE;
        }
        Self::out(self.lo.sqrt(), self.hi.sqrt()).max(Self::point(0.0))
    }

    /// x^e for x ≥ 0: monotone in x for a fixed e and in e for a fixed x, so the extremes are
    /// at the corners.
    fn pow(self, e: Self) -> Self {
        if self.lo < 0.0 {
            return Self::WHOLE;
        }
        let c = [
            self.lo.powf(e.lo),
            self.lo.powf(e.hi),
            self.hi.powf(e.lo),
            self.hi.powf(e.hi),
        ];
        if c.iter().any(|x| x.is_nan()) {
            return Self::WHOLE;
        }
        let lo = c.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = c.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        Self::out4(lo, hi).max(Self::point(0.0))
    }

    /// sin over the interval: the endpoints, and ±1 where a peak or trough lies inside.
    fn sin(self) -> Self {
        self.periodic(0.0)
    }

    /// cos x = sin(x + π/2): peaks at 2kπ, troughs at π + 2kπ.
    fn cos(self) -> Self {
        self.periodic(FRAC_PI_2)
    }

    /// tan: increasing between its poles at π/2 + kπ; the whole line if one may lie inside.
    fn tan(self) -> Self {
        let slack = 1e-6 * (1.0 + self.lo.abs().max(self.hi.abs()));
        if !self.is_finite() || self.hi - self.lo + 2.0 * slack >= PI {
            return Self::WHOLE;
        }
        let k = ((self.lo - slack - FRAC_PI_2) / PI).ceil();
        if FRAC_PI_2 + k * PI <= self.hi + slack {
            return Self::WHOLE;
        }
        Self::out4(self.lo.tan(), self.hi.tan())
    }

    fn exp(self) -> Self {
        Self::out4(self.lo.exp(), self.hi.exp()).max(Self::point(0.0))
    }

    fn ln(self) -> Self {
        if self.lo < 0.0 {
            return Self::WHOLE;
        }
        Self::out4(self.lo.ln(), self.hi.ln())
    }

    fn floor(self) -> Self {
        Self::exact(self.lo.floor(), self.hi.floor())
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
}

impl Slope {
    /// A value with an unknown (possibly jumping) derivative.
    fn jumping(v: Interval) -> Self {
        Slope {
            v,
            d: Interval::WHOLE,
        }
    }
}

impl Domain for Slope {
    fn constant(x: f32) -> Self {
        Slope {
            v: Interval::point(x),
            d: Interval::point(0.0),
        }
    }
    fn add(self, o: Self) -> Self {
        Slope {
            v: self.v.add(o.v),
            d: self.d.add(o.d),
        }
    }
    fn sub(self, o: Self) -> Self {
        Slope {
            v: self.v.sub(o.v),
            d: self.d.sub(o.d),
        }
    }
    fn mul(self, o: Self) -> Self {
        let zero = Interval::point(0.0);
        let d = if o.d == zero {
            self.d.mul(o.v)
        } else if self.d == zero {
            self.v.mul(o.d)
        } else {
            self.d.mul(o.v).add(self.v.mul(o.d))
        };
        Slope {
            v: self.v.mul(o.v),
            d,
        }
    }
    fn scale(self, k: f32) -> Self {
        Slope {
            v: self.v.scale(k),
            d: self.d.scale(k),
        }
    }
    fn sqr(self) -> Self {
        Slope {
            v: self.v.sqr(),
            d: self.v.mul(self.d).scale(2.0),
        }
    }
    fn div(self, o: Self) -> Self {
        // (a/b)' = (a' − (a/b)·b') / b
        let q = self.v.div(o.v);
        Slope {
            v: q,
            d: self.d.sub(q.mul(o.d)).div(o.v),
        }
    }
    fn min(self, o: Self) -> Self {
        // min is continuous: where both may be the smaller one, its slope is one of theirs.
        if self.v.hi <= o.v.lo {
            self
        } else if o.v.hi <= self.v.lo {
            o
        } else {
            Slope {
                v: self.v.min(o.v),
                d: self.d.hull(o.d),
            }
        }
    }
    fn max(self, o: Self) -> Self {
        if self.v.lo >= o.v.hi {
            self
        } else if o.v.lo >= self.v.hi {
            o
        } else {
            Slope {
                v: self.v.max(o.v),
                d: self.d.hull(o.d),
            }
        }
    }
    fn pow(self, e: Self) -> Self {
        let v = self.v.pow(e.v);
        if e.d != Interval::point(0.0) {
            // A varying exponent: (aᵉ)' = aᵉ·(e'·ln a + e·a'/a); not worth the looseness.
            return Slope::jumping(v);
        }
        // (aᵉ)' = e·a^(e−1)·a'
        let dv = e.v.mul(self.v.pow(e.v.sub(Interval::point(1.0))));
        Slope {
            v,
            d: dv.mul(self.d),
        }
    }
    fn neg(self) -> Self {
        Slope {
            v: self.v.neg(),
            d: self.d.neg(),
        }
    }
    fn abs(self) -> Self {
        if self.v.lo >= 0.0 {
            self
        } else if self.v.hi <= 0.0 {
            self.neg()
        } else {
            Slope {
                v: self.v.abs(),
                d: self.d.hull(self.d.neg()),
            }
        }
    }
    fn sqrt(self) -> Self {
        // (√a)' = a'/(2√a): unbounded where a may reach 0 (the division gives the whole line).
        let v = self.v.sqrt();
        let d = if self.d == Interval::point(0.0) {
            self.d
        } else {
            self.d.div(v.scale(2.0))
        };
        Slope { v, d }
    }
    fn sin(self) -> Self {
        Slope {
            v: self.v.sin(),
            d: self.v.cos().mul(self.d),
        }
    }
    fn cos(self) -> Self {
        Slope {
            v: self.v.cos(),
            d: self.v.sin().neg().mul(self.d),
        }
    }
    fn tan(self) -> Self {
        let v = self.v.tan();
        Slope {
            v,
            d: Interval::point(1.0).add(v.sqr()).mul(self.d),
        }
    }
    fn exp(self) -> Self {
        let v = self.v.exp();
        Slope {
            v,
            d: v.mul(self.d),
        }
    }
    fn ln(self) -> Self {
        Slope {
            v: self.v.ln(),
            d: self.d.div(self.v),
        }
    }
    fn floor(self) -> Self {
        let v = self.v.floor();
        if v.lo == v.hi {
            // one step of the staircase: constant
            Slope {
                v,
                d: Interval::point(0.0),
            }
        } else {
            Slope::jumping(v)
        }
    }
    fn select(c: Self, a: Self, b: Self) -> Self {
        if c.v.lo > 0.0 {
            a
        } else if c.v.hi <= 0.0 {
            b
        } else {
            // the branch may switch inside the box: a jump, as far as the tape can tell
            Slope::jumping(a.v.hull(b.v))
        }
    }
    fn length(lanes: &[Self]) -> Self {
        // |p|' = (p·p')/|p|, and by Cauchy–Schwarz |(p·p')/|p|| ≤ |p'|: the quotient is
        // unbounded where |p| may be 0, the second bound never is.
        let sq = lanes
            .iter()
            .fold(Interval::point(0.0), |s, x| s.add(x.v.sqr()));
        let v = sq.sqrt();
        let dot = lanes
            .iter()
            .fold(Interval::point(0.0), |s, x| s.add(x.v.mul(x.d)));
        let m = lanes
            .iter()
            .fold(Interval::point(0.0), |s, x| s.add(x.d.sqr()))
            .sqrt()
            .hi;
        let d = dot.div(v).meet(Interval { lo: -m, hi: m });
        Slope { v, d }
    }
}

/// Scratch registers for the interval evaluators (4 lanes per register), and the lanes each
/// instruction of the last tape must compute.
pub struct IntervalRegisters<T> {
    regs: Box<[[T; 4]; MAX_REGISTERS]>,
    live: Vec<u8>,
}

impl<T: Domain> IntervalRegisters<T> {
    /// Fresh registers.
    pub fn new() -> Self {
        IntervalRegisters {
            regs: Box::new([[T::constant(0.0); 4]; MAX_REGISTERS]),
            live: Vec::new(),
        }
    }
}

/// The lanes of each instruction's result that the tape's result depends on (a backward
/// liveness pass). Most registers of a distance tape are scalars carried in lane x, and an
/// interval lane costs tens of point operations: computing only live lanes pays for the pass.
fn live_lanes(tape: &Tape, live: &mut Vec<u8>) {
    let reg = |i: u32| i as usize & (MAX_REGISTERS - 1);
    let mut need = [0u8; MAX_REGISTERS];
    need[reg(tape.result)] = 1;
    live.clear();
    live.resize(tape.instrs.len(), 0);
    for (k, ins) in tape.instrs.iter().enumerate().rev() {
        let op = ins.opcode();
        if matches!(op, Op::MatLoad | Op::MatMix) {
            continue;
        }
        let m = need[reg(ins.dst)];
        need[reg(ins.dst)] = 0;
        live[k] = m;
        if m == 0 {
            continue;
        }
        let mut use_a = 0;
        let mut use_b = 0;
        let mut use_c = 0;
        match op {
            Op::Const | Op::MatLoad | Op::MatMix => {}
            Op::Select => {
                (use_a, use_b, use_c) = (m, m, 1);
            }
            Op::Swizzle => {
                for i in 0..4 {
                    let s = (ins.aux >> (3 * i)) & 7;
                    if m & (1 << i) != 0 && s < 4 {
                        use_a |= 1 << s;
                    }
                }
            }
            Op::Pack => {
                if m & 1 != 0 {
                    use_a = 1 << (ins.aux & 3);
                }
                if m & 2 != 0 {
                    use_b = 1 << ((ins.aux >> 2) & 3);
                }
                if m & 4 != 0 {
                    use_c = 1 << ((ins.aux >> 4) & 3);
                }
            }
            Op::Dot3 => {
                (use_a, use_b) = ((m & 1) * 7, (m & 1) * 7);
            }
            Op::Length | Op::MaxLane => {
                use_a = if m & 1 == 0 {
                    0
                } else if ins.aux == 2 {
                    3
                } else {
                    7
                };
            }
            Op::Affine => use_a = if m & 7 != 0 { 7 } else { 0 },
            _ => (use_a, use_b, use_c) = (m, m, m),
        }
        need[reg(ins.a)] |= use_a;
        if ins.b != IMM {
            need[reg(ins.b)] |= use_b;
        }
        need[reg(ins.c)] |= use_c;
    }
}

impl<T: Domain> Default for IntervalRegisters<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// An enclosure of the tape's value (lane x of its result) over the box [lo, hi].
pub fn eval_box(
    tape: &Tape,
    lo: Vec3,
    hi: Vec3,
    regs: &mut IntervalRegisters<Interval>,
) -> Interval {
    let p = [0, 1, 2].map(|i| Interval::exact(lo[i].min(hi[i]), lo[i].max(hi[i])));
    run(tape, [p[0], p[1], p[2], Interval::point(0.0)], regs)
}

/// Enclosures of the tape's value and of its derivative along `dir` over the bounding box of
/// the segment from `a` to `b` (for a ray p(t) = o + t·dir, the derivative is ∂f/∂t).
pub fn eval_segment(
    tape: &Tape,
    a: Vec3,
    b: Vec3,
    dir: Vec3,
    regs: &mut IntervalRegisters<Slope>,
) -> Slope {
    let p = [0, 1, 2].map(|i| Slope {
        v: Interval::exact(a[i].min(b[i]), a[i].max(b[i])),
        d: Interval::point(dir[i]),
    });
    run(tape, [p[0], p[1], p[2], Slope::constant(0.0)], regs)
}

/// The tape interpreter of [`Tape::eval_in`] on a [`Domain`].
fn run<T: Domain>(tape: &Tape, p: [T; 4], scratch: &mut IntervalRegisters<T>) -> T {
    live_lanes(tape, &mut scratch.live);
    let regs = &mut *scratch.regs;
    let zero = T::constant(0.0);
    let reg = |i: u32| i as usize & (MAX_REGISTERS - 1);
    regs[0] = p;
    for (ins, &m) in tape.instrs.iter().zip(&scratch.live) {
        if m == 0 {
            continue;
        }
        // Operands by reference: a register is four (value, slope) pairs, 64 bytes, and most
        // ops read one or two of its lanes.
        let r = &*regs;
        let imm;
        let a = &r[reg(ins.a)];
        let b = if ins.b == IMM {
            imm = ins.imm.map(T::constant);
            &imm
        } else {
            &r[reg(ins.b)]
        };
        let c = &r[reg(ins.c)];
        // a·a is tighter as a² (an interval straddling 0 times itself looks negative).
        let same = ins.b != IMM && reg(ins.a) == reg(ins.b);
        // Componentwise ops compute the live lanes only; the others hold zero, never read.
        let lanes = |f: fn(T, T, T) -> T| -> [T; 4] {
            let mut out = [zero; 4];
            for i in 0..4 {
                if m & (1 << i) != 0 {
                    out[i] = f(a[i], b[i], c[i]);
                }
            }
            out
        };
        let out = match ins.opcode() {
            Op::Const => ins.imm.map(T::constant),
            Op::Add => lanes(|a, b, _| a.add(b)),
            Op::Sub => lanes(|a, b, _| a.sub(b)),
            Op::Mul if same => lanes(|a, _, _| a.sqr()),
            Op::Mul => lanes(|a, b, _| a.mul(b)),
            Op::Div => lanes(|a, b, _| a.div(b)),
            Op::Min => lanes(|a, b, _| a.min(b)),
            Op::Max => lanes(|a, b, _| a.max(b)),
            Op::Pow => lanes(|a, b, _| a.pow(b)),
            Op::Neg => lanes(|a, _, _| a.neg()),
            Op::Abs => lanes(|a, _, _| a.abs()),
            Op::Sqrt => lanes(|a, _, _| a.sqrt()),
            Op::Sin => lanes(|a, _, _| a.sin()),
            Op::Cos => lanes(|a, _, _| a.cos()),
            Op::Tan => lanes(|a, _, _| a.tan()),
            Op::Exp => lanes(|a, _, _| a.exp()),
            Op::Ln => lanes(|a, _, _| a.ln()),
            Op::Floor => lanes(|a, _, _| a.floor()),
            Op::MulAdd if same => lanes(|a, _, c| a.sqr().add(c)),
            Op::MulAdd => lanes(|a, b, c| a.mul(b).add(c)),
            Op::Select => {
                let mut out = [zero; 4];
                for i in 0..4 {
                    if m & (1 << i) != 0 {
                        out[i] = T::select(c[0], a[i], b[i]);
                    }
                }
                out
            }
            Op::Swizzle => {
                let lane = |i: u32| {
                    let s = (ins.aux >> (3 * i)) & 7;
                    if s < 4 { a[s as usize] } else { zero }
                };
                [lane(0), lane(1), lane(2), lane(3)]
            }
            Op::Pack => [
                a[(ins.aux & 3) as usize],
                b[((ins.aux >> 2) & 3) as usize],
                c[((ins.aux >> 4) & 3) as usize],
                zero,
            ],
            Op::Dot3 => {
                let x = if same {
                    a[0].sqr().add(a[1].sqr()).add(a[2].sqr())
                } else {
                    a[0].mul(b[0]).add(a[1].mul(b[1])).add(a[2].mul(b[2]))
                };
                [x, zero, zero, zero]
            }
            Op::Length => {
                let n = if ins.aux == 2 { 2 } else { 3 };
                [T::length(&a[..n]), zero, zero, zero]
            }
            Op::MaxLane => {
                let m = if ins.aux == 2 {
                    a[0].max(a[1])
                } else {
                    a[0].max(a[1]).max(a[2])
                };
                [m, zero, zero, zero]
            }
            Op::Affine => {
                let k = ins.aux as usize;
                let mut out = [zero; 4];
                for (i, o) in out.iter_mut().take(3).enumerate() {
                    if m & (1 << i) != 0 {
                        let r = tape.constants[k + i];
                        *o = a[0]
                            .scale(r[0])
                            .add(a[1].scale(r[1]))
                            .add(a[2].scale(r[2]))
                            .add(T::constant(r[3]));
                    }
                }
                out
            }
            Op::MatLoad | Op::MatMix => continue,
        };
        regs[reg(ins.dst)] = out;
    }
    regs[reg(tape.result)][0]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sdf::conformance::{CASES, distance_tape, parse_node};
    use proptest::prelude::*;
    use std::sync::OnceLock;

    /// The distance tapes of every shipped scene's objects and of the conformance catalogue,
    /// with the centre and half-size of the region their boxes are drawn from.
    fn tapes() -> &'static [(String, Tape, Vec3, f32)] {
        static TAPES: OnceLock<Vec<(String, Tape, Vec3, f32)>> = OnceLock::new();
        TAPES.get_or_init(|| {
            let mut out = Vec::new();
            for (name, scene) in crate::scene::shipped_scenes() {
                for o in &scene.objects {
                    let b = o.bounds();
                    let (c, r) = if b.min.is_finite() && b.max.is_finite() {
                        (
                            0.5 * (b.min + b.max),
                            0.6 * (b.max - b.min).max_element() + 0.5,
                        )
                    } else {
                        (Vec3::ZERO, 8.0)
                    };
                    out.push((
                        format!("{name}/{}", o.name),
                        o.lowered.distance.clone(),
                        c,
                        r,
                    ));
                }
            }
            for case in CASES {
                let tape = distance_tape(&parse_node(case.src));
                out.push((case.name.to_string(), tape, Vec3::ZERO, case.extent));
            }
            out
        })
    }

    /// The point interpreter rounds too: a value may sit a few ulps of its magnitude outside
    /// an enclosure of the exact reals.
    fn slack(x: f32) -> f32 {
        1e-5 * (1.0 + x.abs())
    }

    fn inside(e: Interval, x: f32) -> bool {
        e.contains(x) || (x.is_finite() && e.lo - slack(x) <= x && x <= e.hi + slack(x))
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2048))]

        /// Samples inside a box evaluate inside the box's enclosure; samples along a segment
        /// inside the segment's value enclosure, and their difference quotients (mean values
        /// of ∂f/∂t) inside its slope enclosure.
        #[test]
        fn every_sample_lies_in_the_enclosures(
            which in any::<prop::sample::Index>(),
            u in prop::array::uniform3(-1.0f32..1.0),
            size in -3.0f32..0.5,
            shape in prop::array::uniform3(0.0f32..1.0),
            picks in prop::collection::vec(prop::array::uniform3(0.0f32..1.0), 16),
        ) {
            let (name, tape, centre, reach) = which.get(tapes());
            let c = *centre + Vec3::from_array(u) * *reach;
            // half extents from 10⁻³ to ~3, some boxes flat along one axis
            let h = Vec3::from_array(shape) * 10f32.powf(size) * *reach;
            let (lo, hi) = (c - h, c + h);
            let at = |f: [f32; 3]| lo + (hi - lo) * Vec3::from_array(f);
            let e = eval_box(tape, lo, hi, &mut IntervalRegisters::new());
            for &f in &picks {
                let p = at(f);
                let v = tape.eval(p);
                prop_assert!(inside(e, v), "{name}: f({p}) = {v} outside {e:?} over {lo}..{hi}");
            }
            // a segment between two corners-ish points of the box
            let (a, b) = (at(picks[0]), at(picks[1]));
            let len = (b - a).length();
            prop_assume!(len > 1e-3);
            let dir = (b - a) / len;
            let g = eval_segment(tape, a, b, dir, &mut IntervalRegisters::new());
            let n = 64;
            let ts: Vec<f32> = (0..=n).map(|k| len * k as f32 / n as f32).collect();
            let fs: Vec<f32> = ts.iter().map(|&t| tape.eval(a + dir * t)).collect();
            for (t, v) in ts.iter().zip(&fs) {
                prop_assert!(inside(g.v, *v), "{name}: f at t = {t} is {v}, outside {:?}", g.v);
            }
            if g.d.is_finite() {
                for k in 0..n {
                    let q = (fs[k + 1] - fs[k]) / (ts[k + 1] - ts[k]);
                    let tol = 2.0 * slack(fs[k].abs().max(fs[k + 1].abs())) / (ts[k + 1] - ts[k]);
                    prop_assert!(
                        g.d.lo - tol <= q && q <= g.d.hi + tol,
                        "{name}: slope {q} at t = {} outside {:?} along {a}..{b}", ts[k], g.d
                    );
                }
            }
        }
    }

    #[test]
    fn elementary_enclosures_are_sound_and_tight_where_they_can_be() {
        let i = |lo, hi| Interval { lo, hi };
        // the peak of sin inside, the troughs of cos at both ends of [π, 3π]
        let s = i(0.0, PI).sin();
        assert!(s.hi == 1.0 && s.lo <= 0.0 && s.lo > -1e-6, "{s:?}");
        let c = i(PI, 3.0 * PI).cos();
        assert!(c.lo == -1.0 && c.hi == 1.0, "{c:?}");
        let c = i(0.1, 0.2).cos();
        assert!(c.contains(0.1f32.cos()) && c.contains(0.2f32.cos()) && c.lo > 0.97);
        // a divisor that may be 0, a tangent pole, a negative square root: anything
        assert_eq!(i(1.0, 2.0).div(i(-1.0, 1.0)), Interval::WHOLE);
        assert_eq!(i(1.0, 2.0).tan(), Interval::WHOLE);
        assert_eq!(i(-1.0, 4.0).sqrt(), Interval::WHOLE);
        assert_eq!(i(-1.0, 4.0).pow(i(0.5, 0.5)), Interval::WHOLE);
        // x² of an interval straddling 0 stays non-negative; x·x need not
        assert_eq!(i(-2.0, 1.0).sqr().lo, 0.0);
        assert!(i(-2.0, 1.0).mul(i(-2.0, 1.0)).lo < 0.0);
        // 0·∞ is 0 for the reals behind the bounds
        assert!(i(0.0, 0.0).mul(Interval::WHOLE).contains(0.0));
        // floor: the staircase has a jump inside [0.5, 1.5], so its slope is unknown
        let f = Slope {
            v: i(0.5, 1.5),
            d: Interval::point(1.0),
        }
        .floor();
        assert_eq!((f.v, f.d), (i(0.0, 1.0), Interval::WHOLE));
        let f = Slope {
            v: i(0.2, 0.7),
            d: Interval::point(1.0),
        }
        .floor();
        assert_eq!(f.d, Interval::point(0.0));
        // a NaN from the point interpreter lies only in the whole line
        assert!(Interval::WHOLE.contains(f32::NAN) && !i(0.0, 1.0).contains(f32::NAN));
    }

    #[test]
    fn a_plane_has_an_exact_slope_and_a_sphere_a_bounded_one() {
        let plane = distance_tape(&parse_node("Plane(normal: (0, 1, 0), offset: -1)"));
        let dir = Vec3::new(0.6, -0.8, 0.0);
        let (a, b) = (
            Vec3::new(0.0, 3.0, 0.0),
            Vec3::new(0.0, 3.0, 0.0) + 2.0 * dir,
        );
        let g = eval_segment(&plane, a, b, dir, &mut IntervalRegisters::new());
        assert!(
            (g.d.lo + 0.8).abs() < 1e-5 && (g.d.hi + 0.8).abs() < 1e-5,
            "{g:?}"
        );
        assert!(
            g.v.lo <= 2.4 && g.v.lo > 2.39 && g.v.hi >= 4.0 && g.v.hi < 4.01,
            "{g:?}"
        );
        // over a box holding the sphere's centre, |∂f/∂t| ≤ |d| (Cauchy–Schwarz), not ∞
        let sphere = distance_tape(&parse_node("Sphere(radius: 1.0)"));
        let g = eval_segment(
            &sphere,
            Vec3::new(-2.0, 0.0, 0.0),
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::X,
            &mut IntervalRegisters::new(),
        );
        assert!(g.d.lo >= -1.0 - 1e-5 && g.d.hi <= 1.0 + 1e-5, "{g:?}");
    }
}
