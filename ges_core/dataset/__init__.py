"""The ContactGrasp-style grasp dataset: records, the on-disk folder, checks and summaries.

See ``docs/dataset.md`` for the format. Writers and readers:
:class:`DatasetWriter` (incremental, atomic, resumable, one per folder) and :func:`open_dataset`; both rebuild
the index from the records. Record files are byte-reproducible; their times live beside them (:mod:`.timing`).
"""

from __future__ import annotations

from ges_core.dataset.layout import DATASET_FORMAT, DATASET_VERSION, record_relpath
from ges_core.dataset.record import (
    HELD_NO_BETTER,
    NONE_LOWER,
    NOT_RUN,
    SAME_CONTACTS,
    SKIPPED,
    STEPS,
    TOTAL_STEPS,
    AttemptVerdict,
    GraspRecord,
    HandPose,
    Quality,
    RefinementInfo,
    SimVerdict,
    StepOutcome,
    TrialVerdict,
    software_versions,
)
from ges_core.dataset.store import Dataset, DatasetWriter, load_record, open_dataset
from ges_core.dataset.summary import summarize
from ges_core.dataset.validate import validate_dataset

__all__ = [
    "DATASET_FORMAT",
    "DATASET_VERSION",
    "HELD_NO_BETTER",
    "NONE_LOWER",
    "NOT_RUN",
    "SAME_CONTACTS",
    "SKIPPED",
    "STEPS",
    "TOTAL_STEPS",
    "AttemptVerdict",
    "Dataset",
    "DatasetWriter",
    "GraspRecord",
    "HandPose",
    "Quality",
    "RefinementInfo",
    "SimVerdict",
    "StepOutcome",
    "TrialVerdict",
    "load_record",
    "open_dataset",
    "record_relpath",
    "software_versions",
    "summarize",
    "validate_dataset",
]
