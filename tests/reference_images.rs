//! Stored reference images, as Mitsuba 3 keeps them: every shipped scene and every glTF test
//! scene (`common::gltf_test_models`, rendered as `hytrace render MODEL` does; stored as
//! `gltf-NAME.png`) rendered small and checked in under `tests/reference/`, and each run's CPU and GPU images compared with them.
//! The other image tests are differential (CPU against GPU, against Embree): a bug in code both
//! backends share passes those unseen, and is caught here.
//!
//! A pixel passes when no sRGB channel differs from the stored one by more than
//! [`LEVELS`] of 255; a scene passes when at least [`PASS_RATE`] of its pixels do. (The renders
//! are deterministic — fixed sample positions, the same bits for any thread count — so on this
//! machine the images are equal; the margins absorb another CPU's or driver's last-bit
//! differences in `sin`/`cos`/`pow` and the few silhouette pixels they can tip.) A failure
//! writes the stored image, the new one and their difference heatmap into
//! `target/reference-failures/` and names them.
//!
//! `scripts/update-reference-images.sh` regenerates the stored images on purpose (after a
//! change meant to alter the pictures): it runs this test with `HYTRACE_UPDATE_REFERENCES=1`.
//! A missing stored image fails the test and says so; it is never written silently.

use hytrace::render::metrics::{difference, heatmap};
use hytrace::render::output::{ToneMapping, save_png};
use hytrace::render::view::{View, picture};
use hytrace::render::{Framebuffer, RenderOptions, cpu};
use hytrace::scene::Scene;
use image::RgbImage;
use std::path::{Path, PathBuf};

mod common;

/// Largest per-channel difference a pixel may show, in 8-bit sRGB levels.
const LEVELS: u8 = 3;
/// Share of pixels that must be within [`LEVELS`].
const PASS_RATE: f64 = 0.995;
/// Width of the stored images (the height keeps the scene's aspect).
const WIDTH: u32 = 160;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Every shipped 3D scene (the slices are 2D and have their own tests).
fn scenes() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(root().join("assets/scenes"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "ron"))
        .collect();
    v.sort();
    assert!(v.len() >= 10, "the shipped scenes: {v:?}");
    v
}

/// Every scene with a stored reference: the shipped scenes, then the glTF test scenes.
fn cases() -> Vec<(String, Scene)> {
    let mut out: Vec<(String, Scene)> = scenes()
        .iter()
        .map(|p| {
            (
                p.file_stem().unwrap().to_str().unwrap().to_string(),
                load(p),
            )
        })
        .collect();
    for model in common::gltf_test_models().unwrap_or_default() {
        let scene = Scene::from_model(&model, None).unwrap_or_else(|e| panic!("{e}"));
        let stem = model.file_stem().unwrap().to_str().unwrap();
        out.push((format!("gltf-{stem}"), scene));
    }
    out
}

fn load(path: &Path) -> Scene {
    Scene::load(path).unwrap_or_else(|e| {
        panic!("{e} (hybrid.ron needs the shared models: set HYTRACE_ASSETS to their folder)")
    })
}

fn options(scene: &Scene) -> RenderOptions {
    let height = (WIDTH as f64 * scene.image.height as f64 / scene.image.width as f64).round();
    RenderOptions {
        width: WIDTH,
        height: height as u32,
        samples: scene.image.samples,
        threads: None,
        progress: false,
    }
}

fn shaded(scene: &Scene, fb: &Framebuffer) -> RgbImage {
    let tone = ToneMapping {
        exposure: scene.image.exposure,
        operator: scene.image.tonemap,
    };
    picture(fb, View::Shaded, tone, scene.tracer.max_steps)
}

fn stored_path(name: &str) -> PathBuf {
    root().join("tests/reference").join(format!("{name}.png"))
}

/// Compares `image` with the stored reference of `name`; the failure, if any, in words (with
/// the files it wrote).
fn check(name: &str, backend: &str, image: &RgbImage) -> Result<String, String> {
    let path = stored_path(name);
    let stored = image::open(&path)
        .map_err(|e| {
            format!(
                "{name}: no stored reference image at {} ({e}); run scripts/update-reference-images.sh to make it",
                path.display()
            )
        })?
        .into_rgb8();
    if stored.dimensions() != image.dimensions() {
        return Err(format!(
            "{name} ({backend}): {}×{} rendered, {}×{} stored",
            image.width(),
            image.height(),
            stored.width(),
            stored.height()
        ));
    }
    let diff = difference(&stored, image);
    let within = diff
        .iter()
        .filter(|&&d| d * 255.0 <= LEVELS as f32 + 0.5)
        .count();
    let rate = within as f64 / diff.len() as f64;
    let worst = diff.iter().copied().fold(0.0, f32::max) * 255.0;
    let summary = format!(
        "{name} ({backend}): {:.3}% of pixels within {LEVELS} levels, largest difference {worst:.0} levels",
        100.0 * rate
    );
    if rate >= PASS_RATE {
        return Ok(summary);
    }
    let out = root().join("target/reference-failures");
    std::fs::create_dir_all(&out).unwrap();
    let files = [
        (format!("{name}-{backend}-expected.png"), stored.clone()),
        (format!("{name}-{backend}-actual.png"), image.clone()),
        (
            format!("{name}-{backend}-diff.png"),
            heatmap(&stored, image),
        ),
    ];
    for (file, img) in &files {
        save_png(img, &out.join(file)).unwrap();
    }
    Err(format!(
        "{summary}: below {:.1}%; wrote {} and {}",
        100.0 * PASS_RATE,
        files.map(|(f, _)| f).join(", "),
        out.display()
    ))
}

fn updating() -> bool {
    std::env::var_os("HYTRACE_UPDATE_REFERENCES").is_some_and(|v| v == "1")
}

#[test]
fn cpu_images_match_the_stored_references() {
    let mut failures = Vec::new();
    for (name, scene) in cases() {
        let fb = cpu::render(&scene, &options(&scene)).unwrap();
        let image = shaded(&scene, &fb);
        if updating() {
            save_png(&image, &stored_path(&name)).unwrap();
            println!("{name}: stored {}", stored_path(&name).display());
            continue;
        }
        match check(&name, "cpu", &image) {
            Ok(s) => println!("{s}"),
            Err(e) => failures.push(e),
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[cfg(feature = "gpu")]
#[test]
fn gpu_images_match_the_stored_references() {
    use hytrace::gpu::context::GpuContext;
    use hytrace::gpu::render::GpuRenderer;
    if updating() {
        // the CPU's images are the stored ones
        return;
    }
    let ctx = GpuContext::new().expect(
        "a GPU adapter (on a machine without a GPU, Mesa's lavapipe: scripts/setup.sh installs it)",
    );
    let renderer = GpuRenderer::new(&ctx);
    let mut failures = Vec::new();
    for (name, scene) in cases() {
        let fb = renderer.render(&ctx, &scene, &options(&scene)).unwrap();
        match check(&name, "gpu", &shaded(&scene, &fb)) {
            Ok(s) => println!("{s}"),
            Err(e) => failures.push(e),
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
