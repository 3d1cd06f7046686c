"""Diagnosis kit: why does the detector learn what it learns? ``python -m experiments.diagnose [overrides]``.

Parts (``diagnose.parts``; settings in ``conf/diagnose.yaml``):

* ``latent``: the latent space as a sampling domain: reconstruction error of every mesh that builds the box
  (trained on or held out), box volume per level against the training codes' box, how step-like the decoder
  is along the level-1 axes (tanh saturation, motion in the busiest 5 % of a line), how plausible U(Z)
  samples are (edge stretch and ACAP feature range of the data set), and the label's roughness (flip rate
  under small shifts of the normalised code).
* ``curve``: the learning curve of ``supv`` (train / validation / test accuracy) from a few thousand to tens of
  thousands of uniform samples, next to HistGradientBoosting and kNN on the same rows and a wider detector;
  extrapolates the rows needed to reach ``diagnose.curve.target``.
* ``projection``: the active-learning projection quality per round from finished run directories
  (``diagnose.runs``): share of projected samples within eps and 2 eps of the true boundary, colliding, on
  a box face, and the distance moved per latent level.

Writes ``diagnosis.json`` and ``latent.png`` / ``curve.png`` / ``projection.png`` into the Hydra run directory
(``outputs/diagnose/<dataset>/<time>``) and, with ``diagnose.out=DIR``, copies them there.
Examples::

    python -m experiments.diagnose dataset=scape
    python -m experiments.diagnose dataset=proc_hand diagnose.curve.sizes=[2000,4000,8000,16000]
    python -m experiments.diagnose dataset=scape diagnose.parts=[projection] \\
        'diagnose.runs=[outputs/multiruns/scape/x/2,outputs/multiruns/scape/x/5]'
"""

from __future__ import annotations

import json
import logging
import shutil
import time
import warnings
from pathlib import Path

import hydra
import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from neuralcol.errors import UserInputError
from neuralcol.resources import conf_dir
from neuralcol.utils.cli import report_user_errors
from neuralcol.utils.config import as_dict

PARTS = ("latent", "curve", "projection")


def diagnose_context(cfg: DictConfig):
    """The run context of ``cfg`` with its latent space: trained or from the cache, as ``experiments.run`` would,
    or the file ``diagnose.latent_space``."""
    from neuralcol.pipeline import RunContext

    ctx = RunContext(cfg)
    path = OmegaConf.select(cfg, "diagnose.latent_space", default=None)
    if path:
        try:
            ctx.use_latent_space_file(Path(str(path)))
        except UserInputError as e:
            raise UserInputError(f"diagnose.latent_space={e}") from e
    else:
        ctx.latent_space()
    return ctx


def diagnose_latent(cfg: DictConfig, ds, space, report: dict, oracle) -> dict:
    from neuralcol.diagnose.latent import (
        box_report,
        decoder_report,
        label_roughness,
        plausibility_report,
        reconstruction_report,
    )

    c = as_dict(cfg.diagnose.latent)
    gen = torch.Generator().manual_seed(int(cfg.seed))
    z = space.sample(int(c["n_samples"]), gen)
    t0 = time.perf_counter()
    out = {"reconstruction": reconstruction_report(space, ds.vertices, report["train_index"]),
           "box": box_report(space, ds.vertices, report["train_index"]),
           "decoder": decoder_report(space, z),
           "plausibility": plausibility_report(space, z, ds.vertices, ds.faces.numpy(), float(c["tolerance"]))}
    zr = z[: int(c["roughness_samples"])]
    out["roughness"] = label_roughness(lambda codes: oracle(codes).collides, zr, space.box_lo, space.box_hi,
                                       list(c["roughness_scales"]), seed=int(cfg.seed))
    out["seconds"] = time.perf_counter() - t0
    r, d, p, f = out["reconstruction"], out["decoder"], out["plausibility"], out["roughness"]
    b = out["box"]
    print(f"latent: reconstruction error {r['train_mean']:.2%} (trained meshes) / {r['heldout_mean']:.2%} (held out); "
          f"box from {b['box_from']}; log10 volume of the all-codes box over the training box: level 1 "
          f"{b['level1']['all_over_train']:.2f}, level 2 {b.get('level2', {}).get('all_over_train', 0):.2f}")
    print(f"  decoder: tanh saturation {d['saturation']:.1%}, motion in the busiest 5 % of a line "
          f"{d['busiest_share_mean']:.2f} (even: {d['even_share']:.2f}); U(Z) within the data set's edge stretch "
          f"{p['edge_within']:.1%}, feature range {p['feature_within']:.1%}")
    print("  label flip rate under shifts " + ", ".join(f"{s:g}: {v:.3f}" for s, v in zip(f["scales"], f["flip_rate"])))
    return out


def diagnose_curve(cfg: DictConfig, space, report: dict, oracle) -> dict:
    from neuralcol.diagnose.curve import learning_curve, needed_size
    from neuralcol.nn.detector import build_detector
    from neuralcol.samples.cache import samples_cache_dir, shared_test_set
    from neuralcol.samples.uniform import uniform_rows

    c = as_dict(cfg.diagnose.curve)
    det = as_dict(cfg.detector)
    sizes = sorted(int(s) for s in c["sizes"])
    key = report["cache_key"]
    test, _, _ = shared_test_set(oracle, det, key, cfg.paths.cache_dir)
    shared = samples_cache_dir(cfg.paths.cache_dir, key, oracle.pool.labeler)
    t0 = time.perf_counter()
    pool = uniform_rows(shared / f"uniform_s{int(c['pool_seed'])}.h5", oracle, sizes[-1], int(c["pool_seed"]),
                        desc="labeling uniform samples").rows
    label_s = time.perf_counter() - t0
    lo, hi = space.box_lo.numpy().astype(np.float64), space.box_hi.numpy().astype(np.float64)
    records = learning_curve(pool, test, sizes, list(c["variants"]),
                             lambda net: build_detector(space, {**det, "net": net}), float(oracle.pool.labeler.cap),
                             det, list(c["seeds"]), lo, hi, references=bool(c["references"]))
    base = float(np.mean(test.collides))
    majority = max(base, 1 - base)
    target = float(c["target"]) if c.get("target") is not None else majority + 0.5 * (1 - majority)
    needed = {}
    for model in dict.fromkeys(r["model"] for r in records):
        accs = [np.mean([r["test"]["accuracy"] for r in records if r["model"] == model and r["size"] == n])
                for n in sizes]
        needed[model] = needed_size(sizes, accs, target)
    print(f"rows needed for accuracy {target:.3f} (log-linear trend): "
          + ", ".join(f"{m} {v:,.0f}" for m, v in needed.items()))
    return {"sizes": sizes, "records": records, "test_size": len(test.z), "base_rate": base,
            "majority_accuracy": majority, "target": target, "needed_rows": needed,
            "pool_label_seconds": label_s}


def diagnose_projection(cfg: DictConfig) -> dict:
    runs = {}
    for d in cfg.diagnose.runs:
        path = Path(str(d)) / "metrics.json"
        if not path.is_file():
            path = Path(str(d)) / "detector_rounds.json"
        if not path.is_file():
            raise UserInputError(f"diagnose.runs: {d} has neither metrics.json nor detector_rounds.json; give the "
                                 "directory of an (active) run of experiments.run")
        m = json.loads(path.read_text())
        rounds = [r for r in m["rounds"] if r.get("projection")]
        if not rounds:
            raise UserInputError(f"diagnose.runs: {d} has no projected samples (not method=active, or recorded "
                                 "before projection statistics existed)")
        runs[str(d)] = [{"round": r["round"], "dataset_size": r["dataset_size"], **r["projection"]} for r in rounds]
    for d, rs in runs.items():
        w = ", ".join(f"{r['within_2eps']:.2f}" for r in rs)
        print(f"projection {d}: share within 2 eps per round {w}")
    return runs


def plot(results: dict, out: Path, title: str) -> list[Path]:
    """latent.png, curve.png, projection.png from the results (each only if its part ran)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []

    def save(fig, name: str) -> None:
        fig.suptitle(title)
        fig.tight_layout()
        paths.append(out / name)
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)

    if "latent" in results:
        lat = results["latent"]
        fig, ax = plt.subplots(1, 3, figsize=(15, 4))
        r = lat["reconstruction"]
        err, train = np.asarray(r["errors"]), np.asarray(r["train"])
        ax[0].bar(np.flatnonzero(train), 100 * err[train], color="tab:blue", label="trained on")
        ax[0].bar(np.flatnonzero(~train), 100 * err[~train], color="tab:red", label="held out")
        ax[0].set(xlabel="mesh", ylabel="mean vertex error, % of diagonal", title="embedding of the meshes")
        ax[0].legend()
        d = lat["decoder"]
        ax[1].bar(np.arange(len(d["busiest_share"])), d["busiest_share"], color="tab:purple")
        ax[1].axhline(d["even_share"], color="k", ls="--", label="even motion")
        ax[1].set(xlabel="level-1 component", ylabel="share of motion in busiest 5 %", ylim=(0, 1),
                  title=f"decoder along z0 (tanh saturation {d['saturation']:.0%})")
        ax[1].legend()
        f = lat["roughness"]
        ax[2].plot(f["scales"], f["flip_rate"], "o-")
        ax[2].set(xscale="log", xlabel="shift of every normalised coordinate", ylabel="label flip rate",
                  title="label roughness")
        ax[2].grid(alpha=0.3)
        save(fig, "latent.png")
    if "curve" in results:
        cur = results["curve"]
        fig, ax = plt.subplots(1, 2, figsize=(13, 4.5))
        models = list(dict.fromkeys(r["model"] for r in cur["records"]))
        for i, model in enumerate(models):
            rs = [r for r in cur["records"] if r["model"] == model]
            sizes = sorted({r["size"] for r in rs})
            test = [np.mean([r["test"]["accuracy"] for r in rs if r["size"] == n]) for n in sizes]
            fnr = [np.mean([r["test"]["fnr"] for r in rs if r["size"] == n]) for n in sizes]
            color = f"C{i}"
            ax[0].plot(sizes, test, "o-", color=color, label=f"{model} (test)")
            if "train_accuracy" in rs[0]:
                ax[0].plot(sizes, [np.mean([r["train_accuracy"] for r in rs if r["size"] == n]) for n in sizes],
                           ":", color=color, label=f"{model} (train)")
                ax[0].plot(sizes, [np.mean([r["val_accuracy"] for r in rs if r["size"] == n]) for n in sizes],
                           "--", color=color, alpha=0.6, label=f"{model} (validation)")
            ax[1].plot(sizes, fnr, "o-", color=color, label=model)
        ax[0].axhline(cur["majority_accuracy"], color="grey", ls="-.", label="majority class")
        ax[0].axhline(cur["target"], color="k", ls=":", lw=0.8, label="target")
        ax[0].set(xscale="log", xlabel="uniform samples (rows)", ylabel="accuracy", title="learning curve (supv)")
        ax[0].legend(fontsize=7, ncol=2)
        ax[1].set(xscale="log", xlabel="uniform samples (rows)", ylabel="false negative rate", title="FNR")
        ax[1].legend(fontsize=7)
        for a in ax:
            a.grid(alpha=0.3)
        save(fig, "curve.png")
    if results.get("projection"):
        fig, ax = plt.subplots(1, 3, figsize=(15, 4))
        for i, (run, rs) in enumerate(results["projection"].items()):
            x = [r["dataset_size"] for r in rs]
            name = "/".join(Path(run).parts[-2:]) if Path(run).name.isdigit() else Path(run).name
            ax[0].plot(x, [r["within_2eps"] for r in rs], "o-", color=f"C{i}", label=f"{name}: 2 eps")
            ax[0].plot(x, [r["within_eps"] for r in rs], "s--", color=f"C{i}", alpha=0.6, label=f"{name}: eps")
            if rs[0].get("start"):
                ax[0].plot(x, [r["start"]["within_2eps"] for r in rs], ":", color=f"C{i}", alpha=0.5,
                           label=f"{name}: 2 eps before projecting")
            ax[1].plot(x, [r["moved_level1"] for r in rs], "o-", color=f"C{i}", label=f"{name}: level 1")
            ax[1].plot(x, [r["moved_level2"] for r in rs], "s--", color=f"C{i}", label=f"{name}: level 2")
            ax[2].plot(x, [r["on_face_level1"] for r in rs], "o-", color=f"C{i}", label=f"{name}: level 1")
            ax[2].plot(x, [r["on_face_level2"] for r in rs], "s--", color=f"C{i}", label=f"{name}: level 2")
        ax[0].axhline(0.5, color="k", ls=":", lw=0.8)
        ax[0].set(xlabel="|D_c| of the projecting detector", ylabel="share of projected samples",
                  title="near the true boundary |PD| <= eps, 2 eps", ylim=(0, 1))
        ax[1].set(xlabel="|D_c|", ylabel="mean |dz| / half-range", title="distance moved per level")
        ax[2].set(xlabel="|D_c|", ylabel="share of coordinates", title="on a box face")
        for a in ax:
            a.grid(alpha=0.3)
            a.legend(fontsize=7)
        save(fig, "projection.png")
    return paths


def run(cfg: DictConfig, out_dir: Path) -> dict:
    parts = list(cfg.diagnose.parts)
    bad = [p for p in parts if p not in PARTS]
    if bad or not parts:
        raise UserInputError(f"diagnose.parts={parts}: use a non-empty list of {', '.join(PARTS)}")
    results: dict = {"dataset": cfg.dataset.name, "parts": parts}
    if "latent" in parts or "curve" in parts:
        ctx = diagnose_context(cfg)
        ds, (space, report, _) = ctx.dataset, ctx.latent_space()
        results["latent_space"] = {"cache_key": report["cache_key"], "dim": space.dim, "n_parts": space.n_parts}
        if "latent" in parts and getattr(space, "net", None) is None:
            raise UserInputError("diagnose.parts=[latent] studies the bilevel autoencoder's decoder (tanh saturation, "
                                 "feature ranges); autoencoder=pca has no decoder network: drop 'latent' from "
                                 "diagnose.parts (curve and projection work on any latent space)")
        with ctx.pool(ctx.sample_labeler()) as pool:
            oracle = ctx.oracle(pool)
            if "latent" in parts:
                results["latent"] = diagnose_latent(cfg, ds, space, report, oracle)
            if "curve" in parts:
                results["curve"] = diagnose_curve(cfg, space, report, oracle)
    if "projection" in parts:
        results["projection"] = diagnose_projection(cfg)
    (out_dir / "diagnosis.json").write_text(json.dumps(results, indent=1, default=float))
    files = [out_dir / "diagnosis.json", *plot(results, out_dir, f"{cfg.dataset.name}: diagnosis")]
    if cfg.diagnose.out:
        dest = Path(str(cfg.diagnose.out))
        dest.mkdir(parents=True, exist_ok=True)
        for f in files:
            shutil.copy2(f, dest / f.name)
        print(f"copied {', '.join(f.name for f in files)} to {dest}")
    print(f"results: {out_dir}")
    return results


@hydra.main(version_base="1.3", config_path=str(conf_dir()), config_name="diagnose")
@report_user_errors
def main(cfg: DictConfig) -> None:
    logging.getLogger("lightning.pytorch.utilities.rank_zero").setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\).*")
    run(cfg, Path(HydraConfig.get().runtime.output_dir))


if __name__ == "__main__":
    main()
