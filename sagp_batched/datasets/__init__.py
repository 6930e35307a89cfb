"""Labelled grasp datasets: which grasps an object's dataset holds (``verdicts``), their labels from
simulation (``labelling``, in its own worlds built by ``collision_urdf``), one object's plan and
labels (``datagen``), the run over objects (``run``), the files (``dataset``: GraspGen's layout;
``export``: ACRONYM's) and the report (``report``)."""
from .labelling import GraspLabel, ObjectPlacement, grasps_from_poses, label_grasps_arm, label_grasps_hand
from .run import DatasetResult, generate_dataset

__all__ = ["DatasetResult", "GraspLabel", "ObjectPlacement", "generate_dataset", "grasps_from_poses", "label_grasps_arm", "label_grasps_hand"]
