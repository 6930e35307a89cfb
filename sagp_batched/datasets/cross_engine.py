"""Labels from several engines at once (``[dataset] engines``), and how far the engines agree.

A label that one simulator gives and another does not is a property of the simulators, not of the
grasp: the dataset's label (``grasps/qualities/flex/object_in_gripper``, GraspGen's boolean) is held
only where every engine held it, and each engine's own label is kept beside it. Agreement is counted
on the grasps the engines simulated (a grasp geometry decided is the same collision in every engine),
per object, per planner verdict and overall, with Cohen's kappa; a disagreement is named by the
engine that dropped the grasp and how (``slipped@shake``), so a systematic difference shows.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..statistics import count_and_rate
from .agreement import cohen_kappa
from .protocols import GraspLabel

LABEL_RULE = ("held in every engine of `engines` (the conservative label); grasps/qualities/<engine>/ keeps each engine's "
              "label, held_fraction and failure; the flex fields (motions, held_fraction, failure_reason) are the first "
              "engine's that dropped the grasp, else the first engine's")


def combined_labels(by_engine: dict[str, list[GraspLabel]]) -> list[GraspLabel]:
    """Per grasp, the dataset's label from each engine's (lists in the same grasp order): the label of
    the first engine that dropped the grasp, else of the first engine, with every engine's in ``by_engine``;
    untested (``GraspLabel.untested``) where an engine did not test it."""
    counts = {engine: len(labels) for engine, labels in by_engine.items()}
    if len(set(counts.values())) > 1:
        raise ValueError(f"every engine labels the same grasps, got {counts}")
    combined = []
    for labels in zip(*by_engine.values()):
        deciding = next((label for label in labels if label.untested), next((label for label in labels if not label.held), labels[0]))
        combined.append(dataclasses.replace(deciding, by_engine=tuple(labels)))
    return combined


def diverged_by_engine(reasons: list[str], engines: tuple[str, ...]) -> dict[str, int]:
    """How many of the untested grasps' ``reasons`` each engine's diverged simulation made untested (the
    reason names the engine: "<engine> diverged: ...")."""
    return {engine: sum(f"{engine} diverged" in reason for reason in reasons) for engine in engines}


def diverged_text(diverged: dict[str, int], engines: tuple[str, ...] | list[str]) -> str:
    """The untested grasps whose simulation diverged, per engine of ``engines``, as the report and the run's last lines say it."""
    return "diverged and kept untested: " + ", ".join(f"{engine} {diverged.get(engine, 0)}" for engine in engines)


def failure_text(label: GraspLabel) -> str:
    """How a label failed as the files write it: "" where held, else "reason@phase"."""
    return "" if label.held else f"{label.failure_reason}@{label.failed_at}"


def engine_columns(labels: list[GraspLabel], engines: tuple[str, ...]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, list[str]]]:
    """Each engine's held, held fraction and failure per grasp of ``labels`` (one engine's labels stand for themselves)."""
    held: dict[str, np.ndarray] = {}
    fraction: dict[str, np.ndarray] = {}
    failure: dict[str, list[str]] = {}
    for index, engine in enumerate(engines):
        own = [label.by_engine[index] if label.by_engine else label for label in labels]
        if any(label.engine != engine for label in own):
            raise ValueError(f"labels are not {engine}'s: the engines are {engines}")
        held[engine] = np.array([label.held for label in own], dtype=bool)
        fraction[engine] = np.array([float(label.held) if label.held_fraction is None else label.held_fraction for label in own])
        failure[engine] = [failure_text(label) for label in own]
    return held, fraction, failure


def object_engine_agreement(held: dict[str, np.ndarray], failure: dict[str, list[str]], simulated: np.ndarray,
                            verdicts: list[str]) -> dict[str, Any] | None:
    """An object's agreement between its first two engines on its simulated grasps: the confusion
    counts, per verdict (agreeing, compared) and the disagreements by the dropping engine's failure;
    None with one engine."""
    if len(held) < 2:
        return None
    (first, first_held), (second, second_held) = list(held.items())[:2]
    simulated = np.asarray(simulated, dtype=bool)
    agree = first_held == second_held
    by_phase: dict[str, int] = {}
    for index in np.flatnonzero(simulated & ~agree):
        dropping = first if not first_held[index] else second
        key = f"{dropping}: {failure[dropping][index]}"
        by_phase[key] = by_phase.get(key, 0) + 1
    verdict_names = np.asarray(verdicts, dtype=object)
    return {
        "engines": [first, second],
        "both_held": int((simulated & first_held & second_held).sum()),
        "first_only": int((simulated & first_held & ~second_held).sum()),
        "second_only": int((simulated & ~first_held & second_held).sum()),
        "both_dropped": int((simulated & ~first_held & ~second_held).sum()),
        "by_verdict": {verdict: [int((simulated & agree & (verdict_names == verdict)).sum()), int((simulated & (verdict_names == verdict)).sum())]
                       for verdict in sorted(set(verdicts)) if (simulated & (verdict_names == verdict)).any()},
        "disagreements_by_phase": by_phase,
    }


def _kappa(counts: dict[str, int]) -> float | None:
    """Cohen's kappa of the confusion counts, as the two engines' labels they count."""
    repeats = [counts["both_held"], counts["first_only"], counts["second_only"], counts["both_dropped"]]
    return cohen_kappa(np.repeat([True, True, False, False], repeats), np.repeat([True, False, True, False], repeats))


def _row(counts: dict[str, int]) -> tuple[str, str]:
    compared = counts["both_held"] + counts["first_only"] + counts["second_only"] + counts["both_dropped"]
    kappa = _kappa(counts)
    return count_and_rate(counts["both_held"] + counts["both_dropped"], compared), "-" if kappa is None else f"{kappa:.2f}"


def pooled_agreement(entries: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The objects' engine agreements summed: confusion counts, agreement, kappa, per verdict and by phase."""
    rows = [entry["engine_agreement"] for entry in entries if entry.get("engine_agreement")]
    if not rows:
        return None
    keys = ("both_held", "first_only", "second_only", "both_dropped")
    pooled: dict[str, Any] = {"engines": rows[0]["engines"], **{key: sum(row[key] for row in rows) for key in keys}}
    compared = sum(pooled[key] for key in keys)
    pooled["compared"] = compared
    pooled["agreement"] = (pooled["both_held"] + pooled["both_dropped"]) / compared if compared else None
    pooled["kappa"] = _kappa(pooled)
    by_verdict: dict[str, list[int]] = {}
    by_phase: dict[str, int] = {}
    for row in rows:
        for verdict, (agreeing, total) in row["by_verdict"].items():
            by_verdict.setdefault(verdict, [0, 0])
            by_verdict[verdict][0] += agreeing
            by_verdict[verdict][1] += total
        for phase, count in row["disagreements_by_phase"].items():
            by_phase[phase] = by_phase.get(phase, 0) + count
    pooled["by_verdict"] = by_verdict
    pooled["disagreements_by_phase"] = dict(sorted(by_phase.items(), key=lambda item: -item[1]))
    return pooled


def agreement_report_lines(entries: list[dict[str, Any]]) -> list[str]:
    """The report's section on the engines: overall, per verdict, per object, the disagreements by phase."""
    pooled = pooled_agreement(entries)
    if pooled is None:
        return ["Labelled in one engine (`--engines pybullet,mujoco` labels every grasp in both and keeps the conservative label)."]
    first, second = pooled["engines"]
    agreement, kappa = _row(pooled)
    lines = [f"Every grasp labelled in {first} and {second}; the dataset's label is held in both. On the {pooled['compared']} grasps "
             f"the engines simulated: agreement {agreement}, Cohen's kappa {kappa}; held in {first} only: {pooled['first_only']}, "
             f"in {second} only: {pooled['second_only']}.", "",
             "| verdict | agree / simulated |", "|---|---|",
             *[f"| {verdict} | {count_and_rate(*counts)} |" for verdict, counts in pooled["by_verdict"].items()], "",
             f"| object | agreement | kappa | both held | {first} only | {second} only | both dropped |", "|---|---|---|---|---|---|---|"]
    for entry in entries:
        row = entry.get("engine_agreement")
        if row:
            agreement, kappa = _row(row)
            lines.append(f"| {entry['object']} | {agreement} | {kappa} | {row['both_held']} | {row['first_only']} | "
                         f"{row['second_only']} | {row['both_dropped']} |")
    lines += ["", "Disagreements by the engine that dropped the grasp and how:", "", "| engine: failure@phase | grasps |", "|---|---|",
              *[f"| {phase} | {count} |" for phase, count in pooled["disagreements_by_phase"].items()]]
    return lines
