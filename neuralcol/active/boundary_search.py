"""Exact boundary search: move labeled codes onto the true boundary ``PD = 0`` with a few more exact labels.

The detector's 0.5 level set is tens of eps away from the true boundary for most codes (docs/diagnosis.md), so
neither the paper's Newton projector nor uncertainty sampling puts samples within 2 eps of it. The signed PD of
the exact labeler is continuous across the boundary (docs/labels.md), so a bracket ``(z_a, z_b)`` with PD of
opposite signs can be shrunk by root finding on the segment, one exact label per step. The Illinois variant of
regula falsi is used: the secant point of the bracket, and when the same end is kept twice in a row its PD is
halved, which keeps the method converging where PD is flat on one side (the clearance cap ``-cap`` of free
codes far from contact).

``python -m bench.boundary_search RUN_DIR`` measured how many labels it takes on SCAPE: 52 % of uncertain picks
within 2 eps after 7 labels (docs/diagnosis.md).
"""

from __future__ import annotations

import numpy as np
import torch


def collides(pd: np.ndarray) -> np.ndarray:
    """The side of the boundary: PD > 0 (collides) or not."""
    return np.asarray(pd) > 0


def nearest_opposite(z: np.ndarray, pd: np.ndarray, ref_z: np.ndarray, ref_pd: np.ndarray, box_lo: np.ndarray,
                     box_hi: np.ndarray, chunk: int = 1024) -> np.ndarray:
    """For each code, the index of the nearest reference row on the other side of the boundary.

    Args:
        z: (B, D) codes, pd: (B,) their PD.
        ref_z: (N, D) reference codes (D_c), ref_pd: (N,) their PD.
        box_lo, box_hi: (D,) the box; distances are measured in box-normalised coordinates.

    Returns:
        (B,) int64 indices into ``ref_z``; -1 where the reference has no row on the other side.
    """
    lo, hi = np.asarray(box_lo, np.float64), np.asarray(box_hi, np.float64)
    scale = np.where(hi > lo, hi - lo, 1.0)
    zn = torch.as_tensor((np.asarray(z, np.float64) - lo) / scale)
    rn = torch.as_tensor((np.asarray(ref_z, np.float64) - lo) / scale)
    side, ref_side = collides(pd), collides(ref_pd)
    out = np.full(len(zn), -1, np.int64)
    for s in (False, True):
        rows = np.flatnonzero(side == s)
        other = np.flatnonzero(ref_side != s)
        if len(rows) == 0 or len(other) == 0:
            continue
        for start in range(0, len(rows), chunk):
            r = rows[start:start + chunk]
            d = torch.cdist(zn[r], rn[other])
            out[r] = other[d.argmin(dim=1).numpy()]
    return out


class BracketSearch:
    """Illinois regula falsi on B brackets at once.

    Args:
        za, fa: (B, D) codes and (B,) PD on one side; zb, fb: the other side (``collides(fa) != collides(fb)``).
    """

    def __init__(self, za: np.ndarray, fa: np.ndarray, zb: np.ndarray, fb: np.ndarray):
        self.za, self.zb = np.array(za, np.float64), np.array(zb, np.float64)
        self.fa, self.fb = np.array(fa, np.float64), np.array(fb, np.float64)
        if self.za.shape != self.zb.shape or self.fa.shape != self.fb.shape or len(self.fa) != len(self.za):
            raise ValueError(f"brackets: za {self.za.shape}, zb {self.zb.shape}, fa {self.fa.shape}, "
                             f"fb {self.fb.shape} must hold the same number of rows")
        if np.any(collides(self.fa) == collides(self.fb)):
            raise ValueError("every bracket needs PD of opposite sides at its two ends")
        self.last = np.zeros(len(self.fa), np.int8)  # +1: the last step replaced end a, -1: end b, 0: none yet
        self.newest = np.full(len(self.fa), np.nan)  # PD of each bracket's latest point

    def __len__(self) -> int:
        return len(self.fa)

    def propose(self) -> np.ndarray:
        """(B, D) the next point of every bracket: the zero of the secant through its two ends."""
        w = self.fa / (self.fa - self.fb)  # in [0, 1]: fa and fb have opposite signs (or fa == 0)
        return self.za + w[:, None] * (self.zb - self.za)

    def update(self, z: np.ndarray, f: np.ndarray, ok: np.ndarray | None = None) -> None:
        """Take the labeled points ``z`` (B, D) with PD ``f`` (B,); rows with ``ok`` False leave their bracket
        unchanged. The point replaces the end on its side; the kept end's PD is halved when it was kept in the
        previous step too (Illinois)."""
        z, f = np.asarray(z, np.float64), np.asarray(f, np.float64)
        ok = np.ones(len(f), bool) if ok is None else np.asarray(ok, bool)
        same_a = collides(f) == collides(self.fa)
        ra, rb = ok & same_a, ok & ~same_a  # replace end a / end b
        self.fb = np.where(ra & (self.last == 1), self.fb / 2, self.fb)
        self.fa = np.where(rb & (self.last == -1), self.fa / 2, self.fa)
        self.za[ra], self.fa[ra] = z[ra], f[ra]
        self.zb[rb], self.fb[rb] = z[rb], f[rb]
        self.last = np.where(ra, 1, np.where(rb, -1, self.last)).astype(np.int8)
        self.newest = np.where(ok, f, self.newest)
