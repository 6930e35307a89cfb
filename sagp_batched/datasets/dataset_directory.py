"""A labelled grasp dataset on disk, in the layouts grasp-learning code reads.

Layout of a dataset directory::

    grasps/<object>.h5          one file per object (and scale), ACRONYM's layout plus SAGP's fields
    graspgen/<object>.json      the same grasps in GraspGen's JSON: object file and scale, transforms,
                                boolean object_in_gripper
    meshes/<object>/<mesh>      the mesh each file names (``object/file`` is relative to meshes/)
    splits/train.txt, valid.txt object mesh paths (relative to meshes/), GraspGen's split files
    manifest.json               objects, counts, conventions, the rater, the settings
    objects.jsonl               one line per finished object: what a resumed run skips

The keys, dtypes, units and frames of the files are ``sagp_batched.formats``' (``formats.acronym``,
``formats.graspgen``), which writes them; ``write_object`` writes one finished object's files and its line.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..description_files import read_urdf_document, urdf_file_path
from ..formats.acronym import write_object_file
from ..formats.frames import grasp_poses_from_acronym, mesh_reference
from ..formats.graspgen import write_graspgen_file
from ..formats.object_grasps import ObjectPhysics
from ..robot.gripper_description import GripperDescription
from ..world.objects import METADATA_FILE, ObjectSpec, objects_root
from .cross_engine import diverged_by_engine, object_engine_agreement

if TYPE_CHECKING:
    import trimesh

    from .object_plan import ObjectLabels

OBJECTS_PROGRESS_FILE = "objects.jsonl"
# The report's coverage figure: grasps closer than this, and turned less, count as one.
DISTINCT_TRANSLATION_M = 0.01
DISTINCT_ROTATION_DEG = 20.0


def write_object(out_dir: Path, spec: ObjectSpec, labels: "ObjectLabels", mode: str, protocol: str, gripper: GripperDescription) -> dict:
    """Write one finished object (its grasps made by ``gripper``): its mesh, its ACRONYM and GraspGen files, then
    its progress line (what the report and a resume read), which is returned."""
    from sagp_batched_kernels.pose_nms import distinct_grasp_count

    clock = time.perf_counter()
    for sub in ("grasps", "graspgen", "meshes"):
        (out_dir / sub).mkdir(exist_ok=True)
    physics = object_physics(spec)
    mesh_file, scale, mesh_to_link = copy_object_mesh(spec, out_dir / "meshes")
    grasps = labels.grasps
    write_object_file(out_dir / "grasps" / f"{spec.id}.h5", spec.id, mesh_file, scale, mesh_to_link, physics,
                      grasps, labels.untested, mode, protocol, labels.rater, gripper)
    poses = grasp_poses_from_acronym(grasps.transforms, gripper)
    distinct = distinct_grasp_count(poses.position, poses.rotation, DISTINCT_TRANSLATION_M, math.radians(DISTINCT_ROTATION_DEG))
    write_graspgen_file(out_dir / "graspgen" / f"{spec.id}.json", mesh_file, scale, grasps, gripper)
    write_s = time.perf_counter() - clock
    # Whether positives spread over the object or gather on one part: how many of the eight octants of the
    # object's bounding box hold the contact midpoint of a held grasp.
    held_sides = grasps.contacts[grasps.held].mean(axis=1) > labels.surface_centre
    entry = {
        "object": spec.id, "mesh": mesh_file, "labelled": len(grasps), "held": int(grasps.held.sum()),
        "untested": len(labels.untested.reason), "diverged": diverged_by_engine(labels.untested.reason, tuple(labels.engine_seconds)),
        "shortfall": labels.shortfall,
        "distinct_1cm_20deg": distinct, "rater": labels.rater,
        "decided_by_geometry": grasps.decided_by.count("geometry"),
        "held_octants": len({tuple(side) for side in held_sides.astype(int)}),
        "unanimous": int(((grasps.held_fraction == 0.0) | (grasps.held_fraction == 1.0)).sum()),
        "hull_fidelity": spec.import_record.fidelity_summary() if spec.import_record is not None else None,
        "neutral_tasks": labels.neutral_tasks, "skipped_captures": labels.skipped_poses,
        "by_verdict": {v: [int(sum(h for h, w in zip(grasps.held, grasps.verdict) if w == v)), grasps.verdict.count(v)]
                       for v in sorted(set(grasps.verdict))},
        "times_s": {**labels.times_s, "write": write_s}, "engine_seconds": labels.engine_seconds,
        "engine_agreement": object_engine_agreement(grasps.engine_held, grasps.engine_failure,
                                                    np.array([by == "simulation" for by in grasps.decided_by], dtype=bool), grasps.verdict),
    }
    append_progress(out_dir, entry)
    return entry


def copy_object_mesh(spec: ObjectSpec, meshes_dir: Path) -> tuple[str, float, np.ndarray]:
    """Copy the object's visual mesh to ``meshes_dir/<object>/``: its path there, its scale and its
    (4, 4) mesh-to-link transform (identity for YCB and imported objects)."""
    mesh_file, _, scale, mesh_to_link = mesh_reference(spec)
    source = objects_root(Path(spec.urdf_path).resolve()) / mesh_file  # an absolute mesh_file stays itself
    target = meshes_dir / spec.id / source.name
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(source, target)
    return f"{spec.id}/{source.name}", scale, mesh_to_link


def object_physics(spec: ObjectSpec) -> ObjectPhysics:
    """What the simulator was given for ``spec``: an imported object's figures from its import
    metadata (the solid's volume and full inertia, the density that made its mass), else the
    URDF's mass, COM, inertia and friction with the volume of its collision hulls (the solid
    PyBullet collides) and density = mass / volume."""
    metadata_path = Path(spec.urdf_path).with_name(METADATA_FILE)
    if metadata_path.is_file():
        metadata = json.loads(metadata_path.read_text())
        return ObjectPhysics(float(metadata["mass_kg"]), float(metadata["density_kg_m3"]), float(metadata["friction"]),
                             tuple(metadata["com_m"]), tuple(tuple(row) for row in metadata["inertia_kg_m2"]),
                             float(metadata["volume_m3"]))
    return _urdf_physics(spec)


def _urdf_physics(spec: ObjectSpec) -> ObjectPhysics:
    import trimesh

    link = read_urdf_document(spec.urdf_path).links[0]
    inertial = link.inertial
    mass = inertial.mass_kg if inertial is not None else spec.mass_kg
    com = tuple(float(v) for v in inertial.frame_in_link[:3, 3]) if inertial is not None else (0.0, 0.0, 0.0)
    tensor = inertial.tensor_kg_m2 if inertial is not None else np.zeros((3, 3))
    inertia = tuple(tuple(float(v) for v in row) for row in tensor)
    friction = link.friction[0]
    mesh_collision = next((collision for collision in link.collisions if collision.shape == "mesh"), None)
    volume = 0.0
    if mesh_collision is not None:
        mesh = trimesh.load(urdf_file_path(spec.urdf_path, mesh_collision.filename), force="mesh")
        mesh.apply_scale(np.array(mesh_collision.scale))
        volume = float(sum(_hull_volume(part) for part in mesh.split(only_watertight=False)))
    density = mass / volume if volume > 0 else math.nan
    return ObjectPhysics(mass, density, friction, com, inertia, volume)  # type: ignore[arg-type]


def _hull_volume(part: "trimesh.Trimesh") -> float:
    """The volume of a mesh part's convex hull; a part lying in one plane (a stray triangle or
    sheet in a scanned mesh) has none, and qhull refuses to build its hull."""
    from scipy.spatial import QhullError

    try:
        return float(part.convex_hull.volume)
    except QhullError:
        return 0.0


def split_of(object_id: str, valid_fraction: float) -> str:
    """"train" or "valid" for an object, from a hash of its id: stable across runs and machines."""
    bucket = int(hashlib.sha256(object_id.encode()).hexdigest()[:8], 16) / 0xFFFFFFFF
    return "valid" if bucket < valid_fraction else "train"


def write_splits(out_dir: Path, mesh_files: dict[str, str], valid_fraction: float) -> dict[str, list[str]]:
    """GraspGen's split files: each object's mesh path (relative to meshes/) in train.txt or valid.txt."""
    splits: dict[str, list[str]] = {"train": [], "valid": []}
    for object_id, mesh_file in sorted(mesh_files.items()):
        splits[split_of(object_id, valid_fraction)].append(mesh_file)
    (out_dir / "splits").mkdir(exist_ok=True)
    for name, files in splits.items():
        (out_dir / "splits" / f"{name}.txt").write_text("".join(f"{file}\n" for file in files), encoding="utf-8")
    return splits


def read_progress(out_dir: Path) -> dict[str, dict[str, Any]]:
    """Object id -> its progress line, for the objects a previous run finished (torn lines skipped)."""
    path = out_dir / OBJECTS_PROGRESS_FILE
    finished: dict[str, dict[str, Any]] = {}
    if not path.exists():
        return finished
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        try:
            entry = json.loads(line)
        except ValueError:
            continue  # the line a killed run was writing: that object runs again
        if isinstance(entry, dict) and isinstance(entry.get("object"), str):
            finished[entry["object"]] = entry
    return finished


def append_progress(out_dir: Path, entry: dict[str, Any]) -> None:
    """Record a finished object, synced, after its files are in place."""
    with (out_dir / OBJECTS_PROGRESS_FILE).open("a", encoding="utf-8") as file:
        file.write(json.dumps(entry, sort_keys=True) + "\n")
        file.flush()
        os.fsync(file.fileno())
