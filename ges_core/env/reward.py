"""The paper's reward ``r = ω_g r_g + ω_r r_r + ω_l r_l + ω_m r_m + ω_s r_s + ω_c r_c``, batched torch.

Every term is returned on its own for logging. Forms (our reading of the paper, see ``docs/env.md``):

* ``r_g = exp(-λ_g r_pf)``, ``r_pf = max_f ‖Δq_f‖₁``: the worst finger's L1 joint distance to the goal grasp.
* ``r_r = exp(-λ_r d_ho)``: ``d_ho`` mean fingertip-to-object-centre distance, m.
* ``r_l = exp(-λ_l d_ot)``: ``d_ot`` object centre to lift target distance, m.
* ``r_m = clip(Δz / h, 0, 1)``: object rise above its start as a fraction of the lift height ``h``.
* ``r_s = -Σ_i v_i²``: hand joint velocities (rad/s) and wrist linear + angular velocity.
* ``r_c = -Σ_j Var_f(sign(v_{j,f}))``: same-position joints across the non-thumb fingers.

:func:`compute_reward` is the plain torch statement of these formulas; :class:`RewardFunction` computes the
same in numpy float64 with the hand's index structure prepared once, for the environment's per-step path
(tests/test_env_fast_path.py checks that the two agree).
"""

from __future__ import annotations

import numpy as np
import torch
from pydantic import Field

from ges_core.config import ConfigModel
from ges_core.errors import ConfigError
from ges_core.hand import HandDescription

__all__ = [
    "REWARD_PRESETS",
    "RewardConfig",
    "RewardFunction",
    "compute_reward",
    "consistency_groups",
    "direction_variance_np",
    "reward_preset",
]

TERMS = ("goal", "reach", "lift", "move", "smooth", "consistency")


class RewardConfig(ConfigModel):
    """Weights and decay rates of the reward."""

    w_goal: float = Field(1.0, description="ω_g, weight of the goal-pose term r_g")
    w_reach: float = Field(1.0, description="ω_r, weight of the reach term r_r")
    w_lift: float = Field(2.0, description="ω_l, weight of the lift term r_l")
    w_move: float = Field(1.0, description="ω_m, weight of the move term r_m")
    w_smooth: float = Field(0.0, ge=0, description="ω_s, weight of the smoothness penalty r_s (<= 0 itself)")
    w_consistency: float = Field(0.0, ge=0, description="ω_c, weight of the consistency penalty r_c (<= 0 itself)")
    lambda_goal: float = Field(1.0, gt=0, description="λ_g, 1/rad, decay of r_g in the worst finger's L1 error")
    lambda_reach: float = Field(20.0, gt=0, description="λ_r, 1/m: r_r halves every 3.5 cm")
    lambda_lift: float = Field(10.0, gt=0, description="λ_l, 1/m: r_l halves every 7 cm")
    lift_height: float = Field(0.2, gt=0, description="h, metres: the paper's lift target above the start")


REWARD_PRESETS: dict[str, RewardConfig] = {
    # UniDexGrasp-style: reach, lift and move terms only, no goal-pose prior, no smoothness terms.
    "udgr": RewardConfig(w_goal=0.0, w_reach=1.0, w_lift=2.0, w_move=1.0),
    # task-success reward: r_g, r_r, r_l, r_m
    "tsr": RewardConfig(),
    # TSR + smoothness and consistency; weights scaled so the penalties stay well below the task terms
    # at typical grasping speeds (|v| ~ 1 rad/s on 16-24 joints gives r_s ~ -20).
    "tsr_scr": RewardConfig(w_smooth=0.005, w_consistency=0.05),
}
"""The paper's reward ablation (Table 3)."""


def reward_preset(name: str) -> RewardConfig:
    """One of :data:`REWARD_PRESETS` by name."""
    if name not in REWARD_PRESETS:
        raise ConfigError(f"unknown reward preset '{name}'; choose one of {', '.join(REWARD_PRESETS)}")
    return REWARD_PRESETS[name]


def consistency_groups(hand: HandDescription, thumb_slot: str = "thumb") -> torch.Tensor:
    """(J, P) joint indices: row j holds the j-th joint (proximal first) of each of the P non-thumb fingers.

    Only positions every non-thumb finger has are used (J = shortest finger's joint count).
    """
    fingers = [f for f in hand.fingers if f.slot != thumb_slot]
    if len(fingers) < 2:
        raise ConfigError(f"hand '{hand.name}': the consistency term needs >= 2 non-thumb fingers, has {len(fingers)}")
    depth = min(len(f.joints) for f in fingers)
    rows = [[int(hand.joint_index([f.joints[j]])[0]) for f in fingers] for j in range(depth)]
    return torch.tensor(rows, dtype=torch.int64)


def finger_l1(dq: torch.Tensor, finger_joints: list[torch.Tensor]) -> torch.Tensor:
    """r_pf: (n,) max over fingers of ``‖Δq_f‖₁``; dq (n, K) rad; finger_joints: index tensors per finger."""
    per_finger = torch.stack([dq[:, idx].abs().sum(dim=1) for idx in finger_joints], dim=1)
    return per_finger.max(dim=1).values


def direction_variance(v: torch.Tensor, groups: torch.Tensor) -> torch.Tensor:
    """(n,) ``Σ_j Var_f(sign(v_{j,f}))`` (population variance); v (n, K) joint velocities; groups (J, P)."""
    return torch.sign(v[:, groups]).var(dim=2, unbiased=False).sum(dim=1)


def compute_reward(
    cfg: RewardConfig,
    *,
    q_error: torch.Tensor,
    finger_joints: list[torch.Tensor],
    tip_pos: torch.Tensor,
    obj_pos: torch.Tensor,
    obj_start: torch.Tensor,
    joint_vel: torch.Tensor,
    wrist_vel: torch.Tensor,
    groups: torch.Tensor,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Total reward (n,) and every term (n,) before weighting.

    q_error: (n, K) goal minus current joint angles, rad. tip_pos: (n, F, 3) world, m. obj_pos,
    obj_start: (n, 3) object centre now and at episode start, world, m. joint_vel: (n, K) rad/s.
    wrist_vel: (n, 6) m/s and rad/s. groups: (J, P) from :func:`consistency_groups`.
    """
    target = obj_start + torch.tensor([0.0, 0.0, cfg.lift_height], dtype=obj_start.dtype)
    terms = {
        "goal": torch.exp(-cfg.lambda_goal * finger_l1(q_error, finger_joints)),
        "reach": torch.exp(-cfg.lambda_reach * (tip_pos - obj_pos[:, None]).norm(dim=-1).mean(dim=1)),
        "lift": torch.exp(-cfg.lambda_lift * (obj_pos - target).norm(dim=-1)),
        "move": ((obj_pos[:, 2] - obj_start[:, 2]) / cfg.lift_height).clamp(0.0, 1.0),
        "smooth": -(joint_vel.square().sum(dim=1) + wrist_vel.square().sum(dim=1)),
        "consistency": -direction_variance(joint_vel, groups),
    }
    weights = (cfg.w_goal, cfg.w_reach, cfg.w_lift, cfg.w_move, cfg.w_smooth, cfg.w_consistency)
    total = sum(w * terms[name] for w, name in zip(weights, TERMS, strict=True))
    return total, terms


def direction_variance_np(v: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Numpy :func:`direction_variance`: (n,) float64 from v (n, K) and groups (J, P); sign(NaN) = 0 as in torch."""
    g = v[:, groups]
    signs = (g > 0).view(np.int8) - (g < 0).view(np.int8)  # np.sign would give NaN for NaN
    p = groups.shape[1]
    deviation = signs - np.add.reduce(signs, axis=2, keepdims=True) / p
    return np.add.reduce(np.add.reduce(deviation * deviation, axis=2) / p, axis=1)


class RewardFunction:
    """:func:`compute_reward` in numpy float64 for one hand: ``fn(...) -> (total (n,), terms (6, n))``.

    finger_joints: per physical finger, its joint indices; groups: (J, P) from :func:`consistency_groups`;
    num_joints: K. ``terms`` rows follow :data:`TERMS`. Sums may add in another order than torch's (the
    results agree to ~1e-16 relative).
    """

    def __init__(self, cfg: RewardConfig, finger_joints: list, groups: torch.Tensor, num_joints: int) -> None:
        self.cfg = cfg
        self.finger_sum = np.zeros((num_joints, len(finger_joints)))
        """(K, F) 0/1: ``|Δq| @ finger_sum`` is each finger's L1 joint error."""
        for f, idx in enumerate(finger_joints):
            np.add.at(self.finger_sum[:, f], np.asarray(idx, dtype=np.int64), 1.0)
        self.groups = np.asarray(groups, dtype=np.int64)
        self.weights = np.array([cfg.w_goal, cfg.w_reach, cfg.w_lift, cfg.w_move, cfg.w_smooth, cfg.w_consistency])
        self.decay = -np.array([[cfg.lambda_goal], [cfg.lambda_reach], [cfg.lambda_lift]])
        """(3, 1) the exponents' factors of r_g, r_r, r_l."""
        self.lift = np.array([0.0, 0.0, cfg.lift_height])

    def __call__(
        self,
        q_error: np.ndarray,
        tip_pos: np.ndarray,
        obj_pos: np.ndarray,
        obj_start: np.ndarray,
        joint_vel: np.ndarray,
        wrist_vel: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Arguments as :func:`compute_reward` (numpy float64); total (n,) and terms (6, n) in TERMS order."""
        f = tip_pos.shape[1]
        terms = np.empty((len(TERMS), len(q_error)))
        # (n, F + 1) distances to the object centre: every fingertip, then the lift target
        to_obj = np.concatenate([tip_pos, (obj_start + self.lift)[:, None]], axis=1) - obj_pos[:, None]
        dist = np.sqrt(np.add.reduce(to_obj * to_obj, axis=2))
        terms[0] = np.maximum.reduce(np.abs(q_error) @ self.finger_sum, axis=1)
        terms[1] = np.add.reduce(dist[:, :f], axis=1) / f
        terms[2] = dist[:, f]
        np.exp(np.multiply(terms[:3], self.decay, out=terms[:3]), out=terms[:3])
        rise = (obj_pos[:, 2] - obj_start[:, 2]) / self.cfg.lift_height
        np.minimum(np.maximum(rise, 0.0), 1.0, out=terms[3])
        vel = np.concatenate([joint_vel, wrist_vel], axis=1)
        np.negative(np.add.reduce(vel * vel, axis=1), out=terms[4])
        np.negative(direction_variance_np(joint_vel, self.groups), out=terms[5])
        return self.weights @ terms, terms
