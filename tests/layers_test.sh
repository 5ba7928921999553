#!/usr/bin/env bash
# The include graph goes one way: sim <- render <- engine <- harness <- bench, ui <- app (DESIGN §2).
# Fails, naming the file and the include, when a folder includes one above it (so engine/, render/ and
# sim/ never include harness/, ui/ or bench/), when a layer's CMakeLists.txt links a library above it, or when a
# render/ header includes or names sim/ types other than the plain mesh arrays (sim/mesh.h,
# sim/surface_mesh.h), when a layer above sim/ includes a sim/ internal, or when engine/, ui/ or app/
# (or harness/) call a stage of the step instead of world_step.
#   tests/layers_test.sh [SOURCE_DIR]
#   tests/layers_test.sh --self-test [SOURCE_DIR]   (a copy with one violation of each kind must fail)
set -uo pipefail
script="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)/$(basename "${BASH_SOURCE[0]}")"

# Self-test: the check must see an include of ui/ from engine/, of bench/ from sim/, of harness/ from
# engine/, a sim/ type named in a render/ header, a higher library linked from engine/'s
# CMakeLists.txt, a sim/ internal included by engine/ and a stage of the step called by engine/ (seven
# failures).
if [[ "${1:-}" == --self-test ]]; then
  src="${2:-$(cd "$(dirname "$script")/.." && pwd)}"
  copy="$(mktemp -d)"
  trap 'rm -rf "$copy"' EXIT
  for layer in sim render engine harness bench ui app; do
    [[ -d $src/$layer ]] && cp -r "$src/$layer" "$copy/"
  done
  echo '#include "ui/app.h"' >>"$copy/engine/errors.h"
  echo '#include "bench/bench.h"' >>"$copy/sim/mesh.h"
  echo '#include "harness/plot.h"' >>"$copy/engine/errors.h"
  echo 'struct CutSurface;  // a forward declaration hides the include' >>"$copy/render/camera.h"
  echo 'target_link_libraries(divvox_engine PUBLIC $<$<TARGET_EXISTS:divvox_ui>:divvox_ui>)' >>"$copy/engine/CMakeLists.txt"
  echo '#include "sim/pbd_kernels.h"' >>"$copy/engine/errors.h"
  printf 'void f(dvx::Session& s) { pbd_step(s.state.cut, *s.state.pbd); }\n' >>"$copy/engine/errors.cpp"
  output="$(bash "$script" "$copy")" && { echo "layers self-test: the violations passed"; exit 1; }
  echo "$output"
  [[ $(grep -v 'against the layer order' <<<"$output" | grep -c '^layers: ') == 7 ]] || { echo "layers self-test: expected 7 failures"; exit 1; }
  echo "layers self-test: ok (7 violations found)"
  exit 0
fi

root="${1:-$(cd "$(dirname "$script")/.." && pwd)}"
cd "$root" || exit 2

# What each layer may include (project folders; system and package headers are not checked).
declare -A allowed=(
  [sim]="sim"
  [render]="sim render"
  [engine]="sim render engine"
  [harness]="sim render engine harness"
  [bench]="sim render engine harness bench"
  [ui]="sim render engine ui"
  [app]="sim render engine harness bench ui app"
)

failures=0
for layer in sim render engine harness bench ui app; do
  [[ -d $layer ]] || continue
  # Every quoted include of a project folder: FILE:LINE:#include "FOLDER/...".
  while IFS= read -r hit; do
    file="${hit%%:*}"
    target="$(sed -E 's/.*#[[:space:]]*include[[:space:]]*"([^"]+)".*/\1/' <<<"$hit")"
    folder="${target%%/*}"
    [[ " sim render engine harness bench ui app " == *" $folder "* ]] || continue
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

# render/ headers: nor any sim/ type by name (a forward declaration would hide it from the include
# check). The types are those sim/ headers other than the plain arrays declare; comments do not count.
sim_types="$(grep -hoE '^[[:space:]]*(struct|class|enum class|enum|using)[[:space:]]+[A-Za-z_][A-Za-z0-9_]*' \
               $(ls sim/*.h | grep -v -e '^sim/mesh\.h$' -e '^sim/surface_mesh\.h$') |
             sed -E 's/.*[[:space:]]([A-Za-z_][A-Za-z0-9_]*)$/\1/' | sort -u | paste -sd '|')"
if [[ -n $sim_types ]]; then
  while IFS= read -r hit; do
    echo "layers: ${hit%%:*} names the sim/ type $(grep -owE "$sim_types" <<<"${hit#*:}" | head -1) (render/ headers take plain arrays)"
    failures=$((failures + 1))
  done < <(for h in render/*.h; do sed -E 's://.*$::' "$h" | grep -nwE -- "$sim_types" | sed "s|^|$h:|"; done)
fi

# Link graph: a layer's CMakeLists.txt links only the libraries of the layers it may include
# (divvox_glad is render's; generator expressions and if() branches count alike).
for layer in sim render engine harness bench ui app; do
  [[ -f $layer/CMakeLists.txt ]] || continue
  while IFS= read -r hit; do
    lib="${hit##*:}"
    folder="${lib#divvox_}"
    [[ $folder == glad ]] && folder=render
    [[ " sim render engine harness bench ui app " == *" $folder "* ]] || continue
    if [[ " ${allowed[$layer]} " != *" $folder "* ]]; then
      echo "layers: $layer/CMakeLists.txt links $lib ($layer/ may use only: ${allowed[$layer]})"
      failures=$((failures + 1))
    fi
  done < <(sed -E 's/#.*$//' "$layer/CMakeLists.txt" | tr '\n' ' ' | grep -oE 'target_link_libraries\([^)]*\)' |
           grep -oE '\bdivvox_[a-z]+\b' | sort -u | sed "s|^|$layer:|")
done

# sim/'s internals (the solver's kernels, colouring, the pieces' shared internals, the cut's and the rest mapping's
# shared internals) stay inside sim/: the layers above include only its public headers.
sim_internal="sim/pbd_kernels.h sim/pbd_kernels_lanes.inc sim/colouring.h sim/pbd_internal.h"
sim_internal+=" sim/cut_internal.h sim/world_to_rest_internal.h"
for layer in engine render harness bench ui app; do
  [[ -d $layer ]] || continue
  while IFS= read -r hit; do
    target="$(sed -E 's/.*"([^"]+)".*/\1/' <<<"$hit")"
    if [[ " $sim_internal " == *" $target "* ]]; then
      echo "layers: ${hit%%:*} includes $target (a sim/ internal: include sim/'s public headers, e.g. sim/world.h)"
      failures=$((failures + 1))
    fi
  done < <(grep -rnE '^[[:space:]]*#[[:space:]]*include[[:space:]]*"sim/' --include='*.h' --include='*.cpp' "$layer")
done

# One step: the engine, the harness, the window and the command line step the world through world_step (sim/world.h)
# only, never by calling its stages themselves; and only sim/world.cpp maps a sweep to rest space for a
# cut (the tests of the mapping itself excepted).
stages='\b(map_sweep|cut_divide|cut_update_surface|pbd_apply_cut|pbd_step)[[:space:]]*\('
for layer in engine harness ui app; do
  [[ -d $layer ]] || continue
  while IFS= read -r hit; do
    echo "layers: ${hit%%:*} calls a stage of the step ($(grep -oE "$stages" <<<"${hit#*:}" | head -1 | tr -d '( ')): call world_step"
    failures=$((failures + 1))
  done < <(grep -rnE "$stages" --include='*.h' --include='*.cpp' "$layer" | grep -vE '^[^:]+:[0-9]+:[[:space:]]*//')
done
while IFS= read -r hit; do
  echo "layers: ${hit%%:*} maps a sweep itself (map_sweep): a cut step goes through world_step"
  failures=$((failures + 1))
done < <(grep -rnE '\bmap_sweep[[:space:]]*\(' --include='*.cpp' sim bench tests 2>/dev/null |
         grep -vE '^(sim/world\.cpp|sim/sweep_map\.cpp|tests/sim/test_world_to_rest\.cpp):' |
         grep -vE '^[^:]+:[0-9]+:[[:space:]]*//')

if ((failures > 0)); then
  echo "layers: $failures include(s), sim/ type name(s) or link(s) against the layer order"
  exit 1
fi
echo "layers: ok (sim <- render <- engine <- harness <- bench, ui <- app)"
