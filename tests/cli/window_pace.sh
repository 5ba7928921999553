#!/usr/bin/env bash
# Issue 31's scripted window run (a benchmark, not part of ctest: timing depends on the machine): the
# default scene (the liver) at 1280x720 under its own Xvfb, three scalpel strokes meant to take
# pieces off (across the left lobe from under it upwards: its tip, then further in, then where
# window_sever.sh takes the lobe off; the two earlier vertical strokes through the thick right lobe
# took nothing off), 4 s after each, then shift+Esc. The strokes are timed in wall-clock time: under
# load (the simulation slower than real time) they cut differently. Prints the window's exit statistics — fps p50 / p5, the
# frames that showed a new snapshot, the simulation's pace overall and per second of running (min,
# p1, p50, the seconds under x0.995), input-to-cut latency — and, from the --record file replayed
# headless, the components each stroke created (summary.json "strokes") and whether its hashes match.
# Usage: tests/cli/window_pace.sh DIVVOX [OUTDIR]   (OUTDIR keeps the recording and screenshots)
set -u
divvox=$(realpath "$1")
out=${2:-}
if [[ -z ${DISPLAY:-} && -z ${WINDOW_PACE_IN_XVFB:-} ]]; then
  WINDOW_PACE_IN_XVFB=1 exec xvfb-run -a -s "-screen 0 1280x720x24" "$0" "$divvox" "$out"
fi
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
# Without OUTDIR a temporary folder, removed at the end and on failure (start_window's trap only
# kills the window).
keep=1
if [[ -z $out ]]; then
  out=$(mktemp -d)
  keep=0
fi
mkdir -p "$out"
cd "$out" || exit 1
fail() {
  echo "FAIL (pace): $*"
  [[ $keep -eq 1 ]] || rm -rf "$out"
  exit 1
}
source "$here/tests/cli/window_drag.sh"
start_window --size 1280x720 --record "$out/session.jsonl"
wait_for "^window: ready" 150
wait_step 120  # 2 s simulated: the liver has settled where the strokes expect it
# Screen coordinates of the default view (the view starts right of the 384 px panel).
# WINDOW_PACE_STROKES="X0 Y0 X1 Y1;..." replaces the strokes (for choosing them).
IFS=';' read -r -a strokes <<<"${WINDOW_PACE_STROKES:-1050 470 1055 170;1025 470 1030 170;1000 470 1005 170}"
for stroke in "${strokes[@]}"; do
  drag $stroke 16
  wait_step $(($(sim_step) + 240))  # 4 s simulated
  xdotool mousemove 1200 700 key F12  # out/window/divvox_*.png after each stroke
  sleep 1
done
xdotool key shift+Escape
for _ in $(seq 120); do kill -0 $pid 2>/dev/null || break; sleep 0.5; done
wait $pid
trap - EXIT
grep -E "^window:|^input to cut" "$out/win.out"
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg), $(nproc) cores"
"$divvox" replay "$out/session.jsonl" --headless --out "$out/replay" >"$out/replay.out" 2>&1 || fail "replay failed: $(tail -2 "$out/replay.out")"
python3 - "$out/replay/summary.json" <<'PY'
import json, sys
d = json.load(open(sys.argv[1]))
created = [s['created'] for s in d['strokes']]
print('strokes: %d, components created by each: %s, components at the end: %d, hashes: %d checked, %d differ'
      % (len(created), created, d['pieces']['components'], d['hash_checks']['checked'], d['hash_checks']['mismatched']))
PY
[[ $keep -eq 1 ]] || rm -rf "$out"
