"""The Shadow hand as a :class:`~ges_core.hand.HandModel`: cached URDF + ``shadow.yaml``."""

from __future__ import annotations

from itertools import combinations
from pathlib import Path
from typing import Any

from ges_core.errors import ConfigError
from ges_core.hand import HandDescription, HandModel
from ges_core.hand_yaml import description_from_yaml
from ges_core.urdf import neighbour_link_pairs, parse_urdf, solid_links
from ges_plugins.hands.shadow.assets import cached_contact_pairs, cached_urdf

__all__ = ["DESCRIPTION_FILE", "SELF_COLLISION", "ShadowHand", "build_hand", "pairs_left_out"]

DESCRIPTION_FILE = Path(__file__).with_name("shadow.yaml")
"""Fingers, wrist convention, sizes, open pose, PD gains and tendon couplings of the hand."""


SELF_COLLISION = ("mjcf_pairs", "all")
"""Which hand-hand link pairs collide (docs/hands/shadow.md, "Self-collision"): the MJCF's own pair list (default),
or every pair but the neighbours (the rule of a hand given as a URDF; the only one before 5 December 2026)."""


class ShadowHand(HandModel):
    """The Shadow Dexterous Hand with its forearm: 24 revolute joints, base link ``forearm``.

    asset_dir: a folder laid out like ``gymnasium_robotics/envs/assets`` (default: the installed
        package's); the URDF is converted from it on first use and cached by content hash.
    self_collision: ``mjcf_pairs`` (only the 18 link pairs of the MJCF's ``<contact><pair>`` list collide, as in
        MuJoCo) or ``all`` (every pair but the neighbours); a ``self_collision_exclude`` override replaces either.
    overrides: top-level ``shadow.yaml`` keys to replace (registry ``settings.hand.shadow``).
    """

    def __init__(
        self, *, asset_dir: str | Path | None = None, self_collision: str = SELF_COLLISION[0], **overrides: Any
    ) -> None:
        if self_collision not in SELF_COLLISION:
            raise ConfigError(
                f"hand 'shadow': self_collision '{self_collision}' is not one of {', '.join(SELF_COLLISION)} "
                "(mjcf_pairs: only the link pairs the MJCF lists collide; all: every pair but the neighbours)"
            )
        folder = Path(asset_dir) if asset_dir is not None else None
        self._urdf_path = cached_urdf(folder)
        if self_collision == "mjcf_pairs" and "self_collision_exclude" not in overrides:
            overrides["self_collision_exclude"] = pairs_left_out(self.urdf_text(), cached_contact_pairs(folder))
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


def pairs_left_out(urdf_text: str, allowed: list[tuple[str, str]]) -> list[list[str]]:
    """Sorted link pairs that collide under the usual rule (both links with collision geometry, not neighbours:
    :func:`ges_core.urdf.neighbour_link_pairs`) but are not in ``allowed``: the hand's ``self_collision_exclude``
    that leaves exactly ``allowed`` colliding."""
    solid = sorted(solid_links(parse_urdf(urdf_text)))
    neighbours, keep = neighbour_link_pairs(urdf_text), {frozenset(pair) for pair in allowed}
    return [[a, b] for a, b in combinations(solid, 2) if frozenset((a, b)) not in neighbours | keep]


def build_hand(**settings: Any) -> ShadowHand:
    """Registry factory: ``settings`` are ``asset_dir``, ``self_collision`` and ``shadow.yaml`` overrides."""
    return ShadowHand(**settings)
