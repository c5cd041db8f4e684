"""Wrist placement of grasp retargeting: topology descriptors, wrist rotation, wrist origin.

Everything here is batched over B contact sets and lives in the object frame (metres). The
equations and our readings of the paper are in ``docs/synthesis/retargeting.md``:

* ``n_palm``: unit normal of the contacts' best-fit plane (smallest right singular vector of the
  centred contacts), signed to point from the palm toward the contacts.
* ``d_palm`` (grasp axis, "wrist -> middle"): thumb contact -> middle contact, projected on the plane.
* ``u_palm`` (lateral axis, "middle -> little"): completes the frame, ``u = chi * (n x d)``, with the
  sign of ``n`` chosen so that ``u`` points from the index/middle contacts toward ring/little;
  ``chi`` = +1 for a right hand (``n = d x u``), -1 for a left hand.
* ``R_wrist = [d u n] Rx(-chi roll) Ry(-pitch) [f l p]^T``: the hand's declared finger direction
  ``f`` goes to ``d``, its palm normal ``p`` to ``n``, then the constant coupling: pitch tilts the
  fingers toward the object (the wrist backs away), roll pronates (the palm turns toward the little
  finger side, the thumb side toward the object).
* ``O_palm = O_center - (3/4) l_p n_palm`` (the paper's ``+[0, 0, 3 l_p/4]`` for a top-down grasp);
  the hand's knuckle centre goes there, then ``y_d`` shifts the hand along its own finger axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ges_core.arrays import checked_array
from ges_core.contact import FINGER_SLOTS
from ges_core.errors import ArrayError, AssetError, SynthesisError
from ges_core.hand import HandDescription

__all__ = [
    "HandFrame",
    "TopologyDescriptors",
    "check_contact_array",
    "check_handedness_fingers",
    "contact_problems",
    "coupling_rotation",
    "hand_frame",
    "topology_descriptors",
    "wrist_poses",
]

THUMB, INDEX, MIDDLE, RING, LITTLE = range(len(FINGER_SLOTS))

MIN_SPREAD = 1e-3
"""Metres: contacts whose second principal extent (or thumb-middle distance in the plane, or lateral
spread) is below this give no palm plane or axis; such contact sets are rejected as degenerate."""


@dataclass(frozen=True)
class TopologyDescriptors:
    """Grasp topology G = (F, n_palm, d_palm, u_palm) of B contact sets, object frame."""

    contacts: np.ndarray
    """(B, 5, 3) contact positions F, slots in FINGER_SLOTS order, metres."""
    center: np.ndarray
    """(B, 3) O_center, the contacts' centroid, metres."""
    palm_normal: np.ndarray
    """(B, 3) n_palm, unit, from the palm toward the contacts."""
    grasp_axis: np.ndarray
    """(B, 3) d_palm, unit, thumb -> middle in the palm plane."""
    lateral_axis: np.ndarray
    """(B, 3) u_palm, unit, toward the little finger; (d, u, n) is right-handed for chi = +1."""

    @property
    def basis(self) -> np.ndarray:
        """(B, 3, 3) columns d, u, n."""
        return np.stack([self.grasp_axis, self.lateral_axis, self.palm_normal], axis=-1)


@dataclass(frozen=True)
class HandFrame:
    """What wrist placement needs to know about a hand, in its wrist-link frame (open pose)."""

    finger_direction: np.ndarray
    """(3,) f, unit (``WristConvention.finger_direction``)."""
    palm_normal: np.ndarray
    """(3,) p, unit, made orthogonal to f."""
    knuckle_center: np.ndarray
    """(3,) mean base (first keypoint) of the non-thumb fingers, metres."""
    chirality: float
    """+1 right hand, -1 left hand: sign of (f x lateral) . p, lateral = middle tip -> little-slot tip."""
    middle_finger_length: float
    """l_p, metres."""

    @property
    def basis(self) -> np.ndarray:
        """(3, 3) columns f, l, p with l = chi (p x f): the hand's own (d, u, n)."""
        lateral = self.chirality * np.cross(self.palm_normal, self.finger_direction)
        return np.stack([self.finger_direction, lateral, self.palm_normal], axis=-1)


def check_contact_array(positions: np.ndarray) -> np.ndarray:
    """(B, 5, 3) float64 ``positions`` (or (5, 3) -> (1, 5, 3)); ArrayError on shape or NaN."""
    shape = (len(FINGER_SLOTS), 3) if np.ndim(positions) == 2 else (None, len(FINGER_SLOTS), 3)
    layout = f"slots {', '.join(FINGER_SLOTS)}, object frame; check the contact generator"
    pos = checked_array(positions, shape, "contact positions", layout=layout)
    pos = pos[None] if pos.ndim == 2 else pos
    if len(pos) == 0:
        raise ArrayError("contact positions: no contact set given (B = 0)")
    return pos


def contact_problems(positions: np.ndarray) -> list[str | None]:
    """Per contact set of ``positions`` (B, 5, 3): None, or why it gives no palm frame."""
    _, _, _, _, ok = _frame_parts(check_contact_array(positions))
    return [next((what for what, mask in ok.items() if not mask[b]), None) for b in range(len(positions))]


def topology_descriptors(positions: np.ndarray, chirality: float = 1.0) -> TopologyDescriptors:
    """Descriptors of B contact sets ``positions`` (B, 5, 3), object frame, metres.

    chirality: +1 right hand, -1 left hand (see :class:`HandFrame`).
    Raises SynthesisError(reason="degenerate_contacts") naming the first bad set when the contacts
    are (nearly) collinear or the thumb, middle and ring/little contacts give no axes.
    """
    pos = check_contact_array(positions)
    center, normal, d, lateral_raw, ok = _frame_parts(pos)
    for what, mask in ok.items():
        if not mask.all():
            first = int(np.flatnonzero(~mask)[0])
            raise SynthesisError(
                f"grasp retargeting: contact set {first}: {what} (spread < {MIN_SPREAD * 1000:.0f} mm); "
                "the contact generator must give five contacts spanning a plane",
                reason="degenerate_contacts",
            )
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    sign = np.sign(np.sum(np.cross(d, lateral_raw) * normal, axis=1, keepdims=True))
    normal = chirality * sign * normal  # n = chi (d x u): the palm faces the contacts
    lateral = chirality * np.cross(normal, d)
    return TopologyDescriptors(pos, center, normal, d, lateral)


def _frame_parts(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Centroid, unsigned plane normal, raw grasp and lateral axes (B, 3) each, and the checks' masks."""
    center = pos.mean(axis=1)
    _, sing, vt = np.linalg.svd(pos - center[:, None], full_matrices=False)
    normal = vt[:, 2]
    d = _project(pos[:, MIDDLE] - pos[:, THUMB], normal)
    d_len = np.linalg.norm(d, axis=1)
    d_unit = d / np.maximum(d_len, 1e-12)[:, None]
    lateral = (pos[:, RING] + pos[:, LITTLE] - pos[:, INDEX] - pos[:, MIDDLE]) / 2
    lateral = _project(lateral, d_unit)
    ok = {
        "the contacts are (nearly) collinear: no palm plane": sing[:, 1] >= MIN_SPREAD,
        "thumb and middle contacts coincide in the palm plane": d_len >= MIN_SPREAD,
        "no lateral spread from index/middle to ring/little": np.linalg.norm(lateral, axis=1) >= MIN_SPREAD,
    }
    return center, normal, d, lateral, ok


def coupling_rotation(roll_deg: float, pitch_deg: float, chirality: float) -> np.ndarray:
    """(3, 3) Rx(-chi roll) Ry(-pitch) in the (d, u, n) basis: pronation about d, then pitch about u."""
    a, b = np.radians(-chirality * roll_deg), np.radians(-pitch_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    return rx @ ry


def wrist_poses(
    topo: TopologyDescriptors,
    hand: HandFrame,
    *,
    roll_deg: float,
    pitch_deg: float,
    palm_distance: float,
    y_d: float,
) -> np.ndarray:
    """(B, 4, 4) wrist-link poses in the object frame.

    palm_distance: O_palm lies this many l_p behind O_center along -n_palm (paper: 3/4).
    y_d: metres along the hand's finger direction (the paper's wrist y axis); > 0 moves the hand
        toward its fingertips.
    """
    rot = topo.basis @ coupling_rotation(roll_deg, pitch_deg, hand.chirality) @ hand.basis.T
    o_palm = topo.center - palm_distance * hand.middle_finger_length * topo.palm_normal
    origin = o_palm + rot @ (y_d * hand.finger_direction - hand.knuckle_center)
    out = np.zeros((len(rot), 4, 4))
    out[:, :3, :3], out[:, :3, 3], out[:, 3, 3] = rot, origin, 1.0
    return out


def check_handedness_fingers(description: HandDescription) -> None:
    """AssetError when one finger serves both the middle and the little slot (a two-finger gripper's
    ``slot_fill``): the hand frame's left and right come from those two fingertips (:func:`hand_frame`), so Stage 1
    cannot place such a hand. Pure (no kinematics): run before a Stage 1 run creates its dataset."""
    middle, little = description.finger_for_slot("middle"), description.finger_for_slot("little")
    if middle is little:
        raise AssetError(
            f"hand '{description.name}': one finger ('{middle.name}') serves both the middle and the little slot, "
            "and Stage 1 tells the palm's left from its right by those two fingertips, so it cannot place this "
            "hand; it needs two different fingers there (slot_fill), i.e. at least three fingers with the thumb"
        )


def hand_frame(description: HandDescription, wrist_points: dict[str, np.ndarray]) -> HandFrame:
    """A HandFrame from the hand's description and open-pose points in its wrist frame.

    wrist_points: "knuckles" (N, 3) non-thumb finger bases, "middle_tip" (3,), "little_tip" (3,).
    """
    check_handedness_fingers(description)
    w = description.wrist
    f = np.asarray(w.finger_direction, dtype=np.float64)
    f /= np.linalg.norm(f)
    p = np.asarray(w.palm_normal, dtype=np.float64)
    p = p - (p @ f) * f
    p /= np.linalg.norm(p)
    handed = np.cross(f, wrist_points["little_tip"] - wrist_points["middle_tip"]) @ p
    if abs(handed) < MIN_SPREAD:
        raise AssetError(
            f"hand '{description.name}': its middle and little-slot fingertips are not side by side across the "
            "palm at the open pose, so left/right cannot be told; check wrist.palm_normal/finger_direction"
        )
    knuckles = np.asarray(wrist_points["knuckles"], dtype=np.float64)
    return HandFrame(f, p, knuckles.mean(axis=0), float(np.sign(handed)), description.middle_finger_length)


def _project(v: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(B, 3) v minus its component along the unit ``normal``."""
    return v - np.sum(v * normal, axis=1, keepdims=True) * normal
