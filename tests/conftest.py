import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def ycb_dir() -> Path:
    """The YCB models beside the checkout (../shared/ycb) or $SAGP_YCB_DIR."""
    candidates = [os.environ.get("SAGP_YCB_DIR"), REPO.parent / "shared" / "ycb"]
    for candidate in candidates:
        if candidate and (Path(candidate) / "objects.json").is_file():
            return Path(candidate)
    pytest.skip("no YCB directory: set SAGP_YCB_DIR or place shared/ycb beside the checkout")
