"""Write a grasp dataset incrementally and resumably; read it back.

>>> writer = DatasetWriter("runs/demo", run_config={"hands": ["shadow"], "sim": "sapien"})
>>> for obj in objects:
...     if not writer.has(obj.object_id, "shadow"):      # resume: skip what is stored
...         writer.add(synthesize(obj))                  # one atomic file, then the manifest
>>> for record in open_dataset("runs/demo"):
...     print(record.object_id, record.hand, record.success)

Each record is one file written atomically; the manifest is rewritten atomically after it (at most
every ``manifest_interval`` seconds, and on close). A run killed at any moment therefore leaves
whole records only; records written before the kill but missing from the manifest are adopted when
the folder is opened again (by the writer, which rewrites the manifest, and by the reader, in
memory). One writer per folder at a time.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from ges_core.dataset.checks import record_problems
from ges_core.dataset.layout import (
    DATASET_FORMAT,
    DATASET_VERSION,
    MANIFEST,
    RECORDS_DIR,
    config_differences,
    index_entry,
    normalize_config,
    read_manifest,
    record_relpath,
    scan_folder,
    utc_now,
    write_manifest,
)
from ges_core.dataset.record import GraspRecord, raw_to_bytes, record_from_bytes, record_to_raw, software_versions
from ges_core.errors import AssetError, ConfigError
from ges_core.paths import atomic_write_bytes

__all__ = ["MANIFEST_INTERVAL_S", "Dataset", "DatasetWriter", "load_record", "open_dataset"]

MANIFEST_INTERVAL_S = 2.0
"""Default seconds between manifest rewrites: with Stage 1 at about 1 s per record this rewrites the
index every other record or so, and a kill costs at most the adoption of the few newest files."""


def load_record(root: Path, file: str) -> GraspRecord:
    """Read the record stored at ``root / file``; AssetError naming the file if it is damaged."""
    path = root / file
    try:
        return record_from_bytes(path.read_bytes())
    except Exception as exc:  # zip, JSON, key and type errors of a damaged file alike
        raise AssetError(
            f"cannot read grasp record {path}: {type(exc).__name__}: {exc}. Run 'ges dataset validate {root}'; "
            "delete the file to have the next run regenerate it"
        ) from exc


class DatasetWriter:
    """Adds records to a dataset folder, creating it or resuming it.

    path: the dataset folder (created if missing; must be empty or a dataset).
    run_config: the run's settings (dict, pydantic model or dataclass; stored as JSON). Resuming
        a folder written with other settings raises ConfigError unless ``allow_config_change``.
    manifest_interval: seconds between manifest rewrites (0: after every record). Records added in
        between are safe on disk and adopted on the next open; :meth:`close` (or leaving a ``with``
        block) writes the manifest. Rewriting an index of N records after each of N records would
        cost O(N^2) bytes, which a large run notices.
    """

    def __init__(
        self,
        path: str | Path,
        run_config: object,
        *,
        allow_config_change: bool = False,
        manifest_interval: float = MANIFEST_INTERVAL_S,
    ) -> None:
        self.root = Path(path)
        self.run_config = normalize_config(run_config)
        self.manifest_interval = manifest_interval
        self.recovered: list[str] = []
        """What opening repaired: leftover temporary files, adopted or vanished record files."""
        self._manifest = self._open(allow_config_change)
        self._entries = self._reconcile()
        self.flush()

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def flush(self) -> None:
        """Rewrite the manifest (atomically) with every record added so far."""
        write_manifest(self.root, self._manifest, list(self._entries.values()))
        self._dirty, self._last_flush = False, time.monotonic()

    def close(self) -> None:
        """Write the manifest if records were added since the last write."""
        if self._dirty:
            self.flush()

    def __len__(self) -> int:
        return len(self._entries)

    def keys(self) -> list[tuple[str, str]]:
        """(object_id, hand) of every stored record, sorted."""
        return sorted(self._entries)

    def has(self, object_id: str, hand: str) -> bool:
        """Whether the record of ``(object_id, hand)`` is stored (a resumed run skips it)."""
        return (object_id, hand) in self._entries

    def add(self, record: GraspRecord, *, overwrite: bool = False) -> Path:
        """Check ``record``, write its file atomically, then rewrite the manifest; returns the file."""
        if self.has(*record.key) and not overwrite:
            raise ValueError(
                f"dataset {self.root} already holds the record of object '{record.object_id}' with hand "
                f"'{record.hand}'; check writer.has() first to skip it, or pass overwrite=True"
            )
        meta, arrays = record_to_raw(record)
        problems = record_problems(meta, arrays)
        if problems:
            raise ValueError(f"record of ({record.object_id}, {record.hand}) is invalid: " + "; ".join(problems))
        file = record_relpath(record.object_id, record.hand)
        path = atomic_write_bytes(self.root / file, raw_to_bytes(meta, arrays))
        self._entries[record.key] = index_entry(record, file)
        self._dirty = True
        if time.monotonic() - self._last_flush >= self.manifest_interval:
            self.flush()
        return path

    def _open(self, allow_config_change: bool) -> dict:
        if (self.root / MANIFEST).is_file():
            manifest = read_manifest(self.root)
            return dict(self._check_config(manifest, allow_config_change), version=DATASET_VERSION)
        if self.root.exists() and any(self._foreign_files()):
            raise AssetError(
                f"{self.root} is not empty and holds no {MANIFEST}: it is not a grasp dataset. "
                "Choose a new or empty folder for the dataset"
            )
        if (self.root / RECORDS_DIR).is_dir():
            self.recovered.append(f"{MANIFEST} was missing: rebuilt from the record files with this run's config")
        return self._new_manifest()

    def _foreign_files(self) -> Iterator[Path]:
        """Files that are neither records, nor temporary files, nor folders of records."""
        for p in self.root.rglob("*"):
            rel = p.relative_to(self.root)
            if p.is_file() and rel.parts[0] != RECORDS_DIR and not p.name.endswith(".tmp"):
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
                "Rerun with the stored values, or write to a new folder (ges: --out DIR; ges demo --fresh moves "
                "this one aside); in Python, DatasetWriter(..., allow_config_change=True) continues it and keeps "
                "the old config in the manifest's config_history",
                problems=diffs,
            )
        history = [*manifest.get("config_history", []), {"until": utc_now(), "run_config": old}]
        return dict(manifest, run_config=self.run_config, config_history=history)

    def _reconcile(self) -> dict[tuple[str, str], dict]:
        scan = scan_folder(self.root, self._manifest)
        for rel in scan.temp_files:
            (self.root / rel).unlink(missing_ok=True)
            self.recovered.append(f"removed {rel}: temporary file of an interrupted write")
        for rel in scan.missing:
            self.recovered.append(f"{rel}: listed in {MANIFEST} but missing; its pair will be generated again")
        entries = {(e["object_id"], e["hand"]): e for e in scan.listed.values()}
        for rel in scan.unlisted:
            record = load_record(self.root, rel)
            entries[record.key] = index_entry(record, rel)
            self.recovered.append(f"adopted {rel}: written before the last run stopped, not yet in {MANIFEST}")
        return entries


@dataclass(frozen=True)
class Dataset:
    """A dataset folder opened for reading; iterating yields :class:`GraspRecord` (read lazily)."""

    root: Path
    manifest: dict
    entries: tuple[dict, ...]
    """Index entries (manifest entries whose file exists, plus adopted unlisted files), sorted."""
    unlisted: tuple[str, ...]
    """Record files the manifest does not list (adopted into ``entries``)."""
    missing: tuple[str, ...]
    """Files the manifest lists that do not exist (left out of ``entries``)."""
    damaged: tuple[str, ...] = ()
    """Unlisted record files that cannot be read (left out of ``entries``; see ``ges dataset validate``)."""

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

    Record files missing from the manifest (a run stopped before its last manifest write) are
    adopted in memory; unreadable ones are listed in ``damaged`` and left out.
    """
    root = Path(path)
    manifest = read_manifest(root)
    scan = scan_folder(root, manifest)
    entries, damaged = list(scan.listed.values()), []
    for rel in scan.unlisted:
        try:
            entries.append(index_entry(load_record(root, rel), rel))
        except AssetError:
            damaged.append(rel)
    entries.sort(key=lambda e: (e.get("hand", ""), e.get("object_id", "")))
    adopted = tuple(f for f in scan.unlisted if f not in damaged)
    return Dataset(root, manifest, tuple(entries), adopted, scan.missing, tuple(damaged))
