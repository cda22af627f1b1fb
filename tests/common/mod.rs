//! What the integration tests share: the repository, the shared third-party assets and the
//! binary. Each test crate compiles this module on its own and uses a part of it.
#![allow(dead_code)]

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
