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
