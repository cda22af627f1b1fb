//! The `hytrace` command line: render scenes, draw 2D slices of their distance fields (and, as
//! the project grows, validate and compare).

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
    /// Render a scene to a PNG (the built-in showcase when no scene is given).
    Render(cli::render::RenderArgs),
    /// Draw the signed distance of a scene on an axis-aligned plane, with iso-contours.
    Slice(cli::slice::SliceArgs),
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Some(Command::Render(args)) => cli::render::run(args),
        Some(Command::Slice(args)) => cli::slice::run(args),
        None => cli::render::run(cli::render::RenderArgs::parse_from(["render"])),
    };
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

/// Loads the scene file, or the built-in showcase when none is given.
fn load_scene(path: Option<&Path>) -> Result<Scene> {
    Ok(match path {
        Some(p) => Scene::load(p)?,
        None => Scene::from_source(SHOWCASE, Path::new("<built-in showcase.ron>"))?,
    })
}
