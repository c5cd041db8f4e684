"""Write a grasp dataset incrementally and resumably; read it back.

>>> writer = DatasetWriter("runs/demo", run_config={"hands": ["shadow"], "sim": "sapien"})
>>> for obj in objects:
...     if not writer.has(obj.object_id, "shadow"):      # resume: skip what is stored
...         writer.add(synthesize(obj))                  # one atomic file (and its times), then the manifest
>>> for record in open_dataset("runs/demo"):
...     print(record.object_id, record.hand, record.success)

Each record is one file written atomically, its times another beside it (:mod:`.timing`); the manifest is
rewritten atomically after them (at most every ``manifest_interval`` seconds, and on close). A run killed at
any moment therefore leaves whole records only. Records are the truth and the manifest's index a cache of
them: opening a folder reads every record and rebuilds the index from them (:mod:`.reconcile`); the writer
also repairs the folder and rewrites the manifest, the reader keeps the repair in memory. One writer per
folder at a time: the writer holds the folder's lock (:mod:`.lock`) until it is closed.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

from ges_core.config import dotted_leaves
from ges_core.dataset.checks import record_problems
from ges_core.dataset.hands import check_hands
from ges_core.dataset.layout import (
    DAMAGED_DIR,
    DATASET_FORMAT,
    DATASET_VERSION,
    MANIFEST,
    RECORDS_DIR,
    config_differences,
    config_hash,
    index_entry,
    known_config_hashes,
    move_aside,
    normalize_config,
    read_manifest,
    record_relpath,
    try_read_manifest,
    utc_now,
    write_manifest,
)
from ges_core.dataset.lock import LOCK_FILE, FolderLock
from ges_core.dataset.reconcile import FolderIndex, index_folder, read_record_file
from ges_core.dataset.record import GraspRecord, raw_to_bytes, record_to_raw, software_versions
from ges_core.dataset.timing import sha256_hex, timing_relpath, timing_text
from ges_core.errors import AssetError, ConfigError, StorageError
from ges_core.paths import atomic_write_bytes, atomic_write_text, make_dirs, storage_error

__all__ = ["MANIFEST_INTERVAL_S", "Dataset", "DatasetWriter", "load_record", "open_dataset"]

_LOG = logging.getLogger(__name__)
MANIFEST_INTERVAL_S = 2.0
"""Default seconds between manifest rewrites: with Stage 1 at about 1 s per record this rewrites the
index every other record or so, and a kill costs at most the adoption of the few newest files."""


def load_record(root: Path, file: str) -> GraspRecord:
    """Read the record stored at ``root / file`` with its times; AssetError naming the file if it is damaged."""
    path = root / file
    try:
        return read_record_file(root, file)
    except (AssetError, OSError) as exc:
        why = str(exc).removeprefix(f"{file}: ")
        raise AssetError(
            f"cannot read grasp record {path}: {why}. Run 'ges dataset validate {root}'; resuming the run that "
            "wrote it moves it aside and makes it again"
        ) from exc


class DatasetWriter:
    """Adds records to a dataset folder, creating it or resuming it; holds the folder's lock until closed.

    path: the dataset folder (created if missing; must be empty or a dataset). Another process writing it
        raises LockError naming that process.
    run_config: the run's settings (dict, pydantic model or dataclass; stored as JSON, and its hash in every
        record). Resuming a folder written with other settings raises ConfigError unless ``allow_config_change``;
        so does resuming one whose records were made with settings its manifest does not name (a deleted or
        replaced manifest).
    manifest_interval: seconds between manifest rewrites (0: after every record). Records added in
        between are safe on disk and adopted on the next open; :meth:`close` (or leaving a ``with``
        block) writes the manifest. Rewriting an index of N records after each of N records would
        cost O(N^2) bytes, which a large run notices.
    hands: per hand name, ``{"hash", "description"}`` of the hand as this run builds it
        (:func:`ges_core.dataset.hands.hand_entry`), kept in the manifest's ``hands``. Resuming a folder that holds
        records of a hand whose stored hash differs raises ConfigError naming the changed fields, unless
        ``allow_config_change`` (the old entry then goes to ``hands_history``). A folder written before hands were
        recorded (no ``hands`` in its manifest) opens as before: its records' hands cannot be checked (a note says
        so) and this run's hands are recorded from then on. None: the stored ``hands`` are kept, unchecked.
    """

    def __init__(
        self,
        path: str | Path,
        run_config: object,
        *,
        allow_config_change: bool = False,
        manifest_interval: float = MANIFEST_INTERVAL_S,
        hands: dict[str, dict] | None = None,
        absent_means: dict[str, object] | None = None,
    ) -> None:
        self.root = Path(path)
        self.run_config = normalize_config(run_config)
        self.absent_means = dict(absent_means or {})
        """Dotted run-config keys added after folders were written whose absence means a value (what the code did
        before them; :func:`ges_core.config.absent_paths`): a refused resume says so and how to reproduce it."""
        self.hands = None if hands is None else normalize_config(hands)
        self.config_hash = config_hash(self.run_config)
        """What :meth:`add` stamps on records that carry no run-config hash."""
        self.manifest_interval = manifest_interval
        self.recovered: list[str] = []
        """What opening repaired: a lock left behind, leftover files, adopted, damaged or moved records, manifest
        entries that disagreed with their records, a rebuilt manifest; each is also logged as a warning."""
        self._lock = FolderLock.acquire(make_dirs(self.root))
        self._closed = False
        try:
            self.recovered += self._lock.notes
            self._manifest, self._entries = self._open(allow_config_change)
            self.flush()
        except BaseException:
            self._lock.release()
            raise
        for note in self.recovered:  # logged (shown on stderr when nothing else handles it) and kept
            _LOG.warning("ges: note: %s", note)

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(self, exc_type: object, exc: BaseException | None, tb: object) -> None:
        if exc is None:
            self.close()
            return
        try:  # keep what was added; a manifest that cannot be written now is rebuilt on the next open
            self.close()
        except StorageError:
            pass  # the error in flight (often the same full disk) is the one to report
        finally:
            self._lock.release()

    def flush(self) -> None:
        """Rewrite the manifest (atomically) with every record added so far."""
        manifest = dict(self._manifest, run_config_hash=self.config_hash)
        write_manifest(self.root, manifest, list(self._entries.values()))
        self._dirty, self._last_flush = False, time.monotonic()

    def close(self) -> None:
        """Write the manifest if records were added since the last write; give the folder's lock back."""
        try:
            if self._dirty and not self._closed:
                self.flush()
        finally:
            self._closed = True
            self._lock.release()

    def __len__(self) -> int:
        return len(self._entries)

    def keys(self) -> list[tuple[str, str]]:
        """(object_id, hand) of every stored record, sorted."""
        return sorted(self._entries)

    def has(self, object_id: str, hand: str) -> bool:
        """Whether the record of ``(object_id, hand)`` is stored (a resumed run skips it)."""
        return (object_id, hand) in self._entries

    def add(self, record: GraspRecord, *, overwrite: bool = False) -> Path:
        """Check ``record``, write its file and then its timing file atomically, then the manifest (at most every
        ``manifest_interval`` s); returns the record's file. A record without a run-config hash gets this
        writer's."""
        if self._closed:
            raise ValueError(f"the writer of dataset {self.root} is closed; open a new DatasetWriter to add records")
        if self.has(*record.key) and not overwrite:
            raise ValueError(
                f"dataset {self.root} already holds the record of object '{record.object_id}' with hand "
                f"'{record.hand}'; check writer.has() first to skip it, or pass overwrite=True"
            )
        if record.run_config_hash is None:
            record = replace(record, run_config_hash=self.config_hash)
        meta, arrays = record_to_raw(record)
        problems = record_problems(meta, arrays)
        if problems:
            raise ValueError(f"record of ({record.object_id}, {record.hand}) is invalid: " + "; ".join(problems))
        file = record_relpath(record.object_id, record.hand)
        data = raw_to_bytes(meta, arrays)
        path = atomic_write_bytes(self.root / file, data)
        atomic_write_text(self.root / timing_relpath(file), timing_text(record, sha256_hex(data)))
        self._entries[record.key] = index_entry(record, file)
        self._dirty = True
        if time.monotonic() - self._last_flush >= self.manifest_interval:
            self.flush()
        return path

    def record(self, object_id: str, hand: str) -> GraspRecord:
        """The stored record of ``(object_id, hand)``; KeyError if there is none."""
        return load_record(self.root, self._entries[(object_id, hand)]["file"])

    def set_aside(self, object_id: str, hand: str, why: str) -> str:
        """Move the stored record of ``(object_id, hand)`` (and its timing file) into ``.damaged/``, so a resumed
        run makes the pair again; nothing is deleted. Says so in :attr:`recovered` (and the log); returns where
        the record went, relative to the folder."""
        if self._closed:
            raise ValueError(f"the writer of dataset {self.root} is closed; open a new DatasetWriter to change it")
        entry = self._entries.pop((object_id, hand))
        where = _move_with_timing(self.root, entry["file"])
        self._dirty = True
        note = f"moved {entry['file']} to {where}: {why}; its pair will be generated again"
        self.recovered.append(note)
        _LOG.warning("ges: note: %s", note)
        self.flush()  # the manifest no longer lists it, even if this run is killed before it makes the pair
        return where

    def _open(self, allow_config_change: bool) -> tuple[dict, dict[tuple[str, str], dict]]:
        """The manifest to keep and the index, from the records; the folder repaired (checks first, then moves)."""
        manifest, why = try_read_manifest(self.root)
        if manifest is None and any(self._foreign_files()):
            raise AssetError(
                f"{self.root} is not empty and holds no {MANIFEST}: it is not a grasp dataset. "
                "Choose a new or empty folder for the dataset"
            )
        index = index_folder(self.root, manifest)
        if manifest is None:
            rebuilt = self._new_manifest()
            kept = self._check_records_config(rebuilt, index, allow_config_change, why=why)
        else:
            kept = self._check_config(dict(manifest, version=DATASET_VERSION), allow_config_change)
            kept = self._check_records_config(kept, index, allow_config_change)
        kept, notes = check_hands(self.root, kept, self.hands, [hand for _, hand in index.records], allow_config_change)
        self.recovered += notes
        if manifest is None and (self.root / MANIFEST).exists():
            aside = move_aside(self.root, MANIFEST)
            self.recovered.append(f"{MANIFEST} could not be read ({why}): moved to {aside}")
        if manifest is None and index.records:
            self.recovered.append(f"{MANIFEST} rebuilt from the {len(index.records)} record files (this run's config)")
        return kept, _repair(self.root, index, self.recovered)

    def _foreign_files(self) -> Iterator[Path]:
        """Files that are neither records, nor the manifest, the lock, files moved aside or temporary files."""
        for p in self.root.rglob("*"):
            top = p.relative_to(self.root).parts[0]
            if (
                p.is_file()
                and top not in (RECORDS_DIR, DAMAGED_DIR, LOCK_FILE, MANIFEST)
                and not p.name.endswith(".tmp")
            ):
                yield p

    def _new_manifest(self) -> dict:
        created = {"time": utc_now(), "versions": software_versions()}
        return {"format": DATASET_FORMAT, "version": DATASET_VERSION, "created": created, "run_config": self.run_config}

    def _check_config(self, manifest: dict, allow_change: bool) -> dict:
        old = manifest.get("run_config")
        diffs = config_differences(old, self.run_config)
        if not diffs:
            return manifest
        if not allow_change:
            raise ConfigError(
                f"dataset {self.root} was written with another run config ({'; '.join(diffs)}). "
                f"{self._predated(old)}Rerun with the stored values, or write to a new folder (ges: --out DIR; ges "
                "demo --fresh moves this one aside); `ges synth --allow-config-change` (in Python, DatasetWriter(..., "
                "allow_config_change=True)) continues it and keeps the old config in the manifest's config_history",
                problems=diffs,
            )
        history = [*manifest.get("config_history", []), {"until": utc_now(), "run_config": old}]
        return dict(manifest, run_config=self.run_config, config_history=history)

    def _predated(self, stored: object) -> str:
        """The sentence naming the settings the ``stored`` run config was written before (it lacks them, this run
        has them) and the values that reproduce what it ran; empty when there are none."""
        stored_keys, run_keys = dotted_leaves(stored), dotted_leaves(self.run_config)
        old = [key for key in self.absent_means if key not in stored_keys and key in run_keys]
        if not old:
            return ""
        ran = ", ".join(f"{key}={json.dumps(self.absent_means[key])}" for key in old)
        synth = " ".join(f"-o {key}={json.dumps(self.absent_means[key])}" for key in old)
        demo = " ".join(f"-o synthesis.{key}={json.dumps(self.absent_means[key])}" for key in old)
        return (
            f"The folder predates {', '.join(old)}: it ran as {ran} (ges synth: {synth}; ges demo: {demo} resumes it "
            "as it was). "
        )

    def _check_records_config(self, manifest: dict, index: FolderIndex, allow_change: bool, *, why: str = "") -> dict:
        """Refuse records made with a run config the manifest does not name (records without a hash, version 1,
        count as unknown only when the manifest is being rebuilt); allowed, their hashes join config_history."""
        known = known_config_hashes(manifest)
        unknown = {h: n for h, n in index.config_hashes().items() if h not in known and (h is not None or why)}
        if not unknown:
            return manifest
        problems = [_made_with(h, n) for h, n in sorted(unknown.items(), key=lambda kv: str(kv[0]))]
        if not allow_change:
            ours = self.config_hash if why else config_hash(manifest["run_config"])
            whose = f"this run's ({ours})" if why else f"the one {MANIFEST} names ({ours})"
            where = f"has no usable {MANIFEST} ({why}) and holds" if why else "holds"
            raise ConfigError(
                f"dataset {self.root} {where} records made with another run config than {whose}: "
                f"{'; '.join(problems)}. Rerun with the settings the records were made with, or write to a new "
                "folder (ges: --out DIR; ges demo --fresh moves this one aside); in Python, DatasetWriter(..., "
                "allow_config_change=True) continues it and keeps their config hashes in config_history",
                problems=problems,
            )
        now = utc_now()
        history = [{"until": now, "run_config": None, "run_config_hash": h, "records": n} for h, n in unknown.items()]
        return dict(manifest, config_history=[*manifest.get("config_history", []), *history])


def _made_with(config: str | None, count: int) -> str:
    if config is None:
        return f"{count} record(s) carry no run-config hash (version 1: made with settings no longer known)"
    return f"{count} record(s) made with run config {config}"


def _repair(root: Path, index: FolderIndex, notes: list[str]) -> dict[tuple[str, str], dict]:
    """Make the folder match ``index`` (leftovers removed, damaged and duplicate records moved aside, misplaced ones
    moved home); say each in ``notes``; return the index entries by key."""
    scan = index.scan
    for rel in scan.temp_files:
        _unlink(root / rel)
        notes.append(f"removed {rel}: temporary file of an interrupted write")
    for rel in scan.missing:
        notes.append(f"{rel}: listed in {MANIFEST} but missing; its pair will be generated again")
    for rel, why in index.damaged.items():
        notes.append(f"moved {rel} to {_move_with_timing(root, rel)}: {why}; its pair will be generated again")
    for rel, other in index.duplicates.items():
        notes.append(f"moved {rel} to {_move_with_timing(root, rel)}: a second record of the pair stored at {other}")
    for rel in scan.orphan_timings:
        if (root / rel).exists():
            _unlink(root / rel)
            notes.append(f"removed {rel}: timing file whose record is gone")
    notes += index.disagreements
    entries = {}
    for key, stored in index.records.items():
        entry = dict(stored.entry)
        if stored.file in index.misplaced:
            entry["file"] = _move_home(root, stored.file, index.misplaced[stored.file])
            notes.append(f"moved {stored.file} to {entry['file']}: it holds that pair's record")
        elif stored.file in scan.unlisted:
            notes.append(f"adopted {stored.file}: written before the last run stopped, not yet in {MANIFEST}")
        entries[key] = entry
    untimed = index.untimed()
    if untimed:
        notes.append(
            f"{len(untimed)} record(s) have no usable timing file (e.g. {untimed[0]}): their times are unknown"
        )
    return entries


def _move_with_timing(root: Path, rel: str) -> str:
    """Move a record file and its timing file (if any) into .damaged/; returns where the record went."""
    if (root / timing_relpath(rel)).exists():
        move_aside(root, timing_relpath(rel))
    return move_aside(root, rel)


def _move_home(root: Path, rel: str, home: str) -> str:
    for src, dst in ((timing_relpath(rel), timing_relpath(home)), (rel, home)):
        if (root / src).exists():
            make_dirs((root / dst).parent)
            try:
                (root / src).replace(root / dst)
            except OSError as exc:
                raise storage_error(root / dst, exc) from exc
    return home


def _unlink(path: Path) -> None:
    try:
        path.unlink(missing_ok=True)
    except OSError as exc:
        raise storage_error(path, exc) from exc


@dataclass(frozen=True)
class Dataset:
    """A dataset folder opened for reading; iterating yields :class:`GraspRecord` (read lazily, with their times)."""

    root: Path
    manifest: dict
    entries: tuple[dict, ...]
    """Index entries rebuilt from the records (every usable record file, listed or not), sorted."""
    unlisted: tuple[str, ...]
    """Record files the manifest does not list (adopted into ``entries``)."""
    missing: tuple[str, ...]
    """Files the manifest lists that do not exist (left out of ``entries``)."""
    damaged: tuple[str, ...] = ()
    """Record files that cannot be read or fail the record checks (left out; see ``ges dataset validate``)."""
    notes: tuple[str, ...] = ()
    """Where the folder differs from its manifest, one line each (what :func:`open_dataset` did about it)."""

    @property
    def run_config(self) -> dict:
        """The run config the dataset was written with."""
        return self.manifest.get("run_config", {})

    def __len__(self) -> int:
        return len(self.entries)

    def __iter__(self) -> Iterator[GraspRecord]:
        return (load_record(self.root, e["file"]) for e in self.entries)

    def records(self, **match: str) -> Iterator[GraspRecord]:
        """Records whose index fields equal ``match``, e.g. ``records(hand="shadow", split="train")``."""
        for e in self.entries:
            if all(e.get(k) == v for k, v in match.items()):
                yield load_record(self.root, e["file"])

    def get(self, object_id: str, hand: str) -> GraspRecord:
        """The record of ``(object_id, hand)``; KeyError if absent."""
        for e in self.entries:
            if (e["object_id"], e["hand"]) == (object_id, hand):
                return load_record(self.root, e["file"])
        raise KeyError(f"dataset {self.root} holds no record of object '{object_id}' with hand '{hand}'")


def open_dataset(path: str | Path) -> Dataset:
    """Open a dataset folder for reading (the folder is not modified).

    The index is rebuilt in memory from the record files (:mod:`.reconcile`): files the manifest does not list
    are adopted, entries that disagree with their record take the record's fields, damaged files are left out
    (``damaged``); ``notes`` says each. The manifest must be readable (the writer rebuilds a broken one).
    """
    root = Path(path)
    manifest = read_manifest(root)
    index = index_folder(root, manifest)
    used = {r.file for r in index.records.values()}
    adopted = tuple(f for f in index.scan.unlisted if f in used)
    notes = _notes(index, adopted)
    return Dataset(root, manifest, tuple(index.entries()), adopted, index.scan.missing, tuple(index.damaged), notes)


def _notes(index: FolderIndex, adopted: tuple[str, ...]) -> tuple[str, ...]:
    """What the reader found, one line each (``adopted``: the unlisted record files it uses)."""
    notes = [f"{f} is not listed in the manifest (adopted)" for f in adopted]
    notes += [f"{f} is listed in the manifest but missing" for f in index.scan.missing]
    notes += [f"{f} cannot be used (left out): {why}" for f, why in index.damaged.items()]
    notes += [f"{f} holds the record that belongs at {home} (used)" for f, home in index.misplaced.items()]
    notes += [f"{f} is a second record of the pair stored at {o} (left out)" for f, o in index.duplicates.items()]
    notes += index.disagreements
    untimed = index.untimed()
    if untimed:
        notes.append(f"{len(untimed)} record(s) have no usable timing file: their times are unknown")
    return tuple(notes)
