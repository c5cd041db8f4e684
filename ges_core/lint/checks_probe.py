"""The slow lint check: a short physics probe of the fingertip forces validation's squeeze gets.

The hand floats high above the table, gravity off, and closes from 30 % to 50 % of
:meth:`HandDescription.closed_pose`. Scene ``f`` (one per finger, stepped together) holds a fixed 2 cm cube
whose face touches finger ``f``'s tip point at 50 %, on the side that finger presses toward in Stage 1
validation (:func:`~ges_core.synthesis.physics.squeeze.press_directions`). The joints then get
validation's squeeze targets (:func:`~ges_core.synthesis.physics.squeeze.squeeze_targets`, which
ask each tip for :data:`~ges_core.synthesis.physics.squeeze.SQUEEZE_FORCE`), and after
:data:`SQUEEZE_STEPS` steps finger ``f``'s tip force on its cube is read. A tip far below the force
asked cannot hold the demo objects, whatever the grasp: weak drives, drive limits, or a tip link
that nothing touches through. Run by ``ges hand lint --probe`` (1-3 s per simulator).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ges_core.hand import HandDescription, HandModel
from ges_core.lint.problems import LintProblem
from ges_core.sim import SceneConfig, SimBackend

__all__ = [
    "DAMPED",
    "PROBE_SHARE",
    "SQUEEZE_STEPS",
    "ProbeReading",
    "check_tip_forces",
    "drive_time_constant",
    "probe_fingers",
    "probe_tip_forces",
]

PROBE_SHARE = 0.5
"""A fingertip pressing less than this share of the squeeze force is reported: with two tips at mu = 1, half
of 5 N (2.5 N each) is what a 0.25 kg object needs against gravity, the heavy end of the demo objects."""
SQUEEZE_STEPS = 60
"""Steps (0.5 s at 1/120 s) of squeezing before the forces are read: the PD drives settle in about 20."""
HOVER = np.array([0.0, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0])
"""(7,) base pose of the probe (x, y, z, qw, qx, qy, qz): half a metre over the table, nothing near it."""
START = 0.3
"""The fingers start at this fraction of the closed pose, short of the cubes (placed for 0.5), and close onto
them: a cube placed where a tip already is would start inside the finger (the Ability's tip point lies 1.6 mm
inside its fingertip sphere) and read hundreds of newtons of depenetration."""
CUBE_HALF = 0.01
"""m, half edge of each finger's fixed cube."""


def probe_tip_forces(hand: HandModel, make_sim: Callable[[str, SceneConfig], SimBackend], sim_name: str):
    """(F,) each finger's tip force on its cube after the squeeze, N, and the force asked, N (module docs)."""
    reading = probe_fingers(hand, make_sim, sim_name)
    return reading.forces, reading.asked


@dataclass(frozen=True)
class ProbeReading:
    """What :func:`probe_fingers` measured after the squeeze."""

    forces: np.ndarray
    """(F,) finger f's tip force on its own cube (scene f), N."""
    asked: float
    """The tip force the squeeze targets ask for, N."""
    joint_speed: float
    """The largest hand joint speed in any scene, rad/s (m/s): a blocked finger that chatters moves, a still one
    does not."""


def probe_fingers(
    hand: HandModel,
    make_sim: Callable[[str, SceneConfig], SimBackend],
    sim_name: str,
    *,
    alone: bool = False,
    thumb_force: float | None = None,
) -> ProbeReading:
    """The probe (module docs). ``alone``: in scene f only finger f gets its squeeze targets, the others stay at the
    start pose, so no neighbour presses on f's cube (the lint squeezes every finger in every scene). ``thumb_force``:
    N the thumb's targets ask for instead of the squeeze force (``squeeze_targets``' own; ``asked`` stays the
    fingers')."""
    from ges_core.synthesis.physics.squeeze import MAX_SQUEEZE, MIN_SQUEEZE, SQUEEZE_FORCE, squeeze_targets

    d = hand.description
    q = d.closed_pose(0.5)
    targets = squeeze_targets(
        hand, q, force=SQUEEZE_FORCE, min_squeeze=MIN_SQUEEZE, max_squeeze=MAX_SQUEEZE, thumb_force=thumb_force
    )
    start, n = d.closed_pose(START), len(d.fingers)
    per_scene = np.tile(start if alone else targets, (n, 1))
    if alone:
        for f, finger in enumerate(d.fingers):
            joints = d.joint_index(finger.joints)
            per_scene[f, joints] = targets[joints]
    cubes = _cube_poses(hand, q)
    with make_sim(sim_name, SceneConfig(num_envs=n, gravity=0.0)) as sim:
        sim.load_hand(hand, floating=True)
        sim.set_hand_state(np.tile(start, (n, 1)), np.tile(HOVER, (n, 1)))
        for f in range(n):
            sim.load_object(_cube(), cubes[f], env_ids=[f], fixed=True)
        sim.set_wrist_targets(np.tile(HOVER, (n, 1)))
        sim.set_joint_targets(per_scene)
        sim.step(SQUEEZE_STEPS)
        forces = np.linalg.norm(sim.contact_forces(list(d.tip_links), "object"), axis=-1)  # (n, F)
        _, speed = sim.joint_state()
    return ProbeReading(forces[np.arange(n), np.arange(n)], SQUEEZE_FORCE, float(np.abs(speed).max()))


def _cube():
    from ges_core.objects.simple import box_asset

    return box_asset((CUBE_HALF,) * 3, object_id="lint/probe_cube")


def _cube_poses(hand: HandModel, q: np.ndarray) -> np.ndarray:
    """(F, 7) world poses of the cubes: a face through each tip point, facing back along its press direction."""
    import torch

    from ges_core.kinematics import shared_kinematics
    from ges_core.synthesis.physics.squeeze import press_directions
    from ges_core.transforms import pose_to_matrix

    d = hand.description
    tips = shared_kinematics(hand).points(
        torch.as_tensor(q)[None], list(d.tip_links), [f.tip_offset for f in d.fingers]
    )
    base = pose_to_matrix(HOVER)
    tips = tips[0].numpy() @ base[:3, :3].T + base[:3, 3]
    press = press_directions(d, tips)
    out = np.tile(HOVER, (len(tips), 1))
    out[:, :3] = tips + press * CUBE_HALF  # a cube is the same along every axis: only its centre matters
    return out


def check_tip_forces(
    hand: HandModel, sim_name: str, make_sim: Callable[[str, SceneConfig], SimBackend]
) -> list[LintProblem]:
    """Each fingertip presses at least :data:`PROBE_SHARE` of the squeeze force on the probe box in ``sim_name``."""
    forces, asked = probe_tip_forces(hand, make_sim, sim_name)
    d = hand.description
    out = []
    for finger, force in zip(d.fingers, forces, strict=True):
        if force >= PROBE_SHARE * asked:
            continue
        how = "did not touch its probe cube" if force < 0.05 else f"pressed only {force:.2f} N on its probe cube"
        out.append(
            LintProblem(
                "tip-force",
                f"finger '{finger.name}' {how} in {sim_name} under validation's squeeze (asks {asked:g} N per tip; "
                f"below {PROBE_SHARE * asked:g} N two tips do not hold the heavier demo objects)",
                _tip_force_fix(drive_time_constant(d, finger.joints), armature=bool(d.armature)),
            )
        )
    return out


DAMPED = 0.02
"""s: a finger whose drives' Kd/Kp is longer than this is told to lower its damping first. Measured with this probe
(2026-12-04): the blocked tip's force falls about as 1/Kd at a fixed Kp in both engines, e.g. the Inspire hand
(Kp 1000) 0.46 / 2.0 N at Kd/Kp 0.1 s and 5.8 / 8.4 N at 0.01 s (SAPIEN / PyBullet index finger), the example
gripper (Kp 20) 0.30 / 1.6 N at 0.1 s and 5.3 / 2.9 N at 0.0025 s, the built-in Shadow (Kp 1; then without its
MJCF's armature, which SAPIEN now applies: 4.5-6.8 N there at 0.1 s) 1.1-2.3 / 3.5-6.4 N at 0.1 s and 2.0-4.5 /
1.8-5.9 N at 0.01 s. Lower damping is not always better in every engine: the Shadow at 0.01 s
held 15 of the 20 real scans robustly in SAPIEN (13 at 0.1 s) but 4 in PyBullet (15), so the built-in keeps its
MJCF's damping and the advice says to check both."""


def drive_time_constant(d: HandDescription, joints: Sequence[str]) -> float:
    """s: the longest ``Kd / Kp`` among ``joints`` with a positive stiffness (0 when none has one)."""
    k = d.joint_index(list(joints))
    kp, kd = np.asarray(d.pd_stiffness)[k], np.asarray(d.pd_damping)[k]
    taus = kd[kp > 0] / kp[kp > 0]
    return float(taus.max()) if taus.size else 0.0


def _tip_force_fix(tau: float, *, armature: bool) -> str:
    stiffness = (
        "raise pd_stiffness of its joints (a drive presses Kp x the angle its target lies past contact, and the "
        "squeeze goes at most 0.6 rad past), check effort limits, and make its tip link collide (see tip-collision)"
    )
    if not armature:  # first: light links without their actuators' inertia chatter against a contact (SAPIEN)
        stiffness = (
            "declare the actuators' armature (reflected inertia, kg·m²) if the hand's source gives one (an MJCF's "
            "armature; docs/hands/format.md): without it a light finger link can chatter against the object and "
            f"press a fraction of its drive's force, as the Shadow did in SAPIEN (1.1-2.3 N of 5 N); else {stiffness}"
        )
    if tau <= DAMPED:
        return stiffness
    return (
        f"lower pd_damping of its joints first: their Kd/Kp is {tau:.3g} s, and a heavily damped drive presses far "
        f"less than Kp x the angle within the squeeze's 0.5 s (the probe force falls about as 1/Kd; Kd/Kp of about "
        f"0.01 s or less presses), then run Stage 1 in every engine you use, since a light finger with little damping "
        f"can hold less in PyBullet (the Shadow hand at Kd/Kp 0.01 s: robust on 4 of 20 real scans there instead of "
        f"15, on 15 instead of 13 in SAPIEN); otherwise {stiffness}"
    )
