"""What an evaluation runs with: :class:`BaselineConfig` (stored with the results) and the expert's settings."""

from __future__ import annotations

import inspect

from pydantic import Field, field_validator

from ges_core.config import ConfigModel
from ges_core.env.baseline import ScriptedExpert
from ges_core.env.grasp_env import EnvConfig
from ges_core.env.grasp_source import SELECTIONS
from ges_core.objects.splits import SPLITS
from ges_core.sim import SceneConfig

__all__ = ["BaselineConfig", "ScriptedSettings", "scripted_defaults"]


class ScriptedSettings(ConfigModel):
    """Overrides of :class:`~ges_core.env.baseline.ScriptedExpert`'s parameters; None keeps the expert's default."""

    approach_steps: int | None = Field(None, ge=0, description="control steps moving the wrist to the grasp first")
    close_steps: int | None = Field(None, ge=1, description="control steps ramping the fingers to the goal")
    pause_steps: int | None = Field(None, ge=0, description="control steps held between closing and lifting")
    overshoot: float | None = Field(None, ge=0, description="fraction of (goal - start) pushed past the goal joints")
    lift: float | None = Field(None, gt=0, description="metres to lift (see ScriptedExpert)")
    carry_margin: float | None = Field(None, ge=0, description="m the wrist may rise past lift for a slipping object")
    carry_gain: float | None = Field(None, ge=0, le=1, description="share of the object's sideways drift corrected")
    squeeze_force: float | None = Field(None, ge=0, description="N each fingertip is driven to press with")

    def kwargs(self) -> dict:
        """The given overrides as ScriptedExpert keyword arguments."""
        return {k: v for k, v in self.model_dump().items() if v is not None}


def scripted_defaults() -> dict:
    """ScriptedExpert's current default parameters (stored with results: a changed default invalidates them)."""
    sig = inspect.signature(ScriptedExpert.__init__)
    return {k: p.default for k, p in sig.parameters.items() if p.default is not inspect.Parameter.empty}


class BaselineConfig(ConfigModel):
    """Settings of one expert evaluation (stored in the results file; a resume needs the same)."""

    hand: str = Field(..., description="registry name of the hand")
    sim: str = Field(..., description="registry name of the simulator the episodes run in")
    envs: int = Field(1, ge=1, description="envs (episodes) per object, all from the same grasp")
    selection: str = Field("validated", description=f"which records give grasps: {', '.join(SELECTIONS)}")
    splits: tuple[str, ...] = Field(SPLITS, min_length=1, description="splits to evaluate")
    seed: int = Field(0, description="torch seed given to GraspVecEnv")
    env: EnvConfig = Field(default_factory=EnvConfig)
    expert: ScriptedSettings = Field(default_factory=ScriptedSettings)
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
