"""Pack a finished run into a small folder that loads anywhere, and check it on fresh exact labels:

    python -m experiments.pack RUN_DIR OUT_DIR [--note TEXT] [--overwrite] [--check N]
    python -m experiments.pack --check-only OUT_DIR [--check N]

``OUT_DIR`` gets the run's config (paths reset to the defaults), metrics, detector, latent space, the cascade's
calibration and round records, and ``package.json`` (source run and command, the figures it was measured at,
each file's size and SHA-256); ``neuralcol.load_run(OUT_DIR)`` loads it without the cache or the data set
(:mod:`neuralcol.api.package`). ``--check N`` (default 2000; 0: skip) labels N fresh codes from U(Z) exactly and
compares the detector's accuracy there with the documented one; the result is written to ``OUT_DIR/check.json``
and printed. The repository ships ``pretrained/scape`` this way (docs/api.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from neuralcol.api import load_run
from neuralcol.api.package import FRESH_SEED, fresh_check, pack_run
from neuralcol.utils.cli import report_user_errors
from neuralcol.utils.files import write_json_atomic


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.pack", description=__doc__.splitlines()[0])
    parser.add_argument("dirs", type=Path, nargs="+", help="RUN_DIR OUT_DIR, or OUT_DIR with --check-only")
    parser.add_argument("--note", default="", help="a sentence for package.json (what the run is)")
    parser.add_argument("--overwrite", action="store_true", help="replace the package in OUT_DIR")
    parser.add_argument("--check", type=int, default=2000, help="fresh U(Z) codes labeled exactly (0: no check)")
    parser.add_argument("--check-only", action="store_true", help="check an existing package")
    parser.add_argument("--seed", type=int, default=FRESH_SEED, help="seed of the fresh codes")
    parser.add_argument("--workers", type=int, default=None, help="label workers (default: the run's)")
    args = parser.parse_args(argv)
    if len(args.dirs) != (1 if args.check_only else 2):
        parser.error("give RUN_DIR OUT_DIR, or --check-only OUT_DIR")
    out = args.dirs[-1]
    if not args.check_only:
        manifest = pack_run(args.dirs[0], out, note=args.note, overwrite=args.overwrite)
        size = sum(f["bytes"] for f in json.loads(manifest.read_text())["files"].values())
        print(f"packed {args.dirs[0]} into {out} ({size / 2**20:.1f} MiB)", file=sys.stderr)
    if args.check > 0:
        with load_run(out, workers=args.workers, progress=True) as run:
            result = fresh_check(run, args.check, args.seed)
        write_json_atomic(out / "check.json", result)
        print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
