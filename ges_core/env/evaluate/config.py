"""What an evaluation runs with: :class:`BaselineConfig`, stored with the results (a resume needs the same)."""

from __future__ import annotations

from typing import Any

from pydantic import Field, field_validator

from ges_core.config import ConfigModel
from ges_core.env.grasp_env import EnvConfig
from ges_core.env.grasp_source import SELECTIONS
from ges_core.objects.splits import SPLITS
from ges_core.sim import SceneConfig

__all__ = ["BaselineConfig"]


class BaselineConfig(ConfigModel):
    """Settings of one expert evaluation (stored in the results file; a resume needs the same)."""

    hand: str = Field(..., description="registry name of the hand")
    sim: str = Field(..., description="registry name of the simulator the episodes run in")
    envs: int = Field(1, ge=1, description="envs (episodes) per object, all from the same grasp")
    selection: str = Field("validated", description=f"which records give grasps: {', '.join(SELECTIONS)}")
    splits: tuple[str, ...] = Field(SPLITS, min_length=1, description="splits to evaluate")
    seed: int = Field(0, description="torch seed given to GraspVecEnv")
    env: EnvConfig = Field(default_factory=EnvConfig)
    expert: str = Field("scripted", description="registry name of the expert (ges list)")
    expert_settings: dict[str, Any] = Field(
        default_factory=dict,
        description="the expert's settings over its registered ones (plugin defaults, then registry.yaml); "
        "ges info expert NAME lists them",
    )
    scene: SceneConfig | None = Field(
        None, description="physics settings; None: the dataset's Stage 1 scene (num_envs set to envs)"
    )

    @field_validator("selection")
    @classmethod
    def _known_selection(cls, value: str) -> str:
        if value not in SELECTIONS:
            raise ValueError(f"unknown selection '{value}'; choose one of {', '.join(SELECTIONS)}")
        return value

    @field_validator("splits")
    @classmethod
    def _known_splits(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [s for s in value if s not in SPLITS]
        if unknown:
            raise ValueError(f"unknown splits {unknown}; choose from {', '.join(SPLITS)}")
        return value
