#!/usr/bin/env bash
# The interactive window under Xvfb: driven by a recording (--play), it must reach the recording's
# last step with the same final hash as the headless replay, write a screenshot that shows the
# object (5-95 % of the pixels differ from the background), and exit 0. Without a display it must
# exit 2 with the one-line "no display" message. Skips (exit 0) when xvfb-run is missing, unless
# DIVVOX_REQUIRE_GL=1 (tools/test.sh), where that is a failure.
# With xdotool, real mouse input (tests/cli/window_input.sh): scalpel drags across the default
# scene's (the liver's) thick middle and its thin left lobe, and across the bunny's ear, cut (their
# --record files replay headless with voxels_cut > 0); ctrl+z restores the kept state's hash; a
# drag at the panel's edge leaves its width alone; S pressed mid-grab ends the grab and reports no
# cut (window_tools.sh); SIGTERM and SIGINT close the window with its statistics (window_signal.sh).
# Usage: window_test.sh DIVVOX REPO
set -u
divvox=$1
repo=$2
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
failures=0
fail() {
  echo "FAIL: $*"
  failures=$((failures + 1))
}

# No display: exit 2, one line.
DISPLAY= WAYLAND_DISPLAY= "$divvox" "$repo/assets/scenes/bunny.json" >"$tmp/out" 2>"$tmp/err"
code=$?
if [[ $code -ne 2 ]] || ! grep -q "no display" "$tmp/err" || [[ $(grep -c . "$tmp/err") -ne 1 ]]; then
  fail "DISPLAY= divvox -> exit $code (want 2 and one 'no display' line):"
  sed 's/^/    /' "$tmp/err"
fi

if ! command -v xvfb-run >/dev/null 2>&1; then
  if [[ ${DIVVOX_REQUIRE_GL:-} == 1 ]]; then
    fail "xvfb-run not installed, but DIVVOX_REQUIRE_GL=1 (tools/test.sh installs xvfb and xauth)"
  else
    echo "SKIP: xvfb-run not installed (apt-get install xvfb xauth); the window was not started"
  fi
  [[ $failures -eq 0 ]]
  exit $?
fi

rec="$repo/assets/recordings/bunny_cut.jsonl"
# The headless replay's final hash.
"$divvox" replay "$rec" --headless --out "$tmp/replay" >"$tmp/replay.out" 2>"$tmp/replay.err"
want=$(sed -n 's/.*final hash \([0-9a-f]*\).*/\1/p' "$tmp/replay.out" | head -1)
[[ -n $want ]] || fail "headless replay printed no final hash: $(cat "$tmp/replay.out" "$tmp/replay.err")"

# The window, driven by the same recording.
cd "$tmp" || exit 1
timeout 240 xvfb-run -a -s "-screen 0 1280x720x24" "$divvox" --play "$rec" --exit-after-frames 20 \
  --screenshot "$tmp/cut.png" --size 960x540 >"$tmp/win.out" 2>"$tmp/win.err"
code=$?
cat "$tmp/win.out"
if [[ $code -ne 0 ]]; then
  fail "window --play exited $code:"
  sed 's/^/    /' "$tmp/win.err"
fi
got=$(sed -n 's/^final hash \([0-9a-f]*\).*/\1/p' "$tmp/win.out" | head -1)
[[ -n $got && $got == "$want" ]] || fail "window final hash '$got' != headless replay '$want'"
[[ -s "$tmp/cut.png" ]] || fail "no screenshot written"
[[ $(head -c 8 "$tmp/cut.png" | od -An -tx1 | tr -d ' \n') == 89504e470d0a1a0a ]] || fail "screenshot is not a PNG"

# Coverage: decode the PNG independently when python3 is there, else trust the window's own count.
cover=""
if command -v python3 >/dev/null 2>&1; then
  cover=$(python3 - "$tmp/cut.png" <<'PY'
import struct, sys, zlib
data = open(sys.argv[1], "rb").read()
pos, idat, w, h, ctype = 8, b"", 0, 0, 0
while pos < len(data):
    n, kind = struct.unpack(">I4s", data[pos:pos + 8])
    body = data[pos + 8:pos + 8 + n]
    if kind == b"IHDR":
        w, h, depth, ctype = struct.unpack(">IIBB", body[:10])
    elif kind == b"IDAT":
        idat += body
    pos += 12 + n
bpp = {2: 3, 6: 4}[ctype]
raw = zlib.decompress(idat)
stride = w * bpp
prev = bytearray(stride)
covered = 0
bg = raw[1:4]  # the top-left pixel is background
rows = []
for y in range(h):
    f = raw[y * (stride + 1)]
    line = bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
    for i in range(stride):
        a = line[i - bpp] if i >= bpp else 0
        b = prev[i]
        c = prev[i - bpp] if i >= bpp else 0
        if f == 1: line[i] = (line[i] + a) & 255
        elif f == 2: line[i] = (line[i] + b) & 255
        elif f == 3: line[i] = (line[i] + (a + b) // 2) & 255
        elif f == 4:
            p = a + b - c
            pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
            line[i] = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
    if y == 0: bg = line[0:3]
    for x in range(0, stride, bpp):
        if abs(line[x] - bg[0]) + abs(line[x + 1] - bg[1]) + abs(line[x + 2] - bg[2]) > 12: covered += 1
    prev = line
print("%.1f" % (100.0 * covered / (w * h)))
PY
)
else
  cover=$(sed -n 's/.*object coverage \([0-9.]*\) %.*/\1/p' "$tmp/win.out" | head -1)
fi
echo "screenshot coverage: ${cover:-?} %"
if [[ -z $cover ]] || ! awk -v c="$cover" 'BEGIN { exit !(c >= 5 && c <= 95) }'; then
  fail "screenshot coverage '${cover}' % not in [5, 95]"
fi

# Real input (xdotool): each case in its own X server.
if command -v xdotool >/dev/null 2>&1; then
  for case in middle lobe ear undo; do
    timeout 300 xvfb-run -a -s "-screen 0 1280x720x24" bash "$repo/tests/cli/window_input.sh" "$divvox" "$repo" "$case" \
      "$tmp/input_$case" >"$tmp/input_$case.log" 2>&1
    code=$?
    sed 's/^/    /' "$tmp/input_$case.log"
    [[ $code -eq 0 ]] || fail "window input case '$case' (exit $code)"
  done
  # A stroke across the liver's left lobe takes it off (issue 29).
  timeout 300 xvfb-run -a -s "-screen 0 1280x720x24" bash "$repo/tests/cli/window_sever.sh" "$divvox" "$repo" \
    "$tmp/sever" >"$tmp/sever.log" 2>&1
  code=$?
  sed 's/^/    /' "$tmp/sever.log"
  [[ $code -eq 0 ]] || fail "window sever (exit $code)"
  # S pressed in the middle of a grab ends the grab and reports no cut (issue 32).
  timeout 300 xvfb-run -a -s "-screen 0 1280x720x24" bash "$repo/tests/cli/window_tools.sh" "$divvox" "$repo" \
    "$tmp/tools" >"$tmp/tools.log" 2>&1
  code=$?
  sed 's/^/    /' "$tmp/tools.log"
  [[ $code -eq 0 ]] || fail "window tools (exit $code)"
  # SIGTERM and SIGINT close the window with its statistics, paused time left out (issue 31).
  for case in term int; do
    timeout 300 xvfb-run -a -s "-screen 0 1280x720x24" bash "$repo/tests/cli/window_signal.sh" "$divvox" "$repo" "$case" \
      "$tmp/signal_$case" >"$tmp/signal_$case.log" 2>&1
    code=$?
    sed 's/^/    /' "$tmp/signal_$case.log"
    [[ $code -eq 0 ]] || fail "window signal case '$case' (exit $code)"
  done
elif [[ ${DIVVOX_REQUIRE_GL:-} == 1 ]]; then
  fail "xdotool not installed, but DIVVOX_REQUIRE_GL=1 (tools/setup.sh installs it)"
else
  echo "SKIP: xdotool not installed (tools/setup.sh installs it); no real-input checks"
fi

if [[ $failures -ne 0 ]]; then
  echo "$failures window check(s) failed"
  exit 1
fi
echo "window checks passed"
