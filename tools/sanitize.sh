#!/usr/bin/env bash
# Builds divvox with clang sanitizers and runs the tests under them.
#   tools/sanitize.sh            -> ASan + UBSan build in build-asan/, the whole CTest suite
#   tools/sanitize.sh thread     -> TSan build in build-tsan/, the engine and harness tests (ctest -R '(engine|harness)/')
#   tools/sanitize.sh sim        -> ASan + UBSan with g++ (no extra packages) in build-asan-sim/, the
#                                   sim/ tests: the subset README command 2 (and so CI) runs
# Idempotent: configures once per build folder, then incremental builds.
# Needs clang/clang++ with the sanitizer runtimes (Debian: clang-14, libclang-rt-14-dev).
# Extra CTest arguments may follow the mode, e.g. `tools/sanitize.sh address -R sim/`.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"

mode="${1:-address}"
(($#)) && shift
cc=clang cxx=clang++ engine=ON
build_flags=(-DCMAKE_BUILD_TYPE=RelWithDebInfo)
case "$mode" in
  address | asan)
    build="$here/build-asan"
    sanitize="address;undefined"
    # The whole suite: sim/, engine/ and cli/ tests.
    ctest_filter=()
    graphics=OFF
    ;;
  thread | tsan)
    build="$here/build-tsan"
    sanitize="thread"
    # The engine and harness tests: the task pool behind the PBD loops, the simulation thread + render
    # thread of a headless replay with frames (EGL), record/replay with 1 and 2 workers.
    ctest_filter=(-R '(engine|harness)/')
    graphics=ON
    ;;
  sim)
    build="$here/build-asan-sim"
    sanitize="address;undefined"
    # The simulation core alone (voxelizer, cutting, dual contouring, PBD): the whole suite under
    # ASan does not fit CI's time; the parsers are covered by the fuzzers and `address`.
    # One test is left out: the fresh cut and box drop at 8 fine voxels per simulation voxel takes
    # 11 s in the Release suite and 380-430 s here (-O1 with Eigen's asserts), the long pole of CI's
    # time; its code paths (the same 2 x 2 x 2 contact cells) run here in the tests at 4. Likewise the
    # 24 random sweeps of a hanging bar (157 s here; the same sweep paths run in the other sever tests).
    ctest_filter=(-R '^sim/' -E 'at 8 fine voxels per simulation voxel|severed at any height')
    graphics=OFF
    engine=OFF
    cc=gcc cxx=g++
    # -O1 with asserts on: half the build time of -O2, and the asserts check the invariants too.
    build_flags=(-DCMAKE_BUILD_TYPE=Debug "-DCMAKE_CXX_FLAGS_DEBUG=-O1 -g1")
    ;;
  -h | --help)
    sed -n '2,9p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'
    exit 0
    ;;
  *)
    echo "sanitize: unknown mode '$mode' (use: address | thread)" >&2
    exit 2
    ;;
esac

for c in "$cc" "$cxx"; do
  command -v "$c" >/dev/null 2>&1 ||
    { echo "sanitize: '$c' not found on PATH (install clang and libclang-rt-dev, e.g. apt-get install clang-14 libclang-rt-14-dev)" >&2; exit 2; }
done
command -v ninja >/dev/null 2>&1 || { echo "sanitize: 'ninja' not found on PATH (apt-get install ninja-build)" >&2; exit 2; }

# Sanitizer run-time options, for the tests and for the test discovery doctest_discover_tests runs at
# build time. Callers may add options of their own in front (later options win, so ours are kept).
export ASAN_OPTIONS="${ASAN_OPTIONS:+$ASAN_OPTIONS:}detect_leaks=1:abort_on_error=1"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:+$UBSAN_OPTIONS:}print_stacktrace=1:halt_on_error=1"
# tools/tsan.supp: races inside Mesa's uninstrumented llvmpipe driver (see the file).
export TSAN_OPTIONS="${TSAN_OPTIONS:+$TSAN_OPTIONS:}halt_on_error=1:second_deadlock_stack=1:suppressions=$here/tools/tsan.supp"

# Configure once (a reconfigure happens by itself through Ninja when a CMakeLists.txt changes).
if [[ ! -f "$build/CMakeCache.txt" || ! -f "$build/build.ninja" ]]; then
  echo "sanitize: configuring $build ($sanitize)"
  mkdir -p "$build"
  if ! CC="$cc" CXX="$cxx" cmake -S "$here" -B "$build" -G Ninja \
      "${build_flags[@]}" \
      -DDIVVOX_SANITIZE="$sanitize" \
      -DDIVVOX_ENGINE="$engine" \
      -DDIVVOX_GRAPHICS="$graphics" >"$build/sanitize-configure.log" 2>&1; then
    cat "$build/sanitize-configure.log"
    exit 1
  fi
fi

echo "sanitize: building $build"
if ! cmake --build "$build" --parallel "$(nproc)" >"$build/sanitize-build.log" 2>&1; then
  cat "$build/sanitize-build.log"
  exit 1
fi

echo "sanitize: running tests ($sanitize${ctest_filter[*]:+, ${ctest_filter[*]}})"
cd "$build"
# --timeout is per test; sanitized binaries are several times slower than Release.
# CTest prints its summary ("N% tests passed, ... out of M", the failed tests, total time) at the end.
ctest --output-on-failure --parallel "$(nproc)" --timeout 3000 "${ctest_filter[@]}" "$@"
