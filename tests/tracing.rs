//! Sphere tracing against closed forms, hole-free deformations, and deterministic images.

use glam::{DVec3, Vec3};
use hytrace::geom::Ray;
use hytrace::reference::analytic::{self, AnalyticHit};
use hytrace::reference::validate::sdf_dt_tolerance;
use hytrace::render::{RenderOptions, cpu};
use hytrace::scene::Scene;
use hytrace::sdf::conformance::Rng;
use hytrace::trace::{SceneTracer, epsilon_at};
use std::path::Path;

fn scene_with(shape: &str, tracer: &str) -> Scene {
    let src = format!(
        "Scene(camera: Perspective(position: (0, 0, 6), look_at: (0, 0, 0)), \
         objects: [(shape: {shape})], tracer: ({tracer}))"
    );
    Scene::from_source(&src, Path::new("test.ron")).unwrap_or_else(|e| panic!("{e}"))
}

type Analytic = dyn Fn(DVec3, DVec3) -> Option<AnalyticHit>;

/// Random rays from a sphere of radius 4 aimed at points near the shape; compares hit/miss and
/// t with the closed form. The tolerance follows from the stopping rule: the tracer stops where
/// f < ε(t), i.e. within ε(t) of the surface for an exact field, which along a ray meeting the
/// surface at angle θ to the normal is |Δt| ≤ ε(t)/cos θ, within the library's tolerance
/// ([`sdf_dt_tolerance`], whose bound holds two tracers to each other and so holds one to the
/// closed form). Rays with cos θ < 0.05 (the grazing band at silhouettes) may disagree on
/// hit/miss; nothing else may.
fn check_against_closed_form(name: &str, shape: &str, closed: &Analytic) {
    let scene = scene_with(shape, "epsilon: 1e-5, epsilon_per_unit: 0, max_steps: 2000");
    let tracer = SceneTracer::new(&scene);
    let mut rng = Rng::new(0xC0FFEE ^ name.len() as u64);
    let (mut agree, mut total, mut max_dt) = (0usize, 0usize, 0.0f32);
    let mut outside_band = Vec::new();
    for _ in 0..4000 {
        let origin = rng.direction() * 4.0;
        let target = rng.in_box(Vec3::splat(-1.2), Vec3::splat(1.2));
        let ray = Ray::new(origin, target - origin);
        if scene.objects[0].lowered.distance.eval(origin) <= 0.0 {
            continue; // a ray born inside the solid is a hit at t = 0 by definition
        }
        let ours = tracer.closest_hit(&ray, 0.0, 100.0);
        let truth = closed(origin.as_dvec3(), ray.direction.as_dvec3());
        total += 1;
        let grazing = |h: &AnalyticHit| h.normal.dot(ray.direction.as_dvec3()).abs() < 0.05;
        match (ours, truth) {
            (Some(a), Some(b)) => {
                agree += 1;
                let cos = b.normal.dot(ray.direction.as_dvec3()).abs().max(1e-3) as f32;
                let tol = sdf_dt_tolerance(&scene.tracer, a.t, cos, 0.0);
                let dt = (a.t - b.t as f32).abs();
                if !grazing(&b) {
                    max_dt = max_dt.max(dt);
                    if dt > tol {
                        outside_band.push(format!("Δt = {dt} > {tol} for {ray:?}"));
                    }
                }
            }
            (None, None) => agree += 1,
            (None, Some(b)) if grazing(&b) => {}
            (Some(a), None) => {
                // a false hit is acceptable only within ε of the surface: the exact field at our
                // hit point measures exactly that
                let d = scene.objects[0].lowered.distance.eval(ray.at(a.t)).abs();
                if d > 2.0 * epsilon_at(&scene.tracer, a.t) {
                    outside_band.push(format!("false hit at t = {} (f = {d}) for {ray:?}", a.t));
                }
            }
            (None, Some(b)) => outside_band.push(format!("missed t = {} for {ray:?}", b.t)),
        }
    }
    let rate = agree as f64 / total as f64;
    eprintln!(
        "{name}: agreement {:.3}%, max |Δt| (non-grazing) {max_dt:e}",
        100.0 * rate
    );
    assert!(
        outside_band.is_empty(),
        "{name}: {} disagreements outside the grazing band, e.g. {}",
        outside_band.len(),
        outside_band[0]
    );
    assert!(rate >= 0.995, "{name}: hit/miss agreement {rate}");
}

const T: (f64, f64) = (0.0, 100.0);

#[test]
fn sphere_hits_match_closed_form() {
    check_against_closed_form("sphere", "Sphere(radius: 1.0)", &|o, d| {
        analytic::sphere(o, d, 1.0, T.0, T.1)
    });
}

#[test]
fn box_hits_match_closed_form() {
    let h = DVec3::new(1.0, 0.5, 0.75);
    check_against_closed_form(
        "box",
        "Box(half_extents: (1.0, 0.5, 0.75))",
        &move |o, d| analytic::box_(o, d, h, T.0, T.1),
    );
}

#[test]
fn plane_hits_match_closed_form() {
    let n = DVec3::new(0.2, 1.0, 0.1).normalize();
    check_against_closed_form(
        "plane",
        "Plane(normal: (0.2, 1.0, 0.1), offset: -0.3)",
        &move |o, d| analytic::plane(o, d, n, -0.3, T.0, T.1),
    );
}

#[test]
fn torus_hits_match_quartic_solution() {
    check_against_closed_form("torus", "Torus(major: 1.0, minor: 0.3)", &|o, d| {
        analytic::torus(o, d, 1.0, 0.3, T.0, T.1)
    });
}

#[test]
fn capsule_hits_match_closed_form() {
    let (a, b) = (DVec3::new(-0.5, -0.3, 0.1), DVec3::new(0.6, 0.4, -0.2));
    check_against_closed_form(
        "capsule",
        "Capsule(a: (-0.5, -0.3, 0.1), b: (0.6, 0.4, -0.2), radius: 0.35)",
        &move |o, d| analytic::capsule(o, d, a, b, 0.35, T.0, T.1),
    );
}

#[test]
fn cylinder_hits_match_closed_form() {
    check_against_closed_form(
        "cylinder",
        "Cylinder(half_height: 0.8, radius: 0.5)",
        &|o, d| analytic::capped_cylinder(o, d, 0.8, 0.5, T.0, T.1),
    );
}

#[test]
fn cone_hits_match_closed_form() {
    check_against_closed_form(
        "cone",
        "Cone(half_height: 0.8, bottom_radius: 0.7, top_radius: 0.2)",
        &|o, d| analytic::capped_cone(o, d, 0.8, 0.7, 0.2, T.0, T.1),
    );
}

#[test]
fn transformed_sphere_hits_match_closed_form() {
    let c = DVec3::new(0.3, -0.2, 0.1);
    check_against_closed_form(
        "scaled, moved sphere",
        "Transform(translate: (0.3, -0.2, 0.1), rotate: (10, 20, 30), scale: 1.5, shape: Sphere(radius: 0.6))",
        &move |o, d| analytic::sphere(o - c, d, 0.9, T.0, T.1),
    );
}

/// The hit mask of sphere tracing against marching with tiny fixed steps and watching the sign
/// of f (the sign does not depend on any Lipschitz scaling, so this reference cannot share a
/// bug in the step correction). A "hole" is a ray the reference sees go at least 1e-3 deep
/// into the solid while sphere tracing reports a miss.
fn check_no_holes(name: &str, shape: &str) {
    let scene = scene_with(shape, "epsilon: 1e-4, epsilon_per_unit: 0, max_steps: 5000");
    let tracer = SceneTracer::new(&scene);
    let tape = &scene.objects[0].lowered.distance;
    let (w, h) = (96u32, 72u32);
    let (mut holes, mut mismatches, mut hits) = (0, 0, 0);
    for y in 0..h {
        for x in 0..w {
            let ray = scene.camera.ray(
                (x as f32 + 0.5) / w as f32,
                (y as f32 + 0.5) / h as f32,
                w as f32 / h as f32,
            );
            let ours = tracer.closest_hit(&ray, 0.0, 12.0).is_some();
            // fixed steps of 2e-3 from t = 3 (the camera is 6 away from the shape's centre)
            let mut reference = None;
            let mut deepest = 0.0f32;
            let mut t = 3.0;
            while t < 9.0 {
                let f = tape.eval(ray.at(t));
                if f < 0.0 {
                    reference.get_or_insert(t);
                    deepest = deepest.min(f);
                }
                t += 2e-3;
            }
            hits += ours as usize;
            if ours != reference.is_some() {
                mismatches += 1;
            }
            // the field is a bound, so f < −1e-3/λ means depth ≥ that; use the raw threshold
            if !ours && deepest < -1e-3 {
                holes += 1;
            }
        }
    }
    eprintln!(
        "{name}: {hits} hits, {mismatches} hit/miss mismatches, {holes} holes of {}",
        w * h
    );
    assert!(hits > 200, "{name}: the test shape is not in view");
    assert_eq!(
        holes, 0,
        "{name}: sphere tracing stepped through the surface"
    );
    assert!(
        mismatches as f32 <= 0.005 * (w * h) as f32,
        "{name}: {mismatches} mismatches"
    );
}

#[test]
fn twisted_box_has_no_holes() {
    check_no_holes(
        "twist",
        "Twist(rate: 2.0, shape: Box(half_extents: (0.6, 1.2, 0.25)))",
    );
}

#[test]
fn bent_box_has_no_holes() {
    check_no_holes(
        "bend",
        "Bend(rate: 1.0, shape: Box(half_extents: (1.4, 0.2, 0.5)))",
    );
}

#[test]
fn implicit_gyroid_has_no_holes() {
    check_no_holes(
        "gyroid",
        "Implicit(expr: \"sin(3*x)*cos(3*y) + sin(3*y)*cos(3*z) + sin(3*z)*cos(3*x)\", half_extents: (1, 1, 1))",
    );
}

#[test]
fn repeated_spheres_have_no_holes() {
    check_no_holes(
        "repeat",
        "Repeat(period: (0.7, 0.7, 0), shape: Sphere(radius: 0.25))",
    );
}

fn showcase() -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes/showcase.ron");
    Scene::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn images_are_identical_for_any_thread_count_and_run() {
    let scene = showcase();
    let render = |threads| {
        cpu::render(
            &scene,
            &RenderOptions {
                width: 120,
                height: 90,
                samples: 2,
                threads: Some(threads),
                progress: false,
            },
        )
        .unwrap()
    };
    let one = render(1);
    assert!(
        one.pixels.iter().any(|p| *p != one.pixels[0]),
        "the image is blank"
    );
    for threads in [2, 4, 1] {
        let other = render(threads);
        assert!(
            one.pixels
                .iter()
                .zip(&other.pixels)
                .all(|(a, b)| a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits)),
            "image with {threads} threads differs from 1 thread"
        );
    }
}

#[test]
fn primary_ray_parameters_are_distances() {
    // The tracer's t is a Euclidean distance: a sphere of radius 1 seen from 6 away is hit at 5.
    let scene = scene_with("Sphere(radius: 1.0)", "epsilon: 1e-6, epsilon_per_unit: 0");
    let tracer = SceneTracer::new(&scene);
    let hit = tracer
        .closest_hit(&Ray::new(Vec3::new(0.0, 0.0, 6.0), -Vec3::Z), 0.0, 100.0)
        .unwrap();
    assert!((hit.t - 5.0).abs() < 1e-5);
    assert!((hit.normal - Vec3::Z).length() < 1e-3);
    assert!(tracer.occluded(&Ray::new(Vec3::new(0.0, 0.0, 6.0), -Vec3::Z), 0.0, 5.5));
    assert!(!tracer.occluded(&Ray::new(Vec3::new(0.0, 0.0, 6.0), -Vec3::Z), 0.0, 4.5));
}

#[test]
fn touching_repeated_copies_show_no_cell_walls() {
    // the copies fill their cells exactly (gap 0): empty cell walls must not read as surfaces
    check_no_holes(
        "touching repeat",
        "Repeat(period: (1.0, 1.0, 0), shape: Sphere(radius: 0.5))",
    );
}

#[test]
fn limited_repetition_has_no_holes() {
    check_no_holes(
        "limited repeat",
        "RepeatLimited(period: (0.8, 0.8, 0.8), copies_each_side: (2, 1, 1), shape: Box(half_extents: (0.3, 0.25, 0.35)))",
    );
}
