"""Pipeline bookkeeping: one object's contact step, what steps 2-5 gave one (object, hand) pair, and its record."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ges_core.dataset import AttemptVerdict, GraspRecord, HandPose, Quality, RefinementInfo, SimVerdict, StepOutcome
from ges_core.synthesis.retarget.search import ObjectCloud
from ges_core.synthesis.types import ContactResult, Grasp, RefinedGrasp

__all__ = ["ObjectWork", "PairResult", "build_record", "contacts_from_record"]


@dataclass(frozen=True)
class ObjectWork:
    """One object of a task after the contact step (shared by every hand)."""

    object_id: str
    category: str
    split: str
    seed: int
    """The object's seed (from the run seed and the object id)."""
    step: StepOutcome = field(default_factory=StepOutcome.skipped)
    """Outcome of the contact step."""
    result: ContactResult | None = None
    """The contacts, strategy, approach and epsilon; None when the step failed."""
    symmetric: bool | None = None
    """Contact generation's symmetry verdict (None: no contacts generated here)."""
    contacts_from: str | None = None
    """The hand whose stored record gave the contacts (cross-hand retargeting), or None."""
    error: str | None = None
    """The contact step's error message, or None."""
    cloud: ObjectCloud | None = None
    """The object's surface samples (retargeting keeps the hand's body out of them); None if unavailable."""

    def failed_contacts(self, reason: str, message: str, seconds: float) -> ObjectWork:
        """This object with a failed contact step."""
        return replace(self, step=StepOutcome.failed(reason, seconds), error=message)

    def with_contacts(self, result: ContactResult, seconds: float, cloud: ObjectCloud | None = None) -> ObjectWork:
        """This object with its contacts (``seconds``: point cloud + contact generation) and its cloud."""
        return replace(
            self, step=StepOutcome(ok=True, seconds=seconds), result=result, symmetric=result.symmetric, cloud=cloud
        )


def contacts_from_record(work: ObjectWork, record: GraspRecord) -> ObjectWork:
    """The contact step taken from a stored record (cross-hand retargeting: no new contact generation).

    The step keeps the stored outcome (its time is the original generation's); ``contacts_from`` names the
    record's hand.
    """
    step = record.steps["contacts"]
    if record.contacts is None or not step.ok:
        return replace(work, step=step, contacts_from=record.hand)
    result = ContactResult(
        contacts=record.contacts,
        strategy=record.strategy or "horizontal",
        approach=np.asarray(record.approach, dtype=np.float64),
        quality=float(record.quality.force_closure or 0.0),
    )
    return replace(work, step=step, result=result, contacts_from=record.hand)


@dataclass(frozen=True)
class PairResult:
    """What retargeting, refinement, the pre-grasp and validation gave one (object, hand) pair."""

    steps: dict[str, StepOutcome]
    """Outcome of every step (the contact step's included)."""
    grasp: Grasp | None = None
    """The final grasp: refined, else retargeted; None when retargeting gave none."""
    stage: str = ""
    """The step that produced ``grasp``."""
    pre: Grasp | None = None
    refined: RefinedGrasp | None = None
    """Refinement's output of the chosen attempt, or None."""
    attempt: int | None = None
    """Index of the attempt that passed refinement and validation, or None."""
    attempts: tuple[AttemptVerdict, ...] = ()
    validations: dict[str, SimVerdict] = field(default_factory=dict)
    """The chosen attempt's verdict per validating simulator."""
    errors: dict[str, str] = field(default_factory=dict)
    """Error message per failed step (retargeting, refinement, validation_<sim>)."""
    setup_seconds: dict[str, float] = field(default_factory=dict)
    """Per simulator built for this pair, its build + hand load, seconds."""
    merit: tuple[int, float] = (0, 0.0)
    """The chosen attempt's merit (``ges_core.synthesis.run.worker._Attempt.merit``; greater held better), which
    compares the two strategies' passes of one pair; (0, 0.0) when no attempt ran."""
    unreached_best: tuple[dict, ...] = ()
    """Per pass whose best fit was left out because it missed its contacts while later placements reached them
    (``ges_core.synthesis.run.worker._reaching``): ``{"before_attempt": index in attempts where the pass's tries
    begin, "residual": the best fit's mean fingertip-to-aim distance, m}``; the record keeps them in
    ``extra["unreached_best_fit"]``."""


def build_record(state, hand: str, work: ObjectWork, pair: PairResult) -> GraspRecord:
    """The dataset record of ``(work.object_id, hand)`` from the steps' outputs."""
    cfg, result, grasp = state.context.config, work.result, pair.grasp
    primary = pair.validations.get(cfg.primary_sim)
    return GraspRecord(
        object_id=work.object_id,
        category=work.category,
        split=work.split,
        hand=hand,
        simulator=cfg.refine_sim,
        joint_names=state.hand(hand).description.joint_names,
        steps=pair.steps,
        contacts=None if result is None else result.contacts,
        strategy=None if result is None else result.strategy,
        approach=None if result is None else result.approach,
        grasp=None if grasp is None else HandPose(grasp.wrist_pose, grasp.q),
        grasp_stage=pair.stage if grasp is not None else "",
        pregrasp=None if pair.pre is None else HandPose(pair.pre.wrist_pose, pair.pre.q),
        quality=_quality(result, grasp, pair.refined),
        validation_flags={} if primary is None else dict(primary.flags),
        versions=state.versions,
        seed=work.seed,
        symmetric=work.symmetric,
        contacts_from=work.contacts_from,
        attempt=pair.attempt,
        attempts=pair.attempts,
        refinement=_refinement_info(pair.refined),
        validations=pair.validations,
        errors={"contacts": work.error, **pair.errors} if work.error is not None else pair.errors,
        setup_seconds=pair.setup_seconds,
    )


def _quality(result: ContactResult | None, grasp: Grasp | None, refined: RefinedGrasp | None) -> Quality:
    return Quality(
        force_closure=None if result is None else float(result.quality),
        retarget_residual=_residual(grasp),
        max_penetration=None if refined is None else float(refined.max_penetration),
        table_contact=None if refined is None else bool(refined.table_contact),
    )


def _refinement_info(refined: RefinedGrasp | None) -> RefinementInfo | None:
    """Refinement's measurements (see :func:`ges_core.synthesis.physics.refine.refine_grasp`), or None."""
    if refined is None:
        return None
    meta = refined.grasp.meta
    return RefinementInfo(
        frozen=refined.frozen,
        touching_fingers=tuple(meta.get("touching_fingers", ())),
        object_shift=float(meta["object_shift"]),
        object_turn_deg=float(meta["object_turn_deg"]),
    )


def _residual(grasp: Grasp | None) -> float | None:
    if grasp is None or "residual" not in grasp.meta:
        return None
    return float(grasp.meta["residual"])
