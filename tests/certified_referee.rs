//! The certified referee on composite SDFs: our tracer passes `validate` on the composite
//! scene, and the referee has teeth there — a tracer with ε × 20, a sphere tracer stepping
//! 1.5 × the field, and one that skips features thinner than 2ε all fail, while the same test
//! tracer unbroken passes; and a property test: random trees of every node kind, randomly
//! placed, traced by our tracer and by the certified referee on random rays.
#![cfg(feature = "embree")]

use hytrace::geom::Ray;
use hytrace::reference::embree::ReferenceOptions;
use hytrace::reference::interval64::{Interval, Program, registers};
use hytrace::reference::validate::{
    Kind, Options, Report, SdfCheck, validate_against_embree, validate_with_embree,
};
use hytrace::scene::Scene;
use hytrace::sdf::tape::Registers;
use hytrace::trace::query::{ObjectId, QueryHit, RayQuery};
use hytrace::trace::{SceneTracer, epsilon_at};
use proptest::prelude::*;
use std::path::Path;

fn options(width: u32, height: u32, random: usize) -> Options {
    Options {
        width,
        height,
        random,
        seed: 3,
    }
}

/// Composite objects with features the broken tracers trip on, at a scale where a few rays
/// meet them: small spheres minus a box, an onion shell 1.6ε thick (Onion's thickness is
/// half the shell's), a twisted box, a smooth-union chain.
const TEETH_SCENE: &str = "Scene(
    camera: Perspective(position: (0, 0.6, 3.2), look_at: (0, 0, 0), fov: 40),
    lights: [Directional(direction: (0.3, -1, -0.5), intensity: 1)],
    objects: [
        (name: \"spheres\", translate: (-0.8, 0, 0), shape: Subtraction(base: Union([
            Transform(translate: (0.1, 0.1, 0), shape: Sphere(radius: 0.06)),
            Transform(translate: (-0.1, 0.2, 0.1), shape: Sphere(radius: 0.06)),
            Transform(translate: (0.0, -0.15, 0.05), shape: Sphere(radius: 0.06)),
            Transform(translate: (0.2, -0.05, -0.1), shape: Sphere(radius: 0.06)),
            Transform(translate: (-0.2, -0.1, 0.0), shape: Sphere(radius: 0.06)),
            Transform(translate: (0.05, 0.3, -0.05), shape: Sphere(radius: 0.06)),
        ]), cut: Transform(translate: (0.15, 0.15, 0.15), shape: Box(half_extents: (0.1, 0.1, 0.1))))),
        (name: \"thin shell\", translate: (0.1, 0, 0), shape: Onion(thickness: 0.0004, shape: Sphere(radius: 0.35))),
        (name: \"twisted box\", translate: (0.8, 0, 0), shape: Twist(rate: 9, shape: Box(half_extents: (0.15, 0.4, 0.06)))),
        (name: \"chain\", translate: (0, -0.55, 0), shape: SmoothUnion(k: 0.02, shapes: [
            Transform(translate: (-0.2, 0, 0), shape: Torus(major: 0.06, minor: 0.015)),
            Transform(translate: (-0.1, 0, 0), rotate: (90, 0, 0), shape: Torus(major: 0.06, minor: 0.015)),
            Transform(translate: (0.0, 0, 0), shape: Torus(major: 0.06, minor: 0.015)),
            Transform(translate: (0.1, 0, 0), rotate: (90, 0, 0), shape: Torus(major: 0.06, minor: 0.015)),
            Transform(translate: (0.2, 0, 0), shape: Torus(major: 0.06, minor: 0.015)),
        ])),
    ],
    tracer: (epsilon: 5e-4, epsilon_per_unit: 0),
)";

fn teeth_scene() -> Scene {
    Scene::from_source(TEETH_SCENE, Path::new("teeth.ron")).unwrap_or_else(|e| panic!("{e}"))
}

/// How the test's sphere tracer is broken.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Breakage {
    /// Not at all.
    None,
    /// Steps of 1.5 × the field (no fallback).
    LongSteps,
    /// Crossings whose solid is left again within 2ε(t) along the ray are ignored.
    SkipThin,
}

/// A plain sphere tracer over each object's whole tape (Hart 1996), with the confirmation of
/// `crate::trace::crossing` in its simplest form: where f < ε(t), the ray is probed every ε/4
/// up to 2ε ahead for f ≤ 0; the hit is the last point before it. Independent of our
/// tracer's octrees and steppers, so that breaking it breaks nothing else.
struct Marcher<'a> {
    scene: &'a Scene,
    how: Breakage,
}

impl Marcher<'_> {
    fn first_hit(&self, object: usize, ray: &Ray, tmax: f32) -> Option<f32> {
        let s = &self.scene.tracer;
        let tape = &self.scene.objects[object].lowered.distance;
        let mut regs = Registers::new();
        let mut f = |t: f32| tape.eval_in(ray.at(t), &mut regs);
        let step_scale = if self.how == Breakage::LongSteps {
            1.5
        } else {
            1.0
        };
        let mut t = 0.0;
        for _ in 0..4 * s.max_steps {
            if t > tmax {
                return None;
            }
            let d = f(t);
            let e = epsilon_at(s, t);
            if d < e {
                let crossing = (0..=8)
                    .map(|k| t + 0.25 * e * k as f32)
                    .find(|&u| f(u) <= 0.0);
                if let Some(u) = crossing {
                    let thin = (1..=8).any(|k| f(u + 0.25 * e * k as f32) > 0.0);
                    if !(self.how == Breakage::SkipThin && thin) {
                        return Some((u - 0.25 * e).max(t));
                    }
                    t = u + 2.0 * e;
                    continue;
                }
                t += d.max(e);
                continue;
            }
            t += step_scale * d;
        }
        None
    }

    fn hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<QueryHit> {
        let tmax = tmax.min(self.scene.tracer.max_distance);
        let (i, t) = (0..self.scene.objects.len())
            .filter_map(|i| Some((i, self.first_hit(i, ray, tmax)?)))
            .filter(|&(_, t)| t >= tmin)
            .min_by(|a, b| a.1.total_cmp(&b.1))?;
        let n = self.scene.objects[i]
            .lowered
            .distance
            .gradient(ray.at(t), 1e-4)
            .normalize_or_zero();
        Some(QueryHit {
            t,
            normal: n,
            object: ObjectId::Sdf(i),
        })
    }
}

impl RayQuery for Marcher<'_> {
    fn closest_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<QueryHit> {
        self.hit(ray, tmin, tmax)
    }

    fn occluded(&self, ray: &Ray, tmin: f32, tmax: f32) -> bool {
        self.hit(ray, tmin, tmax).is_some()
    }
}

fn certified_referee() -> ReferenceOptions {
    ReferenceOptions::default()
}

fn every_object_certified(r: &Report) {
    for o in &r.objects {
        if o.index > 0 || !matches!(o.check, SdfCheck::Analytic) {
            assert!(
                matches!(o.check, SdfCheck::Certified { .. }),
                "#{} {:?}",
                o.index,
                o.check
            );
        }
    }
}

/// Our tracer passes on the composite scene of the benchmark (the objects), every
/// composite object certified, with the composite thresholds.
#[test]
fn our_tracer_passes_on_composite_objects() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/validate/composite.ron");
    let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let r = validate_with_embree(&scene, &options(80, 60, 600)).unwrap();
    println!("{}", r.markdown());
    every_object_certified(&r);
    let c = r.kind(Kind::CertifiedSdf);
    assert!(c.rays > 500, "{c:?}");
    assert!(r.passed(), "{}", r.markdown());
    assert_eq!(r.uncertified_searches, 0);
}

/// The teeth: the unbroken test tracer passes; ε × 20 (our tracer with the scene's ε and its
/// growth scaled, judged by the scene's own ε), steps of 1.5 × the field, and skipping
/// features thinner than 2ε each fail on the composite objects.
#[test]
fn broken_tracers_fail_on_composite_objects() {
    let scene = teeth_scene();
    let opts = options(160, 120, 1500);
    let reference = certified_referee();

    let sound = Marcher {
        scene: &scene,
        how: Breakage::None,
    };
    let r = validate_against_embree(&scene, &sound, &opts, &reference).unwrap();
    println!("unbroken:\n{}", r.markdown());
    every_object_certified(&r);
    assert!(
        r.passed(),
        "the unbroken test tracer fails:\n{}",
        r.markdown()
    );

    let real = SceneTracer::new(&scene);
    let r = validate_against_embree(&scene, &real, &opts, &reference).unwrap();
    println!("our tracer:\n{}", r.markdown());
    assert!(r.passed(), "our tracer fails:\n{}", r.markdown());

    let mut coarse = scene.clone();
    coarse.tracer.epsilon *= 20.0;
    coarse.tracer.epsilon_per_unit *= 20.0;
    let wide = SceneTracer::new(&coarse);
    let r = validate_against_embree(&scene, &wide, &opts, &reference).unwrap();
    println!("ε × 20:\n{}", r.markdown());
    assert!(!r.passed(), "ε × 20 passed");
    assert!(
        r.failures.iter().any(|f| f.starts_with("certified SDFs")),
        "{:?}",
        r.failures
    );

    for how in [Breakage::LongSteps, Breakage::SkipThin] {
        let broken = Marcher { scene: &scene, how };
        let r = validate_against_embree(&scene, &broken, &opts, &reference).unwrap();
        println!("{how:?}:\n{}", r.markdown());
        assert!(!r.passed(), "{how:?} passed");
        assert!(
            r.failures.iter().any(|f| f.starts_with("certified SDFs")),
            "{how:?}: {:?}",
            r.failures
        );
    }
}

/// A random SDF tree of depth ≤ `depth` using every node kind, as scene-file text.
fn tree(depth: u32) -> impl Strategy<Value = String> {
    let v = || -0.3f32..0.3;
    let r = || 0.08f32..0.3;
    let leaf = prop_oneof![
        r().prop_map(|a| format!("Sphere(radius: {a})")),
        (r(), r(), r()).prop_map(|(a, b, c)| format!("Box(half_extents: ({a}, {b}, {c}))")),
        (r(), r(), r()).prop_map(|(a, b, c)| format!(
            "RoundBox(half_extents: ({a}, {b}, {c}), radius: {})",
            0.3 * a.min(b).min(c)
        )),
        (r(), 0.2f32..0.9).prop_map(|(a, f)| format!("Torus(major: {a}, minor: {})", f * a)),
        (r(), r()).prop_map(|(a, b)| format!("Cylinder(half_height: {a}, radius: {b})")),
        (r(), r(), 0.0f32..0.2).prop_map(|(a, b, c)| format!(
            "Cone(half_height: {a}, bottom_radius: {b}, top_radius: {c})"
        )),
        (v(), v(), r()).prop_map(|(a, b, c)| format!(
            "Capsule(a: ({a}, {b}, 0), b: ({b}, 0, {a}), radius: {})",
            0.5 * c
        )),
        (r(), r(), r()).prop_map(|(a, b, c)| format!("Ellipsoid(radii: ({a}, {b}, {c}))")),
        r().prop_map(|a| format!("Octahedron(size: {a})")),
        (r(), r()).prop_map(|(a, b)| format!("HexPrism(radius: {a}, half_length: {b})")),
    ];
    leaf.prop_recursive(depth, 12, 3, move |inner| {
        let v = || -0.3f32..0.3;
        prop_oneof![
            prop::collection::vec(inner.clone(), 1..4).prop_map(|s| format!("Union([{}])", s.join(", "))),
            prop::collection::vec(inner.clone(), 1..3)
                .prop_map(|s| format!("Intersection([{}])", s.join(", "))),
            (inner.clone(), inner.clone())
                .prop_map(|(a, b)| format!("Subtraction(base: {a}, cut: {b})")),
            (0.01f32..0.2, prop::collection::vec(inner.clone(), 1..4)).prop_map(|(k, s)| format!(
                "SmoothUnion(k: {k}, shapes: [{}])",
                s.join(", ")
            )),
            (0.01f32..0.2, prop::collection::vec(inner.clone(), 1..3)).prop_map(|(k, s)| format!(
                "SmoothIntersection(k: {k}, shapes: [{}])",
                s.join(", ")
            )),
            (0.01f32..0.2, inner.clone(), inner.clone()).prop_map(|(k, a, b)| format!(
                "SmoothSubtraction(k: {k}, base: {a}, cut: {b})"
            )),
            (0.01f32..0.1, inner.clone()).prop_map(|(r, s)| format!("Round(radius: {r}, shape: {s})")),
            (0.01f32..0.05, inner.clone()).prop_map(|(t, s)| format!("Onion(thickness: {t}, shape: {s})")),
            (v(), v(), v(), 0f32..90.0, 0.5f32..1.5, inner.clone()).prop_map(|(x, y, z, a, sc, s)| format!(
                "Transform(translate: ({x}, {y}, {z}), rotate: ({a}, {}, 0), scale: {sc}, shape: {s})",
                a / 2.0
            )),
            (0.6f32..1.4, 0.6f32..1.4, inner.clone())
                .prop_map(|(a, b, s)| format!("Scale(factors: ({a}, {b}, 1), shape: {s})")),
            (-4.0f32..4.0, inner.clone()).prop_map(|(k, s)| format!("Twist(rate: {k}, shape: {s})")),
            (-1.5f32..1.5, inner.clone()).prop_map(|(k, s)| format!("Bend(rate: {k}, shape: {s})")),
            (0.7f32..1.2, inner.clone()).prop_map(|(p, s)| format!(
                "RepeatLimited(period: ({p}, 1, 1), copies_each_side: (1, 0, 0), shape: {s})"
            )),
        ]
    })
}

/// Our tracer on one tree placed `at`, with `seed`'s random rays, against the certified referee:
/// within the composite thresholds (see the property test below).
fn tree_agrees_with_the_referee(
    shape: &str,
    at: (f32, f32, f32),
    seed: u64,
) -> Result<(), TestCaseError> {
    let src = format!(
        "Scene(camera: Perspective(position: (0, 0.5, 3.5), look_at: (0, 0, 0), fov: 45),
               lights: [Directional(direction: (0.3, -1, -0.4), intensity: 1)],
               objects: [(shape: {shape}, translate: ({}, {}, {}))])",
        at.0, at.1, at.2
    );
    // Trees the scene loader refuses (a twist of an unbounded child, say) are not SDFs to
    // check: rejected (proptest fails when it must reject too many); every tree it
    // accepts must pass.
    let scene = Scene::from_source(&src, Path::new("random-tree.ron"));
    prop_assume!(scene.is_ok());
    let scene = scene.unwrap();
    let opts = Options {
        seed,
        ..options(40, 30, 300)
    };
    let r = validate_with_embree(&scene, &opts).unwrap();
    // A few hundred rays per tree are too few for the 99.9 % agreement figure (one
    // excused near miss is 0.3 %); every ray must instead be within the thresholds: no
    // disagreement outside the certified band, no |Δt| over tolerance, no uncertified
    // search, no skipped object.
    for kind in [Kind::CertifiedSdf, Kind::AnalyticSdf] {
        let k = r.kind(kind);
        prop_assert!(
            k.disagree_elsewhere == 0 && k.dt_over_tolerance == 0,
            "{src}\n{}",
            r.markdown()
        );
    }
    prop_assert_eq!(r.shadow.disagree_elsewhere, 0, "{}\n{}", src, r.markdown());
    prop_assert_eq!(r.uncertified_searches, 0);
    prop_assert_eq!(r.kind(Kind::UncheckedSdf).rays, 0);
    // A tree whose solid is empty (a subtraction that carves everything away) shows
    // nothing to compare: rejected, and counted by proptest like the refused ones.
    let hits = r.kind(Kind::CertifiedSdf).both_hit + r.kind(Kind::AnalyticSdf).both_hit;
    prop_assume!(hits > 0 || r.both_miss < 40 * 30 + 300);
    prop_assert!(
        matches!(
            r.objects[0].check,
            SdfCheck::Certified { .. } | SdfCheck::Analytic
        ),
        "{:?}",
        r.objects[0].check
    );
    Ok(())
}

/// Trees the property test once drew where a ray skims a surface before crossing it cleanly,
/// and Hart's steps, each the field's value, ran out of the budget (256 then) on the way: a
/// pass at 10⁻⁴ from a carved surface (seed 134, 267 steps), and two rays along a channel
/// about 10⁻³ wide between a rounded box and a smoothly carved hexagonal prism (seed 495,
/// 563 and 589 steps). The default budget (1,024 since) reaches the crossings.
#[test]
fn rays_that_skim_a_surface_before_crossing_it_within_the_default_budget() {
    let cases = [
        (
            "SmoothSubtraction(k: 0.17347813, base: SmoothSubtraction(k: 0.01, \
             base: Cylinder(half_height: 0.20188984, radius: 0.2600777), \
             cut: Capsule(a: (0.2642364, 0, 0), b: (0, 0, 0.2642364), radius: 0.04)), \
             cut: Octahedron(size: 0.21925102))",
            134,
        ),
        (
            "SmoothSubtraction(k: 0.109066434, \
             base: RoundBox(half_extents: (0.08, 0.27699035, 0.23434132), radius: 0.024), \
             cut: HexPrism(radius: 0.21291044, half_length: 0.18005106))",
            495,
        ),
    ];
    for (shape, seed) in cases {
        tree_agrees_with_the_referee(shape, (0.0, 0.0, 0.0), seed)
            .unwrap_or_else(|e| panic!("{e}"));
    }
}

/// Another tree the property test drew (seed 409): a random ray crosses a sliver 3·10⁻⁵ deep
/// (less than ε/2, which our tracer rightly steps over) and the referee's certificate that
/// nothing deeper lies before our hit must pass the boundary between two faces of the
/// octahedron, where the interval enclosure is the union of both faces' formulas however
/// narrow the stretch: the referee bounds such a stretch by its midpoint and the field's
/// Lipschitz bound.
#[test]
fn a_sliver_before_a_branch_boundary_of_the_octahedron_is_certified() {
    let shape = "Subtraction(base: Box(half_extents: (0.19383657, 0.17883419, 0.2379706)), \
                 cut: SmoothUnion(k: 0.17668767, shapes: [\
                 Cylinder(half_height: 0.15366104, radius: 0.17421606), \
                 Octahedron(size: 0.22417057)]))";
    tree_agrees_with_the_referee(shape, (0.0, 0.0, 0.0), 409).unwrap_or_else(|e| panic!("{e}"));
}

/// Another tree the property test drew (seed 453): a rounded flat ellipsoid, whose field (a
/// distance bound) stays below the rounding radius beyond its half-extents + radius along
/// the short axes. Its box was too small, so the tracer clipped the surface flat at the box
/// and the referee, starting inside the solid at the box's face, reported the far side.
#[test]
fn a_rounded_ellipsoid_is_not_clipped_by_its_bounds() {
    let shape = "Round(radius: 0.079884045, \
                 shape: Intersection([Ellipsoid(radii: (0.08156791, 0.1255945, 0.15297))]))";
    tree_agrees_with_the_referee(shape, (0.0, 0.0, 0.0), 453).unwrap_or_else(|e| panic!("{e}"));
}

/// Another tree the property test drew (seed 0): a shadow ray leaving a smoothly blended
/// shell skims it within 4·10⁻³ for a tenth of a unit, where the referee's interval
/// enclosures stay loose and bisection alone ran out of boxes; the field's Lipschitz bound
/// certifies it.
#[test]
fn a_shadow_ray_skimming_a_blended_shell_is_certified() {
    let shape = "Onion(thickness: 0.046525143, shape: SmoothUnion(k: 0.13847673, shapes: [\
                 Octahedron(size: 0.14286256), \
                 HexPrism(radius: 0.22602104, half_length: 0.11174729), \
                 Capsule(a: (0.16238219, 0.29012597, 0), b: (0.29012597, 0, 0.16238219), \
                 radius: 0.09046889)]))";
    tree_agrees_with_the_referee(shape, (-0.21303546, -0.027553627, -0.09540652), 0)
        .unwrap_or_else(|e| panic!("{e}"));
}

/// Another tree the property test drew (seed 638): a random ray clips the rim of a cone,
/// head on to its base, 4·10⁻⁶ deep (ε/2 is 7·10⁻⁵ there): our tracer rightly steps over it,
/// and the closed form's crossing is excused as the sliver it is.
#[test]
fn a_ray_clipping_a_cone_s_rim_by_less_than_half_epsilon_is_a_sliver() {
    let shape = "Transform(translate: (0, 0, -0.055736676), rotate: (35.476044, 17.738022, 0), \
                 scale: 0.76153874, \
                 shape: Cone(half_height: 0.13792805, bottom_radius: 0.2158532, top_radius: 0))";
    tree_agrees_with_the_referee(shape, (-0.22303236, 0.11703984, 0.0), 638)
        .unwrap_or_else(|e| panic!("{e}"));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// Random trees of every node kind, randomly placed, on random rays: our tracer agrees
    /// with the certified referee within the composite thresholds.
    #[test]
    fn random_trees_agree_with_the_certified_referee(
        shape in tree(3),
        at in (-0.5f32..0.5, -0.3f32..0.3, -0.5f32..0.5),
        seed in 0u64..1000,
    ) {
        tree_agrees_with_the_referee(&shape, at, seed)?;
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// The referee's f64 evaluator on whole lowered trees (fused smooth minima, folded
    /// blends and pruning included): over random boxes its enclosure holds the tracer's f32
    /// value at every sampled point, up to that value's own rounding, and so does the
    /// program pruned to the box.
    #[test]
    fn enclosures_of_random_trees_hold_the_tape_s_values(
        shape in tree(3),
        boxes in prop::collection::vec(
            ((-0.6f32..0.6, -0.6f32..0.6, -0.6f32..0.6), 0.001f32..0.4, 0u64..1000),
            8,
        ),
    ) {
        let src = format!(
            "Scene(camera: Perspective(position: (0, 0, 3), look_at: (0, 0, 0), fov: 45),
                   objects: [(shape: {shape})])"
        );
        let scene = Scene::from_source(&src, Path::new("random-tree.ron"));
        prop_assume!(scene.is_ok());
        let scene = scene.unwrap();
        let tape = &scene.objects[0].lowered.distance;
        let program = Program::new(tape);
        let mut r = registers();
        let mut regs = Registers::new();
        for ((x, y, z), half, seed) in boxes {
            let b = |c: f32| Interval::new((c - half) as f64, (c + half) as f64);
            let (enclosure, pruned) = program.prune(b(x), b(y), b(z), &mut r);
            let mut rng = hytrace::rng::Rng::new(seed);
            for _ in 0..40 {
                let p = glam::Vec3::new(x, y, z) + rng.vec3_in(-half, half);
                let v = tape.eval_in(p, &mut regs) as f64;
                // the f32 tape rounds (and approximates sin, cos, exp, ln) on its own
                let slack = 1e-4 * (1.0 + v.abs());
                prop_assert!(
                    enclosure.lo - slack <= v && v <= enclosure.hi + slack,
                    "{src}: f({p}) = {v} outside {enclosure:?}"
                );
                if let Some(cut) = &pruned {
                    let pt = |c: f32| Interval::point(c as f64);
                    let e = cut.eval(pt(p.x), pt(p.y), pt(p.z), &mut r);
                    prop_assert!(
                        e.lo - slack <= v && v <= e.hi + slack,
                        "{src}: pruned f({p}) = {e:?}, tape {v}"
                    );
                }
            }
        }
    }
}
