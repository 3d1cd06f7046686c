"""Prototype: one detector over code and mesh, against the code-only detector, on a finished run's rows.

Reads a finished run (its latent space, D_c, the shared U(Z) test set and realistic set from the cache), chooses
per-sub-domain contact pairs (``neuralcol.nn.part_geometry``) on a stride of the decoded D_c, computes every row's
pair features once, and trains with the same loop, loss, targets, seeds and epochs:

* ``code``: the paper's detector (CSE -> CP_i -> MLP_c) on Z_all;
* ``code_mesh``: the same network whose CP_i also reads a pooled embedding of its own sub-domain's pair features
  (a shared per-pair MLP, max and mean over the sub-domain's slots) and whose CSE reads all of them;

plus references fit on the same rows: the majority class, gradient-boosted trees on the codes and on the codes
with the pair features. Test sets: U(Z) (features of the decoded codes) and the realistic set's clear meshes
(code = encode(mesh), features of the mesh itself; and of the round trip for comparison).

    python -m research.one_detector RUN_DIR OUT_JSON [--per-part 32] [--epochs 60] [--seeds 0 1 2]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from neuralcol.nn.detector import _mlp


class CodeMeshNet(nn.Module):
    """CSE -> CP_i -> MLP_c over [code, pooled pair features of sub-domain i] (geometry=False: codes only)."""

    def __init__(self, k: int, lo: torch.Tensor, hi: torch.Tensor, mask: torch.Tensor | None, state: int = 32,
                 hidden: int = 64, g_hidden: int = 32, pool: str = "deepsets"):
        super().__init__()
        self.k = k
        self.register_buffer("center", (lo + hi) / 2)
        self.register_buffer("half_range", (hi - lo) / 2)
        self.geometry = mask is not None
        self.pool = pool
        gdim = 0
        if self.geometry:
            self.register_buffer("mask", mask)
            if pool == "deepsets":
                self.phi = _mlp([4, g_hidden, g_hidden], nn.CELU)
                gdim = 2 * g_hidden
            else:  # "linear": each sub-domain's own affine map of its slots' features, then CELU
                m = mask.shape[1]
                self.slot_w = nn.Parameter(torch.randn(k, 3 * m, g_hidden) / (3 * m) ** 0.5)
                self.slot_b = nn.Parameter(torch.zeros(k, g_hidden))
                gdim = g_hidden
        d = lo.shape[0]
        part = d // k + gdim
        self.cse = nn.Sequential(_mlp([d + k * gdim, hidden, state], nn.CELU), nn.Tanh())
        self.cp = _mlp([state + part, hidden, hidden, 1], nn.CELU)
        self.mlp_c = _mlp([k, hidden, 1], nn.CELU)

    def pooled(self, g: torch.Tensor) -> torch.Tensor:
        """(B, K, M, 3) -> (B, K, 2 H): max and mean of phi over each sub-domain's filled slots."""
        m = self.mask[None, :, :, None]
        if self.pool == "linear":
            x = (g * m).flatten(2)  # (B, K, 3 M)
            return F.celu(torch.einsum("bkm,kmh->bkh", x, self.slot_w) + self.slot_b)
        x = torch.cat([g, m.expand(*g.shape[:3], 1).to(g)], -1)  # the slot's fill flag as a 4th input
        h = self.phi(x)
        hmax = h.masked_fill(~m, -1e4).amax(2)
        hmax = torch.where(self.mask.any(1)[None, :, None], hmax, torch.zeros_like(hmax))
        hmean = (h * m).sum(2) / m.sum(2).clamp_min(1)
        return torch.cat([hmax, hmean], -1)

    def forward(self, z: torch.Tensor, g: torch.Tensor | None = None):
        x = (z - self.center) / self.half_range
        b = len(z)
        parts = x[:, :self.k, None]
        if x.shape[1] > self.k:  # [z0_i, Z_i] as the detector splits them
            parts = torch.cat([parts, x[:, self.k:].reshape(b, self.k, -1)], -1)
        cse_in = x
        if self.geometry:
            pg = self.pooled(g)
            parts = torch.cat([parts, pg], -1)
            cse_in = torch.cat([x, pg.flatten(1)], -1)
        s0 = self.cse(cse_in)
        h = torch.cat([s0[:, None, :].expand(-1, self.k, -1), parts], -1)
        s = self.cp(h)[..., 0]
        logit = self.mlp_c(s)[:, 0]
        from neuralcol.nn.detector import DetectorOutput
        return DetectorOutput(torch.sigmoid(logit), logit, s)


def features_of(geo, space, z: np.ndarray | None = None, meshes: np.ndarray | None = None,
                batch: int = 512) -> np.ndarray:
    """(N, P, 3) float32 pair features of decoded codes (only the vertices they need) or of whole meshes."""
    out = []
    n_vert = space.rest_vertices.shape[0]
    idx = geo.vertex_index
    with torch.no_grad():
        if z is not None:
            for c in torch.as_tensor(np.asarray(z, np.float32)).split(batch):
                full = torch.zeros(len(c), n_vert, 3)
                full[:, idx] = space.decode_vertices(c, idx.numpy()).float()
                out.append(geo.pair_features(full).numpy())
        else:
            for c in torch.as_tensor(np.asarray(meshes, np.float32)).split(batch):
                out.append(geo.pair_features(c).numpy())
    return np.concatenate(out).astype(np.float32)


def train(net, z, g, pd, pd_sub, subset, loss_kw, epochs, lr, batch, seed, val_frac=0.2):
    from neuralcol.nn.detector import detector_losses

    gen = torch.Generator().manual_seed(seed)
    n = len(z)
    perm = torch.randperm(n, generator=gen)
    nv = int(val_frac * n)
    val, tr = perm[:nv], perm[nv:]
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    best, best_state = -1.0, None
    for _ in range(epochs):
        net.train()
        order = tr[torch.randperm(len(tr), generator=gen)]
        for i in range(0, len(order), batch):
            b = order[i:i + batch]
            out = net(z[b], None if g is None else g[b])
            loss = detector_losses(out, pd[b], pd_sub[b], subset[b], **loss_kw).total
            opt.zero_grad()
            loss.backward()
            opt.step()
        net.eval()
        with torch.no_grad():
            lv = net(z[val], None if g is None else g[val]).logit
        acc = float(((lv > 0) == (pd[val] > 0)).float().mean())
        if acc > best:
            best, best_state = acc, {k: v.clone() for k, v in net.state_dict().items()}
    net.load_state_dict(best_state)
    return best


def metrics(logit, y):
    from neuralcol.metrics.detection import detection_metrics

    m = detection_metrics(np.asarray(logit) > 0, np.asarray(y, bool))
    maj = max(np.mean(y), 1 - np.mean(y))
    return {"accuracy": m["accuracy"], "fnr": m["fnr"], "majority": float(maj),
            "skill": float((m["accuracy"] - maj) / (1 - maj))}


def predict(net, z, g, batch=4096):
    net.eval()
    out = []
    with torch.no_grad():
        for i in range(0, len(z), batch):
            out.append(net(z[i:i + batch], None if g is None else g[i:i + batch]).logit)
    return torch.cat(out).numpy()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir")
    ap.add_argument("out")
    ap.add_argument("--per-part", type=int, default=32)
    ap.add_argument("--min-hops", type=int, default=2)
    ap.add_argument("--fold-ratio", type=float, default=0.5)
    ap.add_argument("--radius", type=float, default=0.02)
    ap.add_argument("--select-stride", type=int, default=8)
    ap.add_argument("--select-from", default="dc", choices=["dc", "uniform"],
                    help="examples for the pair choice: decoded D_c rows (labeled) or unlabeled U(Z) codes")
    ap.add_argument("--epochs", type=int, default=60)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--gbt", action="store_true")
    ap.add_argument("--pool", default="deepsets", choices=["deepsets", "linear"])
    ap.add_argument("--g-hidden", type=int, default=32)
    ap.add_argument("--models", nargs="+", default=["code", "code_mesh"])
    ap.add_argument("--realistic-train", action="store_true",
                    help="add the run's realistic training meshes (cache realistic_train_*.npz, built from the "
                         "autoencoder's training meshes only) as rows: code = encode(mesh), features of the mesh")
    a = ap.parse_args()

    from neuralcol import load_run
    from neuralcol.nn.part_geometry import choose_geometry
    from neuralcol.samples.datamodule import detector_targets
    from neuralcol.samples.store import CollisionStore

    t0 = time.perf_counter()
    run = load_run(a.run_dir)
    space = run.space
    cfg = run.cfg
    det = cfg.detector
    rows = CollisionStore(run.run_dir / "dc.h5", space.dim, space.n_parts).read()
    key = run.metrics["autoencoder"]["cache_key"]
    cache = Path(cfg.paths.cache_dir) / "collision"
    sdir = next(p for p in cache.iterdir() if (p / "labeler.json").is_file()
                and json.loads((p / "labeler.json").read_text())["latent"] == key and list(p.glob("test_s*.h5")))
    test = CollisionStore(next(sdir.glob("test_s*.h5")), space.dim, space.n_parts).read()
    rp = np.load(run.run_dir / "realistic_predictions.npz")
    real_file = max(sdir.glob("realistic_[0-9a-f]*.npz"), key=lambda p: p.stat().st_mtime)
    real = np.load(real_file)
    assert len(real["pd"]) == len(rp["z"]), (real_file, len(real["pd"]), len(rp["z"]))
    clear = rp["clear"].astype(bool)
    print(f"run {a.run_dir}: D_c {len(rows.z)}, test {len(test.z)}, realistic clear {clear.sum()}", flush=True)

    # pairs from a stride of decoded D_c
    if a.select_from == "dc":  # a stride of the decoded D_c, with their labels
        sel = np.arange(0, len(rows.z), a.select_stride)
        sel_z = torch.as_tensor(rows.z[sel], dtype=torch.float32)
        sel_y = rows.collides[sel]
    else:  # unlabeled U(Z) codes, as many as the stride would take, each counted once (what exists before D_c)
        from neuralcol.samples.uniform import uniform_codes

        sel_z = uniform_codes(space, 777, 0, -(-len(rows.z) // a.select_stride))
        sel_y = np.zeros(len(sel_z), bool)
    with torch.no_grad():
        sel_v = space.decode(sel_z).double().numpy()
    if a.realistic_train:  # the mesh detector's pair choice saw them too
        rt = np.load(max(sdir.glob("realistic_train_*.npz"), key=lambda p: p.stat().st_mtime))
        sel_v = np.concatenate([sel_v, rt["vertices"]])
        sel_y = np.concatenate([sel_y, rt["pd"] > 0])
    geo = choose_geometry(space, sel_v, sel_y, radius=a.radius, min_hops=a.min_hops, fold_ratio=a.fold_ratio,
                          per_part=a.per_part)
    chosen, mask = geo.contact.pairs.numpy(), geo.mask.numpy()
    t_pairs = time.perf_counter() - t0
    print(f"{len(chosen)} pairs chosen, slots filled {mask.mean():.2f}, "
          f"{len(geo.vertex_index)} vertices read; {t_pairs:.0f} s", flush=True)

    f_dc = features_of(geo, space, z=rows.z)
    f_test = features_of(geo, space, z=test.z)
    f_real = features_of(geo, space, meshes=real["vertices"])
    f_real_rt = features_of(geo, space, z=rp["z"])
    t_feat = time.perf_counter() - t0 - t_pairs
    print(f"features: {t_feat:.0f} s", flush=True)

    from omegaconf import OmegaConf

    d = OmegaConf.to_container(det, resolve=True)
    use_bd = bool(cfg.method.use_boundary_set)
    z, pd, pd_sub, subset = detector_targets(rows, run.pd_unit, float(d["targets"]["pd_clip"]), use_bd,
                                             d["targets"].get("pd_floor"))
    loss_kw = {k: v for k, v in d["loss"].items()}
    loss_kw["w_b"] = float(cfg.method.w_b)
    if a.realistic_train:
        from neuralcol.collision.labeler import SUBSET_NEGATIVE, SUBSET_POSITIVE

        rt_file = max(sdir.glob("realistic_train_*.npz"), key=lambda p: p.stat().st_mtime)
        rt_v = np.load(rt_file)["vertices"]
        lab = run.label(rt_v)
        keep = np.abs(lab.pd) > 0
        rt_v = rt_v[keep]
        with torch.no_grad():
            rt_z = space.encode(torch.as_tensor(rt_v, dtype=torch.float64)).float()
        low = d["targets"].get("pd_floor")
        low = -np.inf if low is None else float(low)
        clip = float(d["targets"]["pd_clip"])
        z = torch.cat([z, rt_z])
        pd = torch.cat([pd, torch.as_tensor(np.clip(lab.pd[keep] / run.pd_unit, low, clip), dtype=torch.float32)])
        pd_sub = torch.cat([pd_sub, torch.as_tensor(np.clip(lab.pd_sub[keep] / run.pd_unit, low, clip),
                                                    dtype=torch.float32)])
        subset = torch.cat([subset, torch.as_tensor(np.where(lab.pd[keep] > 0, SUBSET_POSITIVE, SUBSET_NEGATIVE))])
        f_dc = np.concatenate([f_dc, features_of(geo, space, meshes=rt_v)])
        print(f"+ {len(rt_v)} realistic training meshes ({(lab.pd[keep] > 0).mean():.2f} colliding)", flush=True)
        run.close()
    g_dc = geo.per_part(torch.as_tensor(f_dc))
    sets = {"uz": (torch.as_tensor(test.z), geo.per_part(torch.as_tensor(f_test)), test.collides),
            "realistic": (torch.as_tensor(rp["z"][clear]), geo.per_part(torch.as_tensor(f_real[clear])),
                          real["pd"][clear] > 0),
            "realistic_round_trip_geometry": (torch.as_tensor(rp["z"][clear]),
                                              geo.per_part(torch.as_tensor(f_real_rt[clear])),
                                              real["pd"][clear] > 0)}
    lo, hi = space.box_lo.cpu().float(), space.box_hi.cpu().float()
    width = OmegaConf.to_container(cfg.dataset.detector_net, resolve=True)
    results = {"run": str(a.run_dir), "settings": vars(a), "n_pairs": int(len(chosen)),
               "n_vertices_read": int(len(geo.vertex_index)), "pairs_seconds": t_pairs, "features_seconds": t_feat,
               "models": {}}
    for name in a.models:
        for seed in a.seeds:
            torch.manual_seed(seed)
            net = CodeMeshNet(space.n_parts, lo, hi, geo.mask if name == "code_mesh" else None,
                              state=int(width["state_dim"]), hidden=int(width["hidden"]), g_hidden=a.g_hidden,
                              pool=a.pool)
            t1 = time.perf_counter()
            val = train(net, z, g_dc if name == "code_mesh" else None, pd, pd_sub, subset, loss_kw, a.epochs,
                        float(d["lr"]), int(d["batch_size"]), seed)
            r = {"val_accuracy": val, "train_seconds": time.perf_counter() - t1,
                 "n_parameters": sum(p.numel() for p in net.parameters())}
            for sname, (zz, gg, yy) in sets.items():
                r[sname] = metrics(predict(net, zz, gg if name == "code_mesh" else None), yy)
            results["models"].setdefault(name, []).append(r)
            print(name, seed, json.dumps({k: (v if not isinstance(v, dict) else
                                               {kk: round(vv, 3) for kk, vv in v.items()}) for k, v in r.items()}),
                  flush=True)
    if a.gbt:
        from sklearn.ensemble import HistGradientBoostingClassifier

        y = (pd > 0).numpy()  # the training rows' labels (realistic training meshes included)
        zn = z.numpy()
        for name, x, xs in (("gbt_code", zn, {k: v[0].numpy() for k, v in sets.items()}),
                            ("gbt_code_pairs", np.concatenate([zn, f_dc.reshape(len(f_dc), -1)], 1),
                             {"uz": np.concatenate([test.z, f_test.reshape(len(f_test), -1)], 1),
                              "realistic": np.concatenate([rp["z"][clear], f_real[clear].reshape(clear.sum(), -1)],
                                                          1)})):
            clf = HistGradientBoostingClassifier(random_state=0).fit(x, y)
            r = {s: metrics(clf.decision_function(xx), sets[s][2]) for s, xx in xs.items()}
            results["models"][name] = [r]
            print(name, r, flush=True)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(results, indent=1))
    print(f"done in {time.perf_counter() - t0:.0f} s -> {a.out}")


if __name__ == "__main__":
    main()
