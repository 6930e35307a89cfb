"""Labelled grasp datasets: for each object and resting pose, capture once, plan, and label grasps by simulation.

``ObjectLabeller.plan_object`` captures and plans each of an object's captures once for all their
grasps; ``ObjectLabeller.simulate`` labels a chunk of them; ``object_plan.object_labels`` joins the chunks.
``dataset_run.generate_dataset`` spreads plans and chunks over workers, writes each finished object at
once (``dataset_directory``) and resumes where a stopped run left off.

What a label is: the outcome of simulating the grasp (``labelling``): held after the lift and the
shake, or dropped, with the object's motion during closing and shaking. The grasps are the planner's
antipodal candidates across its verdicts (``verdicts.classify_grasps``): the feasible ones and those it
rejects, so the dataset has both classes and measures the planner's calibration. A grasp whose
simulation could not run (in ``arm`` mode: no arm solution for a grasp the planner rejected; in either
mode a simulation that diverged, ``labelling``) is kept apart as untested, never written as a failure.
"""
from __future__ import annotations

import time

from ..config import Config
from ..robot.description import robot_of
from ..seeds import capture_trial
from ..types import PerceptionFailure
from ..world.objects import ObjectSet, ObjectSpec
from .captures import Capture, PosePlan, plan_captures
from .cross_engine import combined_labels
from .object_plan import ChunkOutcome, ObjectLabels, ObjectPlan, SimulationChunk, object_labels, pose_chunks
from .protocols import label_protocol
class ObjectLabeller:
    """Plans and simulates grasps of objects in one PyBullet client: a scene, a rater, the object set.

    ``plan_object`` captures and plans each of an object's captures once for all their grasps;
    ``simulate`` labels a chunk of them. Each grasp's simulation starts from its capture's settled
    state alone, so a label is the same whichever labeller simulates it and with whichever others.
    """

    def __init__(self, config: Config, objects: ObjectSet):
        from ..rating import get_rater
        from ..world.scene import Scene

        self.config, self.objects = config, objects
        self.scene = Scene(config)
        self.rater = get_rater(config.rating)

    def close(self) -> None:
        self.scene.close()

    def _reset_to_pose(self, spec: ObjectSpec, pose_index: int) -> None:
        """Capture ``pose_index`` places the object at a fresh seeded position and yaw, in its k-th
        stable resting pose where it lists several."""
        self.scene.reset(spec, trial=capture_trial(self.config, pose_index), resting_pose=pose_index % max(1, len(spec.resting_poses)))

    def plan_object(self, object_id: str, n_grasps: int) -> ObjectPlan:
        """Plan ``n_grasps`` grasps of the object, split over its captures, and over more captures where
        those give fewer (``_plan_more``)."""
        n_poses = self.config.dataset.captures_per_object
        shares = [n_grasps // n_poses + (1 if k < n_grasps % n_poses else 0) for k in range(n_poses)]
        from .grasp_geometry import object_surface

        spec = self.objects.get(object_id)
        planned, times = self._plan_poses(spec, shares)
        shortfall = self._plan_more(spec, planned, times, n_grasps)
        poses = [pose for pose in planned if not isinstance(pose, str)]
        neutral = {}
        for pose in poses:
            neutral.update({task: (r.issues[0] if r.issues else "neutral") for task, r in pose.ratings.items() if r.is_neutral})
        rater = f"{self.rater.backend}:{getattr(self.rater, 'model', '')}"
        return ObjectPlan(object_id, poses, [pose for pose in planned if isinstance(pose, str)], rater, neutral,
                          object_surface(spec).box_centre, times, shortfall)

    def _plan_poses(self, spec: ObjectSpec, shares: list[int], earlier: list[PosePlan | str] = (),
                    spent: dict[str, float] | None = None) -> tuple[list[PosePlan | str], dict[str, float]]:
        """The captures after ``earlier`` taking ``shares`` grasps each, planned (``captures.plan_captures``:
        none the same grasp as an earlier one), or why each gave none, in capture order; with the seconds
        their resets, captures and planning took (added to ``spent``)."""
        spent = dict.fromkeys(("reset", "capture", "plan"), 0.0) if spent is None else spent
        first = len(earlier)
        captured: list[Capture | str] = [self._capture(spec, first + k, share, spent) for k, share in enumerate(shares)]
        clock = time.perf_counter()
        planned = iter(plan_captures([c for c in captured if not isinstance(c, str)], spec, self.config, self.rater, list(earlier)))
        spent["plan"] += time.perf_counter() - clock
        return [c if isinstance(c, str) else next(planned) for c in captured], spent

    def _plan_more(self, spec: ObjectSpec, planned: list[PosePlan | str], spent: dict[str, float], n_grasps: int) -> str | None:
        """Captures added to ``planned`` one at a time, each asked for the grasps still missing, until
        ``n_grasps`` are planned, ``dataset.max_captures_per_object`` are taken, or a capture finds under a
        tenth of those missing (the surface gives few more grasps distinct from those taken); None where
        the count is reached, else why not."""
        dataset = self.config.dataset
        found = sum(len(pose.candidates) for pose in planned if not isinstance(pose, str))
        while found < n_grasps and len(planned) < dataset.max_captures_per_object:
            missing = n_grasps - found
            more, _ = self._plan_poses(spec, [missing], planned, spent)
            planned += more
            new = sum(len(pose.candidates) for pose in more if not isinstance(pose, str))
            found += new
            if new < missing / 10:
                break
        if found >= n_grasps:
            return None
        distinct = f"distinct at {100 * dataset.nms_translation_m:g} cm / {dataset.nms_rotation_deg:g} deg"
        if len(planned) >= dataset.max_captures_per_object:
            return f"{found} of {n_grasps} planned in dataset.max_captures_per_object = {len(planned)} captures, each grasp {distinct}"
        return f"{found} of {n_grasps} planned: after {len(planned)} captures the surface gives no more grasps {distinct} from those taken"

    def _capture(self, spec: ObjectSpec, pose_index: int, n_grasps: int, spent: dict[str, float]) -> Capture | str:
        """Capture ``pose_index`` taken (the whole object's cloud in the floating protocol), or why it
        failed; its reset and capture seconds added to ``spent``."""
        from .grasp_geometry import object_surface, whole_object_cloud
        from .labelling import ObjectPlacement
        from ..world.perception import capture

        clock = time.perf_counter()
        self._reset_to_pose(spec, pose_index)
        spent["reset"] += time.perf_counter() - clock
        clock = time.perf_counter()
        try:
            cloud = capture(self.scene, self.config)
        except PerceptionFailure as failure:
            spent["capture"] += time.perf_counter() - clock
            return f"capture {pose_index}: {failure.reason}"
        if not label_protocol(self.config.dataset.protocol).table:
            cloud = whole_object_cloud(cloud, object_surface(spec), self.config.perception.voxel_size_m)
        spent["capture"] += time.perf_counter() - clock
        placement = ObjectPlacement.from_scene(self.scene)
        return Capture(pose_index, n_grasps, cloud, placement.com_position_world, placement.com_quat_xyzw)

    def simulate(self, chunk: SimulationChunk, mode: str | None = None) -> ChunkOutcome:
        """Label ``chunk`` in ``mode`` (default ``dataset.mode``): ``hand``, the hand alone, each grasp in a
        world of its own with the object where it settled (``labelling.label_grasps_hand``); ``arm``,
        the Panda from the capture's settled state, restored before each grasp (``labelling.label_grasps_arm``;
        a grasp the arm cannot reach is untested)."""
        from .labelling import ObjectPlacement, label_grasps_arm, label_grasps_hand

        clock = time.perf_counter()
        spec = self.objects.get(chunk.object_id)
        if (mode or self.config.dataset.mode) == "arm":
            self._reset_to_pose(spec, chunk.pose_index)
            labels = label_grasps_arm(self.scene, chunk.grasps, self.config)
            outcomes = [label if label is not None else "untested: the arm found no motion that reaches it" for label in labels]
            seconds = time.perf_counter() - clock
            return ChunkOutcome(chunk, outcomes, seconds, {"pybullet": seconds})
        placement = ObjectPlacement(spec, chunk.com_position_world, chunk.com_quat_xyzw)
        by_engine, seconds = {}, {}
        for engine in self.config.dataset.engines:
            started = time.perf_counter()
            by_engine[engine] = label_grasps_hand(placement, chunk.grasps, self.config, self.config.dataset.protocol, engine)
            seconds[engine] = time.perf_counter() - started
        outcomes = [f"untested: {label.engine} {label.untested}" if label.untested else label for label in combined_labels(by_engine)]
        return ChunkOutcome(chunk, outcomes, time.perf_counter() - clock, seconds)

    def label(self, object_id: str, n_grasps: int) -> ObjectLabels:
        """``n_grasps`` grasps of the object planned and simulated here, one chunk a capture."""
        plan = self.plan_object(object_id, n_grasps)
        chunks = plan.chunks(self.config.dataset.mode, n_grasps)
        return object_labels(plan, [self.simulate(chunk) for chunk in chunks], robot_of(self.config).gripper, self.config.dataset.engines)

    def compare_modes(self, object_id: str, n_grasps: int) -> dict[str, int]:
        """The same ``n_grasps`` grasps of the object's first capture simulated in hand and in arm mode:
        how many were compared, executed in both, agreed, and held in each."""
        pose = self._plan_poses(self.objects.get(object_id), [n_grasps])[0][0]
        if isinstance(pose, str):
            return {"compared": 0, "both_tested": 0, "agree": 0, "hand_held": 0, "arm_held": 0, "skipped": pose}
        hand, arm = ([o for chunk in pose_chunks(object_id, pose, mode, max(1, n_grasps)) for o in self.simulate(chunk, mode).outcomes]
                     for mode in ("hand", "arm"))
        both = [(h, a) for h, a in zip(hand, arm) if not isinstance(h, str) and not isinstance(a, str)]
        return {"compared": len(hand), "both_tested": len(both), "agree": sum(h.held == a.held for h, a in both),
                "hand_held": sum(h.held for h, _ in both), "arm_held": sum(a.held for _, a in both)}


def mode_agreement(config: Config, objects: ObjectSet, object_ids: list[str], n_grasps: int) -> dict:
    """Hand-vs-arm agreement on ``n_grasps`` grasps of each object of ``object_ids`` (``ObjectLabeller.compare_modes``)."""
    labeller = ObjectLabeller(config, objects)
    try:
        by_object = {object_id: labeller.compare_modes(object_id, n_grasps) for object_id in object_ids}
    finally:
        labeller.close()
    totals = {key: sum(row[key] for row in by_object.values()) for key in ("compared", "both_tested", "agree", "hand_held", "arm_held")}
    return {**totals, "grasps_per_object": n_grasps, "by_object": by_object}
