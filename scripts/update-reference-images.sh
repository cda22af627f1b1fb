#!/usr/bin/env bash
# Regenerates the stored reference images (tests/reference/*.png) from the CPU renderer, on
# purpose: after a change meant to alter the pictures. Review the new images (git diff shows
# which changed) and say in the commit why they changed.
#
#   scripts/update-reference-images.sh
set -euo pipefail
REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd -P)"
cd "$REPO_ROOT"
export HYTRACE_ASSETS="${HYTRACE_ASSETS:-$REPO_ROOT/../shared/assets}"
mkdir -p tests/reference
HYTRACE_UPDATE_REFERENCES=1 cargo test --release --test reference_images \
    cpu_images_match_the_stored_references -- --nocapture
