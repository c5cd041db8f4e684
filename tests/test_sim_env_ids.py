"""Per-env operations of every simulator backend: ``env_ids`` on set_hand_state, set_object_pose and
reset, and SimulationError.env_ids with the recovery of a blown-up env.

The reference is a second backend of the same kind driven by the same commands, in which nothing is
done to the listed envs: scenes are independent and both engines are deterministic, so every env not
listed must match it bit for bit (state, velocities and PD targets, seen through later steps).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ges_core.errors import ArrayError, ConfigError, SimulationError
from ges_core.sim import SimBackend
from ges_plugins.sims.pybullet.backend import PybulletBackend
from ges_plugins.sims.pybullet.engine import p
from ges_plugins.sims.sapien.backend import SapienBackend

from helpers_sim import UP, allegro_test_hand, box_asset, loaded_sim, open_q

pytestmark = pytest.mark.sim

BACKENDS = {"sapien": SapienBackend, "pybullet": PybulletBackend}
N = 3
BOX_REST_Z = 0.03
"""m: centre height of the 6 cm test box resting on the table."""


@pytest.fixture(scope="module")
def hand():
    return allegro_test_hand()


def _bases(n: int = N) -> np.ndarray:
    """(n, 7) distinct hand base poses, 0.3 m off the box at the origin (no contact when the hand dives)."""
    bases = np.tile(UP, (n, 1))
    bases[:, 0] = -0.3
    bases[:, 1] = 0.1 * np.arange(n)
    return bases


def _moving_scene(cls: type[SimBackend], hand, n: int = N) -> SimBackend:
    """n envs, every one in motion: box falling from 10 cm, fingers closing, wrist sliding."""
    sim = loaded_sim(cls, hand, num_envs=n)
    sim.set_hand_state(open_q(hand, n), _bases(n))
    sim.load_object(box_asset(), pose=np.array([0.0, 0.0, 0.1 + BOX_REST_Z, 1.0, 0.0, 0.0, 0.0]))
    sim.set_joint_targets(np.tile(hand.description.closed_pose(0.8), (n, 1)))
    sim.set_wrist_targets(_bases(n) + [0.05, 0.0, -0.05, 0.0, 0.0, 0.0, 0.0])
    sim.step(6)
    return sim


def _state(sim: SimBackend) -> dict[str, np.ndarray]:
    q, qvel = sim.joint_state()
    return {"q": q, "qvel": qvel, "wrist": sim.wrist_pose(), "object": sim.object_pose()}


def _assert_envs_equal(a: SimBackend, b: SimBackend, envs: list[int]) -> None:
    sa, sb = _state(a), _state(b)
    for key in sa:
        np.testing.assert_array_equal(sa[key][envs], sb[key][envs], err_msg=key)


def _poke_object_velocity(sim: SimBackend, env: int, velocity: list[float]) -> None:
    """Set env ``env``'s object velocity inside the engine (the backends reject non-finite commands)."""
    if isinstance(sim, SapienBackend):
        sim._envs[env].obj_body.set_linear_velocity(np.asarray(velocity, dtype=np.float32))
    else:
        scene = sim._scenes[env]
        p.resetBaseVelocity(scene.obj, velocity, [0.0, 0.0, 0.0], physicsClientId=scene.cid)


# -- teleports and resets change only the listed envs ---------------------------------------------
@pytest.mark.parametrize("name", BACKENDS)
def test_teleports_with_env_ids_leave_other_envs_alone(hand, name):
    a, b = (_moving_scene(BACKENDS[name], hand) for _ in range(2))
    moving = _state(b)
    assert np.abs(moving["qvel"][[0, 2]]).max(axis=1).min() > 0.1  # the untouched envs really move
    q_new = hand.description.closed_pose(0.3)[None]
    wrist_new = np.array([[0.2, 0.3, 0.4, 0.0, 1.0, 0.0, 0.0]])  # flipped upside down
    obj_new = np.array([[0.5, 0.5, 0.2, math.cos(0.3), 0.0, 0.0, math.sin(0.3)]])
    a.set_hand_state(q_new, wrist_new, env_ids=[1])
    a.set_object_pose(obj_new, env_ids=np.array([1]))
    _assert_envs_equal(a, b, [0, 2])
    moved = _state(a)
    np.testing.assert_allclose(moved["q"][1], q_new[0], atol=1e-6)
    np.testing.assert_array_equal(moved["qvel"][1], 0.0)
    np.testing.assert_allclose(moved["wrist"][1], wrist_new[0], atol=1e-6)
    np.testing.assert_allclose(moved["object"][1], obj_new[0], atol=1e-6)
    a.step(10)
    b.step(10)  # the untouched envs keep their velocities and PD targets: they evolve exactly as in b
    _assert_envs_equal(a, b, [0, 2])
    held = _state(a)  # env 1's targets followed the teleport: the hand stays put
    np.testing.assert_allclose(held["q"][1], q_new[0], atol=0.02)
    np.testing.assert_allclose(held["wrist"][1, :3], wrist_new[0, :3], atol=0.01)
    assert held["object"][1, 2] < obj_new[0, 2] - 0.001  # and the teleported box falls from there


@pytest.mark.parametrize("name", BACKENDS)
def test_reset_with_env_ids_resets_only_those_envs(hand, name):
    a, b = (_moving_scene(BACKENDS[name], hand) for _ in range(2))
    a.reset(env_ids=[2, 0])
    a.reset(env_ids=[])  # nothing to do
    _assert_envs_equal(a, b, [1])
    reset = _state(a)
    np.testing.assert_allclose(reset["q"][[0, 2]], open_q(hand, 2), atol=1e-6)
    np.testing.assert_array_equal(reset["qvel"][[0, 2]], 0.0)
    np.testing.assert_allclose(reset["wrist"][[0, 2]], _bases()[[0, 2]], atol=1e-6)
    np.testing.assert_allclose(reset["object"][[0, 2], 2], 0.1 + BOX_REST_Z, atol=1e-6)  # the load pose
    a.step(10)
    b.step(10)
    _assert_envs_equal(a, b, [1])
    still = _state(a)  # targets were reset too: the open hands stay open where they were put
    np.testing.assert_allclose(still["q"][[0, 2]], open_q(hand, 2), atol=1e-3)
    np.testing.assert_allclose(still["wrist"][[0, 2], :3], _bases()[[0, 2], :3], atol=1e-3)


@pytest.mark.parametrize("name", BACKENDS)
def test_env_ids_accept_integer_arrays_in_the_order_given(hand, name):
    sim = loaded_sim(BACKENDS[name], hand, num_envs=N)
    sim.load_object(box_asset())
    poses = np.array([[0.1, 0.0, 0.3, 1.0, 0.0, 0.0, 0.0], [0.2, 0.0, 0.3, 1.0, 0.0, 0.0, 0.0]])
    sim.set_object_pose(poses, env_ids=torch.tensor([2, 0]))
    np.testing.assert_allclose(sim.object_pose()[[2, 0], 0], [0.1, 0.2], atol=1e-6)
    sim.set_hand_state(open_q(hand, 1) + 0.1, env_ids=(np.int64(1),))
    q, _ = sim.joint_state()
    np.testing.assert_allclose(q[1], open_q(hand)[0] + 0.1, atol=1e-6)
    np.testing.assert_allclose(q[[0, 2]], open_q(hand, 2), atol=1e-6)


@pytest.mark.parametrize("name", BACKENDS)
def test_bad_env_ids_are_rejected_before_anything_changes(hand, name):
    sim = _moving_scene(BACKENDS[name], hand)
    before = _state(sim)
    q1, pose1 = open_q(hand, 1), np.array([[0.0, 0.0, 0.3, 1.0, 0.0, 0.0, 0.0]])
    cases = [
        (lambda: sim.set_hand_state(q1, env_ids=[3]), rf"{name}.set_hand_state: env ids \[3\] out of range "),
        (lambda: sim.set_object_pose(pose1, env_ids=[-1]), r"env ids \[-1\] out of range for num_envs=3 \(valid: 0..2"),
        (lambda: sim.reset(env_ids=[1, 2, 1]), rf"{name}.reset: env_ids \[1, 2, 1\] repeat \[1\]; name each env once"),
        (lambda: sim.reset(env_ids=[True, False, True]), r"integer env indices.*boolean mask"),
        (lambda: sim.reset(env_ids=[0.0]), r"integer env indices, got \[0.0\]"),
        (lambda: sim.reset(env_ids=[[0]]), r"1-D sequence"),
    ]
    for call, message in cases:
        with pytest.raises(ConfigError, match=message):
            call()
    rows = [  # arrays that do not match env_ids: the array is wrong, an ArrayError
        (lambda: sim.set_hand_state(open_q(hand, 2), env_ids=[1]), r"q has 2 rows but env_ids names 1 env\(s\) \[1\]"),
        (lambda: sim.set_hand_state(q1, np.tile(UP, (3, 1)), env_ids=[0]), r"wrist_pose has 3 rows but env_ids names"),
        (lambda: sim.set_object_pose(np.tile(pose1, (2, 1)), env_ids=[0]), r"pose has 2 rows but env_ids names 1"),
        (lambda: sim.load_object(box_asset(), np.tile(pose1, (2, 1)), env_ids=[2]), r"load_object: pose has 2 rows"),
    ]
    for call, message in rows:
        with pytest.raises(ArrayError, match=message):
            call()
    after = _state(sim)
    for key in before:
        np.testing.assert_array_equal(after[key], before[key], err_msg=key)


def _poke_hand_velocity(sim: SimBackend, env: int, speed: float) -> None:
    """Set the velocity of env ``env``'s last driven joint inside the engine."""
    if isinstance(sim, SapienBackend):
        articulation = sim._envs[env].hand
        qvel = articulation.get_qvel()
        qvel[-1] = speed
        articulation.set_qvel(qvel)
    else:
        scene = sim._scenes[env]
        joint = int(sim._layout.drive_ids[-1])
        q = p.getJointState(scene.hand, joint, physicsClientId=scene.cid)[0]
        p.resetJointState(scene.hand, joint, q, speed, physicsClientId=scene.cid)
        sim._state = None  # the joint changed behind the backend's back


# -- blown-up envs --------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["object_nan", "object_fast", "hand_nan"])
@pytest.mark.parametrize("name", BACKENDS)
def test_blown_env_is_reported_alone_and_reset_brings_it_back(hand, name, kind):
    """Env 1 blows up (box NaN or 500 m/s, a hand joint NaN): one SimulationError names env 1 only, envs 0
    and 2 still take every step, and reset(env_ids=[1]) gives a scene that collides again like one never
    blown up."""
    a, b = (_moving_scene(BACKENDS[name], hand) for _ in range(2))
    if kind == "hand_nan":
        _poke_hand_velocity(a, 1, math.nan)
    else:
        _poke_object_velocity(a, 1, [math.nan if kind == "object_nan" else 500.0, 0.0, 0.0])
    with pytest.raises(SimulationError, match=rf"{name} env 1: ") as caught:
        a.step(4)
    assert caught.value.env_ids == (1,) and "env 0" not in str(caught.value) and "env 2" not in str(caught.value)
    b.step(4)
    _assert_envs_equal(a, b, [0, 2])
    with pytest.raises(SimulationError) as again:  # still blown until something restores it
        a.step(1)
    assert again.value.env_ids == (1,)
    b.step(1)
    for sim in (a, b):
        sim.reset(env_ids=[1])
        dive = _bases() - [0.0, 0.0, 0.7, 0.0, 0.0, 0.0, 0.0]  # wrist targets 20 cm below the table top
        sim.set_wrist_targets(dive)
        sim.step(90)
    _assert_envs_equal(a, b, [0, 1, 2])  # env 1 too: once reset, it evolves as if it had never blown up
    sa = _state(a)
    np.testing.assert_allclose(sa["object"][1, 2], BOX_REST_Z, atol=1e-3)  # the box lands on the table ...
    assert sa["wrist"][1, 2] > -0.02  # ... and the table stops the hand (a broken world lets both through)


@pytest.mark.parametrize("name", BACKENDS)
def test_every_blown_env_is_listed_and_teleports_restore_them(hand, name):
    a, b = (_moving_scene(BACKENDS[name], hand) for _ in range(2))
    _poke_object_velocity(a, 0, [0.0, math.nan, 0.0])
    _poke_object_velocity(a, 2, [0.0, 0.0, 800.0])
    with pytest.raises(SimulationError, match=rf"{name} env 0: .*; {name} env 2: ") as caught:
        a.step(3)
    assert caught.value.env_ids == (0, 2) and "env 1" not in str(caught.value)
    b.step(3)
    _assert_envs_equal(a, b, [1])
    a.set_hand_state(open_q(hand, 1), env_ids=[0])  # a teleport restores a blown env first ...
    a.set_object_pose(np.array([[0.0, 0.0, BOX_REST_Z + 0.05, 1.0, 0.0, 0.0, 0.0]]), env_ids=[2])
    a.step(60)
    b.step(60)
    _assert_envs_equal(a, b, [1])
    sa = _state(a)
    np.testing.assert_allclose(sa["object"][[0, 2], 2], BOX_REST_Z, atol=1e-3)  # ... object at its load pose or put
    np.testing.assert_allclose(sa["wrist"][0], _bases()[0], atol=2e-3)


@pytest.mark.parametrize("name", BACKENDS)
def test_command_errors_name_no_env(hand, name):
    sim = loaded_sim(BACKENDS[name], hand)
    sim.close()
    with pytest.raises(SimulationError) as caught:  # refused, not blown: no env to blame
        sim.step(1)
    assert caught.value.env_ids == ()
    assert SimulationError("x", env_ids=[3, 1, 3]).env_ids == (1, 3)
