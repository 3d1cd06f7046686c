"""research/paper_scale/handling_curve.py's summary over runs (paper Fig. 5): means over seeds, error bars, --from-json.

The measuring part (``curve``) is tested on a trained tiny run in test_api.py; these cases need no run."""

from __future__ import annotations

import json

import numpy as np
import pytest

from research.paper_scale.handling_curve import by_method, main


def _result(run, method, points, n=1000):
    return {"run": run, "method": method, "n_inputs": n, "missing_rounds": [],
            "points": [{"round": k, "dataset_size": size, "n": n, "success_rate": s, "mean_pd_reduction": pd,
                        "resolved_rate": s} for k, (size, s, pd) in enumerate(points)]}


def test_by_method_means_over_seeds_and_falls_back_to_the_binomial_error():
    results = [_result("a_s0", "active", [(200_000, 0.90, 0.95), (250_000, 0.96, 0.97)]),
               _result("a_s1", "active", [(200_000, 0.94, 0.99)]),  # stopped a round earlier
               _result("s_s0", "supv", [(200_000, 0.80, 0.90)], n=100)]
    out = by_method(results, "success_rate")
    assert list(out) == ["supv", "active"]  # the report's order, not the input's
    sizes, mean, err, runs = out["active"]
    assert sizes.tolist() == [200_000, 250_000] and runs.tolist() == [2, 1]
    assert mean == pytest.approx([0.92, 0.96])
    assert err[0] == pytest.approx(np.std([0.90, 0.94], ddof=1))  # two seeds: their spread
    assert err[1] == pytest.approx(np.sqrt(0.96 * 0.04 / 1000))  # one seed: binomial standard error
    assert out["supv"][2][0] == pytest.approx(np.sqrt(0.8 * 0.2 / 100))
    assert by_method(results, "mean_pd_reduction")["active"][1] == pytest.approx([0.97, 0.97])


def test_from_json_tables_and_plots_earlier_results_without_measuring(tmp_path, capsys):
    saved = tmp_path / "hc.json"
    saved.write_text(json.dumps([_result("bd_s0", "supv_bd", [(200_000, 0.98, 0.97), (375_000, 0.97, 0.96)])]))
    png, out = tmp_path / "fig5.png", tmp_path / "all.json"
    assert main(["--from-json", str(saved), "--plot", str(png), "--out", str(out)]) == 0
    assert "| bd_s0 | supv_bd | 1 | 375 000 | 0.9700 |" in capsys.readouterr().out
    assert png.stat().st_size > 10_000 and json.loads(out.read_text()) == json.loads(saved.read_text())
    with pytest.raises(SystemExit, match="no such file"):
        main(["--from-json", str(tmp_path / "missing.json")])
    with pytest.raises(SystemExit, match="give run directories"):
        main([])
