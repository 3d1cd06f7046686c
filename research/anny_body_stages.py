"""The first stages of `dataset=anny_body` timed on one thread (generation, ACAP features of the 150 poses,
full exact label and verdict per pose over the first 30 poses) and how many of its 150 poses collide.

    python research/anny_body_stages.py [cache dir]     # default /tmp/body_cache (use an empty one to time generation)
"""
import json
import sys
import time

import numpy as np
import torch
from hydra import compose, initialize_config_dir

from neuralcol.pipeline import RunContext

CONF = str(__import__("pathlib").Path(__file__).resolve().parents[1] / "conf")

if __name__ == "__main__":
    torch.set_num_threads(1)
    cache = sys.argv[1] if len(sys.argv) > 1 else "/tmp/body_cache"
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        cfg = compose(config_name="config", overrides=["dataset=anny_body", f"paths.cache_dir={cache}"])
    ctx = RunContext(cfg)
    out = {}
    t = time.perf_counter()
    ds = ctx.dataset
    out["generate_150_s"] = time.perf_counter() - t
    t = time.perf_counter()
    _ = ctx.features
    out["acap_features_150_s"] = time.perf_counter() - t
    lab = ctx.labeler()
    v = ds.vertices.numpy().astype(np.float64)
    t = time.perf_counter()
    for x in v[:30]:
        lab.label(x)
    out["full_label_ms"] = (time.perf_counter() - t) / 30 * 1e3
    t = time.perf_counter()
    for x in v[:30]:
        lab.verdict(x)
    out["verdict_ms"] = (time.perf_counter() - t) / 30 * 1e3
    out["colliding_of_150"] = int(sum(bool(lab.verdict(x)) for x in v))
    print(json.dumps(out, indent=1))
