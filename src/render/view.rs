//! Debug views: what a framebuffer's AOVs look like as pictures (normals, depth, the step-count
//! heatmap, |∇f|), with colour legends, besides the shaded image itself.

use super::Framebuffer;
use super::output::{ToneMapping, to_srgb8};
use glam::Vec3;
use image::{Rgb, RgbImage};

/// Which picture to make of a render.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum View {
    /// The shaded image (tone-mapped radiance).
    #[default]
    Shaded,
    /// Normals as colours: (n + 1)/2.
    Normals,
    /// Distance to the first hit, near = bright, with a legend.
    Depth,
    /// Sphere-tracing steps per pixel as a heatmap with a legend (Hart 1996's "pixels coloured
    /// by number of steps").
    Steps,
    /// |∇f| at the hit: green = 1 (exact), blue < 1 (conservative bound), red > 1 (a field that
    /// over-estimates distance and may step through surfaces), with a legend.
    Gradient,
}

/// The picture of `fb` for `view`. `max_steps` scales the step heatmap.
pub fn picture(fb: &Framebuffer, view: View, tone: ToneMapping, max_steps: u32) -> RgbImage {
    let (w, h) = (fb.width, fb.height);
    let mut img = RgbImage::new(w, h);
    match view {
        View::Shaded => {
            for (i, p) in img.pixels_mut().enumerate() {
                *p = Rgb(to_srgb8(tone.apply(fb.pixels[i])));
            }
        }
        View::Normals => {
            for (i, p) in img.pixels_mut().enumerate() {
                let n = fb.normal[i];
                *p = if n == Vec3::ZERO {
                    Rgb([0, 0, 0])
                } else {
                    Rgb(unit_to_u8(n * 0.5 + 0.5))
                };
            }
        }
        View::Depth => {
            let finite = fb.depth.iter().copied().filter(|d| d.is_finite());
            let lo = finite.clone().fold(f32::INFINITY, f32::min);
            let hi = finite.fold(f32::NEG_INFINITY, f32::max);
            let span = (hi - lo).max(1e-6);
            for (i, p) in img.pixels_mut().enumerate() {
                let d = fb.depth[i];
                *p = if d.is_finite() {
                    let v = 1.0 - 0.9 * (d - lo) / span;
                    Rgb(unit_to_u8(Vec3::splat(v)))
                } else {
                    Rgb([0, 0, 0])
                };
            }
            if lo.is_finite() {
                legend(&mut img, lo, hi, |t| Vec3::splat(1.0 - 0.9 * t));
            }
        }
        View::Steps => {
            let top = max_steps.max(1) as f32;
            for (i, p) in img.pixels_mut().enumerate() {
                *p = Rgb(unit_to_u8(turbo(fb.steps[i] / top)));
            }
            legend(&mut img, 0.0, top, turbo);
        }
        View::Gradient => {
            for (i, p) in img.pixels_mut().enumerate() {
                let g = fb.gradient[i];
                *p = if fb.depth[i].is_finite() {
                    Rgb(unit_to_u8(gradient_colour(g / 2.0)))
                } else {
                    Rgb([0, 0, 0])
                };
            }
            legend(&mut img, 0.0, 2.0, gradient_colour);
        }
    }
    img
}

/// |∇f|/2 ∈ [0, 1] → blue (0) … green (½, i.e. |∇f| = 1) … red (1, |∇f| ≥ 2).
fn gradient_colour(t: f32) -> Vec3 {
    let t = t.clamp(0.0, 1.0);
    if t < 0.5 {
        Vec3::new(0.1, 0.2, 1.0).lerp(Vec3::new(0.1, 0.85, 0.2), t * 2.0)
    } else {
        Vec3::new(0.1, 0.85, 0.2).lerp(Vec3::new(1.0, 0.1, 0.1), (t - 0.5) * 2.0)
    }
}

fn unit_to_u8(c: Vec3) -> [u8; 3] {
    let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    [q(c.x), q(c.y), q(c.z)]
}

/// Google's Turbo colour map (A. Mikhailov, 2019), by its published polynomial fit: a
/// perceptually ordered rainbow from dark blue (0) to dark red (1).
pub fn turbo(t: f32) -> Vec3 {
    let t = t.clamp(0.0, 1.0);
    let r = [
        0.135_721_4,
        4.615_392_6,
        -42.660_324,
        132.131_09,
        -152.942_4,
        59.286_38,
    ];
    let g = [
        0.091_402_61,
        2.194_188_4,
        4.842_966_6,
        -14.185_033,
        4.277_298_6,
        2.829_566,
    ];
    let b = [
        0.106_673_3,
        12.641_946,
        -60.582_05,
        110.362_77,
        -89.903_11,
        27.348_25,
    ];
    let poly = |c: [f32; 6]| c[0] + t * (c[1] + t * (c[2] + t * (c[3] + t * (c[4] + t * c[5]))));
    Vec3::new(poly(r), poly(g), poly(b)).clamp(Vec3::ZERO, Vec3::ONE)
}

/// Draws a colour bar along the bottom of the image with the values at its ends and middle.
fn legend(img: &mut RgbImage, lo: f32, hi: f32, colour: impl Fn(f32) -> Vec3) {
    let (w, h) = img.dimensions();
    // three labels of up to five 8-pixel characters side by side, above a margin
    if w < 128 || h < 40 {
        return; // too small for a legend
    }
    let bar_h = 8;
    let margin = 4;
    let x0 = margin;
    let x1 = w - margin;
    // below the bar: one line of text
    let y0 = h - margin - bar_h - super::draw::LINE;
    // dark backdrop for legibility
    for y in y0 - 2..h - 1 {
        for x in x0 - 2..x1 + 2 {
            let p = img.get_pixel_mut(x, y);
            *p = Rgb(p.0.map(|c| c / 4));
        }
    }
    for x in x0..x1 {
        let t = (x - x0) as f32 / (x1 - x0 - 1) as f32;
        let c = Rgb(unit_to_u8(colour(t)));
        for y in y0..y0 + bar_h {
            img.put_pixel(x, y, c);
        }
    }
    let ty = y0 + bar_h + 1;
    let labels = [(lo, x0), (0.5 * (lo + hi), (x0 + x1) / 2), (hi, x1)];
    for (i, (value, x)) in labels.iter().enumerate() {
        let text = format_value(*value);
        let width = super::draw::text_width(&text);
        let start = match i {
            0 => *x,
            1 => x.saturating_sub(width / 2),
            _ => x.saturating_sub(width),
        };
        super::draw::text(img, start, ty, &text, [255, 255, 255]);
    }
}

fn format_value(v: f32) -> String {
    if v.abs() >= 100.0 || v.fract() == 0.0 {
        format!("{}", v.round() as i64)
    } else if v.abs() >= 10.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}
