"""Stage 1 records into the Stage 2 environment: selection, frames, joint order by name, error messages.

A tiny dataset from the real pipeline (Allegro, SAPIEN): the first of a few primitives that gets a grasp,
and a flat sheet whose contact step fails (no grasp stored).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from ges_core.dataset import open_dataset
from ges_core.env.grasp_env import EnvConfig, GraspEnv
from ges_core.env.grasp_pool import GraspPool
from ges_core.env.grasp_source import (
    SELECTIONS,
    contacts_off_surface,
    grasp_targets,
    library_for,
    load_grasp,
    object_rest_pose,
    open_grasp_dataset,
    record_asset,
    rejection,
    select_records,
)
from ges_core.env.vec_env import GraspVecEnv
from ges_core.errors import ArrayError, AssetError, ConfigError
from ges_core.objects.library import LibraryConfig
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.transforms import compose

pytestmark = pytest.mark.sim
FLAT = "user/flat/sheet"
CANDIDATES = ("procedural/cube/000", "procedural/sphere/000", "procedural/box/000", "procedural/ellipsoid/000")
"""Primitives tried in order until Stage 1 stores a grasp for one (its verdicts change as Stage 1 evolves)."""


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A flat sheet (its contact step fails) and the first candidate that gets a grasp."""
    root = tmp_path_factory.mktemp("grasp_source")
    (root / "objects" / "flat").mkdir(parents=True)
    sheet = "v 0 0 0\nv 0.1 0 0\nv 0.1 0.1 0\nv 0 0.1 0\nf 1 2 3\nf 1 3 4\n"  # zero volume
    (root / "objects" / "flat" / "sheet.obj").write_text(sheet)
    library = LibraryConfig(sources=("procedural", "user"), user_dir=str(root / "objects"), procedural_count=1)
    config = SynthesisConfig.model_validate({"library": library, "validate": {"hold_steps": 60}})
    run_synthesis([FLAT], ["allegro"], config, root / "ds")
    for oid in CANDIDATES:
        run_synthesis([oid], ["allegro"], config, root / "ds")
        if open_dataset(root / "ds").get(oid, "allegro").pregrasp is not None:
            return open_dataset(root / "ds")
    raise AssertionError(f"Stage 1 stored no grasp for any of {CANDIDATES}")


@pytest.fixture(scope="module")
def grasped(dataset) -> str:
    """Id of the object whose record holds a grasp."""
    return next(r.object_id for r in dataset if r.pregrasp is not None)


@pytest.fixture(scope="module")
def registry():
    return load_registry()


@pytest.fixture(scope="module")
def allegro(registry):
    return registry.build_hand("allegro")


def test_each_rule_rejects_what_it_should(dataset, grasped):
    """The real record with its validation, then its refinement, marked failed: only the stricter rules drop it."""
    record = dataset.get(grasped, "allegro")
    assert all(rejection(record, rule) == "" for rule in SELECTIONS)  # validated: every rule takes it
    steps = record.steps
    dropped = dataclasses.replace(steps["validation"], ok=False, reason="dropped")
    unvalidated = dataclasses.replace(record, steps={**steps, "validation": dropped})
    assert rejection(unvalidated, "validated") == "not validated (failed at validation: dropped)"
    assert rejection(unvalidated, "refined") == rejection(unvalidated, "any") == ""
    few = dataclasses.replace(steps["refinement"], ok=False, reason="few_contacts")
    unrefined = dataclasses.replace(record, steps={**steps, "refinement": few, "validation": dropped})
    assert rejection(unrefined, "refined") == "not refined (failed at refinement: few_contacts)"
    assert rejection(unrefined, "validated").startswith("not validated")
    assert rejection(unrefined, "any") == ""


def test_selection_rules_follow_the_records_flags(dataset, grasped):
    records = {r.object_id: r for r in dataset}
    chosen = {rule: select_records(dataset, "allegro", selection=rule) for rule in SELECTIONS}
    for sel in chosen.values():
        assert len(sel.records) + len(sel.rejected) == len(records)
        assert set(sel.splits) == set(records)
    ids = {rule: {r.object_id for r in sel.records} for rule, sel in chosen.items()}
    assert ids["validated"] <= ids["refined"] <= ids["any"]
    assert ids["validated"] == {oid for oid, r in records.items() if r.success}
    assert ids["refined"] == {oid for oid, r in records.items() if r.steps["refinement"].ok}
    assert FLAT not in ids["any"]
    assert chosen["any"].rejected[FLAT] == "no grasp stored (failed at contacts: bad_mesh)"
    assert ids["any"] == {grasped}  # the one whose retargeting reached: a grasp and a pre-grasp stored


def test_targets_are_the_record_in_the_world_with_joints_by_name(dataset, grasped, registry, allegro):
    record = dataset.get(grasped, "allegro")
    asset = library_for(dataset).get(grasped)
    pose = object_rest_pose(registry, "sapien", asset)
    targets = grasp_targets(record, allegro.description, 3, pose)
    assert targets.q.shape == (3, 16) and targets.wrist_pose.shape == (3, 7)
    # cross-check with Stage 1's own frame mapping (ges_core.transforms.compose) and a fresh scene
    with registry.build_sim("sapien", SceneConfig()) as sim:
        sim.load_object(asset)
        world = sim.object_pose()[0]
    np.testing.assert_allclose(targets.wrist_pose[1], compose(world, record.grasp.wrist_pose), atol=1e-9)
    np.testing.assert_allclose(targets.pre_wrist_pose[2], compose(world, record.pregrasp.wrist_pose), atol=1e-9)
    np.testing.assert_allclose(targets.q[0], allegro.description.apply_couplings(record.grasp.q))
    # a record whose joints are stored in another order gives the same targets
    perm = np.random.default_rng(0).permutation(16)
    shuffled = dataclasses.replace(
        record,
        joint_names=tuple(np.array(record.joint_names)[perm]),
        grasp=dataclasses.replace(record.grasp, q=record.grasp.q[perm]),
        pregrasp=dataclasses.replace(record.pregrasp, q=record.pregrasp.q[perm]),
    )
    again = grasp_targets(shuffled, allegro.description, 3, pose)
    np.testing.assert_array_equal(again.q, targets.q)
    np.testing.assert_array_equal(again.pre_q, targets.pre_q)


def test_env_starts_at_the_pregrasp_two_cm_from_the_grasp(dataset, grasped, registry, allegro):
    """End to end in SAPIEN: after stage one the wrist is at the pre-grasp, 2 cm back along the approach."""
    asset, targets = load_grasp(
        dataset, grasped, allegro.description, 2, selection="any", registry=registry, sim_name="sapien"
    )
    sim = registry.build_sim("sapien", SceneConfig(num_envs=2))
    venv = GraspVecEnv(GraspEnv(sim, allegro, asset, targets, EnvConfig(reach_steps=30)))
    goal_pos = venv.env.obs_layout.unpack(venv.get_observations()["policy"], "goal_pos")
    sim.close()
    record = dataset.get(grasped, "allegro")
    expected = record.grasp.wrist_pose[:3] - record.pregrasp.wrist_pose[:3]  # rotation-free: rest pose is upright
    assert np.linalg.norm(expected) == pytest.approx(0.02, abs=1e-6)
    assert torch.allclose(goal_pos, torch.as_tensor(expected, dtype=torch.float32).expand(2, 3), atol=0.006)


def test_dataset_errors_say_what_is_missing(tmp_path, dataset, allegro):
    with pytest.raises(AssetError, match=r"no grasp dataset at .*nowhere: the folder does not exist.*ges synth"):
        open_grasp_dataset(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(AssetError, match="is not a grasp dataset: it has no manifest.json"):
        open_grasp_dataset(tmp_path / "empty")
    with pytest.raises(AssetError, match=r"holds no record of hand 'shadow' \(it holds: allegro\)"):
        select_records(dataset, "shadow")
    with pytest.raises(AssetError, match=r"with simulator 'pybullet' \(its simulators for that hand: sapien\)"):
        select_records(dataset, "allegro", simulator="pybullet")
    with pytest.raises(ConfigError, match="unknown split 'test'; choose one of train, unseen_object"):
        select_records(dataset, "allegro", split="test")
    with pytest.raises(ConfigError, match="unknown grasp selection 'best'; choose one of validated, refined, any"):
        select_records(dataset, "allegro", selection="best")
    with pytest.raises(AssetError, match="holds no record of object 'procedural/plate/000' with hand 'allegro'"):
        load_grasp(dataset, "procedural/plate/000", allegro.description, 1)


def test_record_errors_say_why_it_gives_no_grasp(dataset, grasped, registry, allegro):
    with pytest.raises(
        AssetError, match=r"\(user/flat/sheet, allegro\).*selection 'any'.*failed at contacts: bad_mesh"
    ):
        load_grasp(dataset, FLAT, allegro.description, 1, selection="any")
    flat = dataset.get(FLAT, "allegro")
    assert rejection(flat, "validated").startswith("no grasp stored")
    with pytest.raises(AssetError, match=r"holds no grasp to execute \(failed at contacts: bad_mesh\)"):
        grasp_targets(flat, allegro.description, 1)
    cube = dataset.get(grasped, "allegro")
    shadow = registry.build_hand("shadow").description
    with pytest.raises(ConfigError, match="is for hand 'allegro', not 'shadow'"):
        grasp_targets(cube, shadow, 1)
    renamed = dataclasses.replace(cube, joint_names=("joint_x", *cube.joint_names[1:]))
    with pytest.raises(ConfigError, match=r"missing \['joint_0.0'\], unknown \['joint_x'\].*regenerate"):
        grasp_targets(renamed, allegro.description, 1)
    with pytest.raises(ConfigError, match="num_envs=0; give at least 1"):
        grasp_targets(cube, allegro.description, 0)
    with pytest.raises(ArrayError, match=r"grasp_targets: object_pose (has shape|holds NaN|has a zero quaternion)"):
        grasp_targets(cube, allegro.description, 1, np.zeros(7))


class _Rescaled:
    """Test double of an ObjectLibrary that builds one object 1.5 times as large about its own centre (a library
    change since Stage 1 ran: the stored grasp no longer fits it); other objects as the real library builds them."""

    def __init__(self, library, object_id: str, folder) -> None:
        self.library, self.object_id, self.folder = library, object_id, folder

    def get(self, object_id: str):
        import trimesh

        asset = self.library.get(object_id)
        if object_id != self.object_id:
            return asset
        mesh = trimesh.load(asset.mesh_path, force="mesh", process=False)
        mesh.apply_translation(-mesh.centroid)
        mesh.apply_scale(1.5)
        path = self.folder / "rescaled.obj"
        mesh.export(path)
        return dataclasses.replace(asset, mesh_path=path)

    def processed(self, object_id: str):
        return self.get(object_id)  # what the check reads of it: mesh_path


def test_a_record_is_checked_against_the_object_the_library_builds_now(dataset, grasped, allegro, tmp_path):
    """Every Stage 2 way in (record_asset, load_grasp, the training pool) takes the object only if the record's
    contacts lie on its surface; an object rebuilt 1.5 times as large is refused by name."""
    record, library = dataset.get(grasped, "allegro"), library_for(dataset)
    asset = record_asset(library, record)
    assert asset == library.get(grasped)
    assert contacts_off_surface(asset.mesh_path, record.contacts.positions) < 1e-6  # sampled on the surface
    rescaled = _Rescaled(library, grasped, tmp_path)
    moved = contacts_off_surface(rescaled.get(grasped).mesh_path, record.contacts.positions)
    assert moved > 0.005  # every contact of a convex object moves out by 0.5 x its distance from the centre
    with pytest.raises(AssetError, match=rf"\({grasped}, allegro\): its contacts lie up to {moved * 1e3:.1f} mm off"):
        record_asset(rescaled, record)
    with pytest.raises(AssetError, match=f"regenerate its records \\(`ges synth --objects {grasped} --hands allegro`"):
        GraspPool.from_selection(select_records(dataset, "allegro"), allegro, rescaled)
    from ges_core.env.evaluate import BaselineConfig
    from ges_core.env.evaluate.runner import evaluate_object

    config = BaselineConfig(hand="allegro", sim="sapien", envs=2)
    row = evaluate_object(load_registry(), allegro, record, rescaled, config, SceneConfig())
    assert row["end_reasons"] == ["error", "error"] and "mm off the surface" in row["error"]  # an error row, named
    assert record_asset(rescaled, record, tolerance=moved + 1e-6) is not None  # the tolerance is what decides
    no_contacts = dataclasses.replace(record, contacts=None)  # e.g. imported without them: nothing to check
    assert record_asset(rescaled, no_contacts).mesh_path == tmp_path / "rescaled.obj"


def test_dataset_validate_objects_names_the_records_that_no_longer_fit(dataset, grasped, tmp_path, monkeypatch, capsys):
    from ges_core.cli import main
    from ges_core.env import grasp_source

    assert main(["dataset", "validate", str(dataset.root), "--objects"]) == 0
    assert "no problems, each record's contacts on its object's surface" in capsys.readouterr().out
    real = grasp_source.library_for
    monkeypatch.setattr(grasp_source, "library_for", lambda d: _Rescaled(real(d), grasped, tmp_path))
    assert main(["dataset", "validate", str(dataset.root), "--objects"]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"({grasped}, allegro): its contacts lie up to ") and "mm off the surface" in out[0]
    assert out[-1] == f"1 problem(s) in {dataset.root}"  # the sheet has no contacts: nothing to check
    assert main(["dataset", "validate", str(dataset.root)]) == 0  # without --objects the records alone are checked


def test_contacts_off_surface_is_the_distance_to_the_nearest_face(dataset, grasped):
    """Cross-check with the box geometry: points outside the object's bounding box, straight out from a face
    centre, lie exactly that far from a box-like object (the first candidates are a cube and a box)."""
    asset = library_for(dataset).get(grasped)
    import trimesh

    mesh = trimesh.load(asset.mesh_path, force="mesh", process=False)
    lo, hi = mesh.bounds
    centre = (lo + hi) / 2
    top = np.array([centre[0], centre[1], hi[2]])
    if contacts_off_surface(asset.mesh_path, top[None]) > 1e-6:
        pytest.skip(f"{grasped} has no face at the centre of its top (not a box)")
    for d in (0.0, 0.003, 0.02):
        point = top + np.array([0.0, 0.0, d])
        assert contacts_off_surface(asset.mesh_path, point[None]) == pytest.approx(d, abs=1e-9)
    inside = (top - np.array([0.0, 0.0, 0.004]))[None]  # inside the solid, centimetres from every other face
    assert contacts_off_surface(asset.mesh_path, inside) == pytest.approx(0.004, abs=1e-9)


def test_library_needs_a_pipeline_run_config(dataset):
    bare = dataclasses.replace(dataset, manifest={**dataset.manifest, "run_config": {"hands": ["allegro"]}})
    with pytest.raises(ConfigError, match="run_config has no 'library' section"):
        library_for(bare)


def test_the_hand_of_a_stage_2_command_comes_from_the_dataset_when_not_given(tmp_path, monkeypatch):
    """No --hand: the dataset's only hand, else the registry's default if the dataset holds it, else an error naming
    the dataset's hands; a given hand is used as given."""
    import shutil

    from ges_core.env import grasp_source
    from ges_core.errors import ConfigError
    from ges_core.registry import load_registry

    registry = load_registry()
    two = "tests/data/dataset_v2"  # allegro and shadow records
    default = registry.default("hand")
    assert default in ("allegro", "shadow") and grasp_source.dataset_hand(two, registry) == default
    other = "allegro" if default == "shadow" else "shadow"
    assert grasp_source.dataset_hand(two, registry, other) == other
    only_other = tmp_path / "one_hand"
    shutil.copytree(two, only_other)
    for path in (only_other / "records" / default).glob("*"):
        path.unlink()
    assert grasp_source.dataset_hand(only_other, registry) == other
    monkeypatch.setattr(registry, "default", lambda kind: "ability")
    with pytest.raises(ConfigError, match=r"hands \['allegro', 'shadow'\] and not of the default hand 'ability'"):
        grasp_source.dataset_hand(two, registry)
