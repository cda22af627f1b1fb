//! `hytrace generate`: a test scene of many small SDF objects, for scaling tests and benchmarks.

use anyhow::Result;
use std::path::PathBuf;

/// Arguments of `hytrace generate`.
#[derive(clap::Parser)]
pub struct GenerateArgs {
    /// Number of objects.
    #[arg(long, default_value_t = 10_000)]
    pub objects: usize,
    /// Output scene file (stdout when absent).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Small CSG trees (a box less a sphere, a box smoothly joined to a torus, a box and a
    /// sphere together, each turned about all three axes) instead of single primitives.
    #[arg(long)]
    pub csg: bool,
}

/// Writes the scene.
pub fn run(args: GenerateArgs) -> Result<()> {
    let objects = args.objects;
    if objects == 0 || objects > 1_000_000 {
        anyhow::bail!("--objects {objects} is out of range 1..=1000000");
    }
    use hytrace::scene::generate::{Shapes, many_objects_of};
    let shapes = if args.csg {
        Shapes::Csg
    } else {
        Shapes::Primitives
    };
    let text = many_objects_of(objects, shapes);
    match &args.output {
        Some(p) => std::fs::write(p, text)
            .map_err(|e| anyhow::anyhow!("{}: cannot write: {e}", p.display()))?,
        None => print!("{text}"),
    }
    Ok(())
}
