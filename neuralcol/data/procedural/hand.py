"""Procedural articulated hand (data set ``proc_hand``): palm + five fingers, skinned, collision-free poses.

Generator conventions (return shapes, seeding, keyword errors): :mod:`neuralcol.data.procedural`.

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
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from neuralcol.data.procedural.options import check_n_poses, check_range, merge_kwargs
from neuralcol.errors import UserInputError
from neuralcol.geometry.quad_mesh import box_lattice, catmull_clark, patch_boundary_loop, triangulate_quads
from neuralcol.geometry.smoothing import taubin_smooth

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


# --------------------------------------------------------------------------------------------------
# rig, skinning and pose sampling

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
    verts, quads, grid = box_lattice(xs, ys, zs)
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
        loop = patch_boundary_loop(quads, patch)
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
    fine, fquads = catmull_clark(np.concatenate([ctrl, memb], axis=1), quads)
    rest, memb = fine[:, :3], fine[:, 3:]
    faces = triangulate_quads(rest, fquads)
    rest = taubin_smooth(rest, faces, int(p["smooth_iters"]), float(p["taubin_lambda"]), float(p["taubin_mu"]))
    faces = triangulate_quads(rest, fquads)

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
    r = {k: np.deg2rad(check_range(p, k, who)) for k in (
        "mcp_range", "pip_range", "dip_range", "middle_abduction_range", "thumb_cmc_flex_range",
        "thumb_cmc_abduction_range", "thumb_mcp_range", "thumb_ip_range", "cup_range")}
    spread = np.deg2rad(check_range(p, "spread_range", who, nonneg=True))
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
    check_n_poses(n_poses, "make_proc_hand")
    p = merge_kwargs(_HAND_DEFAULTS, geometry_kwargs, "make_proc_hand", __name__)
    rig = _build_hand_rig(p)
    rng = np.random.default_rng(seed)
    angles = _sample_hand_angles(p, rig, int(n_poses), rng)
    return _pose_hand(rig, angles), rig.faces.copy()
