#!/usr/bin/env bash
# README command 1: set up (packages + build), then the main job:
#   1. voxelize and dual-contour the default scene's mesh, with its error report;
#   2. replay the default recording headlessly (cutting + PBD deformation), checking its state hashes.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/tools/setup.sh"
cd "$here"
out="${DIVVOX_OUT:-$here/out}"
./build/engine/divvox voxelize --scene assets/scenes/bunny.json --out "$out/voxelize"
./build/engine/divvox replay assets/recordings/bunny_cut.jsonl --headless --out "$out/replay"
echo "outputs:"
echo "  $out/voxelize/report.json, $out/voxelize/surface.ply"
echo "  $out/replay/summary.json, $out/replay/timings.csv, $out/replay/final.ply"
