"""How a file mesh rests on the table: its most probable pose (``stable``, the default) or the file's own
orientation (``as_authored``), per object in ``objects.yaml`` / ``object_properties`` or for the whole library;
what is stored and what the processing cache keys on."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ges_core.config import stored_dump
from ges_core.errors import ConfigError
from ges_core.objects.library import LibraryConfig, ObjectLibrary
from ges_core.objects.processed_cache import cache_key
from ges_core.synthesis import SynthesisConfig

TALL = (0.05, 0.07, 0.16)  # a cereal box as scanned: standing, +z up


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """box/tall (5 x 7 x 16 cm, standing in its file, its bottom 2 cm below the file's origin) and fruit/pear
    (an ellipsoid lying along x in its file)."""
    monkeypatch.setenv("GES_CACHE_DIR", str(tmp_path / "cache"))
    root = tmp_path / "mine"
    (root / "box").mkdir(parents=True)
    (root / "fruit").mkdir()
    box = trimesh.creation.box(extents=TALL)
    box.apply_translation((0.01, -0.02, TALL[2] / 2 - 0.02))
    box.export(root / "box" / "tall.stl")
    pear = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    pear.apply_scale((0.05, 0.03, 0.03))
    pear.export(root / "fruit" / "pear.ply")
    return root


def _placed(library: ObjectLibrary, oid: str) -> trimesh.Trimesh:
    return library.processed(oid).mesh


def test_stable_lays_the_tall_box_down_and_as_authored_keeps_it_standing(folder):
    stable = ObjectLibrary(sources=("user",), user_dir=folder)
    lying = _placed(stable, "user/box/tall")
    assert lying.extents[2] == pytest.approx(min(TALL), abs=1e-6)  # trimesh's most probable pose: on a big face
    (folder / "objects.yaml").write_text("objects:\n  box/tall: {rest: as_authored}\n")
    authored = ObjectLibrary(sources=("user",), user_dir=folder)
    standing = _placed(authored, "user/box/tall")
    source = trimesh.load(folder / "box" / "tall.stl", force="mesh")
    # only moved: the same orientation, the lowest point on the table, the centre of mass (trimesh's, computed
    # independently of the placement code) above the origin
    assert np.allclose(standing.extents, source.extents, atol=1e-9)
    assert standing.bounds[0, 2] == pytest.approx(0.0, abs=1e-9)
    assert np.allclose(standing.center_mass[:2], 0.0, atol=1e-9)
    assert np.allclose(standing.vertices - standing.vertices.mean(0), source.vertices - source.vertices.mean(0))
    # the other object keeps its default
    assert np.allclose(_placed(authored, "user/fruit/pear").extents, _placed(stable, "user/fruit/pear").extents)
    assert authored.extents("user/box/tall")[2] == pytest.approx(TALL[2])


def test_the_run_and_the_library_default_choose_too(folder):
    """``object_properties`` (the run's, e.g. the command line's) wins over objects.yaml, which wins over the
    library's ``rest``."""
    everything = ObjectLibrary(sources=("user",), user_dir=folder, rest="as_authored")
    assert everything.extents("user/box/tall")[2] == pytest.approx(TALL[2])
    assert everything.extents("user/fruit/pear")[2] == pytest.approx(0.06, rel=0.02)  # as in the file
    (folder / "objects.yaml").write_text("objects:\n  box/tall: {rest: stable}\n")
    mixed = ObjectLibrary(sources=("user",), user_dir=folder, rest="as_authored")
    assert mixed.extents("user/box/tall")[2] == pytest.approx(min(TALL), abs=1e-6)
    run = ObjectLibrary(
        sources=("user",), user_dir=folder, object_properties={"user/box/tall": {"rest": "as_authored"}}
    )
    assert run.extents("user/box/tall")[2] == pytest.approx(TALL[2])


def test_an_unknown_rest_is_refused_naming_the_choices(folder):
    (folder / "objects.yaml").write_text("objects:\n  box/tall: {rest: sideways}\n")
    with pytest.raises(
        ConfigError, match=r"objects\.box/tall\.rest: Input should be 'stable', 'graspable' or 'as_authored'"
    ):
        ObjectLibrary(sources=("user",), user_dir=folder).list()
    with pytest.raises(ConfigError, match=r"rest: Input should be 'stable', 'graspable' or 'as_authored'"):
        from ges_core.config import parse_model

        parse_model(LibraryConfig, {"rest": "upside_down"}, where="library")


def test_cache_keys_and_stored_configs(folder):
    """Each placement has its own processing-cache key (no rest given is ``stable``). The default is left out of the
    stored run config (datasets written before the option still match it); a choice is stored."""
    library = ObjectLibrary(sources=("user",), user_dir=folder)
    entry = library.entry("user/box/tall")
    from dataclasses import replace

    keys = {rest: cache_key(replace(entry, rest=rest), normalize_size=None, max_faces=20_000) for rest in
            (None, "stable", "graspable", "as_authored")}  # fmt: skip
    assert keys[None] == keys["stable"] and len({keys["stable"], keys["graspable"], keys["as_authored"]}) == 3
    plain = stored_dump(SynthesisConfig.model_validate({"library": {"object_properties": {"a/b/c": {"mass": 1}}}}))
    assert "rest" not in plain["library"] and plain["library"]["object_properties"]["a/b/c"] == {
        "mass": 1.0, "density": None, "friction": None}  # fmt: skip
    data = {"library": {"rest": "as_authored", "object_properties": {"a/b/c": {"rest": "stable"}}}}
    chosen = stored_dump(SynthesisConfig.model_validate(data))
    assert chosen["library"]["rest"] == "as_authored"
    assert chosen["library"]["object_properties"]["a/b/c"]["rest"] == "stable"


def test_cli_rest_option(folder, capsys):
    """``--rest ID=MODE`` (ges objects list/prepare, synth, demo) over objects.yaml; a bad mode or a missing ``=``
    is a clear error."""
    from ges_core.cli import main

    base = ["objects", "list", "--user-dir", str(folder), "--sizes"]
    assert main(base) == 0
    lying = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("user/box/tall"))
    assert main([*base, "--rest", "box/tall=as_authored"]) == 0
    standing = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("user/box/tall"))
    assert " 5.0 cm  min width" in lying and " 16.0 cm  min width" in standing
    assert main([*base, "--rest", "box/tall=upright"]) == 1
    assert (
        "object_properties.user/box/tall.rest: Input should be 'stable', 'graspable' or 'as_authored'"
        in capsys.readouterr().err
    )
    assert main([*base, "--rest", "box/tall"]) == 1
    assert "--rest 'box/tall': write OBJECT_ID=VALUE" in capsys.readouterr().err


def test_prepare_decomposes_the_placement_the_run_uses(folder):
    """A concave mesh is decomposed before a run in the placement the run will use: after preparing an
    ``as_authored`` library, its asset loads without computing anything (before, preparing decomposed the stable
    placement and the run found no collision model for the authored one)."""
    from ges_core.objects.prepare import prepare_before_run
    from ges_core.objects.procedural import _extrude_star_polygon

    ell = np.array([[0, 0], [0.08, 0], [0.08, 0.025], [0.025, 0.025], [0.025, 0.08], [0, 0.08]])
    (folder / "bracket").mkdir()
    _extrude_star_polygon(ell, 0.03).export(folder / "bracket" / "ell.obj")  # lying flat in its file
    library = ObjectLibrary(sources=("user",), user_dir=folder, rest="as_authored")
    stable = ObjectLibrary(sources=("user",), user_dir=folder)
    assert library.processed("user/bracket/ell").mesh_hash != stable.processed("user/bracket/ell").mesh_hash
    results = prepare_before_run(library, ["user/bracket/ell"], progress=False)
    assert [r.status for r in results] == ["decomposed"]
    asset = library.get("user/bracket/ell", decompose=False)  # an AssetError if the authored placement lacked one
    assert len(asset.collision) >= 2
