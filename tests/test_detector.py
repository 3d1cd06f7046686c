"""Neural collision detector: shapes, O(K) parameters, gradients, losses against hand computation."""

from __future__ import annotations

import math

import pytest
import torch

from neuralcol.nn.detector import CollisionDetector, DetectorOutput, detector_losses, smooth_max


def test_shapes_and_probability():
    det = CollisionDetector(n_components=4, level2_dim=2, state_dim=8, hidden=16)
    z = torch.randn(5, 12)
    out = det(z)
    assert out.prob.shape == (5,) and out.s.shape == (5, 4)
    assert ((out.prob > 0) & (out.prob < 1)).all()
    torch.testing.assert_close(out.prob, torch.sigmoid(out.logit))
    with pytest.raises(ValueError, match=r"expected \(B, 12\)"):
        det(torch.randn(5, 10))


def test_parameters_grow_linearly_with_components():
    def n_params(k):
        return sum(p.numel() for p in CollisionDetector(k, 3, state_dim=16, hidden=32).parameters())

    d1, d2 = n_params(8) - n_params(4), n_params(16) - n_params(8)
    assert d2 == 2 * d1, "parameter count is affine in K (shared CP weights), not quadratic"


@pytest.mark.parametrize("level2_dim, features", [(0, False), (2, False), (0, True), (3, True)])
def test_split_first_cp_layer_equals_cp_on_the_concatenation(level2_dim, features):
    """The CP evaluation that computes W_s S_0 once per sample is the paper's CP([S_0, part_i]) for each i."""
    torch.manual_seed(1)
    k = 5
    feats = (torch.randn(k, 3), torch.randn(k, 3), "tanh") if features else None
    det = CollisionDetector(k, level2_dim, state_dim=6, hidden=10, code_features=feats).double()
    z = torch.randn(7, k * (1 + level2_dim), dtype=torch.float64)
    s0 = torch.randn(7, 6, dtype=torch.float64)
    parts = torch.randn(7, k, det.n_code_features + 1 + level2_dim, dtype=torch.float64)
    reference = det.cp(torch.cat([s0[:, None, :].expand(-1, k, -1), parts], dim=-1))[..., 0]
    torch.testing.assert_close(det._cp(s0, parts), reference)
    out = det(z)  # and the whole forward still matches its pieces
    x = (z - det.center) / det.half_range
    parts = det.split(x)
    cse_in = x
    if features:
        h = torch.tanh(z[:, :k, None] * det.feature_w + det.feature_b)
        parts, cse_in = torch.cat([parts, h], -1), torch.cat([x, h.flatten(1)], -1)
    s0 = det.cse(cse_in)
    s = det.cp(torch.cat([s0[:, None, :].expand(-1, k, -1), parts], dim=-1))[..., 0]
    torch.testing.assert_close(out.s, s)
    torch.testing.assert_close(out.logit, det.mlp_c(s)[:, 0])


def test_cpu_inference_in_blocks_equals_one_block(monkeypatch):
    torch.manual_seed(2)
    det = CollisionDetector(4, 1, state_dim=6, hidden=8).eval()
    z = torch.randn(11, 8)
    monkeypatch.setattr(CollisionDetector, "inference_block", None)
    with torch.no_grad():
        whole = det(z)
    calls = []
    monkeypatch.setattr(CollisionDetector, "inference_block", 4)
    monkeypatch.setattr(det, "_forward", lambda x: calls.append(len(x)) or CollisionDetector._forward(det, x))
    with torch.no_grad():
        blocked = det(z)
    assert calls == [4, 4, 3]
    for a, b in zip(whole, blocked):
        torch.testing.assert_close(a, b)
    calls.clear()
    det(z).prob.sum().backward()  # with gradients: one block (autograd, the projector and the handler)
    assert calls == [11]


def test_input_gradient_matches_finite_differences():
    torch.manual_seed(0)
    det = CollisionDetector(3, 2, state_dim=8, hidden=16).double()
    z = torch.randn(2, 9, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: det(x).prob, (z,))


def test_losses_match_hand_computation():
    s = torch.tensor([[0.1, -0.2], [0.3, 0.0], [-0.1, -0.4]])
    logit = torch.tensor([0.5, -1.0, 0.2])
    out = DetectorOutput(torch.sigmoid(logit), logit, s)
    pd = torch.tensor([0.2, -0.1, 0.05])
    pd_sub = torch.tensor([[0.2, -0.1], [-0.1, -0.2], [0.05, -0.3]])
    subset = torch.tensor([0, 1, 2])  # D_p, D_n, D_b
    t, margin = 0.5, 0.1
    w = dict(w_pd=5.0, w_pdsum=0.2, w_r=2.0, w_ce=2.0, w_b=0.5)
    got = detector_losses(out, pd, pd_sub, subset, margin=margin, temperature=t, **w)
    smax = [t * math.log(sum(math.exp(v / t) for v in row)) for row in s.tolist()]
    per_part = [sum((a - b) ** 2 for a, b in zip(s[i].tolist(), pd_sub[i].tolist())) for i in range(3)]
    l_pd = sum(per_part[i] + 0.2 * (smax[i] - pd[i].item()) ** 2 for i in range(3)) / 3
    pairs = [(a, b) for a in range(3) for b in range(3) if pd[a] < pd[b]]
    l_r = sum(max(0.0, margin - (smax[b] - smax[a])) for a, b in pairs) / len(pairs)
    p = torch.sigmoid(logit).tolist()
    l_ce = -(math.log(p[0]) + math.log(1 - p[1])) / 2
    l_b = abs(p[2] - 0.5)
    expected = 5 * l_pd + 2 * l_r + 2 * l_ce + 0.5 * l_b
    for name, value in (("pd", l_pd), ("rank", l_r), ("ce", l_ce), ("boundary", l_b), ("total", expected)):
        assert getattr(got, name).item() == pytest.approx(value, rel=1e-5), name


def test_ranking_loss_equals_the_mean_over_ordered_pairs_with_its_gradient():
    """L_r as a masked sum (the faster form) is the mean of max(0, margin - gap) over the ordered pairs with
    PD_a < PD_b taken by boolean indexing, value and gradient, ties in PD included (they are no pair)."""
    torch.manual_seed(3)
    s = torch.randn(64, 4, dtype=torch.float64, requires_grad=True)
    logit = torch.randn(64, dtype=torch.float64)
    pd = torch.randint(-3, 4, (64,)).double() / 10  # many ties
    zeros = dict(w_pd=0.0, w_pdsum=0.0, w_r=1.0, w_ce=0.0, w_b=0.0)
    got = detector_losses(DetectorOutput(torch.sigmoid(logit), logit, s), pd, torch.zeros(64, 4),
                          torch.zeros(64, dtype=torch.long), margin=0.05, temperature=0.1, **zeros)
    (g_got,) = torch.autograd.grad(got.rank, s)
    agg = smooth_max(s, 0.1)
    less = pd[:, None] < pd[None, :]
    ref = torch.relu(0.05 - (agg[None, :] - agg[:, None]))[less].mean()
    (g_ref,) = torch.autograd.grad(ref, s)
    assert got.rank.item() == pytest.approx(ref.item(), rel=1e-12)
    assert torch.allclose(g_got, g_ref, rtol=1e-10, atol=1e-14)
    flat = torch.full((5,), 0.1, dtype=torch.float64)  # every PD equal: no pair, L_r = 0
    out = DetectorOutput(torch.full((5,), 0.5), torch.zeros(5), torch.zeros(5, 2))
    assert detector_losses(out, flat, torch.zeros(5, 2), torch.zeros(5, dtype=torch.long), margin=0.05,
                           temperature=0.1, **zeros).rank.item() == 0.0


def test_boundary_reduction_batch_weighs_a_boundary_row_like_a_ce_row():
    """L_b of the paper is a mean over the batch's D_b rows; "batch" divides their sum by the batch size."""
    logit = torch.tensor([0.5, -1.0, 0.2, 1.5, -0.3])
    out = DetectorOutput(torch.sigmoid(logit), logit, torch.zeros(5, 2))
    pd, pd_sub = torch.tensor([0.2, -0.1, 0.0, 1e-5, -0.2]), torch.zeros(5, 2)
    subset = torch.tensor([0, 1, 2, 2, 1])  # two D_b rows of five
    w = dict(w_pd=0.0, w_pdsum=0.0, w_r=0.0, w_ce=2.0, w_b=0.5, margin=0.1, temperature=0.5)
    dev = (torch.sigmoid(logit[2:4]) - 0.5).abs()
    paper = detector_losses(out, pd, pd_sub, subset, **w)
    batch = detector_losses(out, pd, pd_sub, subset, boundary_reduction="batch", **w)
    assert paper.boundary.item() == pytest.approx(dev.mean().item())
    assert batch.boundary.item() == pytest.approx(dev.sum().item() / 5)
    assert batch.ce.item() == pytest.approx(paper.ce.item())
    none = detector_losses(out, pd, pd_sub, torch.tensor([0, 1, 0, 1, 1]), boundary_reduction="batch", **w)
    assert none.boundary.item() == 0.0
    with pytest.raises(ValueError, match="boundary_reduction='sum'"):
        detector_losses(out, pd, pd_sub, subset, boundary_reduction="sum", **w)


def test_smooth_max_tends_to_max():
    s = torch.tensor([[0.3, -1.0, 0.25]])
    assert smooth_max(s, 1e-3).item() == pytest.approx(0.3, abs=1e-3)
    assert smooth_max(s, 1.0).item() > 0.3


def _features(k=3, h=4, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(k, h, generator=g) * 2, torch.randn(k, h, generator=g), "tanh"


def test_decoder_features_feed_each_subdomain_and_keep_gradients():
    """With code_features, CP_i also sees tanh(z0_i w_i + b_i): changing only those weights changes the output,
    and the input gradient (through the features) matches finite differences."""
    torch.manual_seed(0)
    w, b, act = _features()
    det = CollisionDetector(3, 2, state_dim=8, hidden=16, code_features=(w, b, act)).double()
    assert det.cse[0][0].in_features == 9 + 3 * 4 and det.cp[0].in_features == 8 + 1 + 2 + 4
    z = torch.randn(4, 9, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: det(x).logit, (z,))
    before = det(z).logit.detach()
    det.feature_w.mul_(-1.0)  # the decoder's reading of z0 changes, nothing else
    assert not torch.allclose(det(z).logit, before)
    with pytest.raises(ValueError, match=r"\(3, H\)"):
        CollisionDetector(3, 2, code_features=(torch.zeros(2, 4), torch.zeros(2, 4), "tanh"))


def test_detector_with_features_round_trips_through_save_and_load(tmp_path):
    from neuralcol.nn.detector import load_detector, save_detector

    torch.manual_seed(1)
    lo, hi = -torch.rand(9) * 100 - 1, torch.rand(9) * 100 + 1
    det = CollisionDetector(3, 2, state_dim=8, hidden=16, box_lo=lo, box_hi=hi, code_features=_features())
    save_detector(tmp_path / "d.pt", det, {"net": {"state_dim": 8, "hidden": 16}}, {"name": "supv"}, 1.0)
    back, meta = load_detector(tmp_path / "d.pt")
    z = lo + torch.rand(16, 9) * (hi - lo)
    torch.testing.assert_close(back(z).logit, det(z).logit, rtol=0, atol=0)
    assert meta["code_features"] == {"hidden": 4, "activation": "tanh"}
