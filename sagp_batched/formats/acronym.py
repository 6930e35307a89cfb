"""ACRONYM's HDF5 layout (Eppner et al., ICRA 2021) as this project writes it: a study trial's grasps, a dataset's
object file and a relabelled grasp file.

ACRONYM's files are read by grasp-learning code (Contact-GraspNet, GraspGen, the `acronym` tools). We keep its keys,
so those loaders read our files unchanged, and add our own fields beside them. Frames are those of `frames`:
*gripper* poses are ACRONYM's gripper frame (z = approach, x = closing axis, origin at the gripper base, the
gripper's grasp depth behind the grasp target), *base link* poses the gripper's URDF base link (`transforms @
Rz(-90 deg)`: what the engines place, for replaying in PyBullet). Lengths are metres, masses kilograms, angles radians; strings are UTF-8.
N is the number of grasps.

Keys every file holds:

| key | dtype, shape | meaning |
|---|---|---|
| `grasps/transforms` | float64 (N, 4, 4) | gripper poses: in the object's link frame (trial, dataset), in the relabelled file's own frame (relabel) |
| `grasps/base_link_transforms` | float64 (N, 4, 4) | the same grasps as base link poses |
| `grasps/qualities/flex/object_in_gripper` | int8 (trial) or int64, (N,) | 1 the grasp held the object, 0 it dropped it: an outcome, never a default (grasps not tested are kept apart) |
| `object/file` | string | the visual mesh, relative to the mesh root the reader is given ("" for a primitive visual) |
| `object/scale` | float64 | the mesh's uniform scale (1.0 for every YCB and imported object; a relabelled file's own) |
| `object/mesh_to_link` | float64 (4, 4) | mesh vertices -> link frame, the scale included (`frames.mesh_reference`); a loader applying only `object/scale` gets the link frame exactly where this is a uniform scale |
| `object/id` | string | the object's id |
| `object/mass` | float64 | kg |
| `gripper/type` | string | the gripper that made the grasps: "franka_panda", "robotiq_2f_85" or "robotiq_2f_140" (files written before grippers were data: "panda" for the Franka's) |

**A study trial's grasps** (`trial_file_bytes`; `grasps/<object>_<task>_<trial>.h5` of a study run). The grasps
some method executed are under `grasps/`; every candidate the planner scored is under `candidates/`, in the planner's
order, so a loader reading `grasps/` never takes an untested grasp for a failure. Both groups hold:

| key | dtype, shape | meaning |
|---|---|---|
| `transforms`, `base_link_transforms` | float64 (N, 4, 4) | as above |
| `width` | float32 (N,) | contact width, m |
| `contacts` | float64 (N, 2, 3) | the two contacts in the link frame, m; contact 0 at gripper -x |
| `zone` | string (N,) | the zone the grasp's contacts lie in |
| `qualities/terms/geom`, `qualities/terms/reach` | float32 (N,) | the geometric and reachability scores |
| `qualities/<method>/{score,afford,avoid,task}` | float32 (N,) | each method's score and its terms |

and besides: `grasps/qualities/flex/object_in_gripper` int8 (N,) (held by any method's attempt),
`grasps/executed/<method>` int8 (N,) (-1 not executed by that method, 0 dropped, 1 held), `grasps/candidate_index`
int64 (N,) (the grasp's row in `candidates/`), `candidates/tested` int8 (C,) (-1 untested, 0 dropped, 1 held) and
`object/urdf` (string, the URDF relative to the objects root).

**A dataset's object file** (`write_object_file`; `grasps/<object>.h5` of a dataset), grasps in the link frame:

| key | dtype, shape | meaning |
|---|---|---|
| `grasps/qualities/flex/held_fraction` | float64 (N,) | share of the grasp's simulations (its pose and its perturbed copies) that held; 0 where geometry decided |
| `grasps/qualities/flex/object_motion_during_{closing,shaking}_{linear,angular}` | float64 (N,) | the object's motion in the hand, m and rad |
| `grasps/qualities/flex/object_in_hand_{after_closing,at_verdict}` | float64 (N, 7) | the object's centre-of-mass pose in the hand's grasp target frame (y = closing axis; position m, xyzw quaternion) at the close's end and when the label was decided; NaN where not reached |
| `grasps/qualities/<engine>/{object_in_gripper, held_fraction, failure_reason}` | int64, float64, string (N,) | each engine's own label; `object_in_gripper` is held in all of them |
| `engines` | string (E,) | the engines that labelled the grasps |
| `grasps/qualities/terms/{geom,reach}` | float64 (N,) | the planner's scores |
| `grasps/width` | float64 (N,) | contact width, m |
| `grasps/contacts` | float64 (N, 2, 3) | contacts in the link frame, m |
| `grasps/resting_pose` | int64 (N,) | the resting pose (and capture) the grasp was planned on |
| `grasps/verdict`, `grasps/verdict_reason` | string (N,) | the planner's verdict on the grasp and why |
| `grasps/failure_reason` | string (N,) | why the grasp dropped the object; "" where held |
| `grasps/decided_by` | string (N,) | "simulation", or "geometry" where the open hand already intersects the object or the table |
| `grasps/zone` | string (N,) | the grasp's zone |
| `grasps/zone_rating/<task>` | string (N,) | the zone's level for the task from the rater named in `rater`; "" unrated |
| `untested/transforms`, `untested/reason` | float64 (U, 4, 4), string (U,) | grasps whose simulation could not run, and why: never labels |
| `object/{density, friction, volume}` | float64 | kg/m^3, the contact friction coefficient, m^3 |
| `object/com`, `object/inertia` | float64 (3,), (3, 3) | centre of mass in the link frame (m); inertia about it, link axes (kg m^2) |
| `mode`, `protocol`, `rater` | string | hand or arm labels, the labelling protocol, the zone rater |

**A relabelled file** (`relabel_file_bytes`; `relabel.h5` of a relabel run): the grasps as the relabelled file gives
them (its mesh, scale and frame, so its readers read both alike), our label as `object_in_gripper`:

| key | dtype, shape | meaning |
|---|---|---|
| `grasps/link_transforms` | float64 (N, 4, 4) | the same gripper poses in our imported object's link frame: what we simulated |
| `grasps/source_index` | int64 (N,) | each grasp's row in the relabelled file |
| `grasps/reference/object_in_gripper` | int64 (N,) | the file's own label |
| `grasps/held_fraction` | float64 (N,) | share of our simulations that held |
| `grasps/simulated` | int64 (N,) | 1 simulated, 0 decided by geometry |
| `grasps/failure_reason`, `grasps/failed_at` | string (N,) | how and in which phase our simulation dropped the object |
| `grasps/region` | string (N,) | the grasp's third of the object: bottom, middle, top |
| `grasps/qualities/<engine>/{object_in_gripper, failed_at, failure_cause}` | int64, string, string (N,) | with several engines, each one's own label; how it lost the object (`datasets.disagreement_causes`: knocked out, torsion, slip, other; "" held) |
| `grasps/width` | float64 (N,) | contact width where the file gives it, m |
| `object/mesh_to_link` | float64 (4, 4) | `diag(scale, scale, scale, 1)`: the file's frame is the scaled mesh's |
| `object/link_from_file` | float64 (4, 4) | rigid, the file's frame -> our object's link frame |
| `protocol`, `engine` | string | our labelling protocol and engine(s) |
| `reference/file`, `reference/format` | string | the relabelled file and its format ("acronym" or "graspgen") |
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..grasps import GraspCandidates
from ..types import GraspAttempt, PerceivedCloud
from ..world.objects import ObjectSpec
from ..robot.gripper_description import GripperDescription
from .frames import acronym_gripper_transforms_object, base_link_transforms_object, mesh_reference
from .grasp_file import FLEX, GraspFile
from .hdf5 import hdf5_bytes, write_hdf5
from .object_grasps import LabelledGrasps, ObjectPhysics, UntestedGrasps

# A candidate no simulation has run: kept under ``candidates/`` only, never as a grasp label.
UNTESTED = -1


def _outcomes(n: int, ranked_by_method: dict[str, GraspCandidates], attempts_by_method: dict[str, Sequence[GraspAttempt]]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(C,) outcome over every method's attempts (held once is held) and each method's own, in the planner's order."""
    outcome = np.full(n, UNTESTED, dtype=np.int8)
    executed_by_method = {}
    for method, ranked in ranked_by_method.items():
        executed = np.full(n, UNTESTED, dtype=np.int8)
        for candidate, attempt in zip(ranked.candidate_id.tolist(), attempts_by_method.get(method, ())):
            executed[candidate] = int(attempt.success)
            outcome[candidate] = max(outcome[candidate], int(attempt.success))
        executed_by_method[method] = executed
    return outcome, executed_by_method


def trial_file_bytes(
    spec: ObjectSpec,
    cloud: PerceivedCloud,
    candidates: GraspCandidates,
    ranked_by_method: dict[str, GraspCandidates],
    attempts_by_method: dict[str, Sequence[GraspAttempt]],
    gripper: GripperDescription,
) -> bytes:
    """One study trial's grasps as the bytes of an HDF5 file: the executed ones under ``grasps/``, every scored
    candidate under ``candidates/``.

    ``candidates`` is the planner's output; ``ranked_by_method`` holds each method's ranking of them and
    ``attempts_by_method`` the outcomes of its leading grasps, in ranked order; ``gripper`` made them.
    """
    n = len(candidates)
    candidates_object = candidates.transform(cloud.object_from_world, "object")
    transforms = acronym_gripper_transforms_object(candidates_object.poses(), gripper)
    reference = mesh_reference(spec)
    outcome, executed_by_method = _outcomes(n, ranked_by_method, attempts_by_method)
    tested = np.flatnonzero(outcome != UNTESTED)
    zone_names = candidates.primary_zone_names()
    rows: dict[str, Any] = {
        "transforms": transforms, "base_link_transforms": base_link_transforms_object(transforms),
        "width": candidates.width_m.numpy(), "contacts": candidates_object.contacts.numpy(),
        "qualities/terms/geom": candidates.s_geom.numpy(), "qualities/terms/reach": candidates.s_reach.numpy(),
    }
    for method, ranked in ranked_by_method.items():
        # Methods re-rank the candidates: put their values back in the planner's order.
        ids = ranked.candidate_id.numpy()
        for term, values in (("score", ranked.score), ("afford", ranked.s_afford), ("avoid", ranked.s_avoid), ("task", ranked.s_task)):
            aligned = np.empty(n, dtype=np.float32)
            aligned[ids] = values.numpy()
            rows[f"qualities/{method}/{term}"] = aligned
    datasets: dict[str, Any] = {}
    for group, selection in (("grasps", tested), ("candidates", np.arange(n))):
        datasets.update({f"{group}/{name}": values[selection] for name, values in rows.items()})
        datasets[f"{group}/zone"] = [zone_names[i] for i in selection]
    datasets[FLEX] = outcome[tested]
    datasets["grasps/candidate_index"] = tested
    datasets.update({f"grasps/executed/{method}": executed[tested] for method, executed in executed_by_method.items()})
    datasets.update({
        "candidates/tested": outcome, "object/file": reference.mesh_file, "object/scale": reference.scale,
        "object/mesh_to_link": reference.mesh_to_link, "object/urdf": reference.urdf_file, "object/id": spec.id,
        "object/mass": float(spec.mass_kg), "gripper/type": gripper.file_name,
    })
    return hdf5_bytes(datasets)


def write_object_file(
    path: Path,
    object_id: str,
    mesh_file: str,
    mesh_scale: float,
    mesh_to_link: np.ndarray,
    physics: ObjectPhysics,
    grasps: LabelledGrasps,
    untested: UntestedGrasps,
    mode: str,
    protocol: str,
    rater: str,
    gripper: GripperDescription,
) -> None:
    """One object's labelled grasps (made by ``gripper``) as a dataset's object file at ``path``, replaced atomically."""
    flex = "grasps/qualities/flex"
    datasets: dict[str, Any] = {
        "grasps/transforms": grasps.transforms.astype(np.float64),
        "grasps/base_link_transforms": base_link_transforms_object(grasps.transforms.astype(np.float64)),
        f"{flex}/object_in_gripper": grasps.held.astype(np.int64),
        f"{flex}/held_fraction": grasps.held_fraction.astype(np.float64),
        f"{flex}/object_motion_during_closing_linear": grasps.motion_closing_linear_m.astype(np.float64),
        f"{flex}/object_motion_during_closing_angular": grasps.motion_closing_angular_rad.astype(np.float64),
        f"{flex}/object_motion_during_shaking_linear": grasps.motion_shaking_linear_m.astype(np.float64),
        f"{flex}/object_motion_during_shaking_angular": grasps.motion_shaking_angular_rad.astype(np.float64),
        **{f"{flex}/{name}": np.full((len(grasps), 7), np.nan) if poses is None else poses.astype(np.float64).reshape(-1, 7)
           for name, poses in (("object_in_hand_after_closing", grasps.object_in_hand_after_closing),
                               ("object_in_hand_at_verdict", grasps.object_in_hand_at_verdict))},
    }
    for engine, held in grasps.engine_held.items():
        datasets[f"grasps/qualities/{engine}/object_in_gripper"] = held.astype(np.int64)
        datasets[f"grasps/qualities/{engine}/held_fraction"] = grasps.engine_held_fraction[engine].astype(np.float64)
        datasets[f"grasps/qualities/{engine}/failure_reason"] = list(grasps.engine_failure[engine])
    datasets.update({
        "engines": list(grasps.engine_held), "grasps/qualities/terms/geom": grasps.s_geom.astype(np.float64),
        "grasps/qualities/terms/reach": grasps.s_reach.astype(np.float64), "grasps/width": grasps.width_m.astype(np.float64),
        "grasps/contacts": grasps.contacts.astype(np.float64), "grasps/resting_pose": grasps.resting_pose.astype(np.int64),
    })
    datasets.update({f"grasps/{name}": list(getattr(grasps, name)) for name in ("verdict", "verdict_reason", "failure_reason", "decided_by", "zone")})
    datasets.update({f"grasps/zone_rating/{task}": list(levels) for task, levels in grasps.zone_rating.items()})
    datasets.update({
        "untested/transforms": untested.transforms.astype(np.float64).reshape(-1, 4, 4), "untested/reason": list(untested.reason),
        "object/file": mesh_file, "object/scale": float(mesh_scale), "object/mesh_to_link": np.asarray(mesh_to_link, dtype=np.float64),
        "object/id": object_id, "object/mass": float(physics.mass_kg), "object/density": float(physics.density_kg_m3),
        "object/friction": float(physics.friction), "object/com": np.asarray(physics.com_m, dtype=np.float64),
        "object/inertia": np.asarray(physics.inertia_kg_m2, dtype=np.float64), "object/volume": float(physics.volume_m3),
        "gripper/type": gripper.file_name, "mode": mode, "protocol": protocol, "rater": rater,
    })
    write_hdf5(path, datasets)


def relabel_file_bytes(grasp_file: GraspFile, rows: np.ndarray, link_from_file: np.ndarray, labels: list[dict[str, Any]],
                       regions: list[str], *, object_id: str, mass_kg: float, protocol: str, engine: str,
                       gripper: GripperDescription, untested: dict[str, Any] | None = None) -> bytes:
    """A relabelled file's rows ``rows`` as HDF5 bytes: the grasps as the file gives them (its mesh, scale and frame,
    so ACRONYM's loaders and ``grasp_file.read_grasp_file`` read them as they read the file), our label as
    ``object_in_gripper`` and the file's under ``grasps/reference/``.

    ``link_from_file`` (4, 4) maps the file's frame into our object's link frame; ``labels`` hold held,
    held_fraction, simulated, failure_reason, failed_at and, with several engines, each one's under "by_engine";
    ``regions`` each grasp's region of the object. ``untested``: the file's rows no simulation tested
    ("rows", and "reason" each), written apart under ``untested/`` (their transforms, source index and
    reason), never as labels.
    """
    transforms = grasp_file.transforms[rows]
    datasets: dict[str, Any] = {
        "grasps/transforms": transforms,
        "grasps/base_link_transforms": base_link_transforms_object(transforms),
        "grasps/link_transforms": link_from_file @ transforms,
        "grasps/source_index": np.asarray(rows, dtype=np.int64),
        FLEX: np.array([label["held"] for label in labels], dtype=np.int64),
        "grasps/reference/object_in_gripper": grasp_file.labels[rows].astype(np.int64),
        "grasps/held_fraction": np.array([label["held_fraction"] for label in labels], dtype=np.float64),
        "grasps/simulated": np.array([label["simulated"] for label in labels], dtype=np.int64),
        "grasps/failure_reason": [label["failure_reason"] for label in labels],
        "grasps/failed_at": [label["failed_at"] for label in labels],
        "grasps/region": list(regions),
    }
    for engine_name in labels[0].get("by_engine", {}) if labels else ():  # several engines: each one's own label
        own = [label["by_engine"][engine_name] for label in labels]
        datasets[f"grasps/qualities/{engine_name}/object_in_gripper"] = np.array([label["held"] for label in own], dtype=np.int64)
        datasets[f"grasps/qualities/{engine_name}/failed_at"] = [label["failed_at"] for label in own]
        datasets[f"grasps/qualities/{engine_name}/failure_cause"] = [label.get("cause", "") for label in own]
    if grasp_file.width_m is not None:
        datasets["grasps/width"] = grasp_file.width_m[rows]
    if untested is not None:
        datasets.update({"untested/transforms": grasp_file.transforms[untested["rows"]].reshape(-1, 4, 4),
                         "untested/source_index": np.asarray(untested["rows"], dtype=np.int64), "untested/reason": list(untested["reason"])})
    datasets.update({
        "object/file": grasp_file.mesh_file, "object/scale": grasp_file.scale,
        "object/mesh_to_link": np.diag([grasp_file.scale] * 3 + [1.0]),  # the file's frame is the scaled mesh's
        "object/link_from_file": link_from_file, "object/id": object_id, "object/mass": float(mass_kg),
        "gripper/type": gripper.file_name, "protocol": protocol, "engine": engine,
        "reference/file": str(grasp_file.path), "reference/format": grasp_file.format,
    })
    return hdf5_bytes(datasets)
