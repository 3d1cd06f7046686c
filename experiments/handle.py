"""Resolve self-collisions of your own poses with a trained run:

    python -m experiments.handle RUN_DIR INPUT... [--out DIR] [--objective latent|cartesian] [--vertices FILE]
                                 [--margins M...] [--no-verify]

INPUT: meshes (``.obj``/``.ply``/``.off``) with the data set's topology, or ``.npy`` files of latent codes
(D,) or (N, D). Each input is encoded (meshes), moved by the augmented-Lagrangian handler to the nearest code
the run's detector calls collision-free, decoded and written to ``DIR/<name>_resolved.obj``; PD is measured
with the exact labeler before and after and printed. ``--objective cartesian`` keeps the result close to the
input mesh's vertices (optionally only those listed in ``--vertices``, a text file of vertex indices, e.g.
a hand to keep in place) instead of close to its latent code. Results the exact labeler still finds
self-penetrating are handled again with the larger margins of the run's ``handler.verify_margins`` (or
``--margins``), and the result with the lowest PD is kept; ``--no-verify`` trusts the detector alone. For
meshes, verification includes the contact repair (``handler.repair``: intersecting triangles pushed apart, tried
on the input first; margin ``repair`` in the table); ``--no-repair`` turns it off. A mesh the exact labeler calls
free (PD <= 0) is returned untouched, at the cost of its exact label: not encoded, not handled, written as given (an
``.obj`` input copied byte for byte), margin ``untouched`` in the table.

A folder INPUT stands for its mesh files in name order. ``--sequence``: the meshes are the frames of a motion, in
the order given, resolved so that the corrections vary smoothly in time (``TrainedRun.resolve_sequence``: each
frame warm-started from the previous frame's correction; ``--rate`` the largest change of the correction between
frames, as a multiple of the input's largest frame-to-frame move, default the run's ``handler.sequence.rate``);
the table then gives each frame's verdict before and after, whether it came back untouched (bit for bit: free frames
away from a collision's ramp) and the correction's change from the previous frame.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np
import torch

from neuralcol.api import TrainedRun
from neuralcol.api import load_run as load_trained_run
from neuralcol.errors import UserInputError
from neuralcol.geometry.mesh_io import MESH_SUFFIXES, natural_key, read_mesh, write_mesh
from neuralcol.nn.latent_space import LatentSpace
from neuralcol.utils.cli import report_user_errors


def load_run(run_dir: Path) -> tuple:
    """(config, latent space, detector) of a finished run directory (see :func:`neuralcol.load_run`)."""
    run = load_trained_run(run_dir)
    return run.cfg, run.space, run.detector


def read_inputs(paths: list[Path], space: LatentSpace) -> tuple[list[str], torch.Tensor | None, torch.Tensor | None]:
    """(names, codes (N, D) or None, input vertices (N, V, 3) or None): meshes only give their vertices (no codes:
    ``resolve`` encodes the colliding ones and leaves the free ones untouched); codes, or codes mixed with meshes,
    give codes (the meshes encoded) and no vertices."""
    names, parts = [], []
    n_vertices = space.acap.n_vertices
    for p in paths:
        if p.suffix.lower() == ".npy":
            if not p.is_file():
                raise UserInputError(f"{p}: no such file")
            z = np.load(p)
            z = z[None] if z.ndim == 1 else z
            if z.ndim != 2 or z.shape[1] != space.dim or not np.isfinite(z).all():
                raise UserInputError(f"{p}: holds an array of shape {z.shape}; expected finite latent codes of "
                                     f"size {space.dim}, shape ({space.dim},) or (N, {space.dim})")
            names += [p.stem] if len(z) == 1 else [f"{p.stem}_{i}" for i in range(len(z))]
            parts.append((torch.as_tensor(z, dtype=torch.float32), False))
        elif p.suffix.lower() in MESH_SUFFIXES:
            v, f = read_mesh(p)
            if len(v) != n_vertices or not np.array_equal(f, space.faces.numpy()):
                raise UserInputError(f"{p}: has {len(v)} vertices and {len(f)} faces; this run's data set has "
                                     f"{n_vertices} and {len(space.faces)}, with the same face list")
            names.append(p.stem)
            parts.append((torch.as_tensor(v[None]), True))
        else:
            raise UserInputError(f"{p}: unsupported input '{p.suffix}'; give meshes ({', '.join(MESH_SUFFIXES)}) "
                                 "or .npy latent codes")
    if parts and all(is_mesh for _, is_mesh in parts):
        return names, None, torch.cat([v for v, _ in parts])
    codes = [space.encode(x) if is_mesh else x for x, is_mesh in parts]
    return names, torch.cat(codes).float() if codes else None, None


def write_result(out_path: Path, vertices: np.ndarray, faces: np.ndarray, source: Path | None,
                 untouched: bool) -> None:
    """Write one result mesh; an untouched ``.obj`` input is copied byte for byte (its own values, not rewritten at
    the writer's precision)."""
    if untouched and source is not None and source.suffix.lower() == out_path.suffix.lower():
        shutil.copyfile(source, out_path)
    else:
        write_mesh(out_path, vertices, faces)


def expand_folders(paths: list[Path]) -> list[Path]:
    """Each folder in ``paths`` replaced by its mesh files in natural name order (``2.obj`` before ``10.obj``), the
    order of ``neuralcol resolve``."""
    out = []
    for p in paths:
        if p.is_dir():
            files = sorted((q for q in p.iterdir() if q.is_file() and q.suffix.lower() in MESH_SUFFIXES),
                           key=lambda q: natural_key(q.name))
            if not files:
                raise UserInputError(f"{p}: a folder with no mesh files ({', '.join(MESH_SUFFIXES)})")
            out += files
        else:
            out.append(p)
    return out


def input_kinds(run: TrainedRun, v_user: torch.Tensor | None, pd_input: np.ndarray) -> list[str]:
    """Per input, the kind of its collision (deep, local fold, distant contact; :mod:`neuralcol.handler.
    collision_kinds`), "-" where it is free or a code."""
    from neuralcol.handler.collision_kinds import collision_kind

    if v_user is None:
        return ["-"] * len(pd_input)
    return [collision_kind(run.labeler, v.numpy()) or "-" if pd > 0 else "-" for v, pd in zip(v_user, pd_input)]


def resolve_frames(run: TrainedRun, names: list[str], v_user: torch.Tensor, args: argparse.Namespace,
                   subset, out: Path) -> None:
    """``--sequence``: resolve the frames as a motion, write them and print the per-frame table (``untouched``: the
    frame came back bit for bit, its file copied where it is an ``.obj``)."""
    before = run.label(v_user).collides
    seq = run.resolve_sequence(v_user, rate=args.rate, objective=args.objective, verify=not args.no_verify,
                               margins=args.margins, subset=subset,
                               repair=False if getattr(args, "no_repair", False) else None)
    diag = run.diagonal
    same = (seq.vertices == v_user.numpy()).all(axis=(1, 2))
    print(f"{'frame':<24} {'collides in':>11} {'after':>6}  resolved  untouched  correction change (% of diagonal)")
    for i, name in enumerate(names):
        write_result(out / f"{name}_resolved.obj", seq.vertices[i], run.faces, args.inputs[i], bool(same[i]))
        change = f"{100 * seq.correction_jump[i - 1] / diag:.3f}" if i else "-"
        print(f"{name:<24} {str(bool(before[i])):>11} {str(bool(seq.collides[i])):>6}  {str(bool(seq.resolved[i])):>8}"
              f"  {str(bool(same[i])):>9}  {change}")
    sys.stdout.flush()
    print(f"wrote {len(names)} frames to {out}: {int((~seq.collides).sum())} free, {int(same.sum())} untouched; the "
          f"correction's largest change between frames {100 * seq.correction_jump.max(initial=0) / diag:.3f} % of the "
          f"diagonal, the input's {100 * seq.input_jump.max(initial=0) / diag:.3f} % (ratio {seq.jump_ratio:.2f})",
          file=sys.stderr)


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.handle", description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("inputs", type=Path, nargs="+")
    parser.add_argument("--out", type=Path, default=None, help="output directory (default: RUN_DIR/handled)")
    parser.add_argument("--objective", choices=("latent", "cartesian"), default="latent")
    parser.add_argument("--vertices", type=Path, default=None, help="vertex indices for --objective cartesian")
    parser.add_argument("--margins", type=float, nargs="+", default=None,
                        help="verification margins (default: the run's handler.verify_margins)")
    parser.add_argument("--no-verify", action="store_true",
                        help="trust the detector: no exact check and no re-handling with larger margins")
    parser.add_argument("--no-repair", action="store_true",
                        help="no contact repair of meshes (default: the run's handler.repair)")
    parser.add_argument("--sequence", action="store_true",
                        help="the meshes are frames of a motion, in order: smooth corrections in time")
    parser.add_argument("--rate", type=float, default=None,
                        help="--sequence: the correction's largest change per frame, x the input's largest move")
    args = parser.parse_args(argv)
    args.inputs = expand_folders(args.inputs)
    with load_trained_run(args.run_dir) as run:
        resolve_files(run, args)


def resolve_files(run: TrainedRun, args: argparse.Namespace) -> None:
    """Resolve the input files of ``args`` with ``run``, write the results and print the PD table."""
    names, z_user, v_user = read_inputs(args.inputs, run.space)
    if args.objective == "cartesian" and v_user is None:
        raise UserInputError("--objective cartesian needs mesh inputs (their vertices are the targets)")
    subset = None
    if args.vertices is not None:
        subset = np.loadtxt(args.vertices, dtype=np.int64).reshape(-1)
        if len(subset) == 0 or subset.min() < 0 or subset.max() >= run.n_vertices:
            raise UserInputError(f"{args.vertices}: vertex indices must lie in [0, {run.n_vertices})")
    out = args.out or args.run_dir / "handled"
    out.mkdir(parents=True, exist_ok=True)
    if getattr(args, "sequence", False):
        if v_user is None:
            raise UserInputError("--sequence needs mesh inputs (the frames of a motion), not latent codes")
        resolve_frames(run, names, v_user, args, subset, out)
        return
    res = run.resolve(v_user if v_user is not None else z_user, objective=args.objective,
                      verify=not args.no_verify, margins=args.margins, subset=subset,
                      repair=False if getattr(args, "no_repair", False) else None)
    after = res.vertices.double().cpu().numpy()
    untouched = res.untouched if res.untouched is not None else np.zeros(len(names), bool)
    kinds = input_kinds(run, v_user, res.pd_input)
    print(f"{'input':<24} {'PD input':>10} {'PD decoded':>11} {'PD result':>10}  |Z - Z_user|  margin  "
          "moved (median / max, % of diagonal)  kind of collision (input)")
    for i, name in enumerate(names):
        write_result(out / f"{name}_resolved.obj", after[i], run.faces, args.inputs[i] if v_user is not None else None,
                     bool(untouched[i]))
        step = "-" if untouched[i] else f"{float((res.codes[i] - res.codes_before[i]).norm()):.2f}"
        print(f"{name:<24} {res.pd_input[i]:>10.4g} {res.pd_before[i]:>11.4g} {res.pd_after[i]:>10.4g}  "
              f"{step:>12}  {margin_label(res, i)}  "
              f"{100 * res.displacement_median[i] / res.diagonal:.3f} / "
              f"{100 * res.displacement_max[i] / res.diagonal:.3f}  {kinds[i]}")
    sys.stdout.flush()
    outside = int(run.space.outside_box(res.codes_before).sum())
    if outside:
        print(f"note: {outside} of {len(names)} inputs encode outside the box Z the latent detector was trained in: "
              "its answer there is an extrapolation; the exact PD columns and the contact repair do not depend on it",
              file=sys.stderr)
    print(f"wrote {len(names)} meshes to {out} (PD > 0: self-penetrating, in units of the mesh; margin: the "
          "detector-logit margin of the kept result, repair: the contact repair's mesh, untouched: a free input "
          f"returned as given; {int(untouched.sum())} of {len(names)} untouched)", file=sys.stderr)


def margin_label(res, i: int) -> str:
    """The margin column of input ``i``: ``untouched`` (free input returned as given), ``repair`` or the margin."""
    if res.untouched is not None and res.untouched[i]:
        return "untouched"
    if res.repaired is not None and res.repaired[i]:
        return "repair"
    return f"{res.margin[i]:g}"

if __name__ == "__main__":
    main()
