"""Speed against accuracy: the stage on a latent space whose labels are known by hand, its chart, and the
report's section from a hand-made sweep.

The latent space is a stand-in with the interface the stage reads (``decode``, ``faces``, ``rest_vertices``,
``partition``, ``box_lo``): a code (d, h) places a second unit icosphere at (d, h, 0) beside the first at the origin,
so a mesh self-collides iff the centres are closer than 2 (the test codes keep clear of 2 by 0.2, more than the
facets' 0.02). Every exact method must then agree with the hand labels exactly.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from experiments.reporting.speed_accuracy import plot_speed_accuracy, speed_accuracy_groups
from experiments.reporting.summary import speed_accuracy_table
from neuralcol.metrics.detection import detection_metrics
from neuralcol.nn.detector import CollisionDetector
from neuralcol.stages.speed import measure_speed_accuracy, speed_accuracy_problems

ROOT = Path(__file__).resolve().parents[1]


class TwoSpheres:
    """Codes (B, 2) -> two icospheres, the second at (z0, z1, 0); sub-domains: the spheres."""

    def __init__(self):
        import trimesh

        m = trimesh.creation.icosphere(subdivisions=2)
        v, f = np.asarray(m.vertices), np.asarray(m.faces)
        self.sphere = torch.as_tensor(v)
        self.faces = torch.as_tensor(np.concatenate([f, f + len(v)]))
        self.rest_vertices = torch.as_tensor(np.concatenate([v, v + [3.0, 0.0, 0.0]]))
        self.partition = torch.as_tensor(np.repeat([0, 1], len(v)))
        self.box_lo = torch.tensor([1.0, -0.3])
        self.box_hi = torch.tensor([3.0, 0.3])

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        shift = torch.cat([z, torch.zeros(len(z), 1, dtype=z.dtype)], 1)[:, None]  # (B, 1, 3)
        a = self.sphere.to(z.dtype).expand(len(z), -1, -1)
        return torch.cat([a, a + shift], 1)


def _codes(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """n codes whose centre distance is in [1.3, 1.8] (colliding) or [2.2, 2.8] (free), alternately."""
    rng = np.random.default_rng(seed)
    h = rng.uniform(-0.3, 0.3, n)
    dist = np.where(np.arange(n) % 2 == 0, rng.uniform(1.3, 1.8, n), rng.uniform(2.2, 2.8, n))
    z = np.stack([np.sqrt(dist ** 2 - h ** 2), h], 1).astype(np.float32)
    return z, dist < 2


def _cfg(**over) -> dict:
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=["speed_accuracy=tiny", *[f"speed_accuracy.{k}={v}" for k, v in
                                                                    over.items()]])
    return cfg


@pytest.fixture(scope="module")
def stage():
    """The stage on 24 test codes (tiny preset, MeshLab on 12 and FCL on 6 of them), a random detector whose run
    predictions are on disk and a cascade of two targets in the run's metrics."""
    import tempfile

    torch.manual_seed(0)
    space = TwoSpheres()
    z, y = _codes(24)
    net = CollisionDetector(2, 0, state_dim=8, hidden=16, box_lo=space.box_lo, box_hi=space.box_hi).eval()
    run_dir = Path(tempfile.mkdtemp())
    # the run's own predictions: the stage reports them for the eager float32 detector (here: every row right
    # but rows 0 and 1, whatever the random net says)
    said = y.copy()
    said[[0, 1]] = ~said[[0, 1]]
    np.savez(run_dir / "test_predictions.npz", logit=np.where(said, 1.0, -1.0).astype(np.float32), collides=y)
    cascade = {"targets": [
        {"target_fnr": 0.01, "test": {"fnr": 0.008, "accuracy": 0.97, "exact_share": 0.2, "n": 24},
         "samples_per_s": 900.0},
        {"target_fnr": 0.05, "test": {"fnr": 0.04, "accuracy": 0.95, "exact_share": 0.05, "n": 24},
         "samples_per_s": 4000.0}]}
    cfg = _cfg(n_timed=4, n_exact=24, n_meshlab=12, n_fcl=6, reps=2)
    lines: list[str] = []
    sa = measure_speed_accuracy(space, net, SimpleNamespace(z=z, collides=y), cfg.speed_accuracy, cfg.labeling,
                                {"cascade": cascade}, run_dir, log=lines.append)
    return SimpleNamespace(sa=sa, net=net, z=z, y=y, lines=lines, said=said)


def _by(sa: dict) -> dict:
    return {(p["method"], p["variant"]): p for p in sa["points"]}


def test_stage_points_their_accuracy_and_timing(stage):
    pytest.importorskip("pymeshlab")
    sa, pts = stage.sa, _by(stage.sa)
    assert set(pts) == {
        ("exact", "verdict"), ("exact", "label + PD"), ("meshlab", "self-intersecting faces"), ("fcl", "verdict"),
        ("latent detector", "float32 eager"), ("latent detector", "bfloat16_checked eager"),
        ("cascade", "FNR<=0.01"), ("cascade", "FNR<=0.05")}
    assert sa["threads"] == torch.get_num_threads() and sa["n_timed"] == 4 and sa["decode_ms_per_sample"] > 0
    # every geometric method agrees with the hand labels on these clear cases
    for key, n in ((("exact", "verdict"), 24), (("exact", "label + PD"), 24), (("meshlab", "self-intersecting faces"),
                                                                                 12), (("fcl", "verdict"), 6)):
        assert (pts[key]["accuracy"], pts[key]["fnr"], pts[key]["n_scored"]) == (1.0, 0.0, n), key
    # timed: code in, verdict out; the latent detector at the config's batch
    for key, p in pts.items():
        if key[0] != "cascade":
            assert p["samples_per_s"] > 0 and p["n_timed"] == (256 if key[0] == "latent detector" else 4), key
    # the eager float32 detector: the run's test_predictions.npz (rows 0 and 1 wrong: one colliding, one free)
    eager = pts[("latent detector", "float32 eager")]
    assert (eager["accuracy"], eager["fnr"], eager["n_scored"]) == (22 / 24, 1 / 12, 24)
    # the bfloat16 copy: measured on the whole test set, against the random net's own float32 predictions
    with torch.no_grad():
        ref = detection_metrics(stage.net(torch.as_tensor(stage.z)).logit.numpy() > 0, stage.y)
    bf = pts[("latent detector", "bfloat16_checked eager")]
    assert bf["n_scored"] == 24 and abs(bf["accuracy"] - ref["accuracy"]) <= 2 / 24
    # the cascade's targets as written, and priced with this stage's timings
    c1 = pts[("cascade", "FNR<=0.01")]
    assert (c1["samples_per_s_stage"], c1["accuracy"], c1["fnr"], c1["n_scored"]) == (900.0, 0.97, 0.008, 24)
    t_det = 1 / eager["samples_per_s"]
    t_exact = 1 / pts[("exact", "verdict")]["samples_per_s"]  # the cascade's exact path: the verdict
    assert c1["samples_per_s"] == pytest.approx(1 / (t_det + 0.2 * t_exact))
    json.dumps(sa, allow_nan=False)  # metrics.json stays valid JSON
    assert any("timing 6 methods" in line for line in stage.lines)
    table = "\n".join(speed_accuracy_table(sa))
    assert "exact            verdict" in table and "FNR<=0.05" in table


def test_stage_without_cascade_or_meshlab(monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_meshlab(name, *a, **k):
        if name == "pymeshlab":
            raise ImportError("No module named 'pymeshlab'")
        return real_import(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_meshlab)
    space = TwoSpheres()
    z, y = _codes(8, seed=1)
    net = CollisionDetector(2, 0, state_dim=8, hidden=16, box_lo=space.box_lo, box_hi=space.box_hi).eval()
    cfg = _cfg(forms="[]", fcl="false", exact_full_label="false")
    sa = measure_speed_accuracy(space, net, SimpleNamespace(z=z, collides=y), cfg.speed_accuracy, None, None,
                                log=lambda s: None)
    assert set(_by(sa)) == {("exact", "verdict"), ("latent detector", "float32 eager")}
    exact = _by(sa)[("exact", "verdict")]
    assert (exact["accuracy"], exact["fnr"], exact["n_scored"]) == (1.0, 0.0, 8)
    notes = " ".join(sa["notes"])
    assert "MeshLab left out: pymeshlab is not importable" in notes
    assert "no cascade" in notes and "mesh detector" not in notes


def test_config_problems_are_named():
    cfg = _cfg()
    assert speed_accuracy_problems(cfg.speed_accuracy) == []
    from neuralcol.pipeline.validate import config_problems

    bad = _cfg(n_timed=0, forms="[float16]", reps=1.5)
    problems = config_problems(bad)
    assert any(p.startswith("speed_accuracy.n_timed=0: must be an integer >= 1") for p in problems)
    assert any(p.startswith("speed_accuracy.forms=['float16']") for p in problems)
    assert any(p.startswith("speed_accuracy.reps=1.5") for p in problems)


POINTS = [
    {"method": "exact", "variant": "verdict", "samples_per_s": 300.0, "accuracy": 1.0, "fnr": 0.0, "n_timed": 32,
     "n_scored": 300},
    {"method": "exact", "variant": "label + PD", "samples_per_s": 250.0, "accuracy": 1.0, "fnr": 0.0, "n_timed": 32,
     "n_scored": 300},
    {"method": "meshlab", "variant": "self-intersecting faces", "samples_per_s": 260.0, "accuracy": 1.0, "fnr": 0.0,
     "n_timed": 32, "n_scored": 300},
    {"method": "fcl", "variant": "verdict", "samples_per_s": 30.0, "accuracy": 0.99, "fnr": 0.02, "n_timed": 32,
     "n_scored": 100},
    {"method": "latent detector", "variant": "float32 compiled", "samples_per_s": 2e6, "accuracy": 0.93,
     "fnr": 0.1, "n_timed": 4096, "n_scored": 3000},
    {"method": "latent detector", "variant": "float32 eager", "samples_per_s": 1.5e6, "accuracy": 0.93,
     "fnr": 0.1, "n_timed": 4096, "n_scored": 3000},
    # the separate mesh detector's point, as older runs that had one recorded it: still charted and tabled
    {"method": "mesh detector", "variant": "decode + network", "samples_per_s": 900.0, "accuracy": None,
     "fnr": None, "n_timed": 32, "n_scored": 0},
    {"method": "cascade", "variant": "FNR<=0.01", "samples_per_s": 2000.0, "accuracy": 0.99, "fnr": 0.009,
     "n_timed": 0, "n_scored": 3000},
    {"method": "cascade", "variant": "FNR<=0.05", "samples_per_s": 9000.0, "accuracy": 0.97, "fnr": 0.04,
     "n_timed": 0, "n_scored": 3000},
]


def test_chart_from_hand_made_points(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    seen = {}
    close = plt.close

    def keep(fig=None):  # look at the figure before the chart's context closes it
        from matplotlib.text import Text

        axes = fig.axes
        renderer = fig.canvas.get_renderer()
        boxes = [Text.get_window_extent(t, renderer) for ax in axes for t in ax.texts]  # the texts, not the leaders
        seen["overlaps"] = sum(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:])
        seen["xscale"] = [ax.get_xscale() for ax in axes]
        seen["ylabels"] = [ax.get_ylabel() for ax in axes]
        seen["texts"] = [t.get_text() for t in axes[0].texts]
        seen["lines"] = [line.get_xdata().tolist() for line in axes[0].lines]
        close(fig)

    monkeypatch.setattr(plt, "close", keep)
    path = tmp_path / "speed_accuracy.png"
    plot_speed_accuracy(POINTS, path, "toy")
    assert path.stat().st_size > 10_000
    assert seen["xscale"] == ["log", "log"]
    assert seen["ylabels"][0].startswith("accuracy") and seen["ylabels"][1].startswith("false negative rate")
    # every point with an accuracy is labelled with its variant (the mesh detector has none here)
    assert sorted(seen["texts"]) == sorted(p["variant"] for p in POINTS if p["accuracy"] is not None)
    assert seen["lines"] == [[2000.0, 9000.0]], "the cascade's targets joined, in target order"
    assert seen["overlaps"] == 0, "no label covers another"


def _run(root: Path, name: str, method: str, seed: int, scale: float, points: bool = True) -> None:
    d = root / name
    d.mkdir(parents=True)
    rounds = [{"round": i, "dataset_size": 4 * (i + 1), "accuracy": 0.8, "fnr": 0.1, "fpr": 0.1,
               "balanced_accuracy": 0.8, "majority_accuracy": 0.6, "label_seconds": 1.0, "train_seconds": 1.0,
               "project_seconds": 0.0} for i in range(2)]
    metrics = {"dataset": {"name": "toy"}, "seed": seed, "latent": {"dim": 4, "n_parts": 2},
               "autoencoder": {"n_parameters": 10},
               "detector": {"method": method, "pd_unit": 1.0, "n_parameters": 50, "test_set": {"n": 8},
                            "net": {"state_dim": 8, "hidden": 16}},
               "rounds": rounds, "handling": None}
    if points:
        pts = [dict(p, samples_per_s=p["samples_per_s"] * scale,
                    accuracy=None if p["accuracy"] is None else p["accuracy"] - (scale - 1) / 10)
               for p in POINTS]
        metrics["speed_accuracy"] = {"points": pts, "threads": 2, "n_timed": 32, "notes": []}
    (d / "metrics.json").write_text(json.dumps(metrics))


def test_report_section_from_a_hand_made_sweep(tmp_path):
    from experiments.report import main as report_main

    sweep = tmp_path / "sweep"
    for i, scale in enumerate((1.0, 2.0, 4.0)):  # three seeds of active: the medians are the scale-2 run's
        _run(sweep, f"a{i}", "active", i, scale)
    _run(sweep, "old", "active", 9, 1.0, points=False)  # a run without speed-accuracy points: named, never a crash
    out = tmp_path / "report"
    report_main([str(sweep), "--out", str(out), "--bench", str(tmp_path / "none.json")])
    assert (out / "speed_accuracy_toy.png").stat().st_size > 10_000
    text = (out / "report.md").read_text()
    block = text.split("### toy: speed against accuracy", 1)[1]
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in block.splitlines()
            if line.startswith("| ") and not line.startswith("| method |")]
    by = {(r[0], r[1]): r[2:] for r in rows}
    assert [(r[0], r[1]) for r in rows] == [
        ("latent detector", "float32 compiled"), ("latent detector", "float32 eager"), ("cascade", "FNR<=0.05"),
        ("cascade", "FNR<=0.01"), ("mesh detector", "decode + network"), ("exact", "verdict"),
        ("meshlab", "self-intersecting faces"), ("exact", "label + PD"), ("fcl", "verdict")], "fastest first"
    assert by[("exact", "verdict")] == ["3", "600", "0.9000", "0.0000", "300"]
    assert by[("latent detector", "float32 compiled")] == ["3", "4e+06", "0.8300", "0.1000", "3000"]
    assert by[("mesh detector", "decode + network")] == ["3", "1800", "—", "—", "0"]
    assert by[("cascade", "FNR<=0.01")] == ["3", "4000", "0.8900", "0.0090", "3000"]
    assert "![toy: speed against accuracy](speed_accuracy_toy.png)" in block
    assert "1 of 4 toy runs have no speed_accuracy" in text
    numbers = json.loads((out / "report.json").read_text())["speed_accuracy"]["toy"]
    assert {(p["method"], p["variant"]): p["samples_per_s"] for p in numbers}[("fcl", "verdict")] == 60.0


def test_report_keeps_trained_methods_apart_per_training_method():
    runs = []
    for m, scale in (("active", 1.0), ("supv", 2.0)):
        pts = [dict(p, samples_per_s=p["samples_per_s"] * scale) for p in POINTS]
        runs.append({"dataset": {"name": "toy"}, "detector": {"method": m},
                     "speed_accuracy": {"points": pts, "threads": 2}})
    groups, notes = speed_accuracy_groups(runs)
    names = {(p["method"], p["variant"]): p for p in groups["toy"]}
    assert names[("exact", "verdict")]["n_runs"] == 2 and names[("exact", "verdict")]["samples_per_s"] == 450.0
    assert names[("latent detector (supv)", "float32 compiled")]["samples_per_s"] == 4e6
    assert names[("cascade (active)", "FNR<=0.01")]["n_runs"] == 1 and notes == []
