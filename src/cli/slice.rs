//! `hytrace slice`: the signed distance on an axis-aligned plane, drawn with iso-contours.

use super::load_scene;
use anyhow::{Context, Result, bail};
use glam::Vec2;
use hytrace::render::output;
use hytrace::render::slice::{Plane, SliceOptions, sample};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `hytrace slice`.
#[derive(clap::Parser)]
#[command(after_help = "\
Axes: the plane AXIS=c is seen from the positive side of AXIS, with the other two axes in
cyclic order x → y → z → x (right × up points at the viewer, so no picture is mirrored):
  z=c: x rightwards, y upwards
  x=c: y rightwards, z upwards
  y=c: z rightwards, x upwards
--center a,b gives the (rightward, upward) coordinates of the image centre.

Colours: orange outside (d > 0), blue inside, darker away from the surface, with bands and
thin dark contours every --spacing and a white line where d = 0. Only SDF objects are drawn:
mesh objects have no distance field.

Example: hytrace slice assets/scenes/slices/union.ron --plane z=0 --size 2.5 -o union.png")]
pub struct SliceArgs {
    /// Scene file (.ron); omit for the built-in showcase.
    pub scene: Option<PathBuf>,
    /// Output image (.png).
    #[arg(short, long, default_value = "slice.png")]
    pub output: PathBuf,
    /// The plane to draw: x=VALUE, y=VALUE or z=VALUE.
    #[arg(long, default_value = "z=0", allow_hyphen_values = true)]
    pub plane: String,
    /// Half-width of the region shown: [-SIZE, SIZE] horizontally, SIZE·height/width vertically.
    #[arg(long, default_value_t = 2.5, allow_negative_numbers = true)]
    pub size: f32,
    /// Plane coordinates a,b (rightward, upward) of the image centre.
    #[arg(long, default_value = "0,0", allow_hyphen_values = true)]
    pub center: String,
    /// Image width in pixels.
    #[arg(long, default_value_t = 512)]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 512)]
    pub height: u32,
    /// Distance between contour lines (default: SIZE/10).
    #[arg(long, allow_negative_numbers = true)]
    pub spacing: Option<f32>,
    /// No summary line.
    #[arg(short, long)]
    pub quiet: bool,
}

/// Reads `a,b` as two finite numbers.
fn parse_center(s: &str) -> Result<Vec2> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let [a, b] = parts[..] else {
        bail!("--center {s:?}: expected two numbers a,b (e.g. --center 0.5,-1)");
    };
    let num = |t: &str| -> Result<f32> {
        match t.parse::<f32>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => bail!("--center {s:?}: `{t}` is not a finite number"),
            Err(_) => bail!("--center {s:?}: `{t}` is not a number"),
        }
    };
    Ok(Vec2::new(num(a)?, num(b)?))
}

/// Draws the slice and writes the PNG.
pub fn run(args: SliceArgs) -> Result<()> {
    let plane: Plane = match args.plane.parse() {
        Ok(p) => p,
        Err(e) => bail!("--plane {:?}: {e}", args.plane),
    };
    if !(args.size.is_finite() && args.size > 0.0) {
        bail!("--size must be a finite number > 0 (got {})", args.size);
    }
    let center = parse_center(&args.center)?;
    let opts = SliceOptions {
        width: args.width,
        height: args.height,
        size: args.size,
        center,
        // (a tenth of a size near the smallest float rounds to 0: kept positive, so that the
        // size's own check speaks, not one of a --spacing the user never gave)
        spacing: args
            .spacing
            .unwrap_or((args.size / 10.0).max(f32::MIN_POSITIVE)),
    };
    if let Err(e) = opts.validate() {
        bail!("{e}");
    }
    let ext = args
        .output
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if ext.as_deref() != Some("png") {
        bail!(
            "{}: unsupported output format (--output must be a .png file)",
            args.output.display()
        );
    }
    let scene = load_scene(args.scene.as_deref())?;
    let start = Instant::now();
    let field = sample(&scene, plane, &opts);
    let img = field.image();
    let elapsed = start.elapsed();
    output::save_png(&img, &args.output)
        .with_context(|| format!("writing {}", args.output.display()))?;
    if !args.quiet {
        let range = match field.range() {
            Some((lo, hi)) => format!(
                "d in [{}, {}]",
                super::readable(lo, 3),
                super::readable(hi, 3)
            ),
            None => "no finite distance".to_string(),
        };
        let (r, u) = plane.image_axes();
        eprintln!(
            "{}: slice {plane} ({} right, {} up), {}×{} px, size {}, spacing {}, {} object(s), {range}, drawn in {:.3} s → {}",
            scene.source_name,
            r.letter(),
            u.letter(),
            opts.width,
            opts.height,
            opts.size,
            opts.spacing,
            scene.sdf_object_count(),
            elapsed.as_secs_f64(),
            args.output.display()
        );
    }
    Ok(())
}
