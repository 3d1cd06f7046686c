"""Stage: speed against accuracy of every way to answer "does the mesh of this code self-collide?".

One chart per run (``speed_accuracy.png``, :func:`experiments.reporting.speed_accuracy.plot_speed_accuracy`):
throughput (samples per second in this one process, timed side by side) against accuracy and against FNR on
the run's U(Z) test set, so a user reads off "FNR 1 % costs X samples/s". The methods (``metrics["speed_accuracy"]
["points"]``, one entry per method and variant):

* ``exact``: :class:`~neuralcol.collision.labeler.ExactLabeler` (``labeling=cpu``; the run's labeler settings)
  on the decoded code, its ``verdict`` (early exit) and its full ``label`` (verdict, PD, PD_i). Accuracy and FNR
  are measured against the test set's labels on ``n_exact`` test codes (1 and 0 when the run labels with
  ``labeling=cpu``: the same definition; anything else is reported, not assumed);
* ``meshlab``: pymeshlab's ``compute_selection_by_self_intersections_per_face`` on the decoded mesh (mesh upload
  included), "collides" iff it selects a face; scored on ``n_meshlab`` test codes. Optional: skipped with a note
  when pymeshlab is not importable;
* ``fcl``: :class:`~neuralcol.collision.fcl_labeler.FCLLabeler` (python-fcl, the paper's labeler), its
  ``verdict``; scored on ``n_fcl`` test codes. Skipped with a note when python-fcl is not importable. MeshLab and
  FCL do not count touching contacts (or one-vertex folds) as ours does, so accuracy < 1 there is a finding;
* ``latent detector`` (``code+mesh detector`` for a detector over code and mesh: its time includes
  decoding the vertices its pair features read): the run's final detector on codes, batch ``batch`` (4096): eager,
  and compiled (:class:`~neuralcol.nn.fast_inference.FastDetector`, forms ``forms``). Accuracy of the eager float32
  form: the run's ``test_predictions.npz`` (its reported test metrics); of the others: measured on the whole test
  set;
* ``cascade``: one point per target FNR of ``metrics["cascade"]`` (written by the cascade stage), priced with this
  stage's timings so it is side by side with the others: the eager detector on every code plus the exact verdict
  (the cascade's exact path; the full label when the verdict is not timed) on its ``exact_share``
  (``samples_per_s_stage``: the cascade stage's own figure).

Throughput: every method is timed on the same ``n_timed`` test codes (the latent detector on a batch of ``batch``
rows: the test codes repeated), code in, verdict out, decoding included for every method that judges the mesh.
Accuracy is scored first (which also warms up numba's kernels, python-fcl and MeshLab), then one warm-up call each
(the mesh methods on one code), then ``reps`` repetitions round-robin over the methods (so all see the same machine
load); the median of the per-repetition rates. The decode alone is timed in the same round (``decode_ms_per_sample``:
the share every mesh method pays). torch's thread count as the run has it (recorded in ``threads``); the labelers
run in this process on one core (no worker pool). Cost on proc_hand with the defaults: ~20-40 s on 2 cores, most of
it FCL (~80 ms a verdict) and the first ``torch.compile``.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from neuralcol.metrics.detection import detection_metrics
from neuralcol.nn.part_geometry import SUMMARY_ROWS, reads_summaries
from neuralcol.utils.config import as_dict

FORMS = ("float32", "bfloat16", "bfloat16_checked")  # neuralcol.nn.fast_inference.FORMS
LABELER_KEYS = ("touch_tol", "clearance_cap", "boundary_eps", "cell_factor")  # shared by ExactLabeler and FCLLabeler
COUNT_KEYS = {"n_timed": 1, "batch": 1, "reps": 1, "n_exact": 0, "n_meshlab": 0, "n_fcl": 0}


def speed_accuracy_problems(cfg) -> list[str]:
    """Problems of the ``speed_accuracy`` config group as ``key=value: rule`` strings (empty: fine)."""
    if cfg is None:
        return []
    c = as_dict(cfg)
    problems = []
    if not isinstance(c.get("enabled"), bool):
        problems.append(f"speed_accuracy.enabled={c.get('enabled')!r}: must be true or false")
    for key, least in COUNT_KEYS.items():
        v = c.get(key)
        if not (isinstance(v, int) and not isinstance(v, bool) and v >= least):
            problems.append(f"speed_accuracy.{key}={v!r}: must be an integer >= {least}")
    for key in ("compile", "meshlab", "fcl", "exact_full_label"):
        if not isinstance(c.get(key), bool):
            problems.append(f"speed_accuracy.{key}={c.get(key)!r}: must be true or false")
    forms = c.get("forms")
    if not isinstance(forms, list) or any(f not in FORMS for f in forms):
        problems.append(f"speed_accuracy.forms={forms!r}: must be a list of {', '.join(FORMS)} (may be empty)")
    if not (isinstance(c.get("seed"), int) and not isinstance(c.get("seed"), bool)):
        problems.append(f"speed_accuracy.seed={c.get('seed')!r}: must be an integer")
    return problems


def _finite(x) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def _point(method: str, variant: str, sps: float | None, accuracy, fnr, n_timed: int, n_scored: int) -> dict:
    return {"method": method, "variant": variant, "samples_per_s": _finite(sps), "accuracy": _finite(accuracy),
            "fnr": _finite(fnr), "n_timed": int(n_timed), "n_scored": int(n_scored)}


def _scores(predicted: np.ndarray, actual: np.ndarray) -> tuple[float, float | None, int]:
    m = detection_metrics(np.asarray(predicted, bool), np.asarray(actual, bool))
    return m["accuracy"], _finite(m["fnr"]), int(m["n"])


def decode(space, z: np.ndarray, batch: int = 256) -> np.ndarray:
    """(N, D) codes -> (N, V, 3) float64 meshes (as the exact oracle decodes them)."""
    zt = torch.as_tensor(np.asarray(z, np.float32))
    with torch.no_grad():
        parts = [space.decode(c.to(space.box_lo)).cpu() for c in zt.split(batch)]
    return torch.cat(parts).numpy().astype(np.float64)


def meshlab_verdict(faces: np.ndarray):
    """A function (V, 3) mesh -> bool: MeshLab selects a self-intersecting face (mesh upload included).
    ImportError when pymeshlab is missing."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    f = np.ascontiguousarray(faces, dtype=np.int32)

    def verdict(v: np.ndarray) -> bool:
        ms.clear()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.ascontiguousarray(v, dtype=np.float64), face_matrix=f))
        ms.compute_selection_by_self_intersections_per_face()
        return ms.current_mesh().selected_face_number() > 0

    return verdict


def _round_robin(fns: dict, reps: int, warm: dict | None = None) -> dict[object, list[float]]:
    """Seconds of ``reps`` calls of each function, one call of each per repetition in turn, after one call of
    each of ``warm`` (default: of ``fns``)."""
    for fn in (warm or fns).values():
        fn()
    times: dict = {k: [] for k in fns}
    for _ in range(reps):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    return times


def cascade_points(cascade: dict | None, exact_sps: float | None = None, detector_sps: float | None = None) -> list:
    """One point per target FNR of ``metrics["cascade"]`` (empty when absent). Its ``samples_per_s`` is the cascade
    priced with this stage's own timings, so it sits on the chart side by side with the other methods:
    ``detector_sps`` for every code plus ``exact_sps`` for its ``exact_share`` of exact calls (without both, the
    cascade stage's own figure); ``samples_per_s_stage`` keeps the cascade stage's figure."""
    out = []
    for t in (cascade or {}).get("targets") or []:
        test = t.get("test") or {}
        share = test.get("exact_share")
        sps = t.get("samples_per_s")
        if exact_sps and detector_sps and share is not None:
            sps = 1.0 / (1.0 / detector_sps + float(share) / exact_sps)
        p = _point("cascade", f"FNR<={t['target_fnr']:g}", sps, test.get("accuracy"), test.get("fnr"), 0,
                   int(test.get("n") or 0))
        p["samples_per_s_stage"] = t.get("samples_per_s")
        p["exact_share"] = share
        out.append(p)
    return out


CODE_AND_MESH = "code+mesh detector"  # the point family of a detector over code and mesh


def detector_family(net) -> str:
    """The speed points' method name of a run's detector: ``latent detector`` (codes only) or
    :data:`CODE_AND_MESH` (a :class:`~neuralcol.nn.part_geometry.DetectorOnCodes` whose detector reads the mesh)."""
    inner = getattr(net, "detector", None)
    return CODE_AND_MESH if inner is not None and inner.geometry is not None else "latent detector"


def measure_speed_accuracy(space, net, test, cfg, labeling=None, metrics: dict | None = None,
                           run_dir: str | Path | None = None, log: Callable[[str], None] = print) -> dict:
    """Throughput against accuracy and FNR of each method on the run's U(Z) test set (see the module docstring).

    Args:
        space: the latent space (decoder, topology, rest mesh, partition).
        net: the run's final latent detector.
        test: the U(Z) test rows (``z`` (N, D), ``collides`` (N,)): the exact labels everything is scored against.
        cfg: the ``speed_accuracy`` config group.
        labeling: the run's ``labeling`` group (its ``labeler`` settings build ExactLabeler and FCLLabeler, and
            ``backend`` names the labels' source); None: the labelers' defaults.
        metrics: the run's metrics so far (``cascade``), or None.
        run_dir: the run directory (its ``test_predictions.npz`` gives the eager detector's test accuracy).
        log: progress lines.

    Returns:
        ``{"points": [...], "threads", "n_timed", "batch", "reps", "decode_ms_per_sample", "decode_device", "n_test",
        "seconds", "notes"}``.
    """
    from neuralcol.collision.labeler import ExactLabeler
    from neuralcol.nn.fast_inference import FastDetector
    from neuralcol.rundir import RunDir

    t_start = time.perf_counter()
    c = as_dict(cfg)
    problems = speed_accuracy_problems(c)
    if problems:
        raise ValueError("; ".join(problems))
    metrics = metrics or {}
    notes: list[str] = []
    z_all = np.asarray(test.z, np.float32)
    y_all = np.asarray(test.collides, bool)
    if len(z_all) == 0:
        raise ValueError("measure_speed_accuracy: the test set is empty")
    order = np.random.default_rng(int(c["seed"])).permutation(len(z_all))
    n_timed = min(int(c["n_timed"]), len(z_all))
    z_t = z_all[order[:n_timed]]
    lab_cfg = as_dict(labeling) if labeling is not None else {}
    settings = {k: lab_cfg["labeler"][k] for k in LABELER_KEYS if k in (lab_cfg.get("labeler") or {})}
    backend = lab_cfg.get("backend", "cpu")
    if backend != "cpu":
        notes.append(f"the test set's labels come from labeling={backend}, not ExactLabeler: the exact labeler's "
                     "accuracy is its agreement with them")
    faces = space.faces.cpu().numpy()
    rest = space.rest_vertices.cpu().numpy()
    partition = space.partition.cpu().numpy()
    exact = ExactLabeler(faces, rest, partition=partition, **settings)
    threads = torch.get_num_threads()
    net = copy.deepcopy(net).cpu().eval()  # the caller's network stays where and as it was
    family = detector_family(net)

    # ---------------------------------------------------------------- the methods: code(s) -> verdicts
    mesh_methods: dict[tuple[str, str], Callable[[np.ndarray], object]] = {("exact", "verdict"): exact.verdict}
    if c["exact_full_label"]:
        mesh_methods[("exact", "label + PD")] = exact.label
    if c["meshlab"]:
        try:
            mesh_methods[("meshlab", "self-intersecting faces")] = meshlab_verdict(faces)
        except ImportError as e:
            notes.append(f"MeshLab left out: pymeshlab is not importable ({e}); pip install pymeshlab")
    if c["fcl"]:
        try:
            from neuralcol.collision.fcl_labeler import FCLLabeler

            mesh_methods[("fcl", "verdict")] = FCLLabeler(faces, rest, partition=partition, **settings).verdict
        except ImportError as e:
            notes.append(f"FCL left out: python-fcl is not importable ({e}); pip install python-fcl")
    detectors: dict[tuple[str, str], FastDetector] = {}
    forms = ["float32", *[f for f in c["forms"] if f != "float32"]]  # eager float32: the run's own forward pass
    summaries = reads_summaries(net)
    if summaries:  # its close-pair search runs outside torch: never compiled, timed on fewer codes
        notes.append(f"{family}: reads contact summaries (a CPU search per mesh): eager only, timed on at most "
                     f"{SUMMARY_ROWS} codes")
    for form in forms:
        for compiled in ([False, True] if c["compile"] and form in c["forms"] and not summaries else [False]):
            key = (family, f"{form} {'compiled' if compiled else 'eager'}")
            t0 = time.perf_counter()
            try:
                detectors[key] = FastDetector.from_form(net, form, compile=compiled)
            except RuntimeError as e:
                notes.append(f"{key[1]} left out: {str(e).splitlines()[0]}")
                continue
            if compiled:
                log(f"[speed] compiled the detector ({form}) in {time.perf_counter() - t0:.1f} s")
    if family == CODE_AND_MESH:
        notes.append(f"{family}: its time includes decoding the {len(net.detector.geometry.vertex_index)} vertices "
                     "its pair features read")

    # ---------------------------------------------------------------- accuracy against the test set's labels
    # (first: it also warms up numba's kernels, python-fcl and MeshLab before the timing)
    n_of = {"exact": c["n_exact"], "meshlab": c["n_meshlab"], "fcl": c["n_fcl"]}
    n_mesh = min(max([int(n_of[k[0]]) for k in mesh_methods]), len(z_all))
    idx = order[:n_mesh]
    t0 = time.perf_counter()
    meshes = decode(space, z_all[idx]) if n_mesh else None
    log(f"[speed] decoded {n_mesh} test codes in {time.perf_counter() - t0:.1f} s")
    y_mesh = y_all[idx]
    scored: dict[tuple[str, str], tuple] = {}
    for key, verdict in mesh_methods.items():
        if key == ("exact", "label + PD"):  # one labeler, one verdict definition: the label's is the verdict's
            scored[key] = scored[("exact", "verdict")]
            continue
        n = min(int(n_of[key[0]]), n_mesh)
        if n == 0:
            scored[key] = (None, None, 0)
            continue
        t0 = time.perf_counter()
        pred = np.array([bool(verdict(v)) for v in meshes[:n]], bool)
        log(f"[speed] {key[0]} scored on {n} test codes ({time.perf_counter() - t0:.1f} s)")
        scored[key] = _scores(pred, y_mesh[:n])
    t0 = time.perf_counter()
    preds_path = RunDir(run_dir).test_predictions if run_dir is not None else None
    for key, det in detectors.items():
        if key[1] == "float32 eager" and preds_path is not None and preds_path.is_file():
            with np.load(preds_path) as p:
                if len(p["logit"]) == len(y_all):
                    scored[key] = _scores(p["logit"] > 0, p["collides"])
                    continue
        scored[key] = _scores(det(torch.as_tensor(z_all)).logit.numpy() > 0, y_all)
    log(f"[speed] {len(detectors)} latent detector forms scored on {len(z_all)} test codes "
        f"({time.perf_counter() - t0:.1f} s)")

    # ---------------------------------------------------------------- throughput, timed on the same codes
    batch = min(int(c["batch"]), SUMMARY_ROWS) if summaries else int(c["batch"])
    z_b = torch.as_tensor(np.resize(z_t, (batch, z_t.shape[1])))  # the timed codes repeated up to the batch
    timed: dict[tuple[str, str], Callable[[], object]] = {}
    warm: dict[tuple[str, str], Callable[[], object]] = {}
    per_call: dict[tuple[str, str], int] = {}
    for key, verdict in mesh_methods.items():
        timed[key] = (lambda f: lambda: [f(v) for v in decode(space, z_t)])(verdict)
        warm[key] = (lambda f: lambda: [f(v) for v in decode(space, z_t[:1])])(verdict)  # warm already: one code
        per_call[key] = n_timed
    for key, det in detectors.items():
        timed[key] = warm[key] = (lambda d: lambda: d(z_b))(det)
        per_call[key] = batch
    timed[("decode", "")] = warm[("decode", "")] = lambda: decode(space, z_t)  # the share all mesh methods pay
    per_call[("decode", "")] = n_timed
    reps = int(c["reps"])
    log(f"[speed] timing {len(timed) - 1} methods on the same {n_timed} test codes (latent detector: batch {batch}), "
        f"{reps} repetitions round-robin, torch threads: {threads} ...")
    t0 = time.perf_counter()
    times = _round_robin(timed, reps, warm)
    log(f"[speed] timed in {time.perf_counter() - t0:.1f} s")
    sps = {k: float(np.median([per_call[k] / t for t in ts])) for k, ts in times.items()}
    decode_ms = 1e3 / sps.pop(("decode", ""))
    timed.pop(("decode", ""))

    points = [_point(k[0], k[1], sps[k], *scored.get(k, (None, None, 0))[:2], per_call[k],
                     scored.get(k, (None, None, 0))[2]) for k in timed]
    cascade = metrics.get("cascade")
    if cascade:
        exact_key = ("exact", "verdict") if ("exact", "verdict") in sps else ("exact", "label + PD")
        points += cascade_points(cascade, sps[exact_key], sps.get((family, "float32 eager")))
        notes.append("cascade: samples/s priced with this stage's timings (eager float32 detector on every code, exact "
                     f"{exact_key[1]} on its exact share); samples_per_s_stage: the cascade stage's own figure")
    else:
        notes.append("no cascade in this run's metrics: left out")
    out = {"points": points, "threads": threads, "n_timed": n_timed, "batch": batch, "reps": reps,
           "decode_ms_per_sample": decode_ms, "decode_device": str(space.box_lo.device), "n_test": int(len(z_all)),
           "notes": notes}
    out["seconds"] = time.perf_counter() - t_start
    log(f"[speed] done in {out['seconds']:.1f} s")
    return out
