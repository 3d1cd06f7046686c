#!/bin/bash
cd /work/main
for spec in cloth_def_s0:60:140 scape_def_s0:40:120 anny_def_s0:0:40 ../issue41/item4/makerun4_fresh:0:60; do
  IFS=: read n a b <<< "$spec"
  for tree in /work/wt_before /work/main; do
    echo "== $tree $n $a:$b"
    NEURALCOL_DATA=/work/shared/data PYTHONPATH=$tree /work/main/.venv/bin/python $tree/research/issue43/untangle_probe.py outputs/issue41/$n $a:$b --untangle-only
  done
done
echo DONE
