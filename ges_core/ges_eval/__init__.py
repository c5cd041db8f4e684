"""GES end to end (``ges evaluate``): gates pick an expert per object, the picked expert runs, Table 2 compares.

* :mod:`~ges_core.ges_eval.gates`: ``--gate`` checkpoints, checked against the experts; clouds; the picks;
* :mod:`~ges_core.ges_eval.results`: the resumable results file (``ges-HAND-SIM.json``);
* :mod:`~ges_core.ges_eval.run`: :func:`evaluate_ges`, the pipeline;
* :mod:`~ges_core.ges_eval.table`: Table 2 (experts alone, baseline, oracle, GES per gate);
* :mod:`~ges_core.ges_eval.figure` and :mod:`~ges_core.ges_eval.outputs`: the expert-fusion PNG, the files.

See ``docs/evaluate.md``.
"""

from __future__ import annotations

from ges_core.ges_eval.gates import GateChoice, parse_gate
from ges_core.ges_eval.run import GesReport, evaluate_ges
from ges_core.ges_eval.table import Table2

__all__ = ["GateChoice", "GesReport", "Table2", "evaluate_ges", "parse_gate"]
