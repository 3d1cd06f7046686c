"""The exact labeler beside other self-intersection checks, for ``bench/labeler.py``: our verdict and full label on
collision-free and colliding SCAPE poses, CGAL's Polygon Mesh Processing and ipctk where they import, and
``resolve`` of a free SCAPE mesh with the shipped model.

Colliding poses are SCAPE extrapolations ``v[i] + t (v[j] - v[i])``, ``t ~ U(1.5, 2.5)`` from a seeded generator,
kept when the full label says they collide (most SCAPE poses are free). All checks run single-threaded in this
process and are timed rep by rep in turn (each rep times every method over the same meshes), so a background load
weighs on all of them alike; each method is called once on every mesh before the timing. Meshes are built in each
library's own structure (CGAL ``Polyhedron_3``, ipctk ``CollisionMesh``) outside the timing.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import contextmanager

import numpy as np

from bench.timing import ratio, summarize

EXTRAPOLATION = (1.5, 2.5)  # range of t in v[i] + t (v[j] - v[i])


def colliding_poses(lab, verts: np.ndarray, n: int, seed: int = 0, max_tries: int = 50) -> tuple[np.ndarray, list]:
    """``n`` colliding meshes extrapolated from pairs of ``verts``, in a fixed order (a smaller ``n`` gives a prefix).

    Args:
        lab: an exact labeler of the topology. verts: (N, V, 3) float64 poses (the first, the rest mesh, is not used).
        n: meshes to keep. seed: the generator's seed. max_tries: draws allowed per kept mesh.

    Returns:
        ((n, V, 3) float64 meshes, their recipes ``(i, j, t)``).
    """
    rng = np.random.default_rng(seed)
    out, recipes = [], []
    for _ in range(max_tries * n):
        i, j = (int(k) for k in rng.choice(np.arange(1, len(verts)), 2, replace=False))
        t = float(rng.uniform(*EXTRAPOLATION))
        w = verts[i] + t * (verts[j] - verts[i])
        if lab.label(w).collides:
            out.append(w)
            recipes.append((i, j, round(t, 3)))
            if len(out) == n:
                return np.stack(out), recipes
    raise RuntimeError(f"only {len(out)} of {n} extrapolated SCAPE poses collide after {max_tries * n} draws")


@contextmanager
def single_thread():
    """torch (and ipctk, if it imports) on one thread inside the block; their settings restored after."""
    import torch

    torch_threads = torch.get_num_threads()
    try:
        import ipctk
    except ImportError:
        ipctk = None
    ipc_threads = ipctk.get_num_threads() if ipctk else None
    torch.set_num_threads(1)
    if ipctk:
        ipctk.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(torch_threads)
        if ipctk:
            ipctk.set_num_threads(ipc_threads)


def interleaved_times(fns: dict[str, Callable[[int], object]], n: int, reps: int) -> dict[str, list[float]]:
    """Seconds per mesh of each ``fns[name](k)`` over ``k = 0 .. n-1``, once per rep; in each rep every method runs
    over all meshes in turn (warm up first)."""
    out: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(reps):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            for k in range(n):
                fn(k)
            out[name].append((time.perf_counter() - t0) / n)
    return out


def cgal_meshes(verts: np.ndarray, faces: np.ndarray) -> list:
    """One CGAL ``Polyhedron_3`` per mesh of ``verts`` (N, V, 3) with ``faces`` (F, 3) (a polygon soup made a mesh).

    Raises:
        ImportError: the ``cgal`` bindings are missing (``pip install cgal``).
        RuntimeError: a mesh did not keep its F triangles.
    """
    from CGAL import CGAL_Polygon_mesh_processing as pmp
    from CGAL.CGAL_Kernel import Point_3
    from CGAL.CGAL_Polyhedron_3 import Polyhedron_3

    polys = faces.astype(int).tolist()
    out = []
    for v in verts:
        mesh = Polyhedron_3()
        pmp.polygon_soup_to_polygon_mesh([Point_3(*p) for p in v.tolist()], polys, mesh)
        if mesh.size_of_facets() != len(faces):
            raise RuntimeError(f"CGAL's Polyhedron_3 has {mesh.size_of_facets()} facets, the mesh {len(faces)}")
        out.append(mesh)
    return out


def cgal_checks(meshes: list) -> dict[str, Callable[[int], object]]:
    """``does_self_intersect`` and ``self_intersections`` (all intersecting face pairs, into a fresh list) of
    mesh ``k`` of ``meshes``; each returns the verdict."""
    from CGAL import CGAL_Polygon_mesh_processing as pmp

    def pairs(k):
        out: list = []
        pmp.self_intersections(meshes[k], out)
        return len(out) > 0

    return {"cgal_does_self_intersect": lambda k: bool(pmp.does_self_intersect(meshes[k])),
            "cgal_self_intersections": pairs}


def ipctk_check(rest: np.ndarray, faces: np.ndarray, verts: np.ndarray) -> Callable[[int], object]:
    """``ipctk.has_intersections`` (its default broad phase) of mesh ``k`` of ``verts`` (N, V, 3), on a
    ``CollisionMesh`` built from ``rest`` (V, 3) and ``faces`` (F, 3), its edges from ``ipctk.edges``."""
    import ipctk

    f = np.asfortranarray(faces, dtype=np.int32)
    mesh = ipctk.CollisionMesh(np.asfortranarray(rest, dtype=np.float64), ipctk.edges(f), f)
    fv = [np.asfortranarray(v, dtype=np.float64) for v in verts]
    return lambda k: bool(ipctk.has_intersections(mesh, fv[k]))


def compare(lab, faces: np.ndarray, sets: dict[str, np.ndarray], reps: int, notes: list[str]) -> dict:
    """Our verdict and full label beside CGAL and ipctk (those that import) on each set of meshes.

    Args:
        lab: the exact labeler. faces: (F, 3) int. sets: name -> (n, V, 3) float64 meshes. reps: repetitions.
        notes: what was skipped and why is appended here.

    Returns:
        ``{"<method>_<set>_ms": summary, ratios, "<method>_<set>_disagreements": scalar}``.
    """
    from bench.timing import scalar

    try:
        cgal_ok = bool(cgal_meshes(next(iter(sets.values()))[:1], faces))
    except ImportError as err:
        cgal_ok = False
        notes.append(f"CGAL skipped ({err}; pip install cgal)")
    try:
        import ipctk  # noqa: F401
        ipc_ok = True
    except ImportError as err:
        ipc_ok = False
        notes.append(f"ipctk skipped ({err}; pip install ipctk)")
    out: dict = {}
    for set_name, meshes in sets.items():
        fns: dict[str, Callable[[int], object]] = {"verdict": lambda k, m=meshes: lab.verdict(m[k]),
                                                   "full_label": lambda k, m=meshes: lab.label(m[k]).collides}
        if cgal_ok:
            fns.update(cgal_checks(cgal_meshes(meshes, faces)))
        if ipc_ok:
            fns["ipctk_has_intersections"] = ipctk_check(lab.rest, faces, meshes)
        verdicts = {name: np.array([bool(fn(k)) for k in range(len(meshes))]) for name, fn in fns.items()}  # warm-up
        times = interleaved_times(fns, len(meshes), reps)
        ms = {name: summarize(t, 1e3) for name, t in times.items()}
        for name, s in ms.items():
            out[f"{name}_{set_name}_ms"] = s
        out[f"verdict_vs_full_label_{set_name}"] = ratio(ms["verdict"], ms["full_label"])
        for name in fns:
            if name.startswith("cgal_self"):
                out[f"{name}_vs_full_label_{set_name}"] = ratio(ms[name], ms["full_label"])
            if name.startswith(("cgal_does", "ipctk")):
                out[f"{name}_vs_verdict_{set_name}"] = ratio(ms[name], ms["verdict"])
            if name != "verdict":
                out[f"{name}_{set_name}_disagreements"] = scalar(int((verdicts[name] != verdicts["verdict"]).sum()))
    return out


def resolve_free(verts: np.ndarray, reps: int) -> dict:
    """Milliseconds of ``pretrained("scape").resolve(v[None])`` for one free mesh ``verts`` (V, 3) float64 (median
    over ``reps`` after a warm-up), and whether its vertices come back bit for bit.

    Raises:
        Whatever loading the shipped model raises (the caller reports it).
    """
    import neuralcol

    with neuralcol.pretrained("scape", workers=0) as run:
        first = run.resolve(verts[None])
        times = []
        same = np.array_equal(first.vertices[0].cpu().numpy(), verts)
        for _ in range(reps):
            t0 = time.perf_counter()
            res = run.resolve(verts[None])
            times.append(time.perf_counter() - t0)
            same = same and np.array_equal(res.vertices[0].cpu().numpy(), verts)
        untouched = bool(first.untouched[0])
    from bench.timing import scalar

    return {"resolve_free_ms": summarize(times, 1e3), "resolve_free_bit_identical": scalar(int(same)),
            "resolve_free_untouched": scalar(int(untouched))}


def resolve_colliding(meshes: np.ndarray, faces: np.ndarray, rest: np.ndarray, n_trained: int) -> dict:
    """Seconds per colliding mesh (B, V, 3) of ``neuralcol.resolve`` without a run (the exact repairs; the labeler
    built once, outside the timing) and, on the first ``n_trained`` of them, of the shipped SCAPE model's
    ``resolve`` (its learned handler, then the same repairs), side by side: each mesh resolved by both in turn; and
    the share each frees (exact).

    Raises:
        Whatever loading the shipped model raises (the caller reports it).
    """
    import neuralcol
    from bench.timing import scalar
    from neuralcol.api.anymesh import labeler_for, repair_batch

    lab = labeler_for(faces, rest, clearance=False)
    runless, trained, free_runless, free_trained = [], [], [], []
    with neuralcol.pretrained("scape", workers=0) as run:
        for k, v in enumerate(meshes):
            t0 = time.perf_counter()
            r = repair_batch(lab, rest, v[None], faces, None, False)
            runless.append(time.perf_counter() - t0)
            free_runless.append(bool(r.pd_after[0] <= 0))
            if k < n_trained:
                t0 = time.perf_counter()
                r = run.resolve(v[None])
                trained.append(time.perf_counter() - t0)
                free_trained.append(bool(r.pd_after[0] <= 0))
    return {"resolve_runless_colliding_s": summarize(runless), "resolve_trained_colliding_s": summarize(trained),
            "resolve_runless_vs_trained_colliding": ratio(summarize(runless[:n_trained]), summarize(trained)),
            "resolve_runless_freed": scalar(float(np.mean(free_runless))),
            "resolve_trained_freed": scalar(float(np.mean(free_trained)))}


def target(key: str, value: float | None, limit: float, kind: str = "<=") -> dict:
    """A target ``key <= limit`` (``kind="=="``: ``key == limit``) and whether ``value`` meets it (None: not
    measured)."""
    met = None if value is None else bool(value <= limit if kind == "<=" else value == limit)
    return {"key": key, "target": f"{kind} {limit}", "value": value, "met": met}
