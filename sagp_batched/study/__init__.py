"""The study: the loop over objects x tasks x trials (``study_run``), one trial (``experiment``), the
methods' rankings (``methods``), the task judgement (``judging``), a trial's record (``records``) and the
file of them (``trials_file``), the summary (``metrics``) and its report (``study_report``)."""
from typing import TYPE_CHECKING

from ..lazy_exports import lazy_exports

# Imported on first use: ``records`` reads ``judging`` while ``study_run`` reads ``records``.
if TYPE_CHECKING:
    from .study_run import StudyResult, run_study

__all__ = [
    "StudyResult", "run_study",
]
__getattr__ = lazy_exports(__name__, __file__)
