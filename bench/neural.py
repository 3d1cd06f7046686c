"""``neural``: the trained detector against exact labels (eager, compiled, ONNX), Newton projection onto its 0.5
level set and the collision handler, on a finished SCAPE run."""

from __future__ import annotations

import copy
import tempfile
import time
from pathlib import Path

import torch

from bench.context import ROOT, BenchContext, where
from bench.export import onnx_detector
from bench.timing import ratio, repeat, summarize

FAST_KEYS = {"compiled": "float32", "compiled_bf16": "bfloat16",
             "compiled_bf16_checked": "bfloat16_checked"}  # bench key -> FastDetector form (run.detect(fast=...))


def concat_forward(net, z_all: torch.Tensor) -> torch.Tensor:
    """The collision probability with CP applied to the concatenation [S_0, part_i], K times per sample: the
    detector's earlier forward (docs/studies/detector_inference_speed.md; ``python -m research.detector_forward``
    has more)."""
    parts, cse_in = net.inputs(z_all)
    s0 = net.cse(cse_in)
    s = net.cp(torch.cat([s0[:, None, :].expand(-1, net.n_components, -1), parts], dim=-1))[..., 0]
    return torch.sigmoid(net.mlp_c(s)[:, 0])


def as_ms(us: dict) -> dict:
    """A summary in µs -> the same summary in ms (its rep count kept)."""
    return {k: (v / 1e3 if k != "reps" else v) for k, v in us.items()}


def measure(ctx: BenchContext) -> dict:
    """Neural detector vs exact labels, Newton projection and the collision handler, with a trained detector."""
    from omegaconf import OmegaConf

    from neuralcol import load_run
    from neuralcol.active.newton import newton_project
    from neuralcol.collision.backends import build_labeler
    from neuralcol.handler.resolve import alm_settings, handle_codes
    from neuralcol.nn.fast_inference import RECHECK_BAND

    run_dir = ctx.trained_run()
    run = load_run(run_dir)
    cfg, space, net = run.cfg, run.space, run.detector
    reps, quick = ctx.reps, ctx.quick
    gen = torch.Generator().manual_seed(0)
    z = space.sample(4096, generator=gen)
    out: dict = {}
    with torch.no_grad():
        one = z[:1]
        b1 = repeat(lambda: net(one).logit, 200 if quick else 1000, warmup=20)
        b4096 = repeat(lambda: net(z).logit, reps * 3, warmup=2)
    out["detector_us_per_sample_b1"] = summarize(b1, 1e6)
    out["detector_us_per_sample_b4096"] = summarize(b4096, 1e6 / len(z))
    # side by side, interleaved: the earlier forward (CP on the concatenation, one block of 4096) and today's
    # (first CP layer split, row blocks of CollisionDetector.inference_block)
    old_t, new_t = [], []
    with torch.no_grad():
        for _ in range(reps * 10 + 2):
            old_t += repeat(lambda: concat_forward(net, z), 1, warmup=0)
            new_t += repeat(lambda: net(z).prob, 1, warmup=0)
    old_t, new_t = old_t[2:], new_t[2:]
    out["detector_before_stop23_us_per_sample_b4096"] = summarize(old_t, 1e6 / len(z))
    out["detector_forward_speedup_b4096"] = summarize([a / b for a, b in zip(old_t, new_t)])  # per interleaved pair
    # the exact reference on the same kind of samples: decode + full label, one core
    labeler = build_labeler(cfg.labeling, space.faces.numpy(), space.rest_vertices.numpy(),
                            partition=space.partition.numpy())
    n_exact = 16 if quick else 48
    out["exact_ms_per_sample"] = exact_ms_per_sample(space, labeler, z[:n_exact], reps // 2)
    out["neural_vs_exact_speedup"] = ratio(out["exact_ms_per_sample"], as_ms(out["detector_us_per_sample_b4096"]))
    fast_notes: list[str] = []
    out.update(fast_forms(net, z, space, reps, out["exact_ms_per_sample"], fast_notes))
    # the same detector exported to ONNX and run by ONNX Runtime (experiments.export), same codes and threads
    with tempfile.TemporaryDirectory() as tmp:
        ort_run = onnx_detector(run, Path(tmp))
        if ort_run is not None:
            out["detector_onnx_us_per_sample_b4096"] = summarize(repeat(lambda: ort_run(z), reps * 3, warmup=2),
                                                                 1e6 / len(z))
            out["neural_vs_exact_speedup_onnx"] = ratio(out["exact_ms_per_sample"],
                                                        as_ms(out["detector_onnx_us_per_sample_b4096"]))
    # Newton projection onto the 0.5 level set (float64, as in active learning), batched
    newton_cfg = dict(cfg.detector.newton)
    net64 = copy.deepcopy(net).double().eval()
    zn = z[:512 if quick else 1024].double()
    lo, hi = space.box_lo.double(), space.box_hi.double()
    iters = []

    def project():
        p = newton_project(lambda q: net64(q).logit, zn, lo, hi, **newton_cfg)
        iters.append(float(p.iterations.float().mean()))

    newton_s = repeat(project, max(2, reps // 2))
    out["newton_ms_per_sample"] = summarize(newton_s, 1e3 / len(zn))
    out["newton_mean_iterations"] = summarize(iters)
    # the handler on codes the detector calls colliding, batched as configured
    with torch.no_grad():
        colliding = z[net(z).logit > 0][: 256 if quick else 1024]
    # the current defaults (conf/handler/default.yaml), not the settings the run was made with
    handler_cfg = OmegaConf.load(ROOT / "conf" / "handler" / "default.yaml")
    settings = alm_settings(handler_cfg.alm)
    outer = []

    def handle():
        res = handle_codes(net, colliding, space.box_lo, space.box_hi, settings,
                           batch_size=int(handler_cfg.batch_size))
        outer.append(float(res.outer.float().mean()))

    handler_s = repeat(handle, max(2, reps // 2), warmup=0)
    out["handler_ms_per_mesh"] = summarize(handler_s, 1e3 / max(len(colliding), 1))
    out["handler_mean_outer_iterations"] = summarize(outer)
    ctx.notes["neural"] = (f"detector and latent space of {where(run_dir)}; "
                           f"exact reference: decode + full label of {n_exact} uniform codes on one core; "
                           f"detector: {torch.get_num_threads()} threads, torch and ONNX Runtime (`_onnx` keys); "
                           "FastDetector (torch.compile, `_compiled` float32, `_compiled_bf16` and "
                           "`_compiled_bf16_checked` (float32 recheck of logits within "
                           f"{RECHECK_BAND} of 0) keys; eager and all three interleaved call by call, "
                           "`_vs_eager` per call; label flips and largest "
                           f"probability change against eager on 100 000 uniform codes; {'; '.join(fast_notes)}); "
                           f"handler: {len(colliding)} codes the detector calls colliding, batch "
                           f"{int(handler_cfg.batch_size)}, conf/handler/default.yaml settings, detector only "
                           "(no verification)")
    return out


def exact_ms_per_sample(space, labeler, z: torch.Tensor, reps: int) -> dict:
    """Milliseconds per code of the exact path on the CPU: decode the (B, D) codes ``z`` and label every mesh fully
    (``labeler.label``, one core); ``max(2, reps)`` repetitions after one warm-up."""

    def exact():
        with torch.no_grad():
            verts = space.decode(z).double().numpy()
        return [labeler.label(v) for v in verts]

    return summarize(repeat(exact, max(2, reps)), 1e3 / len(z))


def fast_forms(net, z: torch.Tensor, space, reps: int, exact_ms: dict, notes: list[str],
               forms: dict[str, str] = FAST_KEYS, n_agree: int = 100_000) -> dict:
    """The detector's eager forward against FastDetector (torch.compile; ``forms``: bench key -> form, default float32
    and bfloat16) at batch ``len(z)`` on the device of ``net`` and ``z`` (on CUDA each call is synchronised),
    interleaved call by call; their agreement with eager on ``n_agree`` uniform codes; speedups over ``exact_ms``.
    Keys ``detector_{compiled,compiled_bf16,...}_*`` (``_b<len(z)>`` for the timings); a form that fails to compile
    is left out (``notes`` says why)."""
    from neuralcol.nn.fast_inference import FastDetector, bf16_is_native

    out: dict = {}
    device = "this CPU" if z.device.type == "cpu" else str(z.device)
    notes.append(f"bfloat16 {'native' if bf16_is_native(z.device) else 'emulated'} on {device}")
    sync = torch.cuda.synchronize if z.device.type == "cuda" else (lambda: None)
    batch = f"b{len(z)}"
    built = {}
    for key, form in forms.items():
        t0 = time.perf_counter()
        try:
            built[key] = FastDetector.from_form(net, form, compile=True)
        except RuntimeError as exc:
            notes.append(f"{key}: {str(exc).splitlines()[0]}")
            continue
        out[f"detector_{key}_build_s"] = summarize([time.perf_counter() - t0])
    if not built:
        return out
    timings: dict[str, list[float]] = {"eager": [], **{k: [] for k in built}}
    calls = {"eager": lambda: (net(z).prob, sync()),
             **{k: (lambda f=f: (f(z).prob, sync())) for k, f in built.items()}}
    with torch.no_grad():
        for _ in range(reps * 10 + 2):
            for key, call in calls.items():
                timings[key] += repeat(call, 1, warmup=0)
        gen = torch.Generator().manual_seed(1)
        codes = space.sample(n_agree, generator=gen).to(z.device)
        ref = torch.cat([net(c).prob for c in codes.split(4096)])
        for key, f in built.items():
            prob = f(codes).prob
            out[f"detector_{key}_label_flips"] = summarize([float(((prob > 0.5) != (ref > 0.5)).float().mean())])
            out[f"detector_{key}_max_prob_diff"] = summarize([float((prob - ref).abs().max())])
            if f.recheck_band is not None:
                out[f"detector_{key}_rechecked_fraction"] = summarize([f.rechecked_fraction])
    eager = timings.pop("eager")[2:]
    out[f"detector_eager_interleaved_us_per_sample_{batch}"] = summarize(eager, 1e6 / len(z))
    for key, t in timings.items():
        t = t[2:]
        out[f"detector_{key}_us_per_sample_{batch}"] = summarize(t, 1e6 / len(z))
        out[f"detector_{key}_vs_eager_{batch}"] = summarize([a / b for a, b in zip(eager, t)])  # per interleaved call
        out[f"neural_vs_exact_speedup_{key}"] = ratio(exact_ms, as_ms(out[f"detector_{key}_us_per_sample_{batch}"]))
    return out
