"""A trained run's ``resolve_sequence`` on SCAPE motions: the shipped model (``neuralcol.pretrained("scape")``) on
there-and-back sweeps ``v_i + t(k) (v_j - v_i)``, ``t(k) = t_peak sin(pi k / (T - 1))``, whose middle frames collide,
beside ``neuralcol.resolve_sequence`` without the run: every frame free (exact), the worst frame's largest vertex move
(fraction of the diagonal), the jump ratio (the correction's largest frame-to-frame change over the input's).

    .venv/bin/python -m research.repair.trained_motion [--frames 24] [--data ../shared/data]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
# (i, j, t_peak): pose pairs whose sweep collides at its peak (the bench's SCAPE extrapolations, seed 3)
SWEEPS = [(23, 31, 1.66), (34, 49, 1.614), (20, 46, 1.793), (7, 37, 1.707)]


def summary(seq, frames: np.ndarray, faces: np.ndarray, diag: float) -> dict:
    import neuralcol

    out = np.asarray(seq.vertices, np.float64)
    after = neuralcol.check(out, faces, rest=frames[0])
    move = np.linalg.norm(out - frames, axis=-1).max(1) / diag
    return {"every_frame_free": bool(not after.collides.any()), "worst_frame_largest_move": float(move.max()),
            "jump_ratio": float(seq.jump_ratio)}


def main(argv: list[str] | None = None) -> None:
    import neuralcol
    from neuralcol.data.datasets import load_mesh_dataset

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    args = ap.parse_args(argv)
    ds = load_mesh_dataset(args.data / "scape")
    verts = ds.vertices.numpy().astype(np.float64)
    faces = ds.faces.numpy().astype(np.int64)
    diag = float(np.linalg.norm(np.ptp(verts[0], axis=0)))
    rows = []
    with neuralcol.pretrained("scape", workers=0) as run:
        for i, j, peak in SWEEPS:
            t = peak * np.sin(np.pi * np.arange(args.frames) / (args.frames - 1))
            frames = verts[i][None] + t[:, None, None] * (verts[j] - verts[i])[None]
            colliding = int(neuralcol.check(frames, faces, rest=frames[0]).collides.sum())
            row = {"sweep": [i, j, peak], "colliding_in": colliding,
                   "with_run": summary(run.resolve_sequence(frames), frames, faces, diag),
                   "without_run": summary(neuralcol.resolve_sequence(frames, faces), frames, faces, diag)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    out = ROOT / "outputs" / "repair" / "trained_motion.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
