"""The ``neuralcol`` command: check and resolve self-intersections of any triangle meshes, trained run or not.

    neuralcol check PATH... [--json]
    neuralcol resolve PATH... --out DIR [--run RUN_DIR] [--sequence] [--json]
    neuralcol train [OVERRIDES...]        # python -m experiments.run OVERRIDES... (a learned handler)

Folders expand to their mesh files (natural order); meshes of different topologies may be mixed (each topology gets
its own exact labeler, built on its first mesh or on ``--rest``). Bad input gets one line on stderr naming the file
and the fix; the other meshes are still processed.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

import numpy as np

from neuralcol.geometry.mesh_files import (
    MeshEntry,
    expand_paths,
    failure_reason,
    read_entry,
    read_source_entry,
    topology_key,
)

EXIT_FREE, EXIT_COLLIDES, EXIT_BAD_INPUT = 0, 1, 2

EXAMPLES = """examples:
  neuralcol check body.obj                        # one line: collides, intersecting pairs, signed depth
  neuralcol check scans/ --json                   # a folder, one JSON object per mesh
  neuralcol resolve pose.obj --out fixed/         # fixed/pose.obj: free, moved as little as the repairs can
  neuralcol resolve frames/ --out fixed/ --sequence   # the files are the frames of one motion, in order
  neuralcol resolve poses/ --out fixed/ --run outputs/runs/scape/active_s0/...   # the learned handler of a run
  neuralcol train dataset=meshes dataset.source.path=my_meshes/     # train one (python -m experiments.run)

exit status: 0 every mesh free (check) / written (resolve), 1 some mesh collides (check) or stays colliding
(resolve), 2 some PATH could not be read or processed (named on stderr; the rest still processed)."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="neuralcol", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EXAMPLES,
        description="Check and resolve self-intersections of triangle meshes. A mesh collides iff two of its "
                    "triangles that share no edge have intersecting interiors (exact, for the coordinates in the "
                    "file; touching does not count). 'pd' is the signed penetration depth in mesh units: > 0 the "
                    "deepest penetration, < 0 minus the clearance (capped at 1 % of the bounding-box diagonal).")
    sub = parser.add_subparsers(dest="command", required=True, metavar="{check,resolve,train}")
    chk = sub.add_parser("check", help="the exact verdict of each mesh", epilog=EXAMPLES,
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    chk.add_argument("paths", nargs="+", metavar="PATH", help="mesh files (.obj, .off, .ply, .stl; triangles or "
                                                                     "polygons) or folders of them")
    chk.add_argument("--json", action="store_true", help="one JSON object per mesh: file, collides, pairs, pd")
    chk.add_argument("--rule", choices=("paper", "cgal"), default="paper",
                     help="paper (default): triangles count when their interiors meet, edge neighbours never; "
                          "cgal: CGAL's self_intersections, pair for pair (closed triangles: touching counts, "
                          "edge neighbours folded flat count, a degenerate face pairs with itself; pd null)")
    chk.add_argument("--verdict", action="store_true", help="the verdict alone, which stops at the first "
                                                            "intersecting pair (pairs and pd not computed: null)")
    chk.add_argument("--pairs", action="store_true", help="also list the intersecting face pairs, as indices of "
                                                          "the file's faces from 0 (JSON: pair_list)")
    chk.add_argument("--rest", metavar="FILE", help="rest mesh of its topology (sets the clearance scale; default: "
                                                    "each topology's first mesh)")
    res = sub.add_parser("resolve", help="write each mesh back free of self-intersections", epilog=EXAMPLES,
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    res.add_argument("paths", nargs="+", metavar="PATH", help="mesh files (.obj, .off, .ply, .stl; triangles or "
                                                                     "polygons) or folders of them")
    res.add_argument("--out", required=True, metavar="DIR", help="output folder: DIR/<input file name>, same format")
    res.add_argument("--run", metavar="RUN_DIR", help="a finished run of the meshes' topology: its learned handler, "
                                                       "then the exact repairs (default: the exact repairs alone)")
    res.add_argument("--sequence", action="store_true", help="the inputs are the frames of one motion in the order "
                                                             "given: corrected smoothly in time")
    res.add_argument("--json", action="store_true", help="one JSON object per mesh: file, out, collides_before, "
                                                         "collides_after, pd_before, pd_after, max_move, "
                                                         "move_to_depth, seconds")
    res.add_argument("--rest", metavar="FILE", help="as for check (sets the repairs' scale)")
    res.add_argument("--overwrite", action="store_true", help="allow --out to be the inputs' own folder: a result "
                                                              "then replaces its input file")
    res.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    trn = sub.add_parser("train", help="train a run (python -m experiments.run OVERRIDES...)", add_help=False)
    trn.add_argument("overrides", nargs=argparse.REMAINDER, help="Hydra overrides, e.g. dataset=meshes "
                                                                  "dataset.source.path=DIR")
    return parser


class Inputs:
    """The meshes named on the command line, read and grouped by topology; unreadable ones reported on ``err``."""

    def __init__(self, paths: Sequence[str], err: TextIO, rest: str | None = None):
        self.entries = expand_paths(paths)
        self.meshes: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.sources: dict[int, object] = {}  # SourceMesh of each file read: written back through it
        self.groups: dict[tuple, list[int]] = {}
        self.ok = True
        self.err = err
        for i, entry in enumerate(self.entries):
            if entry.error is not None:
                self.fail(i, entry.error)
                continue
            try:
                self.sources[i] = read_source_entry(entry)
            except Exception as exc:  # MeshFileError or anything else a broken file raises
                self.fail(i, f"cannot read: {failure_reason(entry.name, entry.path, exc)}")
                continue
            self.meshes[i] = (self.sources[i].vertices, self.sources[i].faces)
            self.groups.setdefault(topology_key(*self.meshes[i]), []).append(i)
        self.rest = None
        if rest is not None:
            try:
                self.rest = read_entry(MeshEntry(rest, Path(rest)))
            except Exception as exc:
                self.fail(None, f"{rest}: cannot read the --rest mesh: {failure_reason(rest, Path(rest), exc)}")

    def reading_note(self, i: int) -> str:
        """What reading changed, said beside the verdict: an STL soup's merged corners."""
        src = self.sources[i]
        if getattr(src, "merged", 0):
            return f"STL soup: {3 * src.n_file_faces} corners merged into {len(src.vertices)} vertices"
        return ""

    def fail(self, i: int | None, message: str) -> None:
        print(message if i is None else f"{self.entries[i].name}: {message}", file=self.err)
        self.ok = False

    def group_arrays(self, idx: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(B, V, 3) vertices, faces and the rest mesh (--rest when it has this topology, else the first mesh)."""
        vertices = np.stack([self.meshes[i][0] for i in idx])
        faces = self.meshes[idx[0]][1]
        if self.rest is not None and topology_key(*self.rest) == topology_key(vertices[0], faces):
            return vertices, faces, self.rest[0]
        return vertices, faces, vertices[0]


def check_main(args, out: TextIO, err: TextIO) -> int:
    from neuralcol.api.anymesh import check

    inputs = Inputs(args.paths, err, args.rest)
    rows: dict[int, tuple[bool, int, float]] = {}
    listed: dict[int, list] = {}  # --pairs: the file's face pairs of each mesh
    for idx in inputs.groups.values():
        vertices, faces, rest = inputs.group_arrays(idx)
        try:
            if args.rule == "cgal":
                from neuralcol.api.anymesh import labeler_for

                lab = labeler_for(faces, rest, clearance=False)
                for k, i in enumerate(idx):
                    tri = lab.closed_rule_pairs(vertices[k])
                    rows[i] = (bool(len(tri)), int(len(tri)), None)
                    if args.pairs:
                        listed[i] = inputs.sources[i].file_pairs(tri, keep_self=True).tolist()
            elif args.verdict:
                from neuralcol.api.anymesh import labeler_for

                lab = labeler_for(faces, rest, clearance=False)
                for k, i in enumerate(idx):
                    rows[i] = (bool(lab.verdict(vertices[k])), None, None)
            else:
                c = check(vertices, faces, rest=rest)
                for k, i in enumerate(idx):
                    rows[i] = (bool(c.collides[k]), int(c.pairs[k]), float(c.pd[k]))
        except Exception as exc:
            for i in idx:
                inputs.fail(i, f"cannot check: {' '.join(str(exc).split())}")
            continue
        if args.pairs and args.rule == "paper":
            from neuralcol.api.anymesh import labeler_for

            lab = labeler_for(faces, rest, clearance=False)
            for k, i in enumerate(idx):
                tri = lab.intersecting_pairs(vertices[k]) if rows[i][0] else np.zeros((0, 2), np.int64)
                listed[i] = inputs.sources[i].file_pairs(tri).tolist()
    width = max((len(inputs.entries[i].name) for i in rows), default=0)
    for i in sorted(rows):
        name, (collides, pairs, pd) = inputs.entries[i].name, rows[i]
        note = inputs.reading_note(i)
        if args.json:
            row = {"file": name, "collides": collides, "pairs": pairs, "pd": pd, "rule": args.rule}
            if note:
                row["note"] = note
            if args.pairs:
                row["pair_list"] = listed[i]
            print(json.dumps(row), file=out)
        else:
            figures = "" if pairs is None else f"  pairs={pairs:<6d}" + ("" if pd is None else f"  pd={pd:.6g}")
            print(f"{name:<{width}}  {'collides' if collides else 'free':<8}{figures}"
                  + (f"  ({note})" if note else ""), file=out)
            if args.pairs and listed[i]:
                print("  face pairs: " + " ".join(f"{a}-{b}" for a, b in listed[i]), file=out)
    if not inputs.ok:
        return EXIT_BAD_INPUT
    return EXIT_COLLIDES if any(r[0] for r in rows.values()) else EXIT_FREE


def _write(path: Path, source, vertices: np.ndarray, untouched: bool, overwrite: bool) -> None:
    """The result as ``path``: the input file (a :class:`~neuralcol.geometry.source_mesh.SourceMesh`) with its
    vertex positions replaced, everything else as it was; an untouched input is copied byte for byte."""
    if untouched and not source.sidecars:
        if not (path.exists() and source.path.resolve() == path.resolve()):
            shutil.copyfile(source.path, path)
        return
    source.write(path, vertices, overwrite=overwrite)


def _resolve_each(vertices: np.ndarray, faces: np.ndarray, rest: np.ndarray, run, progress: bool):
    """Resolve meshes (B, V, 3) of one topology one at a time (one labeler for all of them without a run): the
    results (B, V, 3), PD before and after (B,), untouched (B,) bool and seconds (B,) per mesh."""
    from neuralcol.api.anymesh import labeler_for, repair_batch, resolve
    from neuralcol.repair.meshes import LARGE_FACES
    from neuralcol.utils.progress import progress_bar

    lab = None if run is not None else labeler_for(faces, rest, clearance=False)
    n = len(vertices)
    result = np.empty_like(vertices)
    pd_b, pd_a, seconds = np.empty(n), np.empty(n), np.empty(n)
    untouched = np.zeros(n, bool)
    for k in progress_bar(range(n), desc="resolving", unit="mesh", disable=not progress):
        t0 = time.perf_counter()
        if run is None:
            r = repair_batch(lab, rest, vertices[k:k + 1], faces, None,
                             progress and len(faces) >= LARGE_FACES)  # a large mesh: its exact checks counted
        else:
            r = resolve(vertices[k], faces, run=run)
        result[k] = r.vertices[0].detach().cpu().numpy()
        pd_b[k], pd_a[k] = r.pd_input[0], r.pd_after[0]
        untouched[k] = bool(r.untouched[0]) if r.untouched is not None else False
        seconds[k] = time.perf_counter() - t0
    return result, pd_b, pd_a, untouched, seconds


def resolve_main(args, out: TextIO, err: TextIO) -> int:
    from neuralcol.api.anymesh import check, resolve_sequence
    from neuralcol.repair.cap import move_to_depth

    inputs = Inputs(args.paths, err, args.rest)
    outdir = Path(args.out)
    outdir.mkdir(parents=True, exist_ok=True)
    names = [Path(e.name).name for e in inputs.entries]
    dup = {n for n in names if names.count(n) > 1}
    for i in list(inputs.meshes):
        if names[i] in dup:
            inputs.fail(i, f"another input has the file name {names[i]}; outputs are DIR/<file name>: rename one")
            inputs.meshes.pop(i)
        elif not args.overwrite and (outdir / names[i]).resolve() == inputs.entries[i].path.resolve():
            inputs.fail(i, f"--out {args.out} would overwrite this input with its result: give another folder "
                           "(or --overwrite to replace the inputs)")
            inputs.meshes.pop(i)
    for key in list(inputs.groups):
        inputs.groups[key] = [i for i in inputs.groups[key] if i in inputs.meshes]
        if not inputs.groups[key]:
            inputs.groups.pop(key)
    run = None
    if args.run is not None:
        from neuralcol.api import load_run

        try:
            run = load_run(args.run)
        except Exception as exc:
            print(f"--run {args.run}: {' '.join(str(exc).split())}", file=err)
            return EXIT_BAD_INPUT
    if args.sequence and len(inputs.groups) > 1:
        print(f"--sequence: the {len(inputs.meshes)} frames have {len(inputs.groups)} topologies; the frames of one "
              "motion share their faces: give one motion at a time", file=err)
        return EXIT_BAD_INPUT
    still, progress = False, not args.no_progress
    for idx in inputs.groups.values():
        vertices, faces, rest = inputs.group_arrays(idx)
        t0 = time.perf_counter()
        try:
            if args.sequence:
                result = resolve_sequence(vertices, faces, run=run, rest=None if run else rest,
                                          progress=progress).vertices
                chk0, chk1 = check(vertices, faces, rest=rest), check(result, faces, rest=rest)
                before, after, pd_b, pd_a = chk0.collides, chk1.collides, chk0.pd, chk1.pd
                untouched = np.array([np.array_equal(a, b) for a, b in zip(result, vertices)])
                seconds = np.full(len(idx), (time.perf_counter() - t0) / len(idx))
            else:
                result, pd_b, pd_a, untouched, seconds = _resolve_each(vertices, faces, rest, run, progress)
                before, after = pd_b > 0, ~(pd_a <= 0)
        except Exception as exc:
            for i in idx:
                inputs.fail(i, f"cannot resolve: {' '.join(str(exc).split())}")
            continue
        diag = float(np.linalg.norm(np.ptp(rest, axis=0)))
        lab = None
        for k, i in enumerate(idx):
            target = outdir / names[i]
            src = inputs.sources[i]
            if not untouched[k]:
                stored = src.stored(result[k])  # what the file holds once written (float32 in binary STL, most PLY)
                if not np.array_equal(stored, result[k]):
                    from neuralcol.api.anymesh import labeler_for

                    lab = lab or labeler_for(faces, rest, clearance=False)
                    label = lab.label(stored)  # the verdict on the file as written
                    after[k], pd_a[k], result[k] = label.collides, label.pd, stored
            try:
                _write(target, src, result[k], bool(untouched[k]), args.overwrite)
            except Exception as exc:
                inputs.fail(i, f"cannot write {target}: {' '.join(str(exc).split())}")
                continue
            largest = float(np.linalg.norm(result[k] - vertices[k], axis=1).max())
            move = largest / diag
            ratio = float(move_to_depth(largest, pd_b[k], diag))  # the largest move over the input's depth
            ratio = None if np.isnan(ratio) else ratio
            still |= bool(after[k])
            row = {"file": inputs.entries[i].name, "out": str(target), "collides_before": bool(before[k]),
                   "collides_after": bool(after[k]), "pd_before": float(pd_b[k]), "pd_after": float(pd_a[k]),
                   "max_move": move, "move_to_depth": ratio, "seconds": float(seconds[k])}
            note = inputs.reading_note(i)
            if args.json:
                print(json.dumps({**row, **({"note": note} if note else {})}), file=out)
            else:
                state = "untouched (free)" if untouched[k] else ("STILL COLLIDES" if after[k] else "freed")
                depth = "" if ratio is None else f" ({ratio:.2g}x the input's depth)"
                print(f"{row['file']} -> {target}  {state}  max move {100 * move:.3g} % of the diagonal{depth}"
                      + (f"  ({note})" if note else ""), file=out)
    if not inputs.ok:
        return EXIT_BAD_INPUT
    return EXIT_COLLIDES if still else EXIT_FREE


def main(argv: Sequence[str] | None = None, out: TextIO | None = None, err: TextIO | None = None) -> int:
    """Run the ``neuralcol`` command; returns its exit status."""
    out = sys.stdout if out is None else out
    err = sys.stderr if err is None else err
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["train"]:  # everything after it goes to the Hydra app untouched
        return subprocess.call([sys.executable, "-m", "experiments.run", *argv[1:]])
    args = build_parser().parse_args(argv)
    try:
        return check_main(args, out, err) if args.command == "check" else resolve_main(args, out, err)
    except BrokenPipeError:  # piped into `head`: stop quietly
        return EXIT_FREE


if __name__ == "__main__":
    sys.exit(main())
