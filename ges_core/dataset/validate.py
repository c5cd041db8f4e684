"""``ges dataset validate``: every problem of a dataset folder, one line each."""

from __future__ import annotations

import json
from pathlib import Path

from ges_core.dataset.checks import record_problems
from ges_core.dataset.layout import (
    INDEX_FIELDS,
    MANIFEST,
    index_entry,
    known_config_hashes,
    read_manifest,
    record_relpath,
    scan_folder,
)
from ges_core.dataset.reconcile import entry_differences, read_timing
from ges_core.dataset.record import read_raw, record_from_raw
from ges_core.dataset.timing import sha256_hex, timing_relpath, with_timing
from ges_core.errors import AssetError

__all__ = ["validate_dataset"]

_MANIFEST_KEYS = ("format", "version", "created", "run_config", "records")
_ENTRY_KEYS = ("file", *INDEX_FIELDS, "success", "failed_step", "steps")


def validate_dataset(path: str | Path) -> list[str]:
    """Problems of the manifest, of every record file and of their agreement; [] when all is well."""
    root = Path(path)
    try:
        manifest = read_manifest(root)
    except AssetError as exc:
        return [str(exc)]
    problems = _manifest_problems(manifest)
    scan = scan_folder(root, manifest)
    problems += [f"{MANIFEST}: lists {f}, which does not exist" for f in scan.missing]
    problems += [f"{f}: record file not listed in {MANIFEST} (the writer adopts it on resume)" for f in scan.unlisted]
    problems += [
        f"{f}: leftover temporary file from an interrupted write (the writer removes it)" for f in scan.temp_files
    ]
    problems += [f"{f}: timing file whose record is not there (the writer removes it)" for f in scan.orphan_timings]
    known = known_config_hashes(manifest) if isinstance(manifest.get("run_config"), dict) else set()
    for file, entry in scan.listed.items():
        problems += _file_problems(root, file, entry, known)
    for file in scan.unlisted:
        problems += _file_problems(root, file, None, known)
    return problems


def _manifest_problems(manifest: dict) -> list[str]:
    problems = [f"{MANIFEST}: missing key '{k}'" for k in _MANIFEST_KEYS if k not in manifest]
    if not isinstance(manifest.get("run_config", {}), dict):
        problems.append(f"{MANIFEST}: run_config must be an object")
    entries = manifest.get("records", [])
    if not isinstance(entries, list):
        return [*problems, f"{MANIFEST}: records must be a list"]
    seen_keys: set[tuple] = set()
    seen_files: set[str] = set()
    for i, entry in enumerate(entries):
        missing = [k for k in _ENTRY_KEYS if not isinstance(entry, dict) or k not in entry]
        if missing:
            problems.append(f"{MANIFEST}: records[{i}] lacks {missing}")
            continue
        key = (entry["object_id"], entry["hand"])
        if key in seen_keys or entry["file"] in seen_files:
            problems.append(f"{MANIFEST}: records[{i}] repeats object {key[0]!r} with hand {key[1]!r} or its file")
        seen_keys.add(key)
        seen_files.add(entry["file"])
    return problems


def _file_problems(root: Path, file: str, entry: dict | None, known: set[str]) -> list[str]:
    data = (root / file).read_bytes()
    try:
        meta, arrays = read_raw(data)
    except Exception as exc:  # damaged zip, bad CRC, bad JSON: all mean an unreadable record
        return [f"{file}: unreadable record ({type(exc).__name__}: {exc})"]
    problems = record_problems(meta, arrays)
    if problems:
        return [f"{file}: {p}" for p in problems]
    try:
        record = record_from_raw(meta, arrays)
    except Exception as exc:  # e.g. a contact header of another format
        return [f"{file}: cannot build the record ({type(exc).__name__}: {exc})"]
    expected_file = record_relpath(record.object_id, record.hand)
    if file != expected_file:
        what = f"object {record.object_id!r} with hand {record.hand!r}"
        problems.append(f"{file}: holds {what}, which belongs at {expected_file}")
    if record.run_config_hash is not None and known and record.run_config_hash not in known:
        problems.append(
            f"{file}: made with run config {record.run_config_hash}, which {MANIFEST} does not name (its run_config "
            "and config_history)"
        )
    timed = meta.get("version") == 1
    if not timed:
        timing, why = read_timing(root, file, sha256_hex(data))
        if timing is None and why != "no timing file":
            problems.append(f"{timing_relpath(file)}: {why} (the record's times are unknown)")
        record, timed = with_timing(record, timing), timing is not None
    if entry is not None:
        expected = json.loads(json.dumps(index_entry(record, file)))
        wrong = entry_differences(entry, expected, timed=timed, keys=_ENTRY_KEYS)
        if wrong:
            problems.append(f"{file}: {MANIFEST} index disagrees with the record on {wrong}")
    return problems
