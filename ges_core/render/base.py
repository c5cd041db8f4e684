"""What a grasp picture is, engine-free: its settings, its colours and the :class:`Renderer` interface.

A renderer draws one scene per picture, in the **object frame**: the object's collision mesh with its
frame at the origin, resting on a table plane at z = 0 (grey), the contacts of a
:class:`~ges_core.contact.ContactSet` as coloured spheres (one colour per finger slot,
:data:`SLOT_COLORS`) with a short stick along each outward normal, and the hand at its grasp pose. A
simulator plugin provides the drawing (``SimSpec.renderer``; the PyBullet plugin's TinyRenderer
runs on the CPU); get one with :func:`ges_core.render.open_renderer`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ges_core.contact import ContactSet
    from ges_core.hand import HandModel
    from ges_core.objects.asset import ObjectAsset

__all__ = ["HAND_COLOR", "OBJECT_COLOR", "SLOT_COLORS", "TABLE_COLOR", "RenderConfig", "Renderer"]

SLOT_COLORS: dict[str, tuple[float, float, float]] = {
    "thumb": (0.90, 0.12, 0.12),
    "index": (0.10, 0.70, 0.15),
    "middle": (0.12, 0.30, 0.95),
    "ring": (0.95, 0.80, 0.05),
    "little": (0.80, 0.15, 0.85),
}
"""RGB in [0, 1] of each finger slot's contact marker."""
HAND_COLOR = (0.42, 0.48, 0.60)
"""RGB in [0, 1] of the hand."""
OBJECT_COLOR = (0.85, 0.62, 0.38)
"""RGB in [0, 1] of the object."""
TABLE_COLOR = (0.92, 0.92, 0.92)
"""RGB in [0, 1] of the table plane."""


@dataclass(frozen=True, kw_only=True)
class RenderConfig:
    """Camera, sizes and styling of a grasp picture."""

    size: tuple[int, int] = (320, 240)
    """(width, height) in pixels; TinyRenderer takes ~0.03 s at 320 x 240 here, ~0.15 s at 640 x 480."""
    azimuth_deg: float = -60.0
    """Camera direction about z, degrees from the object frame's +x axis toward +y (see ``away_from_base``)."""
    away_from_base: float | None = 30.0
    """With a hand: the camera looks from the side opposite the hand's base link, turned this many degrees
    (a 3/4 view) instead of ``azimuth_deg``; None keeps ``azimuth_deg``. The Shadow's base is its forearm,
    29 cm behind the palm, which from the fixed view hid the object in 6 of its 20 demo pictures."""
    elevation_deg: float = 35.0
    """Camera height above the table plane, degrees."""
    fov_deg: float = 40.0
    """Vertical field of view, degrees."""
    margin: float = 1.15
    """Scene radius multiplier: room around the framed points."""
    hand_opacity: float = 0.65
    """0 = invisible hand, 1 = opaque; in between the object shows through the fingers."""
    hidden_contact_opacity: float = 0.5
    """Strength of a contact marker hidden behind the object or the hand (1 = as if in front)."""
    contact_radius: float = 0.005
    """Radius of a contact sphere, metres (a fingertip is ~0.01 m thick, so the sphere pokes out)."""
    normal_length: float = 0.025
    """Length of the stick drawn along each contact's outward normal, metres."""

    def __post_init__(self) -> None:
        w, h = self.size
        if int(w) != w or int(h) != h or w < 8 or h < 8:
            raise ValueError(f"picture size must be two integers >= 8 (width, height), got {self.size}")
        if not 0.0 <= self.hand_opacity <= 1.0:
            raise ValueError(f"hand_opacity must lie in [0, 1], got {self.hand_opacity}")


class Renderer(ABC):
    """Draws grasp pictures headless; reuse one for many pictures, then :meth:`close` it (or use ``with``).

    :meth:`render` checks its arguments and calls the engine's :meth:`_render`. Built by a simulator plugin
    as ``factory(config)`` (``SimSpec.renderer``), ``config`` a :class:`RenderConfig` or None for the defaults.
    """

    def __init__(self, config: RenderConfig | None = None) -> None:
        self.config = config or RenderConfig()

    def render(
        self,
        obj: ObjectAsset | None,
        contacts: ContactSet | None = None,
        hand: HandModel | None = None,
        wrist_pose: np.ndarray | None = None,
        joints: Mapping[str, float] | None = None,
    ) -> np.ndarray:
        """(H, W, 3) uint8 RGB picture (H, W from ``config.size``) of the object, the contacts and the hand.

        Each part is optional. contacts: positions and normals in the object frame, metres. wrist_pose:
        (7,) pose of the hand's base link in the object frame, position m, quaternion wxyz; given with
        ``hand`` or not at all. joints: joint name -> value, rad (m for a prismatic joint), by the hand's
        URDF names; joints not named keep 0. A name the hand lacks is an UnknownNameError.
        """
        if (hand is None) != (wrist_pose is None):
            raise ValueError("render needs both a hand and its wrist_pose, or neither")
        wrist = None if wrist_pose is None else np.asarray(wrist_pose, dtype=np.float64)
        return self._render(obj, contacts, hand, wrist, joints or {})

    @abstractmethod
    def _render(
        self,
        obj: ObjectAsset | None,
        contacts: ContactSet | None,
        hand: HandModel | None,
        wrist_pose: np.ndarray | None,
        joints: Mapping[str, float],
    ) -> np.ndarray:
        """The picture of :meth:`render`; ``wrist_pose`` (7,) float64 exactly when ``hand`` is given."""

    @abstractmethod
    def link_positions(self, hand: HandModel, links: Sequence[str]) -> np.ndarray:
        """(N, 3) origins of ``links`` of ``hand`` as last drawn, object frame, metres (for checks).

        A link the hand's URDF lacks is an UnknownNameError.
        """

    @abstractmethod
    def close(self) -> None:
        """Release the engine; calling twice is harmless."""

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
