"""Per-episode randomization of the grasp environment: object start pose, mass, friction, observation noise.

Each env has its own random streams, one per kind (pool draws, start pose, mass and friction, noise), from
``numpy.random.SeedSequence(seed, spawn_key=(env,)).spawn(4)`` where ``env`` is the env's *global* index
(:attr:`Randomizer.env_index`): what an env draws depends only on the seed, its index and its own episode
history, never on which other envs restarted with it or on how the envs are split between worker processes
(:mod:`ges_core.env.workers`). Switching one kind on or off never changes what another draws: with the start pose
on and the noise off, the poses are the same as with both on. The draws of an env happen when its episode starts
(:meth:`GraspEnv.reset_envs`, :meth:`GraspEnv.reset_all`); its noise at every observation.

A grasp that holds only on one exact float path is not a grasp: evaluate with randomization on and off
(``RandomizationConfig(enabled=False)`` turns every kind off at once).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from pydantic import Field, field_validator

from ges_core.config import ConfigModel
from ges_core.errors import ConfigError
from ges_core.objects.asset import ObjectAsset
from ges_core.transforms import quat_mul

__all__ = ["NOISE_BLOCKS", "RandomizationConfig", "Randomizer"]

NOISE_BLOCKS: dict[str, float] = {
    "q": 0.005,
    "dq": 0.05,
    "tip_pos": 0.002,
    "wrist_pose": 0.002,
    "obj_pos": 0.002,
}
"""Default observation-noise standard deviations per observation block (``docs/env.md``): joint angles rad
(0.3 degrees, an encoder's error), joint velocities rad/s, fingertip and object positions m (2 mm, a tracker's
error), wrist pose m, and per rotation-matrix entry (or rad, ``wrist_rotation: rotvec``). Blocks not named get none
(contact flags, forces, previous action, goal blocks)."""


class RandomizationConfig(ConfigModel):
    """Which per-episode randomization runs, how much, and its seed (every kind off by default)."""

    enabled: bool = Field(True, description="master switch: False turns every kind below off at once")
    seed: int = Field(0, ge=0, description="seed of every random stream (one stream per kind)")
    start_pose: bool = Field(False, description="object start pose shifted and turned about its rest pose")
    max_shift: float = Field(
        0.005, ge=0, le=0.05, description="m, largest shift in x and y (uniform in the square), table plane"
    )
    max_yaw: float = Field(
        5.0, ge=0, le=180, description="degrees, largest turn about the world z axis through the object's origin"
    )
    mass: bool = Field(False, description="object mass scaled by a factor uniform in 1 +- mass_range")
    mass_range: float = Field(0.2, ge=0, lt=1, description="fraction: mass x U(1 - r, 1 + r) (density scaled)")
    friction: bool = Field(False, description="object friction scaled by a factor uniform in 1 +- friction_range")
    friction_range: float = Field(0.2, ge=0, lt=1, description="fraction: friction x U(1 - r, 1 + r)")
    obs_noise: bool = Field(False, description="Gaussian noise on the policy's observation (not on the reward)")
    noise_std: dict[str, float] = Field(
        default_factory=lambda: dict(NOISE_BLOCKS),
        description="per observation block, the noise's standard deviation in the block's unit",
    )

    @field_validator("noise_std")
    @classmethod
    def _check_noise(cls, value: dict[str, float]) -> dict[str, float]:
        bad = {k: v for k, v in value.items() if not (math.isfinite(v) and v >= 0)}
        if bad:
            raise ValueError(f"noise standard deviations must be finite and >= 0, not {bad}")
        return value

    def active(self, kind: str) -> bool:
        """True when ``kind`` (start_pose, mass, friction, obs_noise) is switched on and the master switch too."""
        return self.enabled and bool(getattr(self, kind))


class Randomizer:
    """The per-env random streams and draws of one environment's randomization (:class:`RandomizationConfig`)."""

    def __init__(self, cfg: RandomizationConfig, noise_slices: dict[str, slice], env_index: Sequence[int]) -> None:
        """noise_slices: observation block name -> slice of the flat observation (``ObservationLayout.slices``);
        env_index: (n,) the global index of each env (row) this randomizer serves, which seeds its streams.

        A ``noise_std`` block the layout lacks is a ConfigError (a NoGoal layout has no goal blocks)."""
        unknown = sorted(set(cfg.noise_std) - set(noise_slices))
        if unknown:
            raise ConfigError(
                f"randomization.noise_std names {unknown}, not blocks of the observation; "
                f"its blocks: {', '.join(noise_slices)}"
            )
        self.cfg = cfg
        self.env_index = tuple(int(e) for e in env_index)
        """Global env index of each row (its streams' spawn key)."""
        noisy = [(noise_slices[k], s) for k, s in cfg.noise_std.items() if s > 0]
        self._noise_cols = np.concatenate([np.arange(w.start, w.stop) for w, _ in noisy] or [np.zeros(0, int)])
        self._noise_std = np.concatenate([np.full(w.stop - w.start, s) for w, s in noisy] or [np.zeros(0)])
        self.reseed(cfg.seed)

    def reseed(self, seed: int) -> None:
        """Restart every env's streams from ``seed``: pool draws, start pose, physics, noise (in that spawn order)."""
        self._rngs = [
            tuple(np.random.default_rng(s) for s in np.random.SeedSequence(seed, spawn_key=(e,)).spawn(4))
            for e in self.env_index
        ]

    def state(self) -> list[list[dict]]:
        """Per env (row order), its four streams' states (JSON-ready dicts), for a checkpoint."""
        return [[g.bit_generator.state for g in rngs] for rngs in self._rngs]

    def set_state(self, state: list[list[dict]]) -> None:
        """Restore :meth:`state`; ConfigError if it was taken with another number of envs. A state saved before
        per-env streams (four dicts, one stream per kind for all envs) cannot map onto them: the streams stay as
        they are (seeded) and a warning says so, so such a checkpoint still resumes."""
        if len(state) == 4 and all(isinstance(s, dict) for s in state):
            warnings.warn(
                "randomization state from before per-env random streams: the streams restart from the seed",
                stacklevel=2,
            )
            return
        if len(state) != len(self._rngs) or any(not isinstance(s, list) or len(s) != 4 for s in state):
            raise ConfigError(
                f"randomization state: {len(state)} entries, this environment has {len(self._rngs)} envs with 4 "
                "streams each; resume with the num_envs the state was saved with"
            )
        for rngs, states in zip(self._rngs, state, strict=True):
            for g, s in zip(rngs, states, strict=True):
                g.bit_generator.state = s

    def pool_entries(self, pool, rows: Sequence[int]) -> np.ndarray:
        """(m,) int64: one entry of ``pool`` (a GraspPool) drawn for each env row in ``rows``, from its own stream."""
        return np.array([pool.draw(self._rngs[r][0], 1)[0] for r in rows], dtype=np.int64)

    def start_poses(self, rest: np.ndarray, rows: Sequence[int]) -> np.ndarray:
        """(m, 7) object start poses from rest poses (m, 7) of env rows ``rows``, world: shifted in x, y and turned
        about world z.

        The turn is about the vertical through the object's origin, so an object resting on its base still
        rests; the rest poses themselves when the start pose is off (a copy)."""
        out = np.array(rest, dtype=np.float64)
        if not self.cfg.active("start_pose"):
            return out
        shift, yaw = self.cfg.max_shift, self.cfg.max_yaw
        draws = np.array([self._rngs[r][1].uniform([-shift, -shift, -yaw], [shift, shift, yaw]) for r in rows])
        out[:, :2] += draws[:, :2]
        half = np.radians(draws[:, 2]) / 2
        zeros = np.zeros(len(out))
        out[:, 3:] = quat_mul(np.stack([np.cos(half), zeros, zeros, np.sin(half)], axis=1), out[:, 3:])
        return out

    def physics(self, asset: ObjectAsset, row: int) -> ObjectAsset:
        """``asset`` with its mass (density) and friction scaled for env row ``row``, as switched on; ``asset``
        itself if neither is."""
        cfg, rng = self.cfg, self._rngs[row][2]
        scale_m = rng.uniform(1 - cfg.mass_range, 1 + cfg.mass_range) if cfg.active("mass") else None
        scale_f = rng.uniform(1 - cfg.friction_range, 1 + cfg.friction_range) if cfg.active("friction") else None
        if scale_m is None and scale_f is None:
            return asset
        changes: dict[str, float] = {}
        if scale_m is not None:
            changes.update(density=asset.density * scale_m, mass=asset.mass * scale_m)
        if scale_f is not None:
            changes["friction"] = asset.friction * scale_f
        return replace(asset, **changes)

    def add_noise(self, obs: np.ndarray, rows=None) -> None:
        """Add the configured Gaussian noise to ``obs`` (n, obs size) float32 in place, row r from env row r's
        stream (nothing if it is off). rows: only these rows (a 1-D int array or tensor; None: every row)."""
        if not self.cfg.active("obs_noise") or not len(self._noise_cols):
            return
        rows = range(len(obs)) if rows is None else [int(r) for r in rows]
        k = len(self._noise_cols)
        z = np.array([self._rngs[r][3].standard_normal(k) for r in rows]).reshape(len(rows), k)
        obs[np.ix_(np.asarray(rows, dtype=np.int64), self._noise_cols)] += (z * self._noise_std).astype(np.float32)
