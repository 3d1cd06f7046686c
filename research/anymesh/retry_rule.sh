#!/usr/bin/env bash
# The deciding runs of the rule "A wider untangle where both repairs fail" (docs/studies/wider_untangle.md): held-out draws
# (seed 1, none of the realistic meshes the seed-0 study resolved) of the four data sets, resolved without a run by
# the default repairs and with handler.repair.retry={anchor: 0.01}. No motions (they do not enter the rule).
# Needs the seed-0 study's output: .venv/bin/python -m research.anymesh.realistic_resolve (outputs/anymesh/).
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=outputs/anymesh
SEED0="$OUT/realistic_resolve.json"
common=(--seed 1 --motions 0 --exclude-from "$SEED0")
[ -f "$OUT/heldout_default.json" ] || .venv/bin/python -m research.anymesh.realistic_resolve "${common[@]}" \
  --out "$OUT/heldout_default.json" > "$OUT/heldout_default.log" 2>&1
[ -f "$OUT/heldout_retry.json" ] || .venv/bin/python -m research.anymesh.realistic_resolve "${common[@]}" \
  --repair retry.anchor=0.01 --out "$OUT/heldout_retry.json" > "$OUT/heldout_retry.log" 2>&1
