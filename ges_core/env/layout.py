"""The paper's observation ``s = (J, a_{t-1}, p_o, G)`` and action, as a named layout.

``J = (q, q̇, c_b, f, p̃_f, T_wrist, Ṫ_wrist)``, ``G = (ĝ_p, ĝ_r, g_q)``. Every block has a name, a
slice into the flat observation vector and a size that depends on the hand: K joints, L contact links,
F fingertips. Frames and units are in ``docs/env.md`` and in :data:`BLOCK_DOCS`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import torch

from ges_core.errors import ConfigError
from ges_core.hand import HandDescription
from ges_core.transforms import columns_to_matrix, matrix_columns, quat_to_matrix
from ges_core.transforms import rotvec_to_quat as rotvec_to_quat_np
from ges_core.transforms_torch import rotvec_to_quat

__all__ = ["BLOCK_DOCS", "GOAL_BLOCKS", "WRIST_DOF", "WRIST_ROTATIONS", "ObservationLayout", "ActionLayout"]

WRIST_DOF = 6
"""Virtual wrist joints of the floating base: 3 translations + 3 rotations."""

BLOCK_DOCS: dict[str, str] = {
    "q": "(K,) hand joint positions, hand joint_names order, rad",
    "dq": "(K,) hand joint velocities, rad/s",
    "contact": "(L,) 1.0 where the link touches the object (contact force > threshold), else 0.0",
    "tip_force": "(F, 3) contact force of the object on each fingertip link, wrist frame, N",
    "tip_pos": "(F, 3) fingertip points, wrist (base-link) frame, m",
    "wrist_pose": "(3 + R,) base-link position (world, m) then its rotation (world): R = 6, the rotation matrix's "
    "first two columns (wrist_rotation 'matrix'), or R = 3, a rotation vector, rad ('rotvec')",
    "wrist_vel": "(6,) base-link linear (m/s) then angular (rad/s) velocity, world, finite difference per control step",
    "prev_action": "(K + 6,) the previous normalized action, in ActionLayout order",
    "obj_pos": "(3,) object-frame origin, world, m",
    "goal_pos": "(3,) ĝ_p: target wrist position minus current, world, m",
    "goal_rot": "(3,) ĝ_r: rotation vector of R_target R_current^T, world, rad",
    "goal_q": "(K,) g_q: goal joint angles minus current, rad",
}
"""Shape, frame and unit of every observation block, in layout order."""

WRIST_ROTATIONS: dict[str, int] = {"matrix": 6, "rotvec": 3}
"""Forms of the ``wrist_pose`` block's rotation -> its floats. ``matrix``: the first two columns of the base link's
rotation matrix, world frame (continuous in the rotation; Zhou et al., CVPR 2019). ``rotvec``: a rotation vector,
angle in [0, pi], which jumps to the opposite vector where the angle passes pi (the same wrist, a hair apart, reads
as two vectors 2 pi apart); the only form before 8 December 2026."""

GOAL_BLOCKS = ("goal_pos", "goal_rot", "goal_q")
"""The goal prior G = (ĝ_p, ĝ_r, g_q): left out of layouts with ``goal=False`` (the NoGoal ablation)."""


@dataclass(frozen=True)
class ObservationLayout:
    """Slices of the flat (num_envs, size) float32 observation, for K joints, L contact links, F tips.

    goal: False leaves out the goal blocks :data:`GOAL_BLOCKS` (6 + K floats; the NoGoal ablation).
    wrist_rotation: how ``wrist_pose`` holds the wrist's rotation, a key of :data:`WRIST_ROTATIONS`.
    """

    num_joints: int
    num_contact_links: int
    num_tips: int
    goal: bool = True
    wrist_rotation: str = "matrix"
    slices: dict[str, slice] = field(init=False, repr=False)
    _total: int = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if min(self.num_joints, self.num_contact_links, self.num_tips) < 1:
            raise ConfigError(
                f"observation layout: K={self.num_joints}, L={self.num_contact_links}, F={self.num_tips}; "
                "every count must be >= 1 (check the hand's joints, fingers and contact links)"
            )
        if self.wrist_rotation not in WRIST_ROTATIONS:
            raise ConfigError(
                f"observation layout: wrist_rotation '{self.wrist_rotation}' is not one of {list(WRIST_ROTATIONS)}"
            )
        start, slices = 0, {}
        for name, size in self.sizes().items():
            slices[name] = slice(start, start + size)
            start += size
        object.__setattr__(self, "slices", slices)
        object.__setattr__(self, "_total", start)

    @classmethod
    def for_hand(
        cls, hand: HandDescription, contact_links: tuple[str, ...], goal: bool = True, wrist_rotation: str = "matrix"
    ) -> ObservationLayout:
        """Layout for ``hand`` with contact booleans on ``contact_links``, goal blocks if ``goal``, the wrist's
        rotation as ``wrist_rotation`` (:data:`WRIST_ROTATIONS`)."""
        return cls(hand.num_joints, len(contact_links), len(hand.fingers), goal, wrist_rotation)

    def sizes(self) -> dict[str, int]:
        """Block name -> number of floats, in layout order."""
        k, f = self.num_joints, self.num_tips
        sizes = {
            "q": k,
            "dq": k,
            "contact": self.num_contact_links,
            "tip_force": 3 * f,
            "tip_pos": 3 * f,
            "wrist_pose": 3 + WRIST_ROTATIONS[self.wrist_rotation],
            "wrist_vel": 6,
            "prev_action": k + WRIST_DOF,
            "obj_pos": 3,
            "goal_pos": 3,
            "goal_rot": 3,
            "goal_q": k,
        }
        return sizes if self.goal else {name: n for name, n in sizes.items() if name not in GOAL_BLOCKS}

    @property
    def size(self) -> int:
        """Total length of the observation vector."""
        return sum(self.sizes().values())

    def pack(self, blocks: dict[str, torch.Tensor]) -> torch.Tensor:
        """Concatenate named blocks (num_envs, ...) into (num_envs, size) float32, checking names and sizes."""
        sizes = self.sizes()
        if set(blocks) != set(sizes):
            missing, extra = sorted(set(sizes) - set(blocks)), sorted(set(blocks) - set(sizes))
            raise ConfigError(f"observation pack: missing blocks {missing}, unknown blocks {extra}")
        n = next(iter(blocks.values())).shape[0]
        parts = [blocks[name].reshape(n, -1).to(torch.float32) for name in sizes]
        bad = [name for name, part in zip(sizes, parts, strict=True) if part.shape[1] != sizes[name]]
        if bad:
            got = {name: blocks[name].reshape(n, -1).shape[1] for name in bad}
            raise ConfigError(f"observation pack: blocks {got} have the wrong size; expected {sizes}")
        return torch.cat(parts, dim=1)

    def pack_np(self, blocks: dict[str, np.ndarray]) -> np.ndarray:
        """:meth:`pack` for numpy blocks (num_envs, block size) in any order: one concatenation, only the total checked.

        The environment's per-step path: blocks must already be 2-D; a wrong block size shows as a wrong total.
        """
        obs = np.concatenate([blocks[name] for name in self.slices], axis=1, dtype=np.float32)
        if obs.shape[1] != self._total:
            got = {name: blocks[name].shape[1] for name in self.slices}
            raise ConfigError(
                f"observation pack: block sizes {got} give {obs.shape[1]} floats; expected {self.sizes()}"
            )
        return obs

    def with_goal(self) -> ObservationLayout:
        """This layout with the goal blocks :data:`GOAL_BLOCKS` (itself if it has them)."""
        if self.goal:
            return self
        return ObservationLayout(self.num_joints, self.num_contact_links, self.num_tips, True, self.wrist_rotation)

    def add_goal(self, obs: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Observations of :meth:`with_goal`'s layout (num_envs, size + 6 + K) float32: ``obs`` (num_envs, size) of
        this goal-less layout with ``goal`` (num_envs, 6 + K), the blocks G in :data:`GOAL_BLOCKS` order, put in.

        The view a goal-less policy's teacher reads (the warm start of a NoGoal run, docs/training.md)."""
        full = self.with_goal()
        k = full.sizes()
        width = sum(k[name] for name in GOAL_BLOCKS)
        if self.goal or obs.shape[-1] != self.size or goal.shape[-1] != width or goal.shape[0] != obs.shape[0]:
            raise ConfigError(
                f"add_goal: needs a goal-less layout's observations ({self.size} floats) and their goal blocks "
                f"({width} floats: {', '.join(GOAL_BLOCKS)}) per row; got a {'goal' if self.goal else 'goal-less'} "
                f"layout, observations {tuple(obs.shape)} and goal {tuple(goal.shape)}"
            )
        out = torch.empty(obs.shape[0], full.size, dtype=torch.float32)
        for name, sl in self.slices.items():
            out[:, full.slices[name]] = obs[:, sl]
        start = full.slices[GOAL_BLOCKS[0]].start
        out[:, start : start + width] = goal.to(torch.float32)
        return out

    def unpack(self, obs: torch.Tensor, name: str) -> torch.Tensor:
        """The block ``name`` of observations (num_envs, size) as (num_envs, block size)."""
        if name not in self.slices:
            hint = " (a NoGoal layout: goal=False leaves out the goal blocks)" if name in GOAL_BLOCKS else ""
            raise ConfigError(f"observation block '{name}' is not in this layout{hint}; blocks: {list(self.slices)}")
        return obs[:, self.slices[name]]

    def wrist_quat(self, obs: torch.Tensor) -> torch.Tensor:
        """(num_envs, 4) float64 wxyz: the base link's world rotation held in observations (num_envs, size), read
        from either form of :data:`WRIST_ROTATIONS`: from the matrix's two columns made orthonormal first (so
        observation noise on them still gives a rotation), w >= 0; from a rotation vector its own quaternion (w < 0
        only where noise took its angle past pi: the same rotation)."""
        rot = self.unpack(obs, "wrist_pose")[:, 3:].to(torch.float64)
        if self.wrist_rotation == "rotvec":
            return rotvec_to_quat(rot)
        quat = _from_matrices(columns_to_matrix(rot.detach().cpu().numpy()), "quat")
        quat *= np.where(quat[:, :1] < 0, -1.0, 1.0)
        return torch.from_numpy(quat)

    def with_wrist_rotation(self, form: str) -> ObservationLayout:
        """This layout with the wrist's rotation in ``form`` (:data:`WRIST_ROTATIONS`; itself if it is already)."""
        return self if form == self.wrist_rotation else replace(self, wrist_rotation=form)

    def recast(self, obs: torch.Tensor, to: ObservationLayout) -> torch.Tensor:
        """Observations (num_envs, size) of this layout as ``to`` lays them out, ``to`` being this layout with the
        wrist's rotation in another form (:meth:`with_wrist_rotation`): every other block copied, the rotation read
        and written in ``to``'s form (float64 in between), in ``obs``'s dtype. ``obs`` itself when the forms agree;
        ConfigError when the layouts differ in anything else."""
        if to == self:
            return obs
        if to.with_wrist_rotation(self.wrist_rotation) != self:
            raise ConfigError(f"observation recast: {self} and {to} differ in more than the wrist's rotation form")
        out = torch.empty(obs.shape[0], to.size, dtype=obs.dtype, device=obs.device)
        for name, sl in self.slices.items():
            if name != "wrist_pose":
                out[:, to.slices[name]] = obs[:, sl]
        start, stop = to.slices["wrist_pose"].start, to.slices["wrist_pose"].stop
        wrist = obs[:, self.slices["wrist_pose"]]
        out[:, start : start + 3] = wrist[:, :3]
        rot = wrist[:, 3:].detach().cpu().numpy().astype(np.float64)
        if to.wrist_rotation == "rotvec":  # from the matrix's columns
            new = _from_matrices(columns_to_matrix(rot), "rotvec")
        else:
            new = matrix_columns(quat_to_matrix(rotvec_to_quat_np(rot)))
        out[:, start + 3 : stop] = torch.from_numpy(new).to(device=obs.device, dtype=obs.dtype)
        return out


def _from_matrices(mat: np.ndarray, form: str) -> np.ndarray:
    """(n, 4) wxyz quaternions (``form`` 'quat') or (n, 3) rotation vectors ('rotvec') of (n, 3, 3) rotation matrices
    that are orthonormal already (:func:`~ges_core.transforms.columns_to_matrix`'s), float64; NaN rows where a
    matrix is not finite (an observation that holds no rotation, a blown-up env's)."""
    from scipy.spatial.transform import Rotation

    out = np.full((len(mat), 4 if form == "quat" else 3), np.nan)
    ok = np.isfinite(mat).all(axis=(1, 2))
    if ok.any():
        rot = Rotation.from_matrix(mat[ok], assume_valid=True)  # orthonormal: no SVD (49 -> 10 us for 8)
        out[ok] = rot.as_quat(scalar_first=True) if form == "quat" else rot.as_rotvec()
    return out


@dataclass(frozen=True)
class ActionLayout:
    """Normalized action in [-1, 1]: 6 wrist values then K hand joint targets.

    Wrist: ``a[:3] * max_wrist_step`` (m) is added to the previous wrist target position and
    ``a[3:6] * max_wrist_turn`` (rad, rotation vector, world) turns the previous target orientation
    (the target starts at the measured wrist pose on reset); hand:
    ``q_target = lower + (a + 1) / 2 * (upper - lower)``.
    """

    lower: torch.Tensor
    """(K,) joint lower limits, rad."""
    upper: torch.Tensor
    """(K,) joint upper limits, rad."""
    max_wrist_step: float = 0.02
    """Metres the wrist target may move from the current wrist position per control step."""
    max_wrist_turn: float = 0.1
    """Radians the wrist target may turn from the current orientation per control step."""
    _lower_np: np.ndarray = field(init=False, repr=False, compare=False)
    _half_range_np: np.ndarray = field(init=False, repr=False, compare=False)
    _wrist_scale_np: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        """Cache the float64 numpy forms of the limits and the wrist scales for the ``*_np`` methods."""
        lower, upper = (np.asarray(t.detach().cpu(), dtype=np.float64) for t in (self.lower, self.upper))
        object.__setattr__(self, "_lower_np", lower)
        object.__setattr__(self, "_half_range_np", 0.5 * (upper - lower))  # x 0.5 is exact: equals joint_targets
        scale = np.array([self.max_wrist_step] * 3 + [self.max_wrist_turn] * 3)
        object.__setattr__(self, "_wrist_scale_np", scale)

    @property
    def size(self) -> int:
        """K + 6."""
        return WRIST_DOF + self.lower.shape[0]

    def describe(self) -> str:
        """What a row holds, for messages: ``"6 wrist values (...), then K=16 joint targets, each in [-1, 1]"``."""
        k = self.size - WRIST_DOF
        return (
            f"one row per env: {WRIST_DOF} wrist values (3 position steps, 3 rotation-vector steps), "
            f"then K={k} joint targets, each in [-1, 1]"
        )

    def joint_targets(self, action: torch.Tensor) -> torch.Tensor:
        """(n, K) joint targets, rad, from actions (n, K + 6) (clipped to [-1, 1] first)."""
        a = action[:, WRIST_DOF:].clamp(-1.0, 1.0).to(self.lower.dtype)
        return self.lower + (a + 1.0) * 0.5 * (self.upper - self.lower)

    def normalize_joints(self, q: torch.Tensor) -> torch.Tensor:
        """Inverse of :meth:`joint_targets` for the hand part: (n, K) rad -> (n, K) in [-1, 1]."""
        return (2.0 * (q - self.lower) / (self.upper - self.lower) - 1.0).clamp(-1.0, 1.0)

    def joint_targets_np(self, action: np.ndarray) -> np.ndarray:
        """:meth:`joint_targets` for numpy actions (n, K + 6) **already clipped** to [-1, 1]: (n, K) float64, rad."""
        return self._lower_np + (action[:, WRIST_DOF:] + 1.0) * self._half_range_np

    def wrist_deltas_np(self, action: np.ndarray) -> np.ndarray:
        """(n, 6) position step (m) then rotation-vector step (rad), from numpy actions already clipped to [-1, 1]."""
        return action[:, :WRIST_DOF] * self._wrist_scale_np

    def wrist_deltas(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(n, 3) position step (m) and (n, 3) rotation-vector step (rad) from actions (n, K + 6)."""
        a = action[:, :WRIST_DOF].clamp(-1.0, 1.0).to(self.lower.dtype)
        return a[:, :3] * self.max_wrist_step, a[:, 3:] * self.max_wrist_turn
