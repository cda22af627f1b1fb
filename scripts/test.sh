#!/usr/bin/env bash
# The whole test suite: what `.ci/run` runs and what the README's test command is.
#
#   scripts/test.sh [ARGS...]    ARGS go to `cargo test`, e.g. `scripts/test.sh embree_smoke`
#
# Stages: scripts/setup.sh (Debian packages, Embree 4), then
#   cargo test --release --features embree,fidget --no-fail-fast [ARGS...]
#   cargo clippy --release --all-targets --features embree,fidget -- -D warnings
#   cargo check --release --bins (default features, then --no-default-features)
#   cargo fmt --all -- --check
# and stops at the first that fails. Tests find the shared test models through HYTRACE_ASSETS
# (default: ../shared/assets beside the checkout), exported here as an absolute path; under
# CI=true a missing assets folder is an error, elsewhere a warning.
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd -P)"

# Resolve HYTRACE_ASSETS before leaving the caller's directory, so a relative value means
# relative to where the command was typed.
assets="${HYTRACE_ASSETS:-$REPO_ROOT/../shared/assets}"
if [[ -d "$assets" ]]; then
    assets="$(cd "$assets" && pwd -P)"
else
    [[ "$assets" == /* ]] || assets="$PWD/$assets"
fi
export HYTRACE_ASSETS="$assets"
cd "$REPO_ROOT"

banner() { printf '\n==== %s\n' "$*"; }
if [[ ! -d "$HYTRACE_ASSETS" ]]; then
    if [[ "${CI:-}" == true ]]; then
        banner "ERROR: test assets not found at HYTRACE_ASSETS=$HYTRACE_ASSETS" >&2
        echo "ERROR: CI must have ../shared/assets beside the checkout (or HYTRACE_ASSETS set)." >&2
        exit 1
    fi
    banner "WARNING: test assets not found at HYTRACE_ASSETS=$HYTRACE_ASSETS"
    echo "WARNING: tests that need the shared models will fail or be skipped. Put shared/ beside"
    echo "WARNING: the checkout or set HYTRACE_ASSETS to the assets folder."
fi

declare -a timings=()
stage_name=""
stage_start=0
elapsed_since() { awk -v a="$1" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }'; }
start_stage() {
    banner "$1"
    stage_name="$1"
    stage_start="$(date +%s.%N)"
}
end_stage() {
    local elapsed
    elapsed="$(elapsed_since "$stage_start")"
    timings+=("$(printf '%8s s  %s' "$elapsed" "$stage_name")")
    echo "---- $stage_name: ${elapsed} s"
    stage_name=""
}
print_timings() {
    if [[ -n "$stage_name" ]]; then # the stage that failed
        timings+=("$(printf '%8s s  %s  (FAILED)' "$(elapsed_since "$stage_start")" "$stage_name")")
        stage_name=""
    fi
    [[ ${#timings[@]} -gt 0 ]] || return 0
    banner "elapsed per stage"
    printf '%s\n' "${timings[@]}"
}

test_log="$(mktemp "${TMPDIR:-/tmp}/hytrace-test.XXXXXX")"
# cargo test prints one "test result:" line per test binary; add them up so that the last line
# of the run says how many tests ran, even after clippy's and rustfmt's output or a failure.
print_test_totals() {
    grep -q '^test result: ' "$test_log" 2>/dev/null || return 0
    awk '/^test result: / {
            for (i = 2; i <= NF; i++) {
                if ($(i) ~ /^passed;?$/) passed += $(i - 1)
                if ($(i) ~ /^failed;?$/) failed += $(i - 1)
                if ($(i) ~ /^ignored;?$/) ignored += $(i - 1)
            }
        }
        END { printf "\ntests: %d passed, %d failed, %d skipped\n", passed, failed, ignored }' "$test_log"
}
trap 'print_timings; print_test_totals; rm -f "$test_log"' EXIT

start_stage "setup (scripts/setup.sh)"
"$REPO_ROOT/scripts/setup.sh"
# shellcheck source=/dev/null
source "$REPO_ROOT/.deps/embree4/env"
export HYTRACE_EMBREE_LIB_DIR
echo "HYTRACE_EMBREE_LIB_DIR=$HYTRACE_EMBREE_LIB_DIR"
echo "HYTRACE_ASSETS=$HYTRACE_ASSETS"
end_stage

# --no-fail-fast: run every test binary and report all failures, not just the first binary's.
# With the bench's fidget peer: its tape conversion and the peer section are tested too.
start_stage "cargo test --release --features embree,fidget --no-fail-fast${*:+ $*}"
cargo test --release --features embree,fidget --no-fail-fast "$@" 2>&1 | tee "$test_log"
end_stage

# --release, as the checks below: clippy then shares the test build's build scripts and proc
# macros (built and run once, not again for the dev profile), and the checks share clippy's
# checked dependencies. After the test build of a fresh clone on a 2-core machine, this stage
# took 385 s in the dev profile and takes 118 s in the release profile.
start_stage "cargo clippy --release --all-targets --features embree,fidget -- -D warnings"
cargo clippy --release --all-targets --features embree,fidget -- -D warnings
end_stage

# The renderer must build without Embree (and without the GPU backend): the render command's
# build, and the leanest one.
start_stage "cargo check --release --bins (default features; --no-default-features)"
cargo check --release --bins
cargo check --release --bins --no-default-features
end_stage

start_stage "cargo fmt --all -- --check"
cargo fmt --all -- --check
end_stage
