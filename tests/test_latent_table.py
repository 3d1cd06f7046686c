"""experiments.latent_table: one row per run, skill against the majority class, mean ± std over seeds."""

from __future__ import annotations

import json

import pytest

from experiments.latent_table import grouped, main, row


def _metrics(acc: float, base: float, kind: str = "pca") -> dict:
    return {"autoencoder": {"kind": kind, "basis": "vertex", "train_mean_vertex_error": 0.01,
                            "val_mean_vertex_error": 0.02,
                            "references": {"vertex_pca": {"val_mean_vertex_error": 0.02},
                                           "acap_pca": {"val_mean_vertex_error": 0.03},
                                           "too_big": {"reason": "spans at most 3"}}},
            "latent": {"uniform_collision_fraction": base},
            "rounds": [{"accuracy": 0.5, "fnr": 0.9}, {"accuracy": acc, "fnr": 0.2}],
            "handling": None, "realistic": None}


def test_row_skill_is_against_the_majority_class_of_the_runs_own_box():
    r = row(_metrics(0.9, 0.2))
    assert r["majority"] == pytest.approx(0.8) and r["U(Z) skill"] == pytest.approx(0.5)
    assert r["best PCA held-out"] == 0.02 and r["latent"] == "pca (vertex)" and r["real acc"] is None
    assert row(_metrics(0.9, 0.6, kind="bilevel"))["U(Z) skill"] == pytest.approx(0.75)


def test_grouped_mean_and_sample_std_over_seeds():
    rows = [("a_s0", row(_metrics(0.9, 0.2))), ("a_s1", row(_metrics(0.8, 0.2))), ("b_s0", row(_metrics(0.9, 0.2)))]
    g = dict(grouped(rows))
    assert set(g) == {"a (n=2)", "b (n=1)"}
    assert g["a (n=2)"]["U(Z) acc"] == "0.850 ± 0.071" and g["b (n=1)"]["U(Z) acc"] == "0.900 ± 0.000"


def test_main_prints_a_table_and_names_a_missing_run(tmp_path, capsys):
    (tmp_path / "r_s0").mkdir()
    (tmp_path / "r_s0" / "metrics.json").write_text(json.dumps(_metrics(0.9, 0.2)))
    main([str(tmp_path / "r_s0")])
    assert "| r_s0 | pca (vertex) | 1.00% | 2.00% | 2.00% |" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        main([str(tmp_path / "missing")])
    assert e.value.code == 2 and "metrics.json" in capsys.readouterr().err


def test_report_has_a_latent_table_per_kind():
    from experiments.reporting.markdown import latent_markdown

    a, b = _metrics(0.9, 0.2), _metrics(0.8, 0.2, kind="bilevel")
    b["autoencoder"]["val_mean_vertex_error"] = 0.05
    a["latent"]["box_probe"] = {"space": {"collision_share": 0.4},
                                "references": {"vertex_pca": {"collision_share": 0.5}}}
    lines = latent_markdown([a, b, {"autoencoder": {}}])  # a run without references is left out
    assert "mean over 2 runs" in lines[0]
    assert "| the runs' (bilevel, 1) | 1.00% | 5.00% | — | — |" in lines
    assert "| the runs' (pca, 1) | 1.00% | 2.00% | 40.0% | — |" in lines
    assert "| vertex_pca | — | 2.00% | 50.0% | — |" in lines
    assert latent_markdown([{"autoencoder": {}}]) == []
