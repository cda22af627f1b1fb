//! The subcommands of the `hytrace` binary, one module each.
pub mod bench;
pub mod compare;
pub mod info;
pub mod render;
pub mod slice;
pub mod validate;
pub mod view;

use anyhow::{Result, bail};
use std::path::Path;

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
    if let Some(dir) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        if !dir.is_dir() {
            bail!(
                "{flag} {}: cannot write there: {} is not a directory",
                path.display(),
                dir.display()
            );
        }
    }
    Ok(())
}
