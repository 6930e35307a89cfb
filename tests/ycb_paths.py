"""Where the tests find the YCB models: $SAGP_YCB_DIR, else ../shared/ycb beside the checkout, else the
embedded compact YCB set that ships inside the package (so no test skips for want of YCB files)."""
import os
from pathlib import Path

import pytest

from sagp_batched.world.objects import YCB_DIR_ENV, embedded_ycb_dir

REPO = Path(__file__).resolve().parent.parent
SHARED_YCB_DIR = REPO.parent / "shared" / "ycb"
# The full-resolution set the embedded one was made from, when present.
FULL_YCB_DIR = Path(os.environ.get(YCB_DIR_ENV) or SHARED_YCB_DIR)
HAVE_FULL_YCB = (FULL_YCB_DIR / "objects.json").is_file()
YCB_DIR = FULL_YCB_DIR if HAVE_FULL_YCB or os.environ.get(YCB_DIR_ENV) else embedded_ycb_dir()
HAVE_YCB = (YCB_DIR / "objects.json").is_file()
needs_ycb = pytest.mark.skipif(not HAVE_YCB, reason=f"YCB models not found at {YCB_DIR}")
