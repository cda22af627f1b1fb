//! `hytrace validate`: our CPU tracer against Embree 4, ray by ray, with the stated
//! thresholds; a Markdown table per object kind, a mismatch image, JSON and a report page.

use anyhow::Result;
use std::path::PathBuf;

/// Arguments of `hytrace validate`.
#[derive(clap::Parser)]
#[command(after_help = "\
Casts one camera ray per pixel of a WIDTH×HEIGHT image, N random rays through the scene's
bounds (origins outside every object) and, from every camera-ray hit of Embree, a shadow ray
toward every light (offset from the surface as the renderer offsets it); asks our tracer and
Embree the same rays and compares hit/miss, hit distance and occlusion per object kind
(mesh, analytic SDF, certified SDF, meshed SDF). SDF objects without a closed-form
intersection are intersected by a certified search (the first root of the field along the
ray, by f64 interval bisection of its tape, enclosed within delta = eps/64); --meshed meshes
them instead (the older, looser cross-check).

Thresholds: meshes >= 99.99% agreement and |dt| <= 1e-4 x scene diameter; analytic SDFs
>= 99.9% agreement, disagreements only at silhouettes (|n.d| < 0.05 or within 3 eps(t) of
the surface), |dt| <= max(10 eps(t), 2 eps(t)/|n.d|); meshed SDFs |dt| <= max(10 eps(t),
(tolerance + 2 eps(t))/|n.d|), disagreements only within the tolerance band; certified SDFs
>= 99.9% agreement, |dt| <= max(10 eps(t), (2 eps(t) + delta)/|n.d|), disagreements only
where the certified field shows a near miss (f <= eps(t) at our hit) or a sliver at most
eps(t)/2 deep; shadow rays >= 99.9%; every SDF object checked. Exit status 1 when any fails.

Mismatch image colours: grey = agree (brighter = head-on), dark blue = both miss, yellow =
hit/miss mismatch at a silhouette, red = hit/miss mismatch elsewhere, magenta = |dt| over
tolerance, cyan = a shadow ray disagrees, green = an object Embree skipped, dark purple = our
hit beyond a clipped unbounded object's mesh (left out). The legend is drawn below the picture.")]
pub struct ValidateArgs {
    /// Scene file (.ron) or mesh file (.gltf, .glb, .obj, .ply); omit for the built-in
    /// showcase.
    pub scene: Option<PathBuf>,
    /// For a mesh file: the file's camera with this name or number (from 0).
    #[arg(long)]
    pub camera: Option<String>,
    /// Width of the camera-ray grid (default: the scene's image width).
    #[arg(long)]
    pub width: Option<u32>,
    /// Height of the camera-ray grid (default: the scene's image height).
    #[arg(long)]
    pub height: Option<u32>,
    /// Random rays through the scene's bounds.
    #[arg(long, default_value_t = 10_000)]
    pub random: usize,
    /// Seed of the random rays.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Also write the figures as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write the mismatch image (PNG) to this file.
    #[arg(long)]
    pub mismatch: Option<PathBuf>,
    /// Write a report page to browse (HTML, self-contained) to this file: the tables, the
    /// mismatch image with its legend, zoomable to single rays, and the disagreeing rays,
    /// each a link to its pixel.
    #[arg(long)]
    pub html: Option<PathBuf>,
    /// Grid cells along the longest side of each meshed SDF object's box (the referee's
    /// default when omitted); the mesh tolerance is about one cell.
    #[arg(long)]
    pub mesh_resolution: Option<u32>,
    /// Mesh the SDF objects without a closed form (marching cubes, checked within the mesh's
    /// tolerance) instead of intersecting them by the certified root search.
    #[arg(long)]
    pub meshed: bool,
}

/// Runs the validation, prints the report, writes the files; an error when a threshold fails.
#[cfg(feature = "embree")]
pub fn run(args: ValidateArgs) -> Result<()> {
    use anyhow::{Context, bail};
    use hytrace::reference::embree::ReferenceOptions;
    use hytrace::reference::validate::{Options, validate_with_embree_options};
    use hytrace::render::draw;
    use hytrace::scene::{MAX_IMAGE_SIDE, MAX_PIXELS};
    use std::time::Instant;
    /// Most random rays accepted.
    const MAX_RANDOM: usize = 10_000_000;

    let scene = super::load_any(args.scene.as_deref(), args.camera.as_deref())?;
    let width = args.width.unwrap_or(scene.image.width);
    let height = args.height.unwrap_or(scene.image.height);
    if width == 0 || height == 0 {
        bail!("--width and --height must be at least 1 (got {width}×{height})");
    }
    if width > MAX_IMAGE_SIDE
        || height > MAX_IMAGE_SIDE
        || width as u64 * height as u64 > MAX_PIXELS
    {
        bail!(
            "grid {width}×{height} is too large (at most {MAX_IMAGE_SIDE} per side and {MAX_PIXELS} pixels)"
        );
    }
    if args.random > MAX_RANDOM {
        bail!("--random {} is out of range 0..={MAX_RANDOM}", args.random);
    }
    for (flag, path, ext) in [
        ("--json", &args.json, "json"),
        ("--mismatch", &args.mismatch, "png"),
        ("--html", &args.html, "html"),
    ] {
        if let Some(p) = path {
            super::check_output(flag, p, ext)?;
        }
    }
    let options = Options {
        width,
        height,
        random: args.random,
        seed: args.seed,
    };
    let start = Instant::now();
    let mut reference = ReferenceOptions {
        meshed: args.meshed,
        ..ReferenceOptions::default()
    };
    if let Some(r) = args.mesh_resolution {
        if !(2..=4096).contains(&r) {
            bail!("--mesh-resolution {r} is out of range 2..=4096");
        }
        reference.mesh_resolution = r;
    }
    let report = validate_with_embree_options(&scene, &options, &reference)
        .map_err(|e| anyhow::anyhow!("{}: {e}", scene.source_name))?;
    let elapsed = start.elapsed();
    print!("{}", report.markdown());
    println!(
        "\n({} rays and {} shadow rays in {:.2} s)",
        width as usize * height as usize + args.random,
        report.shadow.rays,
        elapsed.as_secs_f64()
    );
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report)?;
        std::fs::write(path, text + "\n")
            .with_context(|| format!("{}: cannot write", path.display()))?;
    }
    if let Some(path) = &args.mismatch {
        let grid = report.mismatch_image();
        let factor = (480 / width.max(1)).clamp(1, 8);
        let picture = draw::upscale(&grid, factor);
        let entries = report.legend();
        let legend_h = entries.len() as u32 * (draw::LINE + 2) + 8;
        let legend_w = entries
            .iter()
            .map(|(_, s)| draw::text_width(s) + 24)
            .max()
            .unwrap_or(0);
        let w = picture.width().max(legend_w);
        let mut img =
            image::RgbImage::from_pixel(w, picture.height() + legend_h, image::Rgb([0, 0, 0]));
        image::imageops::replace(&mut img, &picture, 0, 0);
        draw::swatches(&mut img, 4, picture.height() + 4, &entries);
        hytrace::render::output::save_png(&img, path)?;
        println!("mismatch image → {}", path.display());
    }
    if let Some(path) = &args.html {
        report.page(elapsed.as_secs_f64())?.write(path)?;
        println!("report → {}", path.display());
    }
    if !report.passed() {
        bail!(
            "{}: validation against Embree FAILED ({} threshold(s); see above)",
            scene.source_name,
            report.failures.len()
        );
    }
    Ok(())
}

/// Without Embree there is no referee: says so and how to get one.
#[cfg(not(feature = "embree"))]
pub fn run(_args: ValidateArgs) -> Result<()> {
    anyhow::bail!("{}", super::NO_EMBREE)
}
