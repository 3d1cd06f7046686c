"""NaN guards: a Newton projection that produces NaN/inf drops the sample (counted), never written to D_c."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch
from test_active import RADIUS, BallOracle, D

from neuralcol.active.acquisition import ProjectedAcquisition
from neuralcol.samples.store import CollisionStore, Origin


class HalfNaNDetector(torch.nn.Module):
    """The ball's signed distance as a logit, but NaN wherever z_0 > 0 (a detector that blew up there)."""

    def __init__(self):
        super().__init__()
        self.scale = torch.nn.Parameter(torch.ones(()))

    def forward(self, z):
        logit = self.scale * (RADIUS - z.norm(dim=-1))
        return SimpleNamespace(logit=torch.where(z[:, 0] > 0, torch.full_like(logit, float("nan")), logit))


def test_projection_nan_samples_are_dropped_counted_and_replaced(tmp_path):
    oracle = BallOracle()
    acq = ProjectedAcquisition(tmp_path / "pool.h5", oracle, seed=0, box_lo=-torch.ones(D), box_hi=torch.ones(D),
                               projected_fraction=0.5, newton={"eps_z": 1e-7, "max_iter": 20})
    store = CollisionStore(tmp_path / "dc.h5", D, 4)
    boot = acq.take_uniform(200)
    store.append(boot.z, boot.pd, boot.pd_sub, boot.collides, boot.subset, 0, boot.origin)
    new = acq(1, HalfNaNDetector(), store, 100)
    failed = new.info["n_projection_failed"]
    assert 20 < failed < 80, "about half of the picked codes start with z_0 > 0"
    assert new.info["n_projected"] == 50 - failed
    assert len(new.z) == 100, "failed projections are replaced by uniform samples"
    assert (new.origin == Origin.PROJECTED).sum() == 50 - failed and (new.origin == Origin.UNIFORM).sum() == 50 + failed
    store.append(new.z, new.pd, new.pd_sub, new.collides, new.subset, 1, new.origin)
    rows = store.read()
    assert np.isfinite(rows.z).all() and np.isfinite(rows.pd).all() and np.isfinite(rows.pd_sub).all()
    assert (rows.z[rows.origin == Origin.PROJECTED][:, 0] <= 0).all(), "no sample from the NaN region"
    store.close()


def test_handler_nan_inputs_are_counted_and_left_out_of_the_means():
    from neuralcol.handler.alm import ALMSettings
    from neuralcol.stages.handler import evaluate_handler

    oracle = BallOracle()
    gen = torch.Generator().manual_seed(0)
    z_user = 0.3 * (2 * torch.rand(40, D, generator=gen) - 1)  # inside the ball: PD > 0
    pd_before = oracle(z_user).pd
    metrics, arrays = evaluate_handler(HalfNaNDetector(), oracle, z_user, pd_before, ALMSettings(), batch_size=16)
    nan_inputs = (z_user[:, 0] > 0).numpy()
    assert metrics["n_nonfinite"] == nan_inputs.sum() > 0
    assert np.isnan(arrays["pd_after"][nan_inputs]).all(), "never labeled"
    assert np.isfinite(arrays["pd_after"][~nan_inputs]).all()
    assert all(np.isfinite(metrics[k]) for k in ("success_rate", "mean_pd_reduction"))
