"""Expert plugins at work: choosing them by name (:mod:`~ges_core.experts.choice`), evaluating them on every object
(:mod:`~ges_core.experts.evaluate`, ``ges eval-experts``) and the objects x experts success matrix it writes
(:mod:`~ges_core.experts.matrix`). The expert interface and its factory contract are in :mod:`ges_core.policy`;
format and commands in ``docs/experts.md``.
"""

from __future__ import annotations

from ges_core.experts.choice import ExpertChoice, parse_expert

__all__ = ["ExpertChoice", "parse_expert"]
