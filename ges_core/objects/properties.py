"""Per-object properties: mass or density, friction, and how the object rests on the table.

Three places give them, the later winning: the source (the real set's published masses), an
``objects.yaml`` beside a user's meshes, and ``LibraryConfig.object_properties`` (what ``--mass``,
``--density`` and ``--friction`` on the command line fill). What none of them gives comes from the
library's ``density`` and ``friction``. A given mass sets the density to mass / collision volume, so
that every simulator (which computes mass from density and collision shapes) gets that mass.

``objects.yaml``::

    defaults:                 # every object of the folder (optional)
      friction: 0.8
    objects:                  # keyed <category>/<instance> (or the full id user/<category>/<instance>)
      mug/blue:   {mass: 0.35}          # kg
      fruit/pear: {density: 900, friction: 0.5}
      box/cereal: {rest: as_authored}   # stands as the file has it (z up), not in its most probable pose
      box/tray:   {rest: graspable}     # its most probable pose a hand can grasp across

``rest``: ``stable`` (the default: the most probable resting pose of :func:`.placement.stable_rotation`),
``graspable`` (the same, unless no squeeze across that pose is as narrow as :data:`.placement.GRASPABLE_WIDTH`,
12 cm: then the most probable pose with one that does not tip over; a flat cracker box stands on its side) or
``as_authored`` (the file's own orientation, its +z up; only moved so its lowest point is on the table and its
centre of mass above the origin). Scans are usually authored standing (the YCB boxes and bottles are), while their
most probable pose lies them flat. Stage 1 checks in both engines that the pose is stable before grasping.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator

from ges_core.config import STORED_WHEN_SET, ConfigModel, parse_model, read_yaml
from ges_core.errors import ConfigError

__all__ = [
    "OBJECTS_FILE",
    "Rest",
    "ObjectProperties",
    "ObjectsFile",
    "merge_properties",
    "parse_assignments",
    "read_objects_file",
]

OBJECTS_FILE = "objects.yaml"

Rest = Literal["stable", "graspable", "as_authored"]
"""How an object is set on the table (module docs)."""


class ObjectProperties(ConfigModel):
    """Physical properties and resting pose of one object; each one unset (None) falls back to the next source."""

    mass: float | None = Field(None, gt=0, description="kg; the density becomes mass / collision volume")
    density: float | None = Field(None, gt=0, description="kg/m^3")
    friction: float | None = Field(None, ge=0, description="Coulomb friction coefficient of the object's surface")
    rest: Rest | None = Field(
        None,
        description="stable (most probable resting pose, the default), graspable (the most probable one a hand can "
        "squeeze across: 12 cm or less) or as_authored (the file's +z up)",
        json_schema_extra=STORED_WHEN_SET,  # added after datasets were written: stored only when set
    )

    @model_validator(mode="after")
    def _mass_or_density(self) -> ObjectProperties:
        if self.mass is not None and self.density is not None:
            raise ValueError("give mass or density, not both (a mass sets the density)")
        return self


class ObjectsFile(ConfigModel):
    """The contents of a user folder's ``objects.yaml``."""

    defaults: ObjectProperties = Field(default_factory=ObjectProperties, description="for every object of the folder")
    objects: dict[str, ObjectProperties] = Field(
        default_factory=dict, description="per object, keyed <category>/<instance> (or user/<category>/<instance>)"
    )


def merge_properties(base: ObjectProperties | None, top: ObjectProperties | None) -> ObjectProperties | None:
    """``top`` over ``base``: a mass or density in ``top`` replaces both of ``base``'s; friction and rest field by
    field."""
    if base is None or top is None:
        return top if base is None else base
    weight = top if (top.mass is not None or top.density is not None) else base
    friction = top.friction if top.friction is not None else base.friction
    rest = top.rest if top.rest is not None else base.rest
    return ObjectProperties(mass=weight.mass, density=weight.density, friction=friction, rest=rest)


def read_objects_file(folder: Path, object_ids: Iterable[str]) -> dict[str, ObjectProperties]:
    """Properties per object id from ``folder/objects.yaml`` (empty when there is none).

    object_ids: the folder's ids (``user/<category>/<instance>``). ConfigError for unknown keys, bad values
    or a key naming no mesh of the folder (with the known names)."""
    path = folder / OBJECTS_FILE
    if not path.is_file():
        return {}
    parsed = parse_model(ObjectsFile, read_yaml(path), where=str(path))
    known = list(object_ids)
    found: dict[str, ObjectProperties] = {}
    for key, props in parsed.objects.items():
        oid = key if key.startswith("user/") else f"user/{key}"
        if oid not in known:
            names = ", ".join(k.removeprefix("user/") for k in known) or "none"
            raise ConfigError(f"{path}: objects.{key} names no mesh of {folder} (its objects: {names})")
        found[oid] = props
    return {oid: merge_properties(parsed.defaults, found.get(oid)) for oid in known}


def parse_assignments(
    items: Iterable[str], field: str, *, option: str, convert=float, example: str = "user/mug/blue=0.35"
) -> dict[str, dict]:
    """``["ID=VALUE", ...]`` (command line) -> ``{ID: {field: convert(VALUE)}}``; ConfigError naming ``option``
    (``convert`` raising ValueError: a bad value; its range is checked where the properties are parsed)."""
    out: dict[str, dict] = {}
    for item in items:
        oid, sep, raw = item.partition("=")
        try:
            value = convert(raw)
        except ValueError:
            value = None
        if not sep or not oid.strip() or value is None or value == "":
            what = "NUMBER" if convert is float else "VALUE"
            raise ConfigError(f"{option} '{item}': write OBJECT_ID={what}, e.g. {option} {example}")
        out.setdefault(oid.strip(), {})[field] = value
    return out
