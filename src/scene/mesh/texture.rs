//! Textures: decoded images in linear RGBA, sampled bilinearly with glTF's wrap modes, and
//! `KHR_texture_transform`'s texture-coordinate transforms.
//!
//! Filtering is bilinear on the base level only: there are no mipmaps, so glTF samplers'
//! `minFilter` and `magFilter` are not followed (a minified texture aliases rather than
//! blurs). An image's colour space follows its use, as glTF 2.0 §3.9 defines: base colour and
//! emissive textures hold sRGB colours, decoded to linear before filtering (as a GPU's sRGB
//! texture formats do); metallic-roughness, normal and occlusion textures hold linear values,
//! taken as stored. An image used both ways is decoded once per colour space.

use glam::{Mat3, Vec2, Vec3, Vec4};
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
    /// Whether the colour channels were decoded from sRGB (colour textures) rather than taken
    /// as stored (data textures); alpha is always as stored.
    pub srgb: bool,
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

impl Texture {
    /// The texels as the 8-bit values they were decoded from, RGBA in the bytes of a `u32`
    /// from the lowest (so that decoding them — from sRGB for an sRGB texture — gives back
    /// `texels` exactly); `None` when some texel is not such a value (16-bit and float
    /// images, or textures built otherwise). The GPU stores textures this way, at a quarter
    /// of the size.
    pub fn packed8(&self) -> Option<Vec<u32>> {
        let code = |x: f32, srgb: bool| -> Option<u32> {
            let decode = |i: u32| {
                let c = i as f32 / 255.0;
                if srgb { srgb_to_linear(c) } else { c }
            };
            let guess = if srgb { linear_to_srgb(x) } else { x };
            let g = (guess * 255.0).round();
            if !(0.0..=255.0).contains(&g) {
                return None;
            }
            let g = g as u32;
            [g, g.saturating_sub(1), (g + 1).min(255)]
                .into_iter()
                .find(|&i| decode(i) == x)
        };
        self.texels
            .iter()
            .map(|t| {
                Some(
                    code(t.x, self.srgb)?
                        | code(t.y, self.srgb)? << 8
                        | code(t.z, self.srgb)? << 16
                        | code(t.w, false)? << 24,
                )
            })
            .collect()
    }
}

/// The sRGB encoding of a linear channel in [0, 1] (the inverse of [`srgb_to_linear`]).
fn linear_to_srgb(c: f32) -> f32 {
    if c <= 0.0031308 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
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

/// The linear value of an sRGB-encoded channel in [0, 1] (IEC 61966-2-1).
pub fn srgb_to_linear(c: f32) -> f32 {
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
/// colour channels from sRGB to linear when `srgb` (colour textures), else as stored (data
/// textures: metallic-roughness, normal, occlusion); alpha as stored.
pub(super) fn decode(
    bytes: &[u8],
    mime: Option<&str>,
    name: String,
    wrap_u: Wrap,
    wrap_v: Wrap,
    srgb: bool,
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
            let lut: Vec<f32> = (0..256)
                .map(|i| {
                    let c = i as f32 / 255.0;
                    if srgb { srgb_to_linear(c) } else { c }
                })
                .collect();
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
                if srgb {
                    Vec4::new(srgb_to_linear(r), srgb_to_linear(g), srgb_to_linear(b), a)
                } else {
                    Vec4::new(r, g, b, a)
                }
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
        srgb,
    })
}

/// `KHR_texture_transform`: texture coordinates are mapped by T · R · S (the extension's
/// order: scale first, then rotation, then offset), with R rotating by `rotation` radians
/// counter-clockwise in uv space — `[cos r, sin r; −sin r, cos r]` as the extension's
/// reference GLSL writes it. The identity when the extension is absent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UvTransform {
    /// Translation, added last.
    pub offset: Vec2,
    /// Rotation in radians.
    pub rotation: f32,
    /// Per-axis scale, applied first.
    pub scale: Vec2,
}

impl Default for UvTransform {
    fn default() -> Self {
        UvTransform::IDENTITY
    }
}

impl UvTransform {
    /// No transform.
    pub const IDENTITY: UvTransform = UvTransform {
        offset: Vec2::ZERO,
        rotation: 0.0,
        scale: Vec2::ONE,
    };

    /// The transform as a 3×3 matrix on (u, v, 1), as the extension defines it: translation ·
    /// rotation · scale.
    pub fn matrix(&self) -> Mat3 {
        let (s, c) = self.rotation.sin_cos();
        let translation = Mat3::from_cols(Vec3::X, Vec3::Y, self.offset.extend(1.0));
        // the extension's column-major GLSL: mat3(cos, sin, 0, -sin, cos, 0, 0, 0, 1)
        let rotation = Mat3::from_cols(Vec3::new(c, -s, 0.0), Vec3::new(s, c, 0.0), Vec3::Z);
        let scale = Mat3::from_diagonal(self.scale.extend(1.0));
        translation * rotation * scale
    }

    /// The first two rows of [`Self::matrix`], column by column (what the GPU records hold).
    pub fn columns(&self) -> [[f32; 2]; 3] {
        let m = self.matrix();
        [
            m.x_axis.truncate(),
            m.y_axis.truncate(),
            m.z_axis.truncate(),
        ]
        .map(|c| c.to_array())
    }

    /// `uv` transformed.
    pub fn apply(&self, uv: Vec2) -> Vec2 {
        if *self == UvTransform::IDENTITY {
            return uv;
        }
        self.matrix().transform_point2(uv)
    }

    /// Whether every component is finite.
    pub fn is_finite(&self) -> bool {
        self.offset.is_finite() && self.rotation.is_finite() && self.scale.is_finite()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texture_transform_follows_the_extensions_order() {
        // scale, then rotate, then offset (KHR_texture_transform's README: T * R * S)
        let t = UvTransform {
            offset: Vec2::new(0.5, 0.0),
            rotation: std::f32::consts::FRAC_PI_2,
            scale: Vec2::new(2.0, 1.0),
        };
        // (1, 0) → scale (2, 0) → rotate by π/2 with [c s; −s c]: (c·x + s·y, −s·x + c·y)
        // = (0, −2) → offset (0.5, −2)
        let p = t.apply(Vec2::new(1.0, 0.0));
        assert!((p - Vec2::new(0.5, -2.0)).length() < 1e-6, "{p}");
        let [c0, c1, c2] = t.columns();
        let q = Vec2::from(c0) + Vec2::from(c2);
        assert!((q - p).length() < 1e-6);
        assert_eq!(c1.len(), 2);
        assert_eq!(
            UvTransform::IDENTITY.apply(Vec2::new(0.3, 7.0)),
            Vec2::new(0.3, 7.0)
        );
    }

    #[test]
    fn colour_space_follows_the_use() {
        let mut png = Vec::new();
        let img = image::RgbaImage::from_pixel(1, 1, image::Rgba([128, 128, 128, 128]));
        img.write_to(&mut Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        let colour = decode(&png, None, "c".into(), Wrap::Repeat, Wrap::Repeat, true).unwrap();
        let data = decode(&png, None, "d".into(), Wrap::Repeat, Wrap::Repeat, false).unwrap();
        let (c, d) = (colour.texels[0], data.texels[0]);
        assert!((d.x - 128.0 / 255.0).abs() < 1e-6);
        assert!((c.x - srgb_to_linear(128.0 / 255.0)).abs() < 1e-6);
        assert!((c.x - 0.2158).abs() < 1e-3);
        // alpha is linear in both
        assert_eq!(c.w, d.w);
        // both pack back into the bytes they came from
        assert_eq!(colour.packed8(), Some(vec![0x8080_8080]));
        assert_eq!(data.packed8(), Some(vec![0x8080_8080]));
        let mut odd = data.clone();
        odd.texels[0].x = 0.3;
        assert_eq!(odd.packed8(), None);
    }
}
