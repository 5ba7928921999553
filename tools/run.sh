#!/usr/bin/env bash
# README command 1: set up (packages + build), then the main job:
#   1. voxelize and dual-contour the default scene's mesh, with its error report;
#   2. replay the default recording headlessly (cutting + PBD deformation on a simulation thread, EGL
#      rendering on a render thread), checking its state hashes, writing frames and timings.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/tools/setup.sh"
cd "$here"
out="${DIVVOX_OUT:-$here/out}"
./build/engine/divvox voxelize --scene assets/scenes/bunny.json --out "$out/voxelize"
./build/engine/divvox replay assets/recordings/bunny_cut.jsonl --headless --frames 10 --out "$out/replay"
echo "outputs:"
echo "  $out/voxelize/report.json, $out/voxelize/surface.ply"
echo "  $out/replay/summary.json, $out/replay/timings.csv, $out/replay/timings.svg, $out/replay/final.ply"
echo "  $out/replay/frames/ (a PNG every 10 steps), $out/replay/frame_timings.csv"
