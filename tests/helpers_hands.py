"""Hands for tests: the example gripper (tests/data/ges_example_hand) with a concave L-shaped palm mesh (a hand whose
collision mesh stands far inside its convex hull, for the hull checks and ``ges hand prepare``), and a local plugin
registering a hand package from the repository's source (the suite installs none of ``examples/``)."""

from __future__ import annotations

from pathlib import Path

from conftest import EXAMPLE_HAND_PKG

SRC = EXAMPLE_HAND_PKG / "ges_example_hand"
PALM_BOX = (
    '<collision><origin xyz="0.04 0 0" rpy="0 0 0"/><geometry><box size="0.08 0.08 0.02"/></geometry></collision>'
)
"""The example gripper's palm collision, replaced by the L mesh."""


def write_l_palm(folder: Path, suffix: str = ".obj") -> str:
    """Write the L palm mesh (``palm_l<suffix>``) into ``folder``; returns its ``<collision>`` element.

    The gripper's slab, a thin floor under the fingers and a post beyond their tips: the L's convex hull spans over
    both fingers' distal links (6-7 mm off the real mesh at the open pose) and stands tens of mm off the floor.
    """
    import trimesh

    parts = [([0.08, 0.08, 0.02], [0.04, 0, 0]), ([0.09, 0.08, 0.005], [0.125, 0, -0.0075]),
             ([0.01, 0.08, 0.045], [0.165, 0, 0.0125])]  # fmt: skip
    palm = trimesh.util.concatenate([trimesh.creation.box(extents=e).apply_translation(c) for e, c in parts])
    palm.export(folder / f"palm_l{suffix}")
    return f'<collision><geometry><mesh filename="palm_l{suffix}"/></geometry></collision>'


def write_l_palm_hand(folder: Path, suffix: str = ".obj") -> Path:
    """The example gripper with the L palm (``hand.urdf`` + ``hand.yaml`` in ``folder``); returns the YAML path."""
    urdf = (SRC / "gripper.urdf").read_text()
    assert PALM_BOX in urdf
    (folder / "hand.urdf").write_text(urdf.replace(PALM_BOX, write_l_palm(folder, suffix), 1))
    (folder / "hand.yaml").write_text((SRC / "gripper.yaml").read_text())
    return folder / "hand.yaml"


SOURCE_PLUGIN = """
import importlib.util
from ges_core import hookimpl
from ges_core.specs import HandSpec

def build(**settings):
    spec = importlib.util.spec_from_file_location("_{name}_source", {source!r})
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.build_hand(**settings)

@hookimpl
def ges_register_hands(register):
    register(HandSpec(name={name!r}, entry_point="{name}_plugin:build", description="{name} from source"))
"""


def write_source_plugin(folder: Path, name: str, package_init: Path) -> Path:
    """A local plugin ``<name>_plugin.py`` registering hand ``name`` built by the package whose ``__init__.py`` is
    ``package_init`` (its ``build_hand``), and a ``registry.yaml`` loading it, both in ``folder``; returns the registry
    path. The caller puts ``folder`` on ``sys.path`` (the entry point's module). ``name`` should differ from the
    package's own registered name, which an installed copy would also claim."""
    (folder / f"{name}_plugin.py").write_text(SOURCE_PLUGIN.format(name=name, source=str(package_init)))
    registry = folder / "registry.yaml"
    registry.write_text(f"plugins: [{name}_plugin.py]\n")
    return registry
