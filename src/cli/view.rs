//! `hytrace view`: the interactive window.

use super::render::ImageArgs;
use anyhow::{Result, bail};
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
    #[command(flatten)]
    image: ImageArgs,
    /// Frames per second to hold while the camera moves: previews render at the size that
    /// fits.
    #[arg(long, default_value_t = 30.0)]
    fps: f32,
    /// Run the steps of this script (timed camera moves, keys, screenshots, quit); see the
    /// README.
    #[arg(long)]
    script: Option<PathBuf>,
    /// Close the window after this many frames (or once the image has all its samples, when
    /// that comes first: no frame follows it until something changes).
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
    args.image.check()?;
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
        if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty())
            && !dir.is_dir()
        {
            bail!(
                "--screenshot {}: {} is not a directory",
                p.display(),
                dir.display()
            );
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
    // (the window opens the GPU's device again, on the adapter that presents to it)
    let render_on_gpu = match super::render::choose_backend(args.image.backend, true, false)? {
        Chosen::Cpu => false,
        Chosen::Gpu(_) => true,
    };
    let (path, camera) = (args.scene.clone(), args.camera.clone());
    let load = Arc::new(move || super::load_any(path.as_deref(), camera.as_deref()));
    let is_scene_file = args.scene.as_ref().filter(|p| {
        p.extension()
            .and_then(|e| e.to_str())
            .is_none_or(|e| e.eq_ignore_ascii_case("ron"))
    });
    let title = match &args.scene {
        Some(p) => p.display().to_string(),
        None => "built-in showcase".into(),
    };
    let size = match (args.image.width, args.image.height) {
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
        load_options: super::load_options(),
        size,
        samples: args.image.spp,
        exposure: args.image.exposure,
        tonemap: args.image.tonemap.map(Into::into),
        aov: super::flags::convert_all(&args.image.aov),
        threads: args.image.threads,
        frame_budget: Duration::from_secs_f32(1.0 / args.fps),
        script: steps,
        frames: args.frames,
        screenshot_dir: args.screenshot_dir,
        render_on_gpu,
    })
}
