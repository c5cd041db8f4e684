"""The SimBackend contract, checked the same way on every built-in backend and on every registered outside
backend that declares its tolerances (:func:`_outside_backends`; ``examples/ges-mujoco-sim``).

Tests that used to be written once per backend (test_sim_sapien.py, test_sim_pybullet.py) with the
same scene and the same references: forward kinematics from pytorch-kinematics, rest heights of
primitives, joint and wrist driving, object replacement, reset semantics, determinism, and every
argument and state error (checked once, in ``ges_core.sim``, so the messages are the same). Where the
engines differ in precision, :data:`TOLERANCES` says by how much. Engine-specific behaviour (each
engine's own API as a reference, its internals) stays in the per-backend files.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np
import pytest

from ges_core.errors import ArrayError, ConfigError, SimulationError, UnknownNameError
from ges_core.objects.asset import ObjectAsset, PrimitiveShape
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.transforms import euler_xyz_to_quat, quat_to_matrix
from ges_plugins.sims.pybullet.backend import REST_MARGIN as PYBULLET_REST_MARGIN
from ges_plugins.sims.pybullet.backend import PybulletBackend
from ges_plugins.sims.sapien.backend import SapienBackend
from ges_plugins.sims.sapien.loading import REST_MARGIN as SAPIEN_REST_MARGIN

from conftest import benchmark_module
from helpers_sim import ALLEGRO_TIPS, UP, allegro_test_hand, box_asset, loaded_sim, open_q, reordered

pytestmark = pytest.mark.sim


@dataclass(frozen=True)
class Tolerances:
    """How closely one backend meets the contract where its precision shows."""

    rest_margin: float
    """m between the table and an object put down by ``load_object(pose=None)`` (the backend's constant)."""
    joint_target: float
    """rad: a free joint's position against its PD target after 120 steps."""
    reset_q: float
    """rad: joint positions right after reset() against the open pose (SAPIEN stores float32)."""
    reset_object: float
    """m (and unit-quaternion components): the object right after reset() against its load pose."""


TOLERANCES = {
    "sapien": Tolerances(rest_margin=SAPIEN_REST_MARGIN, joint_target=0.02, reset_q=1e-6, reset_object=1e-6),
    "pybullet": Tolerances(rest_margin=PYBULLET_REST_MARGIN, joint_target=5e-3, reset_q=1e-12, reset_object=1e-7),
}
BACKENDS = {"sapien": SapienBackend, "pybullet": PybulletBackend}


def _outside_backends() -> None:
    """Add every registered simulator from an outside package whose backend class declares its tolerances
    (``contract_tolerances``: the :class:`Tolerances` fields, e.g. ``examples/ges-mujoco-sim``) to the same checks.

    One installed but unable to load fails here, loudly; a registered backend without the attribute is left out.
    """
    registry = load_registry()
    for spec in registry.specs("sim"):
        if spec.name in BACKENDS or spec.missing():
            continue
        cls = spec.load()
        declared = getattr(cls, "contract_tolerances", None)
        if declared is not None:
            BACKENDS[spec.name], TOLERANCES[spec.name] = cls, Tolerances(**declared)


_outside_backends()


@pytest.fixture(scope="module")
def hand():
    return allegro_test_hand()


@pytest.fixture(params=sorted(BACKENDS))
def backend(request):
    """(make_sim, rest margin) of one backend: ``make_sim(hand=None, floating=True, **scene)``."""
    return partial(loaded_sim, BACKENDS[request.param]), TOLERANCES[request.param].rest_margin


@pytest.fixture(params=sorted(BACKENDS))
def named(request):
    """(name, make_sim, tolerances) of one backend."""
    name = request.param
    return name, partial(loaded_sim, BACKENDS[name]), TOLERANCES[name]


def test_registry_builds_the_backend(named):
    name, _, _ = named
    registry = load_registry(blocked=tuple({"shadow", "allegro", *BACKENDS} - {name}))
    assert registry.spec("sim", name).requires == (name,)
    with registry.build_sim(name, SceneConfig(num_envs=2)) as sim:
        assert isinstance(sim, BACKENDS[name]) and sim.num_envs == 2 and sim.name == name


@pytest.mark.parametrize("floating", [True, False])
def test_link_poses_match_pytorch_kinematics(backend, hand, floating):
    """Every link at random joints and random base poses, against pytorch-kinematics composed with the base."""
    import pytorch_kinematics as pk
    import torch

    make_sim, _ = backend
    chain = pk.build_chain_from_urdf(hand.urdf_path().read_bytes()).to(dtype=torch.float64)
    links = [n for n in chain.get_frame_names() if n != chain._root.name]
    rng = np.random.default_rng(7)
    lim = hand.description.limits_array
    qs = rng.uniform(lim[:, 0], lim[:, 1], size=(3, len(lim)))
    order = [hand.description.joint_names.index(n) for n in chain.get_joint_parameter_names()]
    fk = chain.forward_kinematics(torch.as_tensor(qs[:, order]))
    sim = make_sim(hand, floating=floating)
    for i, q in enumerate(qs):
        wrist = np.r_[rng.uniform(-0.3, 0.3, 3), euler_xyz_to_quat(rng.uniform(-2.5, 2.5, 3))]
        sim.set_hand_state(q[None], wrist[None])
        got = sim.link_poses(links)[0]
        np.testing.assert_allclose(sim.wrist_pose()[0, :3], wrist[:3], atol=1e-5)
        assert abs(float(np.dot(sim.wrist_pose()[0, 3:], wrist[3:]))) > 1 - 1e-6  # PyBullet's frames are float32
        rot = quat_to_matrix(wrist[3:])
        for j, name in enumerate(links):
            expected = fk[name].get_matrix()[i].numpy()
            np.testing.assert_allclose(got[j, :3], wrist[:3] + rot @ expected[:3, 3], atol=1e-3, err_msg=name)
            np.testing.assert_allclose(quat_to_matrix(got[j, 3:]), rot @ expected[:3, :3], atol=2e-3, err_msg=name)


def test_base_poses_at_gimbal_lock_reach_the_engine_turned_as_asked(backend, hand):
    """The wrist's hinges are rx, ry, rz with R = Rx Ry Rz: at ry = +-pi/2 rx and rz turn about one axis. Base poses
    there (a palm-down start with the fingers along an axis is one), teleported and then driven to, must reach the
    engine turned as asked; before the lock was handled 32 of these 54 came back turned by 1.3-180 degrees."""
    from scipy.spatial.transform import Rotation

    make_sim, _ = backend
    sim = make_sim(hand)
    poses = []
    for turn in np.linspace(-np.pi, np.pi, 9):
        for sign in (1.0, -1.0):
            matrix = Rotation.from_euler("XYZ", [turn, sign * np.pi / 2, 0.0]).as_matrix()
            for rotation in (matrix, np.round(matrix, 12), Rotation.from_matrix(matrix).as_matrix()):
                poses.append(np.r_[0.05, -0.02, 0.4, Rotation.from_matrix(rotation).as_quat()[[3, 0, 1, 2]]])
    for pose in poses:
        sim.set_hand_state(open_q(hand), pose[None])
        got = sim.wrist_pose()[0]
        np.testing.assert_allclose(got[:3], pose[:3], atol=1e-5)
        assert abs(float(np.dot(got[3:], pose[3:]))) > 1 - 1e-6, (pose, got)
    sim.set_hand_state(open_q(hand), UP[None])
    sim.set_wrist_targets(poses[4][None])
    sim.step(240)
    assert abs(float(np.dot(sim.wrist_pose()[0, 3:], poses[4][3:]))) > 0.9999


def test_wrist_targets_turning_through_gimbal_lock_keep_the_hand_on_them(backend, hand):
    """The palm-down start of ``ges sim check`` (at ry = pi/2 for this hand) turned 15 degrees about world x, then
    about world y, over 50 steps each and held 50 (``benchmarks/wrist_lock.py``'s protocol): the hand follows its
    targets within a few degrees at every step. With the principal angles alone (ry within +-pi/2) one of the two
    turns jumped the targets' rx and rz by pi and the drives swung the hand 159-179 degrees off on the way: about x
    while the start read (-pi, pi/2, -pi), about y once it read (0, pi/2, 0)."""
    from scipy.spatial.transform import Rotation

    from ges_core.sim_check import grasp_start_pose
    from ges_core.transforms import quat_to_euler_xyz

    make_sim, _ = backend
    sim = make_sim(hand)
    pose = grasp_start_pose(hand, np.array([0.0, 0.0, 0.3]), 0.7)
    assert abs(quat_to_euler_xyz(pose[None, 3:])[0, 1] - np.pi / 2) < 1e-9  # at the lock
    start = Rotation.from_quat(pose[[4, 5, 6, 3]])
    for axis in "xy":
        worst, last = benchmark_module("wrist_lock").follow_errors(sim, hand, pose, start, axis)
        assert worst < 3.0 and last < 0.1, (axis, worst, last)  # measured 1.2 and 0.003 degrees


def test_wrist_targets_move_the_base(backend, hand):
    make_sim, _ = backend
    sim = make_sim(hand)
    sim.set_hand_state(open_q(hand), UP[None])
    goal = np.r_[0.1, -0.05, 0.4, euler_xyz_to_quat(np.array([0.3, -0.4, 2.9]))]
    sim.set_wrist_targets(goal[None])
    sim.step(240)
    got = sim.wrist_pose()[0]
    np.testing.assert_allclose(got[:3], goal[:3], atol=2e-3)
    assert abs(float(np.dot(got[3:], goal[3:]))) > 0.9999


def test_default_pose_rests_the_object_on_the_table(backend):
    make_sim, margin = backend
    sim = make_sim()
    sim.load_object(box_asset((0.03, 0.03, 0.05)))
    np.testing.assert_allclose(sim.object_pose()[0], [0, 0, 0.05 + margin, 1, 0, 0, 0], atol=1e-6)
    sim.step(60)
    assert abs(sim.object_pose()[0, 2] - 0.05) < 1e-3


def test_dropped_box_rests_at_half_height(backend):
    make_sim, _ = backend
    sim = make_sim()
    sim.load_object(box_asset((0.04, 0.03, 0.02)), pose=np.array([0.1, 0.0, 0.2, 1.0, 0.0, 0.0, 0.0]))
    sim.step(180)
    pose = sim.object_pose()[0]
    assert abs(pose[2] - 0.02) < 2e-3
    np.testing.assert_allclose(pose[:2], [0.1, 0.0], atol=2e-3)
    np.testing.assert_allclose(np.abs(pose[3]), 1.0, atol=1e-4)


def test_a_fixed_object_stays_put_and_still_reports_contacts(backend, hand):
    """load_object(fixed=True): no fall under gravity, no push from a hand driven into it, contacts read as usual;
    the next load_object is free again (the same box dropped from the same pose falls)."""
    make_sim, _ = backend
    sim = make_sim(hand)
    start = np.array([0.0, 0.0, 0.1, 1.0, 0.0, 0.0, 0.0])  # 10 cm above the table
    sim.load_object(box_asset(), pose=start, fixed=True)
    palm_down = np.array([0.0, 0.0, 0.3, 0.0, 1.0, 0.0, 0.0])  # well above, then driven down through the box
    sim.set_hand_state(open_q(hand), palm_down[None])
    pushed = 0.0
    for i in range(90):
        sim.set_wrist_targets((palm_down - [0, 0, 0.25 * min(1.0, (i + 1) / 60), 0, 0, 0, 0])[None])
        sim.step()
        pushed = max(pushed, float(np.abs(sim.contact_forces(["base_link", *hand.description.tip_links])[0]).max()))
    np.testing.assert_allclose(sim.object_pose()[0], start, atol=1e-6)
    assert pushed > 1.0  # the hand did push on it, N
    sim.load_object(box_asset(), pose=start)
    sim.step(60)
    assert sim.object_pose()[0, 2] < 0.05


@pytest.mark.parametrize(
    ("shape", "rest_z"),
    [
        (PrimitiveShape(kind="sphere", size=(0.03,)), 0.03),
        (PrimitiveShape(kind="capsule", size=(0.02, 0.05)), 0.02),  # axis along local x: it lies down
        (PrimitiveShape(kind="cylinder", size=(0.02, 0.05)), 0.02),  # standing on an end would be 0.05
        (PrimitiveShape(kind="box", size=(0.02, 0.02, 0.02), pose=(0, 0, 0.03, 1, 0, 0, 0)), -0.01),
    ],
)
def test_primitives_fall_to_their_physical_rest_height(backend, shape, rest_z):
    make_sim, _ = backend
    sim = make_sim()
    obj = ObjectAsset(object_id="t/p", category="p", mesh_path=box_asset().mesh_path, collision=(shape,))
    sim.load_object(obj, pose=np.array([0.0, 0.0, 0.3, 1.0, 0.0, 0.0, 0.0]))
    sim.step(150)
    assert abs(sim.object_pose()[0, 2] - rest_z) < 2e-3


@pytest.mark.parametrize("floating", [True, False])
def test_joint_targets_reach_each_named_joint(named, hand, floating):
    """A hand declaring its joints in reverse order, a distinct target per joint: each comes back by name."""
    _, make_sim, tol = named
    flipped = reordered(hand, list(range(hand.description.num_joints))[::-1])
    d = flipped.description
    lim = d.limits_array
    target = lim[:, 0] + (np.arange(d.num_joints) + 1) / (d.num_joints + 1) * (lim[:, 1] - lim[:, 0])
    sim = make_sim(flipped, floating=floating, self_collision=False)
    sim.set_hand_state(open_q(flipped), UP[None])
    sim.set_joint_targets(target[None])
    sim.step(120)
    q, qvel = sim.joint_state()
    np.testing.assert_allclose(q[0], target, atol=tol.joint_target)
    assert np.abs(qvel).max() < 0.05
    assert np.array_equal(sim.idx_sim_to_hand[sim.idx_hand_to_sim], np.arange(d.num_joints))


def test_an_object_of_twenty_shapes_stands_on_its_last_one(named):
    """Every collision shape of an object collides, however many: PyBullet keeps only 16 per collision array, so a
    backend that passed them in one array lost the rest (a CoACD mug has 17-45 parts). Here shape 20 is the object's
    only foot; the 19 others are small cubes 5 cm above it. Resting on the foot, the object stays where it was put
    down, touching the table with its whole weight; without the foot it would fall 5 cm."""
    name, make_sim, _ = named
    sim = make_sim()
    cubes = [PrimitiveShape(kind="box", size=(0.005,) * 3, pose=(0.004 * i - 0.036, 0.0, 0.06, 1.0, 0.0, 0.0, 0.0))
             for i in range(19)]  # fmt: skip
    foot = PrimitiveShape(kind="box", size=(0.04, 0.04, 0.005), pose=(0.0, 0.0, 0.005, 1.0, 0.0, 0.0, 0.0))
    base = box_asset((0.04, 0.04, 0.005), object_id="t/twenty_shapes")
    obj = ObjectAsset(object_id=base.object_id, category="t", mesh_path=base.mesh_path, collision=(*cubes, foot),
                      density=500.0)  # fmt: skip
    sim.load_object(obj)
    start = sim.object_pose()[0].copy()
    sim.step(120)
    end = sim.object_pose()[0]
    assert np.linalg.norm(end[:3] - start[:3]) < 2e-3, (name, start, end)
    weight = 500.0 * (0.08 * 0.08 * 0.01 + 19 * 0.01**3) * 9.81
    touching = [c for c in sim.contact_pairs(0) if {c.body_a, c.body_b} == {"object", "table"}]
    assert len(touching) == 1 and touching[0].force == pytest.approx(weight, rel=0.05), touching


def test_object_replacement_and_env_ids(named):
    """load_object(env_ids=[1]) replaces env 1's object only; each env holds one object, the one last loaded."""
    name, make_sim, _ = named
    sim = make_sim(num_envs=2)
    sim.load_object(box_asset(object_id="t/small"))
    sim.load_object(box_asset((0.05, 0.05, 0.05), object_id="t/big"), env_ids=[1])
    sim.step(60)
    np.testing.assert_allclose(sim.object_pose()[:, 2], [0.03, 0.05], atol=1e-3)
    for env, size in enumerate((0.03, 0.05)):
        (pair,) = sim.contact_pairs(env)  # the object on the table: one pair, one object
        assert {pair.body_a, pair.body_b} == {"object", "table"}
        assert pair.force == pytest.approx(500.0 * (2 * size) ** 3 * 9.81, rel=0.02)  # its weight
    with pytest.raises(ConfigError, match=rf"{name}.load_object: env ids \[2\] out of range for num_envs=2 \(valid"):
        sim.load_object(box_asset(), env_ids=[2])
    with pytest.raises(ConfigError, match=rf"{name}.contact_pairs: env ids \[5\] out of range for num_envs=2"):
        sim.contact_pairs(5)


@pytest.mark.parametrize("floating", [True, False])
def test_reset_opens_the_hand_at_the_last_base_pose(named, hand, floating):
    """reset(): open hand at the base pose last given to set_hand_state, targets there, object at its load pose."""
    _, make_sim, tol = named
    sim = make_sim(hand, floating=floating, num_envs=2)
    start = np.array([0.3, 0.0, 0.2, 1.0, 0.0, 0.0, 0.0])
    sim.load_object(box_asset(), pose=start)
    bases = np.stack([UP, [0.1, -0.2, 0.4, *euler_xyz_to_quat(np.array([0.4, -0.3, 1.2]))]])
    sim.set_hand_state(open_q(hand, 2) + 0.1, bases)
    sim.set_hand_state(open_q(hand, 2) + 0.2)  # no base pose: the last one given still counts
    sim.set_joint_targets(np.tile(hand.description.closed_pose(0.5), (2, 1)))
    if floating:
        sim.set_wrist_targets(bases + [0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    sim.step(30)
    sim.reset()
    np.testing.assert_allclose(sim.object_pose(), np.tile(start, (2, 1)), atol=tol.reset_object)
    np.testing.assert_allclose(sim.wrist_pose(), bases, atol=1e-6)
    q, qvel = sim.joint_state()
    np.testing.assert_allclose(q, open_q(hand, 2), atol=tol.reset_q)
    np.testing.assert_array_equal(qvel, 0.0)
    sim.step(30)  # joint and wrist targets were reset too: nothing moves
    np.testing.assert_allclose(sim.joint_state()[0], open_q(hand, 2), atol=1e-4)
    np.testing.assert_allclose(sim.wrist_pose(), bases, atol=1e-5)


def _scripted_run(make_sim, hand) -> tuple[np.ndarray, ...]:
    """A hand closing on a box for 40 steps: the state and contact forces at the end."""
    sim = make_sim(hand)
    sim.load_object(box_asset((0.015, 0.04, 0.03)))
    base = np.array([-0.01, -0.02, 0.115, np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0])  # palm down over the box
    sim.set_hand_state(open_q(hand), base[None])
    sim.set_wrist_targets(base[None])
    sim.set_joint_targets(hand.description.closed_pose(0.55)[None])
    sim.step(40)
    return (*sim.joint_state(), sim.wrist_pose(), sim.object_pose(), sim.contact_forces(ALLEGRO_TIPS, "any"))


def test_identical_runs_give_identical_states(named, hand):
    _, make_sim, _ = named
    first, second = _scripted_run(make_sim, hand), _scripted_run(make_sim, hand)
    assert np.abs(first[-1]).max() > 0.01  # the fingers touch something: contacts are part of the run
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a, b)


def test_unknown_link_names_suggest_a_close_one(named, hand):
    _, make_sim, _ = named
    sim = make_sim(hand)
    with pytest.raises(UnknownNameError, match="unknown hand link 'link_3.0_tp'. Did you mean 'link_3.0_tip'"):
        sim.link_poses(["link_3.0_tp"])
    with pytest.raises(UnknownNameError, match="unknown hand link 'thumb'"):
        sim.contact_forces(["thumb"])


def test_bad_arguments_raise_one_error_type_each(named, hand):
    """Shapes, NaN and zero quaternions: ArrayError; env_ids, partner, step count: ConfigError; both name the call."""
    name, make_sim, _ = named
    sim = make_sim(hand, num_envs=2)
    k = hand.description.num_joints
    cases = [
        (ArrayError, lambda: sim.set_joint_targets(np.zeros(k)), rf"{name}.set_joint_targets: q has shape \({k},\), "
         rf"expected \(2, {k}\) \(one row per env, hand joint_names order, rad\)"),
        (ArrayError, lambda: sim.set_hand_state(np.full((2, k), np.nan)), rf"{name}.set_hand_state: q holds NaN"),
        (ArrayError, lambda: sim.set_hand_state(open_q(hand, 2), np.zeros((2, 7))),
         rf"{name}.set_hand_state: wrist_pose has a zero quaternion \(row \[0, 1\]\)"),
        (ArrayError, lambda: sim.set_wrist_targets(UP[None]), rf"{name}.set_wrist_targets: pose has shape \(1, 7\)"),
        (ArrayError, lambda: sim.set_hand_state(open_q(hand, 2), UP), r"wrist_pose has shape \(7,\), expected \(2, 7"),
        (ArrayError, lambda: sim.load_object(box_asset(), pose=np.zeros(6)), rf"{name}.load_object: pose has shape"),
        (ArrayError, lambda: sim.set_hand_state(open_q(hand, 2), env_ids=[1]),
         rf"{name}.set_hand_state: q has 2 rows but env_ids names 1 env\(s\) \[1\]"),
        (ConfigError, lambda: sim.reset(env_ids=[0, 0]), rf"{name}.reset: env_ids \[0, 0\] repeat \[0\]"),
        (ConfigError, lambda: sim.contact_forces(ALLEGRO_TIPS, "hand"),
         rf"{name}.contact_forces: partner 'hand' is not one of object, table, any"),
        (ConfigError, lambda: sim.step(-1), rf"{name}.step: n=-1; give a whole number of steps >= 0"),
        (ConfigError, lambda: sim.step(1.5), rf"{name}.step: n=1.5"),
    ]  # fmt: skip
    for error, call, message in cases:
        with pytest.raises(error, match=message):
            call()
    sim.load_object(box_asset())
    with pytest.raises(ArrayError, match=rf"{name}.set_object_pose: pose has shape \(2, 6\)"):
        sim.set_object_pose(np.zeros((2, 6)))


def test_calls_the_state_does_not_allow_are_simulation_errors(named, hand):
    name, make_sim, _ = named
    sim = make_sim()
    no_hand = rf"{name}.joint_state: no hand loaded; call load_hand\(hand\) first"
    with pytest.raises(SimulationError, match=no_hand) as caught:
        sim.joint_state()
    assert caught.value.env_ids == ()
    with pytest.raises(SimulationError, match=rf"{name}.object_pose: no object in env\(s\) \[0\]; call load_object"):
        sim.object_pose()
    sim.load_hand(hand, floating=False)
    with pytest.raises(SimulationError, match=rf"{name}: hand 'allegro_test' is already loaded; build a new backend"):
        sim.load_hand(hand)
    with pytest.raises(SimulationError, match=rf"{name}.set_wrist_targets: the hand was loaded with floating=False"):
        sim.set_wrist_targets(UP[None])
    sim.close()
    sim.close()  # twice is harmless
    with pytest.raises(SimulationError, match=rf"{name}: this backend is closed; build a new one with registry"):
        sim.step()


def test_reset_without_a_base_pose_returns_to_the_origin(backend, hand):
    make_sim, _ = backend
    sim = make_sim(hand)
    sim.set_wrist_targets(UP[None])
    sim.set_joint_targets(open_q(hand) + 0.2)
    sim.step(30)
    assert sim.wrist_pose()[0, 2] > 0.1
    sim.reset()
    np.testing.assert_allclose(sim.wrist_pose()[0], [0, 0, 0, 1, 0, 0, 0], atol=1e-6)
    np.testing.assert_allclose(sim.joint_state()[0], open_q(hand), atol=1e-6)


def _tip_lever(sim, hand, joint: str, tip: str) -> tuple[np.ndarray, np.ndarray, float]:
    """(tip position (3,), unit direction the tip moves when ``joint`` flexes (3,), lever arm m) at the open
    pose, measured by a 1 mrad teleport of that joint (hand already placed at UP)."""
    q0, j = open_q(hand), hand.description.joint_names.index(joint)
    sim.set_hand_state(q0, UP[None])
    p0 = sim.link_poses([tip])[0, 0, :3]
    bent = q0.copy()
    bent[0, j] += 1e-3
    sim.set_hand_state(bent, UP[None])
    step = sim.link_poses([tip])[0, 0, :3] - p0
    sim.set_hand_state(q0, UP[None])
    return p0, step / np.linalg.norm(step), float(np.linalg.norm(step) / 1e-3)


def test_drive_limits_cap_what_a_blocked_finger_pushes(named, hand):
    """The index finger's MCP flexion (joint_1.0) driven 1.5 rad into a fixed box just ahead of its tip: with every
    hand joint capped at L, the tip pushes the box with about L / lever (the cap, not the 400 N·m/rad spring, sets
    the force); the lever is measured, the contact sits within the 12 mm tip radius of it."""
    _, make_sim, _ = named
    d = hand.description
    sim = make_sim(hand, floating=False)
    tip, u, lever = _tip_lever(sim, hand, "joint_1.0", "link_3.0_tip")
    half = 0.01
    box_pose = np.r_[tip + u * (0.012 + half + 0.002), 1.0, 0.0, 0.0, 0.0]  # 2 mm ahead of the tip's surface
    sim.load_object(box_asset((half, half, half)), pose=box_pose, fixed=True)
    target = open_q(hand)
    target[0, d.joint_names.index("joint_1.0")] = 1.5  # Kp = 400: a spring torque of 600 N·m uncapped
    pushes, bent = {}, {}
    j = d.joint_names.index("joint_1.0")
    for limit in (0.05, 0.2):
        sim.set_hand_state(open_q(hand), UP[None])
        sim.set_drive_limits(np.full(d.num_joints, limit))
        sim.set_joint_targets(target)
        sim.step(60)
        pushed = [-sim.contact_forces(["link_3.0_tip", "link_3.0", "link_2.0"])[0].sum(axis=0) @ u]
        for _ in range(30):
            sim.step()
            pushed.append(-sim.contact_forces(["link_3.0_tip", "link_3.0", "link_2.0"])[0].sum(axis=0) @ u)
        pushes[limit], bent[limit] = float(np.mean(pushed)), float(sim.joint_state()[0][0, j])
        assert max(pushed) <= 1.1 * limit / (lever - 0.012), (limit, lever, pushed)
        assert min(pushed) >= 0.7 * limit / (lever + 0.012), (limit, lever, pushed)
    assert 3.2 < pushes[0.2] / pushes[0.05] < 4.8  # the force follows the cap (x4)
    sim.set_drive_limits(None)  # caps lifted: the 600 N·m drive bends the finger into (or through) the box
    sim.set_hand_state(open_q(hand), UP[None])
    sim.set_joint_targets(target)
    sim.step(60)
    assert sim.joint_state()[0][0, j] > bent[0.2] + 0.05, (bent, sim.joint_state()[0][0, j])


def test_drive_limits_are_checked(named, hand):
    name, make_sim, _ = named
    sim = make_sim()
    with pytest.raises(SimulationError, match=rf"{name}.set_drive_limits: no hand loaded"):
        sim.set_drive_limits(None)
    sim.load_hand(hand)
    k = hand.description.num_joints
    with pytest.raises(ArrayError, match=rf"{name}.set_drive_limits: limits has shape \(3,\), expected \({k},\)"):
        sim.set_drive_limits([1.0, 2.0, 3.0])
    bad = np.full(k, 0.5)
    bad[2] = 0.0
    third = hand.description.joint_names[2]
    with pytest.raises(ArrayError, match=rf"limits must be > 0 N·m \(inf: no cap\), not for \['{third}'\]"):
        sim.set_drive_limits(bad)
    bad[2] = np.nan
    with pytest.raises(ArrayError, match="limits must be > 0"):
        sim.set_drive_limits(bad)
    sim.set_drive_limits(np.full(k, np.inf))  # inf: no cap on that joint
    sim.set_drive_limits(None)
