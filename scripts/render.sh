#!/usr/bin/env bash
# Renders with hytrace: `scripts/render.sh [ARGS...]` runs `hytrace render ARGS...` (release
# build) in the caller's directory, so relative paths in ARGS mean what they say. Builds without
# the `embree` feature: it needs neither Embree nor any Debian package.
set -euo pipefail
REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd -P)"
# Scenes name shared third-party meshes as $HYTRACE_ASSETS/...: default to ../shared/assets
# beside the checkout, whatever the working directory.
export HYTRACE_ASSETS="${HYTRACE_ASSETS:-$REPO_ROOT/../shared/assets}"
exec cargo run --release --manifest-path "$REPO_ROOT/Cargo.toml" -- render "$@"
