"""Run reports: ``summary.json``, ``summary.md`` (the tables a paper would print) and PNG plots."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..statistics import count_and_rate
from ..world.functional_regions import load_regions
from .methods import REGISTRY
from .metrics import per_object

RATE_METRICS = ("GSR", "FAS", "TSR", "PZA", "AC", "OP", "FRA", "FAR")
METHOD_LABELS = {name: method.label for name, method in REGISTRY.items()}


def format_rate(metrics: dict[str, Any], name: str) -> str:
    """'17/20 (85.0 %, 62.1-94.8)': counts first, so a reader sees 17/20 and not only 85 %."""
    k, n = metrics["counts"][name]
    if not n:
        return "-"
    low, high = metrics["ci95"][name]
    return f"{k}/{n} ({100 * k / n:.1f} %, {100 * low:.1f}-{100 * high:.1f})"


def _seconds(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def _label(method: str) -> str:
    return METHOD_LABELS.get(method, method)


def _task_table(summary: dict[str, Any], task: str) -> list[str]:
    lines = ["| method | trials | errors | " + " | ".join(RATE_METRICS) + " | MPT s | geometry s | rating s |",
             "|---|" + "---|" * (len(RATE_METRICS) + 5)]
    for method, by_task in summary.items():
        if task not in by_task:
            continue
        m = by_task[task]["all"]
        rates = " | ".join(format_rate(m, key) for key in RATE_METRICS)
        lines.append(f"| {_label(method)} | {m['n']} | {m['errors']} | {rates} | {_seconds(m['MPT_s'])} | {_seconds(m['geometry_s'])} "
                     f"| {_seconds(m['rating_s'])} |")
    return lines


def _neutral_ratings_lines(summary: dict[str, Any], task: str, methods: list[str]) -> list[str]:
    """How many trials each method ran on a neutral zone rating, and why; empty when none did."""
    lines = []
    for method in methods:
        m = summary[method][task]["all"]
        if m["neutral_ratings"]:
            reasons = "; ".join(f"{reason} ×{count}" for reason, count in m["neutral_rating_reasons"].items())
            lines.append(f"- {_label(method)}: {m['neutral_ratings']} of {m['n'] + m['errors']} trials: {reasons}")
    return lines


def _group_table(summary: dict[str, Any], task: str, methods: list[str]) -> list[str]:
    groups = sorted({g for method in methods for g in summary[method][task]} - {"all"})
    lines = ["| group | " + " | ".join(f"{_label(m)} GSR | {_label(m)} PZA" for m in methods) + " |", "|---|" + "---|---|" * len(methods)]
    for group in groups:
        cells = []
        for method in methods:
            metrics = summary[method][task].get(group)
            cells += [format_rate(metrics, "GSR"), format_rate(metrics, "PZA")] if metrics else ["-", "-"]
        lines.append(f"| {group} | " + " | ".join(cells) + " |")
    return lines


def _failure_table(summary: dict[str, Any], task: str, methods: list[str]) -> list[str]:
    """Failed attempts by reason@stage, one column per key any method hit, so methods compare cell by cell."""
    keys = sorted({key for method in methods for key in summary[method][task]["all"]["attempt_failures"]})
    lines = ["| method | " + " | ".join(keys + ["prediction mismatches", "attempts"]) + " |", "|---|" + "---|" * (len(keys) + 2)]
    for method in methods:
        m = summary[method][task]["all"]
        cells = [str(m["attempt_failures"].get(key, 0)) for key in keys] + [str(m["prediction_mismatches"]), str(m["n_attempts"])]
        lines.append(f"| {_label(method)} | " + " | ".join(cells) + " |")
    return lines


def _failures_list(metrics: dict[str, Any]) -> str:
    """'collision@descent×2, slipped@lift×1': compact enough for one cell per object and method."""
    return ", ".join(f"{key}×{count}" for key, count in metrics["attempt_failures"].items()) or "-"


def _count_and_rate(metrics: dict[str, Any] | None, name: str) -> str:
    """``count_and_rate`` of one metric's counts; '-' without metrics."""
    return count_and_rate(*metrics["counts"][name]) if metrics else "-"


def _functional_object_table(by_object: dict[str, Any], task: str, annotated: set[str]) -> list[str]:
    """FRA per annotated object and method; empty when no annotated object was run in ``task``."""
    methods = [m for m in by_object if task in by_object[m]]
    objects = sorted({obj for method in methods for obj in by_object[method][task]} & annotated)
    if not objects:
        return []
    lines = ["| object | " + " | ".join(f"{_label(m)} FRA" for m in methods) + " |", "|---|" + "---|" * len(methods)]
    for obj in objects:
        lines.append(f"| {obj} | " + " | ".join(_count_and_rate(by_object[m][task].get(obj), "FRA") for m in methods) + " |")
    return lines


def _object_table(by_object: dict[str, Any], task: str) -> list[str]:
    methods = [m for m in by_object if task in by_object[m]]
    objects = sorted({obj for method in methods for obj in by_object[method][task]})
    lines = ["| object | " + " | ".join(f"{_label(m)} FAS | {_label(m)} GSR | {_label(m)} failed attempts" for m in methods) + " |",
             "|---|" + "---|---|---|" * len(methods)]
    for obj in objects:
        cells = []
        for method in methods:
            metrics = by_object[method][task].get(obj)
            cells += [format_rate(metrics, "FAS"), format_rate(metrics, "GSR"), _failures_list(metrics)] if metrics else ["-", "-", "-"]
        lines.append(f"| {obj} | " + " | ".join(cells) + " |")
    return lines


def summary_markdown(summary: dict[str, Any], not_run: dict[str, str], by_object: dict[str, Any] | None = None) -> str:
    """The study's tables; ``by_object`` (``metrics.per_object``) adds a per-object table to each task."""
    lines = ["# Study summary", "", "Rates are successes/trials (rate, 95 % Wilson interval). "
             "GSR: lifted and held; FAS: lifted by the first attempt, over trials that made an attempt; "
             "TSR: the task's own success; PZA/AC/OP are over successful grasps. "
             "FRA/FAR: successful grasps on annotated objects whose contact midpoint lies in the object's "
             "functional region (handle, grip) / avoid region (rim, chuck, blades), over those grasps. "
             "MPT: mean planning time per trial in seconds (geometry + rating + ranking; perception excluded). "
             "Failed attempts are counted by reason@stage; prediction mismatches are failed attempts "
             "the planner had predicted reachable and collision-free. "
             "Trials that ended in an error (an exception or the time limit) are counted under errors, "
             "apart from failed grasps, and left out of every rate.", ""]
    tasks = sorted({task for by_task in summary.values() for task in by_task})
    for task in tasks:
        methods = [m for m in summary if task in summary[m]]
        lines += [f"## Task {task}", ""] + _task_table(summary, task)
        lines += ["", f"### Task {task} by group (GSR / PZA)", ""] + _group_table(summary, task, methods)
        lines += ["", f"### Task {task} failed attempts", ""] + _failure_table(summary, task, methods)
        neutral = _neutral_ratings_lines(summary, task, methods)
        lines += ["", f"### Task {task} neutral zone ratings", ""] + (neutral or ["none"])
        if by_object is not None:
            lines += ["", f"### Task {task} by object (FAS / GSR / failed attempts)", ""] + _object_table(by_object, task)
            functional = _functional_object_table(by_object, task, set(load_regions()))
            if functional:
                lines += ["", f"### Task {task} FRA by object", ""] + functional
        lines.append("")
    if not_run:
        lines += ["## Not run", ""] + [f"- {_label(m)}: {why}" for m, why in not_run.items()] + [""]
    return "\n".join(lines)


def write_plots(out_dir: Path, summary: dict[str, Any]) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plots_dir = out_dir / "plots"
    plots_dir.mkdir(exist_ok=True)
    written = []
    methods = list(summary)
    tasks = sorted({task for by_task in summary.values() for task in by_task})
    if not methods or not tasks:
        return written

    fig, axes = plt.subplots(1, len(tasks), figsize=(4.5 * len(tasks), 3.8), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        _method_bars(ax, {m: [(summary[m].get(task, {}).get("all"), k) for k in RATE_METRICS] for m in methods}, list(RATE_METRICS), f"Task {task}")
    written.append(_save_figure(fig, plots_dir / "methods_by_task.png"))

    fig, axes = plt.subplots(1, len(tasks), figsize=(5 * len(tasks), 3.8), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        groups = sorted({g for m in methods for g in summary[m].get(task, {})} - {"all"})
        _method_bars(ax, {m: [(summary[m].get(task, {}).get(g), "PZA") for g in groups] for m in methods}, groups, f"PZA by group, {task}")
    written.append(_save_figure(fig, plots_dir / "pza_by_category.png"))

    fig, ax = plt.subplots(figsize=(6, 3.8))
    labels = [f"{METHOD_LABELS.get(m, m)}\n{t}" for m in methods for t in tasks if t in summary[m]]
    geometry = [summary[m][t]["all"]["geometry_s"] or 0.0 for m in methods for t in tasks if t in summary[m]]
    rating = [summary[m][t]["all"]["rating_s"] or 0.0 for m in methods for t in tasks if t in summary[m]]
    ax.bar(labels, geometry, label="geometry")
    ax.bar(labels, rating, bottom=geometry, label="rating")
    ax.set_ylabel("mean planning time per trial (s)")
    ax.legend()
    written.append(_save_figure(fig, plots_dir / "planning_time.png"))
    return written


def _method_bars(ax, values_by_method: dict[str, list], labels: list[str], title: str) -> None:
    """Grouped bars of one rate per label, one bar per method, with its 95 % interval;
    values_by_method: method -> list of (group metrics or None, metric name), one per label."""
    import numpy as np

    width = 0.8 / max(1, len(values_by_method))
    x = np.arange(len(labels))
    for i, (method, values) in enumerate(values_by_method.items()):
        rates = [(m[name] or 0.0) if m else 0.0 for m, name in values]
        intervals = [m["ci95"][name] if m and m["ci95"][name] else None for m, name in values]
        errors = [[r - ci[0] if ci else 0 for ci, r in zip(intervals, rates)],
                  [ci[1] - r if ci else 0 for ci, r in zip(intervals, rates)]]
        ax.bar(x + i * width, rates, width, yerr=errors, capsize=3, label=METHOD_LABELS.get(method, method))
    ax.set_xticks(x + width * (len(values_by_method) - 1) / 2, labels, rotation=30, ha="right")
    ax.set_ylim(0, 1.05)
    ax.set_title(title)
    ax.legend(fontsize=8)


def _save_figure(fig, path: Path) -> Path:
    """Lay out ``fig``, write it to ``path`` and close it; the path."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


RATER_NOTES = {
    "prior": "an offline prior table written from common knowledge, not a VLM",
    "oracle": "UPPER BOUND: zones rated from the objects' annotated regions with the true object pose (privileged simulation knowledge), not a model",
}


def rater_note(records: list[dict[str, Any]]) -> str:
    """A line naming the zone raters behind the records (a prior or an upper bound is said to be one)."""
    backends = sorted({(r.get("rating") or {}).get("backend") for r in records} - {None})
    if not backends:
        return ""
    return "Zone rater: " + "; ".join(f"{b} ({RATER_NOTES[b]})" if b in RATER_NOTES else b for b in backends) + "\n\n"


def write_reports(out_dir: Path, records: list[dict[str, Any]], summary: dict[str, Any], not_run: dict[str, str]) -> None:
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True))
    # The failed-attempt lists use "×", which a non-UTF-8 default locale could not encode.
    markdown = summary_markdown(summary, not_run, by_object=per_object(records))
    (out_dir / "summary.md").write_text(rater_note(records) + markdown, encoding="utf-8")
    write_plots(out_dir, summary)
