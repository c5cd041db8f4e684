"""Contact reads of one MuJoCo env: net force per hand link from a partner, and the touching pairs.

``MjData.contact`` holds the contacts found at the start of the last ``mj_step`` and ``efc_force`` the
forces that acted over it (the reads do not run the collision pipeline again). ``mj_contactForce`` gives a
contact's force in its frame (rows of ``contact.frame``: normal, first and second tangent); the force acts on
``geom[1]``'s body along +normal (from geom 0 to geom 1) and on ``geom[0]``'s body the opposite way (checked:
a box resting on the table plane, geom 0 the plane, reads +m g on the box).
"""

from __future__ import annotations

from collections.abc import Mapping

import mujoco
import numpy as np

from ges_core.sim import ContactPair

__all__ = ["contact_pairs", "link_forces"]


def link_forces(
    model: mujoco.MjModel, data: mujoco.MjData, slots: Mapping[int, int], partners: frozenset[int] | None, rows: int
) -> np.ndarray:
    """(rows, 3) net contact force on hand bodies from ``partners``, world frame, N.

    slots: body id -> output row; partners: body ids whose contacts count (None: every body, the hand's
    other links included: a link-link contact then counts on both links, with opposite signs).
    """
    out = np.zeros((rows, 3))
    ncon = data.ncon
    if not ncon:
        return out
    bodies = model.geom_bodyid[data.contact.geom[:ncon]]  # (ncon, 2)
    wrench = np.zeros(6)
    for i in range(ncon):
        b0, b1 = int(bodies[i, 0]), int(bodies[i, 1])
        s0 = slots.get(b0) if partners is None or b1 in partners else None
        s1 = slots.get(b1) if partners is None or b0 in partners else None
        if (s0 is None and s1 is None) or data.contact.efc_address[i] < 0:
            continue
        mujoco.mj_contactForce(model, data, i, wrench)
        force = data.contact.frame[i].reshape(3, 3).T @ wrench[:3]  # on body b1
        if s1 is not None:
            out[s1] += force
        if s0 is not None:
            out[s0] -= force
    return out


def contact_pairs(
    model: mujoco.MjModel, data: mujoco.MjData, names: Mapping[int, tuple[str, str]]
) -> list[ContactPair]:
    """Every touching body pair: deepest separation (m, negative = penetration) and summed normal force (N).

    names: body id -> (body, link) names (e.g. ``("hand", "palm")``, ``("table", "table")``).
    """
    pairs: dict[tuple[int, int], list[float]] = {}
    wrench = np.zeros(6)
    for i in range(data.ncon):
        if data.contact.efc_address[i] < 0:
            continue
        b0, b1 = (int(b) for b in model.geom_bodyid[data.contact.geom[i]])
        mujoco.mj_contactForce(model, data, i, wrench)
        sep, force = pairs.get((b0, b1), (np.inf, 0.0))
        pairs[(b0, b1)] = [min(sep, float(data.contact.dist[i])), force + float(wrench[0])]
    out = []
    for (b0, b1), (sep, force) in sorted(pairs.items()):
        (body_a, link_a), (body_b, link_b) = (names.get(b, ("unknown", str(b))) for b in (b0, b1))
        out.append(ContactPair(body_a, link_a, body_b, link_b, float(sep), float(force)))
    return out
