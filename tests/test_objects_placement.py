"""The resting pose's roll test (``placement.tilt_rise``) and the rule that sets a rolling pose aside."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from ges_core.objects import placement


@pytest.mark.parametrize("half", [(0.02, 0.03, 0.01), (0.05, 0.015, 0.04)])
@pytest.mark.parametrize("tilt_deg", [3.0, 5.0, 10.0])
def test_a_box_on_a_face_rises_as_the_tilt_about_its_shorter_side_says(half, tilt_deg):
    """Tilted about a horizontal axis at angle a, a box of half-extents (A, B, C) on its C face lifts its centre
    by sin(t) (A|sin a| + B|cos a|) + C (cos t - 1) above its lowest corner; the worst axis is a = 0 or 90 deg."""
    a, b, c = half
    box = trimesh.creation.box(extents=2 * np.asarray(half))
    t = np.radians(tilt_deg)
    expected = min(a, b) * np.sin(t) + c * (np.cos(t) - 1.0)
    assert placement.tilt_rise(box.vertices, np.zeros(3), tilt_deg) == pytest.approx(expected, rel=1e-9)


def test_a_cylinder_on_its_side_rolls_and_upright_does_not():
    cylinder = trimesh.creation.cylinder(radius=0.034, height=0.10, sections=128)
    upright = placement.tilt_rise(cylinder.vertices, cylinder.center_mass)
    lying = Rotation.from_euler("x", 90, degrees=True).apply(cylinder.vertices)
    assert upright > 2e-3  # 34 mm * sin 5 deg - 50 mm * (1 - cos 5 deg) = 2.77 mm
    assert placement.tilt_rise(lying, np.zeros(3)) < 0.05 * placement.ROLL_FLOOR


def _poses() -> tuple[np.ndarray, np.ndarray]:
    """A can's hull (r 34 mm, h 10 cm) and two resting transforms: on its side (x turned 90 deg), upright."""
    can = trimesh.creation.cylinder(radius=0.034, height=0.10, sections=128)
    side, up = np.eye(4), np.eye(4)
    side[:3, :3] = Rotation.from_euler("x", 90, degrees=True).as_matrix()
    return can.vertices, np.stack([side, up])


@pytest.mark.parametrize(
    ("probs", "picked"),
    [
        ((0.09, 0.08), 1),  # the YCB soup can's case: the side barely more probable, upright far steadier
        ((0.09, 0.02), 0),  # an upright pose under ROLL_MIN_SHARE of the side's probability is not taken
    ],
)
def test_a_rolling_most_probable_pose_gives_way_to_a_steady_one(probs, picked):
    vertices, transforms = _poses()
    assert placement._steadiest(transforms, np.asarray(probs), vertices, np.zeros(3)) == picked


def test_a_steady_most_probable_pose_is_kept():
    vertices, transforms = _poses()
    upright_first = transforms[::-1].copy()
    assert placement._steadiest(upright_first, np.asarray([0.09, 0.08]), vertices, np.zeros(3)) == 0
