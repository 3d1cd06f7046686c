"""What :class:`~neuralcol.api.TrainedRun` answers: :class:`Detection` and :class:`Resolved`."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from neuralcol.errors import UserInputError

OBJECTIVES = ("latent", "cartesian")
FOLDED_MESH_DETECTOR = ("the separate mesh detector (mesh_detector.pt) was folded into the run's detector: "
                        "train with detector.inputs=code_and_mesh (the default), whose detector judges a mesh by its "
                        "own geometry")


def check_removed_choice(name: str, value, folded: tuple[str, ...]) -> None:
    """An old caller's ``inputs=`` / ``constraint=`` (both removed): None and ``"latent"`` (the run's
    detector, what they always meant) pass; ``folded`` (the separate mesh detector) raise
    :data:`FOLDED_MESH_DETECTOR`, anything else that the option is gone."""
    if value is None or value == "latent":
        return
    if value in folded:
        raise UserInputError(f"{name}={value!r}: {FOLDED_MESH_DETECTOR}")
    raise UserInputError(f"{name}={value!r}: the option was removed (the run's one detector judges "
                         "meshes and codes); leave it out")


class Detection(NamedTuple):
    """The detector's answer for B codes (tensors on the run's device, float32).

    prob (B,): collision probability. logit (B,): its logit (the handler's constraint is ``logit <= -margin``).
    pd (B,): the detector's PD estimate in mesh units, ``pd_unit * smooth_max(S, temperature)`` (the quantity
    its loss fits to the exact PD; trained on targets clipped to ``detector.loss.pd_clip`` units, so deep
    penetrations saturate). pd_sub (B, K): the per-sub-domain estimates ``pd_unit * S_i``. outside_box (B,) bool:
    the code (of a mesh: its encoding) lies outside the box Z the detector was trained in, so its answer is an
    extrapolation (a detector over code and mesh, ``detector.inputs=code_and_mesh``, reads the mesh's own geometry
    beside it); None where not computed.
    collides (B,) bool: the verdict: ``logit > 0``, or with ``certify`` the certified cascade's (the network below
    and above the band, the exact label inside it; docs/cascade.md). exact (B,) bool: with ``certify``, the rows
    the exact labeler decided (their ``prob`` is then 1.0 or 0.0, the exact answer); None without ``certify``.
    """

    prob: torch.Tensor
    logit: torch.Tensor
    pd: torch.Tensor
    pd_sub: torch.Tensor
    outside_box: torch.Tensor | None = None
    collides: torch.Tensor | None = None
    exact: torch.Tensor | None = None


class Resolved(NamedTuple):
    """Result of :meth:`TrainedRun.resolve` for N inputs.

    vertices (N, V, 3): the resolved meshes. For mesh inputs (float64, the precision they were labeled in), the
    input mesh plus the correction the handled code implies (in the input's frame, keeping its detail); for
    code inputs (float32), the decoded ``codes``.
    codes (N, D) float32: the handled latent codes. codes_before (N, D): the inputs' codes. pd_input (N,)
    float64: exact PD of the input meshes (NaN for code inputs). pd_before (N,): exact PD of the decoded input
    codes (the autoencoder's round trip). pd_after (N,): exact PD of the returned ``vertices`` (NaN: the
    handler or the labeler failed). Without a run (and for the path without the run) a free mesh's clearance is
    not measured: its PD is ``-cap``, the clearance cap of the rest mesh (``labeler_for(..., clearance=False)``), so
    large meshes never pay for the near table; a colliding mesh's PD is exact either way.
    margin (N,): the detector-logit margin of the kept result (NaN where the
    contact repair's mesh was kept, or the input came back ``untouched``). repaired (N,) bool: the contact repair
    (``handler.repair``, mesh inputs with ``verify``) produced the returned mesh.
    displacement_mean, displacement_max, displacement_median (N,): how far the returned vertices lie from the
    input's (code inputs: from the decoded input code), in mesh units; divide by ``diagonal`` (the rest mesh's
    bounding-box diagonal) for a fraction. decoded (N, V, 3) float32: the handled codes decoded (the latent
    result, in the decoder's frame); NaN, and ``codes`` the input's, where ``handler.repair.first`` freed the input
    mesh and the neural handler was skipped.
    With ``certify`` (else None): exact (N,) bool: the verdict on the returned result is the exact labeler's
    (``pd_after`` is NaN where the detector was trusted instead); free (N,) bool: the certified cascade calls the
    returned result collision-free (exact PD <= 0, or the detector's logit below the band); exact_share: exact labels
    per verification decision (the full verification labels every result: 1.0).
    shrink (N,) or None: the share of the neural path's correction the returned mesh was repaired from
    (``handler.repair.shrink_steps``; NaN where not tried, 1 where the full correction was kept); None without a
    repair or for code inputs.
    cap (N,) or None: the cap on the returned mesh's vertex moves, a fraction of the largest move before it
    (``handler.repair.cap_steps``; NaN where not tried, 1 where not clipped); None as ``shrink``.
    untouched (N,) bool or None (code inputs): the input mesh was free by the exact label and came back as given,
    bit for bit (``pd_after`` = ``pd_input``, displacements 0, ``margin`` NaN; it skipped the encoder, handler and
    repair, so its ``codes``, ``codes_before``, ``decoded`` and ``pd_before`` are NaN).
    without_run (N,) bool or None: ``neuralcol.resolve`` with a run only: the returned mesh is the path without the
    run's (the exact repairs alone), kept because it freed the mesh and moved it less than the run's path, or freed
    it where the run's path did not (``codes`` and ``decoded`` then still describe the run's attempt).
    """

    vertices: torch.Tensor
    codes: torch.Tensor
    codes_before: torch.Tensor
    pd_input: np.ndarray
    pd_before: np.ndarray
    pd_after: np.ndarray
    margin: np.ndarray
    displacement_mean: np.ndarray
    displacement_max: np.ndarray
    displacement_median: np.ndarray
    diagonal: float
    decoded: torch.Tensor
    repaired: np.ndarray | None = None
    exact: np.ndarray | None = None
    free: np.ndarray | None = None
    exact_share: float | None = None
    shrink: np.ndarray | None = None
    cap: np.ndarray | None = None
    untouched: np.ndarray | None = None
    without_run: np.ndarray | None = None

    @property
    def move_to_depth(self) -> np.ndarray:
        """(N,) each colliding input's largest vertex move over its exact PD (NaN for free inputs and code inputs): how
        many times the depth of the input's deepest penetration the repair moved a vertex. About 0.5 when the two sides
        of the deepest contact each moved half of it, 1 when one side moved all of it; much larger means it moved the
        wrong part, or too much of it. NaN too where the depth is below 1e-9 of the diagonal (a contact at round-off:
        :func:`~neuralcol.repair.cap.move_to_depth`)."""
        from neuralcol.repair.cap import move_to_depth

        return move_to_depth(self.displacement_max, self.pd_input, self.diagonal)

