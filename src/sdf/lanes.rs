//! Lanes: the arithmetic every tape evaluator is written over, one point per lane.
//!
//! The interpreter ([`crate::sdf::tape`]) and the transcendental kernels ([`crate::sdf::math`])
//! are generic over [`Lanes`], and instantiated for a single `f32` (the scalar evaluator), for
//! SSE2 (4 lanes) and AVX2 (8 lanes) registers ([`crate::sdf::simd`]) and for a portable array
//! of 8. Every implementation performs the same IEEE-754 single-precision operation per lane —
//! no fused multiply-adds, `min`/`max` that drop a NaN operand as `f32::min` does, an exact
//! `floor` — so an 8-wide evaluation gives, lane for lane, the bits of 8 scalar evaluations
//! (tested in `sdf::simd`). The `wide` and `std::simd` types do not serve here: the first picks
//! its instruction set when the crate is compiled (our builds stay portable and choose AVX2 at
//! run time, as the BVH node test does), the second is not stable Rust.

/// One IEEE single per lane, with the operations tapes are made of.
pub trait Lanes: Copy + 'static {
    /// Number of lanes.
    const WIDTH: usize;
    /// Every lane `v`.
    fn splat(v: f32) -> Self;
    /// a + b
    fn add(self, b: Self) -> Self;
    /// a − b
    fn sub(self, b: Self) -> Self;
    /// a · b
    fn mul(self, b: Self) -> Self;
    /// a / b
    fn div(self, b: Self) -> Self;
    /// min(a, b) as `(a < b || b is NaN) ? a : b`: a NaN operand is dropped, as by `f32::min`.
    fn min(self, b: Self) -> Self;
    /// max(a, b) as `(a > b || b is NaN) ? a : b`: a NaN operand is dropped.
    fn max(self, b: Self) -> Self;
    /// −a (the sign bit flipped).
    fn neg(self) -> Self;
    /// |a| (the sign bit cleared).
    fn abs(self) -> Self;
    /// √a, correctly rounded.
    fn sqrt(self) -> Self;
    /// ⌊a⌋, exact (−0 stays −0, NaN stays NaN).
    fn floor(self) -> Self;
    /// Per lane: `c > 0 ? a : b` (a NaN `c` picks `b`).
    fn select_pos(c: Self, a: Self, b: Self) -> Self;
    /// Per lane: `a < b ? x : y`.
    fn select_lt(a: Self, b: Self, x: Self, y: Self) -> Self;
    /// Per lane: `a` is NaN ? x : y.
    fn select_nan(a: Self, x: Self, y: Self) -> Self;
    /// 2ⁿ for lanes holding integers n in [−126, 127].
    fn pow2i(n: Self) -> Self;
    /// (m, e) with a = m·2ᵉ and m in [0.5, 1), for positive normal finite lanes (others give
    /// unspecified values that the callers select away).
    fn frexp(self) -> (Self, Self);
}

impl Lanes for f32 {
    const WIDTH: usize = 1;
    #[inline(always)]
    fn splat(v: f32) -> Self {
        v
    }
    #[inline(always)]
    fn add(self, b: Self) -> Self {
        self + b
    }
    #[inline(always)]
    fn sub(self, b: Self) -> Self {
        self - b
    }
    #[inline(always)]
    fn mul(self, b: Self) -> Self {
        self * b
    }
    #[inline(always)]
    fn div(self, b: Self) -> Self {
        self / b
    }
    // Written out rather than `f32::min`, whose choice between −0 and +0 is unspecified:
    // every lane type computes exactly this.
    #[inline(always)]
    fn min(self, b: Self) -> Self {
        if self < b || b.is_nan() { self } else { b }
    }
    #[inline(always)]
    fn max(self, b: Self) -> Self {
        if self > b || b.is_nan() { self } else { b }
    }
    #[inline(always)]
    fn neg(self) -> Self {
        -self
    }
    #[inline(always)]
    fn abs(self) -> Self {
        f32::abs(self)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
    // `f32::floor` is a library call on baseline x86-64 (no SSE4.1 rounding instruction):
    // truncation, corrected below and at zero, as the SSE2 lanes do it.
    #[inline(always)]
    fn floor(self) -> Self {
        // |x| ≥ 2²³ is an integer already; NaN and ±∞ stay (written so that NaN takes it)
        if self.abs().partial_cmp(&8_388_608.0) != Some(std::cmp::Ordering::Less) {
            return self;
        }
        let t = self as i32 as f32;
        let r = if t > self { t - 1.0 } else { t };
        if r == 0.0 { 0.0f32.copysign(self) } else { r }
    }
    #[inline(always)]
    fn select_pos(c: Self, a: Self, b: Self) -> Self {
        if c > 0.0 { a } else { b }
    }
    #[inline(always)]
    fn select_lt(a: Self, b: Self, x: Self, y: Self) -> Self {
        if a < b { x } else { y }
    }
    #[inline(always)]
    fn select_nan(a: Self, x: Self, y: Self) -> Self {
        if a.is_nan() { x } else { y }
    }
    #[inline(always)]
    fn pow2i(n: Self) -> Self {
        f32::from_bits(((n as i32 + 127) as u32) << 23)
    }
    #[inline(always)]
    fn frexp(self) -> (Self, Self) {
        let bits = self.to_bits();
        let e = ((bits >> 23) & 0xff) as i32 - 126;
        let m = f32::from_bits((bits & 0x807f_ffff) | 0x3f00_0000);
        (m, e as f32)
    }
}

/// Eight lanes as a plain array, each computed by the scalar implementation: the portable
/// fallback where neither AVX2 nor SSE2 is available (and the model the SIMD types are
/// tested against).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Array8(pub [f32; 8]);

impl Array8 {
    #[inline(always)]
    fn map(self, f: impl Fn(f32) -> f32) -> Self {
        Array8(std::array::from_fn(|i| f(self.0[i])))
    }
    #[inline(always)]
    fn zip(self, o: Self, f: impl Fn(f32, f32) -> f32) -> Self {
        Array8(std::array::from_fn(|i| f(self.0[i], o.0[i])))
    }
}

impl Lanes for Array8 {
    const WIDTH: usize = 8;
    #[inline(always)]
    fn splat(v: f32) -> Self {
        Array8([v; 8])
    }
    #[inline(always)]
    fn add(self, b: Self) -> Self {
        self.zip(b, |a, b| a + b)
    }
    #[inline(always)]
    fn sub(self, b: Self) -> Self {
        self.zip(b, |a, b| a - b)
    }
    #[inline(always)]
    fn mul(self, b: Self) -> Self {
        self.zip(b, |a, b| a * b)
    }
    #[inline(always)]
    fn div(self, b: Self) -> Self {
        self.zip(b, |a, b| a / b)
    }
    #[inline(always)]
    fn min(self, b: Self) -> Self {
        self.zip(b, <f32 as Lanes>::min)
    }
    #[inline(always)]
    fn max(self, b: Self) -> Self {
        self.zip(b, <f32 as Lanes>::max)
    }
    #[inline(always)]
    fn neg(self) -> Self {
        self.map(|a| -a)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        self.map(f32::abs)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        self.map(f32::sqrt)
    }
    #[inline(always)]
    fn floor(self) -> Self {
        self.map(<f32 as Lanes>::floor)
    }
    #[inline(always)]
    fn select_pos(c: Self, a: Self, b: Self) -> Self {
        Array8(std::array::from_fn(|i| {
            <f32 as Lanes>::select_pos(c.0[i], a.0[i], b.0[i])
        }))
    }
    #[inline(always)]
    fn select_lt(a: Self, b: Self, x: Self, y: Self) -> Self {
        Array8(std::array::from_fn(|i| {
            <f32 as Lanes>::select_lt(a.0[i], b.0[i], x.0[i], y.0[i])
        }))
    }
    #[inline(always)]
    fn select_nan(a: Self, x: Self, y: Self) -> Self {
        Array8(std::array::from_fn(|i| {
            <f32 as Lanes>::select_nan(a.0[i], x.0[i], y.0[i])
        }))
    }
    #[inline(always)]
    fn pow2i(n: Self) -> Self {
        n.map(<f32 as Lanes>::pow2i)
    }
    #[inline(always)]
    fn frexp(self) -> (Self, Self) {
        let mut m = [0.0; 8];
        let mut e = [0.0; 8];
        for i in 0..8 {
            (m[i], e[i]) = <f32 as Lanes>::frexp(self.0[i]);
        }
        (Array8(m), Array8(e))
    }
}
