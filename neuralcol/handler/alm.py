"""Collision handler: ``argmin_Z E(Z)  s.t.  MLP_c(Z) <= 0.5`` by an augmented Lagrangian method (paper eq. 4).

The constraint is written on the detector's logit with a margin, ``c(Z) = logit(Z) + margin <= 0`` (so the
probability ends at most ``sigmoid(-margin)``). For a batch of B independent problems, the
Powell-Hestenes-Rockafellar augmented Lagrangian of problem b is

    L_b(Z) = E_b(Z) + (max(0, lam_b + mu_b c_b(Z))^2 - lam_b^2) / (2 mu_b),

minimised over Z (inside the box Z) by an inner solver, after which ``lam_b <- max(0, lam_b + mu_b c_b)``
and, if the violation ``max(0, c_b)`` did not shrink below ``shrink`` times its previous value,
``mu_b <- min(mu_growth mu_b, mu_max)``. A problem is done when ``c_b <= feas_tol`` and its code moved less than
``tol`` (relative to the box size) in the last outer iteration; ``max_outer`` caps the outer iterations.
The inner solver is a batched L-BFGS with one curvature history and one line search per problem
(:mod:`neuralcol.handler.lbfgs`). (Adam on the sum of the problems was tried first: with the penalty grown
to 1e3-1e4 it oscillated around the boundary and missed the analytic projection by up to 0.6 in
``tests/test_handler.py``; ``torch.optim.LBFGS`` on the sum shares one line search across problems and left
errors of 1e-3.)

Codes are optimised in box-normalised coordinates ``x = (Z - center) / half_range`` (the raw level-1 codes span
hundreds of units, the level-2 ones tens) and E is scaled by ``1 / mean(half_range^2)``; this changes the
conditioning and the meaning of ``mu0`` and the tolerances, not the solution. (Unscaled, the projected
gradients of SCAPE problems were ~1e5 and never met the L-BFGS tolerance: every inner iteration ended in a
failed line search, 2 s per mesh.)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import torch

from neuralcol.handler.lbfgs import batched_lbfgs


@dataclass(frozen=True)
class ALMSettings:
    """Settings of :func:`alm_resolve` (``conf/handler/*.yaml``)."""

    margin: float = 0.5          # feasible: logit <= -margin (probability <= sigmoid(-margin))
    mu0: float = 1.0             # initial penalty
    mu_growth: float = 10.0      # penalty increase when the violation does not shrink enough
    mu_max: float = 1.0e6
    shrink: float = 0.25         # required violation reduction per outer iteration
    max_outer: int = 20
    inner_iters: int = 30        # L-BFGS iterations per outer iteration
    inner_gtol: float = 1.0e-6   # L-BFGS stops a problem when its projected gradient is below this
    tol: float = 1.0e-5          # stop when feasible and max |dx| < tol (box-normalised units)
    feas_tol: float = 1.0e-6     # feasible: logit + margin <= feas_tol (ALM approaches the boundary from outside)

    def __post_init__(self):
        if self.mu0 <= 0 or self.mu_growth < 1 or self.mu_max < self.mu0 or not 0 < self.shrink <= 1:
            raise ValueError(f"handler settings {self}: need mu0 > 0, mu_growth >= 1, mu_max >= mu0, "
                             "0 < shrink <= 1")
        if self.max_outer < 1 or self.inner_iters < 1 or self.tol <= 0 or self.inner_gtol <= 0 or self.feas_tol < 0:
            raise ValueError(f"handler settings {self}: iteration counts and tolerances must be positive")


class Resolution(NamedTuple):
    """Result for B problems: z (B, D) the handled codes; feasible (B,) bool (the detector's constraint holds);
    converged (B,) bool (feasible and settled before the iteration cap); finite (B,) bool (False where the
    objective or detector produced NaN/inf: such problems keep their last finite code); outer (B,) outer
    iterations used; logit (B,) the detector's final logit; objective (B,) final E."""

    z: torch.Tensor
    feasible: torch.Tensor
    converged: torch.Tensor
    finite: torch.Tensor
    outer: torch.Tensor
    logit: torch.Tensor
    objective: torch.Tensor


def alm_resolve(objective: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
                logit_fn: Callable[[torch.Tensor], torch.Tensor], z_start: torch.Tensor, box_lo: torch.Tensor,
                box_hi: torch.Tensor,
                settings: ALMSettings = ALMSettings(), logit_takes_rows: bool = False) -> Resolution:
    """Move each code to the nearest (in ``objective``) code the detector calls collision-free.

    Args:
        objective: ``(z, idx) -> (len(idx),)``: E of the problems ``idx`` (indices into the batch) at the raw
            codes z (len(idx), D), e.g. :class:`~neuralcol.handler.objectives.LatentObjective`.
        logit_fn: raw codes (B, D) -> (B,) the detector's collision logit.
        z_start: (B, D) starting codes (usually Z_user).
        box_lo, box_hi: (D,) the latent box.
        settings: ALM settings.
        logit_takes_rows: ``logit_fn`` is called as ``logit_fn(z, idx)`` with the problems' indices (a
            constraint that differs per problem, e.g. a detector judging each problem's own corrected mesh).

    Returns:
        Resolution.
    """
    if logit_takes_rows:
        logit_rows = logit_fn
    else:
        def logit_rows(z, idx):
            return logit_fn(z)
    lo_z, hi_z = box_lo.to(z_start), box_hi.to(z_start)
    center, half = (lo_z + hi_z) / 2, ((hi_z - lo_z) / 2).clamp_min(1e-12)
    lo, hi = (lo_z - center) / half, (hi_z - center) / half
    to_z = lambda x: center + half * x  # noqa: E731
    # E is minimised as scale * E with scale = 1 / mean(half_range^2): |Z - Z_user|^2 / 2 then reads in
    # box-normalised units, so mu0 and the tolerances mean the same for every latent space (same minimiser)
    scale = 1.0 / float((half ** 2).mean())
    b = z_start.shape[0]
    x = ((z_start.detach() - center) / half).clamp(-1, 1)
    lam = torch.zeros(b, dtype=z_start.dtype, device=z_start.device)
    mu = torch.full_like(lam, settings.mu0)
    active = torch.ones(b, dtype=torch.bool, device=z_start.device)
    finite = torch.ones_like(active)
    converged = torch.zeros_like(active)
    outer = torch.zeros(b, dtype=torch.long, device=z_start.device)
    with torch.no_grad():
        viol = torch.relu(logit_rows(to_z(x), torch.arange(b, device=z_start.device)) + settings.margin)
    for _ in range(settings.max_outer):
        idx = torch.nonzero(active).flatten()
        if len(idx) == 0:
            break
        lam_a, mu_a = lam[idx], mu[idx]

        def lagrangian(xa, sub, lam_a=lam_a, mu_a=mu_a, idx=idx):
            za = to_z(xa)
            c = logit_rows(za, idx[sub]) + settings.margin
            la, ma = lam_a[sub], mu_a[sub]
            return scale * objective(za, idx[sub]) + (torch.relu(la + ma * c) ** 2 - la ** 2) / (2 * ma)

        with torch.enable_grad():
            new = batched_lbfgs(lagrangian, x[idx], lo, hi, max_iter=settings.inner_iters,
                                gtol=settings.inner_gtol).x
        with torch.no_grad():
            c = logit_rows(to_z(new), idx) + settings.margin
            ok = torch.isfinite(new).all(-1) & torch.isfinite(c)
            finite[idx[~ok]] = False
            active[idx[~ok]] = False
            idx, new, c = idx[ok], new[ok], c[ok]
            step = (new - x[idx]).abs().amax(-1)
            x[idx] = new
            outer[idx] += 1
            lam[idx] = torch.relu(lam[idx] + mu[idx] * c)
            v = torch.relu(c)
            grow = v > settings.shrink * viol[idx]
            mu[idx] = torch.where(grow, (mu[idx] * settings.mu_growth).clamp_max(settings.mu_max), mu[idx])
            viol[idx] = v
            done = (c <= settings.feas_tol) & (step < settings.tol)
            converged[idx[done]] = True
            active[idx[done]] = False
    with torch.no_grad():
        z = to_z(x)
        logit = logit_rows(z, torch.arange(b, device=z.device))
        obj = objective(z, torch.arange(b, device=z.device))
    feasible = (logit + settings.margin <= settings.feas_tol) & finite
    return Resolution(z, feasible, converged & feasible, finite, outer, logit, obj)

