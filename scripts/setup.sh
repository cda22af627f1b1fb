#!/usr/bin/env bash
# Installs what hytrace's tests need on a Debian 12 machine, and finds or fetches Embree 4.
#
#  1. Debian packages (apt-get runs only when one of them is missing):
#       libclang-dev         libclang for bindgen, which embree4-sys runs in its build script
#       mesa-vulkan-drivers  lavapipe, a CPU Vulkan driver, for the wgpu tests
#       assimp-testmodels    a real test corpus under /usr/share/assimp/models/
#       unzip                to take the Embree libraries out of the wheel
#       xvfb, xdotool        a virtual X display and synthetic input for the viewer's tests
#       chromium, chromium-driver
#                            a headless browser and its WebDriver, for the report pages' tests
#  2. Embree 4: the system's if `pkg-config embree4` says 4.x, otherwise the shared libraries
#     inside the PyPI wheel embreex (Embree 4.4.0 + its TBB), unpacked to .deps/embree4/lib/.
#     Either way it writes .deps/embree4/env, which exports HYTRACE_EMBREE_LIB_DIR for build.rs.
#
# Idempotent and quick once done; runs from any directory; needs root or sudo only when a
# Debian package is missing.
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd -P)"
DEPS_DIR="$REPO_ROOT/.deps/embree4"
ENV_FILE="$DEPS_DIR/env"

EMBREEX_VERSION="4.4.0.post1"
# The cp311 manylinux wheel (pinned below by tags, so the interpreter's own version does not
# matter) and its sha256 as PyPI serves it.
EMBREEX_WHEEL="embreex-4.4.0.post1-cp311-cp311-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl"
EMBREEX_SHA256="2cd0f7d5c6342e6247e31f700761689cae7829454d8c6de0c41e62124a023e1f"
STAMP="embreex==$EMBREEX_VERSION sha256=$EMBREEX_SHA256"

APT_PACKAGES=(libclang-dev mesa-vulkan-drivers assimp-testmodels unzip xvfb xdotool chromium chromium-driver)

log() { echo "setup: $*"; }
die() {
    echo "setup: ERROR: $*" >&2
    exit 1
}

# ---------------------------------------------------------------- apt
is_installed() {
    [[ "$(dpkg-query -W -f='${db:Status-Abbrev}' "$1" 2>/dev/null)" == ii* ]]
}

APT_UPDATED=0
apt_install() {
    local as_root=()
    if [[ "$(id -u)" -ne 0 ]]; then
        command -v sudo >/dev/null 2>&1 ||
            die "need root or sudo to install Debian packages: $*"
        as_root=(sudo)
    fi
    log "installing Debian packages: $*"
    if [[ "$APT_UPDATED" -eq 0 ]]; then
        "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update -q
        APT_UPDATED=1
    fi
    "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive \
        apt-get install -y -q --no-install-recommends "$@"
}

command -v dpkg-query >/dev/null 2>&1 || die "this script expects Debian (dpkg-query not found)"
missing=()
for pkg in "${APT_PACKAGES[@]}"; do
    is_installed "$pkg" || missing+=("$pkg")
done
if [[ ${#missing[@]} -gt 0 ]]; then
    apt_install "${missing[@]}"
fi

# ---------------------------------------------------------------- Embree 4
write_env() {
    # $1: absolute library directory, $2: description
    local tmp
    mkdir -p "$DEPS_DIR"
    tmp="$(mktemp "$DEPS_DIR/env.XXXXXX")"
    chmod 644 "$tmp"
    {
        echo "# Written by scripts/setup.sh: $2"
        printf 'export HYTRACE_EMBREE_LIB_DIR=%q\n' "$1"
    } >"$tmp"
    mv -f "$tmp" "$ENV_FILE"
}

if command -v pkg-config >/dev/null 2>&1 && pkg-config --atleast-version=4 embree4 2>/dev/null; then
    libdir="$(pkg-config --variable=libdir embree4)"
    version="$(pkg-config --modversion embree4)"
    [[ -d "$libdir" ]] || die "pkg-config embree4 names libdir '$libdir', which does not exist"
    write_env "$libdir" "system Embree $version"
    log "Embree 4: system Embree $version (pkg-config embree4) in $libdir"
    exit 0
fi

LIB_DIR="$DEPS_DIR/lib"
if [[ -f "$DEPS_DIR/STAMP" && "$(cat "$DEPS_DIR/STAMP")" == "$STAMP" &&
    -e "$LIB_DIR/libembree4.so" && -f "$ENV_FILE" ]]; then
    # Rewrite env in case the checkout moved (it holds an absolute path).
    write_env "$LIB_DIR" "Embree from the embreex $EMBREEX_VERSION wheel"
    log "Embree 4: embreex $EMBREEX_VERSION wheel libraries in $LIB_DIR (already there)"
    exit 0
fi

[[ "$(uname -m)" == x86_64 ]] ||
    die "no system Embree 4 (pkg-config embree4) and the embreex wheel is x86_64 only; install Embree 4 so that pkg-config finds embree4"
command -v python3 >/dev/null 2>&1 || apt_install python3 python3-pip
python3 -m pip --version >/dev/null 2>&1 || apt_install python3-pip

log "no system Embree 4; fetching embreex==$EMBREEX_VERSION from PyPI"
mkdir -p "$DEPS_DIR"
# Work inside .deps so the final move of the lib dir is a rename on one filesystem.
work="$(mktemp -d "$DEPS_DIR/tmp.XXXXXX")"
trap 'rm -rf "$work"' EXIT
# --python-version/--abi/--platform pin the cp311 wheel whatever python3 is (pip allows these
# only with --only-binary=:all: and --no-deps). --no-input: CI has no stdin.
python3 -m pip download --no-deps --only-binary=:all: --no-input --disable-pip-version-check \
    --python-version 3.11 --implementation cp --abi cp311 --platform manylinux_2_28_x86_64 \
    "embreex==$EMBREEX_VERSION" -d "$work/wheel" >"$work/pip.log" 2>&1 || {
    cat "$work/pip.log" >&2
    die "pip download of embreex==$EMBREEX_VERSION failed"
}
wheel="$work/wheel/$EMBREEX_WHEEL"
[[ -f "$wheel" ]] || die "expected $EMBREEX_WHEEL, pip gave: $(ls "$work/wheel")"
echo "$EMBREEX_SHA256  $wheel" | sha256sum -c --quiet - ||
    die "sha256 of $EMBREEX_WHEEL does not match the pinned one"

new_lib="$work/lib"
mkdir -p "$new_lib"
unzip -q -j -o "$wheel" 'embreex.libs/libembree4-*.so.4' 'embreex.libs/libtbb-*.so.12' -d "$new_lib"
shopt -s nullglob
embree_libs=("$new_lib"/libembree4-*.so.4)
tbb_libs=("$new_lib"/libtbb-*.so.12)
shopt -u nullglob
[[ ${#embree_libs[@]} -eq 1 && ${#tbb_libs[@]} -eq 1 ]] ||
    die "expected one libembree4-*.so.4 and one libtbb-*.so.12 in the wheel, got: $(ls "$new_lib")"
embree_name="$(basename "${embree_libs[0]}")"
tbb_name="$(basename "${tbb_libs[0]}")"
# The libraries keep their hashed SONAMEs, so binaries record NEEDED libembree4-<hash>.so.4;
# libembree4 finds its TBB (NEEDED libtbb-<hash>.so.12) through its own RPATH $ORIGIN.
# The linker only needs the unversioned name that embree4-sys's `-l embree4` looks for.
if command -v readelf >/dev/null 2>&1; then
    readelf -d "${embree_libs[0]}" | grep -q "NEEDED.*\[$tbb_name\]" ||
        die "$embree_name does not list $tbb_name as NEEDED; the wheel's layout changed"
fi
ln -sfn "$embree_name" "$new_lib/libembree4.so"

# Swap the new lib dir in whole, so a half-finished run never leaves a broken one behind.
rm -rf "$DEPS_DIR/lib.old"
if [[ -e "$LIB_DIR" ]]; then
    mv "$LIB_DIR" "$DEPS_DIR/lib.old"
fi
mv "$new_lib" "$LIB_DIR"
rm -rf "$DEPS_DIR/lib.old"
echo "$STAMP" >"$DEPS_DIR/STAMP"
write_env "$LIB_DIR" "Embree from the embreex $EMBREEX_VERSION wheel"
log "Embree 4: embreex $EMBREEX_VERSION wheel libraries ($embree_name, $tbb_name) in $LIB_DIR"
