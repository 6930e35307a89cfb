"""The grasp batch owns its operations (indexing to a typed grasp, ranking, the transform to the
object frame); the trial record is one type built from typed results and serialised once."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from sagp_batched.attempt import ATTEMPT_RECORD_FIELDS, AttemptDiagnostics, PlannerPrediction
from sagp_batched.config import Config
from sagp_batched.grasps import Grasp, GraspCandidates, InvalidGraspError
from sagp_batched.semantics.zones import decompose
from sagp_batched.study.judging import GraspPlacement, TaskOutcome
from sagp_batched.study.methods import RankingInputs, get_method
from sagp_batched.study.records import ExecutedGrasps, PlanSummary, TrialRecord, TrialUnit
from sagp_batched.types import GraspAttempt, PerceivedCloud
from sagp_batched.world.objects import ObjectSpec


def _batch(n: int, seed: int = 0) -> GraspCandidates:
    rng = np.random.default_rng(seed)
    rotations = torch.tensor(Rotation.random(n, random_state=seed).as_matrix(), dtype=torch.float32)
    centres = torch.tensor(rng.uniform([0.4, -0.1, 0.65], [0.6, 0.1, 0.75], (n, 3)), dtype=torch.float32)
    width = torch.tensor(rng.uniform(0.01, 0.07, n), dtype=torch.float32)
    closing = rotations[:, :, 1]
    zeros = torch.zeros(n)
    return GraspCandidates(
        contacts=torch.stack([centres - 0.5 * width[:, None] * closing, centres + 0.5 * width[:, None] * closing], dim=1),
        closing_axis=closing, width_m=width, s_geom=torch.tensor(rng.uniform(0, 1, n), dtype=torch.float32),
        approach=rotations[:, :, 2], rotation=rotations, s_reach=torch.ones(n), ik_solution=torch.zeros(n, 7),
        zone=torch.full((n,), -1, dtype=torch.int64), s_afford=zeros, s_avoid=zeros, s_task=zeros, score=zeros,
        hand_clearance_m=torch.full((n,), 0.02), joint_path=torch.zeros(n, 19, 7),
    )


def _cloud(points: torch.Tensor, position=(0.5, 0.02, 0.63), euler_deg=(0.0, 0.0, 35.0)) -> PerceivedCloud:
    return PerceivedCloud(
        points_world=points, normals_world=torch.zeros_like(points), view_index=torch.zeros(len(points), dtype=torch.int64),
        crop_rgb=np.zeros((1, 1, 3), np.uint8), cameras=[], object_id="box", object_position_world=np.array(position),
        object_quat_xyzw=Rotation.from_euler("xyz", euler_deg, degrees=True).as_quat(),
    )


def test_indexing_gives_a_typed_grasp_and_slices_give_a_batch_that_keeps_candidate_ids():
    batch = _batch(6)
    ranked = batch.ranked_by(batch.s_geom)
    best = ranked[0]
    assert isinstance(best, Grasp) and best.candidate_id == int(torch.argmax(batch.s_geom))
    assert torch.equal(best.position, batch.position[best.candidate_id])
    assert best.terms["geom"] == pytest.approx(float(batch.s_geom.max()))
    assert best.joint_path.shape == (19, 7) and best.hand_clearance_m == pytest.approx(0.02)
    leading = ranked[:2]
    assert isinstance(leading, GraspCandidates) and leading.candidate_id.tolist() == ranked.candidate_id[:2].tolist()
    with pytest.raises(IndexError):
        ranked[6]
    # The orientation round-trips through the quaternion execution commands.
    assert np.allclose(Rotation.from_quat(best.quat_xyzw.numpy()).as_matrix(), best.rotation.numpy(), atol=1e-6)


def test_a_grasp_carries_the_zones_zoning_found_primary_first():
    rng = np.random.default_rng(4)
    side = rng.uniform(-1, 1, (4000, 3)) * [0.03, 0.03, 0.08] + [0.5, 0.0, 0.70]
    zones = decompose(torch.tensor(side, dtype=torch.float32))
    zoned = zones.zone_candidates(_batch(5))
    for i in range(5):
        grasp = zoned[i]
        primary, rated = zones.candidate_zones(zoned.position[i:i + 1])
        assert grasp.zone == zones.zone_names[int(primary[0])] == grasp.zones[0]
        assert set(grasp.zones) == {name for name, member in zip(zones.zone_names, rated[0].tolist()) if member}
        assert len(grasp.zones) == 3, "its third and its two sides"


def test_the_transform_to_the_object_frame_agrees_with_the_clouds_pose_and_keeps_the_grasp_rigid():
    batch = _batch(8)
    cloud = _cloud(torch.zeros(0, 3))
    in_object = batch.transform(cloud.object_from_world, "object")
    assert batch.frame == "world" and in_object.frame == "object" and in_object[0].frame == "object"
    assert "contacts_object" in in_object[0].record() and "contacts_world" in batch[0].record()
    expected = cloud.in_object_frame(batch.contacts.double().numpy().reshape(-1, 3)).reshape(8, 2, 3)
    assert np.allclose(in_object.contacts.numpy(), expected, atol=1e-9)
    # Moving to the object frame and back is the identity; rotations stay rotations.
    back = in_object.transform(np.linalg.inv(cloud.object_from_world), "world")
    assert torch.allclose(back.rotation, batch.rotation.double(), atol=1e-6)
    assert torch.allclose(back.approach, batch.approach.double(), atol=1e-6)
    assert torch.allclose(torch.linalg.det(in_object.rotation), torch.ones(8, dtype=torch.float64), atol=1e-6)
    with pytest.raises(ValueError, match="rigid"):
        batch.transform(np.diag([2.0, 1.0, 1.0, 1.0]), "object")
    with pytest.raises(ValueError, match="frame must be one of"):
        batch.transform(cloud.object_from_world, "camera")


def test_a_grasp_given_as_a_pose_holds_its_contacts_across_its_width_and_names_bad_fields():
    quat = Rotation.from_euler("z", 30, degrees=True).as_quat()
    grasp = Grasp.from_pose([0.5, 0.0, 0.7], quat, 0.04, [0.0, 0.0, -2.0])
    assert np.allclose(grasp.position.numpy(), [0.5, 0.0, 0.7])
    assert float(torch.linalg.norm(grasp.contacts[1] - grasp.contacts[0])) == pytest.approx(0.04)
    assert np.allclose(grasp.approach.numpy(), [0.0, 0.0, -1.0])
    with pytest.raises(InvalidGraspError, match="quat_xyzw"):
        Grasp.from_pose([0.5, 0.0, 0.7], [0.0, 0.0, float("nan"), 1.0], 0.04, [0.0, 0.0, -1.0])


def test_vlm_direct_ranks_the_models_picks_first_then_every_other_candidate_geometrically():
    from test_rating_vlm_direct import ScriptedClient, candidates, cloud

    batch = candidates(25)
    zones = decompose(torch.zeros(0, 3))
    inputs = RankingInputs(zones.zone_candidates(batch), cloud(), _neutral(), zones, "mug", "t2", Config(),
                           lambda: ScriptedClient('{"ranking": [3, 1]}'))
    ranked = get_method("vd").rank(inputs)
    geometric = torch.sort(batch.s_geom, descending=True, stable=True).indices.tolist()
    assert ranked.candidate_id.tolist() == [geometric[2], geometric[0]] + [g for g in geometric if g not in (geometric[2], geometric[0])]


def _neutral():
    from sagp_batched.rating import neutral_rating

    return neutral_rating("prior", "zone_priors.json", "prior-1", 0.0, "unknown object")


SPEC = ObjectSpec("025_mug", "mug", "mug.urdf", "containers", True, 0.118, (0.117, 0.0931, 0.0813))
UNIT = TrialUnit("025_mug", "t2", 3, ("go", "sagp"))


def test_a_record_is_built_once_from_typed_results_and_serialises_every_field():
    config = Config()
    batch = _batch(4)
    grasps = [batch[1], batch[3]]
    attempts = [GraspAttempt(False, "slipped", 3.0, AttemptDiagnostics(failed_at="lift"), frames={"contact": np.zeros((2, 2, 3), np.uint8)}),
                GraspAttempt(True, None, 4.0, AttemptDiagnostics(planned_width_m=0.05))]
    placement = GraspPlacement([0.0, 0.01, 0.05], True, False, True, False)
    executed = ExecutedGrasps(grasps, attempts, placement, TaskOutcome(4.0, True, 0.0, True))
    plan = PlanSummary({"sampled": 5000, "antipodal": 40, "collision_free": 9, "ik_feasible": 9},
                       {"perception": 0.3, "geometry": 0.2, "rating": 0.0, "total_plan": 0.2}, {"backend": "prior"})
    record = TrialRecord.build(SPEC, UNIT, "sagp", config, plan=plan, executed=executed).to_json()
    assert json.loads(json.dumps(record)) == record, "plain JSON: no arrays, no tensors"
    assert (record["object"], record["task"], record["method"], record["trial"]) == ("025_mug", "t2", "sagp", 3)
    assert record["seed"] == config.scene.seed_base + 3 and record["candidate_seed"] == config.planner.seed + config.scene.seed_base + 3
    assert record["success"] and record["task_success"] and record["failure_reason"] is None and record["attempts"] == 2
    assert [entry["candidate"] for entry in record["attempt_log"]] == [1, 3] and "frames" not in record["attempt_log"][0]
    assert record["attempt_log"][1]["planned_width_m"] == 0.05
    assert record["grasp"]["midpoint_object"] == [0.0, 0.01, 0.05] and record["grasp"]["width"] == pytest.approx(float(batch.width_m[3]))
    assert record["in_preferred_zone"] and record["in_functional_region"] and not record["in_avoid_region"]
    assert record["n_candidates"]["antipodal"] == 40 and record["rating"] == {"backend": "prior"}
    assert "traceback" not in record and "frames" not in record


def _measured_everything() -> AttemptDiagnostics:
    """Diagnostics with every field measured (as a labelled collision never is, but the schema allows)."""
    return AttemptDiagnostics(
        ik_fallback="no planned path", ik_source="pybullet", descent_tracking_error_rad=1e-4, fingers_touching_after_close=True,
        finger_width_after_close_m=0.05, planned_width_m=0.052, object_motion_during_closing_linear=0.001,
        object_motion_during_closing_angular=0.01, lift_tracking_error_rad=2e-4, object_motion_during_shaking_linear=0.002,
        object_motion_during_shaking_angular=0.02, shake_achieved_peak_accelerations=(9.0, 0.0, 0.0, 0.0, 0.0, 30.0),
        failed_at="shake", distractors_max_displacement_m=0.0, object_height_above_table_m=0.2, collision_links=["panda_hand->table"],
        candidate_index=0, predicted=PlannerPrediction(reachable=True, collision_free=False, clearance_m=None),
    )


def test_an_attempt_entry_holds_exactly_the_schema_s_fields_in_order_and_never_its_images():
    batch = _batch(2)
    attempt = GraspAttempt(False, "slipped", 3.0, _measured_everything(), frames={"failed_shake": np.zeros((4, 4, 3), np.uint8)})
    executed = ExecutedGrasps([batch[1]], [attempt], GraspPlacement([0.0, 0.0, 0.05], False, False, None, None), TaskOutcome(3.0, True, 0.0, False))
    line = json.dumps(TrialRecord.build(SPEC, UNIT, "sagp", Config(), executed=executed).to_json())
    entry = json.loads(line)["attempt_log"][0]
    assert tuple(entry) == ATTEMPT_RECORD_FIELDS
    assert entry["predicted"] == {"reachable": True, "collision_free": False, "clearance_m": None}
    assert entry["shake_achieved_peak_accelerations"] == [9.0, 0.0, 0.0, 0.0, 0.0, 30.0]
    assert '"frames"' not in line and "failed_shake" not in line


def test_an_unmeasured_diagnostic_is_left_out_but_a_success_s_failed_at_is_written():
    entry = GraspAttempt(True, None, 1.0, AttemptDiagnostics(ik_source="planner", object_height_above_table_m=0.21)).record(7)
    assert entry == {"candidate": 7, "success": True, "failure_reason": None, "ik_source": "planner", "failed_at": None,
                     "object_height_above_table_m": 0.21}


def test_a_failed_trial_records_why_with_every_field_present():
    config = Config()
    executed_keys = set(TrialRecord.build(SPEC, UNIT, "go", config).to_json())
    failed = TrialRecord.build(SPEC, UNIT, "go", config, error="TrialTimeout: trial exceeded its time limit", traceback="...").to_json()
    assert set(failed) == executed_keys | {"traceback"} and failed["error"].startswith("TrialTimeout")
    assert not failed["success"] and failed["attempts"] == 0 and failed["grasp"] is None
    perception = TrialRecord.build(SPEC, UNIT, "go", config, failure_reason="perception:not_visible").to_json()
    assert perception["failure_reason"] == "perception:not_visible" and perception["error"] is None
    assert math.isclose(perception["seed"], config.scene.seed_base + 3)


def test_grasp_poses_are_one_form_for_quaternions_matrices_and_a_batch():
    from sagp_batched import GraspPoses

    batch = _batch(6)
    poses = batch.poses()
    assert poses.frame == "world" and len(poses) == 6 and poses.position.dtype == torch.float64
    assert torch.allclose(poses.approach, batch.approach.double(), atol=1e-6)
    again = GraspPoses.from_matrices(poses.matrices(), "world")
    assert torch.equal(again.position, poses.position) and torch.equal(again.rotation, poses.rotation)
    from_quats = GraspPoses.from_quat_xyzw(poses.position.numpy(), poses.quat_xyzw().numpy())
    assert torch.allclose(from_quats.rotation, poses.rotation, atol=1e-9)
    joined = GraspPoses.cat([poses, again], "world")
    assert len(joined) == 12 and len(GraspPoses.cat([], "object")) == 0
    with pytest.raises(ValueError, match="cannot be joined"):
        GraspPoses.cat([poses, batch.transform(np.eye(4), "object").poses()], "world")
    with pytest.raises(InvalidGraspError, match=r"\(N, 4, 4\)"):
        GraspPoses.from_matrices(np.eye(4), "world")
