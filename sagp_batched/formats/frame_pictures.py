"""Pictures of each gripper's file frame on an object: the open gripper's collision hulls at a grasp on the mug's
rim, the frame ACRONYM's and GraspGen's files write (x closing, y = approach x closing, z approach, origin at the
gripper base) and the grasp target between the pads, drawn from the same functions that write the files."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from sagp_batched_kernels.grasp_frames import grasp_rotations

from ..grasps import GraspPoses
from ..robot.description import load_robot
from ..robot.hand import load_hand_geometry
from ..world.objects import ObjectSpec
from .frames import acronym_gripper_transforms_object

# How far below the rim the grasp target sits, and the length of the drawn axes (m).
RIM_DEPTH_M = 0.012
AXIS_LENGTH_M = 0.07
AXIS_COLOURS = ("tab:red", "tab:green", "tab:blue")


def rim_grasp(mesh) -> GraspPoses:
    """A top-down grasp (object frame) pinching the wall of an upright open container at its +x rim."""
    vertices = np.asarray(mesh.vertices)
    top = vertices[:, 2].max()
    near_top = vertices[vertices[:, 2] > top - 0.005]
    rim = near_top[np.argmax(near_top[:, 0])]
    rotation = grasp_rotations(torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64), torch.tensor([[0.0, 0.0, -1.0]], dtype=torch.float64))
    centre = np.array([rim[0] - 0.003, 0.0, top - RIM_DEPTH_M])
    return GraspPoses(torch.tensor(centre[None], dtype=torch.float64), rotation, "object")


def draw_gripper_frame(gripper_name: str, spec: ObjectSpec, mesh, out_path: Path) -> Path:
    """Draw ``gripper_name``'s open hand at the rim grasp on ``spec`` (its visual ``mesh`` in the link frame) with
    its file frame, to ``out_path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    from scipy.spatial import ConvexHull

    robot = load_robot("panda", gripper_name)
    gripper, hand = robot.gripper, load_hand_geometry(robot)
    pose = rim_grasp(mesh)
    rotation, position = pose.rotation[0].numpy(), pose.position[0].numpy()
    file_frame = acronym_gripper_transforms_object(pose, gripper)[0]

    figure = plt.figure(figsize=(6, 6))
    axes = figure.add_subplot(projection="3d")
    axes.add_collection3d(Poly3DCollection(np.asarray(mesh.vertices)[np.asarray(mesh.faces)], facecolor="0.75", edgecolor="none", alpha=0.35))
    for link, hull in zip(hand.links, hand.hull_vertices):
        vertices = hull.double().numpy() @ rotation.T + position
        faces = vertices[ConvexHull(vertices).simplices]
        colour = "tab:orange" if link in gripper.pad_links else "tab:gray"
        axes.add_collection3d(Poly3DCollection(faces, facecolor=colour, edgecolor="0.3", linewidths=0.05, alpha=0.2))
    origin = file_frame[:3, 3]
    for column, (colour, name) in enumerate(zip(AXIS_COLOURS, "xyz")):
        direction = file_frame[:3, column] * AXIS_LENGTH_M
        axes.quiver(*origin, *direction, color=colour, linewidth=2.5, zorder=10)
        axes.text(*(origin + direction * 1.15), name, color=colour)
    axes.scatter(*position, color="k", s=12)
    axes.text(*(position + [0.01, 0.0, 0.0]), "grasp target", fontsize=7)
    points = np.concatenate([np.asarray(mesh.vertices), torch.cat(hand.hull_vertices).double().numpy() @ rotation.T + position])
    centre, half = (points.max(0) + points.min(0)) / 2, (points.max(0) - points.min(0)).max() / 2
    axes.set(xlim=(centre[0] - half, centre[0] + half), ylim=(centre[1] - half, centre[1] + half), zlim=(centre[2] - half, centre[2] + half),
             xlabel="x (m)", ylabel="y (m)", zlabel="z (m)")
    axes.view_init(elev=18, azim=-60)
    axes.set_title(f"{gripper.name}: gripper/type \"{gripper.file_name}\"\nbase {gripper.grasp_depth_m * 1000:.1f} mm behind the grasp target, "
                   f"opening {gripper.open_width_m * 1000:.1f} mm", fontsize=9)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out_path, dpi=110, bbox_inches="tight")
    plt.close(figure)
    return out_path
