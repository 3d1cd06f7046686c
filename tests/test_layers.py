"""The package's layers point down only: read every import in neuralcol/ (lazy ones too) and check that no module
imports a package above its own, no private name crosses a package, no stage module imports another stage module,
neuralcol never imports the entry points, and the module import graph has no cycle."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "neuralcol"

# lowest first; a module may import its own package and the packages of lower layers
LAYERS = [
    {"errors", "rundir", "resources"},
    {"utils"},
    {"geometry"},
    {"collision", "metrics"},
    {"repair"},
    {"nn"},
    {"data", "operating"},
    {"samples"},
    {"active", "handler"},
    {"lit"},
    {"diagnose"},
    {"stages"},
    {"pipeline"},
    {"api", "__init__"},
    {"cli"},
]
LAYER = {pkg: i for i, group in enumerate(LAYERS) for pkg in group}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _package(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _imports(path: Path) -> list[tuple[str, list[str], int]]:
    """(imported module, imported names, line) of every import statement in the file, lazy ones included."""
    module = _module_name(path)
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            out.append((target, [a.name for a in node.names], node.lineno))
        elif isinstance(node, ast.Import):
            out += [(a.name, [], node.lineno) for a in node.names]
    return out


def _graph() -> dict[str, list[tuple[str, list[str], int, Path]]]:
    graph = {}
    for path in sorted(ROOT.rglob("*.py")):
        graph[_module_name(path)] = [(t, names, line, path) for t, names, line in _imports(path)]
    return graph


def test_every_package_has_a_layer():
    packages = {_package(m) for m in _graph()}
    assert packages <= set(LAYER), f"add {sorted(packages - set(LAYER))} to LAYERS in {__file__}"


def test_imports_point_down_and_stay_public():
    graph, problems = _graph(), []
    for module, imports in graph.items():
        pkg = _package(module)
        for target, names, line, path in imports:
            where = f"{path.relative_to(ROOT.parent)}:{line}"
            top = target.split(".")[0]
            if top in ("experiments", "bench", "research", "tests"):
                problems.append(f"{where}: neuralcol imports the entry point {target}")
            if top != "neuralcol":
                continue
            tpkg = _package(target) if target != "neuralcol" else "__init__"
            if tpkg == pkg:
                continue
            if LAYER[tpkg] >= LAYER[pkg]:
                problems.append(f"{where}: {pkg} (layer {LAYER[pkg]}) imports {target} (layer {LAYER[tpkg]})")
            private = [n for n in names if n.startswith("_")] + [p for p in target.split(".")[1:] if p.startswith("_")]
            if private:
                problems.append(f"{where}: private {private} of another package ({target})")
    assert not problems, "\n".join(problems)


def _stage_imports(module: str, imports) -> list[str]:
    """The other stage modules ``module`` (one of ``neuralcol.stages``) imports, as ``file:line: target``."""
    out = []
    for target, names, line, path in imports:
        if target == "neuralcol.stages":  # from neuralcol.stages import detector
            hits = [f"{target}.{n}" for n in names if f"{target}.{n}" != module]
        elif target.startswith("neuralcol.stages.") and target != module:
            hits = [target]
        else:
            hits = []
        out += [f"{path.relative_to(ROOT.parent)}:{line}: {module} imports {h}" for h in hits]
    return out


def test_stage_modules_import_no_other_stage():
    """Each module of neuralcol/stages/ is one stage's logic: it imports lower layers only (shared helpers live
    there, e.g. neuralcol/samples/, neuralcol/nn/), and the pipeline (neuralcol/pipeline/) wires the stages."""
    problems = [p for module, imports in _graph().items() if _package(module) == "stages"
                for p in _stage_imports(module, imports)]
    assert not problems, "\n".join(problems)


def test_no_import_cycle():
    graph = _graph()
    modules = set(graph)
    edges = {m: sorted({t if t in modules else t.rsplit(".", 1)[0] for t, *_ in imps
                        if t.startswith("neuralcol")} & modules - {m}) for m, imps in graph.items()}
    # a package imports its parent's __init__ only through the import system: drop parent-package edges
    edges = {m: [t for t in ts if not m.startswith(t + ".")] for m, ts in edges.items()}
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for t in edges[m]:
            if state.get(t) == 1:
                return stack[stack.index(t):] + [t]
            if t not in state:
                cycle = visit(t)
                if cycle:
                    return cycle
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(modules):
        if m not in state:
            cycle = visit(m)
            assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_checker_sees_a_violation(tmp_path):
    """The import reader resolves relative and lazy imports (so the checks above can fail)."""
    f = tmp_path / "neuralcol" / "geometry" / "x.py"
    f.parent.mkdir(parents=True)
    f.write_text("def f():\n    from ..stages.detector import _private\n    import neuralcol.api\n")
    global ROOT
    saved, ROOT = ROOT, tmp_path / "neuralcol"
    try:
        found = _imports(f)
    finally:
        ROOT = saved
    assert ("neuralcol.stages.detector", ["_private"], 2) in found and ("neuralcol.api", [], 3) in found
    stage = tmp_path / "neuralcol" / "stages" / "x.py"
    stage.parent.mkdir(parents=True)
    stage.write_text("from neuralcol.stages import cascade\nfrom .realistic import f\n"
                     "from neuralcol.samples import y\n")
    ROOT = tmp_path / "neuralcol"
    try:
        imports = [(t, n, line, stage) for t, n, line in _imports(stage)]
        found = _stage_imports("neuralcol.stages.x", imports)
    finally:
        ROOT = saved
    assert [f.rsplit(" ", 1)[-1] for f in found] == ["neuralcol.stages.cascade", "neuralcol.stages.realistic"]
