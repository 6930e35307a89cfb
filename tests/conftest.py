from pathlib import Path

import pytest
from ycb_paths import HAVE_YCB, YCB_DIR


@pytest.fixture(scope="session")
def ycb_dir() -> Path:
    """$SAGP_YCB_DIR, else the YCB models beside the checkout (../shared/ycb), else the embedded compact set."""
    if not HAVE_YCB:
        pytest.skip(f"no YCB directory at {YCB_DIR}: $SAGP_YCB_DIR is set but holds no objects.json")
    return YCB_DIR
