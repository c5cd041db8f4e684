"""Contact reads of one SAPIEN scene: a fast per-link force sum and a slow pair listing.

SAPIEN lists every shape pair within the contact offset (1 cm by default), about four points
each, and reading a point from Python costs about a microsecond. The fast path therefore looks up
each pair's two bodies in a cached map first and touches points only for the few pairs between a
requested hand link and the requested partner. ``PhysxContactPoint.impulse`` is the impulse on
``contact.bodies[0]`` over the last step (checked: a resting box gets +m g from the table).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ges_core.errors import UnknownNameError
from ges_core.sim import ContactPair, ContactPartner
from ges_plugins.sims.sapien.engine import sapien

__all__ = ["TOUCH_DISTANCE", "ContactReader"]

TOUCH_DISTANCE = 5e-4
"""Pairs closer than this (m) count as touching in :meth:`ContactReader.pairs`. A resting box shows
separations of about 1e-7 m; pairs that are only inside the 1 cm contact offset show 1-20 mm."""

Body = sapien.physx.PhysxRigidBaseComponent
_Query = tuple[dict[Body, int], "frozenset[Body] | None", "np.ndarray | None"]


class ContactReader:
    """Who is who among the bodies of one scene, and the contact reads built on it."""

    def __init__(self, scene: sapien.Scene, table: Body, timestep: float) -> None:
        self._system = scene.physx_system
        self._table = table
        self._inv_dt = 1.0 / timestep
        self._links: dict[Body, str] = {}
        self._object: Body | None = None
        self._object_name = ""
        self._queries: dict[tuple[tuple[str, ...], str], _Query] = {}
        self._stale = False
        """True between replacing a body and the next step: PhysX's contact list still names the
        removed body, and touching it from Python segfaults, so reads see no contacts until then."""

    def after_step(self) -> None:
        """The scene stepped: the contact list is current again."""
        self._stale = False

    def set_hand(self, links: dict[str, Body]) -> None:
        """Register the hand's link bodies by name."""
        self._links = {body: name for name, body in links.items()}
        self._queries.clear()
        self._stale = True

    def set_object(self, body: Body | None, name: str = "") -> None:
        """Register the current object body (None: no object)."""
        self._object, self._object_name = body, name
        self._queries.clear()
        self._stale = True

    def forces(self, links: Sequence[str], partner: ContactPartner) -> np.ndarray:
        """Net contact force on each named link from ``partner`` over the last step, (L, 3), world frame, N."""
        slots, partners, rows = self._query(tuple(links), partner)
        out = np.zeros((len(slots), 3))
        for contact in () if self._stale else self._system.get_contacts():
            body0, body1 = contact.bodies
            slot0, slot1 = slots.get(body0), slots.get(body1)
            if slot0 is not None and (partners is None or body1 in partners):
                out[slot0] += _impulse(contact)
            if slot1 is not None and (partners is None or body0 in partners):
                out[slot1] -= _impulse(contact)
        out *= self._inv_dt
        return out if rows is None else out[rows]

    def _query(self, links: tuple[str, ...], partner: str) -> _Query:
        """(link body -> row of the unique links, allowed partners or None for any, rows of ``links`` or None)."""
        key = (links, partner)
        if key not in self._queries:
            by_name = {name: body for body, name in self._links.items()}
            unknown = [name for name in links if name not in by_name]
            if unknown:
                raise UnknownNameError("hand link", unknown[0], by_name)
            unique = list(dict.fromkeys(links))
            slots = {by_name[name]: i for i, name in enumerate(unique)}
            rows = None if len(unique) == len(links) else np.array([unique.index(n) for n in links])
            self._queries[key] = (slots, self._partners(partner), rows)
        return self._queries[key]

    def _partners(self, partner: str) -> frozenset[Body] | None:
        if partner == "any":
            return None
        if partner == "table":
            return frozenset([self._table])
        return frozenset([self._object] if self._object is not None else [])

    def pairs(self) -> list[ContactPair]:
        """Every pair closer than :data:`TOUCH_DISTANCE` or pushing, with names (slow: reads every point)."""
        out = []
        for contact in () if self._stale else self._system.get_contacts():
            points = contact.points
            if not points:
                continue
            separation = min(p.separation for p in points)
            normal_impulse = sum(float(np.dot(p.impulse, p.normal)) for p in points)
            force = abs(normal_impulse) * self._inv_dt
            if separation < TOUCH_DISTANCE or force > 0.0:
                out.append(self._pair(contact.bodies, separation, force))
        return out

    def _pair(self, bodies: Sequence[Body], separation: float, force: float) -> ContactPair:
        (body_a, link_a), (body_b, link_b) = (self._name(b) for b in bodies)
        return ContactPair(body_a, link_a, body_b, link_b, float(separation), float(force))

    def _name(self, body: Body) -> tuple[str, str]:
        if body in self._links:
            return "hand", self._links[body]
        if body == self._object:
            return "object", self._object_name
        if body == self._table:
            return "table", "table"
        return "unknown", body.name


def _impulse(contact: sapien.physx.PhysxContact) -> np.ndarray:
    """Sum of the contact's point impulses on ``bodies[0]``, (3,), N·s."""
    total = np.zeros(3)
    for point in contact.points:
        total += point.impulse
    return total
