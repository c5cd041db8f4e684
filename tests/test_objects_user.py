"""A user's own folder: objects.yaml (mass / density / friction), command-line overrides, the hull test,
the processing cache, preparing before a run, and the CLI's --user-dir / --with-library rules."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from ges_core.cli import main
from ges_core.errors import AssetError, ConfigError
from ges_core.objects.decompose import hull_depth
from ges_core.objects.library import ObjectLibrary
from ges_core.objects.prepare import prepare_before_run
from ges_core.objects.procedural import _extrude_star_polygon
from ges_core.objects.processing import process_entry

ELL = np.array([[0, 0], [0.08, 0], [0.08, 0.025], [0.025, 0.025], [0.025, 0.08], [0, 0.08]])


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """box/small (5 x 7 x 9 cm), bracket/ell (concave, 40 faces), fruit/orange (icosphere, 7 cm), objects.yaml."""
    monkeypatch.setenv("GES_CACHE_DIR", str(tmp_path / "cache"))
    root = tmp_path / "mine"
    for category in ("box", "bracket", "fruit"):
        (root / category).mkdir(parents=True)
    trimesh.creation.box(extents=(0.05, 0.07, 0.09)).export(root / "box" / "small.stl")
    _extrude_star_polygon(ELL, 0.04).export(root / "bracket" / "ell.obj")
    trimesh.creation.icosphere(subdivisions=2, radius=0.035).export(root / "fruit" / "orange.ply")
    (root / "objects.yaml").write_text(
        "defaults:\n  friction: 0.8\nobjects:\n  fruit/orange: {mass: 0.15}\n"
        "  user/box/small: {density: 300, friction: 0.5}\n"
    )
    return root


def test_objects_yaml_reaches_the_assets(folder):
    library = ObjectLibrary(sources=("user",), user_dir=folder)
    box, orange, ell = (library.get(f"user/{n}", decompose=True) for n in ("box/small", "fruit/orange", "bracket/ell"))
    assert (box.density, box.friction) == (300.0, 0.5)
    assert box.mass == pytest.approx(300 * 0.05 * 0.07 * 0.09)
    hull = trimesh.load(orange.collision[0].path, force="mesh")
    assert orange.mass == 0.15 and orange.density * hull.volume == pytest.approx(0.15)  # what the engines compute
    assert (ell.density, ell.friction) == (500.0, 0.8)  # library density, folder's default friction


def test_command_line_properties_override_objects_yaml(folder):
    library = ObjectLibrary(
        sources=("user",), user_dir=folder, object_properties={"user/fruit/orange": {"density": 900.0}}
    )
    orange = library.get("user/fruit/orange")
    assert orange.density == 900.0 and orange.friction == 0.8  # the density replaces the yaml's mass
    with pytest.raises(ConfigError, match=r"object_properties: user/fruit/lime not in the library"):
        ObjectLibrary(sources=("user",), user_dir=folder, object_properties={"user/fruit/lime": {"mass": 1}}).list()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("objects:\n  fruit/orange: {colour: red}\n", r"objects\.fruit/orange\.colour: Extra inputs are not permitted"),
        ("objects:\n  fruit/lime: {mass: 0.1}\n", r"objects\.fruit/lime names no mesh of .*box/small"),
        ("objects:\n  box/small: {mass: 0.1, density: 5}\n", r"give mass or density, not both"),
        ("defaults:\n  friction: -1\n", r"defaults\.friction: Input should be greater than or equal to 0"),
    ],
)
def test_bad_objects_yaml_is_refused(folder, text, message):
    (folder / "objects.yaml").write_text(text)
    with pytest.raises(ConfigError, match=message):
        ObjectLibrary(sources=("user",), user_dir=folder).list()


def test_hull_test_keeps_coacd_for_an_l_and_not_for_a_box(folder):
    """The L's inner wall is 20 mm below its hull half-way up (the top and bottom planes bound it there); its
    vertices all lie on hull planes, so only surface samples find the depth."""
    ell = trimesh.load(folder / "bracket" / "ell.obj", force="mesh")
    assert hull_depth(ell) == pytest.approx(0.020, abs=0.001)
    assert hull_depth(ell, samples=0) < 1e-9
    library = ObjectLibrary(sources=("user",), user_dir=folder)
    assert library.processed("user/bracket/ell").kind == "concave"
    assert library.processed("user/box/small").kind == "convex"


def test_processing_is_cached_on_disk(folder):
    entry = ObjectLibrary(sources=("user",), user_dir=folder).entry("user/bracket/ell")
    first, second = process_entry(entry), process_entry(entry)
    assert second.mesh is not first.mesh  # loaded, not rebuilt
    assert np.array_equal(second.mesh.vertices, first.mesh.vertices)
    assert np.array_equal(second.mesh.faces, first.mesh.faces)
    assert (second.kind, second.volume, second.hull_depth) == (first.kind, first.volume, first.hull_depth)
    _extrude_star_polygon(ELL * 1.2, 0.04).export(folder / "bracket" / "ell.obj")  # a new file: a new key
    assert process_entry(entry).volume == pytest.approx(first.volume * 1.44, rel=1e-6)


def test_the_processing_key_follows_the_code_not_its_layout():
    """The key's code part (``processed_cache.code_hash``): the processing modules reformatted at another line
    length (ruff), with a comment or with a docstring changed keep every processed mesh cached; a changed constant
    does not. (Before, the key hashed the modules' text, so ``placement.py`` was left unformatted.)"""
    import subprocess
    import sys

    from ges_core.objects import processed_cache

    here = Path(processed_cache.__file__).parent
    sources = [(here / name).read_text() for name in processed_cache._MODULES]
    base = processed_cache.code_hash(sources)
    pytest.importorskip("ruff")
    narrow = [
        subprocess.run(
            [sys.executable, "-m", "ruff", "format", "--line-length", "60", "-"],
            input=text, capture_output=True, text=True, check=True,
        ).stdout
        for text in sources
    ]  # fmt: skip
    assert sum(a != b for a, b in zip(sources, narrow, strict=True)) >= 3  # the layout did change
    placement = sources[processed_cache._MODULES.index("placement.py")]
    first_def = placement.index("\ndef ") + 1
    noted = placement[:first_def] + "# a comment\n" + placement[first_def:]
    docstring = placement.replace('"""', '"""Reworded. ', 1)
    for variant in (
        narrow,
        [noted if t is placement else t for t in sources],
        [docstring if t is placement else t for t in sources],
    ):
        assert processed_cache.code_hash(variant) == base
    changed = placement + "\nEXTRA_CONSTANT = 1\n"
    assert processed_cache.code_hash([changed if t is placement else t for t in sources]) != base


def test_a_damaged_processing_cache_entry_is_processed_again(folder):
    entry = ObjectLibrary(sources=("user",), user_dir=folder).entry("user/bracket/ell")
    first = process_entry(entry)
    (stored,) = (folder.parent / "cache" / "objects" / "processed").glob("*.npz")
    stored.write_bytes(stored.read_bytes()[:100])  # cut short (a disk that filled up, a copy interrupted)
    again = process_entry(entry)
    assert np.array_equal(again.mesh.vertices, first.mesh.vertices) and again.kind == first.kind
    assert len(stored.read_bytes()) > 100  # written again


def test_prepare_before_run_decomposes_only_what_needs_it(folder):
    library = ObjectLibrary(sources=("user", "procedural"), user_dir=folder, procedural_count=1)
    ids = ["user/bracket/ell", "user/box/small", "procedural/can/000", "procedural/torus/000"]
    first = {r.object_id: r.status for r in prepare_before_run(library, ids, progress=False)}
    assert first == {
        "user/bracket/ell": "decomposed",
        "user/box/small": "not_needed",
        "procedural/torus/000": "decomposed",
    }
    again = {r.object_id: r.status for r in prepare_before_run(library, ids, progress=False)}
    assert again["user/bracket/ell"] == "cached" and again["procedural/torus/000"] == "cached"


def test_cli_user_dir_alone_unless_with_library(folder, capsys):
    assert main(["objects", "list", "--user-dir", str(folder)]) == 0
    alone = capsys.readouterr().out
    assert alone.splitlines()[-1] == "3 objects" and "procedural/" not in alone
    assert main(["objects", "list", "--user-dir", str(folder), "--with-library", "--count", "1"]) == 0
    both = capsys.readouterr().out
    assert "procedural/can/000" in both and "user/fruit/orange" in both
    assert main(["objects", "list", "--with-library"]) == 1
    assert "give the folder with --user-dir" in capsys.readouterr().err


def test_cli_says_which_option_is_missing(folder, tmp_path, capsys):
    out = str(tmp_path / "ds")
    cases = [
        (["--objects", "user/fruit/orange"], "is a user object but no user folder is given: add --user-dir DIR"),
        (["--user-dir", str(folder), "--objects", "fruit/lime"], "unknown object 'user/fruit/lime'. Did you mean"),
        (["--user-dir", str(folder), "--objects", "procedural/can/000"], "or --with-library beside --user-dir"),
        (["--user-dir", str(folder), "--mass", "fruit/orange=heavy"], "--mass 'fruit/orange=heavy': write OBJECT_ID="),
    ]
    for extra, message in cases:
        assert main(["synth", "--out", out, "--hands", "allegro", *extra]) == 1
        assert message in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()  # refused before anything is written


@pytest.mark.sim
def test_synth_on_a_user_folder_keeps_its_properties_and_draws_the_sheet(folder, tmp_path, capsys):
    from ges_core.dataset import open_dataset
    from ges_core.synthesis import SynthesisConfig

    out, pictures = tmp_path / "ds", tmp_path / "pics"
    args = ["--user-dir", str(folder), "--objects", "box/small", "--hands", "allegro", "--mass", "box/small=0.2"]
    assert main(["synth", *args, "--out", str(out), "--pictures", str(pictures), "--no-progress"]) == 0
    assert f"contact sheet: {pictures / 'contact_sheet.png'}" in capsys.readouterr().out
    assert (pictures / "contact_sheet.png").is_file()
    dataset = open_dataset(out)
    assert [r.object_id for r in dataset] == ["user/box/small"]
    library = SynthesisConfig.of_dataset(dataset).library  # what Stage 2 rebuilds
    assert library.sources == ("user",) and library.object_properties["user/box/small"].mass == 0.2
    assert library.build().get("user/box/small").mass == pytest.approx(0.2)


@pytest.mark.sim
def test_demo_on_a_user_folder(folder, tmp_path, capsys):
    out = tmp_path / "demo"
    args = ["demo", "--user-dir", str(folder), "--objects", "fruit/orange", "-o", "hands=[allegro]", "--out", str(out)]
    assert main([*args, "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "| allegro | sapien | 1 |" in text and (out / "contact_sheet.png").is_file()
    assert main(["demo", "--objects", "user/fruit/orange", "--out", str(out)]) == 1
    assert "add --user-dir DIR" in capsys.readouterr().err


def test_missing_decomposition_names_the_command_that_works(folder, capsys):
    library = ObjectLibrary(sources=("user",), user_dir=folder)
    with pytest.raises(AssetError) as info:
        library.get("user/bracket/ell")
    command = f"ges objects prepare --user-dir {folder} --objects user/bracket/ell"
    assert f"run `{command}`" in str(info.value)
    assert main(command.split()[1:]) == 0  # that command, as printed
    assert "1 objects: 1 decomposed" in capsys.readouterr().out
    assert len(ObjectLibrary(sources=("user",), user_dir=folder).get("user/bracket/ell").collision) >= 2


def test_long_objects_get_a_lower_coacd_threshold(folder):
    """CoACD's threshold is relative to size: a 32 cm L gets FAST's threshold x 15/32, a 8 cm one FAST's own."""
    from ges_core.objects.decompose import FAST, cached_parts, settings_for

    _extrude_star_polygon(ELL * 4, 0.04).export(folder / "bracket" / "long.obj")
    library = ObjectLibrary(sources=("user",), user_dir=folder, decompose=True)
    short, long = library.processed("user/bracket/ell"), library.processed("user/bracket/long")
    assert settings_for(short.mesh, FAST) == FAST
    assert settings_for(long.mesh, FAST).threshold == pytest.approx(FAST.threshold * 0.15 / 0.32, abs=1e-4)
    library.get("user/bracket/long")
    assert cached_parts(long.mesh_hash, settings_for(long.mesh, FAST)) is not None
    assert cached_parts(long.mesh_hash, FAST) is None  # its parts are cached under its own settings
