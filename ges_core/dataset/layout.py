"""The dataset folder: file names, the manifest and its index, and a scan of what is on disk.

::

    DATASET/
      manifest.json                       format tag + version, creation info, run config, index
      records/<hand>/<object-slug>-<hash>.npz           one record per (object, hand)
      records/<hand>/<object-slug>-<hash>.timing.json   its wall-clock times (ges_core.dataset.timing)
      .lock                               while a writer has the folder open (ges_core.dataset.lock)
      .damaged/                           files the writer moved aside (unreadable records, a broken manifest)

Every file is written through :func:`ges_core.paths.atomic_write_bytes` (temporary file + rename),
so a killed run leaves whole files and at most some hidden ``.*.tmp`` files.
"""

from __future__ import annotations

import dataclasses
import datetime
import hashlib
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path

from ges_core.dataset.record import STEPS, GraspRecord
from ges_core.dataset.timing import TIMING_SUFFIX
from ges_core.errors import AssetError
from ges_core.paths import atomic_write_text, make_dirs, storage_error

__all__ = [
    "DATASET_FORMAT",
    "DATASET_VERSION",
    "DAMAGED_DIR",
    "MANIFEST",
    "READABLE_VERSIONS",
    "RECORDS_DIR",
    "FolderScan",
    "config_differences",
    "config_hash",
    "index_entry",
    "known_config_hashes",
    "move_aside",
    "normalize_config",
    "read_manifest",
    "record_relpath",
    "scan_folder",
    "try_read_manifest",
    "utc_now",
    "write_manifest",
]

DATASET_FORMAT = "ges.contactgrasp_dataset"
DATASET_VERSION = 2
"""Version 2: records of record version 2 (typed fields instead of ``extra``) and, from the Stage 1 pipeline, a
``run_config`` with one ``thumb_keep`` and the whole ``library`` section. Version 1 is still read."""
READABLE_VERSIONS = (1, 2)
"""Dataset versions this code opens; a writer resuming an older one rewrites its manifest as DATASET_VERSION."""
MANIFEST = "manifest.json"
RECORDS_DIR = "records"
DAMAGED_DIR = ".damaged"
"""Where the writer moves files it cannot use (kept for a look, never read): ``.damaged/<their path>``."""

INDEX_FIELDS = ("object_id", "hand", "simulator", "category", "split")
"""Record fields copied into each manifest index entry (with file, success, failed_step, steps)."""


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text.replace("/", "__")).strip("._") or "x"


def record_relpath(object_id: str, hand: str) -> str:
    """Path of the record of ``(object_id, hand)`` relative to the dataset folder (POSIX separators).

    Readable (the object id with '/' as '__') and unique (8 hex digits of a hash of the exact key).
    """
    digest = hashlib.sha256(f"{object_id}\n{hand}".encode()).hexdigest()[:8]
    return f"{RECORDS_DIR}/{_slug(hand)}/{_slug(object_id)}-{digest}.npz"


def index_entry(record: GraspRecord, file: str) -> dict:
    """The manifest's summary of one record: enough for ``ges dataset info`` without opening it."""
    steps = {name: [record.steps[name].ok, record.steps[name].reason, record.steps[name].seconds] for name in STEPS}
    entry = {"file": file, **{k: getattr(record, k) for k in INDEX_FIELDS}}
    return entry | {"success": record.success, "failed_step": record.failed_step, "steps": steps}


def config_hash(config: dict) -> str:
    """16 hex digits of the SHA-256 of a normalized run config (:func:`normalize_config`): what a record stores
    to tell which settings it was made with."""
    text = json.dumps(config, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def known_config_hashes(manifest: dict) -> set[str]:
    """Hashes of the run configs a manifest names: its run_config and those in its config_history."""
    configs = [manifest.get("run_config"), *(h.get("run_config") for h in manifest.get("config_history", []))]
    known = {config_hash(c) for c in configs if isinstance(c, dict)}
    return known | {h["run_config_hash"] for h in manifest.get("config_history", []) if h.get("run_config_hash")}


def utc_now() -> str:
    """Current UTC time, ISO 8601 to the second."""
    return datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0).isoformat()


def normalize_config(config: object) -> dict:
    """A run config (dict, pydantic model or dataclass) as plain JSON data, for storing and comparing."""
    if hasattr(config, "model_dump"):
        config = config.model_dump(mode="json")
    elif dataclasses.is_dataclass(config) and not isinstance(config, type):
        config = dataclasses.asdict(config)
    if not isinstance(config, dict):
        raise TypeError(f"run_config must be a dict, a pydantic model or a dataclass, got {type(config).__name__}")
    return json.loads(json.dumps(config, sort_keys=True, default=str))


def config_differences(old: object, new: object, prefix: str = "") -> list[str]:
    """Dotted paths where two JSON configs differ, as ``path: old -> new``."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for key in sorted(set(old) | set(new)):
            path = f"{prefix}.{key}" if prefix else str(key)
            out += config_differences(old.get(key, "<absent>"), new.get(key, "<absent>"), path)
        return out
    return [] if old == new else [f"{prefix or '<root>'}: {old!r} -> {new!r}"]


def read_manifest(root: Path) -> dict:
    """The parsed manifest of the dataset at ``root``; AssetError if missing, unreadable or foreign."""
    path = root / MANIFEST
    if not path.is_file():
        raise AssetError(f"{root} is not a grasp dataset: it has no {MANIFEST}")
    manifest, why = try_read_manifest(root)
    if manifest is None:
        raise AssetError(
            f"cannot read {path}: {why}. Resume the run that wrote the folder (or open it with DatasetWriter): the "
            "writer moves the broken manifest aside and rebuilds the index from the record files"
        )
    return manifest


def try_read_manifest(root: Path) -> tuple[dict | None, str]:
    """(the manifest at ``root``, '') or (None, why it is damaged: unreadable JSON, not an object, missing).

    AssetError for a manifest of another format or of a version this code does not read (nothing to repair).
    """
    path = root / MANIFEST
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        return None, f"{MANIFEST} is missing"
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        return None, f"{type(exc).__name__}: {exc}"
    if not isinstance(data, dict):
        return None, f"it holds a JSON {type(data).__name__}, not an object"
    if data.get("format") != DATASET_FORMAT:
        raise AssetError(
            f"{path} is not a grasp dataset manifest: format {data.get('format')!r}, expected {DATASET_FORMAT!r}"
        )
    if data.get("version") not in READABLE_VERSIONS:
        readable = ", ".join(str(v) for v in READABLE_VERSIONS)
        raise AssetError(
            f"{path}: dataset version {data.get('version')!r} is not supported by this GES-UniGrasp "
            f"(reads versions {readable}); use the GES-UniGrasp version that wrote it"
        )
    return data, ""


def write_manifest(root: Path, manifest: dict, entries: list[dict]) -> None:
    """Write ``manifest`` with ``entries`` as its index (sorted by hand then object id), atomically.

    The header is indented; the index holds one compact line per record (diffs and ``grep`` stay easy).
    """
    header = {k: v for k, v in manifest.items() if k not in ("records", "hands")} | {"updated": utc_now()}
    index = sorted(entries, key=lambda e: (e["hand"], e["object_id"]))
    rows = ",\n".join("  " + json.dumps(e, sort_keys=True) for e in index)
    hands = _hands_text(manifest["hands"]) if "hands" in manifest else ""
    text = json.dumps(header, indent=1, sort_keys=True)[:-2] + hands + f',\n "records": [\n{rows}\n ]\n}}\n'
    atomic_write_text(root / MANIFEST, text)


def _hands_text(hands: dict) -> str:
    """The manifest's ``hands`` (:mod:`ges_core.dataset.hands`) as JSON text with one line per description field."""
    parts = []
    for name, entry in sorted(hands.items()):
        fields = entry.get("description", {}) if isinstance(entry, dict) else {}
        lines = ",\n".join(f"    {json.dumps(k)}: {json.dumps(v)}" for k, v in sorted(fields.items()))
        head = json.dumps({k: v for k, v in entry.items() if k != "description"}, sort_keys=True)[1:-1]
        parts.append(f'  {json.dumps(name)}: {{{head}, "description": {{\n{lines}\n  }}}}')
    return ',\n "hands": {\n' + ",\n".join(parts) + "\n }"


def move_aside(root: Path, rel: str) -> str:
    """Move ``root / rel`` to ``root / .damaged / rel`` (``-2``, ``-3``, ... when taken); returns where, relative."""
    target = Path(DAMAGED_DIR) / rel
    n = 1
    while (root / target).exists():
        n += 1
        target = Path(DAMAGED_DIR) / f"{rel}-{n}"
    make_dirs((root / target).parent)
    try:
        os.replace(root / rel, root / target)
    except OSError as exc:
        raise storage_error(root / target, exc) from exc
    return target.as_posix()


@dataclass(frozen=True)
class FolderScan:
    """What the manifest lists against what the folder holds."""

    listed: dict[str, dict]
    """Relative file -> index entry, for every manifest entry whose file exists."""
    missing: tuple[str, ...]
    """Files the manifest lists that are not on disk."""
    unlisted: tuple[str, ...]
    """Record files on disk that the manifest does not list (a run killed between the two writes)."""
    temp_files: tuple[str, ...]
    """Leftover temporary files of interrupted atomic writes."""
    orphan_timings: tuple[str, ...] = ()
    """Timing files whose record file is not there."""


def scan_folder(root: Path, manifest: dict | None) -> FolderScan:
    """Compare the manifest's index with the record, timing and ``.tmp`` files under ``root`` (hidden folders,
    e.g. ``.damaged``, left out)."""
    entries = [e for e in (manifest or {}).get("records", []) if isinstance(e, dict) and isinstance(e.get("file"), str)]
    on_disk = _visible_files(root, f"{RECORDS_DIR}/**/*.npz")
    timings = _visible_files(root, f"{RECORDS_DIR}/**/*{TIMING_SUFFIX}")
    temp = sorted(p.relative_to(root).as_posix() for p in root.glob("**/.*.tmp"))
    return FolderScan(
        listed={e["file"]: e for e in entries if e["file"] in on_disk},
        missing=tuple(sorted({e["file"] for e in entries if e["file"] not in on_disk})),
        unlisted=tuple(sorted(on_disk - {e["file"] for e in entries})),
        temp_files=tuple(f for f in temp if not f.startswith(f"{DAMAGED_DIR}/")),
        orphan_timings=tuple(sorted(t for t in timings if t.removesuffix(TIMING_SUFFIX) + ".npz" not in on_disk)),
    )


def _visible_files(root: Path, pattern: str) -> set[str]:
    """Files under ``root`` matching ``pattern`` (relative, POSIX), none of whose path parts is hidden."""
    found = (p.relative_to(root).as_posix() for p in root.glob(pattern))
    return {f for f in found if not any(part.startswith(".") for part in f.split("/"))}
