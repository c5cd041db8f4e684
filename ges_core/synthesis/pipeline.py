"""The Stage 1 pipeline: objects x hands -> contacts -> retargeting -> refinement -> pre-grasp -> validation -> dataset.

>>> config = SynthesisConfig(refine_sim="sapien", validate_sims=("sapien",))
>>> report = run_synthesis(["procedural/can/000", "procedural/box/000"], ["allegro"], config, "runs/mine")
>>> report.written, report.skipped

Per object (one seed per object, derived from ``(seed, object_id)``, never from the order):
point cloud (``points`` samples) -> five contacts (shared by every hand). Per hand: the contact sets of
a whole chunk of objects are retargeted as one batch (batched solves are much cheaper per grasp;
each grasp's solution does not depend on its batch mates, see ``tests/test_synthesis_pipeline.py``),
then per object: refinement in ``refine_sim``, pre-grasp, validation in every ``validate_sims``
simulator, one :class:`~ges_core.dataset.GraspRecord`. A ``SynthesisError``, ``SimulationError`` or
``AssetError`` of one object becomes that record's failed step with its reason and the run goes on.

Objects are cut into fixed chunks of ``chunk_size`` (in the order given) whatever the number of
workers; each (object, hand) gets fresh simulators (a reused scene carries the previous object's
history, see ``run_worker``), so a record does not depend on its chunk mates, on resuming or on
``workers``. The parent process alone writes the dataset (atomic, resumable:
stored (object, hand) pairs are skipped).
"""

from __future__ import annotations

import hashlib
import multiprocessing
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from ges_core.errors import ConfigError
from ges_core.sim import SceneConfig
from ges_core.synthesis.contacts import ContactConfig
from ges_core.synthesis.pregrasp import PregraspConfig
from ges_core.synthesis.refine import RefineConfig
from ges_core.synthesis.retarget import RetargetConfig
from ges_core.synthesis.validate import ValidateConfig

__all__ = [
    "LibrarySettings",
    "RunReport",
    "SynthesisConfig",
    "Task",
    "object_seed",
    "plan_tasks",
    "run_synthesis",
]


class LibrarySettings(BaseModel):
    """Which object library the run draws from (see :class:`ges_core.objects.library.LibraryConfig`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    sources: tuple[str, ...] = Field(("procedural", "pybullet"), description="procedural, pybullet and/or user")
    seed: int = Field(0, description="seed of the procedural dimensions")
    procedural_count: int = Field(10, ge=0, description="objects per procedural category")
    user_dir: str | None = Field(None, description="folder <category>/<instance>.{obj,stl,ply,glb} of user objects")
    user_scale: float = Field(1.0, gt=0, description="factor taking the user files' units to metres")
    decompose: bool = Field(
        False, description="compute a missing convex decomposition on demand (slow, ~5-20 s per mesh, then cached)"
    )

    def build(self):
        """The :class:`ObjectLibrary` these settings describe."""
        from ges_core.objects.library import LibraryConfig, ObjectLibrary

        user_dir = Path(self.user_dir) if self.user_dir else None
        cfg = LibraryConfig(
            sources=self.sources,
            seed=self.seed,
            procedural_count=self.procedural_count,
            user_dir=user_dir,
            user_scale=self.user_scale,
            decompose=self.decompose,
        )
        return ObjectLibrary(cfg)


class SynthesisConfig(BaseModel):
    """Settings of one Stage 1 run; stored as the dataset's ``run_config``."""

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)

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
    library: LibrarySettings = Field(default_factory=LibrarySettings)
    scene: SceneConfig = Field(default_factory=SceneConfig)
    contacts: ContactConfig = Field(default_factory=ContactConfig)
    retarget: RetargetConfig = Field(default_factory=RetargetConfig)
    refine: RefineConfig = Field(default_factory=RefineConfig)
    pregrasp: PregraspConfig = Field(default_factory=PregraspConfig)
    validate_: ValidateConfig = Field(default_factory=ValidateConfig, alias="validate")

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
    def _same_opened_hand(self) -> SynthesisConfig:
        keeps = {
            "pregrasp.thumb_keep": self.pregrasp.thumb_keep,
            "refine.thumb_keep": self.refine.thumb_keep,
            "retarget.wrist_search.thumb_keep": self.retarget.wrist_search.thumb_keep,
        }
        if len(set(keeps.values())) > 1:
            raise ValueError(
                f"the opened hand must be the same in every step, but {keeps}: set all three to one value "
                "(retargeting checks the table clearance of the hand refinement and the pre-grasp open)"
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


def object_seed(seed: int, object_id: str) -> int:
    """A 31-bit seed of one object, from the run seed and the object id only (not the run order)."""
    digest = hashlib.sha256(f"{seed}:{object_id}".encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFFFFFF


@dataclass(frozen=True)
class Task:
    """One chunk of work: objects, and per object the hands still missing from the dataset."""

    index: int
    pairs: tuple[tuple[str, tuple[str, ...]], ...]
    """((object_id, (hand, ...)), ...) in the run's object order."""

    @property
    def size(self) -> int:
        """Number of (object, hand) records this task produces."""
        return sum(len(hands) for _, hands in self.pairs)


@dataclass(frozen=True)
class RegistrySpec:
    """How workers build the registry (the CLI's --registry / --set / --no-plugin)."""

    path: str | None = None
    overrides: tuple[str, ...] = ()
    blocked: tuple[str, ...] = ()

    def load(self):
        from ges_core.registry import load_registry

        return load_registry(self.path, overrides=self.overrides, blocked=self.blocked)


@dataclass
class RunReport:
    """What a run did."""

    root: Path
    written: list[tuple[str, str]] = field(default_factory=list)
    """(object_id, hand) of the records written by this run."""
    skipped: list[tuple[str, str]] = field(default_factory=list)
    """Pairs already in the dataset (resume)."""
    recovered: list[str] = field(default_factory=list)
    """What opening the dataset repaired (see DatasetWriter.recovered)."""


def plan_tasks(
    object_ids: Sequence[str], hands: Sequence[str], chunk_size: int, done: Callable[[str, str], bool]
) -> tuple[list[Task], list[tuple[str, str]]]:
    """Fixed chunks of ``object_ids`` with the pairs ``done`` says are missing; returns (tasks, skipped pairs)."""
    tasks, skipped = [], []
    for start in range(0, len(object_ids), chunk_size):
        pairs = []
        for oid in object_ids[start : start + chunk_size]:
            missing = tuple(h for h in hands if not done(oid, h))
            skipped += [(oid, h) for h in hands if h not in missing]
            if missing:
                pairs.append((oid, missing))
        if pairs:
            tasks.append(Task(start // chunk_size, tuple(pairs)))
    return tasks, skipped


def run_synthesis(
    object_ids: Sequence[str],
    hands: Sequence[str],
    config: SynthesisConfig,
    out: str | Path,
    *,
    workers: int = 1,
    progress: bool = False,
    registry: RegistrySpec | None = None,
    pictures: str | Path | None = None,
    source: tuple[str, str] | None = None,
    on_record: Callable | None = None,
) -> RunReport:
    """Synthesize and validate grasps of ``object_ids`` x ``hands``; write them to the dataset ``out``.

    workers: processes (1 = this process). pictures: folder for one PNG per record (None: none).
    source: (dataset folder, hand): that hand's stored contacts replace contact generation (cross-hand
    retargeting); every object needs a record of that hand there. on_record: called with each record as it is written.
    """
    from ges_core.dataset import DatasetWriter

    _check_run(object_ids, hands, workers)
    registry = registry or RegistrySpec()
    with DatasetWriter(out, config.dump()) as writer:
        report = RunReport(Path(out), recovered=list(writer.recovered))
        tasks, report.skipped = plan_tasks(list(object_ids), list(hands), config.chunk_size, writer.has)
        context = _Context(config, registry, str(pictures) if pictures else None, _source(source))
        bar = _progress_bar(sum(t.size for t in tasks), progress)
        try:
            for records in _results(tasks, context, workers):
                for record in records:
                    writer.add(record)
                    report.written.append(record.key)
                    if on_record is not None:
                        on_record(record)
                bar.update(len(records))
        finally:
            bar.close()
    return report


@dataclass(frozen=True)
class _Context:
    """Everything a worker needs besides its task (picklable)."""

    config: SynthesisConfig
    registry: RegistrySpec
    pictures: str | None
    source: tuple[str, str] | None
    """(dataset folder, hand) whose stored contacts are reused, or None."""


def _source(source: tuple[str, str] | None) -> tuple[str, str] | None:
    return None if source is None else (str(source[0]), str(source[1]))


def _check_run(object_ids: Sequence[str], hands: Sequence[str], workers: int) -> None:
    problems = []
    if not object_ids:
        problems.append("no objects given")
    if not hands:
        problems.append("no hands given")
    if len(set(object_ids)) != len(object_ids):
        problems.append("an object is listed twice")
    if workers < 1:
        problems.append(f"workers must be >= 1, got {workers}")
    if problems:
        raise ConfigError("cannot start the synthesis run: " + "; ".join(problems), problems=problems)


def _results(tasks: list[Task], context: _Context, workers: int) -> Iterator[list]:
    """Records of each task, in task order (so the dataset is written in the same order for any N)."""
    from ges_core.synthesis.run_worker import run_task

    if workers == 1 or len(tasks) <= 1:
        for task in tasks:
            yield run_task(task, context)
        return
    ctx = multiprocessing.get_context("spawn")  # fork would copy engine state (SAPIEN, PyBullet clients, torch threads)
    with ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=ctx) as pool:
        futures = [pool.submit(run_task, task, context) for task in tasks]
        for future in futures:
            yield future.result()


def _progress_bar(total: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, disable=not enabled, unit="grasp", desc="synthesis", dynamic_ncols=True)
