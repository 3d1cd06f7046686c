"""GPU kit: ``python -m bench.gpu_check [--dry-run] [--out DIR]`` (``make gpu-check``).

One command measures, in at most 9 minutes on a CUDA machine, what needs a GPU. Each step runs in its own
process under a time cap, so a failure, a hang or a CUDA fault in one step is recorded and the next step runs:

1. ``cuda_tests``: ``pytest -m gpu`` on the test files with a ``gpu`` mark; passed / failed / skipped counts.
2. ``warp_labeler``: the Warp labeler (``labeling=gpu``) against ``ExactLabeler`` on perturbed SCAPE poses
   (:func:`bench.gpu.compare_labelers`): verdict agreement, max |PD - PD_cpu| / bbox diagonal, labels/s of both.
3. ``e2e_run``: a short ``python -m experiments.run`` on SCAPE, labels by Warp on the GPU, autoencoder and detector
   trained there (``autoencoder.accelerator=gpu detector.accelerator=gpu``), timed.
4. ``compiled_detector``: that run's detector (if the run did not finish: an untrained one over its latent space,
   which costs the same) eager and compiled (``FastDetector`` float32, bfloat16, bfloat16_checked) on the GPU, against
   the exact path (decode + full label, one CPU core): ``neural_vs_exact_speedup`` (:func:`bench.neural.fast_forms`).
5. ``paper_slice``: the first slice of ``experiment=paper_scape``: seconds per autoencoder epoch, per detector epoch
   and 10 000 rows, decode + label rate on U(Z) codes, and from them the hours of the whole paper run.

Budget on a CUDA machine. Each step's size is chosen from this machine's CPU timings (``bench/results.json``,
2 cores) and the H100's published throughput (132 SMs, 67 TFLOP/s FP32, 34 TFLOP/s FP64, 3.35 TB/s); its cap
bounds it whatever the GPU does. The caps add up to 530 s, and no step gets more than what is left of 540 s:

============== ======================================== ============================================== =====
step           size                                     expected (CPU rates measured here; H100 seen)  cap
============== ======================================== ============================================== =====
cuda_tests     the 2 gpu-marked tests                   9 s here (collection, SCAPE fixture), plus    130 s
                                                        Warp's first CUDA build of its kernels; H100
                                                        2026-11-27: > 75 s cold, 16 s warm
warp_labeler   2048 poses; a warm-up pass, then <= 5    CPU labeler 2048 / 51 labels/s (H100 host) =  130 s
               timed passes, none started after 20 s    40 s plus numba's first build; Warp passes
                                                        1.3 s each (1564 labels/s); H100: > 90 s
                                                        cold, 76 s warm
e2e_run        autoencoder 200 + 100 epochs; N_init     the same run at tiny sizes: 24 s here; H100:  120 s
               2000, 2 rounds of 1000, test 4000,       94 s (labels 48 s, autoencoder 6 s)
               calibration 1000, 20 epochs, 64 handled
compiled_      batch 65 536; 3 compiled forms; 139      139 x 65 536 codes x 2.3 us = 21 s at the       70 s
detector       timed calls (32 interleaved rounds of 4  CPU rate; H100: 36 s (Triton builds 21 s)
               forms, 11 eager); 48 exact codes
paper_slice    AE 20 and 120 epochs per level (after a  AE 300 level-epochs x 0.091 s = 27 s at the     80 s
               20-epoch warm-up); detector 20 000       CPU rate; H100: 48 s (labels 22 s)
               rows, 1 and 3 epochs; <= 8192 labels,
               none started after 20 s
============== ======================================== ============================================== =====

Without CUDA (or with ``--dry-run``) the same steps run at tiny sizes on the CPU (Warp on its CPU device, training
on the CPU, one thread per process: on 2 shared cores two threads per process ran the autoencoder 5x slower) in
about a minute; ``tests/test_gpu_check.py`` runs this dry run, so ``make test`` keeps the kit working.

Output: ``<out>/gpu_check.json`` (device, versions, per step: status ``ok | failed | timeout | skipped``, seconds,
cap, numbers in the median/min/max/reps form of ``bench/results.json``, sizes), ``<out>/gpu_check.md`` and
``<out>/logs/<step>.log``. Run directories and caches go to ``--work`` (default ``bench/tmp/gpu_check``).
``--merge-into bench/results.json`` runs nothing: it adds the numbers of a CUDA run's ``<out>/gpu_check.json`` to
the benchmark results as ``cuda_*`` keys and rewrites ``results.md`` (docs/gpu.md).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import json
import os
import platform
import re
import shutil
import signal
import subprocess
import sys
import time
import traceback
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import NamedTuple

from bench.context import HERE, ROOT, compose_config
from bench.timing import ratio, repeat, scalar, summarize
from neuralcol.errors import UserInputError
from neuralcol.utils.cli import report_user_errors

STEPS = ("cuda_tests", "warp_labeler", "e2e_run", "compiled_detector", "paper_slice")  # in this order
CAPS_S = {"cuda_tests": 130, "warp_labeler": 130, "e2e_run": 120, "compiled_detector": 70, "paper_slice": 80}
BUDGET_S = 540  # 9 minutes for the whole check; the caps add up to 530 s
MIN_STEP_S = 10  # a step is skipped when less than this is left of the budget
PD_TOLERANCE = 1e-6  # Warp vs CPU labels: |PD - PD_cpu| / bbox diagonal (conf/labeling/gpu.yaml, docs/labels.md)
MERGE_PREFIX = "cuda_"  # keys of a CUDA run in bench/results.json
FACT_KEYS = ("cores", "date", "machine", "torch", "command", "sections", "notes", "details")  # bench.run's facts


@dataclass(frozen=True)
class Plan:
    """The sizes of one mode: ``cuda`` (the budget table of the module docstring) or ``dry-run`` (tiny, CPU)."""

    mode: str
    threads: int | None  # OMP_NUM_THREADS of every step's processes; None: the machine's default
    accelerator: str  # Lightning accelerator of every training
    warp_device: str  # Warp device of the labeler
    warp_poses: int
    warp_reps: int
    warp_budget_s: float  # no timed Warp pass starts after this many seconds of timed passes
    ae_epochs: tuple[int, int]  # e2e_run: autoencoder epochs of level 1, level 2
    detector: dict  # e2e_run: detector.<key>=<value> overrides
    handler_inputs: int
    detector_batch: int  # compiled_detector: codes per timed call
    detector_reps: int
    detector_forms: tuple[str, ...]  # keys of bench.neural.FAST_KEYS
    n_agree: int  # codes on which the compiled forms are compared with eager
    n_exact: int  # codes of the exact reference path
    paper_ae_epochs: tuple[int, int]  # paper_slice: the two epoch counts of the autoencoder slope
    paper_det_rows: int
    paper_det_epochs: tuple[int, int]
    paper_labels: int  # at most this many labels ...
    paper_label_chunk: int  # ... in chunks of this many codes ...
    paper_label_budget_s: float  # ... none started after this many seconds

    @property
    def torch_device(self) -> str:
        return "cuda" if self.accelerator == "gpu" else "cpu"

    @property
    def labeling(self) -> tuple[str, ...]:
        """Overrides selecting the Warp labeler on this plan's device."""
        return ("labeling=gpu", f"labeling.labeler.device={self.warp_device}", "labeling.pool.progress=false")


CUDA_PLAN = Plan(
    mode="cuda", threads=None, accelerator="gpu", warp_device="cuda:0", warp_poses=2048, warp_reps=5,
    warp_budget_s=20.0, ae_epochs=(200, 100),
    detector={"n_init": 2000, "n_aug": 1000, "max_rounds": 2, "test_size": 4000, "cascade.calibration_size": 1000,
              "epochs": 20, "batch_size": 512},
    handler_inputs=64, detector_batch=65536, detector_reps=3,
    detector_forms=("compiled", "compiled_bf16", "compiled_bf16_checked"), n_agree=100_000, n_exact=48,
    paper_ae_epochs=(20, 120), paper_det_rows=20_000, paper_det_epochs=(1, 3), paper_labels=8192,
    paper_label_chunk=1024, paper_label_budget_s=20.0)
DRY_PLAN = Plan(
    mode="dry-run", threads=1, accelerator="cpu", warp_device="cpu", warp_poses=12, warp_reps=1, warp_budget_s=5.0,
    ae_epochs=(5, 2),
    detector={"n_init": 40, "n_aug": 20, "max_rounds": 1, "test_size": 60, "cascade.calibration_size": 60,
              "epochs": 2, "batch_size": 64},
    handler_inputs=4, detector_batch=256, detector_reps=1, detector_forms=("compiled",), n_agree=4096, n_exact=4,
    paper_ae_epochs=(1, 3), paper_det_rows=1000, paper_det_epochs=(1, 2), paper_labels=32, paper_label_chunk=16,
    paper_label_budget_s=5.0)


class Paths(NamedTuple):
    """Where the check reads and writes: ``out`` (JSON, Markdown, logs), ``work`` (runs, caches, step results) and
    ``data_dir`` (the folder holding ``scape/``)."""

    out: Path
    work: Path
    data_dir: Path

    @property
    def run_dir(self) -> Path:
        return self.work / "run"

    @property
    def cache_dir(self) -> Path:
        return self.work / "cache"

    def step_result(self, step: str) -> Path:
        return self.work / "steps" / f"{step}.json"

    def log(self, step: str) -> Path:
        return self.out / "logs" / f"{step}.log"


class StepOutput(NamedTuple):
    """What a step measured: ``numbers`` {key: median/min/max/reps summary}, ``info`` (sizes, devices, notes) and
    ``problem`` (None, or one line saying why the step counts as failed although it ran to the end)."""

    numbers: dict
    info: dict
    problem: str | None = None


# ---------------------------------------------------------------------------------------------- steps (children)
def scape_cfg(paths: Paths, extra: tuple[str, ...] = ()):
    """The SCAPE config of ``experiments.run`` with the check's data and cache folders, and ``extra`` overrides."""
    return compose_config(["dataset=scape", f"paths.data_dir={paths.data_dir}", f"paths.cache_dir={paths.cache_dir}",
                           *extra])


GPU_MARK = re.compile(r"^\s*(@pytest\.mark\.gpu\b|pytestmark\s*=.*\bmark\.gpu\b)", re.M)  # a test or a module


def gpu_test_files(tests_dir: Path) -> list[Path]:
    """The test files holding a ``pytest.mark.gpu`` test (decorated, or marked module-wide by ``pytestmark``)."""
    return sorted(p for p in tests_dir.glob("test_*.py") if GPU_MARK.search(p.read_text()))


def junit_counts(xml: Path) -> tuple[dict[str, int], list[str], list[str]]:
    """Counts ``{passed, failed, skipped}`` of a pytest JUnit XML file, the failed tests (``name: message``) and the
    skipped ones (``name: reason``)."""
    counts = {"passed": 0, "failed": 0, "skipped": 0}
    failed, skipped = [], []
    for case in ET.parse(xml).getroot().iter("testcase"):
        name = f"{case.get('classname')}::{case.get('name')}"
        bad = next((e for e in (case.find("failure"), case.find("error")) if e is not None), None)
        skip = case.find("skipped")
        if bad is not None:
            counts["failed"] += 1
            message = (bad.get("message") or "").strip().splitlines()
            failed.append(f"{name}: {message[0] if message else bad.tag}")
        elif skip is not None:
            counts["skipped"] += 1
            skipped.append(f"{name}: {skip.get('message')}")
        else:
            counts["passed"] += 1
    return counts, failed, skipped


def step_cuda_tests(plan: Plan, paths: Paths) -> StepOutput:
    """``pytest -m gpu`` on the gpu-marked test files, in a subprocess; on CUDA a skipped test is a problem too."""
    files = gpu_test_files(ROOT / "tests")
    xml = paths.work / "pytest_gpu.xml"
    xml.unlink(missing_ok=True)
    cmd = [sys.executable, "-m", "pytest", "-m", "gpu", "-q", "-p", "no:cacheprovider", f"--junitxml={xml}",
           *map(str, files)]
    proc = subprocess.run(cmd, cwd=ROOT, env={**os.environ, "NEURALCOL_DATA": str(paths.data_dir)})
    if not xml.is_file():
        return StepOutput({}, {"files": [str(f.relative_to(ROOT)) for f in files]},
                          f"pytest exited with {proc.returncode} and wrote no report")
    counts, failed, skipped = junit_counts(xml)
    info = {"files": [str(f.relative_to(ROOT)) for f in files], "failed": failed, "skipped": skipped,
            "pytest_exit": proc.returncode}
    problem = None
    if failed or proc.returncode != 0:
        problem = f"{counts['failed']} gpu tests failed (pytest exit {proc.returncode}): {'; '.join(failed)}"
    elif plan.mode == "cuda" and skipped:
        problem = f"{counts['skipped']} gpu tests skipped on a CUDA machine: {'; '.join(skipped)}"
    elif not sum(counts.values()):
        problem = "no gpu-marked test was collected"
    return StepOutput({k: scalar(v) for k, v in counts.items()}, info, problem)


def step_warp_labeler(plan: Plan, paths: Paths) -> StepOutput:
    """The Warp labeler against the CPU labeler on perturbed SCAPE poses (the keys of ``bench.gpu``)."""
    import numpy as np

    from bench.gpu import compare_labelers
    from neuralcol.pipeline import RunContext

    ds = RunContext(scape_cfg(paths)).dataset
    c = compare_labelers(ds.vertices.numpy().astype(np.float64), ds.faces.numpy(), plan.warp_poses,
                         plan.warp_reps, device=plan.warp_device, budget_s=plan.warp_budget_s)
    key = "gpu_labels_per_s" if c.on_cuda else "gpu_labels_per_s_cpu_device"
    rates = summarize(c.warp_labels_per_s)
    numbers = {key: rates, "gpu_ref_cpu_labels_per_s": scalar(c.ref_labels_per_s),
               "gpu_vs_cpu_labels_speedup": scalar(rates["median"] / c.ref_labels_per_s),
               "gpu_vs_cpu_max_pd_err": scalar(c.max_pd_err), "gpu_verdict_agreement": scalar(c.verdict_agreement),
               "gpu_colliding_fraction": scalar(c.n_colliding / c.n)}
    info = {"device": f"{c.device} ({c.device_name})", "poses": c.n, "colliding": c.n_colliding,
            "timed_passes": len(c.warp_seconds), "cpu_reference": "ExactLabeler, one process"}
    problem = None
    if c.verdict_agreement < 1 or c.max_pd_err > PD_TOLERANCE:
        problem = (f"Warp labels differ from the CPU labeler's: verdicts and pair counts agree on "
                   f"{c.verdict_agreement:.4f} of {c.n} poses, max |PD - PD_cpu| = {c.max_pd_err:.3g} x diagonal "
                   f"(allowed {PD_TOLERANCE})")
    return StepOutput(numbers, info, problem)


def e2e_overrides(plan: Plan, paths: Paths) -> list[str]:
    """The ``experiments.run`` command line of the short end-to-end run: SCAPE, the default method (active), the
    plan's sizes, every training on ``plan.accelerator`` and the Warp labeler on ``plan.warp_device``. The stages
    that run on the CPU only (speed/accuracy table) and the realistic set are left out."""
    level1, level2 = plan.ae_epochs
    return ["dataset=scape", "autoencoder=tiny", "detector=tiny", *plan.labeling,
            f"autoencoder.accelerator={plan.accelerator}", f"detector.accelerator={plan.accelerator}",
            f"autoencoder.level1.epochs={level1}", f"autoencoder.level2.epochs={level2}",
            *(f"detector.{k}={v}" for k, v in plan.detector.items()),
            f"handler.n_inputs={plan.handler_inputs}", "realistic.enabled=false",
            "speed_accuracy.enabled=false", "n_example_meshes=0", "resume=false",
            f"paths.data_dir={paths.data_dir}", f"paths.cache_dir={paths.cache_dir}",
            f"hydra.run.dir={paths.run_dir}"]


def step_e2e_run(plan: Plan, paths: Paths) -> StepOutput:
    """``python -m experiments.run`` with :func:`e2e_overrides`, from an empty run directory and cache (so the
    autoencoder trains), timed; its per-round numbers from ``metrics.json``."""
    for folder in (paths.run_dir, paths.cache_dir):
        shutil.rmtree(folder, ignore_errors=True)
    overrides = e2e_overrides(plan, paths)
    log = paths.work / "e2e_run.log"
    t0 = time.perf_counter()
    with log.open("w") as fh:
        proc = subprocess.run([sys.executable, "-m", "experiments.run", *overrides], cwd=ROOT, stdout=fh,
                              stderr=subprocess.STDOUT)
    seconds = time.perf_counter() - t0
    text = log.read_text(errors="replace")
    print(text[-4000:])  # the run's last lines into this step's log
    info = {"command": "python -m experiments.run " + " ".join(overrides)}
    metrics_file = paths.run_dir / "metrics.json"
    if proc.returncode != 0 or not metrics_file.is_file():
        last = text.strip().splitlines()[-1] if text.strip() else ""
        problem = f"experiments.run exited with {proc.returncode}: {last}"
        return StepOutput({"e2e_run_s": scalar(seconds)}, info, problem)
    m = json.loads(metrics_file.read_text())
    rounds = m["rounds"]
    numbers = {"e2e_run_s": scalar(seconds),
               "e2e_autoencoder_s": scalar(m["autoencoder"]["train_seconds"]),
               "e2e_label_s": scalar(sum(r["label_seconds"] for r in rounds)),
               "e2e_detector_train_s": scalar(sum(r["train_seconds"] for r in rounds)),
               "e2e_final_accuracy": scalar(rounds[-1]["accuracy"]), "e2e_final_fnr": scalar(rounds[-1]["fnr"])}
    info["rounds"] = [{k: r[k] for k in ("dataset_size", "accuracy", "fnr", "label_seconds", "train_seconds")}
                      for r in rounds]
    return StepOutput(numbers, info)


def detector_and_space(paths: Paths, plan: Plan):
    """(detector, latent space, where from): the e2e run's, or, if it did not finish, an untrained detector of the
    same configuration over the latent space it left in the cache (same architecture, same cost)."""
    from neuralcol import load_run
    from neuralcol.nn.detector import build_detector
    from neuralcol.nn.latent_space import LatentSpace
    from neuralcol.utils.config import as_dict

    if (paths.run_dir / "metrics.json").is_file():
        run = load_run(paths.run_dir)
        return run.detector, run.space, f"the e2e run ({paths.run_dir})"
    spaces = sorted(paths.cache_dir.glob("autoencoders/*/latent_space.pt"), key=lambda p: p.stat().st_mtime)
    if not spaces:
        raise UserInputError(f"{paths.run_dir}: no finished e2e run and no latent space under {paths.cache_dir}; "
                             "run the e2e_run step first (python -m bench.gpu_check --only e2e_run compiled_detector)")
    space = LatentSpace.load(spaces[-1])
    cfg = scape_cfg(paths, ("detector=tiny",))
    return build_detector(space, as_dict(cfg.detector)), space, f"untrained detector over {spaces[-1]}"


def step_compiled_detector(plan: Plan, paths: Paths) -> StepOutput:
    """The detector eager and compiled on the plan's device against the exact path on the CPU."""
    import copy

    import torch

    from bench.neural import FAST_KEYS, as_ms, exact_ms_per_sample, fast_forms
    from neuralcol.collision.backends import build_labeler

    net, space, source = detector_and_space(paths, plan)
    net = copy.deepcopy(net).to(plan.torch_device).eval()  # the copy: the latent space stays on the CPU
    z = space.sample(plan.detector_batch, generator=torch.Generator().manual_seed(0)).to(plan.torch_device)
    sync = torch.cuda.synchronize if z.device.type == "cuda" else (lambda: None)
    reps = plan.detector_reps
    with torch.no_grad():
        eager = repeat(lambda: (net(z).prob, sync()), reps * 3, warmup=2)
    labeler = build_labeler(scape_cfg(paths).labeling, space.faces.numpy(), space.rest_vertices.numpy(),
                            partition=space.partition.numpy())  # labeling=cpu: ExactLabeler, as bench/neural.py
    exact = exact_ms_per_sample(space, labeler, z[:plan.n_exact].cpu(), reps)
    eager_key = f"detector_us_per_sample_b{len(z)}"
    numbers = {eager_key: summarize(eager, 1e6 / len(z)), "exact_ms_per_sample": exact}
    numbers["neural_vs_exact_speedup"] = ratio(exact, as_ms(numbers[eager_key]))
    notes: list[str] = []
    forms = {k: FAST_KEYS[k] for k in plan.detector_forms}
    numbers.update(fast_forms(net, z, space, reps, exact, notes, forms=forms, n_agree=plan.n_agree))
    info = {"detector": source, "device": str(z.device), "batch": len(z), "exact_codes": plan.n_exact,
            "exact_path": "decode + ExactLabeler full label, one CPU core", "notes": notes}
    missing = [k for k in forms if f"neural_vs_exact_speedup_{k}" not in numbers]
    why = [n for n in notes if n.split(":")[0] in missing]  # fast_forms notes "<key>: <error>" per failed form
    return StepOutput(numbers, info, f"not compiled: {'; '.join(why)}" if missing else None)


class PaperSizes(NamedTuple):
    """The sizes of a paper-scale run that set its duration (from ``experiment=paper_<dataset>``)."""

    n_init: int
    n_aug: int
    max_rounds: int
    test_size: int
    calibration_size: int
    bootstrap_epochs: int
    update_epochs: int
    ae_level_epochs: int  # level 1 + level 2

    @classmethod
    def of(cls, cfg) -> PaperSizes:
        d = cfg.detector
        return cls(int(d.n_init), int(d.n_aug), int(d.max_rounds), int(d.test_size),
                   int(d.cascade.calibration_size) if d.cascade.enabled else 0, int(cfg.method["bootstrap"]["epochs"]),
                   int(cfg.method["update"]["epochs"]),  # ["update"]: .update is the config's dict method
                   int(cfg.autoencoder.level1.epochs) + int(cfg.autoencoder.level2.epochs))


def paper_estimate(sizes: PaperSizes, ae_epoch_s: float, det_epoch_s_per_10k: float, labels_per_s: float) -> dict:
    """Hours of a paper-scale run at the measured rates, as an upper bound: every round up to ``max_rounds`` runs
    (the elbow stops earlier), each round trains ``update_epochs`` epochs on the whole D_c. Left out: the handler's
    inputs, the realistic set, the Newton projections (method active: none) and the fixed start-up cost.

    Returns {labels, labels_h, autoencoder_h, detector_h, total_h}."""
    labels = sizes.test_size + sizes.calibration_size + sizes.n_init + sizes.max_rounds * sizes.n_aug
    rows = [sizes.n_init + r * sizes.n_aug for r in range(1, sizes.max_rounds + 1)]  # |D_c| of each round
    row_epochs = sizes.bootstrap_epochs * sizes.n_init + sizes.update_epochs * sum(rows)
    out = {"labels_h": labels / labels_per_s / 3600, "autoencoder_h": sizes.ae_level_epochs * ae_epoch_s / 3600,
           "detector_h": row_epochs / 1e4 * det_epoch_s_per_10k / 3600}
    return {"labels": labels, **out, "total_h": sum(out.values())}


def label_rate(cfg, space, n_max: int, chunk: int, budget_s: float) -> tuple[float, int, int]:
    """(labels/s, labeled, colliding) of the run's oracle (decode, then ``cfg.labeling``'s labeler through its pool)
    on U(Z) codes of ``space``, in chunks of ``chunk`` after one warm-up chunk, until ``n_max`` codes are labeled or
    ``budget_s`` seconds have passed."""
    import torch

    from neuralcol.collision.backends import build_labeler
    from neuralcol.collision.pool import LabelPool
    from neuralcol.samples.oracle import LatentOracle
    from neuralcol.utils.config import as_dict

    labeler = build_labeler(cfg.labeling, space.faces.numpy(), space.rest_vertices.numpy(),
                            partition=space.partition.numpy())
    gen = torch.Generator().manual_seed(0)
    with LabelPool(labeler, **{**as_dict(cfg.labeling.pool), "progress": False}) as pool:
        oracle = LatentOracle(space, pool)
        oracle(space.sample(chunk, generator=gen))  # kernels built, trees sized for the chunk, workers started
        n = colliding = 0
        seconds = 0.0
        while n < n_max and seconds < budget_s:
            res = oracle(space.sample(min(chunk, n_max - n), generator=gen))
            n, seconds, colliding = n + len(res.pd), seconds + res.seconds, colliding + int(res.collides.sum())
    return n / seconds, n, colliding


def step_paper_slice(plan: Plan, paths: Paths) -> StepOutput:
    """Per-unit costs of ``experiment=paper_scape`` on the plan's device and the paper run's hours from them."""
    from bench.training import ae_epoch_seconds, detector_epoch_seconds
    from neuralcol.pipeline import RunContext
    from neuralcol.utils.config import as_dict

    cfg = compose_config(["experiment=paper_scape", *plan.labeling, f"autoencoder.accelerator={plan.accelerator}",
                          f"detector.accelerator={plan.accelerator}", "autoencoder.progress_bar=false",
                          "autoencoder.val_every=1000000", f"paths.data_dir={paths.data_dir}",
                          f"paths.cache_dir={paths.cache_dir}"])
    ctx = RunContext(cfg)
    clock = [time.perf_counter()]

    def lap() -> float:
        clock.append(time.perf_counter())
        return round(clock[-1] - clock[-2], 1)

    parts = {"data_and_features": (ctx.dataset, ctx.features) and lap()}
    ae_s, space = ae_epoch_seconds(ctx.dataset, ctx.features, as_dict(cfg.autoencoder), as_dict(cfg.dataset.latent),
                                   plan.paper_ae_epochs, 1)
    parts["autoencoder"] = lap()
    det_s = detector_epoch_seconds(space, as_dict(cfg.detector), plan.paper_det_rows, plan.paper_det_epochs, 1,
                                   plan.accelerator)
    det_s = [s * 1e4 / plan.paper_det_rows for s in det_s]  # per 10 000 rows
    parts["detector"] = lap()
    rate, n, colliding = label_rate(cfg, space, plan.paper_labels, plan.paper_label_chunk, plan.paper_label_budget_s)
    parts["labels"] = lap()
    sizes = PaperSizes.of(cfg)
    est = paper_estimate(sizes, ae_s[0], det_s[0], rate)
    problem = noise = None
    if min(ae_s[0], det_s[0]) <= 0:  # timing noise larger than the work: an estimate from it would be nonsense
        noise = (f"a per-epoch slope is not positive (autoencoder {ae_s[0]:.3g} s, detector {det_s[0]:.3g} s per "
                 f"10 000 rows): raise plan.paper_ae_epochs / paper_det_epochs so the work outweighs the noise")
        # the dry run's slices are tiny and check the plumbing, not the timings: on a busy machine their noise
        # can outweigh them, which is said but fails nothing; on CUDA the estimate is the step's purpose
        problem = None if plan.mode == "dry-run" else noise
    numbers = {"paper_ae_epoch_s": summarize(ae_s), "paper_detector_epoch_s_per_10k": summarize(det_s),
               "paper_labels_per_s": scalar(rate),
               **{f"paper_scape_estimate_{k}": scalar(v) for k, v in est.items() if k != "labels"}}
    info = {"sizes": sizes._asdict(), "labels_in_estimate": est["labels"], "labeled": n, "colliding": colliding,
            "seconds_per_part": parts,
            "autoencoder": f"paper preset, slope between {plan.paper_ae_epochs[0]} and {plan.paper_ae_epochs[1]} "
                           "epochs per level (seconds per epoch of one level)",
            "detector": f"paper preset (batch {cfg.detector.batch_size}) on {plan.paper_det_rows} random rows, slope "
                        f"between {plan.paper_det_epochs[0]} and {plan.paper_det_epochs[1]} epochs",
            "labels": f"decode + {cfg.labeling.backend} labeler ({plan.warp_device}) on U(Z) codes, chunks of "
                      f"{plan.paper_label_chunk}",
            "estimate": "upper bound: all max_rounds rounds, each retraining on the whole D_c; without the "
                        "handler's inputs, the realistic set and start-up (paper_estimate in bench/gpu_check.py)"}
    if noise is not None:
        info["timing_noise"] = noise
    return StepOutput(numbers, info, problem)


STEP_FUNCS: dict[str, Callable[[Plan, Paths], StepOutput]] = {
    "cuda_tests": step_cuda_tests, "warp_labeler": step_warp_labeler, "e2e_run": step_e2e_run,
    "compiled_detector": step_compiled_detector, "paper_slice": step_paper_slice}


def run_step_here(step: str, plan: Plan, paths: Paths) -> int:
    """Run one step in this process and write its :class:`StepOutput` (or its error) to ``paths.step_result``."""
    result_file = paths.step_result(step)
    result_file.parent.mkdir(parents=True, exist_ok=True)
    try:
        out = STEP_FUNCS[step](plan, paths)
        doc = {"numbers": out.numbers, "info": out.info, "error": out.problem}
    except Exception as exc:  # recorded: the parent goes on with the next step
        traceback.print_exc()
        message = str(exc).strip().splitlines()
        doc = {"numbers": {}, "info": {}, "error": f"{type(exc).__name__}: {message[0] if message else ''}"}
    result_file.write_text(json.dumps(doc, indent=2))
    return 0


# ---------------------------------------------------------------------------------------------- the check (parent)
def log_tail(path: Path, lines: int = 3) -> str:
    """The last ``lines`` non-empty lines of a log, joined by `` | ``."""
    text = path.read_text(errors="replace").strip().splitlines() if path.is_file() else []
    return " | ".join(ln.strip() for ln in text[-lines:] if ln.strip())


def kill_group(proc: subprocess.Popen, wait_s: float = 5.0) -> None:
    """SIGKILL every process of the process group that ``proc`` leads, reap ``proc``, and wait, at most ``wait_s``
    seconds, until the rest of the group (the processes it started) is gone too."""
    deadline = time.perf_counter() + wait_s
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    with contextlib.suppress(ProcessLookupError):
        while time.perf_counter() < deadline:
            os.killpg(proc.pid, 0)  # ProcessLookupError once no process of the group is left
            time.sleep(0.05)


def run_step(step: str, plan: Plan, paths: Paths, timeout: float) -> dict:
    """Run ``step`` in a child process (its own process group, killed whole after ``timeout`` seconds); its status,
    seconds, cap, numbers, info and error."""
    result_file, log = paths.step_result(step), paths.log(step)
    result_file.unlink(missing_ok=True)
    log.parent.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "bench.gpu_check", "--step", step, "--out", str(paths.out), "--work",
           str(paths.work), "--data-dir", str(paths.data_dir), *(["--dry-run"] if plan.mode != "cuda" else [])]
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "NEURALCOL_DATA": str(paths.data_dir),
           **({"OMP_NUM_THREADS": str(plan.threads)} if plan.threads else {})}
    t0 = time.perf_counter()
    with log.open("w") as fh:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=fh, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        try:
            rc = proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            rc = None
        finally:  # the step and whatever it started and left (pytest, experiments.run, label workers)
            kill_group(proc)
    seconds = time.perf_counter() - t0
    child = json.loads(result_file.read_text()) if result_file.is_file() else {"numbers": {}, "info": {}}
    if rc is None:
        status, error = "timeout", f"stopped at its cap of {timeout:.0f} s; last lines: {log_tail(log)}"
    elif rc != 0 or not result_file.is_file():
        status, error = "failed", f"exit code {rc}: {log_tail(log)}"
    else:
        status, error = ("failed", child["error"]) if child.get("error") else ("ok", None)
    return {"status": status, "seconds": round(seconds, 1), "cap_s": round(timeout), "error": error,
            "numbers": child.get("numbers", {}), "info": child.get("info", {}),
            "log": str(log.relative_to(paths.out))}


def device_info(cuda: bool) -> dict:
    """The device, the versions of torch, Warp and Lightning, and the host."""
    import lightning
    import torch

    info = {"torch": torch.__version__, "torch_cuda": torch.version.cuda, "lightning": lightning.__version__,
            "python": platform.python_version(), "cores": os.cpu_count(),
            "machine": f"{platform.machine()} {platform.processor() or platform.system()}"}
    try:
        import warp as wp

        info["warp"], info["warp_sees_cuda"] = wp.__version__, bool(wp.is_cuda_available())
    except Exception as exc:  # recorded, not fatal: the Warp steps will fail with the same error
        info["warp"] = f"not importable ({type(exc).__name__}: {exc})"
    if cuda:
        p = torch.cuda.get_device_properties(0)
        info.update(device=p.name, capability=f"{p.major}.{p.minor}", memory_gib=round(p.total_memory / 2**30, 1),
                    multiprocessors=p.multi_processor_count)
        if shutil.which("nvidia-smi"):
            smi = subprocess.run(["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"],
                                 capture_output=True, text=True)
            info["driver"] = smi.stdout.strip().splitlines()[0] if smi.returncode == 0 and smi.stdout.strip() else None
    else:
        info["device"] = "CPU (no CUDA device: dry run at tiny sizes)"
    return info


def run_check(plan: Plan, paths: Paths, steps: tuple[str, ...], command: str) -> dict:
    """Every step of ``steps`` under its cap and the 540 s budget; writes and returns the results."""
    import torch

    t_start = time.perf_counter()
    paths.out.mkdir(parents=True, exist_ok=True)
    paths.work.mkdir(parents=True, exist_ok=True)
    results = {"date": dt.datetime.now().isoformat(timespec="seconds"), "mode": plan.mode, "command": command,
               "device": device_info(plan.mode == "cuda" and torch.cuda.is_available()), "budget_s": BUDGET_S,
               "plan": asdict(plan), "steps": {}}
    for step in steps:
        left = BUDGET_S - (time.perf_counter() - t_start)
        if left < MIN_STEP_S:
            results["steps"][step] = {"status": "skipped", "seconds": 0.0, "cap_s": CAPS_S[step], "numbers": {},
                                      "info": {}, "error": f"{left:.0f} s left of the {BUDGET_S} s budget"}
            continue
        print(f"[gpu_check] {step} (cap {min(CAPS_S[step], left):.0f} s) ...", flush=True)
        results["steps"][step] = res = run_step(step, plan, paths, min(CAPS_S[step], left))
        print(f"[gpu_check] {step}: {res['status']} in {res['seconds']} s"
              + (f" ({res['error']})" if res["error"] else ""), flush=True)
    results["seconds"] = round(time.perf_counter() - t_start, 1)
    (paths.out / "gpu_check.json").write_text(json.dumps(results, indent=2))
    write_summary(results, paths.out / "gpu_check.md")
    return results


def _fmt(x) -> str:
    return f"{x:.4g}" if isinstance(x, float) else str(x)


def write_summary(results: dict, path: Path) -> None:
    """``gpu_check.md``: device and versions, one row per step, then each step's numbers and facts."""
    d = results["device"]
    lines = ["# GPU check", "",
             f"Date {results['date']}, mode **{results['mode']}**, command `{results['command']}`, "
             f"{results['seconds']} s of the {results['budget_s']} s budget.", "",
             "Device: " + ", ".join(f"{k} {v}" for k, v in d.items()) + ".", "",
             "| step | status | seconds | cap (s) | error |", "| --- | --- | ---: | ---: | --- |"]
    for step, r in results["steps"].items():
        lines.append(f"| {step} | {r['status']} | {r['seconds']} | {r['cap_s']} | {r['error'] or ''} |")
    for step, r in results["steps"].items():
        lines += ["", f"## {step}", ""]
        if r["numbers"]:
            lines += ["| key | median | min | max | reps |", "| --- | ---: | ---: | ---: | ---: |"]
            lines += [f"| `{k}` | {v['median']:.4g} | {v['min']:.4g} | {v['max']:.4g} | {v['reps']} |"
                      for k, v in r["numbers"].items()]
            lines.append("")
        lines += [f"- {k}: {_fmt(v)}" for k, v in r["info"].items()]
    path.write_text("\n".join(lines) + "\n")


def merge_into(results_path: Path, check_path: Path) -> dict:
    """Add the numbers of a CUDA run's ``gpu_check.json`` to ``bench/results.json`` as ``cuda_<key>`` (flat median
    and details), with a section and a note, and rewrite ``results.md`` beside it."""
    from bench.markdown import write_markdown

    if not check_path.is_file():
        raise UserInputError(f"{check_path}: no such file; run `make gpu-check` on a CUDA machine and copy its "
                             "--out folder here first")
    check = json.loads(check_path.read_text())
    if check.get("mode") != "cuda":
        raise UserInputError(f"{check_path}: a {check.get('mode')} result; merge only a check run on a CUDA device")
    if not results_path.is_file():
        raise UserInputError(f"{results_path}: no such file; run `make bench` first or name the benchmark results")
    results = json.loads(results_path.read_text())
    details = dict(results.get("details", {}))
    flat = {k: v for k, v in results.items() if k not in FACT_KEYS}
    for step in check["steps"].values():
        for key, summary in step["numbers"].items():
            details[MERGE_PREFIX + key] = summary
            flat[MERGE_PREFIX + key] = summary["median"]
    d = check["device"]
    notes = {**results.get("notes", {}), "gpu_check": (
        f"`{MERGE_PREFIX}*` keys: python -m bench.gpu_check on {d.get('device')} (compute {d.get('capability')}, "
        f"{d.get('memory_gib')} GiB), torch {d.get('torch')} (CUDA {d.get('torch_cuda')}), warp {d.get('warp')}; "
        + ", ".join(f"{s} {r['status']}" for s, r in check["steps"].items()) + "; docs/gpu.md")}
    sections = {**results.get("sections", {}),
                "gpu_check": {"date": check["date"], "seconds": check["seconds"], "quick": False}}
    merged = {**flat, **{k: results[k] for k in FACT_KEYS if k in results},
              "sections": sections, "notes": notes, "details": details}
    results_path.write_text(json.dumps(merged, indent=2))
    write_markdown(merged, results_path.with_suffix(".md"))
    return merged



# ---------------------------------------------------------------------------------------------- command line
def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dry-run", action="store_true",
                        help="tiny sizes on the CPU (implied without a CUDA device)")
    parser.add_argument("--out", type=Path, default=HERE / "gpu", help="folder for gpu_check.json/.md and logs/")
    parser.add_argument("--work", type=Path, default=HERE / "tmp" / "gpu_check",
                        help="folder for the run directory, caches and step results")
    parser.add_argument("--data-dir", type=Path, default=None,
                        help="folder holding scape/ (default: paths.data_dir, i.e. $NEURALCOL_DATA or data/)")
    parser.add_argument("--only", nargs="+", choices=STEPS, help="run only these steps (in the usual order)")
    parser.add_argument("--merge-into", type=Path, default=None, metavar="RESULTS_JSON",
                        help="run nothing: add <out>/gpu_check.json (a CUDA run) to this bench/results.json")
    parser.add_argument("--step", choices=STEPS, help=argparse.SUPPRESS)  # a child: run this one step here
    return parser.parse_args(argv)


def resolve_paths(args: argparse.Namespace) -> Paths:
    """Absolute folders; the data folder must hold SCAPE."""
    data_dir = args.data_dir or Path(str(compose_config(["dataset=scape"]).paths.data_dir))
    data_dir = data_dir.resolve()
    if not (data_dir / "scape" / "1.obj").is_file():
        raise UserInputError(f"SCAPE not found at {data_dir / 'scape'}; set NEURALCOL_DATA (or --data-dir) to the "
                             "folder holding scape/")
    return Paths(args.out.resolve(), args.work.resolve(), data_dir)


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.merge_into is not None:
        merge_into(args.merge_into, args.out / "gpu_check.json")
        print(f"[gpu_check] merged {args.out / 'gpu_check.json'} into {args.merge_into}")
        return 0
    paths = resolve_paths(args)
    if args.step:
        return run_step_here(args.step, DRY_PLAN if args.dry_run else CUDA_PLAN, paths)
    import torch

    cuda = torch.cuda.is_available() and not args.dry_run
    if not cuda and not args.dry_run:
        print("[gpu_check] no CUDA device: running the CPU dry run (tiny sizes)", flush=True)
    steps = tuple(s for s in STEPS if not args.only or s in args.only)
    command = "python -m bench.gpu_check " + " ".join(argv if argv is not None else sys.argv[1:])
    results = run_check(CUDA_PLAN if cuda else DRY_PLAN, paths, steps, command.strip())
    print(f"[gpu_check] {results['seconds']} s; {paths.out / 'gpu_check.md'}")
    return 0 if all(r["status"] == "ok" for r in results["steps"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
