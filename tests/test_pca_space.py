"""PCA latent spaces and references: fit against scikit-learn, exact round trips where the data lie in
the span, the LatentSpace interface (decode_vertices, gradients, save/load, export) and the degenerate-box stop."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuralcol.data.features import dataset_features
from neuralcol.errors import UserInputError
from neuralcol.metrics.reconstruction import relative_vertex_error
from neuralcol.nn.latent_space import LatentSpace
from neuralcol.nn.pca_space import PCALatentSpace, centred_vertices, fit_pca, pca_space
from neuralcol.stages.autoencoder import reference_spaces, train_or_load_latent_space
from neuralcol.stages.box_check import DegenerateBoxError, check_box, degenerate

LATENT = {"n_components": 2, "level2_dim": 1}  # |Z_all| = 4


def test_fit_pca_matches_sklearn():
    sklearn = pytest.importorskip("sklearn.decomposition")
    rng = np.random.default_rng(0)
    x = rng.normal(size=(20, 7)) @ rng.normal(size=(7, 30)) + rng.normal(size=30)
    ours = fit_pca(x, 5)
    ref = sklearn.PCA(5, svd_solver="full").fit(x)
    np.testing.assert_allclose(ours.mean, ref.mean_, atol=1e-12)
    rec_ours = (x - ours.mean) @ ours.components.T @ ours.components + ours.mean
    rec_ref = ref.inverse_transform(ref.transform(x))
    np.testing.assert_allclose(rec_ours, rec_ref, atol=1e-9)
    np.testing.assert_allclose(ours.components @ ours.components.T, np.eye(5), atol=1e-12)


def test_fit_pca_too_many_components_names_the_setting():
    with pytest.raises(ValueError, match="dataset.latent.n_components"):
        fit_pca(np.zeros((4, 10)), 4)


def _space(tube_dataset, basis, train_idx=None, dim=4):
    feats = dataset_features(tube_dataset, 0)
    n = len(tube_dataset)
    idx = np.arange(n) if train_idx is None else train_idx
    rest = tube_dataset.vertices[0].numpy().astype(np.float64)
    part = (tube_dataset.vertices[0, :, 2] > 1.0).long().numpy()
    return pca_space(basis, tube_dataset.vertices.numpy(), feats.features.numpy(), idx, dim, rest,
                     tube_dataset.faces.numpy(), dict(feats.acap.settings), 2, part), feats


@pytest.mark.parametrize("basis", ["vertex", "acap"])
def test_round_trip_is_exact_when_the_basis_spans_the_meshes(tube_dataset, basis):
    """With N - 1 components of N training meshes the span holds each of them: the round trip returns it (to the
    ACAP inverse's own error for the ACAP basis); with fewer components it does not."""
    train = np.arange(11)
    space, feats = _space(tube_dataset, basis, train_idx=train, dim=10)
    v = tube_dataset.vertices[:11]
    err = relative_vertex_error(space.decode(space.encode(v)), v.float()).mean
    acap_err = relative_vertex_error(feats.acap.decode(feats.features[:11].double()).float(), v.float()).mean
    assert float(err.max()) <= (1e-5 if basis == "vertex" else float(acap_err.max()) + 1e-4), err
    if basis == "acap":  # the features themselves come back
        np.testing.assert_allclose(space.decode_features(space.encode(v).double()).numpy(),
                                   feats.features[:11].numpy(), atol=1e-5)
    else:  # the bent, twisted tubes are not linear in the vertices: 2 components miss
        small, _ = _space(tube_dataset, basis, train_idx=train, dim=2)
        err1 = relative_vertex_error(small.decode(small.encode(v)), v.float()).mean
        assert float(err1.max()) > 10 * float(err.max()) + 1e-5


def test_vertex_basis_against_a_direct_projection(tube_dataset):
    space, _ = _space(tube_dataset, "vertex", train_idx=np.arange(0, 12, 2))
    rows = centred_vertices(tube_dataset.vertices.numpy())
    tr = rows[::2]
    mean = tr.mean(0)
    _, _, vt = np.linalg.svd(tr - mean, full_matrices=False)
    expect = ((rows - mean) @ vt[:4].T @ vt[:4] + mean).reshape(len(rows), -1, 3)
    expect = expect + tube_dataset.vertices[0].numpy().astype(np.float64).mean(0)
    got = space.decode(space.encode(tube_dataset.vertices).double()).numpy()
    np.testing.assert_allclose(got, expect, atol=1e-5)
    z = space.encode(tube_dataset.vertices)
    assert bool((z[::2] >= space.box_lo - 1e-5).all() and (z[::2] <= space.box_hi + 1e-5).all())  # box: train codes


@pytest.mark.parametrize("basis", ["vertex", "acap"])
def test_decode_vertices_gradients_and_save_load(tube_dataset, tmp_path, basis):
    space, _ = _space(tube_dataset, basis)
    z = space.sample(3, torch.Generator().manual_seed(0)).double().requires_grad_(True)
    full = space.decode(z)
    idx = [0, 5, 17, 40]
    np.testing.assert_allclose(space.decode_vertices(z, idx).detach().numpy(), full[:, idx].detach().numpy(),
                               atol=1e-9)
    assert torch.autograd.gradcheck(lambda c: space.decode_vertices(c, idx), (z[:1],), eps=1e-6, atol=1e-5)
    # batch last (the detector over code and mesh on codes): the same vertices, (K, 3, B), in float64 and float32
    decoder = space.vertex_decoder(torch.as_tensor(idx))
    torch.testing.assert_close(decoder(z), full[:, idx].permute(1, 2, 0))
    torch.testing.assert_close(decoder(z.detach().float()), full[:, idx].detach().permute(1, 2, 0).float(),
                               atol=1e-5, rtol=1e-5)
    assert torch.autograd.gradcheck(decoder, (z[:1],), eps=1e-6, atol=1e-5)
    loaded = LatentSpace.load(space.save(tmp_path / "latent_space.pt"))
    assert isinstance(loaded, PCALatentSpace) and loaded.basis == basis
    np.testing.assert_array_equal(loaded.decode(z.detach()).numpy(), space.decode(z.detach()).numpy())
    assert loaded.blocks() == [slice(0, 2), slice(2, 3), slice(3, 4)]


@pytest.mark.parametrize("basis", ["vertex", "acap"])
def test_export_decodes_like_the_space(tube_dataset, basis):
    from neuralcol.nn.export import DecoderExport

    space, _ = _space(tube_dataset, basis)
    z = space.sample(4, torch.Generator().manual_seed(1))
    out = DecoderExport(space, "vertices")(z)
    np.testing.assert_allclose(out.numpy(), space.decode(z).numpy(), atol=2e-5)
    if basis == "vertex":
        with pytest.raises(ValueError, match="output='vertices'"):
            DecoderExport(space, "features")


def test_pca_autoencoder_and_references_in_the_stage(tube_dataset, tmp_path):
    """``autoencoder=pca`` trains through the same stage (cached, same split and report keys), and its vertex-PCA
    reference is the space itself: same errors."""
    from hydra import compose, initialize_config_dir

    from tests.conftest import ROOT

    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3"):
        ae = compose("config", overrides=["autoencoder=pca"]).autoencoder
    feats = dataset_features(tube_dataset, 0)
    space, report, cached = train_or_load_latent_space(tube_dataset, feats, ae, LATENT, 0, tmp_path)
    assert isinstance(space, PCALatentSpace) and not cached and report["kind"] == "pca" and space.dim == 4
    again, _, cached = train_or_load_latent_space(tube_dataset, feats, ae, LATENT, 0, tmp_path)
    assert cached and isinstance(again, PCALatentSpace)
    _, errors = reference_spaces(tube_dataset, feats, space, report)
    assert errors["vertex_pca"]["val_mean_vertex_error"] == pytest.approx(report["val_mean_vertex_error"], rel=1e-5)
    assert set(errors) == {"vertex_pca", "acap_pca"}


def test_references_of_too_small_a_training_set_say_why(tube_dataset, tube_space):
    space, report, feats, _, _ = tube_space
    small = {**report, "train_index": [0, 1, 2]}  # 3 meshes span 2 dimensions; the space has 6
    spaces, errors = reference_spaces(tube_dataset, feats, space, small)
    assert spaces == {} and "n_components" in errors["vertex_pca"]["reason"]


def test_box_check_stops_on_a_degenerate_box_with_one_line():
    assert degenerate(1.0, 0.01) and degenerate(0.0, 0.01) and degenerate(0.995, 0.01)
    assert not degenerate(0.05, 0.01) and not degenerate(None, 0.01)
    check_box({"collision_share": 0.3, "n_labeled": 256}, 0.01, "tubes")  # fine: returns
    with pytest.raises(DegenerateBoxError) as e:
        check_box({"collision_share": 1.0, "n_labeled": 256}, 0.01, "skirt",
                  {"vertex_pca": {"collision_share": 0.4}})
    msg = str(e.value)
    assert isinstance(e.value, UserInputError) and "\n" not in msg
    assert "dataset=skirt" in msg and "100.0%" in msg and "autoencoder=pca" in msg and "vertex_pca 40%" in msg
    assert "box_check.enabled=false" in msg
