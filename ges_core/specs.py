"""Registry entries: frozen specs with a lazy ``"module:Attr"`` entry point.

Listing specs imports nothing heavy; :meth:`PluginSpec.load` imports the factory when a
plugin is built, so ``ges list`` works even where an engine is not installed.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any, ClassVar

from ges_core.errors import BackendUnavailable, PluginError

__all__ = ["ExpertSpec", "GateSpec", "HandSpec", "PluginSpec", "SimSpec", "resolve_entry_point"]


def resolve_entry_point(target: str) -> Any:
    """Import ``"package.module:Attr.Nested"`` and return the attribute."""
    module_name, sep, attr_path = target.partition(":")
    if not sep or not module_name or not attr_path:
        raise PluginError(f"entry point '{target}' must look like 'package.module:Attr'")
    try:
        obj: Any = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        raise BackendUnavailable(f"cannot import '{module_name}' for '{target}': {exc}") from exc
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
    source: str = ""
    """Who registered it (filled by the registry: plugin name and distribution)."""

    def load(self) -> Any:
        """Import and return the factory."""
        return resolve_entry_point(self.entry_point)


@dataclass(frozen=True, kw_only=True)
class HandSpec(PluginSpec):
    """A hand plugin; the factory returns a :class:`ges_core.hand.HandModel`."""

    kind: ClassVar[str] = "hand"


@dataclass(frozen=True, kw_only=True)
class SimSpec(PluginSpec):
    """A simulator plugin; the factory is called ``factory(scene_config, **settings)`` -> SimBackend."""

    kind: ClassVar[str] = "sim"
    requires: tuple[str, ...] = ()
    """Importable module names the engine needs (checked by ``ges list``)."""


@dataclass(frozen=True, kw_only=True)
class ExpertSpec(PluginSpec):
    """An expert plugin; the factory returns a :class:`ges_core.policy.Expert`."""

    kind: ClassVar[str] = "expert"


@dataclass(frozen=True, kw_only=True)
class GateSpec(PluginSpec):
    """A gate plugin; the factory returns a :class:`ges_core.policy.Gate`."""

    kind: ClassVar[str] = "gate"
