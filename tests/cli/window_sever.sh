#!/usr/bin/env bash
# A stroke takes a piece off (issue 29), with real mouse input inside an X server (xvfb-run):
# the window at 1280x720 from the default view of the default scene (the liver), a scalpel drag
# across its thin left lobe at the default depth, from below the lobe upwards (the lobe hangs from
# the uncut tissue above until the stroke ends, as a surgeon would cut it); the blade reaches through
# the tissue under the cursor. The --record file replays headless with one more surface component
# than the uncut liver (summary.json "pieces", "strokes"), its hashes matching, and the piece cut off
# lands on the tray: the smallest component of the replay's final.ply reaches down to the tray plane
# (within 2 mm; before the cut the lobe's lowest point is ~0.1 m above it). Screenshots before, right
# after and 8 s after the cut are left in OUTDIR/out/window to look at.
# The seams the tissue's motion leaves between the steps of a stroke are closed when the stroke ends
# (sim/cut.h cut_close_seams): the lobe comes off on release. The scene's anchors hold the top of the
# right lobe and the middle (x < 0.4 mesh units), not the left lobe.
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

source "$repo/tests/cli/window_drag.sh"
start_window --size 1280x720 --record "$out/session.jsonl"
wait_for "^window: ready" 150
wait_step 120  # 2 s simulated: the lobe has settled where the stroke below expects it
xdotool mousemove 1200 700
xdotool key F12  # out/window/divvox_*.png: before the cut
sleep 1
# Across the left lobe, a little in from its tip (window_input.sh's lobe case crosses the tip
# itself), from under the lobe up to above it. At x 1050: since the liver's solver is converged
# (5 x 2, issue 30) its lobe hangs higher, and the strokes at x 1000 and 1040 cut it through to a
# hairline that kept it on (5 of 9 and 0 of 3 runs took it off, before the blade reached three voxels
# past the far side and through the tissue along its line off the tissue; tests/data/liver_hairline_x1040.jsonl
# replays one: docs/cutting.md); at x 1050, 7 of 7.
drag 1050 470 1055 170 16
wait_for "^cut: " 60
xdotool mousemove 1200 700
xdotool key F12  # right after the release
wait_step $(($(sim_step) + 480))  # 8 s simulated: the cut piece falls and settles
xdotool key F12  # the lobe on the tray
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
# Where the piece lies: the final surface's components (binary PLY, metres), the smallest one's lowest
# vertex against the tray (the scene's plane, in mesh units times metres_per_unit).
python3 - "$out/replay/final.ply" "$repo/assets/scenes/liver.json" <<'PY' || fail "the lobe cut off did not land on the tray"
import json, re, struct, sys
scene = json.loads(re.sub(r'^\s*//.*$', '', open(sys.argv[2]).read(), flags=re.M))
tray = scene['planes'][0]['point'][1] * scene['units']['metres_per_unit']
f = open(sys.argv[1], 'rb')
nv = nf = 0
while True:
    line = f.readline().decode().strip()
    if line.startswith('element vertex'): nv = int(line.split()[2])
    if line.startswith('element face'): nf = int(line.split()[2])
    if line == 'end_header': break
v = [struct.unpack('<3f', f.read(12)) for _ in range(nv)]
parent = list(range(nv))
def find(a):
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a
faces = []
for _ in range(nf):
    n = f.read(1)[0]
    t = struct.unpack('<%di' % n, f.read(4 * n))
    f.read(1)  # the face's cut flag
    faces.append(t)
    for b in t[1:]:
        parent[find(t[0])] = find(b)
parts = {}
for t in faces:
    parts.setdefault(find(t[0]), set()).update(t)
piece = min(parts.values(), key=len)
low = min(v[i][1] for i in piece)
print('sever: %d components; the smallest (%d vertices) reaches %.1f mm above the tray' % (len(parts), len(piece), (low - tray) * 1e3))
sys.exit(0 if len(parts) >= 2 and abs(low - tray) < 0.002 else 1)
PY
echo "sever: ok"
