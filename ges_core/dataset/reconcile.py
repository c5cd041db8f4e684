"""The index of a dataset folder rebuilt from its records: records are the truth, the manifest a cache of them.

:func:`index_folder` reads every record file (and its timing file), checks it, and builds the index the
manifest should hold; it says where the manifest disagrees. The reader (:func:`~ges_core.dataset.open_dataset`)
uses the result in memory; the writer (:class:`~ges_core.dataset.DatasetWriter`) also repairs the folder (moves
damaged files aside, removes leftovers) and rewrites the manifest. Rules:

* an entry whose fields disagree with its record takes the record's (a changed object id included: a file is
  indexed under the (object, hand) it holds, so no two entries name one file);
* a record file the manifest does not list is adopted; an entry whose file is gone is dropped;
* a record file that cannot be read or fails the record checks is *damaged*: left out (the writer moves it to
  ``.damaged/`` and the run makes the pair again);
* a readable record at another pair's path is *misplaced*: used if its own pair has no record at its own
  path (the writer moves it there), else a duplicate, left out (the writer moves it aside).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from ges_core.dataset.checks import record_problems
from ges_core.dataset.layout import MANIFEST, FolderScan, index_entry, record_relpath, scan_folder
from ges_core.dataset.record import GraspRecord, read_raw, record_from_raw
from ges_core.dataset.timing import parse_timing, sha256_hex, timing_relpath, with_timing
from ges_core.errors import AssetError

__all__ = ["FolderIndex", "StoredRecord", "entry_differences", "index_folder", "read_record_file"]


def read_record_file(root: Path, file: str, *, check: bool = False) -> GraspRecord:
    """The record stored at ``root / file`` with its times (from its timing file; version 1: from the record).

    AssetError naming the file when it is damaged (with ``check``: also when it fails the record checks). An
    OSError reading it (no permission, ...) is not damage and propagates.
    """
    data = (root / file).read_bytes()
    try:
        meta, arrays = read_raw(data)
    except Exception as exc:  # zip, CRC, JSON errors of a damaged file alike
        raise AssetError(f"{file}: unreadable record ({type(exc).__name__}: {exc})") from exc
    problems = record_problems(meta, arrays) if check else []
    if problems:
        raise AssetError(f"{file}: invalid record ({'; '.join(problems[:3])})")
    try:
        record = record_from_raw(meta, arrays)
    except Exception as exc:  # e.g. a contact header of another format
        raise AssetError(f"{file}: cannot build the record ({type(exc).__name__}: {exc})") from exc
    if meta.get("version") == 1:
        return record  # version 1 holds its own times
    return with_timing(record, read_timing(root, file, sha256_hex(data))[0])


def read_timing(root: Path, file: str, record_sha256: str) -> tuple[dict | None, str]:
    """(the times of the record ``file``, '') or (None, why not: no timing file, damaged, another record's)."""
    path = root / timing_relpath(file)
    try:
        text = path.read_text()
    except FileNotFoundError:
        return None, "no timing file"
    except (OSError, UnicodeDecodeError) as exc:
        return None, f"unreadable timing file ({exc})"
    return parse_timing(text, record_sha256)


@dataclass(frozen=True)
class StoredRecord:
    """One usable record file: where it is, its index entry (from the record and its times), its config hash."""

    file: str
    entry: dict
    config_hash: str | None
    timed: bool
    """Whether its times are known."""

    @property
    def key(self) -> tuple[str, str]:
        return (self.entry["object_id"], self.entry["hand"])


@dataclass(frozen=True)
class FolderIndex:
    """A dataset folder as its records describe it, and how its manifest differs."""

    records: dict[tuple[str, str], StoredRecord]
    """(object_id, hand) -> its usable record."""
    scan: FolderScan
    damaged: dict[str, str] = field(default_factory=dict)
    """Record file -> why it cannot be used (unreadable, invalid)."""
    misplaced: dict[str, str] = field(default_factory=dict)
    """Used record file that sits at another pair's path -> the path its pair maps to."""
    duplicates: dict[str, str] = field(default_factory=dict)
    """Readable record file at another pair's path whose pair has a record already -> that record's file."""
    disagreements: tuple[str, ...] = ()
    """One line per manifest entry that disagreed with its record (the record's fields are used)."""

    def entries(self) -> list[dict]:
        """The index: one entry per usable record, sorted by hand then object id."""
        return sorted((r.entry for r in self.records.values()), key=lambda e: (e["hand"], e["object_id"]))

    def config_hashes(self) -> dict[str | None, int]:
        """Run-config hash -> number of records made with it (None: records that carry none)."""
        counts: dict[str | None, int] = {}
        for r in self.records.values():
            counts[r.config_hash] = counts.get(r.config_hash, 0) + 1
        return counts

    def untimed(self) -> list[str]:
        """Usable record files whose times are unknown."""
        return sorted(r.file for r in self.records.values() if not r.timed)


def index_folder(root: Path, manifest: dict | None) -> FolderIndex:
    """Read every record file under ``root``; the index they describe against the manifest's (None: none)."""
    scan = scan_folder(root, manifest)
    stored, damaged = {}, {}
    for file in sorted({*scan.listed, *scan.unlisted}):
        try:
            record = read_record_file(root, file, check=True)
        except AssetError as exc:
            damaged[file] = str(exc).removeprefix(f"{file}: ")
            continue
        timed = all(step.seconds is not None for step in record.steps.values())
        stored[file] = StoredRecord(file, _plain(index_entry(record, file)), record.run_config_hash, timed)
    records, misplaced, duplicates = _by_key(stored)
    return FolderIndex(records, scan, damaged, misplaced, duplicates, _disagreements(scan, stored))


def _by_key(stored: dict[str, StoredRecord]):
    """Records by key: a record at its own path first, then misplaced ones whose pair has none."""
    records: dict[tuple[str, str], StoredRecord] = {}
    misplaced, duplicates = {}, {}
    at_home = {f: s for f, s in stored.items() if f == record_relpath(*s.key)}
    for s in at_home.values():
        records[s.key] = s
    for f, s in stored.items():
        if f in at_home:
            continue
        if s.key in records:
            duplicates[f] = records[s.key].file
        else:
            records[s.key], misplaced[f] = s, record_relpath(*s.key)
    return records, misplaced, duplicates


def _disagreements(scan: FolderScan, stored: dict[str, StoredRecord]) -> tuple[str, ...]:
    lines = []
    for file, listed in scan.listed.items():
        if file not in stored:
            continue  # damaged: said elsewhere
        entry = stored[file].entry
        if (listed.get("object_id"), listed.get("hand")) != (entry["object_id"], entry["hand"]):
            lines.append(
                f"{MANIFEST} listed {file} as object {listed.get('object_id')!r} with hand {listed.get('hand')!r}, "
                f"but it holds object {entry['object_id']!r} with hand {entry['hand']!r}: indexed as what it holds"
            )
            continue
        wrong = entry_differences(listed, entry, timed=stored[file].timed)
        if wrong:
            lines.append(
                f"{MANIFEST} entry of {file} disagreed with its record on {wrong}: the record's values are used"
            )
    return tuple(lines)


def entry_differences(listed: dict, entry: dict, *, timed: bool, keys: tuple[str, ...] | None = None) -> list[str]:
    """Keys (of ``keys``, default all) where a manifest entry differs from the one built from its record; the step
    times only when the record's times are known (lost times do not make the manifest's wrong)."""
    keys = keys or tuple(set(entry) | set(listed))
    wrong = {k for k in keys if k != "steps" and listed.get(k) != entry.get(k)}
    steps = listed.get("steps"), _as_listed(entry.get("steps"), listed.get("steps"))
    if "steps" in keys and (steps[0] != steps[1] if timed else _untimed(steps[0]) != _untimed(steps[1])):
        wrong.add("steps")
    return sorted(wrong)


def _as_listed(steps: object, listed: object) -> object:
    """A record's index steps without the ``robust`` step when the manifest's entry predates it (a record of
    version 1 or 2, whose robust step reads ``not_run``); anything else unchanged."""
    if not (isinstance(steps, dict) and isinstance(listed, dict)) or "robust" in listed:
        return steps
    robust = steps.get("robust")
    if isinstance(robust, list) and robust[:2] == [False, "not_run"]:
        return {k: v for k, v in steps.items() if k != "robust"}
    return steps


def _untimed(steps: object) -> object:
    """Index steps ``{step: [ok, reason, seconds]}`` without the seconds (anything else unchanged)."""
    if not isinstance(steps, dict):
        return steps
    return {k: v[:2] if isinstance(v, list) else v for k, v in steps.items()}


def _plain(entry: dict) -> dict:
    """``entry`` as it reads back from JSON (tuples as lists), so it compares with a manifest's."""
    return json.loads(json.dumps(entry))
