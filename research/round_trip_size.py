"""What limits the round trip: ``python -m research.round_trip_size OUT [hydra overrides ...] --sizes ...``.

For the run's data set, PCA latent spaces (vertex and ACAP-feature basis) of each size in ``--sizes``, fit on the
autoencoder's training meshes, encode and decode the realistic set (the run's, from the cache, or built and labeled
as ``experiments.run`` does), and the exact labeler says how often the round trip keeps the label of the clear
meshes (the ``realistic.round_trip.agreement`` of a run), beside the held-out vertex error. Writes
``OUT/round_trip_size.{json,md}``.

    NEURALCOL_DATA=../shared/data python -m research.round_trip_size docs/results/round_trip_size_cloth \\
        experiment=cpu_proc_cloth --sizes 16 32 48 64
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from hydra import compose, initialize_config_dir

from neuralcol.data.realistic import clear_mask
from neuralcol.metrics.reconstruction import relative_vertex_error
from neuralcol.nn.pca_space import pca_space
from neuralcol.pipeline import RunContext
from neuralcol.samples.realistic import realistic_set
from neuralcol.stages.realistic import round_trip_agreement, round_trip_pd
from neuralcol.utils.threads import pin_threads

CONF = Path(__file__).resolve().parents[1] / "conf"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="directory for round_trip_size.{json,md}")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of experiments.run, e.g. experiment=cpu_scape")
    ap.add_argument("--sizes", type=int, nargs="+", default=[16, 32, 48])
    ap.add_argument("--bases", nargs="+", default=["vertex", "acap"], choices=["vertex", "acap"])
    args = ap.parse_args(argv)
    with initialize_config_dir(str(CONF), version_base="1.3"):
        cfg = compose("config", overrides=list(args.overrides))
    pin_threads(cfg.get("threads", 1))
    ctx = RunContext(cfg)
    ds, feats = ctx.dataset, ctx.features
    stage = ctx.latent_space()
    space, report = stage.space, stage.report
    train_idx, val_idx = np.asarray(report["train_index"]), np.asarray(report["val_index"])
    labeler = ctx.sample_labeler()
    rows = []
    with ctx.pool(labeler) as pool:
        meshes, pd, cached = realistic_set(ds.vertices.numpy(), feats.features.numpy(), feats.acap, val_idx, pool,
                                           cfg.realistic, ctx.samples_dir(labeler), float(labeler.eps))
        clear = clear_mask(pd, float(labeler.eps), float(cfg.realistic.clear_eps))
        truth = np.nan_to_num(pd, nan=0.0) > 0
        v = torch.as_tensor(meshes.vertices, dtype=torch.float64)
        held = ds.vertices[torch.as_tensor(val_idx)].float()
        for basis in args.bases:
            for k in args.sizes:
                if k % space.n_parts:
                    print(f"{basis} {k}: not a multiple of the {space.n_parts} sub-domains (|Z_all| = K (1 + d))")
                    continue
                if k > len(train_idx) - 1:
                    print(f"{basis} {k}: more components than {len(train_idx)} training meshes span; skipped")
                    continue
                sp = pca_space(basis, ds.vertices.numpy(), feats.features.numpy(), train_idx, k,
                               space.rest_vertices.numpy(), space.faces.numpy(), dict(feats.acap.settings),
                               space.n_parts, space.partition.numpy(), 0.0)
                with torch.no_grad():
                    rec = sp.decode(sp.encode(held).float()).float()
                err = float(relative_vertex_error(rec, held).mean.mean())
                _, pd_rt = round_trip_pd(sp, v, pool, desc=f"round trips, {basis} PCA {k}")
                row = {"basis": basis, "size": k, "heldout_error": err,
                       **round_trip_agreement(pd_rt, truth, clear),
                       "n_clear": int((clear & np.isfinite(pd_rt)).sum())}
                rows.append(row)
                print(json.dumps(row), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "round_trip_size.json").write_text(json.dumps(
        {"overrides": list(args.overrides), "dataset": str(cfg.dataset.name), "realistic_from_cache": cached,
         "rows": rows}, indent=2))
    lines = [f"# Round trip against latent size: {cfg.dataset.name}", "",
             f"`python -m research.round_trip_size {args.out} {' '.join(args.overrides)} --sizes "
             f"{' '.join(map(str, args.sizes))}`; {rows[0]['n_clear'] if rows else 0} clear realistic meshes.", "",
             "| basis | \\|Z_all\\| | held-out error | round trip keeps | collisions lost | collisions added |",
             "|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['basis']} | {r['size']} | {r['heldout_error']:.2%} | {r['agreement']:.1%} | "
                     f"{r['collides_lost']:.1%} | {r['collides_added']:.1%} |")
    (args.out / "round_trip_size.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
