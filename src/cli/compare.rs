//! `hytrace compare`: one scene rendered by several backends (our CPU tracer, the same shading
//! over Embree 4's hits, the GPU tracer), with each image, difference and ꟻLIP heatmaps, a
//! labelled sheet, PSNR / SSIM / ꟻLIP / share of differing pixels as text and JSON, and a
//! report page to browse them (`index.html`).
// Without the `embree` feature the command is a message; these helpers stay compiled (and the
// metrics unit-tested) so that build still checks them.
#![cfg_attr(not(feature = "embree"), allow(dead_code))]

use anyhow::Result;
#[cfg(feature = "flip")]
use hytrace::render::metrics::Metrics;
use image::RgbImage;
use serde::Serialize;
use std::path::PathBuf;

/// Arguments of `hytrace compare`.
#[derive(clap::Parser)]
#[command(after_help = "\
Writes into DIR: index.html, a self-contained report page (open it in a browser: swipe or flip
between any two images, zoom and pan both together down to single pixels with their values shown,
the metrics table, the scene, size, samples and timings); one PNG per backend (cpu.png,
embree.png, gpu.png); diff-cpu-embree.png (per pixel the largest |difference| of the sRGB
channels, Turbo colour map, scale bar below); flip-cpu-embree.png (the LDR-FLIP error map, magma
colour map, 67 pixels per degree); sheet.png (the images side by side with labels, then the
heatmaps); metrics.txt and metrics.json (PSNR in dB over the 8-bit sRGB channels, SSIM on luma
with Wang et al.'s 11x11 Gaussian window, sigma 1.5, the mean LDR-FLIP error, and the share of
pixels differing by more than --threshold).

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

/// What the JSON file holds.
#[cfg(feature = "flip")]
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

#[cfg(feature = "flip")]
/// PSNR in words: "inf (identical)" when the images are the same.
fn psnr_text(m: &Metrics) -> String {
    m.psnr_db
        .map_or("inf (identical)".to_string(), |p| format!("{p:.2} dB"))
}

#[cfg(feature = "flip")]
/// The metrics as text: one block per comparison.
pub fn metrics_text(metrics: &[Metrics]) -> String {
    let mut s = String::new();
    for m in metrics {
        s += &format!(
            "{} vs {}: PSNR {}, SSIM {:.5}, FLIP {:.5}, {:.3}% of pixels differ by more than {} (largest difference {:.3})\n",
            m.other,
            m.reference,
            psnr_text(m),
            m.ssim,
            m.flip_mean,
            m.percent_over_threshold,
            m.threshold,
            m.max_difference
        );
    }
    s
}

#[cfg(feature = "flip")]
/// The report page: the backends' images, then per comparison its difference and ꟻLIP maps;
/// the metrics table, each row showing its pair; the facts of the run.
#[allow(clippy::too_many_arguments)]
pub fn report_page(
    scene: &str,
    (width, height, samples): (u32, u32, u32),
    backends: &[Backend],
    metrics: &[Metrics],
    maps: &[(String, RgbImage, String, RgbImage)],
    notes: &[String],
) -> Result<hytrace::render::report::Report> {
    use hytrace::render::report::{Picture, Report, Row, Table};
    let mut images = Vec::new();
    for b in backends {
        images.push(Picture::new(b.name, &b.description, &b.image)?);
    }
    let mut rows = Vec::new();
    for (m, (diff_name, diff, flip_name, flip)) in metrics.iter().zip(maps) {
        let reference = backends.iter().position(|b| b.name == m.reference);
        let other = backends.iter().position(|b| b.name == m.other);
        images.push(Picture::new(
            diff_name,
            "largest |difference| of the sRGB channels per pixel (Turbo colour map, saturating at 0.25)",
            diff,
        )?);
        images.push(Picture::new(
            flip_name,
            "LDR-FLIP error per pixel (magma colour map, 67 pixels per degree)",
            flip,
        )?);
        rows.push(Row {
            cells: vec![
                format!("{} vs {}", m.other, m.reference),
                psnr_text(m),
                format!("{:.5}", m.ssim),
                format!("{:.5}", m.flip_mean),
                format!("{:.3}%", m.percent_over_threshold),
                format!("{:.3}", m.max_difference),
            ],
            pair: reference.zip(other),
            failed: false,
        });
    }
    let mut facts = vec![
        ("scene".to_string(), scene.to_string()),
        ("size".to_string(), format!("{width}×{height} pixels")),
        ("samples".to_string(), format!("{samples} per pixel")),
    ];
    for b in backends {
        facts.push((
            b.name.to_string(),
            format!("{:.2} s: {}", b.seconds, b.description),
        ));
    }
    let threshold = metrics.first().map_or(0.0, |m| m.threshold);
    Ok(Report {
        title: format!("hytrace compare: {scene}"),
        facts,
        initial: (0, usize::from(backends.len() > 1)),
        images,
        tables: vec![Table {
            heading: "Metrics (click a row to compare its pair)".into(),
            header: vec![
                "pair".into(),
                "PSNR".into(),
                "SSIM".into(),
                "FLIP mean".into(),
                format!("pixels over {threshold}"),
                "largest difference".into(),
            ],
            rows,
        }],
        notes: notes.to_vec(),
        ..Default::default()
    })
}

/// Renders with every backend, writes the images, the sheet, the heatmaps and the metrics.
#[cfg(feature = "embree")]
pub fn run(args: CompareArgs) -> Result<()> {
    use anyhow::{Context, bail};
    use hytrace::reference::embree::EmbreeScene;
    use hytrace::reference::shading::EmbreeTracer;
    use hytrace::render::metrics::{heatmap, measure, sheet};
    use hytrace::render::output::{ToneMapping, save_png};
    use hytrace::render::view::{View, picture};
    use hytrace::render::{RenderOptions, cpu};
    use hytrace::scene::{MAX_IMAGE_SIDE, MAX_PIXELS, MAX_SAMPLES};
    use hytrace::trace::SceneTracer;
    use std::time::Instant;

    let scene = super::load_any(args.scene.as_deref(), args.camera.as_deref())?;
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

    let opts = RenderOptions {
        width,
        height,
        samples,
        threads: None,
        progress: false,
    };
    let mut backends = Vec::new();
    let mut notes = Vec::new();
    // 1. Our CPU renderer, exactly as `hytrace render` runs it.
    let start = Instant::now();
    let fb = cpu::render(&scene, &opts)?;
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
    let fb = cpu::render_through(&tracer, &opts)?;
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
            scene.objects[i].label()
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
                // (a scene the adapter cannot trace leaves the other images to compare)
                match hytrace::gpu::render::render(&scene, &opts, &ctx) {
                    Ok(gpu) => {
                        if let Some(note) =
                            hytrace::gpu::render::on_cpu_note(&gpu, ctx.adapter_name())
                        {
                            notes.push(format!("gpu image: {note}"));
                        }
                        backends.push(Backend {
                            name: "gpu",
                            description: format!(
                                "our WGSL tracer through wgpu on {} (time includes the \
                                 kernel compile)",
                                ctx.adapter_name()
                            ),
                            image: shaded(&gpu.image),
                            seconds: start.elapsed().as_secs_f64(),
                        })
                    }
                    Err(e) if args.gpu == GpuChoice::Auto => {
                        notes.push(format!("no GPU image on {}: {e}", ctx.adapter_name()));
                    }
                    Err(e) => bail!("--gpu always: {e}"),
                }
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
    let mut maps = Vec::new();
    for other in &backends[1..] {
        let (m, flip) = measure(
            reference.name,
            &reference.image,
            other.name,
            &other.image,
            args.threshold,
        );
        metrics.push(m);
        let diff_name = format!("diff-{}-{}", reference.name, other.name);
        let flip_name = format!("flip-{}-{}", reference.name, other.name);
        let diff = heatmap(&reference.image, &other.image);
        let flip = flip.picture();
        save_png(&diff, &args.output.join(format!("{diff_name}.png")))?;
        save_png(&flip, &args.output.join(format!("{flip_name}.png")))?;
        maps.push((diff_name, diff, flip_name, flip));
    }
    let mut panels: Vec<(String, &RgbImage)> = backends
        .iter()
        .map(|b| (b.name.to_string(), &b.image))
        .collect();
    for (m, (_, diff, _, flip)) in metrics.iter().zip(&maps) {
        panels.push((format!("|{} - {}|", m.other, m.reference), diff));
        panels.push((format!("FLIP {} vs {}", m.other, m.reference), flip));
    }
    save_png(&sheet(&panels), &args.output.join("sheet.png"))?;
    report_page(
        &scene.source_name,
        (width, height, samples),
        &backends,
        &metrics,
        &maps,
        &notes,
    )?
    .write(&args.output.join("index.html"))?;

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
    println!("→ {}", args.output.join("index.html").display());
    Ok(())
}

/// Without Embree there is nothing to compare with: says so and how to get it.
#[cfg(not(feature = "embree"))]
pub fn run(_args: CompareArgs) -> Result<()> {
    anyhow::bail!("{}", super::NO_EMBREE)
}
