"""Run every lint check on one hand and collect the problems."""

from __future__ import annotations

import importlib.util
from collections.abc import Callable, Sequence

from ges_core.errors import ConfigError, GesError
from ges_core.hand import HandModel
from ges_core.lint import checks_assets, checks_contact_load, checks_geometry, checks_physics, checks_static
from ges_core.lint.problems import LintProblem
from ges_core.lint.urdf_tree import UrdfTree
from ges_core.sim import SceneConfig, SimBackend

__all__ = ["CHECKS", "SLOW_CHECKS", "lint_hand"]

CHECKS: tuple[str, ...] = (
    "joint-limits",
    "slots",
    "tip-links",
    "collision",
    "tip-collision",
    "mimic",
    "meshes",
    "inertia",
    "wrist-frame",
    "opposition",
    "hull-gap",
    "hull-overlap",
    "contact-load",
    "self-collision",
    "fk",
    "tip-force",
)
"""Every check, in the order they run and print."""
SLOW_CHECKS: tuple[str, ...] = ("tip-force",)
"""Checks that run only when asked (``probe=True``, ``ges hand lint --probe``): a physics probe of seconds."""

_STATIC = {
    "joint-limits": checks_static.check_joint_limits,
    "slots": checks_static.check_slots,
    "tip-links": checks_static.check_tip_links,
    "collision": checks_static.check_collision_geometry,
}
_ASSETS = {
    "tip-collision": checks_assets.check_tip_collision,
    "mimic": checks_assets.check_mimic,
    "meshes": checks_assets.check_mesh_formats,
}


def lint_hand(
    hand: HandModel,
    *,
    sims: Sequence[str] = (),
    make_sim: Callable[[str, SceneConfig], SimBackend] | None = None,
    skip: Sequence[str] = (),
    probe: bool = False,
    ref: str | None = None,
) -> list[LintProblem]:
    """All problems (and notes) of ``hand``; physical checks run in each simulator of ``sims`` built by ``make_sim``.

    probe: also run :data:`SLOW_CHECKS`. ref: how the user names the hand in a command (default its name).
    skip: names of :data:`CHECKS` not to run; another name is a ConfigError listing them.
    """
    if unknown := sorted(set(skip) - set(CHECKS)):
        raise ConfigError(f"lint: no check named {', '.join(map(repr, unknown))}; the checks are {', '.join(CHECKS)}")
    tree = UrdfTree.from_text(hand.urdf_text())
    d, ref = hand.description, ref or hand.name
    problems: list[LintProblem] = []
    for name, check in _STATIC.items():
        if name not in skip:
            problems += check(d, tree)
    for name, check in _ASSETS.items():
        if name not in skip:
            problems += _guarded(name, lambda c=check: c(hand, tree, ref))
    if "inertia" not in skip:
        problems += checks_static.check_inertia(d, tree)
        problems += _guarded("inertia", lambda: checks_assets.check_inertia_bound(hand))
    problems += _kinematic_checks(hand, problems, skip, ref)
    for sim_name in sims if make_sim is not None else ():
        problems += _sim_checks(hand, sim_name, make_sim, skip, probe)
    return problems


def _kinematic_checks(hand: HandModel, found: list[LintProblem], skip: Sequence[str], ref: str) -> list[LintProblem]:
    if _blocks_kinematics(found):
        return []
    runs = {
        "wrist-frame": lambda: checks_physics.check_wrist_convention(hand),
        "opposition": lambda: checks_geometry.check_thumb_opposition(hand),
        "hull-gap": lambda: checks_geometry.check_hull_gaps(hand, ref),
        "hull-overlap": lambda: checks_geometry.check_hull_overlaps(hand, ref),
        "contact-load": lambda: checks_contact_load.check_contact_load(hand),
    }
    if any(p.check == "meshes" and "does not exist" in p.what for p in found):
        for name in ("hull-gap", "hull-overlap", "contact-load"):  # they load the meshes
            runs.pop(name)
    return [p for name, run in runs.items() if name not in skip for p in _guarded(name, run)]


def _sim_checks(hand: HandModel, sim_name: str, make_sim, skip: Sequence[str], probe: bool) -> list[LintProblem]:
    runs = {
        "self-collision": lambda: checks_physics.check_self_collision(hand, sim_name, make_sim),
        "fk": lambda: checks_physics.check_fk_matches_sims(hand, sim_name, make_sim),
    }
    if probe:
        from ges_core.lint.checks_probe import check_tip_forces

        runs["tip-force"] = lambda: check_tip_forces(hand, sim_name, make_sim)
    return [p for name, run in runs.items() if name not in skip for p in _guarded(name, run)]


def installed_sims(names: Sequence[str], requires: dict[str, Sequence[str]]) -> list[str]:
    """The simulators among ``names`` whose required modules import here."""
    return [n for n in names if all(importlib.util.find_spec(m) is not None for m in requires.get(n, ()))]


def _blocks_kinematics(problems: list[LintProblem]) -> bool:
    """A slot or tip-link problem leaves the kinematic checks nothing sound to measure (a note does not)."""
    return any(p.check in ("tip-links", "slots") and not p.note for p in problems)


def _guarded(check: str, run: Callable[[], list[LintProblem]]) -> list[LintProblem]:
    try:
        return run()
    except GesError as exc:
        return [LintProblem(check, f"could not run: {exc}", "fix the problems above first")]
