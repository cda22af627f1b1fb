//! Surface normals from the distance field: the gradient by finite differences.

use super::epsilon_at;
use crate::scene::TracerSettings;
use crate::scene::file::NormalMethod;
use crate::sdf::tape::{Registers, Tape};
use glam::Vec3;

/// The finite-difference step at distance t: a few ε(t), so the stencil straddles the
/// ε-shell the tracer stopped in, but never below 1e-4 where f32 cancellation dominates.
pub fn step_for(s: &TracerSettings, t: f32) -> f32 {
    (2.0 * epsilon_at(s, t)).max(1e-4)
}

/// The unit normal at p by the chosen estimator, and the gradient's length; a zero gradient
/// (e.g. the centre of a sphere) gives +y rather than NaN.
pub fn estimate(
    tape: &Tape,
    p: Vec3,
    h: f32,
    method: NormalMethod,
    regs: &mut Registers,
) -> (Vec3, f32) {
    let g = match method {
        NormalMethod::Central => central(tape, p, h, regs),
        NormalMethod::Tetrahedral => tetrahedral(tape, p, h, regs),
    };
    (g.try_normalize().unwrap_or(Vec3::Y), g.length())
}

/// Central differences, 6 evaluations: ∇f ≈ (f(p+hx) − f(p−hx), …)/2h, second-order accurate.
pub fn central(tape: &Tape, p: Vec3, h: f32, regs: &mut Registers) -> Vec3 {
    let mut f = |q: Vec3| tape.eval_in(q, regs);
    Vec3::new(
        f(p + Vec3::X * h) - f(p - Vec3::X * h),
        f(p + Vec3::Y * h) - f(p - Vec3::Y * h),
        f(p + Vec3::Z * h) - f(p - Vec3::Z * h),
    ) / (2.0 * h)
}

/// The tetrahedral 4-tap estimate (Quilez, "normals for an SDF"): with the four vertices
/// k of a tetrahedron, Σ k·f(p + h·k) is proportional to ∇f to first order and costs 4
/// evaluations instead of 6. Returned scaled to approximate ∇f (÷ 4h).
pub fn tetrahedral(tape: &Tape, p: Vec3, h: f32, regs: &mut Registers) -> Vec3 {
    const K: [Vec3; 4] = [
        Vec3::new(1.0, -1.0, -1.0),
        Vec3::new(-1.0, -1.0, 1.0),
        Vec3::new(-1.0, 1.0, -1.0),
        Vec3::new(1.0, 1.0, 1.0),
    ];
    K.iter()
        .map(|&k| k * tape.eval_in(p + k * h, regs))
        .sum::<Vec3>()
        / (4.0 * h)
}
