"""GES-UniGrasp core: interfaces, plugin registry, contact representation, config and CLI.

The core never imports a simulator or a concrete hand; those arrive as plugins.
"""

from ges_core.hookspecs import hookimpl, hookspec

__all__ = ["__version__", "hookimpl", "hookspec"]

__version__ = "0.1.0"
