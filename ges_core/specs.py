"""Registry entries: frozen specs with a lazy ``"module:Attr"`` entry point.

Listing specs imports nothing heavy; :meth:`PluginSpec.load` imports the factory when a
plugin is built, so ``ges list`` works even where an engine is not installed.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from ges_core.errors import BackendUnavailable, PluginError

__all__ = ["ExpertSpec", "GateSpec", "HandSpec", "PluginSpec", "SimSpec", "resolve_entry_point"]


def resolve_entry_point(target: str) -> Any:
    """Import ``"package.module:Attr.Nested"`` and return the attribute.

    A malformed target or a missing attribute is a :class:`PluginError`; whatever the import itself
    raises propagates unchanged (:meth:`PluginSpec.load` says which plugin it was).
    """
    module_name, sep, attr_path = target.partition(":")
    if not sep or not module_name or not attr_path:
        raise PluginError(f"entry point '{target}' must look like 'package.module:Attr'")
    obj: Any = importlib.import_module(module_name)
    for part in attr_path.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError as exc:
            raise PluginError(f"entry point '{target}': module '{module_name}' has no '{attr_path}'") from exc
    return obj


@dataclass(frozen=True, kw_only=True)
class PluginSpec:
    """One named thing a plugin provides."""

    kind: ClassVar[str] = "plugin"
    name: str
    """Unique name within its kind (``shadow``, ``sapien`` ...)."""
    entry_point: str
    """``"module:Attr"`` of a factory called as ``factory(**settings)``."""
    description: str = ""
    """One line for ``ges list``."""
    requires: tuple[str, ...] = ()
    """Top-level modules the plugin needs beyond the core (its engine or assets); ``ges list`` checks them."""
    install: str = ""
    """What installs ``requires``, shown when one is missing: ``pip install 'ges-unigrasp[pybullet]'``."""
    settings: Mapping[str, Any] = field(default_factory=dict, hash=False)
    """Default factory keyword arguments (the plugin's tuned values); registry.yaml ``settings`` override
    them key by key. Read-only."""
    source: str = ""
    """Who registered it (filled by the registry: plugin name and distribution)."""

    def missing(self) -> list[str]:
        """The modules of ``requires`` that are not installed (found without importing them)."""
        return [name for name in self.requires if importlib.util.find_spec(name) is None]

    def load(self) -> Any:
        """Import and return the factory; a missing required module is ``BackendUnavailable``, any other
        import failure a ``PluginError`` naming this plugin."""
        self._check_installed(self.missing())
        try:
            return resolve_entry_point(self.entry_point)
        except PluginError:
            raise
        except ModuleNotFoundError as exc:  # a required module that find_spec saw but cannot import
            self._check_installed([m for m in self.requires if m == (exc.name or "").partition(".")[0]])
            raise self._import_error(exc) from exc
        except Exception as exc:  # noqa: BLE001 - a plugin may raise anything; we name it
            raise self._import_error(exc) from exc

    def _check_installed(self, missing: list[str]) -> None:
        if missing:
            how = self.install or f"install the package{'s' if len(missing) > 1 else ''} providing it"
            raise BackendUnavailable(
                f"{self.kind} '{self.name}' needs {', '.join(repr(m) for m in missing)}, not installed here: {how}"
            )

    def _import_error(self, exc: Exception) -> PluginError:
        where = f" ({self.source})" if self.source else ""
        return PluginError(
            f"{self.kind} '{self.name}'{where} failed to import {self.entry_point}: {type(exc).__name__}: {exc}. "
            f"Fix or reinstall the plugin that provides it",
            plugin=self.name,
        )


@dataclass(frozen=True, kw_only=True)
class HandSpec(PluginSpec):
    """A hand plugin; the factory returns a :class:`ges_core.hand.HandModel`."""

    kind: ClassVar[str] = "hand"


@dataclass(frozen=True, kw_only=True)
class SimSpec(PluginSpec):
    """A simulator plugin; the factory is called ``factory(scene_config, **settings)`` -> SimBackend."""

    kind: ClassVar[str] = "sim"
    renderer: str = ""
    """``"module:Attr"`` of the engine's grasp-picture renderer, called ``factory(config)`` with a
    :class:`ges_core.render.RenderConfig` or None -> :class:`ges_core.render.Renderer`; empty: none
    (:meth:`ges_core.registry.Registry.build_renderer`)."""


@dataclass(frozen=True, kw_only=True)
class ExpertSpec(PluginSpec):
    """An expert plugin; the factory returns a :class:`ges_core.policy.Expert`."""

    kind: ClassVar[str] = "expert"
    made_for: str = ""
    """``"module:Attr"`` of a function ``f(settings) -> ExpertScope | None`` saying what an expert built with
    ``settings`` (the merged factory keyword arguments) is made for, read without building it (a trained
    checkpoint's hand and layouts); empty or None: it fits any hand (:meth:`ges_core.registry.Registry.expert_scope`).
    """


@dataclass(frozen=True, kw_only=True)
class GateSpec(PluginSpec):
    """A gate plugin; the factory returns a :class:`ges_core.policy.Gate`."""

    kind: ClassVar[str] = "gate"
