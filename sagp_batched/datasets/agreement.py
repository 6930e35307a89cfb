"""How far our grasp labels agree with another simulator's for the same grasps (ACRONYM's, GraspGen's).

A label is "held" or "dropped". The reference is the other file's label, ours the one our simulation gave;
agreement is the share of grasps both call the same, with its 95 % Wilson interval, and Cohen's kappa
corrects it for the agreement two raters with those positive rates would reach by chance. Disagreements
are counted by the phase our simulation dropped the object in (``held`` where we held and the reference
dropped) and by the grasp's coarse region on the object (``grasp_regions``), so a systematic difference
(our fingers slip on the shake, the other's on the lift; one end of the object) shows.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..statistics import count_and_rate, wilson_interval

REGIONS = ("bottom", "middle", "top")
# The phase name of a disagreement where we held and the reference dropped.
HELD = "held"


def grasp_regions(contact_centres: np.ndarray, bounds: np.ndarray) -> list[str]:
    """Each grasp's third of the object along the longest side of its bounding box: "bottom", "middle" or
    "top", from the box's low end to its high end on that axis (an upright object's bottom is its low z).

    ``contact_centres`` (N, 3) and ``bounds`` (2, 3: lower and upper corner) in the same frame; a centre
    beyond the box counts in the nearer end third. Coarse on purpose: it depends on the box alone, not on
    how the planner divides the object into zones.
    """
    bounds = np.asarray(bounds, dtype=np.float64)
    centres = np.asarray(contact_centres, dtype=np.float64).reshape(-1, 3)
    if bounds.shape != (2, 3) or not (bounds[1] > bounds[0]).all():
        raise ValueError(f"bounds must be (2, 3) lower and upper corners with upper > lower, got {bounds.tolist()}")
    axis = int(np.argmax(bounds[1] - bounds[0]))
    fraction = (centres[:, axis] - bounds[0, axis]) / (bounds[1, axis] - bounds[0, axis])
    index = np.clip(np.floor(fraction * len(REGIONS)), 0, len(REGIONS) - 1).astype(int)
    return [REGIONS[i] for i in index]


def cohen_kappa(reference: np.ndarray, ours: np.ndarray) -> float | None:
    """Cohen's kappa of two boolean raters; None where chance agreement is 1 (both gave one label only)."""
    reference, ours = np.asarray(reference, dtype=bool), np.asarray(ours, dtype=bool)
    if len(reference) == 0:
        return None
    observed = float(np.mean(reference == ours))
    chance = float(reference.mean() * ours.mean() + (1 - reference.mean()) * (1 - ours.mean()))
    return None if chance >= 1.0 else (observed - chance) / (1.0 - chance)


def label_agreement(reference: np.ndarray, ours: np.ndarray, phases: Sequence[str], regions: Sequence[str]) -> dict[str, Any]:
    """Agreement of our labels with the reference's, grasp by grasp (all four of the same length).

    ``phases``: our failure phase per grasp ("" where we held); ``regions``: each grasp's region. Returns
    n, agreeing grasps and their share with its Wilson interval, kappa, the confusion matrix
    (reference held/dropped x ours held/dropped), each rater's share of positives, and the disagreements
    by our phase and by region (with each region's own n and agreement).
    """
    reference, ours = np.asarray(reference, dtype=bool), np.asarray(ours, dtype=bool)
    n = len(reference)
    if not len(ours) == len(phases) == len(regions) == n:
        raise ValueError(f"{n} reference labels, {len(ours)} ours, {len(phases)} phases, {len(regions)} regions: give one of each per grasp")
    agree = reference == ours
    by_phase: dict[str, int] = {}
    for phase in np.asarray(list(phases), dtype=object)[~agree]:
        by_phase[phase or HELD] = by_phase.get(phase or HELD, 0) + 1
    region_names = np.asarray(list(regions), dtype=object)
    by_region = {}
    for region in sorted(set(region_names.tolist()), key=lambda name: (REGIONS + (name,)).index(name)):
        members = region_names == region
        by_region[region] = {"n": int(members.sum()), "disagree": int((members & ~agree).sum()),
                             "agreement": float(agree[members].mean())}
    interval = wilson_interval(int(agree.sum()), n)
    return {
        "n": n,
        "agree": int(agree.sum()),
        "agreement": float(agree.mean()) if n else None,
        "agreement_ci95": list(interval) if interval is not None else None,
        "kappa": cohen_kappa(reference, ours),
        "confusion": {
            "reference_held": {"ours_held": int((reference & ours).sum()), "ours_dropped": int((reference & ~ours).sum())},
            "reference_dropped": {"ours_held": int((~reference & ours).sum()), "ours_dropped": int((~reference & ~ours).sum())},
        },
        "positive_share": {"reference": float(reference.mean()) if n else None, "ours": float(ours.mean()) if n else None},
        "disagreements_by_phase": dict(sorted(by_phase.items(), key=lambda item: -item[1])),
        "disagreements_by_region": by_region,
    }


def _share(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f} %"


def agreement_markdown(result: dict[str, Any], title: str = "Label agreement") -> str:
    """``label_agreement``'s result as a markdown section: the figures, the confusion matrix, the disagreements."""
    interval = result["agreement_ci95"]
    kappa = "undefined (one label only)" if result["kappa"] is None else f"{result['kappa']:.3f}"
    confusion = result["confusion"]
    lines = [
        f"# {title}", "",
        f"- grasps compared: {result['n']}",
        f"- agreement: {count_and_rate(result['agree'], result['n'])}"
        + (f", 95 % Wilson interval {_share(interval[0])} - {_share(interval[1])}" if interval else ""),
        f"- Cohen's kappa: {kappa}",
        f"- held: reference {_share(result['positive_share']['reference'])}, ours {_share(result['positive_share']['ours'])}",
        "", "| reference \\ ours | held | dropped |", "|---|---:|---:|",
        f"| held | {confusion['reference_held']['ours_held']} | {confusion['reference_held']['ours_dropped']} |",
        f"| dropped | {confusion['reference_dropped']['ours_held']} | {confusion['reference_dropped']['ours_dropped']} |",
        "", "## Disagreements by our failure phase", "",
        f"(`{HELD}`: we held, the reference dropped)", "", "| phase | grasps |", "|---|---:|",
    ]
    lines += [f"| {phase} | {count} |" for phase, count in result["disagreements_by_phase"].items()] or ["| - | 0 |"]
    lines += ["", "## By region (thirds along the object's longest side)", "",
              "| region | grasps | disagree | agreement |", "|---|---:|---:|---:|"]
    lines += [f"| {region} | {row['n']} | {row['disagree']} | {_share(row['agreement'])} |"
              for region, row in result["disagreements_by_region"].items()]
    return "\n".join(lines) + "\n"
