"""The Panda hand as PyBullet collides it, derived from ``panda.urdf`` for the planner's checks.

PyBullet collides each link of ``panda.urdf`` with the convex hull of the link's collision mesh
(``meshes/collision/*.obj``) placed at the collision ``<origin>``. This module reads those
elements with pytorch-kinematics' URDF parser, places each hull with pytorch-kinematics' forward
kinematics of the full chain (fingers at a given opening), and expresses the hull vertices in the
grasp frame (``panda_grasptarget``: z = approach, y = closing axis). Nothing about the hand's
shape is typed in.

For batched point tests each hull is bounded by a k-DOP: its extent along 13 fixed directions
(the 3 axes, 6 edge and 4 corner diagonals). A k-DOP contains its hull (conservative) and, unlike
a box, follows the hand's bevels and the fingers' taper; its extents along a straight stroke are
exact (extent + stroke * direction), which is how the descent sweep is built.
"""
from __future__ import annotations

import functools
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytorch_kinematics as pk
import torch
from scipy.spatial import ConvexHull

from .description import RobotDescription

log = logging.getLogger(__name__)



def _dop_directions() -> torch.Tensor:
    axes = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
    edges = [(1, 1, 0), (1, -1, 0), (1, 0, 1), (1, 0, -1), (0, 1, 1), (0, 1, -1)]
    corners = [(1, 1, 1), (1, 1, -1), (1, -1, 1), (-1, 1, 1)]
    directions = torch.tensor(axes + edges + corners, dtype=torch.float64)
    return (directions / directions.norm(dim=1, keepdim=True)).to(torch.float32)


DOP_DIRECTIONS = _dop_directions()  # (13, 3) unit directions, grasp frame


def quiet_urdf(parse, urdf_path: Path):
    """Run ``parse(text)`` on a URDF with pytorch-kinematics' parser, its reports sent to the debug log.

    pybullet_data's panda.urdf carries PyBullet-only tags (``<contact>``, collision ``<material>``)
    that the parser reports on stderr once per link; they affect neither kinematics nor geometry.
    """
    from pytorch_kinematics.urdf_parser_py.xml_reflection import core

    previous, core.on_error = core.on_error, lambda message: log.debug("%s: %s", urdf_path.name, message)
    try:
        return parse(urdf_path.read_text())
    finally:
        core.on_error = previous


def _mesh_vertices(path: Path) -> np.ndarray:
    """(V, 3) vertex positions of a Wavefront OBJ file (the only mesh format panda.urdf uses)."""
    rows = [line.split()[1:4] for line in path.read_text().splitlines() if line.startswith("v ")]
    if not rows:
        raise ValueError(f"{path} holds no vertices")
    return np.asarray(rows, dtype=np.float64)


def _origin_matrix(origin) -> np.ndarray:
    matrix = np.eye(4)
    if origin is not None:
        xyz = origin.xyz or (0.0, 0.0, 0.0)
        rpy = origin.rpy or (0.0, 0.0, 0.0)
        matrix[:3, :3] = pk.euler_angles_to_matrix(torch.tensor(rpy, dtype=torch.float64), "XYZ").numpy()
        matrix[:3, 3] = xyz
    return matrix


@dataclass(frozen=True)
class HandGeometry:
    """Convex collision hulls of the open Panda hand in the grasp frame, and their k-DOP bounds.

    ``hull_vertices[i]`` is link ``links[i]``'s hull, (V_i, 3) metres in the grasp frame, with the
    fingers open to ``open_width_m``; ``dop_low``/``dop_high`` (S, D) bound hull i along
    ``DOP_DIRECTIONS``.
    """

    links: tuple[str, ...]
    open_width_m: float
    hull_vertices: tuple[torch.Tensor, ...]
    dop_low: torch.Tensor
    dop_high: torch.Tensor

    def vertices(self, links: tuple[str, ...] | None = None) -> torch.Tensor:
        """(V, 3) the hull vertices of ``links`` (default: every link), grasp frame: what the table check tests."""
        return torch.cat([hull for name, hull in zip(self.links, self.hull_vertices) if links is None or name in links])

    def swept(self, stroke_local: tuple[float, float, float]) -> tuple[torch.Tensor, torch.Tensor]:
        """k-DOP extents (low, high), (S, D), of each hull swept by the straight stroke from its
        pose to its pose + ``stroke_local`` (grasp frame, metres): exact for k-DOPs, since the
        sweep adds the stroke's projection to one side of every extent."""
        along = DOP_DIRECTIONS @ torch.tensor(stroke_local, dtype=torch.float32)  # (D,)
        return self.dop_low + along.clamp(max=0.0), self.dop_high + along.clamp(min=0.0)


@functools.lru_cache(maxsize=4)
def link_hulls(urdf_path: Path, links: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Per link, the vertices (V, 3) of the convex hull of its collision meshes, in the link's own frame."""
    from pytorch_kinematics.urdf_parser_py.urdf import URDF

    robot = quiet_urdf(URDF.from_xml_string, urdf_path)
    by_name = {link.name: link for link in robot.links}
    hulls = {}
    for name in links:
        if name not in by_name or not by_name[name].collisions:
            raise ValueError(f"{urdf_path.name}: link '{name}' has no collision geometry")
        link_vertices = []
        for collision in by_name[name].collisions:
            mesh_path = urdf_path.parent / collision.geometry.filename.removeprefix("package://")
            vertices = _mesh_vertices(mesh_path) * np.asarray(collision.geometry.scale or (1.0, 1.0, 1.0))
            origin = _origin_matrix(collision.origin)
            link_vertices.append(vertices @ origin[:3, :3].T + origin[:3, 3])
        vertices = np.concatenate(link_vertices)
        hulls[name] = vertices[ConvexHull(vertices).vertices]
    return hulls


@functools.lru_cache(maxsize=4)
def hand_to_grasp_target_m(robot: RobotDescription) -> float:
    """Distance (m) of the grasp target from the hand link's origin along the hand's z axis (the
    approach), from the robot's URDF; the grasp target must lie on that axis with the hand's orientation."""
    chain = quiet_urdf(pk.build_chain_from_urdf, robot.urdf_path).to(dtype=torch.float64)
    poses = chain.forward_kinematics(torch.zeros(1, len(chain.get_joint_parameter_names()), dtype=torch.float64))
    hand_to_target = (torch.linalg.inv(poses[robot.hand_link].get_matrix()[0]) @ poses[robot.grasp_target_link].get_matrix()[0]).numpy()
    if not np.allclose(hand_to_target[:3, :3], np.eye(3), atol=1e-6) or not np.allclose(hand_to_target[:2, 3], 0.0, atol=1e-6):
        raise ValueError(f"{robot.urdf_path}: {robot.grasp_target_link} is not on {robot.hand_link}'s z axis with its orientation")
    return float(hand_to_target[2, 3])


@functools.lru_cache(maxsize=4)
def load_hand_geometry(robot: RobotDescription) -> HandGeometry:
    """The collision hulls of the robot's hand links, in the grasp frame with the fingers fully open."""
    urdf_path, open_width_m, links = robot.urdf_path, robot.open_width_m, robot.hand_collision_links
    chain = quiet_urdf(pk.build_chain_from_urdf, urdf_path)
    joint_names = chain.get_joint_parameter_names()
    joints = torch.zeros(1, len(joint_names), dtype=torch.float64)
    for name in robot.finger_joints:
        joints[0, joint_names.index(name)] = open_width_m / 2.0
    poses = chain.to(dtype=torch.float64).forward_kinematics(joints)
    grasp_from_base = torch.linalg.inv(poses[robot.grasp_target_link].get_matrix()[0]).numpy()
    hulls = []
    for name, vertices in link_hulls(urdf_path, links).items():
        transform = grasp_from_base @ poses[name].get_matrix()[0].numpy()
        hulls.append(torch.tensor(vertices @ transform[:3, :3].T + transform[:3, 3], dtype=torch.float32))
    projections = [hull @ DOP_DIRECTIONS.T for hull in hulls]  # (V_i, D)
    return HandGeometry(
        links=tuple(links),
        open_width_m=float(open_width_m),
        hull_vertices=tuple(hulls),
        dop_low=torch.stack([p.min(dim=0).values for p in projections]),
        dop_high=torch.stack([p.max(dim=0).values for p in projections]),
    )
