import os

# Ray reads these when it is first imported: a cluster on loopback (tests/test_ray_cluster.py) needs
# Ray to keep 127.0.0.1 rather than the machine's outward address, and no token authentication.
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")

from pathlib import Path

import pytest
from ycb_paths import HAVE_YCB, YCB_DIR


@pytest.fixture(scope="session")
def ycb_dir() -> Path:
    """$SAGP_YCB_DIR, else the YCB models beside the checkout (../shared/ycb), else the embedded compact set."""
    if not HAVE_YCB:
        pytest.skip(f"no YCB directory at {YCB_DIR}: $SAGP_YCB_DIR is set but holds no objects.json")
    return YCB_DIR


@pytest.fixture(scope="session")
def designed_box(tmp_path_factory):
    """The box the designed grasps are made for (``designed_grasps.designed_box_grasps``: held across it, dropped
    beside it, a collision in it), imported as an object lying on its 5 x 8 cm face, 4 cm tall."""
    import trimesh

    from sagp_batched.benchmarks.designed_grasps import DESIGNED_BOX_M
    from sagp_batched.world.mesh_settings import MeshImportSettings
    from sagp_batched.world.objects import load_object_set

    folder = tmp_path_factory.mktemp("box")
    trimesh.creation.box(DESIGNED_BOX_M).export(folder / "box.obj")
    return load_object_set(folder, MeshImportSettings(cache_dir=tmp_path_factory.mktemp("cache"))).get("box")
