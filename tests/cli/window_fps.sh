#!/usr/bin/env bash
# Frame rate of the window while cutting (not part of ctest: timing depends on the machine). Starts
# the window at 1280x720 under its own Xvfb with SCENE (default: the bunny), waits until it is ready,
# then sweeps the scalpel back and forth across the object for SECONDS (default 20) while holding the
# button, closes it and prints its frame statistics: fps p50 / p5 (wall clock), phase times, CPU ms
# per frame by thread kind (independent of other load on the machine), input-to-cut latency in frames.
# Usage: tests/cli/window_fps.sh DIVVOX [SCENE] [SECONDS] [RESOLUTION]
set -u
divvox=$1
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
scene=${2:-$here/assets/scenes/bunny.json}
seconds=${3:-20}
resolution=${4:-}
if [[ -z ${DISPLAY:-} && -z ${WINDOW_FPS_IN_XVFB:-} ]]; then
  WINDOW_FPS_IN_XVFB=1 exec xvfb-run -a -s "-screen 0 1280x720x24" "$0" "$divvox" "$scene" "$seconds" "${resolution:-0}"
fi
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
"$divvox" "$scene" --size 1280x720 >"$tmp/out" 2>"$tmp/err" &
pid=$!
for _ in $(seq 300); do grep -q "^window: ready" "$tmp/out" && break; sleep 0.5; done
sleep 2
xdotool mousemove 700 430
xdotool mousedown 1
end=$((SECONDS + seconds))
x=700
dx=6
while ((SECONDS < end)); do
  x=$((x + dx))
  ((x > 940 || x < 680)) && dx=$((-dx))
  xdotool mousemove $x $((430 + (x - 700) / 10))
  sleep 0.03
done
xdotool mouseup 1
sleep 1
xdotool key shift+Escape
wait $pid
grep -E "^window:|^input to cut" "$tmp/out"
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg), $(nproc) cores"
