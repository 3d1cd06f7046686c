"""Finding the runs of a report and what lies beside them; naming, ordering and grouping them.

A run is the dict of its ``metrics.json`` (with detector rounds) plus ``_path`` (its directory) and ``_seed``.
Every round's figures are read at logit 0, the decision each round is tested at and the paper's: a run with an
operating point (``detector.operating_fnr``) records its last round there and keeps logit 0's figures under
``at_logit_0``; :func:`find_runs` swaps them, and keeps the operating point's under the round's ``operating_point``
(accuracy, fnr, fpr, balanced_accuracy, threshold), so the curves do not mix two thresholds and Table 3 compares
like with like (the operating point is a row of its own).
Beside it: ``test_predictions.npz`` and ``handling/per_input.npz`` (absent in older runs; for the handler, the
older ``handling/handling.npz`` holds the same two arrays), ``.hydra/config.yaml`` for the seed and detector
sizes of older runs. In any directory given to the report, ``model_size.json``::

    {"chosen": {"n_components": 8, "level2_dim": 3, "detector_width": 1.0}}

(as ``model_size=auto`` and ``experiments.model_size`` write it). ``chosen`` holds any non-empty subset of the
keys of :data:`CHOSEN_KEYS`; every configuration whose values equal all given ones is marked.
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from neuralcol.errors import UserInputError

ROOT = Path(__file__).resolve().parents[2]
METHOD_ORDER = ("supv", "supv_bd", "active_paper", "active")
LABELS = {"supv": "Supv", "supv_bd": "Supv+bd", "active_paper": "Active+bd (paper's text)",
          "active": "Active+bd (ours)"}
CHOSEN_KEYS = ("dataset", "method", "n_components", "level2_dim", "state_dim", "hidden", "detector_width",
               "n_parameters")
SIZE_KEYS = ("n_components", "level2_dim", "state_dim", "hidden", "detector_width")
# the paper's Table 3 (accuracy and FNR of each method at its final data set size, and the equivalent Supv+bd size
# of Active+bd), for the data sets it reports; active_paper and neuralcol's active are both compared with Active+bd
PAPER_TABLE3 = {
    "scape": {"final_size": 5.5e5, "equivalent_size": 6.63e5, "supv": (0.9181, 0.06914),
              "supv_bd": (0.9282, 0.05576), "active": (0.9383, 0.05151)},
    "swing": {"final_size": 4.5e4, "equivalent_size": 7.64e4, "supv": (0.9460, 0.01969),
              "supv_bd": (0.9609, 0.01766), "active": (0.9638, 0.01485)},
    "jump": {"final_size": 4.5e4, "equivalent_size": 7.02e4, "supv": (0.9347, 0.02713),
             "supv_bd": (0.9500, 0.02644), "active": (0.9552, 0.02573)},
    "skirt": {"final_size": 4e4, "equivalent_size": 7.71e4, "supv": (0.9660, 0.02056),
              "supv_bd": (0.9795, 0.01956), "active": (0.9817, 0.01808)},
    "hand": {"final_size": 5.5e5, "equivalent_size": 7.30e5, "supv": (0.9558, 0.03727),
             "supv_bd": (0.9650, 0.03652), "active": (0.9692, 0.03582)},
}


def paper_figures(dataset_name: str, method_name: str) -> tuple[float, float] | None:
    """The paper's (accuracy, FNR) for a method on a data set of its Table 3, or None."""
    table = PAPER_TABLE3.get(dataset_name)
    if table is None:
        return None
    return table.get("active" if method_name == "active_paper" else method_name)


BENCH_KEYS = ("detector_us_per_sample_b1", "detector_us_per_sample_b4096", "exact_ms_per_sample",
              "neural_vs_exact_speedup")


# ---------------------------------------------------------------------------------------------- runs
def find_runs(dirs: list[Path]) -> list[dict]:
    """metrics.json files below ``dirs`` that hold detector rounds, as dicts (with ``_path`` and ``_seed``)."""
    runs = []
    for d in dirs:
        if not d.exists():
            raise UserInputError(f"{d}: no such directory")
        for path in sorted(d.rglob("metrics.json")):
            m = json.loads(path.read_text())
            if m.get("rounds"):
                m["rounds"] = [at_logit_0(r) for r in m["rounds"]]
                m["_path"] = str(path.parent)
                m["_seed"] = _seed(m)
                runs.append(m)
    if not runs:
        raise UserInputError(f"no metrics.json with detector rounds below {[str(d) for d in dirs]}; run "
                             "`python -m experiments.run` first")
    return runs


def at_logit_0(round_record: dict) -> dict:
    """A round's record with its figures at logit 0 (see the module's docstring); unchanged without an operating
    point."""
    at0 = round_record.get("at_logit_0")
    if not at0:
        return round_record
    op = {k: round_record[k] for k in ("accuracy", "fnr", "fpr", "balanced_accuracy") if k in round_record}
    out = {k: v for k, v in round_record.items() if k not in ("at_logit_0", "threshold")}
    return {**out, **at0, "operating_point": {**op, "threshold": round_record.get("threshold")}}


def _seed(run: dict) -> int | None:
    cfg = Path(run["_path"]) / ".hydra" / "config.yaml"
    if cfg.is_file():
        for line in cfg.read_text().splitlines():
            if line.startswith("seed:"):
                return int(line.split(":", 1)[1])
    return run.get("seed")


def dataset(run: dict) -> str:
    return run["dataset"]["name"]


def method(run: dict) -> str:
    return run["detector"]["method"]


def by_dataset(runs: list[dict]) -> dict[str, list[dict]]:
    """``{data set: its runs}``, data sets sorted by name, runs in their given order."""
    out = defaultdict(list)
    for run in runs:
        out[dataset(run)].append(run)
    return {ds: out[ds] for ds in sorted(out)}


def detector_parameters(run: dict) -> int | None:
    """The run's detector parameter count (metrics.json, or counted from ``detector.pt`` for older runs)."""
    n = run["detector"].get("n_parameters")
    if n is None and (Path(run["_path"]) / "detector.pt").is_file():
        from neuralcol.nn.detector import load_detector

        net, _ = load_detector(Path(run["_path"]) / "detector.pt")
        n = int(sum(p.numel() for p in net.parameters()))
    return n


def size_config(run: dict) -> dict:
    """The run's sizes: n_components K, level2_dim L (from ``latent``), the detector's state_dim, hidden and width
    multiplier (from ``metrics["detector"]["net"]``, else the run's ``.hydra/config.yaml``; None when neither has
    them)."""
    k = int(run["latent"]["n_parts"])
    net = run["detector"].get("net")
    cfg_path = Path(run["_path"]) / ".hydra" / "config.yaml"
    if net is None and cfg_path.is_file():
        from omegaconf import OmegaConf

        net = OmegaConf.to_container(OmegaConf.load(cfg_path).detector.net, resolve=True)
    net = net or {}
    return {"n_components": k, "level2_dim": int(run["latent"]["dim"]) // k - 1,
            "state_dim": net.get("state_dim"), "hidden": net.get("hidden"),
            "detector_width": float(net.get("width", 1.0))}  # detector.net.width (1 in runs older than it)


def config_label(cfg: dict) -> str:
    """``K8 L3 64/128``: sub-domains, level-2 size, detector state width / hidden width."""
    return f"K{cfg['n_components']} L{cfg['level2_dim']} {cfg['state_dim']}/{cfg['hidden']}"


# ------------------------------------------------------------------------------------------- methods
def method_rank(name: str) -> int:
    """Position of a method in :data:`METHOD_ORDER` (after all of them when it is not there)."""
    return METHOD_ORDER.index(name) if name in METHOD_ORDER else len(METHOD_ORDER)


def method_order(name: str) -> tuple[int, str]:
    """Sort key of a method name, or of a label that starts with one (``"active (K8 L3 64/128)"``)."""
    return method_rank(name.split(" (")[0]), name


def ordered_methods(names) -> list[str]:
    """The distinct method names in report order: :data:`METHOD_ORDER`, then the others by name."""
    return sorted(set(names), key=method_order)


def label(name: str) -> str:
    """A method's name in the tables and legends (``Active+bd (ours)``)."""
    return LABELS.get(name, name)


# -------------------------------------------------------------------------------------- side files
def load_chosen(dirs: list[Path]) -> tuple[dict | None, Path | None]:
    """The ``chosen`` entry of the first ``model_size.json`` directly in ``dirs`` (None, None if there is none).

    Raises:
        UserInputError: the file is not JSON, has no ``chosen`` object, or names an unknown key.
    """
    for d in dirs:
        path = Path(d) / "model_size.json"
        if not path.is_file():
            continue
        try:
            chosen = json.loads(path.read_text()).get("chosen")
        except (json.JSONDecodeError, AttributeError) as e:
            raise UserInputError(f"{path}: not a JSON object ({e}); write "
                                 '{"chosen": {"n_components": K, "level2_dim": L, "state_dim": S, "hidden": H}}') from e
        if not isinstance(chosen, dict) or not chosen:
            raise UserInputError(f"{path}: needs a non-empty object under \"chosen\", e.g. "
                                 '{"chosen": {"n_components": 8, "level2_dim": 3, "state_dim": 64, "hidden": 128}}')
        unknown = sorted(set(chosen) - set(CHOSEN_KEYS))
        if unknown:
            raise UserInputError(f"{path}: unknown key(s) {unknown} under \"chosen\"; use some of {list(CHOSEN_KEYS)}")
        return chosen, path
    return None, None


def load_bench(path: Path | None) -> dict | None:
    """Benchmark results for the detection-time figures (default ``bench/results.json``; None without them)."""
    path = path or ROOT / "bench" / "results.json"
    if not path.is_file():
        return None
    b = json.loads(path.read_text())
    return b if all(k in b for k in BENCH_KEYS) else None


def _load_npz(path: Path, keys: tuple[str, ...]) -> dict | None:
    if not path.is_file():
        return None
    with np.load(path) as f:
        if not all(k in f for k in keys):
            return None
        return {k: f[k] for k in f.files}


def load_predictions(run: dict) -> dict | None:
    """``test_predictions.npz`` of the run (None when the run predates it)."""
    return _load_npz(Path(run["_path"]) / "test_predictions.npz", ("prob", "pd", "pd_sub", "collides"))


def load_handler_inputs(run: dict) -> dict | None:
    """pd_before and success per handler input: ``handling/per_input.npz``, else the older ``handling.npz``."""
    h = Path(run["_path"]) / "handling"
    return _load_npz(h / "per_input.npz", ("pd_before", "success")) or \
        _load_npz(h / "handling.npz", ("pd_before", "success"))
