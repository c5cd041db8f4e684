"""The URDF an engine loads for a hand: meshes it can read, no ``<mimic>``, prepared collision.

:func:`engine_urdf` is called by both simulator plugins on the hand's URDF text before anything
else of theirs (materials, floating base, inertias). It

1. removes ``<mimic>`` tags (:mod:`.mimic`: the followers stay PD-driven joints whose targets
   come from :meth:`HandDescription.apply_couplings`);
2. makes every mesh path absolute (relative, ``file://`` and ``package://`` names, see
   :func:`.meshes.resolve_mesh_path`) and replaces formats other than OBJ/STL by a cached OBJ
   conversion (:func:`.meshes.converted_mesh`), in visuals and collisions;
3. replaces a collision mesh by its convex parts when ``ges hand prepare`` decomposed that mesh
   (found in the cache by the mesh's hash, :func:`.decompose.cached_link_parts`).

A URDF that needs none of this (the built-in Allegro and Shadow files) is returned as the very
same string, so what those engines load is unchanged.
"""

from __future__ import annotations

import copy
import xml.etree.ElementTree as ET
from pathlib import Path

from ges_core.hand_prep.decompose import cached_link_parts
from ges_core.hand_prep.meshes import engine_mesh, resolve_mesh_path
from ges_core.hand_prep.mimic import strip_mimic
from ges_core.urdf import parse_urdf

__all__ = ["engine_urdf"]


def engine_urdf(text: str, base_dir: Path) -> str:
    """The engine-ready URDF text (module docs); ``base_dir``: folder relative mesh names start from."""
    text = strip_mimic(text)
    if "<mesh" not in text:
        return text
    root = parse_urdf(text)
    changed = _rewrite_meshes(root, Path(base_dir))
    changed = _use_prepared_collision(root) or changed
    return ET.tostring(root, encoding="unicode") if changed else text


def _rewrite_meshes(root: ET.Element, base_dir: Path) -> bool:
    """Absolute paths and OBJ conversions for every ``<mesh>`` (in place); True if any changed."""
    changed = False
    for mesh in root.iter("mesh"):
        name = mesh.get("filename", "")
        path = engine_mesh(resolve_mesh_path(name, base_dir))
        if str(path) != name:
            mesh.set("filename", str(path))
            changed = True
    return changed


def _use_prepared_collision(root: ET.Element) -> bool:
    """Swap each decomposed collision mesh for one ``<collision>`` per convex part (in place)."""
    changed = False
    for link in root.findall("link"):
        for collision in list(link):
            parts = _parts_of(collision) if collision.tag == "collision" else None
            if not parts:
                continue
            position = list(link).index(collision)
            link.remove(collision)
            for offset, part in enumerate(parts):
                link.insert(position + offset, _part_collision(collision, part))
            changed = True
    return changed


def _parts_of(collision: ET.Element) -> list[Path] | None:
    mesh = collision.find("geometry/mesh")
    return cached_link_parts(Path(mesh.get("filename"))) if mesh is not None else None


def _part_collision(collision: ET.Element, part: Path) -> ET.Element:
    """A copy of ``collision`` (origin, scale, name) whose mesh is the convex ``part``."""
    out = copy.deepcopy(collision)
    out.find("geometry/mesh").set("filename", str(part))
    return out
