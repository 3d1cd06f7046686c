"""Choose the model sizes of a data set (docs/model_size.md); two commands:

``python -m experiments.model_size search [--out DIR] [--preset PATH] [OVERRIDES...]``: the search for the run of
``python -m experiments.run OVERRIDES`` (``conf/model_size/auto.yaml`` gives the candidates and the rule;
``model_size.*`` overrides change them). One autoencoder per latent candidate (trained or taken from the cache), then
one ``supv`` sub-run per detector width at the chosen latent space. Writes the evidence (``DIR/model_size.json`` and
one sub-run directory per width; default ``<paths.output_dir>/model_size/<data set>``, a finished search is read
back) and a preset of the chosen sizes (default ``conf/model_size/<data set>.yaml``); then
``python -m experiments.run OVERRIDES model_size=<data set>`` runs with them.

``python -m experiments.model_size SWEEP_DIR [--recon-tol 0.1] [--accuracy-tol 0.005] [--latent-rule
tolerance|knee]``: the same rule on a size sweep, a Hydra multirun over ``dataset.latent.n_components``,
``dataset.latent.level2_dim`` and ``detector.net.width`` (``experiment=size_<dataset>``): the smallest latent space
within ``recon-tol`` of the best held-out reconstruction (``--latent-rule knee``: the knee of the held-out error
against the latent size), then the smallest detector within ``accuracy-tol`` of the best accuracy at that latent
space. Writes ``SWEEP_DIR/model_size.json`` (read by ``experiments.report`` to mark the chosen point on the Pareto
chart) and prints every run's sizes and scores.
"""

from __future__ import annotations

import argparse
import copy
import itertools
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

from omegaconf import DictConfig, OmegaConf, open_dict

from neuralcol.errors import UserInputError
from neuralcol.resources import conf_dir
from neuralcol.stages.model_size import (
    LATENT_RULES,
    apply_size_rule,
    choose_from_records,
    choose_latent,
    latent_dim,
    size_record,
    validate_model_size,
)
from neuralcol.utils.cli import report_user_errors

CONF = conf_dir()
RESERVED = ("auto", "fixed")  # conf/model_size's own presets: never overwritten


def sweep_records(sweep: Path) -> list[dict]:
    """Records (:func:`~neuralcol.stages.model_size.size_record`) of the finished runs under ``sweep``."""
    runs = sorted(p.parent for p in sweep.glob("*/metrics.json"))
    if not runs:
        raise UserInputError(f"{sweep}: no finished run (no <run>/metrics.json); give the sweep directory of a "
                             "size sweep (python -m experiments.run -m experiment=size_<dataset>)")
    return [size_record(json.loads((r / "metrics.json").read_text()), r.name) for r in runs]


def _set(cfg: DictConfig, dotted: dict) -> DictConfig:
    out = copy.deepcopy(cfg)
    with open_dict(out):
        for key, value in dotted.items():
            OmegaConf.update(out, key, value, merge=False)
    return out


def search(cfg: DictConfig, out_dir: Path, run_fn: Callable[[DictConfig, Path], dict]) -> dict:
    """The size search for ``cfg``'s data set (``cfg.model_size``: candidate lists, tolerances, budget, method);
    returns ``model_size.json``'s content, written to ``out_dir`` (a finished search there is read back).

    Args:
        cfg: a composed run config with ``model_size=auto``.
        out_dir: where the evidence goes: ``model_size.json`` and one sub-run directory per width (``width_<w>``,
            a run directory of its own: ``neuralcol.load_run`` opens it).
        run_fn: runs one sub-run, ``(cfg, run_dir) -> metrics`` (``experiments.run.run``).
    """
    from neuralcol.pipeline import RunContext
    from neuralcol.stages.autoencoder import reference_spaces, train_or_load_latent_space

    ms = cfg.model_size
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "model_size.json"
    if path.is_file():  # a finished search keeps its choice
        return json.loads(path.read_text())
    t0 = time.perf_counter()
    ctx = RunContext(cfg)
    ds, feats = ctx.dataset, ctx.features
    latents = []
    for k, l2 in itertools.product(list(ms.n_components), list(ms.level2_dim)):
        lat_cfg = _set(cfg, {"dataset.latent.n_components": int(k), "dataset.latent.level2_dim": int(l2)})
        space, rep, cached = train_or_load_latent_space(ds, feats, lat_cfg.autoencoder, lat_cfg.dataset.latent,
                                                        int(cfg.autoencoder_seed), Path(cfg.paths.cache_dir))
        # the PCA references at the same |Z_all|: a candidate worse than them is flagged
        _, refs = reference_spaces(ds, feats, space, rep)
        ref_val = {f"{name}_val_error": e.get("val_mean_vertex_error") for name, e in refs.items()}
        latents.append({"n_components": int(k), "level2_dim": int(l2), "latent_dim": latent_dim(k, l2),
                        "val_error": rep.get("val_mean_vertex_error"),
                        "train_error": rep.get("train_mean_vertex_error"), **ref_val,
                        "autoencoder_parameters": rep.get("n_parameters"), "from_cache": cached,
                        "train_seconds": rep.get("train_seconds")})
        refs_txt = ", ".join(f"{n} {v:.4f}" for n, v in ref_val.items() if v is not None)
        print(f"model_size: |Z_0| = {k}, level 2 = {l2}: held-out vertex error {rep.get('val_mean_vertex_error')}"
              f"{' (cached)' if cached else ''}; PCA at the same size: {refs_txt or 'n/a'}", flush=True)
    lat = choose_latent(latents, float(ms.recon_tol), str(ms.latent_rule))
    budget = ms.budget if ms.budget is not None else \
        int(cfg.detector.n_init) + int(cfg.detector.max_rounds) * int(cfg.detector.n_aug)
    records = []
    for w in list(ms.width):
        sub = _set(cfg, {"dataset.latent.n_components": lat["n_components"],
                         "dataset.latent.level2_dim": lat["level2_dim"], "detector.net.width": float(w),
                         "detector.n_init": int(budget), "detector.max_rounds": 0,
                         "method": OmegaConf.to_container(cfg.model_size.method, resolve=True),
                         "handler.verify_margins": [], "handler.eval_every_round": False,
                         "model_size.mode": "fixed"})
        name = f"width_{float(w):g}"
        sub_dir = out_dir / name
        done = sub_dir / "metrics.json"
        # the sub-run's own config, as Hydra writes it for a run: neuralcol.load_run (and the bench, export,
        # handle CLIs) can open a width's sub-run like any run directory
        (sub_dir / ".hydra").mkdir(parents=True, exist_ok=True)
        OmegaConf.save(sub, sub_dir / ".hydra" / "config.yaml")
        metrics = json.loads(done.read_text()) if done.is_file() else run_fn(sub, sub_dir)
        records.append(size_record(metrics, name))
        print(f"model_size: detector width x{float(w):g}: {records[-1]['n_parameters']} parameters, "
              f"accuracy {records[-1]['accuracy']:.4f} at {budget} samples", flush=True)
    doc = {**apply_size_rule(latents, records, float(ms.recon_tol), float(ms.accuracy_tol), str(ms.latent_rule)),
           "budget": int(budget),
           "default": {"n_components": int(cfg.dataset.latent.n_components),
                       "level2_dim": int(cfg.dataset.latent.level2_dim),
                       "detector_width": float(cfg.detector.net.width)},
           "seconds": time.perf_counter() - t0}
    path.write_text(json.dumps(doc, indent=2))
    return doc


def write_preset(path: Path, doc: dict, dataset: str, evidence: Path) -> Path:
    """A ``model_size`` preset of the search's choice (``doc``, :func:`search`'s) at ``path``
    (``conf/model_size/<name>.yaml``: ``model_size=<name>``). It sets the chosen sizes
    (``dataset.latent.n_components``, ``dataset.latent.level2_dim``, ``detector.net.width``) and keeps the choice
    under ``model_size`` (``metrics.json`` repeats it; a run of another data set is refused)."""
    c = doc["chosen"]
    preset = {"dataset": {"latent": {"n_components": int(c["n_components"]), "level2_dim": int(c["level2_dim"])}},
              "detector": {"net": {"width": float(c["detector_width"])}},
              "model_size": {"mode": "fixed", "dataset": dataset, "evidence": str(evidence),
                             **{k: doc[k] for k in ("chosen", "chosen_accuracy", "best_accuracy", "budget", "default",
                                                    "rule")}}}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("# @package _global_\n"
                    f"# The model sizes `python -m experiments.model_size search` chose for {dataset} "
                    f"(docs/model_size.md; evidence: {evidence}).\n"
                    f"# Use: python -m experiments.run dataset={dataset} model_size={path.stem}\n"
                    + OmegaConf.to_yaml(OmegaConf.create(preset)))
    return path


def search_main(argv: list[str]) -> None:
    """``python -m experiments.model_size search ...`` (module docstring)."""
    from hydra import compose, initialize_config_dir

    from experiments.run import run
    from neuralcol.pipeline.validate import validate_run_config
    from neuralcol.utils.seeding import seed_everything
    from neuralcol.utils.threads import pin_threads

    ap = argparse.ArgumentParser(prog="python -m experiments.model_size search",
                                 description="the model-size search; writes the evidence and a preset")
    ap.add_argument("--out", type=Path, help="evidence directory (default <paths.output_dir>/model_size/<data set>)")
    ap.add_argument("--preset", type=Path, help="the preset written (default conf/model_size/<data set>.yaml)")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of the run, e.g. dataset=scape")
    args = ap.parse_args(argv)
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config", overrides=["model_size=auto", *args.overrides])
    validate_model_size(cfg)
    validate_run_config(_set(cfg, {"model_size.mode": "fixed"}))  # the sub-runs' settings, before any work
    dataset = str(cfg.dataset.name)
    preset = args.preset or CONF / "model_size" / f"{dataset}.yaml"
    if preset.parent == CONF / "model_size" and preset.stem in RESERVED:
        raise UserInputError(f"--preset {preset}: {preset.stem} is one of conf/model_size's own presets; choose "
                             "another name")
    pin_threads(cfg.get("threads", 1))  # as a run does before any work
    seed_everything(cfg.seed if cfg.seed is not None else None)
    out = args.out or Path(cfg.paths.output_dir) / "model_size" / dataset
    doc = search(cfg, out, run)
    write_preset(preset, doc, dataset, out / "model_size.json")
    c = doc["chosen"]
    where = "" if preset.parent == CONF / "model_size" else \
        f" (outside conf/model_size/: add 'hydra.searchpath=[file://{preset.parent.parent.resolve()}]')"
    run_overrides = [o for o in args.overrides if not o.startswith("model_size")]  # (the search's own settings)
    command = " ".join(["python -m experiments.run", *run_overrides, f"model_size={preset.stem}"])
    print(f"model_size: chosen |Z_0| = {c['n_components']}, level 2 = {c['level2_dim']}, detector width "
          f"x{c['detector_width']:g} (evidence: {out / 'model_size.json'}); preset {preset}{where}; run with: "
          f"{command}", flush=True)


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["search"]:
        return search_main(argv[1:])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", type=Path)
    ap.add_argument("--recon-tol", type=float, default=0.1, help="relative tolerance on held-out mesh error")
    ap.add_argument("--accuracy-tol", type=float, default=0.005, help="absolute tolerance on test accuracy")
    ap.add_argument("--latent-rule", choices=LATENT_RULES, default="tolerance",
                    help="tolerance: smallest latent space within --recon-tol of the best held-out error; knee: the "
                         "knee of the held-out error against log2 of the latent size")
    args = ap.parse_args(argv)
    records = sweep_records(args.sweep)
    doc = choose_from_records(records, args.recon_tol, args.accuracy_tol, args.latent_rule)
    (args.sweep / "model_size.json").write_text(json.dumps(doc, indent=2))
    print(f"{'run':>14} {'|Z_0|':>5} {'L2':>3} {'width':>5} {'held-out err':>12} {'params':>8} {'accuracy':>8} "
          f"{'majority':>8} {'skill':>6} {'FNR':>6}")
    for r in doc["detector"]:
        mark = "  <- chosen" if r["run"] == doc["chosen_run"] else ""
        err = "n/a" if r["val_error"] is None else f"{r['val_error']:.4f}"
        maj = "n/a" if r.get("majority_accuracy") is None else f"{r['majority_accuracy']:.4f}"
        skill = "n/a" if r.get("skill") is None else f"{r['skill']:.3f}"
        print(f"{r['run']:>14} {r['n_components']:>5} {r['level2_dim']:>3} {r['detector_width']:>5g} {err:>12} "
              f"{r['n_parameters']:>8} {r['accuracy']:>8.4f} {maj:>8} {skill:>6} {r['fnr']:>6.3f}{mark}")
    print("(accuracy compares only within one latent space: each has its own U(Z), test set and collision rate; "
          "skill = (accuracy - majority) / (1 - majority))")
    c = doc["chosen"]
    print(f"chosen: |Z_0| = {c['n_components']}, level 2 = {c['level2_dim']}, detector width x{c['detector_width']:g} "
          f"(accuracy {doc['chosen_accuracy']:.4f}; best at this latent space {doc['best_accuracy']:.4f} in "
          f"{doc['best_run']}) -> "
          f"{args.sweep / 'model_size.json'}")


if __name__ == "__main__":
    main()
