"""Data passed between the Stage 1 steps. Poses are (7,) position (m) + quaternion wxyz."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, get_args

import numpy as np

from ges_core.contact import ContactSet

__all__ = ["STRATEGIES", "ContactResult", "Grasp", "RefinedGrasp", "Strategy", "ValidationResult", "other_strategy"]

Strategy = Literal["horizontal", "vertical"]
"""Horizontal: approach from the side (tall objects); vertical: approach from above."""
STRATEGIES: tuple[Strategy, ...] = get_args(Strategy)
"""Every :data:`Strategy`."""


def other_strategy(strategy: Strategy) -> Strategy:
    """The strategy that is not ``strategy``."""
    return "vertical" if strategy == "horizontal" else "horizontal"


@dataclass(frozen=True)
class ContactResult:
    """Output of contact generation, object frame (the object's resting frame, z up, table at z = 0)."""

    contacts: ContactSet
    """Five contacts (thumb, index, middle, ring, little), object frame."""
    strategy: Strategy
    approach: np.ndarray
    """(3,) unit vector: the direction the hand moves toward the object, object frame."""
    quality: float
    """Ferrari-Canny epsilon of the contacts (0 = no force closure)."""
    symmetric: bool = False
    """True when the object was detected rotationally symmetric about z (z-only alignment)."""
    seconds: float = 0.0


@dataclass(frozen=True)
class Grasp:
    """A hand pose: base-link pose in the object frame and joint angles in the hand's joint order."""

    hand: str
    wrist_pose: np.ndarray
    """(7,) pose of the hand's base link, object frame."""
    q: np.ndarray
    """(K,) joint angles, ``HandDescription.joint_names`` order, radians."""
    meta: dict = field(default_factory=dict)


@dataclass(frozen=True)
class RefinedGrasp:
    """Output of collision-aware refinement."""

    grasp: Grasp
    """The final, settled pose."""
    max_penetration: float
    """Deepest hand-object penetration at the end, metres (>= 0)."""
    table_contact: bool
    """Whether any hand link touches the table at the end."""
    frozen: tuple[str, ...]
    """Names of the fingers whose targets were frozen on contact."""
    seconds: float = 0.0


@dataclass(frozen=True)
class ValidationResult:
    """Outcome of the physics lift-and-hold test of one grasp."""

    success: bool
    reason: str
    """'success' or why not: 'no_contact', 'dropped', 'not_lifted', 'palm_only', 'unstable', ..."""
    flags: dict[str, bool] = field(default_factory=dict)
    """Per-step flags: reached_grasp, fingertips_touching, lifted, held."""
    seconds: float = 0.0
