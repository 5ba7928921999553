#!/usr/bin/env bash
# Issue 32, run inside an X server (xvfb-run): a grab drag on the default scene (the liver) with S
# pressed in the middle of it. The switch must end the grab (the recording's last grab command is a
# release, sent before the button comes up), start no scalpel stroke while the button is still held
# (no cutting blade command in the recording), and print no "cut:" line; the recording replays
# headless with its hashes matching. Then F1: with Help open the panel's sections fit at 1280x720.
# Usage: window_tools.sh DIVVOX REPO OUTDIR
set -u
divvox=$1
repo=$2
out=$3
mkdir -p "$out"
cd "$out" || exit 1
fail() {
  echo "FAIL (tools): $*"
  exit 1
}

source "$repo/tests/cli/window_drag.sh"
start_window --size 1280x720 --record "$out/session.jsonl"

wait_for "^window: ready" 150
sleep 2
# Grab the liver's middle and pull it up; S halfway; the button released after a few more moves.
xdotool key g
sleep 0.5
xdotool mousemove 850 340
sleep 1
xdotool mousedown 1
sleep 0.5
for k in 1 2 3 4; do
  xdotool mousemove 850 $((340 - 15 * k))
  sleep 0.4
done
xdotool key s
sleep 0.5
for k in 5 6 7; do
  xdotool mousemove $((850 + 20 * (k - 4))) $((340 - 15 * k))
  sleep 0.4
done
xdotool mouseup 1
sleep 2
# Help open (F1): the panel's sections still fit at 1280x720 (issue 32: no clipped last section).
xdotool key F1
sleep 1.5

xdotool key shift+Escape
for _ in $(seq 60); do kill -0 $pid 2>/dev/null || break; sleep 0.5; done
kill -0 $pid 2>/dev/null && fail "the window did not close on shift+Esc"
wait $pid
code=$?
trap - EXIT
[[ $code -eq 0 ]] || fail "the window exited $code: $(cat "$out/win.err")"
if grep -q "^cut: " "$out/win.out"; then
  fail "a grab (ended by S) reported a cut: $(grep '^cut: ' "$out/win.out")"
fi

layout=$(grep "^window: layout panel" "$out/win.out")
echo "tools: $layout"
[[ $layout == *"(fit)"* ]] || fail "the panel's sections (Help open) do not fit at 1280x720: $layout"

# The recording: grab targets, then a release as the last grab command; no cutting blade command.
verdict=$(python3 - "$out/session.jsonl" <<'PY'
import json, sys
targets, last, cutting = 0, None, 0
for line in open(sys.argv[1]):
    d = json.loads(line)
    if "grab" in d:
        last = d["grab"]
        targets += 1 if isinstance(d["grab"], dict) else 0
    if d.get("cutting") is True:
        cutting += 1
print(targets, "release" if last == "release" else "held", cutting)
PY
)
read -r targets last cutting <<<"$verdict"
echo "tools: the recording holds $targets grab targets, then the grab $last; $cutting cutting blade commands"
[[ ${targets:-0} -gt 0 ]] || fail "no grab was recorded (the press missed the liver?)"
[[ $last == release ]] || fail "the grab was never released (still pinned after S and the button's release)"
[[ ${cutting:-1} -eq 0 ]] || fail "the held button started a scalpel stroke after S ($cutting cutting commands)"

"$divvox" replay "$out/session.jsonl" --headless --out "$out/replay" >"$out/replay.out" 2>&1 || fail "replay failed: $(cat "$out/replay.out")"
read -r checked mismatched <<<"$(python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(d['hash_checks']['checked'], d['hash_checks']['mismatched'])" "$out/replay/summary.json")"
echo "tools: headless replay hashes $checked checked, $mismatched differ"
[[ $checked -gt 0 && $mismatched -eq 0 ]] || fail "replay hashes: $checked checked, $mismatched differ"
echo "tools: ok"
