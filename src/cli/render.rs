//! `hytrace render`: a scene to an image.

use super::flags::{AovArg, BvhArg, NormalsArg, ToneMapArg, ViewArg, convert_all};
use anyhow::{Result, bail};
use hytrace::render::output::ToneMapping;
use hytrace::render::view::View;
use hytrace::render::write::write_image;
use hytrace::render::{RenderOptions, cpu};
use hytrace::scene::{MAX_EXPOSURE, MAX_IMAGE_SIDE, MAX_PIXELS, MAX_SAMPLES};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `hytrace render`.
#[derive(clap::Parser)]
pub struct RenderArgs {
    /// Scene file (.ron) or mesh file (.gltf, .glb, .obj, .ply); omit for the built-in
    /// showcase.
    scene: Option<PathBuf>,
    /// For a mesh file: render from the file's camera with this name or number (from 0).
    #[arg(long)]
    camera: Option<String>,
    /// Output image: .png (sRGB, tone-mapped) or .exr (linear radiance, plus --aov channels).
    #[arg(short, long, default_value = "out.png")]
    output: PathBuf,
    /// What to draw: the shaded image or a debug view of the first hits.
    #[arg(long, value_enum, default_value = "shaded")]
    view: ViewArg,
    #[command(flatten)]
    image: ImageArgs,
    /// Mesh BVH build quality (overrides the scene's `tracer.bvh`).
    #[arg(long, value_enum)]
    bvh: Option<BvhArg>,
    /// Normal estimator (overrides the scene).
    #[arg(long, value_enum)]
    normals: Option<NormalsArg>,
    /// Say more: the backend and GPU adapter used.
    #[arg(short, long)]
    verbose: bool,
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
}

/// The image flags `render` and `view` share: size, samples, threads, exposure, tone
/// mapping, AOV channels and backend.
#[derive(clap::Args)]
pub(crate) struct ImageArgs {
    /// Image width (overrides the scene; for `view`, the window's).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height (overrides the scene; for `view`, the window's).
    #[arg(long)]
    pub height: Option<u32>,
    /// Samples per pixel (overrides the scene; for `view`, those the image refines to when
    /// the camera rests).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Render threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Exposure in stops (overrides the scene).
    #[arg(long, allow_negative_numbers = true)]
    pub exposure: Option<f32>,
    /// Tone-mapping operator (overrides the scene).
    #[arg(long, value_enum)]
    pub tonemap: Option<ToneMapArg>,
    /// Extra EXR channels: depth, normal, albedo, steps (comma-separated); for `render` in
    /// an .exr output, for `view` in an EXR beside each screenshot.
    #[arg(long, value_enum, value_delimiter = ',')]
    pub aov: Vec<AovArg>,
    /// Where to render. `auto` (the default) uses a hardware GPU when wgpu finds one and
    /// otherwise the CPU; it treats a software Vulkan driver such as Mesa's lavapipe
    /// (llvmpipe) as no GPU, since it runs on the CPU and is slower than the CPU tracer.
    /// `gpu` uses any adapter, lavapipe included, and fails when there is none.
    #[arg(long, value_enum, default_value = "auto")]
    pub backend: Backend,
}

/// Most render threads `--threads` accepts: far past any machine's cores (a thread each is
/// started up front, and tens of thousands exhaust the system's limits first).
pub const MAX_THREADS: usize = 1024;

impl ImageArgs {
    /// Checks `--threads`: 1 to [`MAX_THREADS`].
    pub fn check_threads(&self) -> Result<()> {
        match self.threads {
            Some(n) if n == 0 || n > MAX_THREADS => {
                bail!("--threads {n} is out of range 1..={MAX_THREADS}")
            }
            _ => Ok(()),
        }
    }

    /// Checks the values given on the command line (the scene's own are checked on load).
    pub fn check(&self) -> Result<()> {
        for side in [self.width, self.height].into_iter().flatten() {
            if side == 0 || side > MAX_IMAGE_SIDE {
                bail!("--width and --height must be in 1..={MAX_IMAGE_SIDE} (got {side})");
            }
        }
        if let (Some(w), Some(h)) = (self.width, self.height)
            && w as u64 * h as u64 > MAX_PIXELS
        {
            bail!("image size {w}×{h} is too large (at most {MAX_PIXELS} pixels)");
        }
        if let Some(s) = self.spp
            && (s == 0 || s > MAX_SAMPLES)
        {
            bail!("--spp {s} is out of range 1..={MAX_SAMPLES}");
        }
        self.check_threads()?;
        if let Some(e) = self.exposure
            && (!e.is_finite() || e.abs() > MAX_EXPOSURE)
        {
            bail!("--exposure {e} is out of range -{MAX_EXPOSURE}..={MAX_EXPOSURE} stops");
        }
        Ok(())
    }
}

/// Which tracer renders the image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Backend {
    /// A hardware GPU if there is one, else the CPU.
    Auto,
    /// The CPU tracer.
    Cpu,
    /// The GPU tracer on any adapter (software ones included).
    Gpu,
}

/// The tracer chosen for a render.
pub(crate) enum Chosen {
    Cpu,
    #[cfg(feature = "gpu")]
    Gpu(Box<hytrace::gpu::context::GpuContext>),
}

/// Picks the backend. `auto` says on one line which it took (unless `quiet`).
pub(crate) fn choose_backend(backend: Backend, quiet: bool, verbose: bool) -> Result<Chosen> {
    let say = |line: String| {
        if !quiet || verbose {
            eprintln!("{line}");
        }
    };
    match backend {
        Backend::Cpu => Ok(Chosen::Cpu),
        #[cfg(not(feature = "gpu"))]
        Backend::Gpu => bail!("--backend gpu: this hytrace was built without the `gpu` feature"),
        #[cfg(not(feature = "gpu"))]
        Backend::Auto => {
            say("backend auto: built without the `gpu` feature; rendering on the CPU".into());
            Ok(Chosen::Cpu)
        }
        #[cfg(feature = "gpu")]
        Backend::Gpu => {
            let ctx = hytrace::gpu::context::GpuContext::new()
                .map_err(|e| anyhow::anyhow!("--backend gpu: no usable GPU adapter: {e}"))?;
            if verbose {
                eprintln!("GPU adapter: {}", describe(&ctx));
            }
            Ok(Chosen::Gpu(Box::new(ctx)))
        }
        #[cfg(feature = "gpu")]
        Backend::Auto => match hytrace::gpu::context::GpuContext::new() {
            Ok(ctx) if ctx.adapter_info().device_type != wgpu::DeviceType::Cpu => {
                say(format!(
                    "backend auto: rendering on the GPU ({})",
                    describe(&ctx)
                ));
                Ok(Chosen::Gpu(Box::new(ctx)))
            }
            Ok(ctx) => {
                say(format!(
                    "backend auto: only a software GPU adapter ({}), rendering on the CPU \
                     (--backend gpu uses it anyway)",
                    describe(&ctx)
                ));
                Ok(Chosen::Cpu)
            }
            Err(e) => {
                say(format!(
                    "backend auto: no GPU adapter ({e}), rendering on the CPU"
                ));
                Ok(Chosen::Cpu)
            }
        },
    }
}

/// The adapter's name, device type and driver API.
#[cfg(feature = "gpu")]
fn describe(ctx: &hytrace::gpu::context::GpuContext) -> String {
    let info = ctx.adapter_info();
    format!(
        "{}, {:?} on {:?}",
        info.name, info.device_type, info.backend
    )
}

/// What the scene holds, for the summary line: SDF objects and mesh instances.
fn contents(scene: &hytrace::scene::Scene) -> String {
    let plural = |n: usize, one: &str| format!("{n} {one}{}", if n == 1 { "" } else { "s" });
    let sdf = plural(scene.sdf_object_count(), "SDF object");
    match scene.meshes.instances.len() {
        0 => sdf,
        n if scene.objects.is_empty() => plural(n, "mesh instance"),
        n => format!("{sdf} and {}", plural(n, "mesh instance")),
    }
}

/// Most loader warnings `render` prints; `hytrace info` lists them all.
const SHOWN_WARNINGS: usize = 5;

/// The loader's warnings (what a model file held that is not drawn, or drawn otherwise than
/// it asks), one line each, on stderr: the image is still made, but not quite as the file
/// says.
pub(crate) fn print_warnings(warnings: &[String]) {
    for w in warnings.iter().take(SHOWN_WARNINGS) {
        eprintln!("warning: {w}");
    }
    if warnings.len() > SHOWN_WARNINGS {
        eprintln!(
            "warning: and {} more (`hytrace info` lists them all)",
            warnings.len() - SHOWN_WARNINGS
        );
    }
}

/// Renders and writes the image.
pub fn run(args: RenderArgs) -> Result<()> {
    let mut scene = super::load_any(args.scene.as_deref(), args.camera.as_deref())?;
    if let Some(q) = args.bvh {
        scene.tracer.bvh = q.into();
    }
    if let Some(n) = args.normals {
        scene.tracer.normals = n.into();
    }
    let width = args.image.width.unwrap_or(scene.image.width);
    let height = args.image.height.unwrap_or(scene.image.height);
    let samples = args.image.spp.unwrap_or(scene.image.samples);
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
    args.image.check_threads()?;
    // A flag's value was checked with the flags and a scene file's where it was read; what
    // is left is a model's metered exposure, checked all the same.
    let exposure = args.image.exposure.unwrap_or(scene.image.exposure);
    if !exposure.is_finite() || exposure.abs() > MAX_EXPOSURE {
        bail!("the exposure {exposure} is out of range -{MAX_EXPOSURE}..={MAX_EXPOSURE} stops");
    }
    let tone = ToneMapping {
        exposure,
        operator: args.image.tonemap.map_or(scene.image.tonemap, Into::into),
    };
    let ext = args
        .output
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let exr = match ext.as_deref() {
        Some("png") => false,
        Some("exr") => true,
        _ => bail!(
            "{}: unsupported output format (use a .png or .exr file name)",
            args.output.display()
        ),
    };
    // Fail before a long render rather than after it.
    let parent = args.output.parent().filter(|p| !p.as_os_str().is_empty());
    if let Some(dir) = parent
        && !dir.is_dir()
    {
        bail!(
            "{}: cannot write there: {} is not a directory",
            args.output.display(),
            dir.display()
        );
    }
    if !args.image.aov.is_empty() && !exr {
        bail!("--aov needs an .exr output (PNG holds only the picture; see --view)");
    }
    let view = View::from(args.view);
    if exr && view != View::Shaded {
        bail!("--view applies to PNG output; EXR stores radiance and the --aov channels");
    }
    let opts = RenderOptions {
        width,
        height,
        samples,
        threads: args.image.threads,
        progress: !args.quiet && std::io::stderr().is_terminal(),
    };
    if !args.quiet {
        print_warnings(&scene.meshes.warnings);
    }
    let backend = choose_backend(args.image.backend, args.quiet, args.verbose)?;
    let start = Instant::now();
    let (fb, used) = match &backend {
        Chosen::Cpu => (cpu::render(&scene, &opts)?, "CPU"),
        #[cfg(feature = "gpu")]
        Chosen::Gpu(ctx) => {
            let image = hytrace::gpu::render::render(&scene, &opts, ctx)?;
            if let Some(note) = hytrace::gpu::render::on_cpu_note(&image, ctx.adapter_name()) {
                eprintln!("note: {note}");
            }
            (image.image, "GPU")
        }
    };
    let elapsed = start.elapsed();
    write_image(
        &fb,
        &args.output,
        view,
        tone,
        scene.tracer.max_steps,
        &convert_all(&args.image.aov),
    )?;
    if !args.quiet {
        eprintln!(
            "{}: {}×{} px, {} spp, {}, rendered on the {} in {:.3} s → {}",
            scene.source_name,
            width,
            height,
            samples,
            contents(&scene),
            used,
            elapsed.as_secs_f64(),
            args.output.display()
        );
    }
    Ok(())
}
