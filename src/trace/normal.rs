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

/// The field at up to 8 points, each with the tape of the leaf holding it (or all with a short
/// whole tape, [`crate::accel::field::SHORT_TAPE`], equal there), on SIMD lanes:
/// one pass per distinct tape (the stencil around a hit mostly lies in one leaf; over a large
/// union's small leaves it often straddles two or three, and evaluating those points one by
/// one was about a fifth of a 1,000-box frame). The lanes give the scalar interpreter's bits, so
/// the values are those of [`FieldCursor::eval`] at each point.
fn values<const N: usize>(field: &mut FieldCursor, points: [Vec3; N]) -> [f32; N] {
    const { assert!(N <= 8) };
    let tapes = match field.short_whole_tape() {
        Some(whole) => [whole; N],
        None => points.map(|q| field.region(q).tape),
    };
    let mut xyz = [[0.0f32; 8]; 3];
    for i in 0..8 {
        let q = points[i.min(N - 1)];
        for a in 0..3 {
            xyz[a][i] = q[a];
        }
    }
    let mut out = [0.0f32; N];
    let mut done = [false; N];
    STENCIL.with(|r| {
        let regs = &mut r.borrow_mut();
        for i in 0..N {
            if done[i] {
                continue;
            }
            let d = eval8(
                SimdLevel::detect(),
                tapes[i],
                &xyz[0],
                &xyz[1],
                &xyz[2],
                regs,
            );
            for j in i..N {
                if !done[j] && std::ptr::eq(tapes[j], tapes[i]) {
                    out[j] = d[j];
                    done[j] = true;
                }
            }
        }
    });
    out
}

/// The finite-difference step at distance t for the point p: a few ε(t), so the stencil
/// straddles the ε-shell the tracer stopped in, but never below 1e-4, where the rounding of
/// the field of a unit-sized object dominates the differences (below it, glass spheres at
/// ε = 1e-5 lost light to noisy normals), nor below [`RELATIVE_STEP`]·|p|∞, where the
/// rounding of p's own coordinates does (10,000 units from the origin p ± 1e-4 rounds back
/// to p in f32, and every normal came out along an axis).
pub fn step_for(s: &TracerSettings, t: f32, p: Vec3) -> f32 {
    (2.0 * epsilon_at(s, t))
        .max(STEP_FLOOR)
        .max(p.abs().max_element() * RELATIVE_STEP)
}

/// The absolute floor of the finite-difference step (see [`step_for`]).
pub const STEP_FLOOR: f32 = 1e-4;

/// The smallest finite-difference step relative to the point's largest coordinate: 2⁻¹⁶ (exact
/// to multiply by, on the CPU and in WGSL), at least 128 units in the last place of that
/// coordinate, so the rounding of the two sample points moves their distance 2h by under
/// 0.4 %. It exceeds 1e-4 only beyond 6.5 units from the origin.
pub const RELATIVE_STEP: f32 = 1.0 / 65536.0;

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
    let f = values(field, central_stencil(p, h));
    Vec3::new(f[0] - f[1], f[2] - f[3], f[4] - f[5]) / (2.0 * h)
}

/// The points of [`central`]'s stencil: p ± h along each axis.
fn central_stencil(p: Vec3, h: f32) -> [Vec3; 6] {
    [
        p + Vec3::X * h,
        p - Vec3::X * h,
        p + Vec3::Y * h,
        p - Vec3::Y * h,
        p + Vec3::Z * h,
        p - Vec3::Z * h,
    ]
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

    #[test]
    fn normals_hold_far_from_the_origin() {
        // A unit sphere 10,000 units out, with the default ε: the estimate at points of the
        // surface stays within a degree of the true normal (with the step's floor at 1e-4
        // alone, the normals there came out along the axes).
        let mut rng = Rng::new(11);
        let mut regs = Registers::new();
        let src = "Transform(translate: (10000, 0, 10000), shape: Sphere(radius: 1.0))";
        let centre = Vec3::new(1e4, 0.0, 1e4);
        let t = distance_tape(&parse_node(src));
        let scene = crate::scene::Scene::from_source(
            "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)))",
            std::path::Path::new("t.ron"),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let s = TracerSettings {
            epsilon: 1e-4,
            epsilon_per_unit: 0.0,
            ..scene.tracer
        };
        let mut field = FieldCursor::whole(&t, &mut regs);
        for _ in 0..200 {
            let n = rng.direction();
            let p = centre + n;
            let h = step_for(&s, 5.0, p);
            let (got, _) = estimate(&mut field, p, h, NormalMethod::Central);
            assert!(got.dot(n) > 1f32.to_radians().cos(), "{got} vs {n}");
        }
    }

    #[test]
    fn stencils_across_leaves_give_each_point_its_own_leaf_s_value() {
        // Small boxes side by side: stencils around their faces straddle leaves.
        let scene = crate::accel::field::tests::tiles_scene(8, 8);
        let tracer = crate::trace::SceneTracer::new(&scene);
        let field = &tracer.fields[0];
        assert!(field.octree.is_some(), "the union has an octree");
        let mut rng = Rng::new(9);
        let (mut regs, mut alone) = (Registers::new(), Registers::new());
        let mut straddling = 0;
        for _ in 0..3000 {
            let p = rng.vec3_in(-1.0, 1.0) * Vec3::new(1.0, 1.0, 0.2);
            let points = central_stencil(p, 0.01);
            let got = values(&mut field.cursor(&mut regs), points);
            let mut cursor = field.cursor(&mut alone);
            let tapes = points.map(|q| std::ptr::from_ref(cursor.region(q).tape));
            straddling += usize::from(tapes.iter().any(|&t| t != tapes[0]));
            for (q, g) in points.iter().zip(got) {
                let want = field.cursor(&mut alone).eval(*q);
                assert_eq!(g.to_bits(), want.to_bits(), "at {q}: {g} vs {want}");
            }
        }
        assert!(straddling > 100, "{straddling} stencils straddle leaves");
    }
}
