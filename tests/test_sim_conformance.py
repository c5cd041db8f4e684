"""Every SimBackend subclass matches the interface: the built-in backends and the test doubles alike.

``ges_core.sim.SimBackend`` checks every argument in its concrete public methods and then calls the
backend's ``_hooks``. A subclass that overrides a public method (other than ``engine_step``) skips those
checks, and one whose hook takes other arguments breaks at the first call: both are caught here, for
every subclass found once the modules that define them are imported.
"""

from __future__ import annotations

import inspect

import numpy as np
import pytest
from test_env_fast_path import _RandomBackend  # a test double
from test_synthesis_refine import ExplodingBackend  # a test double

from ges_core.errors import ArrayError, ConfigError
from ges_core.sim import SceneConfig, SimBackend
from ges_plugins.sims.pybullet.backend import PybulletBackend
from ges_plugins.sims.sapien.backend import SapienBackend

OVERRIDABLE = {"engine_step"}
"""Public methods a backend may override (same signature): the raw step only."""
OPTIONAL_HOOKS = {"_rebuild"}
"""Hooks with a default a backend may keep."""


def _subclasses(cls: type) -> list[type]:
    out = []
    for sub in cls.__subclasses__():
        out += [sub, *_subclasses(sub)]
    return out


def _interface() -> tuple[dict[str, object], set[str], set[str]]:
    """(every function SimBackend defines, its public ones, its hooks)."""
    functions = {name: f for name, f in vars(SimBackend).items() if inspect.isfunction(f)}
    public = {name for name in functions if not name.startswith("_")}
    hooks = set(SimBackend.__abstractmethods__) | OPTIONAL_HOOKS
    return functions, public, hooks


def _shape(function: object) -> list[tuple[str, object, object]]:
    """Parameter names, kinds and defaults (annotations left out: a double may have none)."""
    return [(p.name, p.kind, p.default) for p in inspect.signature(function).parameters.values()]


def conformance_problems(cls: type[SimBackend]) -> list[str]:
    """What makes ``cls`` differ from the SimBackend interface; [] if nothing."""
    functions, public, hooks = _interface()
    problems = [f"abstract hook {name} not implemented" for name in sorted(getattr(cls, "__abstractmethods__", ()))]
    if not (isinstance(cls.name, str) and cls.name):
        problems.append("no registry name: set the class attribute `name`")
    for klass in cls.__mro__[: cls.__mro__.index(SimBackend)]:
        for name, member in vars(klass).items():
            if name not in functions or name.startswith("__"):
                continue
            if name in public - OVERRIDABLE or (name.startswith("_") and name not in hooks):
                problems.append(f"{klass.__name__}.{name} overrides the core's {name}, which checks arguments")
            elif not inspect.isfunction(member) or _shape(member) != _shape(functions[name]):
                got, want = inspect.signature(member), inspect.signature(functions[name])
                problems.append(f"{klass.__name__}.{name}{got} differs from the interface's {want}")
    return problems


BACKENDS = sorted(_subclasses(SimBackend), key=lambda c: f"{c.__module__}.{c.__qualname__}")


def test_the_builtins_and_the_doubles_are_found():
    assert {SapienBackend, PybulletBackend, ExplodingBackend, _RandomBackend} <= set(BACKENDS)


@pytest.mark.parametrize("cls", BACKENDS, ids=lambda c: c.__name__)
def test_backend_matches_the_interface(cls):
    assert conformance_problems(cls) == []


@pytest.mark.parametrize("cls", BACKENDS, ids=lambda c: c.__name__)
def test_public_signatures_are_the_interfaces(cls):
    """What a caller sees: every public method of the backend has the interface's exact signature."""
    _, public, _ = _interface()
    for name in public:
        assert inspect.signature(getattr(cls, name)) == inspect.signature(getattr(SimBackend, name)), name


def test_a_drifted_backend_is_caught():
    """The check fails for each way a backend can drift (a local double, a subclass of a conforming one)."""

    class DroppedEnvIds(ExplodingBackend):  # the signature drifted, as the old double's had
        def set_hand_state(self, q, wrist_pose=None):
            pass

    class SameSignature(ExplodingBackend):  # right signature, but the core's checks are skipped
        def set_object_pose(self, pose: np.ndarray, *, env_ids=None) -> None:
            pass

    class HookDrift(ExplodingBackend):
        def _set_hand_state(self, q, base):  # lost ids
            pass

        def engine_step(self, n=1):
            pass

    class Internal(ExplodingBackend):
        def _restore(self, ids):
            pass

    class Missing(SimBackend):
        name = ""

        def _step(self, n):
            return {}

    assert conformance_problems(DroppedEnvIds) == [
        "DroppedEnvIds.set_hand_state overrides the core's set_hand_state, which checks arguments"
    ]
    assert conformance_problems(SameSignature) == [
        "SameSignature.set_object_pose overrides the core's set_object_pose, which checks arguments"
    ]
    hook, raw = conformance_problems(HookDrift)
    assert hook.startswith("HookDrift._set_hand_state(self, q, base) differs from the interface's (self, q: ")
    assert raw.startswith("HookDrift.engine_step(self, n=1) differs")
    assert conformance_problems(Internal) == ["Internal._restore overrides the core's _restore, which checks arguments"]
    missing = conformance_problems(Missing)
    assert "abstract hook _load_hand not implemented" in missing and "no registry name" in missing[-1]
    assert not any("_step" in m for m in missing)


def test_a_conforming_double_gets_the_cores_checks():
    """The double writes no checks, yet rejects what every backend rejects, with the same messages."""
    sim = ExplodingBackend(SceneConfig(num_envs=2))
    with pytest.raises(ConfigError, match=r"exploding.reset: env ids \[2\] out of range"):
        sim.reset(env_ids=[2])
    with pytest.raises(ArrayError, match=r"exploding.set_object_pose: pose has shape \(7,\), expected \(2, 7\)"):
        sim.set_object_pose(np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]))
