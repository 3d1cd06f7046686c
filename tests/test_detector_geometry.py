"""The detector over code and mesh: geometry input per sub-domain, its checks, its gradients in the
code through the decoded vertices, save/load."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from neuralcol.nn.detector import CollisionDetector, load_detector, save_detector
from neuralcol.nn.part_geometry import (
    DetectorOnCodes,
    PartGeometry,
    choose_geometry,
    choose_part_pairs,
    geometry_of_codes,
)

# a strip of 8 vertices (two rows of 4) and 6 triangles; 2 sub-domains (left and right halves)
REST = np.array([[x, y, 0.0] for y in (0.0, 1.0) for x in range(4)])
FACES = np.array([[0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6]])
PARTITION = np.array([0, 0, 1, 1, 0, 0, 1, 1])
PAIRS = np.array([[0, 3], [4, 7], [0, 7], [1, 3]])


class LinearSpace:
    """A linear latent space ``rest + z W`` with the decode interface the detector needs."""

    def __init__(self, dim: int, seed: int = 0):
        g = torch.Generator().manual_seed(seed)
        self.rest_vertices = torch.as_tensor(REST, dtype=torch.float64)
        self.w = torch.randn(dim, REST.size, generator=g, dtype=torch.float64) * 0.3

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        return self.rest_vertices + (z @ self.w.to(z)).view(len(z), -1, 3)

    def decode_vertices(self, z: torch.Tensor, idx) -> torch.Tensor:
        return self.decode(z)[:, torch.as_tensor(np.asarray(idx), dtype=torch.long)]

    def encode(self, v: torch.Tensor) -> torch.Tensor:  # least squares: exact on decoded meshes
        d = (torch.as_tensor(v, dtype=torch.float64) - self.rest_vertices).reshape(len(v), -1)
        return torch.linalg.lstsq(self.w.T, d.T).solution.T


def _geometry(per_part: int = 3) -> PartGeometry:
    chosen, slots, mask = choose_part_pairs(PAIRS, np.array([4.0, 3.0, 2.0, 1.0]), PARTITION, 2, per_part)
    return PartGeometry(chosen, slots, mask, FACES, radius=1.0)


@pytest.mark.parametrize("pool", ["linear", "deepsets"])
def test_geometry_is_read_per_subdomain_and_checked(pool):
    torch.manual_seed(0)
    det = CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=_geometry(), geometry_pool=pool).double()
    space = LinearSpace(2)
    z = torch.randn(5, 2, dtype=torch.float64)
    g = geometry_of_codes(det.geometry, space, z)
    assert g.shape == (5, det.geometry.n_pairs, 3)
    # decoding only the vertices the pairs need gives the features of the whole decoded mesh
    torch.testing.assert_close(g, det.geometry_of_meshes(space.decode(z)))
    out = det(z, g)
    assert out.prob.shape == (5,) and out.s.shape == (5, 2)
    # the geometry changes the verdict's inputs: other meshes, other outputs
    assert not torch.allclose(det(z, g + 0.5).logit, out.logit)
    with pytest.raises(ValueError, match="reads the mesh too"):
        det(z)
    with pytest.raises(ValueError, match=r"shape \(5, 3, 2\), expected \(5, 3, 3\)"):
        det(z, g[:, :, :2])
    with pytest.raises(ValueError, match="codes only"):
        CollisionDetector(2, 0, state_dim=6, hidden=8)(z.float(), g.float())
    with pytest.raises(ValueError, match="geometry_pool"):
        CollisionDetector(2, 0, geometry=_geometry(), geometry_pool="sum")


def test_empty_slots_do_not_matter():
    torch.manual_seed(1)
    for pool in ("deepsets", "linear"):
        det = CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=_geometry(per_part=5),
                                geometry_pool=pool).double()
        assert not det.geometry.mask.all()  # every pair joins both parts: 4 pairs for 5 slots each
        z = torch.randn(3, 2, dtype=torch.float64)
        per_part = det.geometry.per_part(geometry_of_codes(det.geometry, LinearSpace(2), z))
        noisy = per_part.clone()
        noisy[~det.geometry.mask[None].expand(3, -1, -1)] = 7.0
        torch.testing.assert_close(det.geometry_embedding(noisy), det.geometry_embedding(per_part))


def test_gradient_in_the_code_through_the_decoded_geometry_matches_finite_differences():
    torch.manual_seed(2)
    det = CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=_geometry()).double()
    space = LinearSpace(2, seed=3)

    def logit(z):
        return det(z, geometry_of_codes(det.geometry, space, z)).logit

    z = torch.randn(4, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(logit, (z,), eps=1e-6, atol=1e-5)


def test_blocked_inference_and_save_load_keep_the_outputs(tmp_path):
    torch.manual_seed(3)
    det = CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=_geometry(), geometry_pool="deepsets",
                            geometry_hidden=5, box_lo=-torch.ones(2), box_hi=torch.ones(2)).eval()
    z = torch.randn(700, 2)
    g = geometry_of_codes(det.geometry, LinearSpace(2), z.double()).float()
    with torch.no_grad():
        whole = det._forward(z, g).logit
        blocked = det(z, g).logit  # 512-row blocks
    torch.testing.assert_close(blocked, whole)
    save_detector(tmp_path / "d.pt", det, {"net": {"state_dim": 6, "hidden": 8}}, {"name": "active"}, 1.0)
    back, meta = load_detector(tmp_path / "d.pt")
    assert meta["geometry"]["pool"] == "deepsets" and meta["geometry"]["hidden"] == 5
    with torch.no_grad():
        torch.testing.assert_close(back.eval()(z, g).logit, blocked)
    torch.testing.assert_close(back.geometry.vertex_index, det.geometry.vertex_index)


def test_detector_on_codes_is_a_function_of_codes_alone():
    torch.manual_seed(4)
    space = LinearSpace(2, seed=5)
    det = CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=_geometry()).double()
    on_codes = DetectorOnCodes(det, space)
    z = torch.randn(6, 2, dtype=torch.float64, requires_grad=True)
    out = on_codes(z)
    torch.testing.assert_close(out.logit, det(z, det.geometry_of_meshes(space.decode(z))).logit)
    # its parameters and state are the detector's only, and the gradient in z reaches through the decode
    assert {k for k, _ in on_codes.named_parameters()} == {f"detector.{k}" for k, _ in det.named_parameters()}
    out.logit.sum().backward()
    assert z.grad is not None and torch.all(torch.isfinite(z.grad)) and z.grad.abs().sum() > 0
    code_only = CollisionDetector(2, 0, state_dim=6, hidden=8).double()
    torch.testing.assert_close(DetectorOnCodes(code_only, space)(z).logit, code_only(z).logit)


@pytest.mark.parametrize("pool", ["linear", "deepsets"])
def test_batch_last_embedding_equals_the_per_part_one(pool):
    """embed_batch_last on (3 P, B) features = geometry_embedding(per_part(...)) on the (B, P, 3) ones, empty slots
    included (per_part=5 leaves some empty)."""
    torch.manual_seed(6)
    det = CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=_geometry(per_part=5), geometry_pool=pool).double()
    z = torch.randn(7, 2, dtype=torch.float64)
    pair_feats = geometry_of_codes(det.geometry, LinearSpace(2), z)  # (B, P, 3)
    batch_last = pair_feats.permute(2, 1, 0).reshape(-1, len(z))  # (3 P, B): [dist..., s_min..., s_max...]
    torch.testing.assert_close(det.embed_batch_last(batch_last),
                               det.geometry_embedding(det.geometry.per_part(pair_feats)))
    torch.testing.assert_close(det(z, embedding=det.embed_batch_last(batch_last)).logit, det(z, pair_feats).logit)
    with pytest.raises(ValueError, match="not both"):
        det(z, pair_feats, embedding=det.embed_batch_last(batch_last))
    with pytest.raises(ValueError, match="embedding has shape"):
        det(z, embedding=det.embed_batch_last(batch_last)[:, :1])


def test_detector_on_codes_fast_path_equals_decoding_then_reading_the_mesh():
    """DetectorOnCodes (batch-last decode, features and embedding; blocks without gradients) = the detector on the
    pair features of the decoded meshes: outputs, gradients in z, and blocked inference."""
    torch.manual_seed(7)
    space = LinearSpace(2, seed=8)
    det = CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=_geometry()).double()
    on_codes = DetectorOnCodes(det, space)
    z = torch.randn(300, 2, dtype=torch.float64, requires_grad=True)
    fast = on_codes(z).logit
    slow = det(z, geometry_of_codes(det.geometry, space, z)).logit
    torch.testing.assert_close(fast, slow)
    g_fast, = torch.autograd.grad(fast.sum(), z)
    g_slow, = torch.autograd.grad(slow.sum(), z)
    torch.testing.assert_close(g_fast, g_slow)
    assert torch.autograd.gradcheck(lambda c: on_codes(c).logit, (z[:3].detach().requires_grad_(True),),
                                    eps=1e-6, atol=1e-5)
    with torch.no_grad():  # 300 rows > inference_block: three blocks
        torch.testing.assert_close(on_codes(z.detach()).logit, slow.detach())


def test_training_reads_the_pair_features_stored_with_dc(tmp_path):
    """D_c keeps each row's pair features; the datamodule serves them and the LightningModule feeds them in."""
    import lightning as L

    from neuralcol.lit.detector import DetectorLitModule
    from neuralcol.samples.datamodule import CollisionDataModule

    torch.manual_seed(6)
    rng = np.random.default_rng(6)
    space = LinearSpace(2, seed=7)
    det = CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=_geometry())
    z = rng.uniform(-1, 1, size=(40, 2)).astype(np.float32)
    pairs = geometry_of_codes(det.geometry, space, torch.as_tensor(z, dtype=torch.float64)).float().numpy()
    pd = rng.normal(size=40) * 0.01
    dm = CollisionDataModule(tmp_path / "dc.h5", 2, 2, batch_size=8, pd_unit=0.01, pd_clip=0.25,
                             n_pairs=det.geometry.n_pairs)
    dm.append(z, pd, np.stack([pd, pd], 1), pd > 0, np.where(pd > 0, 0, 1), 0, 0, geometry=pairs)
    batch = next(iter(dm.train_dataloader()))
    assert len(batch) == 5 and batch[4].shape == (8, det.geometry.n_pairs, 3)
    module = DetectorLitModule(det, optimizer=torch.optim.Adam, lr=1e-2, w_pd=5, w_pdsum=0.2, w_r=2, w_ce=2,
                               w_b=0.5, margin=0.01, temperature=0.1, space=space)
    with pytest.raises(ValueError, match="needs the latent space"):
        DetectorLitModule(det, optimizer=torch.optim.Adam, lr=1e-2, w_pd=5, w_pdsum=0.2, w_r=2, w_ce=2, w_b=0.5,
                          margin=0.01, temperature=0.1)
    # on codes alone (the test set, the acquisition) it decodes what the features read: the same logits
    zt = torch.as_tensor(z[:5])
    torch.testing.assert_close(module.predict_logits(zt),
                               det(zt, torch.as_tensor(pairs[:5])).logit.detach(), rtol=1e-4, atol=1e-5)
    before = {k: v.clone() for k, v in det.state_dict().items()}
    L.Trainer(max_epochs=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,
              enable_model_summary=False, num_sanity_val_steps=0, accelerator="cpu").fit(
        module, train_dataloaders=dm.train_dataloader(), val_dataloaders=dm.val_dataloader())
    assert not torch.equal(before["slot_w"], det.state_dict()["slot_w"]), "the geometry embedding was trained"
    dm.close()


def test_choose_geometry_reads_the_space_and_the_examples():
    space = LinearSpace(2)
    space.faces = torch.as_tensor(FACES)
    space.partition = torch.as_tensor(PARTITION)
    # fold the strip: its right end (x = 3) comes back over its left end (x = 0)
    folded = REST.copy()
    folded[[3, 7], 0] = 0.1
    folded[[3, 7], 2] = 0.05
    geo = choose_geometry(space, folded[None], radius=0.1, min_hops=2)
    assert sorted(map(tuple, geo.contact.pairs.tolist())) == [(0, 3), (4, 7)]
    assert geo.mask.any(1).tolist() == [True, True] and geo.contact.radius == pytest.approx(0.1 * np.sqrt(10))
    with pytest.raises(ValueError, match="no vertex pair at least 2 edges apart"):
        choose_geometry(space, REST[None], radius=0.1)


def _strip_space(dim: int = 2, seed: int = 7) -> LinearSpace:
    space = LinearSpace(dim, seed=seed)
    space.faces = torch.as_tensor(FACES)
    space.partition = torch.as_tensor(PARTITION)
    space.dim, space.n_parts = dim, 2
    space.box_lo, space.box_hi = -torch.ones(dim), torch.ones(dim)
    return space


def test_run_geometry_is_saved_reloaded_and_featurizes_codes_and_meshes(tmp_path, monkeypatch, capsys):
    """The run stage's pair choice (bootstrap codes + realistic meshes) reloads as the same geometry (a resumed run
    builds the same detector); codes and whole meshes give the same features as the module's own functions."""
    from neuralcol.nn.part_geometry import (
        choose_run_geometry,
        code_mesh_logits,
        codes_featurizer,
        load_run_geometry,
        mesh_pair_features,
    )
    from neuralcol.samples.realistic import RealisticRows

    space = _strip_space()
    folded = REST.copy()
    folded[[3, 7], 0] = 0.1
    folded[[3, 7], 2] = 0.05
    real = RealisticRows(np.zeros((1, 2), np.float32), np.array([0.1]), np.array([[0.1, 0.1]]), np.array([True]),
                         np.zeros(1, np.int8), folded[None])
    cfg = {"radius": 0.1, "min_hops": 2, "fold_ratio": 0.5, "colliding_weight": 3.0, "per_part": 4, "clip": 3.0,
           "select_codes": 3}
    z = np.zeros((10, 2), np.float32)  # the rest mesh: no pair comes close; the realistic fold decides
    geo = choose_run_geometry(space, z, np.zeros(10, bool), real, cfg, tmp_path / "geometry.npz")
    assert sorted(map(tuple, geo.contact.pairs.tolist())) == [(0, 3), (4, 7)]
    with np.load(tmp_path / "geometry.npz") as f:
        assert int(f["n_examples"]) == 3 + 1  # codes 0, 4, 8 (at most select_codes = 3 of the 10) + the mesh
    again = load_run_geometry(space, tmp_path / "geometry.npz")
    for name, buf in geo.state_dict().items():
        torch.testing.assert_close(again.state_dict()[name], buf)
    with pytest.raises(ValueError, match="no vertex pair"):  # without the realistic fold nothing comes close
        choose_run_geometry(space, z, np.zeros(10, bool), None, cfg, tmp_path / "none.npz")
    rng = np.random.default_rng(0)
    zz = rng.uniform(-1, 1, (7, 2)).astype(np.float32)
    monkeypatch.setenv("NEURALCOL_PROGRESS", "lines")
    monkeypatch.setenv("NEURALCOL_PROGRESS_INTERVAL", "1e-9")  # a line at every block
    capsys.readouterr()
    feats = codes_featurizer(geo, space, block=3)(zz)  # 3 blocks: progress lines (2e5 codes took minutes silently)
    assert "pair features of decoded codes: 6/7 code (86%)" in capsys.readouterr().err
    codes_featurizer(geo, space, block=4)(zz)
    assert "pair features" not in capsys.readouterr().err  # two blocks: no line
    torch.testing.assert_close(torch.as_tensor(feats), geometry_of_codes(geo, space, torch.as_tensor(zz)).float())
    meshes = space.decode(torch.as_tensor(zz, dtype=torch.float64)).numpy()
    torch.testing.assert_close(torch.as_tensor(mesh_pair_features(geo, meshes, block=2)), torch.as_tensor(feats),
                               rtol=1e-5, atol=1e-5)
    det = CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=geo)
    torch.testing.assert_close(torch.as_tensor(code_mesh_logits(det, zz, meshes, block=4)),
                               DetectorOnCodes(det, space)(torch.as_tensor(zz)).logit.detach(), rtol=1e-4, atol=1e-5)


def test_fast_detector_reads_the_decoded_geometry():
    """FastDetector around DetectorOnCodes: the same logits as the eager detector on codes (float32, eager)."""
    from neuralcol.nn.fast_inference import FastDetector

    torch.manual_seed(3)
    space = _strip_space()
    det = CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=_geometry()).eval()
    z = torch.rand(40, 2) * 2 - 1
    fast = FastDetector(DetectorOnCodes(det, space), "float32", compile=False, block=16)
    with torch.no_grad():
        torch.testing.assert_close(fast(z).logit, DetectorOnCodes(det, space)(z).logit, rtol=1e-5, atol=1e-6)
    # meshes given whole (40 rows: blocks of 16, the last padded): the detector on the meshes' own features
    meshes = space.decode(z.double()) + 0.05 * torch.randn(40, 8, 3, dtype=torch.float64)
    with torch.no_grad():
        expect = det(z, det.geometry_of_meshes(meshes).float()).logit
        got = fast.on_meshes(z, meshes[:, det.geometry.vertex_index]).logit
    torch.testing.assert_close(got, expect, rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match="vertices_read has shape"):
        fast.on_meshes(z, meshes[:, :3])
    with pytest.raises(ValueError, match="codes only"):
        FastDetector(CollisionDetector(2, 0, state_dim=6, hidden=8), compile=False).on_meshes(z, meshes)


def test_a_copy_of_the_detector_on_codes_shares_the_space():
    """Deep copies (the projector's float64 copy, the speed stage's) copy the detector, never the latent space."""
    import copy

    space = _strip_space()
    on_codes = DetectorOnCodes(CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=_geometry()), space)
    twin = copy.deepcopy(on_codes).double()
    assert twin.space is space and twin.detector is not on_codes.detector
    assert next(twin.parameters()).dtype == torch.float64 and next(on_codes.parameters()).dtype == torch.float32
    z = torch.rand(3, 2, dtype=torch.float64)
    torch.testing.assert_close(twin(z).logit.float(), on_codes(z.float()).logit, rtol=1e-4, atol=1e-5)


def test_features_of_the_few_vertices_equal_those_of_the_whole_mesh():
    """PartGeometry reads only vertex_index (pairs and the faces around them, renumbered): the same features as
    ContactFeatures on the whole mesh, whose normals use every face."""
    torch.manual_seed(9)
    geo = _geometry()
    v = torch.as_tensor(REST)[None] + 0.2 * torch.randn(5, len(REST), 3, dtype=torch.float64)
    whole = geo.contact(v).reshape(5, 3, -1).transpose(1, 2)
    torch.testing.assert_close(geo.pair_features(v), whole)
    torch.testing.assert_close(geo.features_of_vertices(v[:, geo.vertex_index]), whole)


def test_mean_fnr_threshold_is_the_largest_threshold_whose_mean_fnr_meets_the_target():
    from neuralcol.operating import fnr_threshold, mean_fnr_threshold

    rng = np.random.default_rng(5)
    ya, yb = rng.random(300) < 0.5, rng.random(40) < 0.4
    la = np.round(rng.normal(size=300) + 2.0 * ya, 1)  # rounded: ties among the colliding logits
    lb = rng.normal(size=40) + 1.0 * yb - 1.0
    every = np.sort(np.concatenate([la[ya], lb[yb]]))
    for target in (0.0, 0.05, 0.1, 0.25):
        t = mean_fnr_threshold([(la, ya), (lb, yb)], target)
        mean = lambda u: 0.5 * (np.mean(la[ya] <= u) + np.mean(lb[yb] <= u))  # noqa: E731
        assert mean(t) <= target + 1e-12
        above = every[every > t]  # brute force: the next colliding logit up already misses more than the target
        assert len(above) == 0 or mean(above[0]) > target
    assert mean_fnr_threshold([(la, ya)], 0.1) == fnr_threshold(la, ya, 0.1)
    assert mean_fnr_threshold([(la, ya), (lb, np.zeros(40, bool))], 0.1) == fnr_threshold(la, ya, 0.1)
    with pytest.raises(ValueError, match="no colliding row"):
        mean_fnr_threshold([(la, np.zeros(300, bool))], 0.1)


def test_fnr_threshold_misses_at_most_the_target_and_the_shift_moves_the_decision():
    from neuralcol.operating import fnr_threshold

    rng = np.random.default_rng(4)
    y = rng.random(400) < 0.4
    logit = rng.normal(size=400) + 2.0 * y
    for target in (0.0, 0.05, 0.1, 0.3):
        t = fnr_threshold(logit, y, target)
        fnr = np.mean(logit[y] <= t)
        assert fnr <= target + 1e-12
        k = int(np.floor(target * y.sum()))
        assert np.mean(logit[y] <= np.sort(logit[y])[k]) > target, "a threshold at the next colliding logit misses more"
    with pytest.raises(ValueError, match="no colliding row"):
        fnr_threshold(logit, np.zeros(400, bool), 0.1)
    with pytest.raises(ValueError, match="must lie in"):
        fnr_threshold(logit, y, 1.0)
    det = CollisionDetector(2, 0, state_dim=6, hidden=8)
    z = torch.rand(9, 2)
    before = det(z).logit.detach()
    det.shift_decision(0.7)
    torch.testing.assert_close(det(z).logit.detach(), before - 0.7)


@pytest.mark.parametrize("where", ["realistic", "calibration", "both"])
def test_operating_point_is_set_on_its_rows_and_folded_into_the_bias(tmp_path, where, monkeypatch):
    """detector.operating_fnr on the realistic validation rows of D_c (their stored features) or on the calibration
    set (codes, decoded): the threshold misses at most the target there, it moves into the output bias, and the last
    round's test metrics become those at it (the old ones under at_logit_0)."""
    from neuralcol.errors import UserInputError
    from neuralcol.samples.store import CollisionRows, CollisionStore, Origin
    from neuralcol.stages import detector as detector_stage
    from neuralcol.stages.detector import operating_point

    torch.manual_seed(2)
    rng = np.random.default_rng(2)
    space = _strip_space()
    det = CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=_geometry()).eval()
    n = 200
    z = rng.uniform(-1, 1, (n, 2)).astype(np.float32)
    feats = geometry_of_codes(det.geometry, space, torch.as_tensor(z)).float().numpy()
    with torch.no_grad():
        score = det(torch.as_tensor(z), torch.as_tensor(feats)).logit.numpy()
    collides = score + rng.normal(scale=0.05, size=n) > np.median(score)  # labels the detector mostly agrees with
    pd = np.where(collides, 0.1, -0.1)
    rows = CollisionRows(z, pd, np.stack([pd, pd], 1), collides, np.where(collides, 0, 1).astype(np.int8),
                         np.zeros(n, np.int16), np.full(n, Origin.REALISTIC, np.int8), np.arange(n), feats)
    store = CollisionStore(tmp_path / "dc.h5", 2, 2, n_pairs=det.geometry.n_pairs)
    store.append(z, pd, rows.pd_sub, collides, rows.subset, 0, Origin.REALISTIC, feats)
    monkeypatch.setattr(detector_stage, "calibration_set", lambda *a: (rows, 0.0, 0))
    last = {"accuracy": 0.5, "fnr": 0.5}
    cfg = {"operating_fnr": 0.1, "operating_set": where}
    before = det(torch.as_tensor(z), torch.as_tensor(feats)).logit.detach()
    op = operating_point(det, space, None, cfg, "key", tmp_path, rows, last, store)
    assert op["operating_set"] == where and op["calibration"]["fnr"] <= 0.1
    n_cal = {"realistic": int(store.split_mask().sum()), "calibration": n, "both": int(store.split_mask().sum()) + n}
    assert op["calibration"]["n"] == n_cal[where]
    n_pos = {"realistic": int(collides[store.split_mask()].sum()), "calibration": int(collides.sum())}
    n_pos["both"] = n_pos["realistic"] + n_pos["calibration"]
    assert op["calibration"]["n_colliding"] == n_pos[where]
    if where != "both":  # one set: the calibration FNR's exact interval holds it
        lo, hi = op["calibration"]["fnr_ci95"]
        assert lo <= op["calibration"]["fnr"] <= hi
    else:
        assert "fnr_ci95" not in op["calibration"]
    if where == "both":  # the mean of the two sets' FNRs is what the threshold bounds
        val = store.split_mask()
        b = before.numpy()
        means = 0.5 * (np.mean(b[val & collides] <= op["threshold"]) + np.mean(b[collides] <= op["threshold"]))
        assert op["calibration"]["fnr"] == pytest.approx(means)
    torch.testing.assert_close(det(torch.as_tensor(z), torch.as_tensor(feats)).logit.detach(),
                               before - op["threshold"])
    assert last["at_logit_0"] == {"accuracy": 0.5, "fnr": 0.5} and last["threshold"] == op["threshold"]
    assert last["fnr"] == pytest.approx(float(np.mean(before.numpy()[collides] <= op["threshold"])))
    if where in ("realistic", "both"):
        plain = CollisionStore(tmp_path / "plain.h5", 2, 2)
        with pytest.raises(UserInputError, match=f"operating_set={where} needs"):
            operating_point(det, space, None, cfg, "key", tmp_path, rows, {}, plain)
        plain.close()
    store.close()


def test_full_labels_of_the_realistic_training_meshes_are_labeled_once(tmp_path):
    """A second run of the same meshes reads their full labels from the samples folder; other meshes are labeled."""
    from types import SimpleNamespace

    from neuralcol.samples.realistic import full_labels

    calls = []

    class Pool:
        desc = ""

        def label_report(self, v):
            calls.append(len(v))
            return SimpleNamespace(ok=np.array([True, False, True]),
                                   labels=SimpleNamespace(pd=np.array([0.1, np.nan, -0.2]), pd_sub=np.ones((3, 2))))

    v = np.random.default_rng(0).normal(size=(3, 8, 3))
    first = full_labels(Pool(), v, tmp_path)
    again = full_labels(Pool(), v, tmp_path)
    assert calls == [3]
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    assert first[0].tolist() == [True, False, True] and first[2].shape == (3, 2)
    full_labels(Pool(), v + 1e-9, tmp_path)
    assert calls == [3, 3]


def test_realistic_training_meshes_are_labeled_once_per_run(tmp_path, monkeypatch):
    """D_c's realistic training meshes: the candidates are labeled in full once; the kept meshes' full labels are
    taken from that labeling (not labeled again), and a second run labels nothing."""
    from types import SimpleNamespace

    from neuralcol.data.realistic import KINDS, RealisticMeshes
    from neuralcol.samples import realistic as R

    n, k = 12, 2
    cand = np.random.default_rng(1).normal(size=(n, 5, 3))
    monkeypatch.setattr(R, "make_realistic_meshes", lambda *a, **kw: RealisticMeshes(
        cand, np.full(n, KINDS.index("acap_interp"), np.int8), np.zeros((n, 3), np.int64), np.zeros(n)))
    labeled = []

    class Pool:
        desc = ""
        labeler = SimpleNamespace(subsets=lambda pd: np.zeros(len(pd), np.int8))

        def label_report(self, v, clearance_limit=None):
            assert clearance_limit is None  # the training meshes are labeled in full
            labeled.append(len(v))
            pd = np.where(np.arange(len(v)) % 2 == 0, 1.0, -1.0) * (1 + v[:, 0, 0] ** 2)
            return SimpleNamespace(ok=np.ones(len(v), bool), labels=SimpleNamespace(pd=pd, pd_sub=np.c_[pd, -pd]))

    space = SimpleNamespace(n_parts=k, dim=3, encode=lambda v: torch.zeros(len(v), 3, dtype=torch.float64))
    cfg = {"seed": 0, "n_acap_interp": n, "n_vertex_interp": 0, "n_perturbed": 0, "t_range": [0, 1],
           "perturb_scale": 0.1, "clear_eps": 0, "per_class": 3}
    rows = R.realistic_rows(space, np.zeros((4, 5, 3)), np.zeros((4, 5, 9)), None, [0, 1, 2], Pool(), cfg, tmp_path,
                            0.01)
    assert labeled == [n] and len(rows.pd) == 6 and rows.collides.sum() == 3
    assert np.array_equal(rows.pd_sub[:, 0], rows.pd)  # PD_i from the one labeling
    again = R.realistic_rows(space, np.zeros((4, 5, 3)), np.zeros((4, 5, 9)), None, [0, 1, 2], Pool(), cfg,
                             tmp_path, 0.01)
    assert labeled == [n] and np.array_equal(again.pd, rows.pd) and np.array_equal(again.vertices, rows.vertices)


def test_operating_point_on_a_realistic_calibration_set(tmp_path):
    """detector.operating_set=realistic_calibration: the threshold is set on whole meshes apart from D_c, judged as
    detect(mesh) judges them (their codes and their own pair features), and folded into the bias; without the set,
    one clear error."""
    from neuralcol.errors import UserInputError
    from neuralcol.operating import fnr_threshold
    from neuralcol.samples.store import CollisionRows
    from neuralcol.stages.detector import mesh_logits, operating_point

    torch.manual_seed(3)
    rng = np.random.default_rng(3)
    space = _strip_space()
    det = CollisionDetector(2, 0, state_dim=6, hidden=8, geometry=_geometry()).eval()
    z = rng.uniform(-1, 1, (150, 2))
    meshes = space.decode(torch.as_tensor(z)).numpy()
    feats = geometry_of_codes(det.geometry, space, torch.as_tensor(z, dtype=torch.float32)).float()
    with torch.no_grad():
        by_codes = det(torch.as_tensor(z, dtype=torch.float32), feats).logit.double().numpy()
    logit = mesh_logits(det, space, meshes)
    np.testing.assert_allclose(logit, by_codes, atol=1e-4)  # a mesh is judged by its own code and features
    collides = logit + rng.normal(scale=0.3, size=len(z)) > np.median(logit)
    last = {"accuracy": 0.5, "fnr": 0.5}
    test = CollisionRows(z.astype(np.float32), np.zeros(1), None, collides, None, None, None, None)
    twin = copy.deepcopy(det)
    op = operating_point(det, space, None, {"operating_fnr": 0.1, "operating_set": "realistic_calibration"}, "key",
                         tmp_path, test, last, None, (meshes, collides))
    auto = operating_point(twin, space, None, {"operating_fnr": 0.1, "operating_set": "auto"}, "key", tmp_path, test,
                           dict(last), None, (meshes, collides))  # the default picks the set wherever it is built
    assert auto["operating_set"] == "realistic_calibration" and auto["threshold"] == op["threshold"]
    assert op["operating_set"] == "realistic_calibration"
    assert op["threshold"] == pytest.approx(fnr_threshold(logit, collides, 0.1))
    assert op["calibration"]["n"] == len(z) and op["calibration"]["n_colliding"] == int(collides.sum())
    assert op["calibration"]["fnr"] <= 0.1 and len(op["calibration"]["fnr_ci95"]) == 2
    np.testing.assert_allclose(mesh_logits(det, space, meshes), logit - op["threshold"], atol=1e-4)
    with pytest.raises(UserInputError, match="needs the realistic calibration set"):
        operating_point(det, space, None, {"operating_fnr": 0.1, "operating_set": "realistic_calibration"}, "key",
                        tmp_path, test, {}, None, None)


def test_calibration_settings_draw_another_larger_set():
    from neuralcol.errors import UserInputError
    from neuralcol.samples.realistic import calibration_settings

    cfg = {"seed": 0, "n_acap_interp": 1500, "n_vertex_interp": 600, "n_perturbed": 600, "per_class": 150,
           "clear_eps": 10, "calibration": {"seed_offset": 101, "scale": 4, "per_class": 1000}}
    c = calibration_settings(cfg)
    assert (c["seed"], c["n_acap_interp"], c["n_vertex_interp"], c["n_perturbed"], c["per_class"]) == \
        (101, 6000, 2400, 2400, 1000)
    assert c["clear_eps"] == 10 and cfg["seed"] == 0  # the rest as the test set's; the config itself unchanged
    with pytest.raises(UserInputError, match="seed_offset != 0"):
        calibration_settings({**cfg, "calibration": {"seed_offset": 0, "scale": 4, "per_class": 10}})
    with pytest.raises(UserInputError, match="missing"):
        calibration_settings({**cfg, "calibration": {"scale": 4}})
    assert calibration_settings({**cfg, "calibration": {"seed_offset": 101, "scale": 1, "per_class": None}})[
        "per_class"] is None  # every clear colliding mesh, as many free
    with pytest.raises(UserInputError, match="per_class >= 1 or null"):
        calibration_settings({**cfg, "calibration": {"seed_offset": 101, "scale": 1, "per_class": 0}})
