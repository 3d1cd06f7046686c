"""Where each round's new samples come from (paper sec. 4.2 and the baselines of sec. 5).

* :class:`UniformAcquisition` (``supv``, ``supv_bd``): the next rows of the seed's cached pool of labeled
  samples from U(Z), so the baselines at size N train on exactly the first N uniform samples.
* :class:`ProjectedAcquisition` (``active``): half of the new samples are drawn from the current D_c and
  pulled onto the detector's 0.5 level set by the Newton projector (eq. 2), then labeled exactly; the other
  half are the next uniform rows (exploration).

Both keep a cursor into the uniform pool, saved with the training checkpoint (``state_dict``).

Samples the exact labeler fails on (NaN/inf decoded mesh, an exception, a worker that dies or hangs:
:mod:`neuralcol.collision.pool`) never reach D_c: the uniform pool replaces them by the next codes of its
sequence, failed projected samples are replaced by uniform rows (like failed projections), so D_c still grows by
exactly ``n``. ``info["n_label_failures"]`` counts the samples dropped by each acquisition.
"""

from __future__ import annotations

import copy
import os
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from neuralcol.active.newton import Projection, newton_project
from neuralcol.collision.labeler import SUBSET_BOUNDARY
from neuralcol.geometry.contact_summary import reusing_neighbours
from neuralcol.metrics.projection import boundary_shares, projection_quality
from neuralcol.nn.inference import batched_logits
from neuralcol.samples.oracle import LatentOracle
from neuralcol.samples.store import CollisionStore, Origin
from neuralcol.samples.uniform import uniform_rows


class AcquiredRows(NamedTuple):
    """New labeled rows: z (B, D), pd (B,), pd_sub (B, K), collides (B,), subset (B,), origin (B,) int8;
    seconds spent labeling and projecting; info (JSON-able statistics)."""

    z: np.ndarray
    pd: np.ndarray
    pd_sub: np.ndarray
    collides: np.ndarray
    subset: np.ndarray
    origin: np.ndarray
    label_seconds: float
    project_seconds: float
    info: dict


def concat_acquired(parts: list[AcquiredRows]) -> AcquiredRows:
    cat = [np.concatenate([getattr(p, f) for p in parts]) for f in AcquiredRows._fields[:6]]
    info: dict = {}
    for p in parts:
        info.update(p.info)
    info["n_label_failures"] = sum(int(p.info.get("n_label_failures", 0)) for p in parts)
    return AcquiredRows(*cat, sum(p.label_seconds for p in parts), sum(p.project_seconds for p in parts), info)


class UniformAcquisition:
    """Next rows of the seed's pool of labeled uniform samples.

    Args:
        pool_path: the cached pool (``.h5``), shared by the runs of one seed.
        oracle: labels rows the pool does not hold yet.
        seed: the pool's seed.
    """

    def __init__(self, pool_path: str | os.PathLike, oracle: LatentOracle, seed: int):
        self.pool_path = Path(pool_path)
        self.oracle = oracle
        self.seed = int(seed)
        self.cursor = 0

    def take_uniform(self, n: int) -> AcquiredRows:
        """The next ``n`` pool rows (labeling them if the pool is shorter; codes that fail to label are
        replaced by the next ones and counted in ``info["n_label_failures"]``)."""
        stop = self.cursor + int(n)
        rows, seconds, labeled, failed = uniform_rows(self.pool_path, self.oracle, stop, self.seed,
                                                      desc="labeling uniform samples")
        sl = slice(self.cursor, stop)
        self.cursor = stop
        return AcquiredRows(rows.z[sl], rows.pd[sl], rows.pd_sub[sl], rows.collides[sl], rows.subset[sl],
                        np.full(int(n), Origin.UNIFORM, np.int8), seconds, 0.0,
                        {"n_uniform": int(n), "n_uniform_labeled_now": labeled,
                         "n_uniform_label_failures": failed, "n_label_failures": failed})

    def __call__(self, round_: int, net: torch.nn.Module, store: CollisionStore, n: int) -> AcquiredRows:
        return self.take_uniform(n)

    def state_dict(self) -> dict:
        return {"cursor": self.cursor}

    def load_state_dict(self, state: dict) -> None:
        self.cursor = int(state["cursor"])


class ProjectedAcquisition(UniformAcquisition):
    """Algorithm 1's data aggregation: ``round(n * projected_fraction)`` codes drawn from D_c and projected onto
    the detector's 0.5 level set, plus uniform rows for the rest.

    Args:
        pool_path, oracle, seed: as :class:`UniformAcquisition`.
        box_lo, box_hi: (D,) the box Z (projected codes stay inside); None: the oracle's latent space's box.
        projected_fraction: share of projected samples (paper: 1/2).
        newton: keyword arguments of :func:`~neuralcol.active.newton.newton_project`.
        start: where the projected half starts: ``"dc"`` (rows drawn from D_c, the paper's Algorithm 1) or
            ``"uncertain"`` (of ``candidates`` x n fresh codes from U(Z), the n whose detector logit is closest
            to 0, i.e. probability closest to 0.5: pool-based uncertainty sampling; docs/studies/diagnosis_scape.md).
        candidates: candidate codes per selected code with ``start="uncertain"``.
        project: run the Newton projector from the starting codes (paper); False labels them as they are.
    """

    STARTS = ("dc", "uncertain")

    def __init__(self, pool_path, oracle: LatentOracle, seed: int, box_lo: torch.Tensor | None = None,
                 box_hi: torch.Tensor | None = None, projected_fraction: float = 0.5, newton: dict | None = None,
                 start: str = "dc", candidates: int = 10, project: bool = True):
        super().__init__(pool_path, oracle, seed)
        if not 0.0 <= projected_fraction <= 1.0:
            raise ValueError(f"projected_fraction={projected_fraction} must be in [0, 1]")
        if start not in self.STARTS:
            raise ValueError(f"start={start!r}; use one of {self.STARTS}")
        if int(candidates) < 1:
            raise ValueError(f"candidates={candidates} must be >= 1")
        box_lo = oracle.space.box_lo if box_lo is None else box_lo
        box_hi = oracle.space.box_hi if box_hi is None else box_hi
        self.box_lo, self.box_hi = box_lo.detach().cpu().float(), box_hi.detach().cpu().float()
        self.projected_fraction = float(projected_fraction)
        self.newton = dict(newton or {})
        self.start, self.candidates, self.project_codes = start, int(candidates), bool(project)

    def _uncertain_codes(self, round_: int, net: torch.nn.Module, n: int) -> torch.Tensor:
        """The n of ``candidates * n`` fresh U(Z) codes (seeded by seed and round) with the smallest |logit|."""
        state = np.random.SeedSequence([self.seed, round_, 7]).generate_state(2, dtype=np.uint32)
        gen = torch.Generator().manual_seed(int(state[0]) << 32 | int(state[1]))
        u = torch.rand(self.candidates * n, len(self.box_lo), generator=gen)
        cand = self.box_lo + u * (self.box_hi - self.box_lo)
        logit = batched_logits(net, cand, batch=65536)
        pick = torch.argsort(logit.abs(), stable=True)[:n]
        return cand[pick]

    def project(self, round_: int, net: torch.nn.Module, store: CollisionStore, n: int) -> AcquiredRows:
        t0 = time.perf_counter()
        if self.start == "dc":
            gen = np.random.default_rng([self.seed, round_])
            n = min(n, len(store))
            pick = np.sort(gen.choice(len(store), size=n, replace=False))
            start = store.read(pick)
            z0, pd_start = torch.as_tensor(start.z), start.pd
        else:
            z0, pd_start = self._uncertain_codes(round_, net, n), None
        dev = next(net.parameters()).device
        # in float64: eps_z = 1e-7 (paper) is below float32's resolution, so float32 iterates never settle
        net64 = copy.deepcopy(net).double().eval()
        lo, hi = self.box_lo.to(dev, torch.float64), self.box_hi.to(dev, torch.float64)
        if self.project_codes:
            with reusing_neighbours():  # a detector that reads contact summaries sees the same meshes move
                proj = newton_project(lambda z: net64(z).logit, z0.to(dev, torch.float64), lo, hi, **self.newton)
        else:
            ones = torch.ones(len(z0), dtype=torch.bool, device=dev)
            zero = torch.zeros(len(z0), dtype=torch.long, device=dev)
            proj = Projection(z0.to(dev, torch.float64), zero, ones, ones)
        z = proj.z[proj.finite].float().cpu()
        t_proj = time.perf_counter() - t0
        lab = self.oracle(z, desc="labeling projected samples")
        n_failed = lab.n_failed
        kept = np.flatnonzero(proj.finite.cpu().numpy())  # rows of `pick` behind each projected code
        if lab.ok is not None:
            kept = kept[np.asarray(lab.ok, bool)]
        lab = lab.without_failures()  # never written to D_c; the uniform rows make up for them
        z = torch.as_tensor(lab.z)
        quality = projection_quality(z0.numpy()[kept], lab.z, lab.pd, None if pd_start is None else pd_start[kept],
                                     float(self.oracle.pool.labeler.eps),
                                     self.box_lo.numpy(), self.box_hi.numpy(), self.oracle.space.n_parts,
                                     getattr(self.oracle, "clearance_limit", None))
        with torch.no_grad():
            p = torch.sigmoid(net64(z.to(dev, torch.float64)).logit).cpu().numpy() if len(z) else np.zeros(0)
        info = {"n_projected": int(len(z)), "n_projection_failed": int((~proj.finite).sum()),
                "n_projected_label_failures": n_failed, "n_label_failures": n_failed,
                "newton_converged_fraction": float(proj.converged.float().mean()) if n else float("nan"),
                "newton_mean_iterations": float(proj.iterations.float().mean()) if n else float("nan"),
                "projected_prob_mean": float(p.mean()) if len(p) else float("nan"),
                "projected_collide_fraction": float(lab.collides.mean()) if len(z) else float("nan"),
                "projected_boundary_fraction": float((lab.subset == SUBSET_BOUNDARY).mean()) if len(z) else
                float("nan"),
                "projection": quality}
        return AcquiredRows(lab.z, lab.pd, lab.pd_sub, lab.collides, lab.subset,
                        np.full(len(z), Origin.PROJECTED, np.int8), lab.seconds, t_proj, info)

    def __call__(self, round_: int, net: torch.nn.Module, store: CollisionStore, n: int) -> AcquiredRows:
        n_proj = int(round(n * self.projected_fraction))
        projected = self.project(round_, net, store, n_proj)
        # failed projections (non-finite) and projected samples that failed to label are replaced by uniform
        # samples, so D_c grows by exactly n
        uniform = self.take_uniform(n - len(projected.z))
        if "projection" in projected.info:  # the same shares for this round's uniform samples, for comparison
            eps = float(self.oracle.pool.labeler.eps)
            projected.info["projection"]["uniform"] = boundary_shares(uniform.pd, eps,
                                                                      getattr(self.oracle, "clearance_limit", None))
        return concat_acquired([projected, uniform])
