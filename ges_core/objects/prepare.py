"""``prepare``: validate objects and cache the convex decomposition of every concave one.

Runs in a process pool (``workers``), with a tqdm progress bar; each object is independent, so a
killed run resumes where it stopped (finished decompositions are cache hits) and an object that
fails is reported while the others go on.
"""

from __future__ import annotations

import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from functools import cache
from multiprocessing import get_context
from typing import Literal

import numpy as np

from ges_core.errors import GesError
from ges_core.objects.bounds import DEFAULT_MAX_FACES
from ges_core.objects.decompose import CoacdSettings, cached_parts, settings_for
from ges_core.objects.processing import collision_shapes, process_entry
from ges_core.objects.sources import ObjectEntry

__all__ = ["PrepareResult", "prepare", "prepare_before_run", "prepare_one"]

Status = Literal["decomposed", "cached", "not_needed", "failed"]


@dataclass(frozen=True)
class PrepareResult:
    """What ``prepare`` did for one object."""

    object_id: str
    status: Status
    """``decomposed`` now, ``cached`` already, ``not_needed`` (primitive or convex), or ``failed``."""
    seconds: float
    detail: str = ""
    """Number of parts, or the one-line error."""


def prepare_one(
    entry: ObjectEntry,
    settings: CoacdSettings,
    normalize_size: float | None = None,
    max_faces: int = DEFAULT_MAX_FACES,
) -> PrepareResult:
    """Process one entry and decompose it if concave and not cached; never raises a GesError."""
    start = time.perf_counter()
    try:
        obj = process_entry(entry, normalize_size=normalize_size, max_faces=max_faces)
        was_cached = obj.kind == "concave" and cached_parts(obj.mesh_hash, settings_for(obj.mesh, settings)) is not None
        shapes = collision_shapes(obj, settings, compute=True)
    except GesError as exc:
        return PrepareResult(entry.object_id, "failed", time.perf_counter() - start, str(exc))
    status: Status = "not_needed" if obj.kind != "concave" else "cached" if was_cached else "decomposed"
    return PrepareResult(entry.object_id, status, time.perf_counter() - start, f"{len(shapes)} parts ({obj.kind})")


def prepare(
    entries: list[ObjectEntry],
    settings: CoacdSettings,
    *,
    workers: int = 1,
    normalize_size: float | None = None,
    max_faces: int = DEFAULT_MAX_FACES,
    progress: bool = True,
    desc: str = "prepare",
) -> list[PrepareResult]:
    """:func:`prepare_one` for every entry, ``workers`` at a time; results in the entries' order.

    Each object's decomposition is cached as soon as it is done, so a run stopped midway keeps every finished
    object (rerunning finds them cached)."""
    from tqdm import tqdm

    bar = tqdm(total=len(entries), desc=desc, unit="obj", disable=not progress)
    results: dict[str, PrepareResult] = {}
    try:
        for result in _run(entries, settings, workers, (normalize_size, max_faces)):
            results[result.object_id] = result
            bar.update()
            if result.status == "failed":
                bar.write(f"failed: {result.detail}")
    finally:
        bar.close()
    return [results[e.object_id] for e in entries]


def prepare_before_run(library, object_ids, *, workers: int = 1, progress: bool = True) -> list[PrepareResult]:
    """Before a Stage 1 run: process every file mesh of ``object_ids`` and decompose each concave one that has
    no cached decomposition yet, ``workers`` at a time with a progress bar (``prepare objects``), so that the
    run never stalls or fails on a missing decomposition. Procedural shapes other than the concave categories
    need nothing and are skipped. Processing is cached on disk (:mod:`.processed_cache`): the run reuses it,
    and a second run finds everything ready at once. Failures are reported by the bar and returned; the run
    records them as failed objects."""
    entries = [library.entry(oid) for oid in object_ids]
    todo = [e for e in entries if e.source != "procedural" or _concave_category(e.category)]
    if not todo:
        return []
    cfg = library.config
    return prepare(
        todo, cfg.coacd, workers=workers, normalize_size=cfg.normalize_size, max_faces=cfg.max_faces,
        progress=progress, desc="prepare objects",
    )  # fmt: skip


@cache
def _concave_category(category: str) -> bool:
    """Whether a procedural category's shapes need CoACD (the kind is the category's, whatever the seed)."""
    from ges_core.objects.procedural import build_shape

    return build_shape(category, np.random.default_rng(0)).kind == "concave"


def _run(entries, settings, workers, processing):
    """Results as each object finishes (``processing``: normalize_size, max_faces)."""
    if workers <= 1 or len(entries) <= 1:
        for entry in entries:
            yield prepare_one(entry, settings, *processing)
        return
    # spawn, not fork: the parent may hold threads (tqdm, torch) that a fork would copy half-locked
    with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
        futures = [pool.submit(prepare_one, e, settings, *processing) for e in entries]
        try:
            for future in as_completed(futures):
                yield future.result()
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise
