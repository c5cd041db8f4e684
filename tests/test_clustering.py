"""Geometry clustering: shape features against geometry known in closed form, the category rule, seeds, the
clusters file, and ``ges cluster`` on small real datasets (a Stage 1 dataset from tests/data and a dataset folder
of procedural objects written by the real writer)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh

from ges_core.cli import main
from ges_core.clustering import (
    FEATURE_NAMES,
    ClusterConfig,
    ObjectShape,
    cluster_objects,
    load_clusters,
    save_clusters,
    shape_features,
)
from ges_core.clustering.features import check_features
from ges_core.config import parse_model
from ges_core.dataset import open_dataset
from ges_core.errors import AssetError, ConfigError
from ges_core.objects.library import LibraryConfig, ObjectLibrary
from ges_core.objects.pointcloud import sample_surface

STAGE1_DATASET = Path(__file__).parent / "data" / "dataset_v2"
"""Real Stage 1 records of procedural/box/000 and procedural/sphere/000 (Allegro)."""
F = {name: i for i, name in enumerate(FEATURE_NAMES)}


def _features(mesh: trimesh.Trimesh, seed: int = 0) -> np.ndarray:
    points, _ = sample_surface(mesh, 2048, seed=seed)
    return shape_features(mesh, points)


# --- features ---------------------------------------------------------------------------------------------------


def test_box_features_match_its_dimensions():
    dims = (0.03, 0.12, 0.07)  # x, y, z: z is the resting height
    mesh = trimesh.creation.box(extents=dims)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(0.4, [0, 0, 1]))  # yaw: extents must not care
    f = _features(mesh)
    assert f[[F["extent_1_m"], F["extent_2_m"], F["extent_3_m"]]] == pytest.approx([0.12, 0.07, 0.03], abs=1e-6)
    assert f[F["log10_volume_m3"]] == pytest.approx(math.log10(0.03 * 0.12 * 0.07), abs=1e-9)
    assert f[F["hull_ratio"]] == pytest.approx(1.0, abs=1e-6)
    area = 2 * (0.03 * 0.12 + 0.03 * 0.07 + 0.12 * 0.07)
    assert f[F["sphericity"]] == pytest.approx(
        math.pi ** (1 / 3) * (6 * 0.03 * 0.12 * 0.07) ** (2 / 3) / area, rel=1e-6
    )
    assert f[F["height_ratio"]] == pytest.approx(0.07 / 0.12, rel=1e-6)
    assert f[F["com_height_ratio"]] == pytest.approx(0.5, abs=1e-6)


def test_procedural_box_extents_are_its_primitive_sides():
    """The library's box: its features' extents equal the exact box collision shape's sides (half sizes x 2)."""
    library = ObjectLibrary(LibraryConfig(sources=("procedural",), procedural_count=1))
    obj = library.processed("procedural/box/000")
    (box,) = [p for p in obj.primitives if p.kind == "box"]
    cloud, _ = library.point_cloud("procedural/box/000", 1024, seed=0)
    f = shape_features(obj.mesh, cloud, volume=obj.volume)
    assert f[:3] == pytest.approx(sorted((2 * s for s in box.size), reverse=True), rel=1e-4)


def test_sphere_is_round_and_a_rod_is_long():
    sphere = _features(trimesh.creation.icosphere(subdivisions=4, radius=0.05))
    assert sphere[F["pca_ratio_2_1"]] == pytest.approx(1.0, abs=0.1)
    assert sphere[F["pca_ratio_3_1"]] == pytest.approx(1.0, abs=0.1)
    assert sphere[F["sphericity"]] == pytest.approx(1.0, abs=0.02)  # faceted: a little below 1
    assert sphere[:3] == pytest.approx([0.1, 0.1, 0.1], abs=0.005)
    rod = _features(trimesh.creation.cylinder(radius=0.01, height=0.2, sections=32))
    # a 0.2 m rod of radius 0.01 m: variance along it ~ 0.2^2/12, across it ~ 0.01^2/2: ratio ~ 0.015
    assert rod[F["pca_ratio_2_1"]] < 0.05 and rod[F["pca_ratio_3_1"]] < 0.05
    assert rod[F["height_ratio"]] == pytest.approx(1.0, abs=1e-6)  # standing on its end


def test_hull_ratio_is_one_for_convex_and_below_for_an_l_bracket():
    library = ObjectLibrary(LibraryConfig(sources=("procedural",), procedural_count=1))
    ratios = {}
    for oid in ("procedural/can/000", "procedural/l_bracket/000", "procedural/mug/000"):
        obj = library.processed(oid)
        ratios[oid] = shape_features(obj.mesh, library.point_cloud(oid, 512)[0], volume=obj.volume)[F["hull_ratio"]]
    assert ratios["procedural/can/000"] == pytest.approx(1.0, abs=0.01)
    assert 0.3 < ratios["procedural/l_bracket/000"] < 0.9
    assert ratios["procedural/mug/000"] < 0.95  # the handle's gap and the hollow


def _l_prism(height: float) -> trimesh.Trimesh:
    """An L-shaped outline (two 0.02 m wide bars, 0.1 m long) extruded ``height`` m along z."""
    outline = [(0, 0), (0.1, 0), (0.1, 0.02), (0.02, 0.02), (0.02, 0.1), (0, 0.1)]  # counter-clockwise
    fan = [(3, 4, 5), (3, 5, 0), (3, 0, 1), (3, 1, 2)]  # from the inner corner: every triangle inside the L
    vertices = [(x, y, 0.0) for x, y in outline] + [(x, y, height) for x, y in outline]
    faces = [(a, c, b) for a, b, c in fan] + [(a + 6, b + 6, c + 6) for a, b, c in fan]
    faces += [f for i in range(6) for f in ((i, (i + 1) % 6, (i + 1) % 6 + 6), (i, (i + 1) % 6 + 6, i + 6))]
    mesh = trimesh.Trimesh(vertices, faces)
    assert mesh.is_watertight and mesh.volume > 0
    return mesh


def test_l_bracket_hull_ratio_matches_its_outline():
    """An extruded L: volume and hull volume by hand (the hull fills in the triangle between the bars)."""
    area = 0.1 * 0.02 + 0.02 * 0.08
    hull_area = area + 0.5 * 0.08 * 0.08
    f = _features(_l_prism(0.03))
    assert f[F["hull_ratio"]] == pytest.approx(area / hull_area, rel=1e-6)
    assert f[F["log10_volume_m3"]] == pytest.approx(math.log10(area * 0.03), abs=1e-9)


def test_a_flat_mesh_names_the_object_and_the_feature():
    sheet = trimesh.Trimesh([[0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0], [0, 0.1, 0]], [[0, 1, 2], [0, 2, 3]])
    points = np.random.default_rng(0).uniform(0, 0.1, size=(64, 3)) * [1, 1, 0]
    features = shape_features(sheet, points)
    with pytest.raises(AssetError, match=r"user/flat/sheet.*log10_volume_m3 = nan.*ges objects list"):
        check_features("user/flat/sheet", features)
    with pytest.raises(AssetError, match=r"points must be \(n >= 4, 3\)"):
        shape_features(sheet, points[:3])


# --- clustering ---------------------------------------------------------------------------------------------------

BLOBS = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
"""Three well-separated blob centres in a 2-feature space."""


def _shapes(spec: list[tuple[str, int, str]], seed: int = 0) -> list[ObjectShape]:
    """(category, blob, split) per object -> shapes with features near that blob (noise 0.3)."""
    rng = np.random.default_rng(seed)
    return [
        ObjectShape(f"{cat}/{i:03d}", cat, split, BLOBS[blob] + rng.normal(scale=0.3, size=2))
        for i, (cat, blob, split) in enumerate(spec)
    ]


def _cluster(shapes, **settings):
    return cluster_objects(shapes, ClusterConfig(**settings), feature_names=("a", "b"))


def test_kmeans_finds_separated_blobs_and_categories_stay_whole():
    spec = [("a", 0, "train")] * 4 + [("b", 1, "train")] * 4 + [("c", 2, "train")] * 4
    spec += [("mixed", 0, "train")] * 3 + [("mixed", 1, "train")]  # one 'mixed' object sits in blob 1
    clusters = _cluster(_shapes(spec))
    blob_cluster = {b: clusters.categories[c] for c, b in (("a", 0), ("b", 1), ("c", 2))}
    assert sorted(blob_cluster.values()) == [0, 1, 2]
    assert clusters.categories["mixed"] == blob_cluster[0]  # three of its four objects are in blob 0
    stray = clusters.objects[f"mixed/{len(spec) - 1:03d}"]
    assert stray.cluster == blob_cluster[0] and stray.kmeans_cluster == blob_cluster[1]
    assert stray.nearest_cluster == blob_cluster[1] and stray.assigned_by == "category"
    assert clusters.sizes() == [sum(m.cluster == c for m in clusters.objects.values()) for c in range(3)]


def test_a_tied_category_goes_to_the_centre_nearest_its_mean():
    spec = [("a", 0, "train")] * 4 + [("b", 1, "train")] * 4 + [("c", 2, "train")] * 4
    shapes = _shapes(spec)
    # one object in blob 0, one at blob 1's near edge: a 1 : 1 vote, and the category's mean (4.25, 0) is nearer
    # blob 0's centre (about 0.2 away from the origin) than blob 1's (about 9.7)
    shapes += [
        ObjectShape("tie/0", "tie", "train", np.array([0.0, 0.0])),
        ObjectShape("tie/1", "tie", "train", [8.5, 0.0]),
    ]
    clusters = _cluster(shapes, category_share=0.5)  # a 1 : 1 category moves whole only with a share <= 0.5
    assert clusters.objects["tie/0"].kmeans_cluster != clusters.objects["tie/1"].kmeans_cluster
    assert clusters.categories["tie"] == clusters.categories["a"]


def test_a_category_split_evenly_keeps_its_kmeans_clusters():
    spec = [("a", 0, "train")] * 4 + [("b", 1, "train")] * 4 + [("c", 2, "train")] * 4
    spec += [("loose", 0, "train")] * 3 + [("loose", 1, "train")] * 2  # 60 % in blob 0: under the default 2/3
    clusters = _cluster(_shapes(spec))
    assert "loose" not in clusters.categories
    assert sorted(clusters.mixed_categories["loose"]) == [0, 2, 3]
    loose = [m for m in clusters.objects.values() if m.category == "loose"]
    assert {m.assigned_by for m in loose} == {"kmeans"} and all(m.cluster == m.kmeans_cluster for m in loose)
    assert {m.cluster for m in loose} == {clusters.categories["a"], clusters.categories["b"]}
    plain = _cluster(_shapes(spec), category_share=0.0)  # the plain rule: every category whole
    assert plain.categories["loose"] == plain.categories["a"] and not plain.mixed_categories


def test_unseen_objects_go_to_the_nearest_centre_and_do_not_move_it():
    spec = [("a", 0, "train")] * 4 + [("b", 1, "train")] * 4 + [("c", 2, "train")] * 4
    train = _shapes(spec)
    unseen = [
        ObjectShape("new/0", "a", "unseen_object", np.array([9.5, 0.5])),  # category a, shaped like blob 1
        ObjectShape("new/1", "z", "unseen_category", np.array([0.2, 9.0])),
    ]
    alone, together = _cluster(train), _cluster(train + unseen)
    assert np.array_equal(alone.centres, together.centres) and np.array_equal(alone.mean, together.mean)
    assert together.objects["new/0"].cluster == together.categories["b"]
    assert together.objects["new/1"].cluster == together.categories["c"]
    assert {together.objects[o].assigned_by for o in ("new/0", "new/1")} == {"nearest_centre"}
    assert together.objects["new/0"].kmeans_cluster is None


def test_same_seed_same_clusters_file(tmp_path):
    spec = [(c, b, "train") for c, b in (("a", 0), ("b", 1), ("c", 2), ("d", 0), ("e", 1))] * 3
    one, two = _cluster(_shapes(spec), seed=3), _cluster(_shapes(spec), seed=3)
    save_clusters(one, tmp_path / "one.json")
    save_clusters(two, tmp_path / "two.json")
    assert (tmp_path / "one.json").read_bytes() == (tmp_path / "two.json").read_bytes()


def test_small_clusters_are_recorded():
    lonely = _cluster(_shapes([("a", 0, "train")] * 4 + [("b", 1, "train")] * 4 + [("c", 2, "train")]))
    (line,) = lonely.warnings
    assert "holds one training object (c/008)" in line
    spec = [("a", 0, "train")] * 3 + [("b", 1, "train")] * 2 + [("b", 2, "train")] * 2
    two_categories = _cluster(_shapes(spec), category_share=0.0)  # 'b' moved whole: one cluster left empty
    assert any("holds no training object" in w for w in two_categories.warnings)
    assert 0 in two_categories.sizes()


def test_bad_settings_are_clear_errors():
    with pytest.raises(ConfigError, match="cannot make k = 4 clusters from 3 training object"):
        _cluster(_shapes([("a", 0, "train")] * 3 + [("a", 1, "unseen_object")]), k=4)
    with pytest.raises(ConfigError, match="k: Input should be greater than or equal to 1"):
        parse_model(ClusterConfig, {"k": 0}, where="cluster settings")


def test_file_round_trip_and_reader_api(tmp_path):
    spec = [("a", 0, "train")] * 5 + [("b", 1, "train")] * 5 + [("c", 2, "train")] * 5 + [("a", 0, "unseen_object")]
    clusters = _cluster(_shapes(spec))
    path = save_clusters(clusters, tmp_path / "c.json")
    back = load_clusters(path)
    for oid, member in clusters.objects.items():
        again = back.objects[oid]
        assert (again.cluster, again.split, again.assigned_by) == (member.cluster, member.split, member.assigned_by)
        assert np.allclose(again.features, member.features) and again.distance == pytest.approx(member.distance)
    assert np.allclose(back.centres, clusters.centres) and back.categories == clusters.categories
    c = clusters.categories["a"]
    members = back.members(c)
    distances = [back.objects[o].distance for o in members]
    assert distances == sorted(distances) and len(members) == 5
    assert back.central(c, 0.3) == members[:2]  # ceil(0.3 x 5)
    assert back.central(c, 0.01) == members[:1]
    assert len(back.members(c, split=None)) == 6
    with pytest.raises(ConfigError, match="cluster 7 does not exist"):
        back.members(7)
    with pytest.raises(ConfigError, match="object 'nope' is not in this clustering"):
        back.cluster_of("nope")


def test_reader_errors_say_what_to_do(tmp_path):
    with pytest.raises(AssetError, match="run 'ges cluster DATASET' first"):
        load_clusters(tmp_path)
    (tmp_path / "clusters.json").write_text(json.dumps({"format": "ges.object_clusters", "version": 99}))
    with pytest.raises(AssetError, match="version 99"):
        load_clusters(tmp_path)


# --- the command on real dataset folders ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def procedural_dataset(tmp_path_factory) -> Path:
    """A dataset folder written by the real writer: procedural objects (2 per category) of 10 categories and every
    unseen one, one record each whose contact step failed (clustering reads objects, not grasps)."""
    from ges_core.dataset import STEPS, DatasetWriter, GraspRecord, StepOutcome

    root = tmp_path_factory.mktemp("cluster") / "ds"
    config = LibraryConfig(sources=("procedural",), procedural_count=2)
    steps = {s: StepOutcome.failed("no_contacts") if s == "contacts" else StepOutcome.skipped() for s in STEPS}
    with DatasetWriter(root, {"library": config.model_dump(mode="json")}) as writer:
        rows = ObjectLibrary(config).list()
        kept = sorted({o.category for o in rows})[:10]
        for o in (o for o in rows if o.category in kept or o.split != "train"):
            writer.add(GraspRecord(object_id=o.object_id, category=o.category, split=o.split, hand="allegro",
                                   simulator="sapien", joint_names=("j0",), steps=steps))  # fmt: skip
    return root


def test_cluster_command_on_a_procedural_dataset(procedural_dataset, capsys):
    assert main(["cluster", str(procedural_dataset), "--no-progress", "--points", "512"]) == 0
    out = capsys.readouterr().out
    clusters = load_clusters(procedural_dataset)
    assert (procedural_dataset / "clusters.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(clusters.objects) == len(open_dataset(procedural_dataset).entries) and clusters.k == 3
    assert {m.split for m in clusters.objects.values()} == {"train", "unseen_category"}
    for category, cluster in clusters.categories.items():  # the category rule, read back from the file
        train = [m for m in clusters.objects.values() if m.category == category and m.split == "train"]
        assert {m.cluster for m in train} == {cluster}
    assert all(m.assigned_by == "nearest_centre" for m in clusters.objects.values() if m.split != "train")
    for category, counts in clusters.mixed_categories.items():  # categories K-means splits keep its labels
        train = [m for m in clusters.objects.values() if m.category == category and m.split == "train"]
        assert all(m.cluster == m.kmeans_cluster for m in train) and sum(counts) == len(train)
    for c in range(3):
        assert f"{', '.join(sorted(k for k, v in clusters.categories.items() if v == c))}" in out
    assert "wrote" in out


def test_cluster_command_on_stage1_records(tmp_path, capsys):
    """Two real Stage 1 records: k = 2 gives two one-object clusters (warned); k = 3 cannot be made."""
    dataset = tmp_path / "ds"
    shutil.copytree(STAGE1_DATASET, dataset)
    out = tmp_path / "elsewhere" / "k2.json"
    assert main(["cluster", str(dataset), "-k", "2", "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert printed.count("warning: cluster") == 2 and out.with_suffix(".png").is_file()
    clusters = load_clusters(out)
    assert {clusters.cluster_of("procedural/box/000"), clusters.cluster_of("procedural/sphere/000")} == {0, 1}
    assert main(["cluster", str(dataset), "-k", "3", "--no-progress"]) == 1
    assert "cannot make k = 3 clusters from 2 training object(s)" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:  # argparse's usage error, before anything runs
        main(["cluster", str(dataset), "-k", "0"])
    assert exit_.value.code == 2 and "argument -k: '0' is not a whole number >= 1" in capsys.readouterr().err
    assert main(["cluster", str(dataset), "--category-share", "1.5"]) == 1
    assert "category_share: Input should be less than or equal to 1" in capsys.readouterr().err
    assert not (dataset / "clusters.json").exists()


def test_a_broken_object_stops_the_command_or_is_left_out(tmp_path, capsys):
    """A zero-volume sheet among real procedural objects: an error naming it, or with --skip-bad a recorded skip."""
    from ges_core.dataset import STEPS, DatasetWriter, GraspRecord, StepOutcome

    (tmp_path / "objects" / "flat").mkdir(parents=True)
    sheet = "v 0 0 0\nv 0.1 0 0\nv 0.1 0.1 0\nv 0 0.1 0\nf 1 2 3\nf 1 3 4\n"  # zero volume
    (tmp_path / "objects" / "flat" / "sheet.obj").write_text(sheet)
    config = LibraryConfig(sources=("procedural", "user"), user_dir=tmp_path / "objects", procedural_count=1)
    library = ObjectLibrary(config)
    chosen = [o for o in library.list() if o.split == "train"][:6] + library.list(source="user")
    steps = {s: StepOutcome.failed("no_contacts") if s == "contacts" else StepOutcome.skipped() for s in STEPS}
    with DatasetWriter(tmp_path / "ds", {"library": config.model_dump(mode="json")}) as writer:
        for o in chosen:
            writer.add(GraspRecord(object_id=o.object_id, category=o.category, split=o.split, hand="allegro",
                                   simulator="sapien", joint_names=("j0",), steps=steps))  # fmt: skip
    args = ["cluster", str(tmp_path / "ds"), "-k", "2", "--points", "256", "--no-progress"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "shape features of 'user/flat/sheet'" in err and "--skip-bad" in err
    assert main([*args, "--skip-bad"]) == 0
    assert "left out user/flat/sheet" in capsys.readouterr().out
    clusters = load_clusters(tmp_path / "ds")
    assert list(clusters.skipped) == ["user/flat/sheet"] and len(clusters.objects) == len(chosen) - 1
