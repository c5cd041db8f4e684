"""Arguments at the :class:`ges_core.sim.SimBackend` boundary: env ids, row counts, poses and wrist coordinates.

Every backend's public per-env methods check their arguments here, once, in the core (``SimBackend``
calls these before its engine hooks), so two engines cannot drift apart in what they accept. What a
mistake raises:

* ``env_ids`` out of range, repeated, not integers: :class:`~ges_core.errors.ConfigError` (:func:`env_id_list`);
* an array with the wrong shape (rows that do not match ``env_ids`` included), NaN or inf, a zero
  quaternion: :class:`~ges_core.errors.ArrayError` (:func:`check_env_rows`, :mod:`ges_core.arrays`).

A floating hand's base is driven through six virtual joints (:data:`ges_core.urdf.WRIST_JOINTS`):
slides along world x, y, z (m), then hinges rx, ry, rz (rad) with ``R = Rx Ry Rz``, each limited to
+-2 pi. :func:`wrist_coordinates` turns base poses into those six values, and :func:`unwrap_angles`
picks, among the angle sets that give one rotation, the one nearest the wrist's present targets.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ges_core.errors import ArrayError, ConfigError
from ges_core.transforms import quat_to_euler_xyz

__all__ = [
    "IDENTITY_POSE",
    "PARTNERS",
    "check_env_rows",
    "env_id_list",
    "unit_quaternions",
    "unwrap_angles",
    "wrist_coordinates",
]

IDENTITY_POSE = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
"""(7,) the identity pose: x, y, z, qw, qx, qy, qz."""

PARTNERS: tuple[str, ...] = ("object", "table", "any")
"""The ``partner`` values :meth:`ges_core.sim.SimBackend.contact_forces` accepts."""

_TURN = 2 * np.pi


def env_id_list(env_ids: Sequence[int] | None, num_envs: int, who: str) -> list[int]:
    """``env_ids`` as a list of distinct ints in [0, num_envs); None gives every env, ``[]`` none.

    env_ids: a 1-D sequence of integers (list, tuple, numpy or torch integer array). who: the
    method, for messages ("sapien.reset"). Raises ConfigError naming the problem.
    """
    if env_ids is None:
        return list(range(num_envs))
    ids = np.asarray(env_ids)
    if ids.ndim != 1 or (ids.size and ids.dtype.kind not in "iu"):
        raise ConfigError(
            f"{who}: env_ids must be a 1-D sequence of integer env indices, got {_show(env_ids)} "
            f"(shape {ids.shape}, dtype {ids.dtype}); a boolean mask m gives indices with m.nonzero()[0]"
        )
    out = [int(i) for i in ids]
    bad = [i for i in out if not 0 <= i < num_envs]
    if bad:
        raise ConfigError(f"{who}: env ids {bad} out of range for num_envs={num_envs} (valid: 0..{num_envs - 1})")
    values, counts = np.unique(ids, return_counts=True)
    repeated = values[counts > 1].tolist()
    if repeated:
        raise ConfigError(f"{who}: env_ids {out} repeat {repeated}; name each env once")
    return out


def check_env_rows(value: object, env_ids: Sequence[int] | None, ids: list[int], who: str, what: str) -> None:
    """ArrayError when ``env_ids`` was given and ``value`` (M, ...) has M != len(ids) rows.

    A 2-D ``value`` only: other shapes are left to the full shape check that follows.
    """
    if env_ids is None or value is None or np.ndim(value) != 2:
        return
    rows = np.shape(value)[0]
    if rows != len(ids):
        raise ArrayError(
            f"{who}: {what} has {rows} rows but env_ids names {len(ids)} env(s) {ids}; "
            "give one row per listed env, in the order of env_ids"
        )


def unit_quaternions(pose: np.ndarray) -> np.ndarray:
    """(..., 7) poses with each quaternion divided by its norm (float64; non-zero quaternions, checked before)."""
    norm = np.linalg.norm(pose[..., 3:], axis=-1, keepdims=True)
    return np.concatenate([pose[..., :3], pose[..., 3:] / norm], axis=-1)


def wrist_coordinates(pose: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """(M, 7) base poses -> (M, 6) wrist joint values x, y, z (m), rx, ry, rz (rad, ``R = Rx Ry Rz``).

    reference: (M, 3) angles the new ones are unwrapped toward (:func:`unwrap_angles`); None keeps
    :func:`ges_core.transforms.quat_to_euler_xyz`'s principal values (a teleport, which has no "before").
    """
    angles = quat_to_euler_xyz(pose[:, 3:])
    if reference is not None:
        angles = unwrap_angles(angles, reference)
    return np.concatenate([pose[:, :3], angles], axis=1)


def unwrap_angles(angles: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``angles`` shifted by whole turns to lie nearest ``reference``, then kept within the wrist's +-2 pi.

    angles, reference: (M, 3) rad. The reference a backend passes is its wrist's present rotation
    *targets* (what the last command, teleport or reset left), not the joints' present positions: the
    targets follow from the commands alone, so one command sequence gives the same targets in every
    engine, whatever its physics did, and a target stream that crosses +-pi stays continuous however far
    the wrist lags behind. A result beyond a hinge's +-2 pi limit turns back by one turn (a target the
    joint cannot reach would be clipped).
    """
    out = angles + _TURN * np.round((reference - angles) / _TURN)
    return np.where(np.abs(out) > _TURN, out - _TURN * np.sign(out), out)


def _show(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
