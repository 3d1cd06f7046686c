"""Newton projector onto the 0.5 level set, against analytic projections and bisection."""

from __future__ import annotations

import torch

from neuralcol.active.newton import newton_project


def _box(d, half=10.0):
    return -half * torch.ones(d, dtype=torch.float64), half * torch.ones(d, dtype=torch.float64)


def test_linear_classifier_gives_orthogonal_projection():
    g = torch.Generator().manual_seed(0)
    w = torch.randn(6, generator=g, dtype=torch.float64)
    b = 0.3

    def logit(z):
        return 2.0 * (z @ w + b)

    def prob(z):
        return torch.sigmoid(logit(z))

    z0 = torch.randn(50, 6, generator=g, dtype=torch.float64) * 2
    res = newton_project(logit, z0, *_box(6, half=30.0), eps_z=1e-10, max_iter=100)
    exact = z0 - ((z0 @ w + b) / (w @ w))[:, None] * w  # orthogonal projection onto w.z + b = 0
    assert res.converged.all() and res.finite.all()
    torch.testing.assert_close(res.z, exact, rtol=0, atol=1e-6)
    torch.testing.assert_close(prob(res.z), torch.full((50,), 0.5, dtype=torch.float64), rtol=0, atol=1e-8)


def test_ball_classifier_matches_bisection_along_the_ray():
    """f = sigmoid(k (|z| - r)): the gradient is radial, so the projection is the point of the ray at |z| = r,
    found independently by bisection on the ray."""
    g = torch.Generator().manual_seed(1)
    r = 1.5

    def logit(z):
        return 3.0 * (z.norm(dim=-1) - r)

    def prob(z):
        return torch.sigmoid(logit(z))

    z0 = torch.randn(40, 4, generator=g, dtype=torch.float64)
    z0 = z0 / z0.norm(dim=-1, keepdim=True) * torch.empty(40, 1, dtype=torch.float64).uniform_(0.3, 3.0, generator=g)
    res = newton_project(logit, z0, *_box(4), eps_z=1e-10, max_iter=200)
    assert res.converged.all()
    direction = z0 / z0.norm(dim=-1, keepdim=True)
    lo, hi = torch.zeros(40, dtype=torch.float64), torch.full((40,), 5.0, dtype=torch.float64)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        inside = prob(direction * mid[:, None]) < 0.5
        lo = torch.where(inside, mid, lo)
        hi = torch.where(inside, hi, mid)
    torch.testing.assert_close(res.z, direction * lo[:, None], rtol=0, atol=1e-6)


def test_iterates_stay_in_box_and_nan_is_flagged():
    def logit(z):
        return z.sum(-1) - 100.0  # level set outside the box

    z0 = torch.zeros(3, 2, dtype=torch.float64)
    lo, hi = _box(2, half=1.0)
    res = newton_project(logit, z0, lo, hi, max_iter=20)
    assert (res.z >= lo).all() and (res.z <= hi).all()

    def bad(z):
        return torch.where(z[:, 0] > 0.5, torch.full_like(z[:, 0], float("nan")), z[:, 0] - 1.0)

    res = newton_project(bad, torch.tensor([[0.0, 0.0], [0.2, 0.0]], dtype=torch.float64), *_box(2), max_iter=50)
    assert not res.finite.all() and torch.isfinite(res.z).all()


def _anisotropic_problem():
    """A box like a latent space's (2 level-1 axes of half-range 500, 6 level-2 axes of half-range 20) and a
    classifier that is linear in the box-normalised coordinates, with every axis weighted equally."""
    half = torch.tensor([500.0, 500.0] + [20.0] * 6, dtype=torch.float64)
    lo, hi = -half, half

    def logit(z):
        return 4.0 * ((z / half).sum(-1) - 0.5)

    g = torch.Generator().manual_seed(3)
    z0 = (torch.rand(64, 8, generator=g, dtype=torch.float64) * 2 - 1) * half * 0.3
    return logit, z0, lo, hi, half


def test_box_coordinates_move_level1_and_level2_axes_comparably():
    """The step in box coordinates is the orthogonal projection in x = z / half: every axis moves by the same
    amount in box units (the paper's raw-coordinate step moves the wide axes (20/500)^2 = 0.16 % as much)."""
    logit, z0, lo, hi, half = _anisotropic_problem()
    res = newton_project(logit, z0, lo, hi, eps_z=1e-12, max_iter=50, coordinates="box")
    assert res.converged.all()
    torch.testing.assert_close(torch.sigmoid(logit(res.z)), torch.full((64,), 0.5, dtype=torch.float64),
                               rtol=0, atol=1e-9)
    moved = ((res.z - z0) / half).abs()  # (64, 8) box units
    ratio = moved[:, :2].mean(1) / moved[:, 2:].mean(1)
    torch.testing.assert_close(ratio, torch.ones(64, dtype=torch.float64), rtol=1e-6, atol=0)
    # the closed form: x0 - (sum x0 - 0.5) / 8 on every axis
    x0 = z0 / half
    exact = (x0 - ((x0.sum(-1) - 0.5) / 8)[:, None]) * half
    torch.testing.assert_close(res.z, exact, rtol=0, atol=1e-6)


def test_raw_coordinates_are_the_papers_step():
    """``coordinates="raw"`` keeps the paper's recursion: level-1 axes barely move."""
    logit, z0, lo, hi, half = _anisotropic_problem()
    res = newton_project(logit, z0, lo, hi, eps_z=1e-12, max_iter=200, coordinates="raw")
    moved = ((res.z - z0) / half).abs()
    ratio = moved[:, :2].mean(1) / moved[:, 2:].mean(1)
    assert (ratio < 0.01).all(), ratio.max()
