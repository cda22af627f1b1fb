//! Textures: decoded images in linear RGBA, sampled bilinearly with glTF's wrap modes.

use glam::{Vec2, Vec4};
use std::io::Cursor;

/// The most texels a texture may have (2²⁵, e.g. 8192 × 4096); larger images are refused so
/// that a hostile file cannot make the loader allocate without bound.
pub const MAX_TEXELS: u64 = 1 << 25;

/// How texture coordinates outside [0, 1] are mapped back onto the image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Wrap {
    /// The image tiles the plane.
    #[default]
    Repeat,
    /// Coordinates are clamped to the edge texels.
    ClampToEdge,
    /// The image tiles the plane, mirrored in every other tile.
    MirroredRepeat,
}

/// A decoded image.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Linear RGBA texels, row by row, row 0 at the top of the image.
    pub texels: Vec<Vec4>,
    /// Wrap mode along u (image x).
    pub wrap_u: Wrap,
    /// Wrap mode along v (image y).
    pub wrap_v: Wrap,
    /// Where the image came from (file name, glTF image name or index).
    pub name: String,
}

impl Texture {
    /// The bilinearly filtered colour at `uv`, with (0, 0) the top-left corner of the image
    /// and (1, 1) the bottom-right one; texel centres sit at ((i + ½)/width, (j + ½)/height).
    /// Coordinates outside [0, 1] follow the wrap modes. A texture without texels samples as
    /// opaque white.
    pub fn sample(&self, uv: Vec2) -> Vec4 {
        let (w, h) = (self.width as i64, self.height as i64);
        if w == 0 || h == 0 || (self.texels.len() as i64) < w * h {
            return Vec4::ONE;
        }
        let x = uv.x * self.width as f32 - 0.5;
        let y = uv.y * self.height as f32 - 0.5;
        let (fx, fy) = (x.floor(), y.floor());
        let (tx, ty) = (x - fx, y - fy);
        // `as` saturates (and maps NaN to 0), so any input gives indices in range below.
        let (x0, y0) = (fx as i64, fy as i64);
        let xs = [
            wrap(x0, w, self.wrap_u),
            wrap(x0.saturating_add(1), w, self.wrap_u),
        ];
        let ys = [
            wrap(y0, h, self.wrap_v),
            wrap(y0.saturating_add(1), h, self.wrap_v),
        ];
        let at = |x: usize, y: usize| self.texels[y * self.width as usize + x];
        let (tx, ty) = if tx.is_finite() && ty.is_finite() {
            (tx, ty)
        } else {
            (0.0, 0.0)
        };
        let top = at(xs[0], ys[0]).lerp(at(xs[1], ys[0]), tx);
        let bottom = at(xs[0], ys[1]).lerp(at(xs[1], ys[1]), tx);
        top.lerp(bottom, ty)
    }
}

/// Texel index `i` mapped into 0..n by the wrap mode.
fn wrap(i: i64, n: i64, mode: Wrap) -> usize {
    let r = match mode {
        Wrap::Repeat => i.rem_euclid(n),
        Wrap::ClampToEdge => i.clamp(0, n - 1),
        Wrap::MirroredRepeat => {
            let m = i.rem_euclid(2 * n);
            if m >= n { 2 * n - 1 - m } else { m }
        }
    };
    r as usize
}

/// The linear value of an sRGB-encoded channel in [0, 1].
fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// An image reader over `bytes` with the format guessed from the content (else taken from
/// `mime`) and allocation limits set.
fn reader<'a>(
    bytes: &'a [u8],
    mime: Option<&str>,
) -> Result<image::ImageReader<Cursor<&'a [u8]>>, String> {
    let mut reader = image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| e.to_string())?;
    if reader.format().is_none() {
        match mime {
            Some("image/png") => reader.set_format(image::ImageFormat::Png),
            Some("image/jpeg") => reader.set_format(image::ImageFormat::Jpeg),
            _ => return Err("unknown image format (PNG and JPEG are supported)".into()),
        }
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(16384);
    limits.max_image_height = Some(16384);
    limits.max_alloc = Some(512 * 1024 * 1024);
    reader.limits(limits);
    Ok(reader)
}

/// Decodes PNG or JPEG bytes (format guessed from the content, else `mime`) into a texture:
/// colour channels from sRGB to linear, alpha as stored.
pub(super) fn decode(
    bytes: &[u8],
    mime: Option<&str>,
    name: String,
    wrap_u: Wrap,
    wrap_v: Wrap,
) -> Result<Texture, String> {
    let (w, h) = reader(bytes, mime)?
        .into_dimensions()
        .map_err(|e| e.to_string())?;
    if u64::from(w) * u64::from(h) > MAX_TEXELS {
        return Err(format!(
            "the image is {w} × {h} texels, more than the {MAX_TEXELS} a texture may have"
        ));
    }
    let img = reader(bytes, mime)?.decode().map_err(|e| e.to_string())?;
    let (width, height) = (img.width(), img.height());
    let texels: Vec<Vec4> = match img.color() {
        image::ColorType::L8
        | image::ColorType::La8
        | image::ColorType::Rgb8
        | image::ColorType::Rgba8 => {
            let lut: Vec<f32> = (0..256).map(|i| srgb_to_linear(i as f32 / 255.0)).collect();
            img.to_rgba8()
                .pixels()
                .map(|p| {
                    let [r, g, b, a] = p.0;
                    Vec4::new(
                        lut[r as usize],
                        lut[g as usize],
                        lut[b as usize],
                        a as f32 / 255.0,
                    )
                })
                .collect()
        }
        image::ColorType::Rgb32F | image::ColorType::Rgba32F => img
            .to_rgba32f()
            .pixels()
            .map(|p| Vec4::from_array(p.0))
            .collect(),
        _ => img
            .to_rgba32f()
            .pixels()
            .map(|p| {
                let [r, g, b, a] = p.0;
                Vec4::new(srgb_to_linear(r), srgb_to_linear(g), srgb_to_linear(b), a)
            })
            .collect(),
    };
    Ok(Texture {
        width,
        height,
        texels,
        wrap_u,
        wrap_v,
        name,
    })
}
