#!/usr/bin/env bash
# README command 1: set up (packages + build), then the main job.
# Main job until the replay engine exists: voxelize the default scene's mesh and dual-contour it.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/tools/setup.sh"
cd "$here"
out="${DIVVOX_OUT:-$here/out/voxelize}"
./build/engine/divvox voxelize --scene assets/scenes/bunny.json --out "$out"
echo "outputs: $out/report.json, $out/surface.ply"
