#!/usr/bin/env bash
# Smoke test of divvox_peers (CGAL clip, OpenVDB extraction, Bullet soft body) on the shipped bunny: both run and
# write sane reports; a missing mesh -> one line naming the file, exit 2.
# Usage: peers_test.sh DIVVOX_PEERS SOURCE_DIR
set -u
peers=$1
repo=$2
mesh=$repo/assets/meshes/bunny_npm.obj
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
failures=0

fail() {
  echo "FAIL: $*"
  failures=$((failures + 1))
}

# check FILE PYTHON_EXPR...: each expression over the JSON `d` must hold.
check() {
  local file=$1
  shift
  for expr in "$@"; do
    python3 -c "import json, sys; d = json.load(open(sys.argv[1])); sys.exit(0 if ($expr) else 1)" "$file" \
      || fail "$(basename "$file"): $expr"
  done
}

# CGAL clip: both sides closed, a cap and a cut surface, fractions in [0, 1].
if "$peers" clip --mesh "$mesh" --repeats 1 --out "$tmp/out" >"$tmp/clip.out" 2>"$tmp/clip.err"; then
  grep -q "wrote $tmp/out/peers_clip.json" "$tmp/clip.out" || fail "clip: no 'wrote' line"
  check "$tmp/out/peers_clip.json" \
    'd["status"] == "ok"' \
    'd["tool"] == "cgal_clip"' \
    'all(s["closed"] for s in d["sides"]) and len(d["sides"]) == 2' \
    'all(s["cap_triangles"] > 0 and s["triangles"] > 0 for s in d["sides"])' \
    'd["angles"]["cut_surface"]["triangles"] > 0' \
    'd["angles"]["cap"]["triangles"] == sum(s["cap_triangles"] for s in d["sides"])' \
    'all(0 <= a[k] <= 1 for a in d["angles"].values() for k in ("fraction_min_le_10", "fraction_max_ge_160"))' \
    'd["clip_both_ms"] > 0'
  [[ $(wc -l <"$tmp/out/peers_clip.csv") -eq 2 ]] || fail "peers_clip.csv: want a header and one row"
else
  fail "clip exited $?: $(cat "$tmp/clip.err")"
fi

# OpenVDB: a closed surface within a voxel of the input.
if "$peers" vdb --mesh "$mesh" --resolutions 32 --repeats 1 --error-samples 2000 --out "$tmp/out" \
  >"$tmp/vdb.out" 2>"$tmp/vdb.err"; then
  grep -q "wrote $tmp/out/peers_vdb.json" "$tmp/vdb.out" || fail "vdb: no 'wrote' line"
  check "$tmp/out/peers_vdb.json" \
    'd["status"] == "ok"' \
    'd["tool"] == "openvdb"' \
    'len(d["rows"]) == 1 and d["rows"][0]["resolution"] == 32' \
    'd["rows"][0]["error"]["mean"] < 1.0' \
    'd["rows"][0]["boundary_edges"] == 0' \
    'd["rows"][0]["output_triangles"] > 0' \
    'd["rows"][0]["volume"] > 0'
  [[ $(wc -l <"$tmp/out/peers_vdb.csv") -eq 2 ]] || fail "peers_vdb.csv: want a header and one row"
else
  fail "vdb exited $?: $(cat "$tmp/vdb.err")"
fi

# Bullet soft body on the shipped scene's PBD model: both sag (down), times measured, the same links.
if "$peers" bullet --scene "$repo/assets/scenes/bunny.json" --iterations 5 --reference-iterations 10 --seconds 0.1 \
  --out "$tmp/out" >"$tmp/bullet.out" 2>"$tmp/bullet.err"; then
  grep -q "wrote $tmp/out/peers_bullet.json" "$tmp/bullet.out" || fail "bullet: no 'wrote' line"
  check "$tmp/out/peers_bullet.json" \
    'd["status"] == "ok"' \
    'd["tool"] == "bullet_softbody"' \
    'len(d["rows"]) == 1 and d["rows"][0]["iterations"] == 5' \
    'd["rows"][0]["bullet_links"] == d["stretch_constraints"]' \
    'd["rows"][0]["divvox_sag"] > 0 and d["rows"][0]["bullet_sag"] > 0' \
    'd["rows"][0]["divvox_step_ms_p50"] > 0 and d["rows"][0]["bullet_step_ms_p50"] > 0'
  [[ $(wc -l <"$tmp/out/peers_bullet.csv") -eq 2 ]] || fail "peers_bullet.csv: want a header and one row"
else
  fail "bullet exited $?: $(cat "$tmp/bullet.err")"
fi
"$peers" bullet --scene "$tmp/missing.json" --out "$tmp/bad" >/dev/null 2>"$tmp/bad.err"
code=$?
if [[ $code -ne 2 ]] || ! grep -q "missing.json" "$tmp/bad.err"; then
  fail "bullet with a missing scene: exit $code (want 2), stderr: $(cat "$tmp/bad.err")"
fi

# Bad input: a missing mesh -> exit 2, one stderr line naming the file (both subcommands).
for cmd in clip vdb; do
  "$peers" $cmd --mesh "$tmp/missing.obj" --out "$tmp/bad" >/dev/null 2>"$tmp/bad.err"
  code=$?
  if [[ $code -ne 2 ]] || ! grep -q "missing.obj" "$tmp/bad.err" || [[ $(grep -c . "$tmp/bad.err") -ne 1 ]]; then
    fail "$cmd with a missing mesh: exit $code (want 2), stderr: $(cat "$tmp/bad.err")"
  fi
done

if [[ $failures -ne 0 ]]; then
  echo "$failures check(s) failed"
  exit 1
fi
echo "peers smoke: all checks passed"
