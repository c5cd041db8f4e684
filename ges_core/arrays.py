"""The one array checker: every array that crosses a boundary goes through :func:`checked_array`.

A wrong shape, a non-numeric value, NaN or inf, or a zero quaternion raises :class:`~ges_core.errors.ArrayError`
with one message naming who was called, what the argument holds and the shape it should have, e.g.::

    sapien.set_hand_state: q has shape (2, 16), expected (3, 16) (one row per env, hand joint_names order)

Where a bad array is one object's data rather than a caller's mistake, Stage 1 records it instead of raising: the
contact step turns an empty or NaN point cloud into that object's failed step (``SynthesisError`` with a reason
such as ``nan_in_cloud``), and refinement and validation record a non-finite command as ``unstable``; the run goes on.

Checks never normalise or round: a checked array holds the caller's values, as float64 unless another
dtype is asked for (tensors are read through :func:`as_numpy`, without a copy where none is needed).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ges_core.errors import ArrayError

__all__ = ["as_numpy", "checked_array", "checked_poses"]

Shape = Sequence[int | None]
"""Expected shape; None matches any length along that axis."""


def as_numpy(x: object, dtype: type | None = None) -> np.ndarray:
    """A torch tensor (any device, grad or not) or an array-like as numpy of ``dtype`` (None: its own).

    No copy where none is needed: a CPU tensor's array shares its memory. Torch is used only if ``x`` is a tensor.
    """
    if type(x).__module__.startswith("torch"):
        try:
            x = x.numpy()  # type: ignore[attr-defined]
        except (RuntimeError, TypeError):  # requires grad, or not on the CPU
            x = x.detach().cpu().numpy()  # type: ignore[attr-defined]
    return np.asarray(x, dtype=dtype)


def checked_array(
    value: object,
    shape: Shape,
    what: str,
    *,
    layout: str = "",
    dtype: type = np.float64,
    finite: bool = True,
) -> np.ndarray:
    """``value`` as a ``dtype`` array of ``shape`` with only finite values, else one ArrayError.

    what: who and which argument, for the message (``"sapien.set_hand_state: q"``); layout: what the axes
    hold (``"one row per env, hand joint_names order"``); finite: False skips the NaN/inf check.
    """
    try:
        array = as_numpy(value)
        if array.dtype.kind in "bcSU":  # bool, complex, text: not the numbers asked for (no silent 0/1 or real part)
            raise TypeError(f"got {array.dtype} values")
        array = np.asarray(array, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ArrayError(f"{what} must be a numeric array of shape {_show(shape)}{_paren(layout)}; {exc}") from None
    if array.ndim != len(shape) or any(w is not None and w != g for w, g in zip(shape, array.shape, strict=True)):
        raise ArrayError(f"{what} has shape {tuple(array.shape)}, expected {_show(shape)}{_paren(layout)}")
    if finite and array.size and not np.isfinite(array).all():
        bad = np.argwhere(~np.isfinite(array))[:3].tolist()
        raise ArrayError(f"{what} holds NaN or inf (at index {', '.join(map(str, bad))}); check where it was computed")
    return array


def checked_poses(value: object, rows: int | None, what: str) -> np.ndarray:
    """``(rows, 7)`` poses (x, y, z, qw, qx, qy, qz) checked like :func:`checked_array`, plus a non-zero
    quaternion in every row; rows None checks one ``(7,)`` pose. Quaternions are checked, not normalised."""
    shape = (7,) if rows is None else (rows, 7)
    pose = checked_array(value, shape, what, layout="x, y, z, qw, qx, qy, qz; world frame, metres")
    norms = np.einsum("...i,...i->...", pose[..., 3:], pose[..., 3:])
    if not norms.min(initial=np.inf) > 1e-12:
        rows_bad = np.flatnonzero(np.atleast_1d(norms) <= 1e-12).tolist()
        raise ArrayError(f"{what} has a zero quaternion (row {rows_bad}); poses are x, y, z, qw, qx, qy, qz")
    return pose


def _show(shape: Shape) -> str:
    return "(" + ", ".join("N" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def _paren(layout: str) -> str:
    return f" ({layout})" if layout else ""
