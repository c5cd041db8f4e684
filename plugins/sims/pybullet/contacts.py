"""Contact reads: net force per hand link from a partner body, and a slow list of touching pairs.

PyBullet's ``getContactPoints(bodyA, bodyB)`` row ``c`` holds, for one point: ``c[3]`` the link of
A, ``c[7]`` the contact normal on B (pointing from B toward A), ``c[9]`` the normal force, and
``c[10]``/``c[12]`` the friction forces along ``c[11]``/``c[13]``, all forces *on A*, world
frame, newtons (checked: a box pushed sideways on the table reads its weight up and a
friction force opposite the push).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ges_core.sim import ContactPair

from .engine import p

__all__ = ["TOUCH_SEPARATION", "contact_pairs", "link_forces"]

TOUCH_SEPARATION = 5e-4
"""m: contact points further apart than this, and pushing with no force, are not 'touching' in
:func:`contact_pairs` (the SAPIEN backend's value). PyBullet also lists points up to its contact
threshold (~2 cm) ahead of a collision; resting contacts sit at about -5e-5 m."""


def link_forces(cid: int, hand: int, partners: Sequence[int], link_ids: Sequence[int]) -> np.ndarray:
    """(L, 3) net contact force on each hand link in ``link_ids`` from the ``partners`` bodies, world, N.

    ``partners`` may hold ``hand`` itself: a contact between two hand links then counts on both
    (on link A as listed, on link B with the opposite sign).
    """
    slot = {link: i for i, link in enumerate(link_ids)}
    out = [[0.0, 0.0, 0.0] for _ in link_ids]  # plain floats: a handful of points, numpy would cost more
    for body in partners:
        for c in p.getContactPoints(bodyA=hand, bodyB=body, physicsClientId=cid):
            sides = [(slot.get(c[3]), 1.0)] + ([(slot.get(c[4]), -1.0)] if body == hand else [])
            (n, f1, f2), (u, d1, d2) = (c[9], c[10], c[12]), (c[7], c[11], c[13])
            force = [n * u[k] + f1 * d1[k] + f2 * d2[k] for k in range(3)]
            for i, sign in sides:
                if i is not None:
                    out[i] = [total + sign * f for total, f in zip(out[i], force, strict=True)]
    return np.array(out)


def contact_pairs(cid: int, names: dict[int, str], link_names: dict[int, dict[int, str]]) -> list[ContactPair]:
    """Every touching or pushing (body, link) pair of one scene, deepest separation and summed normal force.

    names: body id -> body name; link_names: body id -> {link index -> link name} (bodies with
    one link may be absent: their link is named after the body).
    """
    pairs: dict[tuple[int, int, int, int], list[float]] = {}
    for c in p.getContactPoints(physicsClientId=cid):
        if c[8] > TOUCH_SEPARATION and c[9] <= 0.0:
            continue
        key = (c[1], c[3], c[2], c[4])
        sep, force = pairs.get(key, (np.inf, 0.0))
        pairs[key] = [min(sep, c[8]), force + c[9]]
    named: dict[tuple[str, str, str, str], list[float]] = {}  # the object's shape links are all the link "object"
    for (a, la, b, lb), (sep, force) in sorted(pairs.items()):
        key = (names.get(a, str(a)), link_names.get(a, {}).get(la, names.get(a, str(a))),
               names.get(b, str(b)), link_names.get(b, {}).get(lb, names.get(b, str(b))))  # fmt: skip
        merged = named.setdefault(key, [np.inf, 0.0])
        merged[0], merged[1] = min(merged[0], sep), merged[1] + force
    return [
        ContactPair(body_a=ba, link_a=la, body_b=bb, link_b=lb, separation=float(sep), force=float(force))
        for (ba, la, bb, lb), (sep, force) in named.items()
    ]
