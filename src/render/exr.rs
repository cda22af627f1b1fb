//! OpenEXR output: linear radiance and optional AOV channels.
//!
//! [`write_exr`] writes one single-part, scan-line OpenEXR file whose channels are all 32-bit
//! floats, compressed with ZIP (16 scan lines per block, lossless, so every value reads back
//! bit-identical). The radiance is stored as channels `R`, `G`, `B`: linear, exactly as in the
//! framebuffer — no exposure, tone mapping or clamping. Each requested [`Aov`] adds the
//! channels listed on its variant, named `layer.channel` (e.g. `normal.X`), the convention
//! by which EXR viewers (Nuke, Blender, djv, `exrheader`) group channels into layers. Pixel
//! (x, y) of the framebuffer, with y = 0 the top row, is pixel (x, y) of the EXR data window
//! `(0, 0)–(width − 1, height − 1)`, which is also the display window.

use super::Framebuffer;
use anyhow::{Context, anyhow, bail};
use exr::prelude::{
    AnyChannel, AnyChannels, Blocks, Compression, Encoding, FlatSamples, Image, Layer,
    LayerAttributes, LineOrder, SmallVec, WritableImage,
};
use glam::Vec3;
use std::path::Path;

/// Auxiliary channels an EXR file can carry besides the radiance.
///
/// All channels are 32-bit floats. Requesting an AOV more than once writes its channels once.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Aov {
    /// Distance to the first hit along the camera ray, in scene units (`depth.Z`); +∞ where
    /// every sample of the pixel missed (sky). EXR floats hold infinity, so a miss reads
    /// back as `f32::INFINITY`; over a pixel's samples the nearest hit is kept.
    Depth,
    /// First-hit surface normal in world space (`normal.X`, `normal.Y`, `normal.Z`), averaged
    /// over the pixel's samples (so not renormalised where samples disagree); 0 on a miss.
    Normal,
    /// First-hit albedo, linear (`albedo.R`, `albedo.G`, `albedo.B`); 0 on a miss.
    Albedo,
    /// Sphere-tracing steps of the camera ray, averaged over the pixel's samples (`steps.Y`).
    Steps,
}

impl Aov {
    /// Every AOV, in the order their channels are gathered.
    const ALL: [Aov; 4] = [Aov::Depth, Aov::Normal, Aov::Albedo, Aov::Steps];
}

/// Writes the framebuffer as EXR (32-bit float, linear): channels `R`, `G`, `B` and those of
/// each distinct requested AOV (see [`Aov`] and the module documentation), ZIP-compressed.
///
/// Errors name the file: an unwritable path, or a framebuffer whose buffers do not hold
/// width × height values.
pub fn write_exr(fb: &Framebuffer, aovs: &[Aov], path: &Path) -> anyhow::Result<()> {
    let (w, h) = (fb.width as usize, fb.height as usize);
    let n = w
        .checked_mul(h)
        .with_context(|| format!("{}: image size overflows", path.display()))?;
    if n == 0 {
        bail!(
            "{}: cannot write an empty {}×{} EXR image",
            path.display(),
            fb.width,
            fb.height
        );
    }
    let lengths = [
        ("pixels", fb.pixels.len()),
        ("depth", fb.depth.len()),
        ("normal", fb.normal.len()),
        ("albedo", fb.albedo.len()),
        ("steps", fb.steps.len()),
    ];
    if let Some((name, len)) = lengths.iter().find(|(_, len)| *len != n) {
        bail!(
            "{}: framebuffer {name} holds {len} values, expected {w}×{h} = {n}",
            path.display()
        );
    }

    let mut channels: Vec<AnyChannel<FlatSamples>> = vector(["R", "G", "B"], &fb.pixels).into();
    for aov in Aov::ALL.into_iter().filter(|a| aovs.contains(a)) {
        match aov {
            Aov::Depth => channels.push(scalar("depth.Z", &fb.depth)),
            Aov::Normal => {
                channels.extend(vector(["normal.X", "normal.Y", "normal.Z"], &fb.normal))
            }
            Aov::Albedo => {
                channels.extend(vector(["albedo.R", "albedo.G", "albedo.B"], &fb.albedo))
            }
            Aov::Steps => channels.push(scalar("steps.Y", &fb.steps)),
        }
    }

    let encoding = Encoding {
        compression: Compression::ZIP16,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    // EXR requires channels sorted by name; `sort` does that.
    let layer = Layer::new(
        (w, h),
        LayerAttributes::default(),
        encoding,
        AnyChannels::sort(SmallVec::from_vec(channels)),
    );
    Image::from_layer(layer)
        .write()
        .to_file(path)
        // exr's error already displays its I/O cause; flatten it so `{:#}` says it once.
        .map_err(|e| anyhow!("{}: cannot write EXR: {e}", path.display()))
}

/// One float channel.
fn scalar(name: &str, values: &[f32]) -> AnyChannel<FlatSamples> {
    AnyChannel::new(name, FlatSamples::F32(values.to_vec()))
}

/// Three float channels, one per component of a vector buffer.
fn vector(names: [&str; 3], values: &[Vec3]) -> [AnyChannel<FlatSamples>; 3] {
    [0, 1, 2].map(|c| {
        AnyChannel::new(
            names[c],
            FlatSamples::F32(values.iter().map(|v| v[c]).collect()),
        )
    })
}
