#!/usr/bin/env bash
# README command 2: set up (packages + build), then the whole test suite through CTest.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/tools/setup.sh"
cd "$here/build"
ctest --output-on-failure --parallel "$(nproc)" --timeout 600
