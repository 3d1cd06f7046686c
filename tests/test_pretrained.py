"""The SCAPE model shipped in pretrained/scape: it loads from the checkout alone, detects and resolves
SCAPE meshes, and its accuracy on fresh U(Z) codes labeled exactly is within 1.5 points of the figure its
package.json documents."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "pretrained" / "scape"


@pytest.fixture(scope="module")
def shipped(tmp_path_factory):
    import os

    import neuralcol

    # nothing may be read from a cache or a data set: both point at empty folders while the package is used
    old = {k: os.environ.get(k) for k in ("NEURALCOL_CACHE", "NEURALCOL_DATA")}
    os.environ["NEURALCOL_CACHE"] = str(tmp_path_factory.mktemp("no_cache"))
    os.environ["NEURALCOL_DATA"] = str(tmp_path_factory.mktemp("no_data"))
    try:
        with neuralcol.pretrained("scape", workers=0) as run:
            yield run
    finally:
        for k, v in old.items():
            os.environ.pop(k, None) if v is None else os.environ.__setitem__(k, v)


def test_the_shipped_files_match_their_manifest():
    from neuralcol.api.package import check_package

    manifest = check_package(PACKAGE)
    size = sum(f["bytes"] for f in manifest["files"].values())
    assert size < 8 * 2**20, f"pretrained/scape holds {size / 2**20:.1f} MiB; it should stay a few MB"
    assert manifest["dataset"] == "scape"


def test_detect_and_resolve_scape_meshes(shipped, scape):
    """detect, the certified cascade and resolve on SCAPE meshes, with no data set and no cache at hand."""
    verts = scape.vertices.numpy().astype(np.float64)
    assert shipped.n_vertices == verts.shape[1]
    det = shipped.detect(verts[:8])
    assert det.prob.shape == (8,) and bool(((det.prob >= 0) & (det.prob <= 1)).all())
    # a colliding mesh: the first of 32 decoded U(Z) codes the exact labeler calls colliding
    from neuralcol.samples.uniform import uniform_codes

    meshes = shipped.decode(uniform_codes(shipped.space, 7, 0, 32)).double().numpy()
    labels = shipped.label(meshes)
    assert labels.collides.any()
    mesh = meshes[np.flatnonzero(labels.collides)[0]]
    out = shipped.resolve(mesh[None])
    assert out.pd_input[0] > 0
    assert shipped.detect(mesh[None], certify=0.01).collides.shape == (1,)
    assert np.isfinite(out.pd_after).all()
    assert out.pd_after[0] <= out.pd_input[0]


def test_accuracy_on_fresh_exact_labels_matches_the_documented_figure(shipped):
    """2 000 fresh U(Z) codes (a seed no run uses), labeled exactly: the package's promise (within 1.5 points)."""
    from neuralcol.api.package import fresh_check

    result = fresh_check(shipped, 2000)
    documented = json.loads((PACKAGE / "package.json").read_text())["figures"]["u_z"]["accuracy"]
    assert result["documented_accuracy"] == documented
    assert abs(result["difference"]) <= 0.015, result
