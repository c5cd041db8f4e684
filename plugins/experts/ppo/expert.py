"""A PPO checkpoint of ``ges train-expert`` as an :class:`~ges_core.policy.Expert`.

The checkpoint says what the policy was made for (``ges.made_for``, an :class:`~ges_core.policy.ExpertScope`) and
how to rebuild its actor (``ges.model``: observation groups and sizes, the rsl-rl ``MLPModel`` config; the
observation normalizer's statistics are part of the actor's weights). Built for an environment whose hand,
observation layout or action layout differ, it raises the one ConfigError of
:func:`~ges_core.policy.check_expert_fits`, naming both sides; the one difference it bridges is the form of the
wrist's rotation (:mod:`ges_core.experts.wrist_form`: a checkpoint from before ``EnvConfig.wrist_rotation`` reads a
rotation vector). A residual checkpoint (``action_mode: residual``) builds its base expert through the context's
registry and acts ``clamp(base + residual_scale x policy)``.
"""

from __future__ import annotations

from pathlib import Path

import torch
from rsl_rl.models import MLPModel
from tensordict import TensorDict

from ges_core.errors import ConfigError
from ges_core.experts.wrist_form import RecastWrist, inner_context
from ges_core.policy import Expert, ExpertContext, ExpertScope, check_expert_fits
from ges_core.training.checkpoint import read_checkpoint
from ges_core.training.residual import BASE_GROUP, residual_action

__all__ = ["PPOExpert", "build_expert"]


class PPOExpert(Expert):
    """The actor of a PPO checkpoint (deterministic: the Gaussian's mean; else a sample), clamped to [-1, 1]."""

    name = "ppo"

    def __init__(self, data: dict, *, base: Expert | None = None, deterministic: bool = True, path: str = "") -> None:
        meta = data["ges"]
        self.path, self.meta, self.deterministic = path, meta, deterministic
        self.made_for = ExpertScope.from_dict(meta["made_for"], where=f"checkpoint {path}")
        self.actor = _actor(meta["model"], data["actor_state_dict"])
        self.residual = meta["action_mode"] == "residual"
        self.scale = float(meta["residual_scale"])
        if self.residual and base is None:
            raise ConfigError(f"checkpoint {path} is a residual policy on '{meta['base_expert']}'; give its base")
        self.base = base

    def act(self, obs: torch.Tensor) -> torch.Tensor:
        """(n, K + 6) float32 actions in [-1, 1] for observations (n, obs size) of the layout it was made for."""
        obs = obs.to(torch.float32)
        groups = {"policy": obs}
        if self.residual:
            groups[BASE_GROUP] = self.base.act(obs).to(torch.float32)
        with torch.no_grad():
            out = self.actor(TensorDict(groups, batch_size=[obs.shape[0]]), stochastic_output=not self.deterministic)
        if self.residual:
            return residual_action(groups[BASE_GROUP], out, self.scale)
        return out.clamp(-1.0, 1.0)

    def reset(self, env_ids: torch.Tensor | None = None) -> None:
        """The policy is memoryless; a residual expert's base forgets ``env_ids``' episodes."""
        if self.base is not None:
            self.base.reset(env_ids)


def _actor(model: dict, state: dict) -> MLPModel:
    """The trained actor, rebuilt from the checkpoint's model description and weights, in eval mode."""
    groups, sizes = list(model["obs_groups"]), model["group_sizes"]
    dummy = TensorDict({g: torch.zeros(1, int(sizes[g])) for g in groups}, batch_size=[1])
    cfg = {k: v for k, v in model["actor"].items() if k != "class_name"}
    actor = MLPModel(dummy, {"actor": groups}, "actor", int(model["num_actions"]), **cfg)
    actor.load_state_dict(state)
    return actor.eval()


def build_expert(
    context: ExpertContext, checkpoint: str | None = None, deterministic: bool = True
) -> PPOExpert | RecastWrist:
    """The expert factory (``registry.build_expert("ppo", context, checkpoint=PATH)``).

    A checkpoint made for the other form of the wrist's rotation (one trained before ``EnvConfig.wrist_rotation``
    existed reads a rotation vector) acts through :class:`~ges_core.experts.wrist_form.RecastWrist`, its base
    expert built for that form too. ConfigError without a checkpoint, or when the checkpoint was made for another
    hand or other observation or action layouts (naming both); AssetError when the file is missing or not a GES PPO
    checkpoint."""
    if not checkpoint:
        raise ConfigError(
            "expert 'ppo' needs its checkpoint: give the setting checkpoint=PATH (e.g. --expert "
            "ppo:checkpoint=runs/tiny/experts/expert0/checkpoints/last.pt), a file written by 'ges train-expert'"
        )
    data = read_checkpoint(checkpoint)
    scope = ExpertScope.from_dict(data["ges"]["made_for"], where=f"checkpoint {checkpoint}")
    inner = inner_context(scope, context)
    check_expert_fits(scope, inner, who=f"PPO checkpoint {checkpoint}")
    base = None
    if data["ges"]["action_mode"] == "residual":
        base = _base_expert(data["ges"]["base_expert"], inner, data["ges"].get("base_expert_settings", {}))
    expert = PPOExpert(data, base=base, deterministic=bool(deterministic), path=str(Path(checkpoint)))
    return expert if inner is context else RecastWrist(expert, context, inner.obs_layout)


def _base_expert(name: str, context: ExpertContext, settings: dict) -> Expert:
    """The residual policy's base expert as it trained: ``name`` with the run's ``base_expert_settings`` (a
    checkpoint written before runs stored them trained on the registered settings: ``settings`` = {})."""
    registry = context.registry
    if registry is None:
        from ges_core.registry import load_registry

        registry = load_registry()
    return registry.build_expert(name, context, **settings)
