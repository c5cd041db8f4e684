"""ObjectLibrary: listing, assets by id, masses, sizes, errors, and the ``ges objects list`` CLI."""

from __future__ import annotations

import re

import numpy as np
import pytest
import trimesh
from pydantic import ValidationError

from ges_core.cli import main
from ges_core.errors import AssetError, ConfigError
from ges_core.objects.asset import ConvexPart, ObjectAsset, PrimitiveShape
from ges_core.objects.library import LibraryConfig, ObjectLibrary, UnknownObjectError
from ges_core.objects.procedural import CATEGORIES, HELD_OUT_CATEGORIES
from ges_core.objects.splits import assign_splits


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GES_CACHE_DIR", str(tmp_path / "cache"))


@pytest.fixture
def library():
    return ObjectLibrary(LibraryConfig(procedural_count=3))


def test_list_has_every_source_category_and_split(library):
    rows = library.list()
    assert len(rows) == 3 * len(CATEGORIES) + len(library.entries(source="pybullet"))
    assert {r.source for r in rows} == {"procedural", "pybullet"}
    assert {r.split for r in rows} == {"train", "unseen_object", "unseen_category"}
    train = library.list(split="train")
    assert train and all(r.split == "train" for r in train)
    assert [r.object_id for r in library.list(source="procedural")][:2] == ["procedural/box/000", "procedural/box/001"]


def test_added_categories_are_held_out_by_default():
    held = {"stamp", "cross", "barrel", "channel"}
    assert held <= set(CATEGORIES) and set(HELD_OUT_CATEGORIES) == held
    default = ObjectLibrary(LibraryConfig(sources=("procedural",)))
    assert {r.split for r in default.list() if r.category in held} == {"unseen_category"}
    others = [(r.object_id, r.category) for r in default.list() if r.category not in held]
    assert {oid: default.splits[oid] for oid, _ in others} == assign_splits(others, seed=0)  # as before they came
    drawn = ObjectLibrary(LibraryConfig(sources=("procedural",), held_out_categories=()))
    assert drawn.splits != default.splits


def test_primitive_asset(library):
    asset = library.get("procedural/cube/001")
    assert isinstance(asset, ObjectAsset) and asset.category == "cube" and asset.mesh_path.is_file()
    (box,) = asset.collision
    assert isinstance(box, PrimitiveShape) and box.kind == "box"
    side = 2 * box.size[0]
    assert asset.mass == pytest.approx(asset.density * side**3, rel=1e-6)
    assert box.pose[2] == pytest.approx(side / 2)  # resting on z = 0
    mesh = trimesh.load(asset.mesh_path, force="mesh")
    assert mesh.bounds[0, 2] == pytest.approx(0.0, abs=1e-8)


def test_random_urdf_asset_is_its_convex_parts(library):
    asset = library.get("pybullet/random_urdfs/007")
    obj_text = library.entry("pybullet/random_urdfs/007").path.read_text()
    assert len(asset.collision) == len(re.findall(r"^o ", obj_text, flags=re.M))
    assert all(isinstance(p, ConvexPart) and p.path.is_file() for p in asset.collision)
    parts_volume = sum(trimesh.load(p.path, force="mesh").volume for p in asset.collision)
    assert asset.mass == pytest.approx(asset.density * parts_volume, rel=1e-6)


def test_overlapping_hulls_are_counted_once(library):
    """teddy is 15 overlapping convex hulls: its mass uses the union's volume."""
    obj = library.processed("pybullet/classic/teddy")
    bodies = obj.mesh.split(only_watertight=False)
    assert max(b.volume for b in bodies) < obj.volume < sum(b.volume for b in bodies)
    points = np.random.default_rng(1).uniform(*obj.mesh.bounds, size=(40_000, 3))
    inside = np.zeros(len(points), dtype=bool)
    for body in bodies:  # independent estimate: ray-parity containment of the union
        inside |= body.contains(points)
    assert obj.volume == pytest.approx(inside.mean() * np.prod(np.ptp(obj.mesh.bounds, axis=0)), rel=0.02)


def test_concave_without_decomposition_says_how_to_prepare(library):
    with pytest.raises(
        AssetError,
        match=r"procedural/mug/000: concave mesh has no cached convex decomposition .*"
        r"run `ges objects prepare --source procedural --objects procedural/mug/000` or load it with decompose=True",
    ):
        library.get("procedural/mug/000")


def test_sizes_for_the_hand_span_check(library):
    cube = library.get("procedural/cube/002").collision[0]
    assert library.min_width("procedural/cube/002") == pytest.approx(2 * cube.size[0], rel=1e-6)
    ext = library.extents("procedural/plate/000")
    assert ext.shape == (3,) and ext[2] == pytest.approx(library.min_width("procedural/plate/000"), rel=1e-6)


def test_normalize_size_scales_the_largest_extent(tmp_path):
    lib = ObjectLibrary(LibraryConfig(sources=("pybullet",), normalize_size=0.1))
    assert np.max(lib.extents("pybullet/classic/soccerball")) == pytest.approx(0.1, rel=1e-6)
    prim_lib = ObjectLibrary(LibraryConfig(sources=("procedural",), procedural_count=1, normalize_size=0.1))
    (sphere,) = prim_lib.get("procedural/sphere/000").collision
    assert 2 * sphere.size[0] == pytest.approx(0.1, rel=0.01)


def test_unknown_id_suggests_close_ids(library):
    with pytest.raises(
        UnknownObjectError, match=r"unknown object 'procedural/mugg/000'\. Did you mean procedural/mug/000"
    ):
        library.get("procedural/mugg/000")
    with pytest.raises(KeyError):
        library.entry("nothing/at/all")


def test_config_problems_are_listed_together(tmp_path, capsys):
    with pytest.raises(ConfigError) as info:
        ObjectLibrary(sources=("procedural", "shapenet"), procedural_count=-1, density=0, user_scale=-1)
    msg = str(info.value)
    for part in (
        "invalid object library config",
        "sources: Value error, unknown source(s) ['shapenet'] (known: procedural, pybullet, real, user)",
        "procedural_count: Input should be greater than or equal to 0",
        "density: Input should be greater than 0",
        "user_scale: Input should be greater than 0",
    ):
        assert part in msg
    with pytest.raises(ValidationError, match="user_dir: required when sources include 'user'"):
        LibraryConfig(sources=("user",))
    with pytest.raises(SystemExit) as exit_:  # the command line refuses it first (ges_core.cli.args)
        main(["objects", "list", "--count", "-1"])
    assert exit_.value.code == 2 and "argument --count: '-1' is not a whole number >= 0" in capsys.readouterr().err


def test_user_dir_is_a_str_or_a_path(tmp_path):
    assert LibraryConfig(user_dir=str(tmp_path)) == LibraryConfig(user_dir=tmp_path)
    assert LibraryConfig(user_dir=str(tmp_path)).model_dump(mode="json")["user_dir"] == str(tmp_path)


def test_unknown_split_is_refused():
    with pytest.raises(ConfigError, match="unknown split 'test'"):
        ObjectLibrary(sources=("procedural",)).list(split="test")


def test_user_dir_adds_the_user_source(tmp_path):
    (tmp_path / "objs" / "block").mkdir(parents=True)
    trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(tmp_path / "objs" / "block" / "one.obj")
    lib = ObjectLibrary(procedural_count=1, user_dir=tmp_path / "objs")  # sources not given: user joins
    assert "user/block/one" in {r.object_id for r in lib.list(source="user")}
    (part,) = lib.get("user/block/one").collision  # a convex user mesh: its own hull
    assert isinstance(part, ConvexPart)


def test_cli_list(capsys, tmp_path):
    assert main(["objects", "list", "--source", "procedural", "--count", "2", "--split", "train"]) == 0
    out = capsys.readouterr().out
    lines = out.strip().splitlines()
    assert lines[-1].endswith("objects") and all(" train" in line for line in lines[:-1])
    assert main(["objects", "list", "--source", "procedural", "--count", "1", "--sizes"]) == 0
    assert re.search(r"procedural/cube/000 .* cm  min width +\d+\.\d cm", capsys.readouterr().out)


def test_cli_held_out_names_the_unseen_categories(capsys):
    def splits(*extra) -> dict[str, str]:
        assert main(["objects", "list", "--source", "procedural", "--count", "2", *extra]) == 0
        rows = [line.split() for line in capsys.readouterr().out.splitlines()[:-1]]
        return {row[0]: row[-1] for row in rows}

    def library(**settings) -> dict[str, str]:
        settings = {"sources": ("procedural",), **settings}
        return ObjectLibrary(LibraryConfig(procedural_count=2, **settings)).splits

    default, mugs, drawn = splits(), splits("--held-out", "mug"), splits("--held-out")
    assert default == library()  # the printed split is the library's
    assert {s for oid, s in default.items() if oid.startswith("procedural/stamp/")} == {"unseen_category"}
    assert {s for oid, s in mugs.items() if oid.startswith("procedural/mug/")} == {"unseen_category"}
    assert mugs == library(held_out_categories=("mug",)) != default  # the option replaces the default list
    assert drawn == library(held_out_categories=())
    assert main(["objects", "list", "--source", "procedural", "--count", "2", "--held-out", "mugg"]) == 1
    err = capsys.readouterr().err
    assert "held_out_categories: mugg (did you mean mug?) is no category of the library" in err
    library(sources=("pybullet",))  # no ConfigError: the default names need not be categories of the library


def test_cli_list_error_is_one_line(capsys, tmp_path):
    assert main(["objects", "list", "--source", "user", "--user-dir", str(tmp_path / "none")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("ges: error: user object folder") and "\n" not in err


def test_cli_list_objects_filters_and_unknown_ids_say_so(capsys):
    assert main(["objects", "list", "--source", "procedural", "--count", "2", "--objects", "procedural/cube/001",
                 "procedural/box/000"]) == 0  # fmt: skip
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines[:-1]] == ["procedural/box/000", "procedural/cube/001"]
    assert lines[-1] == "2 objects"
    assert main(["objects", "list", "--source", "procedural", "--count", "2", "--objects", "procedural/cube/01"]) == 1
    out, err = capsys.readouterr()
    assert out == "" and "unknown object 'procedural/cube/01'. Did you mean procedural/cube/001" in err
