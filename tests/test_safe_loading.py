"""Checkpoints and cache files are read without unpickling code.

A crafted file whose pickled object creates a marker file when unpickled stands for a malicious run directory
or cache entry: every loader must refuse it with one clear error naming the file, and the marker must not
appear. Files written by neuralcol hold tensors and plain values only, and files of older versions with numpy
values keep loading.
"""

from __future__ import annotations

import json
import pickle
import re
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf
from test_active import _train

from neuralcol.errors import UnsafeFileError, UserInputError
from neuralcol.nn.detector import detector_for_space, load_detector, save_detector
from neuralcol.nn.latent_space import LatentSpace
from neuralcol.rundir import CacheDir, RunDir
from neuralcol.utils.safe_files import plain_values

ROOT = Path(__file__).resolve().parents[1]
CACHE_KEY = "0123456789abcdef"
DET_NET = {"_target_": "neuralcol.nn.detector.detector_for_space", "_partial_": True, "state_dim": np.int64(8),
           "hidden": 16, "normalize_inputs": True}  # a numpy value, as a config could carry


class CreatesFile:
    """Unpickling this object opens ``path`` for writing, i.e. creates it: the stand-in for arbitrary code."""

    def __init__(self, path: Path):
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


def _write_malicious(path: Path, marker: Path) -> Path:
    """A torch.save'd dict shaped like a neuralcol file, with the marker-creating object inside."""
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"state": {"w": torch.zeros(2)}, "meta": {"note": CreatesFile(marker)}}, path)
    return path


def _refused(path: Path) -> str:
    """The error's expected start: the file, then what it holds."""
    return rf"{re.escape(str(path))}: holds pickled Python objects \(io\.open\); neuralcol does not unpickle"


def _finished_run(tmp_path: Path, space: LatentSpace) -> Path:
    """A finished run's directory as load_run reads it: config, metrics, detector.pt and, in the run's cache,
    the latent space."""
    run, cache = tmp_path / "run", tmp_path / "cache"
    (run / ".hydra").mkdir(parents=True)
    cfg = {"dataset": {"name": "tube"}, "labeling": {}, "detector": {"loss": {"temperature": 0.1}}, "handler": {},
           "paths": {"cache_dir": str(cache)}}
    OmegaConf.save(OmegaConf.create(cfg), RunDir(run).config)
    RunDir(run).metrics.write_text(json.dumps({"autoencoder": {"cache_key": CACHE_KEY}, "detector": {}}))
    space.save(CacheDir(cache).latent_space(CACHE_KEY))
    net = detector_for_space(space, state_dim=8, hidden=16)
    save_detector(RunDir(run).detector, net, {"net": DET_NET}, {"name": "supv"}, 0.25)
    return run


def _assert_same_state(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b)
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0, msg=lambda m, k=k: f"{k}: {m}")


# ----------------------------------------------------------------------------- the payload is live
def test_the_crafted_file_does_run_code_when_unpickled(tmp_path):
    """The attack the other tests refuse is real: unpickling the crafted file creates the marker."""
    marker = tmp_path / "marker"
    path = _write_malicious(tmp_path / "f.pt", marker)
    torch.load(path, weights_only=False)  # what neuralcol used to do
    assert marker.exists()


# ----------------------------------------------------------------------------- refused, with the file named
def test_load_detector_refuses_a_pickled_detector(tmp_path):
    marker = tmp_path / "marker"
    path = _write_malicious(tmp_path / "run" / "detector.pt", marker)
    with pytest.raises(UnsafeFileError, match=_refused(path) + r".*re-create it"):
        load_detector(path)
    assert not marker.exists()


def test_latent_space_load_refuses_a_pickled_cache_entry(tmp_path):
    marker = tmp_path / "marker"
    path = _write_malicious(CacheDir(tmp_path).latent_space(CACHE_KEY), marker)
    with pytest.raises(UnsafeFileError, match=_refused(path) + rf".*delete {re.escape(str(path.parent))}"):
        LatentSpace.load(path)
    assert not marker.exists()


def test_load_run_refuses_a_pickled_detector_or_latent_space(tmp_path, tube_space):
    import neuralcol

    space = tube_space[0]
    run = _finished_run(tmp_path, space)
    with neuralcol.load_run(run) as ok:  # the run as written loads
        _assert_same_state(ok.space.state_dict(), space.state_dict())
    marker = tmp_path / "marker"
    space_path = CacheDir(tmp_path / "cache").latent_space(CACHE_KEY)
    _write_malicious(space_path, marker)
    with pytest.raises(UnsafeFileError, match=_refused(space_path)):
        neuralcol.load_run(run)
    _write_malicious(RunDir(run).detector, marker)
    with pytest.raises(UnsafeFileError, match=_refused(RunDir(run).detector)):
        neuralcol.load_run(run)
    # a mesh_detector.pt (the separate mesh detector, folded into the run's detector) is never read
    _write_malicious(RunDir(run) / "mesh_detector.pt", marker)
    space.save(space_path)
    save_detector(RunDir(run).detector, detector_for_space(space, 8, 16), {"net": DET_NET}, {"name": "supv"}, 0.25)
    with neuralcol.load_run(run) as ok:
        _assert_same_state(ok.space.state_dict(), space.state_dict())
    assert not marker.exists()


def test_entry_points_print_one_line_and_exit_2(tmp_path, tube_space, monkeypatch, capsys):
    from experiments.compare_runs import main as compare_main
    from experiments.handle import main as handle_main

    for var in ("HYDRA_FULL_ERROR", "NEURALCOL_DEBUG"):
        monkeypatch.delenv(var, raising=False)
    run = _finished_run(tmp_path, tube_space[0])
    other = tmp_path / "other"
    shutil.copytree(run, other)
    marker = tmp_path / "marker"
    _write_malicious(RunDir(run).detector, marker)
    codes = tmp_path / "codes.npy"
    np.save(codes, np.zeros((1, tube_space[0].dim), np.float32))
    for main, argv in ((handle_main, [str(run), str(codes)]), (compare_main, [str(other), str(run)])):
        with pytest.raises(SystemExit) as exit_info:
            main(argv)
        assert exit_info.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and re.match("error: " + _refused(RunDir(run).detector), err[0]), err
    assert not marker.exists()


def test_a_damaged_file_is_named_not_a_traceback(tmp_path, tube_space):
    path = tube_space[0].save(tmp_path / "latent_space.pt")
    path.write_bytes(path.read_bytes()[:1000])
    unreadable = "cannot be read as a torch file of tensors and plain values"
    with pytest.raises(UnsafeFileError, match=rf"{re.escape(str(path))}: {unreadable} \(RuntimeError: "
                                              r"PytorchStreamReader.*damaged"):
        LatentSpace.load(path)
    garbage = tmp_path / "detector.pt"
    garbage.write_bytes(b"not a torch file at all")
    with pytest.raises(UnsafeFileError, match=rf"{re.escape(str(garbage))}: {unreadable} .*damaged"):
        load_detector(garbage)


# ----------------------------------------------------------------------------- what neuralcol writes
def test_latent_space_round_trip_holds_plain_values_only(tmp_path, tube_space):
    space = LatentSpace.load(tube_space[0].save(tmp_path / "copy.pt"))  # a copy whose meta this test may change
    space.meta = {**space.meta, "np_scalar": np.float64(0.5), "np_array": np.arange(3),
                  "config": OmegaConf.create({"lr": 1e-3, "sizes": [1, 2]}), "pair": (1, 2), "where": tmp_path}
    path = space.save(tmp_path / "latent_space.pt")
    assert torch.serialization.get_unsafe_globals_in_checkpoint(path) == []
    loaded = LatentSpace.load(path)
    _assert_same_state(loaded.state_dict(), space.state_dict())
    z = space.sample(4, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(loaded.decode(z), space.decode(z), rtol=0, atol=0)
    meta = loaded.meta
    assert meta["np_scalar"] == 0.5 and type(meta["np_scalar"]) is float
    assert meta["np_array"] == [0, 1, 2] and meta["config"] == {"lr": 1e-3, "sizes": [1, 2]}
    assert meta["pair"] == (1, 2) and meta["where"] == str(tmp_path)


def test_detector_round_trip_holds_plain_values_only(tmp_path, tube_space):
    net = detector_for_space(tube_space[0], state_dim=8, hidden=16)
    path = tmp_path / "detector.pt"
    save_detector(path, net, {"net": DET_NET}, {"name": "active"}, np.float32(0.25))
    assert torch.serialization.get_unsafe_globals_in_checkpoint(path) == []
    loaded, facts = load_detector(path)
    _assert_same_state(loaded.state_dict(), net.state_dict())
    assert facts["net"]["state_dim"] == 8 and type(facts["net"]["state_dim"]) is int
    assert facts["pd_unit"] == 0.25 and facts["method"] == "active"


def _as_numpy1(path: Path) -> None:
    """Rewrite a torch file as numpy 1.x pickled it (module ``numpy.core`` instead of numpy 2's ``numpy._core``)."""
    with zipfile.ZipFile(path) as zin:
        entries = [(i.filename, zin.read(i.filename)) for i in zin.infolist()]
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zout:
        for name, data in entries:
            zout.writestr(name, data.replace(b"numpy._core.multiarray", b"numpy.core.multiarray")
                          if name.endswith("data.pkl") else data)


@pytest.mark.parametrize("numpy_major", [2, 1])
def test_files_with_numpy_values_from_older_versions_keep_loading(tmp_path, tube_space, numpy_major):
    path = tube_space[0].save(tmp_path / "latent_space.pt")
    blob = torch.load(path, weights_only=True)
    blob["meta"] = {"train_seconds": np.float64(1.5), "train_index": np.arange(4), "n": np.int64(3)}
    torch.save(blob, path)  # as a writer without plain_values could have: numpy values in the pickle
    if numpy_major == 1:
        _as_numpy1(path)
        assert "numpy.core.multiarray.scalar" in torch.serialization.get_unsafe_globals_in_checkpoint(path)
    loaded = LatentSpace.load(path)
    assert loaded.meta["train_seconds"] == 1.5 and loaded.meta["n"] == 3
    np.testing.assert_array_equal(loaded.meta["train_index"], np.arange(4))
    _assert_same_state(loaded.state_dict(), tube_space[0].state_dict())


def test_plain_values_names_what_it_cannot_store():
    with pytest.raises(TypeError, match=r"detector.pt\['net'\]\['act'\]: a .*CreatesFile cannot be saved"):
        plain_values({"net": {"act": CreatesFile("x")}}, "detector.pt")


# ----------------------------------------------------------------------------- Lightning's resume checkpoint
SMALL = {"epochs": 2, "finetune_epochs": 2, "max_rounds": 2, "n_init": 100, "n_aug": 50, "test_size": 200}


def test_detector_checkpoint_resumes_with_weights_only_and_refuses_pickles(tmp_path, monkeypatch):
    from neuralcol.active import acquisition
    from neuralcol.stages import detector as stage

    real = acquisition.UniformAcquisition.__call__

    def dies_in_round_2(self, round_, net, store, n):
        if round_ == 2:
            raise RuntimeError("simulated crash")
        return real(self, round_, net, store, n)

    monkeypatch.setattr(acquisition.UniformAcquisition, "__call__", dies_in_round_2)
    with pytest.raises(RuntimeError, match="simulated crash"):
        _train(tmp_path, "supv", run="cut", **SMALL)
    monkeypatch.setattr(acquisition.UniformAcquisition, "__call__", real)
    ckpt = RunDir(tmp_path / "cut").checkpoint
    assert torch.serialization.get_unsafe_globals_in_checkpoint(ckpt) == []  # hyperparameters, optimizer, rounds
    shutil.copytree(tmp_path / "cut", tmp_path / "evil")
    resumed, _ = _train(tmp_path, "supv", run="cut", **SMALL)  # Lightning reads it with weights_only=True
    assert resumed.summary["resumed"] is True and [r["round"] for r in resumed.rounds] == [0, 1, 2]

    marker = tmp_path / "marker"
    evil = _write_malicious(RunDir(tmp_path / "evil").checkpoint, marker)
    with pytest.raises(UnsafeFileError, match=_refused(evil) + ".*delete it to restart"):
        _train(tmp_path, "supv", run="evil", **SMALL)
    # without the check before training, Lightning itself refuses the file (fit(..., weights_only=True))
    monkeypatch.setattr(stage, "read_torch_file", lambda *args, **kwargs: None)
    with pytest.raises(pickle.UnpicklingError, match="io.open"):
        _train(tmp_path, "supv", run="evil", **SMALL)
    assert not marker.exists()


# ----------------------------------------------------------------------------- no unsafe load left in the code
def _code_lines(*dirs: str):
    for d in dirs:
        for path in sorted((ROOT / d).rglob("*.py")):
            for no, line in enumerate(path.read_text().splitlines(), 1):
                yield path.relative_to(ROOT), no, line


def test_no_unpickling_load_is_left_in_the_code():
    """Package code reads torch files only through read_torch_file, never with weights_only=False, and never
    unpickles numpy or pickle files. (``save_checkpoint(..., weights_only=False)`` is Lightning's flag for
    *what to save*, the full training state; it is read back with weights_only=True.)"""
    lines = list(_code_lines("neuralcol", "experiments", "bench", "research"))
    assert len(lines) > 1000  # the scan saw the code
    loads = {str(p) for p, _, line in lines if "torch.load(" in line}
    assert loads == {"neuralcol/utils/safe_files.py"}, loads
    def unpickles(p, line):
        return re.search(r"\bpickle\.loads?\(", line) and (str(p), line.strip()) not in IPC

    bad = [f"{p}:{no}: {line.strip()}" for p, no, line in lines
           if ("weights_only=False" in line and "save_checkpoint(" not in line)
           or "allow_pickle=True" in line or unpickles(p, line)]
    assert not bad, "\n".join(bad)
    assert all(any(str(p) == q and line.strip() == t for p, _, line in lines) for q, t in IPC), "IPC: stale entry"


# unpickling that is not reading a user's file: bytes this process pickled for its own label-pool workers (as
# multiprocessing does with every task), so that torch's shared-memory tensors stay out of the workers; and the
# labeler and decoder the pool pickled into its own temporary folder (tempfile: mode 0700, removed by close()),
# which its workers read as they start
IPC = {("neuralcol/samples/oracle.py", 'self.space = pickle.loads(state["space_bytes"])'),
       ("neuralcol/collision/pool.py", "_WORKER_LABELER = pickle.load(f)"),
       ("neuralcol/collision/pool.py", "_WORKER_DECODER = (path, pickle.load(f))")}


def test_load_run_refuses_a_config_naming_foreign_callables(tmp_path, tube_space):
    """A shared run's config is instantiated by Hydra when the run labels or resolves: a ``_target_`` outside
    neuralcol / torch.optim / lightning is refused (an interpolated one too) unless the user trusts the run."""
    import neuralcol
    from neuralcol.api import untrusted_targets

    run = _finished_run(tmp_path, tube_space[0])
    cfg = OmegaConf.load(RunDir(run).config)
    cfg.labeling = {"labeler": {"_target_": "neuralcol.collision.labeler.ExactLabeler"}}
    OmegaConf.save(cfg, RunDir(run).config)
    with neuralcol.load_run(run):  # neuralcol's own targets load
        pass
    for target in ("os.system", "builtins.eval", "${oc.env:EVIL}", "neuralcolx.evil.f"):
        cfg.labeling = {"pool": {"executor": {"_target_": target}}}
        OmegaConf.save(cfg, RunDir(run).config)
        with pytest.raises(UserInputError, match=r"config\.yaml: names callables outside .*labeling\.pool\."
                                                 r"executor\._target_=.*trust_config=True"):
            neuralcol.load_run(run)
        with neuralcol.load_run(run, trust_config=True):
            pass
    assert untrusted_targets(OmegaConf.create({"a": [{"_target_": "torch.optim.Adam"}, {"_target_": "x.y"}]})) \
        == ["a.1._target_='x.y'"]
