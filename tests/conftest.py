"""Shared fixtures: real data from the configured location, small synthetic meshes built in code."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
if os.environ.get("PYTEST_XDIST_WORKER"):
    # `make test` runs two pytest workers on the two cores (pytest-xdist, one worker per test file): one thread
    # each, and for the runs the tests start as subprocesses, so the workers do not oversubscribe the cores
    os.environ["OMP_NUM_THREADS"] = "1"
    torch.set_num_threads(1)

# The test files that take longest (CPU seconds in `make test`, longest first: each runs whole pipelines). xdist's
# loadfile hands out files in collection order once its reordering (most tests first, which put these few-test files
# last) is off, so they start first and the many short files fill in behind them: both workers end together.
LONGEST_FIRST = ("test_run.py", "test_body_dataset.py", "test_reproducibility.py", "test_reliability.py",
                 "test_tutorial.py", "test_progress.py", "test_model_size.py", "test_api.py", "test_gpu_check.py",
                 "test_diagnose.py", "test_tensorboard.py", "test_labeler.py", "test_validate.py", "test_active.py",
                 "test_pool_dask.py", "test_scale_curve.py", "test_pool_faults.py")


def pytest_configure(config):
    if hasattr(config.option, "loadscopereorder"):  # pytest-xdist >= 3.6; older ones keep their order
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(config, items):
    """Files in ``LONGEST_FIRST`` order, then the others by their number of tests (xdist's own order); a stable sort,
    so each file's tests stay together and in their order."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    count: dict = {}
    for item in items:
        count[item.path] = count.get(item.path, 0) + 1
    items.sort(key=lambda item: (rank.get(item.path.name, len(rank)), -count[item.path]))


# SCAPE is read where it lives (never copied): $NEURALCOL_DATA/scape, else ../shared/data/scape.
DATA_DIR = Path(os.environ.get("NEURALCOL_DATA", ROOT.parent / "shared" / "data"))
SCAPE_DIR = DATA_DIR / "scape"


@pytest.fixture(scope="session")
def scape_dir() -> Path:
    if not (SCAPE_DIR / "1.obj").is_file():
        pytest.skip(f"SCAPE not found at {SCAPE_DIR}; set NEURALCOL_DATA to the folder holding scape/")
    return SCAPE_DIR


@pytest.fixture(scope="session")
def scape(scape_dir):
    from neuralcol import load_mesh_dataset

    return load_mesh_dataset(scape_dir, dtype=torch.float64)


@pytest.fixture(scope="session")
def scape_acap(scape):
    from neuralcol import ACAP

    return ACAP(scape.vertices[0], scape.faces)


def make_tube(n_rings: int = 24, n_around: int = 12, radius: float = 0.2, length: float = 2.0,
              capped: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Closed tube along +z (rings of a cylinder plus two cap centre vertices).

    Returns:
        vertices (V, 3) float64 and faces (F, 3) int64; ring 0 is at z = 0.
    """
    z = np.linspace(0.0, length, n_rings)
    ang = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    ring = np.stack([radius * np.cos(ang), radius * np.sin(ang)], -1)  # (A, 2)
    verts = np.concatenate([np.repeat(ring[None], n_rings, 0), np.repeat(z[:, None, None], n_around, 1)], -1)
    verts = verts.reshape(-1, 3)
    faces = []
    for r in range(n_rings - 1):
        for a in range(n_around):
            i0, i1 = r * n_around + a, r * n_around + (a + 1) % n_around
            j0, j1 = i0 + n_around, i1 + n_around
            faces += [[i0, i1, j1], [i0, j1, j0]]
    if capped:
        bottom, top = len(verts), len(verts) + 1
        verts = np.concatenate([verts, [[0, 0, 0], [0, 0, length]]])
        last = (n_rings - 1) * n_around
        for a in range(n_around):
            faces.append([bottom, (a + 1) % n_around, a])
            faces.append([top, last + a, last + (a + 1) % n_around])
    return verts, np.asarray(faces, dtype=np.int64)


def twist(vertices: np.ndarray, total_angle: float, length: float = 2.0) -> np.ndarray:
    """Twist about the z axis, angle growing linearly from 0 at z = 0 to ``total_angle`` at z = length."""
    phi = total_angle * vertices[:, 2] / length
    c, s = np.cos(phi), np.sin(phi)
    x, y = vertices[:, 0], vertices[:, 1]
    return np.stack([c * x - s * y, s * x + c * y, vertices[:, 2]], -1)


@pytest.fixture
def tube():
    return make_tube()


@pytest.fixture
def icosphere():
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=1)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


@pytest.fixture(scope="session")
def tube_dataset():
    """Bent and twisted tubes: 12 meshes, 2 natural parts."""
    from neuralcol.data.datasets import MeshDataset

    rest, faces = make_tube(n_rings=14, n_around=8)
    meshes = []
    for a in np.linspace(0, 1.0, 12):
        v = twist(rest, 0.8 * a)
        bend = 0.4 * a * (v[:, 2] / 2.0) ** 2  # bend the upper half sideways
        v = v + np.stack([bend, np.zeros_like(bend), np.zeros_like(bend)], -1)
        meshes.append(v)
    verts = torch.as_tensor(np.stack(meshes), dtype=torch.float32)
    return MeshDataset(verts, torch.as_tensor(faces), [str(i) for i in range(12)])


TUBE_LATENT = {"n_components": 2, "level2_dim": 2}


@pytest.fixture(scope="session")
def tube_space(tube_dataset, tmp_path_factory):
    """A small trained latent space of the tubes: (space, report, features, config, cache dir)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from neuralcol.data.features import dataset_features
    from neuralcol.stages.autoencoder import train_or_load_latent_space

    feats = dataset_features(tube_dataset, 0)
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3"):  # autoencoder=tiny, its defaults composed
        tiny = compose("config", overrides=["autoencoder=tiny"]).autoencoder
    cfg = OmegaConf.merge(tiny, {"level1": {"epochs": 150}, "level2": {"epochs": 100}, "val_fraction": 0.25})
    cache = tmp_path_factory.mktemp("ae_cache")
    space, report, cached = train_or_load_latent_space(tube_dataset, feats, cfg, TUBE_LATENT, 0, cache)
    assert not cached
    return space, report, feats, cfg, cache
