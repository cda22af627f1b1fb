//! The SDF conformance suite (`hytrace::sdf::conformance`) on every tape evaluator, one test
//! per (case, evaluator): `scalar::torus` failing names the case and the interpreter. The
//! evaluators: the scalar interpreter, the 8-lane packet interpreter at every SIMD level the
//! CPU has, the tapes compiled to native code (where the CPU has AVX2), interval arithmetic on
//! degenerate boxes, the WGSL interpreter on the GPU (feature `gpu`), and fidget's VM and JIT
//! on the converted tapes (feature `fidget`).

#[macro_use]
mod common;

use hytrace::sdf::conformance::{CpuEvaluator, IntervalEvaluator, NativeEvaluator, SimdEvaluator};
use hytrace::sdf::simd::SimdLevel;

sdf_conformance!(scalar => CpuEvaluator);
sdf_conformance!(simd_portable => SimdEvaluator(SimdLevel::Portable));
#[cfg(target_arch = "x86_64")]
sdf_conformance!(simd_sse2 => SimdEvaluator(SimdLevel::Sse2));
#[cfg(target_arch = "x86_64")]
sdf_conformance!(simd_avx2 => match avx2() {
    Some(ev) => ev,
    None => return,
});
sdf_conformance!(native => match native() {
    Some(ev) => ev,
    None => return,
});
sdf_conformance!(interval => IntervalEvaluator);
#[cfg(feature = "gpu")]
sdf_conformance!(gpu_wgsl => *gpu());
#[cfg(feature = "fidget")]
sdf_conformance!(fidget_vm => common::conformance::FidgetEvaluator::<fidget::vm::VmFunction>::new());
#[cfg(feature = "fidget")]
sdf_conformance!(fidget_jit => common::conformance::FidgetEvaluator::<fidget::jit::JitFunction>::new());

/// The AVX2 level where the CPU has it. Elsewhere the tests say loudly that they did not run
/// (they cannot) and pass; under `CI=true` they fail, as the CI machine has AVX2.
#[cfg(target_arch = "x86_64")]
fn avx2() -> Option<SimdEvaluator> {
    if SimdLevel::detect() == SimdLevel::Avx2 {
        return Some(SimdEvaluator(SimdLevel::Avx2));
    }
    eprintln!("!!! this CPU has no AVX2: simd_avx2 NOT RUN !!!");
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "CI must run the AVX2 evaluator"
    );
    None
}

/// Native code where the CPU makes it (AVX2); elsewhere, as for [`avx2`], a loud skip that
/// fails under `CI=true`.
fn native() -> Option<NativeEvaluator> {
    if hytrace::sdf::jit::available() {
        return Some(NativeEvaluator);
    }
    eprintln!("!!! this CPU makes no native code (no AVX2): native NOT RUN !!!");
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "CI must run the native evaluator"
    );
    None
}

/// The WGSL interpreter, compiled once per process.
#[cfg(feature = "gpu")]
fn gpu() -> &'static hytrace::gpu::GpuSdfEvaluator<'static> {
    use std::sync::OnceLock;
    static EV: OnceLock<hytrace::gpu::GpuSdfEvaluator<'static>> = OnceLock::new();
    EV.get_or_init(|| {
        hytrace::gpu::GpuSdfEvaluator::new(common::gpu::ctx()).unwrap_or_else(|e| panic!("{e}"))
    })
}

#[test]
fn every_case_of_the_catalogue_has_a_test() {
    common::conformance::assert_every_case_listed(scalar::CASE_NAMES);
}
