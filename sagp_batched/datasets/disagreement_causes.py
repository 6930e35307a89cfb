"""Why two engines disagree on a grasp: how the engine that dropped it lost the object.

A disagreement (``cross_engine``: a simulated grasp one engine held and the other dropped) is classed
by the dropping engine's record of the object's motion (``protocols.GraspLabel``): in the world during
the close, and in the hand's grasp-target frame (y = closing axis, the contact normal) from the
close's end to the verdict, split into a turn about the contact normal, a turn about the axes of the
pad plane, and the translation of the object's point that sat at the grasp centre, in the pad plane
(x, z) and along the normal (``motion_in_hand``). The rule (``failure_cause``), first match:

- **knocked out**: the grasp failed in the close (or the approach), or the close moved the object more
  than ``execution.knock_tolerance_m``: the pads pushed it away before it was lifted;
- **torsion**: it turned at least ``TURN_MIN_DEG`` about the contact normal, more than about any axis
  of the pad plane: the weight's moment about the contacts beat the pads' torsional friction;
- **slip**: it turned less than ``TURN_MIN_DEG`` about every axis and its grasp-centre point moved
  further in the pad plane than along the normal: it slid out between the pads;
- **other**: the rest (rolled or tipped out about a pad-plane axis, pushed out along the normal, or no record).

The turn decides rather than a translation because a dropped object's verdict comes after it left the
pads: its translation then holds the fall, while its rotation, with no torque in free fall, keeps
the axis it had when it left.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

CAUSES = ("knocked out", "torsion", "slip", "other")
# The smallest turn that counts as the object turning out of the grasp. Held grasps turn a median 1 deg about
# the normal over the lift and shake, but a tenth of them past 15 deg (they pivot about the contacts and stay
# held): a turn alone does not drop a grasp, the rule only names how a drop happened.
TURN_MIN_DEG = 15.0
_MEANING = {"knocked out": "moved by the close (or failed in it)", "torsion": "turned about the contact normal",
            "slip": "slid in the pad plane without turning", "other": "rolled about a pad-plane axis, pushed out along the normal, or no record"}
PICTURE_POINTS = 1500


@dataclass(frozen=True)
class MotionInHand:
    """The object's motion in the hand from the close's end to the verdict (rad, m): its turn's rotation vector
    along the contact normal and in the pad plane, its grasp-centre point's travel in the pad plane and along the normal."""

    turn_about_normal_rad: float
    turn_other_rad: float
    slip_in_pad_plane_m: float
    slip_along_normal_m: float


def motion_in_hand(after_closing: Sequence[float] | None, at_verdict: Sequence[float] | None) -> MotionInHand | None:
    """The motion between two poses of the object in the hand (7 floats each: position, xyzw quaternion;
    ``GraspLabel.object_in_hand_*``), None where either is missing."""
    if after_closing is None or at_verdict is None:
        return None
    before, after = np.asarray(after_closing, dtype=float), np.asarray(at_verdict, dtype=float)
    if not (np.isfinite(before).all() and np.isfinite(after).all()):
        return None
    start, end = Rotation.from_quat(before[3:]), Rotation.from_quat(after[3:])
    turn = end * start.inv()  # in the hand's frame
    # Split by the turn's axis (its rotation vector along the normal and in the pad plane), not by a swing-twist
    # split, whose twist tends to half a turn for any axis off the pad plane as the turn nears half a turn.
    x, y, z = turn.as_rotvec()
    about_normal, other = abs(float(y)), float(math.hypot(x, z))
    centre_point = end.apply(start.inv().apply(-before[:3])) + after[:3]  # where the grasp centre's point of the object went
    return MotionInHand(about_normal, other, float(math.hypot(centre_point[0], centre_point[2])), float(abs(centre_point[1])))


def failure_cause(failed_at: str, closing_linear_m: float | None, after_closing: Sequence[float] | None,
                  at_verdict: Sequence[float] | None, knock_tolerance_m: float) -> str:
    """The cause (``CAUSES``) of one dropped simulation, by the module's rule."""
    if failed_at in ("close", "descent") or (closing_linear_m is not None and closing_linear_m > knock_tolerance_m):
        return "knocked out"
    motion = motion_in_hand(after_closing, at_verdict)
    if motion is None:
        return "other"
    turn_min = math.radians(TURN_MIN_DEG)
    if motion.turn_about_normal_rad >= turn_min and motion.turn_about_normal_rad > motion.turn_other_rad:
        return "torsion"
    if max(motion.turn_about_normal_rad, motion.turn_other_rad) < turn_min and motion.slip_in_pad_plane_m >= motion.slip_along_normal_m:
        return "slip"
    return "other"


def label_cause(label: Any, knock_tolerance_m: float) -> str:
    """A ``GraspLabel``'s cause, "" where it held."""
    if label.held:
        return ""
    return failure_cause(label.failed_at or "", label.object_motion_during_closing_linear, label.object_in_hand_after_closing,
                         label.object_in_hand_at_verdict, knock_tolerance_m)


def cause_counts(dropped_by: Sequence[str], causes: Sequence[str], engines: Sequence[str]) -> dict[str, dict[str, int]]:
    """Cause -> engine that dropped the grasp -> disagreements, every cause and engine present."""
    counts = {cause: {engine: 0 for engine in engines} for cause in CAUSES}
    for engine, cause in zip(dropped_by, causes):
        counts[cause][engine] += 1
    return counts


def causes_table_lines(counts: dict[str, dict[str, int]], engines: Sequence[str], knock_tolerance_m: float,
                       pictures: dict[str, str] | None = None) -> list[str]:
    """The disagreement causes table (markdown): per cause, the grasps each engine dropped that the other held."""
    pictures = pictures or {}
    lines = [f"Disagreements by cause (the dropping engine's record; rule: `datasets/disagreement_causes.py`, knocked out past "
             f"{1000 * knock_tolerance_m:g} mm in the close, turns of at least {TURN_MIN_DEG:g} deg):", "",
             "| cause | " + " | ".join(f"dropped by {engine} only" for engine in engines) + " | meaning | example |",
             "|---|" + "---|" * len(engines) + "---|---|"]
    for cause in CAUSES:
        example = f"[picture]({pictures[cause]})" if cause in pictures else "-"
        lines.append(f"| {cause} | " + " | ".join(str(counts[cause][engine]) for engine in engines) + f" | {_MEANING[cause]} | {example} |")
    return lines


# -- a dataset's disagreements ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Disagreement:
    """One grasp of a dataset's object file that one engine held and the other dropped."""

    object_id: str
    row: int
    dropped_by: str
    failure: str  # "reason@phase"
    cause: str


def _strings(values: np.ndarray) -> list[str]:
    return [value.decode() if isinstance(value, bytes) else str(value) for value in values]


def dataset_disagreements(out_dir: Path, entries: list[dict[str, Any]], knock_tolerance_m: float) -> list[Disagreement]:
    """Every disagreement of the objects ``entries`` name (progress lines with an ``engine_agreement``), classed
    from their files: the flex motions of a grasp one engine dropped are that engine's (``cross_engine.combined_labels``)."""
    import h5py

    found = []
    for entry in entries:
        if not entry.get("engine_agreement"):
            continue
        engines = entry["engine_agreement"]["engines"]
        with h5py.File(out_dir / "grasps" / f"{entry['object']}.h5", "r") as f:
            held = {engine: f[f"grasps/qualities/{engine}/object_in_gripper"][()].astype(bool) for engine in engines}
            failure = {engine: _strings(f[f"grasps/qualities/{engine}/failure_reason"][()]) for engine in engines}
            simulated = np.array(_strings(f["grasps/decided_by"][()])) == "simulation"
            flex = f["grasps/qualities/flex"]
            closing = flex["object_motion_during_closing_linear"][()]
            missing = np.full((len(closing), 7), np.nan)  # a file written before the poses were recorded
            after = flex["object_in_hand_after_closing"][()] if "object_in_hand_after_closing" in flex else missing
            verdict = flex["object_in_hand_at_verdict"][()] if "object_in_hand_at_verdict" in flex else missing
        first, second = engines
        for row in np.flatnonzero(simulated & (held[first] != held[second])):
            dropping = first if not held[first][row] else second
            closing_m = None if math.isnan(closing[row]) else float(closing[row])
            cause = failure_cause(failure[dropping][row].partition("@")[2], closing_m, after[row], verdict[row], knock_tolerance_m)
            found.append(Disagreement(entry["object"], int(row), dropping, failure[dropping][row], cause))
    return found


def write_cause_pictures(out_dir: Path, disagreements: list[Disagreement], objects: Any, gripper: Any) -> dict[str, Path]:
    """For the first disagreement of each cause, a picture (``draw_disagreement``) of the object in ``gripper``'s hand."""
    pictures_dir = out_dir / "pictures"
    pictures_dir.mkdir(exist_ok=True)
    written = {}
    for cause in CAUSES:
        example = next((d for d in disagreements if d.cause == cause), None)
        picture = pictures_dir / f"cause_{cause.replace(' ', '_')}.png"
        if example is not None:
            written[cause] = draw_disagreement(out_dir, example, objects, gripper, picture)
        else:  # a picture an earlier report of this directory drew, of a cause it no longer has
            picture.unlink(missing_ok=True)
    return written


def _object_in_hand(out_dir: Path, disagreement: Disagreement, objects: Any,
                    gripper: Any) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], dict[str, Any]]:
    """The disagreement's object in the hand's grasp-target frame as planned, at the close's end and at the verdict
    (where recorded): name -> (its surface points, its planned contacts); and the grasp's width and recorded poses."""
    import h5py
    import trimesh

    from ..execution.poses import pose_matrix
    from ..formats.frames import grasp_poses_from_acronym
    from .placements import com_in_link

    row = disagreement.row
    with h5py.File(out_dir / "grasps" / f"{disagreement.object_id}.h5", "r") as f:
        mesh_file, mesh_to_link = f["object/file"][()].decode(), f["object/mesh_to_link"][()]
        transform, contacts, width = f["grasps/transforms"][row:row + 1], f["grasps/contacts"][row], float(f["grasps/width"][row])
        recorded = {"after": f["grasps/qualities/flex/object_in_hand_after_closing"][row],
                    "verdict": f["grasps/qualities/flex/object_in_hand_at_verdict"][row]}
    mesh = trimesh.load(out_dir / "meshes" / mesh_file, force="mesh")
    vertices = mesh.vertices[np.random.default_rng(0).choice(len(mesh.vertices), min(PICTURE_POINTS, len(mesh.vertices)), replace=False)]
    points_link = vertices @ mesh_to_link[:3, :3].T + mesh_to_link[:3, 3]
    link_in_com = np.linalg.inv(com_in_link(objects.get(disagreement.object_id)))
    planned = grasp_poses_from_acronym(transform, gripper)
    link_from_hand = np.eye(4)
    link_from_hand[:3, :3], link_from_hand[:3, 3] = planned.rotation[0].numpy(), planned.position[0].numpy()
    hand_from_link = {"as planned": np.linalg.inv(link_from_hand)}
    for name, key in (("at the close's end", "after"), ("at the verdict", "verdict")):
        if np.isfinite(recorded[key]).all():
            hand_from_link[name] = pose_matrix(recorded[key][:3], recorded[key][3:]) @ link_in_com
    shown = {name: (points_link @ pose[:3, :3].T + pose[:3, 3], contacts @ pose[:3, :3].T + pose[:3, 3]) for name, pose in hand_from_link.items()}
    return shown, {"width": width, **recorded}


def draw_disagreement(out_dir: Path, disagreement: Disagreement, objects: Any, gripper: Any, picture: Path) -> Path:
    """The object's surface points in the hand's grasp-target frame as planned (grey: the hand at the grasp before
    the close), at the close's end (blue) and at the verdict (red), with the pads' centres where the grasp's width
    puts them (black), the planned contacts as they moved with the object (blue crosses) and the centre of mass's
    path from the close's end (arrow): seen along the contact normal (the pad plane) and along the hand's x."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown, recorded = _object_in_hand(out_dir, disagreement, objects, gripper)
    after, verdict = recorded["after"], recorded["verdict"]
    views = ((0, 2), (1, 2))
    colours = {"as planned": "0.6", "at the close's end": "tab:blue", "at the verdict": "tab:red"}
    figure, axes = plt.subplots(1, 2, figsize=(9, 4.6))
    pads = np.array([[0.0, -recorded["width"] / 2, 0.0], [0.0, recorded["width"] / 2, 0.0]])
    motion = motion_in_hand(after, verdict)
    for axis, (u, v) in zip(axes, views):
        for name, (points, contacts) in shown.items():
            axis.scatter(points[:, u], points[:, v], s=1.5, color=colours[name], alpha=0.35, label=f"object {name}")
            if name == "at the close's end":
                axis.scatter(contacts[:, u], contacts[:, v], marker="x", s=40, color="tab:blue", label="planned contacts at the close's end")
        axis.scatter(pads[:, u], pads[:, v], marker="s", s=40, color="black", label="pads (grasp width)")
        if motion is not None:
            axis.annotate("", xy=(verdict[u], verdict[v]), xytext=(after[u], after[v]),
                          arrowprops={"arrowstyle": "->", "color": "darkgreen", "lw": 1.5})
    for axis, u, view in zip(axes, ("x", "y, the contact normal"), ("along the contact normal (pad plane)", "along the hand's x")):
        axis.set_xlabel(f"{u} (m)")
        axis.set_ylabel("z, the approach (m)")
        axis.set_aspect("equal", adjustable="datalim")
        axis.set_title(f"seen {view}", fontsize=8)
    axes[0].legend(fontsize=6, loc="best")
    numbers = "" if motion is None else (
        f"; from the close's end: turn about the normal {math.degrees(motion.turn_about_normal_rad):.0f} deg, "
        f"other {math.degrees(motion.turn_other_rad):.0f} deg, grasp-centre point {1000 * motion.slip_in_pad_plane_m:.0f} mm "
        f"in the pad plane, {1000 * motion.slip_along_normal_m:.0f} mm along the normal")
    figure.suptitle(f"{disagreement.cause}: {disagreement.object_id} grasp {disagreement.row}, dropped by {disagreement.dropped_by} "
                    f"({disagreement.failure}){numbers}; arrow: its centre of mass", fontsize=7, wrap=True)
    figure.tight_layout()
    figure.savefig(picture, dpi=100)
    plt.close(figure)
    return picture
