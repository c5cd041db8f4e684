"""Hand meshes in any format trimesh reads, turned into files every engine loads.

Measured with the installed engines: PyBullet 3.2.7 loads ``.obj``, ``.stl`` and ``.dae`` (a
``.glb`` gives "invalid mesh filename extension" and the shape is not created); SAPIEN 3.0.3 reads
meshes through assimp (``.glb`` collision loads) but on a CPU never loads visuals. So every mesh
that is not ``.obj`` or ``.stl`` is converted once to OBJ (geometry only: no ``.mtl``, no
textures) in the cache, named by a hash of the source file's bytes, and the URDF is rewritten to
point at it; both engines then read the same triangles.

Mesh file names may be relative to the URDF, absolute, ``file://`` or ``package://NAME/...`` (a
ROS robot-description package: resolved against the nearest folder above the URDF called NAME,
else against the URDF's folder and its parents).
"""

from __future__ import annotations

from pathlib import Path

from ges_core.errors import AssetError
from ges_core.paths import atomic_write_text, cache_dir, file_sha256

__all__ = [
    "ENGINE_MESH_FORMATS",
    "NATIVE_FORMATS",
    "converted_mesh",
    "converted_mesh_if_cached",
    "engine_mesh",
    "engines_that_cannot_load",
    "resolve_mesh_path",
]

NATIVE_FORMATS = (".obj", ".stl")
"""Suffixes passed to the engines as they are (case-sensitive: a CAD export's ``.STL`` is converted too, so
no engine's handling of upper-case suffixes matters); every other file is converted to OBJ."""
ENGINE_MESH_FORMATS: dict[str, tuple[str, ...]] = {
    "pybullet": (".obj", ".stl", ".dae"),
    "sapien": (".obj", ".stl", ".dae", ".glb", ".gltf", ".ply", ".off"),
}
"""Mesh suffixes each engine loads (PyBullet 3.2.7's URDF importer; SAPIEN 3.0.3 through assimp)."""
FORMAT_NAMES = {
    ".glb": "glTF binary",
    ".gltf": "glTF",
    ".dae": "COLLADA",
    ".ply": "PLY",
    ".off": "OFF",
    ".3mf": "3MF",
    ".fbx": "FBX",
}
"""Words for a suffix in messages."""
CONVERTER_VERSION = "1"
"""Part of every converted file's name: bump it when :func:`converted_mesh` writes something else."""


def resolve_mesh_path(filename: str, base_dir: Path) -> Path:
    """Absolute path of a URDF mesh ``filename`` (relative, absolute, ``file://`` or ``package://``)."""
    if filename.startswith("file://"):
        filename = filename[len("file://") :]
    if filename.startswith("package://"):
        package, _, rest = filename[len("package://") :].partition("/")
        return _package_path(package, rest, base_dir)
    path = Path(filename)
    return path if path.is_absolute() else (base_dir / path).resolve()


def _package_path(package: str, rest: str, base_dir: Path) -> Path:
    """``package://package/rest``: under an ancestor named ``package``, else the first ancestor holding ``rest``."""
    base_dir = base_dir.resolve()
    ancestors = [base_dir, *base_dir.parents]
    for folder in ancestors:
        if folder.name == package and (folder / rest).exists():
            return folder / rest
    for folder in ancestors:
        if (folder / rest).exists():
            return folder / rest
    return base_dir / rest


def engines_that_cannot_load(path: Path) -> list[str]:
    """Engines (of :data:`ENGINE_MESH_FORMATS`) whose loader rejects this file's format."""
    suffix = path.suffix.lower()
    return [engine for engine, formats in ENGINE_MESH_FORMATS.items() if suffix not in formats]


def format_name(path: Path) -> str:
    """``'glTF binary (.glb)'`` and the like."""
    suffix = path.suffix.lower()
    return f"{FORMAT_NAMES.get(suffix, suffix.lstrip('.').upper() or 'no-suffix')} ({suffix or 'no suffix'})"


def _converted_path(source: Path) -> Path:
    key = f"{file_sha256(source)}_v{CONVERTER_VERSION}"
    return cache_dir("hand_meshes") / f"{source.stem}_{key}.obj"


def converted_mesh_if_cached(source: Path) -> Path | None:
    """The OBJ conversion of ``source`` when it is already in the cache, else None."""
    path = _converted_path(source)
    return path if path.is_file() else None


def converted_mesh(source: Path) -> Path:
    """An OBJ with ``source``'s triangles (every node of a glTF scene placed and merged), cached by hash."""
    if not source.is_file():
        raise AssetError(f"mesh file {source} does not exist; fix the URDF's filename or install the missing package")
    path = _converted_path(source)
    if not path.is_file():
        atomic_write_text(path, _obj_text(source))
    return path


def engine_mesh(source: Path) -> Path:
    """The file the engines load for ``source``: itself in a :data:`NATIVE_FORMATS` format, else its OBJ copy."""
    return source if source.suffix in NATIVE_FORMATS else converted_mesh(source)


def _obj_text(source: Path) -> str:
    import trimesh
    from trimesh.exchange.obj import export_obj

    try:
        mesh = trimesh.load(str(source), force="mesh", process=False)
    except Exception as exc:  # noqa: BLE001 - trimesh raises many kinds; name the file
        raise AssetError(f"mesh {source}: trimesh cannot read it ({type(exc).__name__}: {exc})") from exc
    if len(getattr(mesh, "faces", ())) == 0:
        raise AssetError(f"mesh {source} holds no triangles (trimesh read {type(mesh).__name__}); export it as a mesh")
    return export_obj(mesh, include_normals=False, include_color=False, include_texture=False)
