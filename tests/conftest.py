from pathlib import Path

import pytest
from ycb_paths import HAVE_YCB, YCB_DIR


@pytest.fixture(scope="session")
def ycb_dir() -> Path:
    """The YCB models beside the checkout (../shared/ycb) or $SAGP_YCB_DIR."""
    if not HAVE_YCB:
        pytest.skip(f"no YCB directory at {YCB_DIR}: set SAGP_YCB_DIR or place shared/ycb beside the checkout")
    return YCB_DIR
