"""The robot and the gripper: their descriptions read from ``data/robots/<name>.toml`` (``description``) and
``data/grippers/<name>.toml`` (``gripper_description``), the hand's collision hulls (``hand``), the arm's
chain (``kinematics``), the batched IK (``ik``) and the motion a grasp is executed with (``motion``)."""
from .description import RobotDescription, load_robot, robot_of
from .gripper_description import GripperBoxes, GripperDescription, gripper_by_file_name, load_gripper

__all__ = ["GripperBoxes", "GripperDescription", "RobotDescription", "gripper_by_file_name", "load_gripper", "load_robot", "robot_of"]
