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
