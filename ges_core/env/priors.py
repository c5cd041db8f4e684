"""The paper's prior ablation (Init/NoInit x Goal/NoGoal): the EnvConfig overrides of each preset and the NoInit
start pose (the open hand above the object). Re-exported by :mod:`ges_core.env.grasp_env`; see ``docs/env.md``."""

from __future__ import annotations

import numpy as np
import torch

from ges_core.errors import ConfigError
from ges_core.hand import HandModel
from ges_core.transforms import matrix_to_pose, rotation_between_frames

__all__ = ["PRIOR_PRESETS", "open_hand_start_pose", "prior_preset"]

PRIOR_PRESETS: dict[str, dict[str, bool]] = {
    "init_goal": {"init_prior": True, "goal_prior": True},
    "init_nogoal": {"init_prior": True, "goal_prior": False},
    "noinit_goal": {"init_prior": False, "goal_prior": True},
    "noinit_nogoal": {"init_prior": False, "goal_prior": False},
}
"""The paper's prior ablation: EnvConfig overrides per preset (``cfg.model_copy(update=prior_preset(name))``)."""


def prior_preset(name: str) -> dict[str, bool]:
    """The EnvConfig overrides of the prior-ablation preset ``name`` (a fresh dict)."""
    if name not in PRIOR_PRESETS:
        raise ConfigError(f"unknown prior preset '{name}'; choose one of {', '.join(PRIOR_PRESETS)}")
    return dict(PRIOR_PRESETS[name])


def open_hand_start_pose(hand: HandModel, obj_pos: np.ndarray, height: float) -> np.ndarray:
    """(n, 7) base-link poses of the NoInit start: open hand, palm down, wrist link ``height`` m above ``obj_pos``.

    obj_pos: (n, 3) object origins, world, m. Palm down per the hand's wrist convention: ``palm_normal``
    along world -z, ``finger_direction`` toward world +x (as :func:`ges_core.sim_check.grasp_start_pose`).
    """
    from ges_core.kinematics import shared_kinematics

    d = hand.description
    q_open = torch.as_tensor(d.open_pose, dtype=torch.float64)[None]
    base_to_wrist = shared_kinematics(hand).link_poses(q_open, [d.wrist.link])[0, 0].numpy()
    rot = rotation_between_frames(
        np.array(d.wrist.palm_normal),
        np.array(d.wrist.finger_direction),
        np.array([0.0, 0.0, -1.0]),
        np.array([1.0, 0.0, 0.0]),
    )
    world_wrist = np.tile(np.eye(4), (len(obj_pos), 1, 1))
    world_wrist[:, :3, :3] = rot
    world_wrist[:, :3, 3] = np.asarray(obj_pos) + np.array([0.0, 0.0, height])
    return matrix_to_pose(world_wrist @ np.linalg.inv(base_to_wrist))
