"""Where the tests find the YCB models: $SAGP_YCB_DIR, else ../shared/ycb beside the checkout."""
import os
from pathlib import Path

import pytest

from sagp_batched.objects import YCB_DIR_ENV

REPO = Path(__file__).resolve().parent.parent
YCB_DIR = Path(os.environ.get(YCB_DIR_ENV) or REPO.parent / "shared" / "ycb")
HAVE_YCB = (YCB_DIR / "objects.json").is_file()
needs_ycb = pytest.mark.skipif(not HAVE_YCB, reason=f"YCB models not found at {YCB_DIR}")
