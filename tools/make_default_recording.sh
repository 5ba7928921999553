#!/usr/bin/env bash
# Regenerates assets/recordings/bunny_cut.jsonl: poses from make_bunny_recording.py, state hashes
# from a replay with physics (every 60 steps and at the end).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
mkdir -p "$tmp/assets/recordings"
python3 tools/make_bunny_recording.py "assets/recordings/poses.jsonl.tmp"
./build/engine/divvox replay assets/recordings/poses.jsonl.tmp --headless --out "$tmp/out" \
  --record assets/recordings/bunny_cut.jsonl --hash-every 60
rm -f assets/recordings/poses.jsonl.tmp
# The same cuts, then the grab tool pulling the slit open.
python3 tools/make_bunny_recording.py --grab "assets/recordings/poses.jsonl.tmp"
./build/engine/divvox replay assets/recordings/poses.jsonl.tmp --headless --out "$tmp/out2" \
  --record assets/recordings/bunny_grab.jsonl --hash-every 60
rm -f assets/recordings/poses.jsonl.tmp
