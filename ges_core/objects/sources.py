"""Where objects come from: procedural categories, pybullet_data meshes, the real set (:mod:`.real`) and a user
folder.

Listing reads no mesh: an :class:`ObjectEntry` says how to build or load one object, and the
library turns it into a mesh on demand.
"""

from __future__ import annotations

import importlib.util
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from ges_core.errors import AssetError, ConfigError
from ges_core.objects.procedural import CATEGORIES
from ges_core.objects.properties import ObjectProperties, read_objects_file
from ges_core.objects.validate import MESH_SUFFIXES

__all__ = [
    "CLASSICS",
    "SOURCES",
    "ObjectEntry",
    "list_procedural",
    "list_pybullet",
    "list_user",
    "pybullet_data_dir",
    "urdf_mesh",
]

Source = Literal["procedural", "pybullet", "real", "user"]
SOURCES: tuple[Source, ...] = ("procedural", "pybullet", "real", "user")


@dataclass(frozen=True, kw_only=True)
class ObjectEntry:
    """How to obtain one object; no geometry yet."""

    object_id: str
    """Stable id: ``procedural/mug/003``, ``pybullet/random_urdfs/042``, ``real/can/tomato_soup_can``,
    ``user/<category>/<instance>``."""
    category: str
    source: Source
    path: Path | None = None
    """Source mesh file (pybullet, user)."""
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Per-axis scale taking the file's units to metres (from the URDF, or chosen; see CLASSICS)."""
    index: int = 0
    """Instance number within the category (procedural)."""
    seed: int = 0
    """Library seed (procedural)."""
    mass: float | None = None
    """kg, the object's own mass (real set, a user's ``objects.yaml``); None: the library's density decides."""
    density: float | None = None
    """kg/m^3 of this object (a user's ``objects.yaml``); None: the library's."""
    friction: float | None = None
    """Friction coefficient of this object (a user's ``objects.yaml``); None: the library's."""
    rest: str | None = None
    """How it rests on the table (:data:`.properties.Rest`; a user's ``objects.yaml``, or the library's
    ``object_properties``); None: ``stable``."""
    problem: str | None = None
    """Why this object cannot be used, found while listing (two files give its id); processing it raises an
    AssetError with this reason. Listed rather than dropped, so that the rest of its folder stays usable and
    the problem is reported where the object is asked for."""


def list_procedural(*, count: int, seed: int, categories: tuple[str, ...] | None = None) -> list[ObjectEntry]:
    """``count`` objects per procedural category (all by default), ids ``procedural/<cat>/<NNN>``."""
    unknown = sorted(set(categories or ()) - set(CATEGORIES))
    if unknown:
        raise ConfigError(f"unknown procedural categories {unknown}; known: {', '.join(CATEGORIES)}")
    return [
        ObjectEntry(object_id=f"procedural/{cat}/{i:03d}", category=cat, source="procedural", index=i, seed=seed)
        for cat in (categories or tuple(CATEGORIES))
        for i in range(count)
    ]


@dataclass(frozen=True)
class _Classic:
    file: str
    scale: float
    why: str


CLASSICS: dict[str, _Classic] = {
    "bunny": _Classic("bunny.obj", 0.05, "no URDF ships it; 0.05 gives 4.6 x 7.2 x 9.9 cm"),
    "duck": _Classic("duck.obj", 0.05, "duck_vhacd.urdf: scale .05 (8.3 x 7.7 x 5.8 cm)"),
    "teddy": _Classic("teddy2_VHACD_CHs.obj", 0.1, "teddy_vhacd.urdf: scale .1 (7.6 x 9.3 x 6.3 cm)"),
    "soccerball": _Classic("soccerball.obj", 0.08, "soccerball.urdf is 1 m across; 0.08 gives a hand ball"),
    "torus": _Classic("torus/torus_textured.obj", 0.06, "torus_deform.urdf is a soft body; 0.06 gives 9 cm"),
    "cylinder": _Classic("toys/cylinder.obj", 1.0, "toys set, metres already (7.7 x 11.6 x 5.8 cm)"),
    "prism": _Classic("toys/prism.obj", 1.0, "toys set, metres already (8.4 x 6.4 x 11.8 cm)"),
    "jenga": _Classic("jenga/jenga.obj", 1.0, "per-axis scale comes from jenga.urdf"),
    "domino": _Classic("domino/domino.obj", 1.0, "domino.urdf: scale 1 (2.5 x 0.6 x 5.1 cm)"),
}
"""Named pybullet_data meshes that load watertight after repair, with the scale used and why.
Checked in pybullet 3.2.7; mug, lego and toys/cube are left out (open surfaces that repair cannot close)."""

_PER_AXIS = {"jenga": (0.15, 0.05, 0.03)}  # jenga.urdf <mesh scale="0.15 0.05 0.03"> on a unit cube


def pybullet_data_dir() -> Path:
    """The installed ``pybullet_data`` folder (found without importing pybullet)."""
    spec = importlib.util.find_spec("pybullet_data")
    if spec is None or not spec.submodule_search_locations:
        raise AssetError("pybullet_data is not installed; `pip install 'ges-unigrasp[pybullet]'` provides it")
    return Path(next(iter(spec.submodule_search_locations)))


def urdf_mesh(urdf_path: Path) -> tuple[Path, tuple[float, float, float]]:
    """The first collision (else visual) mesh file a URDF references, and its ``scale``."""
    try:
        root = ET.parse(urdf_path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise AssetError(f"{urdf_path}: cannot read URDF ({exc})") from exc
    node = root.find(".//collision/geometry/mesh")
    node = root.find(".//visual/geometry/mesh") if node is None else node  # an Element with no children is falsy
    if node is None or not node.get("filename"):
        raise AssetError(f"{urdf_path}: no <mesh filename=...> in any collision or visual geometry")
    scale = tuple(float(v) for v in (node.get("scale") or "1 1 1").split())
    if len(scale) != 3:
        raise AssetError(f"{urdf_path}: mesh scale must have 3 numbers, got {node.get('scale')!r}")
    return urdf_path.parent / node.get("filename"), scale


def list_pybullet(*, random_urdfs: bool = True, classics: bool = True) -> list[ObjectEntry]:
    """pybullet_data's ``random_urdfs/NNN/NNN.urdf`` (category ``random_urdfs``) and :data:`CLASSICS`
    (each its own category)."""
    root = pybullet_data_dir()
    entries = []
    if random_urdfs:
        for urdf in sorted((root / "random_urdfs").glob("*/*.urdf")):
            mesh, scale = urdf_mesh(urdf)
            oid = f"pybullet/random_urdfs/{urdf.stem}"
            entries.append(
                ObjectEntry(object_id=oid, category="random_urdfs", source="pybullet", path=mesh, scale=scale)
            )
    if classics:
        for name, classic in CLASSICS.items():
            scale = _PER_AXIS.get(name, (classic.scale,) * 3)
            oid = f"pybullet/classic/{name}"
            entries.append(
                ObjectEntry(object_id=oid, category=name, source="pybullet", path=root / classic.file, scale=scale)
            )
    return entries


def list_user(folder: str | Path, *, scale: float = 1.0) -> list[ObjectEntry]:
    """Meshes laid out ``folder/<category>/<instance>.{obj,stl,ply,glb}``, ids ``user/<category>/<instance>``.

    scale: factor taking the files' units to metres (e.g. 0.001 for millimetre STL files).
    An ``objects.yaml`` in ``folder`` gives masses, densities, frictions and resting poses (:mod:`.properties`).
    Two files giving one id (``mug.obj`` and ``mug.stl``) make that one entry unusable (its ``problem``
    names both files); the rest of the folder is listed as usual.
    """
    folder = Path(folder).expanduser()
    if not folder.is_dir():
        raise AssetError(f"user object folder {folder} does not exist; lay it out as <category>/<instance>.obj")
    by_id: dict[str, list[Path]] = {}
    for path in sorted(p for p in folder.glob("*/*") if p.suffix.lower() in MESH_SUFFIXES and p.is_file()):
        by_id.setdefault(f"user/{path.parent.name}/{path.stem}", []).append(path)
    props = read_objects_file(folder, by_id)
    return [_user_entry(oid, paths, scale, props.get(oid)) for oid, paths in by_id.items()]


def _user_entry(object_id: str, paths: list[Path], scale: float, props: ObjectProperties | None) -> ObjectEntry:
    problem = None
    if len(paths) > 1:
        names = " and ".join(p.name for p in paths)
        problem = f"{names} in {paths[0].parent} both give this object id; rename or remove all but one of them"
    category = paths[0].parent.name
    props = props or ObjectProperties()
    return ObjectEntry(
        object_id=object_id, category=category, source="user", path=paths[0], scale=(scale,) * 3, problem=problem,
        mass=props.mass, density=props.density, friction=props.friction, rest=props.rest,
    )  # fmt: skip
