"""Wall-clock times of a record, kept beside it in ``<record>.timing.json``.

A record file holds only what the run's settings and seed determine, so the same run gives byte-identical
record files and a dataset can be checked by hash; the times of a run differ every time and live here::

    records/allegro/procedural__box__000-ccc7a586.npz           the record
    records/allegro/procedural__box__000-ccc7a586.timing.json   its times

::

    {"format": "ges.grasp_timing", "version": 1, "record_sha256": "<SHA-256 of the record file>",
     "steps": {"contacts": 0.016, "retargeting": 0.051, "refinement": 0.022, "validation": 0.086},
     "validations": {"sapien": 0.086, "pybullet": 0.246}, "setup_seconds": {"sapien": 0.013},
     "robust": {"sapien": 0.61, "pybullet": 1.72}}

``robust`` (the perturbation trials' seconds per simulator) is optional: files written before robust validation
have none.

Seconds, ``null`` where unknown. The writer writes the record, then this file (both atomically); a run killed
between the two, or a timing file of an older record at the same place (``record_sha256`` differs), leaves the
record without times: its ``StepOutcome.seconds`` and ``SimVerdict.seconds`` read ``None`` and its
``setup_seconds`` ``{}``. A version-1 record kept its times inside; they are read from there.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import replace

from ges_core.dataset.record import STEPS, GraspRecord

__all__ = [
    "TIMING_FORMAT",
    "TIMING_SUFFIX",
    "TIMING_VERSION",
    "parse_timing",
    "record_timing",
    "timing_problems",
    "timing_relpath",
    "timing_text",
    "with_timing",
]

TIMING_FORMAT = "ges.grasp_timing"
TIMING_VERSION = 1
TIMING_SUFFIX = ".timing.json"
_TIMING_KEYS = ("steps", "validations", "setup_seconds")
_OPTIONAL_KEYS = ("robust",)
"""Keys a timing file may lack (written before they existed)."""


def timing_relpath(record_file: str) -> str:
    """The timing file beside the record file ``record_file`` (``x.npz`` -> ``x.timing.json``)."""
    return record_file.removesuffix(".npz") + TIMING_SUFFIX


def record_timing(record: GraspRecord) -> dict:
    """The times of ``record``: ``{"steps": {step: s}, "validations": {sim: s}, "setup_seconds": {sim: s},
    "robust": {sim: s}}``."""
    return {
        "steps": {name: step.seconds for name, step in record.steps.items()},
        "validations": {sim: verdict.seconds for sim, verdict in record.validations.items()},
        "setup_seconds": dict(record.setup_seconds),
        "robust": {sim: verdict.robust_seconds for sim, verdict in record.validations.items()},
    }


def timing_text(record: GraspRecord, record_sha256: str) -> str:
    """The timing file of ``record``, whose file's bytes have the SHA-256 ``record_sha256``."""
    data = {"format": TIMING_FORMAT, "version": TIMING_VERSION, "record_sha256": record_sha256}
    return json.dumps(data | record_timing(record), sort_keys=True) + "\n"


def with_timing(record: GraspRecord, timing: dict | None) -> GraspRecord:
    """``record`` with the times of ``timing`` (as :func:`record_timing` gives them); None: times unknown."""
    timing = timing or {}
    steps, verdicts, robust = timing.get("steps", {}), timing.get("validations", {}), timing.get("robust", {})
    return replace(
        record,
        steps={name: replace(step, seconds=steps.get(name)) for name, step in record.steps.items()},
        validations={
            sim: replace(v, seconds=verdicts.get(sim), robust_seconds=robust.get(sim) if v.trials else 0.0)
            for sim, v in record.validations.items()
        },
        setup_seconds=dict(timing.get("setup_seconds", {})),
    )


def parse_timing(text: str, record_sha256: str) -> tuple[dict | None, str]:
    """(the times in a timing file's ``text``, '') or (None, why they cannot be used for the record whose
    bytes have the SHA-256 ``record_sha256``)."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        return None, f"unreadable ({exc})"
    problems = timing_problems(data)
    if problems:
        return None, "; ".join(problems)
    if data["record_sha256"] != record_sha256:
        return None, "belongs to another version of the record (record_sha256 differs)"
    return {k: data[k] for k in _TIMING_KEYS + _OPTIONAL_KEYS if k in data}, ""


def timing_problems(data: object, *, header: bool = True) -> list[str]:
    """Problems of a timing file's content (``header``: with its format, version and record hash)."""
    if not isinstance(data, dict):
        return [f"must be a JSON object, got {type(data).__name__}"]
    problems = []
    if header and (data.get("format"), data.get("version")) != (TIMING_FORMAT, TIMING_VERSION):
        found = f"{data.get('format')!r} version {data.get('version')!r}"
        problems.append(f"not a timing file: format {found}, expected {TIMING_FORMAT!r} version {TIMING_VERSION}")
    if header and not (isinstance(data.get("record_sha256"), str) and len(data["record_sha256"]) == 64):
        problems.append(f"record_sha256: must be 64 hex digits, got {data.get('record_sha256')!r}")
    for key in _TIMING_KEYS + tuple(k for k in _OPTIONAL_KEYS if k in data):
        times = data.get(key)
        if not isinstance(times, dict) or not all(isinstance(k, str) and _seconds(v) for k, v in times.items()):
            problems.append(f"{key}: must map names to seconds (finite, >= 0) or null, got {times!r}")
    steps = data.get("steps")
    if isinstance(steps, dict) and not set(steps) <= set(STEPS):
        problems.append(f"steps: unknown step {sorted(set(steps) - set(STEPS))}")
    return problems


def sha256_hex(data: bytes) -> str:
    """SHA-256 of ``data``, 64 hex digits."""
    return hashlib.sha256(data).hexdigest()


def _seconds(value: object) -> bool:
    """A finite number >= 0, or None (unknown)."""
    if value is None:
        return True
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value) and value >= 0
