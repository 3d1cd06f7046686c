"""``fcl``: the python-fcl backend (``labeling=fcl``, the paper's labeler) next to ExactLabeler."""

from __future__ import annotations

import time

import numpy as np

from bench.context import BenchContext
from bench.timing import per_mesh_times, ratio, summarize


def scape_variants(verts: np.ndarray, n: int, seed: int = 0) -> list[np.ndarray]:
    """Inter-/extrapolations ``v_i + t (v_j - v_i)``, ``t ~ U(-0.8, 1.8)``, between collision-free SCAPE poses (as
    in tests/test_labeler.py::test_variants_match_meshlab_including_near_boundary): both classes."""
    rng = np.random.default_rng(seed)
    free = [i for i in range(len(verts)) if i not in (7, 70)]  # files 8 and 71 collide
    out = []
    for _ in range(n):
        i, j = rng.choice(free, 2, replace=False)
        out.append(verts[i] + rng.uniform(-0.8, 1.8) * (verts[j] - verts[i]))
    return out


def measure(ctx: BenchContext) -> dict:
    """python-fcl backend (``labeling=fcl``, the paper's labeler) next to ExactLabeler in the same run:
    full label and verdict per SCAPE mesh (all 71, reps interleaved), the whole-mesh BVH self-collision it
    replaces, and the share of equal verdicts on the 71 meshes plus inter-/extrapolated poses."""
    from neuralcol.collision.fcl_labeler import FCLLabeler
    from neuralcol.collision.labeler import ExactLabeler

    ds = ctx.scape
    verts = ds.vertices.numpy().astype(np.float64)
    faces = ds.faces.numpy()
    reps = ctx.reps
    exact = ExactLabeler(faces, verts[0])
    t0 = time.perf_counter()
    lab = FCLLabeler(faces, verts[0])
    build_s = time.perf_counter() - t0
    bvh = FCLLabeler(faces, verts[0], method="bvh")
    grid = FCLLabeler(faces, verts[0], method="grid")  # same pairs, candidates from neuralcol's grid
    for f in (exact.label, exact.verdict, lab.label, lab.verdict, grid.label):  # numba cache, python-fcl's first calls
        f(verts[1])
    times: dict[str, list[float]] = {k: [] for k in ("fcl_label", "exact_label", "fcl_verdict", "exact_verdict",
                                                     "grid_label", "grid_verdict")}
    for _ in range(reps):  # interleaved, so both labelers see the same machine load
        times["fcl_label"] += per_mesh_times(lab.label, verts, 1)
        times["exact_label"] += per_mesh_times(exact.label, verts, 1)
        times["fcl_verdict"] += per_mesh_times(lab.verdict, verts, 1)
        times["exact_verdict"] += per_mesh_times(exact.verdict, verts, 1)
        times["grid_label"] += per_mesh_times(grid.label, verts, 1)
        times["grid_verdict"] += per_mesh_times(grid.verdict, verts, 1)
    out = {
        "fcl_full_label_ms": summarize(times["fcl_label"], 1e3),
        "fcl_exact_full_label_ms": summarize(times["exact_label"], 1e3),
        "fcl_verdict_ms": summarize(times["fcl_verdict"], 1e3),
        "fcl_exact_verdict_ms": summarize(times["exact_verdict"], 1e3),
        "fcl_grid_full_label_ms": summarize(times["grid_label"], 1e3),
        "fcl_grid_verdict_ms": summarize(times["grid_verdict"], 1e3),
    }
    out["fcl_vs_exact_full_label"] = ratio(out["fcl_full_label_ms"], out["fcl_exact_full_label_ms"])
    out["fcl_vs_exact_verdict"] = ratio(out["fcl_verdict_ms"], out["fcl_exact_verdict_ms"])
    sample = verts[:: 15 if ctx.quick else 5]  # the literal way: the whole mesh's BVH collided with itself
    out["fcl_bvh_self_collide_ms"] = summarize(per_mesh_times(bvh.counted_pairs, sample, 1), 1e3)
    # agreement: the 71 meshes plus inter-/extrapolations between free poses
    n_var = 100 if ctx.quick else 300
    sets = {"scape": list(verts), "variants": scape_variants(verts, n_var)}
    table: dict[str, list] = {"set": [], "meshes": [], "colliding_exact": [], "colliding_fcl": [], "agreement": [],
                              "pd_ratio_colliding": [], "pd_ratio_free": []}
    equal_all, n_all = 0, 0
    for name, meshes in sets.items():
        a = [exact.label(v) for v in meshes]
        b = [lab.label(v) for v in meshes]
        ca = np.array([x.collides for x in a])
        cb = np.array([x.collides for x in b])
        pa = np.array([x.pd for x in a])
        pb = np.array([x.pd for x in b])
        both, free = ca & cb, ~ca & ~cb
        table["set"].append(name)
        table["meshes"].append(len(meshes))
        table["colliding_exact"].append(int(ca.sum()))
        table["colliding_fcl"].append(int(cb.sum()))
        table["agreement"].append(float((ca == cb).mean()))
        # median PD_fcl / PD_exact where both agree: how far the two definitions of PD lie apart
        table["pd_ratio_colliding"].append(float(np.median(pb[both] / pa[both])) if both.any() else float("nan"))
        table["pd_ratio_free"].append(float(np.median(pb[free] / pa[free])) if free.any() else float("nan"))
        equal_all += int((ca == cb).sum())
        n_all += len(meshes)
    out["fcl_agreement"] = summarize([equal_all / n_all])
    out["fcl_agreement_sets"] = table
    ctx.notes["fcl"] = (f"FCLLabeler(method='broadphase', patch_size={lab.patch_size}) built in {build_s:.2f} s on "
                        f"SCAPE file 1 ({len(faces)} triangles); times per mesh over all 71 meshes, {reps} reps "
                        f"interleaved with ExactLabeler; fcl_grid_*: method='grid' (same labels); "
                        f"fcl_bvh_self_collide_ms: method='bvh' on {len(sample)} "
                        f"meshes, 1 rep; agreement: {n_all} meshes (71 SCAPE + {n_var} variants), "
                        f"{sum(table['colliding_exact'])} colliding for ExactLabeler, "
                        f"{sum(table['colliding_fcl'])} for FCL")
    return out
