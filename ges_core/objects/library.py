"""``ObjectLibrary``: list objects, get an :class:`ObjectAsset` or a point cloud by id.

>>> lib = ObjectLibrary(LibraryConfig(sources=("procedural",), procedural_count=3))
>>> [o.object_id for o in lib.list(split="train")][:2]
>>> asset = lib.get("procedural/can/001")          # primitive: exact cylinder collision
>>> points, normals = lib.point_cloud("procedural/mug/000", 1024, fps=True)
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np
from pydantic import Field, field_validator, model_validator

from ges_core.config import STORED_WHEN_SET, ConfigModel, parse_model
from ges_core.errors import ConfigError, UnknownNameError
from ges_core.objects.asset import ObjectAsset
from ges_core.objects.bounds import DEFAULT_MAX_FACES
from ges_core.objects.decompose import FAST, CoacdSettings
from ges_core.objects.pointcloud import sample_surface
from ges_core.objects.procedural import HELD_OUT_CATEGORIES
from ges_core.objects.processing import ProcessedObject, collision_shapes, collision_volume, min_width, process_entry
from ges_core.objects.properties import ObjectProperties, Rest, merge_properties
from ges_core.objects.real import list_real
from ges_core.objects.sources import SOURCES, ObjectEntry, list_procedural, list_pybullet, list_user
from ges_core.objects.splits import SPLITS, assign_splits

__all__ = ["LibraryConfig", "ObjectInfo", "ObjectLibrary", "UnknownObjectError"]

_ASSET_DEFAULTS = ObjectAsset(object_id="", category="", mesh_path=Path(), collision=())


class LibraryConfig(ConfigModel):
    """Which objects the library holds and how it processes them (also a Stage 1 run's ``library`` section)."""

    sources: tuple[str, ...] = Field(
        ("procedural", "pybullet"), description="procedural, pybullet, real (the YCB scans, extra [real]) and/or user"
    )
    seed: int = Field(0, description="seed of the procedural dimensions")
    procedural_count: int = Field(10, ge=0, description="objects per procedural category")
    user_dir: Path | None = Field(
        None, description="folder <category>/<instance>.{obj,stl,ply,glb} of user objects (a str or a Path)"
    )
    user_scale: float = Field(1.0, gt=0, description="factor taking the user files' units to metres")
    normalize_size: float | None = Field(
        None, gt=0, description="if set, every object is scaled uniformly so its largest extent is this many metres"
    )
    max_faces: int = Field(
        DEFAULT_MAX_FACES,
        ge=100,
        description="faces; a loaded mesh with more is simplified to this many before repair (bounds the time and "
        "memory one object costs: a 1.3M-face scan otherwise hangs every command)",
    )
    split_seed: int = Field(0, description="seed of the train / unseen splits")
    held_out_categories: tuple[str, ...] = Field(
        HELD_OUT_CATEGORIES,
        description="categories always in the unseen-category split; the seeded draw runs over the others (default: "
        "the four procedural categories added for that split, so no earlier object's split moved; [] draws over all)",
    )
    coacd: CoacdSettings = Field(default_factory=lambda: FAST, description="decomposition settings (cache key)")
    decompose: bool = Field(
        False, description="compute a missing convex decomposition on demand (slow, ~5-20 s per mesh, then cached)"
    )
    density: float = Field(_ASSET_DEFAULTS.density, gt=0, description="kg/m^3 of every object")
    friction: float = Field(_ASSET_DEFAULTS.friction, description="friction coefficient of every object")
    rest: Rest = Field(
        "stable",
        description="how every object rests on the table unless its own rest says otherwise: stable (its most "
        "probable resting pose), graspable (the most probable one a hand can squeeze across, 12 cm or "
        "less, if the most probable is not) or as_authored (its file's +z up; procedural shapes are built upright "
        "either way)",
        json_schema_extra=STORED_WHEN_SET,  # added after datasets were written: stored only when set
    )
    object_properties: dict[str, ObjectProperties] = Field(
        default_factory=dict,
        description="per object id: mass (kg) or density (kg/m^3), friction, rest (stable, graspable or as_authored); "
        "over the source's and objects.yaml's",
    )

    @field_validator("sources")
    @classmethod
    def _known_sources(cls, sources: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [s for s in sources if s not in SOURCES]
        if unknown:
            raise ValueError(f"unknown source(s) {unknown} (known: {', '.join(SOURCES)})")
        return sources

    @model_validator(mode="after")
    def _user_needs_a_folder(self) -> LibraryConfig:
        if "user" in self.sources and self.user_dir is None:
            raise ValueError("user_dir: required when sources include 'user'")
        return self

    def build(self) -> ObjectLibrary:
        """The :class:`ObjectLibrary` these settings describe."""
        return ObjectLibrary(self)


def _check_held_out(config: LibraryConfig, categories: set[str]) -> None:
    """ConfigError for a held-out name that is no category of the library (a typo would silently hold out
    nothing); the default names are exempt, as a library without the procedural source lacks them."""
    unknown = sorted(set(config.held_out_categories) - categories - set(HELD_OUT_CATEGORIES))
    if unknown:
        hints = [f"{u} (did you mean {', '.join(c)}?)" if (c := difflib.get_close_matches(u, categories, 2)) else u
                 for u in unknown]  # fmt: skip
        raise ConfigError(
            f"held_out_categories: {'; '.join(hints)} is no category of the library (sources "
            f"{', '.join(config.sources)}: {len(categories)} categories, `ges objects list` shows them)"
        )


@dataclass(frozen=True)
class ObjectInfo:
    """One row of :meth:`ObjectLibrary.list`."""

    object_id: str
    category: str
    source: str
    split: str


class UnknownObjectError(UnknownNameError):
    """An object id that the library does not hold (short message: the libraries are large)."""

    def __init__(self, name: str, known: list[str], *, list_command: str = "ges objects list") -> None:
        close = difflib.get_close_matches(name, known, n=3)
        hint = f" Did you mean {', '.join(close)}?" if close else ""
        msg = f"unknown object '{name}'.{hint} `{list_command}` shows the {len(known)} known ids."
        KeyError.__init__(self, msg)
        self.kind, self.name, self.known = "object", name, known


class ObjectLibrary:
    """All objects of the configured sources, with splits, assets, point clouds and sizes."""

    def __init__(self, config: LibraryConfig | None = None, **overrides) -> None:
        config = config or LibraryConfig()
        if overrides:
            config = parse_model(LibraryConfig, {**dict(config), **overrides}, where="object library config")
        if config.user_dir is not None and "user" not in config.sources and not overrides.get("sources"):
            config = config.model_copy(update={"sources": (*config.sources, "user")})
        self.config = config
        self._processed: dict[str, ProcessedObject] = {}

    @cached_property
    def _entries(self) -> dict[str, ObjectEntry]:
        cfg, found = self.config, []
        if "procedural" in cfg.sources:
            found += list_procedural(count=cfg.procedural_count, seed=cfg.seed)
        if "pybullet" in cfg.sources:
            found += list_pybullet()
        if "real" in cfg.sources:
            found += list_real()
        if "user" in cfg.sources:
            found += list_user(cfg.user_dir, scale=cfg.user_scale)
        entries = {e.object_id: e for e in found}
        unknown = sorted(set(cfg.object_properties) - set(entries))
        if unknown:
            raise ConfigError(f"object_properties: {', '.join(unknown)} not in the library (sources {cfg.sources})")
        for oid, e in entries.items():  # how each rests: the run's object_properties, the source's own, the library's
            rest = getattr(cfg.object_properties.get(oid), "rest", None) or e.rest or cfg.rest
            entries[oid] = replace(e, rest=rest) if rest != e.rest else e
        _check_held_out(cfg, {e.category for e in entries.values()})
        return entries

    @cached_property
    def splits(self) -> dict[str, str]:
        """object id → ``train`` / ``unseen_object`` / ``unseen_category`` (see :mod:`.splits`)."""
        items = ((e.object_id, e.category) for e in self._entries.values())
        return assign_splits(items, seed=self.config.split_seed, held_out=self.config.held_out_categories)

    def entries(self, *, source: str | None = None, split: str | None = None) -> list[ObjectEntry]:
        """Entries in listing order, optionally of one source and one split."""
        if split is not None and split not in SPLITS:
            raise ConfigError(f"unknown split '{split}'; choose one of {', '.join(SPLITS)}")
        return [
            e
            for e in self._entries.values()
            if (source is None or e.source == source) and (split is None or self.splits[e.object_id] == split)
        ]

    def list(self, *, source: str | None = None, split: str | None = None) -> list[ObjectInfo]:
        """One :class:`ObjectInfo` per object; reads no mesh."""
        return [
            ObjectInfo(e.object_id, e.category, e.source, self.splits[e.object_id])
            for e in self.entries(source=source, split=split)
        ]

    def entry(self, object_id: str) -> ObjectEntry:
        """The entry of ``object_id``; UnknownObjectError (a KeyError) if there is none."""
        try:
            return self._entries[object_id]
        except KeyError:
            command = "ges objects list" + (f" --user-dir {self.config.user_dir}" if self.config.user_dir else "")
            raise UnknownObjectError(object_id, list(self._entries), list_command=command) from None

    def processed(self, object_id: str) -> ProcessedObject:
        """Repaired, placed geometry of ``object_id`` (memoized per library)."""
        if object_id not in self._processed:
            cfg = self.config
            entry = self.entry(object_id)
            self._processed[object_id] = process_entry(
                entry, normalize_size=cfg.normalize_size, max_faces=cfg.max_faces
            )
        return self._processed[object_id]

    def get(self, object_id: str, *, decompose: bool | None = None) -> ObjectAsset:
        """The :class:`ObjectAsset` of ``object_id``.

        decompose: compute a missing CoACD decomposition now (default: ``config.decompose``); when
        False a concave object without a cached decomposition raises an AssetError that says to run
        ``ges objects prepare``.
        """
        obj = self.processed(object_id)
        compute = self.config.decompose if decompose is None else decompose
        cfg = self.config
        collision = collision_shapes(obj, cfg.coacd, compute=compute)
        props = self.properties(object_id)
        if props.mass is not None:  # simulators take density x collision volume: this gives them this mass
            density, mass = props.mass / collision_volume(collision), props.mass
        else:
            density, mass = props.density, props.density * obj.volume
        return ObjectAsset(
            object_id=object_id, category=obj.entry.category, mesh_path=obj.mesh_path, collision=collision,
            density=density, mass=mass, friction=props.friction,
        )  # fmt: skip

    def properties(self, object_id: str) -> ObjectProperties:
        """The mass / density / friction of ``object_id``: those given (source, objects.yaml, then
        ``config.object_properties``), with ``config.density`` when neither a mass nor a density is given and
        ``config.friction`` when no friction is. Exactly one of mass and density is set; friction always is."""
        entry = self.entry(object_id)
        own = ObjectProperties(mass=entry.mass, density=entry.density, friction=entry.friction)
        given = merge_properties(own, self.config.object_properties.get(object_id))
        cfg = self.config
        density = cfg.density if given.mass is None and given.density is None else given.density
        friction = cfg.friction if given.friction is None else given.friction
        # constructed as is: the library's own density and friction were checked (or not) by LibraryConfig
        return ObjectProperties.model_construct(mass=given.mass, density=density, friction=friction)

    def point_cloud(
        self, object_id: str, n: int = 2048, *, seed: int = 0, fps: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """Surface points (n, 3) and outward unit normals (n, 3), object frame, metres (seeded)."""
        return sample_surface(self.processed(object_id).mesh, n, seed=seed, fps=fps)

    def extents(self, object_id: str) -> np.ndarray:
        """(3,) axis-aligned size (m) in the resting object frame."""
        return np.asarray(self.processed(object_id).mesh.extents, dtype=np.float64)

    def min_width(self, object_id: str) -> float:
        """Narrowest width (m) across the object (convex hull); compare with a hand's span."""
        obj = self.processed(object_id)
        return obj.min_width if obj.min_width is not None else min_width(obj.mesh)
