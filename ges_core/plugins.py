"""Building the plugin manager: discovery in a fixed, documented order.

1. The built-in plugins of :data:`ges_core.builtins.BUILTIN_PLUGINS` (hands and simulators shipped in
   ``plugins/``), found even in a checkout that was not pip-installed.
2. The entry-point group ``ges.plugins`` through pluggy's ``load_setuptools_entrypoints``: every
   installed third-party package. ``GES_DISABLE_PLUGIN_AUTOLOAD=1`` (or ``autoload=False``) skips them.
3. Local plugins named in ``registry.yaml``: a dotted module (``pkg.mod``) or a ``.py`` file.
4. ``pm.check_pending()``: a misspelled hook implementation fails here, not silently.

``--no-plugin NAME`` (``blocked``) skips a plugin of any of the three sources. There is no plugin manager
at import time: call :func:`get_plugin_manager`.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import os
from collections.abc import Iterable
from pathlib import Path
from types import ModuleType

import pluggy

from ges_core import hookspecs
from ges_core.builtins import BUILTIN_PLUGINS, builtin_source, import_builtin, module_from_file
from ges_core.errors import PluginError, naming_plugin

__all__ = ["AUTOLOAD_ENV", "ENTRY_POINT_GROUP", "OWN_DISTRIBUTION", "get_plugin_manager", "plugin_sources"]

ENTRY_POINT_GROUP = "ges.plugins"
"""Entry-point group that third-party plugins declare."""
OWN_DISTRIBUTION = "ges-unigrasp"
"""This project's distribution name; it declares no entry points (its plugins are built-ins)."""
AUTOLOAD_ENV = "GES_DISABLE_PLUGIN_AUTOLOAD"
"""Set to 1 to skip third-party entry points."""


def get_plugin_manager(
    *,
    local_plugins: Iterable[str] = (),
    base_dir: Path | None = None,
    blocked: Iterable[str] = (),
    autoload: bool | None = None,
) -> pluggy.PluginManager:
    """A fresh plugin manager with every plugin discovered and checked.

    local_plugins: registry.yaml ``plugins`` entries; file paths are relative to ``base_dir``.
    blocked: plugin names not to load (the CLI's ``--no-plugin``): built-in, entry point or local entry.
    autoload: load third-party entry points; default: unless ``GES_DISABLE_PLUGIN_AUTOLOAD=1``.
    """
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    for name in blocked:
        pm.set_blocked(name)
    if autoload is None:
        autoload = os.environ.get(AUTOLOAD_ENV, "") not in ("1", "true", "yes")
    _load_builtins(pm)
    if autoload:
        _load_entry_points(pm)
    for ref in local_plugins:
        _load_local_plugin(pm, ref, base_dir or Path.cwd())
    try:
        pm.check_pending()
    except pluggy.PluginValidationError as exc:
        raise PluginError(f"plugin '{pm.get_name(exc.plugin)}' has an invalid hook: {exc}") from exc
    return pm


def plugin_sources(pm: pluggy.PluginManager) -> dict[str, str]:
    """Plugin name -> where it came from (built-in, ``dist-name version`` or ``local``)."""
    sources = {name: f"{name} (local)" for name, _ in pm.list_name_plugin()}
    sources.update({name: builtin_source(name) for name in BUILTIN_PLUGINS if name in sources})
    for plugin, dist in pm.list_plugin_distinfo():
        sources[pm.get_name(plugin)] = f"{pm.get_name(plugin)} from {dist.metadata['name']} {dist.version}"
    return sources


def _load_builtins(pm: pluggy.PluginManager) -> None:
    for name in BUILTIN_PLUGINS:
        if not pm.is_blocked(name):
            pm.register(import_builtin(name), name=name)


def _entry_points() -> list[importlib.metadata.EntryPoint]:
    return list(importlib.metadata.entry_points(group=ENTRY_POINT_GROUP))


def _dist_name(ep: importlib.metadata.EntryPoint) -> str:
    return ep.dist.metadata["name"] if ep.dist is not None else "?"


def _load_entry_points(pm: pluggy.PluginManager) -> None:
    seen: dict[str, str] = {}
    for ep in _entry_points():
        dist = _dist_name(ep)
        if dist == OWN_DISTRIBUTION:
            continue  # an older install's entry points for what are built-ins now
        _check_name(ep.name, dist, seen)
        if pm.is_blocked(ep.name):
            continue
        failed = f"plugin '{ep.name}' (package {dist}) failed to import"
        with naming_plugin(ep.name, failed, f"Fix or uninstall it, or skip it with --no-plugin {ep.name}", keep=()):
            pm.load_setuptools_entrypoints(ENTRY_POINT_GROUP, name=ep.name)


def _check_name(name: str, dist: str, seen: dict[str, str]) -> None:
    """An entry-point name is claimed once: by one package, and by no built-in."""
    if name in BUILTIN_PLUGINS:
        raise PluginError(
            f"package {dist} declares the plugin '{name}', the name of a built-in plugin; "
            f"rename its entry point, or uninstall it",
            plugin=name,
        )
    if name in seen and seen[name] != dist:
        raise PluginError(
            f"two packages declare the plugin '{name}': {seen[name]} and {dist}; uninstall one of them", plugin=name
        )
    seen[name] = dist


def _load_local_plugin(pm: pluggy.PluginManager, ref: str, base_dir: Path) -> None:
    name = f"local:{ref}"
    if pm.is_blocked(ref) or pm.has_plugin(name):
        return
    failed = f"local plugin '{ref}' from registry.yaml failed to import"
    with naming_plugin(ref, failed, "Fix it, or remove it from registry.yaml's plugins"):
        module = _import_file(ref, base_dir) if ref.endswith(".py") else importlib.import_module(ref)
    pm.register(module, name=name)


def _import_file(ref: str, base_dir: Path) -> ModuleType:
    path = Path(ref) if Path(ref).is_absolute() else base_dir / ref
    if not path.is_file():
        raise PluginError(f"local plugin file '{ref}' not found (looked at {path})", plugin=ref)
    module_name = f"ges_local_plugin_{path.stem}_{abs(hash(str(path.resolve()))):x}"
    return module_from_file(module_name, path)
