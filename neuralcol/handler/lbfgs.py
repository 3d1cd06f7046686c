"""Batched, box-constrained L-BFGS for B independent problems ``min_x f_b(x_b)``, ``lo <= x_b <= hi``.

Each problem keeps its own curvature history, step length and stopping state, so a badly scaled problem
(e.g. one whose augmented-Lagrangian penalty is large) does not slow the others down, as it would if the sum
of all problems were handed to one L-BFGS (``torch.optim.LBFGS`` shares one line search and one history).
Per iteration: the two-loop recursion gives a direction per problem (steepest descent where it is not a
descent direction), then a projected Armijo backtracking search per problem (quadratic interpolation, safeguarded to
[0.1, 0.5] of the previous trial step), all evaluated in batches.
A problem stops when its projected gradient ``|P(x - g) - x|_inf`` is below ``gtol``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import torch


class LBFGSResult(NamedTuple):
    """x (B, D) last iterates; value (B,); converged (B,) bool; iterations (B,); finite (B,) bool (False where
    f or its gradient became NaN/inf: x keeps its last finite value)."""

    x: torch.Tensor
    value: torch.Tensor
    converged: torch.Tensor
    iterations: torch.Tensor
    finite: torch.Tensor


def _value_and_grad(fn, x: torch.Tensor, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    with torch.enable_grad():
        xr = x.detach().requires_grad_(True)
        f = fn(xr, idx)
        (g,) = torch.autograd.grad(f.sum(), xr)
    return f.detach(), g.detach()


def batched_lbfgs(fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor], x0: torch.Tensor, lo: torch.Tensor,
                  hi: torch.Tensor, max_iter: int = 100, gtol: float = 1e-9, history: int = 10,
                  c1: float = 1e-4, max_backtracks: int = 12) -> LBFGSResult:
    """Minimise each ``f_b`` from ``x0[b]`` inside the box.

    Args:
        fn: ``(x, idx) -> (len(idx),)``: values of the problems ``idx`` at x (len(idx), D); differentiable.
        x0: (B, D) starting points (projected into the box).
        lo, hi: (D,) box.
        max_iter: iterations per problem.
        gtol: projected-gradient tolerance (max norm).
        history: curvature pairs kept per problem.
        c1: Armijo constant.
        max_backtracks: step halvings before a problem's line search gives up (it then stops, not converged).
    """
    b, d = x0.shape
    dev, dt = x0.device, x0.dtype
    lo, hi = lo.to(x0), hi.to(x0)
    proj = lambda v: torch.maximum(torch.minimum(v, hi), lo)  # noqa: E731
    x = proj(x0.detach().clone())
    all_idx = torch.arange(b, device=dev)
    f, g = _value_and_grad(fn, x, all_idx)
    finite = torch.isfinite(f) & torch.isfinite(g).all(-1)
    s_hist = torch.zeros(history, b, d, device=dev, dtype=dt)
    y_hist = torch.zeros_like(s_hist)
    rho = torch.zeros(history, b, device=dev, dtype=dt)
    n_hist = torch.zeros(b, dtype=torch.long, device=dev)
    iters = torch.zeros(b, dtype=torch.long, device=dev)
    t_last = torch.ones(b, device=dev, dtype=dt)  # last accepted step length per problem
    pg = (proj(x - g) - x).abs().amax(-1)
    converged = finite & (pg < gtol)
    active = finite & ~converged
    for _ in range(max_iter):
        idx = torch.nonzero(active).flatten()
        if len(idx) == 0:
            break
        xa, fa, ga = x[idx], f[idx], g[idx]
        # two-loop recursion over this problem's history (slots ordered oldest -> newest by position mod m)
        q = ga.clone()
        k = n_hist[idx]
        alphas = []
        for j in range(history):
            slot = (k - 1 - j) % history
            use = (j < k.clamp_max(history)).to(dt)
            s_j, y_j, r_j = s_hist[slot, idx], y_hist[slot, idx], rho[slot, idx]
            a_j = use * r_j * (s_j * q).sum(-1)
            q = q - a_j[:, None] * y_j
            alphas.append((slot, a_j, use))
        last = (k - 1) % history
        sy = (s_hist[last, idx] * y_hist[last, idx]).sum(-1)
        yy = (y_hist[last, idx] ** 2).sum(-1)
        gamma = torch.where(k > 0, sy / yy.clamp_min(1e-300), 1.0 / ga.abs().amax(-1).clamp_min(1.0))
        r = gamma[:, None] * q
        for slot, a_j, use in reversed(alphas):
            b_j = use * rho[slot, idx] * (y_hist[slot, idx] * r).sum(-1)
            r = r + (a_j - b_j)[:, None] * s_hist[slot, idx]
        direction = -r
        descent = (direction * ga).sum(-1) < 0
        direction = torch.where(descent[:, None], direction, -ga)
        # projected Armijo backtracking, per problem
        # a problem whose predicted decrease is below the rounding level of f cannot pass an Armijo test:
        # it is as converged as this precision allows (otherwise it would burn max_backtracks trials)
        predicted = -(ga * (proj(xa + direction) - xa)).sum(-1)
        flat = predicted <= 8 * torch.finfo(dt).eps * fa.abs()
        if flat.any():
            converged[idx[flat]] = True
            active[idx[flat]] = False
            keep_p = ~flat
            idx, xa, fa, ga, direction = idx[keep_p], xa[keep_p], fa[keep_p], ga[keep_p], direction[keep_p]
            if len(idx) == 0:
                break
        # first trial: twice the last accepted step (at most 1), so a problem whose steps keep being cut
        # (e.g. a stiff penalty) does not pay the same backtracks every iteration
        t = (2 * t_last[idx]).clamp_max(1.0)
        accepted = torch.zeros(len(idx), dtype=torch.bool, device=dev)
        x_new, f_new = xa.clone(), fa.clone()
        for _ in range(max_backtracks):
            pend = torch.nonzero(~accepted).flatten()
            if len(pend) == 0:
                break
            trial = proj(xa[pend] + t[pend, None] * direction[pend])
            with torch.no_grad():
                ft = fn(trial, idx[pend])
            slope = (ga[pend] * (trial - xa[pend])).sum(-1)  # directional derivative along the projected step
            ok = torch.isfinite(ft) & (ft <= fa[pend] + c1 * slope)
            x_new[pend[ok]], f_new[pend[ok]] = trial[ok], ft[ok]
            accepted[pend[ok]] = True
            # next step: minimiser of the quadratic through f(0), f'(0) and f(t), kept in [0.1 t, 0.5 t]
            # (plain halving where f is not finite); fewer trials than halving when t = 1 overshoots a lot
            bad = ~ok
            tb, fb, sb = t[pend[bad]], ft[bad], slope[bad]
            curv = fb - fa[pend[bad]] - sb
            t_q = torch.where(torch.isfinite(fb) & (curv > 0), -sb * tb / (2 * curv.clamp_min(1e-300)), 0.5 * tb)
            t[pend[bad]] = torch.minimum(torch.maximum(t_q, 0.1 * tb), 0.5 * tb)
        # problems whose line search failed stop where they are
        t_last[idx[accepted]] = t[accepted]
        stuck = idx[~accepted]
        active[stuck] = False
        idx, x_new, xa, ga = idx[accepted], x_new[accepted], xa[accepted], ga[accepted]
        if len(idx) == 0:
            break
        f_val, g_new = _value_and_grad(fn, x_new, idx)
        ok = torch.isfinite(f_val) & torch.isfinite(g_new).all(-1)
        finite[idx[~ok]] = False
        active[idx[~ok]] = False
        idx, x_new, xa, ga, f_val, g_new = idx[ok], x_new[ok], xa[ok], ga[ok], f_val[ok], g_new[ok]
        s, y = x_new - xa, g_new - ga
        sy = (s * y).sum(-1)
        keep = sy > 1e-12 * (s * s).sum(-1).sqrt() * (y * y).sum(-1).sqrt()
        slot = n_hist[idx] % history
        ki = idx[keep]
        s_hist[slot[keep], ki], y_hist[slot[keep], ki] = s[keep], y[keep]
        rho[slot[keep], ki] = 1.0 / sy[keep]
        n_hist[ki] += 1
        x[idx], f[idx], g[idx] = x_new, f_val, g_new
        iters[idx] += 1
        pg = (proj(x_new - g_new) - x_new).abs().amax(-1)
        done = pg < gtol
        converged[idx[done]] = True
        active[idx[done]] = False
    return LBFGSResult(x, f, converged, iters, finite)
