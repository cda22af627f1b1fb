//! `hytrace compare`: one scene rendered by several backends (our CPU tracer; the same shading
//! over Embree 4's hits; the GPU when it lands), with each image, a labelled side-by-side
//! sheet, difference heatmaps with a colour scale, and PSNR / SSIM / share of differing pixels
//! as text and JSON.
// Without the `embree` feature the command is a message; these helpers stay compiled (and the
// metrics unit-tested) so that build still checks them.
#![cfg_attr(not(feature = "embree"), allow(dead_code))]

use anyhow::Result;
use image::RgbImage;
use serde::Serialize;
use std::path::PathBuf;

/// Arguments of `hytrace compare`.
#[derive(clap::Parser)]
#[command(after_help = "\
Writes into DIR: one PNG per backend (cpu.png, embree.png, gpu.png), sheet.png (the images side by
side with labels, then the difference heatmaps), diff-cpu-embree.png (per pixel the largest
|difference| of the sRGB channels, Turbo colour map, scale bar below), metrics.txt and
metrics.json (PSNR in dB over the 8-bit sRGB channels, SSIM on luma with Wang et al.'s 11x11
Gaussian window, sigma 1.5, and the share of pixels differing by more than --threshold).

The embree image is our integrator (materials, lights, reflection, refraction) run on
Embree's hits: camera, reflected and refracted closest hits and hard shadow rays come from
Embree; soft-shadow penumbrae and ambient occlusion are evaluated with our SDF at Embree's hit
points; mesh shading normals, materials and textures are looked up on our side at Embree's hit
distance.")]
pub struct CompareArgs {
    /// Scene file (.ron) or mesh file (.gltf, .glb, .obj, .ply); omit for the built-in
    /// showcase.
    pub scene: Option<PathBuf>,
    /// For a mesh file: the file's camera with this name or number (from 0).
    #[arg(long)]
    pub camera: Option<String>,
    /// Output folder (created if missing).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Image width (default: the scene's).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height (default: the scene's).
    #[arg(long)]
    pub height: Option<u32>,
    /// Samples per pixel (default: the scene's).
    #[arg(long)]
    pub spp: Option<u32>,
    /// A pixel "differs" when an sRGB channel differs by more than this (0..1).
    #[arg(long, default_value_t = 0.05)]
    pub threshold: f32,
    /// Add the GPU backend's image: `auto` when any adapter exists (a CPU one such as lavapipe
    /// included: this is a correctness comparison, not a speed one), `always` (no adapter is
    /// an error), `never`.
    #[arg(long, value_enum, default_value_t = GpuChoice::Auto)]
    pub gpu: GpuChoice,
}

/// Whether `compare` renders with the GPU backend too.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum GpuChoice {
    /// When an adapter exists.
    Auto,
    /// Always; no adapter is an error.
    Always,
    /// Never.
    Never,
}

/// Differences at or above this (on the 0..1 sRGB scale) saturate the heatmap.
const HEATMAP_SCALE: f32 = 0.25;

/// One rendered image and where it came from.
pub struct Backend {
    /// Short name (also the file name).
    pub name: &'static str,
    /// What it is, in words.
    pub description: String,
    /// The tone-mapped picture.
    pub image: RgbImage,
    /// Render time in seconds.
    pub seconds: f64,
}

/// Image metrics of `other` against `reference`.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Metrics {
    /// Name of the reference backend.
    pub reference: String,
    /// Name of the compared backend.
    pub other: String,
    /// Peak signal-to-noise ratio over the 8-bit sRGB channels, dB (None when identical).
    pub psnr_db: Option<f64>,
    /// Mean structural similarity on luma.
    pub ssim: f64,
    /// Share of pixels with a channel differing by more than the threshold, percent.
    pub percent_over_threshold: f64,
    /// The threshold (sRGB, 0..1).
    pub threshold: f32,
    /// Largest channel difference (sRGB, 0..1).
    pub max_difference: f32,
}

/// PSNR = 10·log10(255² / MSE) over every channel of every pixel; None when the images are
/// identical (MSE = 0).
pub fn psnr(a: &RgbImage, b: &RgbImage) -> Option<f64> {
    let (sum, n) = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .fold((0f64, 0usize), |(s, n), (&x, &y)| {
            let d = x as f64 - y as f64;
            (s + d * d, n + 1)
        });
    let mse = sum / n.max(1) as f64;
    (mse > 0.0).then(|| 10.0 * (255.0f64 * 255.0 / mse).log10())
}

/// Luma Y' = 0.2126 R' + 0.7152 G' + 0.0722 B' (Rec. 709 weights on the sRGB-encoded values),
/// in [0, 1].
fn luma(img: &RgbImage) -> Vec<f64> {
    img.pixels()
        .map(|p| {
            let [r, g, b] = p.0.map(|c| c as f64 / 255.0);
            0.2126 * r + 0.7152 * g + 0.0722 * b
        })
        .collect()
}

/// Mean SSIM on luma (Wang, Bovik, Sheikh & Simoncelli, "Image quality assessment: from error
/// visibility to structural similarity", IEEE TIP 2004): local means, variances and covariance
/// under an 11×11 Gaussian window with σ = 1.5, C₁ = (0.01·L)², C₂ = (0.03·L)² with L = 1,
/// averaged over the window positions that fit inside the image (the whole image as one
/// window when it is smaller than 11 pixels).
pub fn ssim(a: &RgbImage, b: &RgbImage) -> f64 {
    const RADIUS: usize = 5;
    const SIGMA: f64 = 1.5;
    let (w, h) = (a.width() as usize, a.height() as usize);
    let (x, y) = (luma(a), luma(b));
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let index = |mx: f64, my: f64, vx: f64, vy: f64, cxy: f64| {
        ((2.0 * mx * my + c1) * (2.0 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    };
    let size = 2 * RADIUS + 1;
    if w < size || h < size {
        let n = (w * h).max(1) as f64;
        let mx = x.iter().sum::<f64>() / n;
        let my = y.iter().sum::<f64>() / n;
        let vx = x.iter().map(|v| (v - mx).powi(2)).sum::<f64>() / n;
        let vy = y.iter().map(|v| (v - my).powi(2)).sum::<f64>() / n;
        let cxy = x
            .iter()
            .zip(&y)
            .map(|(p, q)| (p - mx) * (q - my))
            .sum::<f64>()
            / n;
        return index(mx, my, vx, vy, cxy);
    }
    let kernel: Vec<f64> = {
        let k: Vec<f64> = (0..size)
            .map(|i| {
                let d = i as f64 - RADIUS as f64;
                (-d * d / (2.0 * SIGMA * SIGMA)).exp()
            })
            .collect();
        let s: f64 = k.iter().sum();
        k.into_iter().map(|v| v / s).collect()
    };
    // Separable filtering of the five fields, keeping only positions where the window fits.
    let filter = |f: &dyn Fn(usize) -> f64| -> Vec<f64> {
        let (ow, oh) = (w - 2 * RADIUS, h - 2 * RADIUS);
        let mut rows = vec![0.0; ow * h];
        for j in 0..h {
            for i in 0..ow {
                rows[j * ow + i] = (0..size).map(|k| kernel[k] * f(j * w + i + k)).sum();
            }
        }
        let mut out = vec![0.0; ow * oh];
        for j in 0..oh {
            for i in 0..ow {
                out[j * ow + i] = (0..size).map(|k| kernel[k] * rows[(j + k) * ow + i]).sum();
            }
        }
        out
    };
    let mx = filter(&|i| x[i]);
    let my = filter(&|i| y[i]);
    let sxx = filter(&|i| x[i] * x[i]);
    let syy = filter(&|i| y[i] * y[i]);
    let sxy = filter(&|i| x[i] * y[i]);
    let n = mx.len();
    (0..n)
        .map(|i| {
            let (a, b) = (mx[i], my[i]);
            index(a, b, sxx[i] - a * a, syy[i] - b * b, sxy[i] - a * b)
        })
        .sum::<f64>()
        / n as f64
}

/// Per pixel, the largest |difference| of the three sRGB channels, in [0, 1].
pub fn difference(a: &RgbImage, b: &RgbImage) -> Vec<f32> {
    a.pixels()
        .zip(b.pixels())
        .map(|(p, q)| {
            (0..3)
                .map(|c| (p.0[c] as f32 - q.0[c] as f32).abs() / 255.0)
                .fold(0.0, f32::max)
        })
        .collect()
}

/// The metrics of `other` against `reference`.
pub fn metrics(reference: &Backend, other: &Backend, threshold: f32) -> Metrics {
    let diff = difference(&reference.image, &other.image);
    let over = diff.iter().filter(|&&d| d > threshold).count();
    Metrics {
        reference: reference.name.into(),
        other: other.name.into(),
        psnr_db: psnr(&reference.image, &other.image),
        ssim: ssim(&reference.image, &other.image),
        percent_over_threshold: 100.0 * over as f64 / diff.len().max(1) as f64,
        threshold,
        max_difference: diff.iter().copied().fold(0.0, f32::max),
    }
}

/// The difference heatmap of two pictures (Turbo colour map over [0, HEATMAP_SCALE]) with a
/// numbered colour bar below it.
pub fn heatmap(a: &RgbImage, b: &RgbImage) -> RgbImage {
    use hytrace::render::draw;
    use hytrace::render::view::turbo;
    let diff = difference(a, b);
    let (w, h) = a.dimensions();
    let bar_h = 3 * draw::LINE + 10;
    let width = w.max(220);
    let mut img = RgbImage::from_pixel(width, h + bar_h, image::Rgb([0, 0, 0]));
    for y in 0..h {
        for x in 0..w {
            let d = diff[(y * w + x) as usize];
            img.put_pixel(x, y, image::Rgb(draw::to_u8(turbo(d / HEATMAP_SCALE))));
        }
    }
    draw::colour_bar(
        &mut img,
        4,
        h + 3,
        width - 8,
        "max |sRGB diff| per pixel",
        0.0,
        HEATMAP_SCALE,
        4,
        turbo,
    );
    img
}

/// The pictures side by side, each with its label above, on one sheet.
pub fn sheet(panels: &[(String, &RgbImage)]) -> RgbImage {
    use hytrace::render::draw;
    let gap = 6;
    let label_h = draw::LINE + 6;
    let w: u32 =
        panels.iter().map(|(_, i)| i.width()).sum::<u32>() + gap * (panels.len() as u32 + 1);
    let h = panels.iter().map(|(_, i)| i.height()).max().unwrap_or(0) + label_h + 2 * gap;
    let mut img = RgbImage::from_pixel(w, h, image::Rgb([32, 32, 32]));
    let mut x = gap;
    for (label, panel) in panels {
        draw::text(&mut img, x, gap, label, [240, 240, 240]);
        image::imageops::replace(&mut img, *panel, x as i64, (gap + label_h) as i64);
        x += panel.width() + gap;
    }
    img
}

/// What the JSON file holds.
#[derive(Serialize)]
struct MetricsFile<'a> {
    scene: &'a str,
    width: u32,
    height: u32,
    spp: u32,
    backends: Vec<BackendEntry<'a>>,
    comparisons: &'a [Metrics],
    notes: &'a [String],
}

#[derive(Serialize)]
struct BackendEntry<'a> {
    name: &'a str,
    file: String,
    description: &'a str,
    seconds: f64,
}

/// The metrics as text: one block per comparison.
pub fn metrics_text(metrics: &[Metrics]) -> String {
    let mut s = String::new();
    for m in metrics {
        let psnr = m
            .psnr_db
            .map_or("inf (identical)".to_string(), |p| format!("{p:.2} dB"));
        s += &format!(
            "{} vs {}: PSNR {psnr}, SSIM {:.5}, {:.3}% of pixels differ by more than {} (largest difference {:.3})\n",
            m.other, m.reference, m.ssim, m.percent_over_threshold, m.threshold, m.max_difference
        );
    }
    s
}

/// Renders with every backend, writes the images, the sheet, the heatmaps and the metrics.
#[cfg(feature = "embree")]
pub fn run(args: CompareArgs) -> Result<()> {
    use anyhow::{Context, bail};
    use hytrace::reference::embree::EmbreeScene;
    use hytrace::reference::shading::{EmbreeTracer, render_image};
    use hytrace::render::output::{ToneMapping, save_png};
    use hytrace::render::view::{View, picture};
    use hytrace::render::{RenderOptions, cpu};
    use hytrace::scene::{MAX_IMAGE_SIDE, MAX_PIXELS, MAX_SAMPLES};
    use hytrace::trace::SceneTracer;
    use std::time::Instant;

    let scene = crate::load_any(args.scene.as_deref(), args.camera.as_deref())?;
    let width = args.width.unwrap_or(scene.image.width);
    let height = args.height.unwrap_or(scene.image.height);
    let samples = args.spp.unwrap_or(scene.image.samples);
    if width == 0 || height == 0 {
        bail!("--width and --height must be at least 1 (got {width}×{height})");
    }
    if width > MAX_IMAGE_SIDE
        || height > MAX_IMAGE_SIDE
        || width as u64 * height as u64 > MAX_PIXELS
    {
        bail!(
            "image size {width}×{height} is too large (at most {MAX_IMAGE_SIDE} per side and {MAX_PIXELS} pixels)"
        );
    }
    if samples == 0 || samples > MAX_SAMPLES {
        bail!("--spp {samples} is out of range 1..={MAX_SAMPLES}");
    }
    if !(args.threshold.is_finite() && (0.0..1.0).contains(&args.threshold)) {
        bail!("--threshold {} is out of range 0..1", args.threshold);
    }
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("{}: cannot create the folder", args.output.display()))?;
    let tone = ToneMapping {
        exposure: scene.image.exposure,
        operator: scene.image.tonemap,
    };
    let shaded =
        |fb: &hytrace::render::Framebuffer| picture(fb, View::Shaded, tone, scene.tracer.max_steps);

    let mut backends = Vec::new();
    let mut notes = Vec::new();
    // 1. Our CPU renderer, exactly as `hytrace render` runs it.
    let start = Instant::now();
    let fb = cpu::render(
        &scene,
        &RenderOptions {
            width,
            height,
            samples,
            threads: None,
            progress: false,
        },
    )?;
    backends.push(Backend {
        name: "cpu",
        description: "our CPU tracer: sphere-traced SDFs and our mesh BVH".into(),
        image: shaded(&fb),
        seconds: start.elapsed().as_secs_f64(),
    });
    // 2. The same integrator over Embree's hits.
    let start = Instant::now();
    let embree = EmbreeScene::build(&scene)
        .map_err(|e| anyhow::anyhow!("{}: Embree: {e}", scene.source_name))?;
    let ours = SceneTracer::new(&scene);
    let tracer = EmbreeTracer::new(&embree, &ours);
    let fb = render_image(&tracer, width, height, samples);
    let (fallbacks, mesh_hits) = tracer.fallbacks();
    backends.push(Backend {
        name: "embree",
        description: "our shading over Embree 4's hits: camera, reflection and refraction \
                      rays and hard shadows from Embree; soft-shadow penumbrae and ambient \
                      occlusion from our SDF at Embree's hit points"
            .into(),
        image: shaded(&fb),
        seconds: start.elapsed().as_secs_f64(),
    });
    for (i, why) in embree.skipped() {
        notes.push(format!(
            "SDF object #{i} `{}` is missing from the Embree image: {why}",
            scene.objects[i].name
        ));
    }
    if mesh_hits > 0 {
        notes.push(format!(
            "{fallbacks} of {mesh_hits} Embree mesh hits had no triangle of ours within \
             1e-4 × the scene diameter (shaded with Embree's geometric normal)"
        ));
    }
    // 3. The GPU backend: the same scene description, uploaded and traced in WGSL.
    #[cfg(feature = "gpu")]
    if args.gpu != GpuChoice::Never {
        match hytrace::gpu::context::GpuContext::new() {
            Ok(ctx) => {
                let start = Instant::now();
                let fb = hytrace::gpu::render::render(
                    &scene,
                    &RenderOptions {
                        width,
                        height,
                        samples,
                        threads: None,
                        progress: false,
                    },
                    &ctx,
                )?;
                backends.push(Backend {
                    name: "gpu",
                    description: format!(
                        "our WGSL tracer through wgpu on {} (time includes the kernel compile)",
                        ctx.adapter_name()
                    ),
                    image: shaded(&fb),
                    seconds: start.elapsed().as_secs_f64(),
                });
            }
            Err(e) if args.gpu == GpuChoice::Auto => {
                notes.push(format!("no GPU image: {e}"));
            }
            Err(e) => bail!("--gpu always: {e}"),
        }
    }
    #[cfg(not(feature = "gpu"))]
    if args.gpu == GpuChoice::Always {
        bail!("--gpu always: this hytrace was built without the `gpu` feature");
    }

    // Files.
    for b in &backends {
        save_png(&b.image, &args.output.join(format!("{}.png", b.name)))?;
    }
    let reference = &backends[0];
    let mut metrics = Vec::new();
    let mut heatmaps = Vec::new();
    for other in &backends[1..] {
        metrics.push(self::metrics(reference, other, args.threshold));
        let map = heatmap(&reference.image, &other.image);
        save_png(
            &map,
            &args
                .output
                .join(format!("diff-{}-{}.png", reference.name, other.name)),
        )?;
        heatmaps.push((format!("|{} - {}|", other.name, reference.name), map));
    }
    let mut panels: Vec<(String, &RgbImage)> = backends
        .iter()
        .map(|b| (b.name.to_string(), &b.image))
        .collect();
    panels.extend(heatmaps.iter().map(|(l, m)| (l.clone(), m)));
    save_png(&sheet(&panels), &args.output.join("sheet.png"))?;

    let mut text = format!(
        "scene {}\n{width}×{height} px, {samples} spp\n\n",
        scene.source_name
    );
    for b in &backends {
        text += &format!("{:<8} {} ({:.2} s)\n", b.name, b.description, b.seconds);
    }
    text += "\n";
    text += &metrics_text(&metrics);
    for n in &notes {
        text += &format!("note: {n}\n");
    }
    std::fs::write(args.output.join("metrics.txt"), &text)
        .with_context(|| format!("{}: cannot write metrics.txt", args.output.display()))?;
    let file = MetricsFile {
        scene: &scene.source_name,
        width,
        height,
        spp: samples,
        backends: backends
            .iter()
            .map(|b| BackendEntry {
                name: b.name,
                file: format!("{}.png", b.name),
                description: &b.description,
                seconds: b.seconds,
            })
            .collect(),
        comparisons: &metrics,
        notes: &notes,
    };
    std::fs::write(
        args.output.join("metrics.json"),
        serde_json::to_string_pretty(&file)? + "\n",
    )
    .with_context(|| format!("{}: cannot write metrics.json", args.output.display()))?;
    print!("{text}");
    println!("→ {}", args.output.display());
    Ok(())
}

/// Without Embree there is nothing to compare with: says so and how to get it.
#[cfg(not(feature = "embree"))]
pub fn run(_args: CompareArgs) -> Result<()> {
    anyhow::bail!("{}", super::NO_EMBREE)
}

/// A grey picture of constant value, for the tests.
#[cfg(test)]
fn flat(w: u32, h: u32, v: u8) -> RgbImage {
    RgbImage::from_pixel(w, h, image::Rgb([v, v, v]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use hytrace::rng::Rng;

    fn noisy(w: u32, h: u32, seed: u64, amplitude: f32) -> RgbImage {
        let mut rng = Rng::new(seed);
        RgbImage::from_fn(w, h, |x, y| {
            let base = 128.0 + 60.0 * ((x as f32 * 0.2).sin() + (y as f32 * 0.15).cos());
            let v = (base + amplitude * (rng.next_f32() - 0.5)).clamp(0.0, 255.0) as u8;
            image::Rgb([v, v, v])
        })
    }

    #[test]
    fn identical_images() {
        let a = noisy(64, 48, 1, 0.0);
        assert_eq!(psnr(&a, &a), None);
        assert!((ssim(&a, &a) - 1.0).abs() < 1e-12);
        assert!(difference(&a, &a).iter().all(|&d| d == 0.0));
    }

    /// A uniform offset of 16 levels: MSE = 256, PSNR = 10·log10(255²/256) = 24.048 dB.
    #[test]
    fn psnr_of_a_known_offset() {
        let p = psnr(&flat(20, 20, 100), &flat(20, 20, 116)).unwrap();
        assert!((p - 24.0484).abs() < 1e-3, "{p}");
    }

    /// SSIM falls as noise grows, and stays within [-1, 1].
    #[test]
    fn ssim_orders_noise() {
        let a = noisy(80, 60, 1, 0.0);
        let mild = ssim(&a, &noisy(80, 60, 2, 20.0));
        let strong = ssim(&a, &noisy(80, 60, 3, 120.0));
        assert!(
            mild < 1.0 && strong < mild && strong > -1.0,
            "{mild} {strong}"
        );
        // Tiny images use one window over the whole picture.
        assert!((ssim(&flat(5, 5, 9), &flat(5, 5, 9)) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn heatmap_and_sheet_sizes() {
        let a = flat(40, 30, 10);
        let b = flat(40, 30, 200);
        let map = heatmap(&a, &b);
        assert!(map.width() >= 40 && map.height() > 30);
        // a difference of 190/255 > HEATMAP_SCALE saturates to Turbo's top colour
        let top = hytrace::render::draw::to_u8(hytrace::render::view::turbo(1.0));
        assert_eq!(map.get_pixel(5, 5).0, top);
        let s = sheet(&[("a".into(), &a), ("b".into(), &b)]);
        assert_eq!(s.width(), 40 + 40 + 3 * 6);
    }
}
