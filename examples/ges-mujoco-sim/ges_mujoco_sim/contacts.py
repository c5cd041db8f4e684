"""Contact reads of one MuJoCo env: net force per hand link from a partner, and the touching pairs.

A scene step is ``substeps`` MuJoCo steps. After each one, :func:`add_substep_forces` adds every contact's force
into a body x body table; :func:`link_forces` reads the table divided by the number of substeps: the mean
force over the scene step, as SAPIEN's impulse over its step divided by the step (the last substep alone would
report one 1/960 s slice of it).

Forces: with elliptic cones (:data:`.model.CONE`) ``efc_force[efc_address : efc_address + 3]`` is a contact's
force in its frame (rows of ``contact.frame``: normal, first and second tangent). It acts on ``geom[1]``'s
body along +normal (from geom 0 to geom 1) and on ``geom[0]``'s body the opposite way (checked: a box resting
on the table plane, geom 0 the plane, reads +m g on the box; ``tests/test_sim_contract.py`` checks the weight).
"""

from __future__ import annotations

from collections.abc import Mapping

import mujoco
import numpy as np

from ges_core.sim import ContactPair

__all__ = ["add_substep_forces", "contact_pairs", "link_forces"]

_XYZ = np.arange(3)


def add_substep_forces(model: mujoco.MjModel, data: mujoco.MjData, table: np.ndarray) -> None:
    """Add the forces of ``data``'s present contacts to ``table`` (nbody, nbody, 3): ``table[a, b]`` is the
    force on body a from body b, world frame, N."""
    ncon = data.ncon
    if not ncon:
        return
    adr = data.contact.efc_address[:ncon]
    active = adr >= 0
    if not active.any():
        return
    local = data.efc_force[adr[active, None] + _XYZ]  # (n, 3) normal, tangent 1, tangent 2
    frames = data.contact.frame[:ncon][active].reshape(-1, 3, 3)
    force = np.einsum("nji,nj->ni", frames, local)  # world frame, on geom[1]'s body
    bodies = model.geom_bodyid[data.contact.geom[:ncon][active]]
    np.add.at(table, (bodies[:, 1], bodies[:, 0]), force)
    np.add.at(table, (bodies[:, 0], bodies[:, 1]), -force)


def link_forces(table: np.ndarray, bodies: list[int], partners: list[int] | None, substeps: int) -> np.ndarray:
    """(L, 3) mean contact force over the last scene step on each of ``bodies`` from ``partners`` (None: every
    body, the hand's other links included), world frame, N."""
    rows = table[bodies]  # (L, nbody, 3)
    total = rows.sum(axis=1) if partners is None else rows[:, partners].sum(axis=1)
    return total / substeps


def contact_pairs(
    model: mujoco.MjModel, data: mujoco.MjData, names: Mapping[int, tuple[str, str]]
) -> list[ContactPair]:
    """Every touching body pair in the last substep: deepest separation (m, negative = penetration) and summed
    normal force (N).

    names: body id -> (body, link) names (e.g. ``("hand", "palm")``, ``("table", "table")``).
    """
    pairs: dict[tuple[int, int], list[float]] = {}
    for i in range(data.ncon):
        adr = int(data.contact.efc_address[i])
        if adr < 0:
            continue
        b0, b1 = (int(b) for b in model.geom_bodyid[data.contact.geom[i]])
        sep, force = pairs.get((b0, b1), (np.inf, 0.0))
        pairs[(b0, b1)] = [min(sep, float(data.contact.dist[i])), force + float(data.efc_force[adr])]
    out = []
    for (b0, b1), (sep, force) in sorted(pairs.items()):
        (body_a, link_a), (body_b, link_b) = (names.get(b, ("unknown", str(b))) for b in (b0, b1))
        out.append(ContactPair(body_a, link_a, body_b, link_b, float(sep), float(force)))
    return out
