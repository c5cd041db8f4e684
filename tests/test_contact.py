"""The shared contact representation: validation, frames, save/load."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ges_core.contact import FINGER_SLOTS, ContactSet
from ges_core.errors import ArrayError, AssetError


def _random_set(seed: int = 0) -> ContactSet:
    rng = np.random.default_rng(seed)
    return ContactSet(rng.normal(size=(5, 3)), rng.normal(size=(5, 3)), "procedural/box/000", {"quality": 0.1})


def test_normals_are_normalized_and_slots_addressable():
    cs = _random_set()
    assert np.allclose(np.linalg.norm(cs.normals, axis=1), 1.0)
    pos, nrm = cs.slot("middle")
    assert np.array_equal(pos, cs.positions[FINGER_SLOTS.index("middle")]) and nrm.shape == (3,)


def test_round_trip_through_file(tmp_path):
    cs = _random_set()
    cs.save(tmp_path / "c.json")
    back = ContactSet.load(tmp_path / "c.json")
    assert np.array_equal(back.positions, cs.positions) and np.allclose(back.normals, cs.normals)
    assert back.object_id == cs.object_id and back.meta == cs.meta
    assert not list(tmp_path.glob("*.tmp"))


def test_transform_preserves_distances_and_rotates_normals():
    from scipy.spatial.transform import Rotation

    cs = _random_set()
    rot = Rotation.from_euler("xyz", [0.3, -0.2, 1.0]).as_matrix()
    moved = cs.transformed(rot, np.array([0.1, 0.2, 0.3]))
    d0 = np.linalg.norm(cs.positions[:, None] - cs.positions[None], axis=-1)
    d1 = np.linalg.norm(moved.positions[:, None] - moved.positions[None], axis=-1)
    assert np.allclose(d0, d1)
    assert np.allclose(moved.normals, cs.normals @ rot.T)


@pytest.mark.parametrize(
    ("positions", "normals", "message"),
    [
        (np.zeros((4, 3)), np.ones((4, 3)), r"ContactSet: positions has shape \(4, 3\), expected \(5, 3\)"),
        (np.full((5, 3), np.nan), np.ones((5, 3)), r"ContactSet: positions holds NaN or inf \(at index \[0, 0\]"),
        (np.zeros((5, 3)), np.zeros((5, 3)), r"ContactSet: normals of rows \[0, 1, 2, 3, 4\] are zero"),
    ],
)
def test_invalid_sets_rejected(positions, normals, message):
    with pytest.raises(ArrayError, match=message):
        ContactSet(positions, normals)


def test_foreign_file_rejected(tmp_path):
    path = tmp_path / "x.json"
    path.write_text(json.dumps({"format": "something/else"}))
    with pytest.raises(AssetError, match="not a contact set"):
        ContactSet.load(path)
    data = _random_set().to_dict()
    data["slots"] = list(reversed(FINGER_SLOTS))
    path.write_text(json.dumps(data))
    with pytest.raises(AssetError, match="slots"):
        ContactSet.load(path)
