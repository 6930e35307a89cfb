"""Labels from two engines: the dataset's label is held in both, each engine's own is kept, and the
report counts where they agree; a robust label stops simulating once its majority is decided."""
from __future__ import annotations

import numpy as np
import pytest

from sagp_batched.config import ConfigError, load_config
from sagp_batched.datasets import labelling
from sagp_batched.datasets.cross_engine import (agreement_report_lines, combined_labels, engine_columns, object_engine_agreement,
                                                pooled_agreement)
from sagp_batched.datasets.object_labeller import ObjectLabeller
from sagp_batched.datasets.object_plan import object_labels
from sagp_batched.datasets.protocols import GraspLabel
from sagp_batched.robot import load_gripper
from sagp_batched.world.objects import load_object_set
from tests.ycb_paths import embedded_ycb_dir

GRIPPER = load_gripper("franka_panda")


def _label(engine: str, held: bool, phase: str = "shake") -> GraspLabel:
    return GraspLabel(mode="hand", held=held, failure_reason=None if held else "slipped", failed_at=None if held else phase,
                      protocol="floating", engine=engine, held_fraction=1.0 if held else 0.0)


def test_the_combined_label_is_held_only_where_every_engine_held_and_keeps_each_engines():
    pybullet = [_label("pybullet", h) for h in (True, True, False, False)]
    mujoco = [_label("mujoco", h, "lift") for h in (True, False, True, False)]
    combined = combined_labels({"pybullet": pybullet, "mujoco": mujoco})
    assert [label.held for label in combined] == [True, False, False, False]
    # The dropping engine's fields: MuJoCo's lift where only it dropped, PyBullet's shake where it did.
    assert [label.engine for label in combined] == ["pybullet", "mujoco", "pybullet", "pybullet"]
    assert combined[1].failed_at == "lift" and combined[2].failed_at == "shake"
    held, fraction, failure = engine_columns(combined, ("pybullet", "mujoco"))
    assert held["pybullet"].tolist() == [True, True, False, False] and held["mujoco"].tolist() == [True, False, True, False]
    assert failure["mujoco"] == ["", "slipped@lift", "", "slipped@lift"] and fraction["pybullet"].tolist() == [1, 1, 0, 0]
    with pytest.raises(ValueError, match="same grasps"):
        combined_labels({"pybullet": pybullet, "mujoco": mujoco[:2]})
    with pytest.raises(ValueError, match="not mujoco's"):
        engine_columns(combined, ("mujoco", "pybullet"))


def test_agreement_counts_the_simulated_grasps_per_verdict_and_names_who_dropped_how():
    held = {"pybullet": np.array([1, 1, 0, 0, 0], bool), "mujoco": np.array([1, 0, 1, 0, 0], bool)}
    failure = {"pybullet": ["", "", "slipped@shake", "x@close", "collision@grasp_pose"],
               "mujoco": ["", "slipped@lift", "", "x@close", "collision@grasp_pose"]}
    simulated = np.array([1, 1, 1, 1, 0], bool)  # the last decided by geometry: not compared
    row = object_engine_agreement(held, failure, simulated, ["feasible", "feasible", "boundary", "boundary", "table"])
    assert (row["both_held"], row["first_only"], row["second_only"], row["both_dropped"]) == (1, 1, 1, 1)
    assert row["by_verdict"] == {"boundary": [1, 2], "feasible": [1, 2]}
    assert row["disagreements_by_phase"] == {"mujoco: slipped@lift": 1, "pybullet: slipped@shake": 1}
    assert object_engine_agreement({"pybullet": held["pybullet"]}, failure, simulated, ["feasible"] * 5) is None
    pooled = pooled_agreement([{"object": "a", "engine_agreement": row}, {"object": "b", "engine_agreement": row}])
    assert pooled["compared"] == 8 and pooled["agreement"] == 0.5 and pooled["kappa"] == pytest.approx(0.0)
    lines = "\n".join(agreement_report_lines([{"object": "a", "engine_agreement": row}]))
    assert "agreement 2/4 (50.0 %)" in lines and "| a | 2/4 (50.0 %) | 0.00 | 1 | 1 | 1 | 1 |" in lines


def test_a_robust_label_stops_once_its_majority_is_decided():
    runs = []

    class Protocol:
        def simulate(self, engine, placement, target, config):
            runs.append(target)
            return _label("pybullet", held=len(runs) != 2)  # every simulation holds but the second

    config = load_config("dataset", {"labelling": {"perturb_only_thin_margins": False}})
    targets = [object()] * 5
    outcomes = labelling._decisive_outcomes(Protocol(), None, None, targets, [None] * 5, config)
    assert len(outcomes) == 4 and labelling._majority(outcomes).held_fraction == 0.75  # H, D, H, H: three of five held
    runs.clear()
    dropped = [_label("pybullet", False)] * 2  # two decided by geometry
    outcomes = labelling._decisive_outcomes(Protocol(), None, None, targets, dropped + [None] * 3, config)
    assert [o.held for o in outcomes] == [False, False, True, False]  # the 4th simulation (2nd run) drops: three of five dropped
    assert len(runs) == 2 and not labelling._majority(outcomes).held


@pytest.mark.parametrize("colliding, held, simulations", [(3, False, 1), (2, True, 1)])
def test_copies_whose_open_hands_mostly_collide_drop_a_firm_grasp_in_every_engine(monkeypatch, colliding, held, simulations):
    """A grasp its own simulation holds firmly keeps that label, unless most of its perturbed copies put the
    open hand in the object: geometry every engine shares then decides it, with no copy simulated."""
    import contextlib
    import dataclasses

    from sagp_batched.datasets.protocols import HandTarget

    config = load_config("dataset")
    collision = GraspLabel(mode="hand", held=False, failure_reason="collision", failed_at="grasp_pose", protocol="floating", simulated=False)
    runs = []

    def geometry(protocol, placements, samples, config):
        return [[None] + [collision if k < colliding else None for k in range(len(sample) - 1)] for sample in samples]

    def simulated(protocol, engine, placement, target, config):
        runs.append(target)
        firm = _label("mujoco", True)  # no slip or turn in the shake
        return dataclasses.replace(firm, object_motion_during_shaking_linear=0.0, object_motion_during_shaking_angular=0.0)

    monkeypatch.setattr(labelling, "_geometry_verdicts", geometry)
    monkeypatch.setattr(labelling, "_simulated", simulated)
    monkeypatch.setattr(labelling, "hand_engine", lambda name, config: contextlib.nullcontext())
    target = HandTarget(np.zeros(3), np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
    label = labelling._label(labelling.label_protocol("floating"), [None], [target], config, "mujoco")[0]
    assert label.held is held and len(runs) == simulations
    # Decided after the pose and the colliding copies: one held of four, or the pose's own firm label.
    assert label.held_fraction == (0.25 if colliding > 2 else 1.0)


def test_engines_are_checked_and_arm_mode_stays_pybullets():
    assert load_config("dataset", overrides={"dataset": {"engines": ["pybullet", "mujoco"]}}).dataset.engines == ("pybullet", "mujoco")
    with pytest.raises(ConfigError, match="unknown engine 'flex'"):
        load_config("dataset", overrides={"dataset": {"engines": ["flex"]}})
    with pytest.raises(ConfigError, match="arm mode"):
        load_config("dataset", overrides={"dataset": {"engines": ["mujoco"], "mode": "arm"}})


def test_a_dataset_labelled_in_both_engines_keeps_each_label(tmp_path):
    config = load_config("dataset", overrides={
        "dataset": {"captures_per_object": 1, "protocol": "floating", "engines": ["pybullet", "mujoco"], "boundary_fraction": 0.5},
        "planner": {"n_pairs": 3000}, "labelling": {"perturbed_simulations": 1, "hand_urdf_cache_dir": str(tmp_path)}})
    labeller = ObjectLabeller(config, load_object_set(embedded_ycb_dir()))
    try:
        plan = labeller.plan_object("005_tomato_soup_can", 6)
        labels = object_labels(plan, [labeller.simulate(chunk) for chunk in plan.chunks("hand", 100)], GRIPPER, config.dataset.engines)
    finally:
        labeller.close()
    grasps = labels.grasps
    assert set(grasps.engine_held) == {"pybullet", "mujoco"} and len(grasps) == 6
    assert (grasps.held == (grasps.engine_held["pybullet"] & grasps.engine_held["mujoco"])).all()
    assert labels.engine_seconds["pybullet"] > 0 and labels.engine_seconds["mujoco"] > 0
    assert all(f == "" for f, h in zip(grasps.engine_failure["mujoco"], grasps.engine_held["mujoco"]) if h)
