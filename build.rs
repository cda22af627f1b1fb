//! Build script: tells the linker where Embree 4 is when the `embree` feature is on.
//!
//! `embree4-sys` asks for `-l embree4` but names no directory, and Debian 12 ships only
//! Embree 3, so `scripts/setup.sh` finds a system Embree 4 or unpacks the one in the PyPI wheel
//! `embreex` to `.deps/embree4/lib/`, and writes `.deps/embree4/env`, which exports
//! `HYTRACE_EMBREE_LIB_DIR`. This script takes that directory (or, when the variable is unset,
//! `.deps/embree4/lib` if it exists), adds it to the link search path, and records it as an
//! rpath in this package's binaries, tests, examples and benches so that they find
//! `libembree4` when they run. Without Embree 4 it stops the build and says how to get it.
//! Without the `embree` feature it does nothing.

use std::env;
use std::path::{Path, PathBuf};

const LIB_DIR_VAR: &str = "HYTRACE_EMBREE_LIB_DIR";

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    if env::var_os("CARGO_FEATURE_EMBREE").is_none() {
        return;
    }
    println!("cargo:rerun-if-env-changed={LIB_DIR_VAR}");

    let manifest_dir = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("set by cargo"));
    let fallback = manifest_dir.join(".deps").join("embree4").join("lib");
    let lib_dir = match env::var_os(LIB_DIR_VAR).filter(|v| !v.is_empty()) {
        Some(dir) => {
            let dir = PathBuf::from(dir);
            if !dir.is_dir() {
                fail(&format!(
                    "{LIB_DIR_VAR}={} is not a directory.",
                    dir.display()
                ));
            }
            dir
        }
        None if fallback.is_dir() => {
            // Rerun when scripts/setup.sh replaces it. (A failed build script always reruns,
            // so the case where it does not exist yet needs no such line.)
            println!("cargo:rerun-if-changed={}", fallback.display());
            fallback
        }
        None => fail(&format!(
            "{LIB_DIR_VAR} is not set and {} does not exist.",
            fallback.display()
        )),
    };
    let lib_dir = lib_dir.canonicalize().unwrap_or(lib_dir);
    if !has_embree4(&lib_dir) {
        fail(&format!(
            "{} holds no libembree4.so (the name the linker looks for).",
            lib_dir.display()
        ));
    }
    let dir = lib_dir
        .to_str()
        .unwrap_or_else(|| fail(&format!("{} is not UTF-8.", lib_dir.display())));
    if dir.contains(',') {
        fail(&format!(
            "{dir} contains a comma, which -Wl,-rpath cannot carry."
        ));
    }

    println!("cargo:rustc-link-search=native={dir}");
    println!("cargo:rustc-link-arg=-Wl,-rpath,{dir}");
}

fn has_embree4(dir: &Path) -> bool {
    ["libembree4.so", "libembree4.dylib", "embree4.lib"]
        .iter()
        .any(|name| dir.join(name).exists())
}

fn fail(why: &str) -> ! {
    panic!(
        "\n\nThe `embree` feature needs Embree 4: {why}\n\
         Run `scripts/setup.sh` (it installs or fetches Embree 4 and writes .deps/embree4/env),\n\
         then `source .deps/embree4/env`, or set {LIB_DIR_VAR} to a directory holding \
         libembree4.so.\n\
         (`scripts/test.sh` does all of this.)\n\n"
    );
}
