"""The impossible-inertia check (ges_core/hand_prep/inertia.py; `ges hand lint` reports it as a note).

Independent references: a box's inertia and its farthest corner in closed form, the built-in hands' URDFs."""

from __future__ import annotations

import numpy as np
import pytest

from ges_core.hand_prep.inertia import PLACEHOLDER_MOMENT, implausible_inertias
from ges_core.registry import load_registry

from conftest import ability_hand

SIZE = np.array([0.04, 0.02, 0.01])
"""m, the test link's box."""
MASS = 0.005
"""kg."""
RPY = (0.3, -0.2, 0.5)
"""The inertial origin's rotation: the tensor is written in that frame."""


def _box_inertia() -> np.ndarray:
    """(3, 3) a solid box's inertia about its centre, box axes: m (b^2 + c^2) / 12 ..."""
    a, b, c = SIZE
    return MASS / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])


def _urdf(ixx: float, com=(0.0, 0.0, 0.0), mesh: str | None = None) -> str:
    geometry = f'<mesh filename="{mesh}"/>' if mesh else f'<box size="{" ".join(map(str, SIZE))}"/>'
    x, y, z = com
    return f"""<robot name="t"><link name="a">
      <inertial><origin xyz="{x} {y} {z}" rpy="{" ".join(map(str, RPY))}"/><mass value="{MASS}"/>
        <inertia ixx="{ixx}" iyy="{ixx}" izz="{ixx}" ixy="0" ixz="0" iyz="0"/></inertial>
      <collision><geometry>{geometry}</geometry></collision></link></robot>"""


def test_an_impossible_tensor_is_found_with_its_bound(tmp_path):
    """1e-3 kg m^2 on a 5 g, 4 cm box, centre of mass off the box centre, inertial frame rotated: reported, with
    the file's largest moment and the bound m R^2 to the box's farthest corner from the centre of mass."""
    com = np.array([0.004, 0.0, -0.002])
    (found,) = implausible_inertias(_urdf(1e-3, com), tmp_path)
    assert found.link == "a" and found.mass == MASS and found.largest == pytest.approx(1e-3)
    assert found.bound == pytest.approx(MASS * float(np.sum((SIZE / 2 + np.abs(com)) ** 2)), rel=1e-6)


def test_possible_placeholder_and_unreadable_tensors_are_not_reported(tmp_path):
    """The true box tensor (any orientation: 2.6e-6 > every moment), the placeholder level and a link whose
    mesh is missing are not reported."""
    fine = _box_inertia().max()
    for text in (
        _urdf(fine),
        _urdf(PLACEHOLDER_MOMENT),
        _urdf(1e-3, mesh=str(tmp_path / "missing.obj")),
    ):
        assert implausible_inertias(text, tmp_path) == []


@pytest.mark.parametrize("name", ["allegro", "shadow"])
def test_builtin_hands_have_no_impossible_inertia(name):
    """No Allegro or Shadow link is reported (the Shadow's 1e-5 placeholders are kept)."""
    from ges_core.hand_prep.engine_urdf import engine_urdf

    hand = load_registry().build_hand(name)
    text = engine_urdf(hand.urdf_text(), hand.urdf_path().parent)
    assert implausible_inertias(text, hand.urdf_path().parent) == []


def test_ability_phalanges_are_far_over_the_bound():
    """mani-skill's Ability URDF: every phalanx (and the palm) exceeds m R^2, the phalanges by more than 30x."""
    from ges_core.hand_prep.engine_urdf import engine_urdf

    hand = ability_hand()
    found = implausible_inertias(engine_urdf(hand.urdf_text(), hand.urdf_path().parent), hand.urdf_path().parent)
    phalanges = {f"{finger}_L{k}" for finger in ("thumb", "index", "middle", "ring", "pinky") for k in (1, 2)}
    assert phalanges <= {f.link for f in found}
    assert all(f.largest > 30 * f.bound for f in found if f.link in phalanges)


def test_lint_reports_the_ability_inertias_as_one_note_and_nothing_for_the_builtins():
    """`ges hand lint` (lint_hand) names each implausible link with its factor in one note, which does not fail
    the lint; the built-in hands get none."""
    from ges_core.lint import lint_hand
    from ges_core.lint.checks_assets import check_inertia_bound

    registry = load_registry()
    hand = ability_hand()
    found = lint_hand(hand, skip=("hull-overlap",))
    (note,) = [p for p in found if p.check == "inertia" and p.note]
    # the note names what the check finds (the finder itself is checked against a closed form above)
    expected = implausible_inertias(hand.urdf_text(), hand.urdf_path().parent)
    assert len(expected) >= 10 and f"{len(expected)} link(s)" in note.what
    assert all(f"'{f.link}' ({f.largest / f.bound:.0f}x)" in note.what for f in expected)
    assert all(check_inertia_bound(registry.build_hand(name)) == [] for name in ("allegro", "shadow"))
