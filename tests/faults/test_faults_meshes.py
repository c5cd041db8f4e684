"""Issue 10, point 1: hostile meshes and slow objects. A huge mesh costs bounded time (simplified to
``LibraryConfig.max_faces``, its hull to ``bounds.HULL_FACES``); degenerate, mis-scaled and doubly named
meshes fail that one object with one line; Stage 1 writes each task's records as soon as it finishes.
"""

from __future__ import annotations

import functools
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from doubles_meshes import FakeTask, finish_when_told, records_when_told

from ges_core.cli import build_parser, main
from ges_core.cli.cmd_objects import library_from_args
from ges_core.dataset import open_dataset
from ges_core.errors import AssetError, ConfigError
from ges_core.objects import bounds, placement
from ges_core.objects.library import ObjectLibrary
from ges_core.objects.processing import min_width
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.synthesis.run import pipeline

RADIUS = 0.03
"""m. Every sphere here is 6 cm across."""


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GES_CACHE_DIR", str(tmp_path / "cache"))


def write(root: Path, rel: str, mesh_or_text: trimesh.Trimesh | str) -> Path:
    """Write ``root / rel`` (a mesh, or the file's text) and return it."""
    path = root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(mesh_or_text, str):
        path.write_text(mesh_or_text)
    else:
        mesh_or_text.export(path)
    return path


def user_library(root: Path, **settings) -> ObjectLibrary:
    return ObjectLibrary(sources=("user",), user_dir=root, **settings)


# -- huge: bounded work -------------------------------------------------------------------------------------
def test_a_mesh_above_max_faces_is_simplified_to_the_limit(tmp_path):
    write(tmp_path, "big/ball.obj", trimesh.creation.icosphere(subdivisions=5, radius=RADIUS))  # 20,480 faces
    obj = user_library(tmp_path, max_faces=2000).processed("user/big/ball")
    assert len(obj.mesh.faces) <= 2000 and obj.mesh.is_watertight
    np.testing.assert_allclose(obj.mesh.extents, 2 * RADIUS, rtol=0.02)
    assert obj.volume == pytest.approx(4 / 3 * np.pi * RADIUS**3, rel=0.03)


def test_max_faces_is_checked_and_taken_by_the_command_line(tmp_path, capsys):
    with pytest.raises(ConfigError, match=r"max_faces: Input should be greater than or equal to 100"):
        user_library(tmp_path, max_faces=10)
    write(tmp_path, "big/ball.obj", trimesh.creation.icosphere(subdivisions=5, radius=RADIUS))
    args = ["objects", "prepare", "--source", "user", "--user-dir", str(tmp_path), "--max-faces", "2000"]
    library = library_from_args(build_parser().parse_args(args))
    assert library.config.max_faces == 2000 and len(library.processed("user/big/ball").mesh.faces) <= 2000
    assert main([*args, "--no-progress"]) == 0
    assert "1 objects: 1 not_needed" in capsys.readouterr().out


def test_the_resting_pose_and_the_width_use_a_bounded_hull(monkeypatch):
    """A sphere's 20,480 hull faces took trimesh's stable poses 50 s (cost ~ faces squared) and the min width
    1.9 GB; with the hull bound lowered to 512 both see at most 512 faces."""
    monkeypatch.setattr(bounds, "HULL_FACES", 512)
    monkeypatch.setattr(placement, "HULL_FACES", 512)
    seen = []
    real = trimesh.poses.compute_stable_poses

    def spy(mesh, **kw):
        seen.append(len(mesh.convex_hull.faces))
        assert seen[-1] <= 512, f"stable poses asked of a hull of {seen[-1]} faces"
        return real(mesh, **kw)

    monkeypatch.setattr(trimesh.poses, "compute_stable_poses", spy)
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=RADIUS)
    rotation = placement.stable_rotation(sphere)
    assert seen and np.allclose(rotation[:3, :3] @ rotation[:3, :3].T, np.eye(3))
    assert len(bounds.bounded_hull(sphere).faces) <= 512
    assert min_width(sphere) == pytest.approx(2 * RADIUS, rel=0.02)


@pytest.mark.slow
def test_a_1_3_million_face_mesh_is_listed_in_bounded_time(tmp_path):
    """The issue's mesh: `ges objects list --sizes` ran 20 minutes at 5-6 GB; now about 16 s and 1 GB."""
    write(tmp_path, "big/ball.obj", trimesh.creation.icosphere(subdivisions=8, radius=RADIUS))  # 1,310,720 faces
    write(tmp_path, "good/box.obj", trimesh.creation.box((0.05, 0.06, 0.08)))
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "ges_core.cli", "objects", "list", "--source", "user", "--user-dir", str(tmp_path)]
        + ["--sizes"],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert done.returncode == 0, done.stderr
    assert "user/big/ball" in done.stdout and "6.0 x   6.0 x   6.0 cm" in done.stdout
    assert "user/good/box" in done.stdout and "2 objects" in done.stdout
    assert time.perf_counter() - start < 180


# -- degenerate, mis-scaled, doubly named: one line, that object only ---------------------------------------
FLAT = "v 0 0 0\nv 0.1 0 0\nv 0.1 0.1 0\nv 0 0.1 0\nf 1 2 3\nf 1 3 4\nf 1 3 2\nf 1 4 3\n"
TETRA = "v 0 0 0\nv {x} 0 0\nv 0 0.05 0\nv 0 0 0.05\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
POINT = "v 0 0 0\nv 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n"
HOSTILE = {
    "nan.obj": (TETRA.format(x="nan"), r"1 vertices are NaN or infinite; re-export the mesh"),
    "inf.obj": (TETRA.format(x="inf"), r"1 vertices are NaN or infinite; re-export the mesh"),
    "empty.obj": ("", r"empty\.obj: file holds no triangles; export the object as a triangle mesh"),
    "void.stl": ("solid x\nendsolid x\n", r"void\.stl: file holds no triangles"),
    "flat.obj": (FLAT, r"zero volume \(flat: 0 mm thick, minimum 0\.1 mm\); give the object thickness"),
    "point.obj": (POINT, r"zero volume \(every face is degenerate\); the mesh has no surface"),
    "garbage.glb": ("not a glb file", r"garbage\.glb: cannot read mesh \(ValueError: "),
}


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_a_degenerate_mesh_fails_with_one_line_naming_it(tmp_path, name):
    text, reason = HOSTILE[name]
    write(tmp_path, f"bad/{name}", text)
    oid = f"user/bad/{Path(name).stem}"
    with pytest.raises(AssetError, match=reason) as caught:
        user_library(tmp_path).processed(oid)
    message = str(caught.value)
    assert "\n" not in message and name in message


def test_a_millimetre_mesh_is_refused_with_a_unit_hint(tmp_path):
    write(tmp_path, "parts/box60.stl", trimesh.creation.box((60, 60, 60)))  # a 60 mm box saved in millimetres
    with pytest.raises(AssetError, match=r"user/parts/box60 \(.*box60\.stl\): the mesh is 60 m across") as caught:
        user_library(tmp_path).processed("user/parts/box60")
    assert "if its units are millimetres, set user_scale: 0.001 (`--user-scale 0.001`" in str(caught.value)
    np.testing.assert_allclose(user_library(tmp_path, user_scale=0.001).extents("user/parts/box60"), 0.06)
    np.testing.assert_allclose(user_library(tmp_path, normalize_size=0.08).extents("user/parts/box60"), 0.08)


def test_two_files_with_one_id_refuse_that_id_only(tmp_path, capsys):
    write(tmp_path, "kitchen/mug.obj", trimesh.creation.box((0.05, 0.06, 0.08)))
    write(tmp_path, "kitchen/mug.stl", trimesh.creation.cylinder(0.03, 0.08))
    write(tmp_path, "kitchen/cup.obj", trimesh.creation.box((0.03, 0.06, 0.08)))
    library = user_library(tmp_path)
    assert [o.object_id for o in library.list()] == ["user/kitchen/cup", "user/kitchen/mug"]
    with pytest.raises(AssetError, match=r"^user/kitchen/mug: mug\.obj and mug\.stl in .*kitchen both give this"):
        library.get("user/kitchen/mug")
    assert library.get("user/kitchen/cup").mass > 0
    assert main(["objects", "list", "--source", "user", "--user-dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "user/kitchen/mug" in out and "INVALID: mug.obj and mug.stl" in out and "2 objects, 1 invalid" in out


def test_objects_list_sizes_reports_each_hostile_mesh_and_goes_on(tmp_path, capsys):
    for name, (text, _) in HOSTILE.items():
        write(tmp_path, f"bad/{name}", text)
    write(tmp_path, "parts/box60.stl", trimesh.creation.box((60, 60, 60)))
    write(tmp_path, "good/box.obj", trimesh.creation.box((0.05, 0.06, 0.08)))
    assert main(["objects", "list", "--source", "user", "--user-dir", str(tmp_path), "--sizes"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1] == f"{len(HOSTILE) + 2} objects, {len(HOSTILE) + 1} invalid"
    assert "6.0 x   8.0 x   5.0 cm" in next(line for line in lines if line.startswith("user/good/box"))


# -- results collected as they finish ------------------------------------------------------------------------
def test_a_slow_task_holds_back_no_other_tasks_results(tmp_path):
    flag = tmp_path / "go"
    got = []
    tasks = [FakeTask(i) for i in range(4)]
    for records in pipeline._results(tasks, str(flag), 2, runner=finish_when_told):
        got += records
        if len(got) == 3:
            flag.touch()  # only now may the slow first task finish
    assert sorted(got[:3]) == [1, 2, 3] and got[3] == 0


OBJECTS = ["procedural/box/000", "procedural/cube/000", "procedural/can/000"]


def test_a_stopped_run_keeps_every_finished_task(tmp_path, monkeypatch):
    flag, out = tmp_path / "go", tmp_path / "dataset"
    monkeypatch.setattr(pipeline, "_results", functools.partial(pipeline._results, runner=records_when_told))
    monkeypatch.setattr(pipeline, "RunContext", lambda *args: str(flag))
    written = []

    def stop_after_two(record):
        written.append(record.object_id)
        if len(written) == 2:
            flag.touch()  # let the slow task end so that the pool can close, then stop the run as Ctrl-C would
            raise KeyboardInterrupt

    config = SynthesisConfig.model_validate({"chunk_size": 1})
    with pytest.raises(KeyboardInterrupt):
        run_synthesis(OBJECTS, ["shadow"], config, out, workers=2, on_record=stop_after_two)
    assert sorted(r.object_id for r in open_dataset(out)) == sorted(written) == sorted(OBJECTS[1:])


@pytest.mark.sim
def test_records_do_not_depend_on_the_order_tasks_finish_in(tmp_path):
    """A real run: two workers and one object per task write the same record files as one process, and a
    doubly named and a millimetre object become failed records while the others go on."""
    write(tmp_path / "user", "kitchen/mug.obj", trimesh.creation.box((0.05, 0.06, 0.08)))
    write(tmp_path / "user", "kitchen/mug.stl", trimesh.creation.box((0.05, 0.06, 0.08)))
    write(tmp_path / "user", "parts/box60.stl", trimesh.creation.box((60, 60, 60)))
    library = {"sources": ["procedural", "user"], "user_dir": str(tmp_path / "user"), "procedural_count": 1}
    config = SynthesisConfig.model_validate(
        {"library": library, "refine_sim": "pybullet", "validate_sims": ["pybullet"], "chunk_size": 1}
        | {"validate": {"hold_steps": 60}}
    )
    objects = ["user/kitchen/mug", "procedural/cube/000", "user/parts/box60", "procedural/box/000"]
    for name, workers in (("one", 1), ("two", 2)):
        run_synthesis(objects, ["allegro"], config, tmp_path / name, workers=workers)
    one, two = (
        {p.relative_to(tmp_path / n).as_posix(): p.read_bytes() for p in (tmp_path / n).glob("records/**/*.npz")}
        for n in ("one", "two")
    )
    assert one == two and len(one) == 4
    records = {r.object_id: r for r in open_dataset(tmp_path / "two")}
    assert "mug.obj and mug.stl" in records["user/kitchen/mug"].errors["contacts"]
    assert "60 m across" in records["user/parts/box60"].errors["contacts"]
    assert records["procedural/cube/000"].steps["contacts"].ok
