//! Labels, legends and colour bars drawn into pictures: `validate` and `compare` sheets and
//! the viewer's heads-up line (text from the public-domain 8×8 bitmap font of `font8x8`).

use font8x8::{BASIC_FONTS, UnicodeFonts};
use glam::Vec3;
use image::{Rgb, RgbImage};

/// Height of one line of text, in pixels.
pub const LINE: u32 = 10;

/// Draws `text` (ASCII; other characters are left blank) with its top-left corner at (x, y).
pub fn text(img: &mut RgbImage, x: u32, y: u32, text: &str, colour: [u8; 3]) {
    for (k, c) in text.chars().enumerate() {
        let Some(rows) = BASIC_FONTS.get(c) else {
            continue;
        };
        for (row, bits) in rows.iter().enumerate() {
            for col in 0..8u32 {
                if bits >> col & 1 == 1 {
                    let (px, py) = (x + 8 * k as u32 + col, y + row as u32);
                    if px < img.width() && py < img.height() {
                        img.put_pixel(px, py, Rgb(colour));
                    }
                }
            }
        }
    }
}

/// Width of `text` in pixels.
pub fn text_width(text: &str) -> u32 {
    8 * text.chars().count() as u32
}

/// Fills a rectangle (clipped to the image).
pub fn fill(img: &mut RgbImage, x: u32, y: u32, w: u32, h: u32, colour: [u8; 3]) {
    for py in y..(y + h).min(img.height()) {
        for px in x..(x + w).min(img.width()) {
            img.put_pixel(px, py, Rgb(colour));
        }
    }
}

/// 8-bit colour of a display value in [0, 1]³ (no transfer curve: colour maps are designed
/// for display values).
pub fn to_u8(c: Vec3) -> [u8; 3] {
    let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    [q(c.x), q(c.y), q(c.z)]
}

/// A list of colour swatches with their meanings, one per line, from (x, y); returns the
/// height used.
pub fn swatches(img: &mut RgbImage, x: u32, y: u32, items: &[([u8; 3], String)]) -> u32 {
    for (i, (colour, label)) in items.iter().enumerate() {
        let yy = y + i as u32 * (LINE + 2);
        fill(img, x, yy, 10, LINE - 1, [255, 255, 255]);
        fill(img, x + 1, yy + 1, 8, LINE - 3, *colour);
        text(img, x + 16, yy + 1, label, [230, 230, 230]);
    }
    items.len() as u32 * (LINE + 2)
}

/// A horizontal colour bar for values in [lo, hi] with `ticks` + 1 numbered ticks and a title
/// above it; `map` takes t ∈ [0, 1]. Occupies `LINE + 12 + LINE` pixels from y.
#[allow(clippy::too_many_arguments)]
pub fn colour_bar(
    img: &mut RgbImage,
    x: u32,
    y: u32,
    width: u32,
    title: &str,
    lo: f32,
    hi: f32,
    ticks: u32,
    map: impl Fn(f32) -> Vec3,
) {
    text(img, x, y, title, [230, 230, 230]);
    let bar_y = y + LINE + 1;
    for px in 0..width {
        let t = px as f32 / (width - 1).max(1) as f32;
        fill(img, x + px, bar_y, 1, 10, to_u8(map(t)));
    }
    for i in 0..=ticks {
        let t = i as f32 / ticks.max(1) as f32;
        let px = x + ((width - 1) as f32 * t) as u32;
        fill(img, px, bar_y + 10, 1, 3, [230, 230, 230]);
        let label = format_number(lo + t * (hi - lo));
        let w = text_width(&label);
        let lx = if i == 0 {
            px
        } else if i == ticks {
            px.saturating_sub(w - 1)
        } else {
            px.saturating_sub(w / 2)
        };
        text(img, lx, bar_y + 14, &label, [230, 230, 230]);
    }
}

fn format_number(v: f32) -> String {
    if v == 0.0 {
        "0".into()
    } else if v.abs() >= 10.0 {
        format!("{v:.0}")
    } else if v.abs() >= 0.1 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

/// `img` scaled up by an integer factor (nearest neighbour), so small grids stay legible.
pub fn upscale(img: &RgbImage, factor: u32) -> RgbImage {
    let f = factor.max(1);
    RgbImage::from_fn(img.width() * f, img.height() * f, |x, y| {
        *img.get_pixel(x / f, y / f)
    })
}
