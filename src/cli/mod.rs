//! The subcommands of the `hytrace` binary, one module each.
pub mod bench;
pub mod compare;
pub mod flags;
pub mod generate;
pub mod info;
pub mod render;
pub mod slice;
pub mod validate;
pub mod view;

use anyhow::{Result, bail};
use hytrace::scene::{LoadOptions, Scene};
use std::path::{Path, PathBuf};

/// The showcase scene, built into the binary so `hytrace render` works with no file.
const SHOWCASE: &str = include_str!("../../assets/scenes/showcase.ron");

/// The variable through which the shipped scenes (`$HYTRACE_ASSETS/...` in a mesh path) and
/// `bench` find the shared third-party models.
const ASSETS_VARIABLE: &str = "HYTRACE_ASSETS";

/// Its value when the environment does not set it: the shared folder beside the checkout,
/// relative to the working directory, so the shipped scenes render from the repository root.
const DEFAULT_ASSETS: &str = "../shared/assets";

/// How the command line loads scene files: with the defaults of the variables it documents.
pub fn load_options() -> LoadOptions {
    LoadOptions::default().with_default(ASSETS_VARIABLE, DEFAULT_ASSETS)
}

/// The shared assets folder: `$HYTRACE_ASSETS`, else its default.
pub fn assets_dir() -> PathBuf {
    std::env::var_os(ASSETS_VARIABLE).map_or_else(|| DEFAULT_ASSETS.into(), PathBuf::from)
}

/// What `validate` and `compare` say in a build without the `embree` feature.
#[cfg(not(feature = "embree"))]
pub const NO_EMBREE: &str = "this build of hytrace has no Embree (the referee of `validate` and \
`compare`): run scripts/setup.sh once, then `source .deps/embree4/env` and build with \
`cargo build --release --features embree`";

/// Fails early (before long work) when an output file cannot be written: wrong extension or a
/// parent that is not a directory.
#[cfg_attr(not(feature = "embree"), allow(dead_code))]
pub fn check_output(flag: &str, path: &Path, ext: &str) -> Result<()> {
    let actual = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if actual.as_deref() != Some(ext) {
        bail!("{flag} {}: expected a .{ext} file name", path.display());
    }
    if let Some(dir) = path.parent().filter(|p| !p.as_os_str().is_empty())
        && !dir.is_dir()
    {
        bail!(
            "{flag} {}: cannot write there: {} is not a directory",
            path.display(),
            dir.display()
        );
    }
    Ok(())
}

/// Loads the scene file, or the built-in showcase when none is given.
pub fn load_scene(path: Option<&Path>) -> Result<Scene> {
    load_any(path, None)
}

/// Loads a scene file, or a mesh file as a scene of its own (a default camera framing it, or
/// the file's camera `camera`, and its lights or default ones), or the showcase.
pub fn load_any(path: Option<&Path>, camera: Option<&str>) -> Result<Scene> {
    let is_scene = |p: &Path| {
        p.extension()
            .and_then(|e| e.to_str())
            .is_none_or(|e| e.eq_ignore_ascii_case("ron"))
    };
    Ok(match path {
        Some(p) if is_scene(p) => {
            if camera.is_some() {
                anyhow::bail!(
                    "--camera applies to mesh files (.gltf, .glb, .obj, .ply), not scenes"
                );
            }
            Scene::load_with(p, &load_options())?
        }
        Some(p) => Scene::from_model(p, camera)?,
        None => Scene::from_source(SHOWCASE, Path::new("<built-in showcase.ron>"))?,
    })
}

/// `x` for a summary line: `decimals` places where that shows it (zero, or magnitudes from
/// 0.01 to 10⁶), else scientific notation with as many digits, so that a scene 10⁻⁴ across
/// does not print as zeros.
pub fn readable(x: f32, decimals: usize) -> String {
    if x == 0.0 || !x.is_finite() || (0.01..1e6).contains(&x.abs()) {
        format!("{x:.decimals$}")
    } else {
        format!("{x:.decimals$e}")
    }
}

#[cfg(test)]
mod tests {
    use super::readable;

    #[test]
    fn small_and_large_numbers_keep_their_digits() {
        assert_eq!(readable(-4.831, 4), "-4.8310");
        assert_eq!(readable(0.0, 3), "0.000");
        assert_eq!(readable(-4.049e-4, 4), "-4.0490e-4");
        assert_eq!(readable(2.5e7, 3), "2.500e7");
    }
}
