"""The slow lint check: a short physics probe of the fingertip forces validation's squeeze gets.

The probe is ``ges sim check``'s scene (the hand closes on a 0.1 kg box, :mod:`ges_core.sim_check`)
without the lift, followed by the squeeze Stage 1 validation applies (targets past the measured
joints so each tip presses :data:`~ges_core.synthesis.physics.squeeze.SQUEEZE_FORCE`,
:func:`~ges_core.synthesis.physics.squeeze.squeeze_targets`). A fingertip that then presses far
less than asked cannot hold the demo objects. About 300 steps per simulator (0.5-2 s); run by
``ges hand lint --probe``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ges_core.hand import HandModel
from ges_core.lint.problems import LintProblem
from ges_core.sim import SceneConfig, SimBackend

__all__ = ["PROBE_SHARE", "SQUEEZE_STEPS", "check_tip_forces", "probe_tip_forces"]

PROBE_SHARE = 0.5
"""A fingertip pressing less than this share of the squeeze force is reported: with two tips at mu = 1, half
of 5 N (2.5 N each) is what a 0.25 kg object needs against gravity, the heavy end of the demo objects."""
SQUEEZE_STEPS = 60
"""Steps (0.5 s at 1/120 s) of squeezing before the forces are read: the PD drives settle in about 20."""


def probe_tip_forces(hand: HandModel, sim: SimBackend) -> tuple[np.ndarray, float]:
    """(F,) each finger's tip force on the box after the squeeze, N, and the force asked, N (``sim`` fresh)."""
    from ges_core.sim_check import SimCheckConfig, run_sim_check
    from ges_core.synthesis.physics.squeeze import MAX_SQUEEZE, MIN_SQUEEZE, SQUEEZE_FORCE, squeeze_targets

    run_sim_check(hand, sim, SimCheckConfig(lift_steps=0))
    q = sim.joint_state()[0][0]
    targets = squeeze_targets(hand, q, force=SQUEEZE_FORCE, min_squeeze=MIN_SQUEEZE, max_squeeze=MAX_SQUEEZE)
    sim.set_joint_targets(targets[None])
    sim.step(SQUEEZE_STEPS)
    forces = np.linalg.norm(sim.contact_forces(list(hand.description.tip_links), "object")[0], axis=-1)
    return forces, SQUEEZE_FORCE


def check_tip_forces(
    hand: HandModel, sim_name: str, make_sim: Callable[[str, SceneConfig], SimBackend]
) -> list[LintProblem]:
    """Each fingertip presses at least :data:`PROBE_SHARE` of the squeeze force on the probe box in ``sim_name``."""
    with make_sim(sim_name, SceneConfig()) as sim:
        forces, asked = probe_tip_forces(hand, sim)
    out = []
    for finger, force in zip(hand.description.fingers, forces, strict=True):
        if force >= PROBE_SHARE * asked:
            continue
        how = "did not touch the probe box" if force < 0.05 else f"pressed only {force:.2f} N on the probe box"
        out.append(
            LintProblem(
                "tip-force",
                f"finger '{finger.name}' {how} in {sim_name} under validation's squeeze (asks {asked:g} N per tip; "
                f"below {PROBE_SHARE * asked:g} N two tips do not hold the heavier demo objects)",
                "raise pd_stiffness of its joints (a drive presses Kp x the angle its target lies past contact, and "
                "the squeeze goes at most 0.6 rad past), check effort limits, and make its tip link collide "
                "(see tip-collision)",
            )
        )
    return out
