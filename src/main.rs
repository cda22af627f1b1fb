//! The `hytrace` command line: render scenes, draw 2D slices of their distance fields, and
//! validate and compare our tracer against Embree 4.

mod cli;

use anyhow::Result;
use clap::{Parser, Subcommand};
use hytrace::scene::Scene;
use std::path::Path;

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
    /// Render a scene to a PNG or an EXR (the built-in showcase when no scene is given).
    Render(cli::render::RenderArgs),
    /// Open a window on a scene: orbit, zoom, fly, debug views, hot reload, screenshots.
    View(cli::view::ViewArgs),
    /// Print what a scene holds: meshes, instances, triangles, SDF nodes, bounds, BVH sizes.
    Info(cli::info::InfoArgs),
    /// Draw the signed distance of a scene on an axis-aligned plane, with iso-contours.
    Slice(cli::slice::SliceArgs),
    /// Benchmark: meshes against Embree, SDF steppers, scaling (Markdown tables, --json).
    Bench(cli::bench::BenchArgs),
    /// Compare our tracer with Embree 4 ray by ray (hit/miss, |Δt|, shadow rays) against the
    /// analytic thresholds (README); exit status 1 when one fails (needs the `embree` feature).
    Validate(cli::validate::ValidateArgs),
    /// Render a scene with our CPU tracer and with our shading over Embree's hits; write both,
    /// a side-by-side sheet, a difference heatmap and PSNR/SSIM (needs the `embree` feature).
    Compare(cli::compare::CompareArgs),
    /// Write a generated test scene of N small SDF objects (for scaling tests and benchmarks).
    Generate {
        /// Number of objects.
        #[arg(long, default_value_t = 10_000)]
        objects: usize,
        /// Output scene file (stdout when absent).
        #[arg(short, long)]
        output: Option<std::path::PathBuf>,
    },
}

fn main() {
    quiet_wayland_probe();
    let cli = Cli::parse();
    let result = match cli.command {
        Some(Command::Render(args)) => cli::render::run(args),
        Some(Command::Slice(args)) => cli::slice::run(args),
        Some(Command::Info(args)) => cli::info::run(args),
        Some(Command::View(args)) => cli::view::run(args),
        Some(Command::Bench(args)) => cli::bench::run(args),
        Some(Command::Validate(args)) => cli::validate::run(args),
        Some(Command::Compare(args)) => cli::compare::run(args),
        Some(Command::Generate { objects, output }) => generate(objects, output.as_deref()),
        None => cli::render::run(cli::render::RenderArgs::parse_from(["render"])),
    };
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

/// Gives the Vulkan loader's Wayland probe an absolute XDG_RUNTIME_DIR when the environment
/// has none (ssh sessions, containers, CI): libwayland then looks for a socket there, finds
/// none and stays quiet, instead of printing "XDG_RUNTIME_DIR is invalid" on every run that
/// touches the GPU, whatever the outcome.
fn quiet_wayland_probe() {
    let usable = std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|d| Path::new(&d).is_absolute());
    if !usable {
        // SAFETY: called first thing in main, before any thread exists that could read the
        // environment concurrently.
        unsafe { std::env::set_var("XDG_RUNTIME_DIR", std::env::temp_dir()) };
    }
}

/// Loads the scene file, or the built-in showcase when none is given.
fn load_scene(path: Option<&Path>) -> Result<Scene> {
    load_any(path, None)
}

/// Loads a scene file, or a mesh file as a scene of its own (a default camera framing it, or
/// the file's camera `camera`, and its lights or default ones), or the showcase.
fn load_any(path: Option<&Path>, camera: Option<&str>) -> Result<Scene> {
    let is_scene = |p: &Path| {
        p.extension()
            .and_then(|e| e.to_str())
            .is_none_or(|e| e.eq_ignore_ascii_case("ron"))
    };
    Ok(match path {
        Some(p) if is_scene(p) => {
            if camera.is_some() {
                anyhow::bail!(
                    "--camera applies to mesh files (.gltf, .glb, .obj, .ply), not scenes"
                );
            }
            Scene::load(p)?
        }
        Some(p) => Scene::from_model(p, camera)?,
        None => Scene::from_source(SHOWCASE, Path::new("<built-in showcase.ron>"))?,
    })
}

fn generate(objects: usize, output: Option<&Path>) -> Result<()> {
    if objects == 0 || objects > 1_000_000 {
        anyhow::bail!("--objects {objects} is out of range 1..=1000000");
    }
    let text = hytrace::scene::generate::many_objects(objects);
    match output {
        Some(p) => std::fs::write(p, text)
            .map_err(|e| anyhow::anyhow!("{}: cannot write: {e}", p.display()))?,
        None => print!("{text}"),
    }
    Ok(())
}
