"""Stage 2 interfaces: experts act, gates choose among experts.

Both work on batched torch tensors so that one call serves many environments.

**Experts are plugins.** A plugin registers an :class:`~ges_core.specs.ExpertSpec` through the hook
``ges_register_experts``; its factory is called by :meth:`ges_core.registry.Registry.build_expert` as

    factory(context: ExpertContext, **settings) -> Expert

``context`` says what the expert will drive (:class:`ExpertContext`: observation and action layouts, the
hand, the number of envs); ``settings`` are the spec's defaults, then registry.yaml's
``settings.expert.<name>``, then the caller's (``ges eval-experts --expert NAME:key=value``), key by key.

**What an expert was made for.** An expert that was trained (or otherwise fixed) for one hand and one
observation/action layout says so in :attr:`Expert.made_for`, an :class:`ExpertScope`
(``ExpertScope.of(context)`` at training time; ``to_dict``/``from_dict`` to keep it in a checkpoint).
Before an expert acts in an environment, call the one check::

    expert = load_my_checkpoint(path)                 # made_for = ExpertScope.from_dict(ckpt["made_for"])
    check_expert_fits(expert, context, who=f"checkpoint {path}")

It raises one :class:`~ges_core.errors.ConfigError` naming both sides (what the expert was made for,
what the environment has, and each difference) when the hand, the observation layout or the action
layout differ. An expert whose ``made_for`` is None (the scripted expert, built from the context it
is given) fits every context; the evaluation runner calls the check for every expert it builds.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from ges_core.errors import ConfigError

if TYPE_CHECKING:
    from ges_core.env.layout import ActionLayout, ObservationLayout
    from ges_core.hand import HandModel

__all__ = ["Expert", "ExpertContext", "ExpertScope", "Gate", "check_expert_fits"]

LIMIT_TOLERANCE = 1e-6
"""rad (or m, for the wrist steps): two action layouts agree when every limit differs by less; a YAML or JSON
round trip of a float64 limit keeps it exact, a hand whose limits were edited differs by far more."""


@dataclass(frozen=True, kw_only=True)
class ExpertContext:
    """What an expert factory is told about the environment it will act in (``factory(context, **settings)``)."""

    obs_layout: ObservationLayout
    """The environment's observation layout (``GraspEnv.obs_layout``): (num_envs, obs_layout.size) float32."""
    act_layout: ActionLayout
    """The environment's action layout (``GraspEnv.act_layout``): (num_envs, act_layout.size) in [-1, 1]."""
    hand: HandModel
    """The hand the environment simulates (its description: joint names, limits, fingers, settings)."""
    num_envs: int
    """Rows of every ``act`` call's observation batch."""
    sim: str = ""
    """Registry name of the simulator the episodes run in ("" if not known); for the expert's records only."""
    device: str = "cpu"
    """torch device the observations arrive on."""
    registry: Any = None
    """The :class:`~ges_core.registry.Registry` that built the expert (None outside one): an expert built on
    another (a residual policy on the scripted expert) builds its base through it."""

    @classmethod
    def of_env(cls, env: Any, **kw: Any) -> ExpertContext:
        """The context of a :class:`~ges_core.env.grasp_env.GraspEnv` (its layouts, hand and env count)."""
        return cls(obs_layout=env.obs_layout, act_layout=env.act_layout, hand=env.hand, num_envs=env.n, **kw)


@dataclass(frozen=True, kw_only=True)
class ExpertScope:
    """What an expert was made for: the hand, the observation layout and the action layout, as plain data.

    JSON-ready through :meth:`to_dict` / :meth:`from_dict` (a checkpoint stores it); compared by
    :meth:`differences` and :func:`check_expert_fits`.
    """

    hand: str
    """Registry name of the hand."""
    observation: tuple[tuple[str, int], ...]
    """(block name, floats) per observation block, in layout order (``ObservationLayout.sizes()``)."""
    joint_names: tuple[str, ...]
    """The K action joints, in the hand's order (the last K action entries)."""
    joint_limits: tuple[tuple[float, float], ...]
    """(lower, upper) rad per joint: where -1 and +1 of the normalized action land."""
    max_wrist_step: float
    """m per control step that a wrist action of 1 moves the wrist target."""
    max_wrist_turn: float
    """rad per control step that a wrist action of 1 turns the wrist target."""

    @classmethod
    def of(cls, context: ExpertContext) -> ExpertScope:
        """The scope of ``context`` (what an expert trained there is made for)."""
        act = context.act_layout
        limits = zip(act.lower.tolist(), act.upper.tolist(), strict=True)
        return cls(
            hand=context.hand.name,
            observation=tuple(context.obs_layout.sizes().items()),
            joint_names=tuple(context.hand.description.joint_names),
            joint_limits=tuple((float(lo), float(hi)) for lo, hi in limits),
            max_wrist_step=float(act.max_wrist_step),
            max_wrist_turn=float(act.max_wrist_turn),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (lists for tuples)."""
        return {
            "hand": self.hand,
            "observation": [[name, size] for name, size in self.observation],
            "joint_names": list(self.joint_names),
            "joint_limits": [list(lim) for lim in self.joint_limits],
            "max_wrist_step": self.max_wrist_step,
            "max_wrist_turn": self.max_wrist_turn,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, where: str = "expert scope") -> ExpertScope:
        """Inverse of :meth:`to_dict`; a missing or malformed field is a ConfigError naming ``where``."""
        try:
            return cls(
                hand=str(data["hand"]),
                observation=tuple((str(n), int(k)) for n, k in data["observation"]),
                joint_names=tuple(str(n) for n in data["joint_names"]),
                joint_limits=tuple((float(lo), float(hi)) for lo, hi in data["joint_limits"]),
                max_wrist_step=float(data["max_wrist_step"]),
                max_wrist_turn=float(data["max_wrist_turn"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(
                f"{where}: not an expert scope ({type(exc).__name__}: {exc}); expected the keys hand, observation, "
                "joint_names, joint_limits, max_wrist_step, max_wrist_turn (ExpertScope.to_dict)"
            ) from exc

    @property
    def wrist_rotation(self) -> str | None:
        """The form of the wrist's rotation in its ``wrist_pose`` block (``EnvConfig.wrist_rotation``), read from the
        block's size; None without the block or at a size no form has."""
        from ges_core.env.layout import WRIST_ROTATIONS  # lazy: the interfaces stay free of the env package

        size = dict(self.observation).get("wrist_pose")
        return next((form for form, k in WRIST_ROTATIONS.items() if 3 + k == size), None)

    def with_wrist_rotation(self, form: str) -> ExpertScope:
        """This scope with its ``wrist_pose`` block in ``form`` (a key of ``WRIST_ROTATIONS``)."""
        from ges_core.env.layout import WRIST_ROTATIONS

        blocks = tuple((n, 3 + WRIST_ROTATIONS[form] if n == "wrist_pose" else k) for n, k in self.observation)
        return replace(self, observation=blocks)

    def describe(self) -> str:
        """One line: hand, observation blocks with sizes, action size and wrist steps."""
        blocks = ", ".join(f"{n}:{k}" for n, k in self.observation)
        total = sum(k for _, k in self.observation)
        return (
            f"hand '{self.hand}', observation {total} floats [{blocks}], action {len(self.joint_names) + 6} "
            f"(6 wrist, step {self.max_wrist_step:g} m / {self.max_wrist_turn:g} rad; {len(self.joint_names)} joints)"
        )

    def differences(self, other: ExpertScope) -> list[str]:
        """What differs from ``other``, one phrase each ("this vs other"); [] when they agree."""
        out = [f"hand '{self.hand}' vs '{other.hand}'"] if self.hand != other.hand else []
        if self.observation != other.observation:
            out.append(f"observation blocks {_blocks_diff(self.observation, other.observation)}")
        if self.joint_names != other.joint_names:
            out.append(f"action joints {_names(self.joint_names)} vs {_names(other.joint_names)}")
        elif not _close(sum(self.joint_limits, ()), sum(other.joint_limits, ())):
            bad = [n for n, a, b in zip(self.joint_names, self.joint_limits, other.joint_limits, strict=True)
                   if not _close(a, b)]  # fmt: skip
            out.append(f"joint limits of {bad}")
        for key in ("max_wrist_step", "max_wrist_turn"):
            if not _close((getattr(self, key),), (getattr(other, key),)):
                out.append(f"{key} {getattr(self, key):g} vs {getattr(other, key):g}")
        return out


def _wrist_hint(expert: ExpertScope, env: ExpertScope) -> str:
    """The setting that turns the environment's ``wrist_pose`` block into the expert's, where only its form differs."""
    a, b = expert.wrist_rotation, env.wrist_rotation
    if a != b and a is not None and b is not None:
        return f"; its wrist_pose holds the rotation as '{a}': set -o env.wrist_rotation={a}"
    return ""


def _close(a: Sequence[float], b: Sequence[float]) -> bool:
    return len(a) == len(b) and all(
        math.isclose(x, y, rel_tol=0, abs_tol=LIMIT_TOLERANCE) for x, y in zip(a, b, strict=True)
    )


def _names(names: tuple[str, ...], shown: int = 4) -> str:
    """``16 [a, b, c, d, ...]``: the count and the first few names."""
    more = ", ..." if len(names) > shown else ""
    return f"{len(names)} [{', '.join(names[:shown])}{more}]"


def _blocks_diff(mine: tuple[tuple[str, int], ...], env: tuple[tuple[str, int], ...]) -> str:
    """Which blocks differ: sizes of shared blocks, blocks only on one side, or the order."""
    a, b = dict(mine), dict(env)
    parts = [f"{n} {a[n]} vs {b[n]}" for n in a if n in b and a[n] != b[n]]
    parts += [f"{n} only in the expert's" for n in a if n not in b]
    parts += [f"{n} only in the environment's" for n in b if n not in a]
    return "(" + ("; ".join(parts) or "same blocks, other order") + ")"


def check_expert_fits(expert: Expert | ExpertScope, context: ExpertContext, *, who: str = "") -> None:
    """ConfigError naming both sides unless ``expert`` (or the scope it was made for) fits ``context``.

    expert: an :class:`Expert` (its :attr:`~Expert.made_for`; None fits everything) or an
    :class:`ExpertScope` read from a checkpoint. who: how to name the expert in the message
    (default: its name, e.g. ``"checkpoint runs/x/model_100.pt"``).
    """
    scope = expert if isinstance(expert, ExpertScope) else expert.made_for
    if scope is None:
        return
    env = ExpertScope.of(context)
    diffs = scope.differences(env)
    if diffs:
        name = who or f"expert '{getattr(expert, 'name', '') or '?'}'"
        raise ConfigError(
            f"{name} was made for {scope.describe()}; this environment has {env.describe()}. They differ in: "
            f"{'; '.join(diffs)}. Use an expert trained for this hand and environment settings, or evaluate it "
            "where it was trained (same hand, env.goal_prior, env.wrist_rotation, env.max_wrist_step, "
            f"env.max_wrist_turn){_wrist_hint(scope, env)}",
            problems=diffs,
        )


class Expert(ABC):
    """A grasp-execution policy (scripted, or PPO-trained), built by its plugin as ``factory(context, **settings)``."""

    name: str = ""
    """Registry name."""

    made_for: ExpertScope | None = None
    """The hand and layouts the expert was made for (see the module docs); None: it adapts to any context."""

    @abstractmethod
    def act(self, obs: torch.Tensor) -> torch.Tensor:
        """Actions for a batch of observations.

        obs: (num_envs, obs_dim) float32, the environment's documented observation layout.
        Returns (num_envs, num_actions) float32 in [-1, 1] (normalized joint targets).
        """

    def reset(self, env_ids: torch.Tensor | None = None) -> None:  # noqa: B027 - optional hook
        """Forget per-episode state for ``env_ids`` (all if None); stateless experts ignore it."""


class Gate(ABC):
    """Chooses one expert per object from its point cloud.

    A gate is trained for a fixed, ordered list of experts (:attr:`experts`, the columns of
    :meth:`predict`); its checkpoint names them, and using it with other experts is an error
    (:meth:`check_experts`). Training, data and checkpoint formats live in :mod:`ges_core.gating`.
    """

    name: str = ""
    """Registry name."""

    experts: tuple[str, ...] = ()
    """Names of the experts the gate chooses among, in the order of :meth:`predict`'s columns."""

    @abstractmethod
    def predict(self, points: torch.Tensor) -> torch.Tensor:
        """Expert probabilities.

        points: (n, N, 3) float32 object point clouds, object frame, metres.
        Returns (n, k) float32, rows sum to 1, k = number of experts.
        """

    @abstractmethod
    def fit(self, data: Any, **options: Any) -> Any:
        """Train on ``data`` (a :class:`ges_core.gating.GateData`: object clouds and per-expert success
        rates); sets :attr:`experts` to the data's experts and returns the training history."""

    @abstractmethod
    def save(self, path: str | Path) -> None:
        """Write a checkpoint that names :attr:`experts`."""

    @classmethod
    @abstractmethod
    def load(cls, path: str | Path) -> Gate:
        """The gate saved at ``path``, with the experts it was trained for."""

    def check_experts(self, experts: Sequence[str]) -> None:
        """ConfigError naming both lists unless ``experts`` are the ones this gate was trained for (same order)."""
        if tuple(experts) != tuple(self.experts):
            raise ConfigError(
                f"gate '{self.name}' was trained for experts {list(self.experts)} but is used with "
                f"{list(experts)}; retrain it (ges train-gate) on a success matrix of these experts, "
                f"or pass the experts it was trained for"
            )

    def select(self, points: torch.Tensor) -> torch.Tensor:
        """Index (n,) int64 of the expert with the highest predicted score."""
        return self.predict(points).argmax(dim=-1)
