#!/usr/bin/env bash
# Frame rate of the window while cutting (not part of ctest: timing depends on the machine). Starts
# the window at 1280x720 under its own Xvfb with SCENE (default: the window's default, the liver on
# its tray; "-" also means the default), waits until it is ready, then sweeps the scalpel back and
# forth across the object's middle for SECONDS (default 20) while holding the button, closes it and
# prints its frame statistics: fps p50 / p5 (wall clock), phase times, CPU ms per frame by thread
# kind (independent of other load on the machine), the X server's CPU per frame, input-to-cut
# latency in frames and ms; last a line
#   fps while cutting: p50 X p5 Y (scene, resolution R)
# Usage: tests/cli/window_fps.sh DIVVOX [SCENE|-] [SECONDS] [RESOLUTION]
#   e.g. tests/cli/window_fps.sh build/engine/divvox - 20 128; ... - 20 256
# Environment passes through (DIVVOX_SNAPSHOT_EVERY_STEP, DIVVOX_GPU_NORMALS, DIVVOX_SCENE_CACHE,
# DIVVOX_MAX_FPS, DIVVOX_SIM_NICE, LP_NUM_THREADS, ...).
set -u
divvox=$1
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
scene=${2:--}
[[ $scene == - ]] && scene=$here/assets/scenes/liver.json
seconds=${3:-20}
resolution=${4:-}
if [[ -z ${DISPLAY:-} && -z ${WINDOW_FPS_IN_XVFB:-} ]]; then
  WINDOW_FPS_IN_XVFB=1 exec xvfb-run -a -s "-screen 0 1280x720x24" "$0" "$divvox" "$scene" "$seconds" "${resolution:-0}"
fi
name=$(basename "$scene" .json)
# The middle of the default view (window coordinates; the view starts right of the 384 px panel).
y0=$([[ $name == bunny ]] && echo 430 || echo 340)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
if [[ -n $resolution && $resolution != 0 ]]; then
  python3 - "$scene" "$resolution" "$tmp/scene.json" <<'PY'
import json, os, re, sys
text = re.sub(r"^\s*//.*$", "", open(sys.argv[1]).read(), flags=re.M)
s = json.loads(text)
s["mesh"] = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(sys.argv[1])), s["mesh"]))
s["resolution"] = int(sys.argv[2])
json.dump(s, open(sys.argv[3], "w"))
PY
  scene=$tmp/scene.json
fi
# The X server's CPU time (every frame shown costs it a copy of the window): utime + stime ticks.
xserver_pid=$(pgrep -n -f "^Xvfb ${DISPLAY:-none}( |$)" || true)
xserver_ticks() { [[ -n $xserver_pid ]] && awk '{print $14 + $15}' "/proc/$xserver_pid/stat" 2>/dev/null || echo 0; }
"$divvox" "$scene" --size 1280x720 >"$tmp/out" 2>"$tmp/err" &
pid=$!
for _ in $(seq 300); do grep -q "^window: ready" "$tmp/out" && break; sleep 0.5; done
sleep 2
xdotool mousemove 720 $y0
xdotool mousedown 1
x_start=$(xserver_ticks)
end=$((SECONDS + seconds))
x=720
dx=6
while ((SECONDS < end)); do
  x=$((x + dx))
  ((x > 960 || x < 700)) && dx=$((-dx))
  xdotool mousemove $x $((y0 + (x - 720) / 10))
  sleep 0.03
done
xdotool mouseup 1
x_end=$(xserver_ticks)
sleep 1
xdotool key shift+Escape
wait $pid
grep -E "^window:|^input to cut" "$tmp/out"
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg), $(nproc) cores"
# The X server's CPU while the scalpel swept, per frame shown (the frames of the whole run, so a rough figure).
frames=$(sed -n 's/^window: \([0-9]*\) frames in.*/\1/p' "$tmp/out" | head -1)
if [[ -n $xserver_pid && -n $frames && $frames -gt 0 ]]; then
  awk -v t=$((x_end - x_start)) -v hz="$(getconf CLK_TCK)" -v f="$frames" -v s="$seconds" \
    'BEGIN {printf "X server: %.1f ms cpu per frame (%.0f ms per second of the sweep)\n", 1000 * t / hz / f, 1000 * t / hz / s}'
fi
fps=$(sed -n 's/.*; fps p50 \([0-9.]*\) p5 \([0-9.]*\)$/p50 \1 p5 \2/p' "$tmp/out" | head -1)
[[ -z $resolution || $resolution == 0 ]] && resolution="the scene's"
echo "fps while cutting: ${fps:-?} ($name, resolution $resolution)"
