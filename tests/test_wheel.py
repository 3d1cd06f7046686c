"""The built wheel, installed outside the checkout: it carries the configs and the shipped model, so
``neuralcol check/resolve``, ``neuralcol.pretrained`` and ``neuralcol train`` work from any folder."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import numpy as np

from tests.conftest import ROOT


def test_wheel_installed_in_a_fresh_venv_carries_conf_and_the_shipped_model(tmp_path):
    src = tmp_path / "src"  # a copy of what the wheel is built from: setuptools writes build/ beside its sources
    src.mkdir()
    for name in ("pyproject.toml", "setup.py", "README.md", "neuralcol", "experiments", "conf", "pretrained"):
        copy = shutil.copytree if (ROOT / name).is_dir() else shutil.copy2
        copy(ROOT / name, src / name, **({"ignore": shutil.ignore_patterns("__pycache__")} if copy is shutil.copytree
                                         else {}))
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(wheels), str(src)], check=True, capture_output=True, timeout=300)
    (wheel,) = wheels.glob("neuralcol-*.whl")
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=False)
    py = env_dir / "bin" / "python"
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               check=True, capture_output=True, text=True).stdout.strip())
    # the dependencies from this environment (a plain path: its .pth files, the editable checkout's among them,
    # are not read), neuralcol itself from the wheel alone
    (site / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", "-q", str(wheel)],
                   check=True, capture_output=True, timeout=300)
    work = tmp_path / "elsewhere"
    work.mkdir()

    # the numba kernels run as Python here: a fresh install compiles them on first use (30 s for check), and what
    # this test is about is the packaging; the compiled kernels are every other test's subject
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}

    def run(*args):
        return subprocess.run([str(py), *args], cwd=work, capture_output=True, text=True, timeout=300, env=env)

    where = run("-c", "import neuralcol, neuralcol.resources as r; print(neuralcol.__file__); print(r.conf_dir()); "
                      "run = neuralcol.pretrained('scape'); print(run.n_vertices)")
    assert where.returncode == 0, where.stderr[-2000:]
    module, conf, n_vertices = where.stdout.split()
    assert Path(module).is_relative_to(site) and Path(conf).is_relative_to(site), "the wheel's copy, not the clone's"
    assert n_vertices == "2161"
    import trimesh

    a = trimesh.creation.icosphere(subdivisions=1)
    b = a.copy()
    b.apply_translation([1.5, 0.0, 0.0])
    trimesh.util.concatenate([a, b]).export(work / "two.obj")
    check = run("-m", "neuralcol.cli", "check", "two.obj", "--json")
    assert check.returncode == 1 and '"collides": true' in check.stdout, check.stderr[-2000:]
    resolved = run("-m", "neuralcol.cli", "resolve", "two.obj", "--out", "out", "--no-progress")
    assert resolved.returncode == 0 and (work / "out" / "two.obj").is_file(), resolved.stderr[-2000:]
    cfg = run("-m", "experiments.run", "--cfg", "job", "dataset=proc_hand")
    assert cfg.returncode == 0 and "proc_hand" in cfg.stdout, cfg.stderr[-2000:]
    row = json.loads(check.stdout)
    assert row["rule"] == "paper" and np.isfinite(row["pd"]) and row["pd"] > 0
