"""A detector's logits on many inputs: batched, in eval mode, without gradients, its training mode restored.

Every place that asks a trained detector for its verdict on a set of rows (the test set, the calibration set, the
acquisition's candidates, the realistic meshes, the operating point) goes through :func:`batched_logits`, so the
batching, the mode and the device handling are written once.
"""

from __future__ import annotations

import torch
from torch import nn


def batched_logits(net: nn.Module, *inputs: torch.Tensor, batch: int | None = 4096,
                   mode_of: nn.Module | None = None) -> torch.Tensor:
    """``net(*rows).logit`` for the rows of ``inputs``, ``batch`` rows at a time, concatenated on the CPU.

    Args:
        net: a module returning an object with a ``logit`` (B,) field (a detector, or a detector on codes).
        inputs: tensors with the same first dimension N (codes (N, D), and for a detector over code and mesh the
            rows' pair features (N, P, 3)); each batch is moved to the device of ``net``'s parameters.
        batch: rows per forward pass (None: all N in one pass). The split changes float round-off, so each caller
            keeps the batch it always used.
        mode_of: the module whose training mode is set to eval during the passes and restored afterwards (default
            ``net``; e.g. the inner detector when ``net`` wraps it).

    Returns:
        (N,) logits on the CPU in ``net``'s output dtype; ``torch.zeros(0)`` when N is 0.
    """
    module = net if mode_of is None else mode_of
    n = len(inputs[0])
    if n == 0:
        return torch.zeros(0)
    param = next(net.parameters(), None)
    move = (lambda x: x) if param is None else (lambda x: x.to(param.device))  # noqa: E731
    step = n if batch is None else int(batch)
    was_training = module.training
    module.eval()
    try:
        with torch.no_grad():
            out = [net(*(move(x[i:i + step]) for x in inputs)).logit.cpu() for i in range(0, n, step)]
    finally:
        module.train(was_training)
    return torch.cat(out)
