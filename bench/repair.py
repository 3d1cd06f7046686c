"""``repair``: ``neuralcol.resolve`` without a run on colliding meshes nobody tuned on, side by side with ipctk's
barrier path, and on the colliding public test meshes where they were fetched.

Sets (each mesh is resolved alone, as a user's file would be; its own first pose is the rest mesh):

* ``scape``: extrapolations ``v_i + t (v_j - v_i)`` of SCAPE poses, ``t`` in 1.5-2.5, that collide
  (:func:`bench.labeler_contenders.colliding_poses`, seed 3: not the labeler benchmark's draw);
* ``hand``: the same kind of extrapolations of a procedural hand no preset was written for
  (:mod:`bench.newuser_hand`, variant b);
* ``public``: the colliding meshes of ``bench/data/public`` (``python -m bench.public_meshes fetch``), those under
  ``--max-faces``; left out, with a note, where nothing was fetched.

Per set: the share freed (exact), the median of the per-mesh median vertex move, the median and 95th percentile of the
per-mesh largest move (fractions of the bounding-box diagonal), the largest move over the input's exact PD (median),
and seconds per mesh. Beside it, on the first SCAPE meshes the repairs freed, ipctk's barrier path
(:func:`barrier_path`: Newton steps cut by continuous collision detection, so it stays free from a free start) from the
repairs' result towards the input: how much of the move a barrier method would take back, at what time. ipctk is an
optional install (``pip install ipctk``, the ``contenders`` extra); without it the row is left out, with a note.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from bench.context import HERE, BenchContext
from bench.timing import scalar

SCAPE_MESHES, HAND_MESHES, IPC_MESHES = 20, 20, 3
PUBLIC_MAX_FACES = 20_000  # the public meshes above this are timed by bench.public_meshes, not here


def barrier_path(start: np.ndarray, target: np.ndarray, faces: np.ndarray, ell: float, dhat: float = 0.05,
                 kappa: float = 0.1, stiffness: float = 0.0, max_iter: int = 300, tol: float = 1e-3):
    """ipctk's barrier path from the free ``start`` towards ``target`` (V, 3): Newton on
    ``1/2 |x - target|_Q^2 + kappa B(x)`` (``Q = I + stiffness (D - A)``, ``B`` ipctk's barrier with activation
    distance ``dhat`` mean edge lengths ``ell``, its Hessian projected to PSD), each step cut by ipctk's continuous
    collision detection and halved until the energy falls. Returns the last iterate and the iterations used."""
    import ipctk
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from neuralcol.repair.untangle import edge_laplacian

    fortran = np.asfortranarray
    n = len(start)
    mesh = ipctk.CollisionMesh(fortran(start), ipctk.edges(faces), faces)
    q = sp.kron((sp.eye(n) + stiffness * edge_laplacian(faces, n)).tocsr(), sp.eye(3)).tocsc()
    barrier = ipctk.BarrierPotential(dhat * ell, 1.0)
    broad = ipctk.LBVH()
    x, t = np.array(start, np.float64), target.reshape(-1)

    def collisions(y):
        c = ipctk.NormalCollisions()
        c.build(mesh, fortran(y), dhat * ell, 0.0, broad)
        return c

    def energy(y, c):
        d = y.reshape(-1) - t
        return 0.5 * d @ (q @ d) + kappa * barrier(c, mesh, fortran(y))

    its = 0
    while its < max_iter:
        its += 1
        c = collisions(x)
        g = q @ (x.reshape(-1) - t) + kappa * barrier.gradient(c, mesh, fortran(x))
        h = q + kappa * barrier.hessian(c, mesh, fortran(x), ipctk.PSDProjectionMethod.CLAMP)
        p = -spla.spsolve(h.tocsc(), g).reshape(-1, 3)
        if np.abs(p).max() < tol * ell:
            break
        a = min(1.0, 0.9 * ipctk.compute_collision_free_stepsize(mesh, fortran(x), fortran(x + p), 0.0, broad))
        e0 = energy(x, c)
        for _ in range(20):
            xn = x + a * p
            if energy(xn, collisions(xn)) <= e0:
                break
            a *= 0.5
        x = xn
    return x, its


def _hand_poses() -> tuple[np.ndarray, np.ndarray]:
    from bench.newuser_hand import VARIANTS
    from neuralcol.data.procedural.hand import make_proc_hand

    seed, geometry = VARIANTS["b"]
    v, f = make_proc_hand(n_poses=60, seed=seed, **geometry)
    return np.asarray(v, np.float64), np.asarray(f, np.int64)


def resolve_set(meshes: list[np.ndarray], faces: list[np.ndarray]) -> tuple[dict, list]:
    """``neuralcol.resolve`` of each mesh alone (its own rest): the summary and the per-mesh results."""
    import neuralcol

    rows = []
    for v, f in zip(meshes, faces):
        t0 = time.perf_counter()
        r = neuralcol.resolve(v, f)
        seconds = time.perf_counter() - t0
        diag = float(r.diagonal)
        rows.append({"freed": bool(r.pd_after[0] <= 0), "largest": float(r.displacement_max[0]) / diag,
                     "median": float(r.displacement_median[0]) / diag, "to_depth": float(r.move_to_depth[0]),
                     "seconds": seconds, "out": r.vertices[0].numpy()})
    return summary(rows), rows


def summary(rows: list[dict]) -> dict:
    """The set's figures (see the module docstring)."""
    col = {k: np.array([r[k] for r in rows], np.float64) for k in ("largest", "median", "to_depth", "seconds")}
    return {"freed": scalar(float(np.mean([r["freed"] for r in rows]))), "meshes": scalar(len(rows)),
            "median_move": scalar(float(np.median(col["median"]))),
            "largest_move_median": scalar(float(np.median(col["largest"]))),
            "largest_move_p95": scalar(float(np.percentile(col["largest"], 95))),
            "move_to_depth_median": scalar(float(np.nanmedian(col["to_depth"]))),
            "seconds_mean": scalar(float(col["seconds"].mean())), "seconds_max": scalar(float(col["seconds"].max()))}


def ipc_beside(meshes: np.ndarray, faces: np.ndarray, rows: list[dict], notes: list[str]) -> dict:
    """ipctk's barrier path from the repairs' free result towards the input, on the first freed meshes."""
    try:
        import ipctk  # noqa: F401
    except ImportError:
        notes.append("ipctk not installed (pip install ipctk): its barrier path not measured")
        return {}
    from neuralcol.api.anymesh import labeler_for

    picked = [k for k, r in enumerate(rows) if r["freed"] and r["largest"] > 0][:IPC_MESHES]
    out = []
    for k in picked:
        lab = labeler_for(faces, meshes[k], clearance=False)
        t0 = time.perf_counter()
        x, its = barrier_path(rows[k]["out"], meshes[k], faces, lab.ell, max_iter=60)
        seconds = time.perf_counter() - t0
        diag = float(lab.diag)
        out.append({"freed": not lab.verdict(x), "largest": float(np.linalg.norm(x - meshes[k], axis=1).max()) / diag,
                    "repairs_largest": rows[k]["largest"], "seconds": seconds, "iterations": its})
    notes.append(f"ipctk barrier path (60 Newton steps at most) from the repairs' result on SCAPE meshes "
                 f"{picked}: largest move " + ", ".join(f"{o['repairs_largest']:.4f} -> {o['largest']:.4f}"
                                                         for o in out))
    return {"ipc_free": scalar(float(np.mean([o["freed"] for o in out]))),
            "ipc_largest_over_repairs": scalar(float(np.median([o["largest"] / o["repairs_largest"] for o in out]))),
            "ipc_seconds_mean": scalar(float(np.mean([o["seconds"] for o in out]))),
            "ipc_vs_repairs_seconds": scalar(float(np.mean([o["seconds"] for o in out])
                                                   / np.mean([rows[k]["seconds"] for k in picked])))}


def public_meshes(notes: list[str]) -> tuple[list, list, list[str]]:
    """The colliding public test meshes with at most PUBLIC_MAX_FACES faces, read as ``neuralcol resolve`` would."""
    import neuralcol
    from neuralcol.geometry.mesh_io import read_mesh

    root = HERE / "data" / "public"
    if not (root / "manifest.json").is_file():
        notes.append("no public test meshes (python -m bench.public_meshes fetch SOURCE ...): set skipped")
        return [], [], []
    meshes, faces, names = [], [], []
    for path in sorted(p for p in root.rglob("*") if p.suffix.lower() in (".obj", ".ply", ".off")):
        try:
            v, f = read_mesh(path)
        except Exception:
            continue  # refused files are bench.public_meshes' subject
        if len(f) > PUBLIC_MAX_FACES or not neuralcol.check(v, f).collides[0]:
            continue
        meshes.append(np.asarray(v, np.float64))
        faces.append(np.asarray(f, np.int64))
        names.append(str(Path(path).relative_to(root)))
    return meshes, faces, names


def measure(ctx: BenchContext) -> dict:
    from bench.labeler_contenders import colliding_poses
    from neuralcol.api.anymesh import labeler_for

    notes: list[str] = []
    n = 4 if ctx.quick else SCAPE_MESHES
    scape = ctx.scape.vertices.numpy().astype(np.float64)
    scape_faces = ctx.scape.faces.numpy().astype(np.int64)
    coll, recipes = colliding_poses(labeler_for(scape_faces, scape[0], clearance=False), scape, n, seed=3)
    out = {}
    fig, rows = resolve_set(list(coll), [scape_faces] * len(coll))
    out.update({f"repair_scape_{k}": v for k, v in fig.items()})
    notes.append(f"SCAPE extrapolations (i, j, t) {recipes}")
    out.update({f"repair_scape_{k}": v for k, v in ipc_beside(coll, scape_faces, rows, notes).items()})
    hand, hand_faces = _hand_poses()
    hcoll, hrec = colliding_poses(labeler_for(hand_faces, hand[0], clearance=False), hand,
                                  4 if ctx.quick else HAND_MESHES, seed=3)
    fig, _ = resolve_set(list(hcoll), [hand_faces] * len(hcoll))
    out.update({f"repair_hand_{k}": v for k, v in fig.items()})
    notes.append(f"hand (bench.newuser_hand variant b) extrapolations (i, j, t) {hrec}")
    pm, pf, names = public_meshes(notes)
    if pm:
        fig, prow = resolve_set(pm, pf)
        out.update({f"repair_public_{k}": v for k, v in fig.items()})
        notes.append("public test meshes " + ", ".join(
            f"{nm} ({'freed' if r['freed'] else 'STILL COLLIDES'}, {100 * r['largest']:.2g} %, {r['seconds']:.1f} s)"
            for nm, r in zip(names, prow)))
    ctx.notes["repair"] = "; ".join(notes)
    return out
