"""SAPIEN-like joint drives and friction on top of PyBullet's motors and friction rule.

**PD drives.** SAPIEN (PhysX) drives a joint with an *implicit* spring-damper in physical units:
over one step ``dt`` the drive force is ``f = Kp (q* - q') - Kd v'``, evaluated at the *next*
state, so a joint of effective inertia ``I`` moves to ``v' = v + alpha (v_t - v)`` with
``v_t = Kp (q* - q) / (Kd + Kp dt)`` (the velocity at which the drive force vanishes),
``c = dt (Kd + Kp dt)`` and ``alpha = c / (I + c)``. For a dexterous hand's light links
(``I`` ~ 1e-4 kg m^2) and the usual gains (Allegro: Kp = 400 N m/rad, Kd = 10 N m s/rad) this
is heavily overdamped (``alpha`` ~ 1): an explicit PD (PyBullet's ``TORQUE_CONTROL`` or
``PD_CONTROL``) explodes, and PyBullet's ``STABLE_PD_CONTROL`` drove Allegro joints the wrong way
and past their limits when we tried it (PyBullet 3.2.7).

PyBullet's ``POSITION_CONTROL`` motor is a velocity constraint, solved together with the contacts,
that seeks ``v' = positionGain (q* - q) / dt + (1 - velocityGain) v* + velocityGain targetVelocity``
with at most ``force``, where ``v*`` is the joint velocity after gravity and applied forces
(Bullet's ``btMultiBodyJointMotor``; measured). Every physics step we send:

* ``positionGain = alpha Kp dt / (Kd + Kp dt)``, ``velocityGain = alpha``, ``targetVelocity = 0``:
  the servo seeks ``v' = alpha v_t + (1 - alpha) v*``, which is SAPIEN's implicit step including
  gravity, with ``I`` the diagonal of the joint-space mass matrix at the start pose;
* ``force = |Kp (q* - q)|``: the spring force at the current position. A joint blocked by
  contact therefore pushes with the spring force, as SAPIEN's implicit drive does (its force
  ``Kp (q* - q') - (Kd + Kp dt) v'`` at a blocked ``v' = 0``), instead of PyBullet's usual "hold
  position with up to the effort limit". (SAPIEN's own blocked drive only approximates it: measured
  +15 % at 20 solver iterations, -26 % at 10, +104 % at 100; see ``docs/simulators.md``.) Where the
  joint ends the step moving toward its target, the implicit force is below the spring force, so
  the limit does not bind and the servo makes SAPIEN's step exactly (free motion: unchanged).

  The limit must not depend on the joint's *current* velocity. It used to be the PD force at the
  current state, ``|Kp (q* - q) - (Kd + Kp dt) v|``: an explicit damping term, and on a light link
  an explicit term rings. Measured (Shadow, Kp = 1, Kd = 0.1, I ~ 1e-6 kg m^2 at the distal
  joints): a thumb tip pressed on a box alternated every step between v = -1.4 and +2.9 rad/s with
  a limit of 0.004 and 0.46 N m, its torque a tenth of the spring force or less; fingertip grasps that
  SAPIEN lifts slid out (of 7 Shadow grasps SAPIEN held, PyBullet validation held 0; 6 with
  this limit).
  PyBullet's reported velocity of a link in contact is no guide either: it includes motion that
  something (we think the contact's split-impulse position correction) takes back, e.g. a blocked
  FFJ1 read +1.1 to +1.7 rad/s while its angle stayed within 0.04 rad for 40 steps. The price: a
  joint pushed *away* from its target within one step is braked with at most the spring force, not
  the spring force plus ``(Kd + Kp dt) v'`` (the servo still seeks SAPIEN's velocity, so this is
  capped, not lost).

  The floating wrist's six virtual joints (which carry the whole hand) keep the PD force at the current
  state, ``|Kp (q* - q) - (Kd + Kp dt) v|``: with the spring limit there too, the scripted expert of the
  Stage 2 environment dropped the Allegro test box during the carry in PyBullet
  (``tests/test_env_grasp_env.py::test_scripted_expert_lifts_the_box``); with it the box is carried as
  in SAPIEN. The ringing was measured on the light finger links only; why the wrist needs the old
  limit is not understood yet. Two variants were measured and rejected: the damping term only while a
  joint moves away from its target (drops the same box), and the velocity taken from the change of
  position over the last step (the Shadow finger on the table still rings, 0.57 rad/s rms).

  Known cost: fingers that hit an object while still far from their targets hit harder. Allegro fingers
  (Kp = 400) still closing from the open pose when the hand arrived (a 5-step reach in the Stage 2
  environment) shot the test box out of the hand in PyBullet (SAPIEN and the earlier limit keep it);
  with the fingers settled at the pre-grasp first (20 reach steps), and in Stage 1 validation, the box
  stays (tests on both engines).

**Actuator caps** (``SimBackend.set_drive_limits``): the backend clips this per-step ``force`` of each hand
joint at the actuator's torque, ``min(|Kp (q* - q)|, cap)``, so a blocked finger pushes with at most the cap,
as SAPIEN's drive ``force_limit`` does (``tests/test_sim_contract.py``: within 10 % of cap / lever in both).

Static loads: a contact (a constraint) meets exactly the spring force. Gravity on the hand (off by
default) is exact for the floating wrist (the whole hand falls with ``g``: sag ``m g / Kp``), but a
finger loaded through its children settles at ``I_j (M^-1 tau)_j / Kp`` instead of ``tau_j / Kp``
(Allegro joint_1.0 at Kp = 1: 0.097 vs 0.058 rad; at Kp = 400 both are below 2e-4 rad). Seeking
``alpha v_t + (1 - alpha) v`` with ``velocityGain = 1`` gets the mean sag right but rings with
period two under gravity (measured with the earlier force limit and its explicit damping term),
so we keep the smooth form.

A target beyond a joint limit: PyBullet clips ``POSITION_CONTROL`` targets to the limits itself
(measured), so the servo seeks the limit, while the force limit keeps the raw target's spring
force, as SAPIEN's drive does against its hard limit.

Measured against SAPIEN 3.0.3 (Allegro joint_1.0 stepped 0 -> 1 rad, 1/120 s, no contacts): at
Kp, Kd = 0.5, 0.01 both follow the same underdamped curve within 0.05 rad; at 400, 10 SAPIEN is
ahead by up to 0.05 rad over the first 3 steps (its TGS solver integrates the drive over
sub-iterations), both settle within 0.1 s.

**Friction.** PhysX combines two materials' coefficients by their *average* (its default
combine mode, which SAPIEN keeps); Bullet multiplies them. With three bodies (hand, object,
table) the three per-body values whose pairwise products equal the pairwise averages exist
and are computed by :func:`product_friction`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

__all__ = ["ImplicitPD", "product_friction"]

_MIN_PAIR_FRICTION = 1e-9
"""Floor of a pairwise friction in :func:`product_friction`; only guards a division by zero."""


@dataclass(frozen=True)
class ImplicitPD:
    """PD gains of J joints in physical units and the PyBullet motor settings that mimic them.

    stiffness: (J,) N m/rad (N/m for prismatic joints); damping: (J,) N m s/rad (N s/m);
    inertia: (J,) effective inertia of each joint, kg m^2 (kg), the diagonal of the joint-space
    mass matrix at the start pose; dt: physics step, seconds; spring_limit: (J,) bool, joints whose
    force limit is the spring force alone (the hand's joints), the others keep the PD force at the
    current state (the floating wrist's virtual joints; module docs). None: every joint.
    """

    stiffness: np.ndarray
    damping: np.ndarray
    inertia: np.ndarray
    dt: float
    spring_limit: np.ndarray | None = None

    @property
    def blend(self) -> np.ndarray:
        """(J,) ``alpha = c / (I + c)``, ``c = dt (Kd + Kp dt)``: fraction of the gap to ``v_t`` closed per step."""
        c = self.dt * self._velocity_coefficient
        return np.divide(c, self.inertia + c, out=np.ones_like(c), where=(self.inertia + c) > 0)

    @property
    def position_gains(self) -> np.ndarray:
        """(J,) PyBullet ``positionGains``: ``alpha Kp dt / (Kd + Kp dt)``."""
        closed = np.divide(
            self.stiffness * self.dt,
            self._velocity_coefficient,
            out=np.zeros_like(self.stiffness),
            where=self._velocity_coefficient > 0,
        )
        return self.blend * closed

    @property
    def velocity_gains(self) -> np.ndarray:
        """(J,) PyBullet ``velocityGains`` (with zero ``targetVelocities``): ``alpha``."""
        return self.blend

    def force_limits(self, q: np.ndarray, v: np.ndarray, target: np.ndarray) -> np.ndarray:
        """(E, J) PyBullet ``forces``: ``|Kp (q* - q)|``, the spring force at ``q`` (E, J), on the
        ``spring_limit`` joints; ``|Kp (q* - q) - (Kd + Kp dt) v|``, the PD force at ``q``, ``v``, on the others."""
        return np.abs(self.stiffness * (target - q) - self._limit_damping * v)

    @cached_property
    def _limit_damping(self) -> np.ndarray:
        """(J,) the force limit's velocity coefficient: ``Kd + Kp dt``, 0 on the ``spring_limit`` joints."""
        if self.spring_limit is None:
            return np.zeros_like(self.stiffness)
        return np.where(self.spring_limit, 0.0, self._velocity_coefficient)

    @cached_property
    def _velocity_coefficient(self) -> np.ndarray:
        return self.damping + self.stiffness * self.dt


def product_friction(hand: float, obj: float, table: float) -> tuple[float, float, float]:
    """Per-body Bullet friction (hand, object, table) whose products are PhysX's pairwise averages.

    Bullet uses ``mu_a * mu_b`` for a touching pair; PhysX ``(mu_a + mu_b) / 2``. Hand-hand
    contacts get ``k_hand**2`` instead of ``hand`` (a fourth equation three values cannot meet).
    """
    ho = max((hand + obj) / 2, _MIN_PAIR_FRICTION)
    ot = max((obj + table) / 2, _MIN_PAIR_FRICTION)
    ht = max((hand + table) / 2, _MIN_PAIR_FRICTION)
    k_obj = math.sqrt(ho * ot / ht)
    return ho / k_obj, k_obj, ot / k_obj
