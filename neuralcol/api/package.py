"""A finished run packed into one small folder that loads anywhere (e.g. the shipped SCAPE model).

A run directory reads its latent space from the cache (``paths.cache_dir``) and holds D_c, checkpoints and
pictures beside what :func:`~neuralcol.load_run` needs. :func:`pack_run` copies only what detection, exact
labels, the certified cascade and ``resolve`` need (the config, metrics, detector, latent space, the cascade's
calibration, the round records) into a folder with a ``package.json`` manifest: the source run, its command, the
figures it was measured at, and each file's size and SHA-256, which :func:`check_package` verifies on load (a
truncated copy or a Git LFS pointer gets one line naming the file). :func:`pretrained` loads the packages shipped
in the repository's ``pretrained/`` folder (:func:`~neuralcol.api.run.pretrained`)::

    run = neuralcol.pretrained("scape")     # = load_run("<repo>/pretrained/scape")
    python -m experiments.pack RUN_DIR pretrained/scape --note "..."
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import time
from pathlib import Path

from omegaconf import OmegaConf

from neuralcol.api.files import check_run_dir
from neuralcol.errors import UserInputError
from neuralcol.rundir import CacheDir, RunDir
from neuralcol.utils.files import write_json_atomic

FORMAT = 1
#: what a package holds (besides ``package.json``); the optional ones are copied when the run has them
REQUIRED = (".hydra/config.yaml", "metrics.json", "detector.pt", "latent_space.pt")
OPTIONAL = (".hydra/overrides.yaml", "cascade.npz", "detector_rounds.json", "sittings.json")
#: the config entries a package resets to the defaults of conf/paths (the source machine's folders mean nothing
#: where the package is loaded)
PATH_DEFAULTS = {"data_dir": "${oc.env:NEURALCOL_DATA,data}", "cache_dir": "${oc.env:NEURALCOL_CACHE,.cache}",
                 "output_dir": "${oc.env:NEURALCOL_OUTPUT,outputs}"}


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _git_commit() -> str | None:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10,
                             cwd=Path(__file__).resolve().parent)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None if out.returncode == 0 else None


def documented_figures(metrics: dict) -> dict:
    """The figures a package promises (from the run's ``metrics.json``): the final detector on the U(Z) test set
    as saved (``u_z``: at its operating threshold, which ``detector.pt`` has folded in, so these are what
    :meth:`~neuralcol.api.TrainedRun.detect` gives; with the test set's size and seed) and at the raw network's
    logit 0 (``u_z_at_logit_0``), on the realistic set, and the handler's success and PD reduction, where measured."""
    det, last = metrics["detector"], metrics["rounds"][-1]
    test = det.get("test_set") or {}
    keys = ("accuracy", "fnr", "fpr", "base_rate", "majority_accuracy")
    figures = {"dataset_size": last.get("dataset_size"), "threshold": last.get("threshold", 0.0),
               "u_z": {**{k: last.get(k) for k in keys}, "n": test.get("n"), "seed": test.get("seed")},
               "u_z_at_logit_0": {k: (last.get("at_logit_0") or last).get(k) for k in keys}}
    real = (metrics.get("realistic") or {}).get("detection")
    if isinstance(real, dict):
        figures["realistic"] = {k: real.get(k) for k in ("accuracy", "fnr", "n", "skill")}
    hand = metrics.get("handling")
    if isinstance(hand, dict):
        figures["handler"] = {k: hand.get(k) for k in ("n", "success_rate", "mean_pd_reduction")}
    return figures


def pack_run(run_dir: str | Path, out_dir: str | Path, note: str = "", overwrite: bool = False) -> Path:
    """Copy a finished run into ``out_dir`` as a package (see the module's docstring); returns ``package.json``.

    Raises:
        UserInputError: not a finished run, its latent space is not in the cache, or ``out_dir`` exists and is
            not a package (a package is replaced only with ``overwrite``).
    """
    run_dir, out_dir = Path(run_dir), Path(out_dir)
    cfg, metrics = check_run_dir(run_dir)
    rd, od = RunDir(run_dir), RunDir(out_dir)
    key = metrics["autoencoder"].get("cache_key")
    space = rd.latent_space if rd.latent_space.is_file() else CacheDir(str(cfg.paths.cache_dir)).latent_space(key)
    if not space.is_file():
        raise UserInputError(f"{space}: the run's latent space is not in the cache (paths.cache_dir="
                             f"{cfg.paths.cache_dir}); run the run's command again to rebuild it, then pack")
    if out_dir.exists():
        if not od.package.is_file() or not overwrite:
            raise UserInputError(f"{out_dir}: exists; " + ("give --overwrite to replace the package there"
                                 if od.package.is_file() else "choose a new folder (it is not a package)"))
        shutil.rmtree(out_dir)
    (out_dir / ".hydra").mkdir(parents=True)
    sources = {name: run_dir / name for name in REQUIRED + OPTIONAL}
    sources["latent_space.pt"] = space
    files = {}
    for name, src in sources.items():
        if name == ".hydra/config.yaml":
            packed = OmegaConf.load(src)
            for k, v in PATH_DEFAULTS.items():
                OmegaConf.update(packed, f"paths.{k}", v, force_add=True)
            OmegaConf.save(packed, out_dir / name)
        elif src.is_file():
            shutil.copyfile(src, out_dir / name)
        else:
            continue
        files[name] = {"bytes": (out_dir / name).stat().st_size, "sha256": sha256(out_dir / name)}
    overrides = OmegaConf.load(rd.overrides) if rd.overrides.is_file() else []
    manifest = {
        "format": FORMAT,
        "packed": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "source": {"run_dir": str(run_dir.resolve()), "latent_space": str(space), "cache_key": key,
                   "command": "python -m experiments.run " + " ".join(map(str, overrides)),
                   "neuralcol_commit": _git_commit()},
        "dataset": str(cfg.dataset.name),
        "note": note,
        "figures": documented_figures(metrics),
        "files": files,
    }
    write_json_atomic(od.package, manifest)
    return od.package


def check_package(run_dir: str | Path) -> dict:
    """``package.json`` of a packed run, after checking every file it lists (size and SHA-256).

    Raises:
        UserInputError: a listed file is missing, of another size (e.g. a Git LFS pointer where ``git lfs pull``
            was not run) or of another checksum.
    """
    rd = RunDir(run_dir)
    try:
        manifest = json.loads(rd.package.read_text())
        files = dict(manifest["files"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise UserInputError(f"{rd.package}: not a readable package manifest ({exc}); restore the package from "
                             "the repository (git checkout -- <folder>)") from exc
    for name, facts in files.items():
        path = rd.path / name
        if not path.is_file():
            raise UserInputError(f"{path}: missing from the package; restore it (git checkout -- {rd.path})")
        size = path.stat().st_size
        with open(path, "rb") as f:
            if f.read(64).startswith(b"version https://git-lfs") and facts["bytes"] != size:
                raise UserInputError(f"{path}: a Git LFS pointer, not the file; run `git lfs pull` in the "
                                     "repository (or restore the package from a full copy)")
        if size != facts["bytes"] or sha256(path) != facts["sha256"]:
            raise UserInputError(f"{path}: {size} bytes and a checksum other than package.json lists "
                                 f"({facts['bytes']} bytes); the file was changed or not fully fetched "
                                 f"(a Git LFS pointer?): restore it (git checkout -- {rd.path})")
    return manifest


#: the seed of :func:`fresh_check`'s codes (no run's test set, pool or calibration set uses it)
FRESH_SEED = 20261127


def fresh_labels(run, n: int, seed: int):
    """``n`` fresh codes from U(Z) of ``seed``, labeled exactly through the run's label pool as its training targets
    were (clearances capped at ``detector.targets.pd_floor`` where set: the same verdicts); failed rows dropped."""
    from neuralcol.samples.uniform import uniform_codes

    floor = OmegaConf.select(run.cfg, "detector.targets.pd_floor")
    oracle = run.context().oracle(run.label_pool())
    oracle = oracle if floor is None else oracle.for_training(float(floor))
    return oracle(uniform_codes(run.space, int(seed), 0, int(n)), desc="labeling fresh U(Z) codes").without_failures()


def fresh_check(run, n: int = 2000, seed: int = FRESH_SEED) -> dict:
    """The run's detector (its verdict as :meth:`~neuralcol.api.TrainedRun.detect` gives it: the operating
    threshold, ``detector.operating_fnr``, is folded into the saved network) on ``n``
    fresh codes from U(Z) labeled exactly, beside the figure the run documents (``package.json``'s, else its
    metrics'): accuracy, FNR, the base rate, and the difference in accuracy with its binomial standard error.

    The verdicts are the exact labeler's (with clearances capped at the training targets' floor where the run
    has one: the same verdicts, docs/labels.md)."""
    import numpy as np
    import torch

    lab = fresh_labels(run, n, seed)
    pred = run.detect(torch.as_tensor(lab.z)).collides.cpu().numpy()
    y = np.asarray(lab.collides, bool)
    acc = float(np.mean(pred == y))
    fnr = float(np.mean(~pred[y])) if y.any() else float("nan")
    rd = RunDir(run.run_dir)
    figures = json.loads(rd.package.read_text())["figures"] if rd.package.is_file() else \
        documented_figures(run.metrics)
    documented = figures["u_z"]["accuracy"]
    return {"n": int(len(y)), "seed": int(seed), "n_failed": int(n - len(y)), "accuracy": acc, "fnr": fnr,
            "base_rate": float(y.mean()), "documented_accuracy": documented,
            "documented_fnr": figures["u_z"]["fnr"], "difference": acc - float(documented),
            "standard_error": float(np.sqrt(acc * (1 - acc) / max(len(y), 1)))}
