#!/usr/bin/env bash
# A stroke takes a piece off (issue 29), with real mouse input inside an X server (xvfb-run):
# the window at 1280x720 from the default view of the default scene (the liver), a scalpel drag
# across its thin left lobe at the default depth; the blade reaches through the tissue under the
# cursor. The --record file replays headless with one more surface component than the uncut liver
# (summary.json "pieces", "strokes"), its hashes matching; a screenshot after the cut is left in
# OUTDIR/out/window to look at.
# The seams the tissue's motion leaves between the steps of a stroke are closed when the stroke ends
# (sim/cut.h cut_close_seams): the lobe comes off on release. It stays where it is: the scene's anchor
# box holds the top of the liver, the lobe's included.
# Usage: xvfb-run -a -s "-screen 0 1280x720x24" bash window_sever.sh DIVVOX REPO OUTDIR
set -u
divvox=$1
repo=$2
out=$3
mkdir -p "$out"
cd "$out" || exit 1
fail() {
  echo "FAIL (sever): $*"
  exit 1
}
command -v xdotool >/dev/null || { echo "skipped: no xdotool"; exit 0; }

"$divvox" --size 1280x720 --record "$out/session.jsonl" >"$out/win.out" 2>"$out/win.err" &
pid=$!
trap 'kill $pid 2>/dev/null' EXIT
wait_for() {
  local deadline=$((SECONDS + $2))
  while ! grep -q "$1" "$out/win.out" 2>/dev/null; do
    kill -0 $pid 2>/dev/null || fail "the window exited before printing '$1': $(cat "$out/win.err")"
    ((SECONDS < deadline)) || fail "no '$1' within $2 s"
    sleep 0.5
  done
}
source "$repo/tests/cli/window_drag.sh"
wait_for "^window: ready" 150
sleep 2
# Across the left lobe, a little in from its tip (window_input.sh's lobe case crosses the tip itself).
drag 1005 140 1035 420 16
wait_for "^cut: " 60
sleep 8  # the cut piece settles
xdotool mousemove 1200 700
xdotool key F12  # out/window/divvox_*.png: the cut, after the lobe came off
sleep 1
xdotool key shift+Escape
for _ in $(seq 60); do kill -0 $pid 2>/dev/null || break; sleep 0.5; done
kill -0 $pid 2>/dev/null && fail "the window did not close on shift+Esc"
wait $pid
trap - EXIT
"$divvox" replay "$out/session.jsonl" --headless --out "$out/replay" >"$out/replay.out" 2>&1 || fail "replay failed: $(cat "$out/replay.out")"
read -r components created mismatched <<<"$(python3 -c "
import json, sys
d = json.load(open(sys.argv[1]))
print(d['pieces']['components'], sum(s['created'] for s in d['strokes']), d['hash_checks']['mismatched'])" "$out/replay/summary.json")"
echo "sever: the replay has $components components, the strokes created $created, $mismatched hashes differ"
[[ $mismatched -eq 0 ]] || fail "replay hashes differ"
[[ $created -ge 1 ]] || fail "the stroke across the lobe took nothing off"
echo "sever: ok"
