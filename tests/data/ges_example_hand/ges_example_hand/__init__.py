"""An outside GES-UniGrasp plugin: registers the hand ``example_gripper`` through its entry point."""

from __future__ import annotations

from pathlib import Path

from ges_core import hookimpl
from ges_core.hand_files import FileHand
from ges_core.specs import HandSpec

HERE = Path(__file__).resolve().parent


def build_hand(**settings) -> FileHand:
    """Two fingers of two joints each, box geometry, both closing toward the palm normal."""
    return FileHand(HERE / "gripper.yaml", HERE / "gripper.urdf", **settings)


@hookimpl
def ges_register_hands(register):
    register(HandSpec(name="example_gripper", entry_point="ges_example_hand:build_hand", description="two-finger test gripper"))
