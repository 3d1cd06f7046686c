"""Realistic human bodies in motion from anny's default body model: a Swing/Jump-class data set.

`anny <https://pypi.org/project/anny/>`_ (Apache-2.0, ``pip install anny`` or ``make install``) ships its own
template, rig and linear-blend skinning and loads offline; nothing here uses its downloadable non-commercial
assets. The generator poses the default full body in short action sequences, in the spirit of MIT's Swing and
Jump captures: arm swings with a walking stride, crouch-and-jump, torso turns, and reaching across the body (the
sequences that bring limbs close to the body give self-contact, as captures do).

What ``research/anny_probe.py`` found decides two things:

- **Only the main shell is kept.** anny's default mesh (13 718 vertices, 27 420 triangles) is four shells; both
  eyes (72 vertices each) cut the head in every pose, and a 226-vertex inner shell is no surface a collision
  handler should see. The body shell has 13 348 vertices and 26 692 triangles.
- **The little toes are turned out** ``toe_out_deg`` (6 deg) in every pose: in anny's rest pose each little toe
  cuts its neighbour (52 triangle pairs), and 6 deg about the toe's y axis leaves the rest pose collision-free.

Bone axes (``research/anny_axes.py``): about a limb bone's local x it swings forward/back (hip and elbow flex
forward with negative angles, the knee with positive ones), about y sideways, about z it twists; the spine bends
forward about x and turns about z.

Keywords of :func:`make_anny_body` (besides ``n_poses`` and ``seed``): ``frames`` (poses per sequence, 10),
``amplitude_jitter`` (relative spread of each sequence's amplitudes, 0.25), ``toe_out_deg`` (6.0). Units are
anny's metres (height about 1.7).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from neuralcol.errors import UserInputError

ACTIONS = ("arm_swing", "crouch_jump", "turn", "reach_across")
DEFAULTS = {"frames": 10, "amplitude_jitter": 0.25, "toe_out_deg": 6.0}
INSTALL = "pip install anny (or `make install`, which installs the `body` extra)"


def _anny():
    """The anny module; a UserInputError saying how to get it when it is missing."""
    try:
        import anny
    except ImportError as exc:
        raise UserInputError(f"the anny_body data set needs the anny body model, which is not installed: "
                             f"{INSTALL}") from exc
    return anny


@lru_cache(maxsize=1)
def _model_and_shell():
    """anny's default body model and the main shell: (model, keep (V,) bool, faces (F', 3) int64 of the shell)."""
    import torch

    model = _anny().Anny()
    faces = model.get_triangular_faces().cpu().numpy().astype(np.int64)
    with torch.no_grad():
        n = model(pose_parameters=None)["vertices"].shape[1]
    keep, shell_faces = main_shell(faces, n)
    return model, keep, shell_faces


def shells(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """(V,) int connected-shell id of each vertex (shells joined by triangle edges)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    g = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n_vertices, n_vertices))
    return connected_components(g, directed=False)[1]


def main_shell(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """The largest shell: keep (V,) bool and its faces (F', 3) int64 renumbered to the kept vertices."""
    comp = shells(faces, n_vertices)
    keep = comp == np.argmax(np.bincount(comp))
    return keep, (np.cumsum(keep) - 1)[faces[keep[faces].all(1)]]


def bone_rotation(axis: str, degrees):
    """(B, 4, 4) float32 homogeneous rotations about a bone's local ``axis`` by ``degrees`` (B,)."""
    import torch

    a = torch.as_tensor(np.deg2rad(degrees), dtype=torch.float32).reshape(-1)
    c, s = torch.cos(a), torch.sin(a)
    m = torch.eye(4).repeat(len(a), 1, 1)
    i, j = {"x": (1, 2), "y": (0, 2), "z": (0, 1)}[axis]
    m[:, i, i], m[:, i, j], m[:, j, i], m[:, j, j] = c, -s, s, c
    return m


def action_angles(action: str, t: np.ndarray, amp: np.ndarray, side: int) -> dict[tuple[str, str], np.ndarray]:
    """Joint angles (degrees) of one action sequence: ``{(bone, axis): (T,) angles}``.

    Args:
        action: one of :data:`ACTIONS`.
        t: (T,) times in [0, 1] along the sequence.
        amp: (4,) amplitude factors of this sequence (about 1).
        side: +1 or -1, the body side that leads (the reaching arm, the stride's first leg).
    """
    lead, other = ("L", "R") if side > 0 else ("R", "L")
    s, c = np.sin(2 * np.pi * t), np.sin(np.pi * t)  # a full swing; a 0 -> 1 -> 0 bump
    if action == "arm_swing":  # a walking stride: arms and legs swing in opposition, the torso counter-turns
        return {(f"upperarm01.{lead}", "x"): 45 * amp[0] * s, (f"upperarm01.{other}", "x"): -45 * amp[0] * s,
                (f"lowerarm01.{lead}", "x"): -20 * amp[1] * (1 + s) / 2,
                (f"lowerarm01.{other}", "x"): -20 * amp[1] * (1 - s) / 2,
                (f"upperleg01.{lead}", "x"): -30 * amp[2] * s, (f"upperleg01.{other}", "x"): 30 * amp[2] * s,
                (f"lowerleg01.{lead}", "x"): 25 * amp[2] * np.clip(s, 0, None),
                (f"lowerleg01.{other}", "x"): 25 * amp[2] * np.clip(-s, 0, None),
                ("spine03", "z"): 10 * amp[3] * s}
    if action == "crouch_jump":  # down into a crouch, then up with the arms thrown above the head
        crouch = np.sin(np.pi * np.clip(t / 0.6, 0, 1))
        jump = np.clip((t - 0.5) / 0.5, 0, 1)
        out = {("spine03", "x"): 25 * amp[3] * crouch}
        for b in ("L", "R"):
            sign = 1 if b == "L" else -1
            out |= {(f"upperleg01.{b}", "x"): -75 * amp[0] * crouch,
                    (f"lowerleg01.{b}", "x"): 110 * amp[1] * crouch,
                    (f"upperarm01.{b}", "x"): -40 * amp[2] * crouch,
                    (f"upperarm01.{b}", "y"): sign * 100 * amp[2] * jump}
        return out
    if action == "turn":  # the torso, neck and head turn to one side and back, arms follow a little
        return {("spine03", "z"): side * 30 * amp[0] * c, ("spine01", "z"): side * 15 * amp[1] * c,
                ("neck01", "z"): side * 35 * amp[2] * c, (f"upperarm01.{lead}", "x"): -30 * amp[3] * c,
                (f"lowerarm01.{lead}", "x"): -50 * amp[3] * c}
    if action == "reach_across":  # one arm reaches forward and across the chest to the other side
        r = 3 * t**2 - 2 * t**3  # smoothstep
        sign = 1 if lead == "L" else -1
        return {(f"upperarm01.{lead}", "x"): -60 * amp[0] * r, (f"upperarm01.{lead}", "y"): -sign * 45 * amp[1] * r,
                (f"lowerarm01.{lead}", "x"): -70 * amp[2] * r, ("spine03", "z"): -side * 20 * amp[3] * r,
                ("spine03", "x"): 10 * amp[3] * r}
    raise ValueError(f"action {action!r}: use one of {ACTIONS}")


def make_anny_body(n_poses: int = 150, seed: int = 0, **geometry) -> tuple[np.ndarray, np.ndarray]:
    """Poses of anny's default body (main shell) in action sequences.

    Args:
        n_poses: number of meshes N (sequences of ``frames`` poses, cycling through :data:`ACTIONS`).
        seed: amplitudes and leading sides come from ``np.random.default_rng(seed)``.
        **geometry: ``frames``, ``amplitude_jitter``, ``toe_out_deg`` (module docstring).

    Returns:
        vertices (N, 13348, 3) float64 and faces (26692, 3) int64 (one topology).
    """
    import torch

    unknown = sorted(set(geometry) - set(DEFAULTS))
    if unknown:
        raise UserInputError(f"anny_body: unknown setting(s) {unknown}; valid: {sorted(DEFAULTS)}")
    p = {**DEFAULTS, **geometry}
    frames = int(p["frames"])
    if frames < 1 or n_poses < 1:
        raise UserInputError(f"anny_body: n_poses={n_poses} and frames={frames} must be >= 1")
    rng = np.random.default_rng(seed)
    model, keep, faces = _model_and_shell()
    angles: dict[tuple[str, str], np.ndarray] = {}
    n_seq = -(-n_poses // frames)
    t = np.linspace(0.0, 1.0, frames)
    for k in range(n_seq):
        amp = 1 + p["amplitude_jitter"] * rng.uniform(-1, 1, 4)
        side = 1 if rng.random() < 0.5 else -1
        for key, value in action_angles(ACTIONS[k % len(ACTIONS)], t, amp, side).items():
            angles.setdefault(key, np.zeros(n_seq * frames))[k * frames:(k + 1) * frames] = value
    n = n_seq * frames
    toe = float(p["toe_out_deg"])
    angles[("toe5-1.L", "y")], angles[("toe5-1.R", "y")] = np.full(n, toe), np.full(n, -toe)
    pose: dict[str, torch.Tensor] = {}
    for (bone, axis), deg in sorted(angles.items()):  # rotations of one bone compose in x, y, z order
        rot = bone_rotation(axis, deg)
        pose[bone] = pose[bone] @ rot if bone in pose else rot
    with torch.no_grad():
        verts = model(pose_parameters=pose)["vertices"].double().cpu().numpy()
    return np.ascontiguousarray(verts[:n_poses, keep]), faces
