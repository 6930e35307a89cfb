"""The study: the loop over objects x tasks x trials (``run``), one trial (``experiment``), the
methods' rankings (``methods``), the task judgement (``judging``), the summary (``metrics``) and its
report (``report``)."""
from ..lazy_exports import lazy_exports

# Imported on first use: ``records`` reads ``judging`` while ``run`` reads ``records``.
_PUBLIC = {"StudyResult": "run", "run_study": "run"}

__all__ = sorted(_PUBLIC)
__getattr__ = lazy_exports(__name__, _PUBLIC)
