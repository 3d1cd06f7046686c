"""Set a finished run's operating point again, on a realistic calibration set drawn with the settings in force.

A run's decision threshold (``detector.operating_fnr``) is set once, when it trains, on the calibration rows of its
version of neuralcol; a package keeps it (``pretrained/scape`` was set on 237 realistic validation meshes). This
module draws the realistic calibration set and the realistic test set as a run of the run's config draws them now
(the ``realistic`` settings of today's ``conf/``, or those given), measures the run's detector on both, and, when
asked, moves the threshold to where the rule puts it (FNR <= target on the calibration set's clear colliding
meshes) and writes what depends on it:

* ``detector.pt``: the output bias shifted (:func:`neuralcol.operating.fold_into_file`), so
  ``detect``, ``resolve``, the handler and the cascade decide at the new threshold;
* ``cascade.npz``: the calibration logits shifted by as much (the cascade's bands are chosen on them at load);
* ``metrics.json``: ``detector.operating_point`` (the new one, with ``previous`` and ``recalibrated``), the last
  round's U(Z) figures at the new threshold (from ``test_predictions.npz``, else on fresh U(Z) codes labeled exactly),
  ``realistic.detection`` on the new test set; the handler's figures, measured at the old threshold, move under
  ``handling_at_previous_threshold`` and ``handling`` is measured again on fresh colliding U(Z) codes (for a run
  with its own test set, only as many fresh codes are labeled as that needs: :func:`fresh_codes_needed`);
* for a package: ``package.json``'s figures and checksums.

The command: ``python -m experiments.recalibrate RUN_DIR [--write]`` (docs/detector.md).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from neuralcol.errors import UserInputError
from neuralcol.rundir import RunDir
from neuralcol.utils.files import write_json_atomic

#: seed of the fresh U(Z) codes that score a package's operating point (a package has no test set of its own)
UZ_SEED = 20261129


class RuleSets(NamedTuple):
    """The realistic sets a threshold rule reads: clear meshes (M, V, 3) float64 and their exact verdicts (M,) bool."""

    calibration: tuple[np.ndarray, np.ndarray]
    test: tuple[np.ndarray, np.ndarray]
    realistic: dict


def current_realistic(run_dir: Path, overrides: list[str]) -> dict:
    """The ``realistic`` settings a run of ``run_dir``'s command would get from today's ``conf/`` (its recorded
    overrides composed again, their ``realistic.*`` entries left out), with ``overrides`` (``realistic.KEY=VALUE``)
    on top."""
    from hydra import compose, initialize_config_dir

    from neuralcol.resources import conf_dir

    conf = conf_dir()
    rd = RunDir(run_dir)
    recorded = [str(o) for o in OmegaConf.load(rd.overrides)] if rd.overrides.is_file() else []
    keep = [o for o in recorded if not o.lstrip("+~").startswith(("realistic", "paths.", "hydra."))]
    bad = [o for o in overrides if not o.startswith("realistic.")]
    if bad:
        raise UserInputError(f"{' '.join(bad)}: only realistic.KEY=VALUE settings can be given here")
    with initialize_config_dir(config_dir=str(conf), version_base=None):
        cfg = compose(config_name="config", overrides=keep + list(overrides))
    return OmegaConf.to_container(cfg.realistic, resolve=True)


def rule_sets(run_dir: str | Path, cfg: DictConfig, realistic: dict) -> RuleSets:
    """Draw (or read from the cache) the realistic calibration and test sets of ``cfg`` (the run's config, its paths
    pointing at a cache and the data sets) with ``realistic`` settings, as the pipeline draws them."""
    from neuralcol.data.realistic import clear_mask
    from neuralcol.pipeline import RunContext
    from neuralcol.samples.realistic import calibration_meshes, evaluation_limit, realistic_set

    cfg = OmegaConf.merge(cfg, {"realistic": realistic})
    ctx = RunContext(cfg)
    stage = ctx.latent_space()
    labeler = ctx.sample_labeler()
    ds, feats = ctx.dataset, ctx.features
    eps = float(labeler.eps)
    args = (ds.vertices.numpy(), feats.features.numpy(), feats.acap, stage.report["val_index"])
    with ctx.pool(labeler) as pool:
        folder = ctx.samples_dir(labeler, ctx.fit_box(pool, labeler))  # where the pipeline caches these sets
        cal = calibration_meshes(*args, pool, cfg.realistic, folder, eps)
        meshes, pd, _ = realistic_set(*args, pool, cfg.realistic, folder, eps,
                                      clearance_limit=evaluation_limit(cfg.realistic, eps))
    keep = np.isfinite(pd) & clear_mask(pd, eps, float(cfg.realistic.clear_eps))
    return RuleSets(cal, (meshes.vertices[keep], pd[keep] > 0), realistic)


def measure(run, sets: RuleSets, target: float) -> dict:
    """The run's detector on both sets: its own threshold and the rule's (FNR <= ``target`` on the calibration
    set), each scored on both; ``shift`` is the rule's threshold in the run's current logits."""
    from neuralcol.operating import fnr_threshold, score

    logits = {name: run.detect(v).logit.double().numpy() for name, (v, _) in
              (("calibration", sets.calibration), ("test", sets.test))}
    ys = {"calibration": np.asarray(sets.calibration[1], bool), "test": np.asarray(sets.test[1], bool)}
    shift = fnr_threshold(logits["calibration"], ys["calibration"], float(target))
    op = run.metrics["detector"].get("operating_point") or {}
    base = float(op.get("threshold", 0.0))
    return {"target": float(target), "shift": shift,
            "current": {"threshold": base, **{k: score(logits[k], ys[k], 0.0) for k in logits}},
            "rule": {"threshold": base + shift, **{k: score(logits[k], ys[k], shift) for k in logits}}}


def _uz_at(run, shift: float, fresh) -> dict:
    """U(Z) figures at logit ``shift`` of the current net: the run's test set where it is saved, else the ``fresh``
    labeled codes."""
    from neuralcol.metrics.detection import detection_metrics

    rd = RunDir(run.run_dir)
    if rd.test_predictions.is_file():
        with np.load(rd.test_predictions) as z:
            logit, y = z["logit"].astype(np.float64), z["collides"].astype(bool)
        source = {"n": int(len(y)), "seed": (run.metrics["detector"].get("test_set") or {}).get("seed")}
    else:
        logit = run.detect(torch.as_tensor(fresh.z)).logit.double().numpy()
        y = np.asarray(fresh.collides, bool)
        source = {"n": int(len(y)), "seed": UZ_SEED, "fresh": True}
    m = detection_metrics(logit > shift, y)
    return {**{k: m[k] for k in ("accuracy", "fnr", "fpr", "balanced_accuracy", "base_rate", "majority_accuracy")
               if k in m}, **source}


def _handler_at_new_threshold(run, fresh, n: int) -> dict:
    """The handler (the run's settings) on the first ``n`` colliding ``fresh`` codes with the detector as now saved
    in ``detector.pt``, labeled exactly after (``metrics.json``'s ``handling``, on fresh codes)."""
    from neuralcol.handler.resolve import alm_settings
    from neuralcol.nn.detector import load_detector
    from neuralcol.nn.part_geometry import DetectorOnCodes
    from neuralcol.stages.handler import evaluate_handler

    pick = np.flatnonzero(np.asarray(fresh.collides, bool) & (np.asarray(fresh.pd) > 0))[:int(n)]
    net, _ = load_detector(RunDir(run.run_dir).detector)
    cfg = run.cfg.handler
    m, _ = evaluate_handler(DetectorOnCodes(net.eval(), run.space), run.context().oracle(run.label_pool()),
                            torch.as_tensor(np.asarray(fresh.z)[pick]), np.asarray(fresh.pd)[pick],
                            alm_settings(cfg.alm), int(cfg.batch_size), list(cfg.verify_margins))
    return {**m, "inputs": {"n": int(len(pick)), "fresh_seed": UZ_SEED}}


def fresh_codes_needed(rd: RunDir, n_fresh: int, n_handler: int) -> int:
    """How many fresh U(Z) codes :func:`write_recalibration` labels: ``n_fresh`` where they score the new threshold
    (a package: no test set of its own); for a run with its own test set they only feed the handler, so as many as
    give ``n_handler`` colliding codes at the test set's rate of collisions, with half as many again to spare
    (the first codes of the same sequence: the handler's inputs are the same ones ``n_fresh`` would give)."""
    if not rd.test_predictions.is_file():
        return int(n_fresh)
    if n_handler <= 0:
        return 0
    with np.load(rd.test_predictions) as z:
        rate = float(np.mean(z["collides"].astype(bool))) if len(z["collides"]) else 0.5
    return min(int(n_fresh), int(np.ceil(1.5 * n_handler / max(rate, 0.05))))


def write_recalibration(run, result: dict, sets: RuleSets, n_fresh: int = 10000, n_handler: int = 500) -> dict:
    """Move ``run``'s threshold to ``result["rule"]`` (from :func:`measure`) and rewrite the files that depend on it
    (see the module's docstring). Returns the new ``detector.operating_point``."""
    from neuralcol.api.package import documented_figures, fresh_labels, sha256
    from neuralcol.operating import fold_into_file
    from neuralcol.stages.cascade import load_calibration, save_calibration

    rd = RunDir(run.run_dir)
    shift = float(result["shift"])
    n_codes = fresh_codes_needed(rd, n_fresh, n_handler)
    fresh = fresh_labels(run, n_codes, UZ_SEED) if n_codes else None
    uz = _uz_at(run, shift, fresh)
    fold_into_file(rd.detector, shift)
    if rd.cascade.is_file():
        logits, collides = load_calibration(rd.cascade)
        with np.load(rd.cascade) as z:
            seed = int(z["seed"])
        save_calibration(rd.cascade, logits - shift, collides, seed)
    metrics = json.loads(rd.metrics.read_text())
    previous = metrics["detector"].get("operating_point")
    cal, test = result["rule"]["calibration"], result["rule"]["test"]
    op = {"operating_fnr": result["target"], "operating_set": "realistic_calibration",
          "threshold": result["rule"]["threshold"],
          "calibration": {k: cal[k] for k in ("n", "n_colliding", "accuracy", "fnr", "fpr", "fnr_ci95")},
          "recalibrated": {"date": time.strftime("%Y-%m-%d"), "realistic": sets.realistic},
          "previous": previous}
    metrics["detector"]["operating_point"] = op
    last = metrics["rounds"][-1]
    keep = {k: last[k] for k in ("at_logit_0",) if k in last}
    last.update({k: uz[k] for k in ("accuracy", "fnr", "fpr", "balanced_accuracy", "base_rate", "majority_accuracy")
                 if k in uz}, threshold=op["threshold"], scored_on=uz, **keep)
    metrics.setdefault("realistic", {})["detection"] = test
    if "handling" in metrics:
        metrics["handling_at_previous_threshold"] = metrics.pop("handling")
    if n_handler > 0:  # the handler's constraint is the detector's decision: measured again at the new threshold
        metrics["handling"] = _handler_at_new_threshold(run, fresh, n_handler)
    write_json_atomic(rd.metrics, metrics)
    if rd.package.is_file():
        manifest = json.loads(rd.package.read_text())
        figures = documented_figures(metrics)
        figures["u_z"].update(n=uz["n"], seed=uz["seed"])
        manifest["figures"] = figures
        manifest["recalibrated"] = op["recalibrated"]["date"]
        for name, entry in manifest["files"].items():
            path = Path(run.run_dir) / name
            entry.update(bytes=path.stat().st_size, sha256=sha256(path))
        write_json_atomic(rd.package, manifest)
    return op
