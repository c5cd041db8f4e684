"""SAPIEN, imported without its warning about the system's Vulkan loader.

``import sapien`` (3.0.3) looks for a system ``libvulkan`` and, on a machine without one (every
CPU-only machine here), warns "Failed to find system libvulkan. Fallback to SAPIEN builtin
libvulkan." The CPU PhysX path this plugin uses never touches Vulkan, so the warning says nothing
to our users; it is filtered for the import only, by its message, and every other warning still
shows. Every module of this plugin imports ``sapien`` through here, so the first import is this one.
"""

from __future__ import annotations

import warnings

__all__ = ["VULKAN_WARNING", "sapien"]

VULKAN_WARNING = "Failed to find system libvulkan"
"""Start of the one warning filtered (a regular expression matched at the message's start)."""

with warnings.catch_warnings():
    warnings.filterwarnings("ignore", message=VULKAN_WARNING, category=UserWarning)
    import sapien
