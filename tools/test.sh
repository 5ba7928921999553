#!/usr/bin/env bash
# README command 2: set up (packages + build), then the whole test suite through CTest, then the
# simulation core's tests again under AddressSanitizer + UndefinedBehaviorSanitizer (g++, in
# build-asan-sim/): the subset of `tools/sanitize.sh` that fits CI's time.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/tools/setup.sh"
# The set-up above installed Mesa's EGL and Xvfb: the EGL, frame and window tests must run here, and
# fail rather than skip when GL or a display cannot be had.
export DIVVOX_REQUIRE_GL=1
# It also installed CalculiX: the tests against it must run here, and fail rather than skip without ccx.
export DIVVOX_REQUIRE_CCX=1
(cd "$here/build" && ctest --output-on-failure --parallel "$(nproc)" --timeout 600)
"$here/tools/sanitize.sh" sim
