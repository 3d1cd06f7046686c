"""How the box Z is drawn against what keeps U(Z) informative:
``python -m research.box_rule OUT [hydra overrides ...]``.

For the run's latent space (the autoencoder or ``autoencoder=pca``, trained or taken from the cache) and its PCA
references, the paper's box (per-entry min/max of the training meshes' codes) is shrunk or widened by a fraction
of each side (``--margins``); for each box it labels ``--n`` codes of U(Z) and reports the share that collides and
the share of the held-out meshes' codes that fall outside the box. Writes ``OUT/box_rule.{json,md}``.

    NEURALCOL_DATA=../shared/data python -m research.box_rule docs/results/box_rule_scape experiment=cpu_scape
"""

from __future__ import annotations

import argparse
import json
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch
from hydra import compose, initialize_config_dir

from neuralcol.pipeline import RunContext
from neuralcol.stages.box_check import probe_share
from neuralcol.utils.threads import pin_threads

CONF = Path(__file__).resolve().parents[1] / "conf"


@contextmanager
def widened(space, margin: float):
    """``space`` with its box widened by ``margin`` of each side on both ends (negative: shrunk), restored after."""
    lo, hi = space.box_lo.clone(), space.box_hi.clone()
    side = hi - lo
    space.box_lo.copy_(lo - margin * side)
    space.box_hi.copy_(hi + margin * side)
    try:
        yield space
    finally:
        space.box_lo.copy_(lo)
        space.box_hi.copy_(hi)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="directory for box_rule.{json,md}")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of experiments.run, e.g. experiment=cpu_scape")
    ap.add_argument("--margins", type=float, nargs="+", default=[-0.25, 0.0, 0.25, 0.5])
    ap.add_argument("--n", type=int, default=256, help="U(Z) codes labeled per box")
    args = ap.parse_args(argv)
    with initialize_config_dir(str(CONF), version_base="1.3"):
        cfg = compose("config", overrides=list(args.overrides))
    pin_threads(cfg.get("threads", 1))
    ctx = RunContext(cfg)
    stage = ctx.latent_space()
    spaces = {"run": stage.space, **ctx.references[0]}
    val = np.asarray(stage.report["val_index"])
    held = ctx.dataset.vertices[torch.as_tensor(val)]
    rows = []
    with ctx.pool(ctx.sample_labeler()) as pool:
        for name, space in spaces.items():
            z_held = space.encode(held)
            for m in args.margins:
                with widened(space, m) as box:
                    probe = probe_share(box, pool, args.n, int(cfg.box_check.seed), desc=f"{name}, margin {m:g}")
                    outside = float(box.outside_box(z_held).float().mean())
                rows.append({"space": name, "margin": m, "collision_share": probe["collision_share"],
                             "n_labeled": probe["n_labeled"], "heldout_outside": outside})
                print(json.dumps(rows[-1]), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    doc = {"overrides": list(args.overrides), "kind": stage.report.get("kind", "bilevel"), "rows": rows}
    (args.out / "box_rule.json").write_text(json.dumps(doc, indent=2))
    lines = ["| space | margin | U(Z) collides | held-out codes outside |", "|---|---:|---:|---:|"]
    lines += [f"| {r['space']} | {r['margin']:+.2f} | {r['collision_share']:.1%} | {r['heldout_outside']:.0%} |"
              for r in rows]
    (args.out / "box_rule.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
