#!/usr/bin/env bash
# resolve without a run on two topologies no preset was written for: the procedural hands of bench.newuser_hand
# (variants a and b, 150 poses each, written to data/newuser_a and data/newuser_b), as the generic data set
# dataset=meshes; the seed-0 draw and a held-out seed-1 draw each. A finished output is skipped.
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=outputs/anymesh/unseen
mkdir -p "$OUT"
for v in a b; do
  dir=data/newuser_$v
  [ -d "$dir" ] || .venv/bin/python -m bench.newuser_hand "$dir" --variant $v
  common=(--datasets meshes --meshes "$dir")
  [ -f "$OUT/seed0_$v.json" ] || .venv/bin/python -m research.anymesh.realistic_resolve "${common[@]}" \
    --out "$OUT/seed0_$v.json" > "$OUT/seed0_$v.log" 2>&1
  [ -f "$OUT/heldout_$v.json" ] || .venv/bin/python -m research.anymesh.realistic_resolve "${common[@]}" --seed 1 \
    --motions 0 --exclude-from "$OUT/seed0_$v.json" --out "$OUT/heldout_$v.json" > "$OUT/heldout_$v.log" 2>&1
  echo "newuser $v: done"
done
