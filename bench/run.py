"""Benchmarks: ``python -m bench.run [--quick] [--only NAME ...]`` (``make bench``).

Each benchmark measures one cost of the method on SCAPE, repeated; every figure is reported as the median
with min and max, and ratios are taken from numbers measured in the same run. Results go to
``bench/results.json`` (flat keys with medians, plus a ``details`` object with min/max/reps) and
``bench/results.md``.
"""

from __future__ import annotations

import argparse
import copy
import datetime as dt
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SCAPE_DIR = Path(os.environ.get("NEURALCOL_DATA", ROOT.parent / "shared" / "data")) / "scape"


class Timing(dict):
    """median / min / max of repeated measurements (in the unit named by the key)."""


def repeat(fn: Callable[[], object], reps: int, warmup: int = 1) -> list[float]:
    """Wall-clock seconds of ``reps`` calls of ``fn`` after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def summarize(values: list[float], scale: float = 1.0) -> dict:
    vals = [v * scale for v in values]
    return {"median": statistics.median(vals), "min": min(vals), "max": max(vals), "reps": len(vals)}


# ---------------------------------------------------------------------------------------------- benches
def bench_acap(ctx: dict) -> dict:
    """ACAP encode and decode of all 71 SCAPE meshes (batched), ms per mesh."""
    from neuralcol import ACAP

    ds = ctx["scape"]
    verts = ds.vertices.to(torch.float64)
    acap = ACAP(verts[0], ds.faces)
    n = len(verts)
    reps = ctx["reps"]
    enc = repeat(lambda: acap.encode(verts), reps)
    feats = acap.encode(verts)
    with torch.no_grad():
        dec = repeat(lambda: acap.decode(feats), reps)
    feats32 = feats.float()
    with torch.no_grad():
        dec32 = repeat(lambda: acap.decode(feats32), reps)
    return {
        "acap_encode_ms": summarize(enc, 1e3 / n),
        "acap_decode_ms": summarize(dec, 1e3 / n),
        "acap_decode_float32_ms": summarize(dec32, 1e3 / n),
    }


def _jittered_subdivision(verts, faces, levels: int, rng):
    """SCAPE meshes subdivided ``levels`` times (midpoints), vertices jittered by 1e-6 of the bbox diagonal
    (exactly coplanar sub-triangles trip MeshLab's filter)."""
    import trimesh

    out = []
    f = faces
    for v in verts:
        vv, ff = v, faces
        for _ in range(levels):
            vv, ff = trimesh.remesh.subdivide(vv, ff)
        diag = float(np.linalg.norm(vv.max(0) - vv.min(0)))
        out.append(vv + rng.normal(scale=1e-6 * diag / np.sqrt(3), size=vv.shape))
        f = ff
    return np.stack(out), np.asarray(f)


def _meshlab_times(verts, faces, reps):
    """Per-mesh seconds of MeshLab's self-intersection filter (mesh upload excluded)."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    per_rep = []
    for _ in range(reps):
        total = 0.0
        for v in verts:
            ms.clear()
            ms.add_mesh(pymeshlab.Mesh(vertex_matrix=v, face_matrix=faces))
            t0 = time.perf_counter()
            ms.compute_selection_by_self_intersections_per_face()
            total += time.perf_counter() - t0
        per_rep.append(total / len(verts))
    return per_rep


def _per_mesh_times(fn, verts, reps):
    per_rep = []
    for _ in range(reps):
        t0 = time.perf_counter()
        for v in verts:
            fn(v)
        per_rep.append((time.perf_counter() - t0) / len(verts))
    return per_rep


def bench_labeler(ctx: dict) -> dict:
    """Exact verdict and full label per SCAPE mesh, side by side with MeshLab, and scaling with mesh size."""
    from neuralcol.collision.labeler import ExactLabeler

    ds = ctx["scape"]
    verts = ds.vertices.numpy().astype(np.float64)
    faces = ds.faces.numpy()
    reps = ctx["reps"]
    lab = ExactLabeler(faces, verts[0])
    lab.label(verts[1])  # compile / load the numba cache outside the timing
    lab.verdict(verts[1])
    out = {
        "verdict_ms": summarize(_per_mesh_times(lab.verdict, verts, reps), 1e3),
        "meshlab_ms": summarize(_meshlab_times(verts, faces, reps), 1e3),
        "full_label_ms": summarize(_per_mesh_times(lab.label, verts, reps), 1e3),
    }
    out["verdict_vs_meshlab"] = _ratio(out["verdict_ms"], out["meshlab_ms"])
    # scaling: the same collision-free SCAPE poses at every level, subdivided 0, 1, 2 times; the labeler is built
    # on the (subdivided) rest mesh, which is not among the timed poses. Its own rest mesh is the full label's
    # worst case (every part's clearance sits at the cap, nothing can be pruned): timed apart.
    rng = np.random.default_rng(0)
    free = [i for i in range(1, len(verts)) if not lab.verdict(verts[i])]
    sample = free[: 3 if ctx["quick"] else 6]
    scaling = {"triangles": [], "verdict_ms": [], "meshlab_ms": [], "full_label_ms": [], "full_label_rest_mesh_ms": [],
               "poses": [ds.names[i] for i in sample]}
    r = max(2, reps // 2)
    for level in (0, 1, 2):
        if level == 0:
            sv, sf, slab = verts[sample], faces, lab
        else:
            sv, sf = _jittered_subdivision(verts[[0, *sample]], faces, level, rng)
            slab = ExactLabeler(sf, sv[0])
            sv = sv[1:]
        flagged = sum(slab.verdict(v) for v in sv)
        if flagged:
            raise RuntimeError(f"{flagged} collision-free SCAPE meshes flagged after {level} subdivision(s)")
        scaling["triangles"].append(len(sf))
        scaling["verdict_ms"].append(summarize(_per_mesh_times(slab.verdict, sv, r), 1e3)["median"])
        scaling["meshlab_ms"].append(summarize(_meshlab_times(sv, sf, r), 1e3)["median"])
        scaling["full_label_ms"].append(summarize(_per_mesh_times(slab.label, sv, r), 1e3)["median"])
        scaling["full_label_rest_mesh_ms"].append(
            summarize(_per_mesh_times(slab.label, slab.rest[None], r), 1e3)["median"])
    tri = np.asarray(scaling["triangles"], float)
    for key in ("verdict_ms", "meshlab_ms", "full_label_ms", "full_label_rest_mesh_ms"):
        # growth exponent k of time ~ triangles^k between the smallest and the largest mesh (linear: 1)
        scaling[key.replace("_ms", "_exponent")] = round(float(
            np.log(scaling[key][-1] / scaling[key][0]) / np.log(tri[-1] / tri[0])), 3)
    out["scaling"] = scaling
    return out


def bench_pool(ctx: dict) -> dict:
    """Labels per second of LabelPool with 1 and 2 workers on the same 142 SCAPE meshes, interleaved."""
    from neuralcol.collision.labeler import ExactLabeler
    from neuralcol.collision.pool import LabelPool

    ds = ctx["scape"]
    verts = ds.vertices.numpy().astype(np.float64)
    batch = np.concatenate([verts, verts])
    lab = ExactLabeler(ds.faces.numpy(), verts[0])
    reps = 3 if ctx["quick"] else 5
    with LabelPool(lab, workers=1, chunk_size=8) as one, LabelPool(lab, workers=2, chunk_size=8) as two:
        one.label(batch[:4])
        two.label(batch[:16])  # start the worker processes outside the timing
        t1, t2 = [], []
        for _ in range(reps):  # interleaved, so both see the same machine load
            t0 = time.perf_counter()
            one.label(batch)
            t1.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            two.label(batch)
            t2.append(time.perf_counter() - t0)
    n = len(batch)
    r1 = summarize([n / t for t in t1])
    r2 = summarize([n / t for t in t2])
    return {"pool_labels_per_s_1": r1, "pool_labels_per_s_2": r2,
            "pool_speedup": summarize([a / b for a, b in zip(t1, t2)])}


def _scape_variants(verts: np.ndarray, n: int, seed: int = 0) -> list[np.ndarray]:
    """Inter-/extrapolations ``v_i + t (v_j - v_i)``, ``t ~ U(-0.8, 1.8)``, between collision-free SCAPE poses (as
    in tests/test_labeler.py::test_variants_match_meshlab_including_near_boundary): both classes."""
    rng = np.random.default_rng(seed)
    free = [i for i in range(len(verts)) if i not in (7, 70)]  # files 8 and 71 collide
    out = []
    for _ in range(n):
        i, j = rng.choice(free, 2, replace=False)
        out.append(verts[i] + rng.uniform(-0.8, 1.8) * (verts[j] - verts[i]))
    return out


def bench_fcl(ctx: dict) -> dict:
    """python-fcl backend (``labeling.backend=fcl``, the paper's labeler) next to ExactLabeler in the same run:
    full label and verdict per SCAPE mesh (all 71, reps interleaved), the whole-mesh BVH self-collision it
    replaces, and the share of equal verdicts on the 71 meshes plus inter-/extrapolated poses."""
    from neuralcol.collision.fcl_labeler import FCLLabeler
    from neuralcol.collision.labeler import ExactLabeler

    ds = ctx["scape"]
    verts = ds.vertices.numpy().astype(np.float64)
    faces = ds.faces.numpy()
    reps = ctx["reps"]
    exact = ExactLabeler(faces, verts[0])
    t0 = time.perf_counter()
    lab = FCLLabeler(faces, verts[0])
    build_s = time.perf_counter() - t0
    bvh = FCLLabeler(faces, verts[0], method="bvh")
    grid = FCLLabeler(faces, verts[0], method="grid")  # same pairs, candidates from neuralcol's grid
    for f in (exact.label, exact.verdict, lab.label, lab.verdict, grid.label):  # numba cache, python-fcl's first calls
        f(verts[1])
    times: dict[str, list[float]] = {k: [] for k in ("fcl_label", "exact_label", "fcl_verdict", "exact_verdict",
                                                     "grid_label", "grid_verdict")}
    for _ in range(reps):  # interleaved, so both labelers see the same machine load
        times["fcl_label"] += _per_mesh_times(lab.label, verts, 1)
        times["exact_label"] += _per_mesh_times(exact.label, verts, 1)
        times["fcl_verdict"] += _per_mesh_times(lab.verdict, verts, 1)
        times["exact_verdict"] += _per_mesh_times(exact.verdict, verts, 1)
        times["grid_label"] += _per_mesh_times(grid.label, verts, 1)
        times["grid_verdict"] += _per_mesh_times(grid.verdict, verts, 1)
    out = {
        "fcl_full_label_ms": summarize(times["fcl_label"], 1e3),
        "fcl_exact_full_label_ms": summarize(times["exact_label"], 1e3),
        "fcl_verdict_ms": summarize(times["fcl_verdict"], 1e3),
        "fcl_exact_verdict_ms": summarize(times["exact_verdict"], 1e3),
        "fcl_grid_full_label_ms": summarize(times["grid_label"], 1e3),
        "fcl_grid_verdict_ms": summarize(times["grid_verdict"], 1e3),
    }
    out["fcl_vs_exact_full_label"] = _ratio(out["fcl_full_label_ms"], out["fcl_exact_full_label_ms"])
    out["fcl_vs_exact_verdict"] = _ratio(out["fcl_verdict_ms"], out["fcl_exact_verdict_ms"])
    sample = verts[:: 15 if ctx["quick"] else 5]  # the literal way: the whole mesh's BVH collided with itself
    out["fcl_bvh_self_collide_ms"] = summarize(_per_mesh_times(bvh.counted_pairs, sample, 1), 1e3)
    # agreement: the 71 meshes plus inter-/extrapolations between free poses
    n_var = 100 if ctx["quick"] else 300
    sets = {"scape": list(verts), "variants": _scape_variants(verts, n_var)}
    table: dict[str, list] = {"set": [], "meshes": [], "colliding_exact": [], "colliding_fcl": [], "agreement": [],
                              "pd_ratio_colliding": [], "pd_ratio_free": []}
    equal_all, n_all = 0, 0
    for name, meshes in sets.items():
        a = [exact.label(v) for v in meshes]
        b = [lab.label(v) for v in meshes]
        ca = np.array([x.collides for x in a])
        cb = np.array([x.collides for x in b])
        pa = np.array([x.pd for x in a])
        pb = np.array([x.pd for x in b])
        both, free = ca & cb, ~ca & ~cb
        table["set"].append(name)
        table["meshes"].append(len(meshes))
        table["colliding_exact"].append(int(ca.sum()))
        table["colliding_fcl"].append(int(cb.sum()))
        table["agreement"].append(float((ca == cb).mean()))
        # median PD_fcl / PD_exact where both agree: how far the two definitions of PD lie apart
        table["pd_ratio_colliding"].append(float(np.median(pb[both] / pa[both])) if both.any() else float("nan"))
        table["pd_ratio_free"].append(float(np.median(pb[free] / pa[free])) if free.any() else float("nan"))
        equal_all += int((ca == cb).sum())
        n_all += len(meshes)
    out["fcl_agreement"] = summarize([equal_all / n_all])
    out["fcl_agreement_sets"] = table
    ctx["notes"]["fcl"] = (f"FCLLabeler(method='broadphase', patch_size={lab.patch_size}) built in {build_s:.2f} s on "
                           f"SCAPE file 1 ({len(faces)} triangles); times per mesh over all 71 meshes, {reps} reps "
                           f"interleaved with ExactLabeler; fcl_grid_*: method='grid' (same labels); "
                           f"fcl_bvh_self_collide_ms: method='bvh' on {len(sample)} "
                           f"meshes, 1 rep; agreement: {n_all} meshes (71 SCAPE + {n_var} variants), "
                           f"{sum(table['colliding_exact'])} colliding for ExactLabeler, "
                           f"{sum(table['colliding_fcl'])} for FCL")
    return out
def bench_dask(ctx: dict) -> dict:
    """Labels per second of LabelPool on a dask LocalCluster (2 worker processes x 1 thread) and of the local pool
    (2 worker processes), interleaved on the 71 SCAPE meshes repeated 8 times (568 meshes), both with the runs'
    chunk size (``labeling.pool.chunk_size``, 32); ``dask_vs_pool``: their ratio."""
    from neuralcol.collision.labeler import ExactLabeler
    from neuralcol.collision.pool import LabelPool

    ds = ctx["scape"]
    verts = ds.vertices.numpy().astype(np.float64)
    batch = np.concatenate([verts] * 8)
    lab = ExactLabeler(ds.faces.numpy(), verts[0])
    reps = 3 if ctx["quick"] else 5
    with LabelPool(lab, workers=2, chunk_size=32) as local, \
            LabelPool(lab, executor="dask", workers=2, chunk_size=32) as dask_pool:
        local.label(batch)  # start the workers (and the cluster) and load the kernels outside the timing
        dask_pool.label(batch)
        tl, td = [], []
        for _ in range(reps):  # interleaved, so both see the same machine load
            t0 = time.perf_counter()
            local.label(batch)
            tl.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            dask_pool.label(batch)
            td.append(time.perf_counter() - t0)
    n = len(batch)
    ctx["notes"]["dask"] = ("LocalCluster of 2 worker processes x 1 thread on this machine (executor=dask, "
                            "scheduler=null), 568 SCAPE meshes, chunk_size 32, vs the local pool with workers=2; "
                            "target dask_vs_pool >= 0.8")
    return {"dask_labels_per_s": summarize([n / t for t in td]),
            "dask_local_pool_labels_per_s": summarize([n / t for t in tl]),
            "dask_vs_pool": summarize([a / b for a, b in zip(tl, td)])}


def _neural_run(ctx: dict) -> Path:
    """A finished SCAPE run to take the detector and latent space from: ``--run-dir``, else the newest one under
    ``outputs/``, else a small one built now into ``bench/tmp/run`` (tiny autoencoder and data, but the CPU
    preset's detector size, so per-sample costs are representative; iteration counts less so)."""
    if ctx.get("run_dir"):
        return Path(ctx["run_dir"])
    runs = [p.parent for p in (ROOT / "outputs").glob("**/detector.pt")
            if (p.parent / "metrics.json").is_file() and (p.parent / ".hydra" / "config.yaml").is_file()
            and json.loads((p.parent / "metrics.json").read_text()).get("dataset", {}).get("name") == "scape"]
    if runs:
        return max(runs, key=lambda p: (p / "detector.pt").stat().st_mtime)
    run_dir = HERE / "tmp" / "run"
    if not (run_dir / "detector.pt").is_file():
        import subprocess

        print("[bench] no finished SCAPE run under outputs/: building a small one in bench/tmp/run", flush=True)
        subprocess.run([sys.executable, "-m", "experiments.run", "dataset=scape", "autoencoder=tiny", "detector=tiny",
                        "detector.net.state_dim=64", "detector.net.hidden=128", "handler.n_inputs=0",
                        f"paths.data_dir={SCAPE_DIR.parent}", f"hydra.run.dir={run_dir}"], cwd=ROOT, check=True)
    return run_dir


def bench_neural(ctx: dict) -> dict:
    """Neural detector vs exact labels, Newton projection and the collision handler, with a trained detector."""
    from hydra.utils import instantiate

    from neuralcol import load_run
    from neuralcol.active.newton import newton_project
    from neuralcol.stages.handling import alm_settings, handle_codes

    run_dir = _neural_run(ctx)
    run = load_run(run_dir)
    cfg, space, net = run.cfg, run.space, run.detector
    reps, quick = ctx["reps"], ctx["quick"]
    gen = torch.Generator().manual_seed(0)
    z = space.sample(4096, generator=gen)
    out: dict = {}
    with torch.no_grad():
        one = z[:1]
        b1 = repeat(lambda: net(one).logit, 200 if quick else 1000, warmup=20)
        b4096 = repeat(lambda: net(z).logit, reps * 3, warmup=2)
    out["detector_us_per_sample_b1"] = summarize(b1, 1e6)
    out["detector_us_per_sample_b4096"] = summarize(b4096, 1e6 / len(z))
    # side by side, interleaved: the forward before stop 23 (CP on the concatenation, one block of 4096) and today's
    # (first CP layer split, row blocks of CollisionDetector.inference_block); bench/detector_forward.py has more
    from bench.detector_forward import concat_forward
    old_t, new_t = [], []
    with torch.no_grad():
        for _ in range(reps * 10 + 2):
            old_t += repeat(lambda: concat_forward(net, z), 1, warmup=0)
            new_t += repeat(lambda: net(z).prob, 1, warmup=0)
    old_t, new_t = old_t[2:], new_t[2:]
    out["detector_before_stop23_us_per_sample_b4096"] = summarize(old_t, 1e6 / len(z))
    out["detector_forward_speedup_b4096"] = summarize([a / b for a, b in zip(old_t, new_t)])  # per interleaved pair
    # the exact reference on the same kind of samples: decode + full label, one core
    labeler = instantiate(cfg.labeling.labeler)(space.faces.numpy(), space.rest_vertices.numpy(),
                                                partition=space.partition.numpy())
    n_exact = 16 if quick else 48
    ze = z[:n_exact]

    def exact():
        with torch.no_grad():
            verts = space.decode(ze).double().numpy()
        return [labeler.label(v) for v in verts]

    exact_s = repeat(exact, max(2, reps // 2))
    out["exact_ms_per_sample"] = summarize(exact_s, 1e3 / n_exact)
    def as_ms(us: dict) -> dict:  # a summary in µs -> the same summary in ms (its rep count kept)
        return {k: (v / 1e3 if k != "reps" else v) for k, v in us.items()}

    out["neural_vs_exact_speedup"] = _ratio(out["exact_ms_per_sample"], as_ms(out["detector_us_per_sample_b4096"]))
    from neuralcol.nn.fast_inference import RECHECK_BAND

    fast_notes: list[str] = []
    out.update(_fast_forms(net, z, space, reps, out["exact_ms_per_sample"], as_ms, fast_notes))
    # the same detector exported to ONNX and run by ONNX Runtime (experiments.export), same codes and threads
    with tempfile.TemporaryDirectory() as tmp:
        ort_run = _onnx_detector(run, Path(tmp))
        if ort_run is not None:
            out["detector_onnx_us_per_sample_b4096"] = summarize(repeat(lambda: ort_run(z), reps * 3, warmup=2),
                                                                 1e6 / len(z))
            out["neural_vs_exact_speedup_onnx"] = _ratio(out["exact_ms_per_sample"],
                                                         as_ms(out["detector_onnx_us_per_sample_b4096"]))
    # Newton projection onto the 0.5 level set (float64, as in active learning), batched
    newton_cfg = dict(cfg.detector.newton)
    net64 = copy.deepcopy(net).double().eval()
    zn = z[:512 if quick else 1024].double()
    lo, hi = space.box_lo.double(), space.box_hi.double()
    iters = []

    def project():
        p = newton_project(lambda q: net64(q).logit, zn, lo, hi, **newton_cfg)
        iters.append(float(p.iterations.float().mean()))

    newton_s = repeat(project, max(2, reps // 2))
    out["newton_ms_per_sample"] = summarize(newton_s, 1e3 / len(zn))
    out["newton_mean_iterations"] = summarize(iters)
    # the handler on codes the detector calls colliding, batched as configured
    with torch.no_grad():
        colliding = z[net(z).logit > 0][: 256 if quick else 1024]
    # the current defaults (conf/handler/default.yaml), not the settings the run was made with
    from omegaconf import OmegaConf

    handler_cfg = OmegaConf.load(ROOT / "conf" / "handler" / "default.yaml")
    settings = alm_settings(handler_cfg.alm)
    outer = []

    def handle():
        res = handle_codes(net, colliding, space.box_lo, space.box_hi, settings,
                           batch_size=int(handler_cfg.batch_size))
        outer.append(float(res.outer.float().mean()))

    handler_s = repeat(handle, max(2, reps // 2), warmup=0)
    out["handler_ms_per_mesh"] = summarize(handler_s, 1e3 / max(len(colliding), 1))
    out["handler_mean_outer_iterations"] = summarize(outer)
    where = run_dir.relative_to(ROOT) if run_dir.is_relative_to(ROOT) else run_dir
    ctx["notes"]["neural"] = (f"detector and latent space of {where}; "
                              f"exact reference: decode + full label of {n_exact} uniform codes on one core; "
                              f"detector: {torch.get_num_threads()} threads, torch and ONNX Runtime (`_onnx` keys); "
                              "FastDetector (torch.compile, `_compiled` float32, `_compiled_bf16` and "
                              "`_compiled_bf16_checked` (float32 recheck of logits within "
                              f"{RECHECK_BAND} of 0) keys; eager and all three interleaved call by call, "
                              "`_vs_eager` per call; label flips and largest "
                              f"probability change against eager on 100 000 uniform codes; {'; '.join(fast_notes)}); "
                              f"handler: {len(colliding)} codes the detector calls colliding, batch "
                              f"{int(handler_cfg.batch_size)}, conf/handler/default.yaml settings, detector only "
                              "(no verification)")
    return out


FAST_KEYS = {"compiled": "float32", "compiled_bf16": "bfloat16",
             "compiled_bf16_checked": "bfloat16_checked"}  # bench key -> FastDetector form (run.detect(fast=...))


def _fast_forms(net, z: torch.Tensor, space, reps: int, exact_ms: dict, as_ms, notes: list[str]) -> dict:
    """The detector's eager forward against FastDetector (torch.compile, float32 and bfloat16) at batch ``len(z)``,
    interleaved call by call; their agreement with eager on 100 000 uniform codes; speedups over ``exact_ms``.
    Keys ``detector_{compiled,compiled_bf16}_*``; a form that fails to compile is left out (``notes`` says why)."""
    from neuralcol.nn.fast_inference import FastDetector, bf16_is_native

    out: dict = {}
    notes.append(f"bfloat16 {'native' if bf16_is_native('cpu') else 'emulated'} on this CPU")
    forms = {}
    for key, form in FAST_KEYS.items():
        t0 = time.perf_counter()
        try:
            forms[key] = FastDetector.from_form(net, form, compile=True)
        except RuntimeError as exc:
            notes.append(f"{key}: {str(exc).splitlines()[0]}")
            continue
        out[f"detector_{key}_build_s"] = summarize([time.perf_counter() - t0])
    if not forms:
        return out
    timings: dict[str, list[float]] = {"eager": [], **{k: [] for k in forms}}
    calls = {"eager": lambda: net(z).prob, **{k: (lambda f=f: f(z).prob) for k, f in forms.items()}}
    with torch.no_grad():
        for _ in range(reps * 10 + 2):
            for key, call in calls.items():
                timings[key] += repeat(call, 1, warmup=0)
        gen = torch.Generator().manual_seed(1)
        codes = space.sample(100_000, generator=gen)
        ref = torch.cat([net(c).prob for c in codes.split(4096)])
        for key, f in forms.items():
            prob = f(codes).prob
            out[f"detector_{key}_label_flips"] = summarize([float(((prob > 0.5) != (ref > 0.5)).float().mean())])
            out[f"detector_{key}_max_prob_diff"] = summarize([float((prob - ref).abs().max())])
            if f.recheck_band is not None:
                out[f"detector_{key}_rechecked_fraction"] = summarize([f.rechecked_fraction])
    eager = timings.pop("eager")[2:]
    out["detector_eager_interleaved_us_per_sample_b4096"] = summarize(eager, 1e6 / len(z))
    for key, t in timings.items():
        t = t[2:]
        out[f"detector_{key}_us_per_sample_b4096"] = summarize(t, 1e6 / len(z))
        out[f"detector_{key}_vs_eager_b4096"] = summarize([a / b for a, b in zip(eager, t)])  # per interleaved call
        out[f"neural_vs_exact_speedup_{key}"] = _ratio(exact_ms, as_ms(out[f"detector_{key}_us_per_sample_b4096"]))
    return out


def _onnx_detector(run, tmp: Path):
    """The run's detector exported to ONNX under ``tmp`` and loaded into ONNX Runtime with torch's thread count:
    a callable codes -> outputs, or None when onnx / onnxruntime are not installed."""
    try:
        import onnx  # noqa: F401
        import onnxruntime as ort
    except ImportError:
        return None
    from experiments.export import export_run

    export_run(run, tmp / "onnx", "onnx")
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = torch.get_num_threads()
    sess = ort.InferenceSession(str(tmp / "onnx" / "detector.onnx"), opts)
    return lambda z: sess.run(None, {"codes": z.numpy()})


def bench_export(ctx: dict) -> dict:
    """The detector exported by ``experiments.export`` (TorchScript; ONNX Runtime when installed) next to the live
    module, µs per sample at batch 4096, on the same codes."""
    from experiments.export import export_run
    from neuralcol import load_run

    run_dir = _neural_run(ctx)
    run = load_run(run_dir)
    z = run.space.sample(4096, generator=torch.Generator().manual_seed(0))
    reps = ctx["reps"] * 3
    out: dict = {}
    with torch.no_grad():
        out["export_live_detector_us_b4096"] = summarize(repeat(lambda: run.detector(z), reps, warmup=2),
                                                         1e6 / len(z))
    with tempfile.TemporaryDirectory() as tmp:
        export_run(run, Path(tmp) / "torchscript", "torchscript")
        module = torch.jit.load(str(Path(tmp) / "torchscript" / "detector.pt"))
        with torch.no_grad():
            out["export_torchscript_detector_us_b4096"] = summarize(repeat(lambda: module(z), reps, warmup=2),
                                                                    1e6 / len(z))
        ort_run = _onnx_detector(run, Path(tmp))
        if ort_run is not None:
            out["export_onnx_detector_us_b4096"] = summarize(repeat(lambda: ort_run(z), reps, warmup=2), 1e6 / len(z))
    where = run_dir.relative_to(ROOT) if run_dir.is_relative_to(ROOT) else run_dir
    ctx["notes"]["export"] = (f"detector of {where} (outputs prob and the PD estimate), 4096 uniform codes per call, "
                              f"{torch.get_num_threads()} threads (ONNX Runtime intra-op threads the same)"
                              + ("" if ort_run is not None else "; onnxruntime not installed: ONNX not measured"))
    run.close()
    return out


def _compose(overrides: list[str]):
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


def bench_training(ctx: dict) -> dict:
    """Seconds per epoch: the SCAPE autoencoder (CPU preset) and the detector (CPU preset, 10 000 rows).

    Each is timed at two epoch counts; the per-epoch figure is the slope, so set-up costs (Trainer, data,
    partition) cancel."""
    from lightning.pytorch import Trainer

    from neuralcol.data.collision_datamodule import CollisionDataModule
    from neuralcol.data.collision_store import CollisionStore
    from neuralcol.data.features import dataset_features
    from neuralcol.lit.detector import DetectorLitModule
    from neuralcol.stages.autoencoder import train_latent_space
    from neuralcol.stages.detector import build_detector
    from neuralcol.utils.config import as_dict

    cfg = _compose(["dataset=scape", f"paths.data_dir={SCAPE_DIR.parent}", "autoencoder.progress_bar=false",
                    "autoencoder.val_every=1000000"])
    ds = ctx["scape"]
    acap_cfg = as_dict(cfg.acap)
    norm_cfg = acap_cfg.pop("normalizer")
    feats = dataset_features(ds, 0, acap_cfg, norm_cfg)
    ae = as_dict(cfg.autoencoder)
    lo_e, hi_e = (5, 15) if ctx["quick"] else (10, 40)

    def train_ae(epochs: int):
        a = {**ae, "level1": {**ae["level1"], "epochs": epochs}, "level2": {**ae["level2"], "epochs": epochs}}
        return train_latent_space(ds, feats, a, as_dict(cfg.dataset.latent), 0)

    reps = max(2, ctx["reps"] // 3)
    t_lo = repeat(lambda: train_ae(lo_e), reps, warmup=0)
    t_hi = repeat(lambda: train_ae(hi_e), reps, warmup=0)
    # per level-epoch: both levels run `epochs` epochs
    ae_epoch = [(b - a) / (2 * (hi_e - lo_e)) for a, b in zip(t_lo, t_hi)]
    space, _ = train_ae(2)
    # detector: 10 000 random rows of the SCAPE latent box, the CPU preset's network, batch and loss
    det = as_dict(cfg.detector)
    n = 10_000
    gen = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        store = CollisionStore(Path(tmp) / "dc.h5", space.dim, space.n_parts)
        pd_sub = gen.normal(0, 0.01, size=(n, space.n_parts))
        pd = pd_sub.max(1)
        store.append(space.sample(n).numpy(), pd, pd_sub, pd > 0, np.where(pd > 0, 0, 1), 0, np.zeros(n))
        store.close()
        dm = CollisionDataModule(Path(tmp) / "dc.h5", space.dim, space.n_parts, int(det["batch_size"]), 0.01,
                                 float(det["targets"]["pd_clip"]))
        dm.refresh()
        loss = det["loss"]

        def train_det(epochs: int):
            net = build_detector(space, det)
            module = DetectorLitModule(net, lr=float(det["lr"]), w_pd=loss["w_pd"], w_pdsum=loss["w_pdsum"],
                                       w_r=loss["w_r"], w_ce=loss["w_ce"], w_b=1.0, margin=loss["margin"],
                                       temperature=loss["temperature"])
            Trainer(max_epochs=epochs, accelerator="cpu", logger=False, enable_checkpointing=False,
                    enable_progress_bar=False, enable_model_summary=False).fit(module, datamodule=dm)

        d_lo, d_hi = (1, 3) if ctx["quick"] else (2, 6)
        t_dlo = repeat(lambda: train_det(d_lo), reps, warmup=0)
        t_dhi = repeat(lambda: train_det(d_hi), reps, warmup=0)
        dm.store.close()
    det_epoch = [(b - a) / (d_hi - d_lo) for a, b in zip(t_dlo, t_dhi)]
    ctx["notes"]["training"] = (f"autoencoder: SCAPE, CPU preset, slope between {lo_e} and {hi_e} epochs per level "
                                f"(seconds per epoch of one level); detector: CPU preset on {n} rows (80 % trained, "
                                f"20 % validated each epoch), slope between {d_lo} and {d_hi} epochs")
    return {"ae_epoch_s": summarize(ae_epoch), "detector_epoch_s_per_10k": summarize(det_epoch)}


def _tree_rss_mb(pid: int) -> float:
    """Resident memory of a process and its descendants (Linux /proc), MB."""
    total, stack = 0, [pid]
    while stack:
        p = stack.pop()
        try:
            with open(f"/proc/{p}/status") as f:
                for line in f:
                    if line.startswith("VmRSS:"):
                        total += int(line.split()[1])
                        break
            with open(f"/proc/{p}/task/{p}/children") as f:
                stack += [int(c) for c in f.read().split()]
        except (FileNotFoundError, ProcessLookupError):
            continue
    return total / 1024


def bench_memory(ctx: dict) -> dict:
    """Peak resident memory (this process + its 2 workers) while labeling decoded SCAPE samples, and the size
    of the HDF5 D_c per 10 000 rows."""
    import threading

    from hydra.utils import instantiate

    from neuralcol import load_run
    from neuralcol.active.oracle import LatentOracle
    from neuralcol.collision.pool import LabelPool
    from neuralcol.data.collision_store import CollisionStore

    run = load_run(_neural_run(ctx))
    cfg, space = run.cfg, run.space
    labeler = instantiate(cfg.labeling.labeler)(space.faces.numpy(), space.rest_vertices.numpy(),
                                                partition=space.partition.numpy())
    n = 2000 if ctx["quick"] else 10_000
    z = space.sample(n, generator=torch.Generator().manual_seed(1))
    peak, stop = [0.0], threading.Event()

    def watch():
        while not stop.is_set():
            peak[0] = max(peak[0], _tree_rss_mb(os.getpid()))
            time.sleep(0.1)

    before = _tree_rss_mb(os.getpid())
    t = threading.Thread(target=watch, daemon=True)
    t.start()
    t0 = time.perf_counter()
    with LabelPool(labeler, workers=2, progress=False) as pool:
        lab = LatentOracle(space, pool)(z, desc="bench")
    seconds = time.perf_counter() - t0
    stop.set()
    t.join()
    with tempfile.TemporaryDirectory() as tmp:
        store = CollisionStore(Path(tmp) / "dc.h5", space.dim, space.n_parts)
        store.append(lab.z, lab.pd, lab.pd_sub, lab.collides, lab.subset, 0, np.zeros(len(lab.z)))
        store.close()
        size_mb = (Path(tmp) / "dc.h5").stat().st_size / 2 ** 20
    ctx["notes"]["memory"] = (f"{n} uniform SCAPE codes decoded and labeled by LabelPool(workers=2) in "
                              f"{seconds:.0f} s; RSS of this process and its workers sampled every 0.1 s "
                              f"({before:.0f} MB before labeling)")
    return {"label_peak_rss_mb": summarize([peak[0]]), "dc_mb_per_10k": summarize([size_mb * 10_000 / n]),
            "label_oracle_per_s": summarize([n / seconds])}


def _scalar(x: float) -> dict:
    """A single measured value in the median/min/max form of the other keys."""
    return {"median": float(x), "min": float(x), "max": float(x), "reps": 1}


def bench_gpu(ctx: dict) -> dict:
    """Batched Warp labeler (labeling.backend=gpu): labels per second on a batch of perturbed SCAPE poses, and its
    agreement with the exact CPU labeler on every pose (verdict and pair count, max |PD - PD_cpu| / diag).

    On a CUDA device the rate is ``gpu_labels_per_s``; without one Warp runs the same kernels on the CPU (one
    thread) and the rate is ``gpu_labels_per_s_cpu_device``. ``gpu_ref_cpu_labels_per_s`` is the numba labeler
    on the same poses, one process.
    """
    import warp as wp

    from neuralcol.collision.gpu_labeler import BatchedLabeler, default_device
    from neuralcol.collision.labeler import ExactLabeler, Labels

    ds = ctx["scape"]
    verts = ds.vertices.numpy().astype(np.float64)
    faces = ds.faces.numpy()
    device = default_device()
    on_cuda = not wp.get_device(device).is_cpu
    n = 512 if (on_cuda or not ctx["quick"]) else 256
    reps = ctx["reps"] if on_cuda else (2 if ctx["quick"] else 3)
    # the 71 poses repeated, each moved a random 0-50 % of the way towards another pose (a mix of free and
    # colliding poses, as a sampler near the data produces)
    rng = np.random.default_rng(0)
    i = np.arange(n) % len(verts)
    j = rng.integers(0, len(verts), n)
    t = rng.uniform(0.0, 0.5, n)
    poses = verts[i] + t[:, None, None] * (verts[j] - verts[i])
    part = (np.arange(len(verts[0])) * 4) // len(verts[0])  # 4 blocks of vertices: PD_i is compared too
    gl = BatchedLabeler(faces, verts[0], partition=part, device=device)
    ref = ExactLabeler(faces, verts[0], partition=part)
    gl.label_batch(poses[:2])  # compile / load the kernels outside the timing
    ref.label(poses[0])
    if on_cuda:
        import torch as _torch

        poses_dev = _torch.as_tensor(poses, device=wp.device_to_torch(device))  # the batch stays on the device

        def run():
            gl.label_batch(poses_dev)
            wp.synchronize_device(device)
    else:
        def run():
            gl.label_batch(poses)
    times = repeat(run, reps, warmup=1 if on_cuda else 0)
    got = gl.label_batch(poses)
    t0 = time.perf_counter()
    want = Labels.stack([ref.label(v) for v in poses], ref.n_parts)
    t_ref = time.perf_counter() - t0
    same = (got.collides == want.collides) & (got.n_pairs == want.n_pairs)
    err = max(np.abs(got.pd - want.pd).max(), np.abs(got.pd_sub - want.pd_sub).max()) / ref.diag
    key = "gpu_labels_per_s" if on_cuda else "gpu_labels_per_s_cpu_device"
    ctx["notes"]["gpu"] = (f"device {device} ({wp.get_device(device).name}), {n} poses, "
                           f"{int(want.collides.sum())} colliding, partition of 4 blocks")
    return {key: summarize([n / s for s in times]),
            "gpu_ref_cpu_labels_per_s": _scalar(n / t_ref),
            "gpu_vs_cpu_max_pd_err": _scalar(err),
            "gpu_verdict_agreement": _scalar(same.mean()),
            "gpu_colliding_fraction": _scalar(want.collides.mean())}


def _ratio(a: dict, b: dict) -> dict:
    """Ratio of two medians measured in the same run (min/max: the ratio of the extremes)."""
    return {"median": a["median"] / b["median"], "min": a["min"] / b["max"], "max": a["max"] / b["min"],
            "reps": min(a["reps"], b["reps"])}


BENCHES: dict[str, Callable[[dict], dict]] = {"acap": bench_acap, "labeler": bench_labeler, "pool": bench_pool,
                                              "dask": bench_dask, "fcl": bench_fcl, "neural": bench_neural,
                                              "training": bench_training, "memory": bench_memory, "gpu": bench_gpu,
                                              "export": bench_export}


def write_markdown(results: dict, path: Path) -> None:
    lines = [
        "# Benchmark results",
        "",
        f"Date {results['date']}, {results['cores']} cores, {results['machine']}, torch {results['torch']}. "
        f"Command: `{results['command']}`. Each figure: median, min and max over the repetitions; ratios "
        "come from numbers measured in the same run. Sections (date, seconds): "
        + ", ".join(f"{k} ({v['date']}, {v['seconds']})" for k, v in results.get("sections", {}).items()) + ".",
        "",
        *[f"- {k}: {v}" for k, v in results.get("notes", {}).items()],
        "",
        "| key | median | min | max | reps |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for key, d in results["details"].items():
        if "median" in d:
            lines.append(f"| `{key}` | {d['median']:.4g} | {d['min']:.4g} | {d['max']:.4g} | {d['reps']} |")
    for key, d in results["details"].items():
        if "median" not in d:  # tables such as the scaling series
            n = len(next(iter(d.values())))
            cols = [c for c in d if isinstance(d[c], list) and len(d[c]) == n
                    and all(isinstance(x, (int, float)) for x in d[c])]
            lines += ["", f"`{key}`:", "", "| " + " | ".join(cols) + " |", "|" + " ---: |" * len(cols)]
            for row in zip(*(d[c] for c in cols)):
                lines.append("| " + " | ".join(f"{x:.4g}" for x in row) + " |")
            lines += [""] + [f"- {c}: {d[c]}" for c in d if c not in cols]
    path.write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer repetitions (development)")
    parser.add_argument("--only", nargs="*", choices=sorted(BENCHES), help="run only these benchmarks")
    parser.add_argument("--out", type=Path, default=HERE, help="folder for results.json / results.md")
    parser.add_argument("--run-dir", type=Path, default=None,
                        help="finished SCAPE run for the neural benchmarks (default: the newest under outputs/)")
    args = parser.parse_args(argv)
    if not (SCAPE_DIR / "1.obj").is_file():
        print(f"error: SCAPE not found at {SCAPE_DIR}; set NEURALCOL_DATA to the folder holding scape/",
              file=sys.stderr)
        return 2
    from neuralcol import load_mesh_dataset

    torch.set_num_threads(os.cpu_count() or 1)
    ctx = {"scape": load_mesh_dataset(SCAPE_DIR), "reps": 3 if args.quick else 7, "quick": args.quick,
           "run_dir": args.run_dir, "notes": {}}
    details: dict = {}
    sections: dict = {}
    previous = args.out / "results.json"
    if args.only and previous.is_file():  # partial run: keep the other sections' last results
        old = json.loads(previous.read_text())
        details.update(old.get("details", {}))
        sections.update(old.get("sections", {}))
        notes = old.get("notes", {})
        ctx["notes"].update({k: v for k, v in notes.items() if k not in (args.only or [])})
    for name in args.only or list(BENCHES):
        t0 = time.perf_counter()
        details.update(BENCHES[name](ctx))
        sections[name] = {"date": dt.datetime.now().isoformat(timespec="seconds"),
                          "seconds": round(time.perf_counter() - t0, 1), "quick": args.quick}
        print(f"[bench] {name}: {time.perf_counter() - t0:.1f} s", flush=True)
    results = {key: (d["median"] if "median" in d else d) for key, d in details.items()}
    results.update({
        "cores": os.cpu_count(),
        "date": dt.datetime.now().isoformat(timespec="seconds"),
        "machine": f"{platform.machine()} {platform.processor() or platform.system()}",
        "torch": torch.__version__,
        "command": "python -m bench.run" + (" --quick" if args.quick else ""),
        "sections": sections,
        "notes": ctx["notes"],
        "details": details,
    })
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(results, indent=2))
    write_markdown(results, args.out / "results.md")
    print(json.dumps({k: v for k, v in results.items() if k != "details"}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
