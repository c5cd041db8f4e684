"""Small shared helpers for simulator tests: a test Allegro hand and a box object.

The hand is built straight from the mani-skill Allegro URDF (render data stripped, mesh paths
absolute) with an inline YAML, so simulator tests do not depend on the Allegro hand plugin.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from contextlib import contextmanager
from functools import cache
from pathlib import Path

import numpy as np

from ges_core.hand import HandDescription, HandModel
from ges_core.hand_yaml import description_from_yaml
from ges_core.objects.asset import ObjectAsset
from ges_core.objects.simple import box_asset as simple_box
from ges_core.paths import cached_text_file
from ges_core.sim import SceneConfig, SimBackend
from ges_core.urdf import absolutize_mesh_paths, strip_render_data

__all__ = [
    "UP",
    "loaded_sim",
    "open_q",
    "pybullet_body",
    "ALLEGRO_TIPS",
    "TestHand",
    "allegro_test_hand",
    "allegro_urdf_source",
    "box_asset",
    "reordered",
    "run_python",
]

ALLEGRO_TIPS: tuple[str, ...] = ("link_15.0_tip", "link_3.0_tip", "link_7.0_tip", "link_11.0_tip")
"""Fingertip links of the test Allegro: thumb, index, middle, ring."""

ALLEGRO_YAML = """
name: allegro_test
fingers:
  - {name: thumb, slot: thumb, joints: [joint_12.0, joint_13.0, joint_14.0, joint_15.0], tip_link: link_15.0_tip}
  - {name: index, slot: index, joints: [joint_0.0, joint_1.0, joint_2.0, joint_3.0], tip_link: link_3.0_tip}
  - {name: middle, slot: middle, joints: [joint_4.0, joint_5.0, joint_6.0, joint_7.0], tip_link: link_7.0_tip}
  - {name: ring, slot: ring, joints: [joint_8.0, joint_9.0, joint_10.0, joint_11.0], tip_link: link_11.0_tip}
slot_fill: {little: ring}
wrist: {link: palm, palm_normal: [1, 0, 0], finger_direction: [0, 0, 1]}
middle_finger_length: 0.105
scale: 1.33
open_pose: {default: 0.0, "joint_12\\\\.0": 0.263}  # thumb rotation's lower limit is 0.263 rad
pd_stiffness: {default: 400.0}  # mani-skill's Allegro agent (joint_stiffness = 4e2)
pd_damping: {default: 10.0}  # mani-skill's Allegro agent (joint_damping = 1e1)
"""


REPO_ROOT = Path(__file__).resolve().parents[1]


def run_python(*args: str) -> subprocess.CompletedProcess[str]:
    """``python ARGS`` in a fresh process at the repository root, output captured.

    PYTHONUNBUFFERED is dropped so that C's stdout is block-buffered on the pipe, as for a user
    piping ``ges`` into a file (with it set, C output is unbuffered and leaks differently).
    """
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    return subprocess.run(
        [sys.executable, *args], cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=120, check=False
    )


def allegro_urdf_source() -> Path:
    """The mani-skill right Allegro URDF (found without importing mani_skill, which is slow)."""
    from ges_plugins.hands.allegro.hand import source_urdf_path

    return source_urdf_path()


class TestHand(HandModel):
    """A HandModel over a ready URDF file and a description."""

    __test__ = False  # not a pytest test class

    def __init__(self, description: HandDescription, urdf: Path) -> None:
        self._description = description
        self._urdf = urdf

    @property
    def description(self) -> HandDescription:
        return self._description

    def urdf_path(self) -> Path:
        return self._urdf


@cache
def allegro_test_hand() -> TestHand:
    """The right Allegro hand (16 joints), URDF cleaned and cached under the GES cache dir."""
    source = allegro_urdf_source()
    text = absolutize_mesh_paths(strip_render_data(source.read_text()), source.parent)
    return TestHand(
        description_from_yaml(ALLEGRO_YAML, text), cached_text_file(text, "test_hands", stem="allegro_right")
    )


def reordered(hand: HandModel, order: list[int]) -> TestHand:
    """The same hand with its per-joint data listed in another joint order (``order``: old index per new slot)."""
    d = hand.description
    fields = ("joint_names", "joint_limits", "open_pose", "pd_stiffness", "pd_damping")
    return TestHand(
        dataclasses.replace(d, **{f: tuple(getattr(d, f)[i] for i in order) for f in fields}), hand.urdf_path()
    )


def box_asset(
    half_extents: tuple[float, float, float] = (0.03, 0.03, 0.03),
    *,
    object_id: str = "test/box",
    density: float = 500.0,
    friction: float = 1.0,
) -> ObjectAsset:
    """A box centred on its object frame (the simulator tests' convention), one exact box primitive."""
    return simple_box(half_extents, object_id=object_id, density=density, friction=friction, resting=False)


UP = np.array([0.0, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0])
"""A base pose well above the table."""


def loaded_sim(backend_cls: type[SimBackend], hand: HandModel | None = None, *, floating: bool = True, **scene):
    """A backend of ``backend_cls`` with ``SceneConfig(**scene)``, the hand loaded if given."""
    sim = backend_cls(SceneConfig(**scene))
    if hand is not None:
        sim.load_hand(hand, floating=floating)
    return sim


def open_q(hand: HandModel, n: int = 1) -> np.ndarray:
    """(n, K) open poses."""
    return np.tile(np.asarray(hand.description.open_pose), (n, 1))


@contextmanager
def pybullet_body(urdf: Path):
    """A private PyBullet DIRECT client with ``urdf`` loaded fixed: yields (pybullet, client, body, joint infos).

    Every call names the client, so a client left open elsewhere in the process cannot interfere.
    """
    import pybullet

    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(urdf), useFixedBase=True, physicsClientId=client)
        count = pybullet.getNumJoints(body, physicsClientId=client)
        yield pybullet, client, body, [pybullet.getJointInfo(body, j, physicsClientId=client) for j in range(count)]
    finally:
        pybullet.disconnect(client)
