//! The bench's tape → fidget conversions compute what our tapes compute: fidget's point evaluator
//! against our interpreter at random points, for every elementary operation, for every object
//! of the shipped scenes and of the peer section's generated models (SSA conversion), and for
//! the compiled tapes the tracer runs, whole and specialised to octree leaves (register-tape
//! conversion). Runs with `--features fidget`.
#![cfg(feature = "fidget")]

mod common;
use common::assets;

use fidget::vm::VmShape;
use hytrace::bench::peer::{
    self,
    fidget::{tape_to_tree, to_tree},
};
use hytrace::rng::Rng;
use hytrace::scene::Scene;
use hytrace::sdf::ssa::{Builder, SsaTape};
use hytrace::sdf::tape::{Op, Shape, Tape};
use std::path::Path;

/// |b − a| / (1 + |a|), NaN on one side only infinitely wrong.
fn relative(a: f32, b: f32) -> f32 {
    if a.is_nan() && b.is_nan() || a == b {
        0.0
    } else if a.is_nan() || b.is_nan() {
        f32::INFINITY
    } else {
        (a - b).abs() / (1.0 + a.abs())
    }
}

/// [`worst`] for a compiled register tape, through [`tape_to_tree`].
fn worst_compiled(tape: &Tape, points: &[[f32; 3]]) -> (f32, [f32; 3], f32, f32) {
    let shape = VmShape::from(tape_to_tree(tape).expect("converts"));
    let fidget_tape = shape.point_tape(Default::default());
    let mut eval = VmShape::new_point_eval();
    let mut worst = (0.0f32, [0.0; 3], 0.0, 0.0);
    for &p in points {
        let a = tape.eval(glam::Vec3::from(p));
        let (b, _) = eval
            .eval(&fidget_tape, p[0], p[1], p[2])
            .expect("evaluates");
        let err = relative(a, b);
        if err > worst.0 {
            worst = (err, p, a, b);
        }
    }
    worst
}

/// Evaluates `tape` with fidget after conversion and with our interpreter at `points`; returns
/// the worst |difference| / (1 + |ours|) and where.
fn worst(tape: &SsaTape, points: &[[f32; 3]]) -> (f32, [f32; 3], f32, f32) {
    let ours = tape.compile_distance().expect("compiles");
    let shape = VmShape::from(to_tree(tape));
    let fidget_tape = shape.point_tape(Default::default());
    let mut eval = VmShape::new_point_eval();
    let mut worst = (0.0f32, [0.0; 3], 0.0, 0.0);
    for &p in points {
        let a = ours.eval(glam::Vec3::from(p));
        let (b, _) = eval
            .eval(&fidget_tape, p[0], p[1], p[2])
            .expect("evaluates");
        // NaN on one side only counts as the worst error.
        let err = relative(a, b);
        if err > worst.0 {
            worst = (err, p, a, b);
        }
    }
    worst
}

fn random_points(rng: &mut Rng, lo: glam::Vec3, hi: glam::Vec3, n: usize) -> Vec<[f32; 3]> {
    (0..n)
        .map(|_| {
            [
                rng.range_f32(lo.x, hi.x),
                rng.range_f32(lo.y, hi.y),
                rng.range_f32(lo.z, hi.z),
            ]
        })
        .collect()
}

#[test]
fn every_operation_converts() {
    let mut rng = Rng::new(5);
    let points = random_points(
        &mut rng,
        glam::Vec3::splat(-3.0),
        glam::Vec3::splat(3.0),
        500,
    );
    for &op in Op::ALL {
        let mut b = Builder::new();
        let [x, y, z] = b.point();
        // Operands inside each operation's domain: ln and sqrt of positive values, pow of a
        // non-negative base.
        let pos = b.unary(Op::Abs, x);
        let pos = b.with_imm(Op::AddImm, pos, 0.1);
        let v = match op.shape() {
            _ if op.is_material() || op == Op::Input => continue,
            Shape::Nullary => b.konst(1.25),
            Shape::Unary if matches!(op, Op::Sqrt | Op::Ln) => b.unary(op, pos),
            Shape::Unary => b.unary(op, x),
            Shape::Binary if op == Op::Pow => b.binary(op, pos, y),
            Shape::Binary => b.binary(op, x, y),
            Shape::WithImm if op == Op::PowImm => b.with_imm(op, pos, 1.7),
            Shape::WithImm => b.with_imm(op, x, 0.7),
            Shape::Ternary if op == Op::Select => b.select(z, x, y),
            Shape::Ternary => b.hypot3(x, y, z),
            Shape::MatLoad | Shape::MatMix => continue,
        };
        let tape = b.finish(v, None);
        let (err, p, a, f) = worst(&tape, &points);
        // sin, cos, tan, exp and ln are our own polynomial approximations; fidget calls the
        // standard library's.
        assert!(err <= 2e-5, "{op:?}: ours {a}, fidget {f} at {p:?}");
    }
}

#[test]
fn select_takes_the_right_branch_at_zero_values() {
    // c > 0 with a = 0 must give a (0), not b: what the and/or formulation has to get right.
    let mut b = Builder::new();
    let [x, y, z] = b.point();
    let v = b.select(z, x, y);
    let tape = b.finish(v, None);
    let points = [
        [0.0, 2.0, 1.0],
        [3.0, 0.0, 1.0],
        [3.0, 2.0, -1.0],
        [3.0, 2.0, 0.0],
    ];
    assert_eq!(worst(&tape, &points).0, 0.0);
}

/// The shipped scenes and the peer section's generated models.
fn shipped_and_generated() -> Vec<(String, Scene)> {
    // hybrid.ron finds its meshes through HYTRACE_ASSETS.
    if std::env::var_os("HYTRACE_ASSETS").is_none() {
        // SAFETY: set before any thread of this test reads the environment.
        unsafe { std::env::set_var("HYTRACE_ASSETS", assets()) };
    }
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes");
    let mut scenes: Vec<(String, Scene)> = hytrace::scene::scene_files(&dir)
        .expect("assets/scenes")
        .iter()
        .map(|p| (p.display().to_string(), Scene::load(p).expect("loads")))
        .collect();
    for (name, source) in peer::generated() {
        scenes.push((
            name.clone(),
            Scene::from_source(&source, Path::new(&name)).unwrap(),
        ));
    }
    scenes
}

#[test]
fn every_shipped_and_generated_model_converts() {
    let scenes = shipped_and_generated();
    let mut rng = Rng::new(9);
    for (name, scene) in &scenes {
        for o in &scene.objects {
            let b = o.bounds();
            let (lo, hi) = if b.is_finite() {
                let pad = 0.1 * (b.max - b.min).max_element();
                (b.min - pad, b.max + pad)
            } else {
                (glam::Vec3::splat(-5.0), glam::Vec3::splat(5.0))
            };
            let points = random_points(&mut rng, lo, hi, 300);
            let (err, p, a, f) = worst(&o.lowered.program, &points);
            assert!(
                err <= 1e-4,
                "{name} / {}: ours {a}, fidget {f} at {p:?}",
                o.name
            );
        }
    }
}

/// Leaves checked per object (evenly spread over the octree's leaves), points per leaf.
const LEAVES: usize = 48;
const LEAF_POINTS: usize = 24;

#[test]
fn compiled_whole_and_leaf_tapes_convert() {
    let mut rng = Rng::new(17);
    let mut checked = 0;
    for (name, scene) in &shipped_and_generated() {
        let fields = hytrace::trace::build_fields(scene, true, true);
        for (o, field) in scene.objects.iter().zip(&fields) {
            let b = o.bounds();
            let (lo, hi) = if b.is_finite() {
                let pad = 0.1 * (b.max - b.min).max_element();
                (b.min - pad, b.max + pad)
            } else {
                (glam::Vec3::splat(-5.0), glam::Vec3::splat(5.0))
            };
            let points = random_points(&mut rng, lo, hi, 200);
            let (err, p, a, f) = worst_compiled(&field.whole, &points);
            assert!(
                err <= 1e-4,
                "{name} / {} whole tape: ours {a}, fidget {f} at {p:?}",
                o.name
            );
            let Some(tree) = &field.octree else { continue };
            let leaves = tree.leaf_boxes();
            let step = leaves.len().div_ceil(LEAVES).max(1);
            for (i, (leaf, cell)) in leaves.iter().enumerate().step_by(step) {
                let tape = &tree.tapes[leaf.tape as usize];
                let points = random_points(&mut rng, cell.min, cell.max, LEAF_POINTS);
                let (err, p, a, f) = worst_compiled(tape, &points);
                assert!(
                    err <= 1e-4,
                    "{name} / {} leaf {i} ({:?}, {} instructions): ours {a}, fidget {f} at {p:?}",
                    o.name,
                    leaf.verdict,
                    tape.len()
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 100, "only {checked} leaf tapes checked");
}

#[test]
fn an_empty_tape_converts_to_its_input_register() {
    // No instruction: the result is register 0, the point's x (a degenerate tape).
    let empty = Tape::default();
    let (err, p, a, f) = worst_compiled(&empty, &[[1.5, -2.0, 3.0], [-0.25, 0.0, 0.0]]);
    assert_eq!(err, 0.0, "ours {a}, fidget {f} at {p:?}");
}
