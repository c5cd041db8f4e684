"""Settings of ``ges train-expert``: one PPO expert, its env, its curriculum; presets tiny, small, paper.

A preset is a YAML file beside this module (``presets/<name>.yaml``, the one source of its values); a run's
config is the preset, then ``--config`` YAML, then ``-o key=value`` overrides (:func:`load_train_config`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import Field, model_validator

from ges_core.config import ConfigModel, parse_overridden, read_yaml
from ges_core.env.grasp_env import EnvConfig
from ges_core.errors import ConfigError
from ges_core.sim import SceneConfig

__all__ = [
    "PRESETS",
    "CurriculumConfig",
    "EvaluationConfig",
    "PPOSettings",
    "TrainConfig",
    "WarmStartConfig",
    "load_train_config",
    "preset_path",
]

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
    clipped_value_loss: bool = Field(
        True,
        description="rsl-rl's clipped value loss: each update moves a value at most clip_param from the rollout's. "
        "False for the grasp rewards: returns are ~250 (about 2.5 per step over a 0.99 horizon, scripted rollouts "
        "measured 2026-12-02), so a critic starting at 0 would need > 1,000 iterations to reach them",
    )
    critic_fit_epochs: int = Field(
        0,
        ge=0,
        description="passes of a separate critic regression on each rollout's returns (its own Adam at "
        "critic_learning_rate, unclipped MSE) before the PPO update; 0: off. rsl-rl's PPO moves actor and critic "
        "with one optimizer at the adaptive rate, which a small action std keeps at its 1e-5 floor: in the "
        "residual runs of 2026-12-02 the value loss grew from ~80 to ~1,160 over 1,500 iterations",
    )
    critic_warmup_iterations: int = Field(
        0,
        ge=0,
        description="first iterations that fit only the critic (the actor frozen) when no warm start runs (the "
        "warm start has its own, warm_start.critic_iterations): residual mode starts at its base expert, and the "
        "first actor updates would otherwise follow the advantages of a critic that outputs ~0 for returns ~400",
    )
    critic_learning_rate: float = Field(
        1e-3, gt=0, description="Adam step size of critic_fit_epochs and critic_warmup_iterations"
    )
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
    promote_on: Literal["training", "evaluation"] = Field(
        "training",
        description="what the rule reads: training, the success of the episodes PPO collects (with its action "
        "noise) over the last `window` of them; evaluation, the success of the stage's objects in the latest "
        "in-run evaluation (the noise-free policy, needs evaluation.interval > 0; `window` unused)",
    )
    max_iterations: int = Field(
        200, ge=1, description="iteration cap per stage: promote after this many even below the threshold"
    )


class EvaluationConfig(ConfigModel):
    """Evaluation during training (``ges_core.training.evaluation``): every ``interval`` iterations the policy as a
    checkpoint, acting without noise as ``ges eval-experts`` runs it, on every object of the run's curriculum."""

    interval: int = Field(
        0,
        ge=0,
        description="iterations between evaluations (0: none). The training episodes show the policy with its "
        "action noise: the residual experts' training success stayed flat at 79-86 % while the noise-free policy "
        "gained (stop 43)",
    )
    episodes: int = Field(4, ge=1, description="episodes per object (envs of one fresh simulator per object)")
    seed: int = Field(
        100,
        ge=0,
        description="seed of the evaluation episodes (the env's torch seed and the randomization's), the same at "
        "every evaluation so they compare on the same draws; away from ges eval-experts' seeds 0-7, so the best "
        "checkpoint is not chosen on the draws it is later reported on",
    )
    keep_best: bool = Field(
        True, description="copy the checkpoint with the highest success so far to checkpoints/best.pt"
    )


class WarmStartConfig(ConfigModel):
    """Behaviour-cloning warm start of an absolute-mode actor (``ges_core.training.warm_start``, docs/training.md).

    What it fixes: from the Init prior, PPO in the paper's absolute action mode starts with joint targets at
    mid-range (a zero mean opens the hand) and action noise 0.5; success needs ~190 precise control steps of 200
    (the scripted expert succeeds at step 189), and noise of 0.05 on the scripted expert's own actions already took
    it from 16/16 to 0/16 (0.02: 15/16). The cold start lifted nothing in 2,820 episodes. Here the actor first
    imitates the base expert's actions in the same absolute action space, then the critic learns its values with
    the actor frozen, then PPO fine-tunes from a small action noise. The output stays the absolute action.
    """

    enabled: bool = Field(False, description="absolute mode only (residual mode already starts at its base expert)")
    expert: str = Field("scripted", description="registry expert whose actions are imitated")
    expert_settings: dict = Field(
        default_factory=dict,
        description="settings of the demonstrating expert (over its registered ones), e.g. the scripted expert's "
        "pause_steps=0: its 5-step pause before the carry is timed by a clock the observation does not hold, so "
        "the cloned actor averaged pause (wrist z 0) and carry (z 1) and carried at a fifth of the speed",
    )
    samples: int = Field(
        8192, ge=1, description="demonstration samples (env steps x envs, rounded up to whole control steps)"
    )
    demo_noise: float = Field(
        0.02,
        ge=0,
        description="Gaussian noise (normalized action units) added to the executed demonstration actions, the "
        "labels stay clean (DART): the actor sees states slightly off the expert's path and how it corrects them; "
        "0.02 keeps the scripted expert at 15/16 successes (0.05: 0/16, measured 2026-12-02)",
    )
    all_objects: bool = Field(
        True,
        description="demonstrations on every object of the curriculum (all stages), not only stage 1's; the pool's "
        "weights are restored afterwards (episodes running then finish on their object)",
    )
    epochs: int = Field(60, ge=1, description="passes of the MSE regression over the demonstrations")
    batch_size: int = Field(256, ge=1, description="samples per gradient step of the regression")
    learning_rate: float = Field(1e-3, gt=0, description="Adam step size of the regression")
    critic_iterations: int = Field(
        8,
        ge=0,
        description="first PPO iterations that fit only the critic (value regression on the returns, actor frozen): "
        "without it the first actor updates follow the advantages of a critic that outputs ~0 for returns of ~250",
    )
    critic_learning_rate: float = Field(1e-3, gt=0, description="Adam step size of the critic warm-up")
    init_std: float = Field(
        0.02,
        gt=0,
        description="action std after the warm start (replaces ppo.init_noise_std): 0.5 would erase the imitated "
        "behaviour (noise 0.05 on the scripted expert: 0/16 held)",
    )
    anchor_steps: int = Field(
        0,
        ge=0,
        description="after every PPO update, this many mini-batch steps of the imitation loss on the demonstrations "
        "(a DAPG-style anchor). Without it PPO undid the cloning: the adaptive rate sat at its 1e-5 floor (KL of a "
        "0.02-std policy), success fell from 0.58 (stage 1) to ~0.1 within 30 iterations, mean return 355 -> -253",
    )
    anchor_learning_rate: float = Field(1e-4, gt=0, description="Adam step size of the anchor steps")
    freeze_actor_normalizer: bool = Field(
        True,
        description="keep the actor's observation normalizer at its fit on the demonstrations (the critic's goes on "
        "updating): a drifting normalizer would shift every input of the cloned actor",
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
    workers: int = Field(
        1,
        ge=1,
        description="env worker processes the envs are split across (ges_core.env.workers, docs/training.md "
        "'Env workers'); 1: the envs step in the training process itself. Same trajectories for any count",
    )
    iterations: int = Field(100, ge=1, description="PPO iterations (each num_envs x ppo.num_steps_per_env steps)")
    seed: int = Field(0, ge=0, description="seeds torch, the pool draws and the randomization")
    action_mode: Literal["absolute", "residual"] = Field(
        "absolute",
        description="absolute: the paper's action (joint targets + wrist motion); residual: base expert's action "
        "+ residual_scale x the policy's",
    )
    residual_scale: float = Field(0.1, gt=0, le=2, description="residual mode: scale of the policy's output")
    base_expert: str = Field("scripted", description="residual mode: the registry expert the residual is added to")
    base_expert_settings: dict[str, Any] = Field(
        default_factory=dict,
        description="residual mode: the base expert's settings over its registered ones, e.g. {palm_shift: 0.01}",
    )
    """Stored in the checkpoint: the PPO expert rebuilds its base with them (a checkpoint without them: none)."""
    reward_preset: Literal["udgr", "tsr", "tsr_scr", "custom"] = Field(
        "tsr_scr", description="reward weights (env/reward.py REWARD_PRESETS); custom: env.reward as given"
    )
    env: EnvConfig = Field(default_factory=EnvConfig, description="the environment (randomization included)")
    scene: SceneConfig | None = Field(
        None,
        description="physics of the training envs and of the in-run evaluation; None: the dataset's Stage 1 scene, "
        "as ges eval-experts uses (num_envs is set per process)",
    )
    ppo: PPOSettings = Field(default_factory=PPOSettings)
    curriculum: CurriculumConfig = Field(default_factory=CurriculumConfig)
    warm_start: WarmStartConfig = Field(default_factory=WarmStartConfig)
    evaluation: EvaluationConfig = Field(default_factory=EvaluationConfig)
    checkpoint_interval: int = Field(10, ge=1, description="iterations between checkpoints (and one at the end)")
    keep_checkpoints: int = Field(3, ge=1, description="numbered checkpoints kept besides last.pt")
    time_limit: float | None = Field(None, gt=0, description="seconds: stop (with a checkpoint) after this long")

    @model_validator(mode="after")
    def _evaluation_for_promotion(self) -> TrainConfig:
        if self.curriculum.promote_on == "evaluation" and not self.evaluation.interval:
            raise ValueError(
                "curriculum.promote_on=evaluation reads the in-run evaluation, which is off: set evaluation.interval "
                "(e.g. -o evaluation.interval=100) or promote_on=training"
            )
        return self


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
    return parse_overridden(TrainConfig, data, overrides, where=str(path or f"preset {preset}"))


def _merge(base: dict, top: dict) -> dict:
    """``top`` over ``base``, nested mappings merged key by key."""
    out = dict(base)
    for key, value in top.items():
        out[key] = _merge(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out
