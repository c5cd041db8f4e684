"""The one array checker: shapes, dtypes, NaN/inf, zero quaternions, one error type, no normalising."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ges_core.arrays import as_numpy, checked_array, checked_poses
from ges_core.errors import ArrayError


def test_a_good_array_comes_back_unchanged_as_float64():
    value = np.arange(6, dtype=np.float32).reshape(2, 3) / 3
    out = checked_array(value, (2, None), "f: x")
    assert out.dtype == np.float64 and np.array_equal(out, value.astype(np.float64))


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (np.zeros((2, 2)), r"f: x has shape \(2, 2\), expected \(N, 3\) \(rows per env\)"),
        (np.zeros(3), r"has shape \(3,\), expected \(N, 3\)"),
        ([[1.0, "a", 3.0]], r"must be a numeric array of shape \(N, 3\)"),
        ([[1.0, np.nan, 3.0], [0.0, 0.0, np.inf]], r"holds NaN or inf \(at index \[0, 1\], \[1, 2\]\)"),
    ],
)
def test_each_mistake_is_one_array_error_naming_the_argument(value, message):
    with pytest.raises(ArrayError, match=message) as info:
        checked_array(value, (None, 3), "f: x", layout="rows per env")
    assert isinstance(info.value, ValueError)


def test_nan_allowed_when_asked():
    assert np.isnan(checked_array([np.nan], (1,), "x", finite=False)[0])


def test_poses_check_quaternions_without_normalising():
    pose = np.array([[0.1, 0.2, 0.3, 2.0, 0.0, 0.0, 0.0]])
    assert np.array_equal(checked_poses(pose, 1, "p"), pose)
    with pytest.raises(ArrayError, match=r"p has a zero quaternion \(row \[1\]\)"):
        checked_poses(np.vstack([pose, np.zeros((1, 7))]), 2, "p")
    assert checked_poses(pose[0], None, "p").shape == (7,)


def test_tensors_are_read_without_a_copy_and_with_grad():
    t = torch.arange(3.0)
    assert np.shares_memory(as_numpy(t), t.numpy())
    assert np.array_equal(as_numpy(torch.ones(2, requires_grad=True)), np.ones(2))


@pytest.mark.parametrize("value", [np.ones(3, bool), np.ones(3, complex), ["a", "b", "c"]])
def test_bools_complex_numbers_and_text_are_not_taken_for_numbers(value):
    with pytest.raises(ArrayError, match=r"x must be a numeric array of shape \(3,\); got (bool|complex128|<U1) "):
        checked_array(value, (3,), "x")
