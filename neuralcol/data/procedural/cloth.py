"""Procedural skirt (data set ``proc_cloth``): an open cone with free-form folds, twist, sway, flare and bumps.

Generator conventions (return shapes, seeding, keyword errors): :mod:`neuralcol.data.procedural`.

Construction: an open cone (skirt) of ``n_rings`` rings of ``n_around`` vertices from the waist (radius
``waist_radius``, z = 0) to the hem (radius ``hem_radius``, z = -``height``); the ring spacing grows
geometrically with the radius so the quads stay near square, and each quad is split into two triangles
with alternating diagonals. A 2-manifold with boundary: edges of the waist and hem loops have one
triangle, all others two. Defaults: 2640 vertices, 5104 triangles.

A pose, in cylindrical coordinates (column angle t, height fraction h in [0, 1]) around the rest radius
R(h) = waist_radius + (flare hem_radius - waist_radius) h:

* folds: ``n_folds`` modes with distinct wave numbers k drawn from ``fold_k_range``, weight
  w ~ ``fold_weight_range``, phase p ~ U(0, 2 pi), phase drift d ~ U(-fold_drift, fold_drift) over the
  height (slanted folds), radial/tangential ratio r ~ ``fold_ratio_range``, grown toward the hem by h^e,
  e ~ ``fold_exponent_range``: tangential offset ``s h^e sum_k w R_hem / k sin(k t + p + d h)``, radial
  offset ``s h^e sum_k r w R_hem / k cos(k t + p + d h)``. Radial and tangential parts are a quarter period
  apart, so a too strong mode turns the cross-section into a prolate trochoid whose loops pass through
  each other: the skirt folds into itself;
* flare ~ ``flare_range`` (hem radius factor); ``n_bumps`` radial Gaussian bumps (amplitude
  ~ ``bump_range``, centre height ~ ``bump_h_range``, widths ``bump_width`` = (angle in radians, height
  fraction)); twist ``tau h^2`` about the axis, tau ~ ``twist_range`` (radians); sway of the hem
  ``h^2 (sx, sy)``, sx, sy ~ ``sway_range``.

That is 30 varying parameters with the defaults (3 x 5 per fold mode, e, s, flare, 3 x 3 bump
parameters, tau, sx, sy).

Why the data-set poses are collision free: the height depends on h only, so every ring stays in its own
horizontal plane and the surface is embedded when every ring is star-shaped around its centre (polar
angle increasing along the ring; twist and sway move a ring rigidly and keep this). For each pose the fold
scale s* where this first fails, or the radius drops below ``min_radius_frac`` R(h), is found by
bisection, and the pose uses ``s = c s*`` with c ~ ``fold_strength_range`` (< 1). Checked with MeshLab
on 1500 poses, even with c up to 0.97: none intersects. Extrapolating between poses in vertex space
(t = 1.5 / 2) intersects in about 50 % / 80 % of random pairs, scaling the folds of a pose by 1.5 / 2 in
about 45 % / 85 %.

Cloth keywords (defaults): ``n_around=88``, ``n_rings=30``, ``waist_radius=0.35``, ``hem_radius=0.75``,
``height=1.0``, ``n_folds=3``, ``fold_k_range=(3, 10)``, ``fold_weight_range=(0.3, 1.0)``,
``fold_ratio_range=(1.0, 2.2)``, ``fold_drift=1.0``, ``fold_exponent_range=(1.2, 2.0)``,
``fold_strength_range=(0.45, 0.85)``, ``min_radius_frac=0.25``, ``flare_range=(0.85, 1.15)``,
``n_bumps=3``, ``bump_range=(-0.04, 0.04)``, ``bump_h_range=(0.2, 1.0)``, ``bump_width=(0.4, 0.15)``,
``twist_range=(-0.5, 0.5)``, ``sway_range=(-0.12, 0.12)``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from neuralcol.data.procedural.options import check_n_poses, check_range, merge_kwargs
from neuralcol.errors import UserInputError

_CLOTH_DEFAULTS: dict = {
    "n_around": 88,
    "n_rings": 30,
    "waist_radius": 0.35,
    "hem_radius": 0.75,
    "height": 1.0,
    "n_folds": 3,
    "fold_k_range": (3, 10),
    "fold_weight_range": (0.3, 1.0),
    "fold_ratio_range": (1.0, 2.2),
    "fold_drift": 1.0,
    "fold_exponent_range": (1.2, 2.0),
    "fold_strength_range": (0.45, 0.85),
    "min_radius_frac": 0.25,
    "flare_range": (0.85, 1.15),
    "n_bumps": 3,
    "bump_range": (-0.04, 0.04),
    "bump_h_range": (0.2, 1.0),
    "bump_width": (0.4, 0.15),
    "twist_range": (-0.5, 0.5),
    "sway_range": (-0.12, 0.12),
}


class _ClothRest(NamedTuple):
    """Rest cone of the skirt.

    Attributes:
        theta: (A,) angle of each vertex column, radians.
        h: (R,) height fraction of each ring, 0 at the waist, 1 at the hem.
        faces: (F, 3) int64, F = 2 A (R - 1), outward oriented; vertex (i, j) has index i A + j.
    """

    theta: np.ndarray
    h: np.ndarray
    faces: np.ndarray


def _cloth_rest(p: dict) -> _ClothRest:
    """Rest grid of the skirt from merged cloth keywords ``p``."""
    who = "make_proc_cloth"
    n_a, n_r = int(p["n_around"]), int(p["n_rings"])
    r_w, r_h, height = float(p["waist_radius"]), float(p["hem_radius"]), float(p["height"])
    if n_a < 8 or n_r < 3 or min(r_w, r_h, height) <= 0:
        raise UserInputError(
            f"{who}: n_around={n_a}, n_rings={n_r}, waist_radius={r_w}, hem_radius={r_h}, height={height}; "
            "need n_around >= 8, n_rings >= 3 and positive sizes"
        )
    t = np.linspace(0.0, 1.0, n_r)
    ratio = r_h / r_w
    # geometric grading: ring spacing proportional to the local circumference, so quads stay near square
    h = t if abs(ratio - 1.0) < 1e-9 else (ratio**t - 1.0) / (ratio - 1.0)
    theta = 2.0 * np.pi * np.arange(n_a) / n_a
    i, j = (m.ravel() for m in np.meshgrid(np.arange(n_r - 1), np.arange(n_a), indexing="ij"))
    v00, v01 = i * n_a + j, i * n_a + (j + 1) % n_a
    v10, v11 = v00 + n_a, v01 + n_a
    even = ((i + j) % 2 == 0)[:, None]  # alternate the diagonals (checkerboard) for a symmetric mesh
    t1 = np.where(even, np.stack([v00, v10, v11], 1), np.stack([v00, v10, v01], 1))
    t2 = np.where(even, np.stack([v00, v11, v01], 1), np.stack([v01, v10, v11], 1))
    return _ClothRest(theta, h, np.concatenate([t1, t2]).astype(np.int64))


class _ClothParams(NamedTuple):
    """Per-pose parameters of the skirt (N poses, M fold modes, K bumps).

    Attributes:
        k: (N, M) fold wave numbers; w, phase, drift, ratio: (N, M) weight, phase, phase drift, radial ratio.
        exponent: (N,) growth exponent of the folds toward the hem.
        scale: (N,) fold scale s (the collision-free poses use c * s*).
        flare: (N,) hem radius factor.
        bump_theta, bump_h, bump_amp: (N, K) centres and amplitudes of the radial bumps.
        twist: (N,) twist at the hem (radians). sway: (N, 2) hem offset.
    """

    k: np.ndarray
    w: np.ndarray
    phase: np.ndarray
    drift: np.ndarray
    ratio: np.ndarray
    exponent: np.ndarray
    scale: np.ndarray
    flare: np.ndarray
    bump_theta: np.ndarray
    bump_h: np.ndarray
    bump_amp: np.ndarray
    twist: np.ndarray
    sway: np.ndarray


def _cloth_fields(p: dict, rest: _ClothRest, q: _ClothParams) -> tuple[np.ndarray, ...]:
    """Unscaled fold fields and the base radius of every vertex.

    Returns:
        radius (N, R, A) rest radius with flare and bumps, fold_r and fold_t (N, R, A) radial and
        tangential fold offsets for scale 1, ring radius (N, R, 1) without bumps.
    """
    th = rest.theta[None, None, :, None]  # (1, 1, A, 1)
    h = rest.h[None, :, None, None]  # (1, R, 1, 1)
    r_w = float(p["waist_radius"])
    r_hem = float(p["hem_radius"]) * q.flare  # (N,)
    ring = r_w + (r_hem[:, None] - r_w) * rest.h[None, :]  # (N, R)
    arg = q.k[:, None, None, :] * th + q.phase[:, None, None, :] + q.drift[:, None, None, :] * h
    # arg: (N, R, A, M)
    amp = q.w * r_hem[:, None] / q.k  # (N, M) tangential amplitude at scale 1
    grow = rest.h[None, :, None] ** q.exponent[:, None, None]  # (N, R, 1)
    fold_t = grow * np.einsum("nram,nm->nra", np.sin(arg), amp)
    fold_r = grow * np.einsum("nram,nm->nra", np.cos(arg), amp * q.ratio)
    sw_t, sw_h = (float(x) for x in p["bump_width"])
    dth = np.cos(rest.theta[None, None, :, None] - q.bump_theta[:, None, None, :]) - 1.0  # (N, 1, A, K)
    dh = rest.h[None, :, None, None] - q.bump_h[:, None, None, :]  # (N, R, 1, K)
    bumps = (q.bump_amp[:, None, None, :] * np.exp(dth / sw_t**2 - 0.5 * (dh / sw_h) ** 2)).sum(-1)
    return ring[:, :, None] + bumps, fold_r, fold_t, ring[:, :, None]


def _star_shaped(radius: np.ndarray, fold_r: np.ndarray, fold_t: np.ndarray, ring: np.ndarray, s: np.ndarray,
                 min_frac: float) -> np.ndarray:
    """Whether every ring stays star-shaped at fold scale s (N,): polar angle increasing, radius kept.

    Args:
        radius, fold_r, fold_t: (N, R, A) from :func:`_cloth_fields`; ring: (N, R, 1).
        s: (N,) fold scale.
        min_frac: smallest allowed radius as a fraction of the ring radius.

    Returns:
        (N,) bool.
    """
    rho = radius + s[:, None, None] * fold_r
    dpsi = np.arctan2(s[:, None, None] * fold_t, rho)  # polar angle offset from the column angle
    n_a = rho.shape[-1]
    step = 2.0 * np.pi / n_a + np.roll(dpsi, -1, axis=-1) - dpsi  # (N, R, A) polar-angle increment
    step = (step + np.pi) % (2.0 * np.pi) - np.pi
    return (step > 0).all(axis=(1, 2)) & (rho >= min_frac * ring).all(axis=(1, 2))


def _sample_cloth_params(p: dict, rest: _ClothRest, n: int, rng: np.random.Generator) -> _ClothParams:
    """Draw n collision-free skirt poses (fold scale set to c times the critical scale)."""
    who = "make_proc_cloth"
    m = int(p["n_folds"])
    k_lo, k_hi = (int(x) for x in p["fold_k_range"])
    if m < 1 or k_lo < 1 or k_hi - k_lo + 1 < m:
        raise UserInputError(
            f"{who}: n_folds={m}, fold_k_range=({k_lo}, {k_hi}); need n_folds >= 1 distinct wave numbers "
            ">= 1 in the range"
        )
    ks = np.argsort(rng.random((n, k_hi - k_lo + 1)), axis=1)[:, :m] + k_lo
    u = {key: check_range(p, key, who) for key in (
        "fold_weight_range", "fold_ratio_range", "fold_exponent_range", "fold_strength_range", "flare_range",
        "bump_range", "bump_h_range", "twist_range", "sway_range")}

    def draw(key: str, shape) -> np.ndarray:
        lo, hi = u[key]
        return lo + (hi - lo) * rng.random(shape)

    d = float(p["fold_drift"])
    nb = int(p["n_bumps"])
    q = _ClothParams(
        k=ks.astype(np.float64), w=draw("fold_weight_range", (n, m)), phase=2 * np.pi * rng.random((n, m)),
        drift=d * (2 * rng.random((n, m)) - 1), ratio=draw("fold_ratio_range", (n, m)),
        exponent=draw("fold_exponent_range", n), scale=np.zeros(n), flare=draw("flare_range", n),
        bump_theta=2 * np.pi * rng.random((n, nb)), bump_h=draw("bump_h_range", (n, nb)),
        bump_amp=draw("bump_range", (n, nb)), twist=draw("twist_range", n), sway=draw("sway_range", (n, 2)),
    )
    strength = draw("fold_strength_range", n)
    c_lo, c_hi = u["fold_strength_range"]
    if not 0 <= c_lo <= c_hi < 1:
        raise UserInputError(f"{who}: fold_strength_range=({c_lo}, {c_hi}); need 0 <= lo <= hi < 1")
    min_frac = float(p["min_radius_frac"])
    radius, fold_r, fold_t, ring = _cloth_fields(p, rest, q)
    if not _star_shaped(radius, fold_r, fold_t, ring, np.zeros(n), min_frac).all():
        raise UserInputError(
            f"{who}: the bumps alone (bump_range={u['bump_range']}) make a ring non star-shaped or too thin; "
            "lower bump_range or min_radius_frac"
        )
    lo, hi = np.zeros(n), np.ones(n)
    for _ in range(60):  # double hi until every pose folds through (s* < hi); 60 doublings is far enough
        ok = _star_shaped(radius, fold_r, fold_t, ring, hi, min_frac)
        if not ok.any():
            break
        hi = np.where(ok, 2 * hi, hi)
    for _ in range(40):  # bisection for the critical scale s*, relative precision 2^-40
        mid = 0.5 * (lo + hi)
        ok = _star_shaped(radius, fold_r, fold_t, ring, mid, min_frac)
        lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
    return q._replace(scale=strength * lo)


def _pose_cloth(p: dict, rest: _ClothRest, q: _ClothParams) -> np.ndarray:
    """Vertices (N, R * A, 3) of the skirt poses ``q``."""
    radius, fold_r, fold_t, _ = _cloth_fields(p, rest, q)
    rho = radius + q.scale[:, None, None] * fold_r  # (N, R, A)
    tan = q.scale[:, None, None] * fold_t
    ang = rest.theta[None, None, :] + q.twist[:, None, None] * rest.h[None, :, None] ** 2  # (N, R, A)
    c, s = np.cos(ang), np.sin(ang)
    hh = rest.h[None, :, None] ** 2
    x = rho * c - tan * s + q.sway[:, 0, None, None] * hh
    y = rho * s + tan * c + q.sway[:, 1, None, None] * hh
    z = np.broadcast_to(-float(p["height"]) * rest.h[None, :, None], x.shape)
    return np.stack([x, y, z], axis=-1).reshape(len(x), -1, 3)


def make_proc_cloth(n_poses: int = 100, seed: int = 0, **geometry_kwargs) -> tuple[np.ndarray, np.ndarray]:
    """Procedural skirt: an open cone with free-form folds, twist, sway, flare and bumps.

    Args:
        n_poses: number of poses N.
        seed: seed of ``np.random.default_rng``; same arguments give bit-identical output.
        **geometry_kwargs: geometry and pose-range settings, see the module docstring.

    Returns:
        vertices (N, V, 3) float64 and faces (F, 3) int64 (V = n_around * n_rings = 2640 and F = 5104 with
        the defaults; a 2-manifold with two boundary loops).
    """
    check_n_poses(n_poses, "make_proc_cloth")
    p = merge_kwargs(_CLOTH_DEFAULTS, geometry_kwargs, "make_proc_cloth", __name__)
    rest = _cloth_rest(p)
    rng = np.random.default_rng(seed)
    q = _sample_cloth_params(p, rest, int(n_poses), rng)
    return _pose_cloth(p, rest, q), rest.faces.copy()
