"""The world a trial runs in: the objects (``objects``, a user's meshes made into objects by
``mesh_import`` with ``mesh_sources``, ``mesh_physics``, ``mesh_decompose``, ``mesh_files`` and
``mesh_settings``; sent to workers by ``object_transfer``), their annotated functional parts
(``functional_regions``), the PyBullet scene (``scene``) and the cameras' perceived cloud
(``perception``)."""
from typing import TYPE_CHECKING

from ..lazy_exports import lazy_exports

# Imported on first use: the objects are read by engines without PyBullet too.
if TYPE_CHECKING:
    from .objects import ObjectSet, ObjectSpec, load_object_set
    from .perception import capture
    from .scene import Scene

__all__ = [
    "ObjectSet", "ObjectSpec", "Scene", "capture", "load_object_set",
]
__getattr__ = lazy_exports(__name__, __file__)
