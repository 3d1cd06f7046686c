"""Risk-seeking Newton projector (paper eq. 2): pull latent codes onto the 0.5 level set of the detector.

Minimises ``r(z)^2 / 2`` by the recursion ``z <- z - H^-1 grad r r`` with the Gauss-Newton (first-order)
Hessian ``H = grad r grad r^T + damping I``; by Sherman-Morrison ``H^-1 grad r = grad r / (damping +
|grad r|^2)``, so each step costs one batched gradient. The residual is the detector's *logit*
(``r = logit(MLP_c)``, whose 0 level set is MLP_c's 0.5 level set): on the probability ``MLP_c - 0.5``
itself the step ``~ r / |grad|`` explodes wherever the sigmoid saturates (seen while writing
``tests/test_newton.py``: samples of a linear classifier thrown to the box faces), while on the logit it is
projected exactly in one step. Steps are limited to ``max_step`` times the box's largest side, iterates
are kept inside the box Z, and a sample stops when the largest change of its coordinates relative to its
largest coordinate (floored at 1) falls below ``eps_z`` (paper: 1e-7), or after ``max_iter`` steps.

Coordinates (``coordinates``): ``"box"`` (default) takes the Gauss-Newton step in the box-normalised
coordinates ``x = (z - c) / h`` (c centre, h half-range of each axis), so every axis moves in proportion to
its own range; ``"raw"`` takes it in the raw latent coordinates as the paper writes it. In raw coordinates
the step along axis j is ``~ g_x,j / h_j^2``: with level-1 codes spanning hundreds of units and level-2 codes
tens, level-1 axes barely move and level-2 axes are thrown to the box faces (docs/studies/diagnosis_scape.md).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import torch


class Projection(NamedTuple):
    """z (B, D) projected codes; iterations (B,) steps taken; converged (B,) bool; finite (B,) bool
    (False where the detector or the step produced NaN/inf: such samples keep their last finite value and
    must be dropped by the caller)."""

    z: torch.Tensor
    iterations: torch.Tensor
    converged: torch.Tensor
    finite: torch.Tensor


def newton_project(logit_fn: Callable[[torch.Tensor], torch.Tensor], z0: torch.Tensor, box_lo: torch.Tensor,
                   box_hi: torch.Tensor, eps_z: float = 1e-7, max_iter: int = 50, damping: float = 1e-6,
                   max_step: float = 0.25, coordinates: str = "box") -> Projection:
    """Project latent codes onto ``{z : logit_fn(z) = 0}`` = the 0.5 level set (batched, device-agnostic).

    Args:
        logit_fn: (B, D) -> (B,) differentiable collision logit (the detector's MLP_c before the sigmoid).
        z0: (B, D) starting codes.
        box_lo, box_hi: (D,) the box Z; iterates are clamped into it.
        eps_z: stop when max |dz| / max(1, max |z|) < eps_z (paper: 1e-7).
        max_iter: iteration cap.
        damping: Levenberg term of the Gauss-Newton Hessian (keeps flat regions from exploding).
        max_step: largest step, as a fraction of the box's largest side (``"box"``: of every side).
        coordinates: ``"box"`` (step and stopping test in box-normalised coordinates) or ``"raw"`` (paper).

    Returns:
        Projection.
    """
    if eps_z <= 0 or max_iter < 1 or damping < 0 or max_step <= 0:
        raise ValueError(f"eps_z={eps_z} must be > 0, max_iter={max_iter} >= 1, damping={damping} >= 0, "
                         f"max_step={max_step} > 0")
    if coordinates not in ("box", "raw"):
        raise ValueError(f"coordinates={coordinates!r}; use 'box' (normalised) or 'raw' (paper)")
    z = z0.detach().clone()
    lo, hi = box_lo.to(z), box_hi.to(z)
    if coordinates == "box":
        center, scale = (lo + hi) / 2, ((hi - lo) / 2).clamp_min(torch.finfo(z.dtype).tiny)
    else:
        center, scale = torch.zeros_like(lo), torch.ones_like(lo)
    # largest step (max-norm, in the coordinates the step is taken in): max_step x the box's largest side
    step_cap = max_step * float((hi - lo).max()) if coordinates == "raw" else 2.0 * max_step  # normalised sides: 2
    n = z.shape[0]
    active = torch.ones(n, dtype=torch.bool, device=z.device)
    converged = torch.zeros(n, dtype=torch.bool, device=z.device)
    finite = torch.ones(n, dtype=torch.bool, device=z.device)
    iters = torch.zeros(n, dtype=torch.long, device=z.device)
    for _ in range(max_iter):
        if not active.any():
            break
        idx = torch.nonzero(active).flatten()
        za = z[idx].requires_grad_(True)
        with torch.enable_grad():
            p = logit_fn(za)
            (grad,) = torch.autograd.grad(p.sum(), za)
        r = p.detach()[:, None]
        gx = grad * scale  # gradient w.r.t. the (normalised) coordinates x = (z - center) / scale
        step = gx * r / (damping + (gx * gx).sum(-1, keepdim=True))  # step in x
        big = step.abs().amax(-1, keepdim=True)
        step = torch.where(big > step_cap, step * (step_cap / big), step)
        new = torch.maximum(torch.minimum(za.detach() - step * scale, hi), lo)
        ok = torch.isfinite(new).all(-1) & torch.isfinite(p.detach())
        finite[idx[~ok]] = False
        active[idx[~ok]] = False
        idx, new, old = idx[ok], new[ok], za.detach()[ok]
        xn, xo = (new - center) / scale, (old - center) / scale
        change = (xn - xo).abs().amax(-1) / xo.abs().amax(-1).clamp_min(1.0)
        z[idx] = new
        iters[idx] += 1
        done = change < eps_z
        converged[idx[done]] = True
        active[idx[done]] = False
    return Projection(z, iters, converged, finite)
