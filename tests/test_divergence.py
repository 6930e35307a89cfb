"""A simulation that diverges is never a label: each engine says so (``HandEngine.diverged``), the simulation is
run again at a smaller step, and where it diverges again the grasp is untested, kept apart from the labels in
the dataset's files and counted per engine in its report and the run's last lines.

The diverging worlds are made on purpose: the MuJoCo object's mass and inertia all but zero in the compiled model
(MuJoCo warns of a singular inertia at any step), the PyBullet object thrown faster than any protocol motion
could throw it, and a bad velocity (NaN) that MuJoCo resets and carries on from."""
from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from runners import datagen
from sagp_batched.benchmarks.designed_grasps import designed_box_grasps
from sagp_batched.config import load_config
from sagp_batched.datasets import pybullet_hand
from sagp_batched.datasets.cross_engine import combined_labels
from sagp_batched.datasets.labelling import _majority, label_object_grasps
from sagp_batched.datasets.protocols import GraspLabel
from sagp_batched.grasps import GraspPoses
from sagp_batched.robot.description import load_robot

mujoco_hand = pytest.importorskip("sagp_batched.datasets.mujoco_hand", exc_type=ImportError)
h5py = pytest.importorskip("h5py")

ONE_SIMULATION = {"labelling": {"perturbed_simulations": 1}}


def _weightless_mujoco_object(hand) -> None:
    # An inertia under MuJoCo's smallest value (1e-15): its first step warns of a singular inertia matrix.
    hand.world.model.body_mass[hand.world.object_body] = 1e-12
    hand.world.model.body_inertia[hand.world.object_body] = 1e-20


def _thrown_pybullet_object(hand) -> None:
    pybullet_hand.pybullet.resetBaseVelocity(hand.target, [200.0, 0.0, 0.0], physicsClientId=hand.client)


def _nan_mujoco_velocity(hand) -> None:
    hand.data.qvel[:] = np.nan


def _diverging(monkeypatch, engine_class, spoil, only_at_the_configured_step: bool = False) -> list[int]:
    """Every world ``engine_class`` builds spoilt by ``spoil`` (at the configured step alone, where asked); the
    step divisions the builds ran at."""
    divisions: list[int] = []
    build = engine_class.build

    def spoilt(self, start):
        build(self, start)
        divisions.append(self.step_division)
        if self.step_division == 1 or not only_at_the_configured_step:
            spoil(self)

    monkeypatch.setattr(engine_class, "build", spoilt)
    return divisions


def _held_grasp(box) -> GraspPoses:
    designed = designed_box_grasps(box, load_robot())
    return GraspPoses(designed.position[:1], designed.rotation[:1], "object")


@pytest.mark.parametrize("engine, engine_class, spoil, reason", [
    ("mujoco", mujoco_hand.MuJoCoHand, _weightless_mujoco_object, "diverged: singular inertia warning"),
    ("pybullet", pybullet_hand.PyBulletHand, _thrown_pybullet_object, "diverged: object speed"),
])
def test_a_simulation_that_diverges_at_both_steps_is_untested_never_held_or_dropped(designed_box, monkeypatch, engine, engine_class,
                                                                                    spoil, reason):
    divisions = _diverging(monkeypatch, engine_class, spoil)
    (label,) = label_object_grasps(designed_box, _held_grasp(designed_box), None, "floating", load_config(None, ONE_SIMULATION), engine=engine)
    assert divisions == [1, 4], "run once as configured, once more at a quarter of the step"
    assert label.untested.startswith(reason) and label.untested.endswith("(also at 1/4 of the step)") and label.engine == engine
    assert label.failed_at == "close", "caught at the end of the first phase, not judged held or dropped"


@pytest.mark.parametrize("engine, engine_class, spoil", [
    ("mujoco", mujoco_hand.MuJoCoHand, _nan_mujoco_velocity),
    ("pybullet", pybullet_hand.PyBulletHand, _thrown_pybullet_object),
])
def test_a_simulation_that_diverges_only_at_the_configured_step_is_labelled_at_the_smaller_one(designed_box, monkeypatch, engine,
                                                                                              engine_class, spoil):
    divisions = _diverging(monkeypatch, engine_class, spoil, only_at_the_configured_step=True)
    config = load_config(None, {"labelling": {"perturbed_simulations": 1, "divergence_step_division": 2}})
    (label,) = label_object_grasps(designed_box, _held_grasp(designed_box), None, "floating", config, engine=engine)
    assert divisions == [1, 2] and label.untested is None and label.held


def test_a_robust_label_is_the_majority_of_its_tested_simulations_and_untested_where_its_own_pose_is():
    def outcome(held: bool, untested: str | None = None) -> GraspLabel:
        return GraspLabel(mode="hand", held=held and untested is None, failure_reason=None if held else "slipped",
                          failed_at=None if held else "shake", untested=untested)

    spoilt = outcome(False, "diverged: QACC warning")
    assert _majority([outcome(True), spoilt, spoilt, outcome(False), outcome(True)]).held_fraction == pytest.approx(2 / 3)
    assert _majority([spoilt, outcome(True), outcome(True)]).untested == "diverged: QACC warning"
    # Two engines: the grasp is untested where either left it so.
    both = combined_labels({"pybullet": [outcome(True)], "mujoco": [spoilt]})
    assert both[0].untested == "diverged: QACC warning"


def _box_dataset(tmp_path, monkeypatch, engines: str, grasps: int, pairs: int):
    """A dataset of a box in ``engines`` (one capture) where every MuJoCo simulation diverges; its folder."""
    _diverging(monkeypatch, mujoco_hand.MuJoCoHand, _weightless_mujoco_object)
    folder, out = tmp_path / "meshes", tmp_path / "dataset"
    folder.mkdir()
    trimesh.creation.box((0.05, 0.04, 0.08)).export(folder / "box.stl")
    argv = ["--objects-dir", str(folder), "--out", str(out), "--protocol", "floating", "--engines", engines, "--workers", "1",
            "--grasps-per-object", str(grasps), "--captures", "1", "--pairs", str(pairs), "--no-progress"]
    assert datagen.main(argv) == 0
    return out


@pytest.mark.slow
def test_a_dataset_keeps_diverged_grasps_untested_and_counts_them_per_engine(tmp_path, monkeypatch, capsys):
    out = _box_dataset(tmp_path, monkeypatch, "pybullet,mujoco", grasps=6, pairs=3000)
    with h5py.File(out / "grasps" / "box.h5", "r") as f:
        reasons = [reason.decode() for reason in f["untested/reason"][()]]
        decided_by = [d.decode() for d in f["grasps/decided_by"][()]]
    # Every simulation diverged in MuJoCo: only the grasps geometry decided are labels.
    assert reasons and all(r.endswith("untested: mujoco diverged: singular inertia warning (also at 1/4 of the step)") for r in reasons)
    assert set(decided_by) <= {"geometry"} and len(reasons) + len(decided_by) == 6
    entry = json.loads((out / "objects.jsonl").read_text().splitlines()[0])
    assert entry["diverged"] == {"pybullet": 0, "mujoco": len(reasons)} and entry["untested"] == len(reasons)
    line = f"diverged and kept untested: pybullet 0, mujoco {len(reasons)}"
    report = (out / "report.md").read_text()
    assert line in report and line in capsys.readouterr().err and "Every object has the 6 grasps asked planned." in report


@pytest.mark.slow
def test_a_run_short_of_the_count_asked_says_per_object_how_many_it_found_and_why(tmp_path, monkeypatch, capsys):
    # Every simulation diverging spares this test the labelling: it is about the count planned.
    out = _box_dataset(tmp_path, monkeypatch, "mujoco", grasps=3000, pairs=200)
    entry = json.loads((out / "objects.jsonl").read_text().splitlines()[0])
    found = entry["labelled"] + entry["untested"]
    assert found < 3000 and entry["shortfall"].startswith(f"{found} of 3000 planned")
    line = f"box: {entry['shortfall']} ({entry['labelled']} labelled, {entry['untested']} untested)"
    assert f"short: {line}" in capsys.readouterr().err and f"- {line}" in (out / "report.md").read_text()
