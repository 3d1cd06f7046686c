"""Labels per second of the exact oracle (decode in this process + LabelPool(workers=2)) on 256 U(Z) codes of a
latent space, for the neuralcol checkout on ``PYTHONPATH``; run it alternately on two checkouts for a side by side:

    for d in /tmp/before29 .; do PYTHONPATH=$d OMP_NUM_THREADS=1 python research/oracle_throughput.py \\
        .cache/autoencoders/<key>/latent_space.pt; done

Prints one JSON line: the checkout, labels per second, and the sum of the PD values (equal labels, equal sum).
"""

from __future__ import annotations

import json
import sys
import time

if __name__ == "__main__":
    import numpy as np
    import torch

    import neuralcol
    from neuralcol.collision.labeler import ExactLabeler
    from neuralcol.collision.pool import LabelPool
    from neuralcol.nn.latent_space import LatentSpace
    from neuralcol.samples.oracle import LatentOracle

    torch.set_num_threads(1)
    space = LatentSpace.load(sys.argv[1])
    z = space.sample(256, generator=torch.Generator().manual_seed(1))
    labeler = ExactLabeler(space.faces.numpy(), space.rest_vertices.numpy(), partition=space.partition.numpy())
    with LabelPool(labeler, workers=2) as pool:
        oracle = LatentOracle(space, pool)
        oracle(z[:16])  # start the workers outside the timing
        t0 = time.perf_counter()
        labels = oracle(z)
        seconds = time.perf_counter() - t0
    print(json.dumps({"checkout": neuralcol.__file__, "labels_per_s": len(z) / seconds,
                      "pd_sum": float(np.nansum(labels.pd))}))
