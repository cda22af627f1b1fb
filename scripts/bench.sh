#!/usr/bin/env bash
# Runs hytrace's benchmarks from a fresh clone: installs what they need (scripts/setup.sh: Embree 4
# and the Debian packages), then `hytrace bench` with Embree built in. Extra arguments go to
# `hytrace bench` (e.g. --quick, --runs 3, --only mesh). Writes bench.json beside the tables
# unless --json is given. Built with the `fidget` feature, so the peer section (our SDF renderer
# against fidget's) runs too.
set -euo pipefail
REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd -P)"
cd "$REPO_ROOT"
bash scripts/setup.sh
# shellcheck disable=SC1091
source .deps/embree4/env
export HYTRACE_ASSETS="${HYTRACE_ASSETS:-$REPO_ROOT/../shared/assets}"
args=("$@")
if [[ " ${args[*]-} " != *" --json "* ]]; then
    args+=(--json bench.json)
fi
# The `benchmark` profile: release with fat LTO and one codegen unit (Cargo.toml).
exec cargo run --profile benchmark --features embree,fidget -- bench "${args[@]}"
