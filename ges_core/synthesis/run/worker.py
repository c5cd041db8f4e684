"""One pipeline task (a chunk of objects) in one process: the Stage 1 steps, in order, per object and hand.

Used by :func:`ges_core.synthesis.run.pipeline.run_synthesis`, in the parent (``workers=1``) or in spawned
worker processes. Hands, retargeters and the object library are built once per process; a simulator
backend once per physics trial (:class:`ges_core.synthesis.physics.scene.TrialScenes`): each refinement, each
nominal validation and each perturbation trial gets a new one with the hand loaded.

Why not once per task, or once per object: a SAPIEN scene reused across objects gives an object a result that
depends on the objects before it (measured: ``procedural/can/001`` after ``pybullet/random_urdfs/002`` ended
15-24 mm of wrist position away from the same grasp refined first, though every input was equal, even
with PhysX's enhanced determinism on and one step with the hand far from everything before each new
object), so a record depended on which objects shared its chunk; and one reused across one object's trials
made a placement's verdict depend on the trials before it (``benchmarks/trial_history.py``). A fresh scene with
the hand costs about 20-40 ms (summed per simulator in the record's ``setup_seconds``).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

from ges_core.dataset import (
    HELD_NO_BETTER,
    NONE_LOWER,
    NOT_RUN,
    SAME_CONTACTS,
    AttemptVerdict,
    GraspRecord,
    SimVerdict,
    StepOutcome,
    TrialVerdict,
    software_versions,
)
from ges_core.errors import ArrayError, AssetError, SimulationError, StorageError, SynthesisError
from ges_core.synthesis.contacts.generate import LIBRARY_CENTER_OF_MASS, ContactConfig, generate_contacts
from ges_core.synthesis.contacts.lift_friction import lift_friction_bound
from ges_core.synthesis.physics.pregrasp import pregrasp
from ges_core.synthesis.physics.refine import UNSTABLE_REST, check_rest, refine_grasp, refine_verdict
from ges_core.synthesis.physics.robust import (
    Perturbation,
    friction_trial_name,
    perturbations,
    run_trial,
    trial_limits,
)
from ges_core.synthesis.physics.scene import TrialScenes
from ges_core.synthesis.physics.validate import validate_grasp
from ges_core.synthesis.retarget.retargeter import GraspRetargeter, raise_contacts
from ges_core.synthesis.retarget.search import ObjectCloud
from ges_core.synthesis.run.config import SynthesisConfig
from ges_core.synthesis.run.records import ObjectWork, PairResult, build_record, contacts_from_record
from ges_core.synthesis.run.tasks import RunContext, Task, object_seed
from ges_core.synthesis.types import Grasp, RefinedGrasp, Strategy, other_strategy

__all__ = ["run_task"]

_STATES: dict[int, _State] = {}
"""Per-process cache: the run context (one per run) -> built hands, retargeters and library."""
_LOG = logging.getLogger(__name__)


def run_task(task: Task, context: RunContext) -> list[GraspRecord]:
    """Records of every (object, hand) pair of ``task``, object order then hand order."""
    state = _state(context)
    works = _all_contacts(state, task)
    sims = _Sims(state)
    records: dict[tuple[str, str], GraspRecord] = {}
    try:
        for hand in _hands_in_order(task):
            key = _contact_key(state, hand)
            todo = [works[(oid, key)] for oid, hands in task.pairs if hand in hands]
            for work, result in zip(todo, _retarget(state, hand, todo), strict=True):
                records[(work.object_id, hand)] = _finish(state, sims, hand, work, result)
                sims.reset()  # setup times and rest checks are per object
    finally:
        sims.reset()
    return [_with_picture(state, records[(oid, h)]) for oid, hands in task.pairs for h in hands]


@dataclass
class _State:
    """What a process builds once per run context."""

    context: RunContext
    registry: object
    library: object
    hands: dict = field(default_factory=dict)
    configs: dict = field(default_factory=dict)
    retargeters: dict = field(default_factory=dict)
    renderer: object | None = None
    source: object | None = None
    versions: dict = field(default_factory=dict)
    picture_failed: bool = False
    """Whether a picture could not be written (reported once per process)."""

    def hand(self, name: str):
        if name not in self.hands:
            self.hands[name] = self.registry.build_hand(name)
        return self.hands[name]

    def config(self, name: str) -> SynthesisConfig:
        """The settings of hand ``name``'s steps: the run's, the hand's YAML ``settings`` and the run's
        ``hand_settings[name]``, in that order (:meth:`SynthesisConfig.for_hand`)."""
        if name not in self.configs:
            self.configs[name] = self.context.config.for_hand(name, self.hand(name).description.settings)
        return self.configs[name]

    def retargeter(self, name: str, *, low_raise: bool = False) -> GraspRetargeter:
        """Hand ``name``'s retargeter; ``low_raise``: the one whose raise is ``retarget.low_raise_height`` (the same
        kinematics)."""
        key = (name, low_raise)
        if key not in self.retargeters:
            cfg = self.config(name)
            settings, kinematics = cfg.retarget, None
            if low_raise:
                settings = settings.model_copy(update={"min_contact_height": settings.low_raise_height})
                kinematics = self.retargeter(name).kinematics
            self.retargeters[key] = GraspRetargeter(
                self.hand(name), settings, kinematics=kinematics, thumb_keep=cfg.thumb_keep
            )
        return self.retargeters[key]


def _state(context: RunContext) -> _State:
    key = hash((context.config.model_dump_json(), context.registry, context.pictures, context.source, context.run_id))
    if key not in _STATES:
        cfg = context.config
        state = _State(context, context.registry.load(), cfg.library.build())
        state.versions = software_versions(*dict.fromkeys((cfg.refine_sim, *cfg.validate_sims)))
        if context.source is not None:
            from ges_core.dataset import open_dataset

            state.source = open_dataset(context.source[0])
        _STATES.clear()  # one run context at a time per process
        _STATES[key] = state
    return _STATES[key]


def _hands_in_order(task: Task) -> list[str]:
    return list(dict.fromkeys(h for _, hands in task.pairs for h in hands))


# -- step 1: contacts (shared by every hand with the same contact settings) ---------------------
def _contact_key(state: _State, hand: str) -> str:
    """The hand's contact settings as text: hands with equal ones share each object's contacts."""
    return state.config(hand).contacts.model_dump_json()


def _all_contacts(state: _State, task: Task) -> dict[tuple[str, str], ObjectWork]:
    """(object id, contact key) -> the object's contact step, once per distinct contact setting its hands use.

    With no hand setting its own ``contacts``, every hand shares one generation per object (as before per-hand
    settings existed: same seed, same result). A hand with other contact settings gets its own, from the same
    point cloud and seed.
    """
    works: dict[tuple[str, str], ObjectWork] = {}
    for oid, hands in task.pairs:
        for hand in hands:
            key = _contact_key(state, hand)
            if (oid, key) not in works:
                works[(oid, key)] = _contacts(state, oid, state.config(hand).contacts)
    return works


def _contacts(
    state: _State,
    object_id: str,
    contacts: ContactConfig,
    strategy: Strategy | None = None,
    cloud: ObjectCloud | None = None,
) -> ObjectWork:
    """The object's contact step (``strategy``: None chooses it, else only that one is tried; ``cloud``: the
    object's samples when already drawn with the object's seed, else they are drawn here)."""
    lib, cfg = state.library, state.context.config
    entry = lib.entry(object_id)
    seed = object_seed(cfg.seed, object_id)
    work = ObjectWork(object_id, entry.category, lib.splits[object_id], seed)
    if state.source is not None:
        work = contacts_from_record(work, state.source.get(object_id, state.context.source[1]))
        try:  # the stored contacts are reused; the cloud only guides the wrist search
            return replace(work, cloud=ObjectCloud(*lib.point_cloud(object_id, cfg.points, seed=seed)))
        except (AssetError, SynthesisError):
            return work
    start = time.perf_counter()
    try:
        if cloud is None:
            points, normals = lib.point_cloud(object_id, cfg.points, seed=seed)
        else:
            points, normals = cloud.points, cloud.normals
        result = generate_contacts(
            points, normals, contacts, object_id=object_id, seed=seed, strategy=strategy,
            center_of_mass=LIBRARY_CENTER_OF_MASS,
        )  # fmt: skip
    except SynthesisError as error:
        return work.failed_contacts(error.reason, str(error), time.perf_counter() - start)
    except AssetError as error:
        return work.failed_contacts("bad_mesh", str(error), time.perf_counter() - start)
    return work.with_contacts(result, time.perf_counter() - start, ObjectCloud(points, normals))


# -- step 2: retargeting (one batch per hand and chunk) ----------------------------------------
def _retarget(
    state: _State, hand: str, works: Sequence[ObjectWork], retargeter: GraspRetargeter | None = None
) -> list[list[Grasp] | SynthesisError | None]:
    """One result per work: its grasps best first (the attempts of :func:`_attempts`), a SynthesisError,
    or None (no contacts to retarget); by ``retargeter``, else the hand's."""
    ready = [i for i, w in enumerate(works) if w.result is not None]
    out: list = [None] * len(works)
    if ready:
        solved = (retargeter or state.retargeter(hand)).retarget_ranked(
            [works[i].result.contacts for i in ready],
            [works[i].cloud for i in ready],
            keep=state.context.config.attempts,
        )
        for i, result in zip(ready, solved, strict=True):
            out[i] = result
    return out


# -- steps 3-5: refinement, pre-grasp, validation ---------------------------------------------
def _finish(state: _State, sims: _Sims, hand: str, work: ObjectWork, result) -> GraspRecord:
    """The record of ``(work.object_id, hand)``: steps 3-5 on ``result`` (the retargeted placements), and on the
    other strategy's placements, then a balanced thumb's, then the kept contacts' with a lower raise, each when the
    passes before fell short (:func:`_wants_other_strategy`, :func:`_wants_balanced_thumb`, :func:`_wants_low_raise`,
    :func:`_second_pass`)."""
    pair = _pair(state, sims, hand, work, result)
    notes: dict[str, dict] = {}
    if _wants_other_strategy(state, hand, work, pair):
        strategy = other_strategy(work.result.strategy)
        other = _contacts(state, work.object_id, state.config(hand).contacts, strategy=strategy, cloud=work.cloud)
        work, pair, notes["other_strategy"] = _second_pass(state, sims, hand, work, pair, other, "the first strategy's")
        notes["other_strategy"] = {"strategy": strategy, **notes["other_strategy"]}
    if _wants_balanced_thumb(state, hand, work, pair):
        contacts = state.config(hand).contacts.model_copy(update={"thumb_balance_torque": True})
        other = _contacts(state, work.object_id, contacts, strategy=work.result.strategy, cloud=work.cloud)
        unchanged = _no_new_contacts(work, other)
        if unchanged:  # nothing to retarget: the note says why, the contact step counts the seconds spent
            notes["balanced_thumb"] = {"kept": False, "reason": f"contacts: {unchanged}"}
            pair = _with_contact_seconds(pair, other.step.seconds)
        else:
            work, pair, notes["balanced_thumb"] = _second_pass(
                state, sims, hand, work, pair, other, "the first contacts'"
            )
    if _wants_low_raise(state, hand, work, pair):
        low = state.retargeter(hand, low_raise=True)
        if _raised_alike(state.retargeter(hand), low, work):  # no contact the lower raise would place lower
            notes["low_raise"] = {"kept": False, "reason": f"contacts: {NONE_LOWER}"}
        else:
            again = replace(work, step=replace(work.step, seconds=0.0))  # the same contacts: their time counted once
            work, pair, notes["low_raise"] = _second_pass(
                state, sims, hand, work, pair, again, "the raised contacts'", retargeter=low
            )
    if pair.unreached_best:
        notes["unreached_best_fit"] = list(pair.unreached_best)
    record = build_record(state, hand, work, pair)
    return replace(record, extra={**record.extra, **notes}) if notes else record


def _pair(state: _State, sims: _Sims, hand: str, work: ObjectWork, result) -> PairResult:
    steps = {"contacts": work.step}
    if result is None:
        return PairResult(steps | _skipped("retargeting", "refinement", "validation", "robust"))
    if isinstance(result, SynthesisError):
        steps["retargeting"] = StepOutcome.failed(result.reason)
        return PairResult(steps | _skipped("refinement", "validation", "robust"), errors={"retargeting": str(result)})
    reaching = _reaching(result)
    best = reaching[0]
    seconds = float(best.meta.get("seconds", 0.0))
    if not _reached(best):
        steps["retargeting"] = StepOutcome.failed("unreachable", seconds)
        return PairResult(steps | _skipped("refinement", "validation", "robust"), grasp=best, stage="retargeting")
    steps["retargeting"] = StepOutcome(ok=True, seconds=seconds)
    pair = _attempts(state, sims, hand, work, reaching, steps)
    if reaching[0] is result[0]:
        return pair
    residual = result[0].meta.get("residual")
    skipped = {"before_attempt": 0, "residual": None if residual is None else float(residual)}
    return replace(pair, unreached_best=(skipped,))


def _reached(grasp: Grasp) -> bool:
    return bool(grasp.meta.get("reached", True))


def _reaching(grasps: list[Grasp]) -> list[Grasp]:
    """The ranked placements the attempts take: all of them, but without the best fit when it does not reach its
    contacts and a later one does. The ranking's first placement is the lowest objective whether it reaches or not,
    every later one reaches (:func:`ges_core.synthesis.retarget.search.distinct_ranking`): on the Ability hand's mug
    the best fit missed by 18 mm while 15 placements reached, and the pair stopped at ``unreachable``; now those are
    tried (docs/synthesis/pipeline.md, "Attempts")."""
    if _reached(grasps[0]):
        return grasps
    return [g for g in grasps if _reached(g)] or grasps


def _wants_other_strategy(state: _State, hand: str, work: ObjectWork, pair: PairResult) -> bool:
    """Whether the pair goes on to the other strategy: ``other_strategy`` is not 'never' and :func:`_may_do_better`
    ('failed': only where no placement passed refinement and the nominal validation, or retargeting failed)."""
    cfg = state.config(hand)
    if cfg.other_strategy == "never":
        return False
    return _may_do_better(state, cfg, work, pair, fragile_too=cfg.other_strategy == "not_robust")


def _wants_balanced_thumb(state: _State, hand: str, work: ObjectWork, pair: PairResult) -> bool:
    """Whether the pair goes on to contacts whose thumb balances the squeeze's torque too: ``balanced_thumb``
    'not_robust', the run's contacts not already balanced so, and :func:`_may_do_better` for the contacts kept so
    far, fragile pairs only where validation runs (without it no pass can hold better than another)."""
    cfg = state.config(hand)
    if cfg.balanced_thumb == "never" or cfg.contacts.thumb_balance_torque:
        return False
    return _may_do_better(state, cfg, work, pair, fragile_too=bool(cfg.validate_sims))


def _wants_low_raise(state: _State, hand: str, work: ObjectWork, pair: PairResult) -> bool:
    """Whether the pair's kept contacts are retargeted again with a lower raise (``low_raise`` 'not_robust',
    :func:`_may_do_better` as for the balanced thumb)."""
    cfg = state.config(hand)
    if cfg.low_raise == "never":
        return False
    return _may_do_better(state, cfg, work, pair, fragile_too=bool(cfg.validate_sims))


def _raised_alike(raised: GraspRetargeter, low: GraspRetargeter, work: ObjectWork) -> bool:
    """Whether ``work``'s contacts aim both retargeters' fingertips at the same points (no contact between the two
    raises' heights; or the "lower" raise is not lower)."""
    if low.config.min_contact_height >= raised.config.min_contact_height:
        return True
    positions = work.result.contacts.positions[None]
    return np.array_equal(
        raise_contacts(positions, raised.config.min_contact_height),
        raise_contacts(positions, low.config.min_contact_height),
    )


def _may_do_better(state: _State, cfg, work: ObjectWork, pair: PairResult, *, fragile_too: bool) -> bool:
    """Whether a second pass of other contacts could give the pair a better placement: contacts were generated here
    (not taken from a stored record), the object rests in the refining engine, and no placement passed refinement
    and the nominal validation (or retargeting failed); with ``fragile_too`` (and ``robust.enabled``,
    ``robust.retry``) also when placements passed but none held every trial in every validating simulator, unless
    the friction trial is out of any placement's reach (:func:`_friction_out_of_reach`: it is the cloud's, so any
    contacts')."""
    if state.source is not None or work.result is None:
        return False
    if pair.steps["refinement"].reason == UNSTABLE_REST:  # the object moves on its own: no grasp can refine
        return False
    if pair.attempt is None:
        return True
    fragile = pair.merit[0] < _HOLDS_EVERYWHERE and cfg.robust.enabled and cfg.robust.retry
    return fragile_too and fragile and _friction_out_of_reach(cfg, work)[0] is None


def _no_new_contacts(work: ObjectWork, other: ObjectWork) -> str:
    """Why ``other``'s contacts give a second pass nothing to try ('' when they do): their step's failure reason, or
    :data:`SAME_CONTACTS` when they are ``work``'s own."""
    if other.result is None:
        return other.step.reason
    if np.array_equal(other.result.contacts.positions, work.result.contacts.positions):
        return SAME_CONTACTS
    return ""


def _with_contact_seconds(pair: PairResult, seconds: float) -> PairResult:
    """``pair`` with ``seconds`` more in its contact step (another set of contacts generated and not used; both are
    timed here, never None)."""
    step = pair.steps["contacts"]
    return replace(pair, steps={**pair.steps, "contacts": replace(step, seconds=step.seconds + seconds)})


def _second_pass(
    state: _State,
    sims: _Sims,
    hand: str,
    work: ObjectWork,
    first: PairResult,
    other: ObjectWork,
    first_name: str,
    retargeter: GraspRetargeter | None = None,
) -> tuple[ObjectWork, PairResult, dict]:
    """``other``'s contacts (another strategy's, a balanced thumb's, or ``work``'s own) retargeted (by
    ``retargeter``, else the hand's) and taken through steps 3-5 like ``work``'s. Returns the work and pass kept
    (``other``'s when its chosen placement held better, :attr:`PairResult.merit`, else ``work``'s; its ``attempts``
    list both passes' placements, the first's first, and every step's seconds are the two passes' sums) and the
    note the record keeps: ``first_attempt`` (the index of the second pass's first attempt), ``kept``, ``reason``
    when not kept (:func:`_why_not_kept`, which names the first pass ``first_name``)."""
    solved = _retarget(state, hand, [other], retargeter)[0] if other.result else None
    second = _pair(state, sims, hand, other, solved)
    kept = second.merit > first.merit
    pair = replace(_joined(first, second, kept), setup_seconds=sims.setup_seconds())  # every backend of both passes
    note = {"first_attempt": len(first.attempts), "kept": kept}
    if not kept:
        note["reason"] = _why_not_kept(first, second, first_name)
    return (other if kept else work), pair, note


def _why_not_kept(first: PairResult, second: PairResult, first_name: str) -> str:
    """``step: reason`` of the second pass's first failed step; when it passed, how it held no better than
    ``first_name`` (the first pass, named in the note)."""
    if second.attempt is None:
        failed = next((n for n, o in second.steps.items() if not o.ok), "contacts")
        return f"{failed}: {second.steps[failed].reason}"
    return f"{HELD_NO_BETTER}: merit {list(second.merit)} against {first_name} {list(first.merit)}"


def _joined(first: PairResult, second: PairResult, second_kept: bool) -> PairResult:
    """The kept pass (``second`` when ``second_kept``, else ``first``) with both passes' attempts and summed step
    seconds (``setup_seconds`` is left to the caller: :meth:`_Sims.setup_seconds` already counts both)."""
    kept = second if second_kept else first
    offset = len(first.attempts) if second_kept else 0
    attempt = None if kept.attempt is None else offset + kept.attempt
    steps = {
        name: replace(outcome, seconds=first.steps[name].seconds + second.steps[name].seconds)
        for name, outcome in kept.steps.items()
    }
    later = tuple(
        {**note, "before_attempt": note["before_attempt"] + len(first.attempts)} for note in second.unreached_best
    )
    return replace(
        kept,
        steps=steps,
        attempts=first.attempts + second.attempts,
        attempt=attempt,
        unreached_best=first.unreached_best + later,
    )


def _skipped(*names: str) -> dict[str, StepOutcome]:
    return dict.fromkeys(names, StepOutcome.skipped())


_HOLDS_EVERYWHERE = 4
"""The :attr:`_Attempt.merit` level of an attempt that held every trial in every validating simulator."""


@dataclass(eq=False)
class _Attempt:
    """One wrist placement taken through refinement, the pre-grasp and validation."""

    retargeted: Grasp
    refined: RefinedGrasp | None
    refinement: StepOutcome
    pre: Grasp
    validation: StepOutcome
    robust: StepOutcome
    """The primary simulator's perturbation trials (skipped unless the nominal validation passed)."""
    validations: dict[str, SimVerdict]
    """Per validating simulator, its verdict ({} when validation did not run)."""
    errors: dict[str, str]
    """Error message per failed step of this attempt."""
    primary: SimVerdict | None = None
    """The primary simulator's verdict, or None."""
    pending: dict[str, tuple[Perturbation, ...]] = field(default_factory=dict)
    """Per validating simulator, the perturbation trials not run yet (``robust.defer_trials``: they stopped at a
    failed trial, or another simulator's did): :func:`_completed` runs them when the choice needs every score."""

    @property
    def passed(self) -> bool:
        """Refinement and the nominal (single-trial) validation passed."""
        return self.refinement.ok and (self.validation.ok or self.validation.reason == NOT_RUN)

    @property
    def robust_ok(self) -> bool:
        """Passed, and every perturbation held (or robust validation is off)."""
        return self.passed and (self.robust.ok or self.robust.reason == NOT_RUN)

    @property
    def resting_validations(self) -> list[SimVerdict]:
        """The verdicts of the validating simulators in which the object stays at rest (a grasp can be judged)."""
        return [v for v in self.validations.values() if v.reason != UNSTABLE_REST]

    @property
    def holds_everywhere(self) -> bool:
        """:attr:`robust_ok`, and in every other validating simulator in which the object stays at rest too: every
        trial held there, or with robust validation off the nominal trial did."""
        if self.robust.reason == NOT_RUN:
            return self.passed and all(v.success for v in self.resting_validations)
        return self.holds_all_but(None)

    def holds_all_but(self, trial: str | None) -> bool:
        """Passed, and in every validating simulator in which the object stays at rest every perturbation trial but
        ``trial`` held (``None``: every trial, ``SimVerdict.robust`` there); False when the trials did not run."""
        if not self.passed or self.robust.reason == NOT_RUN or not self.resting_validations:
            return False
        return all(
            v.success and v.robustness is not None and all(t.success or t.name == trial for t in v.trials)
            for v in self.resting_validations
        )

    @property
    def robustness(self) -> float | None:
        """The primary simulator's robustness score, or None when its trials did not run."""
        return self.primary.robustness if self.primary is not None else None

    @property
    def merit(self) -> tuple[int, float]:
        """How well this attempt held, greater is better (:attr:`PairResult.merit`): the level (4 held every trial in
        every validating simulator where the object rests, 3 robust in the primary one, 2 passed and its nominal trial
        held in every such simulator, 1 passed, 0 did not pass) and the mean over those simulators of the robustness
        score (a failed nominal trial 0; trials off: 1 for a held nominal trial)."""
        if not self.passed:
            return 0, 0.0
        resting = self.resting_validations
        if self.holds_everywhere:
            level = _HOLDS_EVERYWHERE
        else:
            level = 3 if self.robust_ok else 2 if all(v.success for v in resting) else 1
        scores = [(1.0 if v.robustness is None else v.robustness) if v.success else 0.0 for v in resting]
        return level, sum(scores) / len(scores) if scores else 0.0

    @property
    def verdict(self) -> AttemptVerdict:
        """What the record lists for this attempt; its robustness is None while trials are deferred (a score over
        some of the trials would read as a lower or higher one than the placement's)."""
        return AttemptVerdict(
            refinement=self.refinement.reason or "ok",
            validation=self.validation.reason or "ok",
            robust=self.robust.reason or "ok",
            robustness=None if any(self.pending.values()) else self.robustness,
        )


def _attempts(
    state: _State, sims: _Sims, hand: str, work: ObjectWork, grasps: list[Grasp], steps: dict[str, StepOutcome]
) -> PairResult:
    """Take ``grasps`` (best wrist placement first) through refinement and validation until one passes both in
    every validating simulator, and its perturbation trials too when robust validation is on; with
    ``robust.retry`` off, until one passes the primary simulator's nominal trial.

    The result is the passing attempt of the highest :attr:`_Attempt.merit`, the first of equals: the first that
    holds in every validating simulator; else, of those robust in the primary one (with robust validation off: that
    passed there), the one of the highest robustness score averaged over the validating simulators; else the same
    among those whose nominal trial held in every validating simulator, else among all that passed. None passing,
    the first that refined, else the first. It
    lists every attempt's verdicts and the chosen one's index when it passed; its refinement, validation and robust
    times are the sums over the attempts. With ``robust.defer_trials`` the trials a placement left after its first
    failure (:attr:`_Attempt.pending`) run before the choice when no placement holds everywhere (:func:`_completed`).

    An object that does not stay at rest on its own in a validating simulator (its verdict there is
    ``unstable_rest``, whatever the placement) leaves that simulator out of "every validating simulator"; one that does
    not rest in the refining simulator fails every placement's refinement alike, so the search stops at the first.

    An object that no grasp from above can lift at the friction trial's coefficient
    (:func:`ges_core.synthesis.contacts.lift_friction.lift_friction_bound`) cannot give a robust placement: the search
    then stops at the first placement that holds every other trial, and the record's robust error says why."""
    cfg = state.config(hand)
    retry = cfg.robust.retry
    out_of_reach, why = _friction_out_of_reach(cfg, work)
    tries, stopped = [], False
    for grasp in grasps:
        tries.append(_attempt(state, sims, hand, work, grasp, out_of_reach))
        last = tries[-1]
        stopped = bool(out_of_reach) and last.holds_all_but(out_of_reach)
        unrested = last.refinement.reason == UNSTABLE_REST  # the object moves on its own: no placement can refine
        if last.holds_everywhere or (last.passed and not retry) or stopped or unrested:
            break
    if not tries[-1].holds_everywhere:  # the choice compares scores: every deferred trial is needed
        tries = [_completed(state, sims, hand, work, t) for t in tries]
    index = _chosen(tries)
    chosen = tries[index]
    errors = chosen.errors
    if out_of_reach and not chosen.holds_everywhere:
        stop = "stopped at the first placement" if stopped else "found no placement"
        errors = errors | {"robust": f"{why}; the placement search {stop} that held every other trial"}
    steps = steps | {
        name: replace(getattr(chosen, name), seconds=sum(getattr(t, name).seconds for t in tries))
        for name in ("refinement", "validation", "robust")
    }
    return PairResult(
        steps,
        grasp=chosen.refined.grasp if chosen.refined is not None else chosen.retargeted,
        stage="refinement" if chosen.refined is not None else "retargeting",
        pre=chosen.pre,
        refined=chosen.refined,
        attempt=index if chosen.passed else None,
        attempts=tuple(t.verdict for t in tries),
        validations=chosen.validations,
        errors=errors,
        setup_seconds=sims.setup_seconds(),  # every trial's backend, summed per simulator
        merit=chosen.merit,
    )


def _friction_out_of_reach(cfg: SynthesisConfig, work: ObjectWork) -> tuple[str | None, str]:
    """(the friction trial's name, why no placement can pass it) when the object's surface above the contacts'
    ``min_height`` faces up too steeply for the trial's coefficient; (None, "") otherwise or when unknown."""
    floor = cfg.robust.friction_floor
    if not cfg.robust.enabled or floor is None or work.cloud is None:
        return None, ""
    min_height = cfg.contacts.min_height
    bound = lift_friction_bound(work.cloud.points, work.cloud.normals, min_height)
    if bound <= floor:
        return None, ""
    name = friction_trial_name(floor)
    return name, (
        f"no grasp from above can pass {name}: every surface point above {min_height:g} m faces up more steeply "
        f"than atan({floor:g}) = {math.degrees(math.atan(floor)):.1f} deg, so no contact there can push the object "
        f"up (lifting it needs friction >= {bound:.3f})"
    )


def _chosen(tries: list[_Attempt]) -> int:
    """Index of the attempt a record keeps (see :func:`_attempts`): the passing one of the highest
    :attr:`_Attempt.merit` (the first of equals); none passing, the first that refined, else the first."""
    passed = [i for i, t in enumerate(tries) if t.passed]
    if passed:
        return max(passed, key=lambda i: (tries[i].merit, -i))
    return next((i for i, t in enumerate(tries) if t.refinement.ok), 0)


def _attempt(
    state: _State, sims: _Sims, hand: str, work: ObjectWork, grasp: Grasp, tolerated: str | None = None
) -> _Attempt:
    """``grasp`` through refinement, the pre-grasp and validation; ``tolerated``: the friction trial out of every
    placement's reach (:func:`_friction_out_of_reach`, found once per pair), which does not stop deferred trials."""
    cfg = state.config(hand)
    refined, refinement, errors = _refine(state, sims, hand, work, grasp)
    settled = refined.grasp if refined is not None else grasp
    pre = pregrasp(state.hand(hand), settled, work.result.approach, cfg.pregrasp, thumb_keep=cfg.thumb_keep)
    if not refinement.ok:
        skipped = StepOutcome.skipped()
        return _Attempt(grasp, refined, refinement, pre, skipped, skipped, {}, errors)
    validation, robust, verdicts, failures, pending = _validate(state, sims, hand, work, refined.grasp, pre, tolerated)
    primary = verdicts.get(cfg.primary_sim) if cfg.primary_sim else None
    return _Attempt(grasp, refined, refinement, pre, validation, robust, verdicts, errors | failures, primary, pending)


def _refine(state: _State, sims: _Sims, hand: str, work: ObjectWork, grasp: Grasp):
    """(RefinedGrasp or None, the refinement step's outcome, {"refinement": error message} or {})."""
    cfg, model = state.config(hand), state.hand(hand)
    start, rested = time.perf_counter(), sims.rest_seconds
    try:
        asset = state.library.get(work.object_id)
        drifted = sims.rest_problem(hand, cfg.refine_sim, asset)  # checked once per object, not per placement
        rest_seconds = sims.rest_seconds - rested  # 0 after the first placement
        if drifted is not None:
            outcome = StepOutcome.failed(drifted.reason, rest_seconds)
            return None, outcome, {"refinement": str(drifted)}
        settings = cfg.refine.model_copy(update={"rest_steps": 0})  # the object rests: checked just above
        with sims.scenes(hand, cfg.refine_sim).open() as sim:
            refined = refine_grasp(sim, model, asset, grasp, settings, thumb_keep=cfg.thumb_keep)
    except AssetError as error:
        return None, StepOutcome.failed("no_collision_model", time.perf_counter() - start), {"refinement": str(error)}
    except (SynthesisError, SimulationError, ArrayError) as error:  # a non-finite command counts as a blow-up
        outcome = StepOutcome.failed(getattr(error, "reason", "unstable"), time.perf_counter() - start)
        return None, outcome, {"refinement": str(error)}
    verdict = refine_verdict(refined, model, cfg.refine)
    seconds = float(refined.seconds) + rest_seconds
    outcome = StepOutcome(ok=True, seconds=seconds) if verdict == "ok" else StepOutcome.failed(verdict, seconds)
    return refined, outcome, {}


def _validate(
    state: _State, sims: _Sims, hand: str, work: ObjectWork, grasp: Grasp, pre: Grasp, tolerated: str | None = None
):
    """Validate in every configured simulator, then run the perturbation trials where the nominal trial passed:
    (the primary one's nominal verdict as the validation step, its trials as the robust step, the verdict per
    simulator, {"validation_<sim>": error message} of the simulators that failed to run, the trials deferred per
    simulator). With ``robust.defer_trials`` a simulator's trials stop at its first failed one (but the friction
    trial ``tolerated``, out of every placement's reach: :func:`_friction_out_of_reach`), and once one has failed the
    later simulators' trials are all deferred (the primary simulator's run first): the placement cannot hold
    everywhere any more, and only :func:`_completed` needs the rest."""
    cfg = state.config(hand)
    if not cfg.validate_sims:
        return StepOutcome(ok=False, reason=NOT_RUN), StepOutcome(ok=False, reason=NOT_RUN), {}, {}, {}
    asset = state.library.get(work.object_id)
    verdicts, errors, pending = {}, {}, {}
    for name in sorted(cfg.validate_sims, key=lambda n: n != cfg.primary_sim):  # the primary simulator first
        drifted = sims.rest_problem(hand, name, asset)  # the refining engine's was checked before refinement
        if drifted is not None:  # the object does not stay at rest in this engine: no grasp is judged there
            errors[f"validation_{name}"] = str(drifted)
            verdicts[name] = SimVerdict(success=False, reason=drifted.reason)  # unstable_rest (or unstable)
            continue
        failed = any(_failed_trial(v, tolerated) for v in verdicts.values())
        defer = None if not cfg.robust.defer_trials else "all" if failed else "after_failure"
        try:
            verdicts[name], pending[name] = _sim_verdict(
                state, sims.scenes(hand, name), hand, work, asset, grasp, pre, defer=defer, tolerated=tolerated
            )
        except (SimulationError, ArrayError) as error:  # failing to build or load, or a NaN command: a blow-up
            errors[f"validation_{name}"] = str(error)
            verdicts[name], pending[name] = SimVerdict(success=False, reason="unstable"), ()
    verdicts = {name: verdicts[name] for name in cfg.validate_sims}  # the configured order
    main = verdicts[cfg.primary_sim]
    validation = (
        StepOutcome(ok=True, seconds=main.seconds) if main.success else StepOutcome.failed(main.reason, main.seconds)
    )
    pending = {name: trials for name, trials in pending.items() if trials}
    return validation, _robust_step(main, cfg.robust.enabled), verdicts, errors, pending


def _failed_trial(verdict: SimVerdict, tolerated: str | None) -> bool:
    """Some perturbation trial of ``verdict`` failed, other than ``tolerated``."""
    return any(not t.success and t.name != tolerated for t in verdict.trials)


def _sim_verdict(
    state: _State,
    scenes: TrialScenes,
    hand: str,
    work: ObjectWork,
    asset,
    grasp: Grasp,
    pre: Grasp,
    *,
    defer: Literal["after_failure", "all"] | None = None,
    tolerated: str | None = None,
) -> tuple[SimVerdict, tuple[Perturbation, ...]]:
    """The nominal trial and, if it passed and robust validation is on, the perturbation trials; each in a new
    backend of ``scenes``. defer: None runs every trial; "after_failure" stops after the first failed one other
    than ``tolerated``; "all" runs none. Returns the verdict and the trials not run."""
    cfg, model = state.config(hand), state.hand(hand)
    with scenes.open() as sim:
        result = validate_grasp(sim, model, asset, grasp, pre, cfg.validate_)
    flags = {k: bool(v) for k, v in result.flags.items()}
    verdict = SimVerdict(success=result.success, reason=result.reason, flags=flags, seconds=result.seconds)
    if not (result.success and cfg.robust.enabled):
        return verdict, ()
    todo = tuple(perturbations(cfg.robust, scenes.config.hand_friction, asset, work.seed))
    if defer == "all":
        return verdict, todo
    return _trials_run(
        state, scenes, hand, asset, grasp, pre, verdict, todo, stop=defer is not None, tolerated=tolerated
    )


def _trials_run(
    state: _State,
    scenes: TrialScenes,
    hand: str,
    asset,
    grasp: Grasp,
    pre: Grasp,
    verdict: SimVerdict,
    todo: tuple[Perturbation, ...],
    *,
    stop: bool = False,
    tolerated: str | None = None,
) -> tuple[SimVerdict, tuple[Perturbation, ...]]:
    """``verdict`` with the trials of ``todo`` run and appended in order (its robustness the share held of all its
    trials, its robust seconds summed); with ``stop`` they stop after the first failed one other than ``tolerated``.
    Returns it and the trials not run."""
    cfg = state.config(hand)
    limits = trial_limits(scenes, cfg.robust)
    trials, seconds = list(verdict.trials), verdict.robust_seconds or 0.0
    for i, p in enumerate(todo):
        t = run_trial(scenes, asset, grasp, pre, cfg.validate_, p, limits)
        trials.append(TrialVerdict(name=t.name, success=t.success, reason=t.reason))
        seconds += t.seconds
        if stop and not t.success and t.name != tolerated:
            todo = todo[i + 1 :]
            break
    else:
        todo = ()
    robustness = sum(t.success for t in trials) / len(trials) if trials else 1.0
    return replace(verdict, trials=tuple(trials), robustness=robustness, robust_seconds=seconds), todo


def _completed(state: _State, sims: _Sims, hand: str, work: ObjectWork, attempt: _Attempt) -> _Attempt:
    """``attempt`` with its deferred trials (:attr:`_Attempt.pending`) run: the same verdicts as running them all at
    once, as every trial has a backend of its own. A simulator that fails to build there makes its verdict
    ``unstable``, as in :func:`_validate`."""
    if not attempt.pending:
        return attempt
    cfg = state.config(hand)
    asset = state.library.get(work.object_id)
    verdicts, errors = dict(attempt.validations), dict(attempt.errors)
    for name, todo in attempt.pending.items():
        try:
            scenes = sims.scenes(hand, name)
            verdicts[name], _ = _trials_run(
                state, scenes, hand, asset, attempt.refined.grasp, attempt.pre, verdicts[name], todo
            )
        except (SimulationError, ArrayError) as error:
            errors[f"validation_{name}"] = str(error)
            verdicts[name] = SimVerdict(success=False, reason="unstable")
    main = verdicts[cfg.primary_sim]
    validation = attempt.validation
    if not main.success:  # the primary simulator failed to build for its deferred trials
        validation = StepOutcome.failed(main.reason, attempt.validation.seconds)
    return replace(
        attempt,
        validation=validation,
        robust=_robust_step(main, cfg.robust.enabled),
        validations=verdicts,
        errors=errors,
        primary=main,
        pending={},
    )


def _robust_step(verdict: SimVerdict, enabled: bool) -> StepOutcome:
    """The robust step from the primary simulator's verdict."""
    if not enabled:
        return StepOutcome(ok=False, reason=NOT_RUN)
    if not verdict.success or verdict.robustness is None:
        return StepOutcome.skipped()
    if verdict.robust:
        return StepOutcome(ok=True, seconds=verdict.robust_seconds)
    failed = next(t.name for t in verdict.trials if not t.success)
    return StepOutcome.failed(failed, verdict.robust_seconds)


class _Sims:
    """The simulators of one (object, hand) pair: a :class:`TrialScenes` per (hand, simulator), and whether the
    object stays at rest in each validating simulator."""

    def __init__(self, state: _State) -> None:
        self.state = state
        self.trial_scenes: dict[tuple[str, str], TrialScenes] = {}
        self.rest: dict[tuple[str, str], SynthesisError | None] = {}
        """(hand, simulator) -> why the object does not stay at rest there (None: it does), checked once."""
        self.rest_seconds = 0.0
        """Seconds the rest checks have stepped physics since the last :meth:`reset` (their builds excluded)."""

    def rest_problem(self, hand: str, name: str, asset) -> SynthesisError | None:
        """Why ``asset`` does not stay at its resting pose on its own in simulator ``name`` (None: it does).

        :func:`ges_core.synthesis.physics.refine.check_rest`, once per (object, hand, simulator), in a simulator of
        its own: the refining engine's before the first refinement, every other validating engine's before its
        first validation. Its physics time (not the backend's build) is added to :attr:`rest_seconds`."""
        key = (hand, name)
        if key not in self.rest:
            self.rest[key] = None
            with self.scenes(hand, name).open() as sim:
                start = time.perf_counter()
                try:
                    check_rest(sim, self.state.hand(hand), asset, self.state.config(hand).refine)
                except SynthesisError as error:  # reason unstable_rest, or unstable if it blew up settling
                    self.rest[key] = error
                self.rest_seconds += time.perf_counter() - start
        return self.rest[key]

    def scenes(self, hand: str, name: str) -> TrialScenes:
        """The fresh-backend-per-trial builder of simulator ``name`` with ``hand``."""
        key = (hand, name)
        if key not in self.trial_scenes:
            state = self.state
            self.trial_scenes[key] = TrialScenes(
                state.registry.build_sim, name, state.context.config.scene, state.hand(hand)
            )
        return self.trial_scenes[key]

    def setup_seconds(self) -> dict[str, float]:
        """Per simulator, the seconds spent building backends and loading the hand since the last :meth:`reset`."""
        out: dict[str, float] = {}
        for (_, name), scenes in self.trial_scenes.items():
            out[name] = out.get(name, 0.0) + scenes.seconds
        return out

    def reset(self) -> None:
        """Forget the setup times and rest checks (between objects)."""
        self.trial_scenes.clear()
        self.rest = {}
        self.rest_seconds = 0.0


def _with_picture(state: _State, record: GraspRecord) -> GraspRecord:
    """``record`` with ``picture`` set after drawing it (no picture folder: unchanged).

    A picture that cannot be written (full disk, read-only folder) or drawn (a renderer plugin's own error, e.g. a
    hand asset its engine cannot load) costs the picture, never the record: the record keeps ``picture`` None and
    says why in ``errors["picture"]``; the first such failure of a process is logged (once: the next pictures
    likely fail alike).
    """
    root = state.context.pictures
    if root is None:
        return record
    from ges_core.render import open_renderer, render_record

    if state.renderer is None:
        state.renderer = open_renderer(state.registry)
    path = picture_path(root, record.object_id, record.hand)
    try:
        asset = state.library.get(record.object_id)
    except AssetError:
        asset = None  # no collision model: the picture shows the contacts and the hand only
    try:
        render_record(record, state.hand(record.hand), asset, path, renderer=state.renderer)
    except Exception as error:  # noqa: BLE001 - a picture is never worth the record (docstring)
        why = str(error) if isinstance(error, StorageError) else f"drawing failed: {type(error).__name__}: {error}"
        if not state.picture_failed:
            state.picture_failed = True
            _LOG.warning("ges: warning: %s (the records are saved without their pictures)", why)
        return replace(record, errors={**record.errors, "picture": why})
    return replace(record, picture=path.as_posix())


def picture_path(root: str | Path, object_id: str, hand: str) -> Path:
    """Where the picture of ``(object_id, hand)`` goes under ``root``."""
    return Path(root) / hand / (object_id.replace("/", "__") + ".png")
