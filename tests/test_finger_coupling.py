"""The Panda's fingers are coupled in both label engines, as its one motor drives them: closing on a box
off-centre, one pad meets it first and pushes it to the middle, a shake along the closing axis does not
carry it off to one side, the fingers stay symmetric throughout, and each pad presses the grip force."""
from __future__ import annotations

import numpy as np
import pybullet
import pytest

from sagp_batched.config import Config
from sagp_batched.datasets.protocols import WorldStart
from sagp_batched.datasets.pybullet_hand import PyBulletHand
from sagp_batched.world.mesh_settings import MeshImportSettings
from sagp_batched.world.objects import load_object_set

mujoco = pytest.importorskip("mujoco")
MuJoCoHand = pytest.importorskip("sagp_batched.datasets.mujoco_hand", exc_type=ImportError).MuJoCoHand

HAND_AT = np.array([0.0, 0.0, 1.0])
DOWN_CLOSING_ALONG_Y = (1.0, 0.0, 0.0, 0.0)  # approach down, the fingers closing along world y
BOX_EXTENTS_M = (0.06, 0.03, 0.02)  # 3 cm across the closing axis, in the Panda's 8 cm opening
BOX_BELOW_TARGET_M = 0.01
# Off-centre enough that one pad meets the box well before the other; further, the pushed box turns in the grip.
OFF_CENTRE_M = 0.005
# How far apart the fingers may come: PyBullet's gear gives for a step by up to 0.5 mm where a 70 N finger
# strikes the box and bounces off it (MuJoCo's equality by about a micrometre); free fingers end 10 mm apart here.
SYMMETRY_M = 1e-3
# How far from the middle the box may end, and how far it moves before it counts as pushed.
CENTRED_M, PUSHED_M = 5e-4, 1e-4
# Along the closing axis, the labels' shake's peak acceleration (13 m/s^2), twice; then the hand held still to settle.
SHAKE_AMPLITUDE_M, SHAKE_PERIOD_S, SHAKE_PERIODS, SETTLE_STEPS = 0.02, 0.25, 2, 24


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    import trimesh

    folder = tmp_path_factory.mktemp("coupling")
    trimesh.creation.box(BOX_EXTENTS_M).export(folder / "box.obj")
    return load_object_set(folder, MeshImportSettings(cache_dir=folder / "cache")).get("box")


def _fingers_and_pads(engine) -> tuple[np.ndarray, np.ndarray]:
    """The finger joints' values, and per pad link the normal force of its contacts with the object."""
    if engine.name == "pybullet":
        client = engine.client
        joints = [pybullet.getJointState(engine.hand, joint, physicsClientId=client)[0] for joint in engine.finger_joints]
        pads = [sum(contact[9] for contact in pybullet.getContactPoints(bodyA=engine.hand, bodyB=engine.target, linkIndexA=link,
                                                                        physicsClientId=client)) for link in engine.pad_links]
        return np.array(joints), np.array(pads)
    model, data, world, force = engine.world.model, engine.data, engine.world, np.zeros(6)
    pads = np.zeros(len(world.finger_bodies))
    for index in range(data.ncon):
        bodies = model.geom_bodyid[data.contact.geom[index]]
        for pad, finger in enumerate(world.finger_bodies):
            if finger in bodies and world.object_body in bodies:
                mujoco.mj_contactForce(model, data, index, force)
                pads[pad] += force[0]
    return data.qpos[list(world.finger_qpos)].copy(), pads


@pytest.mark.parametrize("engine_class", [PyBulletHand, MuJoCoHand], ids=["pybullet", "mujoco"])
@pytest.mark.parametrize("grip_force_n", [10.0, 70.0])
def test_the_fingers_close_symmetrically_on_a_box_off_centre_and_each_pad_presses_the_grip_force(box, engine_class, grip_force_n):
    config = Config().override("execution", gripper_force_n=grip_force_n)
    start = WorldStart(box, ((0.0, OFF_CENTRE_M, HAND_AT[2] - BOX_BELOW_TARGET_M), (0.0, 0.0, 0.0, 1.0)), "link", HAND_AT,
                       np.array(DOWN_CLOSING_ALONG_Y), table=False, gravity=False)
    with engine_class(config) as engine:
        engine.build(start)
        engine.command_fingers(0.0)
        # A pad knocks the box on within a step, so a pad alone is seen as the box moving before both pads press.
        asymmetry, pushed_by_one_pad = 0.0, False
        for _ in range(config.labelling.hand_close_steps):
            engine.step(1)
            joints, pads = _fingers_and_pads(engine)
            asymmetry = max(asymmetry, abs(joints[0] - joints[1]))
            pushed_by_one_pad |= abs(engine.object_pose()[0][1] - OFF_CENTRE_M) > PUSHED_M and not (pads > 0.0).all()
        time = np.arange(1, round(SHAKE_PERIODS * SHAKE_PERIOD_S / config.scene.time_step_s) + 1) * config.scene.time_step_s
        shake = np.zeros((len(time) + SETTLE_STEPS, 3)) + HAND_AT
        shake[: len(time), 1] += SHAKE_AMPLITUDE_M * np.sin(2.0 * np.pi * time / SHAKE_PERIOD_S)
        for position in shake:
            engine.follow([position])
            joints, pads = _fingers_and_pads(engine)
            asymmetry = max(asymmetry, abs(joints[0] - joints[1]))
        label = f"{engine.name} at {grip_force_n} N: pads {pads[0]:.2f} N, {pads[1]:.2f} N, fingers apart by up to {asymmetry * 1e3:.4f} mm"
        assert pushed_by_one_pad, label
        assert asymmetry < SYMMETRY_M, label
        assert abs(engine.object_pose()[0][1]) < CENTRED_M, label
        assert pads == pytest.approx([grip_force_n, grip_force_n], rel=0.05), label
