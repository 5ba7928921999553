#!/usr/bin/env bash
# The README's window screenshots (docs/screenshots/), taken under its own Xvfb with xdotool and the
# window's own shift+F12 (the whole window, panel included, into out/window/): the liver on its tray with the scalpel hovering, after two cuts (the
# middle and the left lobe), after the cuts seen from the side, and the panel with Help open.
# Not part of ctest. Look at every image before committing it.
# Usage: tests/cli/window_screenshots.sh DIVVOX OUTDIR
set -u
divvox=$1
out=$(mkdir -p "$2" && cd "$2" && pwd)
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
if [[ -z ${DISPLAY:-} && -z ${WINDOW_SHOTS_IN_XVFB:-} ]]; then
  WINDOW_SHOTS_IN_XVFB=1 exec xvfb-run -a -s "-screen 0 1280x720x24" "$0" "$divvox" "$out"
fi
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
cd "$tmp" || exit 1
"$divvox" --size 1280x720 >"$tmp/win.out" 2>"$tmp/err" &
pid=$!
for _ in $(seq 300); do grep -q "^window: ready" "$tmp/win.out" && break; sleep 0.5; done
sleep 4
# shot NAME: shift+F12, then the PNG it wrote moved to $out/NAME.png (its status-line note fades in 6 s).
shot() {
  local before k
  before=$(ls out/window/*.png 2>/dev/null | wc -l)
  xdotool key shift+F12
  for k in $(seq 40); do (($(ls out/window/*.png 2>/dev/null | wc -l) > before)) && break; sleep 0.25; done
  mv "$(ls -t out/window/*.png | head -1)" "$out/$1.png"
}
# drag X0 Y0 X1 Y1 MOVES
source "$here/window_drag.sh"
xdotool mousemove 860 300
sleep 3
shot liver_hover
drag 740 330 960 350 12
for _ in $(seq 60); do grep -q "^cut: " "$tmp/win.out" && break; sleep 0.5; done
drag 1040 200 1046 320 10
sleep 5
xdotool mousemove 1200 650
sleep 2
shot liver_cut
# Closer (two wheel clicks), then the grab tool pulls the middle cut's lower lip down: the slit opens.
xdotool mousemove 850 500 click 4 sleep 0.5 click 4
sleep 3
xdotool key g
sleep 1
xdotool mousemove 850 372 sleep 1 mousedown 1
for k in $(seq 8); do xdotool mousemove 850 $((372 + 8 * k)); sleep 0.4; done
sleep 3
shot liver_cut_open
xdotool mouseup 1
sleep 1
xdotool key s
xdotool key F1
sleep 6
shot panel
xdotool key shift+Escape
wait $pid
grep "^cut:" "$tmp/win.out"
ls -l "$out"
