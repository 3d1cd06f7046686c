"""Render colliding realistic meshes of a finished run before and after the contact repair
(docs/studies/contact_repair.md):

    python -m experiments.render_repair RUN_DIR [OUT_DIR] [N]

Writes ``OUT_DIR/repair_<i>_{in,out}.png`` (default ``RUN_DIR/repair_renders``) for the first N (default 2)
colliding clear realistic meshes the repair frees, penetrating vertices in red, and prints each one's PD, the
iterations and the largest vertex move (fractions of the diagonal). Labels in this process.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from experiments.evaluate_realistic import realistic_config, run_realistic_set
from neuralcol.api import load_run
from neuralcol.data.realistic import clear_mask
from neuralcol.metrics.plots import depth_colors, render_mesh_png
from neuralcol.repair.contact import outward_sign, repair_contacts


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    if not args:
        raise SystemExit(__doc__)
    run_dir = Path(args[0])
    out_dir = Path(args[1]) if len(args) > 1 else run_dir / "repair_renders"
    n_show = int(args[2]) if len(args) > 2 else 2
    out_dir.mkdir(parents=True, exist_ok=True)
    with load_run(run_dir, workers=0, progress=False) as run:
        _, _, _, _, meshes, pd = run_realistic_set(run, realistic_config(run.cfg, []))
        lab = run.labeler
        colliding = np.flatnonzero(clear_mask(pd, lab.eps, 10) & (np.nan_to_num(pd) > 0))
        s = run.repair_settings(True)
        diag = run.diagonal
        sign = outward_sign(run.faces, run.space.rest_vertices.numpy())
        shown = 0
        for i in colliding:
            r = repair_contacts(meshes.vertices[i], run.faces, lab, s.delta * lab.eps, s.smooth_steps, s.max_iter,
                                sign, max_step=s.max_step * diag, max_smooth=s.max_smooth)
            if not r.resolved:
                continue
            moved = np.linalg.norm(r.vertices - meshes.vertices[i], axis=1)
            print(f"mesh {i}: PD {pd[i] / diag:.4f} of the diagonal, {r.iterations} iterations, largest move "
                  f"{moved.max() / diag:.4f} of the diagonal")
            for name, v in (("in", meshes.vertices[i]), ("out", r.vertices)):
                render_mesh_png(out_dir / f"repair_{i}_{name}.png", v, run.faces,
                                depth_colors(lab.vertex_depths(v)), title=f"{name}: PD {lab.label(v).pd:.4f}")
            shown += 1
            if shown == n_show:
                break
        print(f"wrote {2 * shown} images to {out_dir}")


if __name__ == "__main__":
    main()
