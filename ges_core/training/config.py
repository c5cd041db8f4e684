"""Settings of ``ges train-expert``: one PPO expert, its env, its curriculum; presets tiny, small, paper.

A preset is a YAML file beside this module (``presets/<name>.yaml``, the one source of its values); a run's
config is the preset, then ``--config`` YAML, then ``-o key=value`` overrides (:func:`load_train_config`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field

from ges_core.config import ConfigModel, apply_overrides, parse_model, read_yaml
from ges_core.env.grasp_env import EnvConfig
from ges_core.errors import ConfigError

__all__ = ["PRESETS", "CurriculumConfig", "PPOSettings", "TrainConfig", "load_train_config", "preset_path"]

PRESET_DIR = Path(__file__).resolve().parent / "presets"
PRESETS = ("tiny", "small", "paper")
"""Shipped presets (``docs/training.md``): tiny runs here in about 30 min per expert; paper is for a GPU machine."""


class PPOSettings(ConfigModel):
    """PPO (rsl-rl-lib 5.5.1's ``PPO``) and the actor/critic networks."""

    num_steps_per_env: int = Field(32, ge=1, description="control steps each env collects per iteration")
    learning_rate: float = Field(3e-4, gt=0, description="Adam step size (the start value of the adaptive schedule)")
    schedule: Literal["adaptive", "fixed"] = Field(
        "adaptive", description="adaptive: rsl-rl scales the rate to keep the KL near desired_kl"
    )
    desired_kl: float = Field(0.01, gt=0, description="target KL per update of the adaptive schedule")
    num_learning_epochs: int = Field(5, ge=1, description="passes over each iteration's samples")
    num_mini_batches: int = Field(4, ge=1, description="mini-batches per pass")
    clip_param: float = Field(0.2, gt=0, description="PPO ratio clip")
    gamma: float = Field(0.99, gt=0, le=1, description="discount per control step")
    lam: float = Field(0.95, ge=0, le=1, description="GAE lambda")
    entropy_coef: float = Field(0.0, ge=0, description="entropy bonus weight")
    value_loss_coef: float = Field(1.0, ge=0, description="value loss weight")
    max_grad_norm: float = Field(1.0, gt=0, description="gradient norm clip")
    actor_hidden: list[int] = Field(default_factory=lambda: [256, 128, 64], description="actor MLP widths")
    critic_hidden: list[int] = Field(default_factory=lambda: [256, 128, 64], description="critic MLP widths")
    activation: str = Field("elu", description="activation of both MLPs (rsl-rl names)")
    init_noise_std: float = Field(
        0.5, gt=0, description="initial action std (absolute mode; normalized action units, range [-1, 1])"
    )
    obs_normalization: bool = Field(True, description="running mean/std normalization of the observation")
    normalizer_warmup: int = Field(
        8,
        ge=0,
        description="control steps (x num_envs samples) that prime the normalizer before the first update: "
        "unprimed, the first update sees raw joint velocities ~400 rad/s and tip forces ~270 N and the adaptive "
        "rate fell to its 1e-5 floor (docs/platform-notes, measured 2026-12-01)",
    )


class CurriculumConfig(ConfigModel):
    """The paper's three-stage curriculum (``ges_core.training.curriculum``)."""

    enabled: bool = Field(True, description="False: every training object from the first iteration (no stages)")
    stages: list[Literal[1, 2, 3]] = Field(
        default_factory=lambda: [1, 2, 3],
        description="1: the cluster's objects nearest its centre; 2: the whole cluster; 3: every training object. "
        "The hard-case expert runs [1, 2]",
    )
    centre_fraction: float = Field(0.3, gt=0, le=1, description="share of the cluster in stage 1 (at least one)")
    window: int = Field(64, ge=1, description="episodes (of the current stage) the success rate is taken over")
    promote_success: float = Field(
        0.5, ge=0, le=1, description="promote when the success rate over the window reaches this"
    )
    protocol: Literal["paper", "peers"] = Field("paper", description="which success protocol the rule counts")
    max_iterations: int = Field(
        200, ge=1, description="iteration cap per stage: promote after this many even below the threshold"
    )


class TrainConfig(ConfigModel):
    """Everything a ``ges train-expert`` run needs besides the dataset path."""

    preset: str = Field("custom", description="the preset this config started from (for the records)")
    hand: str | None = Field(None, description="hand plugin (None: registry.yaml defaults.hand)")
    sim: str | None = Field(None, description="simulator plugin (None: registry.yaml defaults.sim)")
    selection: Literal["validated", "refined", "any"] = Field("validated", description="which records give grasps")
    max_objects: int | None = Field(
        None, ge=1, description="use at most this many training objects (the first by id); None: all"
    )
    cluster: int = Field(0, ge=0, description="the cluster this expert is for (ges cluster's numbering)")
    objects: list[str] | None = Field(
        None, description="train on these object ids instead of the cluster (the hard-case expert); stage 3 unused"
    )
    num_envs: int = Field(16, ge=1, description="parallel envs")
    iterations: int = Field(100, ge=1, description="PPO iterations (each num_envs x ppo.num_steps_per_env steps)")
    seed: int = Field(0, ge=0, description="seeds torch, the pool draws and the randomization")
    action_mode: Literal["absolute", "residual"] = Field(
        "absolute",
        description="absolute: the paper's action (joint targets + wrist motion); residual: base expert's action "
        "+ residual_scale x the policy's",
    )
    residual_scale: float = Field(0.1, gt=0, le=2, description="residual mode: scale of the policy's output")
    base_expert: str = Field("scripted", description="residual mode: the registry expert the residual is added to")
    reward_preset: Literal["udgr", "tsr", "tsr_scr", "custom"] = Field(
        "tsr_scr", description="reward weights (env/reward.py REWARD_PRESETS); custom: env.reward as given"
    )
    env: EnvConfig = Field(default_factory=EnvConfig, description="the environment (randomization included)")
    ppo: PPOSettings = Field(default_factory=PPOSettings)
    curriculum: CurriculumConfig = Field(default_factory=CurriculumConfig)
    checkpoint_interval: int = Field(10, ge=1, description="iterations between checkpoints (and one at the end)")
    keep_checkpoints: int = Field(3, ge=1, description="numbered checkpoints kept besides last.pt")
    time_limit: float | None = Field(None, gt=0, description="seconds: stop (with a checkpoint) after this long")


def preset_path(name: str) -> Path:
    """The YAML of preset ``name``; ConfigError naming the presets if there is none."""
    path = PRESET_DIR / f"{name}.yaml"
    if not path.is_file():
        raise ConfigError(f"unknown training preset '{name}'; choose one of {', '.join(PRESETS)}")
    return path


def load_train_config(preset: str | None = "tiny", path: str | Path | None = None, overrides=()) -> TrainConfig:
    """The preset (None: the model's defaults), a YAML at ``path`` over it, then ``key=value`` overrides."""
    data = read_yaml(preset_path(preset)) if preset else {}
    if preset:
        data["preset"] = preset
    if path is not None:
        data = _merge(data, read_yaml(path))
    data = apply_overrides(data, overrides)
    return parse_model(TrainConfig, data, where=str(path or f"preset {preset}"))


def _merge(base: dict, top: dict) -> dict:
    """``top`` over ``base``, nested mappings merged key by key."""
    out = dict(base)
    for key, value in top.items():
        out[key] = _merge(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out
