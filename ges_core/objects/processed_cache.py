"""On-disk cache of processed file meshes: a second command on the same object loads, not reprocesses.

Processing a 16k-face scan (repair, resting pose, hull test) takes 0.5-3 s; ``ges objects list --sizes``,
``prepare`` and every Stage 1 worker used to repeat it. Layout: ``<cache_dir>/objects/processed/<key>.npz``
(the placed mesh's exact float64 vertices and faces, plus its kind, volume, hull depth and min width). The
key covers the source file's bytes, the processing options and the code of the modules that process (so a code
change never serves a stale result): their syntax trees without docstrings (:func:`code_hash`), so reformatting,
comments and docstrings keep the cache. Procedural shapes are built in milliseconds: not cached.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import io
import json
import zipfile
from pathlib import Path

import numpy as np
import trimesh

from ges_core.objects.sources import ObjectEntry
from ges_core.paths import atomic_write_bytes, cache_dir, file_sha256

__all__ = ["cache_key", "code_hash", "load_processed", "store_processed"]

_MODULES = ("processing.py", "placement.py", "validate.py", "bounds.py", "decompose.py", "processed_cache.py")
"""Modules (in this folder) whose code is part of every key: the code that produces a processed object."""


def code_hash(sources: list[str]) -> str:
    """16 hex digits of the modules' code: each source's syntax tree (``ast.dump``, no line numbers) without its
    bare string statements (docstrings, attribute notes), so layout, comments and docstrings do not count and every
    other change does."""
    trees = []
    for text in sources:
        tree = ast.parse(text)
        for node in ast.walk(tree):
            for name in ("body", "orelse", "finalbody"):
                block = getattr(node, name, None)
                if isinstance(block, list) and block and isinstance(block[0], ast.stmt):
                    kept = [s for s in block if not (isinstance(s, ast.Expr) and _is_text(s.value))]
                    setattr(node, name, kept or [ast.Pass()])
        trees.append(ast.dump(tree))
    return hashlib.sha256("\n".join(trees).encode()).hexdigest()[:16]


def _is_text(value: ast.expr) -> bool:
    return isinstance(value, ast.Constant) and isinstance(value.value, str)


@functools.cache  # the sources do not change while a process runs: read them once, not per object
def _code_hash() -> str:
    here = Path(__file__).parent
    return code_hash([(here / name).read_text() for name in _MODULES])


def cache_key(entry: ObjectEntry, *, normalize_size: float | None, max_faces: int) -> str | None:
    """The cache key of a file entry, or None (procedural, or no readable file: processing reports it)."""
    if entry.source == "procedural" or entry.path is None or not Path(entry.path).is_file():
        return None
    spec = {
        "file": file_sha256(entry.path, length=32),
        "suffix": Path(entry.path).suffix.lower(),
        "scale": list(entry.scale),
        "source": entry.source,
        "normalize_size": normalize_size,
        "max_faces": max_faces,
        "rest": entry.rest or "stable",
        "code": _code_hash(),
    }
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:24]


def _path(key: str) -> Path:
    return cache_dir("objects", "processed") / f"{key}.npz"


def load_processed(key: str, entry: ObjectEntry):
    """The cached :class:`.processing.ProcessedObject` of ``key`` for ``entry``, or None."""
    from ges_core.objects.processing import ProcessedObject

    path = _path(key)
    if not path.is_file():
        return None
    try:
        with np.load(path) as data:
            meta = json.loads(str(data["meta"]))
            mesh = trimesh.Trimesh(data["vertices"], data["faces"], process=False)
    except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile):  # damaged entry: a miss, rewritten
        return None
    mesh_path = cache_dir("objects", "meshes") / meta["mesh_file"]
    if not mesh_path.is_file():  # the mesh cache was cleared: process again
        return None
    return ProcessedObject(
        entry=entry, mesh=mesh, mesh_path=mesh_path, mesh_hash=meta["mesh_hash"], kind=meta["kind"],
        volume=meta["volume"], hull_depth=meta["hull_depth"], min_width=meta["min_width"],
    )  # fmt: skip


def store_processed(key: str, obj) -> None:
    """Write ``obj`` (a file mesh's :class:`.processing.ProcessedObject`) under ``key``, atomically."""
    meta = {
        "mesh_file": obj.mesh_path.name, "mesh_hash": obj.mesh_hash, "kind": obj.kind, "volume": obj.volume,
        "hull_depth": obj.hull_depth, "min_width": obj.min_width,
    }  # fmt: skip
    buffer = io.BytesIO()
    np.savez(buffer, vertices=np.asarray(obj.mesh.vertices), faces=np.asarray(obj.mesh.faces), meta=json.dumps(meta))
    atomic_write_bytes(_path(key), buffer.getvalue())
