"""One dataset record: everything Stage 1 produced for one object and one hand.

A :class:`GraspRecord` is self-describing: it carries the hand's joint names beside every joint
vector, the simulator's name and the software versions, so a later stage reads it without
building the hand or the simulator that produced it.

Frames and units: every position, normal, direction and pose is in the **object frame** (the
object's resting frame: z up, table plane z = 0), metres; poses are (7,) position + unit
quaternion w, x, y, z; joint angles radians (metres for prismatic joints); times seconds.

Times are not stored in the record file (the same run gives byte-identical files): the dataset keeps them
beside it (:mod:`ges_core.dataset.timing`). A record read without them has ``None`` for every
``seconds`` and ``{}`` for ``setup_seconds``.
"""

from __future__ import annotations

import io
import json
import platform
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ges_core.contact import ContactSet
from ges_core.dataset.record_v1 import timing_v1
from ges_core.dataset.record_v2 import upgraded

__all__ = [
    "HELD_NO_BETTER",
    "NOT_RUN",
    "RECORD_FORMAT",
    "RECORD_VERSION",
    "SKIPPED",
    "STEPS",
    "TOTAL_STEPS",
    "AttemptVerdict",
    "GraspRecord",
    "HandPose",
    "Quality",
    "RefinementInfo",
    "SimVerdict",
    "StepOutcome",
    "TrialVerdict",
    "record_from_bytes",
    "record_from_raw",
    "raw_to_bytes",
    "read_raw",
    "record_to_bytes",
    "record_to_raw",
    "software_versions",
]

RECORD_FORMAT = "ges.grasp_record"
RECORD_VERSION = 3
"""Version 3: robust validation, a fifth step ``robust`` and, per simulator, the perturbation trials' verdicts and
the robustness score (``SimVerdict.trials``, ``.robustness``); each attempt's ``robust`` verdict. Version 2: the
Stage 1 notes are typed fields (``validations``, ``attempts``, ``refinement``, ``errors``, ...), the times live
beside the record (:mod:`ges_core.dataset.timing`) and ``run_config_hash`` names the settings it was made with;
version 1 kept the notes in the free-form ``extra`` and the times inside. Both are still read
(:mod:`ges_core.dataset.record_v1`, :mod:`ges_core.dataset.record_v2`)."""

STEPS: tuple[str, ...] = ("contacts", "retargeting", "refinement", "validation", "robust")
"""The Stage 1 steps, in pipeline order; every record holds one :class:`StepOutcome` per step. ``validation`` is
the paper's single nominal trial; ``robust`` the perturbation trials of a grasp that passed it."""

TOTAL_STEPS: tuple[str, ...] = ("contacts", "retargeting", "refinement", "validation")
"""The steps whose times make up "total time" everywhere (:attr:`GraspRecord.total_seconds`, ``ges dataset info``,
the run table): the paper's pipeline up to its single validation trial. The robust trials are counted apart."""

SKIPPED = "skipped"
"""Reason of a step that was not attempted because an earlier step failed."""
NOT_RUN = "not_run"
"""Reason of a step that the run configuration switched off (e.g. no physics validation)."""
HELD_NO_BETTER = "held no better"
"""How ``extra["other_strategy"]["reason"]`` begins when the Stage 1 pipeline's second strategy passed but was not
kept (its chosen placement held no better than the first strategy's; docs/synthesis/pipeline.md)."""
NONE_LOWER = "none lower"
"""Why ``extra["low_raise"]`` was not kept when no contact lies between the run's raise and the lower one (the lower
raise would aim every fingertip where the first pass did): its reason is ``contacts: none lower``."""
SAME_CONTACTS = "same contacts"
"""Why ``extra["balanced_thumb"]`` was not kept when the balanced thumb's contacts are the first contacts (the torque
rule moved no contact), so there was nothing to retarget: its reason is ``contacts: same contacts``."""

JSON_KEY = "record_json"
"""Name of the npz entry holding the record's scalars as JSON text (a 0-d unicode array)."""


@dataclass(frozen=True, kw_only=True)
class StepOutcome:
    """Outcome of one pipeline step for one record."""

    ok: bool
    """True when the step succeeded."""
    reason: str = ""
    """'' when ok; otherwise a short failure code, or SKIPPED / NOT_RUN when not attempted."""
    seconds: float | None = 0.0
    """Wall time the step took, seconds (0 when not attempted; None: unknown, the record's timing file is missing)."""

    @property
    def attempted(self) -> bool:
        """Whether the step ran at all (success rates count only attempted steps)."""
        return self.ok or self.reason not in (SKIPPED, NOT_RUN)

    @classmethod
    def failed(cls, reason: str, seconds: float | None = 0.0) -> StepOutcome:
        """A failed step with its reason code."""
        return cls(ok=False, reason=reason, seconds=seconds)

    @classmethod
    def skipped(cls) -> StepOutcome:
        """A step not attempted because an earlier one failed."""
        return cls(ok=False, reason=SKIPPED)


@dataclass(frozen=True)
class HandPose:
    """A hand configuration: base-link pose and joint angles (order: the record's ``joint_names``)."""

    wrist_pose: np.ndarray
    """(7,) float64 pose of the hand's base link, object frame, metres + quaternion wxyz."""
    q: np.ndarray
    """(K,) float64 joint angles, radians, in the record's ``joint_names`` order."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "wrist_pose", np.asarray(self.wrist_pose, dtype=np.float64))
        object.__setattr__(self, "q", np.asarray(self.q, dtype=np.float64))


@dataclass(frozen=True, kw_only=True)
class Quality:
    """Quality figures of a record; None where the step that measures it did not produce one."""

    force_closure: float | None = None
    """Ferrari-Canny epsilon of the contacts (0 = no force closure), unit-wrench scale."""
    retarget_residual: float | None = None
    """Mean distance between the retargeted fingertips and their targets, metres."""
    max_penetration: float | None = None
    """Deepest hand-object penetration after refinement, metres (>= 0)."""
    table_contact: bool | None = None
    """Whether any hand link touches the table after refinement."""


@dataclass(frozen=True, kw_only=True)
class TrialVerdict:
    """One perturbation trial of robust validation (:mod:`ges_core.synthesis.physics.robust`)."""

    name: str
    """The perturbation: 'limits', 'mass_x0.5', 'friction_0.5', 'pose_1', ..."""
    success: bool
    reason: str
    """'success' or why not, as :attr:`SimVerdict.reason`."""


@dataclass(frozen=True, kw_only=True)
class SimVerdict:
    """One simulator's physics validation (lift and hold) of the record's grasp: the nominal (paper's) trial,
    and the perturbation trials when they ran."""

    success: bool
    """The nominal trial held (the paper's single-trial verdict)."""
    reason: str
    """'success' or why not: 'no_contact', 'palm_only', 'dropped', 'not_lifted', 'unstable'."""
    flags: Mapping[str, bool] = field(default_factory=dict)
    """Per-phase flags, e.g. reached_grasp, fingertips_touching, lifted, held ({} when the simulator failed)."""
    seconds: float | None = 0.0
    """Wall time of the nominal validation in this simulator, seconds (None: unknown)."""
    trials: tuple[TrialVerdict, ...] = ()
    """The perturbation trials, in order; () when robust validation did not run (off, or the nominal failed)."""
    robustness: float | None = None
    """Fraction of ``trials`` held, in [0, 1]; None when robust validation did not run."""
    robust_seconds: float | None = 0.0
    """Wall time of the perturbation trials, seconds (0 when none ran; None: unknown)."""

    def __post_init__(self) -> None:
        trials = tuple(t if isinstance(t, TrialVerdict) else TrialVerdict(**t) for t in self.trials)
        object.__setattr__(self, "trials", trials)

    @property
    def robust(self) -> bool:
        """The nominal trial and every perturbation trial held (False when the trials did not run)."""
        return self.success and self.robustness is not None and all(t.success for t in self.trials)


@dataclass(frozen=True, kw_only=True)
class AttemptVerdict:
    """The verdicts of one wrist placement tried (``SynthesisConfig.attempts``), best placement first."""

    refinement: str
    """'ok' or the refinement step's failure reason."""
    validation: str
    """'ok', the primary simulator's failure reason, 'skipped' (refinement failed) or 'not_run'."""
    robust: str = NOT_RUN
    """'ok', the primary simulator's first failed perturbation, 'skipped' (validation failed) or 'not_run'."""
    robustness: float | None = None
    """The primary simulator's robustness score of this attempt, or None when its trials did not run, or stopped at
    the failed one ``robust`` names because a later placement held everywhere (``robust.defer_trials``)."""


@dataclass(frozen=True, kw_only=True)
class RefinementInfo:
    """What collision-aware refinement measured at the end of the chosen attempt."""

    frozen: tuple[str, ...]
    """Fingers whose targets were frozen on contact."""
    touching_fingers: tuple[str, ...]
    """Fingers whose tips touch the object at the end (frozen, or touching when it stopped)."""
    object_shift: float
    """How far the object moved while the hand closed, metres."""
    object_turn_deg: float
    """How far it turned meanwhile, degrees."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "frozen", tuple(self.frozen))
        object.__setattr__(self, "touching_fingers", tuple(self.touching_fingers))


@dataclass(frozen=True, kw_only=True)
class GraspRecord:
    """Everything Stage 1 produced for one (object, hand) pair; see ``docs/dataset.md``."""

    object_id: str
    category: str
    split: str
    """'train', 'unseen_object' or 'unseen_category' (the object library's split)."""
    hand: str
    simulator: str
    joint_names: tuple[str, ...]
    """(K,) names of the hand's joints: the order of every ``q`` in this record."""
    steps: Mapping[str, StepOutcome]
    """One outcome per name in :data:`STEPS`."""
    contacts: ContactSet | None = None
    """Five contacts (thumb..little), object frame; None when contact generation produced none."""
    strategy: str | None = None
    """'horizontal' or 'vertical' (the contact step's grasp strategy)."""
    approach: np.ndarray | None = None
    """(3,) unit direction the hand moves toward the object, object frame."""
    grasp: HandPose | None = None
    """The final grasp: the refined pose when refinement ran, else the retargeted one."""
    grasp_stage: str = ""
    """Which step produced ``grasp``: 'retargeting', 'refinement' or '' (no grasp)."""
    pregrasp: HandPose | None = None
    """The pre-grasp: 0.02 m back along ``approach``, intermediate joints opened."""
    quality: Quality = field(default_factory=Quality)
    validation_flags: Mapping[str, bool] = field(default_factory=dict)
    """Physics validation details, e.g. reached_grasp, fingertips_touching, lifted, held."""
    versions: Mapping[str, str] = field(default_factory=dict)
    """Software versions (see :func:`software_versions`)."""
    seed: int = 0
    run_config_hash: str | None = None
    """The run config the record was made with: 16 hex digits of the SHA-256 of its JSON
    (:func:`ges_core.dataset.layout.config_hash`); the dataset writer fills it. None: unknown (version 1)."""
    symmetric: bool | None = None
    """Whether contact generation found the object rotationally symmetric about z (None: no contacts generated)."""
    contacts_from: str | None = None
    """The hand whose stored record supplied the contacts (cross-hand retargeting), or None."""
    attempt: int | None = None
    """Index in ``attempts`` of the placement that passed refinement and validation; None when none passed."""
    attempts: tuple[AttemptVerdict, ...] = ()
    """Every wrist placement tried, in order."""
    refinement: RefinementInfo | None = None
    """Refinement's measurements of the chosen attempt; None when refinement produced no grasp."""
    validations: Mapping[str, SimVerdict] = field(default_factory=dict)
    """Per validating simulator, its verdict on the chosen attempt (the primary one is the validation step)."""
    errors: Mapping[str, str] = field(default_factory=dict)
    """Error message per failed step: 'contacts', 'retargeting', 'refinement' or 'validation_<simulator>'."""
    setup_seconds: Mapping[str, float] = field(default_factory=dict)
    """Per simulator, the one-time build + hand load for this record (not in the step times), seconds ({}:
    unknown)."""
    picture: str | None = None
    """Path of the record's picture (POSIX), when pictures were drawn."""
    extra: Mapping[str, Any] = field(default_factory=dict)
    """Free-form JSON-ready notes: the Stage 1 pipeline's second passes (``other_strategy``, ``balanced_thumb``,
    ``low_raise``: where each pass's tries begin in ``attempts``, whether it was kept and why not) and
    ``unreached_best_fit`` (per pass whose best fit missed its contacts and was left out for the placements that
    reached: where that pass's tries begin and the fit's residual, m); other writers' notes; a version-1 record's
    ``extra`` keys that have no typed field."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "joint_names", tuple(self.joint_names))
        object.__setattr__(self, "attempts", tuple(self.attempts))
        if self.approach is not None:
            object.__setattr__(self, "approach", np.asarray(self.approach, dtype=np.float64))

    @property
    def key(self) -> tuple[str, str]:
        """(object_id, hand): the identity of a record inside a dataset."""
        return (self.object_id, self.hand)

    @property
    def failed_step(self) -> str | None:
        """The first step that was attempted and failed, or None."""
        return next((s for s in STEPS if self.steps[s].attempted and not self.steps[s].ok), None)

    @property
    def success(self) -> bool:
        """Every step succeeded (a step switched off by the run config, NOT_RUN, does not count)."""
        return all(self.steps[s].ok or self.steps[s].reason == NOT_RUN for s in STEPS)

    @property
    def robust(self) -> bool:
        """The grasp passed robust validation (every perturbation held in the primary simulator)."""
        return self.steps["robust"].ok

    @property
    def robustness(self) -> float | None:
        """The primary simulator's robustness score (fraction of trials held), or None when none ran."""
        verdict = self.validations.get(self.simulator) or next(iter(self.validations.values()), None)
        return None if verdict is None else verdict.robustness

    @property
    def total_seconds(self) -> float | None:
        """Sum of the :data:`TOTAL_STEPS` times (the robust trials not included), seconds; None when one is unknown."""
        times = [self.steps[s].seconds for s in TOTAL_STEPS]
        return None if None in times else float(sum(times))


def software_versions(*packages: str) -> dict[str, str]:
    """Versions of GES-UniGrasp, Python, numpy, torch, pytorch-kinematics and ``packages`` (e.g. the
    simulator's engine: ``software_versions("sapien")``); 'missing' for packages not installed."""
    from importlib import metadata

    import ges_core

    out = {"ges": ges_core.__version__, "python": platform.python_version()}
    for name in ("numpy", "torch", "pytorch-kinematics", *packages):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "missing"
    return out


def record_to_raw(record: GraspRecord) -> tuple[dict, dict[str, np.ndarray]]:
    """The record as (JSON-ready scalars, named float64 arrays): the on-disk layout, times left out."""
    arrays: dict[str, np.ndarray] = {}
    contacts = None
    if record.contacts is not None:
        contacts = {k: v for k, v in record.contacts.to_dict().items() if k not in ("positions", "normals")}
        arrays["contact_positions"] = record.contacts.positions
        arrays["contact_normals"] = record.contacts.normals
    if record.approach is not None:
        arrays["approach"] = record.approach
    for prefix, pose in (("", record.grasp), ("pregrasp_", record.pregrasp)):
        if pose is not None:
            arrays[f"{prefix}wrist_pose"], arrays[f"{prefix}q"] = pose.wrist_pose, pose.q
    meta = {
        "format": RECORD_FORMAT,
        "version": RECORD_VERSION,
        **{k: getattr(record, k) for k in ("object_id", "category", "split", "hand", "simulator")},
        "joint_names": list(record.joint_names),
        "steps": {name: _step_to_dict(record.steps[name]) for name in record.steps},
        "contacts": contacts,
        "strategy": record.strategy,
        "grasp_stage": record.grasp_stage,
        "quality": _quality_to_dict(record.quality),
        "validation_flags": dict(record.validation_flags),
        "versions": dict(record.versions),
        "seed": record.seed,
        "run_config_hash": record.run_config_hash,
        **_notes_to_raw(record),
        "extra": dict(record.extra),
    }
    return _plain(meta), arrays


def _notes_to_raw(record: GraspRecord) -> dict:
    """The Stage 1 notes of ``record`` as JSON-ready values (keys as the field names)."""
    return {
        "symmetric": record.symmetric,
        "contacts_from": record.contacts_from,
        "attempt": record.attempt,
        "attempts": [asdict(a) for a in record.attempts],
        "refinement": None if record.refinement is None else asdict(record.refinement),
        "validations": {sim: _verdict_to_dict(v) for sim, v in record.validations.items()},
        "errors": dict(record.errors),
        "picture": record.picture,
    }


def _verdict_to_dict(verdict: SimVerdict) -> dict:
    return {
        "success": verdict.success,
        "reason": verdict.reason,
        "flags": dict(verdict.flags),
        "trials": [asdict(t) for t in verdict.trials],
        "robustness": verdict.robustness,
    }


def _plain(value: Any) -> Any:
    """``value`` with numpy scalars turned into Python ones (JSON cannot hold np.float32 or np.bool_)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value.item() if isinstance(value, np.generic) else value


def _step_to_dict(step: StepOutcome) -> dict:
    return {"ok": step.ok, "reason": step.reason}


def _quality_to_dict(quality: Quality) -> dict:
    return {k: getattr(quality, k) for k in Quality.__dataclass_fields__}


def record_from_raw(meta: dict, arrays: Mapping[str, np.ndarray]) -> GraspRecord:
    """Inverse of :func:`record_to_raw` (no checks beyond what the types need; see ``validate``).

    Times unknown (None) but for a version-1 record, which held them. Older versions are read through
    :func:`ges_core.dataset.record_v2.upgraded` first.
    """
    timing = timing_v1(meta)
    meta = upgraded(meta)
    steps = timing.get("steps", {})
    contacts = None
    if meta.get("contacts") is not None:
        data = dict(meta["contacts"], positions=arrays["contact_positions"], normals=arrays["contact_normals"])
        contacts = ContactSet.from_dict(data)
    return GraspRecord(
        **{k: meta[k] for k in ("object_id", "category", "split", "hand", "simulator", "strategy", "seed")},
        joint_names=tuple(meta["joint_names"]),
        steps={name: StepOutcome(**step, seconds=steps.get(name)) for name, step in meta["steps"].items()},
        contacts=contacts,
        approach=arrays.get("approach"),
        grasp=_pose(arrays, ""),
        grasp_stage=meta.get("grasp_stage", ""),
        pregrasp=_pose(arrays, "pregrasp_"),
        quality=Quality(**meta.get("quality", {})),
        validation_flags=meta.get("validation_flags", {}),
        versions=meta.get("versions", {}),
        run_config_hash=meta.get("run_config_hash"),
        **_notes_from_raw(meta, timing),
        extra=meta.get("extra", {}),
    )


def _notes_from_raw(meta: dict, timing: dict) -> dict:
    """The typed Stage 1 notes of a version-2 record's scalars (absent keys: the fields' defaults)."""
    refinement, seconds, robust = meta.get("refinement"), timing.get("validations", {}), timing.get("robust", {})
    return {
        "symmetric": meta.get("symmetric"),
        "contacts_from": meta.get("contacts_from"),
        "attempt": meta.get("attempt"),
        "attempts": tuple(AttemptVerdict(**a) for a in meta.get("attempts", ())),
        "refinement": None if refinement is None else RefinementInfo(**refinement),
        "validations": {
            sim: SimVerdict(**v, seconds=seconds.get(sim), robust_seconds=robust.get(sim) if v["trials"] else 0.0)
            for sim, v in meta.get("validations", {}).items()
        },
        "errors": meta.get("errors", {}),
        "setup_seconds": timing.get("setup_seconds", {}),
        "picture": meta.get("picture"),
    }


def _pose(arrays: Mapping[str, np.ndarray], prefix: str) -> HandPose | None:
    if f"{prefix}wrist_pose" not in arrays:
        return None
    return HandPose(arrays[f"{prefix}wrist_pose"], arrays[f"{prefix}q"])


def record_to_bytes(record: GraspRecord) -> bytes:
    """The record as the bytes of one ``.npz`` file: its arrays plus the scalars as JSON text."""
    return raw_to_bytes(*record_to_raw(record))


def raw_to_bytes(meta: dict, arrays: Mapping[str, np.ndarray]) -> bytes:
    """The bytes of one ``.npz`` file holding ``arrays`` and ``meta`` as JSON text under JSON_KEY."""
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays, **{JSON_KEY: np.array(json.dumps(meta, sort_keys=True))})
    return buf.getvalue()


def read_raw(data: bytes) -> tuple[dict, dict[str, np.ndarray]]:
    """(scalars, arrays) of an ``.npz`` record; raises ValueError/OSError/KeyError on a damaged file."""
    if not data.startswith(b"PK"):
        # np.load reads any other bytes as a pickle and then says "contains pickled (object) data", which
        # sends a user looking for pickles in a file that is simply not a record.
        raise ValueError("not an .npz archive (the file does not start with a zip header)")
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        arrays = {name: npz[name] for name in npz.files}  # reading every member checks its CRC
    meta = json.loads(str(arrays.pop(JSON_KEY)))
    if not isinstance(meta, dict):
        raise ValueError(f"{JSON_KEY} holds a {type(meta).__name__}, not an object")
    return meta, arrays


def record_from_bytes(data: bytes) -> GraspRecord:
    """Inverse of :func:`record_to_bytes`."""
    return record_from_raw(*read_raw(data))
