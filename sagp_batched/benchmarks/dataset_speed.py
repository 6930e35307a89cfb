"""Dataset benchmark: labelled grasps per second per core, by mode, engine, protocol and worker count, and where the time goes.

Each case is the real dataset run (``dataset_run.generate_dataset``) of the objects into a fresh
directory: wall time from the first plan to the report (worker start-up included), and the per-stage
seconds the workers report (reset, capture, plan, simulate, write), summed over workers. The
per-core rate divides by wall time x workers, so idle workers (starting up, or waiting while the
only object is planned) count against it; the busy rate divides by the seconds the stages took, the
rate of a core kept busy, as in a run of many objects where one worker plans while others simulate.

``shared_world_step_cost`` measures what a PyBullet step costs per hand-object pair when several
pairs, far apart, share one world: the way to label many grasps per step where a step's fixed
cost dominates.
"""
from __future__ import annotations

import dataclasses
import statistics
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pybullet

from ..config import Config
from ..description_files import load_urdf
from ..seeds import capture_trial
from ..world.objects import ObjectSet

STAGES = ("reset", "capture", "plan", "simulate", "write")


@dataclass(frozen=True)
class DatasetCase:
    """What one benchmark case labels: the mode, and in hand mode the engine and the protocol."""

    mode: str
    grasps: int
    engine: str = "pybullet"
    protocol: str = "tabletop"

    @property
    def name(self) -> str:
        return "arm" if self.mode == "arm" else f"hand {self.engine} {self.protocol}"


def _dataset_config(config: Config, object_ids: Sequence[str], case: DatasetCase, workers: int) -> Config:
    return dataclasses.replace(
        config,
        run=dataclasses.replace(config.run, objects=tuple(object_ids), workers=workers, backend="local"),
        dataset=dataclasses.replace(config.dataset, mode=case.mode, grasps_per_object=case.grasps, engines=(case.engine,),
                                    protocol=case.protocol),
    )


def benchmark_dataset_case(config: Config, objects: ObjectSet, object_ids: Sequence[str], case: DatasetCase, workers: int) -> dict[str, Any]:
    """One dataset run of ``case.grasps`` grasps of each of ``object_ids`` on ``workers`` workers."""
    from ..datasets.dataset_run import generate_dataset

    run_config = _dataset_config(config, object_ids, case, workers)
    entries: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="sagp_dataset_bench_") as out:
        start = time.perf_counter()
        generate_dataset(run_config, objects, Path(out), progress=False, on_object=entries.append)
        wall_s = time.perf_counter() - start
    times = {stage: sum(float(entry["times_s"].get(stage, 0.0)) for entry in entries) for stage in STAGES}
    labelled = sum(int(entry["labelled"]) for entry in entries)
    simulated = sum(int(entry["labelled"]) - int(entry["decided_by_geometry"]) for entry in entries)
    return {
        "objects": list(object_ids), "case": case.name, "mode": case.mode, "engine": case.engine, "protocol": case.protocol,
        "workers": workers, "grasps": case.grasps, "labelled": labelled, "simulated": simulated,
        "untested": sum(int(entry["untested"]) for entry in entries), "held": sum(int(entry["held"]) for entry in entries), "wall_s": wall_s,
        "labels_per_s_per_core": labelled / (wall_s * workers),
        "busy_labels_per_s_per_core": labelled / sum(times.values()),
        "simulated_labels_per_s_per_core": labelled / times["simulate"] if times["simulate"] > 0 else None,
        "stage_s": times,
    }


def benchmark_dataset(config: Config, objects: ObjectSet, object_ids: Sequence[str], cases: Sequence[DatasetCase],
                      worker_counts: Sequence[int], repeats: int) -> list[dict[str, Any]]:
    """Medians over ``repeats`` of every (case, workers), the cases interleaved within each repeat
    so a busy spell on the machine falls on all of them alike."""
    runs: dict[tuple[DatasetCase, int], list[dict]] = {}
    for _ in range(repeats):
        for case in cases:
            for workers in worker_counts:
                runs.setdefault((case, workers), []).append(benchmark_dataset_case(config, objects, object_ids, case, workers))
    rows = []
    for cases_run in runs.values():
        first = cases_run[0]
        rows.append({
            **{key: first[key] for key in ("objects", "case", "mode", "engine", "protocol", "workers", "grasps", "labelled", "simulated",
                                           "untested", "held")},
            "repeats": len(cases_run),
            "wall_s": statistics.median(c["wall_s"] for c in cases_run),
            "labels_per_s_per_core": statistics.median(c["labels_per_s_per_core"] for c in cases_run),
            "busy_labels_per_s_per_core": statistics.median(c["busy_labels_per_s_per_core"] for c in cases_run),
            "simulated_labels_per_s_per_core": statistics.median(c["simulated_labels_per_s_per_core"] or 0.0 for c in cases_run),
            "stage_s": {stage: statistics.median(c["stage_s"][stage] for c in cases_run) for stage in STAGES},
        })
    return rows


def projected_hours(labels_per_s_per_core: float, objects_count: int, grasps_per_object: int, cores: int) -> float:
    """Hours for ``objects_count`` x ``grasps_per_object`` labels at a per-core rate on ``cores`` cores."""
    return objects_count * grasps_per_object / (labels_per_s_per_core * cores) / 3600.0


def shared_world_step_cost(config: Config, objects: ObjectSet, object_id: str, pair_counts: Sequence[int],
                           steps: int = 240, spacing_m: float = 3.0) -> list[dict[str, Any]]:
    """Milliseconds per PyBullet step, in total and per pair, for worlds of 1..N floating hands each
    closed on its own copy of the object (resting on its own table), the pairs ``spacing_m`` apart."""
    from ..datasets.collision_urdf import labelling_hand_urdf
    from ..datasets.labelling import ObjectPlacement
    from ..robot.description import robot_of
    from ..world.scene import Scene, command_fingers, configure_physics, create_table

    with Scene(config) as scene:
        scene.reset(objects.get(object_id), trial=capture_trial(config, pose_index=0))
        placement = ObjectPlacement.from_scene(scene)
        top_z = pybullet.getAABB(scene.target_id, physicsClientId=scene.client)[1][2]
    robot = robot_of(config)
    hand_urdf = str(labelling_hand_urdf(config))
    grasp_offset_m = robot.gripper.grasp_depth_m
    down = (1.0, 0.0, 0.0, 0.0)  # the hand's approach axis pointing at the table
    rows = []
    for count in pair_counts:
        client = pybullet.connect(pybullet.DIRECT)
        try:
            configure_physics(client, config.scene)
            for pair in range(count):
                offset = np.array([pair * spacing_m, 0.0, 0.0])
                table_xy = tuple(np.add(config.scene.table_center_xy_m, offset[:2]))
                create_table(client, dataclasses.replace(config.scene, table_center_xy_m=table_xy))
                body = load_urdf(client, placement.spec.urdf_path, flags=pybullet.URDF_USE_INERTIA_FROM_FILE)
                pybullet.resetBasePositionAndOrientation(body, list(np.add(placement.com_position_world, offset)), placement.com_quat_xyzw,
                                                         physicsClientId=client)
                # A top-down grasp 2 cm below the object's top, the hand pinned by its grasp target.
                target = [placement.com_position_world[0] + offset[0], placement.com_position_world[1], top_z - 0.02]
                hand = load_urdf(client, hand_urdf)
                inertial = pybullet.getDynamicsInfo(hand, -1, physicsClientId=client)[3:5]
                target_in_base = pybullet.multiplyTransforms(*pybullet.invertTransform(*inertial), [0.0, 0.0, grasp_offset_m], [0.0, 0.0, 0.0, 1.0])
                pybullet.resetBasePositionAndOrientation(hand, *pybullet.multiplyTransforms(target, down, *pybullet.invertTransform(*target_in_base)),
                                                         physicsClientId=client)
                pybullet.createConstraint(hand, -1, -1, -1, pybullet.JOINT_FIXED, [0.0, 0.0, 0.0], parentFramePosition=target_in_base[0],
                                          childFramePosition=target, parentFrameOrientation=target_in_base[1], childFrameOrientation=down,
                                          physicsClientId=client)
                names = {pybullet.getJointInfo(hand, j, physicsClientId=client)[1].decode(): j
                         for j in range(pybullet.getNumJoints(hand, physicsClientId=client))}
                command_fingers(client, hand, [names[n] for n in robot.gripper.finger_joints], 0.0, config.execution.gripper_force_n)
            for _ in range(steps // 4):  # the fingers close and the contacts form before the timing
                pybullet.stepSimulation(physicsClientId=client)
            contacts = len(pybullet.getContactPoints(physicsClientId=client))
            start = time.perf_counter()
            for _ in range(steps):
                pybullet.stepSimulation(physicsClientId=client)
            step_ms = (time.perf_counter() - start) / steps * 1e3
        finally:
            pybullet.disconnect(client)
        rows.append({"pairs": count, "contacts": contacts, "step_ms": step_ms, "step_ms_per_pair": step_ms / count})
    return rows
