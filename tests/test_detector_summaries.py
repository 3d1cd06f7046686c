"""The detector over code and mesh with contact summaries (detector.geometry.summaries): the summary rows it reads
per sub-domain, their batch-last form on codes, gradients through the decode, save/load and the run geometry file."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuralcol.geometry.contact_summary import ContactSummary
from neuralcol.nn.detector import CollisionDetector, load_detector, save_detector
from neuralcol.nn.part_geometry import (
    DetectorOnCodes,
    choose_geometry,
    choose_run_geometry,
    geometry_of_codes,
    load_run_geometry,
)
from tests.test_contact_summary import _bent_sheet

SETTINGS = {"radius": 0.04, "min_hops": 2, "fold_ratio": 0.5, "colliding_weight": 3.0, "per_part": 4, "clip": 3.0}


class FoldSpace:
    """A linear latent space over a grid sheet: z[0] folds it about its middle row (1: onto itself at pi-ish), z[1]
    a random smooth bend; the interface the detector's geometry needs."""

    def __init__(self):
        rest, folded, faces, partition = _bent_sheet(n=8, bend=3.0)
        g = torch.Generator().manual_seed(0)
        self.rest_vertices = torch.as_tensor(rest)
        wobble = torch.sin(3.0 * self.rest_vertices[:, :1] + self.rest_vertices[:, 1:2]) * torch.tensor([0, 0, .1])
        self.w = torch.stack([torch.as_tensor(folded - rest).reshape(-1), wobble.reshape(-1)])
        self.w = self.w + 1e-3 * torch.randn(self.w.shape, generator=g, dtype=torch.float64)
        self.faces = torch.as_tensor(faces)
        self.partition = torch.as_tensor(partition)
        self.dim, self.n_parts = 2, 2
        self.box_lo, self.box_hi = -torch.ones(2), torch.ones(2) * 1.2

    def decode(self, z):
        return self.rest_vertices.to(z) + (z @ self.w.to(z)).view(len(z), -1, 3)

    def decode_vertices(self, z, idx):
        return self.decode(z)[:, torch.as_tensor(np.asarray(idx), dtype=torch.long)]


def _codes(n: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.cat([0.85 + 0.2 * torch.rand(n, 1, generator=g), 0.5 * torch.rand(n, 1, generator=g) - 0.25], 1)


def _geometry(space, summaries: bool = True, summary_vertices: int | None = None, smooth: bool = False):
    meshes = space.decode(_codes(40).double()).numpy()
    return choose_geometry(space, meshes, None, radius=SETTINGS["radius"], min_hops=2, fold_ratio=0.5,
                           per_part=4, summaries=summaries, summary_vertices=summary_vertices,
                           summary_smooth=smooth)


def test_summary_rows_follow_the_chosen_pairs_and_fill_two_slots_per_subdomain():
    space = FoldSpace()
    plain, geo = _geometry(space, False), _geometry(space, True)
    p, k = plain.n_pairs, 2
    assert geo.n_pairs == p + 2 * k and len(geo.vertex_index) == len(space.rest_vertices)
    v = space.decode(_codes(6).double())
    feats = geo.pair_features(v)
    torch.testing.assert_close(feats[:, :p], plain.pair_features(v))
    diag = float(np.linalg.norm(np.ptp(space.rest_vertices.numpy(), axis=0)))
    want = ContactSummary(space.rest_vertices.numpy(), space.faces.numpy(), space.partition.numpy(), k,
                          SETTINGS["radius"] * diag).summarize(v.numpy())  # (B, K, 4)
    rows = feats[:, p:].reshape(6, k, 6)
    np.testing.assert_allclose(rows[:, :, :4].numpy(), want, rtol=1e-5, atol=1e-6)
    assert torch.all(rows[:, :, 4:] == 0)
    assert (want[:, :, 0] > 0).any()  # the fold brings pairs close: the summaries are not all empty
    # every sub-domain reads its own two summary rows in its last two slots
    per = geo.per_part(feats)
    for part in range(k):
        torch.testing.assert_close(per[:, part, -2:].reshape(6, 6), rows[:, part])


@pytest.mark.parametrize("pool", ["linear", "deepsets"])
@pytest.mark.parametrize("smooth", [False, True])
def test_codes_path_equals_the_mesh_path_with_gradients(pool, smooth):
    torch.manual_seed(1)
    space = FoldSpace()
    det = CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=_geometry(space, smooth=smooth),
                            geometry_pool=pool).double()
    on_codes = DetectorOnCodes(det, space)
    z = _codes(20, seed=2).double().requires_grad_(True)
    fast = on_codes(z).logit
    slow = det(z, geometry_of_codes(det.geometry, space, z)).logit
    torch.testing.assert_close(fast, slow)
    g_fast, = torch.autograd.grad(fast.sum(), z)
    g_slow, = torch.autograd.grad(slow.sum(), z)
    torch.testing.assert_close(g_fast, g_slow)
    assert torch.all(torch.isfinite(g_fast))


def test_a_detector_with_summaries_saves_loads_and_runs_eagerly_in_the_fast_form(tmp_path):
    from neuralcol.nn.fast_inference import FastDetector

    torch.manual_seed(2)
    space = FoldSpace()
    det = CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=_geometry(space, summary_vertices=90)).eval()
    save_detector(tmp_path / "d.pt", det, {"net": {"state_dim": 6, "hidden": 8}}, {"name": "active"}, 1.0)
    back, meta = load_detector(tmp_path / "d.pt")
    assert meta["geometry"]["summaries"] == {"min_hops": 2, "fold_ratio": 0.5, "max_vertices": 90, "smooth": False}
    assert np.array_equal(back.geometry.summary.sample, det.geometry.summary.sample)
    assert len(back.geometry.summary.sample) == 90
    z = _codes(30, seed=3)
    with torch.no_grad():
        want = DetectorOnCodes(det, space)(z).logit
        torch.testing.assert_close(DetectorOnCodes(back.eval(), space)(z).logit, want)
    fast = FastDetector(DetectorOnCodes(det, space), "float32", block=16)
    assert not fast.compiled  # the close-pair search runs on the CPU, outside a compiled graph
    with torch.no_grad():
        torch.testing.assert_close(fast(z).logit, want, rtol=1e-5, atol=1e-6)


def test_run_geometry_with_summaries_reloads_as_the_same_geometry(tmp_path):
    space = FoldSpace()
    z = _codes(40).numpy()
    cfg = {**SETTINGS, "select_codes": 100, "summaries": True, "summary_vertices": 100, "summary_form": "smooth"}
    geo = choose_run_geometry(space, z, np.zeros(len(z), bool), None, cfg, tmp_path / "geometry.npz")
    back = load_run_geometry(space, tmp_path / "geometry.npz")
    assert back.n_pairs == geo.n_pairs and back.summary is not None and back.summary.max_vertices == 100
    assert back.summary.smooth and geo.summary.smooth
    v = space.decode(_codes(5, seed=4).double())
    torch.testing.assert_close(back.pair_features(v), geo.pair_features(v))
    plain = choose_run_geometry(space, z, np.zeros(len(z), bool), None, {**cfg, "summaries": False},
                                tmp_path / "plain.npz")
    assert load_run_geometry(space, tmp_path / "plain.npz").summary is None and plain.summary is None
