"""Package layout beside pyproject.toml (which holds everything else).

The built-in plugins live in the folder ``plugins/`` (``plugins/hands/``, ``plugins/sims/``, ...) but
install as the import package ``ges_plugins``: a top-level ``plugins`` in site-packages would collide
with any other project's. ``ges_core.builtins`` gives a checkout that was not pip-installed the same name.
"""

from setuptools import find_packages, setup

core = find_packages(include=["ges_core", "ges_core.*"])
builtin = ["ges_plugins" + name[len("plugins") :] for name in find_packages(include=["plugins", "plugins.*"])]
setup(packages=core + builtin, package_dir={"ges_plugins": "plugins"})
