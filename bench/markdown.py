"""``bench/results.md``: the results of :mod:`bench.run` as a Markdown table."""

from __future__ import annotations

from pathlib import Path


def write_markdown(results: dict, path: Path) -> None:
    """One row per summarized key (median, min, max, reps), then one table per series (e.g. ``scaling``) and one
    per set of targets (a dict of ``{"key", "target", "value", "met"}``, e.g. ``labeler_targets``)."""
    lines = [
        "# Benchmark results",
        "",
        f"Date {results['date']}, {results['cores']} cores, {results['machine']}, torch {results['torch']}. "
        f"Command: `{results['command']}`. Each figure: median, min and max over the repetitions; ratios "
        "come from numbers measured in the same run. Sections (date, seconds): "
        + ", ".join(f"{k} ({v['date']}, {v['seconds']})" for k, v in results.get("sections", {}).items()) + ".",
        "",
        *[f"- {k}: {v}" for k, v in results.get("notes", {}).items()],
        "",
        "| key | median | min | max | reps |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for key, d in results["details"].items():
        if "median" in d:
            lines.append(f"| `{key}` | {d['median']:.4g} | {d['min']:.4g} | {d['max']:.4g} | {d['reps']} |")
    for key, d in results["details"].items():
        if is_targets(d):
            lines += ["", f"`{key}`:", "", "| key | target | value | met |", "| --- | --- | ---: | --- |"]
            for t in d.values():
                value = "n/a" if t["value"] is None else f"{t['value']:.4g}"
                met = "not measured" if t["met"] is None else ("yes" if t["met"] else "**no**")
                lines.append(f"| `{t['key']}` | {t['target']} | {value} | {met} |")
            lines.append("")
        elif "median" not in d:  # tables such as the scaling series
            n = len(next(iter(d.values())))
            cols = [c for c in d if isinstance(d[c], list) and len(d[c]) == n
                    and all(isinstance(x, (int, float)) for x in d[c])]
            lines += ["", f"`{key}`:", "", "| " + " | ".join(cols) + " |", "|" + " ---: |" * len(cols)]
            for row in zip(*(d[c] for c in cols)):
                lines.append("| " + " | ".join(f"{x:.4g}" for x in row) + " |")
            lines += [""] + [f"- {c}: {d[c]}" for c in d if c not in cols]
    path.write_text("\n".join(lines) + "\n")


def is_targets(d: dict) -> bool:
    """Whether ``d`` is a set of targets: every value a dict with ``key``, ``target``, ``value`` and ``met``."""
    return bool(d) and all(isinstance(t, dict) and {"key", "target", "value", "met"} <= set(t) for t in d.values())
