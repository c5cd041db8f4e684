"""The environment's numpy per-step path against the plain torch formulas it replaced.

GraspEnv computes targets, observations, rewards and end reasons in numpy float64 (one conversion to torch
per result). Here a test double backend serves random states (random wrist and fingertip orientations,
w < 0 included, contact forces around the threshold, object heights across every end reason, one env
reading NaN) and every result is compared with a reference written with the torch rotation helpers, the
torch ``compute_reward`` and the success tracker's former where-chain.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers_env import grasp_targets

from ges_core.env.grasp_env import EnvConfig, GraspEnv
from ges_core.env.layout import ObservationLayout
from ges_core.env.reward import (
    TERMS,
    RewardConfig,
    RewardFunction,
    compute_reward,
    direction_variance,
    direction_variance_np,
)
from ges_core.env.success import EndReason, SuccessConfig, SuccessTracker
from ges_core.env.vec_env import GraspVecEnv
from ges_core.errors import SimulationError
from ges_core.objects.simple import box_asset
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig, SimBackend
from ges_core.transforms import euler_xyz_to_quat
from ges_core.transforms_torch import quat_conj, quat_mul, quat_rotate, quat_to_rotvec, rotvec_to_quat

N = 5
LIFT = 0.2


def _unit_quats(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    q = rng.normal(size=(*shape, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


class _RandomBackend(SimBackend):
    """Test double of a SimBackend: a fresh random state after every ``step``; reads return copies of it.

    Env 0 holds the same wrist orientation for two states in a row (a zero turn: the small-angle branch);
    ``nan_env`` reads NaN everywhere after the step it is set for. Commands go through the core's checks
    (a real SimBackend subclass, so ``tests/test_sim_conformance.py`` holds it to the interface too); the
    hooks record the targets: ``targets["q"]`` (n, K), ``targets["wrist"]`` (n, 6) wrist joint values.
    """

    name = "random"

    def __init__(self, hand, n: int, seed: int) -> None:
        super().__init__(SceneConfig(num_envs=n))
        d = hand.description
        self.k, self.tips = d.num_joints, list(d.tip_links)
        self.rng = np.random.default_rng(seed)
        self.nan_env: int | None = None
        self.targets: dict[str, np.ndarray] = {"wrist": np.zeros((n, 6))}
        self.state: dict[str, np.ndarray] = {}
        self._draw()

    def _draw(self) -> None:
        rng, n, k, f = self.rng, self.num_envs, self.k, len(self.tips)
        wrist = np.concatenate([rng.normal(0.0, 0.1, (n, 3)), _unit_quats(rng, (n,))], axis=1)
        if "wrist" in self.state:
            wrist[0, 3:] = self.state["wrist"][0, 3:]
        forces = rng.normal(0.0, 0.05, (n, f + 1, 3)) * rng.integers(0, 2, (n, f + 1, 1))  # some links free
        rise = rng.choice([0.0, 0.01, 0.05, 0.19, 0.2, 0.21, 0.3], size=n)
        obj = np.concatenate([rng.normal(0.0, 0.02, (n, 2)), 0.05 + rise[:, None], _unit_quats(rng, (n,))], axis=1)
        tips = np.concatenate([rng.normal(0.0, 0.1, (n, f, 3)), _unit_quats(rng, (n, f))], axis=2)
        self.state = {
            "q": rng.normal(0.0, 0.5, (n, k)),
            "dq": rng.normal(0.0, 2.0, (n, k)) * rng.integers(0, 2, (n, k)),  # zeros: sign 0
            "wrist": wrist,
            "forces": forces,
            "tips": tips,
            "obj": obj,
        }
        if self.nan_env is not None:
            for value in self.state.values():
                value[self.nan_env] = np.nan

    # the engine hooks (building and teleports do nothing: every read is the drawn state)
    def _load_hand(self, hand, floating):
        pass

    def _load_object(self, obj, ids, fixed):
        pass

    def _rest_height(self, obj, env_id):
        return 0.0

    def _set_hand_state(self, q, base, ids):
        pass

    def _set_object_pose(self, pose, ids):
        pass

    def _set_joint_targets(self, q):
        self.targets["q"] = np.array(q)

    def _set_drive_limits(self, limits):
        self.targets["limits"] = None if limits is None else np.array(limits)

    def _set_wrist_targets(self, coords):
        self.targets["wrist"] = np.array(coords)

    def _wrist_rotation_targets(self):
        return self.targets["wrist"][:, 3:]

    def _step(self, n):
        self._draw()
        return {}

    def _joint_state(self):
        return self.state["q"].copy(), self.state["dq"].copy()

    def _wrist_pose(self):
        return self.state["wrist"].copy()

    def _contact_forces(self, links, partner):
        return self.state["forces"].copy()

    def _link_poses(self, links):
        assert list(links) == self.tips
        return self.state["tips"].copy()

    def _object_pose(self):
        return self.state["obj"].copy()

    def _contact_pairs(self, env_id):
        return []

    def _close(self):
        pass


def _wrist_target_pose(coords: np.ndarray) -> torch.Tensor:
    """(n, 7) base poses of (n, 6) wrist joint values (x, y, z, rx, ry, rz with R = Rx Ry Rz), w >= 0."""
    quat = euler_xyz_to_quat(coords[:, 3:])
    return torch.as_tensor(np.concatenate([coords[:, :3], quat * np.sign(quat[:, :1])], axis=1))


# -- references: the torch code the numpy path replaced -------------------------------------------
def _ref_wrist_target(target: torch.Tensor, action: torch.Tensor, env: GraspEnv) -> torch.Tensor:
    dp, dr = env.act_layout.wrist_deltas(action)
    return torch.cat([target[:, :3] + dp, quat_mul(rotvec_to_quat(dr), target[:, 3:])], dim=1)


def _ref_observe(s: dict, prev: torch.Tensor, prev_action: torch.Tensor, env: GraspEnv):
    """Observation and state as GraspEnv.observe computed them in torch; s: the backend's state."""
    t = {k: torch.as_tensor(v) for k, v in s.items()}
    wrist, tips, forces, f = t["wrist"], t["tips"], t["forces"], len(env.tip_links)
    tip_world = tips[..., :3] + quat_rotate(tips[..., 3:], env.tip_offsets.expand_as(tips[..., :3]))
    inv = quat_conj(wrist[:, 3:])[:, None]
    lin = (wrist[:, :3] - prev[:, :3]) / env.control_dt
    ang = quat_to_rotvec(quat_mul(wrist[:, 3:], quat_conj(prev[:, 3:]))) / env.control_dt
    vel = torch.cat([lin, ang], dim=1)
    goal = env.grasps["wrist_pose"]
    blocks = {
        "q": t["q"],
        "dq": t["dq"],
        "contact": (forces.norm(dim=-1) > env.cfg.contact_threshold).to(torch.float64),
        "tip_force": quat_rotate(inv, forces[:, :f]),
        "tip_pos": quat_rotate(inv, tip_world - wrist[:, None, :3]),
        "wrist_pose": torch.cat([wrist[:, :3], _ref_wrist_rotation(wrist[:, 3:], env.cfg.wrist_rotation)], dim=1),
        "wrist_vel": vel,
        "prev_action": prev_action,
        "obj_pos": t["obj"][:, :3],
        "goal_pos": goal[:, :3] - wrist[:, :3],
        "goal_rot": quat_to_rotvec(quat_mul(goal[:, 3:], quat_conj(wrist[:, 3:]))),
        "goal_q": env.grasps["q"] - t["q"],
    }
    blocks = {name: blocks[name] for name in env.obs_layout.slices}
    state = {"q": t["q"], "dq": t["dq"], "tip_world": tip_world, "obj": t["obj"][:, :3], "wrist_vel": vel}
    return env.obs_layout.pack(blocks), state


def _ref_wrist_rotation(quat: torch.Tensor, form: str) -> torch.Tensor:
    """The wrist's rotation as the observation holds it: a rotation vector, or the world x and y axes of the base
    link (the rotation matrix's first two columns) turned by its quaternion."""
    if form == "rotvec":
        return quat_to_rotvec(quat)
    axes = torch.eye(3, dtype=quat.dtype)[:2]  # (2, 3): x, y
    return quat_rotate(quat[:, None], axes.expand(len(quat), 2, 3)).reshape(len(quat), 6)


def _ref_reasons(cfg: SuccessConfig, held, max_rise, rise, timeout) -> torch.Tensor:
    """The tracker's former where-chain."""
    was_lifted = max_rise >= cfg.lifted_rise
    reason = torch.full_like(held, EndReason.RUNNING)
    reason = torch.where(timeout & ~was_lifted, EndReason.NOT_LIFTED, reason)
    reason = torch.where(timeout & was_lifted, EndReason.TIMEOUT, reason)
    reason = torch.where(was_lifted & (rise < cfg.dropped_rise), EndReason.DROPPED, reason)
    return torch.where(held >= cfg.hold_steps, EndReason.SUCCESS, reason)


def _close(a: torch.Tensor, b: torch.Tensor, what: str) -> None:
    torch.testing.assert_close(a, b.to(a.dtype), rtol=1e-6, atol=1e-6, equal_nan=True, msg=what)


# -- tests ----------------------------------------------------------------------------------------
def test_reward_function_matches_compute_reward() -> None:
    rng = np.random.default_rng(1)
    n, k = 6, 16
    fingers = [torch.tensor([0, 1, 2, 3]), torch.tensor([4, 5, 6, 7]), torch.tensor([8, 9, 10]), torch.tensor([15])]
    groups = torch.tensor([[0, 4, 8], [1, 5, 9], [2, 6, 10]])
    cfg = RewardConfig(w_smooth=0.01, w_consistency=0.1)
    args = {
        "q_error": rng.normal(size=(n, k)),
        "tip_pos": rng.normal(size=(n, 4, 3)) * 0.1,
        "obj_pos": rng.normal(size=(n, 3)) * 0.1,
        "obj_start": rng.normal(size=(n, 3)) * 0.1,
        "joint_vel": rng.normal(size=(n, k)) * rng.integers(0, 2, (n, k)),
        "wrist_vel": rng.normal(size=(n, 6)),
    }
    args["joint_vel"][0, 1] = np.nan  # sign(NaN) = 0 in both
    total, terms = RewardFunction(cfg, fingers, groups, k)(**args)
    want_total, want = compute_reward(
        cfg, finger_joints=fingers, groups=groups, **{name: torch.as_tensor(v) for name, v in args.items()}
    )
    for i, name in enumerate(TERMS):
        _close(torch.from_numpy(terms[i]), want[name], name)
    _close(torch.from_numpy(total), want_total, "total")
    v = torch.as_tensor(args["joint_vel"])
    _close(torch.from_numpy(direction_variance_np(v.numpy(), groups.numpy())), direction_variance(v, groups), "var")


def test_folded_end_reasons_match_the_where_chain() -> None:
    cfg = SuccessConfig(hold_steps=4)
    tr = SuccessTracker(cfg, 64, sim_steps=2)
    rng = np.random.default_rng(2)
    tr.reset(torch.arange(64), torch.zeros(64, 3))
    for _ in range(12):
        pos = torch.zeros(64, 3, dtype=torch.float64)
        pos[:, 2] = torch.as_tensor(rng.choice([0.0, 0.02, 0.05, 0.2, 0.25, np.nan], size=64))
        timeout = torch.as_tensor(rng.random(64) < 0.3)
        got = tr.update(pos, timeout)
        want = _ref_reasons(cfg, tr.held, tr.max_rise, pos[:, 2] - tr.start[:, 2], timeout)
        assert torch.equal(got, want)
    assert set(got.tolist()) == {0, 1, 2, 3, 4}  # the draws reach every reason but unstable


@pytest.mark.parametrize(("goal_prior", "wrist_rotation"), [(True, "matrix"), (False, "matrix"), (True, "rotvec")])
def test_grasp_env_steps_match_the_torch_reference(goal_prior: bool, wrist_rotation: str) -> None:
    hand = load_registry().build_hand("allegro")
    sim = _RandomBackend(hand, N, seed=3)
    cfg = EnvConfig(goal_prior=goal_prior, wrist_rotation=wrist_rotation, reach_steps=0, settle_steps=0)
    env = GraspEnv(sim, hand, box_asset((0.02, 0.02, 0.02), object_id="t/box"), grasp_targets(hand, N), cfg)
    env.reset_all()
    assert isinstance(env.obs_layout, ObservationLayout) and env.obs_layout.goal is goal_prior
    gen = torch.Generator().manual_seed(4)
    target = torch.as_tensor(sim.wrist_pose())
    prev = target.clone()
    seen = set()
    for t in range(8):
        sim.nan_env = 2 if t == 6 else None
        action = torch.rand(N, env.act_layout.size, generator=gen) * 2.4 - 1.2  # some beyond [-1, 1]
        before = sim.state
        unstable = env.apply_action(action)
        target = _ref_wrist_target(target, action.double(), env)
        canonical = torch.cat([target[:, :3], target[:, 3:] * torch.sign(target[:, 3:4])], dim=1)
        _close(_wrist_target_pose(sim.targets["wrist"]), canonical, "wrist targets")
        _close(torch.as_tensor(sim.targets["q"]), env.act_layout.joint_targets(action.double()), "joint targets")
        obs, state = env.observe()
        want_obs, want_state = _ref_observe(sim.state, prev, action.double().clamp(-1, 1), env)
        prev = torch.as_tensor(sim.state["wrist"])
        assert sim.state is not before and obs.dtype == torch.float32
        _close(obs, want_obs, "observation")
        for name, value in want_state.items():
            _close(state[name], value, name)
        reward, terms = env.reward(state)
        want_reward, want_terms = compute_reward(
            cfg.reward,
            q_error=env.grasps["q"] - want_state["q"],
            finger_joints=env.finger_joints,
            tip_pos=want_state["tip_world"],
            obj_pos=want_state["obj"],
            obj_start=env.tracker.start,
            joint_vel=want_state["dq"],
            wrist_vel=want_state["wrist_vel"],
            groups=env.groups,
        )
        _close(reward, want_reward, "reward")
        for name in TERMS:
            _close(terms[name], want_terms[name], name)
        held, max_rise = env.tracker.held.clone(), env.tracker.max_rise.clone()
        timeout = torch.tensor([t % 3 == 2] * N)
        reason = env.end_reasons(state, timeout, unstable | (torch.arange(N) == 4))
        rise = want_state["obj"][:, 2] - env.tracker.start[:, 2]
        want_held = torch.where(rise >= LIFT, held + cfg.sim_steps, 0)
        assert torch.equal(env.tracker.held, want_held)
        _close(env.tracker.max_rise, torch.maximum(max_rise, rise), "max_rise")
        want_reason = _ref_reasons(cfg.success, want_held, env.tracker.max_rise, rise, timeout)
        assert reason.tolist() == [*want_reason.tolist()[:4], EndReason.UNSTABLE]
        seen |= set(reason.tolist())
    assert {EndReason.DROPPED, EndReason.TIMEOUT, EndReason.UNSTABLE} <= seen


def test_vec_env_log_means_skip_unstable_envs() -> None:
    hand = load_registry().build_hand("allegro")

    class _BlowsUp(_RandomBackend):
        armed = False

        def step(self, n: int = 1) -> None:
            super().step(n)
            if self.armed:
                raise SimulationError("test: env 1 blew up", env_ids=(1,))

    sim = _BlowsUp(hand, 3, seed=5)
    env = GraspEnv(sim, hand, box_asset((0.02, 0.02, 0.02), object_id="t/box"), grasp_targets(hand, 3), EnvConfig())
    venv = GraspVecEnv(env)
    sim.armed = True
    states = []
    observe = env.observe

    def recording_observe(**kw):  # noise_rows: GraspVecEnv passes it through
        states.append(observe(**kw))
        return states[-1]

    env.observe = recording_observe
    _, reward, done, extras = venv.step(torch.zeros(3, venv.num_actions))
    assert done.tolist() == [0, 1, 0] and reward[1].item() == 0.0
    _, terms = env.reward(states[0][1])
    for name in TERMS:
        want = torch.nan_to_num(terms[name][[0, 2]]).mean()
        assert extras["log"][f"/reward/{name}"].item() == pytest.approx(want.item()), name
    assert extras["log"]["/end/unstable"].item() == 1.0
