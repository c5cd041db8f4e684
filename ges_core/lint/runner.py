"""Run every lint check on one hand and collect the problems."""

from __future__ import annotations

import importlib.util
from collections.abc import Callable, Sequence

from ges_core.errors import GesError
from ges_core.hand import HandModel
from ges_core.lint import checks_physics, checks_static
from ges_core.lint.problems import LintProblem
from ges_core.lint.urdf_tree import UrdfTree
from ges_core.sim import SceneConfig, SimBackend

__all__ = ["CHECKS", "lint_hand"]

CHECKS: tuple[str, ...] = (
    "joint-limits",
    "slots",
    "tip-links",
    "collision",
    "inertia",
    "wrist-frame",
    "self-collision",
    "fk",
)
"""Every check, in the order they run and print."""

_STATIC = {
    "joint-limits": checks_static.check_joint_limits,
    "slots": checks_static.check_slots,
    "tip-links": checks_static.check_tip_links,
    "collision": checks_static.check_collision_geometry,
    "inertia": checks_static.check_inertia,
}


def lint_hand(
    hand: HandModel,
    *,
    sims: Sequence[str] = (),
    make_sim: Callable[[str, SceneConfig], SimBackend] | None = None,
    skip: Sequence[str] = (),
) -> list[LintProblem]:
    """All problems of ``hand``; physical checks run in each simulator of ``sims`` built by ``make_sim``."""
    tree = UrdfTree.from_text(hand.urdf_text())
    d = hand.description
    problems: list[LintProblem] = []
    for name, check in _STATIC.items():
        if name not in skip:
            problems += check(d, tree)
    if "wrist-frame" not in skip and not _blocks_kinematics(problems):
        problems += _guarded("wrist-frame", lambda: checks_physics.check_wrist_convention(hand))
    for sim_name in sims if make_sim is not None else ():
        if "self-collision" not in skip:
            problems += _guarded(
                "self-collision", lambda s=sim_name: checks_physics.check_self_collision(hand, s, make_sim)
            )
        if "fk" not in skip:
            problems += _guarded("fk", lambda s=sim_name: checks_physics.check_fk_matches_sims(hand, s, make_sim))
    return problems


def installed_sims(names: Sequence[str], requires: dict[str, Sequence[str]]) -> list[str]:
    """The simulators among ``names`` whose required modules import here."""
    return [n for n in names if all(importlib.util.find_spec(m) is not None for m in requires.get(n, ()))]


def _blocks_kinematics(problems: list[LintProblem]) -> bool:
    return any(p.check in ("tip-links", "slots") for p in problems)


def _guarded(check: str, run: Callable[[], list[LintProblem]]) -> list[LintProblem]:
    try:
        return run()
    except GesError as exc:
        return [LintProblem(check, f"could not run: {exc}", "fix the problems above first")]
