#!/usr/bin/env bash
# Builds the libFuzzer targets (build-fuzz/, clang) and fuzzes one for SECONDS.
#   tools/fuzz.sh scene|recording|mesh SECONDS [extra libFuzzer args...]
# Working corpus: build-fuzz/corpus/TARGET (seeded from tests/fuzz/corpus/TARGET).
# Crash/timeout/OOM inputs: build-fuzz/crashes/TARGET/. Exit status non-zero when one is found.
set -euo pipefail

usage() { echo "usage: tools/fuzz.sh scene|recording|mesh SECONDS [libFuzzer args...]" >&2; exit 2; }
[[ $# -ge 2 ]] || usage
target=$1; seconds=$2; shift 2
case "$target" in scene|recording|mesh) ;; *) echo "fuzz.sh: unknown target '$target' (scene, recording or mesh)" >&2; exit 2 ;; esac
[[ "$seconds" =~ ^[0-9]+$ ]] || { echo "fuzz.sh: SECONDS must be a whole number, got '$seconds'" >&2; exit 2; }

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
build=build-fuzz

command -v clang >/dev/null 2>&1 || { echo "fuzz.sh: clang not found (install clang and libclang-rt-dev for libFuzzer)" >&2; exit 2; }
command -v clang++ >/dev/null 2>&1 || { echo "fuzz.sh: clang++ not found (install clang and libclang-rt-dev for libFuzzer)" >&2; exit 2; }
command -v cmake >/dev/null 2>&1 || { echo "fuzz.sh: cmake not found" >&2; exit 2; }
command -v ninja >/dev/null 2>&1 || { echo "fuzz.sh: ninja not found" >&2; exit 2; }

if [[ ! -f "$build/CMakeCache.txt" ]]; then
  CC=clang CXX=clang++ cmake -S . -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DDIVVOX_FUZZ=ON -DDIVVOX_GRAPHICS=OFF -DDIVVOX_TESTS=OFF >/dev/null \
    || { echo "fuzz.sh: configuring $build failed (needs clang with libFuzzer: libclang-rt-dev)" >&2; exit 2; }
fi
cmake --build "$build" --target "fuzz_$target" \
  || { echo "fuzz.sh: building fuzz_$target failed" >&2; exit 2; }

corpus="$build/corpus/$target"
crashes="$build/crashes/$target"
mkdir -p "$corpus" "$crashes"

# assimp (a system library, not instrumented) leaks on some malformed files (e.g. a truncated
# ASCII STL): leak reports there are not ours, so the mesh target does not check for leaks.
extra=()
if [[ "$target" == mesh ]]; then
  extra+=(-detect_leaks=0)                                  # per input (libFuzzer)
  export ASAN_OPTIONS="${ASAN_OPTIONS:+$ASAN_OPTIONS:}detect_leaks=0"  # and at exit (LeakSanitizer)
fi

set +e
"$build/tests/fuzz/fuzz_$target" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=4096 \
  -print_final_stats=1 -artifact_prefix="$crashes/" "${extra[@]}" "$@" "$corpus" "tests/fuzz/corpus/$target"
status=$?
set -e
if [[ $status -ne 0 ]]; then
  echo "fuzz.sh: fuzz_$target found a problem (exit $status); inputs in $crashes/" >&2
  exit 1
fi
echo "fuzz.sh: fuzz_$target ran ${seconds}s without a crash"
