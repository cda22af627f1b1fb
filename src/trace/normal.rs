//! Surface normals from the distance field: the gradient by finite differences.

use super::step::epsilon_at;
use crate::accel::field::FieldCursor;
use crate::scene::TracerSettings;
use crate::scene::file::NormalMethod;
use crate::sdf::simd::{PacketRegisters, SimdLevel, eval8};
use glam::Vec3;
use std::cell::RefCell;

thread_local! {
    /// SIMD registers for the stencils, kept per thread.
    static STENCIL: RefCell<PacketRegisters> = RefCell::new(PacketRegisters::new());
}

/// The field at up to 8 points: one SIMD pass when they share a tape (the stencil around a
/// hit mostly lies in one leaf), else point by point — the same values either way.
fn values<const N: usize>(field: &mut FieldCursor, points: [Vec3; N]) -> [f32; N] {
    const { assert!(N <= 8) };
    let tapes = points.map(|q| field.region(q).tape);
    if tapes.iter().all(|t| std::ptr::eq(*t, tapes[0])) {
        let mut xyz = [[0.0f32; 8]; 3];
        for i in 0..8 {
            let q = points[i.min(N - 1)];
            for a in 0..3 {
                xyz[a][i] = q[a];
            }
        }
        let d = STENCIL.with(|r| {
            eval8(
                SimdLevel::detect(),
                tapes[0],
                &xyz[0],
                &xyz[1],
                &xyz[2],
                &mut r.borrow_mut(),
            )
        });
        return std::array::from_fn(|i| d[i]);
    }
    points.map(|q| field.eval(q))
}

/// The finite-difference step at distance t: a few ε(t), so the stencil straddles the
/// ε-shell the tracer stopped in, but never below 1e-4 where f32 cancellation dominates.
pub fn step_for(s: &TracerSettings, t: f32) -> f32 {
    (2.0 * epsilon_at(s, t)).max(1e-4)
}

/// The unit normal at p by the chosen estimator, and the gradient's length; a zero gradient
/// (e.g. the centre of a sphere) gives +y rather than NaN.
pub fn estimate(field: &mut FieldCursor, p: Vec3, h: f32, method: NormalMethod) -> (Vec3, f32) {
    let g = match method {
        NormalMethod::Central => central(field, p, h),
        NormalMethod::Tetrahedral => tetrahedral(field, p, h),
    };
    (g.try_normalize().unwrap_or(Vec3::Y), g.length())
}

/// Central differences, 6 evaluations: ∇f ≈ (f(p+hx) − f(p−hx), …)/2h, second-order accurate.
pub fn central(field: &mut FieldCursor, p: Vec3, h: f32) -> Vec3 {
    let f = values(
        field,
        [
            p + Vec3::X * h,
            p - Vec3::X * h,
            p + Vec3::Y * h,
            p - Vec3::Y * h,
            p + Vec3::Z * h,
            p - Vec3::Z * h,
        ],
    );
    Vec3::new(f[0] - f[1], f[2] - f[3], f[4] - f[5]) / (2.0 * h)
}

/// The tetrahedral 4-tap estimate (Quilez, "normals for an SDF"): with the four vertices
/// k of a tetrahedron, Σ k·f(p + h·k) is proportional to ∇f to first order and costs 4
/// evaluations instead of 6. Returned scaled to approximate ∇f (÷ 4h).
pub fn tetrahedral(field: &mut FieldCursor, p: Vec3, h: f32) -> Vec3 {
    const K: [Vec3; 4] = [
        Vec3::new(1.0, -1.0, -1.0),
        Vec3::new(-1.0, -1.0, 1.0),
        Vec3::new(-1.0, 1.0, -1.0),
        Vec3::new(1.0, 1.0, 1.0),
    ];
    let f = values(field, K.map(|k| p + k * h));
    K.iter().zip(f).map(|(&k, f)| k * f).sum::<Vec3>() / (4.0 * h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use crate::sdf::conformance::{distance_tape, parse_node};
    use crate::sdf::tape::Registers;

    #[test]
    fn tetrahedral_and_central_normals_agree_on_a_sphere() {
        let t = distance_tape(&parse_node("Sphere(radius: 1.0)"));
        let mut rng = Rng::new(5);
        let mut regs = Registers::new();
        let mut field = FieldCursor::whole(&t, &mut regs);
        for _ in 0..200 {
            let n = rng.direction();
            let p = n * 1.0;
            let c = central(&mut field, p, 1e-3).normalize();
            let k = tetrahedral(&mut field, p, 1e-3).normalize();
            assert!((c - n).length() < 1e-3, "central {c} vs {n}");
            assert!((k - n).length() < 1e-3, "tetrahedral {k} vs {n}");
        }
    }
}
