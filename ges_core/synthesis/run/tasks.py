"""What one worker gets: a task (a chunk of objects and their missing hands) and the run context.

Shared by the pipeline, which plans the tasks, and the worker, which runs them (neither imports the
other's module for these, so the import graph stays acyclic).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ges_core.errors import UnknownNameError
from ges_core.synthesis.run.config import SynthesisConfig

if TYPE_CHECKING:
    from ges_core.hand import HandModel
    from ges_core.registry import Registry

__all__ = [
    "RegistrySpec",
    "RunContext",
    "Task",
    "built_hands",
    "check_plugin_names",
    "hand_entries",
    "object_seed",
    "plan_tasks",
]


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


@dataclass(frozen=True)
class RegistrySpec:
    """How workers build the registry (the CLI's --registry / --set / --no-plugin)."""

    path: str | None = None
    overrides: tuple[str, ...] = ()
    blocked: tuple[str, ...] = ()

    def load(self) -> Registry:
        """The registry these settings describe (read in each worker process: a registry does not pickle)."""
        from ges_core.registry import load_registry

        return load_registry(self.path, overrides=self.overrides, blocked=self.blocked)


def check_plugin_names(hands: Sequence[str], config: SynthesisConfig, registry: RegistrySpec) -> None:
    """UnknownNameError ("did you mean") for a hand or simulator of the run, or a hand named in ``hand_settings``,
    that the registry does not hold.

    Called before the dataset folder is created: a manifest naming an unknown simulator would make the corrected
    run look like a change of config.
    """
    loaded = registry.load()
    for hand in hands:
        loaded.spec("hand", hand)
    for hand in config.hand_settings:  # a misspelt hand there would silently set nothing
        if hand not in loaded.names("hand"):
            raise UnknownNameError("hand", hand, loaded.names("hand"), where=" (hand_settings)")
    for field, sims in (("refine_sim", [config.refine_sim]), ("validate_sims", config.validate_sims)):
        for sim in sims:
            if sim not in loaded.names("sim"):
                raise UnknownNameError("sim", sim, loaded.names("sim"), where=f" ({field})")


def built_hands(hands: Sequence[str], registry: RegistrySpec) -> dict[str, HandModel]:
    """The run's hands, built here in the main process (for :func:`hand_entries` and the checks before a run)."""
    loaded = registry.load()
    return {hand: loaded.build_hand(hand) for hand in hands}


def hand_entries(hands: Mapping[str, HandModel]) -> dict[str, dict]:
    """Per hand, what the dataset keeps of it (:func:`ges_core.dataset.hands.hand_entry`: the hash of its description,
    settings, URDF and meshes as this run builds them, and the description field by field)."""
    from ges_core.dataset.hands import hand_entry

    return {name: hand_entry(hand) for name, hand in hands.items()}


@dataclass(frozen=True)
class RunContext:
    """Everything a worker needs besides its task (picklable)."""

    config: SynthesisConfig
    registry: RegistrySpec
    pictures: str | None
    """Folder of one PNG per record, or None."""
    source: tuple[str, str] | None
    """(dataset folder, hand) whose stored contacts are reused, or None."""
    run_id: str = ""
    """Unique per :func:`~ges_core.synthesis.run.pipeline.run_synthesis` call: a process's built library, hands and
    retargeters serve one run only, so a second run in the same process sees objects edited in between."""
