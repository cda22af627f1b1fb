//! The tape's evaluators against each other on the shipped scenes and on random trees of every
//! node kind: SIMD lanes against the scalar interpreter (bit for bit), interval enclosures
//! against point samples, and region-specialised tapes against the whole tape.

mod common;

use glam::Vec3;
use hytrace::accel::field::FieldOctree;
use hytrace::rng::Rng;
use hytrace::scene::{Scene, scene_files};
use hytrace::sdf::conformance::{CASES, parse_node, points_on_faces};
use hytrace::sdf::interval::{IntervalRegisters, eval_box};
use hytrace::sdf::simd::{PacketRegisters, SimdLevel, eval8, material8};
use hytrace::sdf::simplify::{Fault, Simplifier, Verdict};
use hytrace::sdf::ssa::SsaTape;
use hytrace::sdf::tape::Tape;
use hytrace::sdf::{SdfNode, lower};
use proptest::prelude::*;
use std::path::Path;
use std::sync::OnceLock;

/// An object's programs and the region samples are drawn from.
struct Sample {
    name: String,
    program: SsaTape,
    tape: Tape,
    centre: Vec3,
    reach: f32,
}

fn lowered(name: String, node: &SdfNode, centre: Vec3, reach: f32) -> Sample {
    let l = lower(node, &|_| Some(0), 0).unwrap_or_else(|e| panic!("{name}: {e}"));
    Sample {
        name,
        program: l.program,
        tape: l.distance,
        centre,
        reach,
    }
}

/// Every shipped scene's objects and the conformance catalogue.
fn samples() -> &'static [Sample] {
    static SAMPLES: OnceLock<Vec<Sample>> = OnceLock::new();
    SAMPLES.get_or_init(|| {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes");
        let mut out = Vec::new();
        for file in scene_files(&dir).unwrap() {
            let scene = Scene::load(&file).unwrap_or_else(|e| panic!("{e}"));
            let stem = file.file_stem().unwrap().to_string_lossy().into_owned();
            for o in &scene.objects {
                let b = o.bounds();
                let (c, r) = if b.is_finite() {
                    (b.center(), 0.6 * (b.max - b.min).max_element() + 0.5)
                } else {
                    (Vec3::ZERO, 8.0)
                };
                out.push(Sample {
                    name: format!("{stem}/{}", o.name),
                    program: o.lowered.program.clone(),
                    tape: o.lowered.distance.clone(),
                    centre: c,
                    reach: r,
                });
            }
        }
        for case in CASES {
            out.push(lowered(
                case.name.to_string(),
                &parse_node(case.src),
                Vec3::ZERO,
                case.extent,
            ));
        }
        out
    })
}

fn levels() -> Vec<SimdLevel> {
    let mut v = vec![SimdLevel::Portable];
    if cfg!(target_arch = "x86_64") {
        v.push(SimdLevel::Sse2);
    }
    if SimdLevel::detect() == SimdLevel::Avx2 {
        v.push(SimdLevel::Avx2);
    }
    v
}

/// Same value: the same bits, or both NaN, or zeros of either sign.
fn same(a: f32, b: f32) -> bool {
    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()) || (a == 0.0 && b == 0.0)
}

/// Up to eight points as SIMD lanes: x, y and z across them (unused lanes zero).
fn lanes_of(points: &[Vec3]) -> [[f32; 8]; 3] {
    let mut xyz = [[0.0f32; 8]; 3];
    for (i, p) in points.iter().enumerate() {
        for a in 0..3 {
            xyz[a][i] = p[a];
        }
    }
    xyz
}

#[test]
fn simd_lanes_give_the_scalar_bits_on_every_shipped_object() {
    let mut rng = Rng::new(11);
    let mut regs = PacketRegisters::new();
    for s in samples() {
        let pts: Vec<Vec3> = (0..512)
            .map(|_| s.centre + rng.vec3_in(-s.reach, s.reach))
            .collect();
        for level in levels() {
            for chunk in pts.chunks(8) {
                let xyz = lanes_of(chunk);
                let got = eval8(level, &s.tape, &xyz[0], &xyz[1], &xyz[2], &mut regs);
                for (i, p) in chunk.iter().enumerate() {
                    let want = s.tape.eval(*p);
                    assert!(
                        got[i].to_bits() == want.to_bits() || (got[i].is_nan() && want.is_nan()),
                        "{level:?} {} at {p}: {} vs {want}",
                        s.name,
                        got[i]
                    );
                }
            }
        }
    }
}

#[test]
fn simd_materials_give_the_scalar_bits_on_every_shipped_object() {
    // the objects whose shading tapes blend materials (checkerboards, smooth blends, unions
    // of differently coloured shapes): every float of the material, bit for bit
    let mut rng = Rng::new(12);
    let mut regs = PacketRegisters::new();
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes");
    let (mut blended, mut fractional) = (0, 0);
    for file in scene_files(&dir).unwrap() {
        let scene = Scene::load(&file).unwrap_or_else(|e| panic!("{e}"));
        let table = scene.material_table();
        for o in &scene.objects {
            let tape = &o.lowered.shading;
            if tape.has_constant_material() {
                continue;
            }
            blended += 1;
            let b = o.bounds();
            let (c, r) = if b.is_finite() {
                (b.center(), 0.6 * (b.max - b.min).max_element() + 0.5)
            } else {
                (Vec3::ZERO, 8.0)
            };
            let pts: Vec<Vec3> = (0..512).map(|_| c + rng.vec3_in(-r, r)).collect();
            for level in levels() {
                for chunk in pts.chunks(8) {
                    let xyz = lanes_of(chunk);
                    let got = material8(level, tape, &xyz[0], &xyz[1], &xyz[2], &table, &mut regs);
                    for (i, p) in chunk.iter().enumerate() {
                        let (_, want) = tape.eval_material(*p, &table);
                        let mixed = want.iter().zip(&table[0]).any(|(w, t)| w != t);
                        fractional += usize::from(level == SimdLevel::Portable && mixed);
                        for (k, w) in want.iter().enumerate() {
                            assert!(
                                got[k][i].to_bits() == w.to_bits()
                                    || (got[k][i].is_nan() && w.is_nan()),
                                "{level:?} {}/{} at {p}, float {k}: {} vs {w}",
                                file.display(),
                                o.name,
                                got[k][i]
                            );
                        }
                    }
                }
            }
        }
    }
    assert!(blended >= 4, "only {blended} objects blend materials");
    assert!(
        fractional > 0,
        "no point took another material than the first"
    );
}

#[test]
fn distances_found_together_are_each_point_s_distance() {
    // every shipped scene: points around its objects, near and far, in one call against one
    // at a time (equal values: only a zero's sign may differ, min taking objects in another
    // order)
    let mut rng = Rng::new(13);
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes");
    let mut near = 0;
    for file in scene_files(&dir).unwrap() {
        let scene = Scene::load(&file).unwrap_or_else(|e| panic!("{e}"));
        let tracer = hytrace::trace::SceneTracer::new(&scene);
        let points: Vec<Vec3> = (0..400).map(|_| rng.vec3_in(-4.0, 4.0)).collect();
        for reach in [0.05, 0.6, 10.0] {
            let mut together = vec![0.0; points.len()];
            tracer.distances(&points, reach, &mut together);
            for (p, d) in points.iter().zip(&together) {
                let alone = tracer.distance(*p, reach);
                assert!(
                    same(*d, alone),
                    "{} at {p} within {reach}: {d} vs {alone}",
                    file.display()
                );
                near += usize::from(alone < reach);
            }
        }
    }
    assert!(near > 1000, "only {near} points near an object");
}

/// A random box inside a sample's region: half-sizes from 10⁻³ of its reach to about all of
/// it, some flat along an axis.
fn random_box(rng: &mut Rng, centre: Vec3, reach: f32) -> (Vec3, Vec3) {
    let c = centre + rng.vec3_in(-reach, reach);
    let size = 10f32.powf(rng.range_f32(-3.0, 0.0)) * reach;
    let mut h = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * size;
    if rng.chance(0.1) {
        h[rng.below(3) as usize] = 0.0;
    }
    (c - h, c + h)
}

/// Checks a program's specialisations over `boxes` boxes: at sampled points the specialised
/// tape gives the whole tape's value, and the verdicts hold. Returns the first violation.
fn check_specialisation(
    simplifier: &mut Simplifier,
    s: &Sample,
    rng: &mut Rng,
    boxes: usize,
) -> Result<(), String> {
    for _ in 0..boxes {
        let (lo, hi) = random_box(rng, s.centre, s.reach);
        let sp = simplifier.specialise(&s.program, lo, hi);
        let tape = sp
            .program
            .distance_only()
            .compile()
            .map_err(|e| format!("{}: {e}", s.name))?;
        for _ in 0..64 {
            let p = rng.in_box(lo, hi);
            let (a, b) = (tape.eval(p), s.tape.eval(p));
            if !same(a, b) {
                return Err(format!(
                    "{} over {lo}..{hi}: specialised {a} vs whole {b} at {p}",
                    s.name
                ));
            }
            let wrong = match sp.verdict {
                Verdict::Empty => b <= 0.0,
                Verdict::Full => b >= 0.0,
                Verdict::Surface => false,
            };
            if wrong {
                return Err(format!(
                    "{} over {lo}..{hi}: {:?} but f = {b} at {p}",
                    s.name, sp.verdict
                ));
            }
        }
    }
    Ok(())
}

#[test]
fn specialised_tapes_equal_the_whole_tape_inside_their_box_on_every_shipped_object() {
    let mut rng = Rng::new(5);
    let mut simplifier = Simplifier::new();
    for s in samples() {
        check_specialisation(&mut simplifier, s, &mut rng, 48).unwrap_or_else(|e| panic!("{e}"));
    }
}

#[test]
fn interval_enclosures_contain_what_the_interpreter_computes() {
    // Exactly, with no slack: region specialisation relies on a decided branch being the one
    // the interpreter takes at every point.
    let mut rng = Rng::new(9);
    let mut regs = IntervalRegisters::new();
    for s in samples() {
        for _ in 0..64 {
            let (lo, hi) = random_box(&mut rng, s.centre, s.reach);
            let e = eval_box(&s.tape, lo, hi, &mut regs);
            for _ in 0..32 {
                let p = rng.in_box(lo, hi);
                let v = s.tape.eval(p);
                assert!(
                    e.contains(v),
                    "{}: f({p}) = {v} outside {e:?} over {lo}..{hi}",
                    s.name
                );
            }
        }
    }
}

/// Random SDF trees of every node kind, written in scene syntax.
fn tree(depth: u32) -> BoxedStrategy<String> {
    let v = |lo: f32, hi: f32| lo..hi;
    let leaf = prop_oneof![
        v(0.2, 1.0).prop_map(|r| format!("Sphere(radius: {r})")),
        (v(0.1, 0.8), v(0.1, 0.8), v(0.1, 0.8))
            .prop_map(|(x, y, z)| format!("Box(half_extents: ({x}, {y}, {z}))")),
        (v(0.4, 0.8), v(0.05, 0.3)).prop_map(|(a, b)| format!("Torus(major: {a}, minor: {b})")),
        (v(0.2, 0.8), v(0.1, 0.5))
            .prop_map(|(h, r)| format!("Cylinder(half_height: {h}, radius: {r})")),
        (v(0.2, 0.8), v(0.0, 0.6), v(0.1, 0.6)).prop_map(|(h, a, b)| format!(
            "Cone(half_height: {h}, bottom_radius: {a}, top_radius: {b})"
        )),
        v(0.1, 0.4)
            .prop_map(|r| format!("Capsule(a: (-0.4, 0, 0), b: (0.3, 0.4, 0.1), radius: {r})")),
        (v(0.2, 0.8), v(0.2, 0.8), v(0.2, 0.8))
            .prop_map(|(x, y, z)| format!("Ellipsoid(radii: ({x}, {y}, {z}))")),
        v(0.3, 0.9).prop_map(|s| format!("Octahedron(size: {s})")),
        (v(0.2, 0.6), v(0.1, 0.6))
            .prop_map(|(r, h)| format!("HexPrism(radius: {r}, half_length: {h})")),
        (v(0.5, 0.9), v(0.1, 0.4))
            .prop_map(|(r, t)| format!("RoundBox(half_extents: ({r}, {r}, {r}), radius: {t})")),
        Just(
            "Implicit(expr: \"sin(4*x)*cos(4*y) + sin(4*y)*cos(4*z) + sin(4*z)*cos(4*x)\", \
             lipschitz: 9.8, half_extents: (0.8, 0.8, 0.8))"
                .to_string()
        ),
        Just(
            "Implicit(expr: \"max(abs(x) + abs(y) - 0.6, x*x + y*y + z*z - 0.5)\", \
             half_extents: (0.9, 0.9, 0.9))"
                .to_string()
        ),
    ];
    if depth == 0 {
        return leaf.boxed();
    }
    let sub = || tree(depth - 1);
    let offset = || (v(-0.6, 0.6), v(-0.6, 0.6), v(-0.6, 0.6));
    prop_oneof![
        2 => leaf,
        1 => prop::collection::vec(sub(), 2..5).prop_map(|c| format!("Union([{}])", c.join(", "))),
        1 => prop::collection::vec(sub(), 2..4)
            .prop_map(|c| format!("Intersection([{}])", c.join(", "))),
        1 => (sub(), sub()).prop_map(|(a, b)| format!("Subtraction(base: {a}, cut: {b})")),
        1 => (v(0.05, 0.5), prop::collection::vec(sub(), 2..4)).prop_map(|(k, c)| format!(
            "SmoothUnion(k: {k}, shapes: [{}])",
            c.join(", ")
        )),
        1 => (v(0.05, 0.4), prop::collection::vec(sub(), 2..3)).prop_map(|(k, c)| format!(
            "SmoothIntersection(k: {k}, shapes: [{}])",
            c.join(", ")
        )),
        1 => (v(0.05, 0.4), sub(), sub())
            .prop_map(|(k, a, b)| format!("SmoothSubtraction(k: {k}, base: {a}, cut: {b})")),
        1 => (v(0.0, 0.1), sub()).prop_map(|(r, c)| format!("Round(radius: {r}, shape: {c})")),
        1 => (v(0.02, 0.1), sub()).prop_map(|(t, c)| format!("Onion(thickness: {t}, shape: {c})")),
        1 => (offset(), v(-90.0, 90.0), v(0.5, 1.5), sub()).prop_map(|((x, y, z), a, s, c)| format!(
            "Transform(translate: ({x}, {y}, {z}), rotate: ({a}, {}, 0), scale: {s}, shape: {c})",
            a * 0.5
        )),
        1 => (v(0.6, 1.4), v(0.6, 1.4), sub()).prop_map(|(a, b, c)| format!(
            "Scale(factors: ({a}, {b}, 1), shape: {c})"
        )),
        1 => sub().prop_map(|c| format!(
            "RepeatLimited(period: (2.5, 2.5, 2.5), copies_each_side: (1, 0, 1), shape: {c})"
        )),
        1 => (v(0.2, 1.5), sub()).prop_map(|(k, c)| format!("Twist(rate: {k}, shape: {c})")),
        1 => (v(0.1, 0.6), sub()).prop_map(|(k, c)| format!("Bend(rate: {k}, shape: {c})")),
        1 => sub().prop_map(|c| format!("Material(name: \"m\", shape: {c})")),
    ]
    .boxed()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Random trees of every node kind, random boxes, random points: the specialised tape
    /// equals the whole tape inside its box, and empty and full boxes are so.
    #[test]
    fn random_trees_specialise_exactly(src in tree(3), seed in any::<u64>()) {
        let node = parse_node(&src);
        let Ok(l) = lower(&node, &|_| Some(0), 0) else {
            // a random tree may be refused (a repetition's copies overlapping): not our case
            return Ok(());
        };
        let b = l.bounds;
        let (centre, reach) = if b.is_finite() {
            (b.center(), 0.6 * (b.max - b.min).max_element() + 0.3)
        } else {
            (Vec3::ZERO, 4.0)
        };
        let s = Sample { name: src.clone(), program: l.program, tape: l.distance, centre, reach };
        let mut rng = Rng::new(seed);
        let r = check_specialisation(&mut Simplifier::new(), &s, &mut rng, 8);
        prop_assert!(r.is_ok(), "{}", r.unwrap_err());
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Random trees of every node kind: the field is positive just outside the object's
    /// bounds (on a grid over each face), so the box the tracer, the octree and the referee
    /// clip the object to holds its whole surface — also where a parent keeps a child's field
    /// below a positive level (rounding, shells, smooth unions of distance bounds).
    #[test]
    fn random_trees_lie_inside_their_bounds(src in tree(3)) {
        let node = parse_node(&src);
        let Ok(l) = lower(&node, &|_| Some(0), 0) else {
            return Ok(());
        };
        prop_assume!(l.bounds.is_finite());
        let b = l.bounds.expand(1e-4 * (1.0 + (l.bounds.max - l.bounds.min).max_element()));
        for p in points_on_faces(b, 32) {
            let f = l.distance.eval(p);
            prop_assert!(f > 0.0, "{src}: f = {f} at {p}, outside {:?}", l.bounds);
        }
    }
}

#[test]
fn a_simplifier_that_keeps_the_wrong_branch_is_caught() {
    // The check above has teeth: the same sweep over the shipped objects with every decided
    // choice flipped finds a wrong value or verdict.
    let mut rng = Rng::new(5);
    let mut wrong = Simplifier::new();
    wrong.fault = Fault::WrongBranch;
    let caught = samples()
        .iter()
        .filter(|s| check_specialisation(&mut wrong, s, &mut rng, 16).is_err())
        .count();
    assert!(
        caught * 2 > samples().len(),
        "only {caught} of {} objects caught",
        samples().len()
    );
}

#[test]
fn octrees_of_the_shipped_scenes_match_the_whole_tape_at_every_leaf() {
    // Every leaf's tapes at points of its box, against the whole tapes.
    let mut rng = Rng::new(3);
    for s in samples().iter().filter(|s| s.centre.is_finite()) {
        let region = hytrace::geom::Aabb::new(
            s.centre - Vec3::splat(s.reach),
            s.centre + Vec3::splat(s.reach),
        );
        let Some(octree) = FieldOctree::build(&s.program, region) else {
            continue;
        };
        for _ in 0..4000 {
            let p = s.centre + rng.vec3_in(-s.reach, s.reach);
            let cell = octree.locate(p).expect("inside the region");
            assert!(cell.contains(p));
            let (a, b) = (cell.tape.eval(p), s.tape.eval(p));
            assert!(same(a, b), "{} at {p}: leaf {a} vs whole {b}", s.name);
            let wrong = match cell.leaf.verdict {
                Verdict::Empty => b <= 0.0,
                Verdict::Full => b >= 0.0,
                Verdict::Surface => false,
            };
            assert!(
                !wrong,
                "{} at {p}: {:?} leaf, f = {b}",
                s.name, cell.leaf.verdict
            );
        }
    }
}

#[test]
fn packets_give_each_ray_its_own_answer_on_every_shipped_object() {
    use hytrace::trace::packet::{BUNDLE, Lane, PacketScratch, trace_hart_packet};
    use hytrace::trace::{SceneTracer, TraceResult, sphere::trace_hart};
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes");
    let mut rng = Rng::new(21);
    for file in scene_files(&dir).unwrap() {
        let scene = Scene::load(&file).unwrap_or_else(|e| panic!("{e}"));
        let tracer = SceneTracer::new(&scene);
        // camera rays in row order (coherent), and some scattered ones (incoherent)
        let mut rays = common::rays::camera_grid(&scene, 48, 36, 48.0 / 36.0);
        let b = scene.finite_bounds();
        for _ in 0..256 {
            let o = rng.in_box(b.min - Vec3::splat(1.0), b.max + Vec3::splat(1.0));
            rays.push(hytrace::geom::Ray::new(o, rng.direction()));
        }
        for level in levels() {
            let mut scratch = PacketScratch::with_level(level);
            let mut regs = hytrace::sdf::tape::Registers::new();
            for (i, (object, field)) in scene.objects.iter().zip(tracer.fields()).enumerate() {
                let lanes: Vec<Lane> = rays
                    .iter()
                    .filter_map(|r| {
                        let (t0, t1) =
                            object
                                .bounds()
                                .ray_interval(r, 0.0, scene.tracer.max_distance)?;
                        Some(Lane { ray: *r, t0, t1 })
                    })
                    .collect();
                // one SIMD pass's worth, and whole bundles (lanes grouped by leaf across them)
                for chunk in lanes.chunks(8).chain(lanes.chunks(BUNDLE)) {
                    let mut out = vec![TraceResult::of_points(None, 0); chunk.len()];
                    trace_hart_packet(field, chunk, &scene.tracer, &mut scratch, &mut out);
                    for (lane, got) in chunk.iter().zip(&out) {
                        let alone = trace_hart(
                            &mut tracer.cursor(i, &mut regs),
                            &lane.ray,
                            lane.t0,
                            lane.t1,
                            &scene.tracer,
                        );
                        assert!(
                            got.t.map(f32::to_bits) == alone.t.map(f32::to_bits)
                                && got.steps == alone.steps,
                            "{}/{} {level:?}: packet {got:?} vs alone {alone:?} for {:?}",
                            file.display(),
                            object.name,
                            lane.ray
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn bundled_shadow_rays_give_each_ray_its_own_visibility() {
    use hytrace::scene::Shadow;
    use hytrace::trace::{SceneTracer, ShadowQuery};
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes");
    let mut rng = Rng::new(34);
    for file in scene_files(&dir).unwrap() {
        let scene = Scene::load(&file).unwrap_or_else(|e| panic!("{e}"));
        let tracer = SceneTracer::new(&scene);
        let b = scene.finite_bounds();
        // rays from a grid of points on a plane through the scene toward one point (a
        // light's shadow rays: coherent), in every shadow kind, plus scattered ones
        let light = b.max + Vec3::new(0.5, 2.0, 0.7);
        let mut queries = Vec::new();
        for (k, shadow) in [
            Shadow::Hard,
            Shadow::Soft(8.0),
            Shadow::SoftImproved(16.0),
            Shadow::None,
        ]
        .into_iter()
        .enumerate()
        {
            for j in 0..24 {
                for i in 0..24 {
                    let o = b.min
                        + (b.max - b.min)
                            * Vec3::new(i as f32 / 23.0, 0.3 + 0.02 * k as f32, j as f32 / 23.0);
                    let to = light - o;
                    let ray = hytrace::geom::Ray::new(o, to.normalize());
                    queries.push(ShadowQuery {
                        ray,
                        tmin: 1e-3,
                        tmax: to.length(),
                        shadow,
                    });
                }
            }
            for _ in 0..64 {
                let o = rng.in_box(b.min, b.max);
                queries.push(ShadowQuery {
                    ray: hytrace::geom::Ray::new(o, rng.direction()),
                    tmin: 1e-3,
                    tmax: 10.0,
                    shadow,
                });
            }
        }
        let mut bundled = vec![0.0; queries.len()];
        tracer.visibilities(&queries, &mut bundled);
        let mut open = 0;
        for (q, got) in queries.iter().zip(&bundled) {
            let alone = tracer.visibility(&q.ray, q.tmin, q.tmax, q.shadow);
            assert_eq!(
                got.to_bits(),
                alone.to_bits(),
                "{}: bundled {got} vs alone {alone} for {q:?}",
                file.display()
            );
            open += (alone > 0.0 && alone < 1.0) as usize;
        }
        assert!(
            open > 0 || scene.objects.is_empty(),
            "{}: no penumbra sampled",
            file.display()
        );
    }
}
