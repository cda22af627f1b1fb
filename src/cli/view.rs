//! `hytrace view`: the interactive window.

use super::render::Backend;
use anyhow::{Result, bail};
use hytrace::render::exr::Aov;
use hytrace::scene::file::ToneMap;
use hytrace::scene::{MAX_IMAGE_SIDE, MAX_PIXELS, MAX_SAMPLES};
use hytrace::viewer::input::KEY_HELP;
use std::path::PathBuf;

/// Arguments of `hytrace view`.
#[derive(clap::Parser)]
#[command(after_help = keys_help())]
pub struct ViewArgs {
    /// Scene file (.ron) or mesh file (.gltf, .glb, .obj, .ply); omit for the built-in
    /// showcase. The scene file and the mesh files it names are reloaded when they change.
    scene: Option<PathBuf>,
    /// For a mesh file: start from the file's camera with this name or number (from 0).
    #[arg(long)]
    camera: Option<String>,
    /// Window width (default: the scene's image width).
    #[arg(long)]
    width: Option<u32>,
    /// Window height (default: the scene's image height).
    #[arg(long)]
    height: Option<u32>,
    /// Samples per pixel the image refines to when the camera rests (default: the scene's).
    #[arg(long)]
    spp: Option<u32>,
    /// Exposure in stops (overrides the scene; + and - change it).
    #[arg(long, allow_negative_numbers = true)]
    exposure: Option<f32>,
    /// Tone-mapping operator (overrides the scene).
    #[arg(long, value_enum)]
    tonemap: Option<ToneMap>,
    /// With each PNG screenshot, an EXR of these channels too: depth, normal, albedo, steps.
    #[arg(long, value_enum, value_delimiter = ',')]
    aov: Vec<Aov>,
    /// Render threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Frames per second to hold while the camera moves: previews render at the size that
    /// fits.
    #[arg(long, default_value_t = 30.0)]
    fps: f32,
    /// Where to render, as for `render`: `auto` renders on a hardware GPU when wgpu finds
    /// one and otherwise on the CPU (a software Vulkan driver such as lavapipe then only
    /// presents the window); `gpu` renders on any adapter; `cpu` always on the CPU.
    #[arg(long, value_enum, default_value = "auto")]
    backend: Backend,
    /// Run the steps of this script (timed camera moves, keys, screenshots, quit); see the
    /// README.
    #[arg(long)]
    script: Option<PathBuf>,
    /// Close the window after this many frames.
    #[arg(long)]
    frames: Option<u64>,
    /// Once the image has all its samples, write it here (.png, or .exr) and close.
    #[arg(long)]
    screenshot: Option<PathBuf>,
    /// Folder for the screenshots `P` writes (hytrace-view-NNN.png).
    #[arg(long, default_value = ".")]
    screenshot_dir: PathBuf,
}

fn keys_help() -> String {
    let mut s = String::from("Keys and mouse:\n");
    for (k, what) in KEY_HELP {
        s += &format!("  {k:<32} {what}\n");
    }
    s
}

/// Opens the window.
pub fn run(args: ViewArgs) -> Result<()> {
    if let Some(w) = args.width.or(args.height) {
        if w == 0 || w > MAX_IMAGE_SIDE {
            bail!("--width and --height must be in 1..={MAX_IMAGE_SIDE} (got {w})");
        }
    }
    if let (Some(w), Some(h)) = (args.width, args.height) {
        if w as u64 * h as u64 > MAX_PIXELS {
            bail!("window {w}×{h} is too large (at most {MAX_PIXELS} pixels)");
        }
    }
    if let Some(s) = args.spp {
        if s == 0 || s > MAX_SAMPLES {
            bail!("--spp {s} is out of range 1..={MAX_SAMPLES}");
        }
    }
    if args.threads == Some(0) {
        bail!("--threads must be at least 1");
    }
    if let Some(e) = args.exposure {
        if !e.is_finite() || e.abs() > 64.0 {
            bail!("--exposure {e} is out of range -64..=64 stops");
        }
    }
    if !(args.fps.is_finite() && (1.0..=240.0).contains(&args.fps)) {
        bail!("--fps {} is out of range 1..=240", args.fps);
    }
    if args.frames == Some(0) {
        bail!("--frames must be at least 1");
    }
    if !args.screenshot_dir.is_dir() {
        bail!(
            "--screenshot-dir {}: not a directory",
            args.screenshot_dir.display()
        );
    }
    if let Some(p) = &args.screenshot {
        let ext = p
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        if !matches!(ext.as_deref(), Some("png" | "exr")) {
            bail!("--screenshot {}: use a .png or .exr file name", p.display());
        }
        if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
            if !dir.is_dir() {
                bail!(
                    "--screenshot {}: {} is not a directory",
                    p.display(),
                    dir.display()
                );
            }
        }
    }
    run_viewer(args)
}

#[cfg(not(feature = "viewer"))]
fn run_viewer(_: ViewArgs) -> Result<()> {
    bail!("this hytrace was built without the `viewer` feature (cargo build --features viewer)")
}

#[cfg(feature = "viewer")]
fn run_viewer(args: ViewArgs) -> Result<()> {
    use super::render::Chosen;
    use hytrace::viewer::script::{self, Step};
    use hytrace::viewer::window::{ViewerConfig, run};
    use std::sync::Arc;
    use std::time::Duration;

    let mut steps = match &args.script {
        Some(p) => script::load(p).map_err(anyhow::Error::msg)?,
        None => Vec::new(),
    };
    if let Some(out) = &args.screenshot {
        steps.extend([Step::Converge, Step::Screenshot(out.clone()), Step::Quit]);
    }
    hytrace::viewer::window::check_display()?;
    // the heads-up line says which backend renders, so `auto` chooses without a word
    let gpu = match super::render::choose_backend(args.backend, true, false)? {
        Chosen::Cpu => None,
        Chosen::Gpu(ctx) => Some(*ctx),
    };
    let (path, camera) = (args.scene.clone(), args.camera.clone());
    let load = Arc::new(move || crate::load_any(path.as_deref(), camera.as_deref()));
    let is_scene_file = args.scene.as_ref().filter(|p| {
        p.extension()
            .and_then(|e| e.to_str())
            .is_none_or(|e| e.eq_ignore_ascii_case("ron"))
    });
    let title = match &args.scene {
        Some(p) => p.display().to_string(),
        None => "built-in showcase".into(),
    };
    let size = match (args.width, args.height) {
        (None, None) => None,
        (w, h) => {
            let scene = load()?;
            Some((
                w.unwrap_or(scene.image.width),
                h.unwrap_or(scene.image.height),
            ))
        }
    };
    run(ViewerConfig {
        title,
        load,
        scene_file: is_scene_file.cloned().or_else(|| {
            // a mesh file is watched too
            args.scene.clone()
        }),
        size,
        samples: args.spp,
        exposure: args.exposure,
        tonemap: args.tonemap,
        aov: args.aov,
        threads: args.threads,
        frame_budget: Duration::from_secs_f32(1.0 / args.fps),
        script: steps,
        frames: args.frames,
        screenshot_dir: args.screenshot_dir,
        gpu,
    })
}
