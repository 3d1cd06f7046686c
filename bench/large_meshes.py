"""``large``: checking large meshes beside CGAL's Polygon Mesh Processing (``does_self_intersect``,
``self_intersections``), in one process, single-threaded: a 100 k-face scan (``nefertiti.obj``), a colliding
124 k-face mesh (``ogre.obj``) and a 1 M-face one (``igea.ply``, 269 k faces, subdivided once and jittered), all from
the public test meshes (``python -m bench.public_meshes fetch``; skipped with a note where they were not fetched),
and the command's start-up on a small mesh.

Ours: the labeler's set-up (``ExactLabeler(clearance=False)``, what ``neuralcol check`` builds for a mesh against
itself) plus the verdict (stops at the first counted pair), and set-up plus the label (every pair counted, the PD);
CGAL: ``does_self_intersect`` and ``self_intersections`` on a ``Polyhedron_3`` built outside the timing (its build
timed apart); ipctk: ``has_intersections`` (floating-point edge-triangle tests, not exact) on a ``CollisionMesh`` built
outside the timing, after one warm-up call. Each figure is the median of the repetitions; the file is read once,
outside the timing.
"""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np

from bench.context import HERE, ROOT, BenchContext
from bench.labeler_contenders import single_thread
from bench.timing import ratio, repeat, summarize

PUBLIC = HERE / "data" / "public"
MESHES = {"100k": "common-3d-test-models/data/nefertiti.obj", "124k_colliding": "common-3d-test-models/data/ogre.obj",
          "1m": "common-3d-test-models/data/igea.ply"}


def _mesh(key: str):
    from neuralcol.geometry.source_mesh import read_source

    m = read_source(PUBLIC / MESHES[key])
    v, f = m.vertices, m.faces
    if key == "1m":  # 269 k faces, each split in four: 1.07 M; jittered by 1e-7 of the diagonal, since the four
        import trimesh  # children of a face lie exactly in its plane, which a scan's faces do not

        v, f = trimesh.remesh.subdivide(v, f)
        diag = float(np.linalg.norm(np.ptp(v, axis=0)))
        v = v + np.random.default_rng(0).normal(scale=1e-7 * diag / np.sqrt(3), size=v.shape)
    return np.ascontiguousarray(v, np.float64), np.ascontiguousarray(f, np.int64)


def measure(ctx: BenchContext) -> dict:
    reps = 1 if ctx.quick else 3
    out, notes = {}, []
    small = HERE / "tmp" / "startup_two_spheres.obj"
    small.parent.mkdir(parents=True, exist_ok=True)
    import trimesh

    a = trimesh.creation.icosphere(subdivisions=1)
    b = a.copy()
    b.apply_translation([1.5, 0.0, 0.0])
    trimesh.util.concatenate([a, b]).export(small)
    cmd = [sys.executable, "-m", "neuralcol.cli", "check", str(small)]
    out["check_startup_small_s"] = summarize(repeat(lambda: subprocess.run(cmd, capture_output=True, cwd=ROOT),
                                                    3 if ctx.quick else 5))  # (one untimed call warms the caches)
    try:
        from CGAL import CGAL_Polygon_mesh_processing  # noqa: F401
        cgal = True
    except ImportError:
        cgal = False
        notes.append("CGAL not installed (pip install cgal): its columns left out")
    for key in MESHES:
        if not (PUBLIC / MESHES[key]).is_file():
            notes.append(f"{MESHES[key]} not fetched (python -m bench.public_meshes fetch ...): {key} left out")
            continue
        out.update(measure_mesh(key, *_mesh(key), reps, cgal, notes))
    ctx.notes["large"] = "; ".join(notes)
    return out


def measure_mesh(key: str, v: np.ndarray, f: np.ndarray, reps: int, cgal: bool, notes: list[str]) -> dict:
    """Ours and CGAL's figures on one mesh (module docstring)."""
    from bench.labeler_contenders import cgal_checks, cgal_meshes
    from neuralcol.collision.labeler import ExactLabeler

    out = {}
    ExactLabeler(f[:64], v).verdict(v)  # compile / load the kernels outside the timing
    with single_thread():
        setup = repeat(lambda: ExactLabeler(f, v, clearance=False), reps, warmup=0)
        lab = ExactLabeler(f, v, clearance=False)
        verdict = repeat(lambda: lab.verdict(v), reps, warmup=0)
        # a fresh labeler each time: a large mesh's labeler keeps its last pairs for the next check of a moved mesh,
        # which would make a repeated label of the same mesh free
        label = repeat(lambda: ExactLabeler(f, v, clearance=False).label(v), reps, warmup=0)
        collides = bool(lab.verdict(v))
        out[f"large_{key}_ours_verdict_s"] = summarize([s + t for s, t in zip(setup, verdict)])
        out[f"large_{key}_ours_label_s"] = summarize(label)
        notes.append(f"{key}: {MESHES[key]}, {len(v)} vertices, {len(f)} faces, "
                     f"{'collides' if collides else 'free'}; set-up {np.median(setup):.2f} s")
        try:
            from bench.labeler_contenders import ipctk_check

            check = ipctk_check(v, f, v[None])
            check(0)  # (its first call sets up its broad phase)
            out[f"large_{key}_ipctk_has_intersections_s"] = summarize(repeat(lambda: check(0), reps, warmup=0))
            out[f"large_{key}_verdict_vs_ipctk"] = ratio(out[f"large_{key}_ours_verdict_s"],
                                                         out[f"large_{key}_ipctk_has_intersections_s"])
        except ImportError:
            notes.append(f"{key}: ipctk not installed: its column left out")
        if not cgal:
            return out
        t0 = time.perf_counter()
        try:
            meshes = cgal_meshes(v[None], f)
        except RuntimeError as err:  # CGAL could not make the soup one mesh
            notes.append(f"{key}: CGAL left out ({err})")
            return out
        notes.append(f"{key}: CGAL Polyhedron_3 built in {time.perf_counter() - t0:.1f} s (not timed)")
        fns = cgal_checks(meshes)
        out[f"large_{key}_cgal_does_self_intersect_s"] = summarize(
            repeat(lambda: fns["cgal_does_self_intersect"](0), reps, warmup=0))
        out[f"large_{key}_cgal_self_intersections_s"] = summarize(
            repeat(lambda: fns["cgal_self_intersections"](0), reps, warmup=0))
    out[f"large_{key}_verdict_vs_cgal"] = ratio(out[f"large_{key}_ours_verdict_s"],
                                                 out[f"large_{key}_cgal_does_self_intersect_s"])
    out[f"large_{key}_label_vs_cgal_pairs"] = ratio(out[f"large_{key}_ours_label_s"],
                                                     out[f"large_{key}_cgal_self_intersections_s"])
    return out
