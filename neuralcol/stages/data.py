"""Stage: the data set's own meshes: the ACAP round trip and their exact labels.

The paper assumes the data set's meshes are (nearly) collision-free; this stage measures it (a mesh the labeler
fails on is reported with its reason and left out of the statistics) and checks that ACAP features decode back
to the meshes (the error is a fraction of the bounding-box diagonal).
"""

from __future__ import annotations

import time

import numpy as np
import torch

from neuralcol.data.datasets import MeshDataset
from neuralcol.data.features import DatasetFeatures
from neuralcol.metrics.reconstruction import relative_vertex_error


def acap_round_trip(ds: MeshDataset, feats: DatasetFeatures) -> tuple[torch.Tensor, dict]:
    """Decode the data set's ACAP features: ``(reconstructed (N, V, 3) in the data set's dtype, metrics)``."""
    t0 = time.perf_counter()
    with torch.no_grad():
        recon = feats.acap.decode(feats.features.to(torch.float64)).to(ds.vertices.dtype)
    t_decode = time.perf_counter() - t0
    err = relative_vertex_error(recon, ds.vertices)
    return recon, {"mean_rel_error": float(err.mean.mean()), "worst_mesh_mean_rel_error": float(err.mean.max()),
                   "max_rel_error": float(err.max.max()), "decode_ms_per_mesh": 1e3 * t_decode / len(ds)}


def dataset_labels(ds: MeshDataset, pool) -> dict:
    """Exact labels of the data set's meshes through ``pool``: how many collide, their PD range, failures."""
    t0 = time.perf_counter()
    report = pool.label_report(ds.vertices.numpy().astype("float64"))
    labels = report.labels
    return {"n_colliding": int(labels.collides.sum()),
            "colliding": [ds.names[i] for i in np.nonzero(labels.collides)[0]],
            "pd_min": float(np.nanmin(labels.pd)), "pd_max": float(np.nanmax(labels.pd)),
            "seconds": time.perf_counter() - t0,
            "failed": [{"mesh": ds.names[f.index], "reason": f.reason} for f in report.failures]}
