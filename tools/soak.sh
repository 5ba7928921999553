#!/usr/bin/env bash
# Soak test (not part of the quick suite): 100 000 steps of random cuts and grabs on the liver
# (liver2_sofa from ../shared/assets), checked every 1 000 steps: closed consistent surface, no
# NaN/Inf, mass conserved, bounded kinetic energy; cutting stops for the last fifth and resident
# memory must then stay flat. Usage: tools/soak.sh [STEPS]
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/tools/setup.sh"
steps="${1:-100000}"
echo "soak: $steps steps"
DIVVOX_STRESS_STEPS="$steps" "$here/build/tests/divvox_engine_tests" -ts=stress -s 2>&1 |
  grep -E "MESSAGE|after|resident|ERROR|FAILED|test cases|assertions|Status"
