"""The Shadow hand as a :class:`~ges_core.hand.HandModel`: cached URDF + ``shadow.yaml``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ges_core.hand import HandDescription, HandModel
from ges_core.hand_yaml import description_from_yaml
from ges_plugins.hands.shadow.assets import cached_urdf

__all__ = ["DESCRIPTION_FILE", "ShadowHand", "build_hand"]

DESCRIPTION_FILE = Path(__file__).with_name("shadow.yaml")
"""Fingers, wrist convention, sizes, open pose, PD gains and tendon couplings of the hand."""


class ShadowHand(HandModel):
    """The Shadow Dexterous Hand with its forearm: 24 revolute joints, base link ``forearm``.

    asset_dir: a folder laid out like ``gymnasium_robotics/envs/assets`` (default: the installed
        package's); the URDF is converted from it on first use and cached by content hash.
    overrides: top-level ``shadow.yaml`` keys to replace (registry ``settings.hand.shadow``).
    """

    def __init__(self, *, asset_dir: str | Path | None = None, **overrides: Any) -> None:
        self._urdf_path = cached_urdf(Path(asset_dir) if asset_dir is not None else None)
        self._description = description_from_yaml(
            DESCRIPTION_FILE.read_text(), self.urdf_text(), source=str(DESCRIPTION_FILE), **overrides
        )

    @property
    def description(self) -> HandDescription:
        """The hand's declared data (joint limits read from the converted URDF)."""
        return self._description

    def urdf_path(self) -> Path:
        """The cached URDF converted from the MJCF (absolute mesh paths, no materials, no visuals)."""
        return self._urdf_path


def build_hand(**settings: Any) -> ShadowHand:
    """Registry factory: ``settings`` are ``asset_dir`` and ``shadow.yaml`` overrides."""
    return ShadowHand(**settings)
