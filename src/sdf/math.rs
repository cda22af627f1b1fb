//! The transcendental functions of the tape, written once over [`Lanes`].
//!
//! `sin`, `cos`, `tan`, `exp`, `ln` and `pow` are built from the lane operations only
//! (Cody–Waite argument reduction and the minimax polynomials of Moshier's Cephes library,
//! `sinf.c`, `expf.c`, `logf.c`), so the scalar evaluator and the SIMD evaluators compute the
//! same bits: a library `sinf` on one lane and a vector polynomial on eight would differ in the
//! last place, and a specialised tape would no longer reproduce the whole tape's hits. The
//! GPU uses WGSL's built-ins instead (the driver's precision, see `shaders/README.md`).
//!
//! Accuracy (measured against `f64` in the tests below): `sin`/`cos` within
//! [`SIN_COS_ABS_ERROR`] of the exact value for |x| ≤ [`SIN_COS_ACCURATE`], and some value
//! in [−1, 1] beyond; `exp` and `ln` within 2 ulps. The interval evaluator widens its bounds by
//! these figures, so its enclosures contain what these functions return.

use super::lanes::Lanes;

/// Largest |x| for which `sin` and `cos` keep [`SIN_COS_ABS_ERROR`] (the three-part π/2 of
/// the reduction stays exact enough up to here).
pub const SIN_COS_ACCURATE: f32 = 8192.0;

/// Bound on |sin(x) − sin_exact(x)| (and cos) for |x| ≤ [`SIN_COS_ACCURATE`].
pub const SIN_COS_ABS_ERROR: f32 = 2.5e-7;

/// π/2 = C1 + C2 + C3, with C1 and C2 short enough that j·C1 and j·C2 are exact for the
/// quadrant numbers j that matter (Cody & Waite 1980; Cephes `sinf.c` uses the halves).
const PIO2_C1: f32 = 1.570_312_5;
const PIO2_C2: f32 = 4.837_513e-4;
const PIO2_C3: f32 = 7.549_79e-8;
/// 1.5·2²³: adding and subtracting it rounds to the nearest integer for |x| < 2²².
const ROUND_MAGIC: f32 = 12_582_912.0;

/// Beyond this |x| the quadrant number no longer fits the rounding trick: such arguments give
/// sin = 0 and cos = 1 (NaN for ±∞ and NaN).
const REDUCIBLE: f32 = 4_194_304.0 * std::f32::consts::FRAC_PI_2;

/// Sine and cosine of x together (one argument reduction).
#[inline(always)]
pub fn sin_cos<L: Lanes>(x: L) -> (L, L) {
    let reducible = L::select_lt(x.abs(), L::splat(REDUCIBLE), x, L::splat(0.0));
    let j = reducible
        .mul(L::splat(std::f32::consts::FRAC_2_PI))
        .add(L::splat(ROUND_MAGIC))
        .sub(L::splat(ROUND_MAGIC));
    let r = reducible
        .sub(j.mul(L::splat(PIO2_C1)))
        .sub(j.mul(L::splat(PIO2_C2)))
        .sub(j.mul(L::splat(PIO2_C3)));
    let z = r.mul(r);
    // Cephes sinf.c, |r| ≤ π/4.
    let s = L::splat(-1.951_529_6e-4)
        .mul(z)
        .add(L::splat(8.332_161e-3))
        .mul(z)
        .add(L::splat(-1.666_665_5e-1))
        .mul(z)
        .mul(r)
        .add(r);
    let c = L::splat(2.443_315_7e-5)
        .mul(z)
        .add(L::splat(-1.388_731_6e-3))
        .mul(z)
        .add(L::splat(4.166_664_6e-2))
        .mul(z)
        .mul(z)
        .sub(L::splat(0.5).mul(z))
        .add(L::splat(1.0));
    // quadrant q = j mod 4 = 2·hi + odd, all exact in floats
    let quarter = j.mul(L::splat(0.25)).floor();
    let q = j.sub(quarter.mul(L::splat(4.0)));
    let hi = q.mul(L::splat(0.5)).floor();
    let odd = q.sub(hi.mul(L::splat(2.0)));
    let half = L::splat(0.5);
    // sin: s, c, −s, −c; cos: c, −s, −c, s
    let sin_base = L::select_lt(odd, half, s, c);
    let sin = L::select_lt(hi, half, sin_base, sin_base.neg());
    let cos_base = L::select_lt(odd, half, c, s);
    let flip = hi.add(odd).sub(L::splat(1.0)).abs();
    let cos = L::select_lt(flip, half, cos_base.neg(), cos_base);
    // x·0 is 0 for finite x and NaN for ±∞ and NaN
    let zero = x.mul(L::splat(0.0));
    let sin = L::select_lt(x.abs(), L::splat(REDUCIBLE), clamp_unit(sin), zero);
    let cos = L::select_lt(
        x.abs(),
        L::splat(REDUCIBLE),
        clamp_unit(cos),
        zero.add(L::splat(1.0)),
    );
    (sin, cos)
}

/// Clamps to [−1, 1]: only the reduction's rounding far beyond [`SIN_COS_ACCURATE`] can leave
/// it.
#[inline(always)]
fn clamp_unit<L: Lanes>(v: L) -> L {
    v.max(L::splat(-1.0)).min(L::splat(1.0))
}

/// sin x.
#[inline(always)]
pub fn sin<L: Lanes>(x: L) -> L {
    sin_cos(x).0
}

/// cos x.
#[inline(always)]
pub fn cos<L: Lanes>(x: L) -> L {
    sin_cos(x).1
}

/// tan x = sin x / cos x.
#[inline(always)]
pub fn tan<L: Lanes>(x: L) -> L {
    let (s, c) = sin_cos(x);
    s.div(c)
}

/// eˣ (Cephes `expf.c`): x = n·ln 2 + r, eʳ by a degree-6 polynomial, then 2ⁿ in two factors
/// so that results down to the subnormals and up to `f32::MAX` are formed without overflow.
#[inline(always)]
pub fn exp<L: Lanes>(x: L) -> L {
    const MAX_ARG: f32 = 88.722_84;
    const MIN_ARG: f32 = -103.972_08;
    let xc = x.max(L::splat(MIN_ARG)).min(L::splat(MAX_ARG));
    let n = xc
        .mul(L::splat(std::f32::consts::LOG2_E))
        .add(L::splat(0.5))
        .floor();
    let r = xc
        .sub(n.mul(L::splat(0.693_359_4)))
        .sub(n.mul(L::splat(-2.121_944_4e-4)));
    let z = r.mul(r);
    let p = L::splat(1.987_569_1e-4)
        .mul(r)
        .add(L::splat(1.398_2e-3))
        .mul(r)
        .add(L::splat(8.333_452e-3))
        .mul(r)
        .add(L::splat(4.166_579_6e-2))
        .mul(r)
        .add(L::splat(1.666_666_5e-1))
        .mul(r)
        .add(L::splat(5e-1))
        .mul(z)
        .add(r)
        .add(L::splat(1.0));
    let n1 = n.mul(L::splat(0.5)).floor();
    let n2 = n.sub(n1);
    let v = p.mul(L::pow2i(n1)).mul(L::pow2i(n2));
    let v = L::select_lt(L::splat(MAX_ARG), x, L::splat(f32::INFINITY), v);
    let v = L::select_lt(x, L::splat(MIN_ARG), L::splat(0.0), v);
    L::select_nan(x, x, v)
}

/// ln x (Cephes `logf.c`): x = m·2ᵉ with m in [√½, √2), ln m by a degree-9 polynomial.
/// ln 0 = −∞, ln of a negative number is NaN, ln ∞ = ∞.
#[inline(always)]
pub fn ln<L: Lanes>(x: L) -> L {
    const SQRT_HALF: f32 = std::f32::consts::FRAC_1_SQRT_2;
    // subnormals: scale into the normal range first
    let tiny = L::select_lt(x, L::splat(f32::MIN_POSITIVE), L::splat(1.0), L::splat(0.0));
    let xs = x.mul(L::splat(1.0).add(tiny.mul(L::splat(33_554_431.0))));
    let (m, e) = xs.frexp();
    let e = e.sub(tiny.mul(L::splat(25.0)));
    let small = L::select_lt(m, L::splat(SQRT_HALF), L::splat(1.0), L::splat(0.0));
    let e = e.sub(small);
    let m = m.add(m.mul(small)).sub(L::splat(1.0));
    let z = m.mul(m);
    let y = L::splat(7.037_683_6e-2)
        .mul(m)
        .add(L::splat(-1.151_461e-1))
        .mul(m)
        .add(L::splat(1.167_699_9e-1))
        .mul(m)
        .add(L::splat(-1.242_014_1e-1))
        .mul(m)
        .add(L::splat(1.424_932_3e-1))
        .mul(m)
        .add(L::splat(-1.666_805_8e-1))
        .mul(m)
        .add(L::splat(2.000_071_4e-1))
        .mul(m)
        .add(L::splat(-2.499_999_4e-1))
        .mul(m)
        .add(L::splat(3.333_333e-1))
        .mul(m)
        .mul(z);
    let y = y
        .add(e.mul(L::splat(-2.121_944_4e-4)))
        .sub(L::splat(0.5).mul(z));
    let v = m.add(y).add(e.mul(L::splat(0.693_359_4)));
    let v = L::select_lt(L::splat(f32::MAX), x, L::splat(f32::INFINITY), v);
    let v = L::select_lt(L::splat(0.0), x, v, L::splat(f32::NAN));
    // |x| below the least subnormal: x is ±0
    let v = L::select_lt(
        x.abs(),
        L::splat(f32::from_bits(1)),
        L::splat(f32::NEG_INFINITY),
        v,
    );
    L::select_nan(x, x, v)
}

/// aᵇ = e^(b·ln a) for a ≥ 0 (NaN for a < 0; a⁰ = 1).
#[inline(always)]
pub fn pow<L: Lanes>(a: L, b: L) -> L {
    let v = exp(b.mul(ln(a)));
    let zero_exponent = b.abs();
    L::select_lt(zero_exponent, L::splat(f32::from_bits(1)), L::splat(1.0), v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn ulps(a: f32, exact: f64) -> f64 {
        let e = exact as f32;
        if a == e {
            return 0.0;
        }
        let ulp = (f32::from_bits(e.abs().to_bits() + 1) - e.abs()) as f64;
        (a as f64 - exact).abs() / ulp
    }

    #[test]
    fn sin_and_cos_are_within_the_stated_absolute_error() {
        let mut rng = Rng::new(3);
        let mut worst: f64 = 0.0;
        for i in 0..400_000 {
            let range = [1.0f32, 10.0, 100.0, 1000.0, SIN_COS_ACCURATE][i % 5];
            let x = rng.range_f32(-range, range);
            let (s, c) = sin_cos(x);
            worst = worst
                .max((s as f64 - (x as f64).sin()).abs())
                .max((c as f64 - (x as f64).cos()).abs());
        }
        assert!(worst < SIN_COS_ABS_ERROR as f64 * 0.8, "{worst}");
        // exact values and specials
        assert_eq!(sin(0.0f32), 0.0);
        assert_eq!(cos(0.0f32), 1.0);
        assert!(sin(f32::NAN).is_nan() && cos(f32::INFINITY).is_nan());
        for x in [1e6f32, 1e9, -3e7, f32::MAX] {
            let (s, c) = sin_cos(x);
            assert!(
                (-1.0..=1.0).contains(&s) && (-1.0..=1.0).contains(&c),
                "{x}"
            );
        }
    }

    #[test]
    fn exp_and_ln_are_within_two_ulps() {
        let mut rng = Rng::new(5);
        for _ in 0..200_000 {
            let x = rng.range_f32(-87.0, 88.5);
            let u = ulps(exp(x), (x as f64).exp());
            assert!(u <= 2.0, "exp({x}): {u} ulps");
            let y = 10f32.powf(rng.range_f32(-37.0, 38.0));
            let u = ulps(ln(y), (y as f64).ln());
            assert!(u <= 2.0, "ln({y}): {u} ulps");
        }
        assert_eq!(exp(0.0f32), 1.0);
        assert_eq!(exp(100.0f32), f32::INFINITY);
        assert_eq!(exp(-200.0f32), 0.0);
        assert!(exp(f32::NAN).is_nan());
        assert_eq!(ln(1.0f32), 0.0);
        assert_eq!(ln(0.0f32), f32::NEG_INFINITY);
        assert!(ln(-1.0f32).is_nan() && ln(f32::NAN).is_nan());
        assert_eq!(ln(f32::INFINITY), f32::INFINITY);
        let sub = 1e-40f32;
        assert!((ln(sub) as f64 - (sub as f64).ln()).abs() < 1e-4);
        assert_eq!(pow(2.0f32, 0.0), 1.0);
        assert_eq!(pow(0.0f32, 2.5), 0.0);
        assert!((pow(2.0f32, 0.5) - std::f32::consts::SQRT_2).abs() < 1e-6);
        assert!(pow(-1.0f32, 0.5).is_nan());
    }
}
