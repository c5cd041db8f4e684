"""Pose conversion and a one-call pose read of every entity in a SAPIEN scene.

``Scene.pack_poses()`` returns every entity's pose as float32 ``(qw, qx, qy, qz, x, y, z)`` in
``scene.entities`` order, in about 2 µs for 30 entities, where reading one link's ``entity_pose``
and its ``p`` and ``q`` costs about 4 µs. The layout is undocumented, so :class:`PoseTable`
checks it against ``entity.pose`` when it is built and falls back to per-entity reads if it differs.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ges_core.errors import UnknownNameError
from ges_plugins.sims.sapien.engine import sapien

__all__ = ["PoseTable", "pose_array", "sapien_pose"]

_PACKED_TO_POSE = np.array([4, 5, 6, 0, 1, 2, 3])
"""Columns of a packed row (q, p) in our order (p, q)."""


def sapien_pose(pose: np.ndarray) -> sapien.Pose:
    """(7,) x, y, z, qw, qx, qy, qz -> sapien.Pose with a unit quaternion."""
    q = np.asarray(pose[3:], dtype=np.float64)
    return sapien.Pose(p=np.asarray(pose[:3], dtype=np.float32), q=(q / np.linalg.norm(q)).astype(np.float32))


def pose_array(pose: sapien.Pose) -> np.ndarray:
    """sapien.Pose -> (7,) float64 x, y, z, qw, qx, qy, qz."""
    return np.concatenate([pose.p, pose.q]).astype(np.float64)


class PoseTable:
    """Row of each hand link and of the object in one scene's packed poses; rebuilt when entities change."""

    def __init__(
        self, scene: sapien.Scene, hand: sapien.physx.PhysxArticulation | None, obj: sapien.Entity | None
    ) -> None:
        self._scene = scene
        self._entities = list(scene.entities)
        row_of = {entity.per_scene_id: i for i, entity in enumerate(self._entities)}
        links = hand.get_links() if hand is not None else []
        self._link_rows = {link.name: row_of[link.entity.per_scene_id] for link in links}
        self._object_index = _index([row_of[obj.per_scene_id]] if obj is not None else [])
        self._packed = self._layout_matches()
        self._queries: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray]] = {}

    def read(self, links: Sequence[str]) -> np.ndarray:
        """Poses of the named hand links, (L, 7), world frame (float32 values, as SAPIEN keeps them)."""
        return self._rows(self._link_index(tuple(links)))

    def read_object(self) -> np.ndarray:
        """Pose of the object, (7,), world frame."""
        return self._rows(self._object_index)[0]

    def _rows(self, index: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        rows, flat = index
        if self._packed:
            return np.frombuffer(self._scene.pack_poses(), dtype=np.float32)[flat].reshape(-1, 7)
        return np.stack([pose_array(self._entities[r].pose) for r in rows])

    def _link_index(self, links: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        index = self._queries.get(links)
        if index is None:
            unknown = [name for name in links if name not in self._link_rows]
            if unknown:
                raise UnknownNameError("hand link", unknown[0], self._link_rows)
            index = self._queries[links] = _index([self._link_rows[n] for n in links])
        return index

    def _layout_matches(self) -> bool:
        """True when ``pack_poses`` holds one (q, p) row per entity, in ``scene.entities`` order."""
        packed = np.frombuffer(self._scene.pack_poses(), dtype=np.float32)
        if packed.size != 7 * len(self._entities):
            return False
        expected = np.stack([pose_array(e.pose) for e in self._entities])
        return bool(np.allclose(packed.reshape(-1, 7)[:, _PACKED_TO_POSE], expected, atol=1e-6))


def _index(rows: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """(entity rows, flat indices of their (p, q) values in the packed float32 buffer)."""
    rows_array = np.array(rows, dtype=np.int64)
    return rows_array, (rows_array[:, None] * 7 + _PACKED_TO_POSE).ravel()
