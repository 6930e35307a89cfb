"""The robot: its description read from ``data/robots/<name>.toml`` (``description``), the hand's
collision hulls (``hand``), the arm's chain (``kinematics``), the batched IK (``ik``) and the motion
a grasp is executed with (``motion``)."""
from .description import GripperBoxes, RobotDescription, load_robot, robot_of

__all__ = ["GripperBoxes", "RobotDescription", "load_robot", "robot_of"]
