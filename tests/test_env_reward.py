"""Reward terms of ges_core.env.reward on hand-computed small cases."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from ges_core.env.reward import (
    REWARD_PRESETS,
    RewardConfig,
    compute_reward,
    consistency_groups,
    direction_variance,
    finger_l1,
    reward_preset,
)
from ges_core.errors import ConfigError
from ges_core.registry import load_registry


def test_finger_l1_takes_the_worst_finger() -> None:
    dq = torch.tensor([[0.1, -0.2, 0.3, 0.05], [0.0, 0.0, -1.0, 0.0]])
    fingers = [torch.tensor([0, 1]), torch.tensor([2, 3])]
    assert torch.allclose(finger_l1(dq, fingers), torch.tensor([0.35, 1.0]))


def test_direction_variance_of_signs() -> None:
    groups = torch.tensor([[0, 1, 2, 3]])
    v = torch.tensor([[1.0, 2.0, -3.0, -0.5], [1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 0.0, 2.0]])
    # signs (1,1,-1,-1): mean 0, var 1; all equal: 0; (0,0,0,1): mean .25, var 3/16
    assert torch.allclose(direction_variance(v, groups), torch.tensor([1.0, 0.0, 3 / 16]))


def test_consistency_groups_allegro_skip_thumb() -> None:
    hand = load_registry().build_hand("allegro").description
    groups = consistency_groups(hand)
    non_thumb = [f for f in hand.fingers if f.slot != "thumb"]
    assert groups.shape == (min(len(f.joints) for f in non_thumb), len(non_thumb))
    for j, row in enumerate(groups.tolist()):
        assert [hand.joint_names[i] for i in row] == [f.joints[j] for f in non_thumb]


def test_consistency_groups_needs_two_fingers() -> None:
    hand = load_registry().build_hand("allegro").description
    with pytest.raises(ConfigError, match="needs >= 2 non-thumb fingers"):
        consistency_groups(dataclasses.replace(hand, fingers=hand.fingers[:2]), thumb_slot=hand.fingers[0].slot)


def test_compute_reward_hand_computed() -> None:
    cfg = RewardConfig(w_goal=1, w_reach=2, w_lift=3, w_move=4, w_smooth=0.5, w_consistency=0.25, lift_height=0.2)
    obj_start = torch.tensor([[0.0, 0.0, 0.05]], dtype=torch.float64)
    obj_pos = torch.tensor([[0.0, 0.0, 0.15]], dtype=torch.float64)  # halfway up, 0.1 m from the target
    tips = obj_pos[:, None] + torch.tensor([[[0.03, 0.0, 0.0], [0.0, -0.03, 0.0]]], dtype=torch.float64)
    vel = torch.tensor([[1.0, -1.0, 2.0, 0.0]], dtype=torch.float64)
    total, terms = compute_reward(
        cfg,
        q_error=torch.tensor([[0.2, 0.0, 0.1, -0.3]], dtype=torch.float64),
        finger_joints=[torch.tensor([0, 1]), torch.tensor([2, 3])],
        tip_pos=tips,
        obj_pos=obj_pos,
        obj_start=obj_start,
        joint_vel=vel,
        wrist_vel=torch.tensor([[0.1, 0, 0, 0, 0, 0.2]], dtype=torch.float64),
        groups=torch.tensor([[0, 2], [1, 3]]),
    )
    want = {
        "goal": math.exp(-cfg.lambda_goal * 0.4),
        "reach": math.exp(-cfg.lambda_reach * 0.03),
        "lift": math.exp(-cfg.lambda_lift * 0.1),
        "move": 0.5,
        "smooth": -(1 + 1 + 4 + 0.01 + 0.04),
        "consistency": -(0.0 + 0.25),  # signs (1,1): 0; (-1,0): var 0.25
    }
    for name, value in want.items():
        assert terms[name].item() == pytest.approx(value), name
    weights = dict(goal=1, reach=2, lift=3, move=4, smooth=0.5, consistency=0.25)
    assert total.item() == pytest.approx(sum(weights[k] * v for k, v in want.items()))


def test_presets() -> None:
    assert set(REWARD_PRESETS) == {"udgr", "tsr", "tsr_scr"}
    assert reward_preset("udgr").w_goal == 0 and reward_preset("tsr").w_smooth == 0
    assert reward_preset("tsr_scr").w_smooth > 0 and reward_preset("tsr_scr").w_consistency > 0
    with pytest.raises(ConfigError, match=r"unknown reward preset 'tsr\+'; choose one of udgr, tsr, tsr_scr"):
        reward_preset("tsr+")
