"""Settings of one Stage 1 run (:class:`SynthesisConfig`), stored as the dataset's ``run_config``."""

from __future__ import annotations

import copy
from typing import Any, Literal

from pydantic import ConfigDict, Field, field_validator, model_validator

from ges_core.config import STORED_WHEN_SET, ConfigModel, dotted_leaves, fill_absent, parse_model, stored_dump
from ges_core.errors import ConfigError
from ges_core.hand_settings import check_settings, merge_settings, stage1_settings
from ges_core.objects.library import LibraryConfig
from ges_core.sim import SceneConfig
from ges_core.synthesis.contacts.generate import ContactConfig
from ges_core.synthesis.physics.pregrasp import THUMB_KEEP, PregraspConfig
from ges_core.synthesis.physics.refine import RefineConfig
from ges_core.synthesis.physics.robust import RobustConfig
from ges_core.synthesis.physics.validate import ValidateConfig
from ges_core.synthesis.retarget.retargeter import RetargetConfig

__all__ = ["OtherStrategy", "SynthesisConfig"]

OtherStrategy = Literal["never", "failed", "not_robust"]
"""When a pair tries the other grasp strategy (:attr:`SynthesisConfig.other_strategy`)."""


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
    # tries the wrist search's best placement and, when it fails refinement, validation or (robust.retry) a
    # perturbation trial, the next distinct ones (GraspRetargeter.retarget_ranked), best first; 1 is the paper's
    # single pass. 16, not 3 (December 2026): on the 20 demo objects, robust in SAPIEN Allegro 16 -> 18, Shadow
    # 11 -> 16 (8 attempts: 17, 15), and the grasps that also hold 9 held-out pose trials rose with them; an
    # object that passes early costs nothing more (docs/synthesis/refine_validate.md, "Attempts").
    attempts: int = Field(
        16,
        ge=1,
        description="wrist placements tried per object and hand until one passes refinement and validation (and "
        "every perturbation trial, with robust.retry)",
    )
    # other_strategy: the contacts' strategy comes from the cloud's PCA (side grasps of tall objects, docs/synthesis/
    # contacts.md); where none of its placements passes, the other strategy often does. Measured (2026-12-04, the
    # YCB soup can stood upright): the side grasp's 16 placements all touched the table (Allegro) or were out of
    # reach (Shadow), the grasp from above held in both engines. "not_robust" also tries it where placements passed
    # the nominal trial but none held every perturbation trial in every validating engine (docs/synthesis/
    # refine_validate.md, "The other strategy"). It costs time only for the pairs that go on.
    other_strategy: OtherStrategy = Field(
        "not_robust",
        description="when to generate contacts with the other strategy and try its placements too: 'failed' (no "
        "wrist placement of the contacts' strategy passed refinement and the nominal validation, or retargeting "
        "failed), 'not_robust' (that, or none held every perturbation trial in every validating simulator; with "
        "robust.enabled and robust.retry), 'never'; true and false mean 'failed' and 'never'",
    )

    # balanced_thumb: the contacts' thumb sits opposite the index (the paper's pinch) unless the squeeze's net normal
    # force is out of balance (contacts.thumb_balance_shifts). On flat faces that balances wherever the thumb is, so
    # on a long object the thumb can end up at one end of the finger row and the object hangs from a thumb-index axis
    # far from its centre of mass. Where no placement held every trial, this pass generates contacts whose thumb
    # also balances the squeeze's torque and tries their placements; the better pass is kept. Measured (2026-12-06,
    # every fifth random_urdf, SAPIEN): Allegro robust 155 -> 173 of 200, none lost (docs/synthesis/pipeline.md).
    # Stored in every dataset's config: a run resuming a folder written before it existed is refused (it would mix
    # records made with and without the pass).
    balanced_thumb: Literal["never", "not_robust"] = Field(
        "not_robust",
        description="when to generate contacts whose thumb balances the squeeze's torque too "
        "(contacts.thumb_balance_torque, the strategy of the contacts kept so far) and try their placements: "
        "'not_robust' (no placement so far held every perturbation trial in every validating simulator, or none "
        "passed), 'never'",
    )

    # low_raise: retargeting raises every contact below retarget.min_contact_height (25 mm) to it, so a fingertip on
    # a side wall keeps its pad off the table. On low, rounded objects lying down (a marker, a rod, the YCB hammer's
    # handle) that puts the pads on top of the object, where they push it into the table. A lower raise as the run's
    # setting won some objects and lost more (the Shadow at 15 mm on 916 library objects: robust 766 -> 739,
    # docs/synthesis/retargeting.md); as a last pass where no placement held every trial, the better pass is kept,
    # so it can only add. Stored in every dataset's config, as balanced_thumb.
    low_raise: Literal["never", "not_robust"] = Field(
        "not_robust",
        description="when to retarget the contacts kept so far again with retarget.min_contact_height lowered to "
        "retarget.low_raise_height and try their placements: 'not_robust' (no placement so far held every perturbation "
        "trial in every validating simulator, or none passed), 'never'",
    )

    @field_validator("other_strategy", mode="before")
    @classmethod
    def _other_strategy_from_bool(cls, value: Any) -> Any:
        if isinstance(value, bool):  # the key was a bool before 2026-12-04's 'not_robust'
            return "failed" if value else "never"
        return value

    # The open-pose hand of every step: refinement's start with refine.start=open_pose, the pre-grasp's with
    # pregrasp.opening=open_pose (both default to retracting each finger instead), and the hand whose table clearance
    # the wrist search checks (see THUMB_KEEP for the value).
    thumb_keep: int = Field(
        THUMB_KEEP,
        ge=0,
        description="proximal thumb joints the open-pose hand keeps at the grasp's values (refinement's start and "
        "the pre-grasp when they open to the open pose; the wrist search's clearance check)",
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
    # hand_settings: the top layer of the per-hand precedence (run config < the hand's YAML settings < this);
    # ges_core.hand_settings documents it. Stored only when set (STORED_WHEN_SET), so that runs which set none keep
    # their run_config (and its hash in every record) as before.
    hand_settings: dict[str, dict[str, Any]] = Field(
        default_factory=dict,
        description="per hand name, partial sections (contacts, retarget, refine, pregrasp, validate, robust; "
        "thumb_keep) put over the run's and the hand's YAML settings for that hand",
        json_schema_extra=STORED_WHEN_SET,
    )

    @field_validator("hand_settings")
    @classmethod
    def _checked_hand_settings(cls, value: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
        try:
            return {hand: check_settings(section, f"hand_settings.{hand}") for hand, section in value.items()}
        except ConfigError as exc:
            raise ValueError(str(exc)) from None

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
        """JSON-ready settings as stored in a dataset (the ``validate`` key spelled as in YAML; fields added later,
        ``hand_settings`` and ``contacts.layout_rank``, only when set: :func:`ges_core.config.stored_dump`)."""
        return stored_dump(self)

    def for_hand(self, hand: str, settings: dict[str, Any] | None = None) -> SynthesisConfig:
        """The settings of ``hand``'s steps: this config < the hand's YAML ``settings`` < ``hand_settings[hand]``.

        settings: the hand's own (:attr:`ges_core.hand.HandDescription.settings`). Returns ``self`` when neither
        layer sets anything; ConfigError naming the hand when the merged settings are invalid (e.g. a hand's
        ``contacts.max_width`` below the run's ``min_width``). Run-wide fields (simulators, seed, points, chunks,
        attempts, scene, library) are not per hand: the layers cannot name them.
        """
        layers = [stage1_settings(settings), stage1_settings(self.hand_settings.get(hand))]
        if not any(layers):
            return self
        data = merge_settings(self.dump(), *layers)
        where = f"settings of hand '{hand}' (run config < the hand's YAML settings < hand_settings.{hand})"
        merged = parse_model(SynthesisConfig, data, where=where)
        return merged.model_copy(update={"threads": self.threads})

    def shadowed_by(self, hand: str, settings: dict[str, Any] | None) -> list[tuple[str, Any, Any]]:
        """The values this config gives away from the defaults that ``hand``'s YAML ``settings`` replace for that
        hand (:meth:`for_hand`: run config < the hand's YAML settings < ``hand_settings[hand]``), as (dotted key,
        this config's value, the hand's value), JSON-ready. A key ``hand_settings[hand]`` sets is left out (the
        run set it for that hand), as is one where the two values agree."""
        own = dotted_leaves(stage1_settings(settings))
        if not own:
            return []
        ran, default = dotted_leaves(self.dump()), dotted_leaves(type(self)().dump())
        per_hand = dotted_leaves(stage1_settings(self.hand_settings.get(hand)))
        return [
            (key, ran[key], value)
            for key, value in own.items()
            if key in ran and key not in per_hand and ran[key] != default.get(key, _MISSING) and ran[key] != value
        ]

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
        return parse_model(cls, fill_absent(cls, data), where=f"{dataset.root} run_config")


def _v1_keep_sections(data: dict) -> list[dict]:
    """The sections of a version-1 run config that held ``thumb_keep``."""
    retarget = data.get("retarget", {})
    sections = [
        data.get("refine"),
        data.get("pregrasp"),
        retarget.get("wrist_search") if isinstance(retarget, dict) else None,
    ]
    return [s for s in sections if isinstance(s, dict)]


_MISSING = object()
