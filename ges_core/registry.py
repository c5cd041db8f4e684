"""The registry: every hand, simulator, expert and gate by name, and how to build them.

A :class:`Registry` is built from a plugin manager and a ``registry.yaml``; it collects specs
through the ``ges_register_*`` hooks, rejects duplicate names (naming both sources) and builds
plugins by name with their per-plugin settings.
"""

from __future__ import annotations

import inspect
import os
import types
import typing
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import pluggy
from pydantic import ConfigDict, TypeAdapter, ValidationError

from ges_core.config import RegistryConfig, parse_overridden, read_yaml
from ges_core.errors import (
    BackendUnavailable,
    ConfigError,
    GesError,
    PluginError,
    RegistrationError,
    UnknownNameError,
    naming_plugin,
)
from ges_core.hand import HandModel
from ges_core.plugins import get_plugin_manager, plugin_sources
from ges_core.sim import SceneConfig, SimBackend
from ges_core.specs import ExpertSpec, GateSpec, HandSpec, PluginSpec, SimSpec

__all__ = ["KINDS", "REGISTRY_ENV", "Registry", "default_registry_path", "load_registry"]

KINDS: dict[str, tuple[str, type[PluginSpec]]] = {
    "hand": ("ges_register_hands", HandSpec),
    "sim": ("ges_register_sims", SimSpec),
    "expert": ("ges_register_experts", ExpertSpec),
    "gate": ("ges_register_gates", GateSpec),
}
"""Kind -> (registration hook, spec class)."""

REGISTRY_ENV = "GES_REGISTRY"
"""Environment variable naming a registry.yaml to use instead of the default."""


def default_registry_path() -> Path | None:
    """``$GES_REGISTRY``, else ``./registry.yaml``, else the repository's own ``registry.yaml``."""
    if os.environ.get(REGISTRY_ENV):
        return Path(os.environ[REGISTRY_ENV])
    for candidate in (Path.cwd() / "registry.yaml", Path(__file__).resolve().parent.parent / "registry.yaml"):
        if candidate.is_file():
            return candidate
    return None


class Registry:
    """Specs of every kind, collected from a plugin manager."""

    def __init__(self, pm: pluggy.PluginManager, config: RegistryConfig | None = None) -> None:
        self.pm = pm
        self.config = config or RegistryConfig()
        self.rebuild: Callable[[], Registry] | None = None
        """A picklable callable building this registry again in another process (a registry does not pickle);
        set by :func:`load_registry`, None for a registry built by hand."""
        self._specs: dict[str, dict[str, PluginSpec]] = {kind: {} for kind in KINDS}
        sources = plugin_sources(pm)
        for kind, (hook_name, spec_cls) in KINDS.items():
            for plugin, caller in _callers_per_plugin(pm, hook_name):
                caller(register=self._registrar(kind, spec_cls, sources[pm.get_name(plugin)]))

    def _registrar(self, kind: str, spec_cls: type[PluginSpec], source: str):
        def register(spec: PluginSpec) -> None:
            if not isinstance(spec, spec_cls):
                raise RegistrationError(f"{source} registered {spec!r} as a {kind}; expected a {spec_cls.__name__}")
            known = self._specs[kind].get(spec.name)
            if known is not None:
                raise RegistrationError(
                    f"two plugins register the {kind} '{spec.name}': {known.source} and {source}; "
                    f"uninstall one, or block one with --no-plugin"
                )
            self._specs[kind][spec.name] = replace(spec, source=source)

        return register

    # -- look-ups -------------------------------------------------------------------------
    def names(self, kind: str) -> list[str]:
        """Registered names of ``kind`` (hand, sim, expert, gate), sorted."""
        return sorted(self._kind(kind))

    def specs(self, kind: str) -> list[PluginSpec]:
        """Registered specs of ``kind``, sorted by name."""
        return [self._kind(kind)[n] for n in self.names(kind)]

    def spec(self, kind: str, name: str | None = None) -> PluginSpec:
        """The spec called ``name`` (the registry.yaml default if None); unknown names list the known ones."""
        name = name or self.default(kind)
        specs = self._kind(kind)
        if name not in specs:
            raise UnknownNameError(kind, name, specs)
        return specs[name]

    def default(self, kind: str) -> str:
        """The default name of ``kind`` from registry.yaml; UnknownNameError if none is set or it names nothing."""
        name = getattr(self.config.defaults, kind, None)
        if not name:
            raise UnknownNameError(kind, "<default>", self.names(kind))
        if name not in self._kind(kind):
            raise UnknownNameError(kind, name, self.names(kind), where=f" in registry.yaml defaults.{kind}")
        return name

    def check_defaults(self, kinds: tuple[str, ...] = tuple(KINDS)) -> None:
        """UnknownNameError for the first default of ``kinds`` that is set but names no registered plugin."""
        for kind in kinds:
            if getattr(self.config.defaults, kind, None):
                self.default(kind)

    def settings(self, kind: str, name: str) -> dict[str, Any]:
        """Factory keyword arguments of one plugin: its spec's tuned defaults, then registry.yaml ``settings``."""
        return {**self.spec(kind, name).settings, **self.config.settings.get(kind, {}).get(name, {})}

    def checked_settings(self, kind: str, name: str) -> dict[str, Any]:
        """:meth:`settings` checked against the factory's signature, as building the plugin checks them (an
        unknown key or a value of the wrong type is the same error), without building it. A plugin whose
        requirements are missing cannot be loaded: its settings come back unchecked."""
        spec = self.spec(kind, name)
        settings = self.settings(kind, spec.name)
        if spec.missing():
            return settings
        return _check_settings(spec, spec.load(), None, settings)

    def _kind(self, kind: str) -> dict[str, PluginSpec]:
        if kind not in self._specs:
            raise UnknownNameError("plugin kind", kind, self._specs)
        return self._specs[kind]

    # -- building -------------------------------------------------------------------------
    def build_hand(self, name: str | None = None) -> HandModel:
        """Build a hand by name (default from registry.yaml)."""
        spec = self.spec("hand", name)
        hand = self._call(spec, spec.load(), **self.settings("hand", spec.name))
        if not isinstance(hand, HandModel):
            raise PluginError(
                f"hand plugin '{spec.name}' ({spec.source}) returned {type(hand).__name__}, not a HandModel"
            )
        return hand

    def build_sim(self, name: str | None = None, scene: SceneConfig | None = None) -> SimBackend:
        """Build a simulator backend by name (default from registry.yaml)."""
        spec = self.spec("sim", name)
        sim = self._call(spec, spec.load(), scene or SceneConfig(), **self.settings("sim", spec.name))
        if not isinstance(sim, SimBackend):
            raise PluginError(
                f"sim plugin '{spec.name}' ({spec.source}) returned {type(sim).__name__}, not a SimBackend"
            )
        return sim

    def build_expert(self, name: str, context: Any, **settings: Any) -> Any:
        """Build expert ``name`` for ``context`` (a :class:`ges_core.policy.ExpertContext`) as
        ``factory(context, **settings)``: the spec's settings, then registry.yaml's, then ``settings``, key by key.
        The expert must fit the context (:func:`ges_core.policy.check_expert_fits`)."""
        from ges_core.policy import Expert, check_expert_fits

        spec = self.spec("expert", name)
        expert = self._call(spec, spec.load(), context, **{**self.settings("expert", spec.name), **settings})
        if not isinstance(expert, Expert):
            raise PluginError(
                f"expert plugin '{spec.name}' ({spec.source}) returned {type(expert).__name__}, not an Expert"
            )
        check_expert_fits(expert, context, who=f"expert '{spec.name}'")
        return expert

    def expert_scope(self, name: str, **settings: Any) -> Any:
        """What expert ``name`` with ``settings`` (over the spec's and registry.yaml's, as :meth:`build_expert`) is
        made for, read without building it (``ExpertSpec.made_for``): a :class:`ges_core.policy.ExpertScope`, or
        None when the expert fits any hand. Its errors (a missing checkpoint) are the build's own."""
        from ges_core.policy import ExpertScope

        spec = self.spec("expert", name)
        if not spec.made_for:
            return None
        reader = replace(spec, entry_point=spec.made_for).load()
        scope = self._call(spec, reader, {**self.settings("expert", spec.name), **settings})
        if scope is not None and not isinstance(scope, ExpertScope):
            raise PluginError(
                f"expert plugin '{spec.name}' ({spec.source}): made_for returned {type(scope).__name__}, not an "
                "ExpertScope or None"
            )
        return scope

    def build_renderer(self, name: str | None = None, config: Any = None) -> Any:
        """A grasp-picture renderer (:class:`ges_core.render.Renderer`) from simulator ``name``'s plugin, or
        from the first simulator, by name, that offers one (``SimSpec.renderer``); config: a RenderConfig or None."""
        from ges_core.render.base import Renderer

        offering = [spec.name for spec in self.specs("sim") if spec.renderer]
        if name is None and not offering:
            raise BackendUnavailable(
                f"no simulator plugin offers a renderer for grasp pictures (simulators: "
                f"{', '.join(self.names('sim')) or 'none'}); install one that does: "
                "pip install 'ges-unigrasp[pybullet]'"
            )
        spec = self.spec("sim", name or offering[0])
        if not spec.renderer:
            raise BackendUnavailable(
                f"simulator '{spec.name}' offers no renderer for grasp pictures; "
                f"those that do: {', '.join(offering) or 'none'}"
            )
        renderer = self._call(spec, replace(spec, entry_point=spec.renderer).load(), config)
        if not isinstance(renderer, Renderer):
            raise PluginError(
                f"sim plugin '{spec.name}' ({spec.source}) returned {type(renderer).__name__}, not a Renderer"
            )
        return renderer

    @staticmethod
    def _call(spec: PluginSpec, factory: Any, *args: Any, **kwargs: Any) -> Any:
        """``factory(*args, **kwargs)``; settings it cannot take, and any non-GesError it raises, name the plugin."""
        kwargs = _check_settings(spec, factory, args, kwargs)
        failed = f"{spec.kind} plugin '{spec.name}' ({spec.source}) failed while building"
        fix = "This is a bug in the plugin; report it to its authors (--debug shows the traceback)"
        with naming_plugin(spec.name, failed, fix, keep=(GesError,)):
            return factory(*args, **kwargs)


def _callers_per_plugin(pm: pluggy.PluginManager, hook_name: str) -> list[tuple[object, Callable[..., Any]]]:
    """(plugin, hook caller limited to that plugin) per plugin implementing ``hook_name``, in pluggy's call order.

    Each call goes through pluggy's hook caller (argument selection, ordering, wrappers, blocked plugins);
    one plugin at a time, so every spec is credited to the plugin that registered it.
    """
    plugins = list(dict.fromkeys(impl.plugin for impl in reversed(getattr(pm.hook, hook_name).get_hookimpls())))
    return [(p, pm.subset_hook_caller(hook_name, [o for o in plugins if o is not p])) for p in plugins]


def _check_settings(spec: PluginSpec, factory: Any, args: tuple | None, kwargs: dict[str, Any]) -> dict[str, Any]:
    """``kwargs`` checked against the factory's signature and converted to its annotations (as a config model's
    fields are: a YAML list becomes a tuple); a setting that does not fit is one error naming its registry entry.
    ``args``: the positional arguments of the call, or None to check the keywords alone (nothing is called)."""
    signature = _signature(factory)
    if signature is None:  # no signature to check (some builtins); the call will tell
        return kwargs
    try:
        bound = signature.bind_partial(**kwargs) if args is None else signature.bind(*args, **kwargs)
    except TypeError as exc:
        raise PluginError(
            f"{spec.kind} '{spec.name}' rejected its settings {sorted(kwargs)}: {exc}. "
            f"Check settings.{spec.kind}.{spec.name} in registry.yaml (or --set)",
            plugin=spec.name,
        ) from exc
    annotations = _setting_annotations(signature, bound)
    return {key: _typed_setting(spec, key, value, annotations.get(key)) for key, value in kwargs.items()}


def _signature(factory: Any) -> inspect.Signature | None:
    """The factory's signature with its annotations evaluated (left as text where they cannot be); None: none."""
    try:
        signature = inspect.signature(factory)
    except (TypeError, ValueError):
        return None
    try:
        return inspect.signature(factory, eval_str=True)
    except Exception:  # noqa: BLE001 - e.g. an annotation naming what is imported only while type checking
        return signature


def _setting_annotations(signature: inspect.Signature, bound: inspect.BoundArguments) -> dict[str, Any]:
    """Keyword -> annotation of the parameter that takes it (a ``**settings: T`` parameter gives T to each)."""
    out: dict[str, Any] = {}
    for name, value in bound.arguments.items():
        param = signature.parameters[name]
        if param.kind is inspect.Parameter.VAR_KEYWORD:
            out.update(dict.fromkeys(value, param.annotation))
        elif param.kind is not inspect.Parameter.VAR_POSITIONAL:
            out[name] = param.annotation
    return out


def _typed_setting(spec: PluginSpec, key: str, value: Any, annotation: Any) -> Any:
    """``value`` validated against ``annotation`` (unchanged where there is none, or it is not a type)."""
    if annotation in (None, inspect.Parameter.empty, Any) or isinstance(annotation, str):
        return value
    try:
        adapter = TypeAdapter(annotation, config=ConfigDict(arbitrary_types_allowed=True))
    except Exception:  # noqa: BLE001 - an annotation pydantic cannot check; the factory will
        return value
    try:
        return adapter.validate_python(value)
    except ValidationError as exc:
        why = "; ".join(dict.fromkeys(err["msg"] for err in exc.errors()))
        raise ConfigError(
            f"{spec.kind} '{spec.name}': setting {key}={value!r} is not {_type_name(annotation)} ({why}). "
            f"Fix settings.{spec.kind}.{spec.name}.{key} in registry.yaml (or --set)"
        ) from None


def _type_name(annotation: Any) -> str:
    """``float | None`` for the annotation ``float | None`` (or ``Optional[float]``), ``int`` for ``int``."""
    if annotation is type(None):
        return "None"
    if isinstance(annotation, type) and not typing.get_args(annotation):
        return annotation.__name__
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        return " | ".join(_type_name(a) for a in args)
    if origin is typing.Annotated:
        return _type_name(args[0])
    return str(annotation).replace("typing.", "")


def load_registry(
    path: str | Path | None = None,
    *,
    overrides: tuple[str, ...] = (),
    blocked: tuple[str, ...] = (),
    autoload: bool | None = None,
) -> Registry:
    """Read registry.yaml (default: :func:`default_registry_path`), discover plugins, collect specs."""
    path = Path(path) if path is not None else default_registry_path()
    data = read_yaml(path) if path is not None else {}
    config = parse_overridden(RegistryConfig, data, overrides, where=str(path or "registry"), flag="--set")
    base_dir = path.resolve().parent if path is not None else Path.cwd()
    pm = get_plugin_manager(local_plugins=config.plugins, base_dir=base_dir, blocked=blocked, autoload=autoload)
    registry = Registry(pm, config)
    registry.rebuild = partial(
        load_registry, path, overrides=tuple(overrides), blocked=tuple(blocked), autoload=autoload
    )
    return registry
