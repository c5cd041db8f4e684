"""Stage 2 expert training: PPO (rsl-rl's OnPolicyRunner) on multi-object grasp environments with the paper's
three-stage curriculum; ``ges train-expert``. See ``docs/training.md``.

>>> from ges_core.training import load_train_config, train_expert
>>> summary = train_expert("runs/tiny/dataset", load_train_config("tiny"), "runs/tiny/experts/expert0",
...                        registry=load_registry(), clusters=load_clusters("runs/tiny/dataset"))
"""

from __future__ import annotations

from ges_core.training.config import PRESETS, CurriculumConfig, PPOSettings, TrainConfig, load_train_config

__all__ = ["PRESETS", "CurriculumConfig", "PPOSettings", "TrainConfig", "load_train_config", "train_expert"]


def __getattr__(name: str):
    if name == "train_expert":  # lazily: it pulls in rsl-rl and the simulators' registry
        from ges_core.training.run import train_expert

        return train_expert
    raise AttributeError(f"module 'ges_core.training' has no attribute '{name}'")
