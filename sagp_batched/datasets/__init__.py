"""Labelled grasp datasets: which grasps an object's dataset holds (``verdicts``), their labels from
simulation (``labelling``, in its own worlds built by ``collision_urdf``), one object's plan and
labels (``object_labeller``), the run over objects (``dataset_run``), the dataset's directory (``dataset_directory``; its files'
layouts are ``sagp_batched.formats``'), the report (``dataset_report``) and another simulator's grasp file relabelled by ours
(``relabelling``: ``check_relabel_inputs``, then ``relabel_grasp_file``)."""
from typing import TYPE_CHECKING

from ..lazy_exports import lazy_exports

# Imported on first use, so that one engine's modules load without the other's simulator.
if TYPE_CHECKING:
    from .labelling import GraspLabel, ObjectPlacement, grasps_from_poses, label_grasps_arm, label_grasps_hand
    from .relabelling import (
        InputError as RelabelInputError, Inputs as RelabelInputs, check_inputs as check_relabel_inputs, relabel as relabel_grasp_file,
    )
    from .dataset_run import DatasetResult, generate_dataset

__all__ = [
    "DatasetResult", "GraspLabel", "ObjectPlacement", "RelabelInputError", "RelabelInputs", "check_relabel_inputs",
    "generate_dataset", "grasps_from_poses", "label_grasps_arm", "label_grasps_hand", "relabel_grasp_file",
]
__getattr__ = lazy_exports(__name__, __file__)
