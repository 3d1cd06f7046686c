"""Any mesh, no run: ``neuralcol.check`` / ``resolve`` / ``resolve_sequence`` and the ``neuralcol`` command."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

import neuralcol
from neuralcol.cli import EXIT_BAD_INPUT, EXIT_COLLIDES, EXIT_FREE, main
from neuralcol.errors import UserInputError
from neuralcol.geometry.mesh_io import read_mesh, write_mesh


def spheres(offset: float, subdivisions: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Two unit icospheres, the second shifted by ``offset`` along x (< 2: they overlap)."""
    s = trimesh.creation.icosphere(subdivisions=subdivisions)
    v, f = np.asarray(s.vertices, np.float64), np.asarray(s.faces, np.int64)
    return np.concatenate([v, v + [offset, 0.0, 0.0]]), np.concatenate([f, f + len(v)])


def cloth(fold: float, n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """A square sheet (n x n vertices) whose far half is folded back over the near half and pushed ``fold`` through
    it (< 0: it stays above): another topology, with boundary."""
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    far = v[:, 0] > 0.5
    v[far, 0] = 1.0 - v[far, 0] + 0.02
    bump = 16 * v[far, 0] * (0.5 - v[far, 0]) * 4 * v[far, 1] * (1.0 - v[far, 1])  # 1 at the folded half's middle
    v[far, 2] = 0.05 - fold * bump  # fold > 0.05: a dent through the sheet below
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    f = np.concatenate([np.stack([a, a + n, a + 1], 1), np.stack([a + 1, a + n, a + n + 1], 1)])
    return v, f


def test_check_gives_the_exact_verdict_for_any_topology():
    free, f = spheres(2.5)
    hit, _ = spheres(1.6)
    c = neuralcol.check(np.stack([free, hit]), f)
    assert c.collides.tolist() == [False, True] and c.pairs[0] == 0 and c.pairs[1] > 0
    assert c.pd[0] < 0 < c.pd[1]
    cv, cf = cloth(0.3)
    assert neuralcol.check(cv, cf).collides.tolist() == [True]
    assert neuralcol.check(cloth(-0.3)[0], cf).collides.tolist() == [False]


@pytest.mark.parametrize("make, arg", [(spheres, 1.7), (cloth, 0.3)])
def test_resolve_without_a_run_frees_a_colliding_mesh_and_keeps_a_free_one(make, arg):
    hit, f = make(arg)
    free = make(2.5 if make is spheres else -0.3)[0]
    r = neuralcol.resolve(np.stack([free, hit]), f)
    assert r.untouched.tolist() == [True, False]
    assert np.array_equal(r.vertices[0].numpy(), free)  # bit for bit
    assert r.pd_input[1] > 0 and r.pd_after[1] <= 0 and r.repaired[1]
    assert not neuralcol.check(r.vertices[1].numpy(), f).collides[0]  # the exact verdict on what comes back
    assert 0 < r.displacement_max[1] / r.diagonal < 0.5  # moved, not blown up (how little: research/, docs/)
    assert np.isnan(r.move_to_depth[0])  # a free input has no depth
    assert r.move_to_depth[1] == pytest.approx(r.displacement_max[1] / r.pd_input[1])


def test_resolve_sequence_without_a_run_frees_every_frame():
    v0, f = spheres(3.0, subdivisions=1)
    frames = np.stack([np.where(np.arange(len(v0))[:, None] >= len(v0) // 2, v0 - [s, 0, 0], v0)
                       for s in np.linspace(0.0, 1.4, 8)])  # the spheres approach and overlap in the last frames
    seq = neuralcol.resolve_sequence(frames, f)
    assert not seq.collides.any()
    assert not neuralcol.check(seq.vertices, f).collides.any()
    assert np.array_equal(seq.vertices[0], frames[0])  # free and far from the collision: untouched
    assert neuralcol.check(frames, f).collides[-1]


def test_bad_input_is_one_clear_error():
    v, f = spheres(2.5)
    with pytest.raises(UserInputError, match="faces index vertices"):
        neuralcol.check(v[:10], f)
    with pytest.raises(UserInputError, match="shape"):
        neuralcol.check(v[:, :2], f)
    bad = v.copy()
    bad[3, 1] = np.nan
    with pytest.raises(UserInputError, match="NaN or inf"):
        neuralcol.resolve(bad, f)


def test_a_run_of_another_topology_is_one_clear_error():
    v, f = spheres(1.7)

    class Run:  # what _check_run_topology reads of a TrainedRun
        run_dir, n_vertices, faces = "some_run", 2161, np.zeros((4318, 3), np.int64)

    with pytest.raises(UserInputError, match="some_run: trained on meshes of 2161 vertices.*without a run"):
        neuralcol.resolve(v, f, run=Run())


@pytest.fixture()
def folder(tmp_path) -> Path:
    d = tmp_path / "in"
    write_mesh(d / "2.obj", *spheres(2.5))
    write_mesh(d / "10.obj", *spheres(1.7))
    write_mesh(d / "sheet.ply", *cloth(0.3))  # another topology, another format
    return d


def _run(*argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    code = main([str(a) for a in argv], out, err)
    return code, out.getvalue(), err.getvalue()


def test_check_command_lines_json_and_exit_codes(folder):
    code, out, err = _run("check", folder, "--json")
    rows = [json.loads(line) for line in out.splitlines()]
    assert code == EXIT_COLLIDES and not err
    assert [Path(r["file"]).name for r in rows] == ["2.obj", "10.obj", "sheet.ply"]
    assert [r["collides"] for r in rows] == [False, True, True]
    assert set(rows[0]) == {"file", "collides", "pairs", "pd", "rule"} and rows[0]["rule"] == "paper"
    assert _run("check", folder / "2.obj")[0] == EXIT_FREE
    code, out, err = _run("check", folder / "2.obj", folder / "missing.obj")
    assert code == EXIT_BAD_INPUT and "missing.obj: no such file" in err and "2.obj" in out  # the rest still checked


def test_resolve_command_writes_each_result_in_its_format(folder, tmp_path):
    out_dir = tmp_path / "out"
    code, out, err = _run("resolve", folder, "--out", out_dir, "--json", "--no-progress")
    assert code == EXIT_FREE, err
    rows = {Path(r["file"]).name: r for r in map(json.loads, out.splitlines())}
    assert set(rows["10.obj"]) == {"file", "out", "collides_before", "collides_after", "pd_before", "pd_after",
                                   "max_move", "move_to_depth", "seconds"}
    assert rows["2.obj"]["move_to_depth"] is None  # a free input has no depth
    ratio = rows["10.obj"]["move_to_depth"]
    v_in, _ = read_mesh(folder / "10.obj")
    v_out, _ = read_mesh(out_dir / "10.obj")
    largest = float(np.linalg.norm(v_out - v_in, axis=1).max())
    assert ratio == pytest.approx(largest / rows["10.obj"]["pd_before"], rel=1e-9)
    assert (out_dir / "2.obj").read_bytes() == (folder / "2.obj").read_bytes()  # free: written unchanged
    assert rows["2.obj"]["max_move"] == 0 and not rows["2.obj"]["collides_before"]
    for name in ("10.obj", "sheet.ply"):
        assert rows[name]["collides_before"] and not rows[name]["collides_after"] and rows[name]["pd_after"] <= 0
        v, f = read_mesh(out_dir / name)
        assert not neuralcol.check(v, f).collides[0]  # the file as written is free
    assert _run("check", out_dir)[0] == EXIT_FREE


def test_resolve_command_sequence_and_clear_errors(tmp_path):
    v0, f = spheres(3.0, subdivisions=1)
    d = tmp_path / "motion"
    for t, s in enumerate(np.linspace(0.0, 1.4, 6)):
        write_mesh(d / f"{t}.obj", np.where(np.arange(len(v0))[:, None] >= len(v0) // 2, v0 - [s, 0, 0], v0), f)
    code, out, err = _run("resolve", d, "--out", tmp_path / "fixed", "--sequence", "--json", "--no-progress")
    assert code == EXIT_FREE, err
    assert not any(json.loads(line)["collides_after"] for line in out.splitlines())
    write_mesh(d / "other.obj", *spheres(2.5, subdivisions=2))
    code, _, err = _run("resolve", d, "--out", tmp_path / "fixed2", "--sequence")
    assert code == EXIT_BAD_INPUT and "--sequence" in err and "topologies" in err


def test_the_console_script_is_installed():
    script = Path(sys.executable).parent / "neuralcol"
    res = subprocess.run([str(script), "--help"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and "neuralcol check" in res.stdout and "resolve" in res.stdout


def test_the_runless_repair_defaults_are_the_configs():
    """neuralcol.resolve without a run uses RepairSettings() / UntangleSettings(): they must be handler.repair of
    conf/handler/default.yaml, the one source of the hyperparameters."""
    from omegaconf import OmegaConf

    from neuralcol.repair.settings import RepairSettings
    from neuralcol.repair.untangle import UntangleSettings

    handler = OmegaConf.load(Path(__file__).resolve().parents[1] / "conf/handler/default.yaml")
    conf = OmegaConf.to_container(handler.repair, resolve=True)
    untangle = conf.pop("untangle")
    assert RepairSettings(**conf) == RepairSettings()
    assert UntangleSettings(**untangle) == UntangleSettings()


def test_least_move_keeps_whichever_path_frees_with_the_smaller_move():
    """Per colliding input: the path without the run replaces the run's where it frees the mesh and the run's does
    not, or both free it and it moves less; otherwise (it fails, or it moves more) the run's stays; free inputs are
    the run's."""
    from neuralcol.api.anymesh import least_move
    from neuralcol.api.results import Resolved

    n, v = 5, 4
    base = torch.zeros(n, v, 3, dtype=torch.float64)

    def made(marks, pd_after, moves, rows, margin=0.0):
        m = len(rows)
        verts = base[rows].clone() + torch.as_tensor(marks, dtype=torch.float64)[:, None, None]
        nan = np.full(m, np.nan)
        return Resolved(vertices=verts, codes=torch.zeros(m, 2), codes_before=torch.zeros(m, 2),
                        pd_input=np.where(np.isin(rows, [0]), -1.0, 1.0), pd_before=nan, pd_after=np.array(pd_after),
                        margin=np.full(m, margin), displacement_mean=np.array(moves), displacement_max=np.array(moves),
                        displacement_median=np.array(moves), diagonal=1.0, decoded=torch.zeros(m, v, 3),
                        repaired=np.full(m, np.isnan(margin)), cap=np.ones(m), untouched=np.isin(rows, [0]))

    # input 0 free; 1: both free, the run's moves less; 2: both free, the repairs' move less; 3: only the repairs
    # free it; 4: only the run frees it
    with_run = made([0, 1, 1, 1, 1], [-1, -1, -1, 0.5, -1], [0, 0.1, 0.3, 0.2, 0.2], np.arange(n))
    rows = np.array([1, 2, 3, 4])
    alone = made([2, 2, 2, 2], [-1, -1, -1, 0.4], [0.2, 0.1, 0.4, 0.05], rows, margin=np.nan)  # as repair_batch
    out = least_move(with_run, alone, rows)
    assert out.without_run.tolist() == [False, False, True, True, False]
    assert out.vertices[:, 0, 0].tolist() == [0, 1, 2, 2, 1]
    np.testing.assert_array_equal(out.displacement_max, [0, 0.1, 0.1, 0.4, 0.2])
    np.testing.assert_array_equal(out.pd_after, [-1, -1, -1, -1, -1])
    assert out.repaired.tolist() == [False, False, True, True, False]
    assert np.isnan(out.margin).tolist() == [False, False, True, True, False]
    assert with_run.without_run is None and with_run.vertices[2, 0, 0] == 1  # the inputs are not changed
