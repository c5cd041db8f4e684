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
from ges_core.transforms import GIMBAL_LOCK_COS, quat_to_euler_xyz

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
    With a reference, a rotation's angles are the ones nearest it among all that give it:

    * its second set, (rx + pi, pi - ry, rz + pi), is unwrapped too and the nearer set taken. The principal values
      keep ry within +-pi/2, so a stream that turns through ry = +-pi/2 jumped rx and rz by pi each there and the
      wrist drives swung the hand half a turn about and back (measured: 160-180 degrees off a 15 degree turn from
      a palm-down start, both engines; docs/simulators.md, "Gimbal lock").
    * at gimbal lock itself (``cos(ry)`` below :data:`~ges_core.transforms.GIMBAL_LOCK_COS`), where only rx + rz
      (ry = pi/2) or rx - rz (ry = -pi/2) is defined, the change that sum needs is split evenly between rx and rz
      instead of rz going to 0 (:func:`_split_at_lock`).
    """
    angles = quat_to_euler_xyz(pose[:, 3:])
    if reference is not None:
        principal = unwrap_angles(angles, reference)
        far = np.abs(principal - reference).max(axis=1) > np.pi / 4
        if far.any():  # within pi/4 the second set lies over 3 pi/4 off in rx and rz: never nearer
            other = unwrap_angles(angles * _MIRROR + _SECOND_SET, reference)
            nearer = far & (((other - reference) ** 2).sum(axis=1) < ((principal - reference) ** 2).sum(axis=1))
            principal = np.where(nearer[:, None], other, principal)
        angles = principal
        locked = np.abs(np.cos(angles[:, 1])) < GIMBAL_LOCK_COS
        if locked.any():
            angles[locked] = _split_at_lock(angles[locked], reference[locked])
    return np.concatenate([pose[:, :3], angles], axis=1)


_MIRROR = np.array([1.0, -1.0, 1.0])
_SECOND_SET = np.array([np.pi, np.pi, np.pi])
"""``angles * _MIRROR + _SECOND_SET``: (rx + pi, pi - ry, rz + pi), the other angles of the same rotation."""


def _split_at_lock(angles: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(N, 3) angles at gimbal lock (ry = +-pi/2 up to whole turns) re-split nearest ``reference`` (N, 3).

    At ry = pi/2 the rotation depends on rx + rz alone, at ry = -pi/2 on rx - rz: that sum's change from the
    reference's (to the nearest turn) goes half to rx and half (signed) to rz, the split nearest the reference.
    """
    sign = np.sign(np.sin(angles[:, 1]))
    total = angles[:, 0] + sign * angles[:, 2]
    reference_total = reference[:, 0] + sign * reference[:, 2]
    half = 0.5 * (total + _TURN * np.round((reference_total - total) / _TURN) - reference_total)
    split = np.stack([reference[:, 0] + half, angles[:, 1], reference[:, 2] + sign * half], axis=1)
    return unwrap_angles(split, reference)


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
