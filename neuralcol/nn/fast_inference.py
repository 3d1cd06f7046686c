"""Fast inference for a trained collision detector: ``torch.compile`` (inductor) and an optional bfloat16 copy.

The detector's eager float32 forward (``CollisionDetector.forward``) stays the reference and the only path
training, the Newton projector, the handler and the reported metrics use. :class:`FastDetector` is for bulk
inference after training (screening many codes, the inference benchmark):

* ``compile=True``: the block forward is compiled for fixed block shapes (inductor fuses the bias, CELU and
  tanh element-wise work and vectorises the exponentials); the batch is cut into blocks of ``block`` rows and
  the last block is padded to the next power of two (at least 16 rows), so at most a handful of shapes are ever
  compiled, each once. Same outputs as eager to float32
  round-off (tests/test_fast_inference.py).
* ``dtype="bfloat16"``: a bfloat16 copy of the weights (matrix products in bfloat16, outputs returned in
  float32). On CPUs with native bfloat16 dot products (AVX512-BF16, AMX) the matrix products run several times
  faster; the probabilities move by up to ~0.02 and a small share of predicted labels flips
  (docs/studies/detector_inference_speed.md measures both on SCAPE's test sets). Elsewhere bfloat16 is emulated
  and slower: :func:`bf16_is_native` says which.

Inference only: no gradients flow through a :class:`FastDetector`.
"""

from __future__ import annotations

import copy

import torch

from neuralcol.nn.detector import CollisionDetector, DetectorOutput
from neuralcol.nn.part_geometry import reads_summaries, vertex_decoder

DTYPES = {"float32": torch.float32, "bfloat16": torch.bfloat16}
MIN_PADDED_ROWS = 16  # the smallest compiled block
RECHECK_BAND = 0.5  # logit band recomputed in float32 by the "bfloat16_checked" form (> 2x the largest bfloat16
# logit error measured on SCAPE's detectors, 0.22; no test prediction flips: docs/studies/detector_inference_speed.md)
FORMS = {"float32": ("float32", None), "bfloat16": ("bfloat16", None),
         "bfloat16_checked": ("bfloat16", RECHECK_BAND)}  # name -> (dtype, recheck_band): run.detect(fast=name)
CPU_BLOCKS = {"float32": 1024, "bfloat16": 2048}  # default rows per compiled call on the CPU
CPU_BLOCKS_MESH = 256  # ... for a detector that reads the mesh too (128-512 alike compiled, 1024: 1.5x slower)
RECOMPILE_LIMIT = 64  # compiled variants per code object (dynamo's default: 8)


def bf16_is_native(device: torch.device | str = "cpu") -> bool:
    """Whether bfloat16 matrix products run natively on ``device`` (CUDA: compute capability >= 8.0; CPU:
    oneDNN's bfloat16 support, i.e. AVX512-BF16 or AMX)."""
    device = torch.device(device)
    if device.type == "cuda":
        return torch.cuda.is_available() and torch.cuda.get_device_capability(device)[0] >= 8
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


class FastDetector:
    """An inference-only copy of ``net``: callable on codes (B, D) -> :class:`DetectorOutput` in float32.

    Args:
        net: the trained detector (not modified; its weights are copied).
        dtype: ``"float32"`` (same outputs as ``net``) or ``"bfloat16"`` (faster where native, see the module).
        compile: compile the block forward with ``torch.compile`` (needs a C++ compiler on the CPU, Triton on
            CUDA); False runs the copy eagerly (for comparison, or where no compiler exists).
        block: rows per compiled call (default on the CPU: 1024 in float32, 2048 in bfloat16, the fastest of
            256-4096 on a 2-core AVX-512 machine, ``python -m research.detector_forward RUN --fast-blocks ...``,
            docs/studies/detector_inference_speed.md; a detector that reads the mesh too: 256; on CUDA 65536).
        recheck_band: bfloat16 only: rows whose bfloat16 logit lies within this distance of 0 are recomputed by a
            float32 copy (compiled like this one), so their outputs, and every predicted label whose bfloat16
            logit error is below the band, are float32's. None: no recheck. ``rechecked_fraction`` holds the
            share of rows the last call recomputed.

    Raises:
        ValueError: an unknown ``dtype``, a block size < 1 or a negative ``recheck_band``.
        RuntimeError: ``compile=True`` and compiling fails (the message says how to go on without it).
    """

    def __init__(self, net: CollisionDetector, dtype: str = "float32", compile: bool = True,
                 block: int | None = None, recheck_band: float | None = None):
        if dtype not in DTYPES:
            raise ValueError(f"dtype={dtype!r}; use one of {sorted(DTYPES)}")
        device = next(net.parameters()).device
        if reads_summaries(net):
            compile = False  # contact summaries search each mesh's close pairs on the CPU (scipy): not compiled
        if block is None:
            reads_mesh = getattr(getattr(net, "detector", net), "geometry", None) is not None
            block = ((CPU_BLOCKS_MESH if reads_mesh else CPU_BLOCKS[dtype]) if device.type == "cpu" else 65536)
        block = int(block)
        if block < 1:
            raise ValueError(f"block={block} must be >= 1")
        if recheck_band is not None and float(recheck_band) < 0:
            raise ValueError(f"recheck_band={recheck_band} must be >= 0")
        self.dtype_name, self.dtype, self.block, self.device = dtype, DTYPES[dtype], block, device
        self.recheck_band = None if recheck_band is None or dtype == "float32" else float(recheck_band)
        self._recheck = None if self.recheck_band is None else FastDetector(net, "float32", compile=compile)
        self.rechecked_fraction = 0.0
        self.compiled = bool(compile)
        # a detector that reads the mesh too comes as DetectorOnCodes: its pair features are computed
        # from the decoded vertices in float32 (a bfloat16 decode would move them by ~0.2 % of the diagonal)
        self._space = getattr(net, "space", None) if getattr(net, "detector", None) is not None else None
        net = net.detector if self._space is not None else net
        self._geometry = None if net.geometry is None else copy.deepcopy(net.geometry).eval()
        self._decode = None if self._geometry is None else vertex_decoder(self._space, self._geometry.vertex_index)
        self._mesh_fn = None  # on_meshes: compiled on first use
        self.net = copy.deepcopy(net).eval().to(self.dtype)
        for p in self.net.parameters():
            p.requires_grad_(False)
        self.latent_dim = net.latent_dim
        # padding rows: the box centre (finite inputs, discarded after the call)
        self._pad = net.center.detach().to(device, torch.float32)
        if self.compiled:
            import torch._dynamo as dynamo

            # every instance compiles the same code object: up to ~6 block shapes each, so dynamo's default of 8
            # compiled variants per code object would send a second instance back to eager without a word
            dynamo.config.recompile_limit = max(dynamo.config.recompile_limit, RECOMPILE_LIMIT)
        self._fn = torch.compile(self._block_forward, dynamic=False) if self.compiled else self._block_forward
        if self.compiled:
            try:  # compile now, so a missing compiler surfaces here and not in the middle of a user's loop
                with torch.inference_mode():
                    self._fn(self._pad.expand(self.block, -1).contiguous())
            except Exception as exc:  # inductor raises several types (BackendCompilerFailed, CalledProcessError)
                raise RuntimeError(
                    f"torch.compile failed for the detector on {device} ({type(exc).__name__}: "
                    f"{str(exc).splitlines()[0] if str(exc) else ''}); install a C++ compiler (CPU) or Triton "
                    "(CUDA), or use FastDetector(..., compile=False)") from exc

    @classmethod
    def from_form(cls, net: CollisionDetector, form: str, **kwargs) -> FastDetector:
        """The copy for one of :data:`FORMS` (``"float32"``, ``"bfloat16"``, ``"bfloat16_checked"``); ``kwargs``:
        ``compile``, ``block``."""
        if form not in FORMS:
            raise ValueError(f"form={form!r}; use one of {sorted(FORMS)}")
        dtype, band = FORMS[form]
        return cls(net, dtype, recheck_band=band, **kwargs)

    def _block_forward(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        if self._geometry is not None:
            embedding = self.net.embed_vertices_batch_last(self._decode(z.float()))  # features in float32
            out = self.net._forward(z.to(self.dtype), embedding=embedding)
            return out.prob.float(), out.logit.float(), out.s.float()
        out = self.net._forward(z.to(self.dtype))
        return out.prob.float(), out.logit.float(), out.s.float()

    def _block_mesh_forward(self, z: torch.Tensor, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        out = self.net._forward(z.to(self.dtype), embedding=self.net.embed_vertices_batch_last(v.permute(1, 2, 0)))
        return out.prob.float(), out.logit.float(), out.s.float()

    def padded_rows(self, rows: int) -> int:
        """Rows a block of ``rows`` (<= block) is padded to: ``block`` or the next power of two >= max(rows, 16)."""
        return min(self.block, max(MIN_PADDED_ROWS, 1 << (int(rows) - 1).bit_length()))

    def __call__(self, z_all: torch.Tensor) -> DetectorOutput:
        """Codes (B, D) (any float dtype, moved to the detector's device) -> probabilities, logits and S_i in
        float32, computed block by block (then the rows within ``recheck_band`` of 0 again in float32)."""
        z = self._checked_codes(z_all)
        return self._rechecked(self._blocks(z), lambda near: self._recheck(z[near]))

    def on_meshes(self, z_all: torch.Tensor, vertices_read: torch.Tensor) -> DetectorOutput:
        """A detector over code and mesh on meshes given whole: their codes (B, D) (``encode(mesh)``) and the
        vertices its pair features read, ``mesh[:, geometry.vertex_index]`` (B, V', 3) -> what ``detector(z,
        pair features of the mesh)`` gives, compiled like the code path (its own graph, built on first use)."""
        if self._geometry is None:
            raise ValueError("this detector reads the codes only: call it on the codes")
        z = self._checked_codes(z_all)
        n_read = len(self._geometry.vertex_index)
        if vertices_read.ndim != 3 or tuple(vertices_read.shape[1:]) != (n_read, 3) or len(vertices_read) != len(z):
            raise ValueError(f"vertices_read has shape {tuple(vertices_read.shape)}, expected ({len(z)}, {n_read}, 3)")
        v = vertices_read.to(self.device, torch.float32)
        if self._mesh_fn is None:
            self._mesh_fn = (torch.compile(self._block_mesh_forward, dynamic=False) if self.compiled
                             else self._block_mesh_forward)
        return self._rechecked(self._blocks(z, v), lambda near: self._recheck.on_meshes(z[near], v[near]))

    def _checked_codes(self, z_all: torch.Tensor) -> torch.Tensor:
        if z_all.ndim != 2 or z_all.shape[1] != self.latent_dim:
            raise ValueError(f"z_all has shape {tuple(z_all.shape)}, expected (B, {self.latent_dim})")
        return z_all.to(self.device, torch.float32)

    def _rechecked(self, out: DetectorOutput, exact_of) -> DetectorOutput:
        """``out`` with its rows within ``recheck_band`` of logit 0 replaced by ``exact_of(rows)`` (float32)."""
        if self._recheck is None or len(out.logit) == 0:
            return out
        near = torch.nonzero(out.logit.abs() < self.recheck_band).flatten()
        self.rechecked_fraction = len(near) / len(out.logit)
        if len(near):
            exact = exact_of(near)
            with torch.inference_mode():  # the outputs are inference tensors
                for full, part in zip(out, exact):
                    full[near] = part
        return out

    def _blocks(self, z: torch.Tensor, vertices: torch.Tensor | None = None) -> DetectorOutput:
        """Block by block through the compiled function: codes (``_fn``) or codes and the meshes' vertices
        (``_mesh_fn``); a short last block is padded to one of few shapes (codes: the box centre; vertices: the
        block's first mesh) and the padding's outputs dropped."""
        n = len(z)
        outs = []
        with torch.inference_mode():
            for start in range(0, n, self.block):
                zb = z[start:start + self.block]
                rows = len(zb)
                size = self.padded_rows(rows)
                if size > rows:  # few compiled shapes: pad with the box centre
                    zb = torch.cat([zb, self._pad.expand(size - rows, -1)])
                if vertices is None:
                    outs.append(tuple(t[:rows] for t in self._fn(zb)))
                    continue
                vb = vertices[start:start + rows]
                if size > rows:
                    vb = torch.cat([vb, vb[:1].expand(size - rows, -1, -1)])
                outs.append(tuple(t[:rows] for t in self._mesh_fn(zb, vb)))
        if not outs:
            empty = z.new_zeros(0)
            return DetectorOutput(empty, empty, z.new_zeros(0, self.net.n_components))
        return DetectorOutput(*(torch.cat(t) for t in zip(*outs)))

    def __repr__(self) -> str:
        band = "" if self.recheck_band is None else f", recheck_band={self.recheck_band}"
        return (f"FastDetector(dtype={self.dtype_name}, compiled={self.compiled}, block={self.block}{band}, "
                f"device={self.device})")
