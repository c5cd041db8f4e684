"""GES-UniGrasp plugin: registers the hand ``inspire`` (Inspire Robotics RH56DFX, right, with its two-joint wrist)
through the ``ges.plugins`` entry point.

The URDF and its ``.glb`` meshes are mani-skill's (``mani_skill/assets/robots/inspire_hand/RH56DFX-2LR/urdf/
inspire_hand_right.urdf``, CC BY-NC-SA 4.0), read where mani-skill installed them: nothing is copied. The
framework converts the ``.glb`` meshes to OBJ, turns the six ``<mimic>`` tags into couplings with offset and
decomposes the meshes whose convex hulls are too far off (``ges hand prepare inspire``, or ``ges synth`` before its
first run). This package only adds the description YAML (``inspire.yaml``). Unlike the Ability package, nothing in
it was tuned on grasp results: every number is read off the URDF or its meshes, or is mani-skill's own setting,
except the two the new-hand tutorial names for one-actuator fingers (docs/hands/inspire.md has what Stage 1 does with
it, and why each).
"""

from __future__ import annotations

from pathlib import Path

from ges_core import hookimpl
from ges_core.hand_files import FileHand, installed_file
from ges_core.specs import HandSpec

__all__ = ["build_hand", "inspire_urdf"]

HERE = Path(__file__).resolve().parent
URDF_RELPATH = "assets/robots/inspire_hand/RH56DFX-2LR/urdf/inspire_hand_right.urdf"
"""mani-skill's right RH56DFX with its wrist (the ``_floating`` twin adds mani-skill's own six root joints)."""


def inspire_urdf() -> Path:
    """Path of mani-skill's right Inspire hand URDF, as installed, found without importing mani-skill (2-3 s);
    raises if mani-skill is missing."""
    return installed_file(
        "mani_skill", URDF_RELPATH, what="the 'inspire' hand", distribution="mani-skill",
        install="pip install mani-skill",
    )  # fmt: skip


def build_hand(**settings) -> FileHand:
    """The Inspire hand: 14 joints (2 wrist, 4 thumb, 2 per finger), 8 driven (each finger's PIP and the thumb's
    MCP and IP follow through ``<mimic>``)."""
    return FileHand(HERE / "inspire.yaml", inspire_urdf(), **settings)


@hookimpl
def ges_register_hands(register):
    """Register ``inspire`` (needs mani-skill for its URDF)."""
    register(
        HandSpec(
            name="inspire",
            entry_point="ges_inspire_hand:build_hand",
            description="Inspire RH56DFX hand (right, wrist + coupled fingers, .glb meshes; mani-skill URDF)",
            requires=("mani_skill",),
            install="pip install mani-skill",
        )
    )
