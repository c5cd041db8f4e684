"""MuJoCo behind :class:`ges_core.sim.SimBackend`: ``num_envs`` ``MjData``, stepped one after another.

Every env holds its own ``MjData``; envs holding the same object share one compiled ``MjModel``
(:mod:`.model`: the physics choices). Loading an object into some envs compiles (or reuses) the model with that
object and moves those envs onto it, hand state and targets kept. Poses are wxyz as in MuJoCo, joint vectors
in the hand's ``joint_names`` order (MuJoCo's depth-first order is mapped once, ``idx_sim_to_hand``).

A scene step (``config.timestep``) is ``substeps`` MuJoCo steps (:data:`DEFAULT_SUBSTEPS`). Reads: link poses
come from ``mj_kinematics`` run lazily on the present state (``mj_step`` leaves the frames of the state before
its integration); contact forces are the mean over the last scene step's substeps (:mod:`.contacts`). A teleport
clears that env's solver warm start, so what happens next depends on the commands only, not on what came
before (an env restored after a blow-up evolves like one that never blew up). A blown env is rebuilt by
``mj_resetData`` before the core resets it.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import mujoco
import numpy as np

from ges_core.errors import ConfigError, UnknownNameError
from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset
from ges_core.sim import ContactPair, SceneConfig, SimBackend
from ges_core.urdf import absolutize_mesh_paths, add_floating_base, root_link, strip_render_data

from .contacts import add_substep_forces, contact_pairs, link_forces
from .model import HandSetup, SceneModel, build_scene
from .shapes import lowest_point

__all__ = ["MAX_JOINT_SPEED", "MAX_OBJECT_SPEED", "REST_MARGIN", "MujocoBackend"]

REST_MARGIN = 2e-4
"""m left between the table and an object put down by ``load_object(pose=None)`` (the other backends' value)."""
MAX_JOINT_SPEED = 1e3
"""rad/s (m/s for the wrist's slides): faster is a blow-up (the other backends' value)."""
MAX_OBJECT_SPEED = 1e2
"""m/s: a box flung by a bad grasp leaves at a few m/s, a blown-up solver at thousands (the other backends' value)."""
BLOWUP_HINT = (
    "likely causes: a start pose deep inside the object or table, gains too stiff for the timestep, or a "
    "target far outside the joint limits; reset() the env, lower the gains or the timestep"
)
DEFAULT_SUBSTEPS = 8
"""MuJoCo steps per scene step (1/120 s: 1.04 ms each). Measured on the contract's scripted grasp (Allegro
closing on a 3 x 8 x 6 cm box for 40 steps): at 1, 2 and 4 the fingertips tunnel into the box and throw it
0.1-6 m away, at 6 and 8 the hand keeps touching it (contacts at the end); 8 leaves a margin. Cost: about
8x a single step (docs/simulators.md)."""
_BAD = (mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADQVEL, mujoco.mjtWarning.mjWARN_BADQPOS)
_Key = tuple[ObjectAsset, bool] | None


class MujocoBackend(SimBackend):
    """MuJoCo (``mujoco`` from PyPI) on the CPU, one ``MjData`` per env (module docs)."""

    name = "mujoco"
    normalise_quaternions = True
    blowup_hint = BLOWUP_HINT
    contract_tolerances = {"rest_margin": REST_MARGIN, "joint_target": 5e-3, "reset_q": 1e-12, "reset_object": 1e-12}
    """How closely this backend meets ``tests/test_sim_contract.py`` where precision shows (its ``Tolerances``):
    float64 state, exact teleports; free joints reach their targets within 1e-3 rad in 120 steps."""

    def __init__(self, config: SceneConfig, *, substeps: int = DEFAULT_SUBSTEPS) -> None:
        """substeps: MuJoCo steps per ``config.timestep`` (registry setting; the spec's tuned value is in
        ``ges_mujoco_sim/__init__.py``). MuJoCo finds a contact only once the shapes overlap: at 1/120 s a
        fingertip closing at 1-5 m/s travels 1-4 cm per step and lands deep inside the object, whose
        penetration is then resolved with a kick that throws it (PhysX's speculative contacts stop it at the
        surface)."""
        super().__init__(config)
        if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
            raise ConfigError(f"mujoco: substeps={substeps!r}; give a whole number >= 1 or leave it unset")
        self.substeps = substeps
        """MuJoCo steps per physics step of the scene (``config.timestep``)."""
        n = config.num_envs
        self._setup: HandSetup | None = None
        self._models: dict[_Key, SceneModel] = {}
        self._keys: list[_Key] = [None] * n
        self._scenes: list[SceneModel] = [self._model(None)] * n
        self._data = [mujoco.MjData(self._scenes[0].model) for _ in range(n)]
        self._forces = [_force_table(self._scenes[0].model) for _ in range(n)]
        """Per env, (nbody, nbody, 3) contact forces summed over the last scene step's substeps (:mod:`.contacts`)."""
        self._posed = [False] * n
        """Whether each env's frames (xpos, xquat) match its present qpos."""
        self._targets = np.zeros((n, 0))
        """(E, D) drive targets: wrist (floating), then hand joint order (= actuator order)."""
        self._caps: np.ndarray | None = None
        self._link_cache: dict[tuple[str, ...], list[int]] = {}

    # -- index maps ----------------------------------------------------------------------------
    @property
    def idx_sim_to_hand(self) -> np.ndarray:
        """(K,) ``q_hand = q_sim[idx_sim_to_hand]``; ``q_sim``: the hand's joints in MuJoCo's (depth-first) order."""
        self._need_hand("idx_sim_to_hand")
        order = self._scenes[0].sim_order
        return np.array([order.index(n) for n in self._setup.joint_names], dtype=np.int64)

    @property
    def idx_hand_to_sim(self) -> np.ndarray:
        """(K,) ``q_sim = q_hand[idx_hand_to_sim]``."""
        return np.argsort(self.idx_sim_to_hand)

    def engine_step(self) -> None:
        """One physics step (``substeps`` bare ``mj_step``) per env: no checks, no bookkeeping (benchmarks)."""
        self._check_open()
        with _quiet():
            for e, (scene, data) in enumerate(zip(self._scenes, self._data, strict=True)):
                mujoco.mj_step(scene.model, data, self.substeps)
                self._forces[e].fill(0.0)  # a raw step keeps no contact forces
                self._posed[e] = False

    # -- building ------------------------------------------------------------------------------
    def _load_hand(self, hand: HandModel, floating: bool) -> None:
        from ges_core.hand_prep.engine_urdf import engine_urdf

        d = hand.description
        source = hand.urdf_path()
        text = absolutize_mesh_paths(engine_urdf(strip_render_data(source.read_text()), source.parent), source.parent)
        pairs = sorted(tuple(sorted(p)) for p in hand.excluded_link_pairs())
        self._setup = HandSetup(
            name=hand.name,
            urdf_text=add_floating_base(text) if floating else text,
            floating=floating,
            joint_names=tuple(d.joint_names),
            stiffness=tuple(float(v) for v in d.pd_stiffness),
            damping=tuple(float(v) for v in d.pd_damping),
            armature=tuple(float(v) for v in d.armature_array),
            base_link=d.base_link or root_link(text),
            excluded=tuple(pairs),
        )
        self._models.clear()
        self._targets = np.zeros((self.num_envs, (6 if floating else 0) + d.num_joints))
        for e in range(self.num_envs):
            self._move(e, self._keys[e])

    def _load_object(self, obj: ObjectAsset, ids: list[int], fixed: bool) -> None:
        for e in ids:
            self._move(e, (obj, fixed))

    def _rest_height(self, obj: ObjectAsset, env_id: int) -> float:
        scene = self._scenes[env_id]
        return REST_MARGIN - lowest_point(scene.model, scene.object_body)

    # -- commands ------------------------------------------------------------------------------
    def _set_joint_targets(self, q: np.ndarray) -> None:
        self._targets[:, self._nw :] = q
        self._send_targets(range(self.num_envs))

    def _set_drive_limits(self, limits: np.ndarray | None) -> None:
        self._caps = None if limits is None else limits.copy()
        for scene in self._models.values():
            self._apply_caps(scene.model)

    def _set_wrist_targets(self, coords: np.ndarray) -> None:
        self._targets[:, :6] = coords
        self._send_targets(range(self.num_envs))

    def _wrist_rotation_targets(self) -> np.ndarray:
        return self._targets[:, 3:6].copy()

    def _set_hand_state(self, q: np.ndarray, base: np.ndarray | None, ids: list[int]) -> None:
        for row, e in enumerate(ids):
            scene, data = self._scenes[e], self._data[e]
            data.qpos[scene.hand_qpos] = q[row]
            if base is not None and self._setup.floating:
                data.qpos[scene.wrist_qpos] = base[row]
            elif base is not None:
                data.mocap_pos[scene.root_mocap] = base[row, :3]
                data.mocap_quat[scene.root_mocap] = base[row, 3:]
            data.qvel[scene.drive_dof] = 0.0
            self._targets[e, self._nw :] = q[row]
            self._targets[e, : self._nw] = data.qpos[scene.wrist_qpos]
            self._teleported(e)
        self._send_targets(ids)

    def _set_object_pose(self, pose: np.ndarray, ids: list[int]) -> None:
        for e, row in zip(ids, pose, strict=True):
            scene, data = self._scenes[e], self._data[e]
            if scene.object_mocap >= 0:
                data.mocap_pos[scene.object_mocap], data.mocap_quat[scene.object_mocap] = row[:3], row[3:]
            else:
                data.qpos[scene.object_qpos : scene.object_qpos + 7] = row
                data.qvel[scene.object_dof : scene.object_dof + 6] = 0.0
            self._teleported(e)

    def _step(self, n: int) -> dict[int, str]:
        """Every env ``n`` steps, each checked after every step; an env that blew up is not stepped further."""
        blown: dict[int, str] = {}
        with _quiet():
            self._step_envs(n, blown)
        return blown

    def _step_envs(self, n: int, blown: dict[int, str]) -> None:
        """``n`` scene steps of every env (each ``substeps`` MuJoCo steps, forces summed); problems into ``blown``."""
        for e, (scene, data, forces) in enumerate(zip(self._scenes, self._data, self._forces, strict=True)):
            model = scene.model
            for _ in range(n):
                forces.fill(0.0)
                for _ in range(self.substeps):
                    mujoco.mj_step(model, data)
                    add_substep_forces(model, data, forces)
                problem = _state_problem(e, scene, data)
                if problem is not None:
                    blown[e] = problem
                    break
            self._posed[e] = False

    def _rebuild(self, ids: list[int]) -> None:
        """Clear the NaNs out of the blown envs' data (the core then teleports hand and object back)."""
        for e in ids:
            mujoco.mj_resetData(self._scenes[e].model, self._data[e])
            self._posed[e] = False

    # -- reading -------------------------------------------------------------------------------
    def _joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        q = np.stack([d.qpos[s.hand_qpos] for s, d in zip(self._scenes, self._data, strict=True)])
        v = np.stack([d.qvel[s.hand_dof] for s, d in zip(self._scenes, self._data, strict=True)])
        return q, v

    def _wrist_pose(self) -> np.ndarray:
        return self._link_poses([self._setup.base_link])[:, 0]

    def _link_poses(self, links: Sequence[str]) -> np.ndarray:
        ids = self._resolve_links(links)
        out = np.empty((self.num_envs, len(ids), 7))
        for e in range(self.num_envs):
            data = self._posed_data(e)
            out[e, :, :3], out[e, :, 3:] = data.xpos[ids], data.xquat[ids]
        return out

    def _contact_forces(self, links: Sequence[str], partner: str) -> np.ndarray:
        ids = self._resolve_links(links)
        out = np.empty((self.num_envs, len(ids), 3))
        for e, (scene, forces) in enumerate(zip(self._scenes, self._forces, strict=True)):
            partners = None if partner == "any" else [0 if partner == "table" else scene.object_body]
            out[e] = link_forces(forces, ids, partners, self.substeps)
        return out

    def _object_pose(self) -> np.ndarray:
        out = np.empty((self.num_envs, 7))
        for e, (scene, data) in enumerate(zip(self._scenes, self._data, strict=True)):
            if scene.object_mocap >= 0:
                out[e, :3], out[e, 3:] = data.mocap_pos[scene.object_mocap], data.mocap_quat[scene.object_mocap]
            else:
                out[e] = data.qpos[scene.object_qpos : scene.object_qpos + 7]
        return out

    def _contact_pairs(self, env_id: int) -> list[ContactPair]:
        scene = self._scenes[env_id]
        names = {0: ("table", "table")} | {b: ("hand", n) for n, b in scene.links.items()}
        if scene.object_body >= 0:
            names[scene.object_body] = ("object", self._keys[env_id][0].object_id)
        return contact_pairs(scene.model, self._data[env_id], names)

    def _close(self) -> None:
        self._models.clear()
        self._data = []

    # -- internals -----------------------------------------------------------------------------
    @property
    def _nw(self) -> int:
        """Number of wrist drives (6 floating, 0 fixed or no hand)."""
        return 6 if self._setup is not None and self._setup.floating else 0

    def _model(self, key: _Key) -> SceneModel:
        """The compiled scene holding ``key``'s object (None: none) and the hand, built once and shared."""
        if key not in self._models:
            obj, fixed = key if key is not None else (None, False)
            scene = build_scene(self.config, self._setup, obj, fixed, self.substeps)
            self._apply_caps(scene.model)
            self._models[key] = scene
        return self._models[key]

    def _move(self, e: int, key: _Key) -> None:
        """Put env ``e`` on the model for ``key``: a new MjData keeping the hand's state, targets and time."""
        old_scene, old = self._scenes[e], self._data[e]
        scene = self._model(key)
        data = mujoco.MjData(scene.model)
        data.time = old.time
        if old_scene.hand_qpos.size and scene.hand_qpos.size:
            for new_idx, old_idx, arr in ((scene.hand_qpos, old_scene.hand_qpos, "qpos"),
                                          (scene.wrist_qpos, old_scene.wrist_qpos, "qpos"),
                                          (scene.drive_dof, old_scene.drive_dof, "qvel")):  # fmt: skip
                getattr(data, arr)[new_idx] = getattr(old, arr)[old_idx]
            if scene.root_mocap >= 0:
                data.mocap_pos[scene.root_mocap] = old.mocap_pos[old_scene.root_mocap]
                data.mocap_quat[scene.root_mocap] = old.mocap_quat[old_scene.root_mocap]
        self._scenes[e], self._data[e], self._keys[e] = scene, data, key
        self._forces[e] = _force_table(scene.model)
        self._posed[e] = False
        self._send_targets([e])

    def _apply_caps(self, model: mujoco.MjModel) -> None:
        """Hand actuators' force range at the caps (inf or None: unlimited); the wrist's never."""
        k = model.nu - self._nw
        if k <= 0:
            return
        caps = np.full(k, np.inf) if self._caps is None else self._caps
        limited = np.isfinite(caps)
        model.actuator_forcelimited[self._nw :] = limited
        model.actuator_forcerange[self._nw :] = (
            np.stack([-caps, caps], axis=1)
            if limited.all()
            else np.stack([np.where(limited, -caps, 0.0), np.where(limited, caps, 0.0)], axis=1)
        )

    def _send_targets(self, ids: Sequence[int]) -> None:
        for e in ids:
            if self._targets.shape[1] and self._data[e].ctrl.size:
                self._data[e].ctrl[:] = self._targets[e]

    def _teleported(self, e: int) -> None:
        self._data[e].qacc_warmstart[:] = 0.0  # the next step depends on the commands only (module docs)
        self._posed[e] = False

    def _posed_data(self, e: int) -> mujoco.MjData:
        data = self._data[e]
        if not self._posed[e]:
            mujoco.mj_kinematics(self._scenes[e].model, data)
            self._posed[e] = True
        return data

    def _resolve_links(self, links: Sequence[str]) -> list[int]:
        key = tuple(links)
        if key not in self._link_cache:
            known = self._scenes[0].links
            for name in key:
                if name not in known:
                    raise UnknownNameError("hand link", name, known)
            self._link_cache[key] = [known[name] for name in key]
        return self._link_cache[key]


@contextmanager
def _quiet() -> Iterator[None]:
    """MuJoCo's warnings (a NaN state: "WARNING: Nan, Inf or huge value in QACC ...") go nowhere while stepping.

    By default MuJoCo prints them and appends them to ``MUJOCO_LOG.TXT`` in the working directory; the backend
    reads the same events from ``MjData.warning`` and reports them as a SimulationError. The previous handler is
    restored afterwards, so other MuJoCo code in the process keeps its own.
    """
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(_ignore)
    try:
        yield
    finally:
        mujoco.set_mju_user_warning(previous)


def _ignore(message: str) -> None:
    return None


def _force_table(model: mujoco.MjModel) -> np.ndarray:
    """An empty (nbody, nbody, 3) contact-force table for ``model``."""
    return np.zeros((model.nbody, model.nbody, 3))


def _state_problem(env: int, scene: SceneModel, data: mujoco.MjData) -> str | None:
    """Description of env ``env``'s non-finite or exploding state after a step, else None."""
    if any(data.warning[w].number for w in _BAD):
        return f"mujoco env {env}: MuJoCo found a NaN, inf or huge value in the state (warning {_warned(data)})"
    speed = float(np.abs(data.qvel[scene.drive_dof]).max(initial=0.0)) if scene.drive_dof.size else 0.0
    if not speed <= MAX_JOINT_SPEED:  # NaN fails too
        return f"mujoco env {env}: a hand joint moves at {speed:.3g} (limit {MAX_JOINT_SPEED:g} in SI units)"
    if scene.object_dof >= 0:
        lin = float(np.linalg.norm(data.qvel[scene.object_dof : scene.object_dof + 3]))
        if not lin <= MAX_OBJECT_SPEED:
            return f"mujoco env {env}: the object moves at {lin:.3g} m/s (limit {MAX_OBJECT_SPEED:g})"
    return None


def _warned(data: mujoco.MjData) -> str:
    return ", ".join(mujoco.mjtWarning(w).name for w in _BAD if data.warning[w].number)
