//! The `hytrace` command line: render scenes, draw 2D slices of their distance fields, and
//! validate and compare our tracer against Embree 4.

mod cli;

use clap::{Parser, Subcommand};
use std::path::Path;

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
    /// Render a scene with our CPU tracer, with our shading over Embree's hits and on the GPU;
    /// write the images, difference and FLIP maps, PSNR/SSIM/FLIP and a report page to browse
    /// (needs the `embree` feature).
    Compare(cli::compare::CompareArgs),
    /// Write a generated test scene of N small SDF objects (for scaling tests and benchmarks).
    Generate(cli::generate::GenerateArgs),
}

fn main() {
    quiet_wayland_probe();
    let cli = Cli::try_parse().unwrap_or_else(|e| exit_on_command_line_error(e));
    let result = match cli.command {
        Some(Command::Render(args)) => cli::render::run(args),
        Some(Command::Slice(args)) => cli::slice::run(args),
        Some(Command::Info(args)) => cli::info::run(args),
        Some(Command::View(args)) => cli::view::run(args),
        Some(Command::Bench(args)) => cli::bench::run(args),
        Some(Command::Validate(args)) => cli::validate::run(args),
        Some(Command::Compare(args)) => cli::compare::run(args),
        Some(Command::Generate(args)) => cli::generate::run(args),
        None => cli::render::run(cli::render::RenderArgs::parse_from(["render"])),
    };
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

/// Reports a bad command line on one line, as every other error is reported: clap's own
/// report adds a tip, the usage and a pointer to `--help` on lines of their own. Help and
/// version requests, and help shown for a missing subcommand, print as clap prints them.
fn exit_on_command_line_error(e: clap::Error) -> ! {
    use clap::error::ErrorKind;
    if matches!(
        e.kind(),
        ErrorKind::DisplayHelp
            | ErrorKind::DisplayVersion
            | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
    ) {
        e.exit();
    }
    let text = e.render().to_string();
    let first = text
        .lines()
        .map(str::trim_end)
        .find(|l| !l.is_empty())
        .unwrap_or("error: invalid command line");
    // The values a flag takes, when clap lists them, stay on the line.
    let values = text
        .lines()
        .map(str::trim)
        .find(|l| l.starts_with("[possible values:"))
        .map_or(String::new(), |v| format!(" {v}"));
    eprintln!("{first}{values} (see --help)");
    std::process::exit(2);
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
