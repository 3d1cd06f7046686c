"""Bilevel autoencoder: shapes, gradients, sub-domains, box sampler, cache reuse."""

from __future__ import annotations

import numpy as np
import torch
from conftest import TUBE_LATENT as LATENT
from omegaconf import OmegaConf

from neuralcol.geometry.topology import edge_topology
from neuralcol.nn.autoencoder import BilevelAutoencoder, Level1Autoencoder, Level2Autoencoders
from neuralcol.nn.latent_space import LatentSpace
from neuralcol.stages.autoencoder import (
    connect_partition,
    count_pieces,
    split_indices,
    train_or_load_latent_space,
)


def test_shapes():
    part = torch.tensor([0, 0, 1, 1, 1])
    net = BilevelAutoencoder(Level1Autoencoder(5, 2, hidden=3), Level2Autoencoders(part, 2, latent_dim=3))
    x = torch.randn(4, 5, 9)
    z = net.encode(x)
    assert z.shape == (4, 2 + 2 * 3) and net.latent_dim == 8
    assert net.decode(z).shape == (4, 5, 9)
    att = net.level1.attention()
    torch.testing.assert_close(att.sum(0), torch.ones(5))


def test_level2_decoder_writes_only_its_subdomain():
    part = torch.tensor([0, 0, 1, 1, 1])
    l2 = Level2Autoencoders(part, 2, latent_dim=2)
    for p in l2.parameters():
        torch.nn.init.normal_(p)
    z = torch.zeros(1, 4)
    z[0, 0] = 1.0  # only Z_1 (sub-domain 0) changes
    diff = l2.decode(z) - l2.decode(torch.zeros(1, 4))
    assert diff[0, 2:].abs().max() == 0 and diff[0, :2].abs().max() > 0


def test_training_reconstructs_and_covers(tube_space, tube_dataset):
    space, report, *_ = tube_space
    assert report["train_mean_vertex_error"] < 0.01, report
    assert space.partition.shape == (tube_dataset.n_vertices,)
    assert set(space.partition.tolist()) == {0, 1}, "every vertex in a sub-domain, both sub-domains used"
    z = space.encode(tube_dataset.vertices[:3])
    rec = space.decode(z)
    assert rec.shape == (3, tube_dataset.n_vertices, 3) and torch.isfinite(rec).all()


def test_sampler_stays_in_box(tube_space):
    space = tube_space[0]
    z = space.sample(2000, torch.Generator().manual_seed(0))
    assert z.shape == (2000, space.dim)
    assert (z >= space.box_lo).all() and (z <= space.box_hi).all()
    assert (z.amax(0) - z.amin(0) > 0.9 * (space.box_hi - space.box_lo)).all(), "fills the box"


def test_decode_gradient_matches_finite_differences(tube_space):
    space = tube_space[0]
    space64 = LatentSpace.load(tube_space[4] / "autoencoders" / next(
        p.name for p in (tube_space[4] / "autoencoders").iterdir()) / "latent_space.pt").double()
    z = space.sample(1, torch.Generator().manual_seed(1)).double().requires_grad_(True)
    w = torch.randn(1, space.acap.n_vertices, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(2))

    def f(zz):
        return (space64.decode(zz) * w).sum()

    f(z).backward()
    eps = 1e-6
    fd = torch.zeros_like(z)
    for j in range(z.shape[1]):
        e = torch.zeros_like(z)
        e[0, j] = eps
        fd[0, j] = (f(z.detach() + e) - f(z.detach() - e)) / (2 * eps)
    torch.testing.assert_close(z.grad, fd, rtol=1e-5, atol=1e-7)


def test_cache_reuse_and_save_load(tube_space, tube_dataset):
    space, report, feats, cfg, cache = tube_space
    again, report2, cached = train_or_load_latent_space(tube_dataset, feats, cfg, LATENT, 0, cache)
    assert cached and report2["train_mean_vertex_error"] == report["train_mean_vertex_error"]
    z = space.sample(4, torch.Generator().manual_seed(3))
    torch.testing.assert_close(again.decode(z), space.decode(z))
    other = OmegaConf.merge(cfg, {"level2": {"epochs": 5}})
    _, _, cached_other = train_or_load_latent_space(tube_dataset, feats, other, LATENT, 0, cache)
    assert not cached_other, "a different config trains a new model"
    # the thread count is part of the key: a latent space trained on the machine's threads is another one
    _, report_free, cached_free = train_or_load_latent_space(tube_dataset, feats, cfg, LATENT, 0, cache, threads=None)
    assert not cached_free and report_free["cache_key"] != report["cache_key"]


def test_connect_partition_merges_islands():
    # a strip 0-1-...-6: part 0 = {0, 1, 2} + island {4}; part 1 = {3} + {5, 6}
    edges = np.array([[i, i + 1] for i in range(6)])
    part = np.array([0, 0, 0, 1, 0, 1, 1])
    assert count_pieces(part, edges, 2) == [2, 2]
    fixed = connect_partition(part, edges, 2)
    assert count_pieces(fixed, edges, 2) == [1, 1]
    assert fixed.tolist() == [0, 0, 0, 1, 1, 1, 1]


def test_split_is_fixed_and_disjoint():
    tr, va = split_indices(71, 0.2, seed=0)
    tr2, va2 = split_indices(71, 0.2, seed=0)
    assert (tr == tr2).all() and (va == va2).all() and len(va) == 14 and len(set(tr) | set(va)) == 71


def test_edges_helper_consistency(tube_dataset):
    e = edge_topology(tube_dataset.faces.numpy()).edges
    assert e.shape[1] == 2


def test_box_spans_the_training_codes(tube_space, tube_dataset):
    """autoencoder.box_from=train (default): Z = [min, max] of the codes of the meshes the autoencoder trained
    on; the held-out meshes' codes may lie outside."""
    space, report, *_ = tube_space
    assert report["box_from"] == "train" and len(report["val_index"]) > 0
    z = space.encode(tube_dataset.vertices)
    tr = torch.as_tensor(report["train_index"])
    torch.testing.assert_close(space.box_lo, z[tr].amin(0), rtol=0, atol=1e-5)
    torch.testing.assert_close(space.box_hi, z[tr].amax(0), rtol=0, atol=1e-5)


def test_linear_components_decode_affinely_and_persist(tmp_path):
    """activation="linear": each level-1 component is affine in its code (so the decoder moves evenly along
    the box), and a saved latent space keeps the activation."""
    torch.manual_seed(0)
    l1 = Level1Autoencoder(6, 2, hidden=3, activation="linear")
    z1, z2 = torch.randn(1, 2) * 50, torch.randn(1, 2) * 50
    for a in (0.25, 0.5, 2.0):
        torch.testing.assert_close(l1.decode(a * z1 + (1 - a) * z2), a * l1.decode(z1) + (1 - a) * l1.decode(z2),
                                   rtol=1e-5, atol=1e-4)
    tanh = Level1Autoencoder(6, 2, hidden=3)
    tanh.load_state_dict(l1.state_dict())
    assert not torch.allclose(tanh.decode(z1), l1.decode(z1))
    try:
        Level1Autoencoder(6, 2, activation="relu")
    except ValueError as e:
        assert "relu" in str(e)
    else:
        raise AssertionError("an unknown activation must be refused")


def test_code_noise_only_while_training():
    """code_noise perturbs the codes the decoder sees in training steps, never at validation."""
    from neuralcol.lit.autoencoder import AutoencoderLitModule

    torch.manual_seed(0)
    net = BilevelAutoencoder(Level1Autoencoder(5, 2, hidden=3))
    mod = AutoencoderLitModule(net, 1, optimizer=lambda params: torch.optim.Adam(params), code_noise=0.3)
    z = torch.randn(8, 2)
    assert torch.equal(mod._noisy(z, "val"), z)
    noisy = mod._noisy(z, "train")
    assert not torch.equal(noisy, z)
    ratio = ((noisy - z).std(0) / z.std(0)).mean()
    assert 0.1 < float(ratio) < 0.6, "noise ~ code_noise x the batch std of each code"
    plain = AutoencoderLitModule(net, 1, optimizer=lambda params: torch.optim.Adam(params))
    assert torch.equal(plain._noisy(z, "train"), z)


def test_interpolations_only_while_training_and_on_segments_between_batch_meshes():
    """interp_ratio adds ceil(ratio * B) rows (1 - t) x_i + t x_j, i != j, t in interp_t, to training batches."""
    from neuralcol.lit.autoencoder import AutoencoderLitModule

    torch.manual_seed(0)
    net = BilevelAutoencoder(Level1Autoencoder(5, 2, hidden=3))
    mod = AutoencoderLitModule(net, 1, optimizer=lambda params: torch.optim.Adam(params), interp_ratio=0.6,
                               interp_t=(-0.5, 1.5))
    x = torch.eye(5).view(5, 5, 1)  # batch of 5 "meshes", one-hot: each extra row names its pair and t
    assert torch.equal(mod._interpolated(x, "val"), x)
    out = mod._interpolated(x, "train")
    assert out.shape == (5 + 3, 5, 1) and torch.equal(out[:5], x)  # ceil(0.6 * 5) = 3
    ts = []
    for row in out[5:, :, 0]:
        nz = torch.nonzero(row.abs() > 1e-7).flatten()
        assert len(nz) == 2 and torch.isclose(row.sum(), torch.tensor(1.0)), row  # two meshes, weights sum to 1
        ts += row[nz].tolist()
    assert all(-0.5 - 1e-6 <= t <= 1.5 + 1e-6 for t in ts)
    plain = AutoencoderLitModule(net, 1, optimizer=lambda params: torch.optim.Adam(params))
    assert torch.equal(plain._interpolated(x, "train"), x)
    for bad in ({"interp_ratio": -0.1}, {"interp_t": (1.0, 0.0)}):
        try:
            AutoencoderLitModule(net, 1, optimizer=lambda params: torch.optim.Adam(params), **bad)
        except ValueError:
            continue
        raise AssertionError(f"{bad} must be refused")


def test_cache_key_ignores_settings_spelled_out_at_their_neutral_value(tube_dataset):
    """Adding `activation: tanh` / `code_noise: 0` to a config keeps the cached latent space's key; other
    values change it."""
    from neuralcol.stages.autoencoder import autoencoder_cache_key

    base = {"level1": {"epochs": 3, "lr": 0.01}, "level2": {"epochs": 3}, "box_from": "train"}
    spelled = {"level1": {"epochs": 3, "lr": 0.01, "activation": "tanh", "code_noise": 0.0, "interp_ratio": 0.0},
               "level2": {"epochs": 3, "code_noise": 0.0, "interp_ratio": 0.0}, "box_from": "train",
               "interp_t": [0, 1]}
    key = lambda cfg: autoencoder_cache_key(tube_dataset, 0, {}, cfg, {"n_components": 2}, 0)  # noqa: E731
    assert key(base) == key(spelled)
    assert spelled["level1"]["activation"] == "tanh", "the caller's config is not modified"
    for group, name, value in (("level1", "activation", "linear"), ("level1", "code_noise", 0.1),
                               ("level2", "code_noise", 0.1), ("level1", "interp_ratio", 0.5),
                               ("level2", "interp_ratio", 1.0), (None, "interp_t", [-0.5, 1.5])):
        changed = {k: dict(v) if isinstance(v, dict) else v for k, v in spelled.items()}
        (changed if group is None else changed[group])[name] = value
        assert key(changed) != key(base), (group, name)


def test_no_level2_trains_no_second_stage(tube_dataset, tube_space, tmp_path):
    """``level2_dim: 0`` (SCAPE's and anny_body's presets) is Z_all = Z_0: no level-2 module and no stage-2 fit
    (earlier, code-free level-2 decoders trained for level2.epochs, learning a constant offset)."""
    _, _, feats, cfg, _ = tube_space
    latent = {**dict(LATENT), "level2_dim": 0}
    one = OmegaConf.merge(cfg, {"level1": {"epochs": 5}, "level2": {"epochs": 1}})
    many = OmegaConf.merge(cfg, {"level1": {"epochs": 5}, "level2": {"epochs": 400}})
    a, rep_a, _ = train_or_load_latent_space(tube_dataset, feats, one, latent, 0, None)
    b, rep_b, _ = train_or_load_latent_space(tube_dataset, feats, many, latent, 0, None)
    assert a.net.level2 is None and a.dim == int(latent["n_components"])
    # skipped, 1 and 400 level-2 epochs give the same model
    z = a.sample(3, torch.Generator().manual_seed(0))
    torch.testing.assert_close(a.decode(z), b.decode(z), rtol=0, atol=0)
    path = a.save(tmp_path / "l1.pt")
    assert LatentSpace.load(path).net.level2 is None
