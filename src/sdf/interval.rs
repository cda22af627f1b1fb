//! Interval arithmetic over the tape: enclosures of a field and of its slope along a ray.
//!
//! Every [`Op`] is evaluated on intervals for a sample point known only to lie in an
//! axis-aligned box (Moore, "Interval Analysis", 1966; the inclusion property of natural
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
//! Soundness: bounds are computed in f32 and widened outwards by one ulp after every operation,
//! so they contain the exact real result of each op on the interval's reals — and, rounding
//! being monotone, the f32 result the point interpreter computes from any operands inside the
//! operand enclosures. The transcendental functions are evaluated with the tape's own kernels
//! ([`crate::sdf::math`]) and widened by their stated error, so the enclosures contain what the
//! point interpreter returns too: a branch of `min` that an enclosure proves unused is unused by
//! the interpreter at every point of the box, which is what region specialisation relies on. An interval that may
//! hold a NaN of the point interpreter (`√` or `ln` of a negative, `pow` of a negative base,
//! `0/0`) is the whole line: `min`/`max` in the point interpreter drop a NaN operand, and only the
//! whole line stays an enclosure of whatever they return then. Material ops (absent from
//! distance tapes) are skipped.

use crate::sdf::math::{self, SIN_COS_ABS_ERROR, SIN_COS_ACCURATE};
use crate::sdf::tape::{MAX_REGISTERS, Op, Tape};
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
    /// which would round). The endpoint values come from the tape's own kernels; widening by
    /// twice their error bound covers the exact values between them and the kernel's values
    /// at every point of the interval.
    fn periodic(self, phase: f32) -> Self {
        // Extremes of sin(x + phase) at x = π/2 − phase + kπ; tested with a small slack, so
        // that rounding in locating them can only widen the result.
        let slack = 1e-6 * (1.0 + self.lo.abs().max(self.hi.abs()));
        if !self.is_finite()
            || self.hi - self.lo + 2.0 * slack >= TAU
            || self.lo.abs().max(self.hi.abs()) > SIN_COS_ACCURATE
        {
            return Interval { lo: -1.0, hi: 1.0 };
        }
        let f = |x: f32| {
            if phase == 0.0 {
                math::sin(x)
            } else {
                math::cos(x)
            }
        };
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
        let w = Self::out(lo - 2.0 * SIN_COS_ABS_ERROR, hi + 2.0 * SIN_COS_ABS_ERROR);
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
    /// √(a² + b²).
    fn hypot(self, b: Self) -> Self;
    /// √(a² + b² + c²).
    fn hypot3(self, b: Self, c: Self) -> Self;
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
            // squares are never negative: the outward rounding stops at 0
            let w = Self::out(a.min(b), a.max(b));
            Interval {
                lo: w.lo.max(0.0),
                hi: w.hi,
            }
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
    /// at the corners. The kernel computes e^(e·ln x), whose error grows with |e·ln x|: the
    /// bounds are widened by that relative error.
    fn pow(self, e: Self) -> Self {
        if self.lo < 0.0 {
            return Self::WHOLE;
        }
        let c = [
            math::pow(self.lo, e.lo),
            math::pow(self.lo, e.hi),
            math::pow(self.hi, e.lo),
            math::pow(self.hi, e.hi),
        ];
        if c.iter().any(|x| x.is_nan()) {
            return Self::WHOLE;
        }
        let lo = c.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = c.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let spread = e.lo.abs().max(e.hi.abs())
            * math::ln(self.hi.max(1.0))
                .abs()
                .max(math::ln(self.lo.max(f32::MIN_POSITIVE)).abs());
        let rel = (8.0 + 4.0 * spread) * f32::EPSILON;
        if !rel.is_finite() || rel > 0.5 {
            return Interval {
                lo: 0.0,
                hi: f32::INFINITY,
            };
        }
        Self::out4(lo * (1.0 - rel), hi * (1.0 + rel)).max(Self::point(0.0))
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
    /// The kernel divides sin by cos, each within [`SIN_COS_ABS_ERROR`]: the quotient errs by
    /// at most about 2E/cos², widened for at the endpoint nearer a pole.
    fn tan(self) -> Self {
        let slack = 1e-6 * (1.0 + self.lo.abs().max(self.hi.abs()));
        if !self.is_finite()
            || self.hi - self.lo + 2.0 * slack >= PI
            || self.lo.abs().max(self.hi.abs()) > SIN_COS_ACCURATE
        {
            return Self::WHOLE;
        }
        let k = ((self.lo - slack - FRAC_PI_2) / PI).ceil();
        if FRAC_PI_2 + k * PI <= self.hi + slack {
            return Self::WHOLE;
        }
        let cos_min = math::cos(self.lo).abs().min(math::cos(self.hi).abs()) - SIN_COS_ABS_ERROR;
        if cos_min <= 1e-3 {
            return Self::WHOLE;
        }
        let err = 3.0 * SIN_COS_ABS_ERROR / (cos_min * cos_min);
        Self::out4(math::tan(self.lo) - err, math::tan(self.hi) + err)
    }

    fn exp(self) -> Self {
        Self::out4(math::exp(self.lo), math::exp(self.hi)).max(Self::point(0.0))
    }

    fn ln(self) -> Self {
        if self.lo < 0.0 {
            return Self::WHOLE;
        }
        Self::out4(math::ln(self.lo), math::ln(self.hi))
    }

    fn floor(self) -> Self {
        Self::exact(self.lo.floor(), self.hi.floor())
    }

    fn hypot(self, b: Self) -> Self {
        let sum = self.sqr().add(b.sqr());
        // a sum of squares is never negative, in the reals and in floats alike
        Interval {
            lo: sum.lo.max(0.0),
            hi: sum.hi,
        }
        .sqrt()
    }

    fn hypot3(self, b: Self, c: Self) -> Self {
        let sum = self.sqr().add(b.sqr()).add(c.sqr());
        Interval {
            lo: sum.lo.max(0.0),
            hi: sum.hi,
        }
        .sqrt()
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
    fn hypot(self, b: Self) -> Self {
        // |p|' = (p·p')/|p|, and by Cauchy–Schwarz |(p·p')/|p|| ≤ |p'|: the quotient is
        // unbounded where |p| may be 0, the second bound never is.
        let v = self.v.hypot(b.v);
        let dot = self.v.mul(self.d).add(b.v.mul(b.d));
        let m = self.d.hypot(b.d).hi;
        let d = dot.div(v).meet(Interval { lo: -m, hi: m });
        Slope { v, d }
    }
    fn hypot3(self, b: Self, c: Self) -> Self {
        let v = self.v.hypot3(b.v, c.v);
        let dot = self.v.mul(self.d).add(b.v.mul(b.d)).add(c.v.mul(c.d));
        let m = self.d.hypot3(b.d, c.d).hi;
        let d = dot.div(v).meet(Interval { lo: -m, hi: m });
        Slope { v, d }
    }
}

/// The value of one operation on a [`Domain`]: [`crate::sdf::tape::apply`] on enclosures.
#[inline]
pub fn apply_domain<T: Domain>(op: Op, a: T, b: T, c: T, imm: f32) -> T {
    let k = || T::constant(imm);
    match op {
        Op::Const => k(),
        Op::Copy => a,
        Op::Neg => a.neg(),
        Op::Abs => a.abs(),
        Op::Sqrt => a.sqrt(),
        Op::Square => a.sqr(),
        Op::Floor => a.floor(),
        Op::Sin => a.sin(),
        Op::Cos => a.cos(),
        Op::Tan => a.tan(),
        Op::Exp => a.exp(),
        Op::Ln => a.ln(),
        Op::Add => a.add(b),
        Op::Sub => a.sub(b),
        Op::Mul => a.mul(b),
        Op::Div => a.div(b),
        Op::Min => a.min(b),
        Op::Max => a.max(b),
        Op::Pow => a.pow(b),
        Op::Hypot => a.hypot(b),
        Op::AddImm => a.add(k()),
        Op::SubImm => a.sub(k()),
        Op::RsubImm => k().sub(a),
        Op::MulImm => a.scale(imm),
        Op::DivImm => a.div(k()),
        Op::RdivImm => k().div(a),
        Op::MinImm => a.min(k()),
        Op::MaxImm => a.max(k()),
        Op::PowImm => a.pow(k()),
        Op::Select => T::select(c, a, b),
        Op::Hypot3 => a.hypot3(b, c),
        Op::MatLoad | Op::MatMix | Op::Input => T::constant(0.0),
    }
}

/// Scratch registers for the interval evaluators.
pub struct IntervalRegisters<T> {
    regs: Box<[T; MAX_REGISTERS]>,
}

impl<T: Domain> IntervalRegisters<T> {
    /// Fresh registers.
    pub fn new() -> Self {
        IntervalRegisters {
            regs: Box::new([T::constant(0.0); MAX_REGISTERS]),
        }
    }
}

impl<T: Domain> Default for IntervalRegisters<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// An enclosure of the tape's value over the box [lo, hi].
pub fn eval_box(
    tape: &Tape,
    lo: Vec3,
    hi: Vec3,
    regs: &mut IntervalRegisters<Interval>,
) -> Interval {
    let p = [0, 1, 2].map(|i| Interval::exact(lo[i].min(hi[i]), lo[i].max(hi[i])));
    run(tape, p, regs)
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
    run(tape, p, regs)
}

/// The tape interpreter of [`Tape::eval_in`] on a [`Domain`].
fn run<T: Domain>(tape: &Tape, p: [T; 3], scratch: &mut IntervalRegisters<T>) -> T {
    let r = &mut *scratch.regs;
    r[..3].copy_from_slice(&p);
    for ins in tape.instrs() {
        if ins.op().is_material() {
            continue;
        }
        let a = r[ins.a() as usize];
        let b = r[ins.b() as usize];
        let c = r[ins.imm_bits() as u8 as usize];
        r[ins.out() as usize] = apply_domain(ins.op(), a, b, c, ins.imm());
    }
    r[tape.result() as usize]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sdf::conformance::{case_tapes, distance_tape, parse_node};
    use proptest::prelude::*;
    use std::sync::OnceLock;

    /// The conformance catalogue's tapes (the shipped scenes' are swept by
    /// `tests/evaluators.rs`).
    fn tapes() -> &'static [(String, Tape, Vec3, f32)] {
        static TAPES: OnceLock<Vec<(String, Tape, Vec3, f32)>> = OnceLock::new();
        TAPES.get_or_init(case_tapes)
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
