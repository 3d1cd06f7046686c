"""The report's Pareto, cost and failure charts from a hand-made sweep whose numbers are known by hand.

Four runs of one toy data set (8 test rows, pd_unit 1): a small configuration (K2 L1 8/16, two seeds of
``active``), a larger one (K2 L1 16/32, ``active``) and an old ``supv`` run of the larger size without the
per-run files (left out of the detector breakdown and the time axis, never a crash). The real runs that
write these files are checked in tests/test_run.py and tests/test_active.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from experiments.report import main as report_main
from experiments.reporting.discover import load_chosen
from neuralcol.errors import UserInputError

PD = np.array([-0.9, -0.1, -0.2, 0.5, 0.7, 2.0, 5.0, 6.0])  # PD bins 0, 1, 1, 2, 2, 3, 4, 4 (pd_unit 1)
# deepest sub-domain of the colliding rows 3..7: 0, 0, 1, 1, 1
PD_SUB = np.array([[-0.9, -1.0], [-0.1, -0.3], [-0.2, -0.5], [0.5, 0.1], [0.7, 0.2], [1.0, 2.0], [1.0, 5.0],
                   [2.0, 6.0]])
HANDLER_PD = np.array([0.5, 2.0, 5.0, 0.8])  # PD bins 2, 3, 4, 2


def _run(root: Path, name: str, size: tuple[int, int], method: str, seed: int, accuracy: float, params: int,
         us4096: float | None, wrong_rows: list[int] | None, handler_success: list[bool], new: bool = True) -> None:
    d = root / name
    (d / "handling").mkdir(parents=True)
    detector = {"method": method, "pd_unit": 1.0, "n_parameters": params,
                "net": {"state_dim": size[0], "hidden": size[1]}, "test_set": {"n": 8}}
    if us4096 is not None:
        detector["inference_us"] = {"batch_1": 100 * us4096, "batch_4096": us4096, "threads": 1}
    rounds = [{"round": i, "dataset_size": 4 * (i + 1), "accuracy": accuracy - 0.1 * (1 - i), "fnr": 0.1,
               "fpr": 0.1, "balanced_accuracy": 0.8, "majority_accuracy": 0.625, "label_seconds": 2.0 * (i + 1),
               "train_seconds": 3.0 * (i + 1), "project_seconds": 0.0} for i in range(2)]
    handling = {"n": 4, "success_rate": float(np.mean(handler_success)), "resolved_rate": 0.5,
                "mean_pd_reduction": 0.9, "mean_embedding_diff": 1.0, "seconds_per_mesh": 0.01}
    metrics = {"dataset": {"name": "toy"}, "seed": seed, "latent": {"dim": 4, "n_parts": 2},
               "autoencoder": {"n_parameters": 10}, "detector": detector, "rounds": rounds, "handling": handling}
    (d / "metrics.json").write_text(json.dumps(metrics))
    hand = {"pd_before": HANDLER_PD, "pd_after": np.where(handler_success, -0.1, 1.0),
            "success": np.array(handler_success)}
    if not new:  # a run from before per-input data were saved: only the handler's full arrays, no predictions
        np.savez(d / "handling" / "handling.npz", **hand)
        return
    np.savez(d / "handling" / "per_input.npz", **hand, pd_sub_before=PD_SUB[3:7])
    collides = PD > 0
    said = collides.copy()
    said[wrong_rows] = ~said[wrong_rows]
    logit = np.where(said, 2.0, -2.0).astype(np.float32)
    np.savez(d / "test_predictions.npz", prob=1 / (1 + np.exp(-logit)), logit=logit, pd=PD.astype(np.float32),
             pd_sub=PD_SUB.astype(np.float32), collides=collides)


@pytest.fixture
def sweep(tmp_path) -> Path:
    s = tmp_path / "sweep"
    _run(s, "0", (8, 16), "active", 0, 0.75, 100, 1.0, [1, 4], [False, True, True, True])
    _run(s, "1", (8, 16), "active", 1, 0.75, 100, 1.4, [4, 6], [False, False, True, True])
    _run(s, "2", (16, 32), "active", 0, 0.875, 400, 3.0, [1], [True, True, True, True])
    _run(s, "3", (16, 32), "supv", 0, 0.75, 400, None, None, [False, True, True, False], new=False)
    return s


def _table(text: str, title: str) -> list[list[str]]:
    """The rows of the Markdown table under the heading that contains ``title`` (cells stripped)."""
    block = text.split(title, 1)[1].split("\n### ", 1)[0].split("\n## ", 1)[0]
    rows = [line for line in block.splitlines() if line.startswith("| ") and not line.startswith("| method |")
            and not line.startswith("| configuration |")]
    return [[c.strip() for c in r.strip("|").split("|")] for r in rows]


def test_pareto_cost_and_failures_from_a_hand_made_sweep(sweep, tmp_path, capsys):
    (sweep / "model_size.json").write_text(json.dumps(
        {"chosen": {"n_components": 2, "level2_dim": 1, "state_dim": 8, "hidden": 16}}))
    out = tmp_path / "report"
    report_main([str(sweep), "--out", str(out), "--bench", str(tmp_path / "none.json")])
    for chart in ("pareto.png", "cost.png", "failures.png"):
        assert (out / chart).stat().st_size > 10_000, chart
    text = (out / "report.md").read_text()
    # Pareto: one row per configuration and method, cheapest first; the small active (6/8) and the large active
    # (7/8) are on the parameter front, the large supv (as accurate as the small active, 4x the parameters) is
    # not; the old supv run has no inference time
    pareto = _table(text, "toy: accuracy against detector size")
    assert [(r[0], r[1], r[2], r[3]) for r in pareto] == [
        ("K2 L1 8/16", "active", "2", "100"), ("K2 L1 16/32", "supv", "1", "400"),
        ("K2 L1 16/32", "active", "1", "400")]
    assert [r[4] for r in pareto] == ["1.20 ± 0.28", "—", "3.00"]
    assert [r[6] for r in pareto] == ["0.750 ± 0.000", "0.750", "0.875"]
    assert [(r[7], r[8], r[9]) for r in pareto] == [("yes", "yes", "**chosen**"), ("", "", ""), ("yes", "yes", "")]
    # failures: one row per method and PD bin; the rates by hand (the two seeds of the small configuration
    # miss rows 1 and 4, and rows 4 and 6)
    fails = _table(text, "toy: where each method fails")
    small = [r for r in fails if r[0] == "active (K2 L1 8/16)"]
    assert [r[1] for r in small] == ["free, clearance > 0.25", "free, clearance ≤ 0.25", "PD ≤ 1", "1 < PD ≤ 4",
                                     "PD > 4"]
    assert [r[2] for r in small] == ["1", "2", "2", "1", "2"]
    assert [r[3] for r in small] == ["1.000 ± 0.000", "0.750 ± 0.354", "0.500 ± 0.000", "1.000 ± 0.000",
                                     "0.750 ± 0.354"]
    # handler: inputs of PD 0.5 and 0.8 (one success of two, both seeds), 2.0 (seed 0 only), 5.0 (both)
    assert [r[4] for r in small] == ["0", "0", "2", "1", "1"]
    assert [r[5] for r in small] == ["—", "—", "0.500 ± 0.000", "0.500 ± 0.707", "1.000 ± 0.000"]
    old = [r for r in fails if r[0] == "supv (K2 L1 16/32)"]
    assert len(old) == 5 and {r[3] for r in old} == {"—"}, "no predictions: no detector breakdown"
    assert [r[5] for r in old][2:] == ["0.000", "1.000", "1.000"], "the handler's older handling.npz is read"
    recall = _table(text, "toy: recall by the deepest sub-domain")
    assert [r[1:] for r in recall if r[0] == "active (K2 L1 8/16)"] == [["0", "2", "0.500 ± 0.000"],
                                                                      ["1", "3", "0.833 ± 0.236"]]
    assert [r[1:] for r in recall if r[0] == "supv (K2 L1 16/32)"] == [["—", "—", "—"]]
    # the old run is named once per missing file, never a crash
    err = capsys.readouterr().err
    assert err.count("left out: ") == 2 and "1 of 4 runs have no test_predictions.npz" in err
    numbers = json.loads((out / "report.json").read_text())
    assert {(p["label"], p["method"]): p["chosen"] for p in numbers["pareto"]} == {
        ("K2 L1 8/16", "active"): True, ("K2 L1 16/32", "active"): False, ("K2 L1 16/32", "supv"): False}


def test_without_model_size_json_nothing_is_marked_and_a_bad_one_is_named(sweep, tmp_path):
    out = tmp_path / "report"
    report_main([str(sweep), "--out", str(out), "--bench", str(tmp_path / "none.json")])
    assert "**chosen**" not in (out / "report.md").read_text()
    (sweep / "model_size.json").write_text(json.dumps({"chosen": {"width": 16}}))
    with pytest.raises(UserInputError, match=r"model_size.json: unknown key\(s\) \['width'\]"):
        load_chosen([sweep])
    (sweep / "model_size.json").write_text(json.dumps({"chosen": {"method": "supv_bd"}}))
    report_main([str(sweep), "--out", str(out), "--bench", str(tmp_path / "none.json")])
    assert "matches no configuration of toy" in (out / "report.md").read_text()


def test_table3_reads_logit_0_with_the_operating_point_beside_and_the_papers_figures(tmp_path):
    """A run that records its last round at an operating point is read at logit 0 in the curves and Table
    3 (the paper's decision), with the operating point as rows of their own; a data set of the paper's Table 3 gets
    the paper's figures beside (SCAPE's: 93.83 % / 5.15 %, equivalent size 663000)."""
    import shutil

    s = tmp_path / "sweep"
    for seed, (op_acc, at0_acc) in enumerate(((0.70, 0.90), (0.72, 0.80))):
        _run(s, str(seed), (8, 16), "active", seed, 0.9, 100, 1.0, [1], [True, True, True, True])
        m = json.loads((s / str(seed) / "metrics.json").read_text())
        m["dataset"]["name"] = "scape"
        last = m["rounds"][-1]
        last["at_logit_0"] = {"accuracy": at0_acc, "fnr": 0.25, "fpr": 0.1, "balanced_accuracy": 0.8,
                              "majority_accuracy": 0.625}
        last.update(accuracy=op_acc, fnr=0.05, threshold=-1.5)
        (s / str(seed) / "metrics.json").write_text(json.dumps(m))
    shutil.rmtree(s / "1" / "handling")  # an older run's files may be missing: no crash
    out = tmp_path / "report"
    report_main([str(s), "--out", str(out), "--bench", str(tmp_path / "none.json")])
    text = (out / "report.md").read_text()
    table = {r[0]: r[1] for r in _table(text, "### Table 3 layout")}
    assert table["accuracy"] == "85.00% ± 7.07"  # logit 0: mean of 0.90 and 0.80, not the operating points'
    assert table["false negative rate"] == "25.00% ± 0.00" and table["seeds"] == "2"
    assert table["accuracy at the operating point"] == "71.00% ± 1.41 (2)"
    assert table["false negative rate at the operating point"] == "5.00% ± 0.00 (2)"
    assert table["paper: accuracy"] == "93.83%" and table["paper: false negative rate"] == "5.15%"
    assert table["paper: equivalent supv_bd size"] == "663000"
    curve = {r[0]: r[1] for r in _table(text, "### accuracy vs data set size")}
    assert curve["8"].startswith("0.8500")  # the curve's last point at logit 0 too
    rows = list(__import__("csv").DictReader((out / "table3.csv").open()))
    assert float(rows[0]["operating_accuracy_mean"]) == pytest.approx(0.71)


def test_curves_mark_the_papers_table3_figure(tmp_path, monkeypatch):
    """accuracy.png / fnr.png: each method's curve with the paper's Table 3 figure at its final size, once for the
    two active methods (both are its Active+bd); the band is the sample std over seeds (the tables' ddof 1)."""
    from contextlib import contextmanager

    import experiments.reporting.plots as plots

    kept = []
    real_figure = plots.figure

    @contextmanager
    def keep(path, *a):
        with real_figure(path, *a) as axes:
            kept.append(axes[0][0])
            yield axes

    monkeypatch.setattr(plots, "figure", keep)
    agg = {"scape": {m: {2e5: {"accuracy": [0.91, 0.93], "fnr": [0.1, 0.1]}} for m in ("active", "active_paper",
                                                                                      "supv")}}
    for metric, paper in (("accuracy", {0.9383, 0.9181}), ("fnr", {0.05151, 0.06914})):
        assert plots.plot(agg, metric, tmp_path / f"{metric}.png")
        stars = [ln for ln in kept[-1].get_lines() if ln.get_marker() == "*"]
        assert {float(ln.get_ydata()[0]) for ln in stars} == paper and len(stars) == 2
        assert all(float(ln.get_xdata()[0]) == 5.5e5 for ln in stars)
    band = kept[0].collections[0].get_paths()[0].vertices[:, 1]
    assert band.min() == pytest.approx(0.92 - np.std([0.91, 0.93], ddof=1))


def test_equivalent_size_only_against_supv_bd_on_the_same_latent_space(tmp_path):
    """Table 3's equivalent supv_bd size reads supv_bd's curve on the method's own latent space (its own U(Z) test
    set): the paper-scale runs put neuralcol's default (PCA space) beside the paper's configuration (bilevel
    autoencoder), and pooling both supv_bd curves, or reading the other space's, compares accuracies of two different
    test sets."""
    s = tmp_path / "sweep"
    for name, m, acc, key in (("act", "active", 0.9, "A"), ("bdA", "supv_bd", 0.95, "A"),
                              ("bdB", "supv_bd", 0.7, "B"), ("sup", "supv", 0.8, "C")):
        _run(s, name, (8, 16), m, 0, acc, 100, 1.0, [1], [True, True, True, True])
        metrics = json.loads((s / name / "metrics.json").read_text())
        metrics["autoencoder"]["cache_key"] = key
        (s / name / "metrics.json").write_text(json.dumps(metrics))
    out = tmp_path / "report"
    report_main([str(s), "--out", str(out), "--bench", str(tmp_path / "none.json")])
    rows = {r["method"]: r for r in __import__("csv").DictReader((out / "table3.csv").open())}
    # active 0.9 on A's supv_bd curve 0.85 @ 4, 0.95 @ 8: 6 (pooled with B's, 0.725 / 0.825: never, "> 8")
    assert float(rows["active"]["equivalent_supv_bd_size"]) == pytest.approx(6.0)
    assert rows["supv"]["equivalent_supv_bd_size"] == "" and rows["supv"]["equivalent_note"] == "other latent space"
    text = (out / "report.md").read_text()
    table = {r[0]: r for r in _table(text, "### Table 3 layout")}
    assert "— (supv_bd ran on another latent space)" in table["equivalent supv_bd size"]
    assert "These runs use 3 latent spaces (Active+bd (ours), Supv+bd; Supv+bd; Supv)" in text


def test_methods_at_equal_size_interpolated_within_each_latent_space(tmp_path):
    """'active ≥ supv_bd ≥ supv at equal size' (a paper-scale target): each method read at every size any method of
    its latent space ran (exact, or ``~`` interpolated between its own sizes, never extrapolated), ranked there; a
    latent space with one method gets no table."""
    from experiments.reporting.equal_size import equal_size_markdown, order_text, value_at

    assert value_at([2, 4], [0.8, 0.9], 3) == (pytest.approx(0.85), False)
    assert value_at([2, 4], [0.8, 0.9], 4) == (0.9, True) and value_at([2, 4], [0.8, 0.9], 5) == (None, False)
    assert order_text({"supv": 0.9, "active_paper": 0.95, "supv_bd": 0.9}) in (
        "Active+bd (paper's text) > Supv = Supv+bd", "Active+bd (paper's text) > Supv+bd = Supv")

    def run(m, sizes, accs, key="A"):
        return {"detector": {"method": m}, "autoencoder": {"cache_key": key},
                "rounds": [{"dataset_size": s, "accuracy": a} for s, a in zip(sizes, accs)]}

    runs = [run("active_paper", [2, 3, 4], [0.90, 0.92, 0.93]), run("active_paper", [2, 3], [0.90, 0.94]),
            run("supv_bd", [2, 5], [0.90, 0.93]), run("active", [2, 4], [0.95, 0.96], key="B")]
    lines = equal_size_markdown(runs)
    assert sum(ln.startswith("### methods at equal size") for ln in lines) == 1  # B has one method
    rows = {ln.split(" | ")[0]: ln for ln in lines if ln.startswith("| ") and ln[2].isdigit()}
    assert rows["| 2"] == "| 2 | 0.9000 | 0.9000 | Supv+bd = Active+bd (paper's text) |"  # ties: report order
    assert rows["| 3"] == "| 3 | ~0.9100 | 0.9300 | Active+bd (paper's text) > Supv+bd |"  # seeds' mean 0.93
    assert rows["| 5"] == "| 5 | 0.9300 | — |  |"
