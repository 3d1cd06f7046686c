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
``--margins``), and the result with the lowest PD is kept; ``--no-verify`` trusts the detector alone.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from neuralcol.collision.backends import build_labeler
from neuralcol.errors import UserInputError
from neuralcol.geometry.mesh_io import MESH_SUFFIXES, read_mesh, write_mesh
from neuralcol.handling.objectives import CartesianObjective, LatentObjective
from neuralcol.nn.latent_space import LatentSpace
from neuralcol.stages.detector import load_detector
from neuralcol.stages.handling import alm_settings, handle_codes, verified_escalation
from neuralcol.utils.cli import report_user_errors


def load_run(run_dir: Path):
    """(config, latent space, detector) of a finished run directory."""
    cfg_path, det_path, metrics_path = run_dir / ".hydra" / "config.yaml", run_dir / "detector.pt", \
        run_dir / "metrics.json"
    for p in (cfg_path, det_path, metrics_path):
        if not p.is_file():
            raise UserInputError(f"{p}: missing; RUN_DIR must be the directory of a finished "
                                 "`python -m experiments.run` (it holds .hydra/, detector.pt and metrics.json)")
    cfg = OmegaConf.load(cfg_path)
    key = json.loads(metrics_path.read_text())["autoencoder"].get("cache_key")
    space_path = Path(cfg.paths.cache_dir) / "autoencoders" / str(key) / "latent_space.pt"
    if key is None or not space_path.is_file():
        raise UserInputError(f"{space_path}: the run's latent space is not in the cache (paths.cache_dir="
                             f"{cfg.paths.cache_dir}); run the same command again to rebuild it")
    net, _ = load_detector(det_path)
    return cfg, LatentSpace.load(space_path), net


def read_inputs(paths: list[Path], space: LatentSpace) -> tuple[list[str], torch.Tensor, torch.Tensor | None]:
    """(names, codes (N, D), input vertices (N, V, 3) or None when the inputs are codes)."""
    names, codes, verts = [], [], []
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
            codes.append(torch.as_tensor(z, dtype=torch.float32))
        elif p.suffix.lower() in MESH_SUFFIXES:
            v, f = read_mesh(p)
            if len(v) != n_vertices or not np.array_equal(f, space.faces.numpy()):
                raise UserInputError(f"{p}: has {len(v)} vertices and {len(f)} faces; this run's data set has "
                                     f"{n_vertices} and {len(space.faces)}, with the same face list")
            names.append(p.stem)
            verts.append(torch.as_tensor(v[None]))
            codes.append(space.encode(torch.as_tensor(v[None])))
        else:
            raise UserInputError(f"{p}: unsupported input '{p.suffix}'; give meshes ({', '.join(MESH_SUFFIXES)}) "
                                 "or .npy latent codes")
    mesh_inputs = verts and len(verts) == len(paths)
    return names, torch.cat(codes).float(), torch.cat(verts) if mesh_inputs else None


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
    args = parser.parse_args(argv)
    cfg, space, net = load_run(args.run_dir)
    names, z_user, v_user = read_inputs(args.inputs, space)
    if args.objective == "cartesian":
        if v_user is None:
            raise UserInputError("--objective cartesian needs mesh inputs (their vertices are the targets)")
        subset = None
        if args.vertices is not None:
            subset = torch.as_tensor(np.loadtxt(args.vertices, dtype=np.int64).reshape(-1))
            if len(subset) == 0 or subset.min() < 0 or subset.max() >= space.acap.n_vertices:
                raise UserInputError(f"{args.vertices}: vertex indices must lie in [0, {space.acap.n_vertices})")
        objective = CartesianObjective(space, v_user.float(), vertices=subset)
    else:
        objective = LatentObjective(z_user)
    settings = alm_settings(cfg.handler.alm)
    margins = [] if args.no_verify else \
        [float(m) for m in (args.margins or OmegaConf.select(cfg, "handler.verify_margins", default=[]))]
    faces = space.faces.numpy()
    labeler = build_labeler(cfg.labeling, faces, space.rest_vertices.numpy(), partition=space.partition.numpy())

    def handle(rows: np.ndarray, margin: float):
        idx_map = torch.as_tensor(rows)
        return handle_codes(net, z_user[idx_map], space.box_lo, space.box_hi, replace(settings, margin=margin),
                            objective=lambda z, idx: objective(z, idx_map[idx]), batch_size=int(cfg.handler.batch_size))

    def label(z: torch.Tensor) -> np.ndarray:
        with torch.no_grad():
            verts = space.decode(z).double().numpy()
        return np.array([labeler.label(v).pd for v in verts])

    res = handle(np.arange(len(z_user)), settings.margin)
    pd_after = np.full(len(z_user), np.nan)
    pd_after[res.finite.numpy()] = label(res.z[res.finite])
    z, stage = res.z, np.zeros(len(z_user), dtype=np.int64)
    if margins:
        z, pd_after, stage, _ = verified_escalation(handle, label, z_user, z, pd_after, margins)
    out = args.out or args.run_dir / "handled"
    out.mkdir(parents=True, exist_ok=True)
    with torch.no_grad():
        before = space.decode(z_user).double().numpy()
        after = space.decode(z).double().numpy()
    print(f"{'input':<24} {'PD input':>10} {'PD decoded':>11} {'PD result':>10}  |Z - Z_user|  margin")
    used = [settings.margin] + margins
    for i, name in enumerate(names):
        pd_in = labeler.label(v_user[i].numpy()).pd if v_user is not None else float("nan")
        pd_b = labeler.label(before[i]).pd
        write_mesh(out / f"{name}_resolved.obj", after[i], faces)
        print(f"{name:<24} {pd_in:>10.4g} {pd_b:>11.4g} {pd_after[i]:>10.4g}  "
              f"{float((z[i] - z_user[i]).norm()):>12.2f}  {used[stage[i]]:g}")
    sys.stdout.flush()
    print(f"wrote {len(names)} meshes to {out} (PD > 0: self-penetrating, in units of the mesh; margin: the "
          "detector-logit margin of the kept result)", file=sys.stderr)


if __name__ == "__main__":
    main()
