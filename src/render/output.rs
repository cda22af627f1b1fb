//! Writing images: linear radiance → display-referred sRGB PNG.

use super::Framebuffer;
use anyhow::Context;
use glam::Vec3;
use std::path::Path;

/// The sRGB transfer function (IEC 61966-2-1) of a linear value clamped to [0, 1].
pub fn linear_to_srgb(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// 8-bit sRGB of a linear colour (values above 1 clip).
pub fn to_srgb8(c: Vec3) -> [u8; 3] {
    let q = |v: f32| (linear_to_srgb(v) * 255.0 + 0.5) as u8;
    [q(c.x), q(c.y), q(c.z)]
}

/// The framebuffer as 8-bit sRGB.
pub fn to_rgb8(fb: &Framebuffer) -> image::RgbImage {
    let mut img = image::RgbImage::new(fb.width, fb.height);
    for (i, p) in img.pixels_mut().enumerate() {
        *p = image::Rgb(to_srgb8(fb.pixels[i]));
    }
    img
}

/// Writes the framebuffer as an sRGB PNG.
pub fn save_png(fb: &Framebuffer, path: &Path) -> anyhow::Result<()> {
    to_rgb8(fb)
        .save_with_format(path, image::ImageFormat::Png)
        .with_context(|| format!("{}: cannot write PNG", path.display()))
}
