"""The least friction coefficient at which any hand reaching from above can push an object up at all.

A point contact with Coulomb friction ``mu`` on a surface whose outward unit normal ``n`` faces up (``n_z > 0``)
pushes the object with ``f = N (-n) + t``, ``|t| <= mu N``, ``t`` perpendicular to ``n``. Its largest upward
component is ``N (mu sqrt(1 - n_z^2) - n_z)``: negative when ``mu < n_z / sqrt(1 - n_z^2) = tan(asin n_z)``. No
contact on such a surface -- fingertip, phalanx or palm -- can then carry any of the weight, and the normal cone of
an edge or apex between such faces faces up at least as steeply. Fingers do not reach below ``min_height`` (the
table; :class:`ges_core.synthesis.contacts.generate.ContactConfig`), so an object whose every surface sample above
it faces up more steeply than ``atan(mu)`` cannot be lifted at ``mu`` by any grasp:

    lift_friction_bound = tan(asin(min n_z over the samples at z >= min_height)),  0 if one faces sideways or down.

A necessary condition, not a sufficient one: balancing the torques and the hand's limited forces ask for more.
Sampling can only lower the bound (a missed steep sample cannot raise the minimum), so an object is never called
out of reach wrongly by a coarse cloud. On the procedural library at the robust trials' floor ``mu = 0.5``
(``atan 0.5 = 26.6 deg``) it singles out the squat cones and pyramids (sides tilted 27-37 deg from the vertical):
10 of the 280 objects, none of them robust before this bound was used. Stage 1 uses it to stop searching for a
placement that passes the friction trial (:mod:`ges_core.synthesis.run.worker`).

:func:`lift_capacity` asks the same of one contact set with torques balanced: the weight it holds per unit of squeeze
(``ContactConfig.lift_candidates`` ranks candidate grasps by it; measured in docs/synthesis/contacts.md).
:func:`held_weight` bounds the squeeze by the hand instead: the weight the contacts hold with every joint's torque
within its actuator's limit (``ges_core.synthesis.physics.capacity`` applies it to a grasp).
"""

from __future__ import annotations

import math

import numpy as np

from ges_core.arrays import checked_array
from ges_core.errors import ArrayError
from ges_core.synthesis.contacts.force_closure import cone_forces

__all__ = ["held_weight", "lift_capacity", "lift_friction_bound"]


def lift_friction_bound(points: np.ndarray, normals: np.ndarray, min_height: float) -> float:
    """The least friction coefficient at which a contact on the surface above ``min_height`` can push up (module docs).

    points, normals: (N, 3) surface samples and outward unit normals, resting frame (z up, table at z = 0), metres.
    Returns 0.0 when a sample above ``min_height`` faces sideways or down, ``inf`` when no sample is above it.
    """
    pts = checked_array(points, (None, 3), "lift_friction_bound: points", layout="resting frame, metres")
    nrm = checked_array(normals, (len(pts), 3), "lift_friction_bound: normals", layout="outward, one per point")
    reach = pts[:, 2] >= min_height
    if not reach.any():
        return math.inf
    lengths = np.linalg.norm(nrm[reach], axis=1)
    lowest = float(np.min(nrm[reach, 2] / np.maximum(lengths, 1e-12)))
    if lowest <= 0.0:
        return 0.0
    return float(lowest / math.sqrt(max(1.0 - lowest * lowest, 1e-24)))


def lift_capacity(
    positions: np.ndarray, normals: np.ndarray, mu: float, center: np.ndarray, *, radius: float, cone_edges: int = 8
) -> float:
    """The largest weight point contacts can hold per unit of their total normal force (0: none).

    positions, normals: (n, 3) contacts and outward unit normals, resting frame (z up), metres. Each contact pushes
    inside its linearized friction cone (``mu``, ``cone_edges``; :func:`.force_closure.cone_forces`, unit normal
    component per edge), the normal forces sum to at most 1, and the net force is ``(0, 0, W)`` with no net torque
    about ``center`` (the object's centre of mass; torques scaled by ``1 / radius``). Returns the largest such ``W``,
    by a linear program (scipy's HiGHS). Where force closure at ``mu`` holds it is above the Ferrari-Canny epsilon;
    it ranks grasps by how hard the hand must squeeze to lift, which epsilon (the worst direction) does not.
    """
    forces = cone_forces(np.asarray(normals, dtype=np.float64), mu, cone_edges)  # (n, e, 3)
    k = forces.shape[0] * forces.shape[1]
    return _largest_lift(positions, forces, center, np.ones((1, k)), np.ones(1), torque_divisor=radius)


def held_weight(
    positions: np.ndarray,
    normals: np.ndarray,
    mu: float,
    center: np.ndarray,
    jacobians: np.ndarray,
    joints: list[np.ndarray],
    effort: np.ndarray,
    *,
    cone_edges: int = 8,
) -> float:
    """The largest weight (N) point contacts can hold quasi-statically with every joint's torque within its limit.

    positions, normals: (n, 3) contacts and outward unit normals, resting frame (z up), metres. jacobians: (n, 3, K)
    d(contact point)/d(joint) for the hand's K joints, same frame; joints: per contact, the indices of the joints
    that move it (its finger's; a joint listed for several contacts sums their torques); effort: (K,) torque limits,
    N·m. Each contact pushes the object with ``f_i`` inside its linearized friction cone (``mu``, ``cone_edges``;
    :func:`.force_closure.cone_forces`), which costs the joints ``tau = sum_i J_i^T f_i`` (restricted to ``joints[i]``,
    ``|tau_k| <= effort_k``); the forces lift ``(0, 0, W)`` with no net torque about ``center`` (the centre of mass).
    Returns the largest such ``W`` by a linear program (scipy's HiGHS), 0 when none holds, ``inf`` when no torque
    limit binds (no listed joint moves the contacts). Gravity on the fingers, contacts off the fingertips (phalanges,
    palm) and the drives' own control law are not in it: it bounds what these fingertips can do within the
    actuators, not what a given closing achieves.
    """
    pos = checked_array(positions, (None, 3), "held_weight: positions", layout="resting frame, metres")
    nrm = checked_array(normals, (len(pos), 3), "held_weight: normals", layout="outward, one per contact")
    jac = checked_array(jacobians, (len(pos), 3, None), "held_weight: jacobians", layout="(n, 3, K) per contact")
    limits = checked_array(effort, (jac.shape[2],), "held_weight: effort", layout="(K,) torque limits, N·m")
    if len(joints) != len(pos):
        raise ArrayError(f"held_weight: {len(joints)} joint lists for {len(pos)} contacts; give one per contact")
    edges = cone_edges
    forces = cone_forces(nrm, mu, edges)  # (n, e, 3)
    torque = np.zeros((jac.shape[2], len(pos) * edges))  # joint torque per unit weight of each cone edge
    for i, idx in enumerate(joints):
        idx = np.asarray(idx, dtype=int)
        torque[idx, i * edges : (i + 1) * edges] += jac[i][:, idx].T @ forces[i].T
    used = np.flatnonzero(np.abs(torque).sum(axis=1) > 0)
    bound_rows = np.concatenate([torque[used], -torque[used]])  # |tau_k| <= effort_k
    return _largest_lift(pos, forces, center, bound_rows, np.concatenate([limits[used], limits[used]]))


def _largest_lift(
    positions: np.ndarray,
    forces: np.ndarray,
    center: np.ndarray,
    a_ub: np.ndarray,
    b_ub: np.ndarray,
    *,
    torque_divisor: float = 1.0,
) -> float:
    """The linear program of :func:`lift_capacity` and :func:`held_weight`: the largest ``W`` such that non-negative
    weights ``x`` of the cone edges ``forces`` (n, e, 3) at ``positions`` (n, 3) sum to the force ``(0, 0, W)`` with no
    torque about ``center`` (torques divided by ``torque_divisor``), under ``a_ub x <= b_ub`` ((m, n e), (m,)). 0 when
    infeasible, ``inf`` when unbounded."""
    from scipy.optimize import linprog  # lazily: every Stage 1 worker imports this module, few call this

    k = forces.shape[0] * forces.shape[1]
    a_eq = np.zeros((6, k + 1))
    a_eq[:3, :k] = forces.reshape(k, 3).T
    a_eq[2, k] = -1.0  # sum of forces - W e_z = 0
    lever = np.asarray(positions, dtype=np.float64) - np.asarray(center, dtype=np.float64)
    a_eq[3:, :k] = (np.cross(lever[:, None, :], forces) / torque_divisor).reshape(k, 3).T
    cost = np.zeros(k + 1)
    cost[k] = -1.0
    bounds = np.concatenate([a_ub, np.zeros((len(a_ub), 1))], axis=1)  # W itself is not bounded by them
    res = linprog(cost, A_ub=bounds, b_ub=b_ub, A_eq=a_eq, b_eq=np.zeros(6), bounds=(0, None), method="highs")
    if res.status == 3:  # unbounded: some contacts push without loading any limit
        return math.inf
    weight = float(res.x[k]) if res.status == 0 else 0.0
    return weight if weight > 0.0 else 0.0  # never -0.0
