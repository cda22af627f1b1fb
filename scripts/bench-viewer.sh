#!/usr/bin/env bash
# The viewer's frame rate while the camera moves and its time to converge, measured in a real
# window on a virtual X server (Xvfb, presented through Mesa's lavapipe), CPU backend.
#
#   scripts/bench-viewer.sh [HYTRACE_BINARY]
#
# For each scene, a scripted drag of 200 mouse moves (about 3 s) orbits the camera; the viewer
# renders previews at the size its frame budget (--fps) allows, then refines to the scene's
# samples once the camera rests. The `stats` lines say previews per second, their size and
# render time, and the seconds from the last move to the converged image. Runs alternate
# between the scenes, three rounds.
set -euo pipefail
REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd -P)"
cd "$REPO_ROOT"
export HYTRACE_ASSETS="${HYTRACE_ASSETS:-$REPO_ROOT/../shared/assets}"
if [[ $# -ge 1 ]]; then
    bin="$1"
else
    bash scripts/setup.sh >/dev/null
    cargo build --profile benchmark --bin hytrace >/dev/null
    bin="$REPO_ROOT/target/benchmark/hytrace"
fi
work="$(mktemp -d)"
Xvfb -displayfd 4 -screen 0 1280x1024x24 -nolisten tcp 4>"$work/display" 2>/dev/null &
xvfb=$!
trap 'kill $xvfb 2>/dev/null; rm -rf "$work"' EXIT
for _ in $(seq 50); do [[ -s "$work/display" ]] && break; sleep 0.1; done
export DISPLAY=":$(cat "$work/display")"
unset WAYLAND_DISPLAY
cat >"$work/orbit.txt" <<'SCRIPT'
wait 0.5
converge
stats
drag 100 150 500 250 left 200
converge
stats
quit
SCRIPT
# scene | window | frame-rate target
runs=(
    "showcase||800 600|20"
    "hybrid.ron|assets/scenes/hybrid.ron|640 360|10"
)
echo "| scene | window | --fps | previews per second while moving | preview size (px) | render ms per preview | seconds to converge (spp) |"
echo "|---|---|---|---|---|---|---|"
for round in 1 2 3; do
    for run in "${runs[@]}"; do
        IFS='|' read -r name scene size fps <<<"$run"
        read -r w h <<<"$size"
        line="$("$bin" view $scene --width "$w" --height "$h" --fps "$fps" --backend cpu \
            --script "$work/orbit.txt" 2>/dev/null | grep '^stats: moving' | tail -1)"
        # stats: moving: N previews in T s = F fps, P px each, M ms render each; converged to S spp C s after ...
        rate="$(sed -E 's/.* = ([0-9.]+) fps.*/\1/' <<<"$line")"
        px="$(sed -E 's/.* fps, ([0-9]+) px each.*/\1/' <<<"$line")"
        ms="$(sed -E 's/.* px each, ([0-9.]+) ms render.*/\1/' <<<"$line")"
        conv="$(sed -E 's/.*converged to ([0-9]+) spp ([0-9.]+) s.*/\2 (\1)/' <<<"$line")"
        echo "| $name (round $round) | ${w}×${h} | $fps | $rate | $px | $ms | $conv |"
    done
done
