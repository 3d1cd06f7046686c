"""docs/tutorial.md, executed: every ```bash and ```python block in order, on a tiny procedural data set.

The blocks run as a reader runs them, from one working directory (here a temporary one, so the tutorial's relative
paths land there), with the repository on PYTHONPATH and this interpreter's folder first on PATH:

- ```bash blocks: ``bash -e``, each starting from the variables the earlier blocks exported (as in one shell);
- ```python blocks: a fresh ``python -c`` (after the bash blocks before them);
- ```text blocks (sample output) are not run; any other fence tag fails the test, so a new block cannot be
  skipped silently.

The only changes, each asserted to apply (so that none goes stale):

1. ``python -m bench.newuser_hand ...`` gets ``--poses 24`` (24 meshes instead of 150);
2. ``python -m experiments.run ...`` gets ``TINY`` appended: the tiny presets of the detector and the evaluation
   stages (the latent space stays the tutorial's: ``dataset=meshes``'s PCA, fit in milliseconds; its box, not
   fitted at ``detector=tiny``, decodes self-colliding samples, which the later blocks need for the run's
   ``handling/example_0_input.obj``), labels in this process, 4 handler inputs; one short training, reused by every
   later block;
3. the block ``tensorboard --logdir DIR`` starts the server on a free port, checks that it serves the stage runs
   the tutorial describes, and stops it.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "tutorial.md"
RUNNABLE, SHOWN = ("bash", "python"), ("text",)
TINY = ("detector=tiny realistic=tiny speed_accuracy=tiny "
        "labeling.pool.workers=0 labeling.pool.progress=false "
        "handler.n_inputs=4 "
        "handler.verify_margins=[] n_example_meshes=0 detector.tensorboard_examples=2")
STAGES = ["data", "detector_active", "handling", "latent"]  # (autoencoder_level1, _level2: autoencoder=cpu only)
FENCE = re.compile(r"^```(\S*)\n(.*?)^```\s*$", re.M | re.S)


def blocks(text: str) -> list[tuple[str, str]]:
    """(tag, code) of every fenced block of a Markdown text, in order."""
    return [(m.group(1), m.group(2)) for m in FENCE.finditer(text)]


def substitute(code: str, counts: dict) -> str:
    """A bash block with the test's changes 1 and 2 (continuation lines joined first); ``counts`` tallies them."""
    lines = []
    for line in code.replace("\\\n", " ").splitlines():
        for key, pattern, extra in (("newuser_hand", r"python -m bench\.newuser_hand\b", "--poses 24"),
                                    ("run", r"python -m experiments\.run\b", TINY)):
            m = re.match(rf"^(\s*{pattern}[^#]*?)(\s+#.*)?$", line)
            if m:
                line = f"{m.group(1)} {extra}{m.group(2) or ''}"
                counts[key] = counts.get(key, 0) + 1
        lines.append(line)
    return "\n".join(lines) + "\n"


def check_tensorboard(code: str, cwd: Path, env: dict) -> None:
    """Change 3: serve the logdir of ``tensorboard --logdir DIR`` on a free port and check its runs."""
    m = re.fullmatch(r'tensorboard --logdir ("?)(\S+)\1\s*', code)
    assert m, f"the tensorboard block must be the one line `tensorboard --logdir DIR`, got {code!r}"
    logdir = subprocess.run(["bash", "-c", f"source state.sh; echo {m.group(2)}"], cwd=cwd, env=env, check=True,
                            capture_output=True, text=True).stdout.strip()
    proc = subprocess.Popen(["tensorboard", "--logdir", logdir, "--port", "0", "--host", "127.0.0.1"], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        url, runs, seen = None, [], []
        deadline = time.monotonic() + 90
        while url is None and time.monotonic() < deadline:
            line = proc.stdout.readline()
            seen.append(line)
            found = re.search(r"(http://127\.0\.0\.1:\d+)/", line)
            url = found.group(1) if found else None
            assert line or proc.poll() is None, f"tensorboard exited: {''.join(seen)}"
        assert url, f"tensorboard printed no address: {''.join(seen)}"
        while sorted(runs) != STAGES and time.monotonic() < deadline:
            time.sleep(1)
            runs = json.loads(urllib.request.urlopen(f"{url}/data/runs", timeout=10).read())
        assert sorted(runs) == STAGES, f"tensorboard at {url} serves runs {runs}; the tutorial describes {STAGES}"
        tags = json.loads(urllib.request.urlopen(f"{url}/data/plugin/images/tags", timeout=10).read())
        assert {"samples/0", "samples/1"} <= set(tags["detector_active"]), tags
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def test_tutorial_blocks_are_known():
    found = blocks(TUTORIAL.read_text())
    unknown = [(i, tag) for i, (tag, _) in enumerate(found) if tag not in RUNNABLE + SHOWN]
    assert not unknown, f"docs/tutorial.md: blocks {unknown} have a tag this test cannot run; use one of " \
                        f"{RUNNABLE} (run) or {SHOWN} (sample output)"
    assert sum(tag == "python" for tag, _ in found) >= 1 and sum(tag == "bash" for tag, _ in found) >= 3


def test_tutorial_images_exist_and_are_small():
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", TUTORIAL.read_text())
    assert links, "the tutorial shows no image"
    for link in links:
        path = TUTORIAL.parent / link
        assert path.is_file(), f"docs/tutorial.md links {link}, which does not exist"
        assert path.stat().st_size < 200_000, f"{link}: {path.stat().st_size} bytes; keep images under 200 kB"


def test_substitute_appends_before_comments():
    counts = {}
    out = substitute("python -m experiments.run a=1 \\\n    b=2   # note\npython -m bench.newuser_hand D\n", counts)
    assert out == f"python -m experiments.run a=1      b=2 {TINY}   # note\npython -m bench.newuser_hand D --poses 24\n"
    assert counts == {"run": 1, "newuser_hand": 1}


def test_tutorial_runs(tmp_path):
    pythonpath = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env = {**os.environ, "PYTHONPATH": pythonpath,
           "PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ["PATH"]]),
           "NEURALCOL_CACHE": str(tmp_path / ".cache"), "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    for var in ("NEURALCOL_OUTPUT", "NEURALCOL_DATA", "MESHES", "RUN"):
        env.pop(var, None)
    (tmp_path / "state.sh").write_text("")
    counts, n_tensorboard = {}, 0
    for i, (tag, code) in enumerate(blocks(TUTORIAL.read_text())):
        where = f"docs/tutorial.md block {i} ({tag})"
        if tag == "text":
            continue
        if tag == "bash" and code.startswith("tensorboard "):
            check_tensorboard(code, tmp_path, env)
            n_tensorboard += 1
            continue
        if tag == "bash":
            script = f"source state.sh\n{substitute(code, counts)}export -p > state.sh\n"
            cmd = ["bash", "-e", "-c", script]
        elif tag == "python":
            cmd = [sys.executable, "-c", code]
        else:
            pytest.fail(f"{where}: cannot run this tag")
        proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, f"{where} failed (exit {proc.returncode}):\n{code}\n--- stdout\n" \
                                     f"{proc.stdout[-3000:]}\n--- stderr\n{proc.stderr[-3000:]}"
    assert counts == {"newuser_hand": 1, "run": 1} and n_tensorboard == 1, (counts, n_tensorboard)
    # what the tutorial says the blocks leave behind
    run = tmp_path / "outputs" / "tutorial"
    for rel in ("metrics.json", ".hydra/config.yaml", "subdomains.png", "scalars.png", "example_0_resolved.obj",
                "handled/example_0_input_resolved.obj", "fixed/example_0_input.obj", "fixed/pose_000.obj",
                "export/manifest.json"):
        assert (run / rel).is_file(), f"{run / rel} is missing after the tutorial"
