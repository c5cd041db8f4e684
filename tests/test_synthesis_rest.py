"""The resting-pose check: objects set down alone on the table, in both real engines.

A box and a sphere stay where the library rests them; an egg-like ellipsoid lying on its side stays too, while
the same egg standing on its tip (a balance point an untouched simulation keeps) tips over once set down
3 degrees off, and refinement then fails with reason ``unstable_rest`` instead of grasping a moving object.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from ges_core.errors import ConfigError, SynthesisError
from ges_core.objects.asset import ConvexPart, ObjectAsset, PrimitiveShape
from ges_core.objects.simple import box_asset
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.synthesis.physics.refine import RefineConfig, check_rest
from ges_core.synthesis.physics.scene import rest_drift

REGISTRY = load_registry(autoload=False)
SIMS = tuple(REGISTRY.names("sim"))
SECOND = 120
"""Physics steps in one second at the default 1/120 s."""


def _egg(tmp_path: Path, *, upright: bool) -> ObjectAsset:
    """A 5 x 5 x 8 cm ellipsoid, convex, in the library's resting frame (lowest point at z = 0, centre of mass
    over the origin): standing on its tip (upright) or lying on its side."""
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    mesh.apply_scale([0.025, 0.025, 0.04])
    if not upright:
        turn = np.eye(4)
        turn[:3, :3] = Rotation.from_euler("x", 90, degrees=True).as_matrix()
        mesh.apply_transform(turn)
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
    path = tmp_path / f"egg_{'up' if upright else 'lying'}.obj"
    path.write_text(mesh.export(file_type="obj"))
    return ObjectAsset(
        object_id=f"test/egg_{'up' if upright else 'lying'}",
        category="egg",
        mesh_path=path,
        collision=(ConvexPart(path=path),),
        mass=500.0 * mesh.volume,
    )


def _sphere(tmp_path: Path) -> ObjectAsset:
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    mesh.apply_translation([0.0, 0.0, 0.03])
    path = tmp_path / "sphere.obj"
    path.write_text(mesh.export(file_type="obj"))
    shape = PrimitiveShape(kind="sphere", size=(0.03,), pose=(0.0, 0.0, 0.03, 1.0, 0.0, 0.0, 0.0))
    return ObjectAsset(object_id="test/sphere", category="sphere", mesh_path=path, collision=(shape,), mass=0.057)


@pytest.fixture(scope="module")
def allegro():
    return REGISTRY.build_hand("allegro")


@pytest.mark.parametrize("sim_name", SIMS)
def test_resting_objects_stay_and_an_egg_on_its_tip_tips_over(allegro, sim_name, tmp_path):
    config = RefineConfig()
    stays = {"box": box_asset(), "sphere": _sphere(tmp_path), "egg lying": _egg(tmp_path, upright=False)}
    for name, obj in stays.items():
        sim = REGISTRY.build_sim(sim_name, SceneConfig(num_envs=1))
        try:
            drift = rest_drift(sim, allegro, obj, SECOND, tilt_deg=config.rest_tilt_deg)
        finally:
            sim.close()
        assert drift.shift < 0.002, (name, drift)
        assert drift.turn_deg < 6.0, (name, drift)  # the sphere keeps its 3 degrees: any turn of it rests
        assert not drift.exceeds(config.rest_max_shift, config.rest_max_turn_deg), name
    sim = REGISTRY.build_sim(sim_name, SceneConfig(num_envs=1))
    try:
        upright = _egg(tmp_path, upright=True)
        untouched = rest_drift(sim, allegro, upright, SECOND)
        tipped = rest_drift(sim, allegro, upright, SECOND, tilt_deg=config.rest_tilt_deg)
        with pytest.raises(SynthesisError, match="does not stay at its resting pose") as info:
            check_rest(sim, allegro, upright, config)
        assert info.value.reason == "unstable_rest"
        check_rest(sim, allegro, upright, RefineConfig(rest_steps=0))  # the check is off: nothing raised
    finally:
        sim.close()
    assert untouched.turn_deg < 1.0, untouched  # the balance point an untouched simulation keeps
    assert tipped.turn_deg > 30.0 and tipped.shift > 0.005, tipped
    assert tipped.seconds == pytest.approx(1.0)


def test_rest_drift_needs_a_step(allegro):
    sim = REGISTRY.build_sim(SIMS[0], SceneConfig(num_envs=1))
    try:
        with pytest.raises(ConfigError, match="steps must be >= 1"):
            rest_drift(sim, allegro, box_asset(), 0)
    finally:
        sim.close()
