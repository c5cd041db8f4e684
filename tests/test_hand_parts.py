"""A hand link mesh's convex parts: at most HAND_MAX_PARTS of them, and how far they reach beyond the mesh
(:func:`parts_gap`), checked against shapes whose answer is known by construction."""

from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest
import trimesh

from ges_core.hand_prep.decompose import HAND_COACD, HAND_MAX_PARTS, decompose_link_mesh, parts_gap
from ges_core.hand_prep.geometry import hull_gap


def _prism(outline: list[tuple[float, float]], triangles: list[tuple[int, int, int]], depth: float) -> trimesh.Trimesh:
    return trimesh.creation.extrude_triangulation(np.array(outline), np.array(triangles), depth)


def _l_shape(side: float, arm: float, depth: float) -> trimesh.Trimesh:
    """[0, side] x [0, arm] and [0, arm] x [0, side] in x, y, extruded over [0, depth] in z: one watertight mesh."""
    outline = [(0, 0), (arm, 0), (side, 0), (side, arm), (arm, arm), (0, arm), (arm, side), (0, side)]
    triangles = [(0, 1, 4), (0, 4, 5), (1, 2, 3), (1, 3, 4), (5, 4, 6), (5, 6, 7)]
    return _prism(outline, triangles, depth)


def _comb(teeth: int = 14, width: float = 0.002, gap: float = 0.003, height: float = 0.02) -> trimesh.Trimesh:
    """A bar 4 mm high with ``teeth`` teeth on it, 4 mm thick: CoACD needs a part per tooth or so."""
    xs = [0.0]
    for i in range(teeth):
        x0 = i * (width + gap) + gap / 2
        xs += [x0, x0 + width]
    xs.append(teeth * (width + gap))
    m = len(xs)
    outline = [(x, 0.0) for x in xs] + [(x, 0.004) for x in xs]
    triangles = [t for j in range(m - 1) for t in ((j, j + 1, m + j + 1), (j, m + j + 1, m + j))]
    for i in range(teeth):
        a, b = m + 1 + 2 * i, m + 2 + 2 * i  # the bar's top vertices under tooth i
        outline += [(xs[1 + 2 * i], 0.004 + height), (xs[2 + 2 * i], 0.004 + height)]
        c, d = len(outline) - 2, len(outline) - 1
        triangles += [(a, b, d), (a, d, c)]
    return _prism(outline, triangles, 0.004)


def _box(lo, hi) -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=np.subtract(hi, lo))
    box.apply_translation(np.add(lo, hi) / 2)
    return box


def _written(folder: Path, meshes: list[trimesh.Trimesh]) -> list[Path]:
    """``meshes`` as part files in ``folder`` (created), as a decomposition's cache holds them."""
    folder.mkdir(parents=True)
    for i, mesh in enumerate(meshes):
        mesh.export(folder / f"part_{i}.obj")
    return [folder / f"part_{i}.obj" for i in range(len(meshes))]


def test_parts_gap_is_how_far_the_parts_reach_beyond_the_mesh(tmp_path):
    """An L of 4 cm sides and 1 cm arms, 5 cm deep: its two boxes as parts reach nowhere beyond it; one box grown
    2 mm past an outer face reaches 2 mm; its convex hull holds the inner corner an arm's width (1 cm) deep, nearer
    the outer faces than the hull's diagonal face ((side - arm) / sqrt(2) = 21 mm), as hull_gap reads the same hull."""
    side, arm, depth = 0.04, 0.01, 0.05
    mesh = _l_shape(side, arm, depth)
    assert mesh.is_watertight and mesh.volume == pytest.approx((2 * side - arm) * arm * depth)
    exact = [_box((0, 0, 0), (side, arm, depth)), _box((0, arm, 0), (arm, side, depth))]
    assert parts_gap(mesh, _written(tmp_path / "exact", exact)) < 1e-6
    grown = [_box((0, 0, 0), (side + 0.002, arm, depth)), exact[1]]
    assert parts_gap(mesh, _written(tmp_path / "grown", grown)) == pytest.approx(0.002, abs=1e-4)
    reach = parts_gap(mesh, _written(tmp_path / "hull", [mesh.convex_hull]))
    assert reach == pytest.approx(arm, abs=1e-3)
    assert reach == pytest.approx(hull_gap(mesh), abs=1e-9)


@pytest.fixture
def empty_cache(monkeypatch, tmp_path) -> Path:
    cache = tmp_path / "cache"
    monkeypatch.setenv("GES_CACHE_DIR", str(cache))
    return cache


def test_a_link_mesh_gets_at_most_hand_max_parts_and_a_smaller_one_its_own(empty_cache, tmp_path):
    """A 14-tooth comb takes CoACD more than HAND_MAX_PARTS parts with the hands' settings uncapped; decomposed as a
    hand's link mesh it gets HAND_MAX_PARTS. The L needs two: with the cap or without, the same parts."""
    import coacd

    coacd.set_log_level("error")
    uncapped = asdict(replace(HAND_COACD, max_convex_hull=-1))

    def raw_parts(mesh):
        return coacd.run_coacd(coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)), **uncapped)

    comb = _comb()
    assert comb.is_watertight and len(raw_parts(comb)) > HAND_MAX_PARTS
    comb.export(tmp_path / "comb.obj")
    parts = decompose_link_mesh(tmp_path / "comb.obj", name="comb")
    assert len(parts) == HAND_MAX_PARTS

    l_mesh = _l_shape(0.04, 0.01, 0.05)
    l_mesh.export(tmp_path / "l.obj")
    capped = [trimesh.load(str(p), force="mesh") for p in decompose_link_mesh(tmp_path / "l.obj", name="l")]
    free = [trimesh.Trimesh(v, f).convex_hull for v, f in raw_parts(l_mesh)]
    assert len(capped) == len(free) < HAND_MAX_PARTS
    assert sorted(p.volume for p in capped) == pytest.approx(sorted(p.volume for p in free), rel=1e-6)  # 8-digit OBJ
