"""Augmented-Lagrangian collision handler against analytic projections; objective gradients against finite
differences; failures reported, not raised."""

from __future__ import annotations

import pytest
import torch

from neuralcol.handler.alm import ALMSettings, alm_resolve
from neuralcol.handler.objectives import CartesianObjective, LatentObjective

D = 6
LO, HI = -3.0 * torch.ones(D, dtype=torch.float64), 3.0 * torch.ones(D, dtype=torch.float64)


def _ball_logit(center, radius, k=4.0):
    """'Collides' inside the ball: logit = k (r^2 - |z - c|^2)."""
    return lambda z: k * (radius ** 2 - ((z - center) ** 2).sum(-1))


@pytest.fixture(autouse=True)
def _float64():
    old = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    yield
    torch.set_default_dtype(old)


def test_ball_constraint_gives_the_exact_projection():
    gen = torch.Generator().manual_seed(0)
    center, radius, k = torch.full((D,), 0.3), 1.5, 4.0
    # inside the ball, away from its centre (where every direction is nearly as good: a non-convex tie)
    z_user = center + radius * torch.nn.functional.normalize(torch.randn(64, D, generator=gen), dim=-1) \
        * (0.2 + 0.7 * torch.rand(64, 1, generator=gen))
    st = ALMSettings(margin=0.5, max_outer=30, tol=1e-7)
    res = alm_resolve(LatentObjective(z_user), _ball_logit(center, radius, k), z_user, LO, HI, st)
    # nearest point with logit = -margin: on the sphere of radius sqrt(r^2 + margin / k), same direction
    r_target = (radius ** 2 + st.margin / k) ** 0.5
    expected = center + r_target * torch.nn.functional.normalize(z_user - center, dim=-1)
    torch.testing.assert_close(res.z, expected, atol=1e-5, rtol=0)
    assert res.feasible.all() and res.finite.all() and res.converged.all()
    torch.testing.assert_close(res.objective, 0.5 * ((expected - z_user) ** 2).sum(-1), atol=1e-4, rtol=0)


def test_half_space_projection_and_feasible_inputs_stay():
    a, b = torch.tensor([1.0, -2.0, 0.5, 0.0, 1.0, 0.3]), 0.7
    logit = lambda z: z @ a - b  # noqa: E731  (collides where a.z > b)
    z_user = torch.tensor([[1.0, 0.0, 0.0, 0.0, 1.0, 0.0],     # a.z = 2 > b: infeasible
                           [-1.0, 1.0, 0.0, 0.0, 0.0, 0.0]])   # a.z = -3: feasible with margin
    st = ALMSettings(margin=0.25, tol=1e-8)
    res = alm_resolve(LatentObjective(z_user), logit, z_user, LO, HI, st)
    t = (z_user[0] @ a - b + st.margin) / (a @ a)
    torch.testing.assert_close(res.z[0], z_user[0] - t * a, atol=1e-6, rtol=0)
    torch.testing.assert_close(res.z[1], z_user[1])
    assert res.converged.all() and res.outer[1] == 1


def test_box_limits_the_solution():
    # the nearest feasible point lies outside the box: the handler stops at the box face, feasible
    logit = lambda z: 2.5 - z[:, 0]  # noqa: E731  (feasible iff z_0 >= 2.5 + margin)
    z_user = torch.zeros(1, D)
    st = ALMSettings(margin=1.0, max_outer=15)
    res = alm_resolve(LatentObjective(z_user), logit, z_user, LO, HI, st)
    assert res.z[0, 0] <= 3.0 + 1e-9 and not res.feasible[0] and not res.converged[0]
    assert res.z[0, 0] == pytest.approx(3.0, abs=1e-6)  # as close to feasible as the box allows


def test_infeasible_and_nan_problems_are_reported_not_raised():
    def logit(z):
        out = torch.full((len(z),), 3.0)  # never below -margin: infeasible everywhere
        return torch.where(z[:, 0] > 0.5, torch.nan, out)  # and NaN for some inputs

    z_user = torch.zeros(3, D)
    z_user[1, 0] = 1.0
    res = alm_resolve(LatentObjective(z_user), logit, z_user, LO, HI, ALMSettings(max_outer=4, inner_iters=5))
    assert not res.feasible.any() and not res.converged.any()
    assert res.finite.tolist() == [True, False, True]
    assert torch.isfinite(res.z).all()


def test_settings_are_validated():
    with pytest.raises(ValueError, match="tolerances"):
        ALMSettings(inner_iters=0)
    with pytest.raises(ValueError, match="mu0"):
        ALMSettings(mu0=0)


def test_cartesian_objective_gradient_matches_finite_differences(tube_space):
    space = tube_space[0]
    space64 = type(space).load(next((tube_space[4] / "autoencoders").rglob("latent_space.pt"))).double()
    gen = torch.Generator().manual_seed(3)
    z = space64.sample(2, gen).double()
    with torch.no_grad():
        target = space64.decode(space64.sample(2, gen).double())
    subset = torch.arange(0, space64.acap.n_vertices, 3)
    obj = CartesianObjective(space64, target, vertices=subset)
    idx = torch.arange(2)
    zz = z.clone().requires_grad_(True)
    obj(zz, idx).sum().backward()
    eps = 1e-6
    fd = torch.zeros_like(z)
    for i in range(2):
        for j in range(z.shape[1]):
            e = torch.zeros_like(z)
            e[i, j] = eps
            fd[i, j] = (obj(z + e, idx)[i] - obj(z - e, idx)[i]) / (2 * eps)
    torch.testing.assert_close(zz.grad, fd, rtol=1e-5, atol=1e-7)
    # the objective of a problem reads that problem's target
    both = obj(z, idx)
    torch.testing.assert_close(obj(z[1:], idx[1:]), both[1:])


def test_batched_lbfgs_solves_independent_badly_scaled_problems():
    from neuralcol.handler.lbfgs import batched_lbfgs

    # problem b: scaled Rosenbrock s_b * [(1 - x0)^2 + 100 (x1 - x0^2)^2]; minimum (1, 1) for every scale
    scales = torch.tensor([1e-2, 1.0, 1e3, 1e5])

    def rosen(x, idx):
        return scales[idx] * ((1 - x[:, 0]) ** 2 + 100 * (x[:, 1] - x[:, 0] ** 2) ** 2)

    x0 = torch.tensor([[-1.2, 1.0]] * 4)
    res = batched_lbfgs(rosen, x0, torch.full((2,), -5.0), torch.full((2,), 5.0), max_iter=500, gtol=1e-10)
    torch.testing.assert_close(res.x, torch.ones(4, 2), atol=1e-5, rtol=0)
    assert res.converged[1:].all() and res.finite.all()

    # box-constrained quadratic: min |x - a|^2 on [0, 1]^3 is clip(a, 0, 1)
    a = torch.tensor([[2.0, -1.0, 0.3], [0.5, 0.5, 3.0]])
    res = batched_lbfgs(lambda x, idx: ((x - a[idx]) ** 2).sum(-1), torch.zeros(2, 3), torch.zeros(3),
                        torch.ones(3), gtol=1e-12)
    torch.testing.assert_close(res.x, a.clamp(0, 1), atol=1e-9, rtol=0)


def test_verified_escalation_keeps_the_smallest_margin_that_resolves():
    """Exact truth: PD = z_0 (collides for z_0 > 0); the detector's boundary is wrong, at z_0 = 0.5, with logit
    4 (z_0 - 0.5). Handling with margin m gives z_0 = 0.5 - m / 4 exactly, so an input needs margin >= 2 to be
    resolved; inputs already below the true boundary after the first handling keep it."""
    from dataclasses import replace

    import numpy as np

    from neuralcol.handler.resolve import verified_escalation
    from neuralcol.stages.handler import pd_reduction_metrics

    z_user = torch.zeros(3, D)
    z_user[:, 0] = torch.tensor([0.9, 0.45, 1.5])
    logit = lambda z: 4.0 * (z[:, 0] - 0.5)  # noqa: E731
    st = ALMSettings(margin=0.5, tol=1e-8, feas_tol=1e-9)

    def handle(rows, margin):
        z0 = z_user[torch.as_tensor(rows)]
        return alm_resolve(LatentObjective(z0), logit, z0, LO, HI, replace(st, margin=margin))

    def label(z, rows=None):
        return z[:, 0].numpy().astype(np.float64)

    first = handle([0, 1, 2], st.margin)
    # input 1 (z_0 = 0.45) is already predicted free: the handler leaves it where it is (still colliding)
    np.testing.assert_allclose(first.z[:, 0].numpy(), [0.375, 0.375, 0.375], atol=1e-6)
    calls = []
    z, pd, stage, handled = verified_escalation(lambda r, m: calls.append(m) or handle(r, m), label, z_user,
                                                first.z, label(first.z), margins=[1.0, 2.0, 3.0])
    assert handled == [3, 3, 0] and calls == [1.0, 2.0]
    np.testing.assert_allclose(z[:, 0].numpy(), [0.0, 0.0, 0.0], atol=1e-6)
    np.testing.assert_array_equal(stage, [2, 2, 2])
    torch.testing.assert_close(z[:, 1:], z_user[:, 1:])
    m, _ = pd_reduction_metrics(z_user.numpy(), z.numpy(), z_user[:, 0].numpy(), np.maximum(pd, 0))
    assert m["success_rate"] == 1.0 and m["resolved_rate"] == 1.0 and m["mean_pd_reduction"] == pytest.approx(1.0)
    assert m["mean_embedding_diff"] == pytest.approx(float(np.mean([0.9, 0.45, 1.5])), abs=1e-5)


def test_pd_reduction_metrics_by_hand():
    import numpy as np

    from neuralcol.stages.handler import pd_reduction_metrics

    z_user = np.zeros((4, 2))
    z = np.array([[3.0, 4.0], [0.0, 1.0], [0.0, 2.0], [1.0, 0.0]])
    pd_before = np.array([1.0, 2.0, 1.0, 4.0])
    pd_after = np.array([-0.5, 1.0, 2.0, np.nan])  # resolved, halved, worse, handler failed (NaN)
    m, arr = pd_reduction_metrics(z_user, z, pd_before, pd_after)
    assert m["n"] == 4 and m["success_rate"] == 0.5 and m["resolved_rate"] == 0.25
    assert m["mean_pd_reduction"] == pytest.approx((1.0 + 0.5) / 2)
    assert m["mean_embedding_diff"] == pytest.approx((5.0 + 1.0) / 2)
    assert m["mean_pd_reduction_all"] == pytest.approx((1.0 + 0.5 - 1.0) / 3)
    np.testing.assert_array_equal(arr["success"], [True, True, False, False])
    # the per-input file the report bins by input PD: the same success criterion, the inputs' PD per sub-domain
    from neuralcol.stages.handler import per_input_results

    pd_sub = np.array([[1.0, 0.2], [0.1, 2.0], [1.0, 0.0], [0.5, 4.0]])
    per = per_input_results({"pd_before": pd_before, "pd_after": pd_after, **arr}, pd_sub)
    assert sorted(per) == ["pd_after", "pd_before", "pd_sub_before", "success"]
    np.testing.assert_array_equal(per["success"], arr["success"])
    np.testing.assert_array_equal(per["pd_after"], pd_after)
    assert "pd_sub_before" not in per_input_results({"pd_before": pd_before, "pd_after": pd_after, **arr})
    with pytest.raises(ValueError, match="pd_sub_before"):
        per_input_results({"pd_before": pd_before, "pd_after": pd_after, **arr}, pd_sub[:3])


def test_per_problem_constraint_with_rows():
    """logit_takes_rows: each problem has its own boundary z_0 = t_i (logit 4 (z_0 - t_i)); the handler moves
    each input to z_0 = t_i - margin / 4 and leaves the other entries alone."""
    import numpy as np

    t = torch.tensor([0.2, -0.1, 0.5], dtype=torch.float64)
    z_user = torch.zeros(3, D, dtype=torch.float64)
    z_user[:, 0] = 0.9
    st = ALMSettings(margin=0.5, tol=1e-8, feas_tol=1e-9)
    res = alm_resolve(LatentObjective(z_user), lambda z, idx: 4.0 * (z[:, 0] - t[idx]), z_user, LO.double(),
                      HI.double(), st, logit_takes_rows=True)
    np.testing.assert_allclose(res.z[:, 0].numpy(), (t - 0.125).numpy(), atol=1e-5)
    torch.testing.assert_close(res.z[:, 1:], z_user[:, 1:])
    assert res.feasible.all()


def test_handle_codes_in_batches_equals_one_batch_and_shows_progress(monkeypatch):
    """handle_codes over 5 codes in batches of 2 gives the single batch's answer (the problems are independent);
    with ``desc`` it counts the codes on a progress bar (the paper-scale run's handler on 10^4 codes
    said nothing for tens of minutes)."""
    from collections import namedtuple

    from neuralcol.handler.resolve import handle_codes
    from neuralcol.utils import progress

    out = namedtuple("Out", "logit")

    class Half(torch.nn.Module):  # collides where z_0 > 0.5
        def __init__(self):
            super().__init__()
            self.w = torch.nn.Parameter(torch.tensor([4.0]))

        def forward(self, z):
            return out(self.w * (z[:, 0] - 0.5))

    bars = []
    real = progress.progress_bar

    def recording(*args, **kwargs):
        bar = real(*args, **kwargs)
        bars.append((kwargs, bar))
        return bar

    monkeypatch.setattr(progress, "progress_bar", recording)
    z = torch.tensor([[0.9, 0.1], [0.7, -0.3], [0.2, 0.0], [0.95, 0.5], [0.6, 0.6]])
    st = ALMSettings(margin=0.5)
    lo, hi = torch.full((2,), -2.0), torch.full((2,), 2.0)
    whole = handle_codes(Half(), z, lo, hi, st, batch_size=8)
    batched = handle_codes(Half(), z, lo, hi, st, batch_size=2, desc="handling codes")
    torch.testing.assert_close(batched.z, whole.z)
    assert (whole.z[:, 0] <= 0.5 - 0.5 / 4 + 1e-4).all()  # logit <= -margin
    (quiet, _), (shown, bar) = bars
    assert quiet["disable"] and not shown["disable"] and shown["desc"] == "handling codes"
    assert shown["total"] == 5 and bar.n == 5
