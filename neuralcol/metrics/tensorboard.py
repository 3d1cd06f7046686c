"""TensorBoard as a researcher reads it: one run per stage, each with its own x axis.

``<run dir>/tensorboard/<stage>/``: ``autoencoder_level1`` and ``autoencoder_level2`` (losses against epoch),
``detector_<method>`` (training losses against epoch, ``test/*`` against |D_c|, and per round a few decoded
samples of the round with their exact verdict as images), ``data`` (the sub-domains mesh) and ``handling``
(the collision handler's results). ``tensorboard --logdir <run dir>/tensorboard`` lists them as separate runs.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np


def stage_logger(run_dir: str | Path, stage: str):
    """A Lightning TensorBoard logger writing to ``<run_dir>/tensorboard/<stage>/``."""
    from lightning.pytorch.loggers import TensorBoardLogger

    return TensorBoardLogger(str(run_dir), name="tensorboard", version=stage, default_hp_metric=False)


def pick_examples(collides: np.ndarray, n: int) -> np.ndarray:
    """Indices of up to ``n`` rows: colliding and free ones alternating (colliding first) while both last,
    earliest rows first."""
    c = np.asarray(collides, bool)
    pairs = itertools.zip_longest(np.flatnonzero(c).tolist(), np.flatnonzero(~c).tolist())
    return np.asarray([i for pair in pairs for i in pair if i is not None][:n], dtype=np.int64)


def log_round_examples(writer, space, rows, step: int, image_dir: Path, n: int = 4) -> int:
    """Render up to ``n`` of a round's new rows (decoded meshes) with their exact verdict and PD as TensorBoard
    images ``samples/<i>`` at ``step`` (|D_c|), also saved as PNGs in ``image_dir``. Returns the count logged.

    Args:
        writer: a ``SummaryWriter`` (``logger.experiment``).
        space: the LatentSpace (decodes the codes).
        rows: CollisionRows of the round's new samples.
        step: x value (|D_c| after the round).
        image_dir: where the PNGs go.
        n: how many.
    """
    import matplotlib.image as mpimg
    import torch

    from neuralcol.metrics.plots import depth_colors, render_mesh_png

    if len(rows.z) == 0 or n <= 0:
        return 0
    pick = pick_examples(np.asarray(rows.collides, bool), n)
    with torch.no_grad():
        verts = space.decode(torch.as_tensor(rows.z[pick])).double().numpy()
    faces = space.faces.numpy()
    for i, (j, v) in enumerate(zip(pick, verts)):
        verdict = "self-colliding" if rows.collides[j] else "collision-free"
        title = f"|D_c| = {step}: {verdict} (exact PD {float(rows.pd[j]):+.3g})"
        colors = depth_colors(np.full(len(v), 1.0 if rows.collides[j] else 0.0))
        png = render_mesh_png(Path(image_dir) / f"dc{step}_{i}.png", v, faces, colors, views=((15, -90), (15, 0)),
                              title=title, size=3.0)
        writer.add_image(f"samples/{i}", mpimg.imread(png)[..., :3], global_step=step, dataformats="HWC")
    return len(pick)
