//! Writing a render to a file, as `hytrace render` and the viewer's screenshots do: the
//! picture of a view as PNG, or the linear radiance and AOV channels as EXR.

use super::Framebuffer;
use super::exr::{Aov, write_exr};
use super::output::{ToneMapping, save_png};
use super::view::{View, picture};
use std::path::Path;

/// Writes a render as `hytrace render` does, by the file's extension: `.exr` stores the linear
/// radiance and the `aov` channels; anything else is a PNG of the picture `view` makes.
pub fn write_image(
    fb: &Framebuffer,
    path: &Path,
    view: View,
    tone: ToneMapping,
    max_steps: u32,
    aov: &[Aov],
) -> anyhow::Result<()> {
    let exr = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("exr"));
    if exr {
        write_exr(fb, aov, path)
    } else {
        save_png(&picture(fb, view, tone, max_steps), path)
    }
}
