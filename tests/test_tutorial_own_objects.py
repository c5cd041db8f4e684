"""docs/tutorials/own-objects.md, run as the page shows it: the page's make_meshes.py and objects.yaml make a
folder of three meshes, then every ``ges`` command of the page, read from the page, runs on it with an empty
object cache. The printed listing is compared with the page's (numbers within their last printed digit) and
cross-checked against the object library; the dataset and pictures are checked on disk.

Real engines at the page's size (3 objects, Allegro, SAPIEN, robust trials on): about 15 s of CPU.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import trimesh
from helpers_tutorial import block_with, commands, console_output, ges_commands, ges_runner, tutorial

from ges_core.dataset import open_dataset
from ges_core.objects.library import ObjectLibrary

PAGE = tutorial("own-objects.md")
pytestmark = [pytest.mark.sim, pytest.mark.slow]  # real engines, about 10-40 s of CPU
_NUMBER = re.compile(r"\d+\.\d+|\d+")


def _same_but_numbers(got: str, shown: str, tol: float) -> None:
    """``got`` reads as ``shown`` word for word, each number within ``tol`` of the page's."""
    assert _NUMBER.sub("#", got).split() == _NUMBER.sub("#", shown).split(), (got, shown)
    for a, b in zip(_NUMBER.findall(got), _NUMBER.findall(shown), strict=True):
        assert abs(float(a) - float(b)) <= tol, (got, shown)


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The reader's folder after steps 1-2: the page's meshes and objects.yaml."""
    root = tmp_path_factory.mktemp("own_objects")
    assert "python make_meshes.py" in commands(PAGE)
    (root / "make_meshes.py").write_text(block_with(PAGE, "python", "trimesh.creation.annulus"))
    subprocess.run([sys.executable, "make_meshes.py"], cwd=root, check=True, timeout=120)
    files = sorted(str(p.relative_to(root)) for p in (root / "my_objects").rglob("*") if p.is_file())
    assert files == console_output(PAGE, "find my_objects -type f | sort").split()
    (root / "my_objects" / "objects.yaml").write_text(block_with(PAGE, "yaml", "fruit/orange: {mass: 0.15}"))
    return root


def test_the_page_commands_in_order(folder: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("GES_CACHE_DIR", str(folder / "cache"))  # the page's run started from an empty cache
    ges = ges_runner(folder)
    cmds = ges_commands(PAGE)
    assert len(cmds) == 6, cmds  # a command added to the page needs its check here
    listed, prepared, synth, info, no_folder, typo = cmds

    out = ges(*listed)
    assert out.returncode == 0, out.stderr
    shown = console_output(PAGE, "ges " + " ".join(listed)).splitlines()
    got = out.stdout.splitlines()
    assert len(got) == len(shown)
    for line, page_line in zip(got, shown, strict=True):
        _same_but_numbers(line, page_line, tol=0.11)  # printed to 0.1 cm / 0.1 g

    library = ObjectLibrary(sources=("user",), user_dir=folder / "my_objects")  # the same facts, from Python
    orange, tea = library.get("user/fruit/orange"), library.get("user/box/tea")
    assert orange.mass == pytest.approx(0.15) and orange.friction == pytest.approx(0.8)
    assert tea.mass == pytest.approx(300 * 0.05 * 0.07 * 0.09, rel=1e-3) and tea.friction == pytest.approx(0.5)

    out = ges(*prepared, "--no-progress")  # the bar is left out: it goes to stderr, the summary to stdout
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("3 objects: 1 decomposed, 2 not_needed"), out.stdout
    assert ges(*prepared, "--no-progress").stdout.startswith("3 objects: 1 cached, 2 not_needed")
    napkin = library.get("user/ring/napkin", decompose=True)
    assert len(napkin.collision) > 1  # the tube is several convex parts
    assert trimesh.load(folder / "my_objects" / "ring" / "napkin.obj", force="mesh").is_watertight

    out = ges(*synth)
    assert out.returncode == 0, out.stderr
    assert "| allegro | sapien | 3 |" in out.stdout
    assert out.stdout.rstrip().endswith("contact sheet: runs/mine-pictures/contact_sheet.png")
    records = list(open_dataset(folder / "runs" / "mine"))
    assert sorted(r.object_id for r in records) == ["user/box/tea", "user/fruit/orange", "user/ring/napkin"]
    assert all(r.steps["contacts"].ok and r.steps["retargeting"].ok for r in records)
    assert sum(r.validations["sapien"].success for r in records) >= 2, out.stdout
    pictures = folder / "runs" / "mine-pictures"
    assert (pictures / "contact_sheet.png").stat().st_size > 1000
    assert len(list((pictures / "allegro").glob("user__*.png"))) == 3

    out = ges(*info)
    assert out.returncode == 0, out.stderr
    assert "by category:  box 1, fruit 1, ring 1\n" in out.stdout

    for cmd in (no_folder, typo):  # the page shows the exact one-line errors; nothing is written
        out = ges(*cmd)
        assert out.returncode == 1
        line = next(ln for ln in out.stderr.splitlines() if ln.startswith("ges: error:"))
        assert line in console_output(PAGE, "ges " + " ".join(cmd))
    assert not (folder / "runs" / "x").exists()

    # the page's note: the dataset stores user_dir as typed, and objects.yaml's values are not stored in it
    stored = open_dataset(folder / "runs" / "mine").run_config["library"]
    assert stored["user_dir"] == "my_objects" and stored["object_properties"] == {}
