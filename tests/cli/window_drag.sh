# Sourced by the window's xdotool scripts (window_input.sh, window_sever.sh, window_tools.sh,
# window_grab.sh, window_screenshots.sh). They set $divvox and $out and define fail().

# Starts the window with the given arguments (stdout to $out/win.out, stderr to $out/win.err) and
# kills it when the script exits early; sets $pid.
start_window() {
  "$divvox" "$@" >"$out/win.out" 2>"$out/win.err" &
  pid=$!
  trap 'kill $pid 2>/dev/null' EXIT
}

# Waits (up to $2 s) until the window's stdout has a line matching $1.
wait_for() {
  local deadline=$((SECONDS + $2))
  while ! grep -q "$1" "$out/win.out" 2>/dev/null; do
    kill -0 $pid 2>/dev/null || fail "the window exited before printing '$1': $(cat "$out/win.err")"
    ((SECONDS < deadline)) || fail "no '$1' within $2 s"
    sleep 0.5
  done
}

# The simulation's step as the window's recording ($out/session.jsonl, --record) shows it (a line per
# step with commands, a hash line every 60 steps, flushed line by line), and a wait until it reaches
# $1 (up to 120 s): the simulation may run at a fraction of real time under a loaded rasteriser, so
# what must have settled or moved is timed in its steps, not in wall-clock seconds.
sim_step() { grep -o '"step":[0-9]*' "$out/session.jsonl" 2>/dev/null | tail -1 | cut -d: -f2; }
wait_step() {
  local deadline=$((SECONDS + 120))
  while (($(sim_step || echo 0) < $1)); do
    ((SECONDS < deadline)) || fail "the simulation did not reach step $1 within 120 s (at $(sim_step))"
    sleep 0.3
  done
}

# A left drag from ($1,$2) to ($3,$4) in $5 moves, slow enough for a few frames per move on a
# loaded software rasteriser.
drag() {
  xdotool mousemove "$1" "$2"
  sleep 1
  xdotool mousedown 1
  sleep 0.5
  local k
  for ((k = 1; k <= $5; ++k)); do
    xdotool mousemove $(($1 + ($3 - $1) * k / $5)) $(($2 + ($4 - $2) * k / $5))
    sleep 0.4
  done
  sleep 0.5
  xdotool mouseup 1
}
