"""The MuJoCo world of hand-mode labels, built from the same URDFs the PyBullet engine loads: the robot's
floating hand (``collision_urdf.labelling_hand_urdf``), one object (its URDF's collision hulls, inertia and
friction) and, for the ``tabletop`` protocol, the study's table. Compiled once per object and table and
reused by every simulation (``mujoco_hand.MuJoCoHand`` resets it).

The hand is the URDF's link tree on a free joint, its prismatic fingers slide joints driven toward their
commanded opening as PyBullet's position motor drives them (``_add_finger_servos``) and coupled as the
URDF's mimic joints say (``_couple_fingers``); a gripper with its own MJCF that the robot does not carry
is that MJCF instead, its linkage and servo as the MJCF models them (``_add_mjcf_hand``). The hand is
carried by a weld of its grasp target to a mocap body the engine moves (PyBullet caps its constraint at
``hand_constraint_max_force_n``; a weld has no cap, and none of these worlds comes near it). Contacts have
PyBullet's friction, the product of the two surfaces' (``_product``), and its geometry: every convex hull
a URDF gives PyBullet is wrapped in ``hull_margin_m``. How soft each contact is, and how the world is
stepped, is ``[labelling.mujoco]``'s.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from .. import description_files
from ..config import Config
from ..description_files import DEFAULT_FRICTION, LinkInertial, UrdfJoint, read_urdf_document
from ..execution.contact_model import engine_pad, mujoco_pad_contact, reduced_mass_kg
from ..robot.description import RobotDescription
from .collision_urdf import link_collision_hulls

OBJECT_BODY = "object"
# Collision bits: the hand touches the object, the object the table; the hand touches the table through explicit pairs.
HAND_BIT, OBJECT_BIT, TABLE_BIT = 1, 2, 4
HAND_TARGET_BODY = "hand_target"  # the mocap body the hand's grasp target is welded to
TABLE_GEOM = "table"
# PyBullet's default positionGain: its position motor asks for a tenth of the remaining travel each step.
PYBULLET_POSITION_GAIN = 0.1
# An MJCF hand's names are the MJCF's behind this prefix; its grasp target is a body of its own (the URDF has none).
MJCF_PREFIX = "gripper/"
MJCF_GRASP_TARGET_BODY = "grasp_target"


@dataclass(frozen=True)
class HandWorld:
    """A compiled world and where its parts are: qpos addresses of the object's and the hand's free joints
    and of the finger joints (with their values when the hand is open), body ids, and the object's
    centre-of-mass frame in its link frame (position, wxyz quaternion) that poses are reported in."""

    model: mujoco.MjModel
    object_body: int
    object_qpos: int
    hand_qpos: int
    finger_qpos: tuple[int, ...]
    finger_open_qpos: tuple[float, ...]
    finger_bodies: tuple[int, ...]  # per pad link, the body whose geoms press on the object
    grasp_target_body: int
    hand_body_mask: np.ndarray  # (nbody,) True for the hand's bodies
    table_geom: int  # -1 without a table
    com_in_link: tuple[np.ndarray, np.ndarray]
    hand_in_target: np.ndarray  # (4, 4) the hand link's pose in the grasp target's frame
    # (driven joint values, controls): the fingers' actuator control for ``GripperDescription.finger_joint_value``,
    # interpolated; None where the control is that value
    finger_ctrl_table: tuple[np.ndarray, np.ndarray] | None
    # (actuator, its lengths, its force cap there): a linkage's servo whose cap presses each pad with the grip
    # force at whatever opening its fingers stand; None where the cap is one constant
    grip_force_caps: tuple[int, np.ndarray, np.ndarray] | None

    def finger_ctrl(self, joint_value: float) -> float:
        """The fingers' actuator control that drives them to ``joint_value`` of the gripper's driven joints."""
        if self.finger_ctrl_table is None:
            return joint_value
        return float(np.interp(joint_value, *self.finger_ctrl_table))

    def cap_grip_force(self, data: mujoco.MjData) -> None:
        """The linkage servo's force cap for where its fingers stand in ``data`` (after a forward pass)."""
        actuator, lengths, caps = self.grip_force_caps
        cap = float(np.interp(data.actuator_length[actuator], lengths, caps))
        self.model.actuator_forcerange[actuator] = (-cap, cap)


def _wxyz(rotation: np.ndarray) -> np.ndarray:
    return np.roll(Rotation.from_matrix(rotation).as_quat(), 1)


def _set_inertial(body: mujoco.MjsBody, inertial: LinkInertial | None) -> None:
    """The URDF's mass and tensor, the tensor turned into the link frame (MuJoCo finds its principal axes)."""
    if inertial is None:
        return
    rotation = inertial.frame_in_link[:3, :3]
    tensor = rotation @ inertial.tensor_kg_m2 @ rotation.T
    body.explicitinertial = True
    body.mass = inertial.mass_kg
    body.ipos = inertial.frame_in_link[:3, 3]
    body.fullinertia = [tensor[0, 0], tensor[1, 1], tensor[2, 2], tensor[0, 1], tensor[0, 2], tensor[1, 2]]


def _product(first: tuple[float, float, float], second: tuple[float, float, float]) -> tuple[float, float, float]:
    """(lateral, spinning, rolling) friction of two surfaces in contact as PyBullet combines them: the
    products. MuJoCo would take the larger of two geoms' frictions; where one geom has the higher
    ``priority`` its own friction is the contact's, so each geom carries the product with what it touches."""
    return first[0] * second[0], first[1] * second[1], first[2] * second[2]


def _add_hulls(spec: mujoco.MjSpec, body: mujoco.MjsBody, hulls: list[np.ndarray], prefix: str, **geom: Any) -> list[str]:
    """The hulls as mesh geoms of ``body`` with the attributes ``geom`` (MuJoCo collides a mesh as its
    convex hull); their names."""
    names = []
    for index, vertices in enumerate(hulls):
        name = f"{prefix}_{index}"
        # The bodies' inertia is the URDF's: a mesh's volume only matters to MuJoCo's checks, and a flat hull has none.
        spec.add_mesh(name=name, uservert=np.asarray(vertices, dtype=np.float64).ravel(), inertia=mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL)
        body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=name, **geom)
        names.append(name)
    return names


def _pad_surface(config: Config) -> tuple[float, float, float]:
    """A pad's (lateral, spinning, rolling) friction where it touches the table: the pad's friction factor alone."""
    return config.execution.finger_lateral_friction, 0.0, 0.0


def _pad_contact_of(robot: RobotDescription, object_surface: tuple[float, float, float], object_mass_kg: float, config: Config):
    """Per pad body's mass, the (friction, solref, solimp) of its geoms from the contact model."""
    pad, options = engine_pad(config.execution, robot), config.labelling.mujoco
    timestep = config.scene.time_step_s / options.substeps

    def pad_contact(pad_mass_kg: float):
        return mujoco_pad_contact(pad, object_surface, reduced_mass_kg(pad_mass_kg, object_mass_kg), timestep, options.contact_solimp[2:])

    return pad_contact


def _finger_mass(body: mujoco.MjsBody, hand_body: str) -> float:
    """The mass a pad's contact pushes: the pad's body and the bodies between it and the hand (a linkage's
    finger moves with its pad)."""
    mass = 0.0
    while body.name != hand_body and body.name != "world":
        mass, body = mass + body.mass, body.parent
    return mass


def _add_hand(spec: mujoco.MjSpec, hand_urdf: Path, robot: RobotDescription, object_surface: tuple[float, float, float],
              object_mass_kg: float, config: Config) -> dict[str, tuple[list[str], tuple[float, float, float]]]:
    """The hand's links as bodies below a free-floating hand link, their geoms touching the object with
    the product of the two surfaces' friction, the pads' from the contact model; per link, its geoms and surface."""
    options = config.labelling.mujoco
    pad_contact = _pad_contact_of(robot, object_surface, object_mass_kg, config)
    document = read_urdf_document(hand_urdf)
    links = {link.name: link for link in document.links}
    joints_below: dict[str, list[UrdfJoint]] = {}
    for joint in document.joints:
        joints_below.setdefault(joint.parent, []).append(joint)
    surfaces = {}

    def add(parent: mujoco.MjsBody, name: str, frame: np.ndarray) -> mujoco.MjsBody:
        body = parent.add_body(name=name, pos=frame[:3, 3], quat=_wxyz(frame[:3, :3]))
        _set_inertial(body, links[name].body_inertial)
        if name in robot.gripper.pad_links:
            surface = _pad_surface(config)
            friction, solref, solimp = pad_contact(_finger_mass(body, robot.gripper.base_link))
            contact = {"condim": options.finger_condim, "friction": friction, "solref": solref, "solimp": solimp}
        else:
            surface = links[name].friction
            contact = {"condim": 3, "friction": list(_product(surface, object_surface)), "solref": options.contact_solref,
                       "solimp": options.contact_solimp}
        geoms = _add_hulls(spec, body, link_collision_hulls(links[name], hand_urdf), name, contype=HAND_BIT, conaffinity=0,
                           priority=2, margin=options.hull_margin_m, **contact)
        surfaces[name] = (geoms, surface)
        for joint in joints_below.get(name, []):
            child = add(body, joint.child, joint.origin)
            if joint.kind == "prismatic":
                child.add_joint(name=joint.name, type=mujoco.mjtJoint.mjJNT_SLIDE, range=list(joint.limits), axis=list(joint.axis),
                                limited=mujoco.mjtLimited.mjLIMITED_TRUE)
            elif joint.kind != "fixed":
                raise ValueError(f"hand joint '{joint.name}' is {joint.kind}; the MuJoCo hand takes prismatic and fixed joints")
        return body

    add(spec.worldbody, robot.gripper.base_link, np.eye(4)).add_freejoint()
    return surfaces


@dataclass(frozen=True)
class _Hand:
    """A hand added to a spec: per link (or pad) its geoms and their surface, and by name the bodies and
    joints ``HandWorld`` locates once the world is compiled."""

    surfaces: dict[str, tuple[list[str], tuple[float, float, float]]]
    target_body: str
    finger_joints: tuple[str, ...]
    finger_open_qpos: tuple[float, ...]
    pad_bodies: tuple[str, ...]
    finger_ctrl_table: tuple[np.ndarray, np.ndarray] | None
    grip_force_caps: tuple[str, np.ndarray, np.ndarray] | None  # HandWorld's, the actuator by name


def builds_from_mjcf(robot: RobotDescription) -> bool:
    """Whether the hand is the gripper's own MJCF: the gripper has one and the robot's URDF does not carry it."""
    return robot.gripper.mjcf_path is not None and not robot.gripper_mounted


def _add_urdf_hand(spec: mujoco.MjSpec, hand_urdf: Path, robot: RobotDescription, object_surface: tuple[float, float, float],
                   object_mass_kg: float, config: Config) -> _Hand:
    gripper = robot.gripper
    surfaces = _add_hand(spec, hand_urdf, robot, object_surface, object_mass_kg, config)
    _add_finger_servos(spec, robot, config)
    _couple_fingers(spec, hand_urdf, config)
    open_value = gripper.finger_joint_value(gripper.open_width_m)
    return _Hand(surfaces, gripper.grasp_target_link, gripper.finger_joints, (open_value,) * len(gripper.finger_joints),
                 gripper.pad_links, None, None)


def _add_mjcf_hand(spec: mujoco.MjSpec, robot: RobotDescription, object_surface: tuple[float, float, float], object_mass_kg: float,
                   config: Config) -> _Hand:
    """The gripper's MJCF below a free-floating hand body in the URDF base link's frame (the MJCF's body
    ``[mujoco] base_body``), its linkage as the MJCF models it: the joints, the equality constraints that
    close the four-bars, the tendon and the servo on it. Its force cap is set each step (``HandWorld.cap_grip_force``)
    so each pad presses the grip force where the fingers stand, and its set point is the tendon length that
    gives the URDF's opening at the driven joint's value (``driver_at_finger_joint``). The grasp target
    is a body ``grasp_depth_m`` along the hand's z. The collision geoms touch the object, and the table,
    as the URDF hand's do, the pads with the contact model's friction and the MJCF's own softness."""
    gripper, execution, options = robot.gripper, config.execution, config.labelling.mujoco
    hand = spec.worldbody.add_body(name=gripper.base_link)
    hand.add_freejoint()
    hand.add_body(name=MJCF_GRASP_TARGET_BODY, pos=[0.0, 0.0, gripper.grasp_depth_m])
    root_in_hand = np.linalg.inv(description_files.mjcf_body_pose(gripper.mjcf_path, gripper.mujoco_value("base_body")))
    mjcf = description_files.read_mjcf(gripper.mjcf_path)
    # The friction impedance its model was tuned with: the 2F-140's linkage lets the box on the table go at 30.
    spec.option.impratio = mjcf.option.impratio
    spec.attach(mjcf, prefix=MJCF_PREFIX, frame=hand.add_frame(pos=root_in_hand[:3, 3], quat=_wxyz(root_in_hand[:3, :3])))
    pad_geoms = [[MJCF_PREFIX + name for name in names] for names in gripper.mujoco_value("pad_geoms")]
    pad_surface, pad_contact = _pad_surface(config), _pad_contact_of(robot, object_surface, object_mass_kg, config)
    surfaces = {link: (names, pad_surface) for link, names in zip(gripper.pad_links, pad_geoms)}
    surfaces[gripper.base_link] = ([], DEFAULT_FRICTION)
    pads = {name for names in pad_geoms for name in names}
    found = set()
    for index, geom in enumerate(hand.find_all(mujoco.mjtObj.mjOBJ_GEOM)):
        if not (geom.contype or geom.conaffinity):
            continue  # drawn only
        geom.name = geom.name or f"{MJCF_PREFIX}hull_{index}"  # the table's pairs name their geoms
        pad = geom.name in pads
        found.add(geom.name)
        if not pad:
            surfaces[gripper.base_link][0].append(geom.name)
        geom.contype, geom.conaffinity, geom.priority, geom.margin = HAND_BIT, 0, 2, options.hull_margin_m
        if pad:
            # The MJCF's own solref and solimp stay: see ``contact_model``.
            geom.condim, geom.friction = options.finger_condim, pad_contact(_finger_mass(geom.parent, gripper.base_link))[0]
        else:
            geom.condim, geom.friction = 3, list(_product(DEFAULT_FRICTION, object_surface))
            geom.solref, geom.solimp = options.contact_solref, options.contact_solimp
    if not pads <= found:
        raise ValueError(f"{gripper.mjcf_path.name}: no colliding geom {', '.join(sorted(pads - found))} ([mujoco] pad_geoms)")
    actuator = spec.actuator(MJCF_PREFIX + gripper.mujoco_value("actuator"))
    lengths, per_tendon_newton, spring_n = np.asarray(gripper.mujoco_value("pad_force_per_tendon_force"), dtype=np.float64)
    order = np.argsort(lengths)
    caps = np.maximum(execution.gripper_force_n - spring_n[order], 0.0) / per_tendon_newton[order]
    # An affine position servo rests where gain * ctrl = -bias[1] * length: the control per unit of the tendon's length.
    ctrl_per_length = -actuator.biasprm[1] / actuator.gainprm[0]
    joint_values, tendon_lengths = np.asarray(gripper.mujoco_value("driver_at_finger_joint"), dtype=np.float64)
    joints = [joint for joint in hand.find_all(mujoco.mjtObj.mjOBJ_JOINT) if joint.type != mujoco.mjtJoint.mjJNT_FREE]
    # The MJCF's joints are at their reference values with the gripper open.
    return _Hand(surfaces, MJCF_GRASP_TARGET_BODY, tuple(joint.name for joint in joints), tuple(float(joint.ref) for joint in joints),
                 tuple(spec.geom(names[0]).parent.name for names in pad_geoms), (joint_values, tendon_lengths * ctrl_per_length),
                 (actuator.name, lengths[order], caps))


def _add_finger_servos(spec: mujoco.MjSpec, robot: RobotDescription, config: Config) -> None:
    """PyBullet's position motor as a MuJoCo actuator. PyBullet asks for the speed that closes a tenth of
    the remaining travel a step, with up to ``gripper_force_n``, solved with the contacts: a free finger
    closes on that exponential and a blocked one pushes with the full force. Here a set point (the
    actuator's activation) follows the command on that exponential and a stiff spring-damper, clamped
    to the grip force, pulls the finger after it: saturated once the finger lags
    ``finger_servo_saturation_m``. A velocity servo stiff enough to push the full force when blocked
    would not do: MuJoCo integrates an unsaturated actuator's damping implicitly, as added mass, and the
    finger would strike the object like a hammer."""
    force, options = config.execution.gripper_force_n, config.labelling.mujoco
    stiffness = force / options.finger_servo_saturation_m
    finger_mass = next(body.mass for body in spec.bodies if body.name == robot.gripper.pad_links[0])
    damping = 2.0 * options.finger_servo_damping_ratio * np.sqrt(stiffness * finger_mass)
    for joint in robot.gripper.finger_joints:
        actuator = spec.add_actuator(name=joint, target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        actuator.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT
        # Whole arrays: newer bindings hand out copies of these parameters (and longer ones), not views.
        actuator.dynprm = _leading(actuator.dynprm, [-config.scene.time_step_s / np.log(1.0 - PYBULLET_POSITION_GAIN)])
        actuator.gaintype, actuator.biastype = mujoco.mjtGain.mjGAIN_FIXED, mujoco.mjtBias.mjBIAS_AFFINE
        actuator.gainprm = _leading(actuator.gainprm, [stiffness])
        actuator.biasprm = _leading(actuator.biasprm, [0.0, -stiffness, -damping])
        actuator.forcelimited, actuator.forcerange = mujoco.mjtLimited.mjLIMITED_TRUE, [-force, force]


def _couple_fingers(spec: mujoco.MjSpec, hand_urdf: Path, config: Config) -> None:
    """Every mimic joint held where its leader puts it, as stiff as the hand's weld: the Panda's one motor
    drives both fingers through a coupling. Free, force-capped fingers let an object the shake pushes along
    the closing axis carry both with it until one meets its limit and its pad lets go. The object's
    balance makes each pad press the mean of the two servos' forces: each capped at the grip force."""
    options = config.labelling.mujoco
    for name, rule in description_files.mimics(hand_urdf).items():
        # The follower's value as a polynomial of the leader's.
        coupling = spec.add_equality(type=mujoco.mjtEq.mjEQ_JOINT, objtype=mujoco.mjtObj.mjOBJ_JOINT, name1=name, name2=rule.leader,
                                     solref=options.hand_weld_solref, solimp=options.hand_weld_solimp)
        coupling.data = _leading(coupling.data, [rule.offset, rule.multiplier])


def _leading(parameters, values: list[float]) -> np.ndarray:
    """An actuator parameter array as long as ``parameters``, ``values`` first and zeros after."""
    array = np.zeros(len(parameters))
    array[:len(values)] = values
    return array


def _set_options(spec: mujoco.MjSpec, config: Config, multiccd: bool) -> None:
    options = config.labelling.mujoco
    spec.option.timestep = config.scene.time_step_s / options.substeps
    spec.option.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{options.integrator.upper()}")
    spec.option.solver = getattr(mujoco.mjtSolver, f"mjSOL_{options.solver.upper()}")
    spec.option.cone = getattr(mujoco.mjtCone, f"mjCONE_{options.cone.upper()}")
    spec.option.impratio = options.impratio
    spec.option.iterations, spec.option.ls_iterations = options.iterations, options.ls_iterations
    spec.option.noslip_iterations = options.noslip_iterations
    if not multiccd:
        spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_MULTICCD


def _add_table(spec: mujoco.MjSpec, hand_surfaces: dict[str, tuple[list[str], tuple[float, float, float]]], config: Config) -> None:
    """The study's table: a box whose top is at ``table_top_z_m``. The object touches it with its own
    geoms' friction; the hand's geoms carry the object's, so they touch it through pairs of their own."""
    scene, options = config.scene, config.labelling.mujoco
    spec.worldbody.add_geom(name=TABLE_GEOM, type=mujoco.mjtGeom.mjGEOM_BOX, contype=TABLE_BIT, conaffinity=0,
                            size=[scene.table_size_m[0] / 2, scene.table_size_m[1] / 2, scene.table_top_z_m / 2],
                            pos=[*scene.table_center_xy_m, scene.table_top_z_m / 2], solref=options.contact_solref, solimp=options.contact_solimp)
    for geoms, surface in hand_surfaces.values():
        lateral, spinning, rolling = _product(surface, DEFAULT_FRICTION)
        for name in geoms:
            spec.add_pair(geomname1=name, geomname2=TABLE_GEOM, condim=3, friction=[lateral, lateral, spinning, rolling, rolling],
                          solref=options.contact_solref, solimp=options.contact_solimp, margin=options.hull_margin_m)


def compile_world(hand_urdf: Path | None, robot: RobotDescription, object_urdf: Path, table: bool, config: Config) -> HandWorld:
    """The world of one object, with the study's table where ``table``, compiled. ``object_urdf``: the
    object's URDF (its first link is the object); the hand's from ``labelling_hand_urdf``, None where the
    hand is the gripper's MJCF (``builds_from_mjcf``)."""
    options = config.labelling.mujoco
    spec = mujoco.MjSpec()
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    # An MJCF hand's pads are on underactuated linkages: on one contact point a pad rocks about it and lets
    # the object go (the 2F-140 drops the designed box in the shake); several points hold it flat.
    _set_options(spec, config, multiccd=options.multiccd or builds_from_mjcf(robot))
    link = read_urdf_document(object_urdf).links[0]
    inertial, object_surface = link.body_inertial, link.friction
    if inertial is None:
        raise ValueError(f"{object_urdf}: the object's link has no mass")
    if builds_from_mjcf(robot):
        hand = _add_mjcf_hand(spec, robot, object_surface, inertial.mass_kg, config)
    else:
        hand = _add_urdf_hand(spec, hand_urdf, robot, object_surface, inertial.mass_kg, config)
    body = spec.worldbody.add_body(name=OBJECT_BODY)
    body.add_freejoint()
    _set_inertial(body, inertial)
    _add_hulls(spec, body, link_collision_hulls(link, object_urdf), OBJECT_BODY, contype=OBJECT_BIT, conaffinity=HAND_BIT | TABLE_BIT,
               priority=1, condim=3, friction=list(_product(object_surface, DEFAULT_FRICTION)),
               solref=options.contact_solref, solimp=options.contact_solimp, margin=options.hull_margin_m)
    if table:
        _add_table(spec, hand.surfaces, config)
    spec.worldbody.add_body(name=HAND_TARGET_BODY, mocap=True)
    # The grasp target's frame held on the mocap body's (anchor, relative position, relative quaternion, torque scale).
    weld = spec.add_equality(type=mujoco.mjtEq.mjEQ_WELD, objtype=mujoco.mjtObj.mjOBJ_BODY, name1=hand.target_body,
                             name2=HAND_TARGET_BODY, solref=options.hand_weld_solref, solimp=options.hand_weld_solimp)
    weld.data = _leading(weld.data, [0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 1])
    return _located(spec.compile(), robot, hand, inertial)


def _located(model: mujoco.MjModel, robot: RobotDescription, parts: _Hand, inertial: LinkInertial) -> HandWorld:
    def body(name: str) -> int:
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)

    hand, target = body(robot.gripper.base_link), body(parts.target_body)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    hand_in_target = np.eye(4)
    target_rotation = data.xmat[target].reshape(3, 3)
    hand_in_target[:3, :3] = target_rotation.T @ data.xmat[hand].reshape(3, 3)
    hand_in_target[:3, 3] = target_rotation.T @ (data.xpos[hand] - data.xpos[target])
    hand_bodies = np.zeros(model.nbody, dtype=bool)
    hand_bodies[[i for i in range(model.nbody) if model.body_rootid[i] == hand]] = True
    object_body = body(OBJECT_BODY)
    frame = inertial.frame_in_link
    return HandWorld(
        model=model, object_body=object_body, object_qpos=int(model.jnt_qposadr[model.body_jntadr[object_body]]),
        hand_qpos=int(model.jnt_qposadr[model.body_jntadr[hand]]),
        finger_qpos=tuple(int(model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j)]) for j in parts.finger_joints),
        finger_open_qpos=parts.finger_open_qpos, finger_bodies=tuple(body(name) for name in parts.pad_bodies), grasp_target_body=target,
        hand_body_mask=hand_bodies, finger_ctrl_table=parts.finger_ctrl_table,
        grip_force_caps=None if parts.grip_force_caps is None else
        (mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, parts.grip_force_caps[0]), *parts.grip_force_caps[1:]),
        table_geom=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, TABLE_GEOM),
        com_in_link=(frame[:3, 3].copy(), _wxyz(frame[:3, :3])), hand_in_target=hand_in_target,
    )
