"""The experiments that decided the diagnosis's fixes, rerunnable: ``python -m research.diagnosis_ablations CMD ...``.

Every table of docs/studies/diagnosis_scape.md that is not produced by ``experiments.diagnose`` or a pipeline run
comes from one of these commands (each prints its table and writes JSON with ``--out``). They use the shared caches of
``experiments.run`` (latent spaces, labeled test sets, labeled uniform pools): run the pipeline or
``experiments.diagnose`` for the data set first, or let them label what is missing.

* ``loss``: detector loss/target variants trained on the same rows, several seeds (PD target band, eps of D_b,
  cross-entropy on D_b, w_b = 0, decoder features on/off).
* ``regression``: HistGradientBoosting classifying the verdict against regressing the clipped PD and
  thresholding it (how much the PD value says about the sign).
* ``latent``: autoencoder variants (box from all / training codes, latent noise, linear level-1
  components): decoder statistics, U(Z) collision rate, and HGB / kNN accuracy on labeled U(Z) samples.
* ``selection``: simulated pool-based uncertainty sampling against uniform sampling at equal label budgets
  (labels drawn from a labeled uniform pool; detector retrained from scratch each round).
* ``margin``: detector-only handler success against the logit margin, for finished runs.

Common options: ``--dataset`` (a data set config), ``--set`` (extra Hydra overrides), ``--out`` (JSON file).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]


def study_config(dataset: str, extra: list[str], config: str = "diagnose"):
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config, overrides=[f"dataset={dataset}", "autoencoder.progress_bar=false",
                                          "labeling.pool.progress=false", *extra])


class _Setup:
    """Data set, latent space, oracle (with an open pool), test rows and a uniform pool of a config."""

    def __init__(self, cfg, need_rows: int = 0, pool_seed: int = 0):
        from experiments.diagnose import diagnose_context
        from neuralcol.samples.cache import shared_test_set
        from neuralcol.samples.uniform import uniform_rows

        self.cfg = cfg
        ctx = diagnose_context(cfg)
        self.ds, self.space, self.report = ctx.dataset, ctx.space, ctx.latent_space().report
        lab = ctx.sample_labeler()
        self._pool = ctx.pool(lab)
        self.oracle = ctx.oracle(self._pool.__enter__())
        det = OmegaConf.to_container(cfg.detector, resolve=True)
        self.test, _, _ = shared_test_set(self.oracle, det, self.report["cache_key"], cfg.paths.cache_dir)
        self.rows = None
        if need_rows:
            shared = ctx.samples_dir(lab)
            self.rows = uniform_rows(shared / f"uniform_s{pool_seed}.h5", self.oracle, need_rows, pool_seed).rows
        self.cap, self.eps = float(lab.cap), float(lab.eps)

    def close(self):
        self._pool.__exit__(None, None, None)


# ------------------------------------------------------------------------------------------------ loss
LOSS_VARIANTS = {
    "paper (before issue 15)": {"decoder_features": False, "pd_clip": 3.0, "pd_floor": None, "eps": 2e-3},
    "decoder features": {"decoder_features": True, "pd_clip": 3.0, "pd_floor": None, "eps": 2e-3},
    "+ PD band 0.25": {"decoder_features": True, "pd_clip": 0.25, "pd_floor": -0.25, "eps": 2e-3},
    "+ CE on D_b": {"decoder_features": True, "pd_clip": 0.25, "pd_floor": -0.25, "eps": 2e-3,
                    "ce_on_boundary": True},
    "+ eps 1e-4 (defaults)": {"decoder_features": True, "pd_clip": 0.25, "pd_floor": -0.25, "eps": 1e-4},
    "w_b = 0 (supv)": {"decoder_features": True, "pd_clip": 0.25, "pd_floor": -0.25, "eps": 1e-4, "w_b": 0.0},
}


def cmd_loss(args) -> dict:
    from neuralcol.collision.labeler import split_subsets
    from neuralcol.diagnose.curve import fit_rows, take_rows
    from neuralcol.nn.detector import build_detector

    s = _Setup(study_config(args.dataset, args.set), need_rows=args.rows)
    det = OmegaConf.to_container(s.cfg.detector, resolve=True)
    diag = s.space.rest_vertices.numpy()
    diag = float(np.linalg.norm(diag.max(0) - diag.min(0)))
    rows = take_rows(s.rows, args.rows)
    out = {}
    for name in args.variants or list(LOSS_VARIANTS):
        v = LOSS_VARIANTS[name]
        r = rows._replace(subset=split_subsets(rows.pd, v["eps"] * diag))
        res = []
        for seed in args.seeds:
            torch.manual_seed(seed)
            net = build_detector(s.space, {**det, "net": {**det["net"], "decoder_features": v["decoder_features"]}})
            det_v = {**det, "loss": {**det["loss"], "ce_on_boundary": v.get("ce_on_boundary", False)},
                     "targets": {"pd_clip": v["pd_clip"], "pd_floor": v["pd_floor"]}}
            m = fit_rows(net, r, s.test, s.cap, det_v, v.get("w_b", 0.5), True, seed)["test"]
            res.append([m["accuracy"], m["fnr"]])
        a = np.asarray(res)
        out[name] = {"accuracy": a[:, 0].tolist(), "fnr": a[:, 1].tolist()}
        print(f"{name:28s} accuracy {a[:, 0].mean():.4f} ± {a[:, 0].std():.4f}  FNR {a[:, 1].mean():.3f} "
              f"± {a[:, 1].std():.3f}  ({len(args.seeds)} seeds, {args.rows} rows)", flush=True)
    s.close()
    return out


# ------------------------------------------------------------------------------------------------ regression
def cmd_regression(args) -> dict:
    from sklearn.ensemble import HistGradientBoostingClassifier, HistGradientBoostingRegressor

    from neuralcol.diagnose.curve import box_scaled

    s = _Setup(study_config(args.dataset, args.set), need_rows=max(args.sizes))
    lo, hi = s.space.box_lo.numpy().astype(np.float64), s.space.box_hi.numpy().astype(np.float64)
    x, xt = box_scaled(s.rows.z, lo, hi), box_scaled(s.test.z, lo, hi)
    pd, yt = np.asarray(s.rows.pd), np.asarray(s.test.pd) > 0
    out = {}
    for n in args.sizes:
        c = HistGradientBoostingClassifier(max_iter=500, early_stopping=True, random_state=0).fit(x[:n], pd[:n] > 0)
        row = {"classify": float(c.score(xt, yt))}
        for clip in (0.25, 1.0, 3.0):
            r = HistGradientBoostingRegressor(max_iter=500, early_stopping=True, random_state=0)
            r.fit(x[:n], np.clip(pd[:n] / s.cap, -clip, clip))
            row[f"regress clip {clip}"] = float(np.mean((r.predict(xt) > 0) == yt))
        out[n] = row
        print(f"n={n}: " + ", ".join(f"{k} {v:.4f}" for k, v in row.items()), flush=True)
    s.close()
    return out


# ------------------------------------------------------------------------------------------------ latent
LATENT_VARIANTS = {
    "tanh, box from all codes (before)": ["autoencoder.box_from=all"],
    "tanh, box from training codes (default)": [],
    "latent noise 0.1": ["autoencoder.level1.code_noise=0.1", "autoencoder.level2.code_noise=0.1"],
    "latent noise 0.3": ["autoencoder.level1.code_noise=0.3", "autoencoder.level2.code_noise=0.3"],
    "linear level-1 components": ["autoencoder.level1.activation=linear"],
}


def cmd_latent(args) -> dict:
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.neighbors import KNeighborsClassifier

    from experiments.diagnose import diagnose_context
    from neuralcol.diagnose.curve import box_scaled
    from neuralcol.diagnose.latent import decoder_report

    out = {}
    for name in args.variants or list(LATENT_VARIANTS):
        cfg = study_config(args.dataset, [*args.set, *LATENT_VARIANTS[name]])
        t0 = time.perf_counter()
        ctx = diagnose_context(cfg)
        space, report = ctx.space, ctx.latent_space().report
        lab = ctx.sample_labeler()
        z = space.sample(args.samples, torch.Generator().manual_seed(0))
        dec = decoder_report(space, z[: space.n_parts])
        with torch.no_grad():
            v = torch.cat([space.decode(c) for c in z.split(256)]).double().numpy()
        with ctx.pool(lab) as pool:
            labels = pool.label(v)
        y = labels.collides
        x = box_scaled(z.numpy(), space.box_lo.numpy(), space.box_hi.numpy())
        n_test = args.samples // 3
        xt, yt, x, y = x[-n_test:], y[-n_test:], x[:-n_test], y[:-n_test]
        majority = max(yt.mean(), 1 - yt.mean())
        row = {"train_error": report["train_mean_vertex_error"], "heldout_error": report["val_mean_vertex_error"],
               "saturation": dec["saturation"], "busiest_share": dec["busiest_share_mean"],
               "collide": float(labels.collides.mean()),
               "near_contact": float(np.mean(np.abs(labels.pd) < lab.cap / 4)), "majority": float(majority)}
        for n in (len(x) // 4, len(x)):
            h = HistGradientBoostingClassifier(max_iter=300, early_stopping=True, random_state=0).fit(x[:n], y[:n])
            k = KNeighborsClassifier(15).fit(x[:n], y[:n])
            row[f"hgb_{n}"], row[f"knn_{n}"] = float(h.score(xt, yt)), float(k.score(xt, yt))
            row[f"hgb_headroom_{n}"] = (row[f"hgb_{n}"] - majority) / (1 - majority)
        out[name] = row
        print(f"{name}: " + ", ".join(f"{k} {v:.4f}" for k, v in row.items()) + f" ({time.perf_counter() - t0:.0f} s)",
              flush=True)
    return out


# ------------------------------------------------------------------------------------------------ selection
def cmd_selection(args) -> dict:
    from neuralcol.collision.labeler import split_subsets
    from neuralcol.diagnose.curve import fit_rows
    from neuralcol.nn.detector import build_detector

    s = _Setup(study_config(args.dataset, args.set), need_rows=args.pool)
    det = OmegaConf.to_container(s.cfg.detector, resolve=True)
    pool = s.rows._replace(subset=split_subsets(s.rows.pd, s.eps))
    n0, na, rounds = args.n_init, args.n_aug, args.rounds
    out: dict = {}

    def sub(idx):
        idx = np.sort(np.asarray(idx))
        return pool.select(idx)

    for seed in args.seeds:
        for mode in ("uniform", "uncertainty"):
            rng = np.random.default_rng(seed)
            perm = rng.permutation(len(pool.z))
            chosen, cand = list(perm[:n0]), list(perm[n0:])
            curve = []
            for r in range(rounds + 1):
                torch.manual_seed(seed)
                net = build_detector(s.space, det)
                m = fit_rows(net, sub(chosen), s.test, s.cap, det, 0.5, True, seed)["test"]
                curve.append({"size": len(chosen), "accuracy": m["accuracy"], "fnr": m["fnr"]})
                print(f"{mode} seed {seed}: {len(chosen)} rows, accuracy {m['accuracy']:.4f}, FNR {m['fnr']:.3f}",
                      flush=True)
                if r == rounds:
                    break
                if mode == "uniform":
                    new, cand = cand[:na], cand[na:]
                else:  # half uniform, half the most uncertain of 10x as many candidates (Algorithm 1's halves)
                    uni, cand = cand[: na // 2], cand[na // 2:]
                    batch = np.asarray(cand[: 10 * (na // 2)])
                    with torch.no_grad():
                        logit = net(torch.as_tensor(pool.z[batch])).logit.numpy()
                    pick = set(batch[np.argsort(np.abs(logit))[: na // 2]].tolist())
                    cand = [c for c in cand if c not in pick]
                    new = uni + sorted(pick)
                chosen += list(new)
            out[f"{mode}_s{seed}"] = curve
    s.close()
    return out


# ------------------------------------------------------------------------------------------------ margin
def cmd_margin(args) -> dict:
    from neuralcol.handler.alm import ALMSettings
    from neuralcol.nn.detector import load_detector
    from neuralcol.rundir import RunDir
    from neuralcol.stages.handler import evaluate_handler

    out = {}
    for run in args.runs:
        run = Path(run)
        cfg = OmegaConf.load(RunDir(run).config)
        overrides = [str(o) for o in OmegaConf.load(RunDir(run).overrides)
                     if not str(o).startswith(("dataset=", "hydra"))]
        s = _Setup(study_config(str(cfg.dataset.name), [*overrides, *args.set]))
        pick = np.flatnonzero(s.test.pd > 0)[: args.inputs]
        z_user, pd_user = torch.as_tensor(s.test.z[pick]), s.test.pd[pick]
        base = ALMSettings(**OmegaConf.to_container(s.cfg.handler.alm, resolve=True))
        net, _ = load_detector(RunDir(run).detector)
        rows = []
        for margin in args.margins:
            m, _ = evaluate_handler(net, s.oracle, z_user, pd_user, replace(base, margin=margin),
                                    int(s.cfg.handler.batch_size))
            rows.append({"margin": margin, **{k: m[k] for k in ("success_rate", "resolved_rate", "mean_pd_reduction",
                                                                 "mean_embedding_diff")}})
            print(f"{run}: margin {margin}: success {m['success_rate']:.3f}, resolved {m['resolved_rate']:.3f}, "
                  f"PD reduction {m['mean_pd_reduction']:.3f}, |Z - Z_user| {m['mean_embedding_diff']:.1f}",
                  flush=True)
        out[str(run)] = rows
        s.close()
    return out


def main(argv=None) -> None:
    p = argparse.ArgumentParser(prog="python -m research.diagnosis_ablations", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)

    def common(q):
        q.add_argument("--dataset", default="scape")
        q.add_argument("--set", nargs="*", default=[], help="extra Hydra overrides, e.g. labeling.pool.workers=1")
        q.add_argument("--out", type=Path, default=None, help="write the results as JSON here")

    q = sub.add_parser("loss")
    common(q)
    q.add_argument("--rows", type=int, default=12000)
    q.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    q.add_argument("--variants", nargs="*", default=None, choices=list(LOSS_VARIANTS))
    q = sub.add_parser("regression")
    common(q)
    q.add_argument("--sizes", type=int, nargs="+", default=[3000, 12000])
    q = sub.add_parser("latent")
    common(q)
    q.add_argument("--samples", type=int, default=6000)
    q.add_argument("--variants", nargs="*", default=None, choices=list(LATENT_VARIANTS))
    q = sub.add_parser("selection")
    common(q)
    q.add_argument("--pool", type=int, default=48000)
    q.add_argument("--n-init", type=int, default=2000)
    q.add_argument("--n-aug", type=int, default=2000)
    q.add_argument("--rounds", type=int, default=5)
    q.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    q = sub.add_parser("margin")
    common(q)
    q.add_argument("runs", nargs="+")
    q.add_argument("--margins", type=float, nargs="+", default=[0.5, 1.0, 2.0, 3.0, 4.0])
    q.add_argument("--inputs", type=int, default=200)
    args = p.parse_args(argv)
    res = globals()[f"cmd_{args.cmd}"](args)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(res, indent=1, default=float))


if __name__ == "__main__":
    main()
