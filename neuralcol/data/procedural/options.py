"""Keyword handling shared by the procedural generators."""

from __future__ import annotations

from neuralcol.errors import UserInputError


def merge_kwargs(defaults: dict, given: dict, who: str, doc_module: str) -> dict:
    """``defaults`` updated with ``given``; an unknown key raises UserInputError naming ``doc_module``."""
    unknown = sorted(set(given) - set(defaults))
    if unknown:
        raise UserInputError(
            f"{who}: unknown keyword argument(s) {unknown}; valid ones are {sorted(defaults)} "
            f"(see the {doc_module} module docstring)"
        )
    out = dict(defaults)
    out.update(given)
    return out


def check_n_poses(n_poses: int, who: str) -> None:
    """Raise UserInputError unless ``n_poses`` is an integer >= 1."""
    if int(n_poses) != n_poses or n_poses < 1:
        raise UserInputError(f"{who}: n_poses={n_poses!r}; must be an integer >= 1")


def check_range(p: dict, key: str, who: str, nonneg: bool = False) -> tuple[float, float]:
    """``p[key]`` as a float range (lo, hi); UserInputError unless lo <= hi (and lo >= 0 if ``nonneg``)."""
    lo, hi = (float(x) for x in p[key])
    if not lo <= hi or (nonneg and lo < 0):
        need = "lo <= hi and lo >= 0" if nonneg else "lo <= hi"
        raise UserInputError(f"{who}: {key}=({lo}, {hi}) is not a valid range; need {need}")
    return lo, hi
