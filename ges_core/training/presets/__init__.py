"""Training presets: ``<name>.yaml`` files read by :mod:`ges_core.training.config` (a package so that the
wheel carries them as package data; nothing to import here)."""
