"""A dataset's manifest, split files and report: the figures a person checks before training on it.

``report.md``: per object, the labelled grasps, the share held, how many are distinct at 1 cm /
20 deg, success by the planner's verdict (its calibration), the semantics' source; overall, the
negatives' share, the hand-vs-arm agreement where it was measured and, with two engines, their
agreement and disagreements by cause (``disagreement_causes``). Plots: success by verdict,
per-object rates, and one picture per object of its labelled grasps on the mesh (held green,
dropped red), drawn the way ACRONYM's grasp viewer draws its gripper markers.
"""
from __future__ import annotations

import collections
import json
from pathlib import Path
from typing import Any

import numpy as np

from ..config import Config
from ..robot.description import robot_of
from ..run_directory import write_json
from ..statistics import count_and_rate
from .cross_engine import LABEL_RULE, agreement_report_lines, diverged_text
from .dataset_directory import read_progress, split_of, write_splits
from .disagreement_causes import cause_counts, causes_table_lines, dataset_disagreements, write_cause_pictures
from .verdicts import VERDICTS

MANIFEST_FILE = "manifest.json"
AGREEMENT_FILE = "agreement.json"
# ACRONYM's Franka gripper marker (its create_gripper_marker): finger tubes at x = +-0.041 m from
# z = 0.066 to 0.112 m, a crossbar at z = 0.066 m and a stem down to the gripper base.
_MARKER_SEGMENTS = np.array([
    [[0.041, 0.0, 0.066], [0.041, 0.0, 0.112]],
    [[-0.041, 0.0, 0.066], [-0.041, 0.0, 0.112]],
    [[-0.041, 0.0, 0.066], [0.041, 0.0, 0.066]],
    [[0.0, 0.0, 0.0], [0.0, 0.0, 0.066]],
])
PICTURE_MAX_GRASPS = 120
PICTURE_MAX_FACES = 4000
PICTURE_MARGIN_M = 0.06


def _verdict_totals(entries: list[dict[str, Any]]) -> dict[str, list[int]]:
    totals = {verdict: [0, 0] for verdict in VERDICTS}
    for entry in entries:
        for verdict, (held, total) in entry["by_verdict"].items():
            totals[verdict][0] += held
            totals[verdict][1] += total
    return {verdict: counts for verdict, counts in totals.items() if counts[1]}


def _object_rows(entries: list[dict[str, Any]]) -> list[str]:
    lines = ["| object | labelled | held | held on octants | distinct at 1 cm / 20 deg | untested | decided by geometry | unanimous | "
             "hulls / mesh volume | " + " | ".join(VERDICTS) + " | semantics |",
             "|---|---|---|---|---|---|---|---|---|" + "---|" * len(VERDICTS) + "---|"]
    for entry in entries:
        by_verdict = entry["by_verdict"]
        cells = [count_and_rate(*by_verdict[v]) if v in by_verdict else "-" for v in VERDICTS]
        semantics = "neutral: " + "; ".join(f"{t} {why}" for t, why in entry["neutral_tasks"].items()) if entry["neutral_tasks"] else entry["rater"]
        lines.append(f"| {entry['object']} | {entry['labelled']} | {count_and_rate(entry['held'], entry['labelled'])} | "
                     f"{entry.get('held_octants', '-')}/8 | {count_and_rate(entry['distinct_1cm_20deg'], entry['labelled'])} | {entry['untested']} | "
                     f"{count_and_rate(entry['decided_by_geometry'], entry['labelled'])} | {count_and_rate(entry['unanimous'], entry['labelled'])} | "
                     f"{_hull_cell(entry['hull_fidelity'])} | " + " | ".join(cells) + f" | {semantics} |")
    return lines


def _hull_cell(fidelity: dict | None) -> str:
    if fidelity is None:
        return "shipped hulls"
    cell = f"{fidelity['volume_ratio']:.2f}x, {1000 * fidelity['max_distance_m']:.1f} mm"
    return cell if fidelity["ok"] else f"**{cell}: past the bound**"


def _agreement_lines(out_dir: Path) -> list[str]:
    path = out_dir / AGREEMENT_FILE
    if not path.exists():
        return ["Hand-vs-arm agreement was not measured for this dataset (`--agreement N` measures it)."]
    agreement = json.loads(path.read_text())
    lines = [f"Hand-vs-arm agreement, the same grasps simulated in both modes (grasps both executed): "
             f"{count_and_rate(agreement['agree'], agreement['both_tested'])}; {agreement['compared']} compared, "
             f"{agreement['compared'] - agreement['both_tested']} left out because one mode could not execute them.", "",
             "| object | compared | both executed | agree | hand held | arm held |", "|---|---|---|---|---|---|"]
    for object_id, row in sorted(agreement["by_object"].items()):
        lines.append(f"| {object_id} | {row['compared']} | {row['both_tested']} | {count_and_rate(row['agree'], row['both_tested'])} | "
                     f"{row['hand_held']} | {row['arm_held']} |")
    return lines


def shortfall_text(entry: dict[str, Any]) -> str:
    """Why an object holds fewer grasps than asked, as the report and the run's last lines say it."""
    return f"{entry['object']}: {entry['shortfall']} ({entry['labelled']} labelled, {entry['untested']} untested)"


def _summed(counts) -> dict[str, int]:
    """Per-key sums of dicts of counts, keys counted zero kept."""
    total: collections.Counter = collections.Counter()
    for count in counts:
        total.update(count)
    return dict(total)


def _summary(entries: list[dict[str, Any]]) -> dict[str, Any]:
    labelled = sum(e["labelled"] for e in entries)
    held = sum(e["held"] for e in entries)
    distinct = sum(e["distinct_1cm_20deg"] for e in entries)
    return {"objects": len(entries), "labelled": labelled, "held": held, "negatives": labelled - held,
            "negative_share": (labelled - held) / labelled if labelled else None,
            "distinct_share": distinct / labelled if labelled else None,
            "untested": sum(e["untested"] for e in entries), "by_verdict": _verdict_totals(entries),
            "diverged": _summed(e.get("diverged", {}) for e in entries),
            "short": {e["object"]: shortfall_text(e) for e in entries if e.get("shortfall")},
            "decided_by_geometry": sum(e["decided_by_geometry"] for e in entries),
            "unanimous_share": sum(e["unanimous"] for e in entries) / labelled if labelled else None,
            "hulls_past_bound": [e["object"] for e in entries if e["hull_fidelity"] and not e["hull_fidelity"]["ok"]],
            "seconds_per_object": float(np.median([sum(e["times_s"].values()) for e in entries])) if entries else None}


def write_dataset_report(out_dir: Path, config: Config, objects, object_ids: list[str]) -> dict[str, Any]:
    """Write splits, ``manifest.json``, ``report.md`` and its pictures for the finished objects; return the manifest."""
    progress = read_progress(out_dir)
    entries = [progress[object_id] for object_id in object_ids if object_id in progress]
    valid_fraction = config.dataset.valid_fraction
    splits = write_splits(out_dir, {e["object"]: e["mesh"] for e in entries}, valid_fraction)
    summary = _summary(entries)
    manifest = {
        "format": {"grasps": "grasps/<object>.h5 (ACRONYM layout, see sagp_batched/formats/acronym.py)",
                   "graspgen": "graspgen/<object>.json", "meshes": "meshes/", "splits": "splits/{train,valid}.txt"},
        "conventions": {
            "frame": "object link frame; ACRONYM Franka gripper: z approach, x closing axis, origin 0.105 m behind the contacts",
            "object_in_gripper": "1 held after lift and shake in most of the grasp's simulations (held_fraction), 0 dropped; "
                                 "decided_by 'geometry' rows are collisions of the open hand at the grasp, not simulated; "
                                 "untested grasps are under untested/"
                                 + (f"; {LABEL_RULE}" if len(config.dataset.engines) > 1 else ""),
        },
        "engines": list(config.dataset.engines),
        "mode": config.dataset.mode, "protocol": config.dataset.protocol, "grasps_per_object": config.dataset.grasps_per_object,
        "robust_labels": {"simulations_per_label": config.labelling.perturbed_simulations,
                          "perturbation_translation_m": config.labelling.perturbation_translation_m,
                          "perturbation_rotation_deg": config.labelling.perturbation_rotation_deg},
        "rater": sorted({e["rater"] for e in entries}),
        "semantics": {e["object"]: ({"neutral": e["neutral_tasks"]} if e["neutral_tasks"] else {"rated": e["rater"]}) for e in entries},
        "objects": [{"id": e["object"], "grasps": f"grasps/{e['object']}.h5", "graspgen": f"graspgen/{e['object']}.json",
                     "mesh": e["mesh"], "split": split_of(e["object"], valid_fraction), "labelled": e["labelled"], "held": e["held"]}
                    for e in entries],
        "skipped_objects": [list(item) for item in getattr(objects, "skipped", [])],
        "missing_objects": [object_id for object_id in object_ids if object_id not in progress],
        "summary": summary, "splits": {name: len(files) for name, files in splits.items()},
    }
    write_json(out_dir / MANIFEST_FILE, manifest)
    pictures = _write_pictures(out_dir, entries)
    plots = _write_plots(out_dir, entries, summary)
    markdown = _report_markdown(out_dir, manifest, summary, entries, pictures, plots, _causes_lines(out_dir, config, objects, entries))
    (out_dir / "report.md").write_text(markdown, encoding="utf-8")
    return manifest


def _causes_lines(out_dir: Path, config: Config, objects, entries: list[dict[str, Any]]) -> list[str]:
    """The engine disagreements by cause (``disagreement_causes``) with a picture of one of each; none with one engine."""
    engines = next((entry["engine_agreement"]["engines"] for entry in entries if entry.get("engine_agreement")), None)
    if engines is None:
        return []
    knock_tolerance_m = config.execution.knock_tolerance_m
    found = dataset_disagreements(out_dir, entries, knock_tolerance_m)
    drawn = write_cause_pictures(out_dir, found, objects, robot_of(config).gripper)
    pictures = {cause: path.relative_to(out_dir).as_posix() for cause, path in drawn.items()}
    counts = cause_counts([d.dropped_by for d in found], [d.cause for d in found], engines)
    return ["", *causes_table_lines(counts, engines, knock_tolerance_m, pictures)]


def _report_markdown(out_dir, manifest, summary, entries, pictures, plots, causes_lines) -> str:
    by_verdict = summary["by_verdict"]
    lines = [
        "# Grasp dataset report", "",
        f"Mode: `{manifest['mode']}`, protocol `{manifest['protocol']}`; {summary['objects']} objects, {summary['labelled']} labelled grasps "
        f"({summary['held']} held, {summary['negatives']} dropped: {100 * (summary['negative_share'] or 0):.1f} % negatives), "
        f"{100 * (summary['distinct_share'] or 0):.1f} % distinct at 1 cm / 20 deg, {summary['untested']} untested (not labels; "
        f"{diverged_text(summary['diverged'], manifest['engines'])}). "
        f"Median time per object: {summary['seconds_per_object'] or 0:.1f} s.", "",
        *([f"Objects with fewer grasps than the {manifest['grasps_per_object']} asked:", "", *[f"- {line}" for line in summary["short"].values()], ""]
          if summary["short"] else [f"Every object has the {manifest['grasps_per_object']} grasps asked planned.", ""]),
        f"Each label is the majority of {manifest['robust_labels']['simulations_per_label']} simulation(s), its pose and copies moved "
        f"{1000 * manifest['robust_labels']['perturbation_translation_m']:.0f} mm / {manifest['robust_labels']['perturbation_rotation_deg']:g} deg; "
        f"unanimous: {100 * (summary['unanimous_share'] or 0):.1f} %. Decided by geometry (the open hand in the object or the "
        f"table at the grasp, not simulated): {count_and_rate(summary['decided_by_geometry'], summary['labelled'])}. "
        f"Collision hulls past the fidelity bound: {', '.join(summary['hulls_past_bound']) or 'none'}.", "",
        "## Success by planner verdict (the planner's calibration)", "",
        "| verdict | held / labelled |", "|---|---|",
        *[f"| {verdict} | {count_and_rate(*counts)} |" for verdict, counts in by_verdict.items()], "",
        "## Per object", "", *_object_rows(entries), "",
        "## Hand vs arm", "", *_agreement_lines(out_dir), "",
        "## Engines", "", *agreement_report_lines(entries), *causes_lines, "",
    ]
    if manifest["skipped_objects"]:
        lines += ["## Objects that could not serve", "", *[f"- `{path}`: {why}" for path, why in manifest["skipped_objects"]], ""]
    skipped_captures = [(e["object"], why) for e in entries for why in e.get("skipped_captures", [])]
    if skipped_captures:
        lines += ["## Captures that gave no labels", "", *[f"- `{object_id}` {why}" for object_id, why in skipped_captures], ""]
    lines += ["## Plots", "", *[f"![{p.stem}]({p.relative_to(out_dir).as_posix()})" for p in plots], ""]
    lines += ["## Labelled grasps on each object (held green, dropped red)", "",
              *[f"![{p.stem}]({p.relative_to(out_dir).as_posix()})" for p in pictures], ""]
    return "\n".join(lines)


def _write_plots(out_dir: Path, entries: list[dict[str, Any]], summary: dict[str, Any]) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plots_dir = out_dir / "plots"
    plots_dir.mkdir(exist_ok=True)
    written = []
    by_verdict = summary["by_verdict"]
    figure, axis = plt.subplots(figsize=(6, 3.5))
    names = list(by_verdict)
    axis.bar(names, [held / total for held, total in by_verdict.values()], color="tab:green")
    for index, (held, total) in enumerate(by_verdict.values()):
        axis.text(index, held / total + 0.02, f"{held}/{total}", ha="center", fontsize=8)
    axis.set_ylim(0, 1.1)
    axis.set_ylabel("held after the shake")
    axis.set_title("Success by planner verdict")
    figure.tight_layout()
    written.append(plots_dir / "success_by_verdict.png")
    figure.savefig(written[-1], dpi=110)
    plt.close(figure)
    figure, axis = plt.subplots(figsize=(max(6, 0.4 * len(entries)), 3.5))
    axis.bar([e["object"] for e in entries], [e["held"] / e["labelled"] if e["labelled"] else 0 for e in entries])
    axis.set_ylim(0, 1)
    axis.set_ylabel("held / labelled")
    axis.tick_params(axis="x", rotation=60, labelsize=7)
    axis.set_title("Positive rate per object")
    figure.tight_layout()
    written.append(plots_dir / "positive_rate_by_object.png")
    figure.savefig(written[-1], dpi=110)
    plt.close(figure)
    return written


def _write_pictures(out_dir: Path, entries: list[dict[str, Any]]) -> list[Path]:
    """Each object's labelled grasps, and where two engines disagree on some, those grasps alone."""
    pictures_dir = out_dir / "pictures"
    pictures_dir.mkdir(exist_ok=True)
    written = []
    for entry in entries:
        h5_path = out_dir / "grasps" / f"{entry['object']}.h5"
        written.append(draw_object_grasps(h5_path, out_dir / "meshes", pictures_dir / f"{entry['object']}.png"))
        engines = entry.get("engine_agreement")
        if engines and engines["first_only"] + engines["second_only"]:
            written.append(draw_object_grasps(h5_path, out_dir / "meshes", pictures_dir / f"{entry['object']}_engines.png",
                                              tuple(engines["engines"])))
    return written


def _marker_colours(f, engines: tuple[str, str] | None) -> tuple[np.ndarray, np.ndarray, str]:
    """Which grasps a picture draws, their colours (RGBA) and its caption: every grasp, held green and
    dropped red; or, for two ``engines``, the grasps they disagree on, orange held in the first only
    and blue in the second only."""
    if engines is None:
        held = f["grasps/qualities/flex/object_in_gripper"][()].astype(bool)
        return (np.arange(len(held)), np.where(held[:, None], [[0.1, 0.7, 0.2, 0.8]], [[0.85, 0.1, 0.1, 0.8]]),
                f"{int(held.sum())} held, {int((~held).sum())} dropped (of {len(held)}")
    first, second = (f[f"grasps/qualities/{engine}/object_in_gripper"][()].astype(bool) for engine in engines)
    differ = np.flatnonzero(first != second)
    return (differ, np.where(first[differ, None], [[0.95, 0.55, 0.0, 0.9]], [[0.1, 0.35, 0.9, 0.9]]),
            f"{engines[0]} only held {int((first & ~second).sum())} (orange), {engines[1]} only {int((~first & second).sum())} (blue) (of {len(first)}")


def draw_object_grasps(h5_path: Path, meshes_dir: Path, picture: Path, engines: tuple[str, str] | None = None) -> Path:
    """The object's mesh (scaled as the file says) with up to ``PICTURE_MAX_GRASPS`` of its labelled
    grasps as gripper markers: held green, dropped red; or where ``engines`` disagree (``_marker_colours``)."""
    import h5py
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import trimesh
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    with h5py.File(h5_path, "r") as f:
        transforms = f["grasps/transforms"][()]
        drawable, marker_colours, caption = _marker_colours(f, engines)
        mesh_file, scale = f["object/file"][()].decode(), float(f["object/scale"][()])
    mesh = trimesh.load(meshes_dir / mesh_file, force="mesh")
    mesh.apply_scale(scale)
    rng = np.random.default_rng(0)
    faces = mesh.faces if len(mesh.faces) <= PICTURE_MAX_FACES else mesh.faces[rng.choice(len(mesh.faces), PICTURE_MAX_FACES, replace=False)]
    order = rng.permutation(len(drawable))[:PICTURE_MAX_GRASPS]
    shown = drawable[order]
    segments = np.einsum("nij,skj->nski", transforms[shown, :3, :3], _MARKER_SEGMENTS) + transforms[shown, None, None, :3, 3]
    colours = np.repeat(marker_colours[order], len(_MARKER_SEGMENTS), axis=0)
    figure = plt.figure(figsize=(6, 6))
    axis = figure.add_subplot(projection="3d")
    axis.add_collection3d(Poly3DCollection(mesh.vertices[faces], facecolor=(0.7, 0.7, 0.75, 0.35), edgecolor="none"))
    if len(shown):
        axis.add_collection3d(Line3DCollection(segments.reshape(-1, 2, 3), colors=colours, linewidths=0.8))
    # Framed on the object with a gripper's length around it: markers reaching further are cut, not the object shrunk.
    centre, half = mesh.bounds.mean(axis=0), mesh.extents.max() / 2 + PICTURE_MARGIN_M
    for setter, c in zip((axis.set_xlim, axis.set_ylim, axis.set_zlim), centre):
        setter(c - half, c + half)
    axis.view_init(elev=30, azim=-60)
    axis.set_title(f"{h5_path.stem}: {caption}; {len(shown)} drawn)", fontsize=8)
    axis.set_axis_off()
    figure.subplots_adjust(left=0, right=1, bottom=0, top=0.95)
    figure.savefig(picture, dpi=100)
    plt.close(figure)
    return picture
