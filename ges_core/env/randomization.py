"""Per-episode randomization of the grasp environment: object start pose, mass, friction, observation noise.

Each kind is switched on its own in :class:`RandomizationConfig` and draws from its own random stream
(``numpy.random.SeedSequence(seed).spawn``), so switching one kind on or off never changes what another
draws: with the start pose on and the noise off, the poses are the same as with both on. The draws of an
env happen when its episode starts (:meth:`GraspEnv.reset_envs`, :meth:`GraspEnv.reset_all`), in env order.

A grasp that holds only on one exact float path is not a grasp: evaluate with randomization on and off
(``RandomizationConfig(enabled=False)`` turns every kind off at once).
"""

from __future__ import annotations

import math
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
error), wrist pose m and rad. Blocks not named get none (contact flags, forces, previous action, goal blocks)."""


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
    """The random streams and draws of one environment's randomization (:class:`RandomizationConfig`)."""

    def __init__(self, cfg: RandomizationConfig, noise_slices: dict[str, slice]) -> None:
        """noise_slices: observation block name -> slice of the flat observation (``ObservationLayout.slices``).

        A ``noise_std`` block the layout lacks is a ConfigError (a NoGoal layout has no goal blocks)."""
        unknown = sorted(set(cfg.noise_std) - set(noise_slices))
        if unknown:
            raise ConfigError(
                f"randomization.noise_std names {unknown}, not blocks of the observation; "
                f"its blocks: {', '.join(noise_slices)}"
            )
        self.cfg = cfg
        self._noise = [(noise_slices[k], s) for k, s in cfg.noise_std.items() if s > 0]
        self.reseed(cfg.seed)

    def reseed(self, seed: int) -> None:
        """Restart every stream from ``seed``: pool draws, start pose, physics, noise (in that spawn order)."""
        streams = np.random.SeedSequence(seed).spawn(4)
        self.pool_rng, self._pose_rng, self._physics_rng, self._noise_rng = (np.random.default_rng(s) for s in streams)

    def state(self) -> list[dict]:
        """The four streams' states (JSON-ready dicts), for a checkpoint."""
        return [g.bit_generator.state for g in self._streams()]

    def set_state(self, state: list[dict]) -> None:
        """Restore :meth:`state`."""
        for g, s in zip(self._streams(), state, strict=True):
            g.bit_generator.state = s

    def _streams(self) -> tuple[np.random.Generator, ...]:
        return self.pool_rng, self._pose_rng, self._physics_rng, self._noise_rng

    def start_poses(self, rest: np.ndarray) -> np.ndarray:
        """(m, 7) object start poses from rest poses (m, 7), world: shifted in x, y and turned about world z.

        The turn is about the vertical through the object's origin, so an object resting on its base still
        rests; the rest poses themselves when the start pose is off (a copy)."""
        out = np.array(rest, dtype=np.float64)
        if not self.cfg.active("start_pose"):
            return out
        m = len(out)
        out[:, :2] += self._pose_rng.uniform(-self.cfg.max_shift, self.cfg.max_shift, (m, 2))
        half = np.radians(self._pose_rng.uniform(-self.cfg.max_yaw, self.cfg.max_yaw, m)) / 2
        yaw = np.stack([np.cos(half), np.zeros(m), np.zeros(m), np.sin(half)], axis=1)
        out[:, 3:] = quat_mul(yaw, out[:, 3:])
        return out

    def physics(self, asset: ObjectAsset) -> ObjectAsset:
        """``asset`` with its mass (density) and friction scaled, as switched on; ``asset`` itself if neither is."""
        cfg = self.cfg
        scale_m = self._physics_rng.uniform(1 - cfg.mass_range, 1 + cfg.mass_range) if cfg.active("mass") else None
        scale_f = (
            self._physics_rng.uniform(1 - cfg.friction_range, 1 + cfg.friction_range)
            if cfg.active("friction")
            else None
        )
        if scale_m is None and scale_f is None:
            return asset
        changes: dict[str, float] = {}
        if scale_m is not None:
            changes.update(density=asset.density * scale_m, mass=asset.mass * scale_m)
        if scale_f is not None:
            changes["friction"] = asset.friction * scale_f
        return replace(asset, **changes)

    def add_noise(self, obs: np.ndarray) -> None:
        """Add the configured Gaussian noise to ``obs`` (n, obs size) float32 in place (nothing if it is off)."""
        if not self.cfg.active("obs_noise"):
            return
        for where, std in self._noise:
            block = obs[:, where]
            block += self._noise_rng.normal(0.0, std, block.shape).astype(np.float32)
