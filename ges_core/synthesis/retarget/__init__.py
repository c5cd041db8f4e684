"""Step 2, retargeting: five contacts -> a wrist pose and joint angles of one hand.

``retargeter`` (:class:`GraspRetargeter`: the paper's wrist placement, then the batched joint solve) uses
``wrist`` (the hand's frame and the paper's placement), ``search`` (the wrist placements tried around it,
their table and object penalties, the ranking of distinct alternatives) and ``solver`` (the vector
retargeting solve of the joints, :class:`VectorRetargeter`).
"""

from __future__ import annotations

from ges_core.synthesis.retarget.retargeter import GraspRetargeter, RetargetConfig, retarget_contacts
from ges_core.synthesis.retarget.search import ObjectCloud, WristSearchConfig
from ges_core.synthesis.retarget.solver import VectorRetargetConfig, VectorRetargeter

__all__ = [
    "GraspRetargeter",
    "ObjectCloud",
    "RetargetConfig",
    "VectorRetargetConfig",
    "VectorRetargeter",
    "WristSearchConfig",
    "retarget_contacts",
]
