//! The GPU render backend against the CPU one: every shipped scene gives the same picture
//! (PSNR ≥ 40 dB on the tone-mapped 8-bit sRGB images) and the same first-hit depths (within
//! the referee's tolerance on ≥ 99.9 % of pixels); a textured glTF model too; tiling does not
//! change a bit; and the `--backend` flag of the CLI.
//!
//! These tests need a GPU adapter: on machines without a GPU, Mesa's lavapipe (Debian package
//! `mesa-vulkan-drivers`, installed by scripts/setup.sh). A missing adapter fails them.
#![cfg(feature = "gpu")]

mod common;

use hytrace::geom::Ray;
use hytrace::gpu::context::GpuContext;
use hytrace::gpu::render::GpuRenderer;
use hytrace::render::output::ToneMapping;
use hytrace::render::view::{View, picture};
use hytrace::render::{Framebuffer, RenderOptions, cpu};
use hytrace::scene::Scene;
use hytrace::trace::{SceneTracer, Surface, epsilon_at};
use image::RgbImage;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// Test image size: small, so the suite stays fast on 2 cores (lavapipe runs on the CPU).
const WIDTH: u32 = 128;
const HEIGHT: u32 = 96;
/// The scenes' own samples per pixel, capped at this to keep time down.
const MAX_SPP: u32 = 4;
/// The picture agreement required.
const MIN_PSNR: f64 = 40.0;
/// The fraction of pixels whose depths must agree.
const MIN_DEPTH_AGREEMENT: f64 = 0.999;

/// Pixels whose steps view must agree between the backends (see `steps_agreement`).
const MIN_STEPS_AGREEMENT: f64 = 0.995;

/// A device and the compiled render kernel.
struct Gpu {
    ctx: GpuContext,
    renderer: GpuRenderer,
}

fn gpu() -> Gpu {
    // One device for the tests of this file, so that they share its compiled kernel.
    let ctx = common::gpu::ctx().clone();
    let renderer = GpuRenderer::new(&ctx);
    let gpu = Gpu { ctx, renderer };
    // lavapipe compiles the kernel on its first dispatch: a tiny warm-up render keeps that
    // compilation out of the first scene's printed time.
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes/primitives.ron");
    let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let warm_up = RenderOptions::single_sample(8, 8);
    gpu.render(&scene, &warm_up);
    gpu
}

impl Gpu {
    /// The GPU image; the pixels llvmpipe cannot trace at all (its loop budget, traced on
    /// the CPU instead) must stay a few, or the image would test the CPU.
    fn render(&self, scene: &Scene, opts: &RenderOptions) -> Framebuffer {
        let gpu = self
            .renderer
            .render_tiled(&self.ctx, scene, opts, hytrace::gpu::render::GPU_TILE)
            .unwrap_or_else(|e| panic!("{}: {e:#}", scene.source_name));
        let pixels = (opts.width * opts.height) as usize;
        if !gpu.on_cpu.is_empty() {
            println!(
                "{}: {} of {pixels} pixels traced on the CPU (the driver's loop budget)",
                scene.source_name,
                gpu.on_cpu.len()
            );
        }
        assert!(
            gpu.on_cpu.len() * 1000 <= pixels,
            "{}: {} of {pixels} pixels could not be traced on the GPU",
            scene.source_name,
            gpu.on_cpu.len()
        );
        gpu.image
    }
}

fn options(samples: u32) -> RenderOptions {
    RenderOptions {
        width: WIDTH,
        height: HEIGHT,
        samples,
        threads: None,
        progress: false,
    }
}

/// The shared third-party assets, or None (loudly) outside CI when they are missing.
fn assets() -> Option<PathBuf> {
    common::assets_or_skip("the scenes using them")
}

/// The tone-mapped 8-bit sRGB picture of a render, as `hytrace render` writes it.
fn shaded(scene: &Scene, fb: &Framebuffer) -> RgbImage {
    let tone = ToneMapping {
        exposure: scene.image.exposure,
        operator: scene.image.tonemap,
    };
    picture(fb, View::Shaded, tone, scene.tracer.max_steps)
}

/// Writes CPU, GPU and amplified-difference images where a failing test can be inspected;
/// returns the folder.
fn evidence(name: &str, cpu: &RgbImage, gpu: &RgbImage) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("gpu_render");
    std::fs::create_dir_all(&dir).unwrap();
    cpu.save(dir.join(format!("{name}-cpu.png"))).unwrap();
    gpu.save(dir.join(format!("{name}-gpu.png"))).unwrap();
    let diff = RgbImage::from_fn(cpu.width(), cpu.height(), |x, y| {
        let (p, q) = (cpu.get_pixel(x, y).0, gpu.get_pixel(x, y).0);
        image::Rgb(std::array::from_fn(|c| {
            (p[c].abs_diff(q[c]) as u32 * 8).min(255) as u8
        }))
    });
    diff.save(dir.join(format!("{name}-diff.png"))).unwrap();
    dir
}

/// The fraction of pixels whose first-hit depths agree: both miss, or both hit within the
/// referee's tolerance (tests/embree_reference.rs) for the surface the CPU's pixel-centre ray
/// hits: max(10·ε(t), 2·ε(t)/|n·d|) for an SDF, 1e-4 × the scene's diameter for a mesh.
/// Both framebuffers are 1-sample renders, whose rays pass through the pixel centres.
fn depth_agreement(scene: &Scene, cpu: &Framebuffer, gpu: &Framebuffer) -> (f64, String) {
    let tracer = SceneTracer::new(scene);
    let diameter = scene
        .finite_bounds()
        .union(&scene.meshes.bounds())
        .diagonal();
    let aspect = WIDTH as f32 / HEIGHT as f32;
    let mut agree = 0usize;
    let mut first_miss = String::new();
    for y in 0..HEIGHT {
        for x in 0..WIDTH {
            let i = (y * WIDTH + x) as usize;
            let (a, b) = (cpu.depth[i], gpu.depth[i]);
            let ray: Ray = scene.camera.ray(
                (x as f32 + 0.5) / WIDTH as f32,
                (y as f32 + 0.5) / HEIGHT as f32,
                aspect,
            );
            let ok = match tracer.closest_hit(&ray, 0.0, f32::INFINITY) {
                None => !a.is_finite() && !b.is_finite(),
                Some(hit) => {
                    let tol = match hit.surface {
                        Surface::Sdf(_) => {
                            let e = epsilon_at(&scene.tracer, hit.t);
                            (10.0 * e).max(2.0 * e / hit.normal.dot(ray.direction).abs())
                        }
                        Surface::Mesh { .. } => 1e-4 * diameter,
                    };
                    (a - b).abs() <= tol
                }
            };
            if ok {
                agree += 1;
            } else if first_miss.is_empty() {
                first_miss = format!("first disagreement at pixel ({x}, {y}): CPU {a}, GPU {b}");
            }
        }
    }
    (agree as f64 / (WIDTH * HEIGHT) as f64, first_miss)
}

/// The fraction of pixels of two 1-sample renders whose steps (the steps view: evaluations of
/// the camera ray's marches) are the same: the backends march by the same rules
/// (leaves, falls, the convexity bound), so only rays whose hits round differently differ.
fn steps_agreement(cpu: &Framebuffer, gpu: &Framebuffer) -> f64 {
    let agree = cpu
        .steps
        .iter()
        .zip(&gpu.steps)
        .filter(|(a, b)| a == b)
        .count();
    agree as f64 / cpu.steps.len() as f64
}

/// One scene's comparison: picture PSNR and depth agreement, with both render times.
struct Outcome {
    name: String,
    spp: u32,
    psnr: f64,
    depth: f64,
    steps: f64,
    cpu_seconds: f64,
    gpu_seconds: f64,
    problems: Vec<String>,
}

/// The eye inside a glass dome: rays that start inside a transparent solid travel inside it
/// on both backends (they had "hit" it at t = 0 and refracted at a surface that is not there).
#[test]
fn an_eye_inside_glass_sees_the_same_on_cpu_and_gpu() {
    let gpu = gpu();
    let scene = Scene::from_source(INSIDE_GLASS, Path::new("inside.ron")).unwrap();
    report(&[compare_scene("eye inside glass", &scene, &gpu)]);
}

/// A camera inside a glass sphere looking at an orange ball outside it.
const INSIDE_GLASS: &str = "Scene(
    image: (width: 48, height: 36, samples: 1, background: (0.5, 0.6, 0.8)),
    camera: Perspective(position: (0.3, 0.2, 0), look_at: (0, 0, -1), fov: 60),
    lights: [Ambient(intensity: 0.3), Directional(direction: (-0.3, -1, -0.6), intensity: 0.9)],
    materials: { \"a\": (color: (0.8, 0.3, 0.1)),
                 \"glass\": (color: (1, 1, 1), transparency: 0.95, ior: 1.33) },
    objects: [
        (material: \"glass\", shape: Sphere(radius: 5)),
        (material: \"a\", translate: (0, 0, -8), shape: Sphere(radius: 1)),
    ],
)";

fn compare_scene(name: &str, scene: &Scene, gpu: &Gpu) -> Outcome {
    let spp = scene.image.samples.min(MAX_SPP);
    let start = Instant::now();
    let cpu_fb = cpu::render(scene, &options(spp)).unwrap();
    let cpu_seconds = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let gpu_fb = gpu.render(scene, &options(spp));
    let gpu_seconds = start.elapsed().as_secs_f64();
    let (cpu_img, gpu_img) = (shaded(scene, &cpu_fb), shaded(scene, &gpu_fb));
    let psnr = common::psnr(&cpu_img, &gpu_img);
    let mut problems = Vec::new();
    if psnr < MIN_PSNR {
        let dir = evidence(name, &cpu_img, &gpu_img);
        problems.push(format!(
            "{name}: PSNR {psnr:.2} dB < {MIN_PSNR} dB (images in {})",
            dir.display()
        ));
    }
    let (one_cpu, one_gpu);
    let (cpu1, gpu1) = if spp == 1 {
        (&cpu_fb, &gpu_fb)
    } else {
        one_cpu = cpu::render(scene, &options(1)).unwrap();
        one_gpu = gpu.render(scene, &options(1));
        (&one_cpu, &one_gpu)
    };
    let (depth, first) = depth_agreement(scene, cpu1, gpu1);
    if depth < MIN_DEPTH_AGREEMENT {
        problems.push(format!(
            "{name}: depths agree on {:.3} % of pixels < {:.1} % ({first})",
            100.0 * depth,
            100.0 * MIN_DEPTH_AGREEMENT
        ));
    }
    let steps = steps_agreement(cpu1, gpu1);
    if steps < MIN_STEPS_AGREEMENT {
        problems.push(format!(
            "{name}: the steps view agrees on {:.3} % of pixels < {:.1} %",
            100.0 * steps,
            100.0 * MIN_STEPS_AGREEMENT
        ));
    }
    Outcome {
        name: name.to_string(),
        spp,
        psnr,
        depth,
        steps,
        cpu_seconds,
        gpu_seconds,
        problems,
    }
}

fn report(outcomes: &[Outcome]) {
    println!(
        "\n{:<22} {:>4} {:>10} {:>9} {:>9} {:>9} {:>14}",
        "scene", "spp", "PSNR (dB)", "depth %", "steps %", "CPU (s)", "lavapipe* (s)"
    );
    for o in outcomes {
        println!(
            "{:<22} {:>4} {:>10.2} {:>9.3} {:>9.3} {:>9.3} {:>14.3}",
            o.name,
            o.spp,
            o.psnr,
            100.0 * o.depth,
            100.0 * o.steps,
            o.cpu_seconds,
            o.gpu_seconds
        );
    }
    println!(
        "{WIDTH}×{HEIGHT} px; PSNR on tone-mapped 8-bit sRGB. *lavapipe runs on the CPU: its \
         times are not GPU figures.\n"
    );
    let problems: Vec<&String> = outcomes.iter().flat_map(|o| &o.problems).collect();
    assert!(
        problems.is_empty(),
        "{}",
        problems
            .iter()
            .map(|s| s.as_str())
            .collect::<Vec<_>>()
            .join("\n")
    );
}

#[test]
fn every_shipped_scene_renders_the_same_on_cpu_and_gpu() {
    let gpu = gpu();
    println!("GPU adapter: {}", gpu.ctx.adapter_name());
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "ron"))
        .collect();
    files.sort();
    assert!(
        files.len() >= 10,
        "expected the shipped scenes in {}",
        dir.display()
    );
    let have_assets = assets().is_some();
    let mut outcomes = Vec::new();
    for path in &files {
        let source = std::fs::read_to_string(path).unwrap();
        if source.contains("$HYTRACE_ASSETS") && !have_assets {
            continue;
        }
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        let scene = Scene::load(path).unwrap_or_else(|e| panic!("{e}"));
        outcomes.push(compare_scene(&name, &scene, &gpu));
    }
    report(&outcomes);
}

#[test]
fn a_textured_gltf_model_renders_the_same_on_cpu_and_gpu() {
    let Some(assets) = assets() else { return };
    let gpu = gpu();
    let mut outcomes = Vec::new();
    for model in [
        "glTF/BoxTextured/glTF/BoxTextured.gltf",
        "glTF/Duck/glTF-Binary/Duck.glb",
    ] {
        let scene = Scene::from_model(&assets.join(model), None).unwrap_or_else(|e| panic!("{e}"));
        assert!(
            !scene.meshes.textures.is_empty(),
            "{model} should carry a base-colour texture"
        );
        let name = Path::new(model).file_stem().unwrap().to_string_lossy();
        outcomes.push(compare_scene(&name, &scene, &gpu));
    }
    report(&outcomes);
}

/// Every glTF test scene (textures of every kind, texture transforms, metals and dielectrics,
/// spot and point lights in the file's units): the GPU's shading mirrors the CPU's.
#[test]
fn gltf_test_scenes_render_the_same_on_cpu_and_gpu() {
    let Some(models) = common::gltf_test_models() else {
        return;
    };
    let gpu = gpu();
    let mut outcomes = Vec::new();
    for model in models {
        let scene = Scene::from_model(&model, None).unwrap_or_else(|e| panic!("{e}"));
        let name = model.file_stem().unwrap().to_string_lossy();
        outcomes.push(compare_scene(&name, &scene, &gpu));
    }
    report(&outcomes);
}

#[test]
fn many_small_tiles_give_the_same_image_as_few_large_ones() {
    let gpu = gpu();
    // Glass: refraction, internal reflection and several bounces; an image size that no tile
    // size divides.
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes/glass.ron");
    let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let opts = RenderOptions {
        width: 75,
        height: 53,
        samples: 2,
        threads: None,
        progress: false,
    };
    let small = gpu
        .renderer
        .render_tiled(&gpu.ctx, &scene, &opts, 8)
        .unwrap()
        .image;
    let large = gpu
        .renderer
        .render_tiled(&gpu.ctx, &scene, &opts, 128)
        .unwrap()
        .image;
    let bits = |fb: &Framebuffer| -> Vec<u32> {
        let v3 = |v: &[glam::Vec3]| -> Vec<u32> {
            v.iter()
                .flat_map(|p| p.to_array().map(f32::to_bits))
                .collect()
        };
        let v1 = |v: &[f32]| -> Vec<u32> { v.iter().map(|x| x.to_bits()).collect() };
        [
            v3(&fb.pixels),
            v1(&fb.depth),
            v3(&fb.normal),
            v3(&fb.albedo),
            v1(&fb.steps),
            v1(&fb.gradient),
        ]
        .concat()
    };
    assert!(
        small.depth.iter().any(|d| d.is_finite()),
        "the test image shows nothing"
    );
    assert!(
        bits(&small) == bits(&large),
        "tiles of 8 and of 128 pixels differ"
    );
}

fn hytrace(args: &[&str], env: &[(&str, &str)]) -> std::process::Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_hytrace"));
    cmd.args(args).current_dir(env!("CARGO_MANIFEST_DIR"));
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().unwrap()
}

#[test]
fn cli_renders_a_png_with_backend_gpu() {
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("gpu_cli_primitives.png");
    let _ = std::fs::remove_file(&out);
    let o = hytrace(
        &[
            "render",
            "assets/scenes/primitives.ron",
            "--backend",
            "gpu",
            "-v",
            "--width",
            "64",
            "--height",
            "48",
            "-o",
            out.to_str().unwrap(),
        ],
        &[],
    );
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "stderr:\n{stderr}");
    assert!(
        stderr.contains("GPU adapter: "),
        "-v names no adapter:\n{stderr}"
    );
    assert!(stderr.contains("rendered on the GPU"), "{stderr}");
    let img = image::open(&out).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (64, 48));
}

/// The environment of a machine with no Vulkan driver: the Vulkan loader is pointed at a
/// driver manifest that does not exist, so it finds no ICD (the variables are the loader's
/// own, VK_DRIVER_FILES and its older name VK_ICD_FILENAMES).
const NO_VULKAN_DRIVER: [(&str, &str); 2] = [
    ("VK_DRIVER_FILES", "/nonexistent/hytrace-no-driver.json"),
    ("VK_ICD_FILENAMES", "/nonexistent/hytrace-no-driver.json"),
];

#[test]
fn backend_gpu_without_an_adapter_is_a_clear_error() {
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("gpu_cli_none.png");
    let o = hytrace(
        &[
            "render",
            "assets/scenes/primitives.ron",
            "--backend",
            "gpu",
            "--width",
            "16",
            "--height",
            "12",
            "-o",
            out.to_str().unwrap(),
        ],
        &NO_VULKAN_DRIVER,
    );
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success(),
        "succeeded without an adapter:\n{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(
        stderr.contains("--backend gpu: no usable GPU adapter"),
        "unclear error:\n{stderr}"
    );
}

#[test]
fn backend_auto_without_an_adapter_falls_back_to_the_cpu() {
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("gpu_cli_auto.png");
    let o = hytrace(
        &[
            "render",
            "assets/scenes/primitives.ron",
            "--width",
            "16",
            "--height",
            "12",
            "-o",
            out.to_str().unwrap(),
        ],
        &NO_VULKAN_DRIVER,
    );
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "stderr:\n{stderr}");
    let line = stderr
        .lines()
        .find(|l| l.starts_with("backend auto:"))
        .unwrap_or_else(|| panic!("auto said nothing about its choice:\n{stderr}"));
    assert!(
        line.contains("no GPU adapter") && line.contains("on the CPU"),
        "{line}"
    );
    assert!(stderr.contains("rendered on the CPU"), "{stderr}");
}
