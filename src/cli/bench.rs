//! `hytrace bench`: our tracer against Embree, the SDF steppers, and scaling, as Markdown
//! tables on stdout and optionally JSON.

use anyhow::{Context, Result};
use hytrace::bench::{BenchOptions, Sections};
use std::path::PathBuf;

/// Arguments of `hytrace bench`.
#[derive(clap::Parser)]
pub struct BenchArgs {
    /// A smoke run: tiny images and ray counts, one timed run, the bunny only. It checks
    /// that the bench runs; its figures mean nothing.
    #[arg(long)]
    pub quick: bool,
    /// Timed runs per figure (after a warm-up), at least; the median is reported.
    #[arg(long)]
    pub runs: Option<usize>,
    /// Keep timing rounds beyond --runs until each backend has been timed this many seconds
    /// per figure (default 1; 0 with --quick).
    #[arg(long)]
    pub min_seconds: Option<f64>,
    /// Thread counts to measure with, comma-separated (default: 1 and all cores).
    #[arg(long, value_delimiter = ',')]
    pub threads: Vec<usize>,
    /// Folder of the shared assets (default: $HYTRACE_ASSETS, else ../shared/assets).
    #[arg(long)]
    pub assets: Option<PathBuf>,
    /// Folder of the SDF scene files (the showcase and the feature scenes).
    #[arg(long, default_value = "assets/scenes")]
    pub scenes: PathBuf,
    /// Mesh scenes to run, comma-separated (ReciprocatingSaw, 2CylinderEngine,
    /// MetalRoughSpheresNoTextures, bunny); default all (the bunny with --quick).
    #[arg(long, value_delimiter = ',')]
    pub mesh_scenes: Vec<String>,
    /// Ray sets of the mesh section, comma-separated (primary, ao, shadow, incoherent);
    /// default all. The geometric means cover the sets that ran.
    #[arg(long, value_delimiter = ',')]
    pub ray_sets: Vec<String>,
    /// Primary-ray image of the mesh section, WIDTHxHEIGHT.
    #[arg(long)]
    pub size: Option<String>,
    /// Image side of the peer section in pixels (square images; default 1024, 64 with
    /// --quick).
    #[arg(long)]
    pub peer_size: Option<u32>,
    /// Seconds after which the peer section cancels a fidget frame (reported as over the
    /// limit; default 30).
    #[arg(long, default_value_t = 30.0)]
    pub peer_frame_limit: f64,
    /// Incoherent rays per mesh scene.
    #[arg(long)]
    pub incoherent: Option<usize>,
    /// Build quality of our mesh BVHs, traced and timed against Embree's HIGH build
    /// (`medium`, the renderer's default, traces as fast as `highest` within a few per cent).
    #[arg(long, value_enum, default_value = "medium")]
    pub bvh: super::flags::BvhArg,
    /// Rays per Embree packet query, 8 or 16 (default: the widest the Embree library runs
    /// natively).
    #[arg(long)]
    pub embree_packet: Option<usize>,
    /// Sections to run, comma-separated: mesh, sdf, scaling, peer (default all; peer needs
    /// the `fidget` feature), or evaluators: only the peer section's "Tape evaluators" table.
    #[arg(long, value_delimiter = ',')]
    pub only: Vec<String>,
    /// Also write the report as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

fn parse_size(s: &str) -> Result<(u32, u32)> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .with_context(|| format!("--size {s}: expected WIDTHxHEIGHT"))?;
    let w: u32 = w
        .parse()
        .with_context(|| format!("--size {s}: bad width"))?;
    let h: u32 = h
        .parse()
        .with_context(|| format!("--size {s}: bad height"))?;
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        anyhow::bail!("--size {s}: width and height must be in 1..=16384");
    }
    Ok((w, h))
}

/// Runs the bench.
pub fn run(args: BenchArgs) -> Result<()> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut threads = if args.threads.is_empty() {
        vec![1, cores]
    } else {
        args.threads.clone()
    };
    if threads.iter().any(|&t| t == 0 || t > 1024) {
        anyhow::bail!("--threads: each count must be in 1..=1024");
    }
    threads.dedup();
    let (width, height) = match &args.size {
        Some(s) => parse_size(s)?,
        None if args.quick => (64, 36),
        None => (1920, 1080),
    };
    let mut sections = Sections {
        mesh: true,
        sdf: true,
        scaling: true,
        peer: true,
        evaluators: true,
    };
    if !args.only.is_empty() {
        sections = Sections {
            mesh: false,
            sdf: false,
            scaling: false,
            peer: false,
            evaluators: false,
        };
        for s in &args.only {
            match s.as_str() {
                "mesh" => sections.mesh = true,
                "sdf" => sections.sdf = true,
                "scaling" => sections.scaling = true,
                "peer" => {
                    sections.peer = true;
                    sections.evaluators = true;
                }
                "evaluators" => sections.evaluators = true,
                other => {
                    anyhow::bail!("--only {other}: expected mesh, sdf, scaling, peer or evaluators")
                }
            }
        }
    }
    let assets = args.assets.clone().unwrap_or_else(super::assets_dir);
    // Said here, where the ways to point at the folder are known, and before any timing.
    if sections.mesh && !assets.is_dir() {
        anyhow::bail!(
            "{}: no shared assets folder for the mesh section (set HYTRACE_ASSETS or --assets \
             to it, or leave the section out with --only)",
            assets.display()
        );
    }
    let mesh_scenes = if args.mesh_scenes.is_empty() && args.quick {
        vec!["bunny".to_string()]
    } else {
        args.mesh_scenes.clone()
    };
    for set in &args.ray_sets {
        if !hytrace::bench::mesh::RAY_SETS.contains(&set.as_str()) {
            anyhow::bail!(
                "--ray-sets {set}: expected some of {}",
                hytrace::bench::mesh::RAY_SETS.join(", ")
            );
        }
    }
    let peer_size = args.peer_size.unwrap_or(if args.quick { 64 } else { 1024 });
    if !(8..=4096).contains(&peer_size) {
        anyhow::bail!("--peer-size {peer_size}: expected a side in 8..=4096 pixels");
    }
    if !(0.1..=3600.0).contains(&args.peer_frame_limit) {
        anyhow::bail!(
            "--peer-frame-limit {}: expected a number of seconds in 0.1..=3600",
            args.peer_frame_limit
        );
    }
    let min_seconds = args
        .min_seconds
        .unwrap_or(if args.quick { 0.0 } else { 1.0 });
    if !(0.0..=600.0).contains(&min_seconds) {
        anyhow::bail!("--min-seconds {min_seconds}: expected a number of seconds in 0..=600");
    }
    if let Some(p) = args.embree_packet
        && p != 8
        && p != 16
    {
        anyhow::bail!("--embree-packet {p}: expected 8 or 16 rays");
    }
    let opts = BenchOptions {
        quick: args.quick,
        runs: args.runs.unwrap_or(if args.quick { 1 } else { 5 }).max(1),
        min_seconds,
        threads,
        assets,
        mesh_scenes,
        ray_sets: args.ray_sets.clone(),
        width,
        height,
        incoherent: args
            .incoherent
            .unwrap_or(if args.quick { 2048 } else { 1 << 20 }),
        bvh: args.bvh.into(),
        sections,
        peer_size,
        peer_frame_limit: args.peer_frame_limit,
        embree_packet: args.embree_packet,
    };
    let sdf_scenes = if sections.sdf || sections.peer || sections.evaluators {
        load_scenes(&args.scenes, args.quick)?
    } else {
        Vec::new()
    };
    let report = hytrace::bench::run(&opts, &sdf_scenes)?;
    print!("{}", report.markdown());
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report)?;
        std::fs::write(path, text)
            .with_context(|| format!("{}: cannot write the JSON report", path.display()))?;
    }
    Ok(())
}

/// The showcase first, then the other scene files of the folder in name order (only the
/// showcase with `quick`).
fn load_scenes(dir: &std::path::Path, quick: bool) -> Result<Vec<(String, hytrace::scene::Scene)>> {
    let mut files = hytrace::scene::scene_files(dir)
        .with_context(|| format!("{}: cannot read the scene folder (--scenes)", dir.display()))?;
    if quick {
        files.truncate(1);
    }
    if files.is_empty() {
        anyhow::bail!("{}: no .ron scene files", dir.display());
    }
    files
        .iter()
        .map(|p| {
            let name = p
                .file_stem()
                .map_or_else(|| p.display().to_string(), |s| s.to_string_lossy().into());
            Ok((
                name,
                hytrace::scene::Scene::load_with(p, &super::load_options())?,
            ))
        })
        .collect()
}
