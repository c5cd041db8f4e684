"""``prepare`` with real CoACD (fast settings, tiny meshes): decompose, cache hit, resume, failures, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from ges_core.cli import main
from ges_core.objects.asset import ConvexPart
from ges_core.objects.decompose import FAST, cached_parts, decomposition_dir
from ges_core.objects.library import ObjectLibrary
from ges_core.objects.prepare import prepare
from ges_core.objects.procedural import _extrude_star_polygon


@pytest.fixture
def user_dir(tmp_path, monkeypatch):
    """Two tiny concave meshes (20 and 144 faces) and one broken file."""
    monkeypatch.setenv("GES_CACHE_DIR", str(tmp_path / "cache"))
    root = tmp_path / "objects"
    for category in ("bracket", "ring", "broken"):
        (root / category).mkdir(parents=True)
    ell = np.array([[0, 0], [0.08, 0], [0.08, 0.02], [0.02, 0.02], [0.02, 0.08], [0, 0.08]])
    _extrude_star_polygon(ell, 0.05).export(root / "bracket" / "ell.obj")
    trimesh.creation.torus(0.04, 0.012, major_sections=12, minor_sections=6).export(root / "ring" / "small.obj")
    (root / "broken" / "nan.obj").write_text(
        "v 0 0 0\nv nan 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n"
    )
    return root


def entries(library, *names):
    return [library.entry(f"user/{n}") for n in names]


def test_prepare_decomposes_then_hits_the_cache(user_dir):
    library = ObjectLibrary(sources=("user",), user_dir=user_dir)
    todo = entries(library, "bracket/ell", "ring/small")
    first = prepare(todo, FAST, progress=False)
    assert [r.status for r in first] == ["decomposed", "decomposed"]
    second = prepare(todo, FAST, progress=False)
    assert [r.status for r in second] == ["cached", "cached"]
    asset = library.get("user/ring/small")
    assert all(isinstance(p, ConvexPart) for p in asset.collision) and len(asset.collision) >= 4
    parts_volume = sum(trimesh.load(p.path, force="mesh").volume for p in asset.collision)
    mesh_volume = library.processed("user/ring/small").volume
    assert mesh_volume <= parts_volume * 1.001 and parts_volume < 1.25 * mesh_volume


def test_killed_run_resumes(user_dir):
    library = ObjectLibrary(sources=("user",), user_dir=user_dir)
    ell, ring = entries(library, "bracket/ell", "ring/small")
    assert prepare([ell], FAST, progress=False)[0].status == "decomposed"
    # a run killed while writing `ring`: a part file on disk but no manifest
    ring_obj = library.processed("user/ring/small")
    stale = decomposition_dir(ring_obj.mesh_hash, FAST)
    stale.mkdir(parents=True)
    (stale / "part_000.obj").write_text("v 0 0 0\n")
    assert cached_parts(ring_obj.mesh_hash, FAST) is None
    results = prepare([ell, ring], FAST, progress=False)
    assert [r.status for r in results] == ["cached", "decomposed"]
    manifest = json.loads((stale / "manifest.json").read_text())
    assert trimesh.load(stale / manifest["parts"][0], force="mesh").volume > 0


def test_failure_is_reported_and_the_run_goes_on(user_dir):
    library = ObjectLibrary(sources=("user",), user_dir=user_dir)
    results = prepare(entries(library, "broken/nan", "bracket/ell"), FAST, progress=False)
    assert results[0].status == "failed" and "nan.obj): 1 vertices are NaN or infinite" in results[0].detail
    assert results[1].status == "decomposed"


def test_non_concave_objects_need_nothing(user_dir):
    library = ObjectLibrary(sources=("procedural",), procedural_count=1)
    results = prepare(
        [library.entry("procedural/cube/000"), library.entry("procedural/cone/000")], FAST, progress=False
    )
    assert [r.status for r in results] == ["not_needed", "not_needed"]


def test_get_can_decompose_on_demand(user_dir):
    library = ObjectLibrary(sources=("user",), user_dir=user_dir, decompose=True)
    asset = library.get("user/bracket/ell")
    assert len(asset.collision) >= 2  # an L is two convex pieces
    assert cached_parts(library.processed("user/bracket/ell").mesh_hash, FAST) is not None


def test_cli_prepare_with_two_workers(user_dir, capsys):
    args = ["objects", "prepare", "--source", "user", "--user-dir", str(user_dir), "--workers", "2", "--no-progress"]
    assert main(args) == 1  # the broken mesh fails the run, after the others are done
    out = capsys.readouterr().out
    assert "3 objects: 2 decomposed, 1 failed" in out
    assert "FAILED user/broken/nan:" in out
    ok = args + ["--ids", "user/bracket/ell", "user/ring/small"]
    assert main(ok) == 0
    assert "2 objects: 2 cached" in capsys.readouterr().out


def test_cli_prepare_rejects_bad_workers(user_dir, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["objects", "prepare", "--source", "user", "--user-dir", str(user_dir), "--workers", "0"])
    assert exit_.value.code == 2  # argparse's usage error, as for every count (ges_core.cli.args)
    assert "argument --workers: '0' is not a whole number >= 1" in capsys.readouterr().err
