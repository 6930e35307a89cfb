"""The one reader of robot and gripper description files (URDF, MJCF).

Every fact the package takes from a robot's or a gripper's URDF (its links' collision geometry, its joints,
their mimic rules, the kinematic chain) is read here, with pytorch-kinematics' URDF parser and chains; an
MJCF is read with MuJoCo's own parser. Modules that need such a fact ask this module, so a file's quirks
(PyBullet-only tags, mesh units, mimic joints PyBullet ignores) are handled once.
"""
from __future__ import annotations

import functools
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

log = logging.getLogger(__name__)


def _quietly(parse: Callable[[str], Any], urdf_path: Path) -> Any:
    """``parse(text)`` of a URDF with pytorch-kinematics' parser, its reports sent to the debug log.

    pybullet_data's panda.urdf carries PyBullet-only tags (``<contact>``, collision ``<material>``)
    that the parser reports on stderr once per link; they affect neither kinematics nor geometry.
    """
    from pytorch_kinematics.urdf_parser_py.xml_reflection import core

    previous, core.on_error = core.on_error, lambda message: log.debug("%s: %s", urdf_path.name, message)
    try:
        return parse(urdf_path.read_text())
    finally:
        core.on_error = previous


@functools.lru_cache(maxsize=16)
def read_urdf(urdf_path: Path):
    """The parsed URDF (pytorch-kinematics' ``urdf_parser_py`` model: ``links``, ``joints``)."""
    from pytorch_kinematics.urdf_parser_py.urdf import URDF

    return _quietly(URDF.from_xml_string, Path(urdf_path))


def chain(urdf_path: Path):
    """The whole kinematic tree of ``urdf_path`` as a pytorch-kinematics chain (float32)."""
    import pytorch_kinematics as pk

    return _quietly(pk.build_chain_from_urdf, Path(urdf_path))


def serial_chain(urdf_path: Path, end_link: str):
    """The serial chain of ``urdf_path`` from its root to ``end_link`` (pytorch-kinematics)."""
    import pytorch_kinematics as pk

    return _quietly(lambda text: pk.build_serial_chain_from_urdf(text, end_link), Path(urdf_path))


@dataclass(frozen=True)
class Mimic:
    """A joint that follows another: value = multiplier * leader + offset."""

    leader: str
    multiplier: float
    offset: float


def mimics(urdf_path: Path) -> dict[str, Mimic]:
    """Per mimic joint of the URDF, the joint it follows and how."""
    return {joint.name: Mimic(joint.mimic.joint, float(joint.mimic.multiplier if joint.mimic.multiplier is not None else 1.0),
                              float(joint.mimic.offset or 0.0))
            for joint in read_urdf(Path(urdf_path)).joints if joint.mimic is not None}


def joint_limits(urdf_path: Path, joint_name: str) -> tuple[float, float]:
    """(lower, upper) of a joint of the URDF."""
    joint = next((joint for joint in read_urdf(Path(urdf_path)).joints if joint.name == joint_name), None)
    if joint is None or joint.limit is None:
        raise ValueError(f"{Path(urdf_path).name}: no joint '{joint_name}' with limits")
    return float(joint.limit.lower), float(joint.limit.upper)


def link_poses(urdf_path: Path, joint_values: dict[str, float]) -> dict[str, np.ndarray]:
    """(4, 4) float64 pose of every link in the URDF's root frame, with the joints at ``joint_values``
    (others at 0) and every mimic joint where its leader puts it: pytorch-kinematics' forward kinematics,
    which leaves mimic rules to its caller."""
    urdf_path = Path(urdf_path)
    tree = chain(urdf_path).to(dtype=torch.float64)
    values = dict(joint_values)
    for name, rule in mimics(urdf_path).items():
        values[name] = rule.multiplier * values.get(rule.leader, 0.0) + rule.offset
    names = tree.get_joint_parameter_names()
    joints = torch.tensor([[values.get(name, 0.0) for name in names]], dtype=torch.float64)
    return {name: pose.get_matrix()[0].numpy() for name, pose in tree.forward_kinematics(joints).items()}


def _origin_matrix(origin) -> np.ndarray:
    import pytorch_kinematics as pk

    matrix = np.eye(4)
    if origin is not None:
        xyz = origin.xyz or (0.0, 0.0, 0.0)
        rpy = origin.rpy or (0.0, 0.0, 0.0)
        matrix[:3, :3] = pk.euler_angles_to_matrix(torch.tensor(rpy, dtype=torch.float64), "XYZ").numpy()
        matrix[:3, 3] = xyz
    return matrix


def _obj_vertices(path: Path) -> np.ndarray:
    """(V, 3) vertex positions of a Wavefront OBJ file, read directly: trimesh would merge and reorder them."""
    rows = [line.split()[1:4] for line in path.read_text().splitlines() if line.startswith("v ")]
    if not rows:
        raise ValueError(f"{path} holds no vertices")
    return np.asarray(rows, dtype=np.float64)


def _mesh_vertices(path: Path) -> np.ndarray:
    if path.suffix.lower() == ".obj":
        return _obj_vertices(path)
    import trimesh

    return np.asarray(trimesh.load(path, force="mesh").vertices, dtype=np.float64)


@functools.lru_cache(maxsize=8)
def link_hulls(urdf_path: Path, links: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Per link, the vertices (V, 3) of the convex hull of its collision geometry (meshes and boxes), in
    the link's own frame: what PyBullet collides the link as."""
    from scipy.spatial import ConvexHull

    urdf_path = Path(urdf_path)
    by_name = {link.name: link for link in read_urdf(urdf_path).links}
    hulls = {}
    for name in links:
        if name not in by_name or not by_name[name].collisions:
            raise ValueError(f"{urdf_path.name}: link '{name}' has no collision geometry")
        link_vertices = []
        for collision in by_name[name].collisions:
            geometry = collision.geometry
            if hasattr(geometry, "filename"):
                mesh_path = urdf_path.parent / geometry.filename.removeprefix("package://")
                vertices = _mesh_vertices(mesh_path) * np.asarray(geometry.scale or (1.0, 1.0, 1.0))
            elif hasattr(geometry, "size"):
                corners = np.array(np.meshgrid([-0.5, 0.5], [-0.5, 0.5], [-0.5, 0.5], indexing="ij")).reshape(3, -1).T
                vertices = corners * np.asarray(geometry.size, dtype=np.float64)
            else:
                raise ValueError(f"{urdf_path.name}: link '{name}' collides as a {type(geometry).__name__}; only meshes and boxes are read")
            origin = _origin_matrix(collision.origin)
            link_vertices.append(vertices @ origin[:3, :3].T + origin[:3, 3])
        vertices = np.concatenate(link_vertices)
        hulls[name] = vertices[ConvexHull(vertices).vertices]
    return hulls


def subtree_links(urdf_path: Path, root_link: str) -> tuple[str, ...]:
    """``root_link`` and every link below it in the URDF's tree, in the file's order."""
    model = read_urdf(Path(urdf_path))
    keep, grown = {root_link}, True
    while grown:
        below = {joint.child for joint in model.joints if joint.parent in keep}
        grown = not below <= keep
        keep |= below
    return tuple(link.name for link in model.links if link.name in keep)


def read_mjcf(mjcf_path: Path):
    """The MJCF as a MuJoCo model specification (``mujoco.MjSpec``), its mesh folder made absolute."""
    import mujoco

    spec = mujoco.MjSpec.from_file(str(mjcf_path))
    spec.meshdir = str((Path(mjcf_path).parent / (spec.meshdir or "")).resolve())
    return spec


@functools.lru_cache(maxsize=8)
def mjcf_body_pose(mjcf_path: Path, body: str) -> np.ndarray:
    """(4, 4) pose of the MJCF's ``body`` in the model's root (world) frame, every joint at its reference value."""
    import mujoco

    model = read_mjcf(mjcf_path).compile()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
    if index < 0:
        raise ValueError(f"{Path(mjcf_path).name}: no body '{body}'")
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = data.xmat[index].reshape(3, 3), data.xpos[index]
    return pose


def write_collision_urdf(source: Path, destination: Path, meshes: dict[str, tuple[str, tuple[float, float, float]]],
                         header: str) -> None:
    """``source`` without its visuals, written to ``destination`` behind the comment ``header``; each collision
    mesh whose file name is a key of ``meshes`` renamed to its (file name, scale)."""
    import xml.etree.ElementTree as ElementTree

    root = ElementTree.parse(source).getroot()
    for link in root.findall("link"):
        for visual in link.findall("visual"):
            link.remove(visual)
        for mesh in link.iter("mesh"):
            if mesh.get("filename") in meshes:
                filename, scale = meshes[mesh.get("filename")]
                mesh.set("filename", filename)
                mesh.set("scale", " ".join(f"{v:g}" for v in scale))
    ElementTree.indent(root)
    destination.write_text(f"<?xml version=\"1.0\"?>\n<!-- {header} -->\n{ElementTree.tostring(root, encoding='unicode')}\n")


def collision_meshes(urdf_path: Path) -> dict[str, tuple[float, ...]]:
    """Per mesh file the URDF's collision geometry names (as written), its scale."""
    return {collision.geometry.filename: tuple(collision.geometry.scale or (1.0, 1.0, 1.0))
            for link in read_urdf(Path(urdf_path)).links for collision in link.collisions if hasattr(collision.geometry, "filename")}
