"""benchmarks/part_bulge.py: how far capped convex parts stand out beyond the uncapped ones, on boxes of known size."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from conftest import benchmark_module


@pytest.fixture(scope="module")
def bulge():
    return benchmark_module("part_bulge")


def _box(extents, centre=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents).apply_translation(centre)


def test_a_merged_part_that_covers_the_same_volume_does_not_bulge(bulge):
    """Two half boxes merged into the whole box: every sample on the whole box's surface, its faces over the halves'
    shared face included, lies in one of the halves."""
    halves = [_box((0.01, 0.02, 0.02), (-0.005, 0, 0)), _box((0.01, 0.02, 0.02), (0.005, 0, 0))]
    got = bulge.mesh_bulge([_box((0.02, 0.02, 0.02))], halves, 0.0005, 0)
    assert got["outside_share"] == 0.0 and got["bulge_max_mm"] == 0.0


def test_a_part_2_mm_too_long_bulges_2_mm_over_the_area_it_adds(bulge):
    """The whole box 2 mm longer at each end: the bulge reads 2 mm (sampling adds at most about the 0.5 mm spacing),
    over the share of its surface that lies beyond the halves (the two end faces and 2 mm bands: 41.2 %)."""
    halves = [_box((0.01, 0.02, 0.02), (-0.005, 0, 0)), _box((0.01, 0.02, 0.02), (0.005, 0, 0))]
    longer = _box((0.024, 0.02, 0.02))
    got = bulge.mesh_bulge([longer], halves, 0.0005, 0)
    added = 2 * 0.02 * 0.02 + 4 * 0.02 * 0.004  # end faces, and the 2 mm bands of the four sides at both ends
    assert got["outside_share"] == pytest.approx(added / longer.area, abs=0.02)
    assert 2.0 <= got["bulge_max_mm"] <= 2.6 and 1.5 <= got["bulge_p95_mm"] <= got["bulge_max_mm"]
    assert bulge.inside_any(np.array([[0.009, 0.0, 0.0], [0.011, 0.0, 0.0]]), halves).tolist() == [True, False]
