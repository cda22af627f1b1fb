//! Unions split into their members, each traced as an object of its own: the same hits as the
//! union traced as one field (up to where in the ε band each march stops), the same materials
//! and pictures; unions whose inside matters (transparent or partly covered materials) stay
//! whole; and a union of very many members is cut into a bounded number of parts.

use glam::Vec3;
use hytrace::render::{RenderOptions, cpu};
use hytrace::scene::{Scene, SdfObject};
use hytrace::sdf;
use hytrace::trace::{SceneTracer, epsilon_at};
use std::path::Path;

/// A scene around `objects`, with a point light casting soft shadows, a directional light
/// casting hard ones, ambient occlusion and a ground plane below.
fn scene_with(objects: &str) -> Scene {
    let src = format!(
        "Scene(
            image: (width: 96, height: 72),
            camera: Perspective(position: (0.4, 2.2, 4.5), look_at: (0, 0.2, 0), fov: 45),
            lights: [
                Ambient(color: (1, 1, 1), intensity: 0.2),
                Directional(direction: (-0.4, -1, -0.3), color: (1, 1, 1), intensity: 0.8),
                Point(position: (2, 3, 2), color: (1, 1, 1), intensity: 12,
                    shadow: Soft(k: 12)),
            ],
            shading: (ambient_occlusion: Some((strength: 1, steps: 4, step: 0.08))),
            materials: {{
                \"red\": (color: (0.8, 0.1, 0.1)),
                \"blue\": (color: (0.1, 0.2, 0.8), specular: (0.5, 0.5, 0.5), shininess: 30),
                \"mirror\": (color: (0.9, 0.9, 0.9), reflectivity: 0.5),
                \"glass\": (color: (1, 1, 1), transparency: 0.9, ior: 1.5),
            }},
            objects: [
                (name: \"ground\", shape: Plane(normal: (0, 1, 0), offset: -1)),
                {objects}
            ],
        )"
    );
    Scene::from_source(&src, Path::new("parts.ron")).unwrap_or_else(|e| panic!("{e}"))
}

/// The scene with the parts of the object named `name` replaced by `shape` (the object's shape
/// as written) traced as one field (its members are painted by their own `Material` nodes;
/// the object has none).
fn whole(scene: &Scene, name: &str, shape: &str) -> Scene {
    assert!(
        scene.objects.iter().filter(|o| o.name == name).count() > 1,
        "{name} was not split"
    );
    let node = sdf::conformance::parse_node(shape);
    let index_of = |m: &str| {
        (scene.material_names.iter())
            .position(|n| n == m)
            .map(|i| i as u32)
    };
    let lowered = sdf::lower(&node, &index_of, 0).unwrap_or_else(|e| panic!("{e}"));
    let mut out = scene.clone();
    out.objects.retain(|o| o.name != name);
    out.objects.push(SdfObject {
        name: name.to_string(),
        node,
        lowered,
        part: None,
    });
    out
}

/// Whether the scene's field along `ray` comes within ε of a surface near t without crossing
/// it deeper than ε (a silhouette: one march may sample that stretch inside the band, the
/// other step over it).
fn grazes(scene: &Scene, ray: &hytrace::geom::Ray, t: f32) -> bool {
    let e = epsilon_at(&scene.tracer, t);
    let field = |p: Vec3| {
        (scene.objects.iter())
            .map(|o| o.lowered.distance.eval(p))
            .fold(f32::INFINITY, f32::min)
    };
    (0..=200)
        .map(|k| field(ray.at(t - 4.0 * e + 16.0 * e * k as f32 / 200.0)))
        .all(|f| f > -2.0 * e)
}

/// Unions of every kind of member and wrapper: a spiral of overlapping spheres painted in
/// turn, transformed and scaled members of nested unions, a box crossing a mirror torus, and a
/// plane inside the union.
fn split_objects() -> Vec<(&'static str, String)> {
    let spiral: Vec<String> = (0..60)
        .map(|i| {
            let a = i as f32 * 0.35;
            let (x, y, z) = (0.9 * a.cos(), -0.8 + 0.03 * i as f32, 0.9 * a.sin());
            let m = if i % 2 == 0 { "red" } else { "blue" };
            format!(
                "Material(name: \"{m}\", shape: Transform(translate: ({x}, {y}, {z}), \
                 shape: Sphere(radius: 0.2)))"
            )
        })
        .collect();
    vec![
        ("spiral", format!("Union([{}])", spiral.join(", "))),
        (
            "nested",
            "Transform(translate: (0.2, 0, 0), rotate: (0, 30, 0), scale: 0.8, shape: Union([
                Material(name: \"blue\", shape: Union([
                    Box(half_extents: (0.5, 0.3, 0.4)),
                    Transform(translate: (0, 0.5, 0), rotate: (20, 0, 0),
                        shape: Torus(major: 0.5, minor: 0.12)),
                ])),
                Scale(factors: (1, 2, 0.5), shape: Union([
                    Material(name: \"red\", shape: Sphere(radius: 0.35)),
                    Transform(translate: (0.6, 0, 0), shape: Cylinder(half_height: 0.3, radius: 0.2)),
                ])),
                Material(name: \"mirror\", shape: Transform(translate: (-0.7, 0.1, 0.3),
                    shape: Octahedron(size: 0.45))),
             ]))"
            .to_string(),
        ),
        (
            "with a plane",
            "Union([
                Material(name: \"blue\", shape: Plane(normal: (0, 0, 1), offset: -1.5)),
                Material(name: \"red\", shape: Transform(translate: (0.3, 0, 0),
                    shape: RoundBox(half_extents: (0.4, 0.4, 0.4), radius: 0.1))),
                Transform(translate: (-0.4, 0.2, 0), shape: Capsule(a: (0, 0, 0), b: (0, 0.6, 0),
                    radius: 0.2)),
             ])"
            .to_string(),
        ),
    ]
}

#[test]
fn a_union_split_into_parts_traces_and_renders_as_the_union_does() {
    for (name, shape) in split_objects() {
        let split = scene_with(&format!("(name: \"{name}\", shape: {shape})"));
        let one = whole(&split, name, &shape);
        assert_eq!(
            split.sdf_object_count(),
            2,
            "{name}: the ground and the union"
        );
        assert_eq!(one.sdf_object_count(), 2);
        let (a, b) = (SceneTracer::new(&split), SceneTracer::new(&one));
        let (w, h) = (96u32, 72u32);
        let (mut same, mut grazing, mut hits) = (0usize, 0usize, 0usize);
        for y in 0..h {
            for x in 0..w {
                let ray = split.camera.ray(
                    (x as f32 + 0.5) / w as f32,
                    (y as f32 + 0.5) / h as f32,
                    w as f32 / h as f32,
                );
                let (ha, hb) = (
                    a.closest_hit(&ray, 0.0, f32::INFINITY),
                    b.closest_hit(&ray, 0.0, f32::INFINITY),
                );
                match (ha, hb) {
                    (Some(ha), Some(hb)) => {
                        hits += 1;
                        let cos = ha.normal.dot(ray.direction).abs().max(0.01);
                        let band = (epsilon_at(&split.tracer, ha.t)
                            + epsilon_at(&split.tracer, hb.t))
                            / cos;
                        if (ha.t - hb.t).abs() <= band {
                            same += 1;
                            // the member hit paints the point as the union does
                            let p = ray.at(ha.t);
                            let materials = split.material_table();
                            let (ma, mb) = (
                                a.material_at(&ha, p, &materials),
                                b.material_at(&hb, ray.at(hb.t), &materials),
                            );
                            // (the union picks its member's material with a lerp: an ulp off)
                            assert!(
                                ma.color.abs_diff_eq(mb.color, 1e-6),
                                "{name} ({x}, {y}): {} and {}",
                                ma.color,
                                mb.color
                            );
                            assert!(
                                ha.normal.dot(hb.normal) > 0.99 || grazes(&split, &ray, ha.t),
                                "{name} ({x}, {y}): normals {} and {}",
                                ha.normal,
                                hb.normal
                            );
                            continue;
                        }
                        assert!(
                            grazes(&split, &ray, ha.t.min(hb.t)),
                            "{name} ({x}, {y}): t {} split, {} whole",
                            ha.t,
                            hb.t
                        );
                        grazing += 1;
                    }
                    (None, None) => same += 1,
                    (Some(hit), None) | (None, Some(hit)) => {
                        assert!(
                            grazes(&split, &ray, hit.t),
                            "{name} ({x}, {y}): {ha:?} split, {hb:?} whole"
                        );
                        grazing += 1;
                    }
                }
            }
        }
        let n = (w * h) as usize;
        println!("{name}: {same} of {n} rays on the same hit or miss, {grazing} grazing");
        assert!(hits * 4 >= n, "{name}: the union is in view ({hits} hits)");
        assert!(grazing * 200 <= n, "{name}: {grazing} grazing of {n}");
        // pictures with hard and soft shadows, ambient occlusion and a mirror
        let opts = RenderOptions::single_sample(w, h);
        let (fa, fb) = (
            cpu::render_with(&a, &opts).unwrap(),
            cpu::render_with(&b, &opts).unwrap(),
        );
        let mean: f32 = (fa.pixels.iter().zip(&fb.pixels))
            .map(|(p, q)| (*p - *q).abs().max_element())
            .sum::<f32>()
            / n as f32;
        println!("{name}: mean radiance difference {mean}");
        assert!(mean < 4e-3, "{name}: mean radiance difference {mean}");
    }
}

#[test]
fn unions_whose_inside_matters_stay_whole() {
    // refraction follows a ray through the one inside of the union, which its members'
    // overlapping insides are not: a transparent member, or a transparent object's default
    // material under members without their own, keeps the union one field
    for material in ["glass", "clear"] {
        let scene = Scene::from_source(
            &format!(
                "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40),
                    materials: {{
                        \"glass\": (color: (1, 1, 1), transparency: 0.9, ior: 1.5),
                        \"clear\": Pbr(base_color: (1, 1, 1), transparency: 0.5),
                        \"red\": (color: (0.8, 0.1, 0.1)),
                    }},
                    objects: [
                        (shape: Union([Sphere(radius: 1), Material(name: \"{material}\",
                            shape: Transform(translate: (0.5, 0, 0), shape: Sphere(radius: 1)))])),
                        (material: \"{material}\", shape: Union([Sphere(radius: 1),
                            Material(name: \"red\", shape: Box(half_extents: (1, 1, 1)))])),
                        (material: \"red\", shape: Union([Sphere(radius: 1),
                            Transform(translate: (0.5, 0, 0), shape: Sphere(radius: 1))])),
                    ])"
            ),
            Path::new("inside.ron"),
        )
        .unwrap_or_else(|e| panic!("{material}: {e}"));
        // the opaque third union is split; the first two are not
        assert_eq!(scene.sdf_object_count(), 3, "{material}");
        assert_eq!(scene.objects.len(), 4, "{material}: two unions whole");
        assert!(scene.objects[..2].iter().all(|o| o.part.is_none()));
        assert!(scene.objects[2..].iter().all(|o| o.part.is_some()));
    }
}

#[test]
fn a_union_of_very_many_members_is_cut_into_a_bounded_number_of_parts() {
    let n = 3 * sdf::parts::MAX_PARTS + 100;
    let spheres: Vec<String> = (0..n)
        .map(|i| {
            let (x, y) = ((i % 64) as f32, (i / 64) as f32);
            format!(
                "Transform(translate: ({}, {}, 0), shape: Sphere(radius: 0.004))",
                x * 0.01 - 0.32,
                y * 0.01 - 0.25
            )
        })
        .collect();
    let scene = Scene::from_source(
        &format!(
            "Scene(camera: Orthographic(position: (0, 0, 3), look_at: (0, 0, 0), height: 1),
                objects: [(name: \"many\", shape: Union([{}]))])",
            spheres.join(", ")
        ),
        Path::new("many.ron"),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.sdf_object_count(), 1);
    assert!(
        scene.objects.len() <= sdf::parts::MAX_PARTS && scene.objects.len() > 1,
        "{} parts",
        scene.objects.len()
    );
    // each part holds spheres near each other: its box is far smaller than the union's
    let union = scene.finite_bounds();
    for o in &scene.objects {
        let b = o.bounds();
        assert!(
            (b.max - b.min).length() < 0.25 * (union.max - union.min).length(),
            "{}: {b:?}",
            o.label()
        );
    }
    let tracer = SceneTracer::new(&scene);
    let centre = scene.camera.ray(0.5, 0.5, 1.0);
    let hit = tracer.closest_hit(&centre, 0.0, f32::INFINITY);
    assert!(hit.is_some_and(|h| (h.t - 2.996).abs() < 1e-3), "{hit:?}");
}
