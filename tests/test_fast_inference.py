"""FastDetector: an inference-only copy of the detector (compiled, optionally bfloat16) against the eager float32
forward it replaces."""

from __future__ import annotations

import shutil

import pytest
import torch

from neuralcol.nn.detector import CollisionDetector
from neuralcol.nn.fast_inference import MIN_PADDED_ROWS, FastDetector

HAS_CXX = any(shutil.which(c) for c in ("c++", "g++", "clang++"))


def _detector(seed: int = 0) -> tuple[CollisionDetector, torch.Tensor]:
    """A small random detector with the decoder's features (K 3, d 2) and 300 codes inside its box."""
    torch.manual_seed(seed)
    lo, hi = -torch.rand(9) * 50 - 1, torch.rand(9) * 50 + 1
    w, b = torch.randn(3, 4) * 0.05, torch.randn(3, 4)
    det = CollisionDetector(3, 2, state_dim=8, hidden=16, box_lo=lo, box_hi=hi, code_features=(w, b, "tanh"))
    for p in det.parameters():  # larger weights than the initialisation: probabilities spread over (0, 1)
        p.data.mul_(3.0)
    z = lo + torch.rand(300, 9) * (hi - lo)
    return det.eval(), z


def test_eager_copy_matches_and_padding_the_last_block_changes_nothing():
    det, z = _detector()
    with torch.no_grad():
        ref = det(z)
    assert ref.prob.min() < 0.2 and ref.prob.max() > 0.8  # a test that can tell outputs apart
    fast = FastDetector(det, "float32", compile=False, block=64)
    out = fast(z)
    torch.testing.assert_close(out.prob, ref.prob, rtol=0, atol=1e-6)
    torch.testing.assert_close(out.logit, ref.logit, rtol=0, atol=1e-5)
    torch.testing.assert_close(out.s, ref.s, rtol=0, atol=1e-5)
    assert not out.prob.requires_grad and out.prob.dtype == torch.float32
    # 300 = 4 full blocks + a tail of 44 rows padded to 64; one row alone is padded to 16
    for n in (1, 7, 44, 65):
        torch.testing.assert_close(fast(z[:n]).prob, out.prob[:n], rtol=0, atol=1e-6)  # GEMM blocking: round-off
    empty = fast(z[:0])
    assert empty.prob.shape == (0,) and empty.s.shape == (0, 3)
    assert [fast.padded_rows(r) for r in (1, MIN_PADDED_ROWS, 17, 33, 64)] == [16, 16, 32, 64, 64]


def test_bfloat16_copy_is_close_and_returns_float32():
    det, z = _detector(1)
    with torch.no_grad():
        ref = det(z).prob
    out = FastDetector(det, "bfloat16", compile=False, block=128)(z)
    assert out.prob.dtype == torch.float32
    diff = (out.prob - ref).abs()
    assert 0 < float(diff.max()) < 0.05  # bfloat16's 8-bit mantissa: close, not equal
    assert next(det.parameters()).dtype == torch.float32  # the original is left as it was


def test_bfloat16_with_a_float32_recheck_keeps_float32_labels_near_the_boundary():
    det, z = _detector(1)
    with torch.no_grad():
        ref = det(z)
    plain = FastDetector(det, "bfloat16", compile=False, block=128)(z)
    band = 4 * float((plain.logit - ref.logit).abs().max())  # wider than the largest bfloat16 error
    fast = FastDetector(det, "bfloat16", compile=False, block=128, recheck_band=band)
    out = fast(z)
    near = plain.logit.abs() < band
    assert 0 < fast.rechecked_fraction < 1 and fast.rechecked_fraction == pytest.approx(float(near.float().mean()))
    torch.testing.assert_close(out.prob[near], ref.prob[near], rtol=0, atol=1e-6)  # float32's outputs there
    torch.testing.assert_close(out.s[near], ref.s[near], rtol=0, atol=1e-5)
    torch.testing.assert_close(out.prob[~near], plain.prob[~near], rtol=0, atol=0)  # bfloat16's elsewhere
    assert torch.equal(out.logit > 0, ref.logit > 0)
    assert "recheck_band" in repr(fast)
    assert FastDetector(det, "float32", compile=False, recheck_band=1.0).recheck_band is None  # nothing to recheck
    with pytest.raises(ValueError, match="recheck_band=-1"):
        FastDetector(det, "bfloat16", compile=False, recheck_band=-1)


@pytest.mark.skipif(not HAS_CXX, reason="torch.compile on the CPU needs a C++ compiler")
def test_compiled_copy_matches_eager():
    det, z = _detector(2)
    with torch.no_grad():
        ref = det(z[:40])
    fast = FastDetector(det, "float32", compile=True, block=32)  # shapes 32 and 16 (the 8-row tail)
    out = fast(z[:40])
    torch.testing.assert_close(out.prob, ref.prob, rtol=0, atol=1e-5)
    torch.testing.assert_close(out.logit, ref.logit, rtol=1e-4, atol=1e-4)


def test_bad_arguments_and_a_failing_compiler_give_clear_errors(monkeypatch):
    det, z = _detector()
    with pytest.raises(ValueError, match="dtype='float16'"):
        FastDetector(det, "float16", compile=False)
    with pytest.raises(ValueError, match="block=0"):
        FastDetector(det, compile=False, block=0)
    with pytest.raises(ValueError, match=r"expected \(B, 9\)"):
        FastDetector(det, compile=False)(z[:, :5])

    def broken_compile(fn, **kwargs):
        def run(*args):
            raise OSError("no C++ compiler")
        return run

    monkeypatch.setattr(torch, "compile", broken_compile)
    with pytest.raises(RuntimeError, match="compile=False"):
        FastDetector(det, "float32", compile=True)
