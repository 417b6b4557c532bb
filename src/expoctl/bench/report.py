"""The benchmark's outputs: leaderboard.json (everything) and leaderboard.txt (the table), written atomically.

leaderboard.json:
  benchmark:   config (where it came from), seed, render size, front ends, windows (split, city, traversal,
               label, frames), warm-up, SumLog's source, wall seconds
  controllers: {name: {label, package, module, import_path, reference}}  (reference: sees the scene)
  skipped:     {name: why it was not scored}
  leaderboard: the rows (`expoctl.bench.leaderboard.leaderboard_rows`)
  metrics:     evaluate's metrics.json object for these controllers (docs/evaluation.md)
  offline_bound: with --bound, the offline optimum per window, section and front end, its grid and paths
               (`expoctl.evaluation.offline_bound.evaluate_bounds`), else null
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from expoctl.bench.leaderboard import format_leaderboard, leaderboard_rows, with_bound


def benchmark_json(outcome, source: str) -> dict[str, Any]:
    from expoctl.bench.score import reference_names
    from expoctl.controllers.registry import controller
    from expoctl.features.registry import frontend_label

    plan, result = outcome.plan, outcome.result
    inputs = plan.inputs
    frontends = list(inputs.evaluate.frontends)
    entries = {name: controller(name) for name in plan.controllers}
    references = reference_names(plan.controllers)
    rows = leaderboard_rows(result.metrics, result.runs, frontends, {n: e.label for n, e in entries.items()},
                            references)
    rows = with_bound(rows, outcome.bound, frontends)
    render = inputs.render
    return {
        "benchmark": {
            "config": source, "seed": inputs.seed, "render_size": [render.width, render.height],
            "frontends": frontends, "frontend_labels": {fe: frontend_label(fe) for fe in frontends},
            "warmup_frames": inputs.evaluate.warmup_frames,
            "windows": [{"split": w.route_split, "city": w.city_name, "traversal": w.traversal, "label": w.label,
                         "frames": [w.start, w.stop]} for w in plan.windows],
            "sumlog": outcome.sumlog_source, "seconds": round(outcome.seconds, 3),
        },
        "controllers": {n: {"label": e.label, "package": e.package, "module": e.module,
                            "import_path": plan.references.get(n), "reference": n in references}
                        for n, e in entries.items()},
        "candidates": list(plan.candidates),
        "skipped": dict(plan.skipped),
        "leaderboard": rows,
        "metrics": result.metrics,
        "offline_bound": outcome.bound,
    }


def leaderboard_text(doc: dict[str, Any], width: int = 120) -> str:
    b = doc["benchmark"]
    head = (f"expoctl bench: {len(doc['controllers'])} controllers, {len(b['windows'])} windows, "
            f"{b['render_size'][0]}×{b['render_size'][1]}, seed {b['seed']} ({b['config']})")
    table = format_leaderboard(doc["leaderboard"], b["frontends"], b["frontend_labels"], width)
    return head[:width] + "\n\n" + table + "\n"


def write_outputs(doc: dict[str, Any], out_dir: str | Path, width: int = 120) -> str:
    """Write leaderboard.json and leaderboard.txt into `out_dir` (swapped in whole); return the table text."""
    from expoctl.io import atomic_dir, write_json

    text = leaderboard_text(doc, width)
    with atomic_dir(Path(out_dir)) as tmp:
        write_json(doc, tmp / "leaderboard.json")
        (tmp / "leaderboard.txt").write_text(text, encoding="utf-8")
    return text
