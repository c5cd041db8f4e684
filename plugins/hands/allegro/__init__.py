"""The Allegro Hand (right, 16 joints, 4 fingers) from the URDF shipped inside ``mani-skill``.

Light on purpose: the hand itself (and any heavy import) lives in :mod:`ges_plugins.hands.allegro.hand`,
loaded only when the registry builds the hand.
"""

from __future__ import annotations

from collections.abc import Callable

from ges_core import hookimpl
from ges_core.specs import HandSpec


@hookimpl
def ges_register_hands(register: Callable[[HandSpec], None]) -> None:
    """Register the right Allegro hand as ``allegro``."""
    register(
        HandSpec(
            name="allegro",
            entry_point="ges_plugins.hands.allegro.hand:build_hand",
            requires=("mani_skill",),  # holds the URDF and meshes (found, not imported)
            install="pip install 'ges-unigrasp[allegro]'",
            description="Allegro Hand, right (16 joints, 4 fingers; little-finger slot served by the ring finger)",
        )
    )
