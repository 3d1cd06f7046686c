"""The colliding meshes the exact repairs leave colliding or move far, and what other repairs do with them.

    .venv/bin/python -m research.repair.hard_cases draw --dataset scape [--n 300] [--seed 0]
    .venv/bin/python -m research.repair.hard_cases run --dataset scape --method repairs
    .venv/bin/python -m research.repair.hard_cases run --dataset scape --method escape --only-failed repairs
    .venv/bin/python -m research.repair.hard_cases table --dataset scape

``draw`` takes ``--n`` colliding meshes (seeded) from the data set's realistic set (its CPU preset, built or read from
the cache exactly as ``research.anymesh.realistic_resolve`` does) and keeps them in the cache
(``--cache``/repair_draws/<dataset>_s<seed>.npz; the meshes, their exact PD, realistic-set rows and kinds, the faces
and the rest mesh). ``run`` resolves every drawn mesh with one method and writes one JSON of per-mesh results
(``outputs/repair/<dataset>_s<seed>_<method>.json``): freed by the exact labeler, largest and median vertex move and
the input's PD (fractions of the rest mesh's diagonal), seconds. ``--only-failed M`` resolves only the meshes method
``M``'s output left colliding (the deep cases), so a slow probe runs where it matters. ``table`` prints every method
run on a draw side by side.

Methods (each from the input mesh unless said):

* ``repairs``: ``neuralcol.repair.repair`` with its defaults (what ``neuralcol.resolve`` runs without a run);
* ``restart``: the repairs again from what ``repairs`` returned (does a second pass free what the first left?);
* ``share1``: the untangle alone with ``share: 1`` (the penetrating side moves all the way, the other stays);
* ``stiff10``: the untangle alone with a stiffer, wider field (``stiffness: 10, anchor: 0.01``: the penetrating part
  moves more as a piece);
* ``escape``: each penetrating region translated as one piece (:mod:`research.repair.escape`), the direction and
  length searched on the exact labeler's pair count, then the repairs; ``escape_fast``: the same with the 64
  directions ranked at the region's depth and only the best 6 tried at every length;
* ``directed``: each penetrating region translated as one piece while the other side of its intersection curves
  stays, along the direction whose rays leave the still surface soonest
  (:func:`research.repair.escape.directed_escape`), then the repairs; ``directed3``: that pair of steps up to three
  times, each from the last one's output;
* ``shipped`` (SCAPE only): the shipped SCAPE model's ``resolve`` (``neuralcol.pretrained("scape")``: the repairs
  first, the learned handler and the repairs again where they fail), to compare with the path without a run;
  ``shipped_least``: ``neuralcol.resolve(mesh, faces, run=shipped)``, which also takes the path without the run and
  keeps the result that frees the mesh with the smaller largest move;
* ``<method>_cap``: that method, then its freed mesh's moves from the *input* capped
  (:func:`neuralcol.repair.cap.cap_displacements`, the cap ``neuralcol.resolve`` applies, 6 bisection steps on the
  exact verdict): the repairs that follow an escape cap their own moves only, from the escaped mesh.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
BASE_METHODS = ("repairs", "restart", "share1", "stiff10", "escape", "escape_fast", "directed", "directed3")
METHODS = (*BASE_METHODS, *(f"{m}_cap" for m in BASE_METHODS[4:]), "shipped", "shipped_least")


def draw_path(cache: Path, dataset: str, seed: int) -> Path:
    return cache / "repair_draws" / f"{dataset}_s{seed}.npz"


def out_path(dataset: str, seed: int, method: str) -> Path:
    return ROOT / "outputs" / "repair" / f"{dataset}_s{seed}_{method}.json"


def draw(args) -> None:
    from research.anymesh.realistic_resolve import compose, realistic_data

    cfg = compose(args.dataset, args.cache, args.data, 2)
    d = realistic_data(cfg)
    rows = np.flatnonzero(d["pd"] > 0)
    pick = np.sort(np.random.default_rng(args.seed).choice(rows, min(args.n, len(rows)), replace=False))
    path = draw_path(args.cache, args.dataset, args.seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, meshes=d["meshes"].vertices[pick], pd=d["pd"][pick], index=pick,
                        kind=d["meshes"].kind[pick], kinds=np.array(d["kinds"]), faces=d["faces"], rest=d["rest"])
    print(f"{args.dataset}: {len(rows)} colliding of {len(d['pd'])} realistic meshes; kept {len(pick)} -> {path}")


def method_of(name: str, faces: np.ndarray, lab, rest: np.ndarray, earlier: dict | None):
    """``mesh index, mesh (V, 3) -> returned mesh (V, 3)`` for method ``name``."""
    from neuralcol.repair import RepairSettings, repair
    from neuralcol.repair.cap import cap_displacements

    if name.endswith("_cap"):
        inner = method_of(name.removesuffix("_cap"), faces, lab, rest, earlier)

        def capped(k, x):
            y = inner(k, x)
            if lab.verdict(y):
                return y
            return cap_displacements(x[None], y[None], lambda m: lab.label_batch(m).pd, 6,
                                     lambda m: np.array([lab.verdict(v) for v in m], bool))[0][0]

        return capped

    def repairs(_k, x, settings=None):
        return repair(x[None], faces, lab, settings, rest=rest).vertices[0]

    if name == "repairs":
        return repairs
    if name in ("shipped", "shipped_least"):
        import neuralcol

        run = neuralcol.pretrained("scape")
        if name == "shipped_least":
            return lambda k, x: neuralcol.resolve(x, faces, run=run).vertices[0].detach().cpu().numpy()
        return lambda k, x: run.resolve(x[None]).vertices[0].detach().cpu().numpy()
    if name == "restart":
        if earlier is None:
            raise SystemExit("--method restart needs the repairs' output: run --method repairs first (--keep)")
        return lambda k, x: repairs(k, earlier[k])
    if name in ("share1", "stiff10"):
        untangle = {"share": 1.0} if name == "share1" else {"stiffness": 10.0, "anchor": 0.01}
        settings = RepairSettings(method="untangle", untangle=untangle, retry=None)
        return lambda k, x: repairs(k, x, settings)
    if name in ("escape", "escape_fast"):
        from research.repair.escape import RegionField, escape

        field = RegionField(faces, len(rest))
        keep = 6 if name == "escape_fast" else None
        return lambda k, x: repairs(k, escape(x, lab, field, keep_dirs=keep).vertices)
    if name in ("directed", "directed3"):
        from research.repair.escape import RegionField, directed_escape

        field = RegionField(faces, len(rest))
        rounds = 3 if name == "directed3" else 1

        def directed(_k, x):
            y = x
            for _ in range(rounds):
                r = repair(directed_escape(y, faces, lab, field).vertices[None], faces, lab, rest=rest)
                y = r.vertices[0]
                if r.freed[0]:
                    break
            return y

        return directed
    raise SystemExit(f"--method {name}: use one of {', '.join(METHODS)}")


def run(args) -> None:
    from neuralcol.api.anymesh import labeler_for

    z = np.load(draw_path(args.cache, args.dataset, args.seed))
    faces, rest, meshes = z["faces"], z["rest"], z["meshes"]
    lab = labeler_for(faces, rest)
    diag = float(lab.diag)
    rows = np.arange(len(meshes))
    if args.only_failed:
        prior = json.loads(out_path(args.dataset, args.seed, args.only_failed).read_text())
        rows = np.array([m["row"] for m in prior["per_mesh"] if not m["freed"]], np.int64)
    earlier = None
    keep_dir = args.cache / "repair_draws" / "outputs"
    if args.method == "restart":
        earlier = dict(np.load(keep_dir / f"{args.dataset}_s{args.seed}_repairs.npz"))
        earlier = {int(k): earlier["vertices"][i] for i, k in enumerate(earlier["rows"])}
    fn = method_of(args.method, faces, lab, rest, earlier)
    per, kept = [], []
    for n, k in enumerate(rows):
        x = meshes[k].astype(np.float64)
        t = time.perf_counter()
        y = np.asarray(fn(int(k), x), np.float64)
        sec = time.perf_counter() - t
        move = np.linalg.norm(y - x, axis=1)
        per.append({"row": int(k), "index": int(z["index"][k]), "kind": str(z["kinds"][z["kind"][k]]),
                    "pd_input_frac": float(z["pd"][k]) / diag, "freed": not bool(lab.verdict(y)),
                    "largest_move_frac": float(move.max()) / diag, "median_move_frac": float(np.median(move)) / diag,
                    "seconds": sec})
        kept.append(y)
        if (n + 1) % 20 == 0 or n + 1 == len(rows):
            print(f"[{args.method}] {n + 1}/{len(rows)}: freed {sum(p['freed'] for p in per)}", flush=True)
    if args.keep:
        keep_dir.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(keep_dir / f"{args.dataset}_s{args.seed}_{args.method}.npz", rows=rows,
                            vertices=np.stack(kept) if kept else np.zeros((0, *meshes.shape[1:])))
    path = out_path(args.dataset, args.seed, args.method)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"dataset": args.dataset, "seed": args.seed, "method": args.method, "only_failed": args.only_failed,
           "n_drawn": int(len(meshes)), "summary": summarize(per), "per_mesh": per}
    path.write_text(json.dumps(doc, indent=1))
    print(json.dumps(doc["summary"]))


def summarize(per: list[dict]) -> dict:
    if not per:
        return {"n": 0}
    freed = np.array([p["freed"] for p in per])
    largest = np.array([p["largest_move_frac"] for p in per])
    pd = np.array([p["pd_input_frac"] for p in per])
    sec = np.array([p["seconds"] for p in per])
    ratio = largest[freed] / pd[freed]
    return {"n": len(per), "freed": int(freed.sum()), "freed_share": float(freed.mean()),
            "median_move": float(np.median([p["median_move_frac"] for p in per])),
            "median_largest": float(np.median(largest)), "p95_largest": float(np.percentile(largest, 95)),
            "p95_largest_freed": float(np.percentile(largest[freed], 95)) if freed.any() else None,
            "move_to_depth_median_freed": float(np.median(ratio)) if freed.any() else None,
            "seconds_mean": float(sec.mean()), "seconds_max": float(sec.max())}


def table(args) -> None:
    print("| method | meshes | freed | median move | median largest | p95 largest | p95 largest, freed | "
          "largest / PD, freed (median) | s/mesh mean (max) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for path in sorted((ROOT / "outputs" / "repair").glob(f"{args.dataset}_s{args.seed}_*.json")):
        doc = json.loads(path.read_text())
        s = doc["summary"]
        if not s.get("n"):
            continue

        def pct(x):
            return "-" if x is None else f"{100 * x:.2f} %"

        scope = f"the {s['n']} `{doc['only_failed']}` left" if doc["only_failed"] else f"{s['n']} drawn"
        ratio = s["move_to_depth_median_freed"]
        print(f"| {doc['method']} | {scope} | {s['freed']}/{s['n']} | {pct(s['median_move'])} | "
              f"{pct(s['median_largest'])} | {pct(s['p95_largest'])} | {pct(s['p95_largest_freed'])} | "
              f"{'-' if ratio is None else f'{ratio:.2f}'} | {s['seconds_mean']:.2f} ({s['seconds_max']:.1f}) |")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m research.repair.hard_cases", description=__doc__.split("\n")[0])
    ap.add_argument("command", choices=("draw", "run", "table"))
    ap.add_argument("--dataset", default="scape")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n", type=int, default=300, help="draw: colliding meshes kept")
    ap.add_argument("--method", default="repairs", choices=METHODS)
    ap.add_argument("--only-failed", metavar="METHOD", help="run: only the meshes METHOD's output left colliding")
    ap.add_argument("--keep", action="store_true", help="run: keep the returned meshes (for --method restart)")
    ap.add_argument("--cache", type=Path, default=Path.home() / "neuralcol-cache")
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    args = ap.parse_args(argv)
    {"draw": draw, "run": run, "table": table}[args.command](args)


if __name__ == "__main__":
    main()
