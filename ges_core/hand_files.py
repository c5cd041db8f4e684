"""A hand defined by two files, a URDF and a description YAML: the quickest way to add a hand.

Use it from a local plugin::

    @hookimpl
    def ges_register_hands(register):
        register(HandSpec(name="my_hand", entry_point="my_lab.hands:build_my_hand"))

    def build_my_hand(**settings):
        return FileHand(HERE / "my_hand.yaml", HERE / "my_hand.urdf", **settings)
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

from ges_core.errors import AssetError, BackendUnavailable
from ges_core.hand import HandDescription, HandModel
from ges_core.hand_prep.mimic import add_mimic_couplings
from ges_core.hand_yaml import description_from_yaml

__all__ = ["FileHand", "installed_file"]


def installed_file(
    package: str, relpath: str, *, what: str, distribution: str, install: str, version: str = ""
) -> Path:
    """A file shipped inside the installed import package ``package`` (e.g. a hand URDF inside ``mani_skill``), found
    without importing it: importing mani-skill takes 2-3 s and pulls in SAPIEN, in every process that builds the hand.

    what: who needs it, for messages ("the 'allegro' hand"); distribution, version: the pip name and pinned version;
    install: the command that installs it. BackendUnavailable when the package is missing, AssetError when the file is.
    """
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        pinned = f" ({version})" if version else ""
        raise BackendUnavailable(f"{what} needs the {distribution} package{pinned}: {install}")
    path = Path(list(spec.submodule_search_locations)[0]) / relpath
    if not path.is_file():
        raise AssetError(f"{what}: {path} is missing; reinstall {distribution}{'==' + version if version else ''}")
    return path


class FileHand(HandModel):
    """A hand read from ``description.yaml`` + ``model.urdf``, the URDF as it comes (mani-skill, a ROS
    robot-description package, a CAD export): meshes in any format trimesh reads, relative or
    ``package://`` paths, ``<material>`` tags and ``<mimic>`` joints are all fine. Each ``<mimic>`` becomes a
    coupling (``q = multiplier * q_leader + offset``) unless the YAML couples that joint itself; the
    simulators convert what they cannot load (:mod:`ges_core.hand_prep`)."""

    def __init__(self, yaml_path: str | Path, urdf_path: str | Path, *, strict: bool = True, **overrides: Any) -> None:
        self._yaml_path, self._urdf_path = Path(yaml_path), Path(urdf_path)
        for path in (self._yaml_path, self._urdf_path):
            if not path.is_file():
                raise AssetError(f"hand file {path} does not exist")
        urdf_text = self._urdf_path.read_text()
        description = description_from_yaml(
            self._yaml_path.read_text(), urdf_text, strict=strict, source=str(self._yaml_path), **overrides
        )
        self._description = add_mimic_couplings(description, urdf_text)

    @property
    def description(self) -> HandDescription:
        """The description read from the YAML file."""
        return self._description

    def urdf_path(self) -> Path:
        """The URDF file as given."""
        return self._urdf_path
