"""bench.public_meshes: the test meshes of a repository are copied out of its git snapshot (any case of suffix, only
its test folder for a known repository, large blobs the snapshot left out named), with a manifest of where each came
from; nothing is copied into the tree (bench/data/ is ignored)."""

from __future__ import annotations

import hashlib
import json
import subprocess
from pathlib import Path

import pytest

import bench.public_meshes as pm

TRI = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"


def _git(repo: Path, *args: str) -> None:
    subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True)


@pytest.fixture
def snapshot(tmp_path):
    """A bare clone of a repository named like trimesh's, holding meshes in and out of models/."""
    work = tmp_path / "trimesh"
    (work / "models" / "sub").mkdir(parents=True)
    (work / "models" / "a.obj").write_bytes(TRI)
    (work / "models" / "sub" / "B.STL").write_bytes(b"solid x\nendsolid x\n")
    (work / "models" / "notes.txt").write_text("not a mesh")
    (work / "docs").mkdir()
    (work / "docs" / "c.obj").write_bytes(TRI)
    _git(work, "init", "-q")
    _git(work, "-c", "user.email=t@t", "-c", "user.name=t", "add", ".")
    _git(work, "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-qm", "meshes")
    bare = tmp_path / "mikedh+trimesh" / "repo"
    subprocess.run(["git", "clone", "-q", "--bare", str(work), str(bare)], check=True)
    return bare


def test_source_names():
    assert pm.source_name("/work/.mirror/alecjacobson+common-3d-test-models/repo") == "common-3d-test-models"
    assert pm.source_name("https://github.com/mikedh/trimesh.git") == "trimesh"
    assert pm.source_name("/data/my-meshes/") == "my-meshes"


def test_fetch_copies_the_test_folder_with_a_manifest(snapshot, tmp_path, monkeypatch):
    monkeypatch.setattr(pm, "DATA", tmp_path / "public")
    pm.fetch([str(snapshot)])
    got = sorted(str(p.relative_to(tmp_path / "public")) for p in (tmp_path / "public").rglob("*") if p.is_file())
    assert got == ["manifest.json", "trimesh/models/a.obj", "trimesh/models/sub/B.STL"]  # docs/ and .txt left out
    manifest = json.loads((tmp_path / "public" / "manifest.json").read_text())
    entry = {e["file"]: e for e in manifest["files"]}["trimesh/models/a.obj"]
    assert entry["sha256"] == hashlib.sha256(TRI).hexdigest() and entry["bytes"] == len(TRI)
    assert entry["source"] == "trimesh" and entry["path"] == "models/a.obj" and len(entry["commit"]) == 40
    pm.fetch([str(snapshot)])  # again: the same entries, not duplicated
    assert len(json.loads((tmp_path / "public" / "manifest.json").read_text())["files"]) == 2


def test_bench_data_is_ignored_by_git():
    root = Path(pm.__file__).resolve().parents[1]
    out = subprocess.run(["git", "-C", str(root), "check-ignore", "bench/data/public/x.obj"], capture_output=True)
    assert out.returncode == 0
