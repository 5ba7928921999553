# Sourced by the window's xdotool scripts (window_input.sh, window_screenshots.sh).
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
