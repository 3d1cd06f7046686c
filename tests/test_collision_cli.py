"""`python -m neuralcol.collision`: text and JSON output, unreadable and missing paths, SCAPE."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from neuralcol.geometry.mesh_io import write_mesh

ROOT = Path(__file__).resolve().parents[1]
SCAPE = Path("/work/shared/data/scape")


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "neuralcol.collision", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


def two_spheres(offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Two unit icospheres, the second shifted by ``offset`` along x: (324, 3) float64, (640, 3) int64."""
    s = trimesh.creation.icosphere(subdivisions=2)
    v, f = np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces, dtype=np.int64)
    return np.concatenate([v, v + [offset, 0.0, 0.0]]), np.concatenate([f, f + len(v)])


@pytest.fixture(scope="module")
def mesh_dir(tmp_path_factory) -> Path:
    """2.obj (free, the rest mesh of the folder) and 10.obj (colliding): natural order puts 2 first."""
    folder = tmp_path_factory.mktemp("meshes")
    write_mesh(folder / "2.obj", *two_spheres(2.5))
    write_mesh(folder / "10.obj", *two_spheres(1.5))
    (folder / "notes.txt").write_text("not a mesh, ignored\n")
    return folder


def test_text_output(mesh_dir):
    res = run_cli(mesh_dir)
    assert res.returncode == 1, res.stderr  # as neuralcol check: some mesh collides
    lines = res.stdout.splitlines()
    assert len(lines) == 2, res.stdout
    free, coll = (line.split() for line in lines)
    assert free[0] == str(mesh_dir / "2.obj") and coll[0] == str(mesh_dir / "10.obj")
    assert free[1:3] == ["free", "pairs=0"] and float(free[3].removeprefix("pd=")) < 0
    assert coll[1] == "collides" and int(coll[2].removeprefix("pairs=")) > 0
    assert float(coll[3].removeprefix("pd=")) > 0
    assert lines[0].index("pairs=") == lines[1].index("pairs=")  # aligned columns
    check = subprocess.run([sys.executable, "-m", "neuralcol.cli", "check", str(mesh_dir)], cwd=ROOT,
                           capture_output=True, text=True, timeout=120)
    assert (check.returncode, check.stdout) == (res.returncode, res.stdout), "the same as neuralcol check"


def test_json_output_and_workers(mesh_dir):
    res = run_cli(mesh_dir / "10.obj", mesh_dir / "2.obj", "--json", "--workers", "2")
    assert res.returncode == 1, res.stderr
    rows = [json.loads(line) for line in res.stdout.splitlines()]
    assert [set(r) for r in rows] == [{"file", "collides", "pairs", "pd"}] * 2
    coll, free = rows
    assert coll["file"] == str(mesh_dir / "10.obj") and free["file"] == str(mesh_dir / "2.obj")
    assert coll["collides"] is True and isinstance(coll["pairs"], int) and coll["pairs"] > 0
    assert coll["pd"] > 0
    assert free["collides"] is False and free["pairs"] == 0 and free["pd"] < 0
    # the verdict does not depend on the order (the rest mesh is 10.obj here) nor on --rest
    res_rest = run_cli(mesh_dir / "10.obj", mesh_dir / "2.obj", "--json", "--rest", mesh_dir / "2.obj")
    assert res_rest.returncode == 1, res_rest.stderr
    rows_rest = [json.loads(line) for line in res_rest.stdout.splitlines()]
    assert [(r["collides"], r["pairs"]) for r in rows_rest] == [(r["collides"], r["pairs"]) for r in rows]


def test_broken_and_missing_paths(mesh_dir, tmp_path):
    folder = tmp_path / "with_bad"
    folder.mkdir()
    for name in ("2.obj", "10.obj"):
        (folder / name).write_bytes((mesh_dir / name).read_bytes())
    (folder / "bad.obj").write_text("this is }{ not an obj file\n\x00\x01 garbage 1 2\n")
    missing = tmp_path / "does_not_exist.obj"
    res = run_cli(folder, missing, "--json")
    assert res.returncode == 2
    err = res.stderr.strip().splitlines()
    assert len(err) == 2, res.stderr
    assert str(folder / "bad.obj") in err[0] and str(missing) in err[1]
    assert "Traceback" not in res.stderr
    rows = [json.loads(line) for line in res.stdout.splitlines()]
    assert [r["file"] for r in rows] == [str(folder / "2.obj"), str(folder / "10.obj")]
    assert [r["collides"] for r in rows] == [False, True]


def test_only_missing_path_and_no_path(tmp_path):
    res = run_cli(tmp_path / "nope")
    assert res.returncode == 2 and "nope" in res.stderr and res.stdout == ""
    res = run_cli()
    assert res.returncode == 2 and "usage" in res.stderr


def test_scape():
    if not (SCAPE / "8.obj").is_file() or not (SCAPE / "1.obj").is_file():
        pytest.skip(f"SCAPE meshes 1.obj and 8.obj not found in {SCAPE}")
    res = run_cli(SCAPE / "1.obj", SCAPE / "8.obj", "--json")
    assert res.returncode == 1, res.stderr
    free, coll = (json.loads(line) for line in res.stdout.splitlines())
    assert free["collides"] is False and free["pairs"] == 0 and free["pd"] < 0
    assert coll["collides"] is True and coll["pairs"] == 73 and coll["pd"] > 0
