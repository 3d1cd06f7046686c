"""Stage: fit the box Z so that U(Z) is worth sampling (docs/autoencoder.md "The box Z").

The paper's box is ``[min, max]`` of the training meshes' codes in each entry (sec. 4.1). How much of it decodes to
self-intersecting meshes is a fact of the latent space, not of the data: SCAPE's meshes give 27 % in the bilevel
space and 64 % in vertex PCA's, whose corners combine every component's extreme; a simulated skirt's bilevel box was
100 %. A margin tuned per data set does not carry over to data nobody tuned for, so the box is fitted to a probe:

1. label a probe of ``U(Z)`` (``n`` codes, one seed) of the paper's box;
2. its colliding share in ``band``: keep the box;
3. above the band: scale the box about its centre by each factor of ``shrink`` in turn (below it: ``grow``), the
   same uniform draws mapped into each box, until a probe lies in the band;
4. none does: the factor whose share is nearest the band (``box_check`` then judges it as before).

:func:`fit_box` changes no space: each trial probes a copy with the scaled box (:func:`boxed`), and the caller makes
the fitted space from the returned factor (:func:`fitted_space`), a new object beside the paper box's.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch

from neuralcol.nn.latent_box import with_box


def scaled_box(lo: torch.Tensor, hi: torch.Tensor, factor: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The box ``[lo, hi]`` scaled about its centre by ``factor`` (1: unchanged; 0.5: half the width)."""
    centre, half = (lo + hi) / 2, (hi - lo) / 2 * float(factor)
    return centre - half, centre + half


def boxed(space, lo: torch.Tensor, hi: torch.Tensor, factor: float):
    """``space`` with the box ``[lo, hi]`` scaled by ``factor`` (:func:`scaled_box`): a new space object
    (:func:`~neuralcol.nn.latent_box.with_box`); ``space`` is unchanged."""
    return with_box(space, *scaled_box(lo, hi, factor))


def fitted_space(space, factor: float):
    """``space`` with its own box scaled by ``factor`` (the fitted space of :func:`fit_box`'s factor); a new object."""
    return boxed(space, space.box_lo.detach().clone(), space.box_hi.detach().clone(), factor)


def band_distance(share: float | None, band: Sequence[float]) -> float:
    """How far ``share`` lies outside ``band`` (0 inside; inf when nothing was labeled)."""
    if share is None:
        return float("inf")
    return max(float(band[0]) - share, share - float(band[1]), 0.0)


def check_ladder(band: Sequence[float], shrink: Sequence[float], grow: Sequence[float]) -> None:
    """Raise ValueError (naming the setting) on a band or ladder the fit cannot use."""
    if len(band) != 2 or not 0.0 <= float(band[0]) < float(band[1]) <= 1.0:
        raise ValueError(f"box_fit.band={list(band)}; give [low, high] with 0 <= low < high <= 1, e.g. [0.10, 0.55]")
    if any(not 0.0 < float(f) < 1.0 for f in shrink):
        raise ValueError(f"box_fit.shrink={list(shrink)}; every factor must lie in (0, 1), e.g. [0.9, 0.8, 0.7]")
    if any(float(f) <= 1.0 for f in grow):
        raise ValueError(f"box_fit.grow={list(grow)}; every factor must be above 1, e.g. [1.25, 1.5, 2.0]")


def fit_box(space, probe: Callable[[object], dict], band: Sequence[float], shrink: Sequence[float],
            grow: Sequence[float]) -> dict:
    """Fit ``space``'s box to ``band`` (see the module's steps); ``space`` is not changed.

    Args:
        space: a latent space (:class:`~neuralcol.nn.latent_box.LatentBox`).
        probe: ``space -> {"collision_share", ...}`` labeling a fixed probe of the given space's ``U(Z)``
            (:func:`~neuralcol.stages.box_check.probe_share` with a fixed seed).
        band: [low, high] colliding share of a box worth sampling.
        shrink, grow: factors tried in order when the paper's box is above / below the band.

    Returns:
        ``{"factor", "in_band", "band", "trials": [{"factor", **probe}, ...]}``; ``trials[-1]`` need not be the
        chosen box's probe (when no factor reached the band). :func:`fitted_space` makes the space of ``factor``.
    """
    check_ladder(band, shrink, grow)
    lo0, hi0 = space.box_lo.detach().clone(), space.box_hi.detach().clone()
    trials = []

    def trial(factor: float) -> float | None:
        result = probe(boxed(space, lo0, hi0, factor))
        trials.append({"factor": float(factor), **result})
        return result["collision_share"]

    share = trial(1.0)
    if share is not None and band_distance(share, band) > 0:
        above = share > float(band[1])
        for factor in (shrink if above else grow):
            share = trial(factor)
            if share is None or band_distance(share, band) == 0 or (share < float(band[0])) == above:
                break  # in the band, or crossed it: more of the ladder only moves further away
    best = min(trials, key=lambda t: (band_distance(t["collision_share"], band), abs(t["factor"] - 1.0)))
    return {"factor": best["factor"], "in_band": band_distance(best["collision_share"], band) == 0,
            "band": [float(b) for b in band], "trials": trials}


def fitted_key(key: str, factor: float) -> str:
    """Cache key of a latent space whose box was scaled by ``factor`` (``key`` itself for the paper's box)."""
    return key if float(factor) == 1.0 else f"{key}-box{float(factor):g}"
