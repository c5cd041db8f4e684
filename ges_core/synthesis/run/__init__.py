"""Running Stage 1 over many objects and hands: settings, tasks, the worker, records, the table, the demo.

``config`` (:class:`SynthesisConfig`, the dataset's ``run_config``) -> ``tasks`` (fixed chunks of objects,
the object seeds) -> ``worker`` (the five steps per object and hand, in one process) -> ``records`` (one
:class:`~ges_core.dataset.GraspRecord` per pair) -> ``pipeline`` (:func:`run_synthesis`: workers, the
dataset writer, resume). ``table`` summarizes a dataset as the paper's Table 1; ``demo`` is ``ges demo``.
"""

from __future__ import annotations

from ges_core.synthesis.run.config import SynthesisConfig
from ges_core.synthesis.run.demo import DEMO_OBJECTS, DemoConfig, run_demo
from ges_core.synthesis.run.pipeline import RunReport, run_synthesis
from ges_core.synthesis.run.table import format_table, table_rows
from ges_core.synthesis.run.tasks import RegistrySpec, object_seed, plan_tasks

__all__ = [
    "DEMO_OBJECTS",
    "DemoConfig",
    "RegistrySpec",
    "RunReport",
    "SynthesisConfig",
    "format_table",
    "object_seed",
    "plan_tasks",
    "run_demo",
    "run_synthesis",
    "table_rows",
]
