#!/usr/bin/env bash
# Runs every benchmark and writes the report (issue 7): REPORT.md with its plots (SVG + PNG, drawn by
# gnuplot; skipped with a message without it), the CSV/JSON results beside them.
#   tools/bench_report.sh            -> full mode: bench/REPORT.md, bench/results/ (the committed reference)
#   tools/bench_report.sh --quick    -> quick mode (< 5 minutes): out/bench_quick/REPORT.md, out/bench_quick/results/
#   tools/bench_report.sh --smoke    -> seconds, on the shipped bunny only (the test suite runs this)
# Options: --out DIR (report at DIR/REPORT.md, results in DIR/results), --bin DIR (use this divvox
# build, skip set-up), --no-peers (skip the CGAL / OpenVDB comparison).
# The peers (CGAL clip, OpenVDB, Bullet soft body) are built into build-peers/ with -DDIVVOX_BENCH_PEERS=ON
# from Debian's libcgal-dev, libopenvdb-dev and libbullet-dev, installed when missing and running as root (or sudo).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"

mode=full out="" bin="" peers=1
while (($#)); do
  case "$1" in
    --quick) mode=quick ;;
    --full) mode=full ;;
    --smoke) mode=smoke ;;
    --out) out="$2"; shift ;;
    --bin) bin="$2"; shift ;;
    --no-peers) peers=0 ;;
    -h | --help) sed -n '2,11p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "bench_report: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
  shift
done
case "$mode" in
  full) out="${out:-$here/bench}" ;;
  quick) out="${out:-$here/out/bench_quick}" ;;
  smoke) out="${out:-$here/out/bench_smoke}"; peers=0 ;;
esac
results="$out/results"
mkdir -p "$results"

# The divvox build (README set-up) unless one was given.
if [[ -z "$bin" ]]; then
  "$here/tools/setup.sh"
  bin="$here/build/engine"
fi
divvox="$bin/divvox"
[[ -x "$divvox" ]] || { echo "bench_report: $divvox not found" >&2; exit 2; }

# The peer comparison tool: Debian packages, then its own build folder.
peers_bin=""
if ((peers)); then
  if "$here/tools/setup.sh" --only libcgal-dev libopenvdb-dev libbullet-dev; then
    pb="$here/build-peers"
    if [[ ! -f "$pb/CMakeCache.txt" ]]; then
      cmake -S "$here" -B "$pb" -G Ninja -DCMAKE_BUILD_TYPE=Release -DDIVVOX_BENCH_PEERS=ON -DDIVVOX_GRAPHICS=OFF \
        -DDIVVOX_TESTS=OFF >"$pb.configure.log" 2>&1 || { cat "$pb.configure.log"; exit 1; }
    fi
    cmake --build "$pb" --target divvox_peers --parallel "$(nproc)" >"$pb.build.log" 2>&1 || { cat "$pb.build.log"; exit 1; }
    peers_bin="$pb/tools/peers/divvox_peers"
  else
    echo "bench_report: could not install libcgal-dev libopenvdb-dev libbullet-dev; the report leaves CGAL, OpenVDB and Bullet out" >&2
  fi
fi

shared="$(cd "$here/.." && pwd)/shared/assets"
bunny="$here/assets/meshes/bunny_npm.obj"
armadillo="$shared/armadillo_100k.obj"
[[ -f "$armadillo" ]] || armadillo="$bunny"

# The settings of each mode: quick trims resolutions, repeats and sweeps.
case "$mode" in
  full)
    vox=(--resolutions 64,128,256,512 --repeats 5)
    cut=(--mesh "$armadillo" --resolutions 64,128,256 --repeats 5)
    scaling=(--resolutions 64,128,256,512)
    length=(--mesh "$armadillo" --resolution 256 --repeats 5)
    quality=(--mesh "$armadillo" --resolutions 64,128,256 --repeats 5)
    deform=()
    replay=(--repeats 3)
    contact=()
    elastic=()
    vdb=(--resolutions 64,128,256,512 --repeats 3)
    bullet=(--iterations 5,10,20 --reference-iterations 100 --seconds 1)
    clip=(--repeats 5)
    ;;
  quick)
    vox=(--mesh "$armadillo" --resolutions 64,128,256 --repeats 2)
    cut=(--mesh "$armadillo" --resolutions 64,128 --repeats 2)
    scaling=(--mesh "$armadillo" --resolutions 64,128,256 --steps 50)
    length=(--mesh "$armadillo" --resolution 128 --repeats 2)
    quality=(--mesh "$armadillo" --resolutions 64,128 --repeats 2)
    deform=(--sim-resolutions 8,16 --iterations 2,5,10,20 --seconds 1 --target-resolution 128)
    replay=(--repeats 1)
    contact=(--liver-cut-steps 40 --liver-rest-steps 80 --sever-resolution 128)
    elastic=(--sim-resolutions 4,8 --substeps 1,5 --iterations 1,2,5)
    vdb=(--resolutions 64,128,256 --repeats 1)
    bullet=(--iterations 10 --reference-iterations 50 --seconds 0.5)
    clip=(--repeats 2)
    ;;
  smoke)
    vox=(--mesh "$bunny" --resolutions 24,48 --repeats 1 --error-samples 5000)
    cut=(--mesh "$bunny" --resolutions 24,48 --repeats 1 --steps 20)
    scaling=(--mesh "$bunny" --resolutions 16,32 --steps 10 --sim-resolution 8)
    length=(--mesh "$bunny" --resolution 32 --repeats 1 --lengths 5 --steps 20)
    quality=(--mesh "$bunny" --resolutions 24,48 --repeats 1 --steps 20)
    deform=(--mesh "$bunny" --resolution 32 --sim-resolutions 4,8 --iterations 2,5 --substep-budgets 4 --seconds 0.2
            --target-mesh "$bunny" --target-resolution 32)
    replay=(--repeats 1 --recording "$here/assets/recordings/bunny_cut.jsonl")
    contact=(--liver-resolution 32 --liver-cut-steps 10 --liver-rest-steps 10 --sever-resolution 32 --sever-strokes 2
             --sever-stroke-steps 10 --sever-rest-steps 2)
    ;;
esac

step() { echo "bench_report: $*" >&2; }
start=$SECONDS
step "voxelize (surface time and error)";  "$divvox" bench voxelize "${vox[@]}" --out "$results" >/dev/null
step "cut (no physics)";                   "$divvox" bench cut "${cut[@]}" --out "$results" >/dev/null
step "scaling (Experiment 1)";             "$divvox" bench scaling "${scaling[@]}" --out "$results" >/dev/null
step "cut-length (Experiment 2)";          "$divvox" bench cut-length "${length[@]}" --out "$results" >/dev/null
step "quality (Fig. 13)";                  "$divvox" bench quality "${quality[@]}" --out "$results" >/dev/null
step "deform (physics speed against error)"; "$divvox" bench deform "${deform[@]}" --out "$results" >/dev/null
step "contact (step time with and without)"; "$divvox" bench contact "${contact[@]}" --out "$results" >/dev/null
step "replay (determinism, throughput)";   "$divvox" bench replay "${replay[@]}" --out "$results" >/dev/null
# Elasticity against CalculiX (the README's set-up installs ccx); without it the results kept in
# the folder stay (the report then shows them as they were).
if [[ $mode != smoke ]]; then
  if command -v ccx >/dev/null; then
    step "elastic (speed against error, CalculiX)"; "$divvox" bench elastic "${elastic[@]}" --out "$results" >/dev/null
  else
    echo "bench_report: ccx (calculix-ccx) not found: bench elastic skipped, its results in $results left as they were" >&2
  fi
fi
# The main job's replay (tools/run.sh: frames every 10 steps; no frames where EGL is missing): its timings plot.
step "replay timings plot (default recording)"
run="$results/replay_run"
"$divvox" replay "$here/assets/recordings/bunny_cut.jsonl" --headless --frames 10 --out "$run" >/dev/null 2>&1 ||
  "$divvox" replay "$here/assets/recordings/bunny_cut.jsonl" --headless --out "$run" >/dev/null
for ext in svg png; do
  if [[ -f "$run/timings.$ext" ]]; then cp "$run/timings.$ext" "$results/replay_timings.$ext"; else rm -f "$results/replay_timings.$ext"; fi
done
rm -rf "$run"
if [[ -n "$peers_bin" ]]; then
  step "peers: CGAL clip";                 "$peers_bin" clip --mesh "$armadillo" "${clip[@]}" --out "$results" >/dev/null
  step "peers: OpenVDB";                   "$peers_bin" vdb --mesh "$armadillo" "${vdb[@]}" --out "$results" >/dev/null
  step "peers: Bullet soft body";          "$peers_bin" bullet --scene "$here/assets/scenes/bunny.json" "${bullet[@]}" --out "$results" >/dev/null
else
  rm -f "$results"/peers_*.json "$results"/peers_*.csv
fi
report_mode=$mode
[[ $mode == smoke ]] && report_mode=quick
"$divvox" bench report --results "$results" --out "$out/REPORT.md" --mode "$report_mode" >/dev/null
echo "bench_report: $mode run took $((SECONDS - start)) s"
echo "report: $out/REPORT.md"
echo "results: $results/ (CSV, JSON, SVG, PNG)"
