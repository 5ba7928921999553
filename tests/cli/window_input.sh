#!/usr/bin/env bash
# One real-input case of the window test, run inside an X server (xvfb-run): starts the window at
# 1280x720, drives it with xdotool from the default view, checks what it printed.
#   middle: a scalpel drag across the default scene's (the liver's) thick middle; lobe: across the
#           tip of its thin left lobe (far from the bounding box's faces, a tissue ~1 unit thick);
#           ear: across the bunny's right ear (assets/scenes/bunny.json given explicitly). With
#           --record; the recording must replay headless with voxels_cut > 0 and its hashes matching.
#   undo:   a cut on the default scene, then ctrl+z: the restored state's hash equals the hash kept
#           before the cut; ctrl+shift+z redoes it (the state after the cut, its hash intact); then a
#           drag starting on the panel's edge: the panel keeps its width.
# Usage: window_input.sh DIVVOX REPO CASE OUTDIR
set -u
divvox=$1
repo=$2
case=$3
out=$4
mkdir -p "$out"
cd "$out" || exit 1
fail() {
  echo "FAIL ($case): $*"
  exit 1
}

record=()
[[ $case != undo ]] && record=(--record "$out/session.jsonl")
scene=()  # the window's default scene (the liver), except for the bunny's ear
[[ $case == ear ]] && scene=("$repo/assets/scenes/bunny.json")
source "$repo/tests/cli/window_drag.sh"
start_window "${scene[@]}" --size 1280x720 "${record[@]}"

wait_for "^window: ready" 150
panel=$(sed -n 's/^window: ready.*panel \([0-9]*\) px.*/\1/p' "$out/win.out" | head -1)
sleep 2
grep -q "^window: ready.*$([[ $case == ear ]] && echo bunny || echo liver).json" "$out/win.out" || fail "wrong scene: $(head -1 "$out/win.out")"
# Window coordinates of the default view at 1280x720 (panel on the left): the liver's middle, its
# left lobe's tip (a drag across it, top to bottom), the bunny's ear.
case $case in
  middle) drag 740 330 960 350 12 ;;
  lobe) drag 1040 200 1046 320 10 ;;
  ear) drag 745 190 830 212 10 ;;
  undo) drag 740 330 960 350 12 ;;
esac
wait_for "^cut: " 60
cut=$(sed -n 's/^cut: \([0-9]*\) voxels.*/\1/p' "$out/win.out" | head -1)
echo "$case: the window says cut $cut voxels"
[[ ${cut:-0} -gt 0 ]] || fail "the drag cut nothing"

if [[ $case == undo ]]; then
  kept=$(sed -n 's/^undo: kept step \([0-9]*\) (hash \([0-9a-f]*\)).*/\1 \2/p' "$out/win.out" | tail -1)
  [[ -n $kept ]] || fail "no state was kept at the press"
  xdotool key ctrl+z
  wait_for "^undo: back to" 30
  line=$(grep "^undo: back to" "$out/win.out" | head -1)
  echo "$line"
  step=$(sed -n 's/^undo: back to step \([0-9]*\) (hash \([0-9a-f]*\), kept \([0-9a-f]*\)).*/\1 \2 \3/p' <<<"$line")
  read -r s_step s_hash s_kept <<<"$step"
  [[ "$s_step $s_hash" == "$kept" ]] || fail "undo restored step/hash '$s_step $s_hash', kept '$kept'"
  [[ $s_hash == "$s_kept" ]] || fail "restored hash $s_hash != kept $s_kept"
  # Redo: back to the state after the cut (moved onto the redo stack by the undo), its hash intact.
  xdotool key ctrl+shift+z
  wait_for "^redo: back to" 30
  line=$(grep "^redo: back to" "$out/win.out" | head -1)
  echo "$line"
  read -r r_hash r_kept <<<"$(sed -n 's/^redo: back to step [0-9]* (hash \([0-9a-f]*\), kept \([0-9a-f]*\)).*/\1 \2/p' <<<"$line")"
  [[ -n $r_hash && $r_hash == "$r_kept" ]] || fail "redo restored hash '$r_hash' != kept '$r_kept'"
  # A drag starting on the panel's right edge must not resize it.
  drag $((panel - 1)) 300 900 320 6
  sleep 1
fi

xdotool key shift+Escape
for _ in $(seq 60); do kill -0 $pid 2>/dev/null || break; sleep 0.5; done
kill -0 $pid 2>/dev/null && fail "the window did not close on shift+Esc"
wait $pid
code=$?
trap - EXIT
[[ $code -eq 0 ]] || fail "the window exited $code: $(cat "$out/win.err")"
grep "^window:" "$out/win.out"
drawn=$(sed -n 's/^window: layout panel [0-9]* px (drawn \([0-9]*\) px).*/\1/p' "$out/win.out")
[[ -n $drawn && $drawn == "$panel" ]] || fail "the panel is $drawn px wide at the end, $panel at the start"

if [[ $case != undo ]]; then
  "$divvox" replay "$out/session.jsonl" --headless --out "$out/replay" >"$out/replay.out" 2>&1 || fail "replay failed: $(cat "$out/replay.out")"
  voxels=$(python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(d['cut']['voxels_cut'], d['hash_checks']['checked'], d['hash_checks']['mismatched'])" "$out/replay/summary.json")
  read -r v checked mismatched <<<"$voxels"
  echo "$case: headless replay voxels_cut $v, hashes $checked checked, $mismatched differ"
  [[ $v -gt 0 ]] || fail "the recording replays with voxels_cut 0"
  [[ $checked -gt 0 && $mismatched -eq 0 ]] || fail "replay hashes: $checked checked, $mismatched differ"
fi
echo "$case: ok"
