"""Draw a run's TensorBoard scalars into one PNG, without a browser or a TensorBoard server:

    python -m experiments.tb_plot LOGDIR [--out FILE] [--tags PREFIX...]

LOGDIR is a run's ``tensorboard/`` folder (one sub-folder per stage, neuralcol/metrics/tensorboard.py) or one stage
folder. One panel per (stage, tag) whose tag starts with one of ``--tags`` (default: every tag but Lightning's
``epoch``), values against the step the tag was logged at: the epoch for the autoencoder's losses, the training
step for the detector's ``train/*`` and ``val/*``, |D_c| for ``test/*``, ``projection/*`` and ``handling/*``.
Default FILE: ``LOGDIR/scalars.png``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from neuralcol.errors import UserInputError
from neuralcol.utils.cli import report_user_errors


def read_scalars(logdir: str | Path) -> dict[str, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Every scalar series of the event files under ``logdir``.

    Returns:
        ``{stage: {tag: (steps (n,) int64, values (n,) float64)}}``, stages in name order; a stage is a folder
        holding event files (``logdir`` itself if it holds them, named by its own name).

    Raises:
        UserInputError: ``logdir`` holds no event files.
    """
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    root = Path(logdir)
    folders = sorted({p.parent for p in root.rglob("events.out.tfevents.*")})
    if not folders:
        raise UserInputError(f"{root}: no TensorBoard event files (events.out.tfevents.*); give a run's "
                             "tensorboard/ folder")
    out = {}
    for folder in folders:
        acc = EventAccumulator(str(folder), size_guidance={"scalars": 0})
        acc.Reload()
        name = folder.relative_to(root).as_posix() if folder != root else root.name
        out[name] = {tag: (np.array([e.step for e in acc.Scalars(tag)], dtype=np.int64),
                           np.array([e.value for e in acc.Scalars(tag)], dtype=np.float64))
                     for tag in acc.Tags()["scalars"]}
    return out


def plot_scalars(scalars: dict, out: str | Path, tags: list[str] | None = None, ncols: int = 4) -> list[str]:
    """One panel per (stage, tag) of ``scalars`` (as :func:`read_scalars` returns) whose tag starts with one of
    ``tags`` (None: all but ``epoch``), saved as a PNG at ``out``.

    Returns:
        The panel titles ``"<stage>: <tag>"``, in drawing order.

    Raises:
        UserInputError: no tag matches.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [(stage, tag) for stage, series in scalars.items() for tag in sorted(series)
              if (tag.startswith(tuple(tags)) if tags else tag != "epoch")]
    if not panels:
        have = sorted({t for series in scalars.values() for t in series})
        raise UserInputError(f"--tags {tags}: no scalar tag starts with these; the event files hold {have}")
    ncols = min(ncols, len(panels))
    nrows = math.ceil(len(panels) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.2 * ncols, 2.4 * nrows), squeeze=False)
    for ax, (stage, tag) in zip(axes.flat, panels):
        steps, values = scalars[stage][tag]
        ax.plot(steps, values, marker="o" if len(steps) < 12 else None, ms=3)
        ax.set_title(f"{stage}: {tag}", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(panels):]:
        ax.axis("off")
    fig.tight_layout()
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=80)
    plt.close(fig)
    return [f"{stage}: {tag}" for stage, tag in panels]


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.tb_plot", description=__doc__.splitlines()[0])
    parser.add_argument("logdir", type=Path)
    parser.add_argument("--out", type=Path, default=None, help="PNG file (default: LOGDIR/scalars.png)")
    parser.add_argument("--tags", nargs="+", default=None, metavar="PREFIX",
                        help="draw only tags starting with these, e.g. test/ val/loss (default: all)")
    args = parser.parse_args(argv)
    out = args.out if args.out is not None else args.logdir / "scalars.png"
    panels = plot_scalars(read_scalars(args.logdir), out, args.tags)
    print(f"{len(panels)} panels -> {out}")


if __name__ == "__main__":
    main()
