"""Where a latent space's labeled samples are cached, and the shared test set.

``<cache_dir>/collision/<key>/`` (key = the latent space's cache key and the labeler's settings) holds the
test set of uniform samples (``test_s<seed>.h5``, one for every method and seed), each seed's pool of labeled
uniform samples (``uniform_s<seed>.h5``) and the realistic sets' caches.
"""

from __future__ import annotations

from pathlib import Path

from neuralcol.rundir import CacheDir
from neuralcol.samples.oracle import LatentOracle
from neuralcol.samples.uniform import labeled_uniform_rows
from neuralcol.utils.config import as_dict
from neuralcol.utils.files import write_json_atomic
from neuralcol.utils.hashing import settings_key


def samples_cache_dir(cache_dir: str | Path, latent_key: str, labeler) -> Path:
    """``<cache>/collision/<key>``: key of the latent space, of the labeler's settings and of its definition's
    version (``label_version``: labels cached by an older definition are never reused)."""
    settings = {"latent": latent_key, "eps": float(labeler.eps), "cap": float(labeler.cap),
                "tau": float(labeler.tau), "n_parts": int(labeler.n_parts),
                "version": int(getattr(labeler, "label_version", 1))}
    kind = getattr(labeler, "label_kind", "exact")
    if kind != "exact":  # another definition of the labels (e.g. python-fcl's): never mixed with ours
        settings["labels"] = str(kind)
    key = settings_key(settings)
    folder = CacheDir(cache_dir).samples(key)
    folder.mkdir(parents=True, exist_ok=True)
    if not (folder / "labeler.json").is_file():
        write_json_atomic(folder / "labeler.json", settings)
    return folder


def shared_test_set(oracle: LatentOracle, det_cfg, latent_key: str, cache_dir: str | Path):
    """The fixed test set of uniform samples (labeled once, cached, shared by every method and seed):
    (rows, seconds spent labeling now, rows labeled now)."""
    det = as_dict(det_cfg)
    shared = samples_cache_dir(cache_dir, latent_key, oracle.pool.labeler)
    return labeled_uniform_rows(shared / f"test_s{det['test_seed']}.h5", oracle, int(det["test_size"]),
                                int(det["test_seed"]), desc="labeling the test set")


def calibration_set(oracle: LatentOracle, det_cfg, latent_key: str, cache_dir: str | Path):
    """The certified cascade's calibration set (``detector.cascade``: ``calibration_size`` uniform codes of their own
    seed, apart from the test set and D_c), labeled once, cached and shared by every method and seed like the test
    set; the operating point may be set on it too: (rows, seconds spent labeling now, rows labeled now)."""
    c = as_dict(det_cfg)["cascade"]
    shared = samples_cache_dir(cache_dir, latent_key, oracle.pool.labeler)
    seed = int(c["calibration_seed"])
    return labeled_uniform_rows(shared / f"calibration_s{seed}.h5", oracle, int(c["calibration_size"]), seed,
                                desc="labeling the cascade's calibration set")


def label_failures(path: Path) -> int:
    """Codes of a cached uniform-sample store the exact labeler failed on (dropped and replaced; 0 if none)."""
    import h5py
    from filelock import FileLock

    with FileLock(str(path) + ".lock"), h5py.File(path, "r") as h5:  # the lock uniform_rows writes under
        return int(h5.attrs.get("n_label_failures", 0))
