"""Export a finished run's decoder and detector as standalone modules:

    python -m experiments.export RUN_DIR --format torchscript|onnx [--out DIR] [--max-dense-vertices N]

Writes into ``DIR`` (default ``RUN_DIR/export``): ``decoder.pt`` / ``decoder.onnx`` (codes (B, D) ->
vertices (B, V, 3) float32), ``detector.pt`` / ``detector.onnx`` (codes (B, D) -> prob (B,), pd (B,) in mesh
units), ``topology.npz`` (faces (F, 3), rest_vertices (V, 3), partition (V,)) and ``manifest.json`` (box,
sizes, what each module outputs, versions, the run's metrics). Load them with ``torch.jit.load`` or an
``onnxruntime.InferenceSession`` alone; neuralcol is not needed. The decoder's ACAP inverse is a dense
``(V, V)`` float64 matrix (:mod:`neuralcol.nn.export`); above ``--max-dense-vertices`` the decoder outputs the
raw ACAP features (B, V, 9) instead and the manifest says so (vertices then need
``neuralcol.geometry.acap.ACAP(rest_vertices, faces, **manifest["acap"]).decode``). Details: docs/api.md.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from pathlib import Path

import numpy as np
import torch

from neuralcol.api import TrainedRun, load_run
from neuralcol.errors import UserInputError
from neuralcol.nn.export import DecoderExport, DetectorExport
from neuralcol.utils.cli import report_user_errors

FORMATS = ("torchscript", "onnx")
SUFFIX = {"torchscript": ".pt", "onnx": ".onnx"}


def _versions(fmt: str) -> dict:
    import neuralcol

    out = {"neuralcol": neuralcol.__version__, "torch": torch.__version__, "python": platform.python_version()}
    if fmt == "onnx":
        import onnx

        out["onnx"] = onnx.__version__
    return out


def manifest(run: TrainedRun, fmt: str, decoder_output: str, opset: int | None) -> dict:
    """The JSON-able description of an export of ``run`` (see the module docstring)."""
    space, m = run.space, run.metrics
    last = m["rounds"][-1] if m.get("rounds") else {}
    handling = m.get("handling") or {}
    decoder_out = {"vertices": f"vertices (B, {run.n_vertices}, 3) float32, centroid at the rest mesh's",
                   "features": f"raw ACAP features (B, {run.n_vertices}, 9) float32 (rotation vector, 6 entries of "
                               "S); vertices = ACAP(rest_vertices, faces, **acap).decode(features)"}[decoder_output]
    return {
        "format": fmt, "onnx_opset": opset, "run_dir": str(run.run_dir), "dataset": run.cfg.dataset.name,
        "files": {"decoder": f"decoder{SUFFIX[fmt]}", "detector": f"detector{SUFFIX[fmt]}",
                  "topology": "topology.npz"},
        "decoder": {"input": f"codes (B, {run.dim}) float32", "output": decoder_output, "output_doc": decoder_out},
        "detector": {"input": f"codes (B, {run.dim}) float32",
                     "outputs": {"prob": "(B,) float32 collision probability (collides: prob > 0.5)",
                                 "pd": "(B,) float32 the detector's PD estimate in mesh units (> 0: penetrating)"},
                     "pd_unit": run.pd_unit, "temperature": run.temperature},
        "sizes": {"latent_dim": run.dim, "n_parts": space.n_parts, "n_vertices": run.n_vertices,
                  "n_faces": len(run.faces)},
        "box": {"lo": space.box_lo.cpu().tolist(), "hi": space.box_hi.cpu().tolist()},
        "acap": dict(space.acap_kwargs),
        "versions": _versions(fmt),
        "metrics": {"detector_accuracy": last.get("accuracy"), "detector_fnr": last.get("fnr"),
                    "detector_fpr": last.get("fpr"), "dataset_size": last.get("dataset_size"),
                    "autoencoder_val_mean_vertex_error": m["autoencoder"].get("val_mean_vertex_error"),
                    "handling_success_rate": handling.get("success_rate"),
                    "handling_verified_resolved_rate": (handling.get("verified") or {}).get("resolved_rate")},
    }


def export_run(run: TrainedRun, out: Path, fmt: str, max_dense_vertices: int = 8000, opset: int = 17) -> dict:
    """Write the decoder, detector, topology and manifest of ``run`` into ``out``; returns the manifest."""
    if fmt not in FORMATS:
        raise UserInputError(f"--format {fmt}: use one of {FORMATS}")
    if fmt == "onnx":
        try:
            import onnx  # noqa: F401
        except ImportError as e:
            raise UserInputError('--format onnx needs the onnx package: pip install -e ".[export]"') from e
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    decoder_output = "vertices" if run.n_vertices <= max_dense_vertices else "features"
    modules = {"decoder": DecoderExport(run.space, decoder_output),
               "detector": DetectorExport(run.detector, run.pd_unit, run.temperature)}
    example = run.space.sample(4, generator=torch.Generator(device=run.space.box_lo.device).manual_seed(0)).cpu()
    outputs = {"decoder": ["vertices" if decoder_output == "vertices" else "features"], "detector": ["prob", "pd"]}
    for name, module in modules.items():
        path = out / f"{name}{SUFFIX[fmt]}"
        with torch.no_grad():
            if fmt == "torchscript":
                torch.jit.trace(module, example, check_trace=False).save(str(path))
            else:
                torch.onnx.export(module, (example,), str(path), dynamo=False, opset_version=opset,
                                  input_names=["codes"], output_names=outputs[name],
                                  dynamic_axes={"codes": {0: "batch"}, **{o: {0: "batch"} for o in outputs[name]}})
    np.savez(out / "topology.npz", faces=run.faces, rest_vertices=run.space.rest_vertices.cpu().numpy(),
             partition=run.space.partition.cpu().numpy())
    doc = manifest(run, fmt, decoder_output, opset if fmt == "onnx" else None)
    (out / "manifest.json").write_text(json.dumps(doc, indent=2))
    return doc


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.export", description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--format", choices=FORMATS, required=True)
    parser.add_argument("--out", type=Path, default=None, help="output directory (default: RUN_DIR/export)")
    parser.add_argument("--max-dense-vertices", type=int, default=8000,
                        help="largest V whose decoder outputs vertices (a dense V x V float64 matrix, 8 V^2 bytes); "
                             "above it the decoder outputs ACAP features")
    args = parser.parse_args(argv)
    out = args.out or args.run_dir / "export"
    with load_run(args.run_dir) as run:
        doc = export_run(run, out, args.format, args.max_dense_vertices)
    print(f"wrote {doc['files']['decoder']} (codes -> {doc['decoder']['output']}), {doc['files']['detector']} "
          f"(codes -> prob, pd), topology.npz and manifest.json to {out}", file=sys.stderr)


if __name__ == "__main__":
    main()
