"""The built-in plugins: which modules they are, and how a checkout that was not pip-installed finds them.

The folder ``plugins/`` beside ``ges_core/`` installs as the import package ``ges_plugins`` (``setup.py``
maps it; a top-level ``plugins`` in site-packages would collide with other projects). In a plain checkout
(``PYTHONPATH=checkout``) nothing maps that name, so :func:`import_builtin` first registers the folder as
the package ``ges_plugins``, the same modules under the same names an install gives.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from ges_core import __version__
from ges_core.errors import PluginError, naming_plugin

__all__ = [
    "BUILTIN_PACKAGE",
    "BUILTIN_PLUGINS",
    "CHECKOUT_FOLDER",
    "builtin_source",
    "import_builtin",
    "module_from_file",
]

BUILTIN_PLUGINS: dict[str, str] = {
    "shadow": "ges_plugins.hands.shadow",
    "allegro": "ges_plugins.hands.allegro",
    "sapien": "ges_plugins.sims.sapien",
    "pybullet": "ges_plugins.sims.pybullet",
    "curvenet": "ges_plugins.gates.curvenet",
    "pointnet2": "ges_plugins.gates.pointnet2",
    "centroid": "ges_plugins.gates.centroid",
    "scripted": "ges_plugins.experts.scripted",
    "ppo": "ges_plugins.experts.ppo",
}
"""Plugin name -> registration module of every built-in plugin, registered first and in this order."""

BUILTIN_PACKAGE = "ges_plugins"
"""Import name of the built-in plugins (the folder ``plugins/``)."""

CHECKOUT_FOLDER = Path(__file__).resolve().parent.parent / "plugins"
"""Where a checkout keeps the built-in plugins (unused once ``ges_plugins`` is installed)."""


def builtin_source(name: str) -> str:
    """How ``ges list`` names a built-in plugin's origin."""
    return f"{name} (built-in, ges-unigrasp {__version__})"


def import_builtin(name: str) -> ModuleType:
    """Import the registration module of the built-in plugin ``name``; failures name the plugin."""
    module_name = BUILTIN_PLUGINS[name]
    failed = f"built-in plugin '{name}' ({module_name}) failed to import"
    with naming_plugin(name, failed, f"Reinstall ges-unigrasp, or skip it with --no-plugin {name}"):
        _ensure_package()
        return importlib.import_module(module_name)


def _ensure_package() -> None:
    """Make ``ges_plugins`` importable: installed as such, else the checkout's ``plugins/`` under that name."""
    if BUILTIN_PACKAGE in sys.modules or importlib.util.find_spec(BUILTIN_PACKAGE) is not None:
        return
    init = CHECKOUT_FOLDER / "__init__.py"
    if not init.is_file():
        raise PluginError(
            f"the built-in plugins are missing: no package '{BUILTIN_PACKAGE}' is installed and there is no "
            f"{init}; reinstall ges-unigrasp (pip install 'ges-unigrasp[all]')"
        )
    module_from_file(BUILTIN_PACKAGE, init, package=True)


def module_from_file(name: str, path: Path, *, package: bool = False) -> ModuleType:
    """Import the file ``path`` as the module ``name`` (a package rooted at its folder if ``package``).

    The module is in ``sys.modules`` while it runs (so it can import itself) and taken out again if it fails.
    """
    search = [str(path.parent)] if package else None
    spec = importlib.util.spec_from_file_location(name, path, submodule_search_locations=search)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    return module
