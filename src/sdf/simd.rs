//! SIMD evaluation of tapes: 8 points per instruction with AVX2, 4 with SSE2, and a portable
//! array of 8 elsewhere, chosen at run time (as the BVH node test is).
//!
//! The lane types implement [`Lanes`] with the same IEEE operation per lane as the scalar
//! evaluator — `min`/`max` as `(a < b || b is NaN) ? a : b`, an exact `floor` (SSE2 has no
//! rounding instruction: truncation, corrected below and at zero), no fused multiply-adds — so
//! [`eval8`] returns, lane for lane, the bits [`Tape::eval`] gives (tested below on every
//! shipped scene and the conformance catalogue).

use crate::sdf::lanes::{Array8, Lanes};
use crate::sdf::tape::{MATERIAL_FLOATS, MAX_REGISTERS, MaterialVec, Tape};

/// Which instruction set [`eval8`] uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimdLevel {
    /// 8 lanes per instruction.
    Avx2,
    /// 4 lanes per instruction (two passes for 8 points).
    Sse2,
    /// A plain array of 8, computed lane by lane.
    Portable,
}

impl SimdLevel {
    /// The best level this CPU runs.
    pub fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                return SimdLevel::Avx2;
            }
            SimdLevel::Sse2
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            SimdLevel::Portable
        }
    }

    /// Points per instruction.
    pub fn lanes(self) -> usize {
        match self {
            SimdLevel::Avx2 | SimdLevel::Portable => 8,
            SimdLevel::Sse2 => 4,
        }
    }
}

/// Eight floats aligned for an AVX register.
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(32))]
pub struct Lane8(pub [f32; 8]);

/// Scratch registers for [`eval8`]: 256 registers of 8 lanes (8 KiB), reused across calls.
pub struct PacketRegisters {
    regs: Box<[Lane8; MAX_REGISTERS]>,
}

impl Default for PacketRegisters {
    fn default() -> Self {
        Self::new()
    }
}

impl PacketRegisters {
    /// Fresh registers.
    pub fn new() -> Self {
        PacketRegisters {
            regs: Box::new([Lane8::default(); MAX_REGISTERS]),
        }
    }

    /// The registers as native code's spill slots ([`crate::sdf::native::Native::eval8`]).
    fn slots(&mut self) -> &mut [[f32; 8]] {
        // SAFETY: `Lane8` is `repr(C)` around `[f32; 8]` (its alignment only adds none: 32
        // bytes, the size), so the buffer is MAX_REGISTERS arrays of 8 floats.
        unsafe {
            std::slice::from_raw_parts_mut(self.regs.as_mut_ptr().cast::<[f32; 8]>(), MAX_REGISTERS)
        }
    }

    /// The registers as an array of another 32-byte-or-smaller, at-most-32-aligned lane type.
    fn as_lanes<L: Lanes>(&mut self) -> &mut [L; MAX_REGISTERS] {
        const {
            assert!(std::mem::size_of::<L>() <= std::mem::size_of::<Lane8>());
            assert!(std::mem::align_of::<L>() <= std::mem::align_of::<Lane8>());
        }
        // SAFETY: the buffer holds MAX_REGISTERS values of at least L's size and alignment;
        // every lane type is plain floats, valid for any bit pattern.
        unsafe { &mut *(self.regs.as_mut_ptr() as *mut [L; MAX_REGISTERS]) }
    }
}

/// The tape at 8 points: lane i is `tape.eval((x[i], y[i], z[i]))`, bit for bit. At the
/// AVX2 level a tape with native code ([`crate::sdf::jit`]) runs it; [`eval8_interpreted`]
/// always interprets.
#[inline]
pub fn eval8(
    level: SimdLevel,
    tape: &Tape,
    x: &[f32; 8],
    y: &[f32; 8],
    z: &[f32; 8],
    regs: &mut PacketRegisters,
) -> [f32; 8] {
    if level == SimdLevel::Avx2
        && let Some(native) = &tape.native
    {
        return native.eval8(x, y, z, regs.slots());
    }
    eval8_interpreted(level, tape, x, y, z, regs)
}

/// [`eval8`] by the interpreter, whether or not the tape has native code (the benchmark and
/// the tests compare the two).
#[inline]
pub fn eval8_interpreted(
    level: SimdLevel,
    tape: &Tape,
    x: &[f32; 8],
    y: &[f32; 8],
    z: &[f32; 8],
    regs: &mut PacketRegisters,
) -> [f32; 8] {
    match level {
        #[cfg(target_arch = "x86_64")]
        SimdLevel::Avx2 => {
            // SAFETY: the level is `Avx2` only where `detect` found AVX2.
            unsafe { x86::eval8_avx2(tape, x, y, z, regs.as_lanes()) }
        }
        #[cfg(target_arch = "x86_64")]
        SimdLevel::Sse2 => {
            let regs = regs.as_lanes::<x86::Sse>();
            let lo = x86::eval4_sse2(tape, &x[..4], &y[..4], &z[..4], regs);
            let hi = x86::eval4_sse2(tape, &x[4..], &y[4..], &z[4..], regs);
            [lo[0], lo[1], lo[2], lo[3], hi[0], hi[1], hi[2], hi[3]]
        }
        _ => {
            let r = tape.eval_lanes(Array8(*x), Array8(*y), Array8(*z), regs.as_lanes());
            r.0
        }
    }
}

/// [`Tape::eval_material_lanes`]' material at 8 points with the widest evaluator `level` allows: entry k
/// of the result holds material float k of each point, the bits [`Tape::eval_material`]
/// gives there.
pub fn material8(
    level: SimdLevel,
    tape: &Tape,
    x: &[f32; 8],
    y: &[f32; 8],
    z: &[f32; 8],
    materials: &[MaterialVec],
    regs: &mut PacketRegisters,
) -> [[f32; 8]; MATERIAL_FLOATS] {
    match level {
        #[cfg(target_arch = "x86_64")]
        SimdLevel::Avx2 => {
            // SAFETY: the level is `Avx2` only where `detect` found AVX2.
            unsafe { x86::material8_avx2(tape, x, y, z, materials, regs.as_lanes()) }
        }
        _ => {
            let (_, m) = tape.eval_material_lanes(
                Array8(*x),
                Array8(*y),
                Array8(*z),
                materials,
                regs.as_lanes(),
            );
            m.map(|v| v.0)
        }
    }
}

#[cfg(target_arch = "x86_64")]
pub(crate) use x86::{apply_avx2, sin_cos_avx2};

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::Lanes;
    use crate::sdf::tape::{MATERIAL_FLOATS, MAX_REGISTERS, MaterialVec, Tape};
    use std::arch::x86_64::*;

    /// Four lanes in an SSE register (SSE2 is part of x86-64: always available).
    #[derive(Clone, Copy)]
    #[repr(transparent)]
    pub struct Sse(__m128);

    /// Eight lanes in an AVX register. Its operations use AVX and AVX2 instructions: values
    /// of this type exist only inside [`eval8_avx2`], which runs after detection.
    #[derive(Clone, Copy)]
    #[repr(transparent)]
    pub struct Avx(__m256);

    /// The tape at 4 points with SSE2.
    pub fn eval4_sse2(
        tape: &Tape,
        x: &[f32],
        y: &[f32],
        z: &[f32],
        regs: &mut [Sse; MAX_REGISTERS],
    ) -> [f32; 4] {
        // SAFETY: SSE2 is part of the x86-64 baseline; the slices hold 4 floats.
        unsafe {
            let load = |s: &[f32]| Sse(_mm_loadu_ps(s[..4].as_ptr()));
            let r = tape.eval_lanes(load(x), load(y), load(z), regs);
            let mut out = [0.0f32; 4];
            _mm_storeu_ps(out.as_mut_ptr(), r.0);
            out
        }
    }

    /// [`super::material8`] with AVX2.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[target_feature(enable = "avx2")]
    pub unsafe fn material8_avx2(
        tape: &Tape,
        x: &[f32; 8],
        y: &[f32; 8],
        z: &[f32; 8],
        materials: &[MaterialVec],
        regs: &mut [Avx; MAX_REGISTERS],
    ) -> [[f32; 8]; MATERIAL_FLOATS] {
        let load = |s: &[f32; 8]| Avx(unsafe { _mm256_loadu_ps(s.as_ptr()) });
        let (_, m) = tape.eval_material_lanes(load(x), load(y), load(z), materials, regs);
        m.map(|v| {
            let mut out = [0.0f32; 8];
            unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v.0) };
            out
        })
    }

    /// The tape at 8 points with AVX2.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[target_feature(enable = "avx2")]
    pub unsafe fn eval8_avx2(
        tape: &Tape,
        x: &[f32; 8],
        y: &[f32; 8],
        z: &[f32; 8],
        regs: &mut [Avx; MAX_REGISTERS],
    ) -> [f32; 8] {
        let load = |s: &[f32; 8]| Avx(unsafe { _mm256_loadu_ps(s.as_ptr()) });
        let r = tape.eval_lanes(load(x), load(y), load(z), regs);
        let mut out = [0.0f32; 8];
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), r.0) };
        out
    }

    /// One operation of the tape on 8 lanes in memory, by the interpreter's own AVX2 lanes:
    /// what native code ([`crate::sdf::jit`]) calls for the operations it does not write out
    /// (the transcendental functions), so that their polynomials exist once. `op` is an
    /// [`crate::sdf::tape::Op`] number, `imm` the instruction's immediate bits.
    ///
    /// # Safety
    /// The CPU must support AVX2; `a`, `b` and `out` point to 8 floats each.
    #[target_feature(enable = "avx2")]
    pub(crate) unsafe extern "sysv64" fn apply_avx2(
        op: u32,
        a: *const f32,
        b: *const f32,
        imm: u32,
        out: *mut f32,
    ) {
        let op = crate::sdf::tape::Op::from_u8(op as u8).expect("native code passes an opcode");
        unsafe {
            let (a, b) = (Avx(_mm256_loadu_ps(a)), Avx(_mm256_loadu_ps(b)));
            let r = crate::sdf::tape::apply(op, a, b, a, f32::from_bits(imm));
            _mm256_storeu_ps(out, r.0);
        }
    }

    /// `sin` and `cos` of 8 lanes in memory by one argument reduction
    /// ([`crate::sdf::math::sin_cos`], of which `Op::Sin` and `Op::Cos` are the halves, so the
    /// bits are theirs): what native code calls for a `sin` and a `cos` of the same value.
    ///
    /// # Safety
    /// The CPU must support AVX2; `a`, `sin` and `cos` point to 8 floats each.
    #[target_feature(enable = "avx2")]
    pub(crate) unsafe extern "sysv64" fn sin_cos_avx2(a: *const f32, sin: *mut f32, cos: *mut f32) {
        unsafe {
            let (s, c) = crate::sdf::math::sin_cos(Avx(_mm256_loadu_ps(a)));
            _mm256_storeu_ps(sin, s.0);
            _mm256_storeu_ps(cos, c.0);
        }
    }

    // SAFETY (every `unsafe` block below): SSE2 intrinsics are part of the x86-64 baseline.
    impl Lanes for Sse {
        const WIDTH: usize = 4;
        #[inline(always)]
        fn splat(v: f32) -> Self {
            unsafe { Sse(_mm_set1_ps(v)) }
        }
        #[inline(always)]
        fn add(self, b: Self) -> Self {
            unsafe { Sse(_mm_add_ps(self.0, b.0)) }
        }
        #[inline(always)]
        fn sub(self, b: Self) -> Self {
            unsafe { Sse(_mm_sub_ps(self.0, b.0)) }
        }
        #[inline(always)]
        fn mul(self, b: Self) -> Self {
            unsafe { Sse(_mm_mul_ps(self.0, b.0)) }
        }
        #[inline(always)]
        fn div(self, b: Self) -> Self {
            unsafe { Sse(_mm_div_ps(self.0, b.0)) }
        }
        #[inline(always)]
        fn min(self, b: Self) -> Self {
            // minps gives a < b ? a : b; a NaN b must give a
            unsafe {
                let m = _mm_min_ps(self.0, b.0);
                let nan = _mm_cmpunord_ps(b.0, b.0);
                Sse(_mm_or_ps(_mm_and_ps(nan, self.0), _mm_andnot_ps(nan, m)))
            }
        }
        #[inline(always)]
        fn max(self, b: Self) -> Self {
            unsafe {
                let m = _mm_max_ps(self.0, b.0);
                let nan = _mm_cmpunord_ps(b.0, b.0);
                Sse(_mm_or_ps(_mm_and_ps(nan, self.0), _mm_andnot_ps(nan, m)))
            }
        }
        #[inline(always)]
        fn neg(self) -> Self {
            unsafe { Sse(_mm_xor_ps(self.0, _mm_set1_ps(-0.0))) }
        }
        #[inline(always)]
        fn abs(self) -> Self {
            unsafe { Sse(_mm_andnot_ps(_mm_set1_ps(-0.0), self.0)) }
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            unsafe { Sse(_mm_sqrt_ps(self.0)) }
        }
        #[inline(always)]
        fn floor(self) -> Self {
            unsafe {
                let x = self.0;
                // truncation toward zero, one less where that rounded a negative up
                let t = _mm_cvtepi32_ps(_mm_cvttps_epi32(x));
                let up = _mm_and_ps(_mm_cmpgt_ps(t, x), _mm_set1_ps(1.0));
                let r = _mm_sub_ps(t, up);
                // |x| ≥ 2²³ (and NaN, ±∞) is already an integer
                let sign = _mm_set1_ps(-0.0);
                let big = _mm_cmpnlt_ps(_mm_andnot_ps(sign, x), _mm_set1_ps(8_388_608.0));
                let r = _mm_or_ps(_mm_and_ps(big, x), _mm_andnot_ps(big, r));
                // a zero result keeps x's sign (⌊−0⌋ = −0)
                let zero = _mm_cmpeq_ps(r, _mm_setzero_ps());
                Sse(_mm_or_ps(r, _mm_and_ps(zero, _mm_and_ps(x, sign))))
            }
        }
        #[inline(always)]
        fn select_pos(c: Self, a: Self, b: Self) -> Self {
            unsafe {
                let m = _mm_cmpgt_ps(c.0, _mm_setzero_ps());
                Sse(_mm_or_ps(_mm_and_ps(m, a.0), _mm_andnot_ps(m, b.0)))
            }
        }
        #[inline(always)]
        fn select_lt(a: Self, b: Self, x: Self, y: Self) -> Self {
            unsafe {
                let m = _mm_cmplt_ps(a.0, b.0);
                Sse(_mm_or_ps(_mm_and_ps(m, x.0), _mm_andnot_ps(m, y.0)))
            }
        }
        #[inline(always)]
        fn select_nan(a: Self, x: Self, y: Self) -> Self {
            unsafe {
                let m = _mm_cmpunord_ps(a.0, a.0);
                Sse(_mm_or_ps(_mm_and_ps(m, x.0), _mm_andnot_ps(m, y.0)))
            }
        }
        #[inline(always)]
        fn pow2i(n: Self) -> Self {
            unsafe {
                let e = _mm_add_epi32(_mm_cvtps_epi32(n.0), _mm_set1_epi32(127));
                Sse(_mm_castsi128_ps(_mm_slli_epi32::<23>(e)))
            }
        }
        #[inline(always)]
        fn frexp(self) -> (Self, Self) {
            unsafe {
                let bits = _mm_castps_si128(self.0);
                let e = _mm_sub_epi32(
                    _mm_and_si128(_mm_srli_epi32::<23>(bits), _mm_set1_epi32(0xff)),
                    _mm_set1_epi32(126),
                );
                let m = _mm_or_si128(
                    _mm_and_si128(bits, _mm_set1_epi32(0x807f_ffff_u32 as i32)),
                    _mm_set1_epi32(0x3f00_0000),
                );
                (Sse(_mm_castsi128_ps(m)), Sse(_mm_cvtepi32_ps(e)))
            }
        }
    }

    // SAFETY (every `unsafe` block below): `Avx` values exist only inside `eval8_avx2`, which
    // is called after AVX2 was detected.
    impl Lanes for Avx {
        const WIDTH: usize = 8;
        #[inline(always)]
        fn splat(v: f32) -> Self {
            unsafe { Avx(_mm256_set1_ps(v)) }
        }
        #[inline(always)]
        fn add(self, b: Self) -> Self {
            unsafe { Avx(_mm256_add_ps(self.0, b.0)) }
        }
        #[inline(always)]
        fn sub(self, b: Self) -> Self {
            unsafe { Avx(_mm256_sub_ps(self.0, b.0)) }
        }
        #[inline(always)]
        fn mul(self, b: Self) -> Self {
            unsafe { Avx(_mm256_mul_ps(self.0, b.0)) }
        }
        #[inline(always)]
        fn div(self, b: Self) -> Self {
            unsafe { Avx(_mm256_div_ps(self.0, b.0)) }
        }
        #[inline(always)]
        fn min(self, b: Self) -> Self {
            unsafe {
                let m = _mm256_min_ps(self.0, b.0);
                let nan = _mm256_cmp_ps::<_CMP_UNORD_Q>(b.0, b.0);
                Avx(_mm256_blendv_ps(m, self.0, nan))
            }
        }
        #[inline(always)]
        fn max(self, b: Self) -> Self {
            unsafe {
                let m = _mm256_max_ps(self.0, b.0);
                let nan = _mm256_cmp_ps::<_CMP_UNORD_Q>(b.0, b.0);
                Avx(_mm256_blendv_ps(m, self.0, nan))
            }
        }
        #[inline(always)]
        fn neg(self) -> Self {
            unsafe { Avx(_mm256_xor_ps(self.0, _mm256_set1_ps(-0.0))) }
        }
        #[inline(always)]
        fn abs(self) -> Self {
            unsafe { Avx(_mm256_andnot_ps(_mm256_set1_ps(-0.0), self.0)) }
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            unsafe { Avx(_mm256_sqrt_ps(self.0)) }
        }
        #[inline(always)]
        fn floor(self) -> Self {
            unsafe { Avx(_mm256_floor_ps(self.0)) }
        }
        #[inline(always)]
        fn select_pos(c: Self, a: Self, b: Self) -> Self {
            unsafe {
                let m = _mm256_cmp_ps::<_CMP_GT_OQ>(c.0, _mm256_setzero_ps());
                Avx(_mm256_blendv_ps(b.0, a.0, m))
            }
        }
        #[inline(always)]
        fn select_lt(a: Self, b: Self, x: Self, y: Self) -> Self {
            unsafe {
                let m = _mm256_cmp_ps::<_CMP_LT_OQ>(a.0, b.0);
                Avx(_mm256_blendv_ps(y.0, x.0, m))
            }
        }
        #[inline(always)]
        fn select_nan(a: Self, x: Self, y: Self) -> Self {
            unsafe {
                let m = _mm256_cmp_ps::<_CMP_UNORD_Q>(a.0, a.0);
                Avx(_mm256_blendv_ps(y.0, x.0, m))
            }
        }
        #[inline(always)]
        fn pow2i(n: Self) -> Self {
            unsafe {
                let e = _mm256_add_epi32(_mm256_cvtps_epi32(n.0), _mm256_set1_epi32(127));
                Avx(_mm256_castsi256_ps(_mm256_slli_epi32::<23>(e)))
            }
        }
        #[inline(always)]
        fn frexp(self) -> (Self, Self) {
            unsafe {
                let bits = _mm256_castps_si256(self.0);
                let e = _mm256_sub_epi32(
                    _mm256_and_si256(_mm256_srli_epi32::<23>(bits), _mm256_set1_epi32(0xff)),
                    _mm256_set1_epi32(126),
                );
                let m = _mm256_or_si256(
                    _mm256_and_si256(bits, _mm256_set1_epi32(0x807f_ffff_u32 as i32)),
                    _mm256_set1_epi32(0x3f00_0000),
                );
                (Avx(_mm256_castsi256_ps(m)), Avx(_mm256_cvtepi32_ps(e)))
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::rng::Rng;
    use crate::sdf::conformance::case_tapes;
    use crate::sdf::ssa::Builder;
    use crate::sdf::tape::Op;
    use glam::Vec3;

    fn levels() -> Vec<SimdLevel> {
        let mut v = vec![SimdLevel::Portable];
        #[cfg(target_arch = "x86_64")]
        {
            v.push(SimdLevel::Sse2);
            if SimdLevel::detect() == SimdLevel::Avx2 {
                v.push(SimdLevel::Avx2);
            }
        }
        v
    }

    /// Checks `eval8` at `level` against the scalar evaluator, bit for bit.
    pub(crate) fn check_bits(level: SimdLevel, name: &str, tape: &Tape, pts: &[Vec3]) {
        let mut regs = PacketRegisters::new();
        for chunk in pts.chunks(8) {
            let mut x = [0.0; 8];
            let mut y = [0.0; 8];
            let mut z = [0.0; 8];
            for (i, p) in chunk.iter().enumerate() {
                (x[i], y[i], z[i]) = (p.x, p.y, p.z);
            }
            let got = eval8(level, tape, &x, &y, &z, &mut regs);
            for (i, p) in chunk.iter().enumerate() {
                let want = tape.eval(*p);
                assert!(
                    got[i].to_bits() == want.to_bits() || (got[i].is_nan() && want.is_nan()),
                    "{level:?} {name} at {p}: {} vs scalar {}",
                    got[i],
                    want
                );
            }
        }
    }

    #[test]
    fn every_level_gives_the_scalar_bits_on_every_case() {
        let mut rng = Rng::new(11);
        for (name, tape, c, r) in case_tapes() {
            let pts: Vec<Vec3> = (0..256)
                .map(|_| c + rng.vec3_in(-r, r))
                .chain([Vec3::ZERO, c, Vec3::splat(1e6), Vec3::splat(-0.0)])
                .collect();
            for level in levels() {
                check_bits(level, &name, &tape, &pts);
            }
        }
    }

    /// Points made of values around every op's edges (fidget's "spicy" inputs): each pair of
    /// them as (x, y) with a random one as z, then random points, seeded by `seed`. Shared by
    /// the tests of native code (`sdf::jit`).
    pub(crate) fn spicy_points(seed: u64) -> Vec<Vec3> {
        let spicy = [
            0.0f32,
            -0.0,
            1.0,
            -1.0,
            0.5,
            -0.5,
            1.5,
            -2.5,
            f32::MIN_POSITIVE,
            1e-40,
            -1e-40,
            8_388_607.5,
            -8_388_609.0,
            1e30,
            -1e30,
            f32::MAX,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            std::f32::consts::PI,
            100.0,
            -88.5,
            89.0,
            3e9,
        ];
        let mut rng = Rng::new(seed);
        let mut pts: Vec<Vec3> = Vec::new();
        for &a in &spicy {
            for &b in &spicy {
                let c = spicy[rng.below(spicy.len() as u64) as usize];
                pts.push(Vec3::new(a, b, c));
            }
        }
        pts.extend((0..512).map(|_| rng.vec3_in(-50.0, 50.0)));
        pts
    }

    #[test]
    fn every_op_gives_the_scalar_bits_on_spicy_inputs() {
        // every operation alone, on values around its edges
        let pts = spicy_points(2);
        for &op in Op::ALL {
            if op.is_material() || op == Op::Input {
                continue;
            }
            let mut b = Builder::new();
            let [x, y, z] = b.point();
            let v = match op.shape() {
                crate::sdf::tape::Shape::Nullary => b.konst(0.25),
                crate::sdf::tape::Shape::Unary => b.unary(op, x),
                crate::sdf::tape::Shape::Binary => b.binary(op, x, y),
                crate::sdf::tape::Shape::WithImm => b.with_imm(op, x, 1.75),
                crate::sdf::tape::Shape::Ternary if op == Op::Hypot3 => b.hypot3(x, y, z),
                crate::sdf::tape::Shape::Ternary => b.select(z, x, y),
                _ => unreachable!(),
            };
            let tape = b.finish(v, None).compile().unwrap();
            for level in levels() {
                check_bits(level, op.name(), &tape, &pts);
            }
        }
    }
}
