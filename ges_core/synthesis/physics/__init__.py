"""Steps 3-5 in physics, through :class:`ges_core.sim.SimBackend` only: refinement, pre-grasp, validation.

``refine`` (:func:`refine_grasp`: close the hand on the object, freezing fingers on contact), ``pregrasp``
(:func:`pregrasp`: back off and open, no simulator; the opened hand's ``THUMB_KEEP``), ``validate``
(:func:`validate_grasp`: lift and hold), ``robust`` (:func:`robust_validate`: the lift and hold again under seeded
perturbations, with the hand's actuator limits). Shared by them: ``scene`` (staging the hand and the object, contact
queries) and ``squeeze`` (closing targets from fingertip forces, Jacobian transpose); the pose algebra
(``compose``, ``relative``, ``interpolate_pose``) is :mod:`ges_core.transforms`.
"""

from __future__ import annotations

from ges_core.synthesis.physics.pregrasp import THUMB_KEEP, PregraspConfig, pregrasp
from ges_core.synthesis.physics.refine import RefineConfig, refine_grasp, refine_verdict
from ges_core.synthesis.physics.robust import RobustConfig, robust_validate
from ges_core.synthesis.physics.validate import ValidateConfig, validate_grasp

__all__ = [
    "THUMB_KEEP",
    "PregraspConfig",
    "RefineConfig",
    "RobustConfig",
    "ValidateConfig",
    "pregrasp",
    "refine_grasp",
    "refine_verdict",
    "robust_validate",
    "validate_grasp",
]
