#!/usr/bin/env bash
# Issue 31, run inside an X server (xvfb-run): SIGTERM or SIGINT ($3: term or int) closes the window
# as shift+Esc does: exit 0, the exit statistics printed. With term, the simulation is paused for a
# few seconds first: the "x real time" figure counts the wall time it ran only (its running seconds
# fall short of the frames' seconds by about the pause).
# Usage: window_signal.sh DIVVOX REPO CASE OUTDIR
set -u
divvox=$1
repo=$2
case=$3
out=$4
mkdir -p "$out"
cd "$out" || exit 1
fail() {
  echo "FAIL (signal $case): $*"
  exit 1
}

"$divvox" "$repo/assets/scenes/bunny.json" --size 1280x720 >"$out/win.out" 2>"$out/win.err" &
pid=$!
trap 'kill -KILL $pid 2>/dev/null' EXIT
deadline=$((SECONDS + 150))
while ! grep -q "^window: ready" "$out/win.out" 2>/dev/null; do
  kill -0 $pid 2>/dev/null || fail "the window exited before it was ready: $(cat "$out/win.err")"
  ((SECONDS < deadline)) || fail "not ready within 150 s"
  sleep 0.5
done
sleep 2
if [[ $case == term ]]; then
  xdotool key space  # pause
  sleep 4
  xdotool key space  # play
  sleep 2
  kill -TERM $pid
  signal=SIGTERM
else
  kill -INT $pid
  signal=SIGINT
fi
for _ in $(seq 60); do kill -0 $pid 2>/dev/null || break; sleep 0.5; done
kill -0 $pid 2>/dev/null && fail "the window did not close on $signal"
wait $pid
code=$?
trap - EXIT
[[ $code -eq 0 ]] || fail "the window exited $code on $signal (want 0): $(cat "$out/win.err")"
grep -q "^window: closing on $signal" "$out/win.out" || fail "no 'window: closing on $signal' line"
line=$(grep "^window: simulation x" "$out/win.out")
[[ -n $line ]] || fail "no statistics line 'window: simulation x... real time' after $signal"
echo "$case: $line"
if [[ $case == term ]]; then
  running=$(sed -n 's/.* simulated in \([0-9.]*\) s running.*/\1/p' <<<"$line")
  frames=$(sed -n 's/^window: [0-9]* frames in \([0-9.]*\) s.*/\1/p' "$out/win.out" | head -1)
  echo "$case: $running s running of $frames s of frames (4 s paused)"
  awk -v r="$running" -v f="$frames" 'BEGIN { exit !(r > 0.5 && r < f - 2.5) }' ||
    fail "running seconds $running not in (0.5, $frames - 2.5): the pause was counted"
fi
echo "$case: ok"
