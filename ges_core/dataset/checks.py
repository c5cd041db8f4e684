"""Checks of one stored record, on its raw on-disk form (JSON scalars + named arrays).

:func:`record_problems` returns one readable line per problem and never raises, whatever the
input holds; the writer runs it before every write and ``ges dataset validate`` on every file.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from ges_core.dataset.record import (
    NOT_RUN,
    RECORD_FORMAT,
    RECORD_VERSION,
    SKIPPED,
    STEPS,
    AttemptVerdict,
    Quality,
    RefinementInfo,
    SimVerdict,
)
from ges_core.dataset.record_v1 import timing_v1
from ges_core.dataset.record_v2 import upgraded
from ges_core.dataset.timing import timing_problems

__all__ = ["READABLE_RECORD_VERSIONS", "UNIT_TOLERANCE", "record_problems"]

READABLE_RECORD_VERSIONS = (1, 2, RECORD_VERSION)
"""Record versions that are read: versions 1 and 2 through :func:`ges_core.dataset.record_v2.upgraded`."""

UNIT_TOLERANCE = 1e-6
"""Largest accepted | |v| - 1 | of a stored normal, direction or quaternion: float64 storage keeps
normalized vectors within ~1e-15, so anything above this was not normalized."""

_TEXT_FIELDS = ("object_id", "category", "split", "hand", "simulator")
_STRATEGIES = (None, "horizontal", "vertical")
_GRASP_STAGES = ("retargeting", "refinement")
_UNIT_ROWS = {"contact_normals": (0, 3), "approach": (0, 3), "wrist_pose": (3, 7), "pregrasp_wrist_pose": (3, 7)}
"""Array -> column range that must have unit norm per row."""


def record_problems(meta: object, arrays: Mapping[str, np.ndarray]) -> list[str]:
    """Every problem of one record: schema, shapes, finite values, unit vectors, flag consistency."""
    if not isinstance(meta, dict):
        return [f"record scalars are a {type(meta).__name__}, not a JSON object"]
    if meta.get("format") != RECORD_FORMAT or meta.get("version") not in READABLE_RECORD_VERSIONS:
        found = f"{meta.get('format')!r} version {meta.get('version')!r}"
        expected = " or ".join(str(v) for v in READABLE_RECORD_VERSIONS)
        return [f"not a grasp record: format {found}, expected {RECORD_FORMAT!r} version {expected}"]
    problems = [f"times: {p}" for p in timing_problems(timing_v1(meta), header=False)] if meta["version"] == 1 else []
    meta = upgraded(meta)
    problems += _text_problems(meta) + _joint_name_problems(meta.get("joint_names"))
    problems += _step_problems(meta.get("steps"))
    problems += _array_problems(arrays, _joint_count(meta))
    problems += _quality_problems(meta.get("quality"))
    problems += _misc_problems(meta) + _note_problems(meta) + _unknown_key_problems(meta)
    if not any(p.startswith("steps") for p in problems):
        problems += _presence_problems(meta, arrays)
    return problems


def _text_problems(meta: dict) -> list[str]:
    bad = [k for k in _TEXT_FIELDS if not isinstance(meta.get(k), str) or not meta.get(k)]
    problems = [f"{k}: must be a non-empty string, got {meta.get(k)!r}" for k in bad]
    if meta.get("strategy") not in _STRATEGIES:
        problems.append(f"strategy: {meta.get('strategy')!r} is not one of {list(_STRATEGIES)}")
    return problems


def _joint_name_problems(names: object) -> list[str]:
    if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names):
        return [f"joint_names: must be a list of non-empty strings, got {names!r}"]
    dupes = sorted({n for n in names if names.count(n) > 1})
    return [f"joint_names: duplicated {dupes}"] if dupes else []


def _joint_count(meta: dict) -> int | None:
    names = meta.get("joint_names")
    return len(names) if isinstance(names, list) else None


def _step_problems(steps: object) -> list[str]:
    if not isinstance(steps, dict) or sorted(steps) != sorted(STEPS):
        keys = sorted(steps) if isinstance(steps, dict) else steps
        return [f"steps: must hold exactly {list(STEPS)}, got {keys!r}"]
    problems = [p for name in STEPS for p in _one_step_problems(name, steps[name])]
    return problems or _order_problems(steps)


def _one_step_problems(name: str, step: object) -> list[str]:
    if not isinstance(step, dict) or sorted(step) != ["ok", "reason"]:
        return [f"steps.{name}: must be {{ok, reason}} (its time lives in the timing file), got {step!r}"]
    ok, reason = step["ok"], step["reason"]
    if not isinstance(ok, bool) or not isinstance(reason, str):
        return [f"steps.{name}: ok must be a bool and reason a string, got {ok!r}, {reason!r}"]
    if ok == bool(reason):
        return [f"steps.{name}: ok={ok} with reason {reason!r} (a success has no reason, a failure has one)"]
    return []


def _order_problems(steps: dict) -> list[str]:
    problems, earlier_failed = [], None
    for name in STEPS:
        ok, reason = steps[name]["ok"], steps[name]["reason"]
        if earlier_failed and reason not in (SKIPPED, NOT_RUN):
            problems.append(f"steps.{name}: is {reason or 'ok'!r} but the earlier step {earlier_failed} failed")
        elif not earlier_failed and reason == SKIPPED:
            problems.append(f"steps.{name}: is {SKIPPED!r} but no earlier step failed")
        if not ok and reason not in (SKIPPED, NOT_RUN):
            earlier_failed = earlier_failed or name
    return problems


_ARRAY_SHAPES = {
    "contact_positions": (5, 3),
    "contact_normals": (5, 3),
    "approach": (3,),
    "wrist_pose": (7,),
    "pregrasp_wrist_pose": (7,),
    "q": ("K",),
    "pregrasp_q": ("K",),
}


def _array_problems(arrays: Mapping[str, np.ndarray], joints: int | None) -> list[str]:
    problems = [f"array {name}: unknown array name" for name in arrays if name not in _ARRAY_SHAPES]
    for name in sorted(set(arrays) & set(_ARRAY_SHAPES)):
        problems += _one_array_problems(name, np.asarray(arrays[name]), joints)
    for a, b in (("contact_positions", "contact_normals"), ("wrist_pose", "q"), ("pregrasp_wrist_pose", "pregrasp_q")):
        if (a in arrays) != (b in arrays):
            problems.append(f"arrays {a} and {b}: one is stored without the other")
    return problems


def _one_array_problems(name: str, arr: np.ndarray, joints: int | None) -> list[str]:
    expected = tuple(joints if d == "K" else d for d in _ARRAY_SHAPES[name])
    if not np.issubdtype(arr.dtype, np.floating):
        return [f"array {name}: dtype {arr.dtype}, expected float64"]
    if joints is not None and arr.shape != expected:
        what = " (one value per joint name)" if name.endswith("q") else ""
        return [f"array {name}: shape {arr.shape}, expected {expected}{what}"]
    if not np.isfinite(arr).all():
        return [f"array {name}: holds NaN or inf"]
    if name in _UNIT_ROWS:
        lo, hi = _UNIT_ROWS[name]
        err = float(np.max(np.abs(np.linalg.norm(arr.reshape(-1, arr.shape[-1])[:, lo:hi], axis=1) - 1.0)))
        if err > UNIT_TOLERANCE:
            kind = "quaternion" if hi == 7 else "vector"
            return [f"array {name}: {kind} norm differs from 1 by {err:.2e} (tolerance {UNIT_TOLERANCE:g})"]
    return []


def _quality_problems(quality: object) -> list[str]:
    fields = set(Quality.__dataclass_fields__)
    if not isinstance(quality, dict) or not set(quality) <= fields:
        return [f"quality: must be an object with keys among {sorted(fields)}, got {quality!r}"]
    problems = []
    for key, value in quality.items():
        if key == "table_contact":
            if value is not None and not isinstance(value, bool):
                problems.append(f"quality.table_contact: must be true, false or null, got {value!r}")
        elif value is not None and (not _is_number(value) or not math.isfinite(value) or value < 0):
            problems.append(f"quality.{key}: must be a finite number >= 0 or null, got {value!r}")
    return problems


def _misc_problems(meta: dict) -> list[str]:
    problems = []
    versions, flags, seed = meta.get("versions"), meta.get("validation_flags"), meta.get("seed")
    if not isinstance(versions, dict) or not all(isinstance(v, str) for v in versions.values()):
        problems.append(f"versions: must map package names to version strings, got {versions!r}")
    if not isinstance(flags, dict) or not all(isinstance(v, bool) for v in flags.values()):
        problems.append(f"validation_flags: must map names to true/false, got {flags!r}")
    if not isinstance(seed, int) or isinstance(seed, bool):
        problems.append(f"seed: must be an integer, got {seed!r}")
    if not isinstance(meta.get("extra"), dict):
        problems.append(f"extra: must be an object, got {meta.get('extra')!r}")
    return problems


_NOTE_KEYS = (
    "symmetric",
    "contacts_from",
    "attempt",
    "attempts",
    "refinement",
    "validations",
    "errors",
    "picture",
    "run_config_hash",
)


def _note_problems(meta: dict) -> list[str]:
    """The typed Stage 1 notes: keys present (version 2), each of its type."""
    if meta.get("version") == 1:
        return []  # a version-1 record whose extra is no object: _misc_problems says so
    missing = [k for k in _NOTE_KEYS if k not in meta]
    if missing:
        return [f"{k}: missing (a version-2+ record stores it, null or empty when there is none)" for k in missing]
    problems = [
        f"{k}: must be {what}, got {meta[k]!r}"
        for k, what, ok in (
            ("symmetric", "true, false or null", meta["symmetric"] is None or isinstance(meta["symmetric"], bool)),
            ("contacts_from", "a hand name or null", meta["contacts_from"] is None or _text(meta["contacts_from"])),
            ("picture", "a path or null", meta["picture"] is None or _text(meta["picture"])),
            ("errors", "an object of messages", _mapping_of(meta["errors"], lambda m: isinstance(m, str))),
            (
                "run_config_hash",
                "16 hex digits or null",
                meta["run_config_hash"] is None or _hex16(meta["run_config_hash"]),
            ),
        )
        if not ok
    ]
    return problems + _attempt_problems(meta) + _refinement_problems(meta["refinement"]) + _verdict_problems(meta)


_KEYS = {
    "format", "version", *_TEXT_FIELDS, "joint_names", "steps", "contacts", "strategy", "grasp_stage", "quality",
    "validation_flags", "versions", "seed", "extra", *_NOTE_KEYS,
}  # fmt: skip
"""The scalars of a version-3 record (an older record's, once upgraded)."""


def _unknown_key_problems(meta: dict) -> list[str]:
    return [f"{k}: not a key of a version-{RECORD_VERSION} record" for k in sorted(set(meta) - _KEYS)]


def _attempt_problems(meta: dict) -> list[str]:
    attempts, attempt = meta["attempts"], meta["attempt"]
    fields = sorted(AttemptVerdict.__dataclass_fields__)
    if not isinstance(attempts, list) or not all(
        isinstance(a, dict)
        and sorted(a) == fields
        and all(_text(a[k]) for k in ("refinement", "validation", "robust"))
        and _score(a["robustness"])
        for a in attempts
    ):
        return [f"attempts: must be a list of {{{', '.join(fields)}}} verdicts, got {attempts!r}"]
    if attempt is not None and (not _index(attempt) or attempt >= len(attempts)):
        return [f"attempt: must be null or an index into the {len(attempts)} attempts, got {attempt!r}"]
    return []


def _refinement_problems(refinement: object) -> list[str]:
    if refinement is None:
        return []
    fields = sorted(RefinementInfo.__dataclass_fields__)
    if not isinstance(refinement, dict) or sorted(refinement) != fields:
        return [f"refinement: must be null or {{{', '.join(fields)}}}, got {refinement!r}"]
    problems = [
        f"refinement.{k}: must be a list of finger names, got {refinement[k]!r}"
        for k in ("frozen", "touching_fingers")
        if not isinstance(refinement[k], list) or not all(_text(f) for f in refinement[k])
    ]
    return problems + [
        f"refinement.{k}: must be a finite number >= 0, got {refinement[k]!r}"
        for k in ("object_shift", "object_turn_deg")
        if not _seconds(refinement[k])
    ]


def _verdict_problems(meta: dict) -> list[str]:
    verdicts = meta["validations"]
    fields = sorted(set(SimVerdict.__dataclass_fields__) - {"seconds", "robust_seconds"})
    if not isinstance(verdicts, dict):
        return [f"validations: must map simulators to verdicts, got {verdicts!r}"]
    problems = []
    for sim, v in verdicts.items():
        if not isinstance(v, dict) or sorted(v) != fields:
            problems.append(f"validations.{sim}: must be {{{', '.join(fields)}}}, got {v!r}")
        elif not (isinstance(v["success"], bool) and _text(v["reason"])):
            problems.append(f"validations.{sim}: success must be a bool and reason a string, got {v!r}")
        elif not _mapping_of(v["flags"], lambda f: isinstance(f, bool)):
            problems.append(f"validations.{sim}.flags: must map names to true/false, got {v['flags']!r}")
        else:
            problems += _trial_problems(sim, v)
    return problems


def _trial_problems(sim: str, verdict: dict) -> list[str]:
    """A verdict's perturbation trials and robustness score: a list of {name, reason, success}, the score their
    share held (null with no trials)."""
    trials, score = verdict["trials"], verdict["robustness"]
    if not isinstance(trials, list) or not all(
        isinstance(t, dict)
        and sorted(t) == ["name", "reason", "success"]
        and _text(t["name"])
        and _text(t["reason"])
        and isinstance(t["success"], bool)
        for t in trials
    ):
        return [f"validations.{sim}.trials: must be a list of {{name, reason, success}}, got {trials!r}"]
    if not trials:
        return [] if score is None else [f"validations.{sim}.robustness: {score!r} but no trial is stored (null)"]
    held = sum(t["success"] for t in trials) / len(trials)
    if not (_score(score) and score is not None and abs(score - held) < 1e-9):
        return [f"validations.{sim}.robustness: must be the share of trials held ({held:g}), got {score!r}"]
    return []


def _presence_problems(meta: dict, arrays: Mapping[str, np.ndarray]) -> list[str]:
    """What the step flags promise must be stored (and nothing claims a step that did not run)."""
    steps, problems = meta["steps"], []
    has_contacts, has_grasp = "contact_positions" in arrays, "wrist_pose" in arrays
    if (meta.get("contacts") is not None) != has_contacts:
        problems.append("contacts: the JSON header and the contact arrays must be stored together")
    elif has_contacts and meta["contacts"].get("object_id") not in ("", meta.get("object_id")):
        problems.append(f"contacts.object_id {meta['contacts'].get('object_id')!r} differs from the record's")
    if steps["contacts"]["ok"] and not has_contacts:
        problems.append("steps.contacts: ok but no contacts stored")
    if steps["retargeting"]["ok"] and not has_grasp:
        problems.append("steps.retargeting: ok but no grasp (wrist_pose, q) stored")
    problems += _grasp_stage_problems(meta.get("grasp_stage"), has_grasp, steps)
    if _attempted(steps["validation"]) and not (has_grasp and "pregrasp_wrist_pose" in arrays):
        problems.append("steps.validation: attempted but the grasp or the pre-grasp is missing")
    return problems + _robust_step_problems(steps["robust"], meta.get("validations"), meta.get("simulator"))


def _robust_step_problems(step: dict, verdicts: object, simulator: object) -> list[str]:
    """A robust step that ran must agree with the primary simulator's trials: ok = every trial held, a failure
    names a failed trial. The primary verdict is the record simulator's, else the first stored."""
    if not _attempted(step) or not isinstance(verdicts, dict):
        return []
    primary = verdicts.get(simulator) if simulator in verdicts else next(iter(verdicts.values()), None)
    trials = primary.get("trials") if isinstance(primary, dict) else None
    if not isinstance(trials, list) or not trials or not all(isinstance(t, dict) for t in trials):
        return ["steps.robust: ran, but the primary simulator's verdict stores no trials"]
    failed = [t.get("name") for t in trials if t.get("success") is not True]
    if step["ok"] and failed:
        return [f"steps.robust: ok, but the primary simulator's trials {failed} failed"]
    if not step["ok"] and step["reason"] not in failed:
        return [f"steps.robust: failed at {step['reason']!r}, which is not a failed trial of the primary simulator"]
    return []


def _grasp_stage_problems(stage: object, has_grasp: bool, steps: dict) -> list[str]:
    if has_grasp and stage not in _GRASP_STAGES:
        return [f"grasp_stage: {stage!r} must be one of {list(_GRASP_STAGES)} when a grasp is stored"]
    if not has_grasp and stage != "":
        return [f"grasp_stage: {stage!r} but no grasp is stored (expected '')"]
    if stage == "refinement" and not _attempted(steps["refinement"]):
        return ["grasp_stage: 'refinement' but the refinement step did not run"]
    return []


def _attempted(step: dict) -> bool:
    return step["ok"] or step["reason"] not in (SKIPPED, NOT_RUN)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _seconds(value: object) -> bool:
    """A finite number >= 0."""
    return _is_number(value) and math.isfinite(value) and value >= 0


def _score(value: object) -> bool:
    """A fraction in [0, 1], or None."""
    return value is None or (_is_number(value) and 0.0 <= value <= 1.0)


def _index(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _hex16(value: object) -> bool:
    return isinstance(value, str) and len(value) == 16 and all(c in "0123456789abcdef" for c in value)


def _text(value: object) -> bool:
    return isinstance(value, str) and bool(value)


def _mapping_of(value: object, check) -> bool:
    """A dict with string keys whose every value passes ``check``."""
    return isinstance(value, dict) and all(isinstance(k, str) and check(v) for k, v in value.items())
