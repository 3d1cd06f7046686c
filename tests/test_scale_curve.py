"""experiments.scale_curve: labels in resumable pieces, one record per (size, method) kept across
reruns, the chart and table."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _cfg(tmp_path, scape_dir, *extra):
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose("scale_curve", overrides=[
            "dataset=scape", f"paths.data_dir={scape_dir.parent}", f"paths.cache_dir={tmp_path}/cache",
            "autoencoder=tiny", "detector=tiny", "labeling.pool.workers=0", "labeling.pool.progress=false",
            "scale.sizes=[40,80]", "scale.test_size=60", "scale.label_piece=50", f"scale.out={tmp_path}/out",
            *extra])


def test_scale_curve_labels_in_pieces_trains_and_resumes(tmp_path, scape_dir, capsys):
    from experiments.scale_curve import run
    from neuralcol.errors import UserInputError

    # training before the labels are complete is refused with what to do
    with pytest.raises(UserInputError, match="run the label part first"):
        run(_cfg(tmp_path, scape_dir, "scale.parts=[train]"))
    # a time limit of 0 labels one piece and stops; a rerun goes on where it stopped
    state = run(_cfg(tmp_path, scape_dir, "scale.parts=[label]", "scale.max_label_minutes=0"))
    assert [(p["store"], p["rows"]) for p in state["pieces"]] == [("pool", 50)]
    state = run(_cfg(tmp_path, scape_dir, "scale.parts=[label]"))
    assert {(p["store"], p["rows"]) for p in state["pieces"]} >= {("pool", 80), ("test", 60)}
    assert all(p["labels_per_s"] > 0 for p in state["pieces"])
    # train + plot: one record per (size, method), the chart, the table and the copy to scale.docs
    state = run(_cfg(tmp_path, scape_dir, "scale.parts=[train,plot]", f"scale.docs={tmp_path}/docs"))
    recs = {(r["size"], r["model"]) for r in state["records"]}
    assert recs == {(40, "supv"), (40, "supv_bd"), (80, "supv"), (80, "supv_bd")}
    assert all(0 <= r["test"]["accuracy"] <= 1 and r["seconds"] > 0 for r in state["records"])
    assert state["test_size"] == 60 and 0.5 <= state["majority_accuracy"] <= 1
    for name in ("scale_curve.json", "scale_curve.png", "scale_curve.md"):
        assert (tmp_path / "docs" / name).stat().st_size > 100, name
    assert "| 80 |" in (tmp_path / "out" / "scale_curve.md").read_text()
    # a rerun with one more size trains only that size (the others are kept, not retrained)
    before = json.loads((tmp_path / "out" / "scale_curve.json").read_text())["records"]
    capsys.readouterr()
    state = run(_cfg(tmp_path, scape_dir, "scale.parts=[train]", "scale.sizes=[40,60,80]"))
    assert len(state["records"]) == len(before) + 2
    assert state["records"][: len(before)] == before
    assert capsys.readouterr().out.count("train: n=") == 2


def test_scale_curve_rejects_bad_parts(tmp_path, scape_dir):
    from experiments.scale_curve import run
    from neuralcol.errors import UserInputError

    with pytest.raises(UserInputError, match="scale.parts"):
        run(_cfg(tmp_path, scape_dir, "scale.parts=[labels]"))
