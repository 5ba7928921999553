#!/usr/bin/env bash
# Command-line contract of divvox: bad input -> one-line message naming the file/flag, exit 2;
# --help -> exit 0; a valid run writes its outputs. Usage: cli_test.sh DIVVOX REPO SHARED_ASSETS
set -u
divvox=$1
repo=$2
shared=${3:-}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
failures=0
count=0

# expect CODE PATTERN -- command...: exit code CODE and stderr matching PATTERN (one line).
expect() {
  local code=$1 pattern=$2
  shift 3
  count=$((count + 1))
  "$@" >"$tmp/out" 2>"$tmp/err"
  local got=$?
  local lines
  lines=$(grep -c . "$tmp/err")
  if [[ $got -ne $code ]] || { [[ -n $pattern ]] && ! grep -q -E -- "$pattern" "$tmp/err"; } || { [[ $code -eq 2 ]] && [[ $lines -ne 1 ]]; }; then
    echo "FAIL: $* -> exit $got (want $code), stderr:"
    sed 's/^/    /' "$tmp/err"
    failures=$((failures + 1))
  fi
}

# check_hashes DIR WHAT: the replay in DIR checked at least one recorded hash and all matched.
check_hashes() {
  count=$((count + 1))
  if ! grep -q '"mismatched": 0' "$1/summary.json" || grep -q '"checked": 0,' "$1/summary.json"; then
    echo "FAIL: $2: hashes not checked or not matching"
    failures=$((failures + 1))
  fi
}

# Bad meshes, each written here.
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\n' >"$tmp/points_only.obj"
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n' >"$tmp/out_of_range.obj"
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 -7\n' >"$tmp/relative_out_of_range.obj"
printf 'v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n' >"$tmp/nan.obj"
printf 'v 0 0 0\nv inf 0 0\nv 0 1 0\nf 1 2 3\n' >"$tmp/inf.obj"
printf 'v 1 1 1\nv 1 1 1\nv 1 1 1\nf 1 2 3\n' >"$tmp/zero_box.obj"
: >"$tmp/empty.obj"
head -c 4096 /dev/urandom >"$tmp/garbage.stl" 2>/dev/null || printf '\x01\x02garbage' >"$tmp/garbage.stl"
printf 'solid x\n' >"$tmp/broken.stl"
printf 'hello' >"$tmp/mesh.xyz123"
printf '{"mesh": "m.obj", "resolutoin": 64}' >"$tmp/typo.json"
printf '{"mesh": "m.obj",\n "resolution": }' >"$tmp/malformed.json"
printf '{"mesh": "missing.obj"}' >"$tmp/missing_mesh.json"

bunny="$repo/assets/meshes/bunny_npm.obj"
expect 0 '' -- "$divvox" --help
expect 0 '' -- "$divvox" voxelize --help
expect 0 '' -- "$divvox" bench voxelize --help
expect 2 'no-such.obj: no such file' -- "$divvox" voxelize "$tmp/no-such.obj" --out "$tmp/o"
expect 2 'mesh.xyz123: unknown mesh format' -- "$divvox" voxelize "$tmp/mesh.xyz123" --out "$tmp/o"
expect 2 'points_only.obj: .*(no triangles|cannot be read)' -- "$divvox" voxelize "$tmp/points_only.obj" --out "$tmp/o"
expect 2 'out_of_range.obj: .*(index|vertex|cannot be read)' -- "$divvox" voxelize "$tmp/out_of_range.obj" --out "$tmp/o"
expect 2 'relative_out_of_range.obj: .*(index|vertex|cannot be read)' -- "$divvox" voxelize "$tmp/relative_out_of_range.obj" --out "$tmp/o"
expect 2 'nan.obj: .*(NaN|cannot be read)' -- "$divvox" voxelize "$tmp/nan.obj" --out "$tmp/o"
expect 2 'inf.obj: .*(infinite|cannot be read)' -- "$divvox" voxelize "$tmp/inf.obj" --out "$tmp/o"
expect 2 'zero_box.obj: .*(zero size|degenerate)' -- "$divvox" voxelize "$tmp/zero_box.obj" --out "$tmp/o"
expect 2 'empty.obj: empty file' -- "$divvox" voxelize "$tmp/empty.obj" --out "$tmp/o"
expect 2 'garbage.stl: ' -- "$divvox" voxelize "$tmp/garbage.stl" --out "$tmp/o"
expect 2 'broken.stl: ' -- "$divvox" voxelize "$tmp/broken.stl" --out "$tmp/o"
expect 2 'resolution' -- "$divvox" voxelize "$bunny" --resolution 100000 --out "$tmp/o"
expect 2 'bunny_npm.obj: resolution 3000 needs a lattice of [0-9]+ nodes' -- "$divvox" voxelize "$bunny" --resolution 3000 --out "$tmp/o"
expect 2 'bunny_npm.obj: resolution 1000 needs about .* but the budget is 100.0 MiB' -- env DIVVOX_MEMORY_LIMIT=100M "$divvox" voxelize "$bunny" --resolution 1000 --out "$tmp/o"
expect 2 'typo.json: resolutoin: unknown key' -- "$divvox" voxelize --scene "$tmp/typo.json" --out "$tmp/o"
expect 2 'malformed.json: malformed JSON.*line 2' -- "$divvox" voxelize --scene "$tmp/malformed.json" --out "$tmp/o"
expect 2 'missing.obj: no such file' -- "$divvox" voxelize --scene "$tmp/missing_mesh.json" --out "$tmp/o"
expect 2 'resolution' -- "$divvox" voxelize "$bunny" --resolution banana --out "$tmp/o"
expect 2 'subcommand' -- "$divvox" frobnicate
expect 2 'resolutions' -- "$divvox" bench voxelize --resolutions 64,x --out "$tmp/b"

# Recordings: a truncated last line is a warning; a corrupted middle line is an error naming it.
rec="$repo/assets/recordings/bunny_cut.jsonl"
head -c -7 "$rec" | sed 's|"mesh":"../meshes/bunny_npm.obj"|"mesh":"'"$repo"'/assets/meshes/bunny_npm.obj"|' >"$tmp/truncated.jsonl"
sed '5s/.*/{"step":4,"blade":[[0,0/' "$rec" | sed 's|"mesh":"../meshes/bunny_npm.obj"|"mesh":"'"$repo"'/assets/meshes/bunny_npm.obj"|' >"$tmp/corrupt.jsonl"
sed '5s/.*/{"step":4,"blade":[[0,0,NaN],[0,0,0]],"cutting":true}/' "$rec" | sed 's|"mesh":"../meshes/bunny_npm.obj"|"mesh":"'"$repo"'/assets/meshes/bunny_npm.obj"|' >"$tmp/nan.jsonl"
expect 0 'truncated last line' -- "$divvox" replay "$tmp/truncated.jsonl" --headless --no-physics --out "$tmp/r1"
expect 2 'corrupt.jsonl: line 5' -- "$divvox" replay "$tmp/corrupt.jsonl" --headless --no-physics --out "$tmp/r2"
expect 2 'nan.jsonl: line 5: step 4' -- "$divvox" replay "$tmp/nan.jsonl" --headless --no-physics --out "$tmp/r3"
expect 2 'no-such.jsonl: no such file' -- "$divvox" replay "$tmp/no-such.jsonl" --headless --no-physics --out "$tmp/r4"
expect 0 '' -- "$divvox" replay "$rec" --headless --out "$tmp/r5" --workers 2
count=$((count + 1))
if ! grep -q '"nonfinite_values": 0' "$tmp/r5/summary.json" || ! grep -q '"mass"' "$tmp/r5/summary.json"; then
  echo "FAIL: the physics replay has non-finite values or no mass"
  failures=$((failures + 1))
fi
expect 0 '' -- "$divvox" replay "$rec" --headless --out "$tmp/r6"
check_hashes "$tmp/r6" "the shipped recording"
# timings.svg: a well-formed SVG drawn by gnuplot; with no gnuplot on PATH the replay says so and succeeds.
if command -v gnuplot >/dev/null && command -v python3 >/dev/null; then
  count=$((count + 1))
  if ! python3 -c 'import sys, xml.etree.ElementTree as E; t = E.parse(sys.argv[1]).getroot(); sys.exit(not t.tag.endswith("svg"))' "$tmp/r6/timings.svg"; then
    echo "FAIL: $tmp/r6/timings.svg is not a well-formed SVG document"
    failures=$((failures + 1))
  fi
fi
mkdir -p "$tmp/empty_path"
expect 0 'timings.svg skipped: gnuplot not found' -- env -u DIVVOX_GNUPLOT PATH="$tmp/empty_path" "$divvox" replay "$rec" --headless --no-physics --out "$tmp/r7"
count=$((count + 1))
if [[ ! -s "$tmp/r7/timings.csv" || -e "$tmp/r7/timings.svg" ]]; then
  echo "FAIL: without gnuplot the replay should write timings.csv and no timings.svg"
  failures=$((failures + 1))
fi

# The grab recording: grab commands replay deterministically.
expect 0 '' -- "$divvox" replay "$repo/assets/recordings/bunny_grab.jsonl" --headless --out "$tmp/g1"
check_hashes "$tmp/g1" "the grab recording"

# Crash-safe recordings: SIGKILL a replay while it records (real-time pace); the partial recording
# replays up to its last complete step.
"$divvox" replay "$rec" --headless --speed realtime --out "$tmp/k1" --record "$tmp/killed.jsonl" --hash-every 10 >/dev/null 2>&1 &
pid=$!
# Kill it once it has recorded a few dozen lines (polls: start-up time varies with the build).
for _ in $(seq 1 300); do
  [[ -f "$tmp/killed.jsonl" ]] && (($(wc -l <"$tmp/killed.jsonl") >= 40)) && break
  sleep 0.1
done
kill -KILL "$pid" 2>/dev/null
wait "$pid" 2>/dev/null
count=$((count + 1))
lines=$(wc -l <"$tmp/killed.jsonl")
if [[ $lines -lt 20 ]]; then
  echo "FAIL: the killed recording has only $lines lines"
  failures=$((failures + 1))
fi
expect 0 '' -- "$divvox" replay "$tmp/killed.jsonl" --headless --out "$tmp/k2"
check_hashes "$tmp/k2" "the killed recording"

# A valid run writes report.json and surface.ply.
expect 0 '' -- "$divvox" voxelize "$bunny" --resolution 32 --error-samples 2000 --out "$tmp/ok"
count=$((count + 1))
if [[ ! -s "$tmp/ok/report.json" || ! -s "$tmp/ok/surface.ply" ]] || ! grep -q '"boundary_edges": 0' "$tmp/ok/report.json"; then
  echo "FAIL: voxelize did not write a closed surface report"
  failures=$((failures + 1))
fi

# Progress (forced on a pipe with DIVVOX_PROGRESS=1): reading reported up to 100 %, then each phase.
count=$((count + 1))
DIVVOX_PROGRESS=1 "$divvox" voxelize "$bunny" --resolution 16 --error-samples 100 --out "$tmp/progress" 2>"$tmp/progress.err" >/dev/null
if ! grep -q 'loading bunny_npm.obj: 100 %' "$tmp/progress.err" || ! grep -q 'read [0-9]* triangles' "$tmp/progress.err" ||
   ! grep -q 'voxelizing' "$tmp/progress.err"; then
  echo "FAIL: voxelize with DIVVOX_PROGRESS=1 did not report its progress:"
  sed 's/^/    /' "$tmp/progress.err"
  failures=$((failures + 1))
fi
# Without a terminal and without DIVVOX_PROGRESS, nothing but errors on stderr.
count=$((count + 1))
"$divvox" voxelize "$bunny" --resolution 16 --error-samples 100 --out "$tmp/quiet" 2>"$tmp/quiet.err" >/dev/null
if [[ -s "$tmp/quiet.err" ]]; then
  echo "FAIL: voxelize wrote to stderr without a terminal:"
  sed 's/^/    /' "$tmp/quiet.err"
  failures=$((failures + 1))
fi

echo "$((count - failures)) passed, $failures failed"
[[ $failures -eq 0 ]]
