#!/usr/bin/env bash
# The include graph goes one way: sim <- render <- engine <- bench, ui <- app (DESIGN §2). Fails,
# naming the file and the include, when a folder includes one above it, or when a render/ header
# names sim/ types other than the plain mesh arrays (sim/mesh.h, sim/surface_mesh.h).
#   tests/layers_test.sh [SOURCE_DIR]
set -uo pipefail
root="${1:-$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)}"
cd "$root" || exit 2

# What each layer may include (project folders; system and package headers are not checked).
declare -A allowed=(
  [sim]="sim"
  [render]="sim render"
  [engine]="sim render engine"
  [bench]="sim render engine bench"
  [ui]="sim render engine ui"
  [app]="sim render engine bench ui app"
)

failures=0
for layer in sim render engine bench ui app; do
  [[ -d $layer ]] || continue
  # Every quoted include of a project folder: FILE:LINE:#include "FOLDER/...".
  while IFS= read -r hit; do
    file="${hit%%:*}"
    target="$(sed -E 's/.*#[[:space:]]*include[[:space:]]*"([^"]+)".*/\1/' <<<"$hit")"
    folder="${target%%/*}"
    [[ " sim render engine bench ui app " == *" $folder "* ]] || continue
    if [[ " ${allowed[$layer]} " != *" $folder "* ]]; then
      echo "layers: $file includes $target ($layer/ may include only: ${allowed[$layer]})"
      failures=$((failures + 1))
    fi
  done < <(grep -rnE '^[[:space:]]*#[[:space:]]*include[[:space:]]*"' --include='*.h' --include='*.cpp' "$layer" |
           grep -v '^render/glad/')
done

# render/ headers: plain arrays only (Vec3f, Tri, SurfaceMesh), no simulation types.
while IFS= read -r hit; do
  target="$(sed -E 's/.*"([^"]+)".*/\1/' <<<"$hit")"
  case "$target" in
    sim/mesh.h | sim/surface_mesh.h) ;;
    *) echo "layers: ${hit%%:*} includes $target (render/ headers take plain arrays: sim/mesh.h, sim/surface_mesh.h)"
       failures=$((failures + 1)) ;;
  esac
done < <(grep -nE '^[[:space:]]*#[[:space:]]*include[[:space:]]*"sim/' render/*.h)

if ((failures > 0)); then
  echo "layers: $failures include(s) against the layer order"
  exit 1
fi
echo "layers: ok (sim <- render <- engine <- bench, ui <- app)"
