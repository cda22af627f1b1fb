//! Meshes and SDFs in one scene: shadows cast both ways, the SDF BVH against the linear scan,
//! and the hybrid showcase on the real assets.

mod common;

use glam::Vec3;
use hytrace::geom::Ray;
use hytrace::render::{Framebuffer, RenderOptions};
use hytrace::scene::Scene;
use hytrace::scene::generate::many_objects;
use hytrace::shade::integrator::{self, trace_camera_ray};
use hytrace::trace::{AccelOptions, SceneTracer, Surface};
use std::path::{Path, PathBuf};

/// A square of side 2·h in the plane y = `y`, as an OBJ file (two triangles).
fn write_quad(dir: &Path, h: f32, y: f32) -> PathBuf {
    let p = dir.join("quad.obj");
    std::fs::write(
        &p,
        format!(
            "v {} {y} {}\nv {h} {y} {}\nv {h} {y} {h}\nv {} {y} {h}\nf 1 3 2\nf 1 4 3\n",
            -h, -h, -h, -h
        ),
    )
    .unwrap();
    p
}

const SIZE: u32 = 120;
const VIEW: f32 = 4.0;

/// Renders with a top-down orthographic camera (image x = world x, rows toward +z).
fn render_top_down(objects: &str) -> Framebuffer {
    let src = format!(
        "Scene(
            image: (width: {SIZE}, height: {SIZE}, background: (0, 0, 0)),
            camera: Orthographic(position: (0, 10, 0), look_at: (0, 0, 0), up: (0, 0, -1), height: {VIEW}),
            lights: [Point(position: (0, 3, 0), intensity: 10)],
            objects: [{objects}],
            tracer: (epsilon: 1e-5, epsilon_per_unit: 0),
        )"
    );
    let scene =
        Scene::from_source(&src, Path::new("hybrid-test.ron")).unwrap_or_else(|e| panic!("{e}"));
    hytrace::render::cpu::render(&scene, &RenderOptions::single_sample(SIZE, SIZE)).unwrap()
}

/// Fraction of plane pixels (outside the occluder's own disk) whose shadowing agrees with the
/// analytic shadow of a sphere of radius 0.5 at height 1 under a light at height 3.
fn shadow_agreement(fb: &Framebuffer, occluder_radius_seen: f32) -> f32 {
    let shadow_radius = 3.0 * (0.5f32 / 2.0).asin().tan();
    let (mut agree, mut total) = (0, 0);
    for j in 0..SIZE {
        for i in 0..SIZE {
            let x = VIEW * ((i as f32 + 0.5) / SIZE as f32 - 0.5);
            let z = VIEW * ((j as f32 + 0.5) / SIZE as f32 - 0.5);
            let rho = (x * x + z * z).sqrt();
            if rho < occluder_radius_seen + 0.03 || (rho - shadow_radius).abs() < 0.03 {
                continue;
            }
            total += 1;
            if (fb.get(i, j).max_element() < 1e-6) == (rho < shadow_radius) {
                agree += 1;
            }
        }
    }
    agree as f32 / total as f32
}

#[test]
fn an_sdf_shadows_a_mesh() {
    let dir_tmp = common::temp_dir("hybrid-sdf-on-mesh");
    let dir = dir_tmp.path().to_path_buf();
    let quad = write_quad(&dir, 3.0, 0.0);
    let fb = render_top_down(&format!(
        "(mesh: \"{}\"), (shape: Sphere(radius: 0.5), translate: (0, 1, 0))",
        quad.display()
    ));
    let rate = shadow_agreement(&fb, 0.5);
    assert!(rate >= 0.99, "SDF sphere on a mesh plane: {rate}");
}

#[test]
fn a_mesh_shadows_an_sdf() {
    // an octahedron-ish closed mesh would do; a small horizontal quad at height 1 with the
    // sphere's silhouette radius gives the same analytic shadow as the sphere: a disk of
    // radius 0.5 at height 1 from a light at height 3 projects to radius 0.75 — use the quad's
    // own geometry: a square of half-side 0.5 projects to a square of half-side 0.75.
    let dir_tmp = common::temp_dir("hybrid-mesh-on-sdf");
    let dir = dir_tmp.path().to_path_buf();
    let quad = write_quad(&dir, 0.5, 1.0);
    let fb = render_top_down(&format!(
        "(shape: Plane(normal: (0, 1, 0), offset: 0)), (mesh: \"{}\")",
        quad.display()
    ));
    let (mut agree, mut total) = (0, 0);
    for j in 0..SIZE {
        for i in 0..SIZE {
            let x = VIEW * ((i as f32 + 0.5) / SIZE as f32 - 0.5);
            let z = VIEW * ((j as f32 + 0.5) / SIZE as f32 - 0.5);
            let m = x.abs().max(z.abs());
            if m < 0.53 || (m - 0.75).abs() < 0.03 {
                continue; // the quad itself, and the shadow's edge
            }
            total += 1;
            if (fb.get(i, j).max_element() < 1e-6) == (m < 0.75) {
                agree += 1;
            }
        }
    }
    let rate = agree as f32 / total as f32;
    assert!(rate >= 0.99, "mesh quad over an SDF plane: {rate}");
}

#[test]
fn closest_hit_picks_the_nearer_of_mesh_and_sdf() {
    let dir_tmp = common::temp_dir("hybrid-nearest");
    let dir = dir_tmp.path().to_path_buf();
    let quad = write_quad(&dir, 2.0, 0.5);
    for (sphere_y, expect_mesh) in [(-1.0, true), (2.0, false)] {
        let src = format!(
            "Scene(camera: Perspective(position: (0, 5, 0.01), look_at: (0, 0, 0)),
                   objects: [(mesh: \"{}\"), (shape: Sphere(radius: 0.5), translate: (0, {sphere_y}, 0))])",
            quad.display()
        );
        let scene = Scene::from_source(&src, Path::new("t.ron")).unwrap();
        let tracer = SceneTracer::new(&scene);
        let hit = tracer
            .closest_hit(&Ray::new(Vec3::new(0.0, 5.0, 0.0), -Vec3::Y), 0.0, 100.0)
            .unwrap();
        match hit.surface {
            Surface::Mesh { .. } => {
                assert!(expect_mesh);
                assert!((hit.t - 4.5).abs() < 1e-4);
            }
            Surface::Sdf(_) => {
                assert!(!expect_mesh);
                assert!((hit.t - 2.5).abs() < 1e-3);
            }
        }
    }
}

fn render_with(scene: &Scene, options: AccelOptions, w: u32, h: u32) -> Vec<[u32; 3]> {
    let tracer = SceneTracer::with_options(scene, options);
    let materials = scene.material_table();
    let mut out = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let ray = scene.camera.ray(
                (x as f32 + 0.5) / w as f32,
                (y as f32 + 0.5) / h as f32,
                w as f32 / h as f32,
            );
            let s = trace_camera_ray(&tracer, &materials, ray);
            out.push(s.radiance.to_array().map(f32::to_bits));
        }
    }
    out
}

#[test]
fn sdf_bvh_gives_the_same_image_as_the_linear_scan() {
    for n in [10, 1000, 10_000] {
        let scene = Scene::from_source(&many_objects(n), Path::new("many.ron")).unwrap();
        let (w, h) = if n > 1000 { (48, 36) } else { (80, 60) };
        let with = render_with(&scene, AccelOptions::default(), w, h);
        let without = render_with(
            &scene,
            AccelOptions {
                sdf_bvh: false,
                ..Default::default()
            },
            w,
            h,
        );
        let differing = with.iter().zip(&without).filter(|(a, b)| a != b).count();
        assert_eq!(
            differing, 0,
            "{n} objects: {differing} pixels differ with the BVH"
        );
    }
}

fn assets() -> Option<PathBuf> {
    common::assets_or_skip("the hybrid showcase test")
}

#[test]
fn hybrid_showcase_renders_with_meshes_and_sdfs() {
    // The scene names its meshes through $HYTRACE_ASSETS, which scripts/test.sh exports and
    // .cargo/config.toml otherwise sets to ../shared/assets beside the checkout, the same
    // folder `assets()` checks.
    if assets().is_none() {
        return;
    }
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes/hybrid.ron");
    let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.meshes.instances.len(), 2);
    assert!(scene.meshes.triangle_count() > 69_000);
    let tracer = SceneTracer::new(&scene);
    let materials = scene.material_table();
    let (w, h) = (64u32, 48u32);
    let (mut mesh_hits, mut sdf_hits) = (0, 0);
    for y in 0..h {
        for x in 0..w {
            let ray = scene.camera.ray(
                (x as f32 + 0.5) / w as f32,
                (y as f32 + 0.5) / h as f32,
                w as f32 / h as f32,
            );
            match tracer
                .closest_hit(&ray, 0.0, f32::INFINITY)
                .map(|h| h.surface)
            {
                Some(Surface::Mesh { .. }) => mesh_hits += 1,
                Some(Surface::Sdf(_)) => sdf_hits += 1,
                None => {}
            }
            let s = trace_camera_ray(&tracer, &materials, ray);
            assert!(s.radiance.is_finite());
        }
    }
    assert!(
        mesh_hits > 100 && sdf_hits > 100,
        "mesh {mesh_hits}, sdf {sdf_hits}"
    );
}

#[test]
fn the_binary_renders_the_hybrid_showcase_from_the_repository_root_without_the_variable() {
    // The README's command: with HYTRACE_ASSETS unset, the binary's default for it
    // (../shared/assets from the working directory) finds the models beside the checkout.
    if assets().is_none() {
        return;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    if !root.join("../shared/assets").is_dir() {
        eprintln!(
            "!!! no ../shared/assets beside the checkout: the binary's default NOT TESTED !!!"
        );
        return;
    }
    let png_tmp = common::temp_dir("hybrid-cli-default-assets");
    let png = png_tmp.path().join("hybrid.png");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_hytrace"))
        .current_dir(root)
        .env_remove("HYTRACE_ASSETS")
        .args([
            "render",
            "assets/scenes/hybrid.ron",
            "--width",
            "32",
            "--height",
            "24",
        ])
        .args(["--spp", "1", "--backend", "cpu", "-q", "-o"])
        .arg(&png)
        .output()
        .expect("run hytrace");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(png.is_file(), "no image at {}", png.display());
}

#[test]
fn cpu_render_traces_tile_rows_as_each_ray_alone() {
    // The CPU renderer finds a tile row's camera hits together (mesh packets and SDF
    // bundles), the mirror reflections of those hits together, and the shadow rays of the
    // later hits of the band's paths (reflections, refractions) together, their local
    // shading added afterwards in each path's order; every pixel must be what tracing its
    // samples' rays one by one gives, bit for bit (adding the put-off terms in another order
    // fails here). shadows.ron has ambient occlusion, whose distances a band finds together. 70×45 has partial tiles on
    // both edges; 3 samples jitter the rays inside the pixels. hybrid.ron has meshes and a
    // Phong mirror, pbr.ron metals whose reflections take their colour, glass.ron
    // dielectrics that reflect part of the light.
    if assets().is_none() {
        return;
    }
    for name in ["hybrid.ron", "pbr.ron", "glass.ron", "shadows.ron"] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("assets/scenes")
            .join(name);
        let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let opts = RenderOptions {
            width: 70,
            height: 45,
            samples: 3,
            threads: Some(2),
            progress: false,
        };
        let fb = hytrace::render::cpu::render(&scene, &opts).expect("renders");
        let tracer = SceneTracer::new(&scene);
        let materials = scene.material_table();
        let mut alone = Framebuffer::new(opts.width, opts.height);
        let (mut mesh_pixels, mut mirrored) = (0, 0);
        for y in 0..opts.height {
            for x in 0..opts.width {
                let samples: Vec<_> = (0..opts.samples)
                    .map(|s| {
                        let (dx, dy) = hytrace::render::sample_offset(x, y, s, opts.samples);
                        let ray = scene.camera.ray(
                            (x as f32 + dx) / opts.width as f32,
                            (y as f32 + dy) / opts.height as f32,
                            opts.width as f32 / opts.height as f32,
                        );
                        if let Some(hit) = tracer.closest_hit(&ray, 0.0, f32::INFINITY) {
                            if let Surface::Mesh { .. } = hit.surface {
                                mesh_pixels += 1;
                            }
                            let surf = integrator::surfaced(&tracer, &materials, &ray, &hit);
                            if integrator::first_reflection(&tracer, &surf, ray.direction).is_some()
                            {
                                mirrored += 1;
                            }
                        }
                        trace_camera_ray(&tracer, &materials, ray)
                    })
                    .collect();
                alone.set(x, y, &samples);
            }
        }
        if name == "hybrid.ron" {
            assert!(
                mesh_pixels > 200,
                "the view should show the meshes: {mesh_pixels}"
            );
        }
        assert!(
            mirrored > 100 || name == "shadows.ron",
            "{name}: the view should show mirror reflections: {mirrored} samples"
        );
        for (i, (a, b)) in fb.pixels.iter().zip(&alone.pixels).enumerate() {
            assert_eq!(
                a.to_array().map(f32::to_bits),
                b.to_array().map(f32::to_bits),
                "{name}: pixel {i}"
            );
            assert_eq!(
                fb.depth[i].to_bits(),
                alone.depth[i].to_bits(),
                "{name}: depth {i}"
            );
        }
    }
}

#[test]
fn bad_mesh_objects_are_clear_errors() {
    let cases = [
        ("(mesh: \"no/such/file.obj\")", "file.obj"),
        ("(mesh: \"model.xyz\")", "unsupported"),
        ("(mesh: \"a.obj\", shape: Sphere(radius: 1))", "not both"),
        ("(name: \"empty\")", "needs a `shape`"),
    ];
    for (object, expect) in cases {
        let src = format!(
            "Scene(\n  camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)),\n  objects: [\n    {object},\n  ],\n)"
        );
        let e = Scene::from_source(&src, Path::new("scene.ron"))
            .expect_err(object)
            .to_string();
        assert!(e.starts_with("scene.ron:4:"), "{object}: {e}");
        assert!(e.contains(expect), "{object}: {e}");
    }
    // a directory and an empty file name the mesh file
    let dir_tmp = common::temp_dir("hybrid-bad-mesh");
    let dir = dir_tmp.path().to_path_buf();
    std::fs::write(dir.join("empty.glb"), b"").unwrap();
    let src = format!(
        "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)), objects: [(mesh: \"{}\")])",
        dir.join("empty.glb").display()
    );
    let e = Scene::from_source(&src, Path::new("scene.ron"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("empty.glb"), "{e}");
}
