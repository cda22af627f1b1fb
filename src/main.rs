//! The `hytrace` command line: render scenes (and, as the project grows, validate and compare).

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use hytrace::render::{RenderOptions, cpu, output};
use hytrace::scene::{MAX_IMAGE_SIDE, MAX_PIXELS, MAX_SAMPLES, Scene};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The showcase scene, built into the binary so `hytrace render` works with no file.
const SHOWCASE: &str = include_str!("../assets/scenes/showcase.ron");

#[derive(Parser)]
#[command(name = "hytrace", version, about = "Hybrid mesh + SDF renderer")]
struct Cli {
    /// What to do; with none, `render` the built-in showcase to out.png.
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene to a PNG (the built-in showcase when no scene is given).
    Render(RenderArgs),
}

#[derive(clap::Parser)]
struct RenderArgs {
    /// Scene file (.ron); omit for the built-in showcase.
    scene: Option<PathBuf>,
    /// Output image.
    #[arg(short, long, default_value = "out.png")]
    output: PathBuf,
    /// Image width (overrides the scene).
    #[arg(long)]
    width: Option<u32>,
    /// Image height (overrides the scene).
    #[arg(long)]
    height: Option<u32>,
    /// Samples per pixel (overrides the scene).
    #[arg(long)]
    spp: Option<u32>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Normal estimator (overrides the scene).
    #[arg(long, value_enum)]
    normals: Option<hytrace::scene::file::NormalMethod>,
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Some(Command::Render(args)) => render(args),
        None => render(RenderArgs::parse_from(["render"])),
    };
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn load_scene(path: Option<&Path>) -> Result<Scene> {
    Ok(match path {
        Some(p) => Scene::load(p)?,
        None => Scene::from_source(SHOWCASE, Path::new("<built-in showcase.ron>"))?,
    })
}

fn render(args: RenderArgs) -> Result<()> {
    let mut scene = load_scene(args.scene.as_deref())?;
    if let Some(n) = args.normals {
        scene.tracer.normals = n;
    }
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
    if args.threads == Some(0) {
        bail!("--threads must be at least 1");
    }
    let ext = args
        .output
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if ext.as_deref() != Some("png") {
        bail!(
            "{}: unsupported output format (use a .png file name)",
            args.output.display()
        );
    }
    let opts = RenderOptions {
        width,
        height,
        samples,
        threads: args.threads,
        progress: !args.quiet && std::io::stderr().is_terminal(),
    };
    let start = Instant::now();
    let fb = cpu::render(&scene, &opts)?;
    let elapsed = start.elapsed();
    output::save_png(&fb, &args.output)
        .with_context(|| format!("writing {}", args.output.display()))?;
    if !args.quiet {
        eprintln!(
            "{}: {}×{} px, {} spp, {} object(s), rendered in {:.3} s → {}",
            scene.source_name,
            width,
            height,
            samples,
            scene.objects.len(),
            elapsed.as_secs_f64(),
            args.output.display()
        );
    }
    Ok(())
}
