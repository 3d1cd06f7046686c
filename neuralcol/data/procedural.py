"""Procedural mesh data sets that need no download: an articulated hand and a folded skirt.

Both generators return ``vertices (N, V, 3) float64`` and ``faces (F, 3) int64`` (one topology for all
poses), are deterministic by ``seed`` (``np.random.default_rng(seed)``, no global RNG) and take their
geometry and pose-range settings as keyword arguments; an unknown keyword raises
:class:`~neuralcol.errors.UserInputError` listing the valid ones. Units are arbitrary (palm width 0.89,
skirt height 1). 100 poses take well under a second each.

proc_hand (:func:`make_proc_hand`)
----------------------------------
Construction (box modelling, one Catmull-Clark step): the palm is the surface of a box lattice of
11 x 6 x 4 cells with non-uniform spacing: x across the palm (thumb side at x = 0), y from the wrist
(y = 0) to the knuckles (y = ``palm_length``), z from the palmar (z = 0) to the dorsal side (z =
``palm_thickness``). Index, middle, ring and little finger are extruded (+y) from 2 x 2-cell patches of
the top face, separated by ``finger_gap``; the thumb from a 2 x 2-cell patch of the side face x = 0 at
``thumb_base_y`` above the wrist, pointing ``thumb_angle`` degrees above -x. Each tube has
``rings_per_finger`` rings of 8 control vertices on an elliptic cross-section (``ring_scale`` x the
patch, tapering to ``tip_taper`` at the tip) and is closed by the removed patch itself, moved to the tip
(``tip_round`` x the half size beyond the last ring). This control mesh is a closed, consistently
oriented genus-0 quad mesh; one Catmull-Clark step (V' = 4 Q + 2 for Q control quads), ``smooth_iters``
Taubin iterations (``taubin_lambda``, ``taubin_mu``) on the rest shape, and a split of every quad along
its shorter diagonal give a closed, watertight, outward-oriented 2-manifold with one component:
2514 vertices and 5024 triangles with the defaults.

Skeleton and skinning: 17 bones: the palm (root), an ulnar palm bone (hinge along +y on the palmar
surface through the middle-ring gap; angle ``cup`` folds the ring/little side toward the palm), and for
each chain (index, middle, ring, little, thumb) three bones (proximal/middle/distal phalanx; thumb:
metacarpal/proximal/distal). Joint 0 (MCP; thumb CMC) has two axes: flexion about the chain's lateral
axis (positive curls toward the palmar side, -z) and abduction about the palm normal z (positive turns
toward the thumb side, -x; for the thumb positive turns it away from the index). Joints 1 and 2 (PIP, DIP;
thumb MCP, IP) are flexion hinges. Joint centres lie on the chain axis, shifted ``joint_palmar_offset``
x the half thickness toward the palmar side (so the palmar skin is not crushed when bending); joint 0
sits ``blend`` x the half thickness beyond the tube base. Ring and little finger hang off the ulnar
bone, the other chains off the root. Linear blend skinning: along a chain two consecutive bones are
blended by a cubic smoothstep over +- ``blend`` x the finger's half thickness around each joint (blend
zones never overlap, so a finger vertex has at most two chain bones); the palm blends root and ulnar
bone across +- ``cup_blend`` x palm width; membership of a vertex in a chain is carried through the
subdivision as a soft label, so weights are continuous across the finger bases (a few vertices there
mix three bones).

Degrees of freedom: 21 angles, all varying, in this order
``[index, middle, ring, little, thumb] x [j0 flexion, j0 abduction, j1 flexion, j2 flexion] + [cup]``.
Sampling (ranges in degrees): a global closure ``g ~ U(0, 1)``, per chain
``c = clip(g + closure_spread N(0, 1), 0, 1)`` and per joint ``q = clip(c + joint_noise N(0, 1), 0, 1)``;
a flexion is ``lo + q (hi - lo)`` with (lo, hi) = ``mcp_range``, ``pip_range``, ``dip_range`` (fingers),
``thumb_cmc_flex_range``, ``thumb_mcp_range``, ``thumb_ip_range`` (thumb), and ``cup_range`` (with its own
noise). Spread: the middle finger's abduction ~ ``middle_abduction_range``; the angles between
neighbouring fingers (index-middle, middle-ring, ring-little) are ``lo + s (hi - lo)`` from
``spread_range`` with a common ``s ~ U(0, 1)`` plus ``spread_noise`` N(0, 1), clipped to [0, 1]; the
thumb's in-plane CMC angle ~ ``thumb_cmc_abduction_range``.

Why the data-set poses are collision free: at rest the fingers are parallel and separated by a small
gap; the spread angles are >= 0 so neighbouring fingers fan out and never converge; a finger flexes in
its own plane; the joint offset and blend width keep the bent joints free of skinning fold-overs; and
every drawn pose is also checked on a capsule proxy (each bone a segment of radius ``capsule_scale`` x
the finger's half size): a pose where capsules of two chains, or a middle/distal bone and the palm box,
come closer than ``clearance`` is redrawn (about 40 % are; after ``max_draws`` rounds an error is
raised). Checked with MeshLab's self-intersection filter on 1500 poses (5 seeds): none intersects.
Going beyond the poses makes the hand collide: linear extrapolation between two poses in vertex space
(``a + t (b - a)``, t = 1.5 / 2) intersects in about 35 % / 55 % of random pairs, scaling a pose's
angles by 1.5 / 2 in about 40 % / 65 % (neighbouring fingers converge and cross, fingertips reach the
palm, the thumb folds into the palm).

Hand keywords (defaults): ``finger_widths=(0.22, 0.23, 0.22, 0.19)`` (index, middle, ring, little),
``finger_gap=0.01``, ``finger_lengths=(0.8, 0.9, 0.85, 0.65)``, ``finger_thickness=0.2``,
``palm_length=0.95``, ``palm_thickness=0.3``, ``thumb_width=0.22``, ``thumb_length=0.72``,
``thumb_base_y=0.1``, ``thumb_angle=35.0`` (degrees), ``phalanx_ratios=(0.45, 0.3, 0.25)``,
``thumb_ratios=(0.4, 0.33, 0.27)``, ``tip_taper=0.9``, ``tip_round=0.6``, ``ring_scale=1.1``,
``rings_per_finger=9``, ``smooth_iters=3``, ``taubin_lambda=0.5``, ``taubin_mu=-0.53``, ``blend=1.2``,
``joint_palmar_offset=0.5``, ``cup_blend=0.2``; pose ranges in degrees: ``mcp_range=(-10, 70)``,
``pip_range=(0, 85)``, ``dip_range=(0, 55)``, ``middle_abduction_range=(-6, 6)``,
``spread_range=(0, 25)``, ``thumb_cmc_flex_range=(0, 40)``, ``thumb_cmc_abduction_range=(-10, 25)``,
``thumb_mcp_range=(0, 35)``, ``thumb_ip_range=(0, 50)``, ``cup_range=(0, 12)``; sampling:
``closure_spread=0.25``, ``joint_noise=0.2``, ``spread_noise=0.25``, ``capsule_scale=0.9``,
``clearance=0.02``, ``max_draws=50``.

proc_cloth (:func:`make_proc_cloth`)
------------------------------------
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

from neuralcol.errors import UserInputError

# --------------------------------------------------------------------------------------------------
# keyword handling

_HAND_DEFAULTS: dict = {
    # geometry
    "finger_widths": (0.22, 0.23, 0.22, 0.19),
    "finger_gap": 0.01,
    "finger_lengths": (0.8, 0.9, 0.85, 0.65),
    "finger_thickness": 0.2,
    "palm_length": 0.95,
    "palm_thickness": 0.3,
    "thumb_width": 0.22,
    "thumb_length": 0.72,
    "thumb_base_y": 0.1,
    "thumb_angle": 35.0,
    "phalanx_ratios": (0.45, 0.3, 0.25),
    "thumb_ratios": (0.4, 0.33, 0.27),
    "tip_taper": 0.9,
    "tip_round": 0.6,
    "ring_scale": 1.1,
    "rings_per_finger": 9,
    "smooth_iters": 3,
    "taubin_lambda": 0.5,
    "taubin_mu": -0.53,
    "blend": 1.2,
    "joint_palmar_offset": 0.5,
    "cup_blend": 0.2,
    # pose ranges, degrees
    "mcp_range": (-10.0, 70.0),
    "pip_range": (0.0, 85.0),
    "dip_range": (0.0, 55.0),
    "middle_abduction_range": (-6.0, 6.0),
    "spread_range": (0.0, 25.0),
    "thumb_cmc_flex_range": (0.0, 40.0),
    "thumb_cmc_abduction_range": (-10.0, 25.0),
    "thumb_mcp_range": (0.0, 35.0),
    "thumb_ip_range": (0.0, 50.0),
    "cup_range": (0.0, 12.0),
    "closure_spread": 0.25,
    "joint_noise": 0.2,
    "spread_noise": 0.25,
    # collision-free sampling
    "capsule_scale": 0.9,
    "clearance": 0.02,
    "max_draws": 50,
}

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


def _merge_kwargs(defaults: dict, given: dict, who: str) -> dict:
    unknown = sorted(set(given) - set(defaults))
    if unknown:
        raise UserInputError(
            f"{who}: unknown keyword argument(s) {unknown}; valid ones are {sorted(defaults)} "
            "(see the neuralcol.data.procedural module docstring)"
        )
    out = dict(defaults)
    out.update(given)
    return out


def _check_n_poses(n_poses: int, who: str) -> None:
    if int(n_poses) != n_poses or n_poses < 1:
        raise UserInputError(f"{who}: n_poses={n_poses!r}; must be an integer >= 1")


def _range(p: dict, key: str, who: str, nonneg: bool = False) -> tuple[float, float]:
    lo, hi = (float(x) for x in p[key])
    if not lo <= hi or (nonneg and lo < 0):
        need = "lo <= hi and lo >= 0" if nonneg else "lo <= hi"
        raise UserInputError(f"{who}: {key}=({lo}, {hi}) is not a valid range; need {need}")
    return lo, hi


# --------------------------------------------------------------------------------------------------
# small geometry helpers (pure, private)


def _smoothstep01(t: np.ndarray) -> np.ndarray:
    """Cubic smoothstep of t clipped to [0, 1]; same shape as t."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices about one unit axis.

    Args:
        axis: (3,) unit vector.
        angle: (N,) radians.

    Returns:
        (N, 3, 3) float64.
    """
    k = np.asarray(axis, dtype=np.float64)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * kx + (1.0 - c) * (kx @ kx)


def _rot_about(point: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """Affine maps x -> point + R (x - point) as (N, 3, 4) from rotations (N, 3, 3) and point (3,)."""
    t = point - rot @ point  # (N, 3)
    return np.concatenate([rot, t[..., None]], axis=-1)


def _compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Affine composition a o b of (N, 3, 4) maps; returns (N, 3, 4)."""
    rot = a[..., :3] @ b[..., :3]
    t = a[..., :3] @ b[..., 3:] + a[..., 3:]
    return np.concatenate([rot, t], axis=-1)


def _apply(aff: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply (..., 3, 4) affine maps to (..., P, 3) points; returns (..., P, 3)."""
    return pts @ np.swapaxes(aff[..., :3], -1, -2) + aff[..., None, :, 3]


def _box_lattice(xs: np.ndarray, ys: np.ndarray, zs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface quads of a box lattice with outward orientation.

    Args:
        xs, ys, zs: (n_a + 1,) increasing lattice coordinates along each axis.

    Returns:
        verts (V, 3), quads (Q, 4) int64 (counter-clockwise seen from outside), grid (nx+1, ny+1, nz+1)
        int64 vertex index of each lattice point (-1 inside).
    """
    coords = (xs, ys, zs)
    n = tuple(len(c) - 1 for c in coords)
    ii, jj, kk = np.meshgrid(*(np.arange(m + 1) for m in n), indexing="ij")
    surf = (ii == 0) | (ii == n[0]) | (jj == 0) | (jj == n[1]) | (kk == 0) | (kk == n[2])
    grid = np.full(surf.shape, -1, dtype=np.int64)
    grid[surf] = np.arange(int(surf.sum()))
    verts = np.stack([xs[ii[surf]], ys[jj[surf]], zs[kk[surf]]], axis=-1)
    quads = []
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        ib, ic = (m.ravel() for m in np.meshgrid(np.arange(n[b]), np.arange(n[c]), indexing="ij"))
        for side, sign in ((0, -1), (n[a], 1)):
            def at(db: int, dc: int, side=side, ib=ib, ic=ic, a=a, b=b, c=c) -> np.ndarray:
                idx = [None, None, None]
                idx[a], idx[b], idx[c] = np.full_like(ib, side), ib + db, ic + dc
                return grid[idx[0], idx[1], idx[2]]

            q = np.stack([at(0, 0), at(1, 0), at(1, 1), at(0, 1)], axis=1)  # normal e_b x e_c = +e_a
            quads.append(q if sign > 0 else q[:, ::-1])
    return verts, np.concatenate(quads).astype(np.int64), grid


def _catmull_clark(verts: np.ndarray, quads: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One Catmull-Clark step on a closed quad mesh; also subdivides any extra vertex attributes.

    Args:
        verts: (V, D) float, positions in the first 3 columns (all columns are subdivided linearly).
        quads: (Q, 4) int, closed 2-manifold.

    Returns:
        verts (V + E + Q, D) ordered [vertex points, edge points, face points], quads (4 Q, 4).
    """
    nv, nq = len(verts), len(quads)
    half = np.stack([quads, np.roll(quads, -1, axis=1)], axis=-1).reshape(-1, 2)  # (4Q, 2)
    edges, inv = np.unique(np.sort(half, axis=1), axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    ne = len(edges)
    if not np.all(np.bincount(inv, minlength=ne) == 2):
        raise ValueError("catmull_clark: control mesh is not closed 2-manifold (an edge without two quads)")
    fp = verts[quads].mean(axis=1)  # (Q, D)
    fsum = np.zeros((ne, verts.shape[1]))
    np.add.at(fsum, inv, np.repeat(fp, 4, axis=0))
    ep = (verts[edges[:, 0]] + verts[edges[:, 1]] + fsum) / 4.0
    val = np.bincount(edges.ravel(), minlength=nv).astype(np.float64)  # valence = incident faces (closed)
    qsum = np.zeros_like(verts)
    np.add.at(qsum, quads.ravel(), np.repeat(fp, 4, axis=0))
    mid = 0.5 * (verts[edges[:, 0]] + verts[edges[:, 1]])
    rsum = np.zeros_like(verts)
    np.add.at(rsum, edges[:, 0], mid)
    np.add.at(rsum, edges[:, 1], mid)
    n = val[:, None]
    vp = (qsum / n + 2.0 * rsum / n + (n - 3.0) * verts) / n
    e_of = inv.reshape(nq, 4)  # edge (c, c+1) of each quad corner c
    fidx = nv + ne + np.arange(nq)
    new_quads = np.concatenate(
        [np.stack([quads[:, c], nv + e_of[:, c], fidx, nv + e_of[:, (c - 1) % 4]], axis=1) for c in range(4)]
    )
    return np.concatenate([vp, ep, fp]), new_quads.astype(np.int64)


def _triangulate(verts: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Split quads (Q, 4) along the shorter diagonal of ``verts`` (V, 3); returns (2Q, 3) int64 faces."""
    a, b, c, d = quads.T
    d_ac = np.linalg.norm(verts[a] - verts[c], axis=1)
    d_bd = np.linalg.norm(verts[b] - verts[d], axis=1)
    use_ac = (d_ac <= d_bd)[:, None]
    t1 = np.where(use_ac, np.stack([a, b, c], 1), np.stack([a, b, d], 1))
    t2 = np.where(use_ac, np.stack([a, c, d], 1), np.stack([b, c, d], 1))
    return np.concatenate([t1, t2]).astype(np.int64)


def _taubin(verts: np.ndarray, faces: np.ndarray, iters: int, lam: float, mu: float) -> np.ndarray:
    """Taubin lambda/mu smoothing with the uniform Laplacian; verts (V, 3), faces (F, 3) -> (V, 3)."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    e = np.unique(e, axis=0)
    deg = np.bincount(e.ravel(), minlength=len(verts)).astype(np.float64)[:, None]
    out = verts.copy()
    for _ in range(iters):
        for f in (lam, mu):
            s = np.zeros_like(out)
            np.add.at(s, e[:, 0], out[e[:, 1]])
            np.add.at(s, e[:, 1], out[e[:, 0]])
            out = out + f * (s / deg - out)
    return out


def _patch_loop(quads: np.ndarray, patch: np.ndarray) -> np.ndarray:
    """Boundary loop of a quad patch, in the patch's orientation.

    Args:
        quads: (Q, 4) all quads.
        patch: (P,) indices into quads forming a disk.

    Returns:
        (L,) vertex indices; the patch quads traverse edge loop[j] -> loop[j+1].
    """
    q = quads[patch]
    half = np.stack([q, np.roll(q, -1, axis=1)], axis=-1).reshape(-1, 2)
    hs = {tuple(h) for h in half.tolist()}
    nxt = {a: b for a, b in half.tolist() if (b, a) not in hs}
    start = min(nxt)
    loop = [start]
    while nxt[loop[-1]] != start:
        loop.append(nxt[loop[-1]])
        if len(loop) > len(nxt):
            raise ValueError("patch boundary is not a single loop")
    return np.asarray(loop, dtype=np.int64)


# --------------------------------------------------------------------------------------------------
# proc_hand

_N_CHAINS = 5  # index, middle, ring, little, thumb
_N_BONES = 2 + 3 * _N_CHAINS
_N_HAND_DOF = 4 * _N_CHAINS + 1


class _HandRig(NamedTuple):
    """Rest mesh and skeleton of the procedural hand (all rest-pose coordinates).

    Attributes:
        rest: (V, 3) rest vertices.
        faces: (F, 3) int64.
        weights: (V, 17) skinning weights, rows sum to 1.
        origin: (5, 3) chain base point (patch centre) per chain.
        joint_origin: (5, 3) point of the chain's joint line (origin moved toward the palmar side).
        axis: (5, 3) unit chain direction.
        flex_axis: (5, 3) unit flexion axis (positive angle curls toward the palmar side, -z).
        joints: (5, 3) joint positions along the chain axis (arc length from origin).
        length: (5,) tube length (origin to tip).
        radius: (5,) capsule radius of the chain.
        parent: (5,) parent bone of joint 0 (0 palm root, 1 ulnar palm).
        cup_point: (3,) point on the ulnar hinge (axis +y).
        palm_box: (2, 3) palm box corners (min, max).
    """

    rest: np.ndarray
    faces: np.ndarray
    weights: np.ndarray
    origin: np.ndarray
    joint_origin: np.ndarray
    axis: np.ndarray
    flex_axis: np.ndarray
    joints: np.ndarray
    length: np.ndarray
    radius: np.ndarray
    parent: np.ndarray
    cup_point: np.ndarray
    palm_box: np.ndarray


def _build_hand_rig(p: dict) -> _HandRig:
    """Build rest mesh, skeleton and skinning weights from merged hand keywords ``p``."""
    who = "make_proc_hand"
    fw = np.asarray(p["finger_widths"], dtype=np.float64)
    fl = np.asarray(p["finger_lengths"], dtype=np.float64)
    if fw.shape != (4,) or fl.shape != (4,) or np.any(fw <= 0) or np.any(fl <= 0):
        raise UserInputError(
            f"{who}: finger_widths={tuple(fw.tolist())}, finger_lengths={tuple(fl.tolist())}; "
            "need 4 positive values each (index, middle, ring, little)"
        )
    gap, t_palm, l_palm = float(p["finger_gap"]), float(p["palm_thickness"]), float(p["palm_length"])
    thick, tw, tl = float(p["finger_thickness"]), float(p["thumb_width"]), float(p["thumb_length"])
    ty0 = float(p["thumb_base_y"])
    m = int(p["rings_per_finger"])
    if min(gap, t_palm, l_palm, thick, tw, tl, ty0) <= 0 or thick >= t_palm or m < 3:
        raise UserInputError(
            f"{who}: need positive sizes, finger_thickness ({thick}) < palm_thickness ({t_palm}) and "
            f"rings_per_finger ({m}) >= 3"
        )
    if ty0 + tw >= l_palm:
        raise UserInputError(
            f"{who}: thumb_base_y + thumb_width = {ty0 + tw:.3g} must stay below palm_length ({l_palm:.3g}) "
            "so the thumb patch fits on the palm side"
        )
    # lattice: x = [f0 f0 gap f1 f1 gap f2 f2 gap f3 f3], y = [0, thumb patch (2 cells), 3 rows], z 4 cells
    dx = []
    for f in range(4):
        dx += [fw[f] / 2, fw[f] / 2] + ([gap] if f < 3 else [])
    xs = np.concatenate([[0.0], np.cumsum(dx)])
    y_top_thumb = ty0 + tw
    ys = np.concatenate([[0.0, ty0, ty0 + tw / 2, y_top_thumb], np.linspace(y_top_thumb, l_palm, 4)[1:]])
    zc = 0.5 * t_palm
    zs = np.array([0.0, zc - thick / 2, zc, zc + thick / 2, t_palm])
    verts, quads, grid = _box_lattice(xs, ys, zs)
    ny = len(ys) - 1

    beta = np.deg2rad(float(p["thumb_angle"]))
    a_thumb = np.array([-np.cos(beta), np.sin(beta), 0.0])
    e1_thumb = np.array([np.sin(beta), np.cos(beta), 0.0])
    ez = np.array([0.0, 0.0, 1.0])
    chains = []  # (patch grid points 3x3, patch axes u, v, ring frame e1, e2, axis, length, half sizes)
    for f in range(4):
        i0 = 3 * f
        pts = grid[i0:i0 + 3, ny, 1:4]
        chains.append((pts, np.array([1.0, 0, 0]), ez, np.array([1.0, 0, 0]), ez, np.array([0, 1.0, 0]),
                       fl[f], fw[f] / 2, thick / 2))
    pts = grid[0, 1:4, 1:4]
    chains.append((pts, np.array([0, 1.0, 0]), ez, e1_thumb, ez, a_thumb, tl, tw / 2, thick / 2))

    verts = list(verts)
    label = [-1] * len(verts)
    keep = np.ones(len(quads), dtype=bool)
    new_quads = []
    taper, ring_scale = float(p["tip_taper"]), float(p["ring_scale"])
    origin, joint_origin, axis, flex_axis, joints, length, radius = [], [], [], [], [], [], []
    blend = float(p["blend"])
    for c, (pts, pu, pv, e1, e2, a, tube_len, wh, th) in enumerate(chains):
        pset = set(pts.ravel().tolist())
        patch = np.nonzero([set(q) <= pset for q in quads.tolist()])[0]
        if len(patch) != 4:
            raise ValueError(f"internal: finger patch {c} has {len(patch)} quads, expected 4")
        keep[patch] = False
        loop = _patch_loop(quads, patch)
        center_idx = int(pts[1, 1])
        o = np.asarray(verts[center_idx], dtype=np.float64).copy()
        base = np.asarray([verts[i] for i in loop]) - o  # (8, 3)
        phi = np.arctan2(base @ pv / th, base @ pu / wh)
        s_base = float((base @ a).max())
        tip_len = float(p["tip_round"]) * min(wh, th)
        s_rings = np.linspace(s_base, tube_len - tip_len, m + 1)[1:]
        prev = loop
        for s in s_rings:
            sc = ring_scale * (1.0 - (1.0 - taper) * s / tube_len)
            ring = o + s * a + sc * (wh * np.cos(phi)[:, None] * e1 + th * np.sin(phi)[:, None] * e2)
            idx = np.arange(len(verts), len(verts) + len(ring))
            verts += list(ring)
            label += [c] * len(ring)
            nxt = np.roll(np.arange(len(loop)), -1)
            new_quads.append(np.stack([prev, prev[nxt], idx[nxt], idx], axis=1))
            prev = idx
        # cap: the removed patch, moved to the tip (centre vertex reused)
        remap = {int(b): int(r) for b, r in zip(loop, prev)}
        remap[center_idx] = center_idx
        new_quads.append(np.array([[remap[int(v)] for v in q] for q in quads[patch]]))
        verts[center_idx] = o + tube_len * a
        label[center_idx] = c
        # skeleton
        b = blend * th
        j0 = s_base + b
        ratios = np.asarray(p["thumb_ratios"] if c == 4 else p["phalanx_ratios"], dtype=np.float64)
        if ratios.shape != (3,) or np.any(ratios <= 0):
            raise UserInputError(
                f"{who}: phalanx_ratios/thumb_ratios {tuple(ratios.tolist())}: need 3 positive values"
            )
        ratios = ratios / ratios.sum()
        rest_len = tube_len - j0
        if rest_len <= 4 * b:
            raise UserInputError(
                f"{who}: chain {c} of length {tube_len} is too short for its blend width {b:.3g}; "
                "lengthen the finger or lower blend"
            )
        js = j0 + rest_len * np.array([0.0, ratios[0], ratios[0] + ratios[1]])
        origin.append(o)
        joint_origin.append(o - float(p["joint_palmar_offset"]) * th * e2)
        axis.append(a)
        flex_axis.append(-e1)
        joints.append(js)
        length.append(tube_len)
        radius.append(max(wh, th))
    quads = np.concatenate([quads[keep]] + new_quads)
    ctrl = np.asarray(verts, dtype=np.float64)
    memb = np.zeros((len(ctrl), _N_CHAINS))
    lab = np.asarray(label)
    memb[lab >= 0, lab[lab >= 0]] = 1.0
    fine, fquads = _catmull_clark(np.concatenate([ctrl, memb], axis=1), quads)
    rest, memb = fine[:, :3], fine[:, 3:]
    faces = _triangulate(rest, fquads)
    rest = _taubin(rest, faces, int(p["smooth_iters"]), float(p["taubin_lambda"]), float(p["taubin_mu"]))
    faces = _triangulate(rest, fquads)

    origin, axis, joints = np.asarray(origin), np.asarray(axis), np.asarray(joints)
    # skinning weights
    x_cup = xs[5] + gap / 2  # centre of the middle-ring gap
    cup_w = float(p["cup_blend"]) * xs[-1]
    ulnar = _smoothstep01((rest[:, 0] - (x_cup - cup_w)) / (2 * cup_w))
    parent = np.array([0, 0, 1, 1, 0])
    w = np.zeros((len(rest), _N_BONES))
    free = 1.0 - memb.sum(axis=1)
    w[:, 0] = free * (1 - ulnar)
    w[:, 1] = free * ulnar
    for c in range(_N_CHAINS):
        wh, th = chains[c][7], chains[c][8]
        s = (rest - origin[c]) @ axis[c]
        js = joints[c]
        b = blend * th
        g01, g12 = js[1] - js[0], js[2] - js[1]
        # blend half-widths: blends of neighbouring joints never overlap
        bj = np.minimum(b, 0.5 * np.array([g01, min(g01, g12), g12]))
        u = [_smoothstep01((s - (js[k] - bj[k])) / (2 * bj[k])) for k in range(3)]
        mc = memb[:, c]
        w[:, parent[c]] += mc * (1 - u[0])
        w[:, 2 + 3 * c] += mc * u[0] * (1 - u[1])
        w[:, 3 + 3 * c] += mc * u[1] * (1 - u[2])
        w[:, 4 + 3 * c] += mc * u[2]
    return _HandRig(
        rest=rest, faces=faces, weights=w, origin=origin, joint_origin=np.asarray(joint_origin), axis=axis,
        flex_axis=np.asarray(flex_axis),
        joints=joints, length=np.asarray(length), radius=np.asarray(radius) * float(p["capsule_scale"]),
        parent=parent, cup_point=np.array([x_cup, 0.0, 0.0]),
        palm_box=np.array([[0.0, 0.0, 0.0], [xs[-1], l_palm, t_palm]]),
    )


def _hand_bones(rig: _HandRig, angles: np.ndarray) -> np.ndarray:
    """Forward kinematics.

    Args:
        rig: the hand rig.
        angles: (N, 21) radians, layout ``[chain c: j0 flex, j0 abduction, j1, j2] * 5 + [cup]``.

    Returns:
        (N, 17, 3, 4) bone maps from rest to posed coordinates.
    """
    n = len(angles)
    ez = np.array([0.0, 0.0, 1.0])
    eye = np.broadcast_to(np.eye(3, 4), (n, 3, 4))
    bones = [eye, _rot_about(rig.cup_point, _axis_angle(np.array([0.0, 1.0, 0.0]), angles[:, -1]))]
    chain_bones = []
    for c in range(_N_CHAINS):
        q = angles[:, 4 * c:4 * c + 4]
        o, a, k = rig.joint_origin[c], rig.axis[c], rig.flex_axis[c]
        jp = o + rig.joints[c][:, None] * a  # (3, 3) joint points
        r0 = _axis_angle(ez, q[:, 1]) @ _axis_angle(k, q[:, 0])
        b1 = _compose(bones[rig.parent[c]], _rot_about(jp[0], r0))
        b2 = _compose(b1, _rot_about(jp[1], _axis_angle(k, q[:, 2])))
        b3 = _compose(b2, _rot_about(jp[2], _axis_angle(k, q[:, 3])))
        chain_bones += [b1, b2, b3]
    return np.stack(bones + chain_bones, axis=1)


def _pose_hand(rig: _HandRig, angles: np.ndarray) -> np.ndarray:
    """Linear blend skinning of the rig; angles (N, 21) radians -> vertices (N, V, 3) float64."""
    bones = _hand_bones(rig, np.asarray(angles, dtype=np.float64))
    mix = np.einsum("vb,nbij->nvij", rig.weights, bones)  # (N, V, 3, 4)
    return np.einsum("nvij,vj->nvi", mix[..., :3], rig.rest) + mix[..., 3]


def _hand_capsule_ok(rig: _HandRig, angles: np.ndarray, clearance: float, n_samples: int = 8) -> np.ndarray:
    """Capsule proxy check of poses; angles (N, 21) -> (N,) bool, True where the pose keeps clearance."""
    bones = _hand_bones(rig, angles)
    t = np.linspace(0.0, 1.0, n_samples)
    seg_pts = []  # per chain: (N, 3, S, 3) posed sample points on its three bones
    for c in range(_N_CHAINS):
        js = np.concatenate([rig.joints[c], [rig.length[c] - rig.radius[c]]])
        pts = []
        for k in range(3):
            s = js[k] + t * (js[k + 1] - js[k])
            rest = rig.origin[c] + s[:, None] * rig.axis[c]
            pts.append(_apply(bones[:, 2 + 3 * c + k], rest))  # (N, S, 3)
        seg_pts.append(np.stack(pts, axis=1))  # (N, 3, S, 3)
    ok = np.ones(len(angles), dtype=bool)
    for c1 in range(_N_CHAINS):
        for c2 in range(c1 + 1, _N_CHAINS):
            p1 = seg_pts[c1].reshape(len(angles), -1, 3)
            p2 = seg_pts[c2].reshape(len(angles), -1, 3)
            d = np.linalg.norm(p1[:, :, None] - p2[:, None], axis=-1).min(axis=(1, 2))
            ok &= d >= rig.radius[c1] + rig.radius[c2] + clearance
    lo, hi = rig.palm_box
    for c in range(_N_CHAINS):
        p = seg_pts[c][:, 1:].reshape(len(angles), -1, 3)  # bones 2 and 3 of the chain
        d = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=-1).min(axis=1)
        ok &= d >= rig.radius[c] + clearance
    return ok


def _sample_hand_angles(p: dict, rig: _HandRig, n: int, rng: np.random.Generator) -> np.ndarray:
    """Draw n collision-free poses; returns angles (n, 21) radians."""
    who = "make_proc_hand"
    r = {k: np.deg2rad(_range(p, k, who)) for k in (
        "mcp_range", "pip_range", "dip_range", "middle_abduction_range", "thumb_cmc_flex_range",
        "thumb_cmc_abduction_range", "thumb_mcp_range", "thumb_ip_range", "cup_range")}
    spread = np.deg2rad(_range(p, "spread_range", who, nonneg=True))
    sd_c, sd_j, sd_s = float(p["closure_spread"]), float(p["joint_noise"]), float(p["spread_noise"])
    out: list[np.ndarray] = []
    have = 0
    for _ in range(int(p["max_draws"])):
        batch = max(2 * (n - have), 16)  # about half of the draws pass the capsule check
        g = rng.random(batch)
        c = np.clip(g[:, None] + sd_c * rng.standard_normal((batch, _N_CHAINS)), 0, 1)  # (B, 5)
        q = np.clip(c[:, :, None] + sd_j * rng.standard_normal((batch, _N_CHAINS, 3)), 0, 1)  # (B, 5, 3)
        s = np.clip(rng.random(batch)[:, None] + sd_s * rng.standard_normal((batch, 3)), 0, 1)  # (B, 3)
        ang = np.zeros((batch, _N_HAND_DOF))
        lo_hi = [r["mcp_range"], r["pip_range"], r["dip_range"]]
        for f in range(4):
            for j, col in enumerate((0, 2, 3)):
                ang[:, 4 * f + col] = lo_hi[j][0] + q[:, f, j] * (lo_hi[j][1] - lo_hi[j][0])
        gaps = spread[0] + s * (spread[1] - spread[0])  # index-middle, middle-ring, ring-little
        mid = r["middle_abduction_range"][0] + rng.random(batch) * np.diff(r["middle_abduction_range"])[0]
        ang[:, 1] = mid + gaps[:, 0]
        ang[:, 5] = mid
        ang[:, 9] = mid - gaps[:, 1]
        ang[:, 13] = mid - gaps[:, 1] - gaps[:, 2]
        tr = [r["thumb_cmc_flex_range"], r["thumb_mcp_range"], r["thumb_ip_range"]]
        for j, col in enumerate((16, 18, 19)):
            ang[:, col] = tr[j][0] + q[:, 4, j] * (tr[j][1] - tr[j][0])
        ab = r["thumb_cmc_abduction_range"]
        ang[:, 17] = ab[0] + rng.random(batch) * (ab[1] - ab[0])
        cup = np.clip(g + sd_j * rng.standard_normal(batch), 0, 1)
        ang[:, 20] = r["cup_range"][0] + cup * (r["cup_range"][1] - r["cup_range"][0])
        good = ang[_hand_capsule_ok(rig, ang, float(p["clearance"]))]
        out.append(good[: n - have])
        have += len(out[-1])
        if have >= n:
            return np.concatenate(out)
    raise UserInputError(
        f"{who}: only {have} of {n} poses passed the capsule collision check after {p['max_draws']} draws; "
        "narrow the flexion/spread ranges or lower clearance"
    )


def make_proc_hand(n_poses: int = 100, seed: int = 0, **geometry_kwargs) -> tuple[np.ndarray, np.ndarray]:
    """Procedural articulated hand: palm + five fingers, skinned, collision-free poses.

    Args:
        n_poses: number of poses N.
        seed: seed of ``np.random.default_rng``; same arguments give bit-identical output.
        **geometry_kwargs: geometry and pose-range settings, see the module docstring.

    Returns:
        vertices (N, V, 3) float64 and faces (F, 3) int64 (closed, outward oriented; V = 2514 and
        F = 5024 with the defaults).
    """
    _check_n_poses(n_poses, "make_proc_hand")
    p = _merge_kwargs(_HAND_DEFAULTS, geometry_kwargs, "make_proc_hand")
    rig = _build_hand_rig(p)
    rng = np.random.default_rng(seed)
    angles = _sample_hand_angles(p, rig, int(n_poses), rng)
    return _pose_hand(rig, angles), rig.faces.copy()


# --------------------------------------------------------------------------------------------------
# proc_cloth


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
    u = {key: _range(p, key, who) for key in (
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
    _check_n_poses(n_poses, "make_proc_cloth")
    p = _merge_kwargs(_CLOTH_DEFAULTS, geometry_kwargs, "make_proc_cloth")
    rest = _cloth_rest(p)
    rng = np.random.default_rng(seed)
    q = _sample_cloth_params(p, rest, int(n_poses), rng)
    return _pose_cloth(p, rest, q), rest.faces.copy()


GENERATORS = {"proc_hand": make_proc_hand, "proc_cloth": make_proc_cloth}
