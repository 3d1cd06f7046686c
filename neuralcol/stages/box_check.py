"""Stage: is the box Z worth sampling?

The detector learns from codes of ``U(Z)`` and is judged on them. When (nearly) every code of the box decodes to a
self-intersecting mesh, or (nearly) none does, a detector that always answers the majority class is right, the
handler has nowhere to go, and every later number measures the latent space, not the method: a simulated skirt put
100 % of its 20 000 test codes in the colliding class and the run printed accuracy 1.000. So each run labels a small
probe of ``U(Z)`` right after the latent space (and, beside it, of its PCA references' boxes), reports the share
that collides, and stops with one line when the minority class is below ``box_check.min_class_share``.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from neuralcol.errors import UserInputError
from neuralcol.samples.oracle import LatentOracle


class DegenerateBoxError(UserInputError):
    """U(Z) is (nearly) all one class; the message names the share, the setting and what to change."""


def probe_share(space, pool, n: int, seed: int, desc: str = "probing the box") -> dict:
    """Label ``n`` codes of ``U(Z)`` of ``space`` through ``pool`` (its labeler must use ``space``'s sub-domains).

    Returns:
        ``{"n", "n_labeled", "collision_share", "seconds"}``; the share is over the labeled codes (None if none).
    """
    t0 = time.perf_counter()
    z = space.sample(int(n), torch.Generator(device=space.box_lo.device).manual_seed(int(seed)))
    lab = LatentOracle(space, pool)(z, desc=desc).without_failures()
    share = float(np.mean(lab.collides)) if len(lab.collides) else None
    return {"n": int(n), "n_labeled": int(len(lab.collides)), "collision_share": share,
            "seconds": time.perf_counter() - t0}


def degenerate(share: float | None, min_class_share: float) -> bool:
    """The minority class of U(Z) is rarer than ``min_class_share`` (None: nothing labeled, not judged)."""
    return share is not None and min(share, 1.0 - share) < float(min_class_share)


def check_box(probe: dict, min_class_share: float, dataset: str, references: dict | None = None) -> None:
    """Raise :class:`DegenerateBoxError` when the probe's minority class is below ``min_class_share``.

    Args:
        probe: :func:`probe_share`'s result for the run's latent space.
        min_class_share: ``box_check.min_class_share``.
        dataset: the data set's name (for the message).
        references: ``{name: probe}`` of the PCA references' boxes, quoted in the message as the alternatives.
    """
    share = probe["collision_share"]
    if not degenerate(share, min_class_share):
        return
    majority = "self-intersecting" if share >= 0.5 else "collision-free"
    alts = ", ".join(f"{name} {p['collision_share']:.0%}" for name, p in (references or {}).items()
                     if p.get("collision_share") is not None)
    raise DegenerateBoxError(
        f"dataset={dataset}: {share:.1%} of {probe['n_labeled']} codes sampled from the latent box Z decode to "
        f"self-intersecting meshes, so U(Z) is nearly all {majority} (minority below box_check.min_class_share="
        f"{min_class_share:g}) and a detector trained and judged on it would learn nothing. Change the latent space: "
        f"autoencoder=pca (the share in the PCA references' boxes: {alts or 'n/a'}), a smaller |Z_all| "
        "(dataset.latent.n_components / level2_dim), or autoencoder.box_margin; box_check.enabled=false runs anyway")


def box_stage(space, ref_spaces: dict, pool, cfg, box_fit: dict | None = None) -> dict | None:
    """``box_check`` of a run: label a probe of U(Z) and of the references' boxes; stop on a degenerate box
    (:func:`check_box`). The fitted box's probe (``box_fit``, same size and seed) is reused, not labeled again.

    Returns:
        ``{"space": probe, "references": {name: probe}, "min_class_share"}`` (``metrics.json``'s
        ``latent.box_probe``; a probe is :func:`probe_share`'s dict), or None when ``box_check`` is off.
    """
    bc = cfg.get("box_check")
    if bc is None or not bc.enabled:
        return None
    n, seed = int(bc.n_probe), int(bc.seed)
    chosen = [t for t in (box_fit or {}).get("trials", []) if t["factor"] == box_fit["factor"]]
    probe = ({k: v for k, v in chosen[0].items() if k != "factor"} if chosen
             else probe_share(space, pool, n, seed, desc="probing the box Z"))
    refs = {name: probe_share(ref, pool, n, seed, desc=f"probing the box of {name}")
            for name, ref in ref_spaces.items()} if bc.references else {}
    check_box(probe, float(bc.min_class_share), str(cfg.dataset.name), refs)
    return {"space": probe, "references": refs, "min_class_share": float(bc.min_class_share)}
