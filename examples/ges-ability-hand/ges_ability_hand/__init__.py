"""GES-UniGrasp plugin: registers the hand ``ability`` (PSYONIC Ability hand, right) through the
``ges.plugins`` entry point.

The URDF and meshes are mani-skill's (``mani_skill/assets/robots/ability_hand/ability_hand_right.urdf``),
read where mani-skill installed them: nothing is copied. The framework turns its ``<mimic>`` tags into
couplings with offset and decomposes its palm and distal-phalanx meshes (``ges hand prepare ability``);
this package only adds the description YAML (``ability.yaml``), whose every tuned number says where it
came from.
"""

from __future__ import annotations

from pathlib import Path

from ges_core import hookimpl
from ges_core.hand_files import FileHand, installed_file
from ges_core.specs import HandSpec

__all__ = ["ability_urdf", "build_hand"]

HERE = Path(__file__).resolve().parent
URDF_NAME = "ability_hand_right.urdf"
"""mani-skill's right Ability hand with OBJ meshes (the ``_glb`` twin carries the same links as .glb)."""


def ability_urdf() -> Path:
    """Path of mani-skill's right Ability hand URDF, as installed, found without importing mani-skill (2-3 s);
    raises if mani-skill is missing."""
    return installed_file(
        "mani_skill", f"assets/robots/ability_hand/{URDF_NAME}", what="the 'ability' hand", distribution="mani-skill",
        install="pip install mani-skill",
    )  # fmt: skip


def build_hand(**settings) -> FileHand:
    """The Ability hand: 10 joints, 6 actuators (each finger's q2 follows its q1; the thumb has two)."""
    return FileHand(HERE / "ability.yaml", ability_urdf(), **settings)


@hookimpl
def ges_register_hands(register):
    """Register ``ability`` (needs mani-skill for its URDF)."""
    register(
        HandSpec(
            name="ability",
            entry_point="ges_ability_hand:build_hand",
            description="PSYONIC Ability hand (right, coupled fingers; mani-skill URDF)",
            requires=("mani_skill",),
            install="pip install mani-skill",
        )
    )
