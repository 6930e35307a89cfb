"""Labelled grasp datasets: which grasps an object's dataset holds (``verdicts``), their labels from
simulation (``labelling``, in its own worlds built by ``collision_urdf``), one object's plan and
labels (``datagen``), the run over objects (``run``), the files (``dataset``: GraspGen's layout;
``export``: ACRONYM's), the report (``report``) and another simulator's grasp file relabelled by ours
(``relabel``: ``check_relabel_inputs``, then ``relabel_grasp_file``)."""
from ..lazy_exports import lazy_exports

# Imported on first use, so that one engine's modules load without the other's simulator.
_PUBLIC = {
    "GraspLabel": "labelling", "ObjectPlacement": "labelling", "grasps_from_poses": "labelling", "label_grasps_arm": "labelling",
    "label_grasps_hand": "labelling", "RelabelInputError": "relabel:InputError", "RelabelInputs": "relabel:Inputs",
    "check_relabel_inputs": "relabel:check_inputs", "relabel_grasp_file": "relabel:relabel", "DatasetResult": "run",
    "generate_dataset": "run",
}

__all__ = sorted(_PUBLIC)
__getattr__ = lazy_exports(__name__, _PUBLIC)
