"""Settings of one Stage 1 run (:class:`SynthesisConfig`), stored as the dataset's ``run_config``."""

from __future__ import annotations

import copy

from pydantic import ConfigDict, Field, field_validator, model_validator

from ges_core.config import ConfigModel, parse_model
from ges_core.objects.library import LibraryConfig
from ges_core.sim import SceneConfig
from ges_core.synthesis.contacts.generate import ContactConfig
from ges_core.synthesis.physics.pregrasp import THUMB_KEEP, PregraspConfig
from ges_core.synthesis.physics.refine import RefineConfig
from ges_core.synthesis.physics.robust import RobustConfig
from ges_core.synthesis.physics.validate import ValidateConfig
from ges_core.synthesis.retarget.retargeter import RetargetConfig

__all__ = ["SynthesisConfig"]


class SynthesisConfig(ConfigModel):
    """Settings of one Stage 1 run; stored as the dataset's ``run_config``."""

    model_config = ConfigDict(populate_by_name=True)  # merged with ConfigModel's

    points: int = Field(1024, ge=16, description="surface samples per object point cloud")
    seed: int = Field(0, description="run seed; each object's seed is derived from (seed, object_id)")
    refine_sim: str = Field("sapien", description="simulator of collision-aware refinement")
    validate_sims: tuple[str, ...] = Field(
        ("sapien",), description="simulators that validate each grasp; the record's verdict is refine_sim's if listed"
    )
    # 8: a batch of 8 grasps costs about as much as one in the batched solver (it is dominated by
    # per-call overhead at small sizes) while the chunk's simulators are still reused for 8 objects.
    chunk_size: int = Field(8, ge=1, description="objects per retargeting batch and per worker task")
    # attempts: the paper refines its one retargeted pose (and validates nothing). Here each (object, hand)
    # tries the wrist search's best placement and, when it fails refinement or validation, the next distinct
    # ones (GraspRetargeter.retarget_ranked), best first; 1 is the paper's single pass. Measured on the 20
    # demo objects (docs/synthesis/refine_validate.md, "Attempts").
    attempts: int = Field(
        3, ge=1, description="wrist placements tried per object and hand until one passes refinement and validation"
    )
    # One opened hand for every step: retargeting checks the table clearance of the hand that refinement
    # starts from and that the pre-grasp opens (see THUMB_KEEP for the value).
    thumb_keep: int = Field(
        THUMB_KEEP,
        ge=0,
        description="proximal thumb joints the opened hand keeps at the grasp's values (refinement's start, "
        "the pre-grasp, the wrist search's clearance check)",
    )
    # threads: how the run executes, not what it computes (records are bit-identical across counts), so it is
    # left out of dump() and of the dataset's run_config hash; ges_core.threads says why one is the default.
    threads: int | None = Field(
        None,
        ge=1,
        exclude=True,
        description="torch threads per process (the parent and each worker); None: $GES_THREADS, else 1",
    )
    library: LibraryConfig = Field(default_factory=LibraryConfig)
    scene: SceneConfig = Field(default_factory=SceneConfig)
    contacts: ContactConfig = Field(default_factory=ContactConfig)
    retarget: RetargetConfig = Field(default_factory=RetargetConfig)
    refine: RefineConfig = Field(default_factory=RefineConfig)
    pregrasp: PregraspConfig = Field(default_factory=PregraspConfig)
    validate_: ValidateConfig = Field(default_factory=ValidateConfig, alias="validate")
    robust: RobustConfig = Field(
        default_factory=RobustConfig,
        description="perturbation trials of every grasp whose nominal validation passed, in every validating simulator",
    )

    @field_validator("validate_sims")
    @classmethod
    def _unique(cls, sims: tuple[str, ...]) -> tuple[str, ...]:
        if len(set(sims)) != len(sims):
            raise ValueError(f"validate_sims lists a simulator twice: {list(sims)}")
        return sims

    @model_validator(mode="after")
    def _one_env(self) -> SynthesisConfig:
        if self.scene.num_envs != 1:
            raise ValueError("scene.num_envs must be 1: refinement and validation run one grasp per scene")
        return self

    @model_validator(mode="after")
    def _reachable_friction_floor(self) -> SynthesisConfig:
        floor, hand = self.robust.friction_floor, self.scene.hand_friction
        if self.robust.enabled and floor is not None and floor < hand / 2:
            raise ValueError(
                f"robust.friction_floor={floor} cannot be reached with scene.hand_friction={hand}: both engines "
                f"average the hand's and the object's coefficients, so the lowest is {hand / 2:g}; raise the floor "
                "or lower scene.hand_friction"
            )
        return self

    @property
    def primary_sim(self) -> str | None:
        """The simulator whose validation verdict goes into the record's validation step."""
        if not self.validate_sims:
            return None
        return self.refine_sim if self.refine_sim in self.validate_sims else self.validate_sims[0]

    def dump(self) -> dict:
        """JSON-ready settings (the ``validate`` key spelled as in YAML)."""
        return self.model_dump(mode="json", by_alias=True)

    @classmethod
    def of_dataset(cls, dataset) -> SynthesisConfig:
        """The settings a dataset was written with (its manifest's ``run_config``); ConfigError if invalid.

        A version-1 dataset stored the opened hand three times (``refine.thumb_keep``, ``pregrasp.thumb_keep``,
        ``retarget.wrist_search.thumb_keep``, kept equal); they are read as the one ``thumb_keep``.
        """
        data = copy.deepcopy(dataset.run_config)
        if dataset.manifest.get("version") == 1:
            keeps = [section.pop("thumb_keep") for section in _v1_keep_sections(data) if "thumb_keep" in section]
            if keeps:
                data["thumb_keep"] = keeps[0]
        return parse_model(cls, data, where=f"{dataset.root} run_config")


def _v1_keep_sections(data: dict) -> list[dict]:
    """The sections of a version-1 run config that held ``thumb_keep``."""
    retarget = data.get("retarget", {})
    sections = [
        data.get("refine"),
        data.get("pregrasp"),
        retarget.get("wrist_search") if isinstance(retarget, dict) else None,
    ]
    return [s for s in sections if isinstance(s, dict)]
