"""A hand whose collision mesh stands far inside its convex hull, before any `ges hand prepare`: the run-side half of
docs/hands/assets.md. :func:`undecomposed_deep_hulls` finds it without writing anything, ``ges synth`` decomposes it
before the run and says so (the dataset then keeps the prepared hand), and :func:`run_synthesis` called directly warns.
The built-in hands have no such mesh; the Ability hand has the two that ``ges hand prepare`` decomposes."""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import pytest

from ges_core.cli import main
from ges_core.dataset.hands import hand_entry
from ges_core.hand_files import FileHand
from ges_core.hand_prep.prepare import (
    HULL_GAP_TOL,
    UnpreparedHandWarning,
    decompose_deep_hulls,
    prepare_hand,
    undecomposed_deep_hulls,
    warn_undecomposed_hulls,
)
from ges_core.registry import load_registry
from ges_core.synthesis.retarget.wrist import check_handedness_fingers

from conftest import ABILITY_PKG, EXAMPLE_HAND_PKG, ability_hand
from helpers_hands import write_l_palm_hand, write_source_plugin


@pytest.fixture
def empty_cache(monkeypatch, tmp_path) -> Path:
    """A cache folder of the test's own: no OBJ copies, no CoACD parts."""
    cache = tmp_path / "cache"
    monkeypatch.setenv("GES_CACHE_DIR", str(cache))
    return cache


def _files(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.is_file()] if folder.exists() else []


@pytest.mark.slow
def test_a_deep_hull_is_found_without_writing_and_gone_once_decomposed(empty_cache, tmp_path):
    yaml = write_l_palm_hand(tmp_path, ".glb")  # a glb: its OBJ copy is not made yet
    hand = FileHand(yaml, yaml.with_suffix(".urdf"), strict=False)
    (found,) = undecomposed_deep_hulls(hand)  # the palm; every other link is a box (its own hull)
    assert found.path.name == "palm_l.glb" and found.links == ["palm"] and found.hull_gap > HULL_GAP_TOL
    assert _files(empty_cache) == []  # measuring converts nothing and decomposes nothing
    with pytest.warns(UnpreparedHandWarning, match=r"'mine'.*palm_l\.glb \([0-9.]+ mm\).*`ges hand prepare mine`"):
        warn_undecomposed_hulls({"mine": hand})

    (done,) = decompose_deep_hulls(hand, progress=False)
    assert done.path.suffix == ".obj" and done.parts >= 2 and done.hull_gap == found.hull_gap
    assert undecomposed_deep_hulls(hand) == []
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_undecomposed_hulls({"mine": hand})
    # `ges hand prepare` (its own measuring and plan) finds the same mesh, gap and parts, already in the cache
    (plan,) = [m for m in prepare_hand(hand, progress=False).meshes if m.path == done.path]
    assert plan.cached and plan.parts == done.parts and plan.hull_gap == pytest.approx(found.hull_gap, abs=1e-9)


def test_builtin_hands_have_none_and_the_ability_hand_has_what_prepare_decomposes(empty_cache):
    """The meshes found are those whose surface lies deeper than 3 mm inside their hull by an independent measure:
    trimesh's exact signed distance to the hull (closest points) at the vertices and 2,000 surface samples, where
    ``hull_gap`` uses face-plane distances at its own samples. Ability: the palm and the distal phalanx (17 and
    7 mm), not the wrist plate (2 mm) or the thumb links (convex)."""
    import numpy as np
    import trimesh

    from ges_core.hand_prep.geometry import link_shapes

    registry = load_registry()
    assert [undecomposed_deep_hulls(registry.build_hand(name)) for name in ("allegro", "shadow")] == [[], []]
    hand = ability_hand()
    depth = {}
    for group in link_shapes(hand.urdf_text(), hand.urdf_path().parent).values():
        for shape in group:
            if shape.source is None:  # a box, sphere or cylinder: its own hull
                continue
            mesh = shape.mesh
            points = np.concatenate([mesh.vertices, trimesh.sample.sample_surface(mesh, 2000, seed=1)[0]])
            depth[shape.source.name] = float(trimesh.proximity.signed_distance(mesh.convex_hull, points).max())
    found = {p.path.name: p.hull_gap for p in undecomposed_deep_hulls(hand)}
    assert (
        set(found) == {name for name, d in depth.items() if d > HULL_GAP_TOL} == {"FB_palm_ref_MIR.obj", "idx-F2_C.obj"}
    )
    assert all(abs(found[name] - depth[name]) < 1e-3 for name in found), (found, depth)
    assert all(abs(d - HULL_GAP_TOL) > 5e-4 for d in depth.values())  # no mesh near the threshold: not a float call


@pytest.mark.sim
@pytest.mark.slow
def test_synth_decomposes_the_hand_before_the_run_and_the_api_warns(empty_cache, tmp_path, capsys, monkeypatch):
    pytest.importorskip("mani_skill")  # the Ability's URDF
    write_source_plugin(tmp_path, "ability_src", ABILITY_PKG / "__init__.py")
    monkeypatch.syspath_prepend(str(tmp_path))  # the entry point's module
    registry = load_registry(tmp_path / "registry.yaml")
    unprepared = hand_entry(registry.build_hand("ability_src"))["hash"]

    from ges_core.synthesis import SynthesisConfig, run_synthesis
    from ges_core.synthesis.run.tasks import RegistrySpec

    config = SynthesisConfig.model_validate({"validate_sims": ["sapien"], "robust": {"enabled": False}})
    api_out, objects = tmp_path / "api", ["procedural/sphere/000"]
    spec = RegistrySpec(str(tmp_path / "registry.yaml"))
    with pytest.warns(UnpreparedHandWarning, match=r"'ability_src'.*FB_palm_ref_MIR\.obj.*idx-F2_C\.obj"):
        run_synthesis(objects, ["ability_src"], config, api_out, registry=spec)
    assert json.loads((api_out / "manifest.json").read_text())["hands"]["ability_src"]["hash"] == unprepared

    out = tmp_path / "cli"
    args = ["--registry", str(tmp_path / "registry.yaml"), "synth", "--hands", "ability_src", "--objects", *objects]
    args += ["--out", str(out), "-o", "validate_sims=[sapien]", "-o", "robust.enabled=false", "--no-progress"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnpreparedHandWarning)
        assert main(args) == 0
    printed = capsys.readouterr().out
    line = re.search(r"hand 'ability_src': 2 collision mesh\(es\) .*", printed)
    meshes = ("FB_palm_ref_MIR", "idx-F2_C")
    assert line and all(re.search(rf"{m}\.obj \([0-9.]+ mm, [0-9]+ parts\)", line[0]) for m in meshes), printed
    prepared = hand_entry(registry.build_hand("ability_src"))["hash"]
    assert prepared != unprepared  # the engines now collide the parts
    assert json.loads((out / "manifest.json").read_text())["hands"]["ability_src"]["hash"] == prepared
    assert main(args) == 0 and "collision mesh(es)" not in capsys.readouterr().out  # nothing left to decompose


def test_a_two_finger_hand_is_refused_before_the_dataset_exists(tmp_path, monkeypatch, capsys):
    """The example gripper's index finger serves the middle, ring and little slots (slot_fill), so Stage 1 cannot
    tell the palm's left from its right. Before, the run stopped inside a worker, after the dataset folder and its
    manifest were written, with a message about the wrist convention."""
    monkeypatch.syspath_prepend(str(EXAMPLE_HAND_PKG))
    (tmp_path / "registry.yaml").write_text("plugins: [ges_example_hand]\n")
    registry = load_registry(tmp_path / "registry.yaml")
    for name in ("allegro", "shadow"):  # the ring finger serves the Allegro's little slot
        check_handedness_fingers(registry.build_hand(name).description)
    out = tmp_path / "dataset"
    args = ["--registry", str(tmp_path / "registry.yaml"), "synth", "--hands", "example_gripper"]
    code = main([*args, "--objects", "procedural/box/000", "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert code != 0 and "one finger ('index') serves both the middle and the little slot" in err, err
    assert not out.exists()
    # ges hand lint says it too, as a note of the slots check (before, it said nothing)
    code = main(["--registry", str(tmp_path / "registry.yaml"), "hand", "lint", "example_gripper", "--sim", "sapien"])
    note = "[slots] note: hand 'example_gripper': one finger ('index') serves both"
    assert code == 0 and note in capsys.readouterr().out


@pytest.mark.slow
def test_stage2_builds_the_hand_decomposed_as_synth_does(empty_cache, tmp_path, capsys):
    """Stage 2's entry points (``training.envs.build_setup``, ``env.evaluate.fanout.evaluate_cells``: their tests
    check they call it) build their hand with :func:`built_prepared`: on a fresh cache it decomposes the deep hull
    first and says so, so the hand is the prepared one Stage 1 ran (the dataset's stored description) instead of a
    hull that warns ``HandChangedWarning``; with the parts cached it builds the same hand and prints nothing."""
    from ges_core.hand_prep.prepare import built_prepared

    yaml = write_l_palm_hand(tmp_path, ".glb")

    class Files:  # the registry's one method used here, over the real file hand
        def build_hand(self, name):
            return FileHand(yaml, yaml.with_suffix(".urdf"), strict=False)

    unprepared = hand_entry(Files().build_hand("mine"))["hash"]
    hand = built_prepared(Files(), "mine")
    assert "hand 'mine': 1 collision mesh(es)" in capsys.readouterr().out and undecomposed_deep_hulls(hand) == []
    prepared = hand_entry(hand)["hash"]
    assert prepared != unprepared  # the engine URDF names the parts: the hand synth would have stored
    assert hand_entry(built_prepared(Files(), "mine"))["hash"] == prepared and capsys.readouterr().out == ""
