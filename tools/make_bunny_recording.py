#!/usr/bin/env python3
"""Writes the blade poses of the default recording (assets/recordings/bunny_cut.jsonl).

Two cuts of the default bunny (y up, about 10 units across):
  1. a vertical blade along z comes down from above at x = 0.7 and stops at y = 4.0, inside the body:
     a partial cut (a slit that ends inside the bunny);
  2. a blade along z sweeps along x through the whole head on a plane sloping down to the front
     (y = 6.8 + 0.55 (x + 2), 29 degrees: steeper than the pieces' friction 0.5 holds): it separates the top
     of the head and the ears from the body; they slide off the stump and land on the tray in front of
     the bunny (contact: sim/contact.h).
The poses are written without state hashes; `divvox replay POSES --no-physics --record OUT` replays
them and writes the final recording with a hash every 60 steps (tools/make_default_recording.sh).
"""
import json
import sys

dt = 1.0 / 60.0
scene = json.load(open("assets/scenes/bunny.json"))
scene["mesh"] = "../meshes/bunny_npm.obj"  # relative to assets/recordings/

lines = [{"format": "divvox-recording", "version": 1, "scene": scene, "dt": dt}]
step = 0

def pose(a, b, cutting):
    global step
    lines.append({"step": step, "blade": [a, b], "cutting": cutting})
    step += 1

# Cut 1: vertical sweep from above, stopping inside the body at y = 4.0 (a partial cut).
y, z = 6.8, 5.0
for i in range(91):
    yy = 11.0 - 7.0 * i / 90
    pose([0.7, yy, -z], [0.7, yy, z], i > 0)
# Lift the blade and move it beside the head.
for i in range(20):
    pose([-7.0, y, -z], [-7.0, y, z], False)
# Cut 2: the sloped sweep through the head: the top of the head comes off, slides and falls.
def cut_height(x):
    return y + 0.55 * (x + 2.0)
pose([-7.0, cut_height(-7.0), -z], [-7.0, cut_height(-7.0), z], False)
for i in range(1, 121):
    x = -7.0 + 14.0 * i / 120
    pose([x, cut_height(x), -z], [x, cut_height(x), z], True)
# Rest: watch the piece slide off and land on the tray. The frames' camera draws back to show the
# tray in front of the bunny, where the head top lands (x about -11 to -5), beside the body. 350
# steps: the slope is only a little steeper than the friction holds, so the top slides slowly and
# reaches the tray ~370 steps after the cut began, lands on an ear and tips over onto the tray by
# ~450 (since the cut faces no longer rest apart, sim/contact.h "Resting offset", friction holds
# them fully; the sweeps that carry every sample with the tissue, issue 29, leave it a slightly
# different face: it slides ~80 steps longer than with the 250 steps this was before).
lines.append({"step": step, "camera": {"target": [-3.0, 2.5, -1.5], "distance": 24.0,
                                       "yaw": 0.4363, "pitch": 0.3491}})
for i in range(350):
    pose([7.0, cut_height(7.0), -z], [7.0, cut_height(7.0), z], False)

# With --grab: then the grab tool pulls the back beside the slit open (a "grab" command per step).
if "--grab" in sys.argv:
    for i in range(90):
        t = i / 89
        lines.append({"step": step, "grab": {"target": [1.0 + 2.5 * t, 6.0 + 1.0 * t, 0.0], "compliance": 1e-6}})
        step += 1
    lines.append({"step": step, "grab": "release"})
    pose([7.0, cut_height(7.0), -z], [7.0, cut_height(7.0), z], False)

paths = [a for a in sys.argv[1:] if not a.startswith("--")]
out = open(paths[0], "w") if paths else sys.stdout
for line in lines:
    out.write(json.dumps(line, separators=(",", ":")) + "\n")
