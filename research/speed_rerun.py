"""The speed-against-accuracy stage again on a finished run, with the code of this checkout:

    python -m research.speed_rerun RUN_DIR [--cache-dir DIR] [--set key=value ...] [--out FILE]

Reads the run's latent space, final detector (as a function of codes), its ``speed_accuracy`` settings and metrics
(``.hydra/config.yaml``, ``metrics.json``), and its U(Z) test set from the shared sample cache (found by the run's
latent-space key and the test seed), then times every method side by side in this one process as the run's last
stage does (:func:`neuralcol.stages.speed.measure_speed_accuracy`) and prints the table. ``--set`` overrides a
``speed_accuracy`` setting (e.g. ``--set n_fcl=0 --set n_meshlab=0`` to skip the slow references). Used to
measure the detector over code and mesh on codes after its batch-last fast path, against the exact verdict.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from types import SimpleNamespace

import h5py
from omegaconf import OmegaConf

from experiments.reporting.summary import speed_accuracy_table
from neuralcol.api.run import load_run
from neuralcol.nn.part_geometry import DetectorOnCodes
from neuralcol.stages.speed import measure_speed_accuracy
from neuralcol.utils.threads import pin_threads


def find_test_set(cache_dir: Path, latent_key: str, test_seed: int) -> Path:
    """The cached U(Z) test set of the latent space ``latent_key`` (``<cache>/collision/*/test_s<seed>.h5``)."""
    hits = [p.parent / f"test_s{test_seed}.h5" for p in sorted((cache_dir / "collision").glob("*/labeler.json"))
            if json.loads(p.read_text()).get("latent") == latent_key]
    hits = [h for h in hits if h.is_file()]
    if not hits:
        raise SystemExit(f"{cache_dir}: no cached test set of latent space {latent_key}; pass the run's "
                         "paths.cache_dir with --cache-dir")
    return hits[0]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m research.speed_rerun", description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--cache-dir", type=Path, default=None, help="default: the run's paths.cache_dir")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a speed_accuracy setting (repeatable)")
    parser.add_argument("--out", type=Path, default=None, help="write the measured block as JSON")
    args = parser.parse_args(argv)
    cfg = OmegaConf.load(args.run_dir / ".hydra" / "config.yaml")
    pin_threads(cfg.get("threads", 1))  # as the run's own stage: its torch thread count
    metrics = json.loads((args.run_dir / "metrics.json").read_text())
    sa_cfg = OmegaConf.merge(cfg.speed_accuracy, OmegaConf.from_dotlist(args.set))
    cache_dir = args.cache_dir or Path(str(cfg.paths.cache_dir)).expanduser()
    latent_key = metrics["autoencoder"]["cache_key"]
    path = find_test_set(cache_dir, latent_key, int(cfg.detector.test_seed))
    with h5py.File(path, "r") as h5:
        test = SimpleNamespace(z=h5["z"][:], collides=h5["collides"][:].astype(bool))
    run = load_run(args.run_dir)
    net = DetectorOnCodes(run.detector, run.space)
    print(f"{args.run_dir}: test set {path} ({len(test.z)} codes)", flush=True)
    sa = measure_speed_accuracy(run.space, net, test, sa_cfg, cfg.labeling, metrics, args.run_dir)
    print("\n".join(speed_accuracy_table(sa)))
    if args.out:
        args.out.write_text(json.dumps(sa, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
