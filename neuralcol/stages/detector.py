"""Stage: train the neural collision detector with one method (``supv``, ``supv_bd``, ``active``).

Inputs: the latent space and an exact oracle. Shared caches under ``<cache_dir>/collision/<key>/`` (key =
latent space + labeler settings): the test set of uniform samples (one for every method and seed) and each
seed's pool of labeled uniform samples. Per run, in the run directory: ``dc.h5`` (D_c),
``checkpoints/detector.ckpt`` (the training state after the last finished round, for resuming),
``detector_rounds.json`` (the round records, rewritten after every round), ``round_detectors/round_<k>.pt`` (each
round's detector as tested), ``detector.pt`` (the final detector) and ``test_predictions.npz`` (the final detector
on the test set, :func:`predict_test_set`). See ``docs/detector.md``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import lightning as L
import numpy as np
import torch
from hydra.utils import instantiate

from neuralcol.active.rounds import Schedule
from neuralcol.errors import UserInputError
from neuralcol.lit.detector import DetectorLitModule, detector_module
from neuralcol.metrics.detection import detection_metrics
from neuralcol.metrics.tensorboard import log_round_examples
from neuralcol.nn.detector import CollisionDetector, build_detector, load_detector, net_widths, save_detector
from neuralcol.nn.inference import batched_logits
from neuralcol.nn.part_geometry import (
    SUMMARY_ROWS,
    DetectorOnCodes,
    choose_run_geometry,
    codes_featurizer,
    detector_inputs,
    load_run_geometry,
    mesh_pair_features,
    reads_summaries,
)
from neuralcol.operating import OPERATING_SETS, calibration_record, choose_set, fold_into, threshold_for
from neuralcol.rundir import RunDir
from neuralcol.samples.cache import calibration_set, label_failures, samples_cache_dir, shared_test_set
from neuralcol.samples.datamodule import CollisionDataModule
from neuralcol.samples.oracle import LatentOracle
from neuralcol.samples.realistic import RealisticRows
from neuralcol.samples.store import CollisionRows, CollisionStore, Origin
from neuralcol.utils.config import as_dict
from neuralcol.utils.files import atomic_path, write_json_atomic
from neuralcol.utils.progress import trainer_progress
from neuralcol.utils.safe_files import numpy_values_allowed, read_torch_file

METHODS = ("supv", "supv_bd", "active", "active_paper")  # method.name


def evaluate_on_test(module: DetectorLitModule, test: CollisionRows) -> dict:
    """Accuracy, FNR, FPR, ... of the detector (logit > 0 = collides) on the test rows."""
    logits = module.predict_logits(torch.as_tensor(test.z))
    return detection_metrics(logits.numpy() > 0, np.asarray(test.collides, bool))


def predict_test_set(net: CollisionDetector, test: CollisionRows, batch: int = 4096) -> dict[str, np.ndarray]:
    """The detector's output on the test rows next to their exact labels (``test_predictions.npz``).

    Args:
        net: the detector (evaluated on its device in eval mode without gradients, then left as it was).
        test: the N test rows, K sub-domains.
        batch: rows evaluated together.

    Returns:
        prob (N,) float32 collision probability, logit (N,) float32 (the metrics' prediction is logit > 0),
        pd (N,) float32, pd_sub (N, K) float32, collides (N,) bool.
    """
    logit = batched_logits(net, torch.as_tensor(np.asarray(test.z, np.float32)), batch=batch)
    return {"prob": torch.sigmoid(logit).numpy().astype(np.float32), "logit": logit.numpy().astype(np.float32),
            "pd": np.asarray(test.pd, np.float32), "pd_sub": np.asarray(test.pd_sub, np.float32),
            "collides": np.asarray(test.collides, bool)}


def inference_us(net: CollisionDetector, z: np.ndarray, batch_sizes=(1, 4096), reps: int = 5) -> dict:
    """Microseconds per sample of the detector's forward pass on the CPU at each batch size.

    A copy of ``net`` runs in eval mode without gradients in float32; per batch size one warm-up pass, then
    the median of ``reps`` timed passes. A batch larger than ``z`` repeats its rows.

    Args:
        net: the detector.
        z: (N, D) codes (the test set's), N >= 1.
        batch_sizes: batch sizes timed.
        reps: timed passes per batch size.

    A detector that reads contact summaries searches every mesh's close pairs on the CPU (milliseconds a mesh): its
    batches are timed at most ``SUMMARY_ROWS`` rows, once, and named by the rows timed.

    Returns:
        ``{"batch_<b>": µs per sample, ..., "threads": torch's CPU threads}``.
    """
    import copy

    z = np.asarray(z, np.float32)
    if z.ndim != 2 or len(z) == 0:
        raise ValueError(f"inference_us: z must be (N, D) with N >= 1, got {z.shape}")
    if reads_summaries(net):
        batch_sizes = sorted({min(int(b), SUMMARY_ROWS) for b in batch_sizes})
        reps = 1
    cpu = copy.deepcopy(net).cpu().float().eval()
    out = {}
    with torch.no_grad():
        for b in batch_sizes:
            x = torch.as_tensor(np.resize(z, (int(b), z.shape[1])))  # rows repeated cyclically up to b
            cpu(x)  # warm-up
            times = []
            for _ in range(int(reps)):
                t0 = time.perf_counter()
                cpu(x)
                times.append(time.perf_counter() - t0)
            out[f"batch_{int(b)}"] = 1e6 * float(np.median(times)) / int(b)
    out["threads"] = torch.get_num_threads()
    return out


def mesh_logits(net: CollisionDetector, space, vertices: np.ndarray, batch: int = 256) -> np.ndarray:
    """(C,) float64 logits of the detector on whole meshes (C, V, 3), as ``detect(mesh)``: their codes
    (``space.encode``) and, for a detector over code and mesh, each mesh's own pair features."""
    from neuralcol.handler.resolve import detector_logits
    from neuralcol.nn.part_geometry import code_mesh_logits

    v = torch.as_tensor(np.asarray(vertices, np.float64))
    with torch.no_grad():
        z = torch.cat([space.encode(b) for b in v.split(batch)]).float().cpu().numpy()
    if getattr(net, "geometry", None) is not None:
        return np.asarray(code_mesh_logits(net, z, np.asarray(vertices)), np.float64)
    return detector_logits(net, z)


def operating_point(net: CollisionDetector, space, oracle: LatentOracle, det: dict, latent_key: str,
                    cache_dir: str | Path, test: CollisionRows, last_round: dict,
                    store: CollisionStore | None = None, calibration_meshes=None) -> dict | None:
    """Set the final detector's decision threshold (``detector.operating_fnr``; None: the paper's p > 0.5).

    The rule lives in :mod:`neuralcol.operating`: on the labeled rows of ``detector.operating_set``
    (:func:`~neuralcol.operating.choose_set`) the largest logit threshold whose FNR is at most ``operating_fnr``
    (:func:`~neuralcol.operating.threshold_for`) is folded into MLP_c's output bias
    (:func:`~neuralcol.operating.fold_into`), so every user of the detector (handler, cascade, ``detect``) decides
    at it. The sets:

    * ``realistic_calibration``: ``calibration_meshes`` ``(vertices (C, V, 3), collides (C,))``, a realistic set
      apart from D_c drawn like the realistic test set
      (:func:`~neuralcol.samples.realistic.calibration_meshes`), judged as ``detect(mesh)`` judges a mesh;
    * ``realistic``: the realistic training meshes among D_c's validation rows (never trained on; a detector over
      code and mesh with ``geometry.realistic_rows``), judged by their own geometry;
    * ``calibration``: the cascade's calibration set, uniform codes of U(Z) labeled once and cached, apart from the
      test set and D_c;
    * ``both``: the realistic validation rows and the calibration set, the **mean** of their two FNRs at most
      ``operating_fnr`` (each set weighs the same);
    * ``auto``: ``realistic_calibration`` where ``calibration_meshes`` are given (a run with the realistic stage),
      else ``realistic`` where D_c holds such rows, else ``calibration``.

    The last round's test metrics become those at the threshold; the ones at logit 0 stay under ``at_logit_0``.

    Returns:
        ``{"operating_fnr", "operating_set", "threshold", "calibration": {n, n_colliding, fnr, fpr, accuracy at
        the threshold, fnr_ci95 (the FNR's 95 % Clopper-Pearson interval)}}`` (``both``: n and accuracy over the two
        sets pooled, fnr the mean of their two, no interval)
        or None.
    """
    target = det.get("operating_fnr")
    if target is None:
        return None
    on_codes = DetectorOnCodes(net, space)
    asked = str(det.get("operating_set", "calibration"))
    if asked not in OPERATING_SETS:
        raise UserInputError(f"detector.operating_set={asked!r}; use one of {', '.join(OPERATING_SETS)}")
    rows = None
    if store is not None and asked in ("realistic", "auto", "both"):  # only the realistic validation rows are read
        rows = store.read_rows((store.column("origin") == Origin.REALISTIC) & store.split_mask())
    found = rows is not None and rows.geometry is not None and len(rows.z) > 0
    has_meshes = calibration_meshes is not None and len(calibration_meshes[0]) > 0
    where = choose_set(asked, has_meshes, found)
    sets = []
    if where in ("realistic", "both"):
        if not found:
            raise UserInputError(f"detector.operating_set={where} needs realistic training meshes among D_c's rows "
                                 "(detector.inputs=code_and_mesh with detector.geometry.realistic_rows=true); use "
                                 "detector.operating_set=calibration")
        logit = batched_logits(net, torch.as_tensor(rows.z), torch.as_tensor(rows.geometry), batch=None).numpy()
        sets.append((logit, np.asarray(rows.collides, bool)))
    if where == "realistic_calibration":
        if not has_meshes:
            raise UserInputError("detector.operating_set=realistic_calibration needs the realistic calibration set "
                                 "(realistic.enabled=true, realistic.calibration in conf/realistic); use "
                                 "detector.operating_set=calibration")
        sets.append((mesh_logits(net, space, calibration_meshes[0]), np.asarray(calibration_meshes[1], bool)))
    if where in ("calibration", "both"):
        calib, _, _ = calibration_set(oracle, det, latent_key, cache_dir)
        sets.append((predict_test_set(on_codes, calib)["logit"], np.asarray(calib.collides, bool)))
    t = threshold_for(sets, float(target))
    fold_into(net, t)
    keys = ("accuracy", "fnr", "fpr", "balanced_accuracy", "base_rate", "majority_accuracy")
    at0 = {k: last_round[k] for k in keys if k in last_round}
    test_logit = predict_test_set(on_codes, test)["logit"]
    last_round.update(detection_metrics(test_logit > 0, np.asarray(test.collides, bool)))
    last_round["at_logit_0"] = at0
    last_round["threshold"] = t
    return {"operating_fnr": float(target), "operating_set": where, "threshold": t,
            "calibration": calibration_record(sets, t)}


def training_oracle(oracle: LatentOracle, det: dict, seed: int) -> tuple[LatentOracle, str]:
    """The oracle of D_c's rows and the file name of the seed's uniform pool (shared by every method of the seed):
    ``detector.targets.training_labels`` ``limited`` (default; needs ``pd_floor``): clearances capped at the
    targets' floor (:meth:`~neuralcol.samples.oracle.LatentOracle.for_training`), pool
    ``uniform_s<seed>_floor<pd_floor>.h5``;
    ``full``: the full labels, pool ``uniform_s<seed>.h5`` (the older pools' name)."""
    targets = det["targets"]
    kind = str(targets.get("training_labels", "limited"))
    if kind not in ("limited", "full"):
        raise UserInputError(f"detector.targets.training_labels={kind!r}; use limited or full")
    floor = targets.get("pd_floor")
    if kind == "full" or floor is None or not hasattr(oracle, "for_training"):  # (an analytic test oracle)
        return oracle, f"uniform_s{seed}.h5"
    return oracle.for_training(float(floor)), f"uniform_s{seed}_floor{float(floor):g}.h5"


class TrainedDetector(NamedTuple):
    """What :func:`train_detector` returns.

    Attributes:
        rounds: one record per round (``metrics.json``'s ``rounds``): ``round``, ``dataset_size`` (|D_c| after it),
            the U(Z) test set's ``accuracy``, ``fnr``, ``fpr``, ``balanced_accuracy``, ``base_rate`` (fractions),
            ``label_seconds``, ``train_seconds``, ``epochs``, ...; the last one at the operating point where one is
            set (its figures at logit 0 under ``at_logit_0``).
        summary: ``metrics.json``'s ``detector`` (method, stopping, test set, operating point, sizes, timings).
        net: the final detector as a function of codes (:class:`~neuralcol.nn.part_geometry.DetectorOnCodes`,
            on the CPU, its operating threshold folded into the output bias): the weights ``detector.pt`` holds,
            kept in memory so nothing in the run reads the file back.
    """

    rounds: list[dict]
    summary: dict
    net: DetectorOnCodes


def train_detector(space, oracle: LatentOracle, det_cfg, method_cfg, latent_key: str, seed: int,
                   cache_dir: str | Path, run_dir: str | Path, logger=None, round_eval=None,
                   real_rows: RealisticRows | None = None, calibration_meshes=None,
                   round_done: Callable[[str, dict], None] | None = None) -> TrainedDetector:
    """Run one method end to end (or resume it).

    ``logger``: a Lightning logger for the training (``test/*`` scalars against |D_c| and the round examples
    too), or None. ``round_eval`` (``net -> dict``, the detector on codes), if given, runs after every round's
    test (e.g. the handler's evaluation). ``real_rows``: realistic training meshes
    (:func:`~neuralcol.samples.realistic.realistic_rows`), rows of D_c in round 0 for a detector over code and
    mesh (``detector.inputs``). ``calibration_meshes``: ``(vertices, collides)`` of the realistic calibration set,
    for ``detector.operating_set: realistic_calibration`` (:func:`operating_point`). ``round_done(method, record)``:
    called after every finished round (e.g. to print a line).
    """
    det, method = as_dict(det_cfg), as_dict(method_cfg)
    name = method["name"]
    if name not in METHODS:
        raise ValueError(f"method.name={name!r}; use one of {METHODS}")
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    rd = RunDir(run_dir)
    rounds_path = rd.detector_rounds
    if rounds_path.is_file():
        done = json.loads(rounds_path.read_text())
        if done.get("finished"):  # an earlier sitting finished it: its detector.pt is the final detector
            return TrainedDetector(done["rounds"], {**done["summary"], "resumed": "already finished"},
                                   DetectorOnCodes(load_detector(rd.detector)[0], space))
    labeler = oracle.pool.labeler
    shared = samples_cache_dir(cache_dir, latent_key, labeler)
    # 1. the fixed test set (shared by every method and seed)
    t0 = time.perf_counter()
    test, test_label_s, test_labeled = shared_test_set(oracle, det, latent_key, cache_dir)
    test_s = time.perf_counter() - t0
    test_failures = label_failures(shared / f"test_s{det['test_seed']}.h5")
    # 2. D_c, the acquisition and the rounds
    pd_unit = float(labeler.cap)
    # D_c's rows get labels for training (clearances capped at the targets' floor: same clipped targets,
    # about half the cost of a free mesh) unless detector.targets.training_labels=full
    train_oracle, pool_name = training_oracle(oracle, det, seed)
    pool_path = shared / pool_name
    # the method's acquisition (method.acquisition: UniformAcquisition or ProjectedAcquisition, built by Hydra)
    acquire = instantiate(method["acquisition"])(pool_path, train_oracle, seed)
    ckpt = rd.checkpoint
    resuming = ckpt.is_file()
    if resuming:  # refused here, with the file's name, if it holds pickled objects; they are never run
        read_torch_file(ckpt, fix=f"delete it to restart the detector's training in {run_dir}, or start a new run "
                                  "directory")
    elif rd.dc.is_file():
        rd.dc.unlink()  # an earlier attempt died before its first checkpoint
    # a detector over code and mesh reads contact pairs chosen on the labeled bootstrap and the
    # realistic training meshes (saved in the run directory, so a resumed run builds the same detector)
    inputs = detector_inputs(det)
    geometry, boot = None, None
    if inputs == "code_and_mesh":
        real_rows = real_rows if bool(det["geometry"]["realistic_rows"]) else None
        if resuming:
            if not rd.geometry.is_file():
                raise UserInputError(f"{rd.geometry} is missing, so this run's detector cannot be rebuilt; delete "
                                     f"{ckpt} to restart its training, or start a new run directory")
            geometry = load_run_geometry(space, rd.geometry)
        else:
            boot = acquire.take_uniform(int(det["n_init"]))
            geometry = choose_run_geometry(space, boot.z, boot.collides, real_rows, det["geometry"], rd.geometry)
    dm = CollisionDataModule(rd.dc, space.dim, space.n_parts, int(det["batch_size"]), pd_unit,
                             float(det["targets"]["pd_clip"]), use_boundary_set=bool(method["use_boundary_set"]),
                             seed=seed, pd_floor=det["targets"].get("pd_floor"),
                             n_pairs=0 if geometry is None else geometry.n_pairs,
                             featurize=None if geometry is None else codes_featurizer(geometry, space))
    sched = {k: Schedule(**method[k]) for k in ("bootstrap", "update")}

    def on_round(rounds: list[dict], finished: bool, echo: bool = True) -> None:
        last = rounds[-1]
        write_json_atomic(rounds_path, {"finished": finished, "rounds": rounds, "summary": summary()})
        if not echo:
            return
        # the round's detector as it was just tested (the best validation epoch's weights): the handler's success
        # against |D_c| (paper Fig. 5) can then be measured afterwards (docs/studies/scape_paper_scale.md)
        rd.round_detectors.mkdir(exist_ok=True)
        save_detector(rd.round_detector(last["round"]), module.net, det, method, pd_unit)
        if logger is not None:
            for key in ("accuracy", "fnr", "fpr", "balanced_accuracy", "base_rate"):
                logger.experiment.add_scalar(f"test/{key}", last[key], global_step=last["dataset_size"])
            if int(det.get("tensorboard_examples", 0)) > 0:  # a few of the round's new samples, decoded
                rows = dm.store.read()
                rows = rows.select(rows.round == last["round"])
                log_round_examples(logger.experiment, space, rows, int(last["dataset_size"]),
                                   RunDir(run_dir).round_examples, int(det["tensorboard_examples"]))
        if round_done is not None:
            round_done(name, last)

    rounds_cb = instantiate(det["rounds"])(datamodule=dm, acquire=acquire, evaluate=lambda m: evaluate_on_test(m, test),
                                           bootstrap=sched["bootstrap"], update=sched["update"], checkpoint_path=ckpt,
                                           seed=seed, on_round=on_round, extra_eval=round_eval)

    def summary() -> dict:
        return {"method": name, "stopped_by": rounds_cb.stopped_by, "elbow_dataset_size": rounds_cb.elbow,
                "test_set": {"n": len(test.z), "seed": int(det["test_seed"]),
                             "base_rate": float(np.mean(test.collides)), "labeled_now": test_labeled,
                             "label_seconds": test_label_s, "seconds": test_s,
                             "n_label_failures": test_failures},
                "pd_unit": pd_unit, "n_parameters": int(sum(p.numel() for p in net.parameters())),
                "operating_point": operating,
                "inputs": inputs, "n_pairs": 0 if geometry is None else int(geometry.n_pairs),
                "n_vertices_read": 0 if geometry is None else int(len(geometry.vertex_index)),
                "n_realistic_rows": n_realistic,
                "training_labels": {"clearance_limit": getattr(train_oracle, "clearance_limit", None),
                                    "pool": pool_name},
                "net": {**net_widths(det["net"]), "width": float(det["net"].get("width", 1.0))}}

    n_realistic = 0  # realistic training meshes among D_c's rows (counted below)
    operating = None  # the decision threshold set after the last round (operating_point)
    L.seed_everything(seed, workers=False, verbose=False)
    net = build_detector(space, det, geometry)
    module = detector_module(net, det, float(method["w_b"]), sched["bootstrap"].lr, space=space)
    if not resuming:  # bootstrap: N_init uniform samples (round 0)
        if boot is None:
            boot = acquire.take_uniform(int(det["n_init"]))
        dm.append(boot.z, boot.pd, boot.pd_sub, boot.collides, boot.subset, 0, boot.origin)
        rounds_cb.add_label_seconds(boot.label_seconds)
        if geometry is not None and real_rows is not None and len(real_rows.z):  # real meshes as rows
            dm.append(real_rows.z, real_rows.pd, real_rows.pd_sub, real_rows.collides, real_rows.subset, 0,
                      Origin.REALISTIC, geometry=mesh_pair_features(geometry, real_rows.vertices))
    if geometry is not None:
        n_realistic = int((dm.store.read().origin == Origin.REALISTIC).sum())
    trainer = instantiate(det["trainer"])(max_epochs=rounds_cb.max_epochs,
                                          logger=logger if logger is not None else False,
                                          **trainer_progress(bool(det.get("progress_bar", False)), name, [rounds_cb]))
    with numpy_values_allowed():  # Lightning reads the checkpoint as read_torch_file does, never unpickling code
        trainer.fit(module, datamodule=dm, ckpt_path=str(ckpt) if resuming else None, weights_only=True)
    final = module.net.cpu()
    operating = operating_point(final, space, oracle, det, latent_key, cache_dir, test, rounds_cb.rounds[-1],
                                dm.store, calibration_meshes)
    save_detector(rd.detector, final, det, method, pd_unit)
    preds = rd.test_predictions
    on_codes = DetectorOnCodes(final, space)  # (the detector itself for one that reads codes only)
    with atomic_path(preds) as tmp:
        np.savez_compressed(tmp, **predict_test_set(on_codes, test))
    out = {**summary(), "resumed": resuming, "inference_us": inference_us(on_codes, test.z)}
    write_json_atomic(rounds_path, {"finished": rounds_cb.finished, "rounds": rounds_cb.rounds, "summary": out})
    dm.close()
    # as detector.pt loads: training mode (no layer depends on it; every evaluation sets eval mode itself), no grads
    final.train()
    final.zero_grad(set_to_none=True)
    return TrainedDetector(rounds_cb.rounds, out, on_codes)
