//! The SDF conformance suite: checks written once and run against every tape evaluator.
//!
//! Each check takes an [`Evaluator`] so the same cases run on every tape evaluator — the scalar
//! and SIMD interpreters, interval arithmetic, the GPU's WGSL interpreter and fidget's VM and
//! JIT — one test per (case, evaluator) in tests/sdf_conformance.rs, as in fidget's shared
//! evaluator tests. The cases cover every node kind: closed-form distances,
//! sampled Lipschitz bounds, and |∇f| = 1 for exact fields.

use crate::geom::Aabb;
use crate::sdf::tape::Tape;
use crate::sdf::{SdfNode, lower};
use glam::Vec3;

/// fidget's demo shape max(‖30p‖ − 25, |gyroid(30p)| − 0.2) as an SDF tree (scene-file
/// syntax): the exact sphere of radius 25/30 intersected with the gyroid shell as an
/// implicit, traced as f/λ with λ = 30·√6 ≈ 73.5 (|∇ gyroid| ≤ √6). Each argument of the max
/// is the original one times a positive constant, so the surface is the same. The peer
/// benchmark renders it beside fidget; tests use it as a short tape whose leaves drop half
/// of it.
pub const FIDGET_GYROID_SPHERE: &str = "Intersection([Sphere(radius: 0.8333333), \
    Implicit(expr: \"abs(sin(30*x)*cos(30*y) + sin(30*y)*cos(30*z) + sin(30*z)*cos(30*x)) - 0.2\", \
    lipschitz: 73.5, half_extents: (0.84, 0.84, 0.84))])";

/// A batch evaluator: distances of `tape` at `points`.
pub trait Evaluator {
    /// Evaluates the tape at every point.
    fn eval(&self, tape: &Tape, points: &[Vec3]) -> Vec<f32>;
}

/// The CPU tape interpreter as an [`Evaluator`].
pub struct CpuEvaluator;

impl Evaluator for CpuEvaluator {
    fn eval(&self, tape: &Tape, points: &[Vec3]) -> Vec<f32> {
        points.iter().map(|&p| tape.eval(p)).collect()
    }
}

/// The packet interpreter at one SIMD level as an [`Evaluator`]: points eight at a time
/// (the last packet padded with its first point).
pub struct SimdEvaluator(pub crate::sdf::simd::SimdLevel);

impl Evaluator for SimdEvaluator {
    fn eval(&self, tape: &Tape, points: &[Vec3]) -> Vec<f32> {
        let mut regs = crate::sdf::simd::PacketRegisters::new();
        let mut out = Vec::with_capacity(points.len());
        for chunk in points.chunks(8) {
            let mut xyz = [[chunk[0].x; 8], [chunk[0].y; 8], [chunk[0].z; 8]];
            for (i, p) in chunk.iter().enumerate() {
                for a in 0..3 {
                    xyz[a][i] = p[a];
                }
            }
            let v = crate::sdf::simd::eval8(self.0, tape, &xyz[0], &xyz[1], &xyz[2], &mut regs);
            out.extend_from_slice(&v[..chunk.len()]);
        }
        out
    }
}

/// Interval arithmetic over the degenerate box of each point as an [`Evaluator`]: the
/// enclosure's lower bound, the bound that decides a region holds no surface, so a lower
/// bound that is wrong (or loose where it should be tight) fails the same checks as a wrong
/// value. (The upper bound is not held to them: on a point box at a cell of `RepeatLimited`
/// it is up to 0.07 above the value, as both neighbouring copies are enclosed.)
pub struct IntervalEvaluator;

impl Evaluator for IntervalEvaluator {
    fn eval(&self, tape: &Tape, points: &[Vec3]) -> Vec<f32> {
        let mut regs = crate::sdf::interval::IntervalRegisters::new();
        points
            .iter()
            .map(|&p| crate::sdf::interval::eval_box(tape, p, p, &mut regs).lo)
            .collect()
    }
}

/// Native code ([`crate::sdf::jit`]) as an [`Evaluator`]: the tape compiled, then run eight
/// points at a time as the packet interpreter is. Only where [`crate::sdf::jit::available`].
pub struct NativeEvaluator;

impl Evaluator for NativeEvaluator {
    fn eval(&self, tape: &Tape, points: &[Vec3]) -> Vec<f32> {
        let mut native = tape.interpreted();
        crate::sdf::jit::compile_all(std::slice::from_mut(&mut native), usize::MAX);
        assert!(native.is_native(), "no native code was made for the tape");
        SimdEvaluator(crate::sdf::simd::SimdLevel::Avx2).eval(&native, points)
    }
}

/// Points on an (n + 1) × (n + 1) grid over each of the six faces of `b`: where a test looks
/// for a surface poking out of a box (a field ≤ 0 there).
pub fn points_on_faces(b: Aabb, n: usize) -> impl Iterator<Item = Vec3> {
    (0..3).flat_map(move |axis| {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        [b.min[axis], b.max[axis]]
            .into_iter()
            .flat_map(move |side| {
                (0..=n).flat_map(move |i| {
                    (0..=n).map(move |j| {
                        let mut p = Vec3::ZERO;
                        p[axis] = side;
                        p[u] = b.min[u] + (b.max[u] - b.min[u]) * i as f32 / n as f32;
                        p[v] = b.min[v] + (b.max[v] - b.min[v]) * j as f32 / n as f32;
                        p
                    })
                })
            })
    })
}

/// Parses one SDF node written in scene syntax (for tests and examples).
pub fn parse_node(src: &str) -> SdfNode {
    ron::Options::default()
        .with_default_extension(ron::extensions::Extensions::IMPLICIT_SOME)
        .from_str(src)
        .unwrap_or_else(|e| panic!("test node `{src}` does not parse: {e}"))
}

/// Lowers a node with every material resolving to 0; returns the distance tape.
pub fn distance_tape(node: &SdfNode) -> Tape {
    lower(node, &|_| Some(0), 0)
        .unwrap_or_else(|e| panic!("test node does not lower: {e}"))
        .distance
}

pub use crate::rng::Rng;

/// The distance tapes of the catalogue ([`CASES`]), each with the centre and half-size of the
/// region its samples are drawn from: what evaluator tests sweep.
pub fn case_tapes() -> Vec<(String, Tape, Vec3, f32)> {
    CASES
        .iter()
        .map(|case| {
            let tape = distance_tape(&parse_node(case.src));
            (case.name.to_string(), tape, Vec3::ZERO, case.extent)
        })
        .collect()
}

/// Closed-form distance oracles for the primitives (independent of the lowering code).
pub mod oracle {
    use glam::{Vec2, Vec3};

    /// Signed distance from q to a simple polygon (negative inside).
    pub fn polygon(q: Vec2, verts: &[Vec2]) -> f32 {
        let mut d = f32::INFINITY;
        let mut inside = false;
        for i in 0..verts.len() {
            let (a, b) = (verts[i], verts[(i + 1) % verts.len()]);
            let ab = b - a;
            let t = ((q - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
            d = d.min((q - (a + ab * t)).length());
            if (a.y > q.y) != (b.y > q.y) && q.x < a.x + (q.y - a.y) / (b.y - a.y) * (b.x - a.x) {
                inside = !inside;
            }
        }
        if inside { -d } else { d }
    }

    /// Distance to an axis-aligned box [−b, b]: by clamping outside, by the nearest face inside.
    pub fn cuboid(p: Vec3, b: Vec3) -> f32 {
        let outside = (p - p.clamp(-b, b)).length();
        if outside > 0.0 {
            outside
        } else {
            -(b - p.abs()).min_element()
        }
    }

    /// Distance to a solid of revolution about y with the given (radius, y) profile polygon.
    pub fn revolved(p: Vec3, profile: &[Vec2]) -> f32 {
        let q = Vec2::new(Vec2::new(p.x, p.z).length(), p.y);
        polygon(q, profile)
    }

    /// Distance to the segment a–b minus r.
    pub fn capsule(p: Vec3, a: Vec3, b: Vec3, r: f32) -> f32 {
        let ab = b - a;
        let t = ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
        (p - (a + ab * t)).length() - r
    }
}

/// A named test shape with its sampling region.
pub struct Case {
    /// Label for failures.
    pub name: &'static str,
    /// Scene syntax of the node.
    pub src: &'static str,
    /// Whether |∇f| = 1 almost everywhere (an exact distance).
    pub exact: bool,
    /// Half-size of the region sampled.
    pub extent: f32,
}

/// Every node kind, alone and combined: the catalogue the suite runs over.
pub const CASES: &[Case] = &[
    Case {
        name: "sphere",
        src: "Sphere(radius: 1.0)",
        exact: true,
        extent: 2.5,
    },
    Case {
        name: "box",
        src: "Box(half_extents: (1.0, 0.5, 0.75))",
        exact: true,
        extent: 2.5,
    },
    Case {
        name: "round box",
        src: "RoundBox(half_extents: (1.0, 0.5, 0.75), radius: 0.2)",
        exact: true,
        extent: 2.5,
    },
    Case {
        name: "plane",
        src: "Plane(normal: (0.3, 1.0, 0.2), offset: 0.25)",
        exact: true,
        extent: 2.5,
    },
    Case {
        name: "torus",
        src: "Torus(major: 1.0, minor: 0.3)",
        exact: true,
        extent: 2.5,
    },
    Case {
        name: "cylinder",
        src: "Cylinder(half_height: 0.8, radius: 0.5)",
        exact: true,
        extent: 2.5,
    },
    Case {
        name: "cone",
        src: "Cone(half_height: 0.8, bottom_radius: 0.7, top_radius: 0.2)",
        exact: true,
        extent: 2.5,
    },
    Case {
        name: "pointed cone",
        src: "Cone(half_height: 1.0, bottom_radius: 0.8, top_radius: 0.0)",
        exact: true,
        extent: 2.5,
    },
    Case {
        name: "capsule",
        src: "Capsule(a: (-0.5, -0.3, 0.1), b: (0.6, 0.4, -0.2), radius: 0.35)",
        exact: true,
        extent: 2.5,
    },
    Case {
        name: "ellipsoid",
        src: "Ellipsoid(radii: (1.2, 0.6, 0.8))",
        exact: false,
        extent: 2.5,
    },
    Case {
        name: "octahedron",
        src: "Octahedron(size: 1.0)",
        exact: true,
        extent: 2.5,
    },
    Case {
        name: "hex prism",
        src: "HexPrism(radius: 0.6, half_length: 0.8)",
        exact: true,
        extent: 2.5,
    },
    Case {
        name: "union",
        src: "Union([Sphere(radius: 0.8), Transform(translate: (0.9, 0, 0), shape: Box(half_extents: (0.5, 0.5, 0.5)))])",
        exact: false,
        extent: 2.5,
    },
    Case {
        name: "intersection",
        src: "Intersection([Sphere(radius: 1.0), Box(half_extents: (0.8, 0.8, 0.8))])",
        exact: false,
        extent: 2.5,
    },
    Case {
        name: "subtraction",
        src: "Subtraction(base: Box(half_extents: (1, 1, 1)), cut: Sphere(radius: 1.2))",
        exact: false,
        extent: 2.5,
    },
    Case {
        name: "smooth union",
        src: "SmoothUnion(k: 0.5, shapes: [Sphere(radius: 0.7), Transform(translate: (0.8, 0.3, 0), shape: Sphere(radius: 0.5))])",
        exact: false,
        extent: 2.5,
    },
    Case {
        name: "smooth intersection",
        src: "SmoothIntersection(k: 0.3, shapes: [Sphere(radius: 1.0), Box(half_extents: (0.8, 0.8, 0.8))])",
        exact: false,
        extent: 2.5,
    },
    Case {
        name: "smooth subtraction",
        src: "SmoothSubtraction(k: 0.3, base: Box(half_extents: (1, 1, 1)), cut: Sphere(radius: 1.1))",
        exact: false,
        extent: 2.5,
    },
    Case {
        name: "round",
        src: "Round(radius: 0.2, shape: Box(half_extents: (0.6, 0.6, 0.6)))",
        exact: true,
        extent: 2.5,
    },
    Case {
        name: "onion",
        src: "Onion(thickness: 0.1, shape: Sphere(radius: 1.0))",
        exact: true,
        extent: 2.5,
    },
    Case {
        name: "transform",
        src: "Transform(translate: (0.3, -0.2, 0.1), rotate: (30, 45, 60), scale: 1.7, shape: Box(half_extents: (0.5, 0.3, 0.4)))",
        exact: true,
        extent: 2.5,
    },
    Case {
        name: "non-uniform scale",
        src: "Scale(factors: (2.0, 0.5, 1.0), shape: Sphere(radius: 0.8))",
        exact: false,
        extent: 2.5,
    },
    Case {
        name: "repeat",
        src: "Repeat(period: (1.5, 0, 1.5), shape: Sphere(radius: 0.4))",
        exact: false,
        extent: 4.0,
    },
    Case {
        name: "repeat limited",
        src: "RepeatLimited(period: (1.0, 1.2, 1.0), copies_each_side: (2, 1, 0), shape: Box(half_extents: (0.3, 0.2, 0.3)))",
        exact: false,
        extent: 4.0,
    },
    Case {
        name: "twist",
        src: "Twist(rate: 1.5, shape: Box(half_extents: (0.5, 1.0, 0.3)))",
        exact: false,
        extent: 2.5,
    },
    Case {
        name: "bend",
        src: "Bend(rate: 0.8, shape: Box(half_extents: (1.0, 0.2, 0.4)))",
        exact: false,
        extent: 2.5,
    },
    Case {
        name: "implicit sphere",
        src: "Implicit(expr: \"x*x + y*y + z*z - 1\")",
        exact: false,
        extent: 3.0,
    },
    Case {
        name: "implicit squircle",
        src: "Implicit(expr: \"max(0.5*(max(abs(x),abs(y)) - 1) + 0.5*(x*x + y*y - 1), abs(z) - 0.5)\", half_extents: (1.5, 1.5, 1.0))",
        exact: false,
        extent: 3.0,
    },
    Case {
        name: "implicit gyroid",
        src: "Implicit(expr: \"sin(3*x)*cos(3*y) + sin(3*y)*cos(3*z) + sin(3*z)*cos(3*x)\", half_extents: (1, 1, 1))",
        exact: false,
        extent: 2.0,
    },
    Case {
        name: "implicit given lipschitz",
        src: "Implicit(expr: \"x*x + y*y + z*z - 1\", lipschitz: 7.0, half_extents: (1.5, 1.5, 1.5))",
        exact: false,
        extent: 3.0,
    },
];

/// Samples random pairs of points and returns the largest |f(a) − f(b)| / |a − b| seen.
/// Pairs are both far apart and close together, so both global and local slopes are probed.
pub fn sampled_lipschitz(
    ev: &dyn Evaluator,
    tape: &Tape,
    extent: f32,
    pairs: usize,
    seed: u64,
) -> f32 {
    let mut rng = Rng::new(seed);
    let lo = Vec3::splat(-extent);
    let hi = Vec3::splat(extent);
    let mut a = Vec::with_capacity(pairs);
    let mut b = Vec::with_capacity(pairs);
    for i in 0..pairs {
        let p = rng.in_box(lo, hi);
        let step = if i % 2 == 0 {
            1e-2
        } else {
            extent * rng.next_f32()
        };
        a.push(p);
        b.push(p + rng.direction() * step.max(1e-3));
    }
    let fa = ev.eval(tape, &a);
    let fb = ev.eval(tape, &b);
    (0..pairs)
        .map(|i| (fa[i] - fb[i]).abs() / (a[i] - b[i]).length())
        .filter(|v| v.is_finite())
        .fold(0.0, f32::max)
}

/// Fraction of random points where the central-difference gradient has length within `tol`
/// of 1 (an exact distance field has |∇f| = 1 except on its medial axis).
pub fn unit_gradient_fraction(
    ev: &dyn Evaluator,
    tape: &Tape,
    extent: f32,
    n: usize,
    tol: f32,
    seed: u64,
) -> f32 {
    let mut rng = Rng::new(seed);
    let h = 1e-3;
    let mut pts = Vec::with_capacity(n * 6);
    for _ in 0..n {
        let p = rng.in_box(Vec3::splat(-extent), Vec3::splat(extent));
        for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
            pts.push(p + axis * h);
            pts.push(p - axis * h);
        }
    }
    let f = ev.eval(tape, &pts);
    let good = (0..n)
        .filter(|&i| {
            let g = Vec3::new(
                f[6 * i] - f[6 * i + 1],
                f[6 * i + 2] - f[6 * i + 3],
                f[6 * i + 4] - f[6 * i + 5],
            ) / (2.0 * h);
            (g.length() - 1.0).abs() < tol
        })
        .count();
    good as f32 / n as f32
}

/// The suite's checks of one case ([`CASES`]`[k]`) on an evaluator: a sampled Lipschitz
/// constant of at most 1 and, for exact fields, |∇f| ≈ 1 almost everywhere. Returns every
/// failure, each naming the case; one case at a time so that a test per (case, evaluator)
/// names what failed.
pub fn check_case(ev: &dyn Evaluator, k: usize) -> Result<(), String> {
    let case = &CASES[k];
    let mut failures = Vec::new();
    let tape = distance_tape(&parse_node(case.src));
    let lambda = sampled_lipschitz(ev, &tape, case.extent, 4000, 17 + k as u64);
    if lambda > 1.0 + 2e-3 {
        failures.push(format!(
            "{}: sampled Lipschitz constant {lambda} > 1",
            case.name
        ));
    }
    if case.exact {
        let frac = unit_gradient_fraction(ev, &tape, case.extent, 2000, 1e-2, 91 + k as u64);
        if frac < 0.97 {
            failures.push(format!(
                "{}: |∇f| ≈ 1 at only {:.1}% of points",
                case.name,
                100.0 * frac
            ));
        }
    }
    if failures.is_empty() {
        Ok(())
    } else {
        Err(failures.join("\n"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec2;
    use proptest::prelude::*;

    fn tape(src: &str) -> Tape {
        distance_tape(&parse_node(src))
    }

    fn vec3() -> impl Strategy<Value = Vec3> {
        (-3.0f32..3.0, -3.0f32..3.0, -3.0f32..3.0).prop_map(|(x, y, z)| Vec3::new(x, y, z))
    }

    const TOL: f32 = 2e-5;

    #[test]
    fn native_code_gives_the_interpreter_bits_on_every_case() {
        // (here rather than in `sdf::jit`, which the catalogue builds on)
        if !crate::sdf::jit::available() {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "no AVX2 on this CPU under CI: native code cannot be tested"
            );
            eprintln!("SKIPPED: no AVX2 on this CPU, so no native code to compare");
            return;
        }
        let mut rng = crate::rng::Rng::new(17);
        for (name, tape, c, r) in case_tapes() {
            let pts: Vec<Vec3> = (0..512)
                .map(|_| c + rng.vec3_in(-r, r))
                .chain([Vec3::ZERO, c, Vec3::splat(1e6), Vec3::splat(-0.0)])
                .collect();
            let want = CpuEvaluator.eval(&tape, &pts);
            let got = NativeEvaluator.eval(&tape, &pts);
            for ((p, w), g) in pts.iter().zip(&want).zip(&got) {
                assert!(
                    w.to_bits() == g.to_bits() || (w.is_nan() && g.is_nan()),
                    "{name} at {p}: native {g} vs interpreter {w}"
                );
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        #[test]
        fn sphere_matches_closed_form(p in vec3(), r in 0.1f32..2.0) {
            let t = tape(&format!("Sphere(radius: {r})"));
            prop_assert!((t.eval(p) - (p.length() - r)).abs() < TOL);
        }

        #[test]
        fn box_matches_closed_form(p in vec3(), bx in 0.1f32..2.0, by in 0.1f32..2.0, bz in 0.1f32..2.0) {
            let t = tape(&format!("Box(half_extents: ({bx}, {by}, {bz}))"));
            prop_assert!((t.eval(p) - oracle::cuboid(p, Vec3::new(bx, by, bz))).abs() < TOL);
        }

        #[test]
        fn round_box_is_inner_box_minus_radius(p in vec3(), r in 0.0f32..0.3) {
            let b = Vec3::new(1.0, 0.6, 0.8);
            let t = tape(&format!("RoundBox(half_extents: ({}, {}, {}), radius: {r})", b.x, b.y, b.z));
            let expect = oracle::cuboid(p, b - Vec3::splat(r)) - r;
            prop_assert!((t.eval(p) - expect).abs() < TOL);
        }

        #[test]
        fn plane_matches_closed_form(p in vec3(), off in -2.0f32..2.0) {
            let n = Vec3::new(1.0, 2.0, -0.5).normalize();
            let t = tape(&format!("Plane(normal: (1, 2, -0.5), offset: {off})"));
            prop_assert!((t.eval(p) - (n.dot(p) - off)).abs() < TOL);
        }

        #[test]
        fn torus_matches_closed_form(p in vec3(), big in 0.5f32..2.0, small in 0.05f32..0.5) {
            let t = tape(&format!("Torus(major: {big}, minor: {small})"));
            let q = Vec2::new(Vec2::new(p.x, p.z).length() - big, p.y);
            prop_assert!((t.eval(p) - (q.length() - small)).abs() < TOL);
        }

        #[test]
        fn cylinder_matches_revolved_rectangle(p in vec3(), h in 0.1f32..2.0, r in 0.1f32..2.0) {
            let t = tape(&format!("Cylinder(half_height: {h}, radius: {r})"));
            // The profile mirrored about the axis: the axis itself is no boundary.
            let full = [Vec2::new(-r, -h), Vec2::new(r, -h), Vec2::new(r, h), Vec2::new(-r, h)];
            let q = Vec2::new(Vec2::new(p.x, p.z).length(), p.y);
            prop_assert!((t.eval(p) - oracle::polygon(q, &full)).abs() < TOL);
        }

        #[test]
        fn cone_matches_revolved_trapezoid(p in vec3(), h in 0.2f32..1.5, r1 in 0.0f32..1.5, r2 in 0.0f32..1.5) {
            prop_assume!(r1 + r2 > 0.05);
            let t = tape(&format!("Cone(half_height: {h}, bottom_radius: {r1}, top_radius: {r2})"));
            let full = [Vec2::new(-r1, -h), Vec2::new(r1, -h), Vec2::new(r2, h), Vec2::new(-r2, h)];
            let q = Vec2::new(Vec2::new(p.x, p.z).length(), p.y);
            let expect = oracle::polygon(q, &full);
            prop_assert!((t.eval(p) - expect).abs() < 1e-4, "got {} expected {}", t.eval(p), expect);
        }

        #[test]
        fn capsule_matches_segment_distance(p in vec3(), r in 0.05f32..1.0) {
            let (a, b) = (Vec3::new(-0.5, -0.3, 0.1), Vec3::new(0.6, 0.4, -0.2));
            let t = tape(&format!("Capsule(a: (-0.5, -0.3, 0.1), b: (0.6, 0.4, -0.2), radius: {r})"));
            prop_assert!((t.eval(p) - oracle::capsule(p, a, b, r)).abs() < TOL);
        }

        #[test]
        fn hex_prism_matches_revolved_hexagon(p in vec3(), r in 0.2f32..1.5, hz in 0.1f32..1.5) {
            // Exact distance to a convex prism: 2D hexagon distance combined with the z slab.
            let t = tape(&format!("HexPrism(radius: {r}, half_length: {hz})"));
            let c = r * 2.0 / 3f32.sqrt();
            // Quilez's hexagon has flat sides at |y| = r (apothem along y), vertices on x.
            let hex: Vec<Vec2> = (0..6)
                .map(|i| {
                    let a = std::f32::consts::FRAC_PI_3 * i as f32;
                    Vec2::new(c * a.cos(), c * a.sin())
                })
                .collect();
            let d2 = oracle::polygon(Vec2::new(p.x, p.y), &hex);
            let dz = p.z.abs() - hz;
            let expect = Vec2::new(d2.max(0.0), dz.max(0.0)).length() + d2.max(dz).min(0.0);
            prop_assert!((t.eval(p) - expect).abs() < 1e-4, "got {} expected {}", t.eval(p), expect);
        }

        #[test]
        fn octahedron_matches_polytope_distance(p in vec3(), s in 0.2f32..2.0) {
            let t = tape(&format!("Octahedron(size: {s})"));
            prop_assert!((t.eval(p) - octahedron_oracle(p, s)).abs() < 1e-4,
                "got {} expected {}", t.eval(p), octahedron_oracle(p, s));
        }

        #[test]
        fn ellipsoid_is_a_bound_with_the_right_sign(p in vec3()) {
            let r = Vec3::new(1.2, 0.6, 0.8);
            let t = tape("Ellipsoid(radii: (1.2, 0.6, 0.8))");
            let inside = (p / r).length_squared() < 1.0;
            let f = t.eval(p);
            prop_assert_eq!(f < 0.0, inside);
            // a bound never exceeds the true distance: compare with the distance to a dense
            // set of surface points (which over-estimates the true distance by ≤ the spacing)
            let mut best = f32::INFINITY;
            for i in 0..=60 {
                for j in 0..120 {
                    let th = std::f32::consts::PI * i as f32 / 60.0;
                    let ph = 2.0 * std::f32::consts::PI * j as f32 / 120.0;
                    let s = r * Vec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin());
                    best = best.min((p - s).length());
                }
            }
            prop_assert!(f.abs() <= best + 1e-3, "|f| = {} > distance ≈ {}", f.abs(), best);
        }
    }

    /// Exact distance to the octahedron |x|+|y|+|z| ≤ s: outside, the distance to the nearest
    /// face, edge or vertex (all found as projections on the faces of the first octant, which
    /// suffices by symmetry); inside, the distance to the nearest face plane.
    fn octahedron_oracle(p: Vec3, s: f32) -> f32 {
        let q = p.abs();
        let n = Vec3::ONE / 3f32.sqrt();
        let plane = (q.dot(Vec3::ONE) - s) / 3f32.sqrt();
        if plane <= 0.0 {
            return plane;
        }
        // closest point on the triangle with vertices s·e_x, s·e_y, s·e_z
        let tri = [Vec3::X * s, Vec3::Y * s, Vec3::Z * s];
        let proj = q - n * plane;
        if proj.min_element() >= 0.0 {
            return plane;
        }
        let mut best = f32::INFINITY;
        for i in 0..3 {
            let (a, b) = (tri[i], tri[(i + 1) % 3]);
            let ab = b - a;
            let t = ((q - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
            best = best.min((q - (a + ab * t)).length());
        }
        best
    }

    #[test]
    fn smooth_union_blends_materials_with_the_same_weight() {
        // Two spheres with materials 1 and 2 (colour lane 0 = 0 and 1): halfway between them
        // the blend weight is ½, so the colour must be ½.
        let node = parse_node(
            "SmoothUnion(k: 1.0, shapes: [Material(name: \"a\", shape: Transform(translate: (-1, 0, 0), shape: Sphere(radius: 0.8))), Material(name: \"b\", shape: Transform(translate: (1, 0, 0), shape: Sphere(radius: 0.8)))])",
        );
        let low = lower(&node, &|n| Some(if n == "a" { 1 } else { 2 }), 0).unwrap();
        let mut table = [[0.0f32; crate::sdf::tape::MATERIAL_FLOATS]; 3];
        table[2][0] = 1.0;
        let (_, mid) = low.shading.eval_material(Vec3::new(0.0, 0.0, 0.0), &table);
        assert!(
            (mid[0] - 0.5).abs() < 1e-6,
            "blend at the midpoint is {}",
            mid[0]
        );
        let (_, left) = low.shading.eval_material(Vec3::new(-1.5, 0.0, 0.0), &table);
        assert_eq!(left[0], 0.0);
        let (_, right) = low.shading.eval_material(Vec3::new(1.5, 0.0, 0.0), &table);
        assert_eq!(right[0], 1.0);
        // and the distance-only tape carries no material work
        assert!(low.distance.instrs.len() < low.shading.instrs.len());
        assert_eq!(low.distance.material_result, None);
    }

    #[test]
    fn a_material_that_is_one_entry_is_read_without_evaluating() {
        let mut table = [[0.0f32; crate::sdf::tape::MATERIAL_FLOATS]; 3];
        table[1][0] = 0.25;
        table[2][0] = 1.0;
        let materials = |n: &str| Some(if n == "a" { 1 } else { 2 });
        // one material: constant, and what evaluating the tape gives everywhere
        let one = lower(
            &parse_node("Material(name: \"b\", shape: Union([Sphere(radius: 1), Box(half_extents: (2, 0.1, 2))]))"),
            &materials,
            0,
        )
        .unwrap();
        assert!(one.shading.has_constant_material());
        // a blend: evaluated, so its value follows the point
        let blend = lower(
            &parse_node("SmoothUnion(k: 1.0, shapes: [Material(name: \"a\", shape: Transform(translate: (-1, 0, 0), shape: Sphere(radius: 0.8))), Material(name: \"b\", shape: Transform(translate: (1, 0, 0), shape: Sphere(radius: 0.8)))])"),
            &materials,
            0,
        )
        .unwrap();
        assert!(!blend.shading.has_constant_material());
        let mut rng = crate::rng::Rng::new(3);
        for _ in 0..200 {
            let p = rng.in_box(Vec3::splat(-3.0), Vec3::splat(3.0));
            for low in [&one, &blend] {
                assert_eq!(
                    low.shading.material_at(p, &table),
                    low.shading.eval_material(p, &table).1,
                    "at {p}"
                );
            }
        }
        assert_eq!(one.shading.material_at(Vec3::ZERO, &table)[0], 1.0);
    }

    #[test]
    fn smooth_min_is_the_documented_polynomial() {
        // f = a(1−h) + b·h − k·h(1−h), h = clamp(½ + ½(a−b)/k, 0, 1), for planes a = x, b = −x + c
        let t = tape(
            "SmoothUnion(k: 0.8, shapes: [Plane(normal: (1, 0, 0), offset: 0), Plane(normal: (-1, 0, 0), offset: -0.5)])",
        );
        for i in 0..50 {
            let x = -1.0 + i as f32 * 0.05;
            let (a, b, k) = (x, -x + 0.5, 0.8f32);
            let h = (0.5 + 0.5 * (a - b) / k).clamp(0.0, 1.0);
            let f = a * (1.0 - h) + b * h - k * h * (1.0 - h);
            assert!((t.eval(Vec3::new(x, 0.3, -0.2)) - f).abs() < 1e-5);
        }
    }

    #[test]
    fn transforms_apply_the_inverse_to_the_point() {
        let t = tape(
            "Transform(translate: (1, 2, 3), rotate: (0, 90, 0), scale: 2.0, shape: Box(half_extents: (1, 0.5, 0.25)))",
        );
        // after R_y(90°) the box's x half-extent 1·2 lies along −z…+z, and its z extent along x
        let c = Vec3::new(1.0, 2.0, 3.0);
        assert!((t.eval(c + Vec3::new(0.5, 0.0, 0.0)) - 0.0).abs() < 1e-5);
        assert!((t.eval(c + Vec3::new(0.0, 0.0, 2.0)) - 0.0).abs() < 1e-5);
        assert!((t.eval(c + Vec3::new(0.0, 3.0, 0.0)) - 2.0).abs() < 1e-5);
    }

    #[test]
    fn tapes_fit_the_register_limits_and_reuse_registers() {
        for case in CASES {
            let low = lower(&parse_node(case.src), &|_| Some(0), 0).unwrap();
            assert!(low.distance.registers <= crate::sdf::tape::MAX_REGISTERS);
            assert!(low.shading.registers <= crate::sdf::tape::MAX_REGISTERS);
            // registers 0–2 hold the point: without reuse a tape needs 3 + one per instruction
            assert!(
                low.distance.instrs.is_empty()
                    || low.distance.registers < 3 + low.distance.instrs.len(),
                "{}: {} registers for {} instructions: no reuse",
                case.name,
                low.distance.registers,
                low.distance.instrs.len()
            );
        }
    }

    #[test]
    fn implicit_lipschitz_estimate_bounds_the_gradient() {
        use crate::sdf::expr;
        // |∇(x²+y²+z²−1)| = 2|p| ≤ 2√3·1.5 on the box of half-size 1.5
        let e = expr::parse("x*x + y*y + z*z - 1").unwrap();
        let l = crate::sdf::lower::estimate_lipschitz(&e, Vec3::splat(1.5)).unwrap();
        let true_max = 2.0 * 3f32.sqrt() * 1.5;
        assert!(
            l >= true_max,
            "estimate {l} below the true bound {true_max}"
        );
        assert!(l <= 2.0 * true_max, "estimate {l} far above {true_max}");
        assert!(
            crate::sdf::lower::estimate_lipschitz(&expr::parse("1").unwrap(), Vec3::ONE).is_err()
        );
    }

    #[test]
    fn wgsl_constants_name_every_opcode() {
        let s = crate::sdf::tape::wgsl_constants();
        for op in crate::sdf::tape::Op::ALL {
            assert!(s.contains(&format!(
                "const OP_{}: u32 = {}u;",
                op.name().to_uppercase(),
                *op as u32
            )));
        }
    }
}
