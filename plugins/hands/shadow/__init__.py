"""The Shadow Dexterous Hand, converted from gymnasium-robotics' MJCF (MIT) to a cached URDF.

Registration only: the converter (MuJoCo) loads when the hand is built.
"""

from __future__ import annotations

from collections.abc import Callable

from ges_core import hookimpl
from ges_core.specs import HandSpec


@hookimpl
def ges_register_hands(register: Callable[[HandSpec], None]) -> None:
    """Register the ``shadow`` hand."""
    register(
        HandSpec(
            name="shadow",
            entry_point="ges_plugins.hands.shadow.hand:build_hand",
            requires=("gymnasium_robotics", "mujoco"),  # the MJCF source and its converter
            install="pip install 'ges-unigrasp[shadow]'",
            # Only the 18 link pairs of the MJCF's <contact><pair> list collide, as in MuJoCo: the same Stage 1 and
            # Stage 2 verdicts as every pair colliding, SAPIEN's env-step a quarter cheaper (docs/hands/shadow.md,
            # "Self-collision"). registry.yaml's settings.hand.shadow.self_collision: all brings back every pair.
            settings={"self_collision": "mjcf_pairs"},
            description="Shadow Dexterous Hand with forearm, 24 joints (gymnasium-robotics MJCF -> URDF)",
        )
    )
