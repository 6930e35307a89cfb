"""The grasp files' formats: ACRONYM's HDF5 and GraspGen's JSON, each read and written here only.

- ``frames``: the gripper frames of the files and the planner's grasp poses, converted both ways; where an
  object's mesh lies in its link frame (``mesh_reference``, ``link_from_scaled_mesh``).
- ``acronym``: ACRONYM's layout, every key documented: a study trial's grasps, a dataset's object file, a
  relabelled file.
- ``graspgen``: GraspGen's JSON layout.
- ``object_grasps``: what a dataset's object file holds, as values (labelled grasps, untested grasps, physics).
- ``grasp_file``: the one reader, of ACRONYM's and GraspGen's files, ours and published ones.
- ``hdf5``: the one HDF5 writer every layout hands its datasets to.

The package sits below the study and the datasets: it imports nothing of either.
"""
