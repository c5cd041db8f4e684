"""The contact representation every hand shares.

A :class:`ContactSet` holds one contact per canonical finger slot (thumb, index, middle,
ring, little): a position and an outward surface normal, both in the object frame, in metres.
Hands map their own fingers onto these slots (see ``HandDescription.fingers`` and
``HandDescription.slot_fill``), which is what lets a grasp found for one hand retarget to
another.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ges_core.arrays import checked_array
from ges_core.errors import ArrayError, AssetError
from ges_core.paths import atomic_write_text

__all__ = ["FINGER_SLOTS", "ContactSet"]

FINGER_SLOTS: tuple[str, ...] = ("thumb", "index", "middle", "ring", "little")
"""Canonical finger slots, in the order every array of a :class:`ContactSet` uses."""

_FORMAT = "ges.contact_set/1"


@dataclass(frozen=True)
class ContactSet:
    """Five finger contacts on one object.

    positions: (5, 3) float64, object frame, metres; row i belongs to ``FINGER_SLOTS[i]``.
    normals: (5, 3) float64, object frame, unit outward surface normals.
    object_id: stable id of the object the contacts lie on.
    """

    positions: np.ndarray
    normals: np.ndarray
    object_id: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        shape, layout = (len(FINGER_SLOTS), 3), f"one row per slot: {', '.join(FINGER_SLOTS)}; object frame"
        pos = checked_array(self.positions, shape, "ContactSet: positions", layout=layout)
        nrm = checked_array(self.normals, shape, "ContactSet: normals", layout=layout)
        lengths = np.linalg.norm(nrm, axis=1)
        if np.any(lengths < 1e-9):
            raise ArrayError(f"ContactSet: normals of rows {np.flatnonzero(lengths < 1e-9).tolist()} are zero")
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "normals", nrm / lengths[:, None])

    def slot(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Position (3,) and normal (3,) of one finger slot, object frame."""
        i = FINGER_SLOTS.index(name)
        return self.positions[i], self.normals[i]

    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> ContactSet:
        """The same contacts in another frame: ``p' = R p + t``, ``n' = R n``."""
        rot = np.asarray(rotation, dtype=np.float64)
        pos = self.positions @ rot.T + np.asarray(translation, dtype=np.float64)
        return ContactSet(pos, self.normals @ rot.T, self.object_id, dict(self.meta))

    def to_dict(self) -> dict:
        """A JSON-ready dict (format tag, slots, positions, normals, object id, meta)."""
        return {
            "format": _FORMAT,
            "slots": list(FINGER_SLOTS),
            "object_id": self.object_id,
            "positions": self.positions.tolist(),
            "normals": self.normals.tolist(),
            "meta": self.meta,
        }

    @classmethod
    def from_dict(cls, data: dict) -> ContactSet:
        """Inverse of :meth:`to_dict`; rejects other formats and slot orders."""
        if data.get("format") != _FORMAT:
            raise AssetError(f"not a contact set: format is {data.get('format')!r}, expected {_FORMAT!r}")
        if tuple(data.get("slots", ())) != FINGER_SLOTS:
            raise AssetError(f"contact set slots {data.get('slots')} differ from {list(FINGER_SLOTS)}")
        return cls(
            np.array(data["positions"]), np.array(data["normals"]), data.get("object_id", ""), data.get("meta", {})
        )

    def save(self, path: str | Path) -> None:
        """Write as JSON, atomically (temporary file, then rename)."""
        atomic_write_text(path, json.dumps(self.to_dict(), indent=1))

    @classmethod
    def load(cls, path: str | Path) -> ContactSet:
        """Read a file written by :meth:`save`."""
        try:
            return cls.from_dict(json.loads(Path(path).read_text()))
        except (OSError, json.JSONDecodeError) as exc:
            raise AssetError(f"cannot read contact set {path}: {exc}") from exc
