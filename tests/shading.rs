//! Shading against closed forms: a lit plane's radiance, a sphere's shadow, penumbrae,
//! lossless reflection and refraction, ambient occlusion, and every debug view of every scene.

use glam::Vec3;
use hytrace::render::output::ToneMapping;
use hytrace::render::view::{View, picture};
use hytrace::render::{Framebuffer, RenderOptions, cpu};
use hytrace::scene::file::ToneMap;
use hytrace::scene::{AmbientOcclusion, Scene};
use hytrace::shade::ambient_occlusion;
use hytrace::trace::SceneTracer;
use std::path::Path;

/// Side of the square orthographic view used below, in world units.
const VIEW: f32 = 4.0;
const SIZE: u32 = 160;

/// A top-down orthographic camera over the plane y = 0: image x is world +x, image rows go
/// toward world +z.
fn top_down(lights: &str, objects: &str, extra: &str) -> Scene {
    let src = format!(
        "Scene(
            image: (width: {SIZE}, height: {SIZE}, background: (0, 0, 0)),
            camera: Orthographic(position: (0, 10, 0), look_at: (0, 0, 0), up: (0, 0, -1), height: {VIEW}),
            lights: [{lights}],
            materials: {{ \"matte\": (color: (0.5, 0.6, 0.7)) }},
            objects: [(shape: Plane(normal: (0, 1, 0), offset: 0), material: \"matte\"), {objects}],
            tracer: (epsilon: 1e-5, epsilon_per_unit: 0),
            {extra}
        )"
    );
    Scene::from_source(&src, Path::new("test.ron")).unwrap_or_else(|e| panic!("{e}"))
}

fn render(scene: &Scene, samples: u32) -> Framebuffer {
    cpu::render(
        scene,
        &RenderOptions {
            width: scene.image.width,
            height: scene.image.height,
            samples,
            threads: None,
            progress: false,
        },
    )
    .unwrap()
}

/// World (x, z) on the plane seen at the centre of pixel (i, j) of the top-down view.
fn world(i: u32, j: u32) -> (f32, f32) {
    let u = (i as f32 + 0.5) / SIZE as f32;
    let v = (j as f32 + 0.5) / SIZE as f32;
    (VIEW * (u - 0.5), VIEW * (v - 0.5))
}

#[test]
fn lit_plane_matches_the_closed_form_radiance() {
    // Lambert under one point light: L = albedo · I · (n·l) / d².
    let light = Vec3::new(0.3, 2.0, -0.4);
    let scene = top_down("Point(position: (0.3, 2.0, -0.4), intensity: 4.0)", "", "");
    let fb = render(&scene, 1);
    let albedo = Vec3::new(0.5, 0.6, 0.7);
    let mut worst: f32 = 0.0;
    for j in (0..SIZE).step_by(7) {
        for i in (0..SIZE).step_by(7) {
            let (x, z) = world(i, j);
            let to_light = light - Vec3::new(x, 0.0, z);
            let d2 = to_light.length_squared();
            let expect = albedo * 4.0 * (to_light.y / d2.sqrt()) / d2;
            let got = fb.get(i, j);
            let rel = ((got - expect).abs() / expect).max_element();
            worst = worst.max(rel);
        }
    }
    assert!(worst < 0.01, "largest relative error {worst}");
}

/// Shadow of a sphere (radius R, centre height c) from a point light straight above it at
/// height L, on the plane: a disk of radius L·tan(asin(R/(L − c))).
#[test]
fn sphere_shadow_matches_the_analytic_umbra() {
    let (r, c, l) = (0.5f32, 1.0f32, 3.0f32);
    let scene = top_down(
        "Point(position: (0, 3, 0), intensity: 10)",
        "(shape: Sphere(radius: 0.5), translate: (0, 1, 0))",
        "",
    );
    let fb = render(&scene, 1);
    let shadow_radius = l * (r / (l - c)).asin().tan();
    let (mut agree, mut total) = (0, 0);
    for j in 0..SIZE {
        for i in 0..SIZE {
            let (x, z) = world(i, j);
            let rho = (x * x + z * z).sqrt();
            if rho < r + 0.02 {
                continue; // the camera sees the sphere here, not the plane
            }
            total += 1;
            let dark = fb.get(i, j).max_element() < 1e-6;
            if dark == (rho < shadow_radius) {
                agree += 1;
            }
        }
    }
    let rate = agree as f32 / total as f32;
    assert!(rate >= 0.99, "shadow mask agreement {rate}");
}

/// The light's visibility along +x from the centre row (outside the sphere's own disk): the
/// shadowed radiance over the radiance without the occluder.
fn radial_visibility(fb: &Framebuffer, unshadowed: &Framebuffer) -> Vec<f32> {
    let j = SIZE / 2;
    (SIZE / 2..SIZE)
        .filter(|&i| world(i, j).0 > 0.55)
        .map(|i| fb.get(i, j).y / unshadowed.get(i, j).y)
        .collect()
}

#[test]
fn soft_shadows_darken_toward_the_umbra_and_approach_hard_shadows() {
    let sphere = "(shape: Sphere(radius: 0.5), translate: (0, 1, 0))";
    let hard = render(
        &top_down("Point(position: (0, 3, 0), intensity: 10)", sphere, ""),
        1,
    );
    let open = render(
        &top_down("Point(position: (0, 3, 0), intensity: 10)", "", ""),
        1,
    );
    for kind in ["Soft", "SoftImproved"] {
        let mut last_difference = f32::INFINITY;
        for k in [2.0, 8.0, 32.0, 128.0, 1024.0] {
            let light =
                format!("Point(position: (0, 3, 0), intensity: 10, shadow: {kind}(k: {k}))");
            let fb = render(&top_down(&light, sphere, ""), 1);
            let profile = radial_visibility(&fb, &open);
            for w in profile.windows(2) {
                assert!(
                    w[1] >= w[0] - 1e-5,
                    "{kind} k={k}: brightness falls away from the umbra: {profile:?}"
                );
            }
            // on the plane: the estimate widens the hard shadow outward (a ray grazing the
            // occluder has h → 0), so a soft shadow is never lighter than the hard one
            for j in 0..SIZE {
                for i in 0..SIZE {
                    let (x, z) = world(i, j);
                    if x * x + z * z > 0.55 * 0.55 {
                        let (a, b, o) = (fb.get(i, j).y, hard.get(i, j).y, open.get(i, j).y);
                        assert!(
                            a >= -1e-7 && a <= b + 1e-5 && b <= o + 1e-5,
                            "{kind} k={k}: {a} vs hard {b}, open {o}"
                        );
                    }
                }
            }
            let difference: f32 = fb
                .pixels
                .iter()
                .zip(&hard.pixels)
                .map(|(a, b)| (a.y - b.y).abs())
                .sum::<f32>()
                / fb.pixels.len() as f32;
            assert!(
                difference <= last_difference + 1e-6,
                "{kind}: k={k} is farther from hard than a smaller k"
            );
            last_difference = difference;
        }
        let mean: f32 = hard.pixels.iter().map(|p| p.y).sum::<f32>() / hard.pixels.len() as f32;
        assert!(
            last_difference < 0.02 * mean,
            "{kind}: k = 1024 still differs by {last_difference}"
        );
    }
}

/// In a uniform white environment with no lights, a lossless mirror or dielectric is
/// invisible: every path ends in the environment with its whole weight (Fresnel splits
/// energy, it does not lose it). Only the paths cut by the bounce limit lose a little.
#[test]
fn lossless_mirrors_and_glass_vanish_in_a_white_environment() {
    for material in [
        "(color: (1, 1, 1), reflectivity: 1.0)",
        "(color: (1, 1, 1), transparency: 1.0, ior: 1.5)",
        "(color: (1, 1, 1), transparency: 1.0, ior: 2.4)",
    ] {
        let src = format!(
            "Scene(
                image: (width: 64, height: 64, background: (1, 1, 1)),
                camera: Orthographic(position: (0, 0, 5), look_at: (0, 0, 0), height: 2.4),
                materials: {{ \"m\": {material} }},
                objects: [(shape: Sphere(radius: 1), material: \"m\")],
                tracer: (epsilon: 1e-5, epsilon_per_unit: 0),
                shading: (max_bounces: 16),
            )"
        );
        let scene = Scene::from_source(&src, Path::new("test.ron")).unwrap();
        let fb = render(&scene, 1);
        let seen: Vec<f32> = fb
            .pixels
            .iter()
            .zip(&fb.depth)
            .filter(|(_, d)| d.is_finite())
            .map(|(p, _)| p.y)
            .collect();
        assert!(seen.len() > 1000, "the sphere is not in view");
        let mean_error = seen.iter().map(|v| (v - 1.0).abs()).sum::<f32>() / seen.len() as f32;
        let worst = seen.iter().map(|v| (v - 1.0).abs()).fold(0.0, f32::max);
        assert!(
            mean_error < 0.01 && worst < 0.06,
            "{material}: mean |L − 1| = {mean_error}, worst {worst}"
        );
    }
}

/// An eye inside a glass dome sees the ball outside it, as from just outside the dome: a ray
/// that starts inside a transparent solid travels inside it (it had "hit" the solid at t = 0
/// and refracted at a surface that is not there, which hid the scene behind a grey band).
#[test]
fn an_eye_inside_glass_sees_out() {
    let scene_at = |z: f32| {
        let src = format!(
            "Scene(
                image: (width: 48, height: 36, background: (0.5, 0.6, 0.8)),
                camera: Perspective(position: (0, 0, {z}), look_at: (0, 0, -8), fov: 40),
                lights: [Ambient(intensity: 1)],
                materials: {{ \"a\": (color: (0.8, 0.3, 0.1)),
                             \"glass\": (color: (1, 1, 1), transparency: 1, ior: 1.33) }},
                objects: [
                    (material: \"glass\", shape: Sphere(radius: 5)),
                    (material: \"a\", translate: (0, 0, -8), shape: Sphere(radius: 1)),
                ],
            )"
        );
        Scene::from_source(&src, Path::new("test.ron")).unwrap()
    };
    // from the dome's centre every ray leaves it head-on: no bending at all
    let inside = render(&scene_at(0.0), 1);
    let centre = (18 * 48 + 24) as usize;
    let ball = inside.pixels[centre];
    assert!(
        ball.x > 2.0 * ball.z && ball.x > 0.3,
        "the orange ball is in the middle of the view: {ball}"
    );
    let corner = inside.pixels[0];
    assert!(
        (corner - Vec3::new(0.5, 0.6, 0.8)).abs().max_element() < 0.05,
        "the sky beyond the dome: {corner}"
    );
}

#[test]
fn ambient_occlusion_darkens_corners_only() {
    let scene = top_down(
        "Ambient(intensity: 1)",
        "(shape: Box(half_extents: (0.5, 1, 2)), translate: (1.5, 1, 0))",
        "shading: (ambient_occlusion: (strength: 1, steps: 5, step: 0.1)),",
    );
    let tracer = SceneTracer::new(&scene);
    let ao = AmbientOcclusion {
        strength: 1.0,
        steps: 5,
        step: 0.1,
    };
    let open = ambient_occlusion(&tracer, Vec3::new(-1.0, 0.0, 0.0), Vec3::Y, &ao);
    let corner = ambient_occlusion(&tracer, Vec3::new(0.98, 0.0, 0.0), Vec3::Y, &ao);
    let near = ambient_occlusion(&tracer, Vec3::new(0.8, 0.0, 0.0), Vec3::Y, &ao);
    assert!((open - 1.0).abs() < 1e-6, "open plane: {open}");
    assert!(
        corner < near && near < open,
        "corner {corner}, near {near}, open {open}"
    );
}

fn scenes() -> Vec<std::path::PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes");
    let mut v: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "ron"))
        .collect();
    v.sort();
    assert!(
        v.len() >= 9,
        "expected the shipped scenes in {}",
        dir.display()
    );
    v
}

#[test]
fn every_view_renders_for_every_shipped_scene() {
    for path in scenes() {
        let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let fb = cpu::render(&scene, &RenderOptions::single_sample(48, 36)).unwrap();
        assert!(
            fb.pixels.iter().all(|p| p.is_finite()),
            "{}: non-finite radiance",
            path.display()
        );
        let tone = ToneMapping {
            exposure: 0.0,
            operator: ToneMap::Aces,
        };
        for view in [
            View::Shaded,
            View::Normals,
            View::Depth,
            View::Steps,
            View::Gradient,
        ] {
            let img = picture(&fb, view, tone, scene.tracer.max_steps);
            assert_eq!(img.dimensions(), (48, 36));
            let first = img.get_pixel(0, 0);
            assert!(
                img.pixels().any(|p| p != first),
                "{} {view:?}: a blank picture",
                path.display()
            );
        }
    }
}
