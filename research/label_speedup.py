"""Full label speed of this checkout against another one, side by side (interleaved rounds, one core each).

    git worktree add /tmp/neuralcol-old <commit>
    python -m research.label_speedup --old /tmp/neuralcol-old [--latent-space .cache/autoencoders/<key>/latent_space.pt]

Each round runs one subprocess per checkout (``OMP_NUM_THREADS=1``), alternating, that labels the same meshes
with ``ExactLabeler.label`` after a warm-up (numba compiled or loaded outside the timing) and reports the mean
ms per mesh and a digest of the labels, so the two checkouts are also checked for equal labels. Meshes: the 71
SCAPE meshes (labeler built on mesh 0, one part), and with ``--latent-space`` the first ``--n-poses`` codes of
U(Z) (seed 1000003, the test set's) decoded by that latent space: the pose workload of the pipeline, labeled
with the latent space's partition. SCAPE is read from ``paths.data_dir`` (``NEURALCOL_DATA``).
Results: median over rounds and the ratio of medians, printed and written to ``--out`` (JSON).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

CHILD = r"""
import hashlib, json, sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
from neuralcol.collision.labeler import ExactLabeler
sets = json.loads(sys.argv[2])
out = {}
for name, spec in sets.items():
    d = np.load(spec)
    lab = ExactLabeler(d["faces"], d["rest"], partition=d["part"] if "part" in d else None, boundary_eps=1e-4)
    v = d["v"]
    lab.label(v[0])
    t0 = time.perf_counter()
    labels = [lab.label(x) for x in v]
    ms = (time.perf_counter() - t0) / len(v) * 1e3
    h = hashlib.sha1()
    for lb in labels:
        h.update(np.asarray([lb.collides, lb.n_pairs], np.int64).tobytes()); h.update(np.asarray(lb.pd_sub).tobytes())
    out[name] = {"ms": ms, "digest": h.hexdigest(), "n": len(v), "colliding": int(sum(lb.collides for lb in labels))}
print(json.dumps(out))
"""


def _scape_npz(tmp: Path) -> Path:
    from bench.context import scape_config
    from neuralcol.pipeline import RunContext

    ds = RunContext(scape_config()).dataset
    v = ds.vertices.numpy().astype(np.float64)
    path = tmp / "scape_meshes.npz"
    np.savez(path, v=v, faces=ds.faces.numpy(), rest=v[0])
    return path


def _poses_npz(tmp: Path, latent_space: Path, n: int) -> Path:
    import torch

    from neuralcol.nn.latent_space import LatentSpace
    from neuralcol.samples.uniform import uniform_codes

    space = LatentSpace.load(latent_space)
    with torch.no_grad():
        v = space.decode(uniform_codes(space, 1000003, 0, n)).double().numpy()
    path = tmp / "decoded_poses.npz"
    np.savez(path, v=v, faces=space.faces.numpy(), rest=space.rest_vertices.numpy(), part=space.partition.numpy())
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--old", type=Path, required=True, help="another neuralcol checkout (its root folder)")
    parser.add_argument("--latent-space", type=Path, default=None, help="latent_space.pt whose U(Z) poses to label")
    parser.add_argument("--n-poses", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--out", type=Path, default=HERE / "label_speedup.json")
    args = parser.parse_args(argv)
    if not (args.old / "neuralcol" / "collision" / "labeler.py").is_file():
        print(f"error: --old {args.old} is not a neuralcol checkout (no neuralcol/collision/labeler.py)",
              file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        return _compare(args, Path(tmp))


def _compare(args, tmp: Path) -> int:
    sets = {"scape_meshes": str(_scape_npz(tmp))}
    if args.latent_space is not None:
        sets["decoded_poses"] = str(_poses_npz(tmp, args.latent_space, args.n_poses))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
    runs: dict[str, list[dict]] = {"old": [], "new": []}
    for r in range(args.rounds):
        for which, root in (("old", args.old.resolve()), ("new", ROOT)):
            res = subprocess.run([sys.executable, "-c", CHILD, str(root), json.dumps(sets)], env=env, cwd=tmp,
                                 capture_output=True, text=True, check=True)
            runs[which].append(json.loads(res.stdout.strip().splitlines()[-1]))
        print(f"round {r + 1}/{args.rounds}: " + ", ".join(
            f"{s}: old {runs['old'][-1][s]['ms']:.2f} ms, new {runs['new'][-1][s]['ms']:.2f} ms" for s in sets),
            flush=True)
    summary = {"old": str(args.old), "rounds": args.rounds, "sets": {}}
    for s in sets:
        old = [x[s]["ms"] for x in runs["old"]]
        new = [x[s]["ms"] for x in runs["new"]]
        same = {x[s]["digest"] for x in runs["old"]} == {x[s]["digest"] for x in runs["new"]}
        summary["sets"][s] = {"old_ms": float(np.median(old)), "new_ms": float(np.median(new)),
                              "speedup": float(np.median(old) / np.median(new)),
                              "speedup_per_round": [o / n for o, n in zip(old, new)],
                              "n": runs["new"][0][s]["n"], "colliding": runs["new"][0][s]["colliding"],
                              "labels_equal": bool(same)}
        print(f"{s}: old {np.median(old):.2f} ms, new {np.median(new):.2f} ms per mesh, speedup "
              f"{np.median(old) / np.median(new):.2f}x, labels equal: {same}")
    args.out.write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
