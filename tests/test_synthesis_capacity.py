"""fingertip_capacity on the real Allegro model: frames (the same grasp moved about the vertical holds the same), the
touching test, friction, the slots' contacts, and two opposed fingertips against finite-difference Jacobians."""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from ges_core.contact import FINGER_SLOTS, ContactSet
from ges_core.errors import ConfigError
from ges_core.kinematics import shared_kinematics
from ges_core.registry import load_registry
from ges_core.synthesis.contacts.lift_friction import held_weight
from ges_core.synthesis.physics.capacity import _pads_in_object_frame, fingertip_capacity
from ges_core.synthesis.types import Grasp
from ges_core.transforms import compose, euler_xyz_to_quat


@pytest.fixture(scope="module")
def allegro():
    return load_registry().build_hand("allegro")


def _curled(hand) -> np.ndarray:
    """Joints halfway between the open pose and the upper limits: the fingertips curl toward the thumb."""
    d = hand.description
    return d.apply_couplings(0.5 * (np.asarray(d.open_pose) + d.limits_array[:, 1]))


def _object_through_pads(hand, grasp: Grasp) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An 'object' whose surface passes through the pads (one sample each) with normals from their centroid: points,
    normals, the centroid."""
    pads, _ = _pads_in_object_frame(hand, grasp)
    centre = pads.mean(axis=0)
    normals = (pads - centre) / np.linalg.norm(pads - centre, axis=1, keepdims=True)
    return pads, normals, centre


def test_the_same_grasp_turned_about_the_vertical_holds_the_same(allegro):
    grasp = Grasp("allegro", np.array([0.0, 0.0, 0.1, 1.0, 0.0, 0.0, 0.0]), _curled(allegro))
    points, normals, centre = _object_through_pads(allegro, grasp)
    base = fingertip_capacity(allegro, grasp, points, normals, 1.0, center=centre)
    assert len(base.fingers) == 4 and 0.0 < base.weight < math.inf
    turn = np.concatenate([[0.1, -0.06, 0.0], euler_xyz_to_quat(np.array([0.0, 0.0, 0.7]))])
    moved = Grasp("allegro", compose(turn, grasp.wrist_pose), grasp.q)
    points2, normals2, centre2 = _object_through_pads(allegro, moved)
    turned = Rotation.from_euler("z", 0.7)  # scipy, not our quaternions: the pads moved with the wrist
    np.testing.assert_allclose(points2, turned.apply(points) + [0.1, -0.06, 0.0], atol=1e-9)
    again = fingertip_capacity(allegro, moved, points2, normals2, 1.0, center=centre2)
    assert again.weight == pytest.approx(base.weight, rel=0.01)  # 1 %: the 8-edge cones turn with the normals
    # the pads moved with the wrist: the first object's samples are now off them, so nothing touches
    assert fingertip_capacity(allegro, moved, points, normals, 1.0, center=centre).fingers == ()


def test_less_friction_holds_less_and_a_surface_off_the_pads_holds_nothing(allegro):
    grasp = Grasp("allegro", np.array([0.0, 0.0, 0.1, 1.0, 0.0, 0.0, 0.0]), _curled(allegro))
    points, normals, centre = _object_through_pads(allegro, grasp)
    one = fingertip_capacity(allegro, grasp, points, normals, 1.0, center=centre).weight
    assert 0.0 < fingertip_capacity(allegro, grasp, points, normals, 0.5, center=centre).weight < one
    far = fingertip_capacity(allegro, grasp, points + [0.0, 0.0, 0.05], normals, 1.0, center=centre)
    assert far.fingers == () and far.weight == 0.0


def test_two_opposed_fingertips_are_held_with_their_own_joints_jacobians(allegro):
    """Only the thumb and the index touch, on a vertical pair of faces through their pads facing each other. The
    capacity must be the linear program fed with Jacobians taken by central finite differences of the pads' forward
    kinematics (positions only, not the analytic Jacobians), each finger with its own joints: this checks which
    columns, joints and limits reach the program (the program itself is checked against closed forms in
    test_synthesis_lift_friction.py), with the hand's limits and with a thumb ten times weaker (so that the thumb's
    joints, not the index's, bind)."""
    q = _curled(allegro)
    shift = np.array([0.0, 0.0, 0.1])
    grasp = Grasp("allegro", np.concatenate([shift, [1.0, 0.0, 0.0, 0.0]]), q)
    d = allegro.description
    kin = shared_kinematics(allegro)
    offsets = torch.tensor([f.tip_offset for f in d.fingers], dtype=torch.float64)

    def pads(joints: np.ndarray) -> np.ndarray:  # (F, 3), hand base frame = object frame shifted by the wrist
        points, _ = kin.points_and_jacobians(torch.as_tensor(joints)[None], list(d.tip_links), offsets)
        return points[0].numpy() + shift

    step = 1e-6
    columns = [(pads(q + step * e) - pads(q - step * e)) / (2 * step) for e in np.eye(len(q))]
    finite = np.stack(columns, axis=-1)  # (F, 3, K)
    names = [f.name for f in d.fingers]
    thumb, index = names.index(d.finger_for_slot("thumb").name), names.index(d.finger_for_slot("index").name)
    at = pads(q)[[thumb, index]]
    u = at[1] - at[0]
    u[2] = 0.0  # horizontal faces
    u /= np.linalg.norm(u)
    normals = np.stack([-u, u])  # outward: the thumb's face looks away from the index
    center = at.mean(axis=0)
    joints = [np.asarray(d.joint_index(d.fingers[f].joints)) for f in (thumb, index)]
    weak_thumb = d.effort_limits_array.copy()
    weak_thumb[joints[0]] /= 10  # then the thumb's joints bind, not the index's
    weights = []
    for effort in (d.effort_limits_array, weak_thumb):
        hand = SimpleNamespace(description=replace(d, effort_limits=tuple(effort)), urdf_text=allegro.urdf_text)
        got = fingertip_capacity(hand, grasp, at, normals, 1.0, center=center, near=1e-6)
        assert set(got.fingers) == {names[thumb], names[index]}
        want = held_weight(at, normals, 1.0, center, finite[[thumb, index]], joints, effort)
        assert 0.0 < got.weight == pytest.approx(want, rel=1e-5)
        weights.append(got.weight)
    assert weights[1] < weights[0]


def test_the_slots_contacts_give_the_normals_where_they_lie_at_the_pads(allegro):
    """With a record's Stage 1 contacts, a finger whose slot's contact lies within ``near`` of its pad pushes along
    that contact's normal instead of the nearest sample's: the same normals as the samples hold the same; turning the
    index's normal straight up (no squeeze, no lift from it) holds less; contacts 5 cm off the pads are ignored."""
    grasp = Grasp("allegro", np.array([0.0, 0.0, 0.1, 1.0, 0.0, 0.0, 0.0]), _curled(allegro))
    points, normals, centre = _object_through_pads(allegro, grasp)
    d = allegro.description
    rows = [FINGER_SLOTS.index(f.slot) for f in d.fingers]
    positions, slot_normals = np.zeros((5, 3)), np.tile([0.0, 0.0, 1.0], (5, 1))
    positions[rows], slot_normals[rows] = points, normals
    plain = fingertip_capacity(allegro, grasp, points, normals, 1.0, center=centre).weight
    same = ContactSet(positions, slot_normals, "test")
    assert fingertip_capacity(allegro, grasp, points, normals, 1.0, center=centre, contacts=same).weight == plain
    index = FINGER_SLOTS.index("index")
    up = slot_normals.copy()
    up[index] = [0.0, 0.0, 1.0]
    turned = ContactSet(positions, up, "test")
    assert fingertip_capacity(allegro, grasp, points, normals, 1.0, center=centre, contacts=turned).weight < plain
    away = ContactSet(positions + [0.0, 0.0, 0.05], up, "test")
    assert fingertip_capacity(allegro, grasp, points, normals, 1.0, center=centre, contacts=away).weight == plain


def test_a_hand_without_effort_limits_has_no_bound(allegro):
    d = allegro.description
    bare = SimpleNamespace(description=replace(d, effort_limits=()))
    grasp = Grasp("allegro", np.array([0.0, 0.0, 0.1, 1.0, 0.0, 0.0, 0.0]), _curled(allegro))
    with pytest.raises(ConfigError, match="declares no effort_limits"):
        fingertip_capacity(bare, grasp, np.zeros((4, 3)), np.ones((4, 3)), 1.0)
