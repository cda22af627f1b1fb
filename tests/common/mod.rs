//! What the integration tests share: the repository, the shared third-party assets, the
//! binary, temporary folders, the rays the backend comparisons cast ([`rays`]), image metrics
//! ([`psnr`], the library's), the GPU context ([`gpu`]) and the conformance macros
//! ([`conformance`]). Each test crate compiles this module on its own and uses a part of it.
#![allow(dead_code, unused_macros, unused_imports)]

#[macro_use]
pub mod conformance;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod rays;

use std::path::{Path, PathBuf};
use std::process::Command;

/// The repository's root.
pub fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The shared assets: `$HYTRACE_ASSETS`, else `../shared/assets` beside the repository.
pub fn assets() -> PathBuf {
    std::env::var_os("HYTRACE_ASSETS")
        .map(PathBuf::from)
        .unwrap_or_else(|| root().join("../shared/assets"))
}

/// [`assets`] when the folder exists. Otherwise says loudly that `what` did not run and
/// returns `None` — and fails under `CI=true`, where the assets must be present.
pub fn assets_or_skip(what: &str) -> Option<PathBuf> {
    let dir = assets();
    if dir.is_dir() {
        return Some(dir);
    }
    eprintln!(
        "!!! shared assets not found at {}: {what} NOT RUN !!!",
        dir.display()
    );
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "CI must have the shared assets at {}",
        dir.display()
    );
    None
}

/// assimp's test models (Debian's `assimp-testmodels`, which the test command installs).
pub const ASSIMP_MODELS: &str = "/usr/share/assimp/models";

/// The glTF test scenes: models that exercise the glTF material and light model (textures of
/// every kind, texture transforms, vertex colours, metals and dielectrics over the roughness
/// range, spot, point and directional lights in the file's units), each rendered on its own
/// as `hytrace render MODEL` does. Missing files fail under `CI=true`; elsewhere the list is
/// `None` and the reason is printed loudly.
pub fn gltf_test_models() -> Option<Vec<PathBuf>> {
    let assets = assets_or_skip("the glTF test scenes")?;
    let mut models: Vec<PathBuf> = [
        "glTF/Avocado/glTF/Avocado.gltf",
        "glTF/BoxTextured/glTF-Binary/BoxTextured.glb",
        "glTF/Duck/glTF-Binary/Duck.glb",
        "glTF/CesiumMilkTruck/glTF-Binary/CesiumMilkTruck.glb",
        "glTF/MetalRoughSpheresNoTextures/glTF/MetalRoughSpheresNoTextures.gltf",
        "glTF/bevy-lights/DepthOfFieldExample.glb",
        "glTF/bevy-lights/Cubes.glb",
    ]
    .iter()
    .map(|p| assets.join(p))
    .collect();
    models.push(Path::new(ASSIMP_MODELS).join("glTF2/textureTransform/TextureTransformTest.gltf"));
    let missing: Vec<String> = models
        .iter()
        .filter(|m| !m.is_file())
        .map(|m| m.display().to_string())
        .collect();
    if !missing.is_empty() {
        eprintln!(
            "!!! glTF test scenes missing ({}): the glTF scene checks NOT RUN !!!",
            missing.join(", ")
        );
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "CI must have every glTF test scene; missing: {}",
            missing.join(", ")
        );
        return None;
    }
    Some(models)
}

/// The `hytrace` binary, run from the repository's root.
pub fn hytrace() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_hytrace"));
    c.current_dir(root());
    c
}

/// A fresh temporary folder, removed when the value is dropped (also when the test panics),
/// named after `what` so that a kept folder says which test made it.
pub fn temp_dir(what: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("hytrace-{what}-"))
        .tempdir()
        .unwrap_or_else(|e| panic!("a temporary folder for {what}: {e}"))
}

/// PSNR of two 8-bit images in dB through the library's metric
/// ([`hytrace::render::metrics::psnr`]), infinite when they are identical.
pub fn psnr(a: &image::RgbImage, b: &image::RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions(), "image sizes");
    hytrace::render::metrics::psnr(a, b).unwrap_or(f64::INFINITY)
}
