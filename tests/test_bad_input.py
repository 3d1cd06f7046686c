"""A corpus of broken data sets: each gives one clear error line naming the file and the fix, no traceback.

The loader's messages are checked in ``test_datasets.py``; here every case goes through the entry points'
error handling (``report_user_errors``: one line on stderr, exit code 2), and one case through the real
command line of ``experiments.run``.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from neuralcol import load_mesh_dataset, write_mesh
from neuralcol.utils.cli import report_user_errors

ROOT = Path(__file__).resolve().parents[1]


def _folder(tmp_path, icosphere, n=3):
    verts, faces = icosphere
    folder = tmp_path / "ds"
    for k in range(1, n + 1):
        write_mesh(folder / f"{k}.obj", verts * (1 + 0.05 * k), faces)
    return folder, verts, faces


def _non_mesh(folder, verts, faces):
    (folder / "poses.csv").write_text("1,2,3\n")
    return "poses.csv", "not a mesh file", "move it out"


def _topology(folder, verts, faces):
    write_mesh(folder / "2.obj", np.concatenate([verts, [[3.0, 3.0, 3.0]]]), faces)
    return "2.obj", "43 vertices", "one topology"


def _nan(folder, verts, faces):
    bad = verts.copy()
    bad[5, 0] = np.inf
    write_mesh(folder / "3.obj", bad, faces)
    return "3.obj", "non-finite coordinates", "fix or drop this mesh"


def _empty(folder, verts, faces):
    for p in folder.iterdir():
        p.unlink()
    return "ds", "no .obj/.ply/.off files", "point the config at the right folder"


def _non_manifold(folder, verts, faces):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], float)
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    for p in folder.iterdir():
        p.unlink()
    write_mesh(folder / "1.obj", v, f)
    return "1.obj", "non-manifold mesh", "shared by 3 triangles"


def _zero_area(folder, verts, faces):
    bad = verts.copy()
    a, b, c = faces[0]
    bad[c] = bad[a]
    write_mesh(folder / "2.obj", bad, faces)
    return "2.obj", "zero area", "collapse or remove degenerate faces"


def _huge(folder, verts, faces):
    write_mesh(folder / "2.obj", verts * 1e15, faces)
    return "2.obj", "coordinates reach", "rescale the data set"


def _far_off(folder, verts, faces):
    write_mesh(folder / "2.obj", verts + 1e6, faces)
    return "2.obj", "from the origin", "translate the data set to the origin"


def _not_a_mesh(folder, verts, faces):
    (folder / "2.obj").write_text("garbage\n")
    return "2.obj", "holds no triangle mesh", ""


CASES = [_non_mesh, _topology, _nan, _empty, _non_manifold, _zero_area, _huge, _far_off, _not_a_mesh]


@pytest.mark.parametrize("break_it", CASES, ids=lambda f: f.__name__.strip("_"))
def test_broken_data_set_is_one_error_line(tmp_path, icosphere, capsys, monkeypatch, break_it):
    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)
    monkeypatch.delenv("NEURALCOL_DEBUG", raising=False)
    folder, verts, faces = _folder(tmp_path, icosphere)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    name, what, fix = break_it(folder, verts, faces)
    after = {p.name: p.read_bytes() for p in folder.iterdir()}
    with pytest.raises(SystemExit) as exit_:
        report_user_errors(load_mesh_dataset)(folder)
    assert exit_.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("error: ") and name in lines[0] and what in lines[0] and fix in lines[0], lines[0]
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == after, "the user's files are left as they were"
    assert set(before) - set(after) <= {"1.obj", "2.obj", "3.obj"}


def test_debug_keeps_the_traceback(tmp_path, icosphere, monkeypatch):
    from neuralcol.errors import MeshFileError

    folder, verts, faces = _folder(tmp_path, icosphere)
    _nan(folder, verts, faces)
    monkeypatch.setenv("NEURALCOL_DEBUG", "1")
    with pytest.raises(MeshFileError, match="3.obj"):
        report_user_errors(load_mesh_dataset)(folder)


def test_command_line_reports_a_broken_folder_in_one_line(tmp_path, icosphere):
    folder, verts, faces = _folder(tmp_path, icosphere)
    _topology(folder, verts, faces)
    env = {k: v for k, v in os.environ.items() if k not in ("HYDRA_FULL_ERROR", "NEURALCOL_DEBUG")}
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.run", "dataset=swing", f"dataset.source.path={folder}",
         "dataset.source.expected_vertices=null", f"paths.output_dir={tmp_path}/out",
         f"paths.cache_dir={tmp_path}/cache"],
        cwd=ROOT, capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "2.obj: 43 vertices" in lines[0], lines
