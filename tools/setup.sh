#!/usr/bin/env bash
# Installs the Debian packages divvox needs (only the missing ones) and builds it.
# Idempotent: quiet and fast when everything is already there.
#   tools/setup.sh            -> install + configure + build (Release) into build/
#   DIVVOX_NO_BUILD=1 tools/setup.sh -> install only
#   tools/setup.sh --only P...        -> install only the missing ones of packages P (no build);
#                                        tools/bench_report.sh uses it for the optional CGAL/OpenVDB peers
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"

# Packages (DESIGN §6). libgl1-mesa-dri is the software rasterizer; xvfb-run needs xauth; xdotool
# drives the window test's real mouse input; gnuplot-nox
# draws the plots (timings.svg, the benchmark report; without it they are skipped, never fatal);
# calculix-ccx is the finite-element reference of `bench elastic` and its tests (ccx).
packages=(
  build-essential cmake pkg-config ninja-build
  libeigen3-dev libassimp-dev nlohmann-json3-dev libcli11-dev doctest-dev
  libglfw3-dev libimgui-dev libstb-dev libglvnd-dev libegl-dev libegl-mesa0 libgl1-mesa-dri
  xvfb xauth xdotool
  gnuplot-nox
  calculix-ccx
)

only=0
if [[ "${1:-}" == --only ]]; then
  shift
  packages=("$@")
  only=1
fi

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}"
  sudo_cmd=()
  [[ $(id -u) -ne 0 ]] && sudo_cmd=(sudo)
  export DEBIAN_FRONTEND=noninteractive
  "${sudo_cmd[@]}" apt-get update -qq
  "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

[[ "${DIVVOX_NO_BUILD:-0}" == 1 || $only == 1 ]] && exit 0

# Configure once, then incremental builds (output shown only when something fails).
build="${DIVVOX_BUILD_DIR:-$here/build}"
if [[ ! -f "$build/CMakeCache.txt" ]]; then
  cmake -S "$here" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release ${DIVVOX_CMAKE_ARGS:-} >"$build.configure.log" 2>&1 ||
    { cat "$build.configure.log"; exit 1; }
fi
if ! cmake --build "$build" --parallel "$(nproc)" >"$build.build.log" 2>&1; then
  cat "$build.build.log"
  exit 1
fi
