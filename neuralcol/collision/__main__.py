"""Command line labeler: ``python -m neuralcol.collision PATH... [--json] [--rest FILE] [--workers N]``.

``neuralcol check`` with label workers: prints the exact self-collision label of every mesh file (see
:mod:`neuralcol.collision.labeler` for the definitions), one line per mesh in the order given, in ``neuralcol
check``'s format (the same JSON keys ``file``, ``collides``, ``pairs``, ``pd``; the same exit status: 0 every mesh
free, 1 some mesh collides, 2 some file unreadable, reported on stderr while the other meshes are still labelled).
Does not import torch.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

import numpy as np

from neuralcol.collision.labeler import ExactLabeler, Label
from neuralcol.collision.pool import LabelPool
from neuralcol.geometry.mesh_files import MeshEntry, expand_paths, failure_reason, read_entry, topology_key
from neuralcol.geometry.source_mesh import SOURCE_SUFFIXES as MESH_SUFFIXES

PROG = "python -m neuralcol.collision"
EXIT_FREE, EXIT_COLLIDES, EXIT_UNREADABLE = 0, 1, 2  # as neuralcol check

DESCRIPTION = (
    "Label triangle meshes for self-collision. A mesh collides iff some pair of non-adjacent triangles "
    "(triangles sharing an edge never count; triangles sharing one vertex count when they meet away from it) "
    "have intersecting interiors: crossings and coplanar overlaps count, touching does not. The verdict is "
    "exact for the coordinates in the file (exact orientation predicates); 'pairs' is the number of such "
    "pairs. 'pd' is the signed penetration depth: > 0 (iff the mesh collides) it is the deepest penetration, "
    "< 0 it is minus the clearance, i.e. how far the mesh is from self-contact, capped at 1% of the rest "
    "mesh's bounding-box diagonal and measured relative to the rest mesh for parts that are already close "
    "there; both are in the units of the mesh coordinates."
)
EPILOG = (
    "Meshes are grouped by topology (identical face lists). Each group is labelled against a rest mesh, "
    "which sets the clearance cap and the rest distances of the clearance (and so the negative PD values): "
    "the --rest mesh if it has the group's topology, otherwise the group's first mesh in the order given. "
    "The verdict and the pair count do not depend on the rest mesh. "
    f"A folder PATH means all its {'/'.join(MESH_SUFFIXES)} files in natural order (2.obj "
    "before 10.obj). Exit status (as neuralcol check): 0 every mesh free, 1 some mesh collides, 2 some PATH or file "
    "could not be read or labelled (reported on stderr, one line each; the other meshes are still labelled)."
)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the command line labeler."""
    parser = argparse.ArgumentParser(prog=PROG, description=DESCRIPTION, epilog=EPILOG)
    parser.add_argument("paths", nargs="+", metavar="PATH",
                        help="mesh files (.obj, .off, .ply, .stl) or folders of mesh files")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object per line with keys file, collides, pairs, pd")
    parser.add_argument("--rest", metavar="FILE", default=None,
                        help="rest mesh for the meshes of its topology (default: the first mesh of each topology)")
    parser.add_argument("--workers", type=int, default=0, metavar="N",
                        help="worker processes for labelling (0 or 1: in this process; default 0)")
    return parser


def label_group(labeler: ExactLabeler, vertices: np.ndarray, workers: int) -> list[Label | BaseException]:
    """Labels of the meshes (B, V, 3) of one topology; a mesh that fails alone gets its exception instead."""
    chunk_size = max(1, min(32, -(-len(vertices) // (4 * max(workers, 1)))))  # ~4 chunks per worker
    with LabelPool(labeler, workers=workers, chunk_size=chunk_size) as pool:
        report = pool.label_report(vertices)  # a failing mesh is retried alone, then reported with its reason
    failed = {f.index: RuntimeError(f.reason) for f in report.failures}
    return [failed[i] if i in failed else Label(bool(c), int(n), float(p), s)
            for i, (c, n, p, s) in enumerate(zip(*report.labels))]


def format_line(name: str, label: Label, as_json: bool, name_width: int = 0, pairs_width: int = 0) -> str:
    """One output line, as ``neuralcol check`` prints it: aligned text, or a JSON object with keys file, collides,
    pairs, pd."""
    if as_json:
        return json.dumps({"file": name, "collides": bool(label.collides), "pairs": int(label.n_pairs),
                           "pd": float(label.pd)})
    return (f"{name:<{name_width}}  {'collides' if label.collides else 'free':<8}  "
            f"pairs={label.n_pairs:<{max(pairs_width, 6)}d}  pd={label.pd:.6g}")


def main(argv: Sequence[str] | None = None, out: TextIO | None = None, err: TextIO | None = None) -> int:
    """Run the command line labeler.

    Args:
        argv: the arguments (default ``sys.argv[1:]``).
        out: stream for the labels (default stdout).
        err: stream for unreadable files and notes (default stderr).

    Returns:
        The exit status: 2 if some mesh could not be read or labelled, else 1 if some mesh collides, else 0.
    """
    out = sys.stdout if out is None else out
    err = sys.stderr if err is None else err
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.workers < 0:
        parser.error(f"--workers {args.workers}: use 0 or more")

    rest = None
    if args.rest is not None:
        try:
            rest = read_entry(MeshEntry(args.rest, Path(args.rest)))
        except Exception as exc:
            reason = failure_reason(args.rest, Path(args.rest), exc)
            print(f"{args.rest}: cannot read the --rest mesh: {reason}", file=err)
            return EXIT_UNREADABLE

    entries, ok = expand_paths(args.paths), True
    groups: dict[tuple, list[int]] = {}  # topology key -> indices into entries
    meshes: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for i, entry in enumerate(entries):
        if entry.error is not None:
            print(f"{entry.name}: {entry.error}", file=err)
            ok = False
            continue
        try:
            meshes[i] = read_entry(entry)
        except Exception as exc:  # MeshFileError or anything trimesh raises
            print(f"{entry.name}: cannot read: {failure_reason(entry.name, entry.path, exc)}", file=err)
            ok = False
            continue
        groups.setdefault(topology_key(*meshes[i]), []).append(i)

    labels: dict[int, Label] = {}
    rest_key = None if rest is None else topology_key(*rest)
    if rest is not None and rest_key not in groups and groups:
        print(f"note: --rest {args.rest} has the topology of none of the meshes; each topology uses its first "
              "mesh as rest mesh", file=err)
    for key, idx in groups.items():
        faces = meshes[idx[0]][1]
        rest_vertices = rest[0] if key == rest_key else meshes[idx[0]][0]
        vertices = np.stack([meshes[i][0] for i in idx])  # (B, V, 3)
        try:
            labeler = ExactLabeler(faces, rest_vertices)
            results = label_group(labeler, vertices, args.workers)
        except Exception as exc:
            results = [exc] * len(idx)
        for i, res in zip(idx, results):
            if isinstance(res, BaseException):
                reason = failure_reason(entries[i].name, entries[i].path, res)
                print(f"{entries[i].name}: cannot label: {reason}", file=err)
                ok = False
            else:
                labels[i] = res

    name_width = max((len(entries[i].name) for i in labels), default=0)
    pairs_width = max((len(str(lb.n_pairs)) for lb in labels.values()), default=0)
    try:
        for i in sorted(labels):
            print(format_line(entries[i].name, labels[i], args.json, name_width, pairs_width), file=out)
        out.flush()
    except BrokenPipeError:  # e.g. piped into `head`: stop quietly
        if out is sys.stdout:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    if not ok:
        return EXIT_UNREADABLE
    return EXIT_COLLIDES if any(lb.collides for lb in labels.values()) else EXIT_FREE


if __name__ == "__main__":
    sys.exit(main())
