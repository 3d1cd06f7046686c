"""``export``: the detector exported by ``experiments.export`` (TorchScript; ONNX Runtime when installed) next to
the live module, µs per sample at batch 4096, on the same codes."""

from __future__ import annotations

import tempfile
from pathlib import Path

import torch

from bench.context import BenchContext, where
from bench.timing import repeat, summarize


def onnx_detector(run, tmp: Path):
    """The run's detector exported to ONNX under ``tmp`` and loaded into ONNX Runtime with torch's thread count:
    a callable codes -> outputs, or None when onnx / onnxruntime are not installed."""
    try:
        import onnx  # noqa: F401
        import onnxruntime as ort
    except ImportError:
        return None
    from experiments.export import export_run

    export_run(run, tmp / "onnx", "onnx")
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = torch.get_num_threads()
    sess = ort.InferenceSession(str(tmp / "onnx" / "detector.onnx"), opts)
    return lambda z: sess.run(None, {"codes": z.numpy()})


def measure(ctx: BenchContext) -> dict:
    """The detector exported by ``experiments.export`` (TorchScript; ONNX Runtime when installed) next to the live
    module, µs per sample at batch 4096, on the same codes."""
    from experiments.export import export_run
    from neuralcol import load_run

    run_dir = ctx.trained_run()
    run = load_run(run_dir)
    z = run.space.sample(4096, generator=torch.Generator().manual_seed(0))
    reps = ctx.reps * 3
    out: dict = {}
    with torch.no_grad():
        out["export_live_detector_us_b4096"] = summarize(repeat(lambda: run.detector(z), reps, warmup=2),
                                                         1e6 / len(z))
    with tempfile.TemporaryDirectory() as tmp:
        export_run(run, Path(tmp) / "torchscript", "torchscript")
        module = torch.jit.load(str(Path(tmp) / "torchscript" / "detector.pt"))
        with torch.no_grad():
            out["export_torchscript_detector_us_b4096"] = summarize(repeat(lambda: module(z), reps, warmup=2),
                                                                    1e6 / len(z))
        ort_run = onnx_detector(run, Path(tmp))
        if ort_run is not None:
            out["export_onnx_detector_us_b4096"] = summarize(repeat(lambda: ort_run(z), reps, warmup=2), 1e6 / len(z))
    ctx.notes["export"] = (f"detector of {where(run_dir)} (outputs prob and the PD estimate), 4096 uniform codes per "
                           f"call, {torch.get_num_threads()} threads (ONNX Runtime intra-op threads the same)"
                           + ("" if ort_run is not None else "; onnxruntime not installed: ONNX not measured"))
    run.close()
    return out
