"""The Shadow hand's source files (from gymnasium-robotics) and the cached URDF made from them.

Source: ``gymnasium_robotics/envs/assets/hand/robot.xml`` (MIT licence, ``envs/assets/LICENSE.md``),
a fragment without ``<worldbody>`` whose classes and meshes live in ``shared.xml`` and
``shared_asset.xml``; STL meshes in ``envs/assets/stls/hand/``. :func:`wrapper_mjcf` includes the
three files into a complete model that MuJoCo compiles; :func:`cached_urdf` converts it once per
set of source and converter bytes and keeps the result under
``$GES_CACHE_DIR/hands/shadow/<key>/``.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from ges_core.errors import AssetError
from ges_core.paths import atomic_write_text, cache_dir, file_sha256
from ges_core.urdf import absolutize_mesh_paths

__all__ = [
    "CONVERTER_FILES",
    "HAND_XML_FILES",
    "ROOT_BODY",
    "cached_contact_pairs",
    "cached_urdf",
    "compile_model",
    "default_asset_dir",
    "source_files",
    "source_key",
    "wrapper_mjcf",
]

HAND_XML_FILES: tuple[str, ...] = ("hand/robot.xml", "hand/shared.xml", "hand/shared_asset.xml")
"""MJCF files of the hand, relative to gymnasium-robotics' ``envs/assets`` folder."""
MESH_DIR = "stls/hand"
"""STL folder, relative to ``envs/assets``."""
ROOT_BODY = "robot0:forearm"
"""Exported root body: the forearm. The MJCF's ``robot0:hand mount`` (0.1 kg mounting plate that
places the hand in gymnasium's scene) is left out."""
URDF_NAME = "shadow.urdf"
PAIRS_NAME = "contact_pairs.json"
"""The MJCF's ``<contact><pair>`` link pairs, beside the URDF (:func:`cached_contact_pairs`)."""
CONVERTER_FILES: tuple[Path, ...] = (Path(__file__), Path(__file__).with_name("convert.py"))
"""Their bytes are part of the cache key, so editing the converter invalidates old URDFs."""
INSTALL_HINT = "pip install 'ges-unigrasp[shadow]'"


def default_asset_dir() -> Path:
    """gymnasium-robotics' ``envs/assets`` folder, found without importing the package."""
    spec = importlib.util.find_spec("gymnasium_robotics")
    if spec is None or not spec.submodule_search_locations:
        raise AssetError(
            f"the Shadow hand needs the MJCF files of gymnasium-robotics, which is not installed: {INSTALL_HINT}"
        )
    return Path(next(iter(spec.submodule_search_locations))) / "envs" / "assets"


def _require(path: Path) -> Path:
    if not path.is_file():
        raise AssetError(
            f"Shadow hand asset {path} is missing; it ships with gymnasium-robotics: {INSTALL_HINT} "
            "(or pass asset_dir= pointing at a folder laid out like gymnasium_robotics/envs/assets)"
        )
    return path


def _mesh_files(asset_dir: Path) -> list[Path]:
    """STL files named by ``shared_asset.xml``'s ``<mesh file=...>``, in file order."""
    text = _require(asset_dir / "hand" / "shared_asset.xml").read_text()
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise AssetError(f"{asset_dir / 'hand' / 'shared_asset.xml'} is not valid XML: {exc}") from exc
    return [asset_dir / MESH_DIR / mesh.get("file", "") for mesh in root.iter("mesh")]


def source_files(asset_dir: Path) -> list[Path]:
    """Every file the conversion reads (three MJCF files, then the STL meshes); AssetError if one is missing."""
    xml_files = [_require(asset_dir / name) for name in HAND_XML_FILES]
    return xml_files + [_require(path) for path in _mesh_files(asset_dir)]


def source_key(files: list[Path], asset_dir: Path) -> str:
    """16 hex digits of SHA-256 over the converter's code and each source file's relative path and content."""
    digest = hashlib.sha256()
    for path in CONVERTER_FILES:
        digest.update(f"converter {path.name} {file_sha256(path, length=64)}\n".encode())
    for path in files:
        digest.update(f"{path.relative_to(asset_dir).as_posix()} {file_sha256(path, length=64)}\n".encode())
    return digest.hexdigest()[:16]


def wrapper_mjcf(asset_dir: Path) -> str:
    """A complete MJCF that includes the hand fragment (absolute paths; angles in radians as in gymnasium)."""
    hand = (asset_dir / "hand").resolve()
    return f"""<mujoco model="shadow_hand">
  <compiler angle="radian" meshdir="{(asset_dir / MESH_DIR).resolve()}"/>
  <include file="{hand / "shared.xml"}"/>
  <asset>
    <include file="{hand / "shared_asset.xml"}"/>
  </asset>
  <worldbody>
    <include file="{hand / "robot.xml"}"/>
  </worldbody>
</mujoco>
"""


def compile_model(asset_dir: Path | None = None) -> Any:
    """MuJoCo's compiled ``MjModel`` of the hand (the converter's ground truth)."""
    import mujoco

    asset_dir = Path(asset_dir) if asset_dir is not None else default_asset_dir()
    source_files(asset_dir)
    try:
        return mujoco.MjModel.from_xml_string(wrapper_mjcf(asset_dir))
    except ValueError as exc:  # mujoco reports XML and compile errors as ValueError
        raise AssetError(f"MuJoCo cannot compile the Shadow hand from {asset_dir}: {exc}") from exc


def cached_urdf(asset_dir: Path | None = None) -> Path:
    """Path of the converted URDF, converting on first use (meshes first, the URDF last, each atomic).

    The folder is keyed by :func:`source_key`: later calls with unchanged sources reuse the file
    untouched; changed sources (or converter code) produce a new folder.
    """
    asset_dir = Path(asset_dir) if asset_dir is not None else default_asset_dir()
    folder = cache_dir("hands", "shadow", source_key(source_files(asset_dir), asset_dir))
    target = folder / URDF_NAME
    if target.is_file():
        return target
    from ges_plugins.hands.shadow.convert import (  # imports mujoco
        collision_meshes_from_mjmodel,
        contact_pairs_from_mjmodel,
        urdf_from_mjmodel,
    )

    model = compile_model(asset_dir)
    for name, text in collision_meshes_from_mjmodel(model, root_body=ROOT_BODY).items():
        atomic_write_text(folder / name, text)
    atomic_write_text(folder / PAIRS_NAME, json.dumps([list(pair) for pair in contact_pairs_from_mjmodel(model)]))
    urdf = absolutize_mesh_paths(urdf_from_mjmodel(model, root_body=ROOT_BODY), folder)
    return atomic_write_text(target, urdf)


def cached_contact_pairs(asset_dir: Path | None = None) -> list[tuple[str, str]]:
    """The link pairs the MJCF lets collide with each other (its ``<contact><pair>`` list; every other hand-hand pair
    it turns off with ``contype=1, conaffinity=0``), converted and cached with the URDF (:func:`cached_urdf`)."""
    path = cached_urdf(asset_dir).with_name(PAIRS_NAME)
    try:
        pairs = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise AssetError(f"{path}: the Shadow hand's cached contact pairs cannot be read ({exc}); delete its folder "
                         f"{path.parent} and it is converted again") from exc  # fmt: skip
    return [(str(a), str(b)) for a, b in pairs]
