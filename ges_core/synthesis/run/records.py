"""Pipeline bookkeeping: one object's contact step, and the dataset record of one (object, hand) pair."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ges_core.dataset import GraspRecord, HandPose, Quality, StepOutcome
from ges_core.synthesis.retarget.search import ObjectCloud
from ges_core.synthesis.types import ContactResult, Grasp, RefinedGrasp

__all__ = ["ObjectWork", "build_record", "contacts_from_record"]


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
    extra: dict = field(default_factory=dict)
    """JSON-ready notes copied into every record of this object."""
    cloud: ObjectCloud | None = None
    """The object's surface samples (retargeting keeps the hand's body out of them); None if unavailable."""

    def failed_contacts(self, reason: str, message: str, seconds: float) -> ObjectWork:
        """This object with a failed contact step."""
        return replace(self, step=StepOutcome.failed(reason, seconds), extra={"errors": {"contacts": message}})

    def with_contacts(self, result: ContactResult, seconds: float, cloud: ObjectCloud | None = None) -> ObjectWork:
        """This object with its contacts (``seconds``: point cloud + contact generation) and its cloud."""
        return replace(
            self,
            step=StepOutcome(ok=True, seconds=seconds),
            result=result,
            extra={"symmetric": result.symmetric},
            cloud=cloud,
        )


def contacts_from_record(work: ObjectWork, record: GraspRecord) -> ObjectWork:
    """The contact step taken from a stored record (cross-hand retargeting: no new contact generation).

    The step keeps the stored outcome (its time is the original generation's); ``extra["contacts_from"]``
    names the record's hand.
    """
    extra = {"contacts_from": record.hand}
    step = record.steps["contacts"]
    if record.contacts is None or not step.ok:
        return replace(work, step=step, extra=extra)
    result = ContactResult(
        contacts=record.contacts,
        strategy=record.strategy or "horizontal",
        approach=np.asarray(record.approach, dtype=np.float64),
        quality=float(record.quality.force_closure or 0.0),
    )
    return replace(work, step=step, result=result, extra=extra)


def build_record(
    state,
    hand: str,
    work: ObjectWork,
    steps: dict[str, StepOutcome],
    extra: dict,
    *,
    grasp: Grasp | None = None,
    stage: str = "",
    pre: Grasp | None = None,
    refined: RefinedGrasp | None = None,
) -> GraspRecord:
    """The dataset record of ``(work.object_id, hand)`` from the steps' outputs."""
    cfg, result = state.context.config, work.result
    quality = Quality(
        force_closure=None if result is None else float(result.quality),
        retarget_residual=_residual(grasp),
        max_penetration=None if refined is None else float(refined.max_penetration),
        table_contact=None if refined is None else bool(refined.table_contact),
    )
    flags = extra.get("validations", {}).get(cfg.primary_sim, {}).get("flags", {})
    return GraspRecord(
        object_id=work.object_id,
        category=work.category,
        split=work.split,
        hand=hand,
        simulator=cfg.refine_sim,
        joint_names=state.hand(hand).description.joint_names,
        steps=steps,
        contacts=None if result is None else result.contacts,
        strategy=None if result is None else result.strategy,
        approach=None if result is None else result.approach,
        grasp=None if grasp is None else HandPose(grasp.wrist_pose, grasp.q),
        grasp_stage=stage if grasp is not None else "",
        pregrasp=None if pre is None else HandPose(pre.wrist_pose, pre.q),
        quality=quality,
        validation_flags={k: bool(v) for k, v in flags.items()},
        versions=state.versions,
        seed=work.seed,
        extra=extra,
    )


def _residual(grasp: Grasp | None) -> float | None:
    if grasp is None or "residual" not in grasp.meta:
        return None
    return float(grasp.meta["residual"])
