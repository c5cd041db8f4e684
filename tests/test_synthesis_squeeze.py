"""The squeeze's press directions reversed: the retracted pre-grasp hand (pure, forward kinematics only)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ges_core.kinematics import HandKinematics
from ges_core.registry import load_registry
from ges_core.synthesis.physics.pregrasp import PregraspConfig, pregrasp
from ges_core.synthesis.physics.squeeze import retract_joints
from ges_core.synthesis.types import Grasp

REGISTRY = load_registry(autoload=False)
HANDS = tuple(REGISTRY.names("hand"))


def _gaps(hand, q: np.ndarray) -> np.ndarray:
    """(F,) distance of each fingertip pad to what it opposes (thumb: the others' mean; others: the thumb)."""
    d = hand.description
    kin = HandKinematics.from_hand(hand)
    offsets = torch.tensor([f.tip_offset for f in d.fingers], dtype=torch.float64)
    tips = kin.points(torch.as_tensor(q)[None], list(d.tip_links), offsets)[0].numpy()
    thumb = [f.name for f in d.fingers].index(d.finger_for_slot("thumb").name)
    aims = np.repeat(tips[thumb][None], len(tips), axis=0)
    aims[thumb] = np.delete(tips, thumb, axis=0).mean(axis=0)
    return np.linalg.norm(aims - tips, axis=1)


@pytest.mark.parametrize("hand_name", HANDS)
def test_retract_backs_every_fingertip_off_what_it_opposes(hand_name):
    """Forward kinematics, not the Jacobian it is built from: moved alone, each finger's tip ends about 5 mm
    farther from what it opposes (2.5-10 mm: first order, and ``J J^T u`` also has a part across ``u`` that adds
    to the distance); within limits; joints of no finger are kept."""
    hand = REGISTRY.build_hand(hand_name)
    d = hand.description
    q = d.apply_couplings(d.closed_pose(0.5))
    out = retract_joints(hand, q, travel=0.005)
    before = _gaps(hand, q)
    for f, finger in enumerate(d.fingers):
        alone = q.copy()
        idx = d.joint_index(finger.joints)
        alone[idx] = out[idx]
        farther = _gaps(hand, alone)[f] - before[f]
        assert 0.0025 < farther < 0.01, (finger.name, farther)
    lim = d.limits_array
    assert np.all(out >= lim[:, 0] - 1e-12) and np.all(out <= lim[:, 1] + 1e-12)
    finger_joints = {j for f in d.fingers for j in f.joints}
    for k, name in enumerate(d.joint_names):
        if name not in finger_joints:
            assert out[k] == q[k], name
    np.testing.assert_allclose(d.apply_couplings(out), out)


@pytest.mark.parametrize("hand_name", HANDS)
def test_retract_grows_with_travel_and_is_capped(hand_name):
    hand = REGISTRY.build_hand(hand_name)
    d = hand.description
    q = d.apply_couplings(d.closed_pose(0.5))
    np.testing.assert_allclose(retract_joints(hand, q, travel=0.0), q)
    small, large = (retract_joints(hand, q, travel=t) for t in (0.005, 0.02))
    assert np.abs(large - q).sum() > np.abs(small - q).sum()
    capped = retract_joints(hand, q, travel=1.0, max_angle=0.2)
    bound = 0.2 * max([1.0, *(abs(c.ratio) for c in d.couplings)])  # a follower moves ratio x its leader
    assert np.abs(capped - q).max() <= bound + 1e-9


@pytest.mark.parametrize("hand_name", HANDS)
def test_pregrasp_opens_by_retracting_by_default(hand_name):
    hand = REGISTRY.build_hand(hand_name)
    d = hand.description
    grasp = Grasp(hand=hand_name, wrist_pose=np.array([0, 0, 0.2, 1, 0, 0, 0.0]), q=d.closed_pose(0.6))
    pre = pregrasp(hand, grasp, np.array([0.0, 0.0, -1.0]))
    np.testing.assert_allclose(pre.q, retract_joints(hand, grasp.q, travel=PregraspConfig().retract))
    other = pregrasp(hand, grasp, np.array([0.0, 0.0, -1.0]), PregraspConfig(retract=0.01))
    assert np.all(_gaps(hand, pre.q) > _gaps(hand, other.q))
