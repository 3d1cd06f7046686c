"""Check a run's configuration before any work starts.

Every problem found is reported at once, each naming the key, its value and what is allowed, as one
:class:`~neuralcol.errors.UserInputError` (printed as one line by the entry points).
"""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf

from neuralcol.collision.backends import labeler_problems
from neuralcol.errors import UserInputError
from neuralcol.operating import config_problems as operating_problems
from neuralcol.samples.realistic import LABEL_CLEARANCES
from neuralcol.stages.cascade import cascade_problems
from neuralcol.stages.detector import METHODS
from neuralcol.stages.model_size import validate_model_size
from neuralcol.stages.speed import speed_accuracy_problems

SEARCH_COMMAND = "python -m experiments.model_size search"  # model_size=auto (docs/model_size.md)
POOL_EXECUTORS = ("local", "dask")  # labeling.pool.executor (neuralcol.collision.pool.EXECUTORS)


def _get(cfg, key: str):
    return OmegaConf.select(cfg, key, default=None)


def config_problems(cfg: DictConfig) -> list[str]:
    """Problems of a composed ``experiments.run`` config, as ``key=value: rule`` strings (empty: fine)."""
    problems: list[str] = []

    def need(key: str, ok, rule: str):
        value = _get(cfg, key)
        try:
            good = value is not None and ok(value)
        except TypeError:
            good = False
        if not good:
            problems.append(f"{key}={value!r}: {rule}")

    is_int = lambda v: isinstance(v, int) and not isinstance(v, bool)  # noqa: E731
    need("method.name", lambda v: v in METHODS, f"use one of {', '.join(METHODS)}")
    for key in ("detector.n_init", "detector.n_aug", "detector.test_size", "detector.epochs",
                "detector.finetune_epochs", "detector.batch_size", "detector.finetune_batch_size",
                "detector.newton.max_iter", "handler.batch_size", "autoencoder.level1.epochs",
                "autoencoder.level2.epochs", "dataset.latent.n_components",
                "detector.net.state_dim", "detector.net.hidden"):
        need(key, lambda v: is_int(v) and v >= 1, "must be an integer >= 1")
    for key in ("detector.max_rounds", "handler.n_inputs", "seed", "autoencoder_seed",
                "dataset.latent.level2_dim"):  # level2_dim 0: no level 2 (Z_all = Z_0)
        need(key, lambda v: is_int(v) and v >= 0, "must be an integer >= 0")
    if _get(cfg, "method.name") in ("active", "active_paper") and _get(cfg, "method.projected_fraction") == 0.5:
        need("detector.n_aug", lambda v: v % 2 == 0, "must be even for method=active (half of each round's "
             "samples are projected, half uniform)")
    for key in ("detector.lr", "detector.finetune_lr", "detector.newton.eps_z", "detector.newton.max_step",
                "labeling.labeler.clearance_cap", "labeling.labeler.boundary_eps", "labeling.labeler.cell_factor",
                "detector.targets.pd_clip", "detector.net.width"):
        need(key, lambda v: float(v) > 0, "must be > 0")
    need("labeling.labeler.touch_tol", lambda v: float(v) >= 0, "must be >= 0")
    if _get(cfg, "detector.inputs") is not None:  # the detector over code and mesh
        need("detector.inputs", lambda v: v in ("latent", "code_and_mesh"), "use latent or code_and_mesh")
    if _get(cfg, "realistic.label_clearance") is not None:
        need("realistic.label_clearance", lambda v: v in LABEL_CLEARANCES, f"use {' or '.join(LABEL_CLEARANCES)}")
    problems += operating_problems(lambda key: _get(cfg, key))
    if _get(cfg, "detector.inputs") == "code_and_mesh":
        for key in ("detector.geometry.per_part", "detector.geometry.select_codes", "detector.geometry.hidden"):
            need(key, lambda v: is_int(v) and v >= 1, "must be an integer >= 1")
        need("detector.geometry.min_hops", lambda v: is_int(v) and v >= 0, "must be an integer >= 0")
        for key in ("detector.geometry.radius", "detector.geometry.fold_ratio", "detector.geometry.clip"):
            need(key, lambda v: float(v) > 0, "must be > 0")
        need("detector.geometry.pool", lambda v: v in ("linear", "deepsets"), "use linear or deepsets")
        if _get(cfg, "detector.geometry.summaries") is not None:
            need("detector.geometry.summaries", lambda v: isinstance(v, bool), "use true or false")
        if _get(cfg, "detector.geometry.summary_form") is not None:
            need("detector.geometry.summary_form", lambda v: v in ("plain", "smooth"), "use plain or smooth")
        if _get(cfg, "detector.geometry.summary_vertices") is not None:
            need("detector.geometry.summary_vertices", lambda v: is_int(v) and v >= 2,
                 "must be an integer >= 2, or null for every vertex")
    threads = _get(cfg, "threads")
    if threads is not None and not (is_int(threads) and threads >= 1):  # null: the machine's default
        problems.append(f"threads={threads!r}: must be an integer >= 1 (1, the default, gives the same numbers on "
                        "every machine) or null for the machine's default")
    if _get(cfg, "labeling.labeler") is not None:  # its _target_ (labeling=<backend>) and its settings
        problems += labeler_problems(cfg.labeling)
    need("method.projected_fraction", lambda v: 0 <= float(v) <= 1, "must lie in [0, 1]")
    choices = {"detector.newton.coordinates": ("box", "raw"), "autoencoder.box_from": ("train", "all"),
               "autoencoder.level1.activation": ("tanh", "linear"), "method.start": ("dc", "uncertain"),
               "detector.loss.boundary_reduction": ("boundary", "batch"),  # nn.detector.BOUNDARY_REDUCTIONS
               "autoencoder.kind": ("bilevel", "pca"), "autoencoder.basis": ("vertex", "acap", "auto")}
    for key, allowed in choices.items():
        if _get(cfg, key) is not None:
            need(key, lambda v, allowed=allowed: v in allowed, f"use one of {', '.join(allowed)}")
    if _get(cfg, "method.candidates") is not None:
        need("method.candidates", lambda v: is_int(v) and v >= 1, "must be an integer >= 1")
    if _get(cfg, "detector.targets.pd_floor") is not None:
        need("detector.targets.pd_floor", lambda v: float(v) < 0, "must be < 0 (or null: no lower clip)")
    if _get(cfg, "detector.targets.training_labels") is not None:
        need("detector.targets.training_labels", lambda v: v in ("limited", "full"), "use limited or full")
    for key in ("autoencoder.level1.code_noise", "autoencoder.level2.code_noise", "autoencoder.level1.interp_ratio",
                "autoencoder.level2.interp_ratio", "method.update.min_steps",
                "method.bootstrap.min_steps"):
        if _get(cfg, key) is not None:
            need(key, lambda v: float(v) >= 0, "must be >= 0")
    if _get(cfg, "autoencoder.interp_t") is not None:
        need("autoencoder.interp_t", lambda v: len(v) == 2 and float(v[0]) <= float(v[1]),
             "must be [lo, hi] with lo <= hi, e.g. [0.0, 1.0]")
    need("labeling.pool.workers", lambda v: is_int(v) and v >= 0, "must be an integer >= 0 (0 or 1: in-process)")
    if _get(cfg, "labeling.data_in_process") is not None:
        need("labeling.data_in_process", lambda v: is_int(v) and v >= 0,
             "must be an integer >= 0 (the most meshes of a data set labeled in this process; 0: always the pool)")
    if _get(cfg, "labeling.pool.timeout") is not None:
        need("labeling.pool.timeout", lambda v: float(v) > 0, "must be > 0 seconds, or null for no limit")
    need("labeling.pool.max_restarts", lambda v: is_int(v) and v >= 0, "must be an integer >= 0")
    executor = _get(cfg, "labeling.pool.executor")
    if executor is not None:
        need("labeling.pool.executor", lambda v: v in POOL_EXECUTORS,
             "use one of local (this machine's worker processes), dask (a dask.distributed cluster)")
    scheduler = _get(cfg, "labeling.pool.scheduler")
    if scheduler is not None:
        if executor != "dask":
            problems.append(f"labeling.pool.scheduler={scheduler!r}: only used with labeling.pool.executor=dask "
                            f"(labeling.pool.executor={executor!r}); set both, or scheduler=null")
        else:
            need("labeling.pool.scheduler", lambda v: isinstance(v, str) and v.strip() != "",
                 "must be a dask scheduler address such as tcp://host:8786, or null for a LocalCluster")
    if executor == "dask":
        import importlib.util

        if importlib.util.find_spec("distributed") is None:
            problems.append("labeling.pool.executor='dask': dask.distributed is not installed; install it with: "
                            'pip install "dask[distributed]"')
    margin = _get(cfg, "handler.alm.margin")
    margins = _get(cfg, "handler.verify_margins")
    if margins is not None:
        m = list(margins)
        if any(float(x) <= float(margin or 0) for x in m) or m != sorted(m):
            problems.append(f"handler.verify_margins={m}: must increase and exceed handler.alm.margin={margin}")
    if _get(cfg, "handler.alm") is not None:
        from neuralcol.handler.alm import ALMSettings

        try:
            ALMSettings(**OmegaConf.to_container(cfg.handler.alm, resolve=True))
        except (TypeError, ValueError) as e:
            problems.append(f"handler.alm: {e}")
    if _get(cfg, "handler.repair") is not None:
        from neuralcol.repair.settings import repair_settings

        try:
            repair_settings(OmegaConf.to_container(cfg.handler.repair, resolve=True))
        except (TypeError, ValueError) as e:
            problems.append(f"handler.repair: {e}")
    problems += speed_accuracy_problems(_get(cfg, "speed_accuracy"))  # None (no such group): nothing to check
    problems += cascade_problems(cfg)  # detector.cascade (absent: nothing to check)
    return problems


def validate_run_config(cfg: DictConfig) -> None:
    """Raise one :class:`UserInputError` listing every problem of ``cfg`` (nothing if it is fine), then check
    ``model_size`` (:func:`~neuralcol.stages.model_size.validate_model_size`; a run takes fixed sizes only)."""
    problems = config_problems(cfg)
    if problems:
        raise UserInputError("bad configuration: " + "; ".join(problems)
                             + " (override on the command line, e.g. detector.n_aug=2000)")
    if _get(cfg, "model_size.mode") == "auto":
        raise UserInputError(f"model_size=auto: the size search is a command of its own: {SEARCH_COMMAND} "
                             "<your overrides> writes a preset of the chosen sizes; then run with model_size=<preset>")
    validate_model_size(cfg)
    searched_for = _get(cfg, "model_size.dataset")  # a preset of the size search names its data set
    if searched_for is not None and searched_for != _get(cfg, "dataset.name"):
        raise UserInputError(f"model_size: this preset holds the sizes searched for dataset={searched_for}, not "
                             f"dataset={_get(cfg, 'dataset.name')}; run {SEARCH_COMMAND} for this data set")
