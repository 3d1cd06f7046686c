"""Public test meshes nobody here made, checked and resolved as a new user would: ``neuralcol check`` and ``neuralcol
resolve`` on each file, one process per call, the way they are typed.

    .venv/bin/python -m bench.public_meshes fetch SOURCE...     # -> bench/data/public/<source>/..., manifest.json
    .venv/bin/python -m bench.public_meshes run [--timeout 180] [--max-faces 300000] [--only colliding]
    .venv/bin/python -m bench.public_meshes table

``fetch`` copies every mesh file (.obj .off .ply .stl .glb .gltf .npz, any case; a .gltf's .bin buffers beside it)
out of each SOURCE into ``bench/data/public/<name>/`` (ignored by git: the meshes are never copied into the tree) and
records each file's source, commit, path, size and SHA-256 in ``bench/data/public/manifest.json``. A SOURCE is a git
repository (a clone, or the bare snapshot the library's ``fetch`` brings, read at its HEAD), a plain folder, or a git
URL (cloned shallow where the network allows). The corpus behind the docs: alecjacobson/common-3d-test-models,
mikedh/trimesh (``models/``) and kmammou/v-hacd (``app/meshes/``); CGAL's test data is larger than the snapshot limit
here.

``run`` calls ``neuralcol check FILE --json`` on every fetched file (at most ``--timeout`` seconds each), then
``neuralcol resolve FILE --out DIR --json`` on each colliding one, and judges each output file with a second
``neuralcol check``: read or refused (the reason), the verdict and pair count, whether resolve freed it, whether the
output keeps the input's vertex and face counts, the largest move (fraction of the diagonal) and its ratio to the
input's PD, and the seconds of each call (start-up included). Writes ``outputs/public_meshes/results.json``.
``table`` prints it as markdown.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "bench" / "data" / "public"
OUT = ROOT / "outputs" / "public_meshes"
SUFFIXES = (".obj", ".off", ".ply", ".stl", ".glb", ".gltf", ".npz")
SIDECARS = (".bin",)  # a .gltf's separate buffers: fetched beside it, not run
# the folders of each known repository that hold its test meshes (others: every mesh file)
FOLDERS = {"common-3d-test-models": "data/", "trimesh": "models/", "v-hacd": "app/meshes/"}


def _git(repo: Path, *args: str) -> bytes:
    return subprocess.run(["git", f"--git-dir={repo}", *args], check=True, capture_output=True).stdout


def _git_dir(path: Path) -> Path | None:
    """The git directory of a clone or of a bare snapshot, or None for a plain folder."""
    if (path / ".git").exists():
        return path / ".git"
    if (path / "HEAD").exists() and (path / "objects").exists():
        return path
    return None


def source_name(source: str) -> str:
    """A short folder name for a source: the repository's name (``owner+name/repo`` snapshots give ``name``)."""
    p = Path(source.rstrip("/"))
    if p.name in ("repo", ".git") and p.parent.name:
        p = p.parent
    name = p.name.removesuffix(".git")
    return name.split("+", 1)[1] if "+" in name else name


def fetch(sources: list[str]) -> None:
    manifest_path = DATA / "manifest.json"
    manifest = json.loads(manifest_path.read_text()) if manifest_path.exists() else {"files": []}
    for source in sources:
        name = source_name(source)
        tmp = None
        path = Path(source)
        if not path.exists():  # a URL: a shallow clone
            tmp = Path(tempfile.mkdtemp())
            try:
                subprocess.run(["git", "clone", "--depth", "1", source, str(tmp / name)], check=True)
            except (subprocess.CalledProcessError, FileNotFoundError) as exc:
                print(f"{source}: cannot clone ({exc}); give a local clone or snapshot instead", file=sys.stderr)
                continue
            path = tmp / name
        git = _git_dir(path)
        prefix = FOLDERS.get(name, "")
        out = DATA / name
        kept = 0
        if git is not None:
            commit = _git(git, "rev-parse", "HEAD").decode().strip()
            listed = [f for f in _git(git, "ls-tree", "-r", "--name-only", "HEAD").decode().splitlines()
                      if f.startswith(prefix)]
            files = [f for f in listed if Path(f).suffix.lower() in SUFFIXES]
            for f in (f for f in listed if Path(f).suffix.lower() in SIDECARS):
                try:
                    (out / f).parent.mkdir(parents=True, exist_ok=True)
                    (out / f).write_bytes(_git(git, "show", f"HEAD:{f}"))
                except subprocess.CalledProcessError:
                    pass  # (a sidecar the snapshot left out: its .gltf is refused with the reason)
            absent = []
            for f in files:
                try:
                    blob = _git(git, "show", f"HEAD:{f}")
                except subprocess.CalledProcessError:  # listed, but the snapshot left the blob out (too large)
                    absent.append(f)
                    continue
                if blob.startswith(b"version https://git-lfs"):
                    absent.append(f)  # an LFS pointer, not a mesh
                    continue
                kept += _keep(manifest, out / f, blob, name, commit, f)
            if absent:
                print(f"{source}: {len(absent)} listed mesh files are not in this copy (too large for the snapshot, "
                      f"or LFS pointers): {', '.join(Path(a).name for a in absent[:8])}"
                      f"{' ...' if len(absent) > 8 else ''}")
        else:
            commit = None
            for f in sorted(p for p in path.rglob("*") if p.is_file() and p.suffix.lower() in SUFFIXES + SIDECARS):
                rel = str(f.relative_to(path))
                if f.suffix.lower() in SIDECARS:
                    (out / rel).parent.mkdir(parents=True, exist_ok=True)
                    (out / rel).write_bytes(f.read_bytes())
                    continue
                kept += _keep(manifest, out / rel, f.read_bytes(), name, commit, rel)
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        print(f"{source}: {kept} mesh files -> {out}")
    manifest["files"].sort(key=lambda e: e["file"])
    manifest_path.parent.mkdir(parents=True, exist_ok=True)
    manifest_path.write_text(json.dumps(manifest, indent=1))


def _keep(manifest: dict, target: Path, blob: bytes, name: str, commit: str | None, rel: str) -> int:
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_bytes(blob)
    entry = {"file": str(target.relative_to(DATA)), "source": name, "commit": commit, "path": rel,
             "bytes": len(blob), "sha256": hashlib.sha256(blob).hexdigest()}
    manifest["files"] = [e for e in manifest["files"] if e["file"] != entry["file"]] + [entry]
    return 1


def _cli(args: list[str], timeout: float) -> tuple[int | None, str, str, float]:
    """``neuralcol ARGS`` in its own process: exit code (None: timed out), stdout, stderr, seconds."""
    t = time.perf_counter()
    try:
        p = subprocess.run([sys.executable, "-m", "neuralcol.cli", *args], capture_output=True, text=True,
                           timeout=timeout)
        return p.returncode, p.stdout, p.stderr, time.perf_counter() - t
    except subprocess.TimeoutExpired:
        return None, "", "", time.perf_counter() - t


def _reason(err: str, path: Path) -> str:
    """The command's one-line reason for ``path`` (its line naming the file; warnings of libraries left out)."""
    lines = [line.strip() for line in err.splitlines() if line.strip()]
    named = [line for line in lines if line.startswith(str(path))]
    line = (named or lines or ["(no message)"])[-1]
    return line.removeprefix(f"{path}: ")[:300]


def _face_count(path: Path) -> int | None:
    """The faces the file holds, as neuralcol reads it (polygons counted once); None where it cannot be read."""
    try:
        from neuralcol.geometry.source_mesh import read_source

        return int(read_source(path).n_file_faces)
    except Exception:
        return None


def _same_structure(a: Path, b: Path) -> bool:
    """Do the two files hold the same vertices count and the same faces, as neuralcol reads them?"""
    from neuralcol.geometry.source_mesh import read_source

    try:
        x, y = read_source(a), read_source(b)
    except Exception:
        return False
    return len(x.vertices) == len(y.vertices) and x.faces.shape == y.faces.shape and bool((x.faces == y.faces).all())


def run(args) -> None:
    manifest = json.loads((DATA / "manifest.json").read_text())
    OUT.mkdir(parents=True, exist_ok=True)
    rows = []
    for e in manifest["files"]:
        path = DATA / e["file"]
        row = {"file": e["file"], "bytes": e["bytes"], "faces": _face_count(path)}
        if row["faces"] is not None and row["faces"] > args.max_faces:
            row["skipped"] = f"more than {args.max_faces} faces"
            rows.append(row)
            continue
        code, out, err, sec = _cli(["check", str(path), "--json"], args.timeout)
        row["check_seconds"] = sec
        if code is None:
            row["check"] = f"timed out after {args.timeout:g} s"
        elif code == 2 or not out.strip():
            row["check"] = "refused"
            row["reason"] = _reason(err, path)
        else:
            c = json.loads(out.splitlines()[0])
            row.update({"check": "read", "collides": c["collides"], "pairs": c["pairs"], "pd": c["pd"]})
        if row.get("collides") and args.only != "free":
            dest = OUT / "resolved" / Path(e["file"]).parent
            dest.mkdir(parents=True, exist_ok=True)
            code, out, err, sec = _cli(["resolve", str(path), "--out", str(dest), "--json", "--no-progress"],
                                       args.timeout)
            row["resolve_seconds"] = sec
            if code is None:
                row["resolve"] = f"timed out after {args.timeout:g} s"
            elif not out.strip():
                row["resolve"] = "failed"
                row["reason"] = _reason(err, path)
            else:
                r = json.loads(out.splitlines()[0])
                result = Path(r["out"])
                again = _cli(["check", str(result), "--json"], args.timeout)
                after = json.loads(again[1].splitlines()[0]) if again[0] in (0, 1) and again[1].strip() else None
                row.update({"resolve": "freed" if after is not None and not after["collides"] else "still collides",
                            "max_move": r["max_move"], "move_to_depth": r.get("move_to_depth"),
                            "same_structure": _same_structure(path, result)})
        rows.append(row)
        state = row.get("resolve") or row.get("check")
        print(f"{e['file']}: {state}" + (f" ({row['pairs']} pairs)" if row.get("collides") else ""), flush=True)
    (OUT / "results.json").write_text(json.dumps({"timeout": args.timeout, "max_faces": args.max_faces,
                                                  "rows": rows}, indent=1))
    table(args)


def table(_args=None) -> None:
    doc = json.loads((OUT / "results.json").read_text())
    rows = doc["rows"]
    read = [r for r in rows if r.get("check") == "read"]
    hit = [r for r in read if r["collides"]]
    freed = [r for r in hit if r.get("resolve") == "freed"]
    print(f"{len(rows)} files: {len(read)} read, {sum(r.get('check') == 'refused' for r in rows)} refused, "
          f"{sum('skipped' in r for r in rows)} skipped (> {doc['max_faces']} faces), "
          f"{sum(str(r.get('check', '')).startswith('timed') for r in rows)} check timed out; "
          f"{len(hit)} collide, {len(freed)} freed by resolve")
    print("\n| file | faces | pairs | resolve | max move | move / PD | check s | resolve s |")
    print("|---|---:|---:|---|---:|---:|---:|---:|")
    for r in hit:
        ratio = r.get("move_to_depth")
        move = r.get("max_move")
        print(f"| {r['file']} | {r['faces']} | {r['pairs']} | {r.get('resolve')} | "
              f"{'-' if move is None else f'{100 * move:.2f} %'} | {'-' if ratio is None else f'{ratio:.2g}'} | "
              f"{r['check_seconds']:.1f} | {r.get('resolve_seconds', float('nan')):.1f} |")
    refused = [r for r in rows if r.get("check") == "refused"]
    if refused:
        print("\n| refused file | reason |\n|---|---|")
        for r in refused:
            print(f"| {r['file']} | {r.get('reason', '')[:160]} |")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.public_meshes", description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    f = sub.add_parser("fetch", help="copy the mesh files of each SOURCE into bench/data/public/")
    f.add_argument("sources", nargs="+", metavar="SOURCE")
    r = sub.add_parser("run", help="check and resolve every fetched file")
    r.add_argument("--timeout", type=float, default=180.0, help="seconds per command")
    r.add_argument("--max-faces", type=int, default=300_000, help="larger files are skipped (reported)")
    r.add_argument("--only", choices=("all", "free"), default="all", help="free: check only, resolve nothing")
    sub.add_parser("table", help="print the last run's table")
    args = ap.parse_args(argv)
    if args.command == "fetch":
        fetch(args.sources)
    elif args.command == "run":
        run(args)
    else:
        table(args)


if __name__ == "__main__":
    main()
